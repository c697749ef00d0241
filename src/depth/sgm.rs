//! Semi-global matching (Hirschmüller, "Stereo Processing by Semiglobal Matching and Mutual
//! Information", TPAMI 2008) on a census/Hamming cost volume.
//!
//! Stages, each a function of its own so that other estimators (the variational TGV matcher) can
//! reuse them:
//! 1. [`CostVolume::from_census`]: matching cost `C(p, d)` = Hamming distance between the census
//!    signatures of left pixel `(x, y)` and right pixel `(x − d, y)`, for
//!    `d ∈ [min_disparity_px, min_disparity_px + num_disparities)`, stored as `u8` with the
//!    disparities of one pixel contiguous. Right pixels outside the image cost the maximum.
//! 2. Path aggregation (eq. 13 of the paper): along each of 4, 5 or 8 directions `r`,
//!    `L_r(p, d) = C(p, d) + min(L_r(p−r, d), L_r(p−r, d±1) + P1, min_k L_r(p−r, k) + P2)
//!    − min_k L_r(p−r, k)`, summed into `S(p, d)` (`u16`). P2 may adapt to the intensity step
//!    along the path, `P2' = max(P1 + 1, P2·s / (s + |I(p) − I(p−r)|))` (after the paper's
//!    `P2/|ΔI|`). The directions run as two passes on two threads, forward (top to bottom) and
//!    backward, which meet row by row; `S` is never stored whole (`src/depth/aggregate.rs`).
//! 3. Winner-take-all with a uniqueness ratio, sub-pixel refinement (parabola, eq. 12 area, or
//!    equiangular fit), left–right consistency with a right disparity map taken from the same
//!    `S` (`D_r(x_r) = argmin_d S(x_r + d, d)`), streamed with the aggregation; then an optional
//!    3×3 median and speckle removal.
//!
//! Invalid pixels (occluded, ambiguous, inconsistent, speckles, matched outside the right
//! image) are NaN and stay NaN: nothing is interpolated or filled.
//!
//! Hot loops are compiled three times on x86-64 (baseline, AVX2, AVX-512 with vector popcount)
//! and picked at run time. A matcher keeps its large buffers (cost volume, aggregation rows)
//! between pairs.

use super::aggregate;
use super::census::{census_transform, CensusImage, CensusParams};
use super::{DisparityEstimator, DisparityMap, ScratchPool};
use crate::error::{Error, Result};
use crate::frame::{GreyImage, Image};
use rayon::prelude::*;

mod filters;

#[allow(unused_imports)]
use filters::*;
pub use filters::{median_filter_3x3, remove_speckles, remove_speckles_in_bands};

/// Largest P2 accepted, so that 8 summed paths fit `u16`: 8·(128 + 2000) < 65 535.
const MAX_P2: u16 = 2000;

/// Which aggregation directions to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SgmPaths {
    /// Left, right, up, down.
    Four,
    /// Left, right, down and the two downward diagonals (OpenCV StereoSGBM's 3-way mode): one
    /// sweep down the image carries four of them, the right→left path runs on its own.
    Five,
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
    /// Strict validity on purpose: fusion wants fewer, surer pixels. With 5 paths, the LR check
    /// at 2 px and no uniqueness test, disparity benchmarks that count missing pixels score
    /// better (KITTI 00/0 bad-2.0 32.2 → 26.9 %), but the 200 m synthetic drive's regularized
    /// map is less accurate (median 3.7 → 6.3 cm; `docs/bench/stereo.md`, run of 2026-11-26).
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
        if self.subpixel_cost_window.is_multiple_of(2) && self.subpixel_cost_window != 0 {
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

/// The size and disparity range of a [`CostVolume`] without its costs (the GPU matchers keep
/// the costs on the device).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VolumeShape {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Disparity of slice 0, pixels.
    pub min_disparity_px: i32,
    /// Number of disparity slices.
    pub num_disparities: usize,
    /// Largest possible cost.
    pub max_cost: u8,
}

impl CostVolume {
    /// Its size and disparity range.
    pub fn shape(&self) -> VolumeShape {
        VolumeShape {
            width: self.width,
            height: self.height,
            min_disparity_px: self.min_disparity_px,
            num_disparities: self.num_disparities,
            max_cost: self.max_cost,
        }
    }

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
        Self::from_census_in(left, right, min_disparity_px, num_disparities, Vec::new())
    }

    /// [`CostVolume::from_census`] into `buffer` (resized; its old contents are overwritten),
    /// so that a matcher can reuse the allocation from frame to frame.
    pub(crate) fn from_census_in(
        left: &CensusImage,
        right: &CensusImage,
        min_disparity_px: i32,
        num_disparities: usize,
        buffer: Vec<u8>,
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
        let mut cost = buffer;
        let n = w * h * num_disparities;
        if cost.len() != n {
            cost = vec![0u8; n];
        }
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

/// Hamming costs of one row: `out[x·nd + k]` for left signature `l[x]` and right signature
/// `r[x − dmin − k]`, `max_cost` where that pixel is outside the image.
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
    // The right row reversed, so that the slices of a pixel read it forwards:
    // r[xr0 − k] = rev[w − 1 − xr0 + k] (one word per pixel; two-word signatures interleave).
    // (Collected, not zeroed and copied pixel by pixel: a `memset` and a `memmove` call per
    // pixel showed up as 4 % of the matcher's samples.)
    let rev: Vec<u64> = r.chunks_exact(words).rev().flatten().copied().collect();
    // Slices whose right pixel is outside the image cost the most. Those pixels are a prefix
    // (k1 < nd: x < nd + dmin − 1) and a suffix (k0 > 0: x > w − 1 + dmin) of the row, each
    // filled whole here (where they overlap, twice); the loop then writes the inside slices
    // only. (One fill per pixel was a `memset` call for a few bytes, 2 % of the matcher's
    // samples.)
    let clamp = |v: i64| v.clamp(0, w as i64) as usize;
    let (prefix, suffix) = (
        clamp(nd as i64 + dmin as i64 - 1),
        clamp(w as i64 + dmin as i64),
    );
    out[..prefix * nd].fill(max_cost);
    out[suffix * nd..].fill(max_cost);
    for x in 0..w {
        let o = &mut out[x * nd..(x + 1) * nd];
        // Slices k ∈ [k0, k1) have their right pixel x − dmin − k inside [0, w).
        let k0 = (x as i64 - dmin as i64 - (w as i64 - 1)).max(0) as usize;
        let k1 = ((x as i64 - dmin as i64 + 1).max(0) as usize).min(nd);
        let k0 = k0.min(k1);
        if k0 == k1 {
            continue;
        }
        // Right pixel of slice k is xr0 − k, at rev index (w − 1 − xr0) + k, which is ≥ 0 for
        // k ≥ k0 (w − 1 − xr0 itself is negative when dmin < 0 puts xr0 past the right edge).
        let start = (w as i64 - 1 - (x as i64 - dmin as i64) + k0 as i64) as usize;
        let rs = &rev[start * words..(start + k1 - k0) * words];
        if words == 1 {
            let a = l[x];
            for (c, &b) in o[k0..k1].iter_mut().zip(rs) {
                *c = (a ^ b).count_ones() as u8;
            }
        } else {
            let (a0, a1) = (l[2 * x], l[2 * x + 1]);
            for (c, b) in o[k0..k1].iter_mut().zip(rs.chunks_exact(2)) {
                *c = ((a0 ^ b[0]).count_ones() + (a1 ^ b[1]).count_ones()) as u8;
            }
        }
    }
}

/// [`cost_row_impl`], dispatched at run time to a copy compiled for AVX-512 (vector popcount),
/// AVX2 or the baseline.
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
    {
        #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512vpopcntdq,avx2,popcnt")]
        fn avx512(
            l: &[u64],
            r: &[u64],
            words: usize,
            dmin: i32,
            nd: usize,
            mc: u8,
            out: &mut [u8],
        ) {
            cost_row_impl(l, r, words, dmin, nd, mc, out)
        }
        #[target_feature(enable = "avx2,popcnt")]
        fn avx2(l: &[u64], r: &[u64], words: usize, dmin: i32, nd: usize, mc: u8, out: &mut [u8]) {
            cost_row_impl(l, r, words, dmin, nd, mc, out)
        }
        if std::is_x86_feature_detected!("avx512vpopcntdq")
            && std::is_x86_feature_detected!("avx512bw")
            && std::is_x86_feature_detected!("avx512vl")
        {
            // SAFETY: the CPU supports the features the copy was compiled for (checked above).
            unsafe { avx512(l, r, words, dmin, nd, max_cost, out) };
            return;
        }
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("popcnt") {
            // SAFETY: as above.
            unsafe { avx2(l, r, words, dmin, nd, max_cost, out) };
            return;
        }
    }
    cost_row_impl(l, r, words, dmin, nd, max_cost, out)
}

/// Sums the path costs `S(p, d)` over the configured directions (`u16`, layout as the cost
/// volume). `image` is the left image (for the adaptive P2). The matcher never stores `S`
/// whole (`src/depth/aggregate.rs` streams it into the selection); this keeps it, for
/// inspection and benchmarks.
pub fn aggregate_paths(
    volume: &CostVolume,
    image: &GreyImage,
    params: &SgmParams,
) -> Result<Vec<u16>> {
    params.validate()?;
    check_volume(volume, image, params)?;
    if volume.width == 0 || volume.height == 0 {
        return Ok(Vec::new());
    }
    Ok(aggregate::aggregate_all(
        volume,
        &image.data,
        params,
        &mut aggregate::AggregateScratch::default(),
    ))
}

/// Checks that `image` and `volume` agree in size and `params` in disparity range.
pub(crate) fn check_volume(
    volume: &CostVolume,
    image: &GreyImage,
    params: &SgmParams,
) -> Result<()> {
    if image.width != volume.width || image.height != volume.height {
        return Err(Error::InvalidArgument(format!(
            "image ({}×{}) and cost volume ({}×{}) sizes differ",
            image.width, image.height, volume.width, volume.height
        )));
    }
    if image.data.len() != image.width as usize * image.height as usize {
        return Err(Error::InvalidArgument(
            "image buffer length does not match its size".into(),
        ));
    }
    let n = volume.width as usize * volume.height as usize * volume.num_disparities;
    if volume.num_disparities != params.num_disparities
        || volume.min_disparity_px != params.min_disparity_px
        || volume.cost.len() != n
    {
        return Err(Error::InvalidArgument(format!(
            "cost volume of {} slices from {} px ({} costs) does not match the parameters' {} \
             slices from {} px",
            volume.num_disparities,
            volume.min_disparity_px,
            volume.cost.len(),
            params.num_disparities,
            params.min_disparity_px
        )));
    }
    Ok(())
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
    if let Some(v) = raw {
        if (v.width, v.height, v.num_disparities) != (width, height, nd) {
            return Err(Error::InvalidArgument(format!(
                "raw cost volume {}×{}×{} differs from the aggregated costs {w}×{h}×{nd}",
                v.width, v.height, v.num_disparities
            )));
        }
    }
    Ok(aggregate::select_all(sum, raw, width, height, params))
}

/// Census + semi-global matching, the baseline disparity estimator (and the initialisation of
/// the variational one).
#[derive(Clone, Debug, Default)]
pub struct SgmMatcher {
    /// Matching parameters.
    pub params: SgmParams,
    /// Buffers kept between pairs (cost volume, aggregation rows).
    scratch: ScratchPool<SgmScratch>,
}

/// What an [`SgmMatcher`] keeps between pairs.
#[derive(Default, Debug)]
pub(crate) struct SgmScratch {
    /// The cost volume's allocation.
    pub(crate) cost: Vec<u8>,
    pub(crate) aggregate: aggregate::AggregateScratch,
}

impl SgmMatcher {
    /// A matcher with `params` (validated).
    pub fn new(params: SgmParams) -> Result<Self> {
        params.validate()?;
        Ok(SgmMatcher {
            params,
            scratch: ScratchPool::default(),
        })
    }

    /// Census cost volume of a rectified pair (left image is the reference).
    pub fn cost_volume(&self, left: &GreyImage, right: &GreyImage) -> Result<CostVolume> {
        self.cost_volume_in(left, right, Vec::new())
    }

    /// [`SgmMatcher::cost_volume`] into a reused allocation.
    pub(crate) fn cost_volume_in(
        &self,
        left: &GreyImage,
        right: &GreyImage,
        buffer: Vec<u8>,
    ) -> Result<CostVolume> {
        check_pair(left, right)?;
        let (cl, cr) = rayon::join(
            || census_transform(left, &self.params.census),
            || census_transform(right, &self.params.census),
        );
        CostVolume::from_census_in(
            &cl?,
            &cr?,
            self.params.min_disparity_px,
            self.params.num_disparities,
            buffer,
        )
    }

    /// The buffers of one estimate (taken from the pool, or new).
    pub(crate) fn take_scratch(&self) -> SgmScratch {
        self.scratch.take()
    }

    /// Returns buffers taken with [`SgmMatcher::take_scratch`].
    pub(crate) fn put_scratch(&self, scratch: SgmScratch) {
        self.scratch.put(scratch)
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
        let mut scratch = self.take_scratch();
        let volume = self.cost_volume_in(left, right, std::mem::take(&mut scratch.cost))?;
        let map = self.estimate_with(left, &volume, &mut scratch.aggregate);
        scratch.cost = volume.cost;
        self.put_scratch(scratch);
        map
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
        let mut scratch = self.take_scratch();
        let map = self.estimate_with(left, volume, &mut scratch.aggregate);
        self.put_scratch(scratch);
        map
    }

    /// [`SgmMatcher::estimate_from_volume`] with the aggregation's buffers given.
    pub(crate) fn estimate_with(
        &self,
        left: &GreyImage,
        volume: &CostVolume,
        scratch: &mut aggregate::AggregateScratch,
    ) -> Result<DisparityMap> {
        let p = &self.params;
        p.validate()?;
        check_volume(volume, left, p)?;
        let (disparity, confidence) =
            aggregate::aggregate_and_select(volume, &left.data, p, scratch);
        Ok(self.filtered(disparity, confidence))
    }

    /// The selection and the filters of [`SgmMatcher::estimate_from_volume`] over the summed path
    /// costs `sums` of `volume` ([`aggregate_paths`]'s, or the GPU's): the same disparities as
    /// the streamed matcher's, bit for bit.
    pub fn estimate_from_sums(&self, volume: &CostVolume, sums: &[u16]) -> Result<DisparityMap> {
        let p = &self.params;
        p.validate()?;
        let (disparity, confidence) =
            select_disparities(sums, Some(volume), volume.width, volume.height, p)?;
        Ok(self.filtered(disparity, confidence))
    }

    /// The median and speckle filters, and confidence 0 where the disparity is invalid (after
    /// the selection, on either device).
    pub(crate) fn filtered(
        &self,
        mut disparity: Image<f32>,
        mut confidence: Image<f32>,
    ) -> DisparityMap {
        let p = &self.params;
        if p.median_filter {
            disparity = median_filter_3x3(&disparity);
        }
        remove_speckles(&mut disparity, p.speckle_max_size_px, p.speckle_max_diff_px);
        for (c, d) in confidence.data.iter_mut().zip(&disparity.data) {
            if d.is_nan() {
                *c = 0.0;
            }
        }
        DisparityMap {
            disparity_px: disparity,
            confidence: Some(confidence),
        }
    }
}

#[cfg(test)]
mod tests;
