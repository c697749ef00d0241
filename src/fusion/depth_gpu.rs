//! Projective depth-map fusion (DENSER Sec. III-A) on the GPU: the host side of
//! `shaders/fuse_depth.wgsl` (blocks uploaded per call) and `shaders/fuse_depth_resident.wgsl`
//! (blocks resident in the GPU pool, [`ResidentMap`]). Both fuse from the CPU's own
//! [`DepthPlan`] (the same blocks, the same f32 geometry) and apply the per-voxel update of
//! `shaders/shared/fuse_common.wgsl`, the twin of [`integrate_depth_plan`]'s loop with
//! `Block::fuse`, one invocation per voxel. The per-call kernel reads the blocks' bases as the
//! CPU computes them; the resident one gets each block as a 4-byte offset from the frame's
//! origin block and computes its base on the device (`frame_keys.wgsl`, [`FrameKeys`]: exact
//! integer arithmetic that gives the CPU's base but for rare rounding ties).
//!
//! The kernels repeat the CPU's f32 arithmetic in the same order, with exact twins of its
//! rounding (`shaders/shared/rounding.wgsl`). Remaining differences come from WGSL's FMA
//! contraction and division precision: a voxel near a pixel border may project to the
//! neighbouring pixel, and a running average may land one quantisation step away
//! (`tests/gpu.rs` states the tolerance). Per-call blocks are sent in batches that fit one
//! storage binding (4 KiB per block: 32 768 blocks in 128 MiB), so any number of blocks works.
//!
//! [`integrate_depth_plan`]: super::integrate_depth_plan

use super::depth::{merge_sorted, DepthFusionParams, DepthPlan};
use super::depth_device::DeviceDepthFrame;
use super::depth_keys::FrameKeys;
use super::FusionStats;
use crate::frame::DepthFrame;
use crate::gpu::layout::{apply_updated, pack_block_into, FuseUniforms, GpuVoxel};
use crate::gpu::resident::alloc::{
    created_bytes, free_stack_words, record_insert, record_lookup_once, AllocBuffers,
};
use crate::gpu::resident::{BlockTable, FrameParts, FramePlacement, ResidentMap, SLOT_TOMBSTONE};
use crate::gpu::{shaders, thread_cpu_s, ErrorScopes, GpuContext};
use crate::grid::{Block, BlockIndex, GridParams, Layer, TouchedBlocks, VOXELS_PER_BLOCK};
use crate::{Error, Result};

/// Fuses one depth frame into `layer` on the GPU with blocks uploaded per call, like
/// [`super::integrate_depth_plan`]: the plan's band plus the allocated blocks in view. Returns
/// the touched blocks (sorted) and work counters. On error the layer holds the blocks as before.
pub fn integrate_depth_gpu(
    ctx: &GpuContext,
    layer: &mut Layer,
    frame: &DepthFrame,
    params: &DepthFusionParams,
    plan: &DepthPlan,
) -> Result<(TouchedBlocks, FusionStats)> {
    let grid = layer.params();
    let blocks = plan.blocks(layer);
    super::update_checked_out(layer, &blocks, plan.measurements, |taken| {
        fuse_blocks(ctx, &grid, taken, frame, params, plan)
    })
}

/// Runs the per-call kernel over `blocks` in batches; returns the number of voxel updates.
fn fuse_blocks(
    ctx: &GpuContext,
    grid: &GridParams,
    blocks: &mut [(BlockIndex, Box<Block>)],
    frame: &DepthFrame,
    params: &DepthFusionParams,
    plan: &DepthPlan,
) -> Result<usize> {
    if blocks.is_empty() {
        return Ok(0);
    }
    let uniforms = fuse_uniforms(plan, frame, params);
    let pixels = frame.depth_m.data.len() as u64;
    ctx.check_binding("depth image (4 bytes per pixel)", pixels * 4)?;
    let kernel = ctx.kernel(&shaders::FUSE_DEPTH)?;
    let scope = ErrorScopes::push(&ctx.device);
    let buf_depth = ctx.storage("fuse_depth", bytemuck::cast_slice(&frame.depth_m.data));
    let buf_color = ctx.storage("fuse_color", color_bytes(frame, params));
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
            bases.push(base_words(grid, plan, *index));
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
                &buf_color,
                &buf_voxels,
                &buf_counters,
            ],
        );
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("fuse_depth"),
            });
        ctx.record_dispatch(&mut encoder, &kernel, &bind, voxel_count)?;
        ctx.submit(encoder);
        scope.pop("running the fusion kernel")?;
        let (voxels, counted) =
            ctx.read_back_voxels(&buf_voxels, &buf_counters, voxel_count as usize)?;
        updates += counted as usize;
        results.push(voxels);
    }
    for (batch, result) in blocks.chunks_mut(per_batch).zip(&results) {
        for ((_, block), vox) in batch.iter_mut().zip(result.chunks_exact(VOXELS_PER_BLOCK)) {
            apply_updated(block, vox);
        }
    }
    Ok(updates)
}

/// Fuses one depth frame into the blocks resident in `map` (the GPU tier over `layer`), like
/// [`super::integrate_depth_plan`]: the plan's blocks are made resident (grown into or spilled
/// for), resolved to pool slots and bases on the GPU (`frame_keys.wgsl`) and updated in place.
/// A frame whose blocks exceed the largest pool goes through [`integrate_depth_gpu`] after its
/// resident blocks are written back (counted, with a warning).
///
/// With [`ResidentMap::set_frames_in_flight`], the frame returns once submitted, and what it
/// touched arrives with a later call (`src/gpu/resident/late.rs`); otherwise it waits for its
/// own results. Returns the blocks touched by the frames collected during the call (this one,
/// when it waited) and their work counters.
pub fn integrate_depth_resident(
    map: &mut ResidentMap,
    layer: &mut Layer,
    frame: &DepthFrame,
    params: &DepthFusionParams,
    plan: &DepthPlan,
) -> Result<(TouchedBlocks, FusionStats)> {
    integrate_resident(map, layer, (frame, None), params, (plan, None))
}

/// [`integrate_depth_resident`] for a frame whose depths are on the device (a matcher left
/// them there): planned from its band slices ([`DeviceDepthFrame::plan`]), its depths copied on
/// the device into the fusion's input, so that only its colour goes up. Equal to fusing the
/// frame's depths from the host (`tests/gpu/device_depth.rs`). A frame too large for the pool
/// reads its depths back (counted) and goes through [`integrate_depth_gpu`].
///
/// `riding`: work recorded for the device and not yet submitted (the next frame's listing,
/// [`DeviceDepthFrame::take_unsubmitted`]), submitted first in the frame's own submit, or
/// alone where the frame makes none; submitted in any case once this returns `Ok`.
pub fn integrate_device_depth_resident(
    map: &mut ResidentMap,
    layer: &mut Layer,
    frame: &DeviceDepthFrame,
    params: &DepthFusionParams,
    (plan, riding): (&DepthPlan, Option<wgpu::CommandEncoder>),
) -> Result<(TouchedBlocks, FusionStats)> {
    let depth = Some(frame.depth_buffer());
    integrate_resident(map, layer, (frame.header(), depth), params, (plan, riding))
}

/// The frame's header (the whole frame where `depth` is `None`) and, where its depths are on
/// the device, their buffer.
type ResidentInput<'a> = (&'a DepthFrame, Option<&'a wgpu::Buffer>);

/// [`fuse_resident`], its host CPU time (and the plan's) counted in the map's statistics.
fn integrate_resident(
    map: &mut ResidentMap,
    layer: &mut Layer,
    input: ResidentInput,
    params: &DepthFusionParams,
    (plan, riding): (&DepthPlan, Option<wgpu::CommandEncoder>),
) -> Result<(TouchedBlocks, FusionStats)> {
    let cpu_s = thread_cpu_s();
    let fused = fuse_resident(map, layer, input, params, (plan, riding));
    map.add_host_cpu(plan.listing_cpu_s + thread_cpu_s() - cpu_s);
    fused
}

fn fuse_resident(
    map: &mut ResidentMap,
    layer: &mut Layer,
    (frame, depth): ResidentInput,
    params: &DepthFusionParams,
    (plan, mut riding): (&DepthPlan, Option<wgpu::CommandEncoder>),
) -> Result<(TouchedBlocks, FusionStats)> {
    if layer.params() != map.grid() {
        return Err(Error::InvalidArgument(
            "resident GPU map and layer have different grids".into(),
        ));
    }
    map.begin_in_flight(layer, true)?;
    let t = std::time::Instant::now();
    // Listed and unsettled (neither the band nor the layer has them: listed only because a
    // frame in flight may have created them).
    let (mut listed, unsettled) = plan.blocks_and_unsettled(layer, &map.unsettled_blocks(layer));
    map.release_empty_except(&[&listed, &unsettled]);
    // The two lists are disjoint.
    let block_count = listed.len() + unsettled.len();
    map.begin_frame(block_count, plan.listing_s + t.elapsed().as_secs_f64());
    if block_count > map.max_blocks() as usize {
        // The frame alone exceeds the largest pool: give its resident blocks back to RAM and
        // fuse it in batches.
        map.note_oversize();
        if let Some(encoder) = riding.take() {
            map.context().submit(encoder);
        }
        tracing::warn!(
            "frame needs {} blocks, more than the GPU pool's {} (raise the GPU memory budget); \
             fusing it in batches",
            block_count,
            map.max_blocks()
        );
        map.flush_blocks(layer, &merge_sorted(&listed, &unsettled))?;
        let ctx = map.context().clone();
        let read_back;
        let frame = match depth {
            Some(buffer) => {
                read_back = DeviceDepthFrame::read_back_from(&ctx, frame, buffer)?;
                &read_back
            }
            None => frame,
        };
        let (mut touched, mut stats) = integrate_depth_gpu(&ctx, layer, frame, params, plan)?;
        let (earlier, updates) = map.take_collected();
        touched.extend(earlier);
        stats.voxel_updates += updates;
        return Ok((touched, stats));
    }
    if block_count > 0 {
        // The unsettled blocks listed last, fused only if a frame in flight created them.
        let first_unsettled = listed.len();
        map.note_listed_in_flight(unsettled.len());
        listed.extend(unsettled);
        // One submit: what rides with it, the empty blocks' fill, the keys' slots and bases,
        // and the fusion.
        let mut encoder = riding
            .take()
            .unwrap_or_else(|| map.context().encoder("fuse_depth_resident"));
        let frame_blocks = (&listed[..], first_unsettled);
        let placed =
            map.make_resident_for_frame(layer, frame_blocks, plan.camera_m, &mut encoder)?;
        let t = std::time::Instant::now();
        let frame_parts = FrameBlocks {
            blocks: listed,
            first_unsettled,
            placed,
            encoder,
        };
        let inputs_s = run_resident(map, layer, frame_parts, (frame, depth), params, plan)?;
        map.add_kernel_time(t.elapsed().as_secs_f64(), inputs_s);
    } else if let Some(encoder) = riding.take() {
        map.context().submit(encoder);
    }
    let (touched, voxel_updates) = map.end_in_flight(layer)?;
    let stats = FusionStats {
        blocks: touched.len(),
        voxel_updates,
        measurements: plan.measurements,
    };
    Ok((touched, stats))
}

/// A frame's listed blocks and what its submit carries.
struct FrameBlocks {
    /// The listed blocks; those from `first_unsettled` on (neither the band nor the layer has
    /// them: listed because a frame in flight may have created them) carry `w = 1` in their
    /// bases, and the kernel fuses them only if a frame did.
    blocks: Vec<BlockIndex>,
    first_unsettled: usize,
    /// The blocks' slots where the host's table has them, and the free slots the device gives
    /// the frame's new blocks, the top last ([`ResidentMap::make_resident_for_frame`]).
    placed: FramePlacement,
    /// Holds the writes of the frame's new blocks' slots and the table's changed entries.
    encoder: wgpu::CommandEncoder,
}

/// Resolves the frame's blocks to slots on the GPU, inserts its new blocks there, fuses the
/// frame into them and submits the encoder with them and the copy of the counters, flags and
/// insertions into the readback ring; returns the seconds spent preparing and writing the
/// inputs.
///
/// Per frame: the blocks' packed offsets from the frame's origin block (4 bytes per block,
/// [`FrameKeys`]; 12 where a block lies beyond the packed range), the free-slot stack (4 bytes
/// per new block), the depth image (4 bytes per pixel), the colour image (3 bytes per pixel,
/// when fused) and the uniforms are written into buffers the map keeps; the fill of the
/// reserved slots, the keys' slots and bases (`frame_keys.wgsl`), the insertion of new blocks
/// (`table_insert.wgsl`), the fusion and the copy of the counters, flags (4 bytes per block)
/// and insertions (12 bytes per new block) into a staging buffer of the ring are one submit,
/// and nothing waits for it. No buffer or bind group is created once the kept ones have grown
/// to the frames' size.
fn run_resident(
    map: &mut ResidentMap,
    layer: &Layer,
    frame_blocks: FrameBlocks,
    (frame, depth): ResidentInput,
    params: &DepthFusionParams,
    plan: &DepthPlan,
) -> Result<f64> {
    let FrameBlocks {
        blocks,
        first_unsettled,
        placed,
        mut encoder,
    } = frame_blocks;
    let reserved = &placed.reserved;
    let t = std::time::Instant::now();
    let FrameParts {
        ctx,
        grid,
        pool,
        exists,
        table: (table, mask),
        kept,
        ring,
    } = map.frame_parts();
    let n = blocks.len() as u64;
    let voxel_count = n * VOXELS_PER_BLOCK as u64;
    if voxel_count > u32::MAX as u64 {
        return Err(Error::GpuCapacity {
            what: "voxels of one dispatch".into(),
            needed_bytes: voxel_count,
            limit_bytes: u32::MAX as u64,
        });
    }
    let uniforms = FuseUniforms {
        voxel_count: voxel_count as u32,
        ..fuse_uniforms(plan, frame, params)
    };
    let depth_bytes = frame.depth_m.width as u64 * frame.depth_m.height as u64 * 4;
    ctx.check_binding("depth image (4 bytes per pixel)", depth_bytes)?;
    ctx.check_binding("block bases (16 bytes per block)", n * 16)?;
    let keys = FrameKeys::new(&grid, &plan.geometry, &blocks, first_unsettled)?;
    let key_uniforms = keys.uniforms(mask);
    let frame_keys = ctx.kernel(&shaders::FRAME_KEYS)?;
    let fuse = ctx.kernel(&shaders::FUSE_DEPTH_RESIDENT)?;
    let scope = ErrorScopes::push(&ctx.device);
    let buf_key_uniforms =
        kept.uniform_with(ctx, "frame_key_uniforms", bytemuck::bytes_of(&key_uniforms));
    let buf_keys = kept.storage_with(ctx, "frame_keys", bytemuck::cast_slice(keys.words()));
    // Every listed block's slot and base are written by frame_keys.wgsl.
    let buf_slots = kept.scratch(ctx, "lookup_slots", n * 4);
    let buf_bases = kept.scratch(ctx, "fuse_block_base", n * 16);
    let buf_uniforms = kept.uniform_with(ctx, "fuse_uniforms", bytemuck::bytes_of(&uniforms));
    let buf_depth = match depth {
        Some(on_device) => {
            kept.storage_copied(ctx, &mut encoder, "fuse_depth", (on_device, depth_bytes))
        }
        None => kept.storage_with(ctx, "fuse_depth", bytemuck::cast_slice(&frame.depth_m.data)),
    };
    let buf_color = kept.storage_with(ctx, "fuse_color", color_bytes(frame, params));
    let buf_counters = kept.scratch(ctx, "fuse_counters", 16);
    let buf_updated = kept.scratch(ctx, "block_updated", n * 4);
    let bind_keys = kept.bind_group(
        ctx,
        "frame_keys",
        &frame_keys.layout,
        &[&buf_key_uniforms, table, &buf_keys, &buf_slots, &buf_bases],
    );
    let bind_fuse = kept.bind_group(
        ctx,
        "fuse_depth_resident",
        &fuse.layout,
        &[
            &buf_uniforms,
            &buf_bases,
            &buf_depth,
            &buf_color,
            pool,
            &buf_counters,
            &buf_slots,
            &buf_updated,
            exists,
        ],
    );
    // Counters and flags start at zero on the device, not uploaded.
    encoder.clear_buffer(&buf_counters, 0, Some(16));
    encoder.clear_buffer(&buf_updated, 0, Some((n * 4).next_multiple_of(4)));
    ctx.record_dispatch(&mut encoder, &frame_keys, &bind_keys, n)?;
    let mut results = vec![(&buf_counters, 8), (&buf_updated, n as usize * 4)];
    let buf_created;
    if !reserved.is_empty() {
        let k = reserved.len() as u64;
        let buf_free = kept.storage_with(
            ctx,
            "free_slots",
            bytemuck::cast_slice(&free_stack_words(reserved)),
        );
        buf_created = kept.scratch(ctx, "created_blocks", created_bytes(k));
        let buffers = AllocBuffers {
            uniforms: &buf_key_uniforms,
            table,
            keys: &buf_keys,
            slots: &buf_slots,
            free: &buf_free,
            created: &buf_created,
        };
        record_insert(
            ctx,
            (&mut encoder, &mut *kept),
            ("table_insert", &buffers),
            n,
        )?;
        results.push((&buf_created, created_bytes(k) as usize));
    }
    ctx.record_dispatch(&mut encoder, &fuse, &bind_fuse, voxel_count)?;
    let inputs_s = t.elapsed().as_secs_f64();
    let readback = ring.submit(ctx, encoder, &results);
    scope.pop("running the resident fusion kernel")?;
    map.frame_submitted(layer, (blocks, placed), readback);
    Ok(inputs_s)
}

/// Each listed block's slot (`None` where absent) and base (xyz, w), as `frame_keys.wgsl`
/// writes them.
pub type ResolvedKeys = (Vec<Option<u32>>, Vec<[f32; 4]>);

/// Runs `frame_keys.wgsl` over `keys` against a copy of `table` uploaded whole: each block's
/// slot (`None` where absent) and base (xyz; w = 1 from the first unsettled block on), as the
/// resident fusion resolves them. For tests of the kernel against its CPU twin
/// ([`FrameKeys::base`], [`BlockTable::lookup`]).
pub fn frame_keys_on_gpu(
    ctx: &GpuContext,
    keys: &FrameKeys,
    table: &BlockTable,
) -> Result<ResolvedKeys> {
    let uniforms = keys.uniforms(table.mask());
    let n = uniforms.block_count as usize;
    if n == 0 {
        return Ok((Vec::new(), Vec::new()));
    }
    let scope = ErrorScopes::push(&ctx.device);
    let (lookup, encoder) = record_lookup_once(ctx, uniforms, table, keys.words())?;
    ctx.submit(encoder);
    scope.pop("resolving a frame's keys on the GPU")?;
    let slots: Vec<u32> = ctx.read_back_as(&lookup.slots, n)?;
    let bases: Vec<[f32; 4]> = ctx.read_back_as(&lookup.bases, n)?;
    let slots = (slots.into_iter())
        .map(|s| (s < SLOT_TOMBSTONE).then_some(s))
        .collect();
    Ok((slots, bases))
}

/// The frame's fusion uniforms (with `voxel_count` 0: set per dispatch), from the plan's
/// geometry: the same camera-frame quantities as the CPU path.
fn fuse_uniforms(plan: &DepthPlan, frame: &DepthFrame, params: &DepthFusionParams) -> FuseUniforms {
    let g = &plan.geometry;
    let [ax, ay, az] = g.axis_m;
    FuseUniforms {
        axis_x: [ax.x, ax.y, ax.z, 0.0],
        axis_y: [ay.x, ay.y, ay.z, 0.0],
        axis_z: [az.x, az.y, az.z, 0.0],
        fx: g.fx,
        fy: g.fy,
        cx: g.cx,
        cy: g.cy,
        width: g.width,
        height: g.height,
        mu: g.truncation_m,
        inv_mu: 1.0 / g.truncation_m,
        voxel_count: 0,
        use_color: (params.use_color && frame.color.is_some()) as u32,
        min_depth_m: params.min_depth_m,
        max_depth_m: params.max_depth_m,
    }
}

/// The colour image as the kernels read it (3 bytes per pixel, as stored), or one unused word
/// when the frame fuses no colour. Which depths are usable the kernels decide themselves
/// (`shaders/shared/fuse_common.wgsl`, the twin of `usable` in `depth.rs`).
fn color_bytes<'a>(frame: &'a DepthFrame, params: &DepthFusionParams) -> &'a [u8] {
    match frame.color.as_ref().filter(|_| params.use_color) {
        Some(c) => bytemuck::cast_slice(&c.data),
        None => &[0; 4],
    }
}

/// [`crate::fusion::DepthGeometry::block_base`] as the kernels read it (`vec4`, w = 0).
fn base_words(grid: &GridParams, plan: &DepthPlan, index: BlockIndex) -> [f32; 4] {
    let b = plan.geometry.block_base(grid, index);
    [b.x, b.y, b.z, 0.0]
}
