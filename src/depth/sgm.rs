//! Semi-global matching (Hirschmüller, "Stereo Processing by Semiglobal Matching and Mutual
//! Information", TPAMI 2008) on a census/Hamming cost volume.
//!
//! Stages, each a function of its own so that other estimators (the variational TGV matcher) can
//! reuse them:
//! 1. [`CostVolume::from_census`]: matching cost `C(p, d)` = Hamming distance between the census
//!    signatures of left pixel `(x, y)` and right pixel `(x − d, y)`, for
//!    `d ∈ [min_disparity_px, min_disparity_px + num_disparities)`, stored as `u8` with the
//!    disparities of one pixel contiguous. Right pixels outside the image cost the maximum.
//! 2. Path aggregation (eq. 13 of the paper): along each of 4 or 8 directions `r`,
//!    `L_r(p, d) = C(p, d) + min(L_r(p−r, d), L_r(p−r, d±1) + P1, min_k L_r(p−r, k) + P2)
//!    − min_k L_r(p−r, k)`, summed into `S(p, d)` (`u16`). P2 may adapt to the intensity step
//!    along the path, `P2' = max(P1 + 1, P2·s / (s + |I(p) − I(p−r)|))` (after the paper's
//!    `P2/|ΔI|`). Horizontal paths run rayon-parallel over rows; vertical and diagonal paths
//!    sweep rows and run parallel over columns within a row.
//! 3. Winner-take-all with a uniqueness ratio, sub-pixel refinement (parabola, eq. 12 area, or
//!    equiangular fit), left–right consistency with a right disparity map taken from the same
//!    `S` (`D_r(x_r) = argmin_d S(x_r + d, d)`), optional 3×3 median, speckle removal.
//!
//! Invalid pixels (occluded, ambiguous, inconsistent, speckles, matched outside the right
//! image) are NaN and stay NaN: nothing is interpolated or filled.
//!
//! Hot loops are compiled twice on x86-64 (baseline and AVX2/POPCNT) and picked at run time.

use super::census::{census_transform, CensusImage, CensusParams};
use super::{DisparityEstimator, DisparityMap};
use crate::error::{Error, Result};
use crate::frame::{GreyImage, Image};
use rayon::prelude::*;

/// Sentinel for "no such disparity" in padded path buffers; larger than any path cost plus P2,
/// small enough that adding P1 cannot overflow `u16`.
const BIG: u16 = 16_384;
/// Largest P2 accepted, so that 8 summed paths fit `u16`: 8·(128 + 2000) < 65 535.
const MAX_P2: u16 = 2000;
/// Pixels per parallel task in the row sweeps of vertical and diagonal paths.
const COLUMN_CHUNK: usize = 64;

/// Which aggregation directions to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SgmPaths {
    /// Left, right, up, down.
    Four,
    /// The four above plus the four diagonals (the paper's recommendation).
    Eight,
}

/// How the winning integer disparity is refined to sub-pixel precision from `S(d−1), S(d), S(d+1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SubpixelFit {
    /// No refinement: integer disparities.
    None,
    /// Parabola through the three costs (Hirschmüller 2008).
    Parabola,
    /// Equiangular (V-shaped) fit (Shimizu & Okutomi 2005); suits the L1-like census cost.
    Equiangular,
}

/// Parameters of [`SgmMatcher`]. Disparities in pixels, costs in Hamming units (bits).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SgmParams {
    /// Smallest disparity searched, pixels (may be negative).
    pub min_disparity_px: i32,
    /// Number of disparities searched: `[min, min + num)`, pixels. KITTI: 128.
    pub num_disparities: usize,
    /// Census window and comparison.
    pub census: CensusParams,
    /// Penalty for a disparity change of one pixel between neighbours along a path.
    pub p1: u16,
    /// Penalty for larger disparity changes (≤ 2000, > `p1`).
    pub p2: u16,
    /// When `Some(s)`, P2 shrinks at intensity edges: `max(P1 + 1, P2·s / (s + |ΔI|))`, ΔI in grey
    /// levels between consecutive pixels of the path.
    pub p2_intensity_scale: Option<u16>,
    /// Aggregation directions.
    pub paths: SgmPaths,
    /// Sub-pixel refinement.
    pub subpixel: SubpixelFit,
    /// When > 0 (odd), the sub-pixel fit uses the raw costs summed over this square window
    /// (pixels) instead of the aggregated `S`, whose values next to the winner saturate near P1
    /// and pull disparities towards integers ("pixel locking"). 0 fits on `S`.
    pub subpixel_cost_window: u32,
    /// Uniqueness margin as a fraction (0.1 = 10 %): a pixel is invalid when some disparity more
    /// than one pixel away from the winner costs less than `S_best / (1 − margin)`. 0 disables.
    pub uniqueness_ratio: f32,
    /// Left–right consistency: largest allowed difference between the left and right integer
    /// disparities, pixels; `None` disables the check.
    pub lr_max_diff_px: Option<u32>,
    /// 3×3 median over valid neighbours before speckle removal.
    pub median_filter: bool,
    /// Connected regions of at most this many pixels are removed as speckles; 0 disables.
    pub speckle_max_size_px: usize,
    /// Neighbours differing by at most this much belong to the same speckle region, pixels.
    pub speckle_max_diff_px: f32,
}

impl Default for SgmParams {
    /// KITTI-sized defaults: 128 disparities from 0, 9×7 binary census, 8 paths, equiangular
    /// sub-pixel fit, P1 = 14, P2 = 110 adapted with scale 16, 5 % uniqueness, LR check at
    /// 1 px, median on, speckles ≤ 100 px (tuned on Middlebury 2014 Motorcycle, quarter size).
    fn default() -> Self {
        SgmParams {
            min_disparity_px: 0,
            num_disparities: 128,
            census: CensusParams::default(),
            p1: 14,
            p2: 110,
            p2_intensity_scale: Some(16),
            paths: SgmPaths::Eight,
            subpixel: SubpixelFit::Equiangular,
            subpixel_cost_window: 5,
            uniqueness_ratio: 0.05,
            lr_max_diff_px: Some(1),
            median_filter: true,
            speckle_max_size_px: 100,
            speckle_max_diff_px: 1.0,
        }
    }
}

impl SgmParams {
    /// Checks ranges (disparity count, penalties, ratios).
    pub fn validate(&self) -> Result<()> {
        self.census.validate()?;
        if self.num_disparities < 2 || self.num_disparities > 4096 {
            return Err(Error::InvalidArgument(format!(
                "num_disparities must be in [2, 4096], got {}",
                self.num_disparities
            )));
        }
        if self.p1 == 0 || self.p2 <= self.p1 || self.p2 > MAX_P2 {
            return Err(Error::InvalidArgument(format!(
                "SGM penalties need 0 < P1 < P2 ≤ {MAX_P2}, got P1 = {}, P2 = {}",
                self.p1, self.p2
            )));
        }
        if self.p2_intensity_scale == Some(0) {
            return Err(Error::InvalidArgument(
                "p2_intensity_scale must be positive".into(),
            ));
        }
        if self.subpixel_cost_window % 2 == 0 && self.subpixel_cost_window != 0 {
            return Err(Error::InvalidArgument(format!(
                "subpixel_cost_window must be 0 or odd, got {}",
                self.subpixel_cost_window
            )));
        }
        if !(0.0..1.0).contains(&self.uniqueness_ratio) {
            return Err(Error::InvalidArgument(format!(
                "uniqueness_ratio must be in [0, 1), got {}",
                self.uniqueness_ratio
            )));
        }
        if !(self.speckle_max_diff_px >= 0.0) {
            return Err(Error::InvalidArgument(
                "speckle_max_diff_px must be ≥ 0".into(),
            ));
        }
        Ok(())
    }
}

/// Matching costs `C(x, y, d)` of a rectified pair, `u8`, disparities of a pixel contiguous.
#[derive(Clone, Debug, PartialEq)]
pub struct CostVolume {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Disparity of slice 0, pixels.
    pub min_disparity_px: i32,
    /// Number of disparity slices.
    pub num_disparities: usize,
    /// Largest possible cost (also the cost where the right pixel is outside the image).
    pub max_cost: u8,
    /// Costs; pixel (x, y), disparity `min + k` at `cost[(y·width + x)·num_disparities + k]`.
    pub cost: Vec<u8>,
}

impl CostVolume {
    /// Costs of all disparities at pixel (x, y).
    #[inline]
    pub fn pixel_costs(&self, x: u32, y: u32) -> &[u8] {
        let i = (y as usize * self.width as usize + x as usize) * self.num_disparities;
        &self.cost[i..i + self.num_disparities]
    }

    /// Hamming costs between left and right census images (rayon-parallel over rows).
    pub fn from_census(
        left: &CensusImage,
        right: &CensusImage,
        min_disparity_px: i32,
        num_disparities: usize,
    ) -> Result<CostVolume> {
        if left.width != right.width
            || left.height != right.height
            || left.words_per_pixel != right.words_per_pixel
        {
            return Err(Error::InvalidArgument(format!(
                "census images differ: {}×{} ({} words) vs {}×{} ({} words)",
                left.width,
                left.height,
                left.words_per_pixel,
                right.width,
                right.height,
                right.words_per_pixel
            )));
        }
        let w = left.width as usize;
        let h = left.height as usize;
        let max_cost = u8::try_from(left.bits).map_err(|_| {
            Error::InvalidArgument(format!(
                "census signatures of {} bits do not fit u8 costs",
                left.bits
            ))
        })?;
        let mut cost = vec![0u8; w * h * num_disparities];
        if w > 0 {
            cost.par_chunks_mut(w * num_disparities)
                .enumerate()
                .for_each(|(y, row)| {
                    let words = left.words_per_pixel;
                    let l = &left.data[y * w * words..(y + 1) * w * words];
                    let r = &right.data[y * w * words..(y + 1) * w * words];
                    cost_row(
                        l,
                        r,
                        words,
                        min_disparity_px,
                        num_disparities,
                        max_cost,
                        row,
                    );
                });
        }
        Ok(CostVolume {
            width: left.width,
            height: left.height,
            min_disparity_px,
            num_disparities,
            max_cost,
            cost,
        })
    }
}

#[inline(always)]
fn cost_row_impl(
    l: &[u64],
    r: &[u64],
    words: usize,
    dmin: i32,
    nd: usize,
    max_cost: u8,
    out: &mut [u8],
) {
    let w = l.len() / words;
    out.fill(max_cost);
    for x in 0..w {
        let o = &mut out[x * nd..(x + 1) * nd];
        // Slices k ∈ [k0, k1) have their right pixel x − dmin − k inside [0, w).
        let k0 = (x as i64 - dmin as i64 - (w as i64 - 1)).max(0) as usize;
        let k1 = ((x as i64 - dmin as i64 + 1).max(0) as usize).min(nd);
        if k0 >= k1 {
            continue;
        }
        // Right pixel of slice k is xr0 − k.
        let xr0 = (x as i64 - dmin as i64) as usize;
        if words == 1 {
            let a = l[x];
            for (k, c) in o[k0..k1].iter_mut().enumerate() {
                *c = (a ^ r[xr0 - (k0 + k)]).count_ones() as u8;
            }
        } else {
            let (a0, a1) = (l[2 * x], l[2 * x + 1]);
            for (k, c) in o[k0..k1].iter_mut().enumerate() {
                let xr = xr0 - (k0 + k);
                *c = ((a0 ^ r[2 * xr]).count_ones() + (a1 ^ r[2 * xr + 1]).count_ones()) as u8;
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
fn cost_row_avx2(
    l: &[u64],
    r: &[u64],
    words: usize,
    dmin: i32,
    nd: usize,
    max_cost: u8,
    out: &mut [u8],
) {
    cost_row_impl(l, r, words, dmin, nd, max_cost, out)
}

fn cost_row(
    l: &[u64],
    r: &[u64],
    words: usize,
    dmin: i32,
    nd: usize,
    max_cost: u8,
    out: &mut [u8],
) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("popcnt") {
        // SAFETY: the CPU supports the features the function was compiled for (checked above).
        unsafe { cost_row_avx2(l, r, words, dmin, nd, max_cost, out) };
        return;
    }
    cost_row_impl(l, r, words, dmin, nd, max_cost, out)
}

/// One step of eq. 13 along a path: `out[1..=D]` ← L_r(p, ·) from `prev[1..=D]` (= L_r(p−r, ·),
/// padded with [`BIG`] at 0 and D+1), and `acc` gets it added (or assigned when `ASSIGN`).
/// Returns `min_d L_r(p, d)`.
#[inline(always)]
fn path_step<const ASSIGN: bool>(
    cost: &[u8],
    prev: &[u16],
    prev_min: u16,
    p1: u16,
    p2: u16,
    out: &mut [u16],
    acc: &mut [u16],
) -> u16 {
    let d = cost.len();
    let (lo, mid, hi) = (&prev[0..d], &prev[1..d + 1], &prev[2..d + 2]);
    let out = &mut out[1..d + 1];
    let acc = &mut acc[..d];
    let jump = prev_min + p2;
    let mut m = u16::MAX;
    for k in 0..d {
        let best = mid[k].min(lo[k] + p1).min(hi[k] + p1).min(jump);
        let v = cost[k] as u16 + best - prev_min;
        out[k] = v;
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
fn path_start<const ASSIGN: bool>(cost: &[u8], out: &mut [u16], acc: &mut [u16]) -> u16 {
    let d = cost.len();
    let out = &mut out[1..d + 1];
    let acc = &mut acc[..d];
    let mut m = u16::MAX;
    for k in 0..d {
        let v = cost[k] as u16;
        out[k] = v;
        if ASSIGN {
            acc[k] = v;
        } else {
            acc[k] += v;
        }
        m = m.min(v);
    }
    m
}

/// P1, P2 and the optional intensity adaptation, as integers for the inner loops.
#[derive(Clone, Copy)]
struct Penalties {
    p1: u16,
    p2: u16,
    scale: Option<u32>,
}

impl Penalties {
    #[inline(always)]
    fn p2_for(&self, a: u8, b: u8) -> u16 {
        match self.scale {
            None => self.p2,
            Some(s) => {
                let delta = (a as i32 - b as i32).unsigned_abs();
                let p = (self.p2 as u32 * s / (s + delta)) as u16;
                p.max(self.p1 + 1)
            }
        }
    }
}

/// Left-to-right and right-to-left paths of one row; assigns `S` for the row.
#[inline(always)]
fn horizontal_row_impl(cost: &[u8], img: &[u8], nd: usize, pen: Penalties, sum: &mut [u16]) {
    let w = img.len();
    let stride = nd + 2;
    let mut a = vec![BIG; stride];
    let mut b = vec![BIG; stride];
    let mut m = 0u16;
    for x in 0..w {
        let c = &cost[x * nd..(x + 1) * nd];
        let s = &mut sum[x * nd..(x + 1) * nd];
        m = if x == 0 {
            path_start::<true>(c, &mut b, s)
        } else {
            path_step::<true>(c, &a, m, pen.p1, pen.p2_for(img[x], img[x - 1]), &mut b, s)
        };
        std::mem::swap(&mut a, &mut b);
    }
    for x in (0..w).rev() {
        let c = &cost[x * nd..(x + 1) * nd];
        let s = &mut sum[x * nd..(x + 1) * nd];
        m = if x == w - 1 {
            path_start::<false>(c, &mut b, s)
        } else {
            path_step::<false>(c, &a, m, pen.p1, pen.p2_for(img[x], img[x + 1]), &mut b, s)
        };
        std::mem::swap(&mut a, &mut b);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn horizontal_row_avx2(cost: &[u8], img: &[u8], nd: usize, pen: Penalties, sum: &mut [u16]) {
    horizontal_row_impl(cost, img, nd, pen, sum)
}

fn horizontal_row(cost: &[u8], img: &[u8], nd: usize, pen: Penalties, sum: &mut [u16]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked above).
        unsafe { horizontal_row_avx2(cost, img, nd, pen, sum) };
        return;
    }
    horizontal_row_impl(cost, img, nd, pen, sum)
}

/// Inputs of one row of a vertical/diagonal sweep.
struct SweepRow<'a> {
    /// Costs of the row being computed.
    cost: &'a [u8],
    /// Intensities of this row and of the previous row of the sweep.
    img: &'a [u8],
    img_prev: &'a [u8],
    /// Path buffers of the previous row: `[x][dir][D+2]`, and their minima `[x][dir]`.
    prev: &'a [u16],
    prev_min: &'a [u16],
    /// False on the first row of the sweep (every path starts).
    has_prev: bool,
    /// Column offsets of the predecessor, one per direction (0 vertical, ±1 diagonal).
    dxs: &'a [isize],
    nd: usize,
    pen: Penalties,
}

/// One chunk of columns `[x0, x0 + n)` of a sweep row; adds into `sum`.
#[inline(always)]
fn sweep_chunk_impl(
    row: &SweepRow,
    x0: usize,
    cur: &mut [u16],
    cur_min: &mut [u16],
    sum: &mut [u16],
) {
    let nd = row.nd;
    let stride = nd + 2;
    let nr = row.dxs.len();
    let w = row.img.len();
    let n = sum.len() / nd;
    for i in 0..n {
        let x = x0 + i;
        let c = &row.cost[x * nd..(x + 1) * nd];
        let s = &mut sum[i * nd..(i + 1) * nd];
        for (r, &dx) in row.dxs.iter().enumerate() {
            let out = &mut cur[(i * nr + r) * stride..(i * nr + r + 1) * stride];
            let xp = x as isize + dx;
            cur_min[i * nr + r] = if !row.has_prev || xp < 0 || xp >= w as isize {
                path_start::<false>(c, out, s)
            } else {
                let xp = xp as usize;
                let prev = &row.prev[(xp * nr + r) * stride..(xp * nr + r + 1) * stride];
                let p2 = row.pen.p2_for(row.img[x], row.img_prev[xp]);
                path_step::<false>(c, prev, row.prev_min[xp * nr + r], row.pen.p1, p2, out, s)
            };
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn sweep_chunk_avx2(
    row: &SweepRow,
    x0: usize,
    cur: &mut [u16],
    cur_min: &mut [u16],
    sum: &mut [u16],
) {
    sweep_chunk_impl(row, x0, cur, cur_min, sum)
}

fn sweep_chunk(row: &SweepRow, x0: usize, cur: &mut [u16], cur_min: &mut [u16], sum: &mut [u16]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked above).
        unsafe { sweep_chunk_avx2(row, x0, cur, cur_min, sum) };
        return;
    }
    sweep_chunk_impl(row, x0, cur, cur_min, sum)
}

/// Sums the path costs `S(p, d)` over the configured directions (`u16`, layout as the cost
/// volume). `image` is the left image (for the adaptive P2).
pub fn aggregate_paths(
    volume: &CostVolume,
    image: &GreyImage,
    params: &SgmParams,
) -> Result<Vec<u16>> {
    params.validate()?;
    if image.width != volume.width || image.height != volume.height {
        return Err(Error::InvalidArgument(
            "image and cost volume sizes differ".into(),
        ));
    }
    let w = volume.width as usize;
    let h = volume.height as usize;
    let nd = volume.num_disparities;
    let pen = Penalties {
        p1: params.p1,
        p2: params.p2,
        scale: params.p2_intensity_scale.map(u32::from),
    };
    let mut sum = vec![0u16; w * h * nd];
    if w == 0 || h == 0 {
        return Ok(sum);
    }
    sum.par_chunks_mut(w * nd).enumerate().for_each(|(y, s)| {
        horizontal_row(
            &volume.cost[y * w * nd..(y + 1) * w * nd],
            &image.data[y * w..(y + 1) * w],
            nd,
            pen,
            s,
        );
    });
    let dxs: &[isize] = match params.paths {
        SgmPaths::Four => &[0],
        SgmPaths::Eight => &[0, -1, 1],
    };
    let nr = dxs.len();
    let stride = nd + 2;
    let mut prev = vec![BIG; w * nr * stride];
    let mut cur = vec![BIG; w * nr * stride];
    let mut prev_min = vec![0u16; w * nr];
    let mut cur_min = vec![0u16; w * nr];
    for downwards in [true, false] {
        for step in 0..h {
            let y = if downwards { step } else { h - 1 - step };
            let y_prev = if downwards {
                y.saturating_sub(1)
            } else {
                (y + 1).min(h - 1)
            };
            let row = SweepRow {
                cost: &volume.cost[y * w * nd..(y + 1) * w * nd],
                img: &image.data[y * w..(y + 1) * w],
                img_prev: &image.data[y_prev * w..(y_prev + 1) * w],
                prev: &prev,
                prev_min: &prev_min,
                has_prev: step > 0,
                dxs,
                nd,
                pen,
            };
            sum[y * w * nd..(y + 1) * w * nd]
                .par_chunks_mut(COLUMN_CHUNK * nd)
                .zip(cur.par_chunks_mut(COLUMN_CHUNK * nr * stride))
                .zip(cur_min.par_chunks_mut(COLUMN_CHUNK * nr))
                .enumerate()
                .for_each(|(ci, ((s, c), cm))| sweep_chunk(&row, ci * COLUMN_CHUNK, c, cm, s));
            std::mem::swap(&mut prev, &mut cur);
            std::mem::swap(&mut prev_min, &mut cur_min);
        }
    }
    Ok(sum)
}

/// Result of winner-take-all on one row.
struct WtaRow {
    disparity: Vec<f32>,
    confidence: Vec<f32>,
}

/// Winner-take-all, uniqueness, sub-pixel fit and left–right check for row `y`.
fn select_row(
    sum_row: &[u16],
    y: usize,
    raw: Option<&CostVolume>,
    w: usize,
    nd: usize,
    dmin: i32,
    params: &SgmParams,
) -> WtaRow {
    let h = raw.map_or(0, |v| v.height as usize);
    let radius = (params.subpixel_cost_window / 2) as usize;
    let mut disparity = vec![f32::NAN; w];
    let mut confidence = vec![0.0f32; w];
    let mut best_k = vec![usize::MAX; w];
    // Right-image winners: for right pixel xr, argmin_d S(xr + d, d).
    let mut right_cost = vec![u16::MAX; w];
    let mut right_k = vec![usize::MAX; w];
    let uniq = params.uniqueness_ratio;
    for x in 0..w {
        let s = &sum_row[x * nd..(x + 1) * nd];
        let mut bk = 0;
        let mut bv = u16::MAX;
        for (k, &v) in s.iter().enumerate() {
            if v < bv {
                bv = v;
                bk = k;
            }
            let xr = x as i64 - dmin as i64 - k as i64;
            if xr >= 0 && (xr as usize) < w && v < right_cost[xr as usize] {
                right_cost[xr as usize] = v;
                right_k[xr as usize] = k;
            }
        }
        let second = s
            .iter()
            .enumerate()
            .filter(|&(k, _)| k + 1 < bk || k > bk + 1)
            .map(|(_, &v)| v)
            .min()
            .unwrap_or(u16::MAX);
        let xr = x as i64 - dmin as i64 - bk as i64;
        if xr < 0 || xr >= w as i64 {
            continue;
        }
        if uniq > 0.0 && (second as f32) * (1.0 - uniq) < bv as f32 {
            continue;
        }
        let mut d = (dmin as i64 + bk as i64) as f32;
        if bk > 0 && bk + 1 < nd {
            let (a, b, c) = match raw {
                // Raw costs summed over a window: free of the P1 plateau of S around the winner.
                Some(vol) if radius > 0 => {
                    let mut abc = [0u32; 3];
                    for yy in y.saturating_sub(radius)..(y + radius + 1).min(h) {
                        for xx in x.saturating_sub(radius)..(x + radius + 1).min(w) {
                            let c = &vol.cost[(yy * w + xx) * nd + bk - 1..][..3];
                            abc[0] += c[0] as u32;
                            abc[1] += c[1] as u32;
                            abc[2] += c[2] as u32;
                        }
                    }
                    (abc[0] as f32, abc[1] as f32, abc[2] as f32)
                }
                _ => (s[bk - 1] as f32, bv as f32, s[bk + 1] as f32),
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
        best_k[x] = bk;
        confidence[x] = if second == u16::MAX || second == 0 {
            0.0
        } else {
            (second.saturating_sub(bv)) as f32 / second as f32
        };
    }
    if let Some(max_diff) = params.lr_max_diff_px {
        for x in 0..w {
            if best_k[x] == usize::MAX {
                continue;
            }
            let xr = (x as i64 - dmin as i64 - best_k[x] as i64) as usize;
            let rk = right_k[xr];
            if rk == usize::MAX || rk.abs_diff(best_k[x]) > max_diff as usize {
                disparity[x] = f32::NAN;
            }
        }
    }
    for x in 0..w {
        if disparity[x].is_nan() {
            confidence[x] = 0.0;
        }
    }
    WtaRow {
        disparity,
        confidence,
    }
}

/// Winner-take-all over aggregated costs `sum` (layout of the cost volume) with uniqueness,
/// sub-pixel fit and left–right check; returns disparities (NaN invalid) and confidences in
/// [0, 1] (`(S_second − S_best) / S_second`, 0 where invalid). `raw` (the cost volume `sum` came
/// from) is needed when `params.subpixel_cost_window > 0`; without it the fit uses `sum`.
pub fn select_disparities(
    sum: &[u16],
    raw: Option<&CostVolume>,
    width: u32,
    height: u32,
    params: &SgmParams,
) -> Result<(Image<f32>, Image<f32>)> {
    let w = width as usize;
    let h = height as usize;
    let nd = params.num_disparities;
    if sum.len() != w * h * nd {
        return Err(Error::InvalidArgument(format!(
            "aggregated costs hold {} values, expected {w}×{h}×{nd}",
            sum.len()
        )));
    }
    let mut disp = Image::filled(width, height, f32::NAN);
    let mut conf = Image::filled(width, height, 0.0f32);
    if w == 0 || h == 0 {
        return Ok((disp, conf));
    }
    disp.data
        .par_chunks_mut(w)
        .zip(conf.data.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (drow, crow))| {
            let r = select_row(
                &sum[y * w * nd..(y + 1) * w * nd],
                y,
                raw,
                w,
                nd,
                params.min_disparity_px,
                params,
            );
            drow.copy_from_slice(&r.disparity);
            crow.copy_from_slice(&r.confidence);
        });
    Ok((disp, conf))
}

/// 3×3 median over the valid (finite) neighbours of every valid pixel; invalid pixels stay NaN.
pub fn median_filter_3x3(disparity: &Image<f32>) -> Image<f32> {
    let w = disparity.width as usize;
    let h = disparity.height as usize;
    let mut out = disparity.clone();
    if w == 0 {
        return out;
    }
    out.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let mut window = [0.0f32; 9];
        for (x, o) in row.iter_mut().enumerate() {
            if disparity.data[y * w + x].is_nan() {
                continue;
            }
            let mut n = 0;
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    let v = disparity.data[yy * w + xx];
                    if !v.is_nan() {
                        window[n] = v;
                        n += 1;
                    }
                }
            }
            let vals = &mut window[..n];
            vals.sort_unstable_by(|a, b| a.total_cmp(b));
            *o = if n % 2 == 1 {
                vals[n / 2]
            } else {
                0.5 * (vals[n / 2 - 1] + vals[n / 2])
            };
        }
    });
    out
}

/// Removes speckles: 4-connected regions (neighbours differing by at most `max_diff_px`) of at
/// most `max_size_px` valid pixels become NaN. Returns how many pixels were removed.
pub fn remove_speckles(disparity: &mut Image<f32>, max_size_px: usize, max_diff_px: f32) -> usize {
    let w = disparity.width as usize;
    let h = disparity.height as usize;
    if max_size_px == 0 || w == 0 || h == 0 {
        return 0;
    }
    let mut label = vec![0u32; w * h];
    let mut stack: Vec<usize> = Vec::new();
    let mut region: Vec<usize> = Vec::new();
    let mut next = 1u32;
    let mut removed = 0;
    for start in 0..w * h {
        if label[start] != 0 || disparity.data[start].is_nan() {
            continue;
        }
        label[start] = next;
        stack.push(start);
        region.clear();
        while let Some(i) = stack.pop() {
            region.push(i);
            let d = disparity.data[i];
            let (x, y) = (i % w, i / w);
            let mut visit = |j: usize| {
                let dj = disparity.data[j];
                if label[j] == 0 && !dj.is_nan() && (dj - d).abs() <= max_diff_px {
                    label[j] = next;
                    stack.push(j);
                }
            };
            if x > 0 {
                visit(i - 1);
            }
            if x + 1 < w {
                visit(i + 1);
            }
            if y > 0 {
                visit(i - w);
            }
            if y + 1 < h {
                visit(i + w);
            }
        }
        if region.len() <= max_size_px {
            for &i in &region {
                disparity.data[i] = f32::NAN;
            }
            removed += region.len();
        }
        next += 1;
    }
    removed
}

/// Census + semi-global matching, the baseline disparity estimator (and the initialisation of
/// the variational one).
#[derive(Clone, Debug, Default)]
pub struct SgmMatcher {
    /// Matching parameters.
    pub params: SgmParams,
}

impl SgmMatcher {
    /// A matcher with `params` (validated).
    pub fn new(params: SgmParams) -> Result<Self> {
        params.validate()?;
        Ok(SgmMatcher { params })
    }

    /// Census cost volume of a rectified pair (left image is the reference).
    pub fn cost_volume(&self, left: &GreyImage, right: &GreyImage) -> Result<CostVolume> {
        check_pair(left, right)?;
        let (cl, cr) = rayon::join(
            || census_transform(left, &self.params.census),
            || census_transform(right, &self.params.census),
        );
        CostVolume::from_census(
            &cl?,
            &cr?,
            self.params.min_disparity_px,
            self.params.num_disparities,
        )
    }
}

/// Checks that a stereo pair is non-empty and equally sized, with consistent buffers.
fn check_pair(left: &GreyImage, right: &GreyImage) -> Result<()> {
    if left.width != right.width || left.height != right.height {
        return Err(Error::InvalidArgument(format!(
            "stereo images differ in size: {}×{} vs {}×{}",
            left.width, left.height, right.width, right.height
        )));
    }
    for img in [left, right] {
        if img.data.len() != img.width as usize * img.height as usize {
            return Err(Error::InvalidArgument(
                "image buffer length does not match its size".into(),
            ));
        }
    }
    if left.width == 0 || left.height == 0 {
        return Err(Error::InvalidArgument("stereo images are empty".into()));
    }
    Ok(())
}

impl DisparityEstimator for SgmMatcher {
    fn name(&self) -> &str {
        "sgm"
    }

    fn estimate(&self, left: &GreyImage, right: &GreyImage) -> Result<DisparityMap> {
        self.params.validate()?;
        let volume = self.cost_volume(left, right)?;
        self.estimate_from_volume(left, &volume)
    }
}

impl SgmMatcher {
    /// SGM on a cost volume already computed with [`SgmMatcher::cost_volume`] (`left` is the
    /// reference image, for the adaptive P2): aggregation, selection, filtering.
    pub fn estimate_from_volume(
        &self,
        left: &GreyImage,
        volume: &CostVolume,
    ) -> Result<DisparityMap> {
        let p = &self.params;
        p.validate()?;
        let sum = aggregate_paths(volume, left, p)?;
        let (mut disparity, mut confidence) =
            select_disparities(&sum, Some(volume), left.width, left.height, p)?;
        drop(sum);
        if p.median_filter {
            disparity = median_filter_3x3(&disparity);
        }
        remove_speckles(&mut disparity, p.speckle_max_size_px, p.speckle_max_diff_px);
        for (c, d) in confidence.data.iter_mut().zip(&disparity.data) {
            if d.is_nan() {
                *c = 0.0;
            }
        }
        Ok(DisparityMap {
            disparity_px: disparity,
            confidence: Some(confidence),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speckles_are_removed_and_large_regions_kept() {
        // 6×4 image: a 2-pixel island of 30 inside a region of 10 (20 pixels), and two NaNs.
        let nan = f32::NAN;
        #[rustfmt::skip]
        let data = vec![
            10.0, 10.0, 10.0, 10.0, 10.0, 10.0,
            10.0, 30.0, 30.5, 10.0, 10.0, nan,
            10.0, 10.0, 10.0, 10.5, 10.0, 10.0,
            10.0, 10.0, 10.0, 10.0, 10.0, nan,
        ];
        let mut img = Image {
            width: 6,
            height: 4,
            data,
        };
        assert_eq!(remove_speckles(&mut img, 2, 1.0), 2);
        assert!(img.at(1, 1).is_nan() && img.at(2, 1).is_nan());
        assert_eq!(img.at(3, 2), 10.5);
        assert_eq!(img.data.iter().filter(|v| v.is_nan()).count(), 4);
        // With a limit below the region size nothing more goes.
        assert_eq!(remove_speckles(&mut img, 19, 1.0), 0);
        assert_eq!(remove_speckles(&mut img, 20, 1.0), 20);
    }

    #[test]
    fn median_ignores_invalid_neighbours_and_keeps_invalid_pixels() {
        let nan = f32::NAN;
        let img = Image {
            width: 3,
            height: 3,
            data: vec![1.0, 2.0, nan, 4.0, 100.0, 6.0, nan, 8.0, nan],
        };
        let m = median_filter_3x3(&img);
        // Centre: valid values {1, 2, 4, 100, 6, 8} → median of six = (4 + 6) / 2.
        assert_eq!(m.at(1, 1), 5.0);
        assert!(m.at(2, 0).is_nan() && m.at(0, 2).is_nan() && m.at(2, 2).is_nan());
        // Corner (0, 0): {1, 2, 4, 100} → (2 + 4) / 2.
        assert_eq!(m.at(0, 0), 3.0);
    }

    #[test]
    fn path_step_matches_the_recurrence() {
        // D = 4, prev L = [5, 1, 9, 20] (padded), C = [3, 0, 7, 2], P1 = 2, P2 = 6.
        let prev = [BIG, 5, 1, 9, 20, BIG];
        let cost = [3u8, 0, 7, 2];
        let mut out = [BIG; 6];
        let mut acc = [100u16; 4];
        let m = path_step::<false>(&cost, &prev, 1, 2, 6, &mut out, &mut acc);
        // d0: 3 + min(5, 1+2, 1+6) − 1 = 5; d1: 0 + min(1, ..) − 1 = 0;
        // d2: 7 + min(9, 1+2, 20+2, 7) − 1 = 9; d3: 2 + min(20, 9+2, 7) − 1 = 8.
        assert_eq!(&out[1..5], &[5, 0, 9, 8]);
        assert_eq!(acc, [105, 100, 109, 108]);
        assert_eq!(m, 0);
        assert_eq!((out[0], out[5]), (BIG, BIG));
    }
}
