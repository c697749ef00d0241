//! The forward pass's row kernel: the four paths of every interior pixel of a row (`L_r` of
//! ←, ↓, ↘, ↙ and their sum), one call per row instead of one per pixel.
//!
//! Called once per pixel, the four-path kernel took its 24 predecessor views, 4 outputs and the
//! penalties as arguments, built on the stack for every call: ~45 stores per pixel, where
//! `perf` found half of the pass's own samples. Here the views are made inside the loop from
//! the row's buffers, which come in as separate arguments, so that the compiler still knows
//! that outputs and inputs do not overlap (the loop vectorises without run-time checks) and
//! still sees the slices `d − 1`, `d`, `d + 1` of a predecessor as unrelated (plain loads, no
//! lane shuffles: the previous row arrives as three arguments that are the same slice).

#[allow(unused_imports)]
use super::*;

/// What [`path_row4`] reads besides the buffers.
#[derive(Clone, Copy)]
pub(super) struct Row4<'a> {
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
}

/// The four-path step ([`path_steps4`]) of every pixel of `a`'s steps, all of which continue
/// every path (interior pixels of a row after the first). `prev`: the previous row's path
/// costs (`[x][dir][D + 2]`, the same slice three times, read as the three neighbour views) and
/// minima; `cur`, `cur_min`: this row's; `h0`, `h1`: the horizontal path at even and odd steps
/// (step `i` reads the other one); `sums`: the row's four-path sums (`[x][D]`). Returns the
/// horizontal path's minimum at the last step.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn path_row4<T: Cell>(
    a: &Row4<'_>,
    cost_row: &[u8],
    (prev_lo, prev_mid, prev_hi): (&[T], &[T], &[T]),
    prev_min: &[u16],
    cur: &mut [T],
    cur_min: &mut [u16],
    h0: &mut [T],
    h1: &mut [T],
    sums: &mut [u16],
) -> u16 {
    let prev = (prev_lo, prev_mid, prev_hi);
    let mut hmin = a.hmin;
    let mut i = a.i0;
    if i < a.i1 && i % 2 == 1 {
        hmin = pixel4(
            a, i, hmin, cost_row, prev, prev_min, cur, cur_min, h0, h1, sums,
        );
        i += 1;
    }
    while i + 1 < a.i1 {
        hmin = pixel4(
            a, i, hmin, cost_row, prev, prev_min, cur, cur_min, h1, h0, sums,
        );
        hmin = pixel4(
            a,
            i + 1,
            hmin,
            cost_row,
            prev,
            prev_min,
            cur,
            cur_min,
            h0,
            h1,
            sums,
        );
        i += 2;
    }
    if i < a.i1 {
        hmin = pixel4(
            a, i, hmin, cost_row, prev, prev_min, cur, cur_min, h1, h0, sums,
        );
    }
    hmin
}

/// One pixel of [`path_row4`] at step `i`, reading the horizontal path from `hprev` (its
/// minimum `hmin`) and writing it to `hout`; returns the new minimum.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn pixel4<T: Cell>(
    a: &Row4<'_>,
    i: usize,
    hmin: u16,
    cost_row: &[u8],
    (prev_lo, prev_mid, prev_hi): (&[T], &[T], &[T]),
    prev_min: &[u16],
    cur: &mut [T],
    cur_min: &mut [u16],
    hprev: &[T],
    hout: &mut [T],
    sums: &mut [u16],
) -> u16 {
    const NR: usize = 3;
    let (w, nd) = (a.w, a.nd);
    let stride = nd + 2;
    let x = if a.forward { i } else { w - 1 - i };
    let xn = if a.forward { x - 1 } else { x + 1 };
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
    let sum = &mut sums[x * nd..(x + 1) * nd];
    let cost = &cost_row[x * nd..(x + 1) * nd];
    let (m, _) = path_steps4::<false, T>(
        cost,
        prevs,
        pmin,
        a.pen.p1,
        p2,
        [hout, o1, o2, o3],
        &[],
        sum,
    );
    cur_min[x * NR..(x + 1) * NR].copy_from_slice(&m[1..]);
    m[0]
}

/// The second pass's row kernel: the `NR + 1` paths of every interior pixel of a row (`NR` = 3,
/// or 0: the lone right→left path of 5 paths), each pixel's `S` (its paths plus `theirs`, the
/// first pass's sums of the row, `[x][D]`) in `own`, and its winner ([`RowSelect`]). Buffers as
/// in [`path_row4`]; `prev_*`, `prev_min`, `cur` and `cur_min` are empty when `NR` is 0.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn path_row_select<const NR: usize, T: Cell>(
    a: &Row4<'_>,
    cost_row: &[u8],
    prev: (&[T], &[T], &[T]),
    prev_min: &[u16],
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
    let mut i = a.i0;
    // (Spelled out, not a closure: the closure of the first version stayed out of line.)
    macro_rules! step {
        ($i:expr, $hprev:expr, $hout:expr) => {
            hmin = pixel_select::<NR, T>(
                a,
                $i,
                hmin,
                cost_row,
                prev,
                prev_min,
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
    if i < a.i1 && i % 2 == 1 {
        step!(i, h0, h1);
        i += 1;
    }
    while i + 1 < a.i1 {
        step!(i, h1, h0);
        step!(i + 1, h0, h1);
        i += 2;
    }
    if i < a.i1 {
        step!(i, h1, h0);
    }
    hmin
}

/// One pixel of [`path_row_select`]; returns the horizontal path's new minimum.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn pixel_select<const NR: usize, T: Cell>(
    a: &Row4<'_>,
    i: usize,
    hmin: u16,
    cost_row: &[u8],
    (prev_lo, prev_mid, prev_hi): (&[T], &[T], &[T]),
    prev_min: &[u16],
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
    let stride = nd + 2;
    let x = if a.forward { i } else { w - 1 - i };
    let xn = if a.forward { x - 1 } else { x + 1 };
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
    let cost = &cost_row[x * nd..(x + 1) * nd];
    let theirs = &theirs_row[x * nd..(x + 1) * nd];
    let (ix, pen) = (a.img[x], a.pen);
    let p2h = pen.p2_for(ix, a.img[xn]);
    let dmin = a.dmin;
    if NR == 0 {
        let prev = Nbrs::of(hprev, nd);
        let (m, best) = path_step_total::<T>(cost, prev, hmin, pen.p1, p2h, hout, theirs, own);
        let (bk, second) = winner(&own[..nd], best, right_cost, right_k, x, w, dmin);
        select.record(&own[..nd], best, bk, second, x);
        return m;
    }
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
    let p2 = [
        p2h,
        pen.p2_for(ix, a.img_prev[xp[0]]),
        pen.p2_for(ix, a.img_prev[xp[1]]),
        pen.p2_for(ix, a.img_prev[xp[2]]),
    ];
    let sx = x * NR * stride;
    let (o1, rest) = cur[sx..sx + NR * stride].split_at_mut(stride);
    let (o2, o3) = rest.split_at_mut(stride);
    let outs = [hout, o1, o2, o3];
    let (m, best) = path_steps4::<true, T>(cost, prevs, pmin, pen.p1, p2, outs, theirs, own);
    let (bk, second) = winner(&own[..nd], best, right_cost, right_k, x, w, dmin);
    select.record(&own[..nd], best, bk, second, x);
    cur_min[x * NR..(x + 1) * NR].copy_from_slice(&m[1..]);
    m[0]
}
