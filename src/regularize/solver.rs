//! The solver seam ([`TvSolver`]: the CPU, a GPU twin, or the backend's policy) and the driver
//! that regularizes a whole layer with one ([`regularize_layer_by`]).

use super::{
    regularize_layer_with, regularize_regions_with, RegionPlan, RegularizeStats, TvParams,
    TvProblem,
};
use crate::grid::{Layer, TouchedBlocks, VOXELS_PER_BLOCK};

/// Runs Chambolle–Pock iterations on a gathered [`TvProblem`]: the CPU ([`CpuSolver`]), a GPU
/// twin ([`GpuSolver`](super::GpuSolver)), or a device policy with fallbacks (`crate::backend::Backend`). Every
/// regularization driver (global, regional in RAM, regional over a stored map) takes one, so
/// the choice of device is made once, by the caller.
pub trait TvSolver {
    /// Runs `params.iterations` iterations from the problem's current state (`u`, `ū`, `p`).
    fn solve(&mut self, problem: &mut TvProblem, params: &TvParams) -> crate::Result<()>;

    /// The most voxels one [`TvSolver::solve`] takes in one piece (`None`: any number). A
    /// driver splits larger maps into regions with the exact halo (the same result).
    fn max_voxels(&self) -> Option<usize> {
        None
    }

    /// Whether splitting one solve into several calls costs this solver a round trip of the
    /// state between host and device (a GPU): callers that report progress then call it once.
    fn prefers_whole_solves(&self) -> bool {
        false
    }

    /// Regularizes the whole of `layer` where its blocks already are, when this solver holds
    /// them (a GPU tier: `src/regularize/resident.rs`), storing `u` as
    /// [`regularize_layer_with`] does. `Ok(None)` when it does not hold them: the caller then
    /// gathers the problem on the host.
    fn solve_in_place(
        &mut self,
        _layer: &mut Layer,
        _params: &TvParams,
    ) -> crate::Result<Option<(TouchedBlocks, RegularizeStats)>> {
        Ok(None)
    }
}

/// The reference solver: [`TvProblem::solve`] on the CPU (rayon).
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuSolver;

impl TvSolver for CpuSolver {
    fn solve(&mut self, problem: &mut TvProblem, params: &TvParams) -> crate::Result<()> {
        problem.solve(params);
        Ok(())
    }
}

/// Edge of the regions [`regularize_layer_by`] uses when a map exceeds the solver's
/// [`TvSolver::max_voxels`], blocks.
pub const FALLBACK_REGION_BLOCKS: i32 = 32;

/// Regularizes every block of `layer` with `solver`: one global solve when the map fits the
/// solver, else regions of [`FALLBACK_REGION_BLOCKS`]³ blocks with the exact halo (the same
/// result, so the choice is invisible in the output). Energies are those of the stored result.
pub fn regularize_layer_by(
    layer: &mut Layer,
    params: &TvParams,
    solver: &mut dyn TvSolver,
) -> crate::Result<(TouchedBlocks, RegularizeStats)> {
    params.validate()?;
    if let Some(done) = solver.solve_in_place(layer, params)? {
        return Ok(done);
    }
    let voxels = layer.block_count() * VOXELS_PER_BLOCK;
    if solver.max_voxels().is_none_or(|max| voxels <= max) {
        return regularize_layer_with(layer, params, |problem| solver.solve(problem, params));
    }
    let blocks = layer.indices_sorted();
    let mut problem = TvProblem::gather(layer, &blocks);
    let energy_before = problem.energy(params.lambda);
    tracing::info!(
        "regularization: {voxels} voxels exceed one solve's {} voxels; solving regions of {}³ \
         blocks with the exact halo",
        solver.max_voxels().unwrap_or(0),
        FALLBACK_REGION_BLOCKS
    );
    let plan = RegionPlan::exact(FALLBACK_REGION_BLOCKS, params.iterations);
    regularize_regions_with(layer, params, &plan, |p| solver.solve(p, params))?;
    // The energy of the stored result (quantised u), as the global path reports it.
    let (u, _, _) = problem.state_mut();
    for (k, index) in blocks.iter().enumerate() {
        if let Some(block) = layer.get(index) {
            for i in 0..VOXELS_PER_BLOCK {
                u[k * VOXELS_PER_BLOCK + i] = block.regularized_or_raw(i);
            }
        }
    }
    let stats = RegularizeStats {
        blocks: blocks.len(),
        omega_voxels: problem.omega_count(),
        iterations: params.iterations,
        energy: Some((energy_before, problem.energy(params.lambda))),
    };
    Ok((blocks, stats))
}
