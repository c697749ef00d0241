//! Variational disparity estimation: census data term + (anisotropic) TGV regulariser, after the
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
//!   bit counts directly, so λ = 0.5 means half a unit of regulariser per differing census bit
//!   (a 9×7 binary census has 62 bits).
//! - `T = exp(−γ|∇I|^β)·n nᵀ + n⊥ n⊥ᵀ`, `n = ∇I/|∇I|`, with `I` the left image scaled to [0, 1]
//!   and `∇I` central differences; `T = 1` where `|∇I| < 1e-6`. [`Regulariser::Tv`] and
//!   [`Regulariser::Tgv`] use `T = 1` (the ablation of the paper's Fig. 3); TV also fixes `v = 0`.
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

use super::sgm::{CostVolume, SgmMatcher, SgmParams};
use super::{DisparityEstimator, DisparityMap};
use crate::error::{Error, Result};
use crate::frame::{GreyImage, Image};
use rayon::prelude::*;

/// Largest cost window: `21² · 128` bits (the largest census) still fits the `u16` sums.
pub const MAX_COST_WINDOW: u32 = 21;

/// Which of the pixels SGM left invalid the variational matcher fills with its regularised
/// disparity.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HoleFill {
    /// None: the result has SGM's validity, with TGV-refined values (for fusion).
    None,
    /// Those visible under the final disparity whose census cost there is at most
    /// [`TgvParams::max_cost_fraction`] of the bits (the default for `denser stereo`).
    Visible,
    /// All, including pixels whose match falls outside the right image (their disparity is
    /// the regulariser's extrapolation): a dense map, for benchmarks that count missing pixels
    /// as errors.
    All,
}

/// Which regulariser the variational matcher uses (the ablation of the paper's Fig. 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Regulariser {
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
    /// Regulariser (TV, TGV, TGV with tensor).
    pub regulariser: Regulariser,
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
    /// Which pixels that SGM left invalid get the regularised disparity (module docs).
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
            regulariser: Regulariser::TgvTensor,
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
        if self.cost_window % 2 == 0 || self.cost_window > MAX_COST_WINDOW {
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

/// Per-pixel diffusion tensor `T` as `[t11, t12, t22]` (symmetric, eigenvalues in (0, 1]).
pub type Tensor = [f32; 3];

/// The tensors of `image`: `T = exp(−γ|∇I|^β) n nᵀ + n⊥ n⊥ᵀ` with `I` in [0, 1] and central
/// differences (one-sided at the border). With `γ = 0` every tensor is the identity.
pub fn diffusion_tensors(image: &GreyImage, gamma: f32, beta: f32) -> Vec<Tensor> {
    let w = image.width as usize;
    let h = image.height as usize;
    let at = |x: usize, y: usize| image.data[y * w + x] as f32 / 255.0;
    let mut out = vec![[1.0, 0.0, 1.0]; w * h];
    if w == 0 {
        return out;
    }
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, t) in row.iter_mut().enumerate() {
            let (xl, xr) = (x.saturating_sub(1), (x + 1).min(w - 1));
            let (yu, yd) = (y.saturating_sub(1), (y + 1).min(h - 1));
            let gx = if xr > xl {
                (at(xr, y) - at(xl, y)) / (xr - xl) as f32
            } else {
                0.0
            };
            let gy = if yd > yu {
                (at(x, yd) - at(x, yu)) / (yd - yu) as f32
            } else {
                0.0
            };
            let norm = (gx * gx + gy * gy).sqrt();
            if norm < 1e-6 {
                continue;
            }
            let (n1, n2) = (gx / norm, gy / norm);
            let k = 1.0 - (-gamma * norm.powf(beta)).exp();
            *t = [1.0 - k * n1 * n1, -k * n1 * n2, 1.0 - k * n2 * n2];
        }
    });
    out
}

/// Forward-difference gradient with Neumann boundary of the scalar field `u` (`w × h`):
/// `[u(x+1) − u(x), u(y+1) − u(y)]`, 0 across the last column/row.
pub fn gradient(u: &[f32], w: usize, h: usize) -> Vec<[f32; 2]> {
    let mut g = vec![[0.0; 2]; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let gx = if x + 1 < w { u[i + 1] - u[i] } else { 0.0 };
            let gy = if y + 1 < h { u[i + w] - u[i] } else { 0.0 };
            g[i] = [gx, gy];
        }
    }
    g
}

/// `div p = −∇ᵀp` for [`gradient`].
pub fn divergence(p: &[[f32; 2]], w: usize, h: usize) -> Vec<f32> {
    let mut d = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            d[y * w + x] = div_at(|i| p[i], w, h, x, y);
        }
    }
    d
}

#[inline(always)]
fn div_at(p: impl Fn(usize) -> [f32; 2], w: usize, h: usize, x: usize, y: usize) -> f32 {
    let i = y * w + x;
    let mut d = 0.0;
    if x + 1 < w {
        d += p(i)[0];
    }
    if x > 0 {
        d -= p(i - 1)[0];
    }
    if y + 1 < h {
        d += p(i)[1];
    }
    if y > 0 {
        d -= p(i - w)[1];
    }
    d
}

/// Symmetrised gradient `ε(v)` of the vector field `v` with backward differences (0 across the
/// first column/row), as `[ε11, ε22, ε12]`.
pub fn sym_gradient(v: &[[f32; 2]], w: usize, h: usize) -> Vec<[f32; 3]> {
    let mut e = vec![[0.0; 3]; w * h];
    for y in 0..h {
        for x in 0..w {
            e[y * w + x] = sym_grad_at(|i| v[i], w, x, y);
        }
    }
    e
}

#[inline(always)]
fn sym_grad_at(v: impl Fn(usize) -> [f32; 2], w: usize, x: usize, y: usize) -> [f32; 3] {
    let i = y * w + x;
    let c = v(i);
    let (l, u) = (
        if x > 0 { v(i - 1) } else { c },
        if y > 0 { v(i - w) } else { c },
    );
    [
        c[0] - l[0],
        c[1] - u[1],
        0.5 * ((c[0] - u[0]) + (c[1] - l[1])),
    ]
}

/// `div_sym q = −εᵀq` for [`sym_gradient`], with the inner product
/// `⟨a, b⟩ = a11·b11 + a22·b22 + 2·a12·b12`.
pub fn sym_divergence(q: &[[f32; 3]], w: usize, h: usize) -> Vec<[f32; 2]> {
    let mut d = vec![[0.0; 2]; w * h];
    for y in 0..h {
        for x in 0..w {
            d[y * w + x] = sym_div_at(|i| q[i], w, h, x, y);
        }
    }
    d
}

#[inline(always)]
fn sym_div_at(q: impl Fn(usize) -> [f32; 3], w: usize, h: usize, x: usize, y: usize) -> [f32; 2] {
    let i = y * w + x;
    let c = q(i);
    let (mut d1, mut d2) = (0.0, 0.0);
    if x > 0 {
        d1 += c[0];
        d2 += c[2];
    }
    if x + 1 < w {
        let r = q(i + 1);
        d1 -= r[0];
        d2 -= r[2];
    }
    if y > 0 {
        d1 += c[2];
        d2 += c[1];
    }
    if y + 1 < h {
        let b = q(i + w);
        d1 -= b[2];
        d2 -= b[1];
    }
    [-d1, -d2]
}

#[inline(always)]
fn apply(t: Tensor, g: [f32; 2]) -> [f32; 2] {
    [t[0] * g[0] + t[1] * g[1], t[1] * g[0] + t[2] * g[1]]
}

/// [`TgvProblem::state`]: primal `[u, v1, v2]`, over-relaxed primal, dual
/// `[p1, p2, q11, q22, q12]`, one entry per pixel.
pub type TgvState<'a> = (&'a [[f32; 3]], &'a [[f32; 3]], &'a [[f32; 5]]);

/// [`TgvProblem::state_mut`].
pub type TgvStateMut<'a> = (&'a mut [[f32; 3]], &'a mut [[f32; 3]], &'a mut [[f32; 5]]);

/// The convex subproblem for fixed `a`: minimise over `(u, v)`
/// `Σ α₁|T(∇u − v)| + α₂|ε(v)| + 1/(2θ)(u − a)²` by Chambolle–Pock (primal `u, v`; dual
/// `p` (|p| ≤ α₁), `q` (|q| ≤ α₂)), steps `τ = σ = 1/√12` (`1/√8` for TV).
#[derive(Clone, Debug)]
pub struct TgvProblem {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Regulariser (TV keeps `v = 0`; TGV uses identity tensors).
    pub regulariser: Regulariser,
    /// α₁.
    pub alpha1: f32,
    /// α₂.
    pub alpha2: f32,
    /// Tensors (identity for TV and TGV).
    pub tensors: Vec<Tensor>,
    /// Primal `[u, v1, v2]` per pixel (disparity in pixels, its slope in pixels per pixel).
    pub primal: Vec<[f32; 3]>,
    /// Over-relaxed primal.
    primal_bar: Vec<[f32; 3]>,
    /// Dual `[p1, p2, q11, q22, q12]` per pixel.
    dual: Vec<[f32; 5]>,
}

impl TgvProblem {
    /// A problem with primal `u0`, `v = 0`, zero duals. `tensors` must have `w·h` entries.
    pub fn new(
        u0: &[f32],
        width: usize,
        height: usize,
        regulariser: Regulariser,
        alpha1: f32,
        alpha2: f32,
        tensors: Vec<Tensor>,
    ) -> Result<Self> {
        let n = width * height;
        if u0.len() != n || tensors.len() != n {
            return Err(Error::InvalidArgument(format!(
                "TGV problem of {width}×{height} got {} disparities and {} tensors",
                u0.len(),
                tensors.len()
            )));
        }
        let primal: Vec<[f32; 3]> = u0.iter().map(|&u| [u, 0.0, 0.0]).collect();
        Ok(TgvProblem {
            width,
            height,
            regulariser,
            alpha1,
            alpha2,
            tensors,
            primal_bar: primal.clone(),
            primal,
            dual: vec![[0.0; 5]; n],
        })
    }

    /// The iteration state `(primal, primal_bar, dual)`: `[u, v1, v2]`, its over-relaxation, and
    /// `[p1, p2, q11, q22, q12]` per pixel (for the GPU twin, `crate::gpu::TgvProblemGpu`).
    pub fn state(&self) -> TgvState<'_> {
        (&self.primal, &self.primal_bar, &self.dual)
    }

    /// Mutable [`TgvProblem::state`], to continue an iteration computed elsewhere.
    pub fn state_mut(&mut self) -> TgvStateMut<'_> {
        (&mut self.primal, &mut self.primal_bar, &mut self.dual)
    }

    /// The step sizes `(τ, σ)` of [`TgvProblem::iterate`]: `1/√8` for TV, `1/√12` otherwise.
    pub fn steps(&self) -> (f32, f32) {
        let step = if self.regulariser == Regulariser::Tv {
            1.0 / 8f32.sqrt()
        } else {
            1.0 / 12f32.sqrt()
        };
        (step, step)
    }

    /// The disparity `u`.
    pub fn u(&self) -> Vec<f32> {
        self.primal.iter().map(|p| p[0]).collect()
    }

    pub(crate) fn check_target(&self, a: &[f32], theta: f32) -> Result<()> {
        if a.len() != self.width * self.height {
            return Err(Error::InvalidArgument(format!(
                "coupling target has {} values, the problem {}×{}",
                a.len(),
                self.width,
                self.height
            )));
        }
        if !(theta.is_finite() && theta > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "θ must be positive and finite, got {theta}"
            )));
        }
        Ok(())
    }

    /// The energy `Σ α₁|T(∇u − v)| + α₂|ε(v)| + 1/(2θ)(u − a)²` at the current primal.
    /// Errors when `a` does not have one value per pixel or θ ≤ 0.
    pub fn energy(&self, a: &[f32], theta: f32) -> Result<f64> {
        self.check_target(a, theta)?;
        let (w, h) = (self.width, self.height);
        let u: Vec<f32> = self.u();
        let v: Vec<[f32; 2]> = self.primal.iter().map(|p| [p[1], p[2]]).collect();
        let g = gradient(&u, w, h);
        let e = sym_gradient(&v, w, h);
        let mut sum = 0.0f64;
        for i in 0..w * h {
            let r = apply(self.tensors[i], [g[i][0] - v[i][0], g[i][1] - v[i][1]]);
            sum += self.alpha1 as f64 * (r[0] as f64).hypot(r[1] as f64);
            if self.regulariser != Regulariser::Tv {
                let [e11, e22, e12] = e[i].map(|c| c as f64);
                sum += self.alpha2 as f64 * (e11 * e11 + e22 * e22 + 2.0 * e12 * e12).sqrt();
            }
            let d = (u[i] - a[i]) as f64;
            sum += d * d / (2.0 * theta as f64);
        }
        Ok(sum)
    }

    /// Runs `iterations` primal–dual iterations towards the minimiser for the coupling target `a`
    /// (`w·h` disparities) and weight `1/(2θ)`. Errors when `a` does not have one value per
    /// pixel or θ ≤ 0.
    pub fn iterate(&mut self, a: &[f32], theta: f32, iterations: u32) -> Result<()> {
        self.check_target(a, theta)?;
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return Ok(());
        }
        let tv = self.regulariser == Regulariser::Tv;
        let (tau, sigma) = self.steps();
        let (a1, a2) = (self.alpha1, self.alpha2);
        for _ in 0..iterations {
            // Dual ascent and projection.
            {
                let pb = &self.primal_bar;
                let tens = &self.tensors;
                self.dual
                    .par_chunks_mut(w)
                    .enumerate()
                    .for_each(|(y, row)| {
                        for (x, d) in row.iter_mut().enumerate() {
                            let i = y * w + x;
                            let c = pb[i];
                            let gx = if x + 1 < w { pb[i + 1][0] - c[0] } else { 0.0 };
                            let gy = if y + 1 < h { pb[i + w][0] - c[0] } else { 0.0 };
                            let t = apply(tens[i], [gx - c[1], gy - c[2]]);
                            let (p1, p2) = (d[0] + sigma * t[0], d[1] + sigma * t[1]);
                            // sqrt(p1² + p2²), not `hypot`: the GPU twin (shaders/tgv_dual.wgsl)
                            // has no hypot, and |p| ≤ α₁ cannot overflow.
                            let s = ((p1 * p1 + p2 * p2).sqrt() / a1).max(1.0);
                            d[0] = p1 / s;
                            d[1] = p2 / s;
                            if !tv {
                                let e = sym_grad_at(|j| [pb[j][1], pb[j][2]], w, x, y);
                                let q11 = d[2] + sigma * e[0];
                                let q22 = d[3] + sigma * e[1];
                                let q12 = d[4] + sigma * e[2];
                                let s = ((q11 * q11 + q22 * q22 + 2.0 * q12 * q12).sqrt() / a2)
                                    .max(1.0);
                                d[2] = q11 / s;
                                d[3] = q22 / s;
                                d[4] = q12 / s;
                            }
                        }
                    });
            }
            // Primal descent, proximal step of the coupling, over-relaxation.
            {
                let dual = &self.dual;
                let tens = &self.tensors;
                let tp = |j: usize| apply(tens[j], [dual[j][0], dual[j][1]]);
                let coupling = tau / theta;
                self.primal
                    .par_chunks_mut(w)
                    .zip(self.primal_bar.par_chunks_mut(w))
                    .enumerate()
                    .for_each(|(y, (prow, brow))| {
                        for x in 0..w {
                            let i = y * w + x;
                            let old = prow[x];
                            let div_tp = div_at(tp, w, h, x, y);
                            let u = (old[0] + tau * div_tp + coupling * a[i]) / (1.0 + coupling);
                            let (v1, v2) = if tv {
                                (0.0, 0.0)
                            } else {
                                let t = tp(i);
                                let ds = sym_div_at(
                                    |j| [dual[j][2], dual[j][3], dual[j][4]],
                                    w,
                                    h,
                                    x,
                                    y,
                                );
                                (old[1] + tau * (t[0] + ds[0]), old[2] + tau * (t[1] + ds[1]))
                            };
                            let new = [u, v1, v2];
                            prow[x] = new;
                            brow[x] = [
                                2.0 * new[0] - old[0],
                                2.0 * new[1] - old[1],
                                2.0 * new[2] - old[2],
                            ];
                        }
                    });
            }
        }
        Ok(())
    }
}

/// Census costs averaged over a square window, as `u16` sums (divide by `window²` for bits),
/// layout of the [`CostVolume`]. Border pixels average over the part of the window inside.
pub fn box_filtered_costs(volume: &CostVolume, window: u32) -> (Vec<u16>, Vec<u16>) {
    let w = volume.width as usize;
    let h = volume.height as usize;
    let nd = volume.num_disparities;
    let r = (window / 2) as usize;
    // Horizontal pass into u16, then vertical; counts per pixel for the normalisation.
    let mut horiz = vec![0u16; w * h * nd];
    horiz
        .par_chunks_mut(w * nd)
        .enumerate()
        .for_each(|(y, row)| {
            let src = &volume.cost[y * w * nd..(y + 1) * w * nd];
            for x in 0..w {
                let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
                let out = &mut row[x * nd..(x + 1) * nd];
                for xx in x0..=x1 {
                    for (o, &c) in out.iter_mut().zip(&src[xx * nd..(xx + 1) * nd]) {
                        *o += c as u16;
                    }
                }
            }
        });
    let mut sum = vec![0u16; w * h * nd];
    sum.par_chunks_mut(w * nd).enumerate().for_each(|(y, row)| {
        let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
        for yy in y0..=y1 {
            for (o, &c) in row.iter_mut().zip(&horiz[yy * w * nd..(yy + 1) * w * nd]) {
                *o += c;
            }
        }
    });
    let mut count = vec![0u16; w * h];
    for y in 0..h {
        for x in 0..w {
            let cx = (x + r).min(w - 1) - x.saturating_sub(r) + 1;
            let cy = (y + r).min(h - 1) - y.saturating_sub(r) + 1;
            count[y * w + x] = (cx * cy) as u16;
        }
    }
    (sum, count)
}

/// The data term's cost `C(x, d)` in bits: raw or window-averaged census costs.
pub(crate) struct DataCost<'a> {
    pub(crate) volume: &'a CostVolume,
    pub(crate) filtered: Option<(Vec<u16>, Vec<u16>)>,
}

impl<'a> DataCost<'a> {
    /// The data cost of `volume` averaged over `window` × `window` (raw when 1).
    pub(crate) fn new(volume: &'a CostVolume, window: u32) -> Self {
        DataCost {
            volume,
            filtered: (window > 1).then(|| box_filtered_costs(volume, window)),
        }
    }

    /// Cost (bits) of slice `k` at pixel index `i`.
    #[inline(always)]
    fn at(&self, i: usize, k: usize) -> f32 {
        let j = i * self.volume.num_disparities + k;
        match &self.filtered {
            None => self.volume.cost[j] as f32,
            Some((sum, count)) => sum[j] as f32 / count[i] as f32,
        }
    }
}

/// The point-wise search of [`TgvMatcher::refine`] on its own: for each pixel, the disparity `a`
/// (pixels) minimising `λ·C(x, a) + (u(x) − a)²/(2θ)` over the census costs of `volume`
/// averaged over `cost_window` × `cost_window` (raw when 1), with the parabola fit. `u` has one
/// disparity per pixel (pixels). The CPU twin of [`crate::gpu::pointwise_search_gpu`].
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
    let nd = v.num_disparities;
    let dmin = v.min_disparity_px as f32;
    let reach = (2.0 * theta * lambda * v.max_cost as f32).sqrt();
    let w = v.width as usize;
    a.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, ax) in row.iter_mut().enumerate() {
            let i = y * w + x;
            let uk = u[i] - dmin;
            let k0 = ((uk - reach).floor().max(0.0) as usize).min(nd - 1);
            let k1 = ((uk + reach).ceil().max(0.0) as usize).min(nd - 1);
            let energy = |k: usize| {
                let d = k as f32 - uk;
                lambda * data.at(i, k) + d * d / (2.0 * theta)
            };
            let mut best = k0;
            let mut best_e = f32::INFINITY;
            for k in k0..=k1 {
                let e = energy(k);
                if e < best_e {
                    best_e = e;
                    best = k;
                }
            }
            let mut d = best as f32;
            if best > 0 && best + 1 < nd {
                let (em, ep) = (energy(best - 1), energy(best + 1));
                let denom = em - 2.0 * best_e + ep;
                if denom > 1e-9 {
                    d += (0.5 * (em - ep) / denom).clamp(-0.5, 0.5);
                }
            }
            *ax = d + dmin;
        }
    });
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

/// Census + TGV (or TV) variational matcher ([`Regulariser`]), initialised by SGM.
#[derive(Clone, Debug, Default)]
pub struct TgvMatcher {
    /// Parameters.
    pub params: TgvParams,
}

/// Intermediate results of [`TgvMatcher::estimate_with_stages`] (for benches and diagnostics).
#[derive(Clone, Debug)]
pub struct TgvStages {
    /// The SGM initialisation (NaN invalid).
    pub sgm: DisparityMap,
    /// The regularised disparity before invalidation, pixels (every pixel finite).
    pub dense_px: Vec<f32>,
    /// The final map.
    pub result: DisparityMap,
}

impl TgvMatcher {
    /// A matcher with `params` (validated).
    pub fn new(params: TgvParams) -> Result<Self> {
        params.validate()?;
        Ok(TgvMatcher { params })
    }

    /// The census cost volume of the pair (the SGM's, whose census parameters it shares).
    pub fn cost_volume(&self, left: &GreyImage, right: &GreyImage) -> Result<CostVolume> {
        SgmMatcher::new(self.params.sgm)?.cost_volume(left, right)
    }

    /// Runs the variational refinement from an SGM map `init` over `volume` (left image `left`):
    /// returns the dense regularised disparity (pixels).
    pub fn refine(
        &self,
        left: &GreyImage,
        volume: &CostVolume,
        init: &DisparityMap,
    ) -> Result<Vec<f32>> {
        let p = &self.params;
        let (mut problem, u0) = self.initial_problem(left, volume, init)?;
        let data = DataCost::new(volume, p.cost_window);
        let mut a = u0.clone();
        let mut u = u0;
        for k in 0..p.outer_iterations {
            let theta = p.theta(k);
            pointwise_search(&data, &u, p.lambda, theta, &mut a);
            problem.iterate(&a, theta, p.inner_iterations)?;
            u = problem.u();
        }
        Ok(u)
    }

    /// The convex subproblem of [`TgvMatcher::refine`] before its first round, and its initial
    /// disparity (SGM's, holes filled from the background side), pixels.
    pub(crate) fn initial_problem(
        &self,
        left: &GreyImage,
        volume: &CostVolume,
        init: &DisparityMap,
    ) -> Result<(TgvProblem, Vec<f32>)> {
        let p = &self.params;
        let w = volume.width as usize;
        let h = volume.height as usize;
        if left.width as usize != w || left.height as usize != h {
            return Err(Error::InvalidArgument(
                "image and cost volume sizes differ".into(),
            ));
        }
        let dmin = volume.min_disparity_px as f32;
        let u0 = fill_from_background(&init.disparity_px, dmin);
        let tensors = match p.regulariser {
            Regulariser::TgvTensor => diffusion_tensors(left, p.gamma, p.beta),
            Regulariser::Tv | Regulariser::Tgv => vec![[1.0, 0.0, 1.0]; w * h],
        };
        let problem = TgvProblem::new(&u0, w, h, p.regulariser, p.alpha1, p.alpha2, tensors)?;
        Ok((problem, u0))
    }

    /// Full estimate, keeping the intermediate maps.
    pub fn estimate_with_stages(&self, left: &GreyImage, right: &GreyImage) -> Result<TgvStages> {
        let p = &self.params;
        p.validate()?;
        let sgm = SgmMatcher::new(p.sgm)?;
        let volume = sgm.cost_volume(left, right)?;
        let init = sgm.estimate_from_volume(left, &volume)?;
        let dense = self.refine(left, &volume, &init)?;
        let result = self.invalidate(&dense, &init, &volume);
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
        let p = &self.params;
        let w = volume.width as usize;
        let h = volume.height as usize;
        let nd = volume.num_disparities;
        let dmin = volume.min_disparity_px as f32;
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
            let k = ((d - dmin).round().max(0.0) as usize).min(nd - 1);
            let c = volume.cost[i * nd + k] as f32;
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
        match self.params.regulariser {
            Regulariser::Tv => "tv",
            Regulariser::Tgv => "tgv",
            Regulariser::TgvTensor => "tgv-tensor",
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
