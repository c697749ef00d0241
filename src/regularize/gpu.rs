//! The Ω-aware TV primal–dual (DENSER Sec. III-C) on the GPU: `shaders/tv_dual.wgsl` and
//! `shaders/tv_primal.wgsl` run over the flat arrays and neighbour table of a [`TvProblem`]
//! (the CPU twin, `src/regularize/`), with the same data layout (masks widened to `u32`, `p` as
//! three `f32` per voxel) and the same f32 arithmetic in the same order.
//!
//! Differences from the CPU come only from floating point: WGSL allows FMA contraction and
//! division within 2.5 ULP, so results agree to about 1e-6 per iteration, not bit for bit
//! (`tests/gpu_compare.rs` states the tolerance). The whole problem must fit one storage binding
//! per array (`p` is the largest: 12 bytes per voxel, about 11 M voxels or 21 845 blocks in
//! 128 MiB); a larger problem is an [`crate::Error::GpuCapacity`], never truncated — solve it
//! in regions with [`regularize_regions_gpu`] and an exact halo instead (the same result).

use crate::gpu::kept::Kept;
use crate::gpu::layout::TvUniforms;
use crate::gpu::shaders;
use crate::gpu::{ErrorScopes, GpuContext, Kernel};
use crate::grid::{Layer, TouchedBlocks};
use crate::regularize::{
    regularize_regions_with, RegionPlan, RegionStats, RegularizeStats, TvParams, TvProblem,
    TvSolver,
};
use crate::Result;
use rayon::prelude::*;

/// Iterations recorded per command buffer (bounds the size of one submission).
const ITERATIONS_PER_SUBMIT: u32 = 64;

/// Runs `params.iterations` primal–dual iterations of `problem` on the GPU, chained in as few
/// submits as [`ITERATIONS_PER_SUBMIT`] allows, and reads the result back: `u` alone when the
/// caller does not keep the iterates ([`TvProblem::keeps_iterates`]; `ū` and `p` are then
/// released), else `u`, `ū` and `p`, so that the problem can continue on either device.
///
/// What crosses the bus: `f`, `w`, `u`, the link masks and the neighbour table go up (40 bytes
/// per voxel); `ū` and `p` too unless the problem is fresh ([`TvProblem::iterates_fresh`]:
/// then `ū` is copied from `f` on the device and `p` starts as zeros there). Down: 4 bytes per
/// voxel, or 20 with the iterates kept.
pub fn solve_gpu(ctx: &GpuContext, problem: &mut TvProblem, params: &TvParams) -> Result<()> {
    solve_gpu_kept(ctx, &mut Kept::default(), problem, params)
}

/// [`solve_gpu`] with its buffers, bind groups and readback staging kept in `kept` between
/// calls (grown to the largest problem, never shrunk): a driver that solves region after region
/// creates nothing once the first regions have sized them. The last iterations are submitted
/// with the copy of the result into the staging buffer.
pub(crate) fn solve_gpu_kept(
    ctx: &GpuContext,
    kept: &mut Kept,
    problem: &mut TvProblem,
    params: &TvParams,
) -> Result<()> {
    params.validate()?;
    let n = problem.masks().len();
    if n == 0 || params.iterations == 0 {
        return Ok(());
    }
    let n64 = n as u64;
    ctx.check_binding("TV dual variable p (12 bytes per voxel)", n64 * 12)?;
    ctx.check_binding("TV arrays (4 bytes per voxel)", n64 * 4)?;
    let dual = ctx.kernel(&shaders::TV_DUAL)?;
    let primal = ctx.kernel(&shaders::TV_PRIMAL)?;
    let mask: Vec<u32> = problem.masks().par_iter().map(|&m| m as u32).collect();
    let uniforms = TvUniforms {
        sigma: params.sigma,
        tau: params.tau,
        lambda: params.lambda,
        theta: params.theta,
        voxel_count: n as u32,
        pad: [0; 3],
    };
    let fresh = problem.iterates_fresh();
    let scope = ErrorScopes::push(&ctx.device);
    let (u, ubar, p) = problem.state();
    let buf_uniforms = kept.uniform_with(ctx, "tv_uniforms", bytemuck::bytes_of(&uniforms));
    // The table as it is (six u32 per voxel), not flattened into a copy.
    let table = bytemuck::cast_slice(problem.neighbor_table());
    let buf_neighbors = kept.storage_with(ctx, "tv_neighbors", table);
    let buf_mask = kept.storage_with(ctx, "tv_mask", bytemuck::cast_slice(&mask));
    let buf_f = kept.storage_with(ctx, "tv_f", bytemuck::cast_slice(&problem.f));
    let buf_w = kept.storage_with(ctx, "tv_w", bytemuck::cast_slice(&problem.w));
    let buf_u = kept.storage_with(ctx, "tv_u", bytemuck::cast_slice(u));
    let mut encoder = ctx.encoder("tv");
    let (buf_ubar, buf_p) = if fresh {
        // ū = f and p = 0: made where they are used.
        let ubar = kept.scratch(ctx, "tv_ubar", n64 * 4);
        encoder.copy_buffer_to_buffer(&buf_f, 0, &ubar, 0, n64 * 4);
        let p = kept.scratch(ctx, "tv_p", n64 * 12);
        encoder.clear_buffer(&p, 0, Some(n64 * 12));
        (ubar, p)
    } else {
        (
            kept.storage_with(ctx, "tv_ubar", bytemuck::cast_slice(ubar)),
            kept.storage_with(ctx, "tv_p", bytemuck::cast_slice(p)),
        )
    };
    let buffers = TvBuffers {
        uniforms: &buf_uniforms,
        neighbors: &buf_neighbors,
        mask: &buf_mask,
        f: &buf_f,
        w: &buf_w,
        u: &buf_u,
        ubar: &buf_ubar,
        p: &buf_p,
    }
    .bindings();
    // The two kernels declare the same bindings (shared/tv_common.wgsl); each pipeline has its
    // own layout object: one bind group per kernel.
    let bind_dual = kept.bind_group(ctx, "tv_dual", &dual.layout, &buffers);
    let bind_primal = kept.bind_group(ctx, "tv_primal", &primal.layout, &buffers);
    let mut left = params.iterations;
    loop {
        let batch = left.min(ITERATIONS_PER_SUBMIT);
        left -= batch;
        let steps = [(&*dual, &bind_dual), (&*primal, &bind_primal)];
        record_iterations(ctx, &mut encoder, steps, n64, batch)?;
        if left == 0 {
            break;
        }
        ctx.submit(encoder);
        encoder = ctx.encoder("tv");
    }
    // Straight into the problem's arrays (one copy, no intermediate vectors).
    let read = if problem.keeps_iterates() {
        let (u, ubar, p) = problem.state_mut();
        ctx.submit_and_read_back(
            encoder,
            kept,
            &mut [
                (&buf_u, bytemuck::cast_slice_mut(u)),
                (&buf_ubar, bytemuck::cast_slice_mut(ubar)),
                (&buf_p, bytemuck::cast_slice_mut(p)),
            ],
        )
    } else {
        // The iterates on the host are stale from here: released, so nothing can read them.
        problem.release_iterates();
        let u = bytemuck::cast_slice_mut(&mut problem.u);
        ctx.submit_and_read_back(encoder, kept, &mut [(&buf_u, u)])
    };
    scope.pop("running the TV kernels")?;
    read
}

/// The buffers `tv_dual.wgsl` and `tv_primal.wgsl` bind (`shared/tv_common.wgsl`).
pub(super) struct TvBuffers<'a> {
    pub uniforms: &'a wgpu::Buffer,
    pub neighbors: &'a wgpu::Buffer,
    pub mask: &'a wgpu::Buffer,
    pub f: &'a wgpu::Buffer,
    pub w: &'a wgpu::Buffer,
    pub u: &'a wgpu::Buffer,
    pub ubar: &'a wgpu::Buffer,
    pub p: &'a wgpu::Buffer,
}

impl<'a> TvBuffers<'a> {
    /// In binding order.
    pub(super) fn bindings(&self) -> [&'a wgpu::Buffer; 8] {
        let b = self;
        [b.uniforms, b.neighbors, b.mask, b.f, b.w, b.u, b.ubar, b.p]
    }
}

/// Records `iterations` primal–dual iterations over `voxels` into `encoder`: the dual step,
/// then the primal step, each its own pass (a pass boundary orders the dual writes before the
/// primal reads). `steps`: the two kernels with their bind groups.
pub(super) fn record_iterations(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    steps: [(&Kernel, &wgpu::BindGroup); 2],
    voxels: u64,
    iterations: u32,
) -> Result<()> {
    let [(dual, bind_dual), (primal, bind_primal)] = steps;
    for _ in 0..iterations {
        ctx.record_dispatch(encoder, dual, bind_dual, voxels)?;
        ctx.record_dispatch(encoder, primal, bind_primal, voxels)?;
    }
    Ok(())
}

/// [`crate::regularize::regularize_layer`] on the GPU: one global solve of every block of
/// `layer`, `u` stored in each block's `regularized` field. Energies are computed on the CPU.
/// Returns the touched blocks (sorted) and counters; the layer is unchanged on error.
pub fn regularize_layer_gpu(
    ctx: &GpuContext,
    layer: &mut Layer,
    params: &TvParams,
) -> Result<(TouchedBlocks, RegularizeStats)> {
    crate::regularize::regularize_layer_with(layer, params, |problem| {
        solve_gpu(ctx, problem, params)
    })
}

/// [`crate::regularize::regularize_regions`] on the GPU: each region (with its halo) is one GPU
/// solve, so maps larger than one storage binding can be regularized; with
/// [`RegionPlan::exact`] the result equals the global solve. A region whose gathered blocks do
/// not fit is an [`crate::Error::GpuCapacity`] (regions written before it keep their result).
pub fn regularize_regions_gpu(
    ctx: &GpuContext,
    layer: &mut Layer,
    params: &TvParams,
    plan: &RegionPlan,
) -> Result<(TouchedBlocks, RegionStats)> {
    regularize_regions_with(layer, params, plan, |problem| {
        solve_gpu(ctx, problem, params)
    })
}

/// [`solve_gpu`] as a [`TvSolver`]: problems up to one storage binding of `p` (12 bytes per
/// voxel); a larger one is an [`crate::Error::GpuCapacity`] (drivers split before that, see
/// [`TvSolver::max_voxels`]).
#[derive(Clone, Copy, Debug)]
pub struct GpuSolver<'c> {
    /// The device.
    pub ctx: &'c GpuContext,
}

impl TvSolver for GpuSolver<'_> {
    fn solve(&mut self, problem: &mut TvProblem, params: &TvParams) -> Result<()> {
        solve_gpu(self.ctx, problem, params)
    }

    fn max_voxels(&self) -> Option<usize> {
        Some((self.ctx.max_binding_bytes() / 12) as usize)
    }

    fn prefers_whole_solves(&self) -> bool {
        true
    }
}
