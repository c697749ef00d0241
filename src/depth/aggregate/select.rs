//! Winner selection of one row of `S`: winner-take-all with uniqueness, the right image's
//! winners for the left–right check, sub-pixel fit and confidence ([`RowSelect`]).

#[allow(unused_imports)]
use super::*;

/// What the second pass to reach a row does with it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Finish {
    /// Selects the disparities of the row (the matcher).
    Select,
    /// Adds its sum into the stored row, leaving the whole `S` (for [`aggregate_paths`]).
    Sum,
}

/// Per-row buffers of the winner selection.
#[derive(Default, Debug)]
pub(super) struct RowSelect {
    /// Winning slice per pixel.
    pub(super) best_k: Vec<u32>,
    /// `S` of the winner.
    pub(super) best: Vec<u16>,
    /// Smallest `S` more than one slice away from the winner (`u16::MAX`: none).
    pub(super) second: Vec<u16>,
    /// `S` at the winner's neighbours (for the sub-pixel fit on `S`).
    pub(super) lo: Vec<u16>,
    pub(super) hi: Vec<u16>,
    /// Right-image winners: the smallest `S` over the pixels matching each right pixel, and
    /// its slice (ties to the smaller slice); `u16::MAX` where none. Indexed `w − 1 − xr`.
    pub(super) right_cost: Vec<u16>,
    pub(super) right_k: Vec<u16>,
    /// Raw costs summed over the rows of the sub-pixel window, `[x][k]`.
    pub(super) colsum: Vec<u16>,
    /// Whether the pixel passed selection (before the left–right check).
    pub(super) valid: Vec<bool>,
    /// The row whose window `colsum` holds (`None`: none yet, for this volume).
    pub(super) colsum_row: Option<usize>,
}

impl RowSelect {
    pub(super) fn reset(&mut self, w: usize) {
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
    pub(super) fn pixel<I: Isa>(&mut self, total: &[u16], x: usize, w: usize, dmin: i32) {
        let best = total.iter().fold(u16::MAX, |m, &v| m.min(v));
        self.pixel_with_min::<I>(total, best, x, w, dmin);
    }

    /// [`RowSelect::pixel`] given `best = min(total)`.
    #[inline(always)]
    pub(super) fn pixel_with_min<I: Isa>(
        &mut self,
        total: &[u16],
        best: u16,
        x: usize,
        w: usize,
        dmin: i32,
    ) {
        let right = (&mut self.right_cost[..], &mut self.right_k[..]);
        let (bk, second) = I::winner(total, best, right, x, w, dmin);
        self.record(total, best, bk, second, x);
    }

    /// Keeps pixel `x`'s winner `bk` (cost `best`), its runner-up cost `second` and its
    /// neighbours' costs in `total` ([`winner`]'s results).
    #[inline(always)]
    pub(super) fn record(&mut self, total: &[u16], best: u16, bk: usize, second: u16, x: usize) {
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
    pub(super) fn window_sums(&mut self, vol: &CostVolume, y: usize, radius: usize) {
        let h = vol.height as usize;
        let n = vol.width as usize * vol.num_disparities;
        let row = |yy: usize| &vol.cost[yy * n..(yy + 1) * n];
        let same_size = self.colsum.len() == n;
        let colsum = &mut self.colsum;
        let mut add_sub = |add: Option<usize>, sub: Option<usize>| match (add, sub) {
            // Both in one sweep over `colsum` (the usual case: it is read and written once).
            (Some(a), Some(b)) => {
                for ((s, &ca), &cb) in colsum.iter_mut().zip(row(a)).zip(row(b)) {
                    *s = s.wrapping_add(ca as u16).wrapping_sub(cb as u16);
                }
            }
            (Some(a), None) => {
                for (s, &c) in colsum.iter_mut().zip(row(a)) {
                    *s = s.wrapping_add(c as u16);
                }
            }
            (None, Some(b)) => {
                for (s, &c) in colsum.iter_mut().zip(row(b)) {
                    *s = s.wrapping_sub(c as u16);
                }
            }
            (None, None) => {}
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
    /// confidence (the rules of [`select_disparities`]). `window_sums`: the raw costs' window
    /// sums of row `y` when the other pass computed them ([`window_sums_into`]), else they are
    /// computed here.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn finish(
        &mut self,
        y: usize,
        raw: Option<&CostVolume>,
        window_sums: Option<&[u16]>,
        w: usize,
        nd: usize,
        params: &SgmParams,
        disparity: &mut [f32],
        confidence: &mut [f32],
    ) {
        let dmin = params.min_disparity_px;
        let radius = (params.subpixel_cost_window / 2) as usize;
        let window = raw.filter(|_| radius > 0);
        if let (Some(vol), None) = (window, window_sums) {
            self.window_sums(vol, y, radius);
        }
        let colsum = window_sums.unwrap_or(&self.colsum);
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
                            let c = &colsum[xx * nd + bk - 1..][..3];
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
pub(super) fn winner(
    total: &[u16],
    best: u16,
    right_cost: &mut [u16],
    right_k: &mut [u16],
    x: usize,
    w: usize,
    dmin: i32,
) -> (usize, u16) {
    let nd = total.len();
    // Slice numbers as u16 lanes (nd ≤ 4096), so that the loops below compare 16-bit lanes
    // rather than carrying a 64-bit index vector.
    let idx = &SLICES[..nd];
    // The first slice with the smallest cost.
    let mut bk = u16::MAX;
    for (&v, &k) in total.iter().zip(idx) {
        bk = bk.min(if v == best { k } else { u16::MAX });
    }
    // Slices more than one away from the winner: k − (bk − 1) > 2 in wrapping arithmetic
    // excludes exactly bk − 1, bk and bk + 1.
    let near_lo = bk.wrapping_sub(1);
    let mut second = u16::MAX;
    for (&v, &k) in total.iter().zip(idx) {
        let far = k.wrapping_sub(near_lo) > 2;
        second = second.min(if far { v } else { u16::MAX });
    }
    let bk = bk as usize;
    // Right pixel of slice k is xr0 − k; slices [k0, k1) fall inside the image.
    let xr0 = x as i64 - dmin as i64;
    let k0 = (xr0 - (w as i64 - 1)).max(0) as usize;
    let k1 = ((xr0 + 1).max(0) as usize).min(nd);
    if k0 < k1 {
        // The right winners are kept in reversed order (index w − 1 − xr), so that slice k of
        // this pixel lands at index w − 1 − xr0 + k: consecutive slices, consecutive entries.
        let n = k1 - k0;
        // (w − 1 − xr0 is negative when dmin < 0 puts xr0 past the right edge; k0 makes up for it.)
        let at = (w as i64 - 1 - xr0 + k0 as i64) as usize;
        let (cost, slice) = (&mut right_cost[at..at + n], &mut right_k[at..at + n]);
        let (src, ks) = (&total[k0..k1], &idx[k0..k1]);
        for j in 0..n {
            let (t, k) = (src[j], ks[j]);
            // Bitwise, not short-circuit, so that it stays a select.
            let better = (t < cost[j]) | ((t == cost[j]) & (k < slice[j]));
            cost[j] = if better { t } else { cost[j] };
            slice[j] = if better { k } else { slice[j] };
        }
    }
    (bk, second)
}

/// 0, 1, 2, … as `u16`: the slice numbers of [`winner`] (at most 4096 disparities).
static SLICES: [u16; 4096] = {
    let mut a = [0u16; 4096];
    let mut i = 0;
    while i < 4096 {
        a[i] = i as u16;
        i += 1;
    }
    a
};

/// The raw costs of the rows `[y − radius, y + radius]` (inside the image) summed per column
/// and slice into `out`, from `prev`, the sums of row `y − 1`, when given (else directly): the
/// forward pass's share of the sub-pixel fit with 5 paths, which it stores beside its path sums
/// for the second pass. The same sums as [`RowSelect::window_sums`]. (Inlined into the pass,
/// so compiled for its instruction set.)
#[inline(always)]
pub(super) fn window_sums_into(
    vol: &CostVolume,
    y: usize,
    radius: usize,
    prev: Option<&[u16]>,
    out: &mut [u16],
) {
    let h = vol.height as usize;
    let n = vol.width as usize * vol.num_disparities;
    let row = |yy: usize| &vol.cost[yy * n..(yy + 1) * n];
    let out = &mut out[..n];
    match prev.filter(|_| y > 0) {
        Some(prev) => {
            let prev = &prev[..n];
            let add = (y + radius < h).then(|| row(y + radius));
            let sub = (y - 1).checked_sub(radius).map(row);
            match (add, sub) {
                (Some(a), Some(b)) => {
                    for (((s, &p), &ca), &cb) in out.iter_mut().zip(prev).zip(a).zip(b) {
                        *s = p.wrapping_add(ca as u16).wrapping_sub(cb as u16);
                    }
                }
                (Some(a), None) => {
                    for ((s, &p), &c) in out.iter_mut().zip(prev).zip(a) {
                        *s = p.wrapping_add(c as u16);
                    }
                }
                (None, Some(b)) => {
                    for ((s, &p), &c) in out.iter_mut().zip(prev).zip(b) {
                        *s = p.wrapping_sub(c as u16);
                    }
                }
                (None, None) => out.copy_from_slice(prev),
            }
        }
        None => {
            out.fill(0);
            for yy in y.saturating_sub(radius)..(y + radius + 1).min(h) {
                for (s, &c) in out.iter_mut().zip(row(yy)) {
                    *s += c as u16;
                }
            }
        }
    }
}

/// How many pixels ahead the second pass prefetches the first pass's sums.
pub(super) const PREFETCH_PX: usize = 6;

/// Hints the CPU to load `data` into the cache (no effect on results; a no-op elsewhere than
/// x86-64).
#[inline(always)]
pub(super) fn prefetch<T>(data: &[T]) {
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
pub(super) fn select_row(
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
    pub(super) fn imp<I: Isa>(
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
        sel.finish(y, raw, None, w, nd, params, drow, crow);
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
