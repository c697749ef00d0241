//! Depth maps from rectified stereo pairs.
//!
//! - [`DisparityEstimator`]: the interface every stereo matcher implements (left image is the
//!   reference; disparity `d = x_left − x_right` in pixels; NaN = invalid). [`StereoMethod`]
//!   names the available matchers and builds them; the baseline is [`sgm::SgmMatcher`] (census +
//!   semi-global matching), which initialises the variational estimator [`tgv::TgvMatcher`]
//!   (census + TV / TGV / TGV with the anisotropic tensor, the paper's Sec. V).
//! - [`census`]: census and ternary census signatures, Hamming cost.
//! - [`metrics`]: Middlebury/KITTI disparity scores (bad-k, D1, EPE, density).
//! - [`disparity_io`]: KITTI 16-bit disparity PNG, and a reader that picks PFM or PNG.
//! - [`ground_truth`]: sparse disparity ground truth from LiDAR points.
//! - [`disparity_to_depth`]: `z = f·B / d`.
//!
//! Does not rectify images, estimate calibration, or fill invalid pixels.

mod aggregate;
pub mod census;
pub mod disparity_io;
mod gpu;
pub mod ground_truth;
pub mod metrics;
pub mod sgm;
pub mod tgv;

pub(crate) use gpu::record_disparity_depth;
pub use gpu::{
    aggregate_paths_gpu, census_transform_gpu, cost_volume_gpu, costs_at_disparities_gpu,
    diffusion_tensors_gpu, disparity_depth_uniforms, disparity_to_depth_gpu, estimate_tgv_gpu,
    fill_from_background_gpu, filter_disparities_gpu, pointwise_search_gpu, refine_gpu,
    select_disparities_gpu, window_costs_gpu, SgmMatcherGpu, TgvMatcherGpu, TgvProblemGpu,
    GPU_SGM_MAX_DISPARITIES,
};
pub use ground_truth::disparity_from_points;
pub use metrics::{evaluate_disparity, StereoMetrics};
pub use sgm::{SgmMatcher, SgmParams};
pub use tgv::{Regularizer, TgvMatcher, TgvParams};

use crate::error::{Error, Result};
use crate::frame::{DepthImage, GreyImage, Image};
use std::fmt;
use std::str::FromStr;

/// Buffers a matcher keeps between pairs (cost volumes, aggregation rows, TGV state), so that a
/// sequence of frames does not map hundreds of megabytes in and out again for every pair. Clones
/// start empty; concurrent estimates each take their own set.
pub(crate) struct ScratchPool<T>(std::sync::Mutex<Vec<T>>);

impl<T: Default> ScratchPool<T> {
    /// A set of buffers: a kept one, or a new (empty) one.
    pub(crate) fn take(&self) -> T {
        let mut kept = self.0.lock().unwrap_or_else(|e| e.into_inner());
        kept.pop().unwrap_or_default()
    }

    /// Keeps `scratch` for the next estimate.
    pub(crate) fn put(&self, scratch: T) {
        let mut kept = self.0.lock().unwrap_or_else(|e| e.into_inner());
        kept.push(scratch);
    }
}

impl<T> Default for ScratchPool<T> {
    fn default() -> Self {
        ScratchPool(std::sync::Mutex::new(Vec::new()))
    }
}

impl<T> Clone for ScratchPool<T> {
    fn clone(&self) -> Self {
        ScratchPool::default()
    }
}

impl<T> fmt::Debug for ScratchPool<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("ScratchPool")
    }
}

/// A disparity map for the left image of a rectified pair.
#[derive(Clone, Debug, PartialEq)]
pub struct DisparityMap {
    /// Disparity `x_left − x_right`, pixels; NaN where invalid (occluded, ambiguous,
    /// inconsistent). Same size as the left image.
    pub disparity_px: Image<f32>,
    /// Optional per-pixel confidence in [0, 1] (1 = certain), 0 where invalid; same size.
    pub confidence: Option<Image<f32>>,
}

impl DisparityMap {
    /// Number of valid (finite) disparities.
    pub fn valid_count(&self) -> usize {
        self.disparity_px
            .data
            .iter()
            .filter(|d| d.is_finite())
            .count()
    }
}

/// A pair's disparities left on the GPU by [`DisparityEstimator::estimate_on_device`]: the
/// encoder that computes them, not yet submitted, and the buffer they will be in.
pub struct OnDeviceDisparity<'a> {
    /// The device's context.
    pub ctx: &'a std::sync::Arc<crate::gpu::GpuContext>,
    /// The matcher's work, to be continued and submitted.
    pub encoder: wgpu::CommandEncoder,
    /// Disparities (f32 pixels, NaN where invalid), row-major, `width` × `height`.
    pub disparity: &'a wgpu::Buffer,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

/// A stereo matcher: rectified grey left/right images of equal size in, disparity map of the left
/// image out. Implementations are deterministic and `Send + Sync` so a pipeline can share them.
pub trait DisparityEstimator: Send + Sync {
    /// Short name, as accepted by [`StereoMethod::from_str`] (e.g. `"sgm"`).
    fn name(&self) -> &str;
    /// Estimates the disparity of every pixel of `left`; invalid pixels are NaN.
    fn estimate(&self, left: &GreyImage, right: &GreyImage) -> Result<DisparityMap>;
    /// Estimates the same disparities as [`DisparityEstimator::estimate`] on a GPU and hands
    /// them to `finish` where they are, nothing read back: `finish` records its own work after
    /// the matcher's and submits the encoder. `None` where the matcher keeps no map on a
    /// device (the CPU matchers; a GPU matcher with more disparities than its aggregation
    /// holds).
    fn estimate_on_device(
        &self,
        _left: &GreyImage,
        _right: &GreyImage,
        _finish: &mut dyn FnMut(OnDeviceDisparity) -> Result<()>,
    ) -> Option<Result<()>> {
        None
    }
}

/// The stereo matchers `denser` offers (the CLI's `--method`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StereoMethod {
    /// Census + semi-global matching ([`sgm::SgmMatcher`]).
    Sgm,
    /// Census + first-order TV, variational ([`tgv::TgvMatcher`] with [`Regularizer::Tv`]).
    Tv,
    /// Census + isotropic second-order TGV ([`Regularizer::Tgv`]).
    Tgv,
    /// Census + TGV with the anisotropic diffusion tensor, the paper's estimator
    /// ([`Regularizer::TgvTensor`]).
    TgvTensor,
}

impl StereoMethod {
    /// Every method, in the order shown to users.
    pub const ALL: &'static [StereoMethod] = &[
        StereoMethod::Sgm,
        StereoMethod::Tv,
        StereoMethod::Tgv,
        StereoMethod::TgvTensor,
    ];

    /// The CLI name.
    pub fn as_str(&self) -> &'static str {
        match self {
            StereoMethod::Sgm => "sgm",
            StereoMethod::Tv => "tv",
            StereoMethod::Tgv => "tgv",
            StereoMethod::TgvTensor => "tgv-tensor",
        }
    }

    /// A matcher of this kind searching `num_disparities` disparities from 0, other parameters at
    /// their defaults (variational methods fill [`tgv::HoleFill::Visible`] holes).
    pub fn estimator(&self, num_disparities: usize) -> Result<Box<dyn DisparityEstimator>> {
        let sgm = SgmParams {
            num_disparities,
            ..SgmParams::default()
        };
        self.estimator_with_fill(sgm, tgv::HoleFill::Visible)
    }

    /// As [`StereoMethod::estimator`], with the variational methods' hole filling (ignored by
    /// SGM) and the SGM parameters (of SGM, and of the variational methods' SGM initialisation:
    /// disparity range, aggregation paths, validity tests) chosen.
    pub fn estimator_with_fill(
        &self,
        sgm: SgmParams,
        hole_fill: tgv::HoleFill,
    ) -> Result<Box<dyn DisparityEstimator>> {
        match self.tgv_matcher(sgm, hole_fill)? {
            Some(m) => Ok(Box::new(m)),
            None => Ok(Box::new(SgmMatcher::new(sgm)?)),
        }
    }

    /// The variational matcher of this method (as [`StereoMethod::estimator_with_fill`] builds
    /// it), or `None` for SGM.
    pub fn tgv_matcher(
        &self,
        sgm: SgmParams,
        hole_fill: tgv::HoleFill,
    ) -> Result<Option<TgvMatcher>> {
        let regularizer = match self {
            StereoMethod::Sgm => return Ok(None),
            StereoMethod::Tv => Regularizer::Tv,
            StereoMethod::Tgv => Regularizer::Tgv,
            StereoMethod::TgvTensor => Regularizer::TgvTensor,
        };
        Ok(Some(TgvMatcher::new(TgvParams {
            regularizer,
            hole_fill,
            sgm,
            ..TgvParams::default()
        })?))
    }

    /// Whether this is one of the variational methods (tv, tgv, tgv-tensor).
    pub fn is_variational(&self) -> bool {
        !matches!(self, StereoMethod::Sgm)
    }
}

impl fmt::Display for StereoMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for StereoMethod {
    type Err = Error;

    /// Parses a CLI name, case-insensitively (`sgm`, `tv`, `tgv`, `tgv-tensor`).
    fn from_str(s: &str) -> Result<Self> {
        let lower = s.trim().to_ascii_lowercase();
        StereoMethod::ALL
            .iter()
            .copied()
            .find(|m| m.as_str() == lower)
            .ok_or_else(|| {
                let names: Vec<&str> = StereoMethod::ALL.iter().map(|m| m.as_str()).collect();
                Error::InvalidArgument(format!(
                    "unknown stereo method `{s}`; expected one of: {}",
                    names.join(", ")
                ))
            })
    }
}

/// A disparity map in false colour, for looking at: blue (0 px) → yellow → red (`scale_px`, by
/// default the 99th percentile of the valid disparities, so one outlier does not wash the image
/// out), black where there is no disparity. Returns the image and the scale used.
pub fn disparity_false_colour(
    disparity_px: &Image<f32>,
    scale_px: Option<f32>,
) -> (crate::frame::RgbImage, f32) {
    let scale = scale_px.unwrap_or_else(|| {
        let mut valid: Vec<f32> = disparity_px
            .data
            .iter()
            .copied()
            .filter(|d| d.is_finite() && *d >= 0.0)
            .collect();
        if valid.is_empty() {
            return 1.0;
        }
        let k = ((valid.len() - 1) as f64 * 0.99).round() as usize;
        *valid.select_nth_unstable_by(k, f32::total_cmp).1
    });
    let scale = if scale > 0.0 { scale } else { 1.0 };
    let data = disparity_px
        .data
        .iter()
        .map(|&d| {
            if d.is_finite() && d >= 0.0 {
                crate::eval::error_colour(d / scale)
            } else {
                [0, 0, 0]
            }
        })
        .collect();
    (
        Image {
            width: disparity_px.width,
            height: disparity_px.height,
            data,
        },
        scale,
    )
}

/// Converts disparities (pixels) to depth (metres) with `z = fx_px · baseline_m / d`.
///
/// Pixels with NaN, non-finite or non-positive disparity are invalid (NaN) in the result. For
/// Middlebury-style calibrations with a principal-point offset `doffs`, pass `d + doffs`.
pub fn disparity_to_depth(disparity: &DisparityMap, fx_px: f64, baseline_m: f64) -> DepthImage {
    let fb = fx_px * baseline_m;
    let img = &disparity.disparity_px;
    Image {
        width: img.width,
        height: img.height,
        data: img
            .data
            .iter()
            .map(|&d| {
                if d.is_finite() && d > 0.0 {
                    let z = fb / d as f64;
                    if z.is_finite() && z > 0.0 {
                        z as f32
                    } else {
                        f32::NAN
                    }
                } else {
                    f32::NAN
                }
            })
            .collect(),
    }
}

/// Converts an RGB image to grey with the Rec. 601 luma weights (0.299, 0.587, 0.114), rounded.
pub fn grey_from_rgb(rgb: &crate::frame::RgbImage) -> GreyImage {
    Image {
        width: rgb.width,
        height: rgb.height,
        data: rgb
            .data
            .iter()
            .map(|&[r, g, b]| {
                ((299 * r as u32 + 587 * g as u32 + 114 * b as u32 + 500) / 1000) as u8
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn method_names_round_trip() {
        for m in StereoMethod::ALL {
            assert_eq!(m.as_str().parse::<StereoMethod>().unwrap(), *m);
        }
        assert_eq!(" SGM ".parse::<StereoMethod>().unwrap(), StereoMethod::Sgm);
        let err = "elas".parse::<StereoMethod>().unwrap_err().to_string();
        assert!(err.contains("elas") && err.contains("sgm"), "{err}");
    }

    #[test]
    fn grey_weights() {
        let rgb = Image {
            width: 3,
            height: 1,
            data: vec![[255, 0, 0], [0, 255, 0], [10, 10, 10]],
        };
        assert_eq!(grey_from_rgb(&rgb).data, vec![76, 150, 10]);
    }
}
