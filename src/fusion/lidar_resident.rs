//! LiDAR fusion into the blocks resident on the GPU ([`ResidentMap`], the depth fusion's pool):
//! `shaders/fuse_lidar_resident.wgsl` applies the per-call kernel's update
//! ([`super::integrate_lidar_gpu`], the same walk in `shaders/shared/lidar_walk.wgsl`) to the
//! scan's blocks where they live on the device, so a scan no longer sends its blocks up and
//! reads them back (4 KiB each, both ways): the blocks already resident stay, those in RAM go up
//! once (as for a depth frame), new ones are made empty on the device, and what comes back is
//! the counters and one flag per block. What goes up besides: each ray once (16 bytes: its
//! point and grey level, sent by the listing where the device listed the scan's blocks,
//! `lidar_listing.rs`, and kept there) and the listed blocks (4 bytes each: an offset from the
//! sensor's block), from which the device lists and orders the (block, ray) pairs and makes the
//! walks the host would prepare, bit for bit (`lidar_device.rs`), and inserts the scan's new
//! blocks into its hash table, slots from a free-slot stack the host reserved (4 bytes per new
//! block; `src/gpu/resident/alloc.rs`, as a depth frame's), which the host learns when the scan
//! is collected. A scan whose rays exceed one binding, or one of whose blocks has more pairs
//! than a kernel invocation reads, sends the host's walks instead (16 bytes per ray, 28 per
//! pair), its new blocks inserted by the host.
//!
//! The result equals the per-call kernel's bit for bit (the same f32 operations on the same
//! values, in the same order per block), so it keeps its relation to the CPU's walk
//! (`tests/gpu/lidar.rs`).

use super::lidar_device::DevicePairs;
use super::lidar_gpu::{dispatch_order, record_passes, upload_rays, PAIR_BYTES};
use super::lidar_listing::{listable, record_lidar_listing};
use super::{begin_lidar_listing, LidarListings, PendingLidarPlan};
use super::{integrate_lidar_gpu, lidar_device, FusionStats, LidarPlan};
use crate::gpu::kept::Kept;
use crate::gpu::layout::{FrameKeyUniforms, LookupUniforms};
use crate::gpu::resident::alloc::{created_bytes, free_stack_words, record_insert, AllocBuffers};
use crate::gpu::resident::{FrameParts, FramePlacement, ResidentMap};
use crate::gpu::{shaders, thread_cpu_s, ErrorScopes, GpuContext};
use crate::grid::{BlockIndex, Layer, TouchedBlocks};
use crate::{Error, Result};
use std::ops::Range;

/// Fuses the LiDAR scan planned in `plan` into the blocks resident in `map` (the GPU tier over
/// `layer`), like [`super::integrate_lidar_plan`]: the plan's blocks are made resident (grown
/// into or spilled for), resolved to pool slots on the GPU (`block_lookup.wgsl`) and updated
/// in place. A scan whose blocks exceed the largest pool, or whose (block, ray) pairs exceed
/// one storage binding, goes through [`integrate_lidar_gpu`] after its resident blocks are
/// written back (counted, with a warning).
///
/// With [`ResidentMap::set_frames_in_flight`], the scan returns once submitted, as a depth
/// frame does (`src/gpu/resident/late.rs`). Returns the blocks touched by the scans and frames
/// collected during the call (each one's sorted) and their work counters.
pub fn integrate_lidar_resident(
    map: &mut ResidentMap,
    layer: &mut Layer,
    plan: &LidarPlan,
) -> Result<(TouchedBlocks, FusionStats)> {
    let (touched, stats, _) = fuse_lidar_then_list(map, layer, plan, None)?;
    Ok((touched, stats))
}

/// The next scan's listing ([`fuse_lidar_then_list`]): the listings' record and the scan's rays
/// ([`LidarPlan::rays_only`]).
pub(crate) type NextListing<'a> = (&'a mut LidarListings, LidarPlan);

/// [`integrate_lidar_resident`], then the listing of the next scan, `next`, begun
/// ([`super::begin_lidar_listing`]): recorded into the scan's fusion submit, after its passes
/// (which read the rays and table the listing overwrites), so that a scan costs one submit
/// where it alone cost two; submitted alone where the scan submits nothing of its own (no
/// blocks, or too many for the pool). Returns also the next scan's pending plan (`None`
/// without `next`).
pub(crate) fn fuse_lidar_then_list(
    map: &mut ResidentMap,
    layer: &mut Layer,
    plan: &LidarPlan,
    next: Option<NextListing<'_>>,
) -> Result<(TouchedBlocks, FusionStats, Option<PendingLidarPlan>)> {
    let cpu_s = thread_cpu_s();
    let fused = fuse_then_list(map, layer, plan, next);
    map.add_host_cpu(thread_cpu_s() - cpu_s);
    fused
}

/// [`fuse_lidar_then_list`], but for counting its host CPU time.
fn fuse_then_list(
    map: &mut ResidentMap,
    layer: &mut Layer,
    plan: &LidarPlan,
    next: Option<NextListing<'_>>,
) -> Result<(TouchedBlocks, FusionStats, Option<PendingLidarPlan>)> {
    if layer.params() != map.grid() {
        return Err(Error::InvalidArgument(
            "resident GPU map and layer have different grids".into(),
        ));
    }
    // A scan's blocks are its rays' alone: they do not depend on what has arrived.
    map.begin_in_flight(layer, false)?;
    let groups = plan.groups();
    let blocks: Vec<BlockIndex> = groups.iter().map(|g| g.0).collect();
    map.begin_frame(blocks.len(), 0.0);
    let pair_bytes = plan.pair_count() as u64 * PAIR_BYTES;
    if blocks.len() > map.max_blocks() as usize || pair_bytes > map.context().max_binding_bytes() {
        map.note_oversize();
        tracing::warn!(
            "a LiDAR scan of {} blocks and {} (block, ray) pairs exceeds the GPU pool ({} blocks) \
             or one binding: fusing it with its blocks uploaded",
            blocks.len(),
            plan.pair_count(),
            map.max_blocks()
        );
        map.flush_blocks(layer, &blocks)?;
        let ctx = map.context().clone();
        let (mut touched, mut stats) = integrate_lidar_gpu(&ctx, layer, plan)?;
        let (earlier, updates) = map.take_collected();
        touched.extend(earlier);
        stats.voxel_updates += updates;
        let next = match next {
            Some((listings, plan)) => Some(begin_lidar_listing(map, listings, plan)?),
            None => None,
        };
        return Ok((touched, stats, next));
    }
    // The rays and table a device listing left on the device for this plan, if any (used
    // once): the listing's table entries.
    let listing = map
        .take_lidar_rays_of()
        .filter(|l| plan.device_listing() == Some(l.0))
        .map(|l| l.1);
    let mut next = next;
    let mut listed = None;
    if !blocks.is_empty() {
        // One submit: the empty blocks' fill, the lookup, the new blocks' insertion, the passes
        // and the next listing.
        map.note_listed_in_flight(0); // a scan lists its rays' blocks alone
        let mut encoder = map.context().encoder("fuse_lidar_resident");
        // Where the device makes the pairs, it inserts the scan's new blocks too (it has their
        // keys): the host reserves their slots. Else the host inserts them.
        let on_device = lidar_device::fits(map.context(), plan, &groups);
        let placed = if on_device {
            let listed = (&blocks[..], blocks.len());
            map.make_resident_for_frame(layer, listed, plan.origin_m(), &mut encoder)?
        } else {
            map.make_resident(layer, &blocks, plan.origin_m(), Some(&mut encoder))?;
            FramePlacement::default()
        };
        let t = std::time::Instant::now();
        let riding = next.take_if(|(_, next)| listable(map.context(), next));
        let scan = ScanBlocks {
            groups: &groups,
            on_device,
            placed,
            encoder,
        };
        let inputs_s;
        (inputs_s, listed) = run_resident(map, layer, (plan, listing), scan, riding)?;
        map.add_kernel_time(t.elapsed().as_secs_f64(), inputs_s);
    }
    if let Some((listings, plan)) = next {
        listed = Some(begin_lidar_listing(map, listings, plan)?);
    }
    let (touched, voxel_updates) = map.end_in_flight(layer)?;
    let stats = FusionStats {
        blocks: touched.len(),
        voxel_updates,
        measurements: plan.ray_count(),
    };
    Ok((touched, stats, listed))
}

/// A scan's blocks as its submit begins.
struct ScanBlocks<'a> {
    /// The plan's blocks, in block order, with their pairs.
    groups: &'a [(BlockIndex, Range<usize>)],
    /// Whether the device makes the pairs ([`lidar_device::fits`]) and inserts the new blocks.
    on_device: bool,
    /// Each block's slot where the host's table has it and the free slots reserved for the
    /// blocks the device inserts ([`ResidentMap::make_resident_for_frame`]); empty where the
    /// host inserted them ([`ResidentMap::make_resident`]).
    placed: FramePlacement,
    /// Holds the fill of the scan's new blocks and the table's changed entries.
    encoder: wgpu::CommandEncoder,
}

/// Resolves the plan's blocks to pool slots, inserts its new blocks on the device (where
/// `scan.placed` reserved slots for them: `table_insert.wgsl` over the keys the listed blocks
/// went up as, `src/gpu/resident/alloc.rs`) and applies their rays there, submitting the
/// encoder with them and the copy of the counters, flags and insertions into the readback
/// ring, collected as a depth frame's are (`src/gpu/resident/late.rs`), and the listing of
/// `next` ([`listable`]) after them. Returns the seconds spent preparing and writing the
/// inputs, and the next scan's listing.
fn run_resident(
    map: &mut ResidentMap,
    layer: &Layer,
    (plan, listing): (&LidarPlan, Option<u32>),
    scan: ScanBlocks,
    next: Option<NextListing<'_>>,
) -> Result<(f64, Option<PendingLidarPlan>)> {
    let t = std::time::Instant::now();
    let ScanBlocks {
        groups,
        on_device,
        placed,
        mut encoder,
    } = scan;
    let device = map.context().clone();
    let FrameParts {
        ctx,
        grid,
        pool,
        exists,
        table: (table, mask),
        kept,
        ring,
    } = map.frame_parts();
    let n = groups.len();
    let (order, offsets) = dispatch_order(groups, 0..n);
    let total = *offsets.last().expect("one offset at least");
    let lookup = ctx.kernel(&shaders::BLOCK_LOOKUP)?;
    let fuse = ctx.kernel(&shaders::FUSE_LIDAR_RESIDENT)?;
    let lookup_uniforms = LookupUniforms {
        key_count: n as u32,
        mask,
        pad: [0; 2],
    };
    let scope = ErrorScopes::push(&ctx.device);
    let bytes = bytemuck::bytes_of(&lookup_uniforms);
    let buf_lookup = kept.uniform_with(ctx, "lookup_uniforms", bytes);
    // Every listed key's slot is written by the lookup.
    let buf_slots = kept.scratch(ctx, "lookup_slots", n as u64 * 4);
    let buf_counters = kept.scratch(ctx, "lidar_counters", 16);
    let buf_updated = kept.scratch(ctx, "lidar_updated", n as u64 * 4);
    // Counters and flags start at zero on the device, not uploaded.
    encoder.clear_buffer(&buf_counters, 0, Some(16));
    encoder.clear_buffer(&buf_updated, 0, Some(n as u64 * 4));
    // The pairs listed and their walks made on the device where its rays fit one binding (the
    // blocks' positions and first pairs made there too), else prepared here.
    let (made, buf_keys, buf_offsets) = if on_device {
        let made = lidar_device::record_device_pairs(
            (ctx, &mut *kept, &mut encoder),
            (&grid, plan),
            (groups, &order),
            (&buf_counters, listing),
        )?;
        let (keys, offsets) = (made.keys.clone(), made.offsets.clone());
        (Some(made), keys, offsets)
    } else {
        ctx.check_binding("block keys (16 bytes per block)", n as u64 * 16)?;
        let keys: Vec<[i32; 4]> = order
            .iter()
            .map(|&b| {
                let k = groups[b].0 .0;
                [k[0], k[1], k[2], 0]
            })
            .collect();
        let buf_keys = kept.storage_with(ctx, "lookup_keys", bytemuck::cast_slice(&keys));
        let bytes = bytemuck::cast_slice(&offsets);
        (
            None,
            buf_keys,
            kept.storage_with(ctx, "lidar_ray_offsets", bytes),
        )
    };
    let bind_lookup = kept.bind_group(
        ctx,
        "block_lookup",
        &lookup.layout,
        &[&buf_lookup, table, &buf_keys, &buf_slots],
    );
    ctx.record_dispatch(&mut encoder, &lookup, &bind_lookup, n as u64)?;
    let buf_created = match &made {
        Some(made) if !placed.reserved.is_empty() => {
            let inserting = (n as u32, &placed.reserved[..], &buf_slots);
            Some(record_insertions(
                (ctx, &mut *kept, &mut encoder),
                made,
                (table, mask),
                inserting,
            )?)
        }
        _ => None,
    };
    let (buf_pairs, buf_dirs, rays_per_pass) = match made {
        Some(made) => (made.pairs, made.dirs, made.rays_per_pass),
        None => {
            let kept = Some(&mut *kept);
            upload_rays((ctx, kept), &grid, (plan, groups), &order, total)?
        }
    };
    let counts: Vec<u32> = order.iter().map(|&b| groups[b].1.len() as u32).collect();
    let buffers = [
        &buf_offsets,
        &buf_pairs,
        pool,
        &buf_counters,
        &buf_slots,
        &buf_updated,
        &buf_dirs,
        exists,
    ];
    let passes = (&counts[..], rays_per_pass);
    let bound = (&*fuse, "fuse_lidar_resident", &buffers[..]);
    record_passes((ctx, &mut encoder, &mut *kept), bound, &grid, passes)?;
    let mut results = vec![(&buf_counters, 8), (&buf_updated, n * 4)];
    if let Some((created, bytes)) = &buf_created {
        results.push((created, *bytes as usize));
    }
    let readback = ring.record(ctx, &mut encoder, &results);
    let next = match next {
        Some((listings, next)) => {
            let parts = (&device, grid, &mut *kept);
            Some(record_lidar_listing(parts, listings, next, &mut encoder)?)
        }
        None => None,
    };
    let inputs_s = t.elapsed().as_secs_f64();
    ctx.submit(encoder);
    readback.submitted();
    if let Some(next) = &next {
        next.submitted();
    }
    scope.pop("running the resident LiDAR fusion kernel")?;
    // The blocks in block order (the order they are touched in), the flags and insertions in
    // dispatch order; where the host inserted every block (make_resident, `placed.slots`
    // empty), their slots are looked up as it is recorded.
    let blocks = groups.iter().map(|g| g.0).collect();
    let placed = FramePlacement {
        dispatch: order.iter().map(|&b| b as u32).collect(),
        ..placed
    };
    map.frame_submitted(layer, (blocks, placed), readback);
    map.set_lidar_rays_of(next.as_ref().map(|n| n.rays_of()));
    let next = next.map(|n| PendingLidarPlan::Listing(Box::new(n)));
    Ok((inputs_s, next))
}

/// Records the insertion of the scan's new blocks into the device's table (`table_insert.wgsl`,
/// after `block_lookup.wgsl` has written each of the `n` listed blocks' slots into `slots`) from
/// the keys they went up as (`made`), slots taken from the free-slot stack `reserved`.
/// Returns the buffer of its insertions and their bytes, for the scan's readback.
fn record_insertions(
    (ctx, kept, encoder): (&GpuContext, &mut Kept, &mut wgpu::CommandEncoder),
    made: &DevicePairs,
    (table, mask): (&wgpu::Buffer, u32),
    (n, reserved, slots): (u32, &[u32], &wgpu::Buffer),
) -> Result<(wgpu::Buffer, u64)> {
    let uniforms = FrameKeyUniforms {
        origin: made.sent_origin,
        block_count: n,
        mask,
        first_unsettled: n,
        ..Default::default()
    };
    let bytes = created_bytes(reserved.len() as u64);
    let free = free_stack_words(reserved);
    let buffers = AllocBuffers {
        uniforms: &kept.uniform_with(ctx, "lidar_insert_uniforms", bytemuck::bytes_of(&uniforms)),
        table,
        keys: &made.sent,
        slots,
        free: &kept.storage_with(ctx, "lidar_free_slots", bytemuck::cast_slice(&free)),
        created: &kept.scratch(ctx, "lidar_created_blocks", bytes),
    };
    record_insert(
        ctx,
        (encoder, kept),
        ("lidar_table_insert", &buffers),
        n as u64,
    )?;
    Ok((buffers.created.clone(), bytes))
}
