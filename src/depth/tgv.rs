//! Variational disparity estimation: census data term + (anisotropic) TGV regularizer, after the
//! DENSER paper (Sec. V), Ranftl et al. 2012 ("Pushing the limits of stereo using variational
//! stereo estimation") and Kuschk & Cremers 2013 ("Fast and accurate large-scale stereo
//! reconstruction using variational methods").
//!
//! Energy over the disparity `u` (pixels), an auxiliary vector field `v` and a decoupling
//! variable `a`:
//!
//! ```text
//! E(u, v, a) = Σ λ·C(x, a(x)) + 1/(2θ)·(u − a)² + α₁·|T(∇u − v)| + α₂·|ε(v)|
//! ```
//!
//! - `C(x, d)`: census Hamming cost of left pixel `x` against right pixel `x − d`, **in bits**,
//!   optionally averaged over a square window ([`TgvParams::cost_window`]). λ multiplies these
//!   bit counts directly, so λ = 0.5 means half a unit of regularizer per differing census bit
//!   (a 9×7 binary census has 62 bits).
//! - `T = exp(−γ|∇I|^β)·n nᵀ + n⊥ n⊥ᵀ`, `n = ∇I/|∇I|`, with `I` the left image scaled to [0, 1]
//!   and `∇I` central differences; `T = 1` where `|∇I| < 1e-6`. [`Regularizer::Tv`] and
//!   [`Regularizer::Tgv`] use `T = 1` (the ablation of the paper's Fig. 3); TV also fixes `v = 0`.
//! - `∇`: forward differences with Neumann boundary (0 on the last column/row); `ε(v)`: the
//!   symmetrised gradient with backward differences (0 on the first column/row), a symmetric
//!   2×2 matrix whose Frobenius norm counts the off-diagonal twice (Bredies et al. 2010).
//!   `div = −∇ᵀ` and `div_sym = −εᵀ` exactly (tested on random data).
//!
//! The non-convex census term is handled by quadratic decoupling (Kuschk & Cremers 2013): for
//! fixed `a` the problem in `(u, v)` is convex and solved by a few Chambolle–Pock primal–dual
//! iterations ([`TgvProblem::iterate`]); for fixed `u` each `a(x)` is found by a point-wise
//! search over the discrete disparities of the cost volume (only where `(u − d)²/(2θ)` can still
//! beat the cost range), refined by a parabola through its two neighbours; θ is annealed
//! geometrically. Initialisation: the SGM disparity ([`crate::depth::sgm`]) with holes filled
//! from the background side.
//!
//! Invalid pixels are NaN in the result. Pixels whose match falls outside the right image are
//! invalid, and so are pixels SGM left invalid unless [`TgvParams::hole_fill`] fills them:
//! [`HoleFill::None`] keeps SGM's validity (the pipeline's choice for fusion);
//! [`HoleFill::Visible`] (default) fills those visible under the final disparity (no other pixel
//! to the right maps to the same or a further-left right pixel with a larger disparity) whose
//! census cost there is at most [`TgvParams::max_cost_fraction`] of the bits ("texture-poor but
//! consistent" pixels); [`HoleFill::All`] fills everything. Confidence: SGM's where TGV agrees
//! with it within 1 px, else half the census match quality `1 − C/C_max`; 0 where invalid.
//! Does not do coarse-to-fine, colour, or the right view. The GPU twin of the cost volume, the
//! point-wise search and the primal–dual iterations is `crate::gpu::refine_gpu` /
//! `crate::gpu::estimate_tgv_gpu` (`src/gpu/stereo.rs`).

use super::sgm::{CostVolume, SgmMatcher, SgmParams, SgmScratch, VolumeShape};
use super::{DisparityEstimator, DisparityMap, ScratchPool};
use crate::error::{Error, Result};
use crate::frame::{GreyImage, Image};
use rayon::prelude::*;

mod operators;
mod problem;
mod search;
mod steps;

pub use operators::*;
pub use problem::*;
pub use search::*;
#[allow(unused_imports)]
use steps::*;

/// Largest cost window: `21² · 128` bits (the largest census) still fits the `u16` sums.
pub const MAX_COST_WINDOW: u32 = 21;

/// Which of the pixels SGM left invalid the variational matcher fills with its regularized
/// disparity.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HoleFill {
    /// None: the result has SGM's validity, with TGV-refined values (for fusion).
    None,
    /// Those visible under the final disparity whose census cost there is at most
    /// [`TgvParams::max_cost_fraction`] of the bits (the default for `denser stereo`).
    Visible,
    /// All, including pixels whose match falls outside the right image (their disparity is
    /// the regularizer's extrapolation): a dense map, for benchmarks that count missing pixels
    /// as errors.
    All,
}

/// Which regularizer the variational matcher uses (the ablation of the paper's Fig. 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Regularizer {
    /// First-order total variation `α₁|∇u|` (piecewise constant).
    Tv,
    /// Second-order TGV, isotropic (`T = 1`; piecewise planar).
    Tgv,
    /// Second-order TGV with the anisotropic image-driven tensor `T` (the paper's choice).
    TgvTensor,
}

/// Parameters of [`TgvMatcher`]. Disparities in pixels, costs in census bits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TgvParams {
    /// Regularizer (TV, TGV, TGV with tensor).
    pub regularizer: Regularizer,
    /// Data weight λ per census bit (paper: 0.5).
    pub lambda: f32,
    /// Weight of the first-order term α₁ (paper: 1.0).
    pub alpha1: f32,
    /// Weight of the second-order term α₂ (paper: 5.0).
    pub alpha2: f32,
    /// Tensor exponent β (paper: 1.0).
    pub beta: f32,
    /// Tensor edge strength γ (paper: 4.0), with grey levels scaled to [0, 1].
    pub gamma: f32,
    /// Side of the square window (pixels, odd) over which census costs are averaged for the data
    /// term; 1 uses the raw costs.
    pub cost_window: u32,
    /// Number of decoupling rounds (point-wise search + primal–dual iterations).
    pub outer_iterations: u32,
    /// Primal–dual iterations per round.
    pub inner_iterations: u32,
    /// Coupling θ of the first round, pixels² per bit-weighted cost unit.
    pub theta_start: f32,
    /// θ of the last round (θ decays geometrically from start to end).
    pub theta_end: f32,
    /// A pixel that SGM left invalid stays invalid when its census cost at the final disparity
    /// exceeds this fraction of the signature bits.
    pub max_cost_fraction: f32,
    /// Occlusion test tolerance, pixels: pixel `x` is occluded when its right-image position
    /// `x − u(x)` lies more than this right of the leftmost right-image position of the pixels
    /// to its right (see [`occluded`]).
    pub occlusion_tolerance_px: f32,
    /// Which pixels that SGM left invalid get the regularized disparity (module docs).
    pub hole_fill: HoleFill,
    /// The SGM initialisation (its census window is also the data term's).
    pub sgm: SgmParams,
}

impl Default for TgvParams {
    /// Paper weights (λ 0.5, α₁ 1, α₂ 5, β 1, γ 4), 5×5 cost averaging, 4 rounds × 10
    /// iterations, θ from 0.2 to 0.02 (a point-wise search reach of ±2.5 px at first: starting
    /// at θ = 4 lets the search jump to noisy census minima and measured 11.8 % instead of 9.2 %
    /// dense bad-2.0 on Middlebury Motorcycle), invalid marking on (cost above 35 % of the bits), SGM
    /// defaults.
    fn default() -> Self {
        TgvParams {
            regularizer: Regularizer::TgvTensor,
            lambda: 0.5,
            alpha1: 1.0,
            alpha2: 5.0,
            beta: 1.0,
            gamma: 4.0,
            cost_window: 5,
            outer_iterations: 4,
            inner_iterations: 10,
            theta_start: 0.2,
            theta_end: 0.02,
            max_cost_fraction: 0.35,
            occlusion_tolerance_px: 0.5,
            hole_fill: HoleFill::Visible,
            sgm: SgmParams::default(),
        }
    }
}

impl TgvParams {
    /// Checks ranges.
    pub fn validate(&self) -> Result<()> {
        self.sgm.validate()?;
        let positive = [
            ("lambda", self.lambda),
            ("alpha1", self.alpha1),
            ("alpha2", self.alpha2),
            ("beta", self.beta),
            ("theta_start", self.theta_start),
            ("theta_end", self.theta_end),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::InvalidArgument(format!(
                    "TGV {name} must be positive and finite, got {v}"
                )));
            }
        }
        if !(self.gamma.is_finite() && self.gamma >= 0.0) {
            return Err(Error::InvalidArgument(format!(
                "TGV gamma must be ≥ 0, got {}",
                self.gamma
            )));
        }
        if self.cost_window.is_multiple_of(2) || self.cost_window > MAX_COST_WINDOW {
            return Err(Error::InvalidArgument(format!(
                "cost_window must be odd and at most {MAX_COST_WINDOW}, got {}",
                self.cost_window
            )));
        }
        if self.outer_iterations == 0 {
            return Err(Error::InvalidArgument(
                "outer_iterations must be ≥ 1".into(),
            ));
        }
        if !(self.max_cost_fraction > 0.0) || !(self.occlusion_tolerance_px >= 0.0) {
            return Err(Error::InvalidArgument(
                "max_cost_fraction must be > 0 and occlusion_tolerance_px ≥ 0".into(),
            ));
        }
        Ok(())
    }

    /// θ of round `k` of `outer_iterations` (geometric from `theta_start` to `theta_end`).
    pub fn theta(&self, k: u32) -> f32 {
        if self.outer_iterations <= 1 {
            return self.theta_end;
        }
        let t = k as f32 / (self.outer_iterations - 1) as f32;
        self.theta_start * (self.theta_end / self.theta_start).powf(t)
    }
}

/// Fills NaN disparities row by row with the smaller (background) of the nearest valid values
/// left and right; rows with no valid value take the column-wise fill, then `fallback`.
pub fn fill_from_background(disparity: &Image<f32>, fallback: f32) -> Vec<f32> {
    let w = disparity.width as usize;
    let h = disparity.height as usize;
    let mut out = disparity.data.clone();
    for y in 0..h {
        let row = &mut out[y * w..(y + 1) * w];
        let mut left = vec![f32::NAN; w];
        let mut last = f32::NAN;
        for x in 0..w {
            if row[x].is_finite() {
                last = row[x];
            }
            left[x] = last;
        }
        let mut right = f32::NAN;
        for x in (0..w).rev() {
            if row[x].is_finite() {
                right = row[x];
                continue;
            }
            row[x] = match (left[x].is_finite(), right.is_finite()) {
                (true, true) => left[x].min(right),
                (true, false) => left[x],
                (false, true) => right,
                (false, false) => f32::NAN,
            };
        }
    }
    for x in 0..w {
        let mut last = f32::NAN;
        for y in 0..h {
            let v = out[y * w + x];
            if v.is_finite() {
                last = v;
            } else if last.is_finite() {
                out[y * w + x] = last;
            }
        }
    }
    for v in out.iter_mut() {
        if !v.is_finite() {
            *v = fallback;
        }
    }
    out
}

/// Each pixel's census cost at its disparity `dense[i]` rounded to the nearest slice (halves
/// away from zero; below the range: slice 0; above it, or infinite: the last; NaN: slice 0):
/// what the invalidation tests against [`TgvParams::max_cost_fraction`]. GPU twin:
/// `shaders/tgv_cost_at.wgsl`.
pub fn costs_at_disparities(dense: &[f32], volume: &CostVolume) -> Vec<u8> {
    let nd = volume.num_disparities;
    let dmin = volume.min_disparity_px as f32;
    dense
        .iter()
        .enumerate()
        .map(|(i, &d)| {
            // `as usize` saturates (and takes NaN to 0): the CPU's rule, which the kernel states.
            let k = ((d - dmin).round().max(0.0) as usize).min(nd - 1);
            volume.cost[i * nd + k]
        })
        .collect()
}

/// Occlusion under the disparity `u` (uniqueness of right-image positions): pixel `x` of a row
/// is occluded when its right-image position `x − u(x)` is more than `tol` right of the minimum
/// of `x' − u(x')` over the pixels `x' > x` (a nearer surface to its right covers it).
pub fn occluded(u: &[f32], w: usize, h: usize, tol: f32) -> Vec<bool> {
    let mut occ = vec![false; w * h];
    for y in 0..h {
        let mut min_r = f32::INFINITY;
        for x in (0..w).rev() {
            let xr = x as f32 - u[y * w + x];
            if xr > min_r + tol {
                occ[y * w + x] = true;
            }
            min_r = min_r.min(xr);
        }
    }
    occ
}

/// Census + TGV (or TV) variational matcher ([`Regularizer`]), initialised by SGM.
#[derive(Clone, Debug, Default)]
pub struct TgvMatcher {
    /// Parameters.
    pub params: TgvParams,
    /// Buffers kept between pairs (cost volume, SGM rows, window-summed costs).
    scratch: ScratchPool<TgvScratch>,
}

/// What a [`TgvMatcher`] keeps between pairs.
#[derive(Default, Debug)]
struct TgvScratch {
    sgm: SgmScratch,
    /// Window sums of the costs and their counts.
    filtered: (Vec<u16>, Vec<u16>),
}

/// Intermediate results of [`TgvMatcher::estimate_with_stages`] (for benches and diagnostics).
#[derive(Clone, Debug)]
pub struct TgvStages {
    /// The SGM initialisation (NaN invalid).
    pub sgm: DisparityMap,
    /// The regularized disparity before invalidation, pixels (every pixel finite).
    pub dense_px: Vec<f32>,
    /// The final map.
    pub result: DisparityMap,
}

impl TgvMatcher {
    /// A matcher with `params` (validated).
    pub fn new(params: TgvParams) -> Result<Self> {
        params.validate()?;
        Ok(TgvMatcher {
            params,
            scratch: ScratchPool::default(),
        })
    }

    /// The census cost volume of the pair (the SGM's, whose census parameters it shares).
    pub fn cost_volume(&self, left: &GreyImage, right: &GreyImage) -> Result<CostVolume> {
        SgmMatcher::new(self.params.sgm)?.cost_volume(left, right)
    }

    /// Runs the variational refinement from an SGM map `init` over `volume` (left image `left`):
    /// returns the dense regularized disparity (pixels).
    pub fn refine(
        &self,
        left: &GreyImage,
        volume: &CostVolume,
        init: &DisparityMap,
    ) -> Result<Vec<f32>> {
        let mut filtered = Default::default();
        self.refine_with(left, volume, init, &mut filtered)
    }

    /// [`TgvMatcher::refine`] with reused buffers for the window-summed costs.
    fn refine_with(
        &self,
        left: &GreyImage,
        volume: &CostVolume,
        init: &DisparityMap,
        filtered: &mut (Vec<u16>, Vec<u16>),
    ) -> Result<Vec<f32>> {
        let p = &self.params;
        let (mut problem, u0) = self.initial_problem(left, volume.shape(), init)?;
        let data = DataCost::with_buffers(volume, p.cost_window, std::mem::take(filtered));
        let mut a = u0;
        for k in 0..p.outer_iterations {
            let theta = p.theta(k);
            pointwise_search(&data, problem.u_slice(), p.lambda, theta, &mut a);
            problem.iterate(&a, theta, p.inner_iterations)?;
        }
        *filtered = data.into_buffers();
        Ok(problem.u())
    }

    /// The initial disparity of [`TgvMatcher::refine`] (SGM's `init`, holes filled from the
    /// background side), pixels. Errors when the image, the volume and `init` differ in size.
    pub(crate) fn initial_disparity(
        &self,
        left: &GreyImage,
        volume: VolumeShape,
        init: &DisparityMap,
    ) -> Result<Vec<f32>> {
        let size = (volume.width, volume.height);
        let init_size = (init.disparity_px.width, init.disparity_px.height);
        if (left.width, left.height) != size || init_size != size {
            return Err(Error::InvalidArgument(format!(
                "image {}×{}, cost volume {}×{} and initial disparity {}×{} differ in size",
                left.width, left.height, size.0, size.1, init_size.0, init_size.1
            )));
        }
        let dmin = volume.min_disparity_px as f32;
        Ok(fill_from_background(&init.disparity_px, dmin))
    }

    /// The convex subproblem of [`TgvMatcher::refine`] before its first round, and its initial
    /// disparity ([`TgvMatcher::initial_disparity`]), pixels.
    fn initial_problem(
        &self,
        left: &GreyImage,
        volume: VolumeShape,
        init: &DisparityMap,
    ) -> Result<(TgvProblem, Vec<f32>)> {
        let p = &self.params;
        let (w, h) = (volume.width as usize, volume.height as usize);
        let u0 = self.initial_disparity(left, volume, init)?;
        let tensors = match p.regularizer {
            Regularizer::TgvTensor => diffusion_tensors(left, p.gamma, p.beta),
            _ => vec![[1.0, 0.0, 1.0]; w * h],
        };
        let problem = TgvProblem::new(&u0, w, h, p.regularizer, p.alpha1, p.alpha2, tensors)?;
        Ok((problem, u0))
    }

    /// Full estimate, keeping the intermediate maps.
    pub fn estimate_with_stages(&self, left: &GreyImage, right: &GreyImage) -> Result<TgvStages> {
        let p = &self.params;
        p.validate()?;
        let sgm = SgmMatcher::new(p.sgm)?;
        let mut scratch = self.scratch.take();
        let volume = sgm.cost_volume_in(left, right, std::mem::take(&mut scratch.sgm.cost))?;
        let init = sgm.estimate_with(left, &volume, &mut scratch.sgm.aggregate)?;
        let dense = self.refine_with(left, &volume, &init, &mut scratch.filtered)?;
        let result = self.invalidate(&dense, &init, &volume);
        scratch.sgm.cost = volume.cost;
        self.scratch.put(scratch);
        Ok(TgvStages {
            sgm: init,
            dense_px: dense,
            result,
        })
    }

    /// Marks pixels invalid (module docs) and computes confidences.
    pub(crate) fn invalidate(
        &self,
        dense: &[f32],
        init: &DisparityMap,
        volume: &CostVolume,
    ) -> DisparityMap {
        let costs = costs_at_disparities(dense, volume);
        self.invalidate_with(dense, init, &costs, volume.shape())
    }

    /// The invalidation (module docs) given each pixel's census cost at its disparity
    /// ([`costs_at_disparities`]): the map made from the dense disparity `dense` and SGM's map
    /// `init` (the twin of the GPU matcher's `shaders/tgv_invalidate.wgsl`).
    pub fn invalidate_with(
        &self,
        dense: &[f32],
        init: &DisparityMap,
        costs_at: &[u8],
        volume: VolumeShape,
    ) -> DisparityMap {
        let p = &self.params;
        let w = volume.width as usize;
        let h = volume.height as usize;
        let occ = occluded(dense, w, h, p.occlusion_tolerance_px);
        let max_bits = p.max_cost_fraction * volume.max_cost as f32;
        let sgm_conf = init.confidence.as_ref();
        let mut disp = Image::filled(volume.width, volume.height, f32::NAN);
        let mut conf = Image::filled(volume.width, volume.height, 0.0f32);
        for i in 0..w * h {
            let x = i % w;
            let d = dense[i];
            if !d.is_finite() || (p.hole_fill != HoleFill::All && (x as f32) - d < -0.5) {
                continue;
            }
            let c = costs_at[i] as f32;
            let sgm_valid = init.disparity_px.data[i].is_finite();
            let agrees = sgm_valid && (init.disparity_px.data[i] - d).abs() <= 1.0;
            let keep = sgm_valid
                || match p.hole_fill {
                    HoleFill::None => false,
                    HoleFill::Visible => !occ[i] && c <= max_bits,
                    HoleFill::All => true,
                };
            if !keep {
                continue;
            }
            disp.data[i] = d;
            let match_quality = (1.0 - c / volume.max_cost as f32).clamp(0.0, 1.0);
            conf.data[i] = if agrees {
                sgm_conf.map_or(match_quality, |s| s.data[i].max(match_quality))
            } else {
                0.5 * match_quality
            };
        }
        DisparityMap {
            disparity_px: disp,
            confidence: Some(conf),
        }
    }
}

impl DisparityEstimator for TgvMatcher {
    fn name(&self) -> &str {
        match self.params.regularizer {
            Regularizer::Tv => "tv",
            Regularizer::Tgv => "tgv",
            Regularizer::TgvTensor => "tgv-tensor",
        }
    }

    fn estimate(&self, left: &GreyImage, right: &GreyImage) -> Result<DisparityMap> {
        Ok(self.estimate_with_stages(left, right)?.result)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn theta_schedule_is_geometric() {
        let p = TgvParams {
            outer_iterations: 3,
            theta_start: 4.0,
            theta_end: 0.25,
            ..TgvParams::default()
        };
        assert!((p.theta(0) - 4.0).abs() < 1e-6);
        assert!((p.theta(1) - 1.0).abs() < 1e-5);
        assert!((p.theta(2) - 0.25).abs() < 1e-6);
    }

    #[test]
    fn background_fill_takes_the_smaller_neighbour() {
        let nan = f32::NAN;
        let img = Image {
            width: 5,
            height: 1,
            data: vec![nan, 10.0, nan, 4.0, nan],
        };
        assert_eq!(
            fill_from_background(&img, 0.0),
            vec![10.0, 10.0, 4.0, 4.0, 4.0]
        );
    }

    #[test]
    fn occlusion_marks_pixels_hidden_by_a_nearer_surface() {
        // Background d = 2, a foreground d = 6 from x = 6: right positions 8−2=6 … covered.
        let mut u = vec![2.0f32; 12];
        for v in u.iter_mut().skip(6) {
            *v = 6.0;
        }
        let occ = occluded(&u, 12, 1, 0.5);
        // Foreground starts at right position 0; background pixels x − 2 > 0.5 are hidden.
        let hidden: Vec<usize> = (0..12).filter(|&x| occ[x]).collect();
        assert_eq!(hidden, vec![3, 4, 5]);
    }
}
