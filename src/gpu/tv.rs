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

use super::context::{ErrorScopes, GpuContext};
use super::layout::TvUniforms;
use crate::grid::{Layer, TouchedBlocks};
use crate::regularize::{
    regularize_regions_with, RegionPlan, RegionStats, RegularizeStats, TvParams, TvProblem,
};
use crate::Result;

/// Iterations recorded per command buffer (bounds the size of one submission).
const ITERATIONS_PER_SUBMIT: u32 = 64;

/// Runs `params.iterations` primal–dual iterations of `problem` on the GPU and writes the state
/// (`u`, `ū`, `p`) back, so that the problem can continue on either device.
pub fn solve_gpu(ctx: &GpuContext, problem: &mut TvProblem, params: &TvParams) -> Result<()> {
    params.validate()?;
    let n = problem.masks().len();
    if n == 0 || params.iterations == 0 {
        return Ok(());
    }
    let n64 = n as u64;
    ctx.check_binding("TV dual variable p (12 bytes per voxel)", n64 * 12)?;
    ctx.check_binding("TV arrays (4 bytes per voxel)", n64 * 4)?;
    let (wx, wy) = ctx.workgroups_2d(n64)?;
    let neighbors: Vec<u32> = problem.neighbor_table().iter().flatten().copied().collect();
    let mask: Vec<u32> = problem.masks().iter().map(|&m| m as u32).collect();
    let uniforms = TvUniforms {
        sigma: params.sigma,
        tau: params.tau,
        lambda: params.lambda,
        theta: params.theta,
        voxel_count: n as u32,
        pad: [0; 3],
    };
    let scope = ErrorScopes::push(&ctx.device);
    let (u, ubar, p) = problem.state();
    let buf_uniforms = ctx.uniform("tv_uniforms", bytemuck::bytes_of(&uniforms));
    let buf_neighbors = ctx.storage("tv_neighbors", bytemuck::cast_slice(&neighbors));
    let buf_mask = ctx.storage("tv_mask", bytemuck::cast_slice(&mask));
    let buf_f = ctx.storage("tv_f", bytemuck::cast_slice(&problem.f));
    let buf_w = ctx.storage("tv_w", bytemuck::cast_slice(&problem.w));
    let buf_u = ctx.storage("tv_u", bytemuck::cast_slice(u));
    let buf_ubar = ctx.storage("tv_ubar", bytemuck::cast_slice(ubar));
    let buf_p = ctx.storage("tv_p", bytemuck::cast_slice(p));
    let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("tv"),
        layout: &ctx.tv_layout,
        entries: &[
            (0, &buf_uniforms),
            (1, &buf_neighbors),
            (2, &buf_mask),
            (3, &buf_f),
            (4, &buf_w),
            (5, &buf_u),
            (6, &buf_ubar),
            (7, &buf_p),
        ]
        .map(|(binding, b)| wgpu::BindGroupEntry {
            binding,
            resource: b.as_entire_binding(),
        }),
    });
    let mut left = params.iterations;
    while left > 0 {
        let batch = left.min(ITERATIONS_PER_SUBMIT);
        left -= batch;
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("tv") });
        for _ in 0..batch {
            // One pass per step: a pass boundary orders the dual writes before the primal reads.
            for pipeline in [&ctx.tv_dual, &ctx.tv_primal] {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("tv"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(pipeline);
                pass.set_bind_group(0, &bind, &[]);
                pass.dispatch_workgroups(wx, wy, 1);
            }
        }
        ctx.queue.submit([encoder.finish()]);
    }
    scope.pop("running the TV kernels")?;
    let out = ctx.read_back(&[(&buf_u, n64 * 4), (&buf_ubar, n64 * 4), (&buf_p, n64 * 12)])?;
    let (u, ubar, p) = problem.state_mut();
    // Staging bytes carry no alignment guarantee: copy into typed vectors.
    u.copy_from_slice(&bytemuck::pod_collect_to_vec::<u8, f32>(&out[0]));
    ubar.copy_from_slice(&bytemuck::pod_collect_to_vec::<u8, f32>(&out[1]));
    p.copy_from_slice(&bytemuck::pod_collect_to_vec::<u8, [f32; 3]>(&out[2]));
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
/// solve, so maps larger than one storage binding can be regularised; with
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
