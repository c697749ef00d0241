// Ray-wise LiDAR TSDF fusion over a list of uploaded blocks: every voxel a ray traverses inside
// its truncation band [r − μ, r + μ] gets `Block::fuse(min(sdf, μ)/μ, grey)` with sdf the
// distance along the ray from the voxel centre to the return.
// CPU twin: `walk_block_ray` in src/gpu/lidar.rs (f32, block-local; `integrate_lidar_f32`), itself
// close to the f64 reference `integrate_lidar_plan` in src/fusion/lidar.rs.
// Buffer layouts: keep in sync with `LidarUniforms`, `GpuLidarRay` and `GpuVoxel` in
// src/gpu/layout.rs. One invocation per listed block applies the block's rays in scan order, so
// the result is deterministic; `voxels` holds the listed blocks in list order (512 each).
// Prepended at load time: shared/dispatch.wgsl, shared/rounding.wgsl, shared/voxel_fuse.wgsl.

struct LidarUniforms {
    // Blocks in this batch.
    block_count: u32,
    // Truncation μ and voxel edge, metres.
    truncation_m: f32,
    voxel_size_m: f32,
    _pad0: u32,
}

// One (block, ray) pair in block-local voxel coordinates (`GpuLidarRay`).
struct LidarRay {
    start_x: f32,
    start_y: f32,
    start_z: f32,
    dir_x: f32,
    dir_y: f32,
    dir_z: f32,
    // Signed distance to the return at the start point, metres.
    sdf_start_m: f32,
    // Length of the walk, voxels (negative: nothing to walk).
    len_vox: f32,
    // Block-local cell the walk starts in, and the most cells it visits (decided in f64).
    start_cell_x: i32,
    start_cell_y: i32,
    start_cell_z: i32,
    steps: u32,
    gray: u32,
}

// `GpuVoxel`: see shared/voxel_fuse.wgsl for the bits.
struct GpuVoxel {
    tsdf_weight: u32,
    color: u32,
}

// Crossing parameter of an axis the ray does not move along (the CPU's f32::MAX stand-in for ∞).
const NEVER: f32 = 3.0e38;

@group(0) @binding(0) var<uniform> params: LidarUniforms;
// Rays of listed block b: rays[ray_offsets[b] .. ray_offsets[b + 1]], in scan order.
@group(0) @binding(1) var<storage, read> ray_offsets: array<u32>;
@group(0) @binding(2) var<storage, read> rays: array<LidarRay>;
// The voxels the kernel updates in place.
@group(0) @binding(3) var<storage, read_write> voxels: array<GpuVoxel>;
// [0]: voxel updates applied.
@group(0) @binding(4) var<storage, read_write> counters: array<atomic<u32>>;

// Walks `ray` through listed block `b` (Amanatides–Woo, the order of operations of
// `walk_block_ray`) and fuses every voxel of the block it visits whose sdf ≥ −μ. Returns the
// number of updates.
fn apply_ray(b: u32, ray: LidarRay) -> u32 {
    let len = ray.len_vox;
    if (len < 0.0) {
        return 0u;
    }
    let s = vec3<f32>(ray.start_x, ray.start_y, ray.start_z);
    let d = vec3<f32>(ray.dir_x, ray.dir_y, ray.dir_z);
    var cell = vec3<i32>(ray.start_cell_x, ray.start_cell_y, ray.start_cell_z);
    var step = vec3<i32>(0);
    var t_max = vec3<f32>(NEVER);
    var t_delta = vec3<f32>(NEVER);
    for (var a = 0; a < 3; a = a + 1) {
        if (d[a] > 0.0) {
            let inv = 1.0 / d[a];
            step[a] = 1;
            t_max[a] = (f32(cell[a] + 1) - s[a]) * inv;
            t_delta[a] = inv;
        } else if (d[a] < 0.0) {
            let inv = 1.0 / d[a];
            step[a] = -1;
            t_max[a] = (f32(cell[a]) - s[a]) * inv;
            t_delta[a] = -inv;
        }
    }
    var remaining = ray.steps;
    let rgb = ray.gray * 0x010101u;
    var n = 0u;
    while (remaining > 0u) {
        if (all(cell >= vec3<i32>(0)) && all(cell < vec3<i32>(8))) {
            let c = vec3<f32>(cell) + 0.5 - s;
            let tc = c.x * d.x + c.y * d.y + c.z * d.z;
            let sdf = ray.sdf_start_m - tc * params.voxel_size_m;
            if (sdf >= -params.truncation_m) {
                let t = min(sdf, params.truncation_m) / params.truncation_m;
                let gv = b * 512u + u32(cell.x) + 8u * (u32(cell.y) + 8u * u32(cell.z));
                let v = voxels[gv];
                let fused = fuse_packed(v.tsdf_weight, v.color, t, rgb, true);
                voxels[gv] = GpuVoxel(fused.x, fused.y);
                n = n + 1u;
            }
        }
        remaining = remaining - 1u;
        // The CPU's choice of axis, ties included.
        var a = 2;
        if (t_max.x < t_max.y) {
            if (t_max.x < t_max.z) {
                a = 0;
            }
        } else if (t_max.y < t_max.z) {
            a = 1;
        }
        if (t_max[a] > len) {
            break;
        }
        cell[a] = cell[a] + step[a];
        t_max[a] = t_max[a] + t_delta[a];
    }
    return n;
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
    var n = 0u;
    let end = ray_offsets[b + 1u];
    for (var k = ray_offsets[b]; k < end; k = k + 1u) {
        n = n + apply_ray(b, rays[k]);
    }
    if (n > 0u) {
        atomicAdd(&counters[0], n);
    }
}
