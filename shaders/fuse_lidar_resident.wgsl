// Ray-wise LiDAR TSDF fusion into the blocks resident in the GPU pool: fuse_lidar.wgsl's update
// (the walk in shared/lidar_walk.wgsl, CPU twin `walk_block_ray` in src/fusion/lidar_gpu.rs),
// with `voxels` the whole pool (512 voxels per slot) and `slots[b]` listed block b's slot,
// resolved by block_lookup.wgsl. One invocation per listed block applies the block's rays in
// scan order, in passes of at most `max_rays` rays (see fuse_lidar.wgsl), so the result is
// deterministic and equals the per-call kernel's. The blocks are listed in dispatch order (by
// decreasing ray count); `block_updated[b]` says whether any voxel of listed block b changed.
// Shared files and bindings: src/gpu/shaders.rs.

@group(0) @binding(0) var<uniform> params: LidarUniforms;
// Pairs of listed block b: pairs[ray_offsets[b] .. ray_offsets[b + 1]], in scan order.
@group(0) @binding(1) var<storage, read> ray_offsets: array<u32>;
@group(0) @binding(2) var<storage, read> pairs: array<LidarPair>;
// The pool: every resident block's voxels.
@group(0) @binding(3) var<storage, read_write> voxels: array<GpuVoxel>;
// [0]: voxel updates applied; [1]: listed blocks the table could not resolve.
@group(0) @binding(4) var<storage, read_write> counters: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read> slots: array<u32>;
// Per listed block: 1 when any of its voxels was updated (the host clears it).
@group(0) @binding(6) var<storage, read_write> block_updated: array<u32>;
// Every ray's direction and grey level, indexed by its pairs.
@group(0) @binding(7) var<storage, read> ray_dirs: array<LidarRayDir>;
// Per pool slot: 1 once a frame or scan updated its block (read by fuse_depth_resident.wgsl,
// cleared by fill_slots.wgsl). One invocation per slot writes it here.
@group(0) @binding(8) var<storage, read_write> slot_exists: array<u32>;

fn voxel_base(b: u32) -> u32 {
    return slots[b] * 512u;
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let b = flat_index(wg, num_wg, local);
    if (b >= params.block_count) {
        return;
    }
    if (slots[b] >= SLOT_TOMBSTONE) {
        if (params.first_ray == 0u) {
            atomicAdd(&counters[1], 1u);
        }
        return;
    }
    let n = apply_pass(b);
    if (n > 0u) {
        atomicAdd(&counters[0], n);
        block_updated[b] = 1u;
        slot_exists[slots[b]] = 1u;
    }
}
