//! The row kernels: every interior pixel of a row (those that continue every path) in one
//! call, instead of one kernel call per pixel. [`path_row4`] is the pass that comes first to a
//! row (its four paths and their sum); [`path_row_select`] the second (its paths, `S` and the
//! winner).
//!
//! Called once per pixel, the four-path kernel took its 24 predecessor views, 4 outputs and the
//! penalties as arguments, built on the stack for every call: ~45 stores per pixel, where
//! `perf` found half of the pass's own samples. Here the views are made inside the loop from
//! the row's buffers: the written ones come in as separate arguments, so that the compiler
//! still knows that outputs and inputs do not overlap (the loop vectorises without run-time
//! checks), and the previous row comes as three fields of [`RowSteps`] that hold the same
//! slice, so that it still sees the slices `d − 1`, `d`, `d + 1` of a predecessor as unrelated
//! (plain loads, no lane shuffles).

#[allow(unused_imports)]
use super::*;

/// Runs `$step!(i, hprev, hout)` for the steps `[i0, i1)` of `$a`: the horizontal path's two
/// buffers swap roles every step (even steps read `$h1` and write `$h0`). Spelled out as a
/// macro: a closure here stayed out of line.
macro_rules! alternate_steps {
    ($a:expr, $h0:expr, $h1:expr, $step:ident) => {{
        let mut i = $a.i0;
        if i < $a.i1 && i % 2 == 1 {
            $step!(i, $h0, $h1);
            i += 1;
        }
        while i + 1 < $a.i1 {
            $step!(i, $h1, $h0);
            $step!(i + 1, $h0, $h1);
            i += 2;
        }
        if i < $a.i1 {
            $step!(i, $h1, $h0);
        }
    }};
}

/// What the row kernels read besides the buffers.
#[derive(Clone, Copy)]
pub(super) struct RowSteps<'a, T> {
    /// Steps `[i0, i1)` of the row: pixel `x = i` (left to right) or `w − 1 − i`.
    pub(super) i0: usize,
    pub(super) i1: usize,
    pub(super) forward: bool,
    pub(super) w: usize,
    /// Disparities.
    pub(super) nd: usize,
    /// Column offsets of the previous-row predecessors (↓, ↘, ↙ as seen from the pass).
    pub(super) dxs: [isize; 3],
    /// The row's and the previous row's intensities (for the adaptive P2).
    pub(super) img: &'a [u8],
    pub(super) img_prev: &'a [u8],
    pub(super) pen: &'a Penalties,
    /// `min_d L` of the horizontal path at the step before `i0`.
    pub(super) hmin: u16,
    /// Disparity of slice 0 (for the right image's winners).
    pub(super) dmin: i32,
    /// The row's raw costs (`[x][D]`).
    pub(super) cost_row: &'a [u8],
    /// The previous row's path costs (`[x][dir][D + 2]`), the same slice three times: read as
    /// the neighbour views `d − 1`, `d`, `d + 1` (reached through three fields, the compiler
    /// does not rebuild two of them from the third with lane shuffles). Empty when the pass
    /// carries the horizontal path only.
    pub(super) prev: (&'a [T], &'a [T], &'a [T]),
    /// Their minima (`[x][dir]`).
    pub(super) prev_min: &'a [u16],
}

/// The four-path step ([`path_steps4`]) of every pixel of `a`'s steps, all of which continue
/// every path (interior pixels of a row after the first). `cur`, `cur_min`: this row's path
/// costs and minima (laid out as `a.prev`, `a.prev_min`); `h0`, `h1`: the horizontal path at even and odd steps
/// (step `i` reads the other one); `sums`: the row's four-path sums (`[x][D]`). Returns the
/// horizontal path's minimum at the last step.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn path_row4<T: Cell>(
    a: &RowSteps<'_, T>,
    cur: &mut [T],
    cur_min: &mut [u16],
    h0: &mut [T],
    h1: &mut [T],
    sums: &mut [u16],
) -> u16 {
    let mut hmin = a.hmin;
    macro_rules! step {
        ($i:expr, $hprev:expr, $hout:expr) => {
            hmin = pixel4(a, $i, hmin, cur, cur_min, $hprev, $hout, sums)
        };
    }
    alternate_steps!(a, h0, h1, step);
    hmin
}

/// One pixel of [`path_row4`] at step `i`, reading the horizontal path from `hprev` (its
/// minimum `hmin`) and writing it to `hout`; returns the new minimum.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn pixel4<T: Cell>(
    a: &RowSteps<'_, T>,
    i: usize,
    hmin: u16,
    cur: &mut [T],
    cur_min: &mut [u16],
    hprev: &[T],
    hout: &mut [T],
    sums: &mut [u16],
) -> u16 {
    let nd = a.nd;
    let (x, xn) = a.pixel(i);
    let (prevs, pmin, p2, outs) = four_paths(a, x, xn, hmin, hprev, hout, cur);
    let sum = &mut sums[x * nd..(x + 1) * nd];
    let cost = &a.cost_row[x * nd..(x + 1) * nd];
    let (m, _) = path_steps4::<false, T>(cost, prevs, pmin, a.pen.p1, p2, outs, &[], sum);
    cur_min[x * 3..(x + 1) * 3].copy_from_slice(&m[1..]);
    m[0]
}

/// The second pass's row kernel: the `NR + 1` paths of every interior pixel of a row (`NR` = 3,
/// or 0: the lone right→left path of 5 paths), each pixel's `S` (its paths plus `theirs`, the
/// first pass's sums of the row, `[x][D]`) in `own`, and its winner ([`RowSelect`]). Buffers as
/// in [`path_row4`]; `cur` and `cur_min` are empty when `NR` is 0.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn path_row_select<const NR: usize, T: Cell>(
    a: &RowSteps<'_, T>,
    cur: &mut [T],
    cur_min: &mut [u16],
    h0: &mut [T],
    h1: &mut [T],
    theirs: &[u16],
    own: &mut [u16],
    select: &mut RowSelect,
    (right_cost, right_k): (&mut [u16], &mut [u16]),
) -> u16 {
    let mut hmin = a.hmin;
    macro_rules! step {
        ($i:expr, $hprev:expr, $hout:expr) => {
            hmin = pixel_select::<NR, T>(
                a,
                $i,
                hmin,
                cur,
                cur_min,
                $hprev,
                $hout,
                theirs,
                own,
                select,
                (&mut *right_cost, &mut *right_k),
            )
        };
    }
    alternate_steps!(a, h0, h1, step);
    hmin
}

/// One pixel of [`path_row_select`]; returns the horizontal path's new minimum.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn pixel_select<const NR: usize, T: Cell>(
    a: &RowSteps<'_, T>,
    i: usize,
    hmin: u16,
    cur: &mut [T],
    cur_min: &mut [u16],
    hprev: &[T],
    hout: &mut [T],
    theirs_row: &[u16],
    own: &mut [u16],
    select: &mut RowSelect,
    (right_cost, right_k): (&mut [u16], &mut [u16]),
) -> u16 {
    let (w, nd) = (a.w, a.nd);
    let (x, xn) = a.pixel(i);
    // The first pass's sums were written long ago (in memory, not in the cache): ask for those
    // of a pixel a few steps ahead.
    let ahead = if a.forward {
        x + PREFETCH_PX
    } else {
        x.wrapping_sub(PREFETCH_PX)
    };
    if ahead < w {
        prefetch(&theirs_row[ahead * nd..(ahead + 1) * nd]);
    }
    let cost = &a.cost_row[x * nd..(x + 1) * nd];
    let theirs = &theirs_row[x * nd..(x + 1) * nd];
    let (pen, dmin) = (a.pen, a.dmin);
    if NR == 0 {
        let prev = Nbrs::of(hprev, nd);
        let p2h = pen.p2_for(a.img[x], a.img[xn]);
        let (m, best) = path_step_total::<T>(cost, prev, hmin, pen.p1, p2h, hout, theirs, own);
        let (bk, second) = winner(&own[..nd], best, right_cost, right_k, x, w, dmin);
        select.record(&own[..nd], best, bk, second, x);
        return m;
    }
    let (prevs, pmin, p2, outs) = four_paths(a, x, xn, hmin, hprev, hout, cur);
    let (m, best) = path_steps4::<true, T>(cost, prevs, pmin, pen.p1, p2, outs, theirs, own);
    let (bk, second) = winner(&own[..nd], best, right_cost, right_k, x, w, dmin);
    select.record(&own[..nd], best, bk, second, x);
    cur_min[x * 3..(x + 1) * 3].copy_from_slice(&m[1..]);
    m[0]
}

impl<T> RowSteps<'_, T> {
    /// The pixel of step `i` and the one before it on the row.
    #[inline(always)]
    fn pixel(&self, i: usize) -> (usize, usize) {
        if self.forward {
            (i, i - 1)
        } else {
            (self.w - 1 - i, self.w - i)
        }
    }
}

/// The inputs of the four-path step at pixel `x` (`xn` before it on the row): the
/// predecessors' views (the horizontal one first), their minima and P2s, and the outputs
/// (`hout`, then this row's three in `cur`).
#[inline(always)]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn four_paths<'p, 'o, T: Cell>(
    a: &RowSteps<'p, T>,
    x: usize,
    xn: usize,
    hmin: u16,
    hprev: &'p [T],
    hout: &'o mut [T],
    cur: &'o mut [T],
) -> ([Nbrs<'p, T>; 4], [u16; 4], [u16; 4], [&'o mut [T]; 4]) {
    const NR: usize = 3;
    let ((prev_lo, prev_mid, prev_hi), prev_min) = (a.prev, a.prev_min);
    let nd = a.nd;
    let stride = nd + 2;
    let xp = a.dxs.map(|dx| (x as isize + dx) as usize);
    let view = |r: usize| {
        let s = (xp[r] * NR + r) * stride;
        Nbrs {
            lo: &prev_lo[s..s + nd],
            mid: &prev_mid[s + 1..s + 1 + nd],
            hi: &prev_hi[s + 2..s + 2 + nd],
        }
    };
    let prevs = [Nbrs::of(hprev, nd), view(0), view(1), view(2)];
    let pmin = [
        hmin,
        prev_min[xp[0] * NR],
        prev_min[xp[1] * NR + 1],
        prev_min[xp[2] * NR + 2],
    ];
    let (ix, pen) = (a.img[x], a.pen);
    let p2 = [
        pen.p2_for(ix, a.img[xn]),
        pen.p2_for(ix, a.img_prev[xp[0]]),
        pen.p2_for(ix, a.img_prev[xp[1]]),
        pen.p2_for(ix, a.img_prev[xp[2]]),
    ];
    let sx = x * NR * stride;
    let (o1, rest) = cur[sx..sx + NR * stride].split_at_mut(stride);
    let (o2, o3) = rest.split_at_mut(stride);
    (prevs, pmin, p2, [hout, o1, o2, o3])
}
