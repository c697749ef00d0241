//! Projective depth-map fusion (DENSER Sec. III-A) on the GPU: `shaders/fuse_depth.wgsl` applies
//! the CPU's per-voxel update ([`crate::fusion::integrate_depth`] with `Block::fuse`) to a list
//! of blocks, one invocation per voxel. Block allocation stays on the CPU, as the CPU path's
//! phase 1: the same blocks ([`depth_frame_blocks`] plus [`visible_blocks`]) are checked out of
//! the layer, packed into [`GpuVoxel`]s, updated on the GPU, unpacked and checked back in.
//!
//! The kernel repeats the CPU's f32 arithmetic in the same order, with exact twins of its
//! rounding (`shaders/shared/rounding.wgsl`). Remaining differences come from WGSL's FMA
//! contraction and division precision: a voxel near a pixel border may project to the
//! neighbouring pixel, and a running average may land one quantisation step away
//! (`tests/gpu_compare.rs` states the tolerance). Blocks are sent in batches that fit one
//! storage binding (4 KiB per block: 32 768 blocks in 128 MiB), so any number of blocks works.

use super::context::{ErrorScopes, GpuContext, READ, READ_WRITE, UNIFORM};
use super::layout::{
    apply_updated, pack_block_into, pack_rgb, FuseUniforms, GpuVoxel, PIXEL_VALID,
};
use super::shaders;
use crate::frame::DepthFrame;
use crate::fusion::{depth_frame_blocks, usable, visible_blocks, DepthFusionParams, FusionStats};
use crate::grid::{Block, BlockIndex, GridParams, Layer, TouchedBlocks, VOXELS_PER_BLOCK};
use crate::Result;
use nalgebra::{Isometry3, Point3, Vector3};

/// Binding types of `shaders/fuse_depth.wgsl`, in binding order.
const FUSE_DEPTH_BINDINGS: [wgpu::BufferBindingType; 6] =
    [UNIFORM, READ, READ, READ, READ_WRITE, READ_WRITE];

/// Fuses one depth frame into `layer` on the GPU, like [`crate::fusion::integrate_depth`]: the
/// blocks crossed by this frame's truncation band plus the allocated blocks in view. Returns the
/// touched blocks (sorted) and work counters. On error the layer holds the blocks as before.
pub fn integrate_depth_gpu(
    ctx: &GpuContext,
    layer: &mut Layer,
    frame: &DepthFrame,
    params: &DepthFusionParams,
) -> Result<(TouchedBlocks, FusionStats)> {
    let grid = layer.params();
    let mut blocks = depth_frame_blocks(&grid, frame, params);
    blocks.extend(visible_blocks(layer, frame, params));
    blocks.sort_unstable();
    blocks.dedup();
    let existed: Vec<bool> = blocks.iter().map(|b| layer.contains(b)).collect();
    let mut taken = layer.take_blocks(&blocks);
    match fuse_blocks(ctx, &grid, &mut taken, frame, params) {
        Ok(updates) => {
            let touched = layer.put_blocks_observed(taken);
            let measurements = frame
                .depth_m
                .data
                .iter()
                .filter(|&&d| usable(d, params))
                .count();
            let stats = FusionStats {
                blocks: touched.len(),
                voxel_updates: updates,
                measurements,
            };
            Ok((touched, stats))
        }
        Err(e) => {
            // Blocks are only written after a successful readback: put back exactly what was
            // there, unchanged, and drop the blocks allocated for this frame.
            layer.put_blocks(
                taken
                    .into_iter()
                    .zip(existed)
                    .filter_map(|(b, was)| was.then_some(b)),
            );
            Err(e)
        }
    }
}

/// Runs the kernel over `blocks` in batches; returns the number of voxel updates.
fn fuse_blocks(
    ctx: &GpuContext,
    grid: &GridParams,
    blocks: &mut [(BlockIndex, Box<Block>)],
    frame: &DepthFrame,
    params: &DepthFusionParams,
) -> Result<usize> {
    if blocks.is_empty() {
        return Ok(0);
    }
    let (uniforms, camera_from_world) = frame_uniforms(grid, frame, params);
    let pixels = frame.depth_m.data.len() as u64;
    ctx.check_binding("depth image (4 bytes per pixel)", pixels * 4)?;
    let pixel_words = pixel_words(frame, params);
    let kernel = ctx.kernel(&shaders::FUSE_DEPTH, &FUSE_DEPTH_BINDINGS)?;
    let scope = ErrorScopes::push(&ctx.device);
    let buf_depth = ctx.storage("fuse_depth", bytemuck::cast_slice(&frame.depth_m.data));
    let buf_pixel = ctx.storage("fuse_pixel", bytemuck::cast_slice(&pixel_words));
    scope.pop("uploading the depth image")?;
    let block_bytes = (VOXELS_PER_BLOCK * std::mem::size_of::<GpuVoxel>()) as u64;
    let per_batch = (ctx.max_binding_bytes() / block_bytes).max(1) as usize;
    let mut updates = 0usize;
    // Results of every batch, applied only once all succeeded (an error leaves blocks untouched).
    let mut results: Vec<Vec<GpuVoxel>> = Vec::new();
    for batch in blocks.chunks(per_batch) {
        let voxel_count = (batch.len() * VOXELS_PER_BLOCK) as u64;
        ctx.check_binding("voxel batch (8 bytes per voxel)", voxel_count * 8)?;
        let mut voxels = Vec::with_capacity(voxel_count as usize);
        let mut bases = Vec::with_capacity(batch.len());
        for (index, block) in batch.iter() {
            bases.push(block_base(grid, &camera_from_world, *index));
            pack_block_into(block, &mut voxels);
        }
        let uniforms = FuseUniforms {
            voxel_count: voxel_count as u32,
            ..uniforms
        };
        let scope = ErrorScopes::push(&ctx.device);
        let buf_uniforms = ctx.uniform("fuse_uniforms", bytemuck::bytes_of(&uniforms));
        let buf_bases = ctx.storage("fuse_block_base", bytemuck::cast_slice(&bases));
        let buf_voxels = ctx.storage("fuse_voxels", bytemuck::cast_slice(&voxels));
        let buf_counters = ctx.storage("fuse_counters", bytemuck::cast_slice(&[0u32; 4]));
        let bind = ctx.bind_group(
            "fuse_depth",
            &kernel.layout,
            &[
                &buf_uniforms,
                &buf_bases,
                &buf_depth,
                &buf_pixel,
                &buf_voxels,
                &buf_counters,
            ],
        );
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("fuse_depth"),
            });
        ctx.record_dispatch(&mut encoder, &kernel.pipeline, &bind, voxel_count)?;
        ctx.queue.submit([encoder.finish()]);
        scope.pop("running the fusion kernel")?;
        let out = ctx.read_back(&[(&buf_voxels, voxel_count * 8), (&buf_counters, 4)])?;
        // Staging bytes carry no alignment guarantee: copy into typed vectors.
        let counter: Vec<u32> = bytemuck::pod_collect_to_vec(&out[1]);
        updates += counter[0] as usize;
        results.push(bytemuck::pod_collect_to_vec(&out[0]));
    }
    for (batch, result) in blocks.chunks_mut(per_batch).zip(&results) {
        for ((_, block), vox) in batch.iter_mut().zip(result.chunks_exact(VOXELS_PER_BLOCK)) {
            apply_updated(block, vox);
        }
    }
    Ok(updates)
}

/// The frame's fusion uniforms (with `voxel_count` 0: set per dispatch) and its camera-from-world
/// transform: the same camera-frame quantities as the CPU path, computed the same way.
pub(crate) fn frame_uniforms(
    grid: &GridParams,
    frame: &DepthFrame,
    params: &DepthFusionParams,
) -> (FuseUniforms, Isometry3<f64>) {
    let camera_from_world = frame.world_from_camera.inverse();
    let rot = camera_from_world.rotation.to_rotation_matrix();
    let vs = grid.voxel_size_m as f64;
    let k = frame.intrinsics;
    let ax: Vector3<f32> = (rot * Vector3::x() * vs).cast();
    let ay: Vector3<f32> = (rot * Vector3::y() * vs).cast();
    let az: Vector3<f32> = (rot * Vector3::z() * vs).cast();
    let uniforms = FuseUniforms {
        axis_x: [ax.x, ax.y, ax.z, 0.0],
        axis_y: [ay.x, ay.y, ay.z, 0.0],
        axis_z: [az.x, az.y, az.z, 0.0],
        fx: k.fx as f32,
        fy: k.fy as f32,
        cx: k.cx as f32,
        cy: k.cy as f32,
        width: frame.depth_m.width,
        height: frame.depth_m.height,
        mu: grid.truncation_m,
        inv_mu: 1.0 / grid.truncation_m,
        voxel_count: 0,
        use_color: (params.use_color && frame.color.is_some()) as u32,
        pad: [0; 2],
    };
    (uniforms, camera_from_world)
}

/// One word per pixel: its colour (`r | g << 8 | b << 16`, 0 without colour) and
/// [`PIXEL_VALID`] when its depth is usable.
pub(crate) fn pixel_words(frame: &DepthFrame, params: &DepthFusionParams) -> Vec<u32> {
    let color = if params.use_color {
        frame.color.as_ref()
    } else {
        None
    };
    frame
        .depth_m
        .data
        .iter()
        .enumerate()
        .map(|(i, &d)| {
            let rgb = color.map_or(0, |c| pack_rgb(c.data[i]));
            rgb | if usable(d, params) { PIXEL_VALID } else { 0 }
        })
        .collect()
}

/// Camera-frame centre of voxel (0, 0, 0) of block `index`, metres (w = 0).
pub(crate) fn block_base(
    grid: &GridParams,
    camera_from_world: &Isometry3<f64>,
    index: BlockIndex,
) -> [f32; 4] {
    let vs = grid.voxel_size_m as f64;
    let o = grid.block_origin(index);
    let centre0 = Point3::new(o[0] + 0.5 * vs, o[1] + 0.5 * vs, o[2] + 0.5 * vs);
    let base: Vector3<f32> = (camera_from_world * centre0).coords.cast();
    [base.x, base.y, base.z, 0.0]
}
