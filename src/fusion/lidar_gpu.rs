//! Ray-wise LiDAR TSDF fusion on the GPU: `shaders/fuse_lidar.wgsl` applies
//! [`crate::fusion::integrate_lidar_plan`]'s update (every voxel a ray traverses inside its
//! truncation band gets `Block::fuse(min(sdf, μ)/μ, grey)`) to the blocks of a [`LidarPlan`].
//! Block listing stays on the CPU (the plan); the blocks are checked out of the layer, packed
//! into [`GpuVoxel`]s, updated by one invocation per block that applies the block's rays in
//! scan order (deterministic), read back, and checked in only after every batch succeeded.
//! Within a batch the blocks are dispatched by decreasing ray count, so that invocations
//! running in lockstep (SIMD lanes, warps) do similar work; a block's result does not depend
//! on its place. Rays are applied in passes of at most `LOOP_BUDGET / (longest walk + 1)` rays
//! per block (one dispatch each, in order): llvmpipe silently ends the loops of an invocation
//! after 65 535 iterations in all, which a block under the car (~10 000 rays) exceeded.
//! The start cell and the walk's length in cells are decided in f64 as the reference decides
//! them, so rays running exactly in a voxel face start on the same side.
//!
//! WGSL has no f64, and a world-frame f32 walk would lose centimetres kilometres from the
//! origin. So each (block, ray) pair is prepared on the CPU in f64 as a [`GpuLidarRay`] in the
//! block's own voxel coordinates ([`block_local_ray`]; it goes up as a 28-byte
//! [`GpuLidarPair`], its ray's direction and grey level once per ray as a [`GpuRayDir`]): the
//! walk starts one voxel before the ray
//! enters the block (or at the band's start) and ends one voxel after it leaves (or at the band's
//! end), and the signed distance is carried from the start point. The kernel then walks in f32
//! with values below ~10 voxels. [`walk_block_ray`] is its CPU twin (same f32 operations in the
//! same order) and the CPU's own LiDAR walk ([`crate::fusion::integrate_lidar_plan`]); on
//! lavapipe the GPU equals it bit for bit (`tests/gpu/lidar.rs`).
//!
//! Against the f64 reference ([`crate::fusion::integrate_lidar_reference`]) the f32 walk
//! differs only where f64 and f32 round differently: a ray passing within ~1e-6 voxel of a
//! voxel edge or corner (the walk may step through the other neighbour), a band end or a start
//! point that close to a voxel face, and the last quantisation step of the TSDF (sdf differs by
//! ~1e-7 m). `tests/gpu/lidar.rs` measures it and states the tolerance.

use crate::fusion::lidar::Ray;
use crate::fusion::{band_m, FusionStats, LidarPlan};
use crate::gpu::kept::Kept;
use crate::gpu::layout::{
    apply_updated, pack_block_into, GpuLidarPair, GpuLidarRay, GpuRayDir, GpuVoxel, LidarUniforms,
};
use crate::gpu::shaders;
use crate::gpu::{ErrorScopes, GpuContext, Kernel};
use crate::grid::{
    floor_i64, linear_index, Block, BlockIndex, GridParams, Layer, TouchedBlocks, VOXELS_PER_BLOCK,
    VOXELS_PER_SIDE,
};
use crate::{Error, Result};
use rayon::prelude::*;
use std::ops::Range;

/// Crossing parameter of an axis the ray does not move along (`NEVER` in the kernel).
const NEVER: f32 = 3.0e38;

/// Loop iterations one invocation may run: llvmpipe (gallivm) ends every loop of an invocation
/// after 65 535 iterations in all (`LP_MAX_TGSI_LOOP_ITERATIONS`, shared by every loop of a
/// shader), silently. Each ray costs one iteration plus one per cell of its walk, so a pass
/// applies at most `LOOP_BUDGET / (longest walk + 1)` rays of each block.
pub(super) const LOOP_BUDGET: u32 = 60_000;

/// Bytes of one block of [`GpuVoxel`]s.
const BLOCK_BYTES: u64 = (VOXELS_PER_BLOCK * std::mem::size_of::<GpuVoxel>()) as u64;
/// Bytes of one [`GpuLidarPair`] (keep the 28 in the messages in sync).
pub(super) const PAIR_BYTES: u64 = std::mem::size_of::<GpuLidarPair>() as u64;
/// Bytes of one [`GpuRayDir`].
const RAY_DIR_BYTES: usize = std::mem::size_of::<GpuRayDir>();

/// The walk of the ray from `origin_m` along the unit `dir` with return at `range_m` through
/// `block`, in the block's voxel coordinates (computed in f64, stored in f32): it covers the
/// ray's truncation band clipped to the block, widened by one voxel at either end (within the
/// band) so that the start and end cells never hinge on rounding at the block's faces.
pub fn block_local_ray(
    grid: &GridParams,
    origin_m: [f64; 3],
    dir: [f64; 3],
    range_m: f64,
    gray: u8,
    block: BlockIndex,
) -> GpuLidarRay {
    let vs = grid.voxel_size_m as f64;
    let (t0, t1) = band_m(range_m, grid.truncation_m as f64);
    let lo_corner = grid.block_origin(block);
    let size = grid.block_size_m();
    // Slab clip of the band to the block.
    let (mut lo, mut hi) = (t0, t1);
    for a in 0..3 {
        if dir[a] != 0.0 {
            let ta = (lo_corner[a] - origin_m[a]) / dir[a];
            let tb = (lo_corner[a] + size - origin_m[a]) / dir[a];
            lo = lo.max(ta.min(tb));
            hi = hi.min(ta.max(tb));
        }
    }
    let ta = (lo - vs).max(t0);
    let tb = (hi + vs).min(t1);
    // End cells as `traverse_cells` computes them (world point times the inverse cell size):
    // at the band's ends they are the reference's own.
    let inv_cell = 1.0 / vs;
    let side = VOXELS_PER_SIDE as i64;
    let first = [0, 1, 2].map(|a| floor_i64((origin_m[a] + ta * dir[a]) * inv_cell));
    let last = [0, 1, 2].map(|a| floor_i64((origin_m[a] + tb * dir[a]) * inv_cell));
    let steps: i64 = (0..3).map(|a| (last[a] - first[a]).abs()).sum::<i64>() + 1;
    GpuLidarRay {
        start_vox: [0, 1, 2].map(|a| ((origin_m[a] + ta * dir[a] - lo_corner[a]) / vs) as f32),
        dir: dir.map(|d| d as f32),
        sdf_start_m: (range_m - ta) as f32,
        len_vox: ((tb - ta) / vs) as f32,
        start_cell: [0, 1, 2].map(|a| (first[a] - block.0[a] as i64 * side) as i32),
        steps: if tb >= ta { steps as u32 } else { 0 },
        gray: gray as u32,
    }
}

/// Walks `ray` through its block in f32 (Amanatides–Woo, with the f64 reference's choice of
/// axis at ties) and calls `update(i, t)` for every voxel of the block it visits whose signed
/// distance is ≥ −μ, in order: `i` the voxel's linear index, `t = min(sdf, μ)/μ`. This is the
/// CPU twin of `apply_ray` in `shaders/fuse_lidar.wgsl` (keep the operations and their order in
/// sync). Returns the number of updates.
pub fn walk_block_ray(
    ray: &GpuLidarRay,
    truncation_m: f32,
    voxel_size_m: f32,
    mut update: impl FnMut(usize, f32),
) -> u32 {
    let len = ray.len_vox;
    if len < 0.0 {
        return 0;
    }
    let s = ray.start_vox;
    let d = ray.dir;
    let mut cell = ray.start_cell;
    let mut step = [0i32; 3];
    let mut t_max = [NEVER; 3];
    let mut t_delta = [NEVER; 3];
    for a in 0..3 {
        if d[a] > 0.0 {
            let inv = 1.0 / d[a];
            step[a] = 1;
            t_max[a] = ((cell[a] + 1) as f32 - s[a]) * inv;
            t_delta[a] = inv;
        } else if d[a] < 0.0 {
            let inv = 1.0 / d[a];
            step[a] = -1;
            t_max[a] = (cell[a] as f32 - s[a]) * inv;
            t_delta[a] = -inv;
        }
    }
    let mut remaining = ray.steps;
    let side = VOXELS_PER_SIDE as i32;
    let mut n = 0;
    while remaining > 0 {
        if cell.iter().all(|&c| (0..side).contains(&c)) {
            let c = [0, 1, 2].map(|a| cell[a] as f32 + 0.5 - s[a]);
            let tc = c[0] * d[0] + c[1] * d[1] + c[2] * d[2];
            let sdf = ray.sdf_start_m - tc * voxel_size_m;
            if sdf >= -truncation_m {
                let t = sdf.min(truncation_m) / truncation_m;
                update(
                    linear_index(cell[0] as usize, cell[1] as usize, cell[2] as usize),
                    t,
                );
                n += 1;
            }
        }
        remaining -= 1;
        let a = if t_max[0] < t_max[1] {
            if t_max[0] < t_max[2] {
                0
            } else {
                2
            }
        } else if t_max[1] < t_max[2] {
            1
        } else {
            2
        };
        if t_max[a] > len {
            break;
        }
        cell[a] += step[a];
        t_max[a] += t_delta[a];
    }
    n
}

/// A ray's direction (as f32) and grey level, as they go up.
pub(super) fn ray_dir(r: &Ray) -> GpuRayDir {
    GpuRayDir {
        dir: r.dir.map(|d| d as f32),
        gray: r.gray as u32,
    }
}

/// The pairs of `range` (one block's, in scan order) as [`GpuLidarRay`]s, with their rays'
/// indices.
pub(super) fn block_local_rays(
    grid: &GridParams,
    plan: &LidarPlan,
    range: Range<usize>,
) -> Vec<(GpuLidarRay, u32)> {
    let origin = plan.origin_m();
    let rays = plan.rays();
    plan.pairs()[range]
        .iter()
        .map(|&(block, k)| {
            let r = &rays[k as usize];
            let ray = block_local_ray(grid, origin, r.dir, r.range_m, r.gray, block);
            (ray, k)
        })
        .collect()
}

/// The (block, ray) pairs of the listed blocks `order` (indices into `groups`, `total` pairs in
/// all) in that order, as [`GpuLidarPair`]s written straight into the memory that goes up, a
/// block per task ([`filled`]), and the rays they refer to as [`GpuRayDir`]s (16 bytes each: every ray of
/// `plan` when they fit one binding, else those of these blocks, numbered afresh); in `kept`'s
/// buffers when given, else new ones. Returns both buffers and the rays a pass may apply per
/// block (`LOOP_BUDGET / (longest walk + 1)`).
pub(super) fn upload_rays(
    (ctx, mut kept): (&GpuContext, Option<&mut Kept>),
    grid: &GridParams,
    (plan, groups): (&LidarPlan, &[(BlockIndex, Range<usize>)]),
    order: &[usize],
    total: u32,
) -> Result<(wgpu::Buffer, wgpu::Buffer, u32)> {
    let count = |b: usize| groups[b].1.len();
    let rays = plan.rays();
    // The rays uploaded, and each plan ray's number among them when they are not all.
    let (uploaded, renumbered): (Vec<u32>, Option<Vec<u32>>) =
        if ((rays.len() * RAY_DIR_BYTES) as u64) <= ctx.max_binding_bytes() {
            ((0..rays.len() as u32).collect(), None)
        } else {
            let mut number = vec![u32::MAX; rays.len()];
            let mut uploaded = Vec::new();
            for &b in order {
                for &(_, k) in &plan.pairs()[groups[b].1.clone()] {
                    if number[k as usize] == u32::MAX {
                        number[k as usize] = uploaded.len() as u32;
                        uploaded.push(k);
                    }
                }
            }
            (uploaded, Some(number))
        };
    // At most one ray per pair: 16 bytes where its pair has 28.
    ctx.check_binding(
        "LiDAR ray directions (16 bytes per ray)",
        (uploaded.len() * RAY_DIR_BYTES) as u64,
    )?;
    let mut longest_walk = 0u32;
    let mut unpacked = 0usize;
    let fill = |out: wgpu::WriteOnly<'_, [u8]>| {
        (longest_walk, unpacked) = pair_slots(out, order.iter().map(|&b| count(b)))
            .into_par_iter()
            .zip(order.par_iter())
            .map(|(slots, &b)| {
                let (mut longest, mut unpacked) = (0u32, 0usize);
                let rays = block_local_rays(grid, plan, groups[b].1.clone());
                for (slot, (ray, k)) in slots.into_iter().zip(&rays) {
                    longest = longest.max(ray.steps);
                    let index = renumbered.as_ref().map_or(*k, |n| n[*k as usize]);
                    match GpuLidarPair::pack(ray, index) {
                        Some(pair) => slot.write(bytemuck::cast(pair)),
                        None => unpacked += 1,
                    }
                }
                (longest, unpacked)
            })
            .reduce(|| (0, 0), |a, b| (a.0.max(b.0), a.1 + b.1));
    };
    let pair_bytes = total as u64 * PAIR_BYTES;
    let buf_pairs = filled((ctx, &mut kept), "lidar_pairs", pair_bytes, fill)?;
    if unpacked > 0 {
        return Err(Error::Gpu(format!(
            "{unpacked} LiDAR (block, ray) walks have a start cell or step count that does not \
             fit their packed word"
        )));
    }
    let dir = |k: u32| ray_dir(&rays[k as usize]);
    let fill = |out: wgpu::WriteOnly<'_, [u8]>| {
        let (slots, _) = out.into_chunks::<RAY_DIR_BYTES>();
        let slots: Vec<_> = slots.into_iter().collect();
        (slots.into_par_iter())
            .zip(uploaded.par_iter())
            .for_each(|(slot, &k)| slot.write(bytemuck::cast(dir(k))));
    };
    let dir_bytes = (uploaded.len() * RAY_DIR_BYTES) as u64;
    let buf_dirs = filled((ctx, &mut kept), "lidar_ray_dirs", dir_bytes, fill)?;
    Ok((
        buf_pairs,
        buf_dirs,
        (LOOP_BUDGET / (longest_walk + 1)).max(1),
    ))
}

/// Records the passes of the LiDAR `kernel` over blocks listed by decreasing ray count (`counts`,
/// the dispatch order's): each pass applies at most `rays_per_pass` rays of every block that
/// still has rays (a prefix of the list). The kernel is bound (as `name`, in `kept`) to a kept
/// uniform buffer and `buffers` (bindings 1 on); the passes' uniforms are written once as a
/// table, and each pass's are copied from it into the uniform buffer on the device before its
/// dispatch, so the passes share one bind group and one submit. Passes run in order (wgpu orders
/// dispatches that write the same buffer), so each block's rays are applied in scan order.
pub(super) fn record_passes(
    (ctx, encoder, kept): (&GpuContext, &mut wgpu::CommandEncoder, &mut Kept),
    (kernel, name, buffers): (&Kernel, &'static str, &[&wgpu::Buffer]),
    grid: &GridParams,
    (counts, rays_per_pass): (&[u32], u32),
) -> Result<()> {
    let mut passes = Vec::new();
    let mut first_ray = 0u32;
    loop {
        let active = counts.partition_point(|&c| c > first_ray);
        if active == 0 {
            break;
        }
        passes.push(LidarUniforms {
            block_count: active as u32,
            truncation_m: grid.truncation_m,
            voxel_size_m: grid.voxel_size_m,
            first_ray,
            max_rays: rays_per_pass,
            pad: [0; 3],
        });
        first_ray += rays_per_pass;
    }
    if passes.is_empty() {
        return Ok(());
    }
    let table = kept.uniform_table(ctx, ("lidar_pass_uniforms", "lidar_uniforms"), &passes);
    let mut bound = vec![table.uniforms()];
    bound.extend_from_slice(buffers);
    let bind = kept.bind_group(ctx, name, &kernel.layout, &bound);
    for (k, pass) in passes.iter().enumerate() {
        table.select(encoder, k);
        ctx.record_dispatch(encoder, kernel, &bind, pass.block_count as u64)?;
    }
    Ok(())
}

/// The listed blocks (indices into `groups`) by decreasing ray count, and each one's first ray
/// in that order (one more offset at the end: the total). Invocations that run in lockstep
/// (SIMD lanes, warps) then have similar work, and the blocks with rays left for a pass are a
/// prefix; a block's result does not depend on its place.
pub(super) fn dispatch_order(
    groups: &[(BlockIndex, Range<usize>)],
    blocks: Range<usize>,
) -> (Vec<usize>, Vec<u32>) {
    // One u64 per block: its count complemented, then its index; distinct, so the unstable
    // sort keeps equal counts in block order, as a stable sort by decreasing count would.
    let mut keys: Vec<u64> = blocks
        .map(|b| (!(groups[b].1.len() as u32) as u64) << 32 | b as u64)
        .collect();
    keys.sort_unstable();
    let mut offsets = Vec::with_capacity(keys.len() + 1);
    let mut total = 0u32;
    let order = keys
        .iter()
        .map(|&key| {
            offsets.push(total);
            total += !((key >> 32) as u32);
            key as u32 as usize
        })
        .collect();
    offsets.push(total);
    (order, offsets)
}

/// A storage buffer `name` with `bytes` bytes written by `fill` straight into the memory that
/// goes up: `kept`'s buffer when given (through the kept staging memory), else a new one
/// (mapped at creation).
fn filled(
    (ctx, kept): (&GpuContext, &mut Option<&mut Kept>),
    name: &'static str,
    bytes: u64,
    fill: impl FnOnce(wgpu::WriteOnly<'_, [u8]>),
) -> Result<wgpu::Buffer> {
    match kept {
        Some(kept) => kept.storage_filled(ctx, name, bytes, fill),
        None => ctx.storage_filled(name, bytes, fill),
    }
}

/// `out` cut into its [`GpuLidarPair`]-sized pieces, grouped by `counts` (their sum at most the
/// pieces there are).
#[allow(clippy::type_complexity)]
fn pair_slots<'a>(
    out: wgpu::WriteOnly<'a, [u8]>,
    counts: impl Iterator<Item = usize>,
) -> Vec<Vec<wgpu::WriteOnly<'a, [u8; PAIR_BYTES as usize]>>> {
    let (slots, _) = out.into_chunks::<{ PAIR_BYTES as usize }>();
    let mut slots = slots.into_iter();
    counts.map(|n| slots.by_ref().take(n).collect()).collect()
}

/// Fuses the LiDAR scan planned in `plan` into `layer` on the GPU, like
/// [`crate::fusion::integrate_lidar_plan`] (same blocks listed, same counters): returns the
/// touched blocks (sorted) and work counters. Blocks go in batches that fit one storage binding
/// (4 KiB of voxels per block, 28 bytes per (block, ray) pair; 16 bytes per ray besides); a
/// single block whose voxels or rays exceed a binding is an [`Error::GpuCapacity`]. On error
/// the layer holds the blocks as before (nothing is written before every batch was read back).
pub fn integrate_lidar_gpu(
    ctx: &GpuContext,
    layer: &mut Layer,
    plan: &LidarPlan,
) -> Result<(TouchedBlocks, FusionStats)> {
    let grid = layer.params();
    let groups = plan.groups();
    let indices: Vec<BlockIndex> = groups.iter().map(|g| g.0).collect();
    super::update_checked_out(layer, &indices, plan.ray_count(), |taken| {
        fuse_blocks(ctx, &grid, plan, &groups, taken)
    })
}

/// Splits the blocks (`groups`, with their ray counts) into consecutive batches whose voxels,
/// rays and ray offsets each fit one binding of `cap_bytes`. A block that alone does not fit is
/// an [`Error::GpuCapacity`].
fn batches(ctx: &GpuContext, groups: &[(BlockIndex, Range<usize>)]) -> Result<Vec<Range<usize>>> {
    let cap = ctx.max_binding_bytes();
    let mut out = Vec::new();
    let mut start = 0;
    while start < groups.len() {
        let (mut end, mut rays) = (start, 0u64);
        while end < groups.len() {
            let blocks = (end - start + 1) as u64;
            let r = groups[end].1.len() as u64;
            if blocks * BLOCK_BYTES > cap || (rays + r) * PAIR_BYTES > cap || (blocks + 1) * 4 > cap
            {
                break;
            }
            rays += r;
            end += 1;
        }
        if end == start {
            let r = groups[start].1.len() as u64;
            ctx.check_binding("voxels of one block (4 KiB)", BLOCK_BYTES)?;
            ctx.check_binding("rays of one block (28 bytes per ray)", r * PAIR_BYTES)?;
            ctx.check_binding("ray offsets of one block", 8)?;
            return Err(Error::Gpu("batching LiDAR blocks: no progress".into()));
        }
        out.push(start..end);
        start = end;
    }
    Ok(out)
}

/// Runs the kernel over `blocks` (listed as `groups`) in batches; returns the number of voxel
/// updates. Blocks are only written once every batch was read back.
fn fuse_blocks(
    ctx: &GpuContext,
    grid: &GridParams,
    plan: &LidarPlan,
    groups: &[(BlockIndex, Range<usize>)],
    blocks: &mut [(BlockIndex, Box<Block>)],
) -> Result<usize> {
    if blocks.is_empty() {
        return Ok(0);
    }
    let batches = batches(ctx, groups)?;
    let kernel = ctx.kernel(&shaders::FUSE_LIDAR)?;
    let mut updates = 0usize;
    // The passes' uniforms and bind group, for every batch (each its own submit).
    let mut kept = Kept::default();
    // Per batch: the blocks in dispatch order and their voxels as read back.
    let mut results: Vec<(Vec<usize>, Vec<GpuVoxel>)> = Vec::with_capacity(batches.len());
    for batch in &batches {
        let count = |b: usize| groups[b].1.len();
        let (order, offsets) = dispatch_order(groups, batch.clone());
        let total = *offsets.last().expect("one offset at least");
        let voxel_count = (batch.len() * VOXELS_PER_BLOCK) as u64;
        // The rays and voxels are written straight into the uploads' mappings, a block per
        // task, in dispatch order.
        let (buf_pairs, buf_dirs, rays_per_pass) =
            upload_rays((ctx, None), grid, (plan, groups), &order, total)?;
        let buf_voxels = ctx.storage_by_piece::<{ BLOCK_BYTES as usize }>(
            "lidar_voxels",
            order.len(),
            |k, dst| {
                let mut voxels = Vec::with_capacity(VOXELS_PER_BLOCK);
                pack_block_into(&blocks[order[k]].1, &mut voxels);
                dst.copy_from_slice(bytemuck::cast_slice(&voxels));
            },
        )?;
        let scope = ErrorScopes::push(&ctx.device);
        let buf_offsets = ctx.storage("lidar_ray_offsets", bytemuck::cast_slice(&offsets));
        let buf_counters = ctx.storage("lidar_counters", bytemuck::cast_slice(&[0u32; 4]));
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("fuse_lidar"),
            });
        let counts: Vec<u32> = order.iter().map(|&b| count(b) as u32).collect();
        let buffers = [
            &buf_offsets,
            &buf_pairs,
            &buf_voxels,
            &buf_counters,
            &buf_dirs,
        ];
        let passes = (&counts[..], rays_per_pass);
        let bound = (&*kernel, "fuse_lidar", &buffers[..]);
        record_passes((ctx, &mut encoder, &mut kept), bound, grid, passes)?;
        ctx.submit(encoder);
        scope.pop("running the LiDAR fusion kernel")?;
        let (voxels, counted) =
            ctx.read_back_voxels(&buf_voxels, &buf_counters, voxel_count as usize)?;
        updates += counted as usize;
        results.push((order, voxels));
    }
    // Each block's voxels back into it, by every core: the blocks in dispatch order matched
    // with their place in `blocks` (each once).
    let mut placed: Vec<(usize, &[GpuVoxel])> = results
        .iter()
        .flat_map(|(order, result)| {
            order
                .iter()
                .copied()
                .zip(result.chunks_exact(VOXELS_PER_BLOCK))
        })
        .collect();
    placed.sort_unstable_by_key(|&(b, _)| b);
    blocks
        .par_iter_mut()
        .zip(placed.par_iter())
        .for_each(|((_, block), &(_, vox))| apply_updated(block, vox));
    Ok(updates)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The f32 block-local walk visits the voxels the f64 world walk visits inside the block,
    /// on rays far from the origin, with sdf within 1e-5 m.
    #[test]
    fn block_local_walk_matches_the_f64_walk() {
        let grid = GridParams {
            voxel_size_m: 0.1,
            truncation_m: 1.0,
        };
        let vs = grid.voxel_size_m as f64;
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut compared, mut differing) = (0usize, 0usize);
        for _ in 0..300 {
            let origin = [
                3000.0 + 10.0 * uniform(),
                -2000.0 + 10.0 * uniform(),
                1500.0 + 10.0 * uniform(),
            ];
            let d = [uniform() - 0.5, uniform() - 0.5, uniform() - 0.5];
            let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let dir = d.map(|x| x / norm);
            let range = 3.0 + 30.0 * uniform();
            let (t0, t1) = band_m(range, grid.truncation_m as f64);
            // The f64 reference walk, grouped per block.
            let mut want: std::collections::BTreeMap<BlockIndex, Vec<(usize, f64)>> =
                Default::default();
            crate::fusion::traverse::traverse_cells(origin, dir, t0, t1, vs, |c| {
                let b = BlockIndex(c.map(|x| x.div_euclid(8) as i32));
                let l = c.map(|x| x.rem_euclid(8) as usize);
                let t: f64 = (0..3)
                    .map(|a| ((c[a] as f64 + 0.5) * vs - origin[a]) * dir[a])
                    .sum();
                let sdf = range - t;
                if sdf >= -(grid.truncation_m as f64) {
                    want.entry(b)
                        .or_default()
                        .push((linear_index(l[0], l[1], l[2]), sdf));
                }
                true
            });
            for (b, cells) in want {
                let ray = block_local_ray(&grid, origin, dir, range, 0, b);
                // What goes to the device gives the same ray back.
                let shared = GpuRayDir {
                    dir: ray.dir,
                    gray: ray.gray,
                };
                let pair = GpuLidarPair::pack(&ray, 7).expect("packs");
                assert_eq!(pair.unpack(&shared), ray);
                let mut got = Vec::new();
                walk_block_ray(&ray, grid.truncation_m, grid.voxel_size_m, |i, t| {
                    got.push((i, t))
                });
                compared += 1;
                let same = got.len() == cells.len()
                    && got
                        .iter()
                        .zip(&cells)
                        .all(|(g, w)| g.0 == w.0 && ((g.1 as f64) - w.1.min(1.0)).abs() < 1e-5);
                if !same {
                    differing += 1;
                }
            }
        }
        assert!(compared > 1000, "{compared}");
        assert_eq!(differing, 0, "{differing} of {compared} block walks differ");
    }

    /// The dispatch order is the stable sort by decreasing pair count (ties in block order),
    /// with each block's first pair, over any range of the blocks.
    #[test]
    fn dispatch_order_is_the_stable_sort_by_decreasing_pairs() {
        let counts = [3usize, 0, 7, 3, 1, 7, 7, 2, 0, 3];
        let mut start = 0;
        let groups: Vec<(BlockIndex, Range<usize>)> = (counts.iter().enumerate())
            .map(|(k, &n)| {
                start += n;
                (BlockIndex([k as i32, 0, 0]), start - n..start)
            })
            .collect();
        for range in [0..counts.len(), 2..8, 4..4] {
            let mut want: Vec<usize> = range.clone().collect();
            want.sort_by_key(|&b| std::cmp::Reverse(counts[b]));
            let mut offsets = vec![0u32];
            for &b in &want {
                offsets.push(offsets.last().unwrap() + counts[b] as u32);
            }
            assert_eq!(
                dispatch_order(&groups, range.clone()),
                (want, offsets),
                "{range:?}"
            );
        }
    }
}
