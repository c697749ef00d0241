//! Semi-global path aggregation and winner selection, streamed row by row: the hot part of
//! [`crate::depth::sgm`] (its module docs give the recurrence, eq. 13 of Hirschmüller 2008).
//!
//! The 8 (or 4) directions are split into two passes that run at the same time on two threads:
//! a forward pass over the rows from top to bottom (left→right, and the three paths entering
//! from the row above: ↓, ↘, ↙) and a backward pass from bottom to top (right→left, ↑, ↗, ↖).
//! Each pass keeps one row of path costs per direction, updated in place pixel by pixel, never
//! a whole `L_r`. For every row, the pass that reaches it first stores its four-path sum in a
//! shared buffer (claiming the row with an atomic compare-and-swap, so it never waits while
//! holding a claim); the second adds its own sum pixel by pixel and selects the winner at once
//! (winner-take-all, uniqueness, the right image's winners), then finishes the row (sub-pixel
//! fit, left–right check, confidence). `S` is thus never stored whole: each row is written once
//! and read once, by whichever pass comes second, and two passes of 4 directions replace three
//! sweeps over an 8-direction sum in memory.
//!
//! Sums of integers do not depend on the order of addition, so the result is bit-identical to
//! summing the paths one after the other (`tests/depth/sgm.rs` checks it against a direct
//! implementation of eq. 13). When the two closures of `rayon::join` run one after the other (no
//! idle worker), the first pass claims every row and the second selects every row: same result,
//! no waiting.
//!
//! The inner loops run over the disparities of one pixel (contiguous in the cost volume) and are
//! compiled three times on x86-64 (AVX-512BW, AVX2, baseline), picked at run time.

use super::sgm::{CostVolume, SgmParams, SgmPaths, SubpixelFit};
use crate::frame::Image;
use std::sync::atomic::{AtomicU8, Ordering};

/// Sentinel for "no such disparity" in padded path buffers; larger than any path cost plus P2,
/// small enough that adding P1 cannot overflow `u16`.
pub(crate) const BIG: u16 = 16_384;

/// Row claim states.
const FREE: u8 = 0;
const CLAIMED: u8 = 1;
const STORED: u8 = 2;

/// P1, P2 and the optional intensity adaptation, as integers for the inner loops.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Penalties {
    pub(crate) p1: u16,
    pub(crate) p2: u16,
    /// P2 for every intensity step |ΔI| (0–255): `max(P1 + 1, P2·s / (s + |ΔI|))` with the
    /// adaptation's scale `s`, or P2 throughout without it.
    table: [u16; 256],
}

impl Penalties {
    pub(crate) fn of(params: &SgmParams) -> Self {
        let (p1, p2) = (params.p1, params.p2);
        let table = std::array::from_fn(|delta| match params.p2_intensity_scale {
            None => p2,
            Some(s) => {
                let s = s as u32;
                let p = (p2 as u32 * s / (s + delta as u32)) as u16;
                p.max(p1 + 1)
            }
        });
        Penalties { p1, p2, table }
    }

    /// P2 between consecutive path pixels of intensities `a` and `b`.
    #[inline(always)]
    pub(crate) fn p2_for(&self, a: u8, b: u8) -> u16 {
        self.table[a.abs_diff(b) as usize]
    }
}

/// How path costs `L_r` are stored between pixels: `u8` when every `L_r` fits (the census's
/// largest cost plus P2 at most 254: `L_r ≤ C + P2`), else `u16`, so that a pass's row of path
/// costs stays in the core's cache. The arithmetic is `u16` either way.
pub(crate) trait Cell: Copy + Default + Send + Sync + std::fmt::Debug + 'static {
    /// Padding before the first and after the last slice: never the best predecessor (it is at
    /// least the largest cost plus P2, so `PAD + P1` loses to the jump `min + P2`).
    const PAD: Self;
    /// The value, for the arithmetic.
    fn widen(self) -> u16;
    /// A value computed in `u16` (fits by the choice of the type).
    fn narrow(v: u16) -> Self;
}

impl Cell for u8 {
    const PAD: u8 = u8::MAX;
    #[inline(always)]
    fn widen(self) -> u16 {
        self as u16
    }
    #[inline(always)]
    fn narrow(v: u16) -> u8 {
        v as u8
    }
}

impl Cell for u16 {
    const PAD: u16 = BIG;
    #[inline(always)]
    fn widen(self) -> u16 {
        self
    }
    #[inline(always)]
    fn narrow(v: u16) -> u16 {
        v
    }
}

/// One step of eq. 13 along a path: `out[1..=D]` ← L_r(p, ·) from `prev[1..=D]` (= L_r(p−r, ·),
/// padded with [`Cell::PAD`] at 0 and D+1), and `acc` gets it added (or assigned when
/// `ASSIGN`). Returns `min_d L_r(p, d)`.
#[inline(always)]
pub(crate) fn path_step<const ASSIGN: bool, T: Cell>(
    cost: &[u8],
    prev: &[T],
    prev_min: u16,
    p1: u16,
    p2: u16,
    out: &mut [T],
    acc: &mut [u16],
) -> u16 {
    let d = cost.len();
    let (lo, mid, hi) = (&prev[0..d], &prev[1..d + 1], &prev[2..d + 2]);
    let out = &mut out[1..d + 1];
    let acc = &mut acc[..d];
    let jump = prev_min + p2;
    let mut m = u16::MAX;
    for k in 0..d {
        let best = mid[k]
            .widen()
            .min(lo[k].widen() + p1)
            .min(hi[k].widen() + p1)
            .min(jump);
        let v = cost[k] as u16 + best - prev_min;
        out[k] = T::narrow(v);
        if ASSIGN {
            acc[k] = v;
        } else {
            acc[k] += v;
        }
        m = m.min(v);
    }
    m
}

/// First pixel of a path: `L_r = C`.
#[inline(always)]
pub(crate) fn path_start<const ASSIGN: bool, T: Cell>(
    cost: &[u8],
    out: &mut [T],
    acc: &mut [u16],
) -> u16 {
    let d = cost.len();
    let out = &mut out[1..d + 1];
    let acc = &mut acc[..d];
    let mut m = u16::MAX;
    for k in 0..d {
        let v = cost[k] as u16;
        out[k] = T::narrow(v);
        if ASSIGN {
            acc[k] = v;
        } else {
            acc[k] += v;
        }
        m = m.min(v);
    }
    m
}

/// [`path_step`] for the 4 directions of a pass at once (all continuing a path): one pass
/// over the disparities computes every direction's `L_r` and their sum, which `acc` receives
/// (assigned). Returns the directions' minima. Separate slice arguments (not arrays of slices)
/// let the compiler know that outputs and inputs do not overlap, so the loop vectorises without
/// run-time overlap checks.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn path_steps4<T: Cell>(
    cost: &[u8],
    (pa, pb, pc, pd): (&[T], &[T], &[T], &[T]),
    prev_min: [u16; 4],
    p1: u16,
    p2: [u16; 4],
    oa: &mut [T],
    ob: &mut [T],
    oc: &mut [T],
    od: &mut [T],
    acc: &mut [u16],
) -> [u16; 4] {
    let d = cost.len();
    let acc = &mut acc[..d];
    let (pa, pb, pc, pd) = (&pa[..d + 2], &pb[..d + 2], &pc[..d + 2], &pd[..d + 2]);
    let (oa, ob, oc, od) = (
        &mut oa[1..d + 1],
        &mut ob[1..d + 1],
        &mut oc[1..d + 1],
        &mut od[1..d + 1],
    );
    let [ja, jb, jc, jd] = [0, 1, 2, 3].map(|r| prev_min[r] + p2[r]);
    let [pma, pmb, pmc, pmd] = prev_min;
    // Separate scalar minima (not an array): recognised as reductions, so the loop vectorises.
    let (mut ma, mut mb, mut mc, mut md) = (u16::MAX, u16::MAX, u16::MAX, u16::MAX);
    for k in 0..d {
        let c = cost[k] as u16;
        let ba = pa[k + 1]
            .widen()
            .min(pa[k].widen() + p1)
            .min(pa[k + 2].widen() + p1)
            .min(ja);
        let bb = pb[k + 1]
            .widen()
            .min(pb[k].widen() + p1)
            .min(pb[k + 2].widen() + p1)
            .min(jb);
        let bc = pc[k + 1]
            .widen()
            .min(pc[k].widen() + p1)
            .min(pc[k + 2].widen() + p1)
            .min(jc);
        let bd = pd[k + 1]
            .widen()
            .min(pd[k].widen() + p1)
            .min(pd[k + 2].widen() + p1)
            .min(jd);
        let (va, vb, vc, vd) = (c + ba - pma, c + bb - pmb, c + bc - pmc, c + bd - pmd);
        oa[k] = T::narrow(va);
        ob[k] = T::narrow(vb);
        oc[k] = T::narrow(vc);
        od[k] = T::narrow(vd);
        acc[k] = va + vb + vc + vd;
        ma = ma.min(va);
        mb = mb.min(vb);
        mc = mc.min(vc);
        md = md.min(vd);
    }
    [ma, mb, mc, md]
}

/// [`path_steps4`] for the pass that comes second to a row: the 4-path sum plus the other
/// pass's (`theirs`) gives `S` of the pixel, written to `total`; returns the directions' minima
/// and `min_d S`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn path_steps4_total<T: Cell>(
    cost: &[u8],
    (pa, pb, pc, pd): (&[T], &[T], &[T], &[T]),
    prev_min: [u16; 4],
    p1: u16,
    p2: [u16; 4],
    oa: &mut [T],
    ob: &mut [T],
    oc: &mut [T],
    od: &mut [T],
    theirs: &[u16],
    total: &mut [u16],
) -> ([u16; 4], u16) {
    let d = cost.len();
    let (theirs, total) = (&theirs[..d], &mut total[..d]);
    let (pa, pb, pc, pd) = (&pa[..d + 2], &pb[..d + 2], &pc[..d + 2], &pd[..d + 2]);
    let (oa, ob, oc, od) = (
        &mut oa[1..d + 1],
        &mut ob[1..d + 1],
        &mut oc[1..d + 1],
        &mut od[1..d + 1],
    );
    let [ja, jb, jc, jd] = [0, 1, 2, 3].map(|r| prev_min[r] + p2[r]);
    let [pma, pmb, pmc, pmd] = prev_min;
    let (mut ma, mut mb, mut mc, mut md) = (u16::MAX, u16::MAX, u16::MAX, u16::MAX);
    let mut mt = u16::MAX;
    for k in 0..d {
        let c = cost[k] as u16;
        let best = |p: &[T], j: u16| {
            p[k + 1]
                .widen()
                .min(p[k].widen() + p1)
                .min(p[k + 2].widen() + p1)
                .min(j)
        };
        let (ba, bb, bc, bd) = (best(pa, ja), best(pb, jb), best(pc, jc), best(pd, jd));
        let (va, vb, vc, vd) = (c + ba - pma, c + bb - pmb, c + bc - pmc, c + bd - pmd);
        oa[k] = T::narrow(va);
        ob[k] = T::narrow(vb);
        oc[k] = T::narrow(vc);
        od[k] = T::narrow(vd);
        let t = va + vb + vc + vd + theirs[k];
        total[k] = t;
        ma = ma.min(va);
        mb = mb.min(vb);
        mc = mc.min(vc);
        md = md.min(vd);
        mt = mt.min(t);
    }
    ([ma, mb, mc, md], mt)
}

/// [`path_steps4`] for the 2 directions of a 4-path pass.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn path_steps2<T: Cell>(
    cost: &[u8],
    (pa, pb): (&[T], &[T]),
    prev_min: [u16; 2],
    p1: u16,
    p2: [u16; 2],
    oa: &mut [T],
    ob: &mut [T],
    acc: &mut [u16],
) -> [u16; 2] {
    let d = cost.len();
    let acc = &mut acc[..d];
    let (pa, pb) = (&pa[..d + 2], &pb[..d + 2]);
    let (oa, ob) = (&mut oa[1..d + 1], &mut ob[1..d + 1]);
    let (ja, jb) = (prev_min[0] + p2[0], prev_min[1] + p2[1]);
    let (pma, pmb) = (prev_min[0], prev_min[1]);
    let (mut ma, mut mb) = (u16::MAX, u16::MAX);
    for k in 0..d {
        let c = cost[k] as u16;
        let ba = pa[k + 1]
            .widen()
            .min(pa[k].widen() + p1)
            .min(pa[k + 2].widen() + p1)
            .min(ja);
        let bb = pb[k + 1]
            .widen()
            .min(pb[k].widen() + p1)
            .min(pb[k + 2].widen() + p1)
            .min(jb);
        let (va, vb) = (c + ba - pma, c + bb - pmb);
        oa[k] = T::narrow(va);
        ob[k] = T::narrow(vb);
        acc[k] = va + vb;
        ma = ma.min(va);
        mb = mb.min(vb);
    }
    [ma, mb]
}

/// The arguments of [`path_steps4`] after the cost: predecessors, their minima, P1, P2s,
/// outputs, sum.
type Steps4Args<'a, T> = (
    (&'a [T], &'a [T], &'a [T], &'a [T]),
    [u16; 4],
    u16,
    [u16; 4],
    [&'a mut [T]; 4],
    &'a mut [u16],
);

/// The pixel kernels compiled for one instruction set. They stay out of line: as separate
/// functions their slice arguments are known not to overlap, so the loops vectorise (inlined
/// into the pass, with the slices taken from shared buffers, they did not).
trait Isa {
    /// [`winner`].
    fn winner(
        total: &[u16],
        best: u16,
        right: (&mut [u16], &mut [u16]),
        x: usize,
        w: usize,
        dmin: i32,
    ) -> (usize, u16);
    fn steps4<T: Cell>(cost: &[u8], a: Steps4Args<'_, T>) -> [u16; 4];
    fn steps4_total<T: Cell>(cost: &[u8], a: Steps4Args<'_, T>, theirs: &[u16]) -> ([u16; 4], u16);
    #[allow(clippy::too_many_arguments)]
    fn steps2<T: Cell>(
        cost: &[u8],
        prev: (&[T], &[T]),
        prev_min: [u16; 2],
        p1: u16,
        p2: [u16; 2],
        oa: &mut [T],
        ob: &mut [T],
        acc: &mut [u16],
    ) -> [u16; 2];
}

macro_rules! isa {
    ($name:ident, $win:ident, $s4:ident, $s4t:ident, $s2:ident, $($feature:literal)?) => {
        struct $name;
        $(#[target_feature(enable = $feature)])?
        #[inline(never)]
        fn $win(
            total: &[u16],
            best: u16,
            (right_cost, right_k): (&mut [u16], &mut [u16]),
            x: usize,
            w: usize,
            dmin: i32,
        ) -> (usize, u16) {
            winner(total, best, right_cost, right_k, x, w, dmin)
        }
        $(#[target_feature(enable = $feature)])?
        #[inline(never)]
        fn $s4<T: Cell>(cost: &[u8], a: Steps4Args<'_, T>) -> [u16; 4] {
            let (prev, pmin, p1, p2, [oa, ob, oc, od], acc) = a;
            path_steps4(cost, prev, pmin, p1, p2, oa, ob, oc, od, acc)
        }
        $(#[target_feature(enable = $feature)])?
        #[inline(never)]
        fn $s4t<T: Cell>(
            cost: &[u8],
            a: Steps4Args<'_, T>,
            theirs: &[u16],
        ) -> ([u16; 4], u16) {
            let (prev, pmin, p1, p2, [oa, ob, oc, od], total) = a;
            path_steps4_total(cost, prev, pmin, p1, p2, oa, ob, oc, od, theirs, total)
        }
        $(#[target_feature(enable = $feature)])?
        #[inline(never)]
        #[allow(clippy::too_many_arguments)]
        fn $s2<T: Cell>(
            cost: &[u8],
            prev: (&[T], &[T]),
            prev_min: [u16; 2],
            p1: u16,
            p2: [u16; 2],
            oa: &mut [T],
            ob: &mut [T],
            acc: &mut [u16],
        ) -> [u16; 2] {
            path_steps2(cost, prev, prev_min, p1, p2, oa, ob, acc)
        }
        impl Isa for $name {
            #[inline(always)]
            fn winner(
                total: &[u16],
                best: u16,
                right: (&mut [u16], &mut [u16]),
                x: usize,
                w: usize,
                dmin: i32,
            ) -> (usize, u16) {
                // SAFETY: `run_pass` and `select_row` instantiate this instruction set only
                // where the CPU has it.
                #[allow(unused_unsafe)]
                unsafe {
                    $win(total, best, right, x, w, dmin)
                }
            }
            #[inline(always)]
            fn steps4<T: Cell>(cost: &[u8], a: Steps4Args<'_, T>) -> [u16; 4] {
                // SAFETY: `run_pass` instantiates this instruction set only where the CPU has
                // it.
                #[allow(unused_unsafe)]
                unsafe {
                    $s4(cost, a)
                }
            }
            #[inline(always)]
            fn steps4_total<T: Cell>(
                cost: &[u8],
                a: Steps4Args<'_, T>,
                theirs: &[u16],
            ) -> ([u16; 4], u16) {
                // SAFETY: as above.
                #[allow(unused_unsafe)]
                unsafe {
                    $s4t(cost, a, theirs)
                }
            }
            #[inline(always)]
            fn steps2<T: Cell>(
                cost: &[u8],
                prev: (&[T], &[T]),
                prev_min: [u16; 2],
                p1: u16,
                p2: [u16; 2],
                oa: &mut [T],
                ob: &mut [T],
                acc: &mut [u16],
            ) -> [u16; 2] {
                // SAFETY: as above.
                #[allow(unused_unsafe)]
                unsafe {
                    $s2(cost, prev, prev_min, p1, p2, oa, ob, acc)
                }
            }
        }
    };
}

isa!(
    Baseline,
    winner_baseline,
    steps4_baseline,
    steps4t_baseline,
    steps2_baseline,
);
#[cfg(target_arch = "x86_64")]
isa!(
    Avx2,
    winner_avx2,
    steps4_avx2,
    steps4t_avx2,
    steps2_avx2,
    "avx2"
);
#[cfg(target_arch = "x86_64")]
isa!(
    Avx512,
    winner_avx512,
    steps4_avx512,
    steps4t_avx512,
    steps2_avx512,
    "avx512f,avx512bw,avx512vl,avx2"
);

/// Rows of a buffer that two threads share, each row used by one thread at a time (the claim
/// protocol of the module docs decides which).
struct SharedRows<T> {
    ptr: *mut T,
    row_len: usize,
    rows: usize,
}

// SAFETY: the buffer outlives the passes (it is borrowed for the whole `rayon::join`), and the
// claim protocol gives every row to one thread at a time; `row` documents the rule.
unsafe impl<T: Send> Send for SharedRows<T> {}
unsafe impl<T: Send> Sync for SharedRows<T> {}

impl<T> SharedRows<T> {
    fn new(buf: &mut [T], row_len: usize, rows: usize) -> Self {
        assert!(
            buf.len() >= row_len * rows,
            "shared rows need {rows}×{row_len} values"
        );
        SharedRows {
            ptr: buf.as_mut_ptr(),
            row_len,
            rows,
        }
    }

    /// Row `y`.
    ///
    /// # Safety
    /// No other reference to row `y` may be alive: a row is written by the pass that claimed it
    /// until it publishes `STORED` (release), and afterwards used by the other pass only (after
    /// an acquire load of `STORED`).
    #[allow(clippy::mut_from_ref)]
    unsafe fn row(&self, y: usize) -> &mut [T] {
        assert!(y < self.rows);
        // SAFETY: in bounds (asserted above and in `new`); exclusive by the caller's contract.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(y * self.row_len), self.row_len) }
    }
}

/// What the second pass to reach a row does with it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Finish {
    /// Selects the disparities of the row (the matcher).
    Select,
    /// Adds its sum into the stored row, leaving the whole `S` (for [`aggregate_paths`]).
    Sum,
}

/// Per-row buffers of the winner selection.
#[derive(Default, Debug)]
struct RowSelect {
    /// Winning slice per pixel.
    best_k: Vec<u32>,
    /// `S` of the winner.
    best: Vec<u16>,
    /// Smallest `S` more than one slice away from the winner (`u16::MAX`: none).
    second: Vec<u16>,
    /// `S` at the winner's neighbours (for the sub-pixel fit on `S`).
    lo: Vec<u16>,
    hi: Vec<u16>,
    /// Right-image winners: the smallest `S` over the pixels matching each right pixel, and
    /// its slice (ties to the smaller slice); `u16::MAX` where none. Indexed `w − 1 − xr`.
    right_cost: Vec<u16>,
    right_k: Vec<u16>,
    /// Raw costs summed over the rows of the sub-pixel window, `[x][k]`.
    colsum: Vec<u16>,
    /// Whether the pixel passed selection (before the left–right check).
    valid: Vec<bool>,
    /// The row whose window `colsum` holds (`None`: none yet, for this volume).
    colsum_row: Option<usize>,
}

impl RowSelect {
    fn reset(&mut self, w: usize) {
        self.best_k.resize(w, 0);
        self.best.resize(w, 0);
        self.second.resize(w, 0);
        self.lo.resize(w, 0);
        self.hi.resize(w, 0);
        self.valid.resize(w, false);
        self.right_cost.clear();
        self.right_cost.resize(w, u16::MAX);
        self.right_k.clear();
        self.right_k.resize(w, u16::MAX);
    }

    /// Winner-take-all at pixel `x` over the aggregated costs `total` (one per slice).
    #[inline(always)]
    fn pixel<I: Isa>(&mut self, total: &[u16], x: usize, w: usize, dmin: i32) {
        let best = total.iter().fold(u16::MAX, |m, &v| m.min(v));
        self.pixel_with_min::<I>(total, best, x, w, dmin);
    }

    /// [`RowSelect::pixel`] given `best = min(total)`.
    #[inline(always)]
    fn pixel_with_min<I: Isa>(&mut self, total: &[u16], best: u16, x: usize, w: usize, dmin: i32) {
        let right = (&mut self.right_cost[..], &mut self.right_k[..]);
        let (bk, second) = I::winner(total, best, right, x, w, dmin);
        let nd = total.len();
        self.best_k[x] = bk as u32;
        self.best[x] = best;
        self.second[x] = second;
        self.lo[x] = if bk > 0 { total[bk - 1] } else { 0 };
        self.hi[x] = if bk + 1 < nd { total[bk + 1] } else { 0 };
    }

    /// Raw costs of the rows `[y − radius, y + radius]` (inside the image) summed per column
    /// and slice into `colsum`: from the previous row's sums when they are for `y ± 1` (the rows
    /// a pass finishes are mostly consecutive), else directly. Integer sums: same either way.
    #[inline(always)]
    fn window_sums(&mut self, vol: &CostVolume, y: usize, radius: usize) {
        let h = vol.height as usize;
        let n = vol.width as usize * vol.num_disparities;
        let row = |yy: usize| &vol.cost[yy * n..(yy + 1) * n];
        let same_size = self.colsum.len() == n;
        let colsum = &mut self.colsum;
        let mut add_sub = |add: Option<usize>, sub: Option<usize>| {
            if let Some(a) = add {
                for (s, &c) in colsum.iter_mut().zip(row(a)) {
                    *s = s.wrapping_add(c as u16);
                }
            }
            if let Some(b) = sub {
                for (s, &c) in colsum.iter_mut().zip(row(b)) {
                    *s = s.wrapping_sub(c as u16);
                }
            }
        };
        match self.colsum_row {
            Some(p) if p + 1 == y && same_size => {
                // Window moves down: row y + r enters, row p − r leaves.
                add_sub(
                    (y + radius < h).then_some(y + radius),
                    p.checked_sub(radius),
                );
            }
            Some(p) if y + 1 == p && same_size => {
                add_sub(
                    y.checked_sub(radius),
                    (p + radius < h).then_some(p + radius),
                );
            }
            _ => {
                colsum.clear();
                colsum.resize(n, 0);
                for yy in y.saturating_sub(radius)..(y + radius + 1).min(h) {
                    for (s, &c) in colsum.iter_mut().zip(row(yy)) {
                        *s += c as u16;
                    }
                }
            }
        }
        self.colsum_row = Some(y);
    }

    /// Row `y` from the per-pixel winners: bounds, uniqueness, sub-pixel fit, left–right check,
    /// confidence (the rules of [`select_disparities`]).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn finish(
        &mut self,
        y: usize,
        raw: Option<&CostVolume>,
        w: usize,
        nd: usize,
        params: &SgmParams,
        disparity: &mut [f32],
        confidence: &mut [f32],
    ) {
        let dmin = params.min_disparity_px;
        let radius = (params.subpixel_cost_window / 2) as usize;
        let window = raw.filter(|_| radius > 0);
        if let Some(vol) = window {
            self.window_sums(vol, y, radius);
        }
        let uniq = params.uniqueness_ratio;
        for x in 0..w {
            disparity[x] = f32::NAN;
            confidence[x] = 0.0;
            self.valid[x] = false;
            let bk = self.best_k[x] as usize;
            let bv = self.best[x];
            let second = self.second[x];
            let xr = x as i64 - dmin as i64 - bk as i64;
            if xr < 0 || xr >= w as i64 {
                continue;
            }
            if uniq > 0.0 && (second as f32) * (1.0 - uniq) < bv as f32 {
                continue;
            }
            let mut d = (dmin as i64 + bk as i64) as f32;
            if bk > 0 && bk + 1 < nd {
                let (a, b, c) = match window {
                    // Raw costs summed over a window: free of the P1 plateau of S around the
                    // winner.
                    Some(_) => {
                        let mut abc = [0u32; 3];
                        for xx in x.saturating_sub(radius)..(x + radius + 1).min(w) {
                            let c = &self.colsum[xx * nd + bk - 1..][..3];
                            abc[0] += c[0] as u32;
                            abc[1] += c[1] as u32;
                            abc[2] += c[2] as u32;
                        }
                        (abc[0] as f32, abc[1] as f32, abc[2] as f32)
                    }
                    None => (self.lo[x] as f32, bv as f32, self.hi[x] as f32),
                };
                let offset = match params.subpixel {
                    SubpixelFit::None => 0.0,
                    SubpixelFit::Parabola => {
                        let den = a - 2.0 * b + c;
                        if den > 0.0 {
                            (a - c) / (2.0 * den)
                        } else {
                            0.0
                        }
                    }
                    SubpixelFit::Equiangular => {
                        let den = a.max(c) - b;
                        if den > 0.0 {
                            (a - c) / (2.0 * den)
                        } else {
                            0.0
                        }
                    }
                };
                d += offset.clamp(-0.5, 0.5);
            }
            disparity[x] = d;
            self.valid[x] = true;
            confidence[x] = if second == u16::MAX || second == 0 {
                0.0
            } else {
                (second.saturating_sub(bv)) as f32 / second as f32
            };
        }
        if let Some(max_diff) = params.lr_max_diff_px {
            for x in 0..w {
                if !self.valid[x] {
                    continue;
                }
                let bk = self.best_k[x] as usize;
                let xr = (x as i64 - dmin as i64 - bk as i64) as usize;
                let rk = self.right_k[w - 1 - xr];
                if rk == u16::MAX || (rk as usize).abs_diff(bk) > max_diff as usize {
                    disparity[x] = f32::NAN;
                    confidence[x] = 0.0;
                }
            }
        }
    }
}

/// Winner-take-all at pixel `x` over its aggregated costs `total` whose minimum is `best`:
/// returns the first slice of cost `best` and the smallest cost more than one slice away from
/// it (`u16::MAX`: none), and updates the right image's winners (`right_cost`, `right_k`:
/// smallest cost over the pixels matching each right pixel, ties to the smaller slice). Every
/// step is a masked minimum or a select over the slices (no search with an early exit), so it
/// vectorises.
#[inline(always)]
fn winner(
    total: &[u16],
    best: u16,
    right_cost: &mut [u16],
    right_k: &mut [u16],
    x: usize,
    w: usize,
    dmin: i32,
) -> (usize, u16) {
    let nd = total.len();
    // The first slice with the smallest cost (nd ≤ 4096 fits u16).
    let mut bk = u16::MAX;
    for (k, &v) in total.iter().enumerate() {
        bk = bk.min(if v == best { k as u16 } else { u16::MAX });
    }
    let bk = bk as usize;
    let mut second = u16::MAX;
    for (k, &v) in total.iter().enumerate() {
        // Bitwise, not short-circuit, so that it stays a select.
        let far = (k + 1 < bk) | (k > bk + 1);
        second = second.min(if far { v } else { u16::MAX });
    }
    // Right pixel of slice k is xr0 − k; slices [k0, k1) fall inside the image.
    let xr0 = x as i64 - dmin as i64;
    let k0 = (xr0 - (w as i64 - 1)).max(0) as usize;
    let k1 = ((xr0 + 1).max(0) as usize).min(nd);
    if k0 < k1 {
        // The right winners are kept in reversed order (index w − 1 − xr), so that slice k of
        // this pixel lands at index w − 1 − xr0 + k: consecutive slices, consecutive entries.
        let n = k1 - k0;
        let at = (w as i64 - 1 - xr0) as usize + k0;
        let (cost, slice) = (&mut right_cost[at..at + n], &mut right_k[at..at + n]);
        let src = &total[k0..k1];
        for j in 0..n {
            let (t, k) = (src[j], (k0 + j) as u16);
            // Bitwise, not short-circuit, so that it stays a select.
            let better = (t < cost[j]) | ((t == cost[j]) & (k < slice[j]));
            cost[j] = if better { t } else { cost[j] };
            slice[j] = if better { k } else { slice[j] };
        }
    }
    (bk, second)
}

/// How many pixels ahead the second pass prefetches the first pass's sums.
const PREFETCH_PX: usize = 6;

/// Hints the CPU to load `data` into the cache (no effect on results; a no-op elsewhere than
/// x86-64).
#[inline(always)]
fn prefetch<T>(data: &[T]) {
    #[cfg(target_arch = "x86_64")]
    {
        let bytes = std::mem::size_of_val(data);
        let base = data.as_ptr() as *const i8;
        for offset in (0..bytes).step_by(64) {
            // SAFETY: a prefetch never faults and reads nothing into the program's state; the
            // address is inside `data`.
            unsafe {
                std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                    base.add(offset),
                )
            };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = data;
}

/// Buffers of one pass./// Buffers of one pass./// Buffers of one pass.
#[derive(Default, Debug)]
struct PassScratch {
    /// Path costs in `u8` or `u16` ([`Cell`]).
    narrow: PathRows<u8>,
    wide: PathRows<u16>,
    /// The pass's path sum at one pixel (when it comes second to the row).
    acc: Vec<u16>,
    select: RowSelect,
}

/// A pass's rows of path costs, updated in place pixel by pixel.
#[derive(Default, Debug)]
struct PathRows<T> {
    /// `L_r` of the row, `[x][dir][D + 2]`, padded with [`Cell::PAD`]: pixels already visited
    /// in this row hold the current row's values, the others the previous row's.
    slots: Vec<T>,
    /// Their minima, `[x][dir]`.
    slot_min: Vec<u16>,
    /// The previous row's values of the last two pixels visited: `[2][dir][D + 2]`.
    save: Vec<T>,
    save_min: Vec<u16>,
    /// The horizontal path at the previous and current pixel: `[2][D + 2]`.
    horiz: Vec<T>,
}

impl<T: Cell> PathRows<T> {
    fn prepare(&mut self, w: usize, nd: usize, nr: usize) {
        let stride = nd + 2;
        fn fill<V: Copy>(v: &mut Vec<V>, n: usize, value: V) {
            v.clear();
            v.resize(n, value);
        }
        fill(&mut self.slots, w * nr * stride, T::PAD);
        fill(&mut self.slot_min, w * nr, 0);
        fill(&mut self.save, 2 * nr * stride, T::PAD);
        fill(&mut self.save_min, 2 * nr, 0);
        fill(&mut self.horiz, 2 * stride, T::PAD);
    }
}

/// Reusable buffers of the aggregation (kept by the matchers between pairs, so that the large
/// ones are not mapped in again for every frame).
#[derive(Default, Debug)]
pub(crate) struct AggregateScratch {
    /// The first pass's four-path sums, row by row (`w·h·D`, each row written by one pass).
    partial: Vec<u16>,
    passes: [PassScratch; 2],
}

/// Inputs of both passes.
struct Job<'a> {
    volume: &'a CostVolume,
    image: &'a [u8],
    params: &'a SgmParams,
    pen: Penalties,
    /// Column offsets of the previous-row predecessors (0 vertical, ±1 diagonal).
    dxs: &'a [isize],
    finish: Finish,
    claims: &'a [AtomicU8],
    partial: SharedRows<u16>,
    disparity: SharedRows<f32>,
    confidence: SharedRows<f32>,
}

fn wait_stored(claim: &AtomicU8) {
    let mut spins = 0u32;
    while claim.load(Ordering::Acquire) != STORED {
        if spins < 256 {
            std::hint::spin_loop();
            spins += 1;
        } else {
            std::thread::yield_now();
        }
    }
}

/// One pass over every row (module docs).
#[inline(always)]
fn run_pass_impl<I: Isa>(job: &Job, forward: bool, ps: &mut PassScratch) {
    let narrow = job.volume.max_cost as u16 + job.pen.p2 <= 254;
    match (job.dxs.len(), narrow) {
        (3, true) => run_pass_n::<3, 4, u8, I>(job, forward, ps),
        (3, false) => run_pass_n::<3, 4, u16, I>(job, forward, ps),
        (_, true) => run_pass_n::<1, 2, u8, I>(job, forward, ps),
        (_, false) => run_pass_n::<1, 2, u16, I>(job, forward, ps),
    }
}

/// The path rows of type `T` in `ps`.
trait RowsOf<T> {
    fn rows_and_rest(&mut self) -> (&mut PathRows<T>, &mut Vec<u16>, &mut RowSelect);
}

impl RowsOf<u8> for PassScratch {
    fn rows_and_rest(&mut self) -> (&mut PathRows<u8>, &mut Vec<u16>, &mut RowSelect) {
        (&mut self.narrow, &mut self.acc, &mut self.select)
    }
}

impl RowsOf<u16> for PassScratch {
    fn rows_and_rest(&mut self) -> (&mut PathRows<u16>, &mut Vec<u16>, &mut RowSelect) {
        (&mut self.wide, &mut self.acc, &mut self.select)
    }
}

/// [`run_pass_impl`] with `NR` previous-row directions (`N = NR + 1` with the horizontal one)
/// and path costs stored as `T`.
#[inline(always)]
fn run_pass_n<const NR: usize, const N: usize, T: Cell, I: Isa>(
    job: &Job,
    forward: bool,
    ps: &mut PassScratch,
) where
    PassScratch: RowsOf<T>,
{
    let vol = job.volume;
    let (w, h, nd) = (vol.width as usize, vol.height as usize, vol.num_disparities);
    let stride = nd + 2;
    let dxs: [isize; NR] = std::array::from_fn(|r| job.dxs[r]);
    let (p1, pen) = (job.pen.p1, job.pen);
    let (rows, own, select) = ps.rows_and_rest();
    rows.prepare(w, nd, NR);
    // A new volume: no window sums to continue from.
    select.colsum_row = None;
    own.clear();
    own.resize(nd, 0);
    let PathRows {
        slots,
        slot_min,
        save,
        save_min,
        horiz,
    } = rows;
    let mut hmin = 0u16;
    for step in 0..h {
        let y = if forward { step } else { h - 1 - step };
        let has_prev = step > 0;
        let y_prev = if !has_prev {
            y
        } else if forward {
            y - 1
        } else {
            y + 1
        };
        let img = &job.image[y * w..(y + 1) * w];
        let img_prev = &job.image[y_prev * w..(y_prev + 1) * w];
        let cost_row = &vol.cost[y * w * nd..(y + 1) * w * nd];
        let first = job.claims[y]
            .compare_exchange(FREE, CLAIMED, Ordering::AcqRel, Ordering::Acquire)
            .is_ok();
        if !first {
            wait_stored(&job.claims[y]);
            select.reset(w);
        }
        // SAFETY: the claim protocol (module docs): the claimer writes the row until it
        // publishes STORED; the other pass uses it only after seeing STORED.
        let stored = unsafe { job.partial.row(y) };
        for i in 0..w {
            let x = if forward { i } else { w - 1 - i };
            let c = &cost_row[x * nd..(x + 1) * nd];
            if !first {
                // The other pass's sums were written long ago (they are in memory, not in the
                // cache): ask for those of a pixel a few steps ahead.
                let ahead = if forward {
                    x + PREFETCH_PX
                } else {
                    x.wrapping_sub(PREFETCH_PX)
                };
                if ahead < w {
                    prefetch(&stored[ahead * nd..(ahead + 1) * nd]);
                }
            }
            // Where the pass's sum goes (the stored row when first), and the other pass's sum.
            let (acc, theirs): (&mut [u16], &[u16]) = if first {
                (&mut stored[x * nd..(x + 1) * nd], &[])
            } else {
                (&mut own[..nd], &stored[x * nd..(x + 1) * nd])
            };
            let (h0, h1) = horiz.split_at_mut(stride);
            let (hprev, hout) = if i % 2 == 0 { (&*h1, h0) } else { (&*h0, h1) };
            // Keep the previous row's values of x before they are overwritten: x itself needs
            // them now (vertical) and the next pixel of the row (diagonal from behind).
            let (cur, other) = (i & 1, (i & 1) ^ 1);
            let (sx, ss) = (x * NR * stride, cur * NR * stride);
            save[ss..ss + NR * stride].copy_from_slice(&slots[sx..sx + NR * stride]);
            save_min[cur * NR..(cur + 1) * NR].copy_from_slice(&slot_min[x * NR..(x + 1) * NR]);
            // Predecessors in the previous row, when every path continues (the usual case).
            let xps: [isize; NR] = std::array::from_fn(|r| x as isize + dxs[r]);
            let inside = has_prev && i > 0 && xps.iter().all(|&xp| xp >= 0 && xp < w as isize);
            // The pixel's slots, and the not yet visited neighbour's (diagonal from ahead).
            let ahead = if forward { x + 1 } else { x.wrapping_sub(1) };
            let (outs, ahead_slots): (&mut [T], &[T]) = if ahead < w && forward {
                let (a, b) = slots.split_at_mut(ahead * NR * stride);
                (&mut a[sx..], &b[..NR * stride])
            } else if ahead < w {
                let (a, b) = slots.split_at_mut(sx);
                (&mut b[..NR * stride], &a[ahead * NR * stride..])
            } else {
                (&mut slots[sx..sx + NR * stride], &[])
            };
            // Where each direction's predecessor values are.
            let pred = |r: usize| -> (&[T], u16) {
                let dx = dxs[r];
                let visited = if forward { dx < 0 } else { dx > 0 };
                if dx == 0 || visited {
                    let which = if dx == 0 { cur } else { other };
                    let s0 = (which * NR + r) * stride;
                    (&save[s0..s0 + stride], save_min[which * NR + r])
                } else {
                    let xp = (x as isize + dx) as usize;
                    let s0 = r * stride;
                    (&ahead_slots[s0..s0 + stride], slot_min[xp * NR + r])
                }
            };
            if inside {
                let xn = if forward { x - 1 } else { x + 1 };
                let mut p2 = [0u16; N];
                let mut pmin = [0u16; N];
                p2[0] = pen.p2_for(img[x], img[xn]);
                pmin[0] = hmin;
                let mut prevs: [&[T]; N] = [&hprev[..]; N];
                for r in 0..NR {
                    let xp = xps[r] as usize;
                    p2[r + 1] = pen.p2_for(img[x], img_prev[xp]);
                    let (pv, pm) = pred(r);
                    prevs[r + 1] = pv;
                    pmin[r + 1] = pm;
                }
                let fused_select = N == 4 && !first && job.finish == Finish::Select;
                let m: [u16; N] = if fused_select {
                    // Second to the row: S of the pixel and its winner at once.
                    let (o1, rest) = outs.split_at_mut(stride);
                    let (o2, o3) = rest.split_at_mut(stride);
                    let prevs = (prevs[0], prevs[1], prevs[2], prevs[3]);
                    let (pm, p2) = (
                        [pmin[0], pmin[1], pmin[2], pmin[3]],
                        [p2[0], p2[1], p2[2], p2[3]],
                    );
                    let (m, best) =
                        I::steps4_total(c, (prevs, pm, p1, p2, [hout, o1, o2, o3], acc), theirs);
                    let total = &own[..nd];
                    select.pixel_with_min::<I>(total, best, x, w, job.params.min_disparity_px);
                    std::array::from_fn(|r| m[r])
                } else if N == 4 {
                    let (o1, rest) = outs.split_at_mut(stride);
                    let (o2, o3) = rest.split_at_mut(stride);
                    let prevs = (prevs[0], prevs[1], prevs[2], prevs[3]);
                    let (pm, p2) = (
                        [pmin[0], pmin[1], pmin[2], pmin[3]],
                        [p2[0], p2[1], p2[2], p2[3]],
                    );
                    let m = I::steps4(c, (prevs, pm, p1, p2, [hout, o1, o2, o3], acc));
                    std::array::from_fn(|r| m[r])
                } else {
                    let prevs = (prevs[0], prevs[1]);
                    let m = I::steps2(
                        c,
                        prevs,
                        [pmin[0], pmin[1]],
                        p1,
                        [p2[0], p2[1]],
                        hout,
                        outs,
                        acc,
                    );
                    std::array::from_fn(|r| m[r])
                };
                hmin = m[0];
                slot_min[x * NR..(x + 1) * NR].copy_from_slice(&m[1..]);
            } else {
                // Path starts: the first row, the first pixel of the row, the image's sides.
                hmin = if i == 0 {
                    path_start::<true, T>(c, hout, acc)
                } else {
                    let xn = if forward { x - 1 } else { x + 1 };
                    let p2 = pen.p2_for(img[x], img[xn]);
                    path_step::<true, T>(c, hprev, hmin, p1, p2, hout, acc)
                };
                let mut m = [0u16; NR];
                for (r, out) in outs.chunks_exact_mut(stride).take(NR).enumerate() {
                    let xp = xps[r];
                    m[r] = if !has_prev || xp < 0 || xp >= w as isize {
                        path_start::<false, T>(c, out, acc)
                    } else {
                        let p2 = pen.p2_for(img[x], img_prev[xp as usize]);
                        let (pv, pm) = pred(r);
                        path_step::<false, T>(c, pv, pm, p1, p2, out, acc)
                    };
                }
                slot_min[x * NR..(x + 1) * NR].copy_from_slice(&m);
            }
            if !first && !(inside && N == 4 && job.finish == Finish::Select) {
                let theirs = &mut stored[x * nd..(x + 1) * nd];
                match job.finish {
                    Finish::Sum => {
                        for (t, &a) in theirs.iter_mut().zip(own.iter()) {
                            *t += a;
                        }
                    }
                    Finish::Select => {
                        for (a, &t) in own.iter_mut().zip(theirs.iter()) {
                            *a += t;
                        }
                        select.pixel::<I>(&own[..nd], x, w, job.params.min_disparity_px);
                    }
                }
            }
        }
        if first {
            job.claims[y].store(STORED, Ordering::Release);
        } else if job.finish == Finish::Select {
            // SAFETY: only the second pass to reach row y writes its output row.
            let (disp, conf) = unsafe { (job.disparity.row(y), job.confidence.row(y)) };
            select.finish(y, Some(vol), w, nd, job.params, disp, conf);
        }
    }
}

/// [`run_pass_impl`], dispatched at run time to a copy compiled for AVX-512BW, AVX2 or the
/// baseline.
fn run_pass(job: &Job, forward: bool, ps: &mut PassScratch) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,popcnt")]
        fn avx512(job: &Job, forward: bool, ps: &mut PassScratch) {
            run_pass_impl::<Avx512>(job, forward, ps)
        }
        #[target_feature(enable = "avx2,popcnt")]
        fn avx2(job: &Job, forward: bool, ps: &mut PassScratch) {
            run_pass_impl::<Avx2>(job, forward, ps)
        }
        if std::is_x86_feature_detected!("avx512bw")
            && std::is_x86_feature_detected!("avx512vl")
            && std::is_x86_feature_detected!("popcnt")
        {
            // SAFETY: the CPU supports the features the copy was compiled for (checked above).
            unsafe { avx512(job, forward, ps) };
            return;
        }
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("popcnt") {
            // SAFETY: as above.
            unsafe { avx2(job, forward, ps) };
            return;
        }
    }
    run_pass_impl::<Baseline>(job, forward, ps)
}

/// Column offsets of the previous-row predecessors for `paths`.
fn predecessors(paths: SgmPaths) -> &'static [isize] {
    match paths {
        SgmPaths::Four => &[0],
        SgmPaths::Eight => &[0, -1, 1],
    }
}

/// Runs both passes (module docs) with `finish`; `partial` receives the stored rows.
#[allow(clippy::too_many_arguments)]
fn run_passes(
    volume: &CostVolume,
    image: &[u8],
    params: &SgmParams,
    finish: Finish,
    scratch: &mut AggregateScratch,
    partial_out: Option<&mut Vec<u16>>,
    disparity: &mut [f32],
    confidence: &mut [f32],
) {
    let (w, h, nd) = (
        volume.width as usize,
        volume.height as usize,
        volume.num_disparities,
    );
    let n = w * h * nd;
    let partial = match partial_out {
        Some(p) => p,
        None => &mut scratch.partial,
    };
    if partial.len() != n {
        // calloc'd: rows no pass stores are never touched.
        *partial = vec![0u16; n];
    }
    let claims: Vec<AtomicU8> = (0..h).map(|_| AtomicU8::new(FREE)).collect();
    let job = Job {
        volume,
        image,
        params,
        pen: Penalties::of(params),
        dxs: predecessors(params.paths),
        finish,
        claims: &claims,
        partial: SharedRows::new(partial, w * nd, h),
        // Empty outputs when summing (no row is selected).
        disparity: SharedRows::new(disparity, w, if finish == Finish::Select { h } else { 0 }),
        confidence: SharedRows::new(confidence, w, if finish == Finish::Select { h } else { 0 }),
    };
    let [fwd, bwd] = &mut scratch.passes;
    rayon::join(|| run_pass(&job, true, fwd), || run_pass(&job, false, bwd));
}

/// Semi-global matching on `volume` (left image `image`): aggregation and selection streamed
/// together (module docs). Returns disparities (NaN invalid) and confidences, as
/// [`select_disparities`] of [`aggregate_paths`] would, bit for bit. `params` must be valid and
/// match the volume's disparity range; `image` must have the volume's size.
pub(crate) fn aggregate_and_select(
    volume: &CostVolume,
    image: &[u8],
    params: &SgmParams,
    scratch: &mut AggregateScratch,
) -> (Image<f32>, Image<f32>) {
    let (width, height) = (volume.width, volume.height);
    let mut disp = Image::filled(width, height, f32::NAN);
    let mut conf = Image::filled(width, height, 0.0f32);
    run_passes(
        volume,
        image,
        params,
        Finish::Select,
        scratch,
        None,
        &mut disp.data,
        &mut conf.data,
    );
    (disp, conf)
}

/// The aggregated costs `S(p, d)` summed over the configured directions, `u16`, layout of the
/// cost volume (the same passes, keeping every row).
pub(crate) fn aggregate_all(
    volume: &CostVolume,
    image: &[u8],
    params: &SgmParams,
    scratch: &mut AggregateScratch,
) -> Vec<u16> {
    let mut sum = Vec::new();
    run_passes(
        volume,
        image,
        params,
        Finish::Sum,
        scratch,
        Some(&mut sum),
        &mut [],
        &mut [],
    );
    sum
}

/// Winner selection over a whole `S` (the second half of [`aggregate_and_select`]), rows in
/// parallel.
pub(crate) fn select_all(
    sum: &[u16],
    raw: Option<&CostVolume>,
    width: u32,
    height: u32,
    params: &SgmParams,
) -> (Image<f32>, Image<f32>) {
    use rayon::prelude::*;
    let (w, nd) = (width as usize, params.num_disparities);
    let mut disp = Image::filled(width, height, f32::NAN);
    let mut conf = Image::filled(width, height, 0.0f32);
    if w == 0 || height == 0 {
        return (disp, conf);
    }
    disp.data
        .par_chunks_mut(w)
        .zip(conf.data.par_chunks_mut(w))
        .enumerate()
        .for_each_init(RowSelect::default, |sel, (y, (drow, crow))| {
            let row = &sum[y * w * nd..(y + 1) * w * nd];
            select_row(sel, row, y, raw, w, nd, params, drow, crow);
        });
    (disp, conf)
}

/// One row of [`select_all`], dispatched to a copy compiled for AVX-512BW or AVX2 where the CPU
/// has it.
#[allow(clippy::too_many_arguments)]
fn select_row(
    sel: &mut RowSelect,
    row: &[u16],
    y: usize,
    raw: Option<&CostVolume>,
    w: usize,
    nd: usize,
    params: &SgmParams,
    drow: &mut [f32],
    crow: &mut [f32],
) {
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn imp<I: Isa>(
        sel: &mut RowSelect,
        row: &[u16],
        y: usize,
        raw: Option<&CostVolume>,
        w: usize,
        nd: usize,
        params: &SgmParams,
        drow: &mut [f32],
        crow: &mut [f32],
    ) {
        sel.reset(w);
        for x in 0..w {
            sel.pixel::<I>(&row[x * nd..(x + 1) * nd], x, w, params.min_disparity_px);
        }
        sel.finish(y, raw, w, nd, params, drow, crow);
    }
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,popcnt")]
        #[allow(clippy::too_many_arguments)]
        fn avx512(
            sel: &mut RowSelect,
            row: &[u16],
            y: usize,
            raw: Option<&CostVolume>,
            w: usize,
            nd: usize,
            params: &SgmParams,
            drow: &mut [f32],
            crow: &mut [f32],
        ) {
            imp::<Avx512>(sel, row, y, raw, w, nd, params, drow, crow)
        }
        #[target_feature(enable = "avx2,popcnt")]
        #[allow(clippy::too_many_arguments)]
        fn avx2(
            sel: &mut RowSelect,
            row: &[u16],
            y: usize,
            raw: Option<&CostVolume>,
            w: usize,
            nd: usize,
            params: &SgmParams,
            drow: &mut [f32],
            crow: &mut [f32],
        ) {
            imp::<Avx2>(sel, row, y, raw, w, nd, params, drow, crow)
        }
        if std::is_x86_feature_detected!("avx512bw") && std::is_x86_feature_detected!("avx512vl") {
            // SAFETY: the CPU supports the features the copy was compiled for (checked above).
            unsafe { avx512(sel, row, y, raw, w, nd, params, drow, crow) };
            return;
        }
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("popcnt") {
            // SAFETY: as above.
            unsafe { avx2(sel, row, y, raw, w, nd, params, drow, crow) };
            return;
        }
    }
    imp::<Baseline>(sel, row, y, raw, w, nd, params, drow, crow)
}
