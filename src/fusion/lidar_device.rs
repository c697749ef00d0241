//! A LiDAR scan's rays and (block, ray) pairs made on the device, so that a resident scan
//! ([`super::integrate_lidar_resident`]) sends 16 bytes per ray and the listed blocks (their
//! positions and how many pairs each has, 20 bytes a block) instead of the host's 16 per ray
//! and 28 per pair. Each ray goes up as its point as scanned and its grey level;
//! `shaders/lidar_rays.wgsl` measures and rotates the rays as [`super::LidarPlan`] does,
//! `shaders/lidar_list.wgsl` walks each ray's band through the blocks as the host's listing
//! does (`traverse_cells`) and writes the ray among each crossed block's pairs (found through a
//! hash table of the listed blocks, `shaders/lidar_listed.wgsl`, at a place taken by an atomic
//! counter), `shaders/lidar_rank.wgsl` puts each block's rays in scan order (each one's rank
//! among its block's), and `shaders/lidar_pairs.wgsl` makes each pair's walk as
//! [`super::block_local_ray`] and [`GpuLidarPair::pack`] do. The arithmetic is exact f64
//! (`shaders/shared/exact_f64.wgsl`, [`crate::gpu::exact_f64`]): the same values bit for bit on
//! any device, the same pairs in the same order, so the fusion's result is the host-prepared
//! one's.
//!
//! The blocks and their pair counts come from the plan: the device's own listing
//! (`super::lidar_listing`, which leaves the rays on the device: [`record_rays`]) or the
//! host's. The passes are sized by [`MAX_WALK_STEPS`], a bound on every walk, instead of the
//! longest one (which only the device knows): more, shorter passes on llvmpipe, the same
//! updates in the same order.

use super::depth_keys::pack_offset;
use super::lidar_gpu::{dispatch_order, LOOP_BUDGET};
use super::LidarPlan;
use crate::gpu::kept::Kept;
use crate::gpu::layout::{GpuLidarPair, GpuRayDir};
use crate::gpu::Kernel;
use crate::gpu::{shaders, GpuContext};
use crate::grid::{BlockIndex, GridParams};
use crate::Result;
use std::ops::Range;
use std::sync::Arc;

/// The most cells a pair's walk visits: it spans at most the block's diagonal and a voxel at
/// either end (8√3 + 2 voxels), so at most 31 cells; the kernel counts a pair beyond this bound
/// as not made (never), and the passes apply `LOOP_BUDGET / (MAX_WALK_STEPS + 1)` rays of each
/// block (keep in sync with `shaders/lidar_pairs.wgsl`).
pub const MAX_WALK_STEPS: u32 = 49;

/// Bytes of one ray as it goes up: its point (3 × f32) and grey level (u32).
const RAY_IN_BYTES: u64 = 16;

/// Where the device made the scan's walks: the pairs (in dispatch order, as the fusion kernel
/// reads them), the rays' directions and grey levels, the listed blocks' positions and first
/// pairs (in dispatch order, for the lookup and the passes), and the rays each pass applies
/// per block; and the listed blocks as they went up (`sent`, in dispatch order), with the
/// block they count from and the words per block (`sent_origin`: xyz and w, as
/// [`crate::gpu::layout::FrameKeyUniforms::origin`] reads them), from which
/// `table_insert.wgsl` inserts the new ones.
pub(super) struct DevicePairs {
    pub(super) pairs: wgpu::Buffer,
    pub(super) dirs: wgpu::Buffer,
    pub(super) keys: wgpu::Buffer,
    pub(super) offsets: wgpu::Buffer,
    pub(super) rays_per_pass: u32,
    pub(super) sent: wgpu::Buffer,
    pub(super) sent_origin: [i32; 4],
}

/// The sensor's block, from which the listed blocks' offsets count.
pub(super) fn sensor_block(grid: &GridParams, plan: &LidarPlan) -> [i32; 3] {
    let o = plan.origin_m();
    [0, 1, 2].map(|a| (o[a] / grid.block_size_m()).floor() as i32)
}

/// The scan's constants as `shaders/shared/lidar_scan.wgsl` reads them.
pub(super) fn scan_words(
    (grid, plan): (&GridParams, &LidarPlan),
    [pairs, blocks, mask]: [usize; 3],
    (origin, key_words, found_entries): ([i32; 3], u32, u32),
) -> Vec<u32> {
    let vs = grid.voxel_size_m as f64;
    let [i, j, k, w] = plan.rotation_ijkw();
    let o = plan.origin_m();
    let f64_words = |values: &[f64]| -> Vec<u32> {
        values
            .iter()
            .flat_map(|v| [v.to_bits() as u32, (v.to_bits() >> 32) as u32])
            .collect()
    };
    let mu = grid.truncation_m as f64;
    let mut words = f64_words(&[o[0], o[1], o[2], i, j, k, w, vs, mu, 1.0 / vs]);
    words.extend([plan.ray_count(), pairs, blocks, mask].map(|n| n as u32));
    // The host's listing walks blocks of this size (`block_ray_pairs`, `traverse_cells`).
    let block = grid.block_size_m();
    words.extend(f64_words(&[block, 1.0 / block]));
    words.extend(origin.map(|c| c as u32));
    words.extend([key_words, found_entries]);
    words
}

/// The listed blocks `order` (indices into `groups`) as they go up: each one's offset from
/// `origin` packed in one word ([`pack_offset`]) where every offset packs, else its position in
/// three; and the words per block.
fn sent_keys(
    groups: &[(BlockIndex, Range<usize>)],
    order: &[usize],
    origin: [i32; 3],
) -> (Vec<u32>, u32) {
    let offset = |b: usize| [0, 1, 2].map(|a| groups[b].0 .0[a] - origin[a]);
    let packed: Option<Vec<u32>> = order.iter().map(|&b| pack_offset(offset(b))).collect();
    match packed {
        Some(words) => (words, 1),
        None => {
            let wide = order.iter().flat_map(|&b| groups[b].0 .0.map(|c| c as u32));
            (wide.collect(), 3)
        }
    }
}

/// Entries of the listed blocks' hash table (`shaders/lidar_listed.wgsl`): a power of two, at
/// least twice the blocks.
fn listed_capacity(blocks: usize) -> usize {
    (2 * blocks).next_power_of_two().max(64)
}

/// Bytes of one ray as the device keeps it for the pairs: direction and range (4 × f64).
const RAY_F64_BYTES: u64 = 32;

/// Whether the device can make this scan's rays and pairs: the rays fit one binding and no
/// block has more pairs than `lidar_rank.wgsl` reads in one invocation (else the host prepares
/// the pairs, numbering only the rays of each batch).
pub(super) fn fits(
    ctx: &GpuContext,
    plan: &LidarPlan,
    groups: &[(BlockIndex, Range<usize>)],
) -> bool {
    let most = groups.iter().map(|g| g.1.len()).max().unwrap_or(0);
    rays_fit(ctx, plan) && most <= LOOP_BUDGET as usize
}

/// Whether the scan's rays, as the device keeps them, fit one binding.
pub(super) fn rays_fit(ctx: &GpuContext, plan: &LidarPlan) -> bool {
    plan.ray_count() as u64 * RAY_F64_BYTES <= ctx.max_binding_bytes()
}

/// Where a scan's rays on the device come from ([`record_rays`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum RaysFrom {
    /// A device listing of this scan made them already.
    Listed,
    /// Sent up for a device listing: into a buffer of the listing's own, so that a listing
    /// may share a submit with the fusion of the scan before, whose rays may be sent up too.
    Listing,
    /// Sent up for the scan's fusion.
    Fusion,
}

/// Uploads the scan's rays (16 bytes each) into `kept`'s buffers and records into `encoder` the
/// kernel that measures and rotates them (`lidar_rays.wgsl`, reading the scan's words
/// `buf_scan`); returns the rays' f64 words and their directions. Where [`RaysFrom::Listed`], a
/// listing ([`super::lidar_listing`]) recorded it for this scan already: the kept buffers are
/// returned as they are, nothing recorded.
pub(super) fn record_rays(
    (ctx, kept, encoder): (&GpuContext, &mut Kept, &mut wgpu::CommandEncoder),
    plan: &LidarPlan,
    (buf_scan, counters): (&wgpu::Buffer, &wgpu::Buffer),
    from: RaysFrom,
) -> Result<(wgpu::Buffer, wgpu::Buffer)> {
    let rays = plan.sent_rays();
    ctx.check_binding(
        "LiDAR rays (16 bytes per ray)",
        rays.len() as u64 * RAY_IN_BYTES,
    )?;
    let buf_rays_f64 = kept.scratch(ctx, "lidar_rays_f64", rays.len() as u64 * RAY_F64_BYTES);
    let dir_bytes = (rays.len() * std::mem::size_of::<GpuRayDir>()) as u64;
    let buf_dirs = kept.scratch(ctx, "lidar_ray_dirs", dir_bytes);
    let (label, bind_label) = match from {
        RaysFrom::Listed => return Ok((buf_rays_f64, buf_dirs)),
        RaysFrom::Listing => ("lidar_listing_rays_in", "lidar_listing_rays"),
        RaysFrom::Fusion => ("lidar_rays_in", "lidar_rays"),
    };
    // The plan keeps them as they go up: one copy into the memory that goes up.
    let buf_rays = kept.storage_with(ctx, label, bytemuck::cast_slice(rays));
    let kernel = ctx.kernel(&shaders::LIDAR_RAYS)?;
    let buffers = [buf_scan, &buf_rays, &buf_rays_f64, &buf_dirs, counters];
    let bind = kept.bind_group(ctx, bind_label, &kernel.layout, &buffers);
    ctx.record_dispatch(encoder, &kernel, &bind, rays.len() as u64)?;
    Ok((buf_rays_f64, buf_dirs))
}

/// Uploads the scan's rays and the listed blocks `order` (indices into `groups`, by decreasing
/// pair count: [`super::lidar_gpu::dispatch_order`]) into `kept`'s buffers and records into
/// `encoder` the kernels that make the rays, count and list each block's pairs, order them and
/// make their walks. Where `listing` (the entries of the table of the device's own listing of
/// this scan, `super::lidar_listing`), the rays it left are used ([`record_rays`]) and the
/// counts read from its table instead of walking the rays again. What goes up is 16 bytes per ray
/// and 4 per block (12 where a block's offset from the sensor's does not pack); `counters[1]`
/// counts what could not be made.
pub(super) fn record_device_pairs(
    (ctx, kept, encoder): (&GpuContext, &mut Kept, &mut wgpu::CommandEncoder),
    (grid, plan): (&GridParams, &LidarPlan),
    (groups, order): (&[(BlockIndex, Range<usize>)], &[usize]),
    (counters, listing): (&wgpu::Buffer, Option<u32>),
) -> Result<DevicePairs> {
    let total: usize = order.iter().map(|&b| groups[b].1.len()).sum();
    let n = order.len();
    let capacity = listed_capacity(n);
    let origin = sensor_block(grid, plan);
    let (key_words, width) = sent_keys(groups, order, origin);
    let found_entries = listing.unwrap_or(0);
    let words = scan_words(
        (grid, plan),
        [total, n, capacity - 1],
        (origin, width, found_entries),
    );
    let pair_bytes = total as u64 * std::mem::size_of::<GpuLidarPair>() as u64;
    ctx.check_binding("LiDAR (block, ray) pairs (28 bytes per pair)", pair_bytes)?;
    ctx.check_binding("block keys (16 bytes per block)", n as u64 * 16)?;
    let buf_scan = kept.storage_with(ctx, "lidar_scan_words", bytemuck::cast_slice(&words));
    let (buf_rays_f64, buf_dirs) = record_rays(
        (ctx, &mut *kept, &mut *encoder),
        plan,
        (&buf_scan, counters),
        match listing {
            Some(_) => RaysFrom::Listed,
            None => RaysFrom::Fusion,
        },
    )?;
    let buf_sent = kept.storage_with(ctx, "lidar_sent_keys", bytemuck::cast_slice(&key_words));
    let buf_keys = kept.scratch(ctx, "lidar_block_keys", n as u64 * 16);
    let buf_offsets = kept.scratch(ctx, "lidar_pair_offsets", (n as u64 + 1) * 4);
    let listed_bytes = capacity as u64 * 4;
    let buf_listed = kept.scratch(ctx, "lidar_listed", listed_bytes);
    let fill_bytes = n as u64 * 4;
    let buf_fill = kept.scratch(ctx, "lidar_fill", fill_bytes);
    let buf_unsorted = kept.scratch(ctx, "lidar_unsorted_rays", total as u64 * 4);
    let buf_pair_rays = kept.scratch(ctx, "lidar_pair_rays", total as u64 * 4);
    let buf_pairs = kept.scratch(ctx, "lidar_pairs", pair_bytes);
    // The listing's table (`lidar_listing.rs`), whose counts `lidar_listed.wgsl` reads where
    // the device listed the scan; unread else.
    let found_bytes = (found_entries as u64 * 8).max(8);
    let buf_found = kept.scratch(ctx, "lidar_found_table", found_bytes);
    let kernel = |src| ctx.kernel(src);
    let walk = [
        &buf_scan,
        &buf_offsets,
        &buf_rays_f64,
        counters,
        &buf_keys,
        &buf_listed,
        &buf_fill,
    ];
    let mut list = walk.to_vec();
    list.push(&buf_unsorted);
    // In order.
    let steps: [(&'static str, Arc<Kernel>, Vec<&wgpu::Buffer>, usize); 7] = [
        (
            "lidar_listed",
            kernel(&shaders::LIDAR_LISTED)?,
            vec![
                &buf_scan,
                &buf_sent,
                &buf_keys,
                &buf_listed,
                counters,
                &buf_found,
                &buf_fill,
            ],
            n,
        ),
        (
            "lidar_count",
            kernel(&shaders::LIDAR_COUNT)?,
            walk.to_vec(),
            plan.ray_count(),
        ),
        (
            "lidar_prefix",
            kernel(&shaders::LIDAR_PREFIX)?,
            vec![&buf_scan, &buf_fill, &buf_offsets, counters],
            64,
        ),
        (
            "lidar_list",
            kernel(&shaders::LIDAR_LIST)?,
            list,
            plan.ray_count(),
        ),
        (
            "lidar_sort",
            kernel(&shaders::LIDAR_SORT)?,
            vec![
                &buf_scan,
                &buf_offsets,
                &buf_fill,
                &buf_unsorted,
                &buf_pair_rays,
            ],
            n * 64,
        ),
        (
            "lidar_rank",
            kernel(&shaders::LIDAR_RANK)?,
            vec![
                &buf_scan,
                &buf_offsets,
                &buf_fill,
                &buf_unsorted,
                &buf_pair_rays,
                counters,
            ],
            total,
        ),
        (
            "lidar_pairs",
            kernel(&shaders::LIDAR_PAIRS)?,
            vec![
                &buf_scan,
                &buf_offsets,
                &buf_rays_f64,
                &buf_pair_rays,
                &buf_keys,
                &buf_pairs,
                counters,
            ],
            total,
        ),
    ];
    // The table and the counts start empty on the device.
    encoder.clear_buffer(&buf_listed, 0, Some(listed_bytes));
    encoder.clear_buffer(&buf_fill, 0, Some(fill_bytes));
    for (label, kernel, buffers, invocations) in &steps {
        // Where the device listed the scan, `lidar_listed` read the counts from its table.
        if kernel.name == "lidar_count" && listing.is_some() {
            continue;
        }
        // The listing counts the rays it writes from zero again.
        if kernel.name == "lidar_list" {
            encoder.clear_buffer(&buf_fill, 0, Some(fill_bytes));
        }
        let bind = kept.bind_group(ctx, label, &kernel.layout, buffers);
        ctx.record_dispatch(encoder, kernel, &bind, *invocations as u64)?;
    }
    Ok(DevicePairs {
        pairs: buf_pairs,
        dirs: buf_dirs,
        keys: buf_keys,
        offsets: buf_offsets,
        rays_per_pass: (LOOP_BUDGET / (MAX_WALK_STEPS + 1)).max(1),
        sent: buf_sent,
        // Three words are a block's position itself, counted from block (0, 0, 0).
        sent_origin: match width {
            1 => [origin[0], origin[1], origin[2], 1],
            _ => [0, 0, 0, 3],
        },
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
    // In dispatch order on the device, put back in plan order below.
    let (order, offsets) = dispatch_order(&groups, 0..groups.len());
    let kept = &mut Kept::default();
    let buf_counters = kept.storage_with(ctx, "counters", &[0u8; 16]);
    let mut encoder = ctx.encoder("lidar_pairs_on_gpu");
    let made = record_device_pairs(
        (ctx, kept, &mut encoder),
        (grid, plan),
        (&groups, &order),
        (&buf_counters, None),
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
    let mut in_plan_order = Vec::with_capacity(pairs.len());
    let mut place = vec![0; groups.len()];
    for (k, &b) in order.iter().enumerate() {
        place[b] = k;
    }
    for p in place {
        in_plan_order.extend_from_slice(&pairs[offsets[p] as usize..offsets[p + 1] as usize]);
    }
    Ok((in_plan_order, dirs, counters[1]))
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
