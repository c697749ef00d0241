//! The convex subproblem for fixed `a` ([`TgvProblem`]): its state, energy and the
//! Chambolle–Pock iterations, whose row kernels are in `steps`.

#[allow(unused_imports)]
use super::*;

/// [`TgvProblem::state`]: primal `[u, v1, v2]`, over-relaxed primal, dual
/// `[p1, p2, q11, q22, q12]`, one entry per pixel (copies).
pub type TgvState = (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 5]>);

/// The convex subproblem for fixed `a`: minimise over `(u, v)`
/// `Σ α₁|T(∇u − v)| + α₂|ε(v)| + 1/(2θ)(u − a)²` by Chambolle–Pock (primal `u, v`; dual
/// `p` (|p| ≤ α₁), `q` (|q| ≤ α₂)), steps `τ = σ = 1/√12` (`1/√8` for TV).
///
/// The state is kept as one array per component (structure of arrays), so that the iterations
/// run over contiguous rows and vectorise; [`TgvProblem::state`] gives it per pixel.
#[derive(Clone, Debug)]
pub struct TgvProblem {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Regularizer (TV keeps `v = 0`; TGV uses identity tensors).
    pub regularizer: Regularizer,
    /// α₁.
    pub alpha1: f32,
    /// α₂.
    pub alpha2: f32,
    /// Tensors as given (identity for TV and TGV).
    tensors: Vec<Tensor>,
    /// The tensors' components `[t11, t12, t22]`, one array each.
    t: [Vec<f32>; 3],
    /// Primal `[u, v1, v2]` (disparity in pixels, its slope in pixels per pixel).
    x: [Vec<f32>; 3],
    /// Over-relaxed primal.
    x_bar: [Vec<f32>; 3],
    /// Dual `[p1, p2, q11, q22, q12]`.
    y: [Vec<f32>; 5],
    /// `T·p`, computed by the dual step for the primal step (not state).
    tp: [Vec<f32>; 2],
}

/// The step sizes `(τ, σ)` of the iterations with `regularizer`: `1/√8` for TV, `1/√12`
/// otherwise.
pub fn steps_for(regularizer: Regularizer) -> (f32, f32) {
    let step = if regularizer == Regularizer::Tv {
        1.0 / 8f32.sqrt()
    } else {
        1.0 / 12f32.sqrt()
    };
    (step, step)
}

/// Rows handed to one parallel task of the iterations.
pub(super) const ROWS_PER_TASK: usize = 8;

impl TgvProblem {
    /// A problem with primal `u0`, `v = 0`, zero duals. `tensors` must have `w·h` entries.
    pub fn new(
        u0: &[f32],
        width: usize,
        height: usize,
        regularizer: Regularizer,
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
        let t = std::array::from_fn(|c| tensors.iter().map(|t| t[c]).collect());
        let zeros = || vec![0.0f32; n];
        Ok(TgvProblem {
            width,
            height,
            regularizer,
            alpha1,
            alpha2,
            tensors,
            t,
            x: [u0.to_vec(), zeros(), zeros()],
            x_bar: [u0.to_vec(), zeros(), zeros()],
            y: std::array::from_fn(|_| zeros()),
            tp: [zeros(), zeros()],
        })
    }

    /// The tensors, `[t11, t12, t22]` per pixel.
    pub fn tensors(&self) -> &[Tensor] {
        &self.tensors
    }

    /// The iteration state `(primal, primal_bar, dual)`: `[u, v1, v2]`, its over-relaxation, and
    /// `[p1, p2, q11, q22, q12]` per pixel (copies; for the GPU twin,
    /// `crate::depth::TgvProblemGpu`).
    pub fn state(&self) -> TgvState {
        let n = self.width * self.height;
        let three = |a: &[Vec<f32>; 3]| (0..n).map(|i| [a[0][i], a[1][i], a[2][i]]).collect();
        let dual = (0..n)
            .map(|i| std::array::from_fn(|c| self.y[c][i]))
            .collect();
        (three(&self.x), three(&self.x_bar), dual)
    }

    /// Replaces the iteration state (as [`TgvProblem::state`] gives it), to continue an
    /// iteration computed elsewhere. Errors when a slice does not have one entry per pixel.
    pub fn set_state(
        &mut self,
        primal: &[[f32; 3]],
        primal_bar: &[[f32; 3]],
        dual: &[[f32; 5]],
    ) -> Result<()> {
        let n = self.width * self.height;
        if primal.len() != n || primal_bar.len() != n || dual.len() != n {
            return Err(Error::InvalidArgument(format!(
                "TGV state of {}, {} and {} pixels for a {}×{} problem",
                primal.len(),
                primal_bar.len(),
                dual.len(),
                self.width,
                self.height
            )));
        }
        for c in 0..3 {
            for i in 0..n {
                self.x[c][i] = primal[i][c];
                self.x_bar[c][i] = primal_bar[i][c];
            }
        }
        for (c, y) in self.y.iter_mut().enumerate() {
            for (yi, d) in y.iter_mut().zip(dual) {
                *yi = d[c];
            }
        }
        Ok(())
    }

    /// The step sizes `(τ, σ)` of [`TgvProblem::iterate`] ([`steps_for`] its regularizer).
    pub fn steps(&self) -> (f32, f32) {
        steps_for(self.regularizer)
    }

    /// Whether the state is [`TgvProblem::new`]'s: `v = 0`, the over-relaxed primal equal to
    /// the primal, the dual zero (bit patterns: −0 is not zero).
    pub(crate) fn is_fresh(&self) -> bool {
        let zero = |a: &[f32]| a.iter().all(|v| v.to_bits() == 0);
        let same = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
        zero(&self.x[1])
            && zero(&self.x[2])
            && (0..3).all(|c| same(&self.x[c], &self.x_bar[c]))
            && self.y.iter().all(|y| zero(y))
    }

    /// The disparity `u`.
    pub fn u(&self) -> Vec<f32> {
        self.x[0].clone()
    }

    /// The disparity `u`, borrowed.
    pub fn u_slice(&self) -> &[f32] {
        &self.x[0]
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
        let u = &self.x[0];
        let v: Vec<[f32; 2]> = self.x[1]
            .iter()
            .zip(&self.x[2])
            .map(|(&a, &b)| [a, b])
            .collect();
        let g = gradient(u, w, h);
        let e = sym_gradient(&v, w, h);
        let mut sum = 0.0f64;
        for i in 0..w * h {
            let r = apply(self.tensors[i], [g[i][0] - v[i][0], g[i][1] - v[i][1]]);
            sum += self.alpha1 as f64 * (r[0] as f64).hypot(r[1] as f64);
            if self.regularizer != Regularizer::Tv {
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
    ///
    /// Each iteration is a dual step over all rows, then a primal step over all rows (rows in
    /// parallel); the arithmetic of every pixel is that of the per-pixel formulas
    /// ([`gradient`], [`sym_gradient`] and their adjoints) in the same order, so the result does
    /// not depend on the layout or the vector width (and its GPU twin can match it bit for bit).
    pub fn iterate(&mut self, a: &[f32], theta: f32, iterations: u32) -> Result<()> {
        self.check_target(a, theta)?;
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return Ok(());
        }
        let tv = self.regularizer == Regularizer::Tv;
        let (tau, sigma) = self.steps();
        let k = StepConsts {
            w,
            h,
            tv,
            tau,
            sigma,
            a1: self.alpha1,
            a2: self.alpha2,
            coupling: tau / theta,
        };
        for _ in 0..iterations {
            dual_step(&k, &self.t, &self.x_bar, &mut self.y, &mut self.tp);
            primal_step(&k, a, &self.tp, &self.y, &mut self.x, &mut self.x_bar);
        }
        Ok(())
    }
}
