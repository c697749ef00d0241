//! The post-filters of SGM's disparities: the vectorised 3×3 median over valid neighbours and
//! the speckle filter (small connected regions of similar disparity removed).

#[allow(unused_imports)]
use super::*;

/// Calls `$exchange!` with the 25 comparators of the 9-input sorting network (depth 7,
/// Dobbelaere's list of optimal networks) as pairs of the nine locals named: one list for the
/// scalar [`sort9`] and the lane network of [`median_lanes`].
#[rustfmt::skip]
macro_rules! sort9_network {
    ($exchange:ident; $k0:ident, $k1:ident, $k2:ident, $k3:ident, $k4:ident, $k5:ident, $k6:ident,
     $k7:ident, $k8:ident) => {
        $exchange!(
            ($k0, $k3), ($k1, $k7), ($k2, $k5), ($k4, $k8),
            ($k0, $k7), ($k2, $k4), ($k3, $k8), ($k5, $k6),
            ($k0, $k2), ($k1, $k3), ($k4, $k5), ($k7, $k8),
            ($k1, $k4), ($k3, $k6), ($k5, $k7),
            ($k0, $k1), ($k2, $k4), ($k3, $k5), ($k6, $k8),
            ($k2, $k3), ($k4, $k5), ($k6, $k7),
            ($k1, $k2), ($k3, $k4), ($k5, $k6)
        )
    };
}

/// 3×3 median over the valid (finite) neighbours of every valid pixel; invalid pixels stay NaN.
/// An even count averages the two middle values. Values are ordered as `f32::total_cmp` orders
/// them (through their integer keys, sorted by a 25-comparator network: no branches), 16 pixels
/// at a time.
pub fn median_filter_3x3(disparity: &Image<f32>) -> Image<f32> {
    let w = disparity.width as usize;
    let h = disparity.height as usize;
    let mut out = disparity.clone();
    if w == 0 {
        return out;
    }
    out.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        // Neighbour rows (the row itself stands in for a missing one, its values then ignored).
        let line = |yy: usize| &disparity.data[yy * w..(yy + 1) * w];
        let rows = [line(y.saturating_sub(1)), line(y), line((y + 1).min(h - 1))];
        let row_ok = [y > 0, true, y + 1 < h];
        median_row(rows, row_ok, row);
    });
    out
}

/// Pixels filtered together by [`median_lanes`].
pub(super) const MEDIAN_LANES: usize = 16;

/// One row of [`median_filter_3x3`], dispatched to a copy compiled for AVX-512 or AVX2 where the
/// CPU has it.
pub(super) fn median_row(rows: [&[f32]; 3], row_ok: [bool; 3], out: &mut [f32]) {
    #[inline(always)]
    fn imp(rows: [&[f32]; 3], row_ok: [bool; 3], out: &mut [f32]) {
        let w = out.len();
        let mut x = 0;
        // The first column, then interior pixels 16 at a time, then the rest one by one.
        if w > 0 {
            median_px(rows, row_ok, 0, &mut out[0]);
            x = 1;
        }
        while x + MEDIAN_LANES < w {
            median_lanes(rows, row_ok, x, &mut out[x..x + MEDIAN_LANES]);
            x += MEDIAN_LANES;
        }
        while x < w {
            median_px(rows, row_ok, x, &mut out[x]);
            x += 1;
        }
    }
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,avx512vl,avx2")]
        fn avx512(rows: [&[f32]; 3], row_ok: [bool; 3], out: &mut [f32]) {
            imp(rows, row_ok, out)
        }
        #[target_feature(enable = "avx2")]
        fn avx2(rows: [&[f32]; 3], row_ok: [bool; 3], out: &mut [f32]) {
            imp(rows, row_ok, out)
        }
        if std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx512vl") {
            // SAFETY: the CPU supports the features the copy was compiled for (checked above).
            unsafe { avx512(rows, row_ok, out) };
            return;
        }
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: as above.
            unsafe { avx2(rows, row_ok, out) };
            return;
        }
    }
    imp(rows, row_ok, out)
}

/// The median at column `x` of the middle row (any column).
#[inline(always)]
pub(super) fn median_px(rows: [&[f32]; 3], row_ok: [bool; 3], x: usize, out: &mut f32) {
    let w = rows[1].len();
    if rows[1][x].is_nan() {
        return;
    }
    let mut keys = [i32::MAX; 9];
    let mut n = 0;
    for (r, (&line, &ok)) in rows.iter().zip(&row_ok).enumerate() {
        for c in 0..3 {
            let xx = (x + c).wrapping_sub(1);
            let v = if ok && xx < w { line[xx] } else { f32::NAN };
            let valid = !v.is_nan();
            keys[3 * r + c] = if valid { total_order_key(v) } else { i32::MAX };
            n += valid as usize;
        }
    }
    sort9(&mut keys);
    *out = median_of_sorted(|i| keys[i], n);
}

/// The median of the `n` smallest of 9 sorted keys.
#[inline(always)]
pub(super) fn median_of_sorted(key: impl Fn(usize) -> i32, n: usize) -> f32 {
    let at = |i: usize| from_total_order_key(key(i));
    if n % 2 == 1 {
        at(n / 2)
    } else {
        0.5 * (at(n / 2 - 1) + at(n / 2))
    }
}

/// The medians of columns `[x0, x0 + 16)` (all with both horizontal neighbours), lane by lane:
/// the network sorts 16 pixels' keys at once.
#[inline(always)]
pub(super) fn median_lanes(rows: [&[f32]; 3], row_ok: [bool; 3], x0: usize, out: &mut [f32]) {
    const L: usize = MEDIAN_LANES;
    // The keys of one neighbour's 16 lanes (i32::MAX where invalid) and their validity, from a
    // fixed-size array and integer tests only, so that the lanes vectorise.
    #[inline(always)]
    fn key_lanes(src: &[f32], ok: bool) -> ([i32; L], [i32; L]) {
        let src: &[f32; L] = src.try_into().expect("16 lanes");
        let (mut keys, mut valid) = ([0i32; L], [0i32; L]);
        for l in 0..L {
            // Not NaN: exponent and mantissa at most those of infinity.
            let v = ok & (src[l].to_bits() & 0x7fff_ffff <= 0x7f80_0000);
            keys[l] = if v { total_order_key(src[l]) } else { i32::MAX };
            valid[l] = i32::from(v);
        }
        (keys, valid)
    }
    let mut keys = [[i32::MAX; L]; 9];
    let mut n = [0i32; L];
    for r in 0..3 {
        for c in 0..3 {
            let (k, v) = key_lanes(&rows[r][x0 + c - 1..x0 + c - 1 + L], row_ok[r]);
            keys[3 * r + c] = k;
            for l in 0..L {
                n[l] += v[l];
            }
        }
    }
    // The network on nine lane vectors held in locals (not indexed from an array), so that
    // they stay in registers.
    let [mut k0, mut k1, mut k2, mut k3, mut k4, mut k5, mut k6, mut k7, mut k8] = keys;
    macro_rules! exchange_lanes {
        ($(($a:ident, $b:ident)),*) => {$(
            let low: [i32; L] = std::array::from_fn(|l| $a[l].min($b[l]));
            $b = std::array::from_fn(|l| $a[l].max($b[l]));
            $a = low;
        )*};
    }
    sort9_network!(exchange_lanes; k0, k1, k2, k3, k4, k5, k6, k7, k8);
    let keys = [k0, k1, k2, k3, k4, k5, k6, k7, k8];
    let centre = &rows[1][x0..x0 + L];
    for l in 0..L {
        // The middle key(s): positions n/2 − 1 and n/2 (n ≥ 1 where the centre is valid).
        let (mut lo, mut hi) = (i32::MAX, i32::MAX);
        let m = n[l] / 2;
        for (p, k) in keys.iter().enumerate() {
            let p = p as i32;
            lo = if p + 1 == m { k[l] } else { lo };
            hi = if p == m { k[l] } else { hi };
        }
        let (vlo, vhi) = (from_total_order_key(lo), from_total_order_key(hi));
        let median = if n[l] % 2 == 1 {
            vhi
        } else {
            0.5 * (vlo + vhi)
        };
        out[l] = if centre[l].is_nan() {
            centre[l]
        } else {
            median
        };
    }
}

/// An integer whose order is `f32::total_cmp`'s (the same bit trick).
#[inline(always)]
pub(super) fn total_order_key(v: f32) -> i32 {
    let b = v.to_bits() as i32;
    b ^ (((b >> 31) as u32) >> 1) as i32
}

/// Inverse of [`total_order_key`].
#[inline(always)]
pub(super) fn from_total_order_key(k: i32) -> f32 {
    f32::from_bits((k ^ (((k >> 31) as u32) >> 1) as i32) as u32)
}

/// Sorts 9 values ascending with a 25-comparator network of depth 7 (Dobbelaere's list of
/// optimal networks; tested on every 0/1 input).
#[inline(always)]
pub(crate) fn sort9(v: &mut [i32; 9]) {
    let [mut k0, mut k1, mut k2, mut k3, mut k4, mut k5, mut k6, mut k7, mut k8] = *v;
    macro_rules! exchange {
        ($(($a:ident, $b:ident)),*) => {$(
            ($a, $b) = ($a.min($b), $a.max($b));
        )*};
    }
    sort9_network!(exchange; k0, k1, k2, k3, k4, k5, k6, k7, k8);
    *v = [k0, k1, k2, k3, k4, k5, k6, k7, k8];
}

/// Removes speckles: 4-connected regions (neighbours differing by at most `max_diff_px`) of at
/// most `max_size_px` valid pixels become NaN. Returns how many pixels were removed.
///
/// Regions are found as runs: each row splits into maximal runs of valid pixels whose
/// horizontal neighbours are connected, the runs of consecutive rows are joined (union–find)
/// where a pixel is connected to the one above it, and a region's size is the sum of its runs'
/// lengths. The same regions as a flood fill from every pixel, in a few operations per pixel.
/// Horizontal bands of rows are labelled on rayon's threads at once and then joined along their
/// borders ([`remove_speckles_in_bands`]).
pub fn remove_speckles(disparity: &mut Image<f32>, max_size_px: usize, max_diff_px: f32) -> usize {
    // At least 64 rows a band: below that the join costs more than it saves.
    let bands = rayon::current_num_threads().min(disparity.height as usize / 64);
    remove_speckles_in_bands(disparity, max_size_px, max_diff_px, bands)
}

/// [`remove_speckles`] with the rows split into `bands` bands (at least one, at most one per
/// row): the same result for any count, since the regions are the same sets.
pub fn remove_speckles_in_bands(
    disparity: &mut Image<f32>,
    max_size_px: usize,
    max_diff_px: f32,
    bands: usize,
) -> usize {
    let w = disparity.width as usize;
    let h = disparity.height as usize;
    if max_size_px == 0 || w == 0 || h == 0 {
        return 0;
    }
    let connected = |a: f32, b: f32| (a - b).abs() <= max_diff_px;
    let bands = bands.clamp(1, h);
    let first_row = |b: usize| b * h / bands;
    let data = &disparity.data;
    let mut labels: Vec<BandRuns> = (0..bands)
        .into_par_iter()
        .map(|b| BandRuns::label(data, w, first_row(b)..first_row(b + 1), connected))
        .collect();
    // One index space: each band's runs after the previous bands'.
    let mut all = labels.remove(0);
    for (b, band) in (1..).zip(labels) {
        let offset = all.runs.len() as u32;
        let y = first_row(b);
        // A row's run ids in the joined index space.
        let shift = |ids: &[u32]| -> Vec<u32> {
            ids.iter()
                .map(|&id| if id == NONE { NONE } else { id + offset })
                .collect()
        };
        let below = shift(&band.first_ids);
        all.runs.extend(band.runs);
        all.parent.extend(band.parent.iter().map(|&p| p + offset));
        all.size.extend(band.size);
        // The band's first row against the previous band's last row.
        let (row, prev) = (&data[y * w..(y + 1) * w], &data[(y - 1) * w..y * w]);
        let above = std::mem::take(&mut all.last_ids);
        all.join_rows(&below, &above, row, prev, connected);
        all.last_ids = shift(&band.last_ids);
    }
    // Whether each run's region is a speckle (roots found once, serially), then the runs
    // cleared band by band.
    let small: Vec<bool> = (0..all.runs.len() as u32)
        .map(|i| {
            let r = root(&mut all.parent, i);
            all.size[r as usize] as usize <= max_size_px
        })
        .collect();
    let runs = &all.runs;
    let mut rest: &mut [f32] = &mut disparity.data;
    let mut chunks = Vec::with_capacity(bands);
    for b in 0..bands {
        let (band, tail) =
            std::mem::take(&mut rest).split_at_mut((first_row(b + 1) - first_row(b)) * w);
        chunks.push((first_row(b), band));
        rest = tail;
    }
    chunks
        .into_par_iter()
        .map(|(y0, band)| {
            // The band's runs: from its first row (runs are in row order) to past its end.
            let start = runs.partition_point(|r| (r.0 as usize) < y0);
            let mut n = 0;
            for (i, &(y, x0, x1)) in runs.iter().enumerate().skip(start) {
                let row = (y as usize - y0) * w;
                if row >= band.len() {
                    break;
                }
                if small[i] {
                    band[row + x0 as usize..row + x1 as usize].fill(f32::NAN);
                    n += (x1 - x0) as usize;
                }
            }
            n
        })
        .sum()
}

/// "No run" in the per-pixel run ids of a row.
const NONE: u32 = u32::MAX;

/// The runs of a band of rows ([`remove_speckles`]) and their union–find forest.
struct BandRuns {
    /// (row, first column, end column), in row order.
    runs: Vec<(u32, u32, u32)>,
    /// Union–find parents and, at roots, region sizes.
    parent: Vec<u32>,
    size: Vec<u32>,
    /// The run of each pixel of the band's first and last row ([`NONE`]: invalid pixel).
    first_ids: Vec<u32>,
    last_ids: Vec<u32>,
}

/// The root of `r`'s tree, halving the path on the way.
fn root(parent: &mut [u32], mut r: u32) -> u32 {
    while parent[r as usize] != r {
        let up = parent[parent[r as usize] as usize];
        parent[r as usize] = up;
        r = up;
    }
    r
}

impl BandRuns {
    /// Runs of the rows `rows` of `data` (`w` pixels a row), joined within the band.
    fn label(
        data: &[f32],
        w: usize,
        rows: std::ops::Range<usize>,
        connected: impl Fn(f32, f32) -> bool + Copy,
    ) -> Self {
        let mut band = BandRuns {
            runs: Vec::new(),
            parent: Vec::new(),
            size: Vec::new(),
            first_ids: Vec::new(),
            last_ids: Vec::new(),
        };
        // The run of each pixel of the previous and the current row.
        let mut above = vec![NONE; w];
        let mut here = vec![NONE; w];
        for y in rows.clone() {
            let row = &data[y * w..(y + 1) * w];
            let mut x = 0;
            while x < w {
                if row[x].is_nan() {
                    here[x] = NONE;
                    x += 1;
                    continue;
                }
                let x0 = x;
                let id = band.runs.len() as u32;
                here[x] = id;
                x += 1;
                while x < w && !row[x].is_nan() && connected(row[x], row[x - 1]) {
                    here[x] = id;
                    x += 1;
                }
                band.runs.push((y as u32, x0 as u32, x as u32));
                band.parent.push(id);
                band.size.push((x - x0) as u32);
            }
            if y == rows.start {
                band.first_ids = here.clone();
            } else {
                let prev = &data[(y - 1) * w..y * w];
                band.join_rows(&here, &above, row, prev, connected);
            }
            std::mem::swap(&mut above, &mut here);
        }
        band.last_ids = above;
        band
    }

    /// Joins the regions of vertically connected pixels of two consecutive rows (`row` below
    /// `prev`, with their pixels' runs `here` and `above`).
    fn join_rows(
        &mut self,
        here: &[u32],
        above: &[u32],
        row: &[f32],
        prev: &[f32],
        connected: impl Fn(f32, f32) -> bool,
    ) {
        let mut last = (NONE, NONE);
        for x in 0..row.len() {
            let (a, b) = (here[x], above[x]);
            if a == NONE || b == NONE || (a, b) == last || !connected(row[x], prev[x]) {
                continue;
            }
            last = (a, b);
            let (ra, rb) = (root(&mut self.parent, a), root(&mut self.parent, b));
            if ra != rb {
                // The larger region becomes the root.
                let (big, small) = if self.size[ra as usize] >= self.size[rb as usize] {
                    (ra, rb)
                } else {
                    (rb, ra)
                };
                self.parent[small as usize] = big;
                self.size[big as usize] += self.size[small as usize];
            }
        }
    }
}
