//! Semi-global path aggregation and winner selection, streamed row by row: the hot part of
//! [`crate::depth::sgm`] (its module docs give the recurrence, eq. 13 of Hirschmüller 2008).
//!
//! The 8 (or 4) directions are split into two passes that run at the same time on two threads:
//! a forward pass over the rows from top to bottom (left→right, and the three paths entering
//! from the row above: ↓, ↘, ↙) and a backward pass from bottom to top (right→left, ↑, ↗, ↖).
//! Each pass keeps two rows of path costs per direction, the previous row's and the current
//! one's, which swap roles every row (no per-pixel copy of the values a pixel overwrites), never
//! a whole `L_r`. For every row, the pass that reaches it first stores its four-path sum in a
//! shared buffer (claiming the row with an atomic compare-and-swap, so it never waits while
//! holding a claim); the second adds its own sum pixel by pixel and selects the winner at once
//! (winner-take-all, uniqueness, the right image's winners), then finishes the row (sub-pixel
//! fit, left–right check, confidence). `S` is thus never stored whole: each row is written once
//! and read once, by whichever pass comes second, and two passes of 4 directions replace three
//! sweeps over an 8-direction sum in memory.
//!
//! With 5 paths (OpenCV's 3-way mode) the forward pass is the same, and the second pass carries
//! the right→left path alone: it needs no previous row, so it follows the forward pass down the
//! image, never claims a row, and adds its path to each stored row and selects it (the light
//! pass takes the selection work; the forward pass computes the raw costs' window sums of the
//! sub-pixel fit and stores them beside its path sums). Since it trails the forward pass
//! closely, the stored rows then live in a ring of [`RING_ROWS`] rows that stays in the cache
//! (the forward pass waits for the slot of row `y − RING_ROWS` to be consumed), not in a `w·h·D`
//! buffer written to memory and read back. The forward pass never waits long for a pass that has not started: when `rayon::join`
//! runs the two closures one after the other (one worker, or the other one busy for longer than
//! [`START_WAIT`]), the forward pass finds the second one not begun at the first full ring and
//! stores the remaining rows in place (`full_from`), as 8 paths always do.
//!
//! Sums of integers do not depend on the order of addition, so the result is bit-identical to
//! summing the paths one after the other (`tests/depth/sgm.rs` checks it against a direct
//! implementation of eq. 13). When the two closures of `rayon::join` run one after the other (no
//! idle worker), the first pass claims every row and the second selects every row: same result,
//! no waiting.
//!
//! The inner loops run over the disparities of one pixel (contiguous in the cost volume) and are
//! compiled three times on x86-64 (AVX-512BW, AVX2, baseline), picked at run time. A row's
//! interior pixels (those that continue every path) run in one call: [`path_row4`] for the pass
//! that comes first to the row, [`path_row_select`] for the second with its selection. Path
//! starts at the image's sides, and the second pass when it only sums (for
//! [`aggregate_paths`]), call a kernel per pixel.

use super::sgm::{CostVolume, SgmParams, SgmPaths, SubpixelFit};
use crate::frame::Image;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicUsize, Ordering};

/// Sentinel for "no such disparity" in padded path buffers; larger than any path cost plus P2,
/// small enough that adding P1 cannot overflow `u16`.
pub(crate) const BIG: u16 = 16_384;

/// Row claim states.
const FREE: u8 = 0;
const CLAIMED: u8 = 1;
const STORED: u8 = 2;
/// A stored row the second pass has finished with (5 paths with a ring of rows: its slot may be
/// written again).
const CONSUMED: u8 = 3;

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

/// How path costs `L_r` are stored between pixels, and the type their recurrence is computed in:
/// `u8` when every `L_r` fits (the census's largest cost plus P2 at most 254: `L_r ≤ C + P2`),
/// else `u16`, so that a pass's row of path costs stays in the core's cache and a vector
/// register holds twice the disparities. Sums over paths are `u16` either way.
///
/// In `u8` the recurrence saturates P1 and the jump `min L + P2` at 255 ([`Cell::sat`]). That is
/// exact: a stored `L_r` is at most 254, so the middle predecessor (never padding) is always at
/// most 254 and beats any term that saturated, as it beats that term's true value; and
/// `best − min L` lies in [0, P2], so `C + best − min L ≤ 254` needs no wider type.
pub(crate) trait Cell:
    Copy + Ord + Default + Send + Sync + std::fmt::Debug + 'static
{
    /// Padding before the first and after the last slice: never the best predecessor (it is at
    /// least the largest cost plus P2, so `PAD + P1` loses to the jump `min + P2`).
    const PAD: Self;
    /// Larger than every path cost (the start of a minimum).
    const MAX: Self;
    /// The value, as a sum's term.
    fn widen(self) -> u16;
    /// A path cost or minimum computed in `u16` (fits by the choice of the type).
    fn narrow(v: u16) -> Self;
    /// A penalty or jump in the stored type, saturated at its largest value.
    fn sat(v: u16) -> Self;
    /// `L_r(p, d) = C + min(L(d), min(L(d − 1), L(d + 1)) + P1, jump) − min L`, eq. 13 with the
    /// jump `min L + P2`, from the predecessor's slices `lo`, `mid`, `hi` (d − 1, d, d + 1).
    fn lane(c: u8, lo: Self, mid: Self, hi: Self, p1: Self, jump: Self, prev_min: Self) -> Self;
}

impl Cell for u8 {
    const PAD: u8 = u8::MAX;
    const MAX: u8 = u8::MAX;
    #[inline(always)]
    fn widen(self) -> u16 {
        self as u16
    }
    #[inline(always)]
    fn narrow(v: u16) -> u8 {
        v as u8
    }
    #[inline(always)]
    fn sat(v: u16) -> u8 {
        v.min(u8::MAX as u16) as u8
    }
    #[inline(always)]
    fn lane(c: u8, lo: u8, mid: u8, hi: u8, p1: u8, jump: u8, prev_min: u8) -> u8 {
        // best ≥ prev_min and C + best − prev_min ≤ 254 (trait docs): wrapping never wraps.
        let best = mid.min(lo.min(hi).saturating_add(p1)).min(jump);
        best.wrapping_sub(prev_min).wrapping_add(c)
    }
}

impl Cell for u16 {
    const PAD: u16 = BIG;
    const MAX: u16 = u16::MAX;
    #[inline(always)]
    fn widen(self) -> u16 {
        self
    }
    #[inline(always)]
    fn narrow(v: u16) -> u16 {
        v
    }
    #[inline(always)]
    fn sat(v: u16) -> u16 {
        v
    }
    #[inline(always)]
    fn lane(c: u8, lo: u16, mid: u16, hi: u16, p1: u16, jump: u16, prev_min: u16) -> u16 {
        c as u16 + mid.min(lo.min(hi) + p1).min(jump) - prev_min
    }
}

/// P1, a predecessor's minimum and its jump (`min + P2`) in the stored type ([`Cell::sat`]).
#[inline(always)]
fn in_cell<T: Cell>(p1: u16, prev_min: u16, p2: u16) -> (T, T, T) {
    (T::sat(p1), T::narrow(prev_min), T::sat(prev_min + p2))
}

/// One step of eq. 13 along a path: `out[1..=D]` ← L_r(p, ·) from `prev[1..=D]` (= L_r(p−r, ·),
/// padded with [`Cell::PAD`] at 0 and D+1), and `acc` gets it added (or assigned when
/// `ASSIGN`). Returns `min_d L_r(p, d)`. Every kernel here computes in the stored type
/// ([`Cell::lane`]) and takes the two neighbouring slices' minimum before adding P1:
/// `min(a, b) + P1 = min(a + P1, b + P1)` exactly.
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
    let (p1, pm, jump) = in_cell::<T>(p1, prev_min, p2);
    let mut m = T::MAX;
    for k in 0..d {
        let v = T::lane(cost[k], lo[k], mid[k], hi[k], p1, jump, pm);
        out[k] = v;
        if ASSIGN {
            acc[k] = v.widen();
        } else {
            acc[k] += v.widen();
        }
        m = m.min(v);
    }
    m.widen()
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

/// A predecessor's path costs at the slices d − 1, d and d + 1 for every d (`[0..D]`, `[1..D+1]`
/// and `[2..D+2]` of its padded row), made by the caller of a kernel compiled out of line. Seen
/// as three unrelated slices there, each is read with plain vector loads. Given the one padded
/// row, the compiler loaded `d + 1` only and rebuilt `d − 1` and `d` from it and the previous
/// vector, two lane shuffles each (`vshufi64x2` + `vpalignr`): 16 shuffles per 32 slices in the
/// four-path kernel, against none with three loads (`docs/bench/sgm-speed.md`).
#[derive(Clone, Copy)]
pub(crate) struct Nbrs<'a, T> {
    lo: &'a [T],
    mid: &'a [T],
    hi: &'a [T],
}

impl<'a, T> Nbrs<'a, T> {
    /// The three views of `prev` (padded: `D + 2` entries) for `d` slices.
    #[inline(always)]
    fn of(prev: &'a [T], d: usize) -> Self {
        Nbrs {
            lo: &prev[..d],
            mid: &prev[1..d + 1],
            hi: &prev[2..d + 2],
        }
    }

    /// [`Nbrs::of`] of four rows (element by element: `array::map` stayed out of line, a call
    /// per pixel that took 4 % of the matcher's samples).
    #[inline(always)]
    fn of4((a, b, c, e): (&'a [T], &'a [T], &'a [T], &'a [T]), d: usize) -> [Self; 4] {
        [
            Self::of(a, d),
            Self::of(b, d),
            Self::of(c, d),
            Self::of(e, d),
        ]
    }
}

/// [`path_step`] for the 4 directions of a pass at once (all continuing a path): one pass
/// over the disparities computes every direction's `L_r` and their sum, which `out` receives.
/// With `TOTAL` (the pass that comes second to a row) the other pass's sum `theirs` is added, so
/// that `out` gets `S` of the pixel, and `min_d S` is returned beside the directions' minima
/// (else `u16::MAX`). Inlined into an out-of-line wrapper that takes the outputs as separate
/// slice arguments (not an array of slices), so that the compiler knows that outputs and inputs
/// do not overlap and the loop vectorises without run-time overlap checks.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn path_steps4<const TOTAL: bool, T: Cell>(
    cost: &[u8],
    [pa, pb, pc, pd]: [Nbrs<'_, T>; 4],
    prev_min: [u16; 4],
    p1: u16,
    p2: [u16; 4],
    [oa, ob, oc, od]: [&mut [T]; 4],
    theirs: &[u16],
    out: &mut [u16],
) -> ([u16; 4], u16) {
    let d = cost.len();
    let out = &mut out[..d];
    let theirs = if TOTAL { &theirs[..d] } else { &[] };
    let (al, am, ah) = (&pa.lo[..d], &pa.mid[..d], &pa.hi[..d]);
    let (bl, bm, bh) = (&pb.lo[..d], &pb.mid[..d], &pb.hi[..d]);
    let (cl, cm, ch) = (&pc.lo[..d], &pc.mid[..d], &pc.hi[..d]);
    let (dl, dm, dh) = (&pd.lo[..d], &pd.mid[..d], &pd.hi[..d]);
    let (oa, ob, oc, od) = (
        &mut oa[1..d + 1],
        &mut ob[1..d + 1],
        &mut oc[1..d + 1],
        &mut od[1..d + 1],
    );
    // Element by element: `array::map` stayed out of line (a call per pixel).
    let (p1t, pma, ja) = in_cell::<T>(p1, prev_min[0], p2[0]);
    let (_, pmb, jb) = in_cell::<T>(p1, prev_min[1], p2[1]);
    let (_, pmc, jc) = in_cell::<T>(p1, prev_min[2], p2[2]);
    let (_, pmd, jd) = in_cell::<T>(p1, prev_min[3], p2[3]);
    // Separate scalar minima (not an array): recognised as reductions, so the loop vectorises.
    let (mut ma, mut mb, mut mc, mut md) = (T::MAX, T::MAX, T::MAX, T::MAX);
    let mut mt = u16::MAX;
    for k in 0..d {
        let c = cost[k];
        let va = T::lane(c, al[k], am[k], ah[k], p1t, ja, pma);
        let vb = T::lane(c, bl[k], bm[k], bh[k], p1t, jb, pmb);
        let vc = T::lane(c, cl[k], cm[k], ch[k], p1t, jc, pmc);
        let vd = T::lane(c, dl[k], dm[k], dh[k], p1t, jd, pmd);
        oa[k] = va;
        ob[k] = vb;
        oc[k] = vc;
        od[k] = vd;
        let sum = va.widen() + vb.widen() + vc.widen() + vd.widen();
        if TOTAL {
            let t = sum + theirs[k];
            out[k] = t;
            mt = mt.min(t);
        } else {
            out[k] = sum;
        }
        ma = ma.min(va);
        mb = mb.min(vb);
        mc = mc.min(vc);
        md = md.min(vd);
    }
    ([ma.widen(), mb.widen(), mc.widen(), md.widen()], mt)
}

/// [`path_step`] for a lone horizontal path in the pass that comes second to a row (5 paths):
/// its `L_r` plus the other pass's sum (`theirs`) gives `S` of the pixel, written to `total`;
/// returns `min_d L_r` and `min_d S`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn path_step_total<T: Cell>(
    cost: &[u8],
    prev: Nbrs<'_, T>,
    prev_min: u16,
    p1: u16,
    p2: u16,
    out: &mut [T],
    theirs: &[u16],
    total: &mut [u16],
) -> (u16, u16) {
    let d = cost.len();
    let (theirs, total) = (&theirs[..d], &mut total[..d]);
    let (lo, mid, hi) = (&prev.lo[..d], &prev.mid[..d], &prev.hi[..d]);
    let out = &mut out[1..d + 1];
    let (p1, pm, jump) = in_cell::<T>(p1, prev_min, p2);
    let (mut m, mut mt) = (T::MAX, u16::MAX);
    for k in 0..d {
        let v = T::lane(cost[k], lo[k], mid[k], hi[k], p1, jump, pm);
        out[k] = v;
        let t = v.widen() + theirs[k];
        total[k] = t;
        m = m.min(v);
        mt = mt.min(t);
    }
    (m.widen(), mt)
}

/// [`path_steps4`] for the 2 directions of a 4-path pass.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn path_steps2<T: Cell>(
    cost: &[u8],
    [pa, pb]: [Nbrs<'_, T>; 2],
    prev_min: [u16; 2],
    p1: u16,
    p2: [u16; 2],
    oa: &mut [T],
    ob: &mut [T],
    acc: &mut [u16],
) -> [u16; 2] {
    let d = cost.len();
    let acc = &mut acc[..d];
    let (al, am, ah) = (&pa.lo[..d], &pa.mid[..d], &pa.hi[..d]);
    let (bl, bm, bh) = (&pb.lo[..d], &pb.mid[..d], &pb.hi[..d]);
    let (oa, ob) = (&mut oa[1..d + 1], &mut ob[1..d + 1]);
    let (p1t, pma, ja) = in_cell::<T>(p1, prev_min[0], p2[0]);
    let (_, pmb, jb) = in_cell::<T>(p1, prev_min[1], p2[1]);
    let (mut ma, mut mb) = (T::MAX, T::MAX);
    for k in 0..d {
        let c = cost[k];
        let va = T::lane(c, al[k], am[k], ah[k], p1t, ja, pma);
        let vb = T::lane(c, bl[k], bm[k], bh[k], p1t, jb, pmb);
        oa[k] = va;
        ob[k] = vb;
        acc[k] = va.widen() + vb.widen();
        ma = ma.min(va);
        mb = mb.min(vb);
    }
    [ma.widen(), mb.widen()]
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

/// The pixel and row kernels compiled for one instruction set. They stay out of line: as
/// separate functions their slice arguments are known not to overlap, so the loops vectorise
/// (inlined into the pass, with the slices taken from shared buffers, they did not).
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
    /// [`path_row4`].
    #[allow(clippy::too_many_arguments)]
    fn row4<T: Cell>(
        a: &RowSteps<'_, T>,
        cur: &mut [T],
        cur_min: &mut [u16],
        h: (&mut [T], &mut [T]),
        sums: &mut [u16],
    ) -> u16;
    /// [`path_row_select`].
    #[allow(clippy::too_many_arguments)]
    fn row_select<const NR: usize, T: Cell>(
        a: &RowSteps<'_, T>,
        cur: &mut [T],
        cur_min: &mut [u16],
        h: (&mut [T], &mut [T]),
        theirs: &[u16],
        own: &mut [u16],
        select: &mut RowSelect,
    ) -> u16;
}

macro_rules! isa {
    ($name:ident, $win:ident, $s4:ident, $r4:ident, $rs:ident, $s2:ident, $($feature:literal)?) => {
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
        #[allow(clippy::too_many_arguments)]
        fn $s4<T: Cell>(
            cost: &[u8],
            prev: [Nbrs<'_, T>; 4],
            pmin: [u16; 4],
            p1: u16,
            p2: [u16; 4],
            oa: &mut [T],
            ob: &mut [T],
            oc: &mut [T],
            od: &mut [T],
            out: &mut [u16],
        ) -> [u16; 4] {
            path_steps4::<false, T>(cost, prev, pmin, p1, p2, [oa, ob, oc, od], &[], out).0
        }
        $(#[target_feature(enable = $feature)])?
        #[inline(never)]
        #[allow(clippy::too_many_arguments)]
        fn $r4<T: Cell>(
            a: &RowSteps<'_, T>,
            cur: &mut [T],
            cur_min: &mut [u16],
            h0: &mut [T],
            h1: &mut [T],
            sums: &mut [u16],
        ) -> u16 {
            path_row4(a, cur, cur_min, h0, h1, sums)
        }
        $(#[target_feature(enable = $feature)])?
        #[inline(never)]
        #[allow(clippy::too_many_arguments)]
        fn $rs<const NR: usize, T: Cell>(
            a: &RowSteps<'_, T>,
            cur: &mut [T],
            cur_min: &mut [u16],
            h0: &mut [T],
            h1: &mut [T],
            theirs: &[u16],
            own: &mut [u16],
            select: &mut RowSelect,
            right_cost: &mut [u16],
            right_k: &mut [u16],
        ) -> u16 {
            let right = (right_cost, right_k);
            path_row_select::<NR, T>(a, cur, cur_min, h0, h1, theirs, own, select, right)
        }
        $(#[target_feature(enable = $feature)])?
        #[inline(never)]
        #[allow(clippy::too_many_arguments)]
        fn $s2<T: Cell>(
            cost: &[u8],
            prev: [Nbrs<'_, T>; 2],
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
                let ((pa, pb, pc, pd), pmin, p1, p2, [oa, ob, oc, od], acc) = a;
                let d = cost.len();
                let prev = Nbrs::of4((pa, pb, pc, pd), d);
                // SAFETY: `run_pass` instantiates this instruction set only where the CPU has
                // it.
                #[allow(unused_unsafe)]
                unsafe {
                    $s4::<T>(cost, prev, pmin, p1, p2, oa, ob, oc, od, acc)
                }
            }
            #[inline(always)]
            fn row4<T: Cell>(
                a: &RowSteps<'_, T>,
                cur: &mut [T],
                cur_min: &mut [u16],
                (h0, h1): (&mut [T], &mut [T]),
                sums: &mut [u16],
            ) -> u16 {
                // SAFETY: as above.
                #[allow(unused_unsafe)]
                unsafe {
                    $r4(a, cur, cur_min, h0, h1, sums)
                }
            }
            #[inline(always)]
            fn row_select<const NR: usize, T: Cell>(
                a: &RowSteps<'_, T>,
                cur: &mut [T],
                cur_min: &mut [u16],
                (h0, h1): (&mut [T], &mut [T]),
                theirs: &[u16],
                own: &mut [u16],
                select: &mut RowSelect,
            ) -> u16 {
                // The right image's winners go in as arguments of their own (known not to
                // overlap the other buffers, for the winner's vectorised update).
                let mut right_cost = std::mem::take(&mut select.right_cost);
                let mut right_k = std::mem::take(&mut select.right_k);
                // SAFETY: as above.
                #[allow(unused_unsafe)]
                let hmin = unsafe {
                    $rs::<NR, T>(
                        a, cur, cur_min, h0, h1, theirs, own, select, &mut right_cost,
                        &mut right_k,
                    )
                };
                select.right_cost = right_cost;
                select.right_k = right_k;
                hmin
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
                let prev = [Nbrs::of(prev.0, cost.len()), Nbrs::of(prev.1, cost.len())];
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
    row4_baseline,
    row_select_baseline,
    steps2_baseline,
);
#[cfg(target_arch = "x86_64")]
isa!(
    Avx2,
    winner_avx2,
    steps4_avx2,
    row4_avx2,
    row_select_avx2,
    steps2_avx2,
    "avx2"
);
#[cfg(target_arch = "x86_64")]
isa!(
    Avx512,
    winner_avx512,
    steps4_avx512,
    row4_avx512,
    row_select_avx512,
    steps2_avx512,
    "avx512f,avx512bw,avx512vl,avx2"
);

mod pass;
mod row;
mod select;

pub(crate) use pass::*;
use row::*;
pub(crate) use select::*;
