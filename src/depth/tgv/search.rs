//! The data term: census costs box-filtered over a window ([`box_filtered_costs`]) and the
//! point-wise decoupling search for `a` ([`decoupling_search`]).

#[allow(unused_imports)]
use super::*;

/// Census costs averaged over a square window, as `u16` sums (divide by `window²` for bits),
/// layout of the [`CostVolume`]. Border pixels average over the part of the window inside.
/// Returns the sums and, per pixel, the number of pixels summed.
pub fn box_filtered_costs(volume: &CostVolume, window: u32) -> (Vec<u16>, Vec<u16>) {
    let (mut sum, mut count) = (Vec::new(), Vec::new());
    box_filter_into(volume, window, &mut sum, &mut count);
    (sum, count)
}

/// Rows of the box filter's output handed to one parallel task (each task also sums the
/// `window − 1` rows around its band once more).
pub(super) const BOX_ROWS_PER_TASK: usize = 32;

/// [`box_filtered_costs`] into reused buffers: running sums along the rows, then along the
/// columns (each output row is the previous one plus the entering row's horizontal sums minus
/// the leaving row's), so the cost per entry does not grow with the window. Integer sums: the
/// result equals summing every window directly.
pub(crate) fn box_filter_into(
    volume: &CostVolume,
    window: u32,
    sum: &mut Vec<u16>,
    count: &mut Vec<u16>,
) {
    let w = volume.width as usize;
    let h = volume.height as usize;
    let nd = volume.num_disparities;
    let r = (window / 2) as usize;
    let row_len = w * nd;
    if sum.len() != w * h * nd {
        *sum = vec![0u16; w * h * nd];
    }
    count.clear();
    count.extend((0..h).flat_map(|y| {
        let cy = (y + r).min(h - 1) - y.saturating_sub(r) + 1;
        (0..w).map(move |x| {
            let cx = (x + r).min(w - 1) - x.saturating_sub(r) + 1;
            (cx * cy) as u16
        })
    }));
    if row_len == 0 {
        return;
    }
    let ring_rows = 2 * r + 1;
    sum.par_chunks_mut(BOX_ROWS_PER_TASK * row_len)
        .enumerate()
        .for_each(|(task, out)| {
            // Horizontal sums of the rows in the current vertical window, slot = row % (2r+1).
            let mut ring = vec![0u16; ring_rows * row_len];
            let horizontal = |yy: usize, dst: &mut [u16]| {
                box_filter_row(&volume.cost[yy * row_len..(yy + 1) * row_len], nd, r, dst)
            };
            let y0 = task * BOX_ROWS_PER_TASK;
            let rows = out.len() / row_len;
            let (first, rest) = out.split_at_mut(row_len);
            // First output row of the band: the window summed directly.
            first.fill(0);
            for yy in y0.saturating_sub(r)..(y0 + r + 1).min(h) {
                let slot = &mut ring[(yy % ring_rows) * row_len..][..row_len];
                horizontal(yy, slot);
                for (o, &v) in first.iter_mut().zip(slot.iter()) {
                    *o = o.wrapping_add(v);
                }
            }
            let mut prev: &[u16] = first;
            for (j, cur) in rest.chunks_exact_mut(row_len).enumerate() {
                let y = y0 + 1 + j;
                debug_assert!(y < y0 + rows);
                cur.copy_from_slice(prev);
                // The row leaving the window, then the row entering it (same ring slot).
                if y > r {
                    let slot = &ring[((y - r - 1) % ring_rows) * row_len..][..row_len];
                    for (o, &v) in cur.iter_mut().zip(slot) {
                        *o = o.wrapping_sub(v);
                    }
                }
                if y + r < h {
                    let slot = &mut ring[((y + r) % ring_rows) * row_len..][..row_len];
                    horizontal(y + r, slot);
                    for (o, &v) in cur.iter_mut().zip(slot.iter()) {
                        *o = o.wrapping_add(v);
                    }
                }
                prev = cur;
            }
        });
}

/// Horizontal window sums of one row of costs (`[x][k]`, `nd` slices): `dst[x] = Σ src[xx]` over
/// `xx ∈ [x − r, x + r] ∩ [0, w)`.
pub(super) fn box_filter_row(src: &[u8], nd: usize, r: usize, dst: &mut [u16]) {
    let w = src.len() / nd;
    let (first, rest) = dst.split_at_mut(nd);
    first.fill(0);
    for xx in 0..(r + 1).min(w) {
        for (o, &c) in first.iter_mut().zip(&src[xx * nd..(xx + 1) * nd]) {
            *o += c as u16;
        }
    }
    let mut prev: &[u16] = first;
    for (j, cur) in rest.chunks_exact_mut(nd).enumerate() {
        let x = j + 1;
        let add = (x + r < w).then(|| &src[(x + r) * nd..(x + r + 1) * nd]);
        let sub = (x > r).then(|| &src[(x - r - 1) * nd..(x - r) * nd]);
        match (add, sub) {
            (Some(a), Some(s)) => {
                for (((o, &p), &a), &s) in cur.iter_mut().zip(prev).zip(a).zip(s) {
                    *o = p.wrapping_add(a as u16).wrapping_sub(s as u16);
                }
            }
            (Some(a), None) => {
                for ((o, &p), &a) in cur.iter_mut().zip(prev).zip(a) {
                    *o = p.wrapping_add(a as u16);
                }
            }
            (None, Some(s)) => {
                for ((o, &p), &s) in cur.iter_mut().zip(prev).zip(s) {
                    *o = p.wrapping_sub(s as u16);
                }
            }
            (None, None) => cur.copy_from_slice(prev),
        }
        prev = cur;
    }
}

/// The data term's cost `C(x, d)` in bits: raw or window-averaged census costs.
pub(crate) struct DataCost<'a> {
    pub(crate) volume: &'a CostVolume,
    pub(crate) filtered: Option<(Vec<u16>, Vec<u16>)>,
}

impl<'a> DataCost<'a> {
    /// The data cost of `volume` averaged over `window` × `window` (raw when 1).
    pub(crate) fn new(volume: &'a CostVolume, window: u32) -> Self {
        Self::with_buffers(volume, window, (Vec::new(), Vec::new()))
    }

    /// [`DataCost::new`] filling reused buffers (sums, counts).
    pub(crate) fn with_buffers(
        volume: &'a CostVolume,
        window: u32,
        (mut sum, mut count): (Vec<u16>, Vec<u16>),
    ) -> Self {
        let filtered = (window > 1).then(|| {
            box_filter_into(volume, window, &mut sum, &mut count);
            (sum, count)
        });
        DataCost { volume, filtered }
    }

    /// The buffers, for reuse.
    pub(crate) fn into_buffers(self) -> (Vec<u16>, Vec<u16>) {
        self.filtered.unwrap_or_default()
    }
}

/// The point-wise search of [`TgvMatcher::refine`] on its own: for each pixel, the disparity `a`
/// (pixels) minimising `λ·C(x, a) + (u(x) − a)²/(2θ)` over the census costs of `volume`
/// averaged over `cost_window` × `cost_window` (raw when 1), with the parabola fit. `u` has one
/// disparity per pixel (pixels). The CPU twin of [`crate::depth::pointwise_search_gpu`].
pub fn decoupling_search(
    volume: &CostVolume,
    cost_window: u32,
    u: &[f32],
    lambda: f32,
    theta: f32,
) -> Result<Vec<f32>> {
    check_search(volume, cost_window, u, lambda, theta)?;
    let data = DataCost::new(volume, cost_window);
    let mut a = vec![0.0; u.len()];
    pointwise_search(&data, u, lambda, theta, &mut a);
    Ok(a)
}

/// Checks the arguments of [`decoupling_search`] (and of its GPU twin).
pub(crate) fn check_search(
    volume: &CostVolume,
    cost_window: u32,
    u: &[f32],
    lambda: f32,
    theta: f32,
) -> Result<()> {
    let n = volume.width as usize * volume.height as usize;
    if u.len() != n || volume.cost.len() != n * volume.num_disparities {
        return Err(Error::InvalidArgument(format!(
            "point-wise search over a {}×{}×{} volume ({} costs) got {} disparities",
            volume.width,
            volume.height,
            volume.num_disparities,
            volume.cost.len(),
            u.len()
        )));
    }
    if volume.num_disparities == 0 {
        return Err(Error::InvalidArgument("cost volume has no slices".into()));
    }
    if cost_window.is_multiple_of(2) || cost_window > MAX_COST_WINDOW {
        return Err(Error::InvalidArgument(format!(
            "cost_window must be odd and at most {MAX_COST_WINDOW}, got {cost_window}"
        )));
    }
    if !(lambda.is_finite() && lambda > 0.0 && theta.is_finite() && theta > 0.0) {
        return Err(Error::InvalidArgument(format!(
            "λ and θ must be positive and finite, got {lambda} and {theta}"
        )));
    }
    Ok(())
}

/// Point-wise search of the decoupling step: `a(x) = argmin_d λ·C(x, d) + (u(x) − d)²/(2θ)` over
/// the integer slices, refined by a parabola through the energies of the winner's neighbours
/// (offset clamped to ±0.5). Only slices with `(u − d)²/(2θ) ≤ λ·C_max` are visited.
pub(crate) fn pointwise_search(data: &DataCost, u: &[f32], lambda: f32, theta: f32, a: &mut [f32]) {
    let v = data.volume;
    match &data.filtered {
        None => search_rows::<u8, false>(v, &v.cost, &[], u, lambda, theta, a),
        Some((sum, count)) => search_rows::<u16, true>(v, sum, count, u, lambda, theta, a),
    }
}

/// A cost as stored: raw `u8` bits or `u16` window sums.
pub(super) trait CostValue: Copy + Send + Sync {
    fn f(self) -> f32;
}

impl CostValue for u8 {
    #[inline(always)]
    fn f(self) -> f32 {
        self as f32
    }
}

impl CostValue for u16 {
    #[inline(always)]
    fn f(self) -> f32 {
        self as f32
    }
}

/// Slices evaluated together by [`search_pixel`] (one AVX-512 vector of `f32`).
pub(super) const SEARCH_LANES: usize = 16;

/// [`pointwise_search`] over costs `costs` (`[pixel][slice]`), divided by `counts[pixel]` when
/// `DIV` (window sums) or taken as they are; rows in parallel.
#[allow(clippy::too_many_arguments)]
pub(super) fn search_rows<C: CostValue, const DIV: bool>(
    v: &CostVolume,
    costs: &[C],
    counts: &[u16],
    u: &[f32],
    lambda: f32,
    theta: f32,
    a: &mut [f32],
) {
    let w = v.width as usize;
    a.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        #[inline(always)]
        #[allow(clippy::too_many_arguments)]
        fn imp<C: CostValue, const DIV: bool>(
            v: &CostVolume,
            costs: &[C],
            counts: &[u16],
            u: &[f32],
            lambda: f32,
            theta: f32,
            y: usize,
            row: &mut [f32],
        ) {
            let w = row.len();
            for (x, ax) in row.iter_mut().enumerate() {
                let i = y * w + x;
                *ax = search_pixel::<C, DIV>(v, costs, counts, u[i], i, lambda, theta);
            }
        }
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2")]
            #[allow(clippy::too_many_arguments)]
            fn avx512<C: CostValue, const DIV: bool>(
                v: &CostVolume,
                costs: &[C],
                counts: &[u16],
                u: &[f32],
                lambda: f32,
                theta: f32,
                y: usize,
                row: &mut [f32],
            ) {
                imp::<C, DIV>(v, costs, counts, u, lambda, theta, y, row)
            }
            #[target_feature(enable = "avx2")]
            #[allow(clippy::too_many_arguments)]
            fn avx2<C: CostValue, const DIV: bool>(
                v: &CostVolume,
                costs: &[C],
                counts: &[u16],
                u: &[f32],
                lambda: f32,
                theta: f32,
                y: usize,
                row: &mut [f32],
            ) {
                imp::<C, DIV>(v, costs, counts, u, lambda, theta, y, row)
            }
            if std::is_x86_feature_detected!("avx512bw")
                && std::is_x86_feature_detected!("avx512vl")
            {
                // SAFETY: the CPU supports the features the copy was compiled for (checked
                // above).
                unsafe { avx512::<C, DIV>(v, costs, counts, u, lambda, theta, y, row) };
                return;
            }
            if std::is_x86_feature_detected!("avx2") {
                // SAFETY: as above.
                unsafe { avx2::<C, DIV>(v, costs, counts, u, lambda, theta, y, row) };
                return;
            }
        }
        imp::<C, DIV>(v, costs, counts, u, lambda, theta, y, row)
    });
}

/// The point-wise search at pixel `i` (module docs): energies of [`SEARCH_LANES`] slices at a
/// time, then the first smallest and the parabola through its neighbours. Every energy is the
/// same IEEE expression `λ·C + (k − u)²/(2θ)` evaluated one by one, so the result does not
/// depend on the grouping.
#[inline(always)]
pub(super) fn search_pixel<C: CostValue, const DIV: bool>(
    v: &CostVolume,
    costs: &[C],
    counts: &[u16],
    u: f32,
    i: usize,
    lambda: f32,
    theta: f32,
) -> f32 {
    let nd = v.num_disparities;
    let dmin = v.min_disparity_px as f32;
    let reach = (2.0 * theta * lambda * v.max_cost as f32).sqrt();
    let uk = u - dmin;
    let k0 = ((uk - reach).floor().max(0.0) as usize).min(nd - 1);
    let k1 = ((uk + reach).ceil().max(0.0) as usize).min(nd - 1);
    let count = if DIV { counts[i] as f32 } else { 1.0 };
    let pixel = &costs[i * nd..(i + 1) * nd];
    let cost = |c: C| if DIV { c.f() / count } else { c.f() };
    let energy = |k: usize| {
        let d = k as f32 - uk;
        lambda * cost(pixel[k]) + d * d / (2.0 * theta)
    };
    let mut best = k0;
    let mut best_e = f32::INFINITY;
    let mut k = k0;
    // Energies of the last group, for the parabola.
    let mut group = [f32::INFINITY; SEARCH_LANES];
    let mut group_k0 = k0;
    while k <= k1 {
        let n = (k1 + 1 - k).min(SEARCH_LANES);
        if k + SEARCH_LANES <= nd {
            // A whole group of slices inside the pixel's costs (lanes past k1 are ignored).
            let src = &pixel[k..k + SEARCH_LANES];
            for (j, (e, &c)) in group.iter_mut().zip(src).enumerate() {
                let d = (k + j) as f32 - uk;
                let ej = lambda * cost(c) + d * d / (2.0 * theta);
                *e = if j < n { ej } else { f32::INFINITY };
            }
        } else {
            for (j, e) in group.iter_mut().enumerate() {
                *e = if j < n { energy(k + j) } else { f32::INFINITY };
            }
        }
        group_k0 = k;
        for (j, &e) in group[..n].iter().enumerate() {
            if e < best_e {
                best_e = e;
                best = k + j;
            }
        }
        k += n;
    }
    let mut d = best as f32;
    if best > 0 && best + 1 < nd {
        let at = |k: usize| {
            if k >= group_k0 && k < group_k0 + SEARCH_LANES && k <= k1 {
                group[k - group_k0]
            } else {
                energy(k)
            }
        };
        let (em, ep) = (at(best - 1), at(best + 1));
        let denom = em - 2.0 * best_e + ep;
        if denom > 1e-9 {
            d += (0.5 * (em - ep) / denom).clamp(-0.5, 0.5);
        }
    }
    d + dmin
}
