//! Ω-aware TV regularization of the fused TSDF (DENSER Sec. III-B, III-C).
//!
//! Minimises `E(u) = Σ_Ω |∇u| + (λ/2) Σ_Ω w (u − f)²` over the voxels in Ω (directly observed)
//! with the first-order primal–dual method of Chambolle & Pock (2011):
//!
//! ```text
//! p ← (p + σ∇ū) / max(1, |p + σ∇ū|)              (dual ascent + projection, isotropic)
//! u ← (u + τ div p + τλ w f) / (1 + τλ w)          (primal descent + prox of the data term)
//! ū ← u_new + θ (u_new − u_old)                    (over-relaxation)
//! ```
//!
//! The gradient is Ω-aware: `∇ₓu(x) = u(x + eₓ) − u(x)` when both voxels are in Ω, else 0
//! (neighbours across block borders come from the neighbouring block; unallocated blocks are
//! outside Ω), and `div` is exactly `−∇ᵀ` for it: `div p(x) = Σ_d m_d(x) p_d(x) − m_d(x − e_d) p_d(x − e_d)`
//! with `m_d(x) = [x ∈ Ω ∧ x + e_d ∈ Ω]`. The paper prints the primal step as `u − τ div p` next to
//! its own `div = −∇ᵀ`, which ascends the energy; the form above is the standard one (the
//! `energy_falls` test checks it). `f` and `u` are normalised TSDF values (distance / μ), `w` the
//! observation count. `u` starts at `f` and `p` at 0 (the paper starts `u` at 0).
//!
//! The solver works on a [`TvProblem`]: a set of blocks gathered from a layer into flat arrays
//! (`f`, `w`, Ω masks, `u`, `ū`, `p`), with a neighbour table across block borders. Blocks outside
//! the set are treated as outside Ω, which is what a region solve with a halo needs.
//! It does not page: the caller gathers what fits.

use crate::grid::{
    decode_tsdf, encode_tsdf, BlockIndex, Layer, TouchedBlocks, VOXELS_PER_BLOCK, VOXELS_PER_SIDE,
};
use rayon::prelude::*;
use std::collections::HashMap;

/// The largest data weight λ accepted. Past about 10⁶ the primal step keeps `u = f` to f32
/// precision (`τ λ w ≫ 1`) anyway, and far larger values overflow `τ λ w` to infinity.
pub const MAX_LAMBDA: f32 = 1.0e6;

/// Parameters of the TV primal–dual solver.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TvParams {
    /// Data-term weight λ (paper: 0.8 at 10 cm voxels, 0.4 at 20 cm).
    pub lambda: f32,
    /// Dual step σ (paper 0.5).
    pub sigma: f32,
    /// Primal step τ (paper 1/6; convergence needs σ·τ·12 ≤ 1 in 3D).
    pub tau: f32,
    /// Relaxation θ (paper 1).
    pub theta: f32,
    /// Number of primal–dual iterations.
    pub iterations: u32,
}

impl TvParams {
    /// The paper's parameters for a voxel size: λ = 0.4 for 20 cm voxels, 0.8 otherwise.
    pub fn paper(voxel_size_m: f32) -> Self {
        let lambda = if voxel_size_m >= 0.15 { 0.4 } else { 0.8 };
        TvParams {
            lambda,
            sigma: 0.5,
            tau: 1.0 / 6.0,
            theta: 1.0,
            iterations: 100,
        }
    }

    /// Checks the step sizes satisfy the convergence condition `σ τ ‖∇‖² ≤ 1` with `‖∇‖² ≤ 12`,
    /// and that λ is in `(0, MAX_LAMBDA]` (an infinite λ makes the primal step ∞/∞ = NaN: issue 36
    /// found `--lambda inf` committing a pass whose mesh was empty).
    pub fn validate(&self) -> crate::Result<()> {
        let ok = self.lambda > 0.0
            && self.lambda <= MAX_LAMBDA
            && self.sigma > 0.0
            && self.tau > 0.0
            && (0.0..=1.0).contains(&self.theta)
            && self.sigma * self.tau * 12.0 <= 1.0 + 1e-6;
        if ok {
            Ok(())
        } else {
            Err(crate::Error::InvalidArgument(format!(
                "TV parameters need 0 < λ ≤ {MAX_LAMBDA:e}, σ, τ > 0, θ ∈ [0, 1] and σ·τ·12 ≤ 1; got {self:?}"
            )))
        }
    }
}

const NONE: u32 = u32::MAX;
/// Blocks per rayon task of [`TvProblem::iterate`] (a block's step takes ~1 µs).
const BLOCKS_PER_TASK: usize = 16;
const STRIDE: [usize; 3] = [1, VOXELS_PER_SIDE, VOXELS_PER_SIDE * VOXELS_PER_SIDE];
const OMEGA: u8 = 1 << 6;
/// Mask bit: the forward link along axis `d` (x and x + e_d both in Ω).
const fn fwd(d: usize) -> u8 {
    1 << d
}
/// Mask bit: the backward link along axis `d` (x − e_d and x both in Ω).
const fn bwd(d: usize) -> u8 {
    1 << (3 + d)
}

/// Blocks gathered into flat arrays for the solver. Voxel `i` of block slot `b` is at `b·512 + i`.
#[derive(Clone, Debug)]
pub struct TvProblem {
    blocks: Vec<BlockIndex>,
    /// Neighbour slot per block and direction (+x, −x, +y, −y, +z, −z), or `NONE`.
    neighbors: Vec<[u32; 6]>,
    /// Raw TSDF f.
    pub f: Vec<f32>,
    /// Data weight w.
    pub w: Vec<f32>,
    /// Ω and link bits per voxel.
    mask: Vec<u8>,
    /// Primal variable u.
    pub u: Vec<f32>,
    ubar: Vec<f32>,
    /// Dual variable, structure of arrays: `p_x` of every voxel, then `p_y`, then `p_z`.
    p: Vec<f32>,
    /// Per block, the iterations left during which it is updated (`None`: every iteration);
    /// see [`TvProblem::limit_updates`].
    horizon: Option<Vec<u32>>,
    /// Whether `ū` still equals `f` and `p` is zero (a problem gathered, not yet iterated): a
    /// GPU solver then makes them on the device instead of uploading them.
    iterates_fresh: bool,
    /// Whether the caller reads `ū` and `p` after a solve (a swept pass stores them); when not,
    /// a GPU solver reads back `u` alone and releases the iterates.
    keep_iterates: bool,
}

impl TvProblem {
    /// The Ω bit of [`TvProblem::masks`].
    pub const OMEGA_BIT: u8 = OMEGA;

    /// Gathers `blocks` (any order; sorted internally) from `layer`. Blocks not allocated are
    /// skipped. Voxels in blocks outside the set count as outside Ω.
    pub fn gather(layer: &Layer, blocks: &[BlockIndex]) -> Self {
        let mut list: Vec<BlockIndex> = blocks
            .iter()
            .copied()
            .filter(|b| layer.contains(b))
            .collect();
        list.sort_unstable();
        list.dedup();
        let n = list.len() * VOXELS_PER_BLOCK;
        let mut f = vec![0.0f32; n];
        let mut w = vec![0.0f32; n];
        let mut omega = vec![false; n];
        f.par_chunks_mut(VOXELS_PER_BLOCK)
            .zip(w.par_chunks_mut(VOXELS_PER_BLOCK))
            .zip(omega.par_chunks_mut(VOXELS_PER_BLOCK))
            .zip(list.par_iter())
            .for_each(|(((f, w), om), index)| {
                if let Some(block) = layer.get(index) {
                    for i in 0..VOXELS_PER_BLOCK {
                        f[i] = decode_tsdf(block.tsdf[i]);
                        w[i] = block.weight(i) as f32;
                        om[i] = block.omega(i);
                    }
                }
            });
        Self::from_arrays(list, f, w, omega)
    }

    /// Builds a problem from flat arrays over `blocks` (sorted, unique): `f`, `w` and Ω per voxel.
    pub fn from_arrays(
        blocks: Vec<BlockIndex>,
        f: Vec<f32>,
        w: Vec<f32>,
        omega: Vec<bool>,
    ) -> Self {
        let n = blocks.len() * VOXELS_PER_BLOCK;
        let (u, ubar) = (f.clone(), f.clone());
        let mut problem = Self::from_state(blocks, [f, w, u, ubar], omega, vec![0.0; 3 * n]);
        problem.iterates_fresh = true;
        problem.keep_iterates = false;
        problem
    }

    /// A problem over `blocks` (sorted, no duplicates) starting from a solver state: `[f, w, u,
    /// ū]` and `omega` of `blocks.len() × 512` voxels each, `p` as three such planes (x, y, z).
    /// What a swept pass builds from the state it stored after the previous sweep; its iterates
    /// are kept after a solve ([`TvProblem::keeps_iterates`]).
    pub fn from_state(
        blocks: Vec<BlockIndex>,
        fields: [Vec<f32>; 4],
        omega: Vec<bool>,
        p: Vec<f32>,
    ) -> Self {
        let n = blocks.len() * VOXELS_PER_BLOCK;
        let [f, w, u, ubar] = fields;
        assert!(
            [f.len(), w.len(), u.len(), ubar.len(), omega.len()]
                .iter()
                .all(|l| *l == n)
                && p.len() == 3 * n,
            "array sizes must be blocks × 512 (p: three times that)"
        );
        let slot: HashMap<BlockIndex, u32> = blocks
            .iter()
            .enumerate()
            .map(|(k, b)| (*b, k as u32))
            .collect();
        let neighbors: Vec<[u32; 6]> = blocks
            .par_iter()
            .map(|b| {
                let mut nb = [NONE; 6];
                for d in 0..3 {
                    let mut off = [0i32; 3];
                    off[d] = 1;
                    nb[2 * d] = *slot.get(&b.offset(off)).unwrap_or(&NONE);
                    off[d] = -1;
                    nb[2 * d + 1] = *slot.get(&b.offset(off)).unwrap_or(&NONE);
                }
                nb
            })
            .collect();
        let mask = sweep::link_masks(&neighbors, &omega);
        TvProblem {
            blocks,
            neighbors,
            u,
            ubar,
            f,
            w,
            mask,
            p,
            horizon: None,
            iterates_fresh: false,
            keep_iterates: true,
        }
    }

    /// Whether `ū` and `p` are still the starting ones (`ū = f`, `p = 0`): true for a gathered
    /// problem until it is iterated or its state is taken mutably.
    pub fn iterates_fresh(&self) -> bool {
        self.iterates_fresh
    }

    /// Whether a solve must leave `ū` and `p` readable (see [`TvProblem::set_keep_iterates`]).
    pub fn keeps_iterates(&self) -> bool {
        self.keep_iterates
    }

    /// Says whether the caller reads `ū` and `p` after a solve (the default: not for a gathered
    /// problem, yes for one built [`TvProblem::from_state`]). When not, a GPU solver reads
    /// back `u` alone and releases them ([`TvProblem::release_iterates`]).
    pub fn set_keep_iterates(&mut self, keep: bool) {
        self.keep_iterates = keep;
    }

    /// Updates block `b` during the next `horizon[b]` iterations only, leaving it as it is
    /// after. For a region's halo: a block `8k + 1` voxels or more from the voxels whose result
    /// is kept influences them only through its first `K − 8k` iterations of `K` (one iteration
    /// moves information one voxel), so those past are work without effect. A GPU solver may
    /// ignore this (the kept voxels are the same either way).
    pub fn limit_updates(&mut self, horizon: Vec<u32>) {
        assert_eq!(horizon.len(), self.blocks.len(), "one horizon per block");
        self.horizon = Some(horizon);
    }

    /// The blocks of the problem, sorted.
    pub fn blocks(&self) -> &[BlockIndex] {
        &self.blocks
    }

    /// Neighbour slot per block and direction (+x, −x, +y, −y, +z, −z), `u32::MAX` when the
    /// neighbour is not in the problem: the table a GPU twin uploads (`src/gpu/tv.rs`).
    pub fn neighbor_table(&self) -> &[[u32; 6]] {
        &self.neighbors
    }

    /// Ω and link bits per voxel: bit `d` = forward link along axis `d` (x and x + e_d in Ω),
    /// bit `3 + d` = backward link, bit 6 = Ω.
    pub fn masks(&self) -> &[u8] {
        &self.mask
    }

    /// The solver state `(u, ū, p)`; `p` as three planes (`p_x` of every voxel, then `p_y`,
    /// then `p_z`: `p[d·n + g]` for `n` voxels).
    pub fn state(&self) -> (&[f32], &[f32], &[f32]) {
        (&self.u, &self.ubar, &self.p)
    }

    /// The solver state, mutably (a GPU twin writes its result back here).
    pub fn state_mut(&mut self) -> (&mut [f32], &mut [f32], &mut [f32]) {
        self.iterates_fresh = false;
        (&mut self.u, &mut self.ubar, &mut self.p)
    }

    /// Number of voxels in Ω.
    pub fn omega_count(&self) -> usize {
        self.mask.iter().filter(|&&m| m & OMEGA != 0).count()
    }

    /// Whether voxel `g` is in Ω.
    pub fn in_omega(&self, g: usize) -> bool {
        self.mask[g] & OMEGA != 0
    }

    /// The flat index of the neighbour `x + e_d` of voxel `g`, if its block is in the problem.
    #[inline]
    fn forward(&self, g: usize, d: usize) -> Option<usize> {
        let (b, i) = (g / VOXELS_PER_BLOCK, g % VOXELS_PER_BLOCK);
        let c = (i / STRIDE[d]) % VOXELS_PER_SIDE;
        if c + 1 < VOXELS_PER_SIDE {
            Some(g + STRIDE[d])
        } else {
            let nb = self.neighbors[b][2 * d];
            (nb != NONE)
                .then(|| nb as usize * VOXELS_PER_BLOCK + i - (VOXELS_PER_SIDE - 1) * STRIDE[d])
        }
    }

    /// The flat index of the neighbour `x − e_d` of voxel `g`, if its block is in the problem.
    #[inline]
    fn backward(&self, g: usize, d: usize) -> Option<usize> {
        let (b, i) = (g / VOXELS_PER_BLOCK, g % VOXELS_PER_BLOCK);
        let c = (i / STRIDE[d]) % VOXELS_PER_SIDE;
        if c > 0 {
            Some(g - STRIDE[d])
        } else {
            let nb = self.neighbors[b][2 * d + 1];
            (nb != NONE)
                .then(|| nb as usize * VOXELS_PER_BLOCK + i + (VOXELS_PER_SIDE - 1) * STRIDE[d])
        }
    }

    /// The Ω-aware forward-difference gradient of `v` at voxel `g`.
    #[inline]
    pub fn gradient_at(&self, v: &[f32], g: usize) -> [f32; 3] {
        let m = self.mask[g];
        let mut out = [0.0; 3];
        for (d, o) in out.iter_mut().enumerate() {
            if m & fwd(d) != 0 {
                if let Some(h) = self.forward(g, d) {
                    *o = v[h] - v[g];
                }
            }
        }
        out
    }

    /// The divergence `−∇ᵀ p` at voxel `g`, `p` as three planes (`p[d·n + g]`, as
    /// [`TvProblem::state`]).
    #[inline]
    pub fn divergence_at(&self, p: &[f32], g: usize) -> f32 {
        let n = self.mask.len();
        let m = self.mask[g];
        let mut div = 0.0;
        for d in 0..3 {
            if m & fwd(d) != 0 {
                div += p[d * n + g];
            }
            if m & bwd(d) != 0 {
                if let Some(h) = self.backward(g, d) {
                    div -= p[d * n + h];
                }
            }
        }
        div
    }

    /// Runs `params.iterations` primal–dual iterations.
    pub fn solve(&mut self, params: &TvParams) {
        // On a worker of rayon's pool, so that each iteration's parallel loops start there
        // instead of waking the pool from outside (a futex round trip per loop, which costs more
        // than a small region's loop itself).
        rayon::scope(|_| {
            for _ in 0..params.iterations {
                self.iterate(params);
            }
        });
    }

    /// One primal–dual iteration (dual step, primal step, relaxation), parallel over blocks.
    /// Per voxel the arithmetic of [`TvProblem::iterate_reference`], bit for bit; the loops are
    /// those of `sweep.rs` (block-sized arrays, selects instead of branches, vectorised).
    pub fn iterate(&mut self, params: &TvParams) {
        self.iterates_fresh = false;
        let n = self.u.len();
        if n == 0 {
            return;
        }
        assert_eq!(self.p.len(), 3 * n, "iterated after release_iterates");
        let vb = VOXELS_PER_BLOCK;
        let (mask, neighbors) = (&self.mask, &self.neighbors);
        let horizon = self.horizon.as_deref();
        let live = |b: usize| horizon.is_none_or(|h| h[b] > 0);
        // Dual step: reads ū everywhere, writes p of its own block.
        let ubar = &self.ubar;
        let (px, rest) = self.p.split_at_mut(n);
        let (py, pz) = rest.split_at_mut(n);
        px.par_chunks_mut(vb)
            .zip(py.par_chunks_mut(vb))
            .zip(pz.par_chunks_mut(vb))
            .with_min_len(BLOCKS_PER_TASK)
            .enumerate()
            .filter(|(b, _)| live(*b))
            .for_each(|(b, ((x, y), z))| {
                sweep::dual_block(
                    ubar,
                    b,
                    &neighbors[b],
                    &mask[b * vb..(b + 1) * vb],
                    [x, y, z],
                    params.sigma,
                )
            });
        // Primal step and relaxation: reads p everywhere, writes u and ū of its own block.
        let p = [&self.p[..n], &self.p[n..2 * n], &self.p[2 * n..]];
        let (f, w) = (&self.f, &self.w);
        let k = sweep::PrimalConstants {
            tau: params.tau,
            lambda: params.lambda,
            theta: params.theta,
        };
        self.u
            .par_chunks_mut(vb)
            .zip(self.ubar.par_chunks_mut(vb))
            .with_min_len(BLOCKS_PER_TASK)
            .enumerate()
            .filter(|(b, _)| live(*b))
            .for_each(|(b, (u, ubar))| {
                let r = b * vb..(b + 1) * vb;
                sweep::primal_block(
                    p,
                    b,
                    &neighbors[b],
                    &mask[r.clone()],
                    &f[r.clone()],
                    &w[r],
                    u,
                    ubar,
                    k,
                )
            });
        if let Some(h) = &mut self.horizon {
            h.iter_mut().for_each(|h| *h = h.saturating_sub(1));
        }
    }

    /// One iteration written voxel by voxel with [`TvProblem::gradient_at`] and
    /// [`TvProblem::divergence_at`] (the solver before issue 14, parallel over blocks): the
    /// reference [`TvProblem::iterate`] is tested against bit for bit, the form the GPU kernels
    /// follow, and the "before" of `cargo bench --bench core -- tv_`.
    pub fn iterate_reference(&mut self, params: &TvParams) {
        self.iterates_fresh = false;
        let n = self.u.len();
        let vb = VOXELS_PER_BLOCK;
        let sigma = params.sigma;
        let (tau, lambda, theta) = (params.tau, params.lambda, params.theta);
        let mut p = std::mem::take(&mut self.p);
        {
            let (px, rest) = p.split_at_mut(n);
            let (py, pz) = rest.split_at_mut(n);
            let this = &*self;
            px.par_chunks_mut(vb)
                .zip(py.par_chunks_mut(vb))
                .zip(pz.par_chunks_mut(vb))
                .enumerate()
                .for_each(|(b, ((x, y), z))| {
                    for i in 0..vb {
                        let g = b * vb + i;
                        if this.mask[g] & OMEGA == 0 {
                            continue;
                        }
                        let grad = this.gradient_at(&this.ubar, g);
                        let q = [
                            x[i] + sigma * grad[0],
                            y[i] + sigma * grad[1],
                            z[i] + sigma * grad[2],
                        ];
                        let scale = 1.0 / (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt().max(1.0);
                        (x[i], y[i], z[i]) = (q[0] * scale, q[1] * scale, q[2] * scale);
                    }
                });
        }
        self.p = p;
        let mut u = std::mem::take(&mut self.u);
        let mut ubar = std::mem::take(&mut self.ubar);
        u.par_chunks_mut(vb)
            .zip(ubar.par_chunks_mut(vb))
            .enumerate()
            .for_each(|(b, (ub, ubarb))| {
                for i in 0..vb {
                    let g = b * vb + i;
                    if self.mask[g] & OMEGA == 0 {
                        continue;
                    }
                    let div = self.divergence_at(&self.p, g);
                    let tlw = tau * lambda * self.w[g];
                    let old = ub[i];
                    let new = (old + tau * div + tlw * self.f[g]) / (1.0 + tlw);
                    ub[i] = new;
                    ubarb[i] = new + theta * (new - old);
                }
            });
        self.u = u;
        self.ubar = ubar;
    }

    /// The energy `Σ_Ω |∇u| + (λ/2) Σ_Ω w (u − f)²` of the current `u`.
    pub fn energy(&self, lambda: f32) -> f64 {
        // Per-block partial sums in parallel, added in block order: the same bits whatever the
        // thread count or scheduling (a plain parallel sum is not).
        let partial: Vec<f64> = (0..self.u.len() / VOXELS_PER_BLOCK)
            .into_par_iter()
            .map(|b| {
                (b * VOXELS_PER_BLOCK..(b + 1) * VOXELS_PER_BLOCK)
                    .filter(|&g| self.mask[g] & OMEGA != 0)
                    .map(|g| {
                        let gr = self.gradient_at(&self.u, g);
                        let tv = ((gr[0] * gr[0] + gr[1] * gr[1] + gr[2] * gr[2]) as f64).sqrt();
                        let r = (self.u[g] - self.f[g]) as f64;
                        tv + 0.5 * lambda as f64 * self.w[g] as f64 * r * r
                    })
                    .sum::<f64>()
            })
            .collect();
        partial.iter().sum()
    }

    /// Frees the iterates that only the solver needs (ū and the dual p), keeping `u`, `f`, `w`
    /// and Ω: what [`TvProblem::scatter`] and [`TvProblem::energy`] read. Call it when done: the
    /// problem cannot be iterated afterwards.
    pub fn release_iterates(&mut self) {
        self.iterates_fresh = false;
        self.ubar = Vec::new();
        self.p = Vec::new();
    }

    /// Writes `u` into the `regularized` field of the given blocks of `layer` (voxels outside Ω
    /// keep their raw value). Blocks not in the problem or not in `layer` are skipped.
    pub fn scatter(&self, layer: &mut Layer, blocks: &[BlockIndex]) {
        for index in blocks {
            let Ok(slot) = self.blocks.binary_search(index) else {
                continue;
            };
            let Some(block) = layer.get_mut(index) else {
                continue;
            };
            let base = slot * VOXELS_PER_BLOCK;
            let mut out = Box::new(block.tsdf);
            for (i, o) in out.iter_mut().enumerate() {
                if self.mask[base + i] & OMEGA != 0 {
                    *o = encode_tsdf(self.u[base + i]);
                }
            }
            block.regularized = Some(out);
        }
    }
}

/// Work counters of a regularization run.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RegularizeStats {
    /// Blocks solved.
    pub blocks: usize,
    /// Voxels in Ω.
    pub omega_voxels: usize,
    /// Iterations run.
    pub iterations: u32,
    /// Energy before and after the iterations, when computed (a solve where the blocks are, on
    /// a GPU tier, does not gather the problem on the host to compute it).
    pub energy: Option<(f64, f64)>,
}

/// Regularizes every block of `layer` in one global solve and stores `u` in each block's
/// `regularized` field. Returns the touched blocks (sorted) and counters.
pub fn regularize_layer(
    layer: &mut Layer,
    params: &TvParams,
) -> crate::Result<(TouchedBlocks, RegularizeStats)> {
    regularize_layer_with(layer, params, |problem| {
        problem.solve(params);
        Ok(())
    })
}

/// [`regularize_layer`] with the solver supplied (the CPU's [`TvProblem::solve`], or a GPU twin):
/// gathers every block, calls `solve`, and scatters `u` only when it succeeded (the layer is
/// unchanged on error).
pub fn regularize_layer_with(
    layer: &mut Layer,
    params: &TvParams,
    solve: impl FnOnce(&mut TvProblem) -> crate::Result<()>,
) -> crate::Result<(TouchedBlocks, RegularizeStats)> {
    params.validate()?;
    let blocks = layer.indices_sorted();
    let resident_mib = || crate::memory::rss_bytes().unwrap_or(0) as f64 / (1 << 20) as f64;
    tracing::debug!(resident_mib = resident_mib(), "regularization: gathering");
    let mut problem = TvProblem::gather(layer, &blocks);
    tracing::debug!(
        resident_mib = resident_mib(),
        voxels = problem.u.len(),
        "regularization: gathered"
    );
    let energy_before = problem.energy(params.lambda);
    solve(&mut problem)?;
    tracing::debug!(resident_mib = resident_mib(), "regularization: solved");
    let energy_after = problem.energy(params.lambda);
    // ū and p (16 of the solver's 29 bytes per voxel) are not needed to write u back: freed
    // first, the blocks' new `regularized` arrays do not add to them.
    problem.release_iterates();
    problem.scatter(layer, &blocks);
    let stats = RegularizeStats {
        blocks: blocks.len(),
        omega_voxels: problem.omega_count(),
        iterations: params.iterations,
        energy: Some((energy_before, energy_after)),
    };
    Ok((blocks, stats))
}

mod gpu;
mod regions;
mod resident;
mod solver;
mod sweep;
#[cfg(test)]
mod tests;

pub(crate) use gpu::solve_gpu_kept;
pub use gpu::{regularize_layer_gpu, regularize_regions_gpu, solve_gpu, GpuSolver};
pub use regions::{regularize_regions, regularize_regions_with, RegionPlan, RegionStats};
pub use resident::regularize_resident;
pub use solver::{regularize_layer_by, CpuSolver, TvSolver, FALLBACK_REGION_BLOCKS};
