// Ray-wise LiDAR TSDF fusion over a list of uploaded blocks: every voxel a ray traverses inside
// its truncation band [r − μ, r + μ] gets `Block::fuse(min(sdf, μ)/μ, grey)` with sdf the
// distance along the ray from the voxel centre to the return.
// CPU twin: `walk_block_ray` in src/fusion/lidar_gpu.rs (f32, block-local; the walk is in
// shared/lidar_walk.wgsl), itself close to the f64 reference `integrate_lidar_plan` in
// src/fusion/lidar.rs.
// Buffer layouts: keep in sync with `LidarUniforms`, `GpuLidarPair`, `GpuRayDir` and `GpuVoxel` in
// src/gpu/layout.rs. One invocation per listed block applies the block's rays in scan order, in
// passes of at most `max_rays` rays dispatched one after the other, so the result is
// deterministic. `voxels` holds the listed blocks (512 voxels each) in the order the host
// dispatches them: by decreasing ray count, so that lockstep invocations do similar work and
// the blocks with rays left in a pass are a prefix (`block_count`).
// Shared files and bindings: src/gpu/shaders.rs.

@group(0) @binding(0) var<uniform> params: LidarUniforms;
// Pairs of listed block b: pairs[ray_offsets[b] .. ray_offsets[b + 1]], in scan order.
@group(0) @binding(1) var<storage, read> ray_offsets: array<u32>;
@group(0) @binding(2) var<storage, read> pairs: array<LidarPair>;
// The voxels the kernel updates in place.
@group(0) @binding(3) var<storage, read_write> voxels: array<GpuVoxel>;
// [0]: voxel updates applied.
@group(0) @binding(4) var<storage, read_write> counters: array<atomic<u32>>;
// Every ray's direction and grey level, indexed by its pairs.
@group(0) @binding(5) var<storage, read> ray_dirs: array<LidarRayDir>;

fn voxel_base(b: u32) -> u32 {
    return b * 512u;
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
    let n = apply_pass(b);
    if (n > 0u) {
        atomicAdd(&counters[0], n);
    }
}
