//! A LiDAR scan's rays and (block, ray) pairs made on the device, so that a resident scan
//! ([`super::integrate_lidar_resident`]) sends 16 bytes per ray and 8 per run of pairs instead of the
//! host's 16 per ray and 28 per pair: each ray goes up as its point as scanned and its grey
//! level, and the pairs' rays as runs of consecutive rays in a block (8 bytes a run, which
//! holds 5–12 pairs on the scans measured: [`ray_runs`]); the listed blocks' keys and pair
//! offsets go up already, for the lookup and the passes. `shaders/lidar_rays.wgsl`
//! measures and rotates the rays as [`super::LidarPlan`] does and `shaders/lidar_pairs.wgsl` makes each
//! pair's walk as [`super::block_local_ray`] and [`GpuLidarPair::pack`] do, both in exact f64
//! (`shaders/shared/exact_f64.wgsl`, [`crate::gpu::exact_f64`]): the same values bit for bit
//! on any device, so the fusion's result is the host-prepared one's.
//!
//! The host still lists the pairs (it pages their blocks in) and numbers them; the passes are
//! sized by [`MAX_WALK_STEPS`], a bound on every walk, instead of the longest one (which only
//! the device knows now): more, shorter passes on llvmpipe, the same updates in the same order.

use super::lidar::run_starts;
use super::lidar_gpu::LOOP_BUDGET;
use super::LidarPlan;
use crate::gpu::kept::Kept;
use crate::gpu::layout::{GpuLidarPair, GpuRayDir};
use crate::gpu::{shaders, GpuContext};
use crate::grid::{BlockIndex, GridParams};
use crate::Result;
use std::ops::Range;

/// The most cells a pair's walk visits: it spans at most the block's diagonal and a voxel at
/// either end (8√3 + 2 voxels), so at most 31 cells; the kernel counts a pair beyond this bound
/// as not made (never), and the passes apply `LOOP_BUDGET / (MAX_WALK_STEPS + 1)` rays of each
/// block (keep in sync with `shaders/lidar_pairs.wgsl`).
pub const MAX_WALK_STEPS: u32 = 49;

/// Bytes of one ray as it goes up: its point (3 × f32) and grey level (u32).
const RAY_IN_BYTES: u64 = 16;

/// Where the device made the scan's walks: the pairs (in dispatch order, as the fusion kernel
/// reads them), the rays' directions and grey levels, and the rays each pass applies per block.
pub(super) struct DevicePairs {
    pub(super) pairs: wgpu::Buffer,
    pub(super) dirs: wgpu::Buffer,
    pub(super) rays_per_pass: u32,
}

/// The scan's constants as `shaders/shared/lidar_scan.wgsl` reads them.
fn scan_words(grid: &GridParams, plan: &LidarPlan, [pairs, blocks, runs]: [usize; 3]) -> Vec<u32> {
    let vs = grid.voxel_size_m as f64;
    let [i, j, k, w] = plan.rotation_ijkw();
    let o = plan.origin_m();
    let values = [
        o[0],
        o[1],
        o[2],
        i,
        j,
        k,
        w,
        vs,
        grid.truncation_m as f64,
        1.0 / vs,
    ];
    let mut words: Vec<u32> = values
        .iter()
        .flat_map(|v| [v.to_bits() as u32, (v.to_bits() >> 32) as u32])
        .collect();
    words.extend([plan.ray_count(), pairs, blocks, runs].map(|n| n as u32));
    words
}

/// The pairs' rays as runs: the listed blocks `order` (indices into `groups`) one after the
/// other, each one's rays (in scan order) cut where the next is not the ray after; per run its
/// first ray and its first pair, then the total, as `[ray, pair]` (a sentinel `[0, total]`).
/// Neighbouring returns cross the same blocks, so a run holds several pairs: 12 on average on
/// KITTI 00/0's scan, 4.9 on a synthetic city's, at 10 cm.
fn ray_runs(
    plan: &LidarPlan,
    groups: &[(BlockIndex, Range<usize>)],
    order: &[usize],
) -> Vec<[u32; 2]> {
    let mut runs = Vec::new();
    let mut at = 0u32;
    for &b in order {
        let pairs = &plan.pairs()[groups[b].1.clone()];
        runs.extend(run_starts(pairs).map(|i| [pairs[i].1, at + i as u32]));
        at += pairs.len() as u32;
    }
    runs.push([0, at]);
    runs
}

/// Bytes of one ray as the device keeps it for the pairs: direction and range (4 × f64).
const RAY_F64_BYTES: u64 = 32;

/// Whether the device can make this scan's rays: they fit one binding (else the host prepares
/// the pairs, numbering only the rays of each batch).
pub(super) fn fits(ctx: &GpuContext, plan: &LidarPlan) -> bool {
    plan.ray_count() as u64 * RAY_F64_BYTES <= ctx.max_binding_bytes()
}

/// Uploads the scan's rays and the pairs' runs of rays (the listed blocks `order`, indices into
/// `groups`, each one's pairs in plan order) into `kept`'s buffers and records the kernels that
/// make the rays and pairs into `encoder`. `offsets` and `keys` are the listed blocks' first
/// pairs (and the total) and positions, as uploaded for the lookup; `counters[1]` counts what
/// could not be made.
pub(super) fn record_device_pairs(
    (ctx, kept, encoder): (&GpuContext, &mut Kept, &mut wgpu::CommandEncoder),
    (grid, plan): (&GridParams, &LidarPlan),
    (groups, order): (&[(BlockIndex, Range<usize>)], &[usize]),
    [offsets, keys, counters]: [&wgpu::Buffer; 3],
) -> Result<DevicePairs> {
    let total: usize = order.iter().map(|&b| groups[b].1.len()).sum();
    let rays = plan.rays();
    let runs = ray_runs(plan, groups, order);
    let words = scan_words(grid, plan, [total, order.len(), runs.len() - 1]);
    let ray_words: Vec<u32> = rays
        .iter()
        .flat_map(|r| {
            let [x, y, z] = r.point_sensor_m.map(f32::to_bits);
            [x, y, z, r.gray as u32]
        })
        .collect();
    ctx.check_binding(
        "LiDAR rays (16 bytes per ray)",
        rays.len() as u64 * RAY_IN_BYTES,
    )?;
    let pair_bytes = total as u64 * std::mem::size_of::<GpuLidarPair>() as u64;
    ctx.check_binding("LiDAR (block, ray) pairs (28 bytes per pair)", pair_bytes)?;
    let buf_scan = kept.storage_with(ctx, "lidar_scan_words", bytemuck::cast_slice(&words));
    let buf_rays = kept.storage_with(ctx, "lidar_rays_in", bytemuck::cast_slice(&ray_words));
    let buf_runs = kept.storage_with(ctx, "lidar_ray_runs", bytemuck::cast_slice(&runs));
    let buf_rays_f64 = kept.scratch(ctx, "lidar_rays_f64", rays.len() as u64 * RAY_F64_BYTES);
    let dir_bytes = (rays.len() * std::mem::size_of::<GpuRayDir>()) as u64;
    let buf_dirs = kept.scratch(ctx, "lidar_ray_dirs", dir_bytes);
    let buf_pairs = kept.scratch(ctx, "lidar_pairs", pair_bytes);
    let make_rays = ctx.kernel(&shaders::LIDAR_RAYS)?;
    let make_pairs = ctx.kernel(&shaders::LIDAR_PAIRS)?;
    let bind_rays = kept.bind_group(
        ctx,
        "lidar_rays",
        &make_rays.layout,
        &[&buf_scan, &buf_rays, &buf_rays_f64, &buf_dirs, counters],
    );
    let bind_pairs = kept.bind_group(
        ctx,
        "lidar_pairs",
        &make_pairs.layout,
        &[
            &buf_scan,
            &buf_rays_f64,
            &buf_runs,
            offsets,
            keys,
            &buf_pairs,
            counters,
        ],
    );
    ctx.record_dispatch(encoder, &make_rays, &bind_rays, rays.len() as u64)?;
    ctx.record_dispatch(encoder, &make_pairs, &bind_pairs, total as u64)?;
    Ok(DevicePairs {
        pairs: buf_pairs,
        dirs: buf_dirs,
        rays_per_pass: (LOOP_BUDGET / (MAX_WALK_STEPS + 1)).max(1),
    })
}

/// What the device makes of `plan`'s rays and pairs (for the tests): every pair in plan order
/// (blocks sorted, each one's rays in scan order), every ray's direction and grey level, and
/// how many rays and pairs it could not make. Creates its buffers and waits.
pub fn lidar_pairs_on_gpu(
    ctx: &GpuContext,
    grid: &GridParams,
    plan: &LidarPlan,
) -> Result<(Vec<GpuLidarPair>, Vec<GpuRayDir>, u32)> {
    if plan.pair_count() == 0 {
        return Ok((Vec::new(), Vec::new(), 0));
    }
    let groups = plan.groups();
    let order: Vec<usize> = (0..groups.len()).collect();
    let mut offsets = vec![0u32];
    for g in &groups {
        offsets.push(offsets.last().copied().unwrap_or(0) + g.1.len() as u32);
    }
    let keys: Vec<[i32; 4]> = groups
        .iter()
        .map(|g| [g.0 .0[0], g.0 .0[1], g.0 .0[2], 0])
        .collect();
    let kept = &mut Kept::default();
    let buf_offsets = kept.storage_with(ctx, "offsets", bytemuck::cast_slice(&offsets));
    let buf_keys = kept.storage_with(ctx, "keys", bytemuck::cast_slice(&keys));
    let buf_counters = kept.storage_with(ctx, "counters", &[0u8; 16]);
    let mut encoder = ctx.encoder("lidar_pairs_on_gpu");
    let made = record_device_pairs(
        (ctx, kept, &mut encoder),
        (grid, plan),
        (&groups, &order),
        [&buf_offsets, &buf_keys, &buf_counters],
    )?;
    let mut pairs: Vec<GpuLidarPair> = bytemuck::zeroed_vec(plan.pair_count());
    let mut dirs: Vec<GpuRayDir> = bytemuck::zeroed_vec(plan.ray_count());
    let mut counters = [0u32; 4];
    ctx.submit_and_read_back(
        encoder,
        kept,
        &mut [
            (&made.pairs, bytemuck::cast_slice_mut(&mut pairs)),
            (&made.dirs, bytemuck::cast_slice_mut(&mut dirs)),
            (&buf_counters, bytemuck::cast_slice_mut(&mut counters)),
        ],
    )?;
    Ok((pairs, dirs, counters[1]))
}

/// The host's preparation of the same (its CPU twin): every pair of `plan` in plan order as
/// [`super::block_local_ray`] and [`GpuLidarPair::pack`] make it (`None` where it does not
/// pack), and every ray's direction and grey level.
pub fn lidar_pairs_on_cpu(
    grid: &GridParams,
    plan: &LidarPlan,
) -> (Vec<Option<GpuLidarPair>>, Vec<GpuRayDir>) {
    let pairs = super::lidar_gpu::block_local_rays(grid, plan, 0..plan.pair_count())
        .iter()
        .map(|(ray, k)| GpuLidarPair::pack(ray, *k))
        .collect();
    let dirs = plan.rays().iter().map(super::lidar_gpu::ray_dir).collect();
    (pairs, dirs)
}
