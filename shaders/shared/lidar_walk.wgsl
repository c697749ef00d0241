// Shared by fuse_lidar.wgsl (blocks uploaded per call) and fuse_lidar_resident.wgsl (blocks
// resident in the GPU pool): the uniforms, the (block, ray) pair and the walk of one ray through
// one listed block (CPU twin: `walk_block_ray` in src/fusion/lidar_gpu.rs). Each kernel declares
// `ray_offsets` and `pairs` (bindings 1 and 2), `voxels` (binding 3), `ray_dirs` and
// `voxel_base(b)`, the index of listed block b's first voxel there.
// Keep in sync with `LidarUniforms`, `GpuLidarPair`, `GpuRayDir` and `GpuVoxel` in
// src/gpu/layout.rs.

struct LidarUniforms {
    // Blocks in this batch.
    block_count: u32,
    // Truncation μ and voxel edge, metres.
    truncation_m: f32,
    voxel_size_m: f32,
    // This pass applies rays first_ray .. first_ray + max_rays of each block (see main).
    first_ray: u32,
    max_rays: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// One (block, ray) pair's own values in block-local voxel coordinates (`GpuLidarPair`).
struct LidarPair {
    start_x: f32,
    start_y: f32,
    start_z: f32,
    // Signed distance to the return at the start point, metres.
    sdf_start_m: f32,
    // Length of the walk, voxels (negative: nothing to walk).
    len_vox: f32,
    // Bytes 0–2: the block-local cell the walk starts in (i8 each); byte 3: the most cells it
    // visits (both decided in f64).
    cells_steps: u32,
    // Index of the ray's LidarRayDir.
    ray: u32,
}

// What a ray's pairs share (`GpuRayDir`): its unit direction and grey level.
struct LidarRayDir {
    dir_x: f32,
    dir_y: f32,
    dir_z: f32,
    gray: u32,
}

// Crossing parameter of an axis the ray does not move along (the CPU's f32::MAX stand-in for ∞).
const NEVER: f32 = 3.0e38;

// Step (−1, 0, 1), first crossing parameter and crossing interval along one axis, voxels, for
// direction component `d` from `s` in cell `c`.
fn axis_setup(d: f32, c: i32, s: f32) -> vec3<f32> {
    if (d > 0.0) {
        let inv = 1.0 / d;
        return vec3<f32>(1.0, (f32(c + 1) - s) * inv, inv);
    } else if (d < 0.0) {
        let inv = 1.0 / d;
        return vec3<f32>(-1.0, (f32(c) - s) * inv, -inv);
    }
    return vec3<f32>(0.0, NEVER, NEVER);
}

// Walks the ray of `pair` through listed block `b` (Amanatides–Woo, the order of operations of
// `walk_block_ray`) and fuses every voxel of the block it visits whose sdf ≥ −μ. Returns the
// number of updates.
fn apply_ray(b: u32, pair: LidarPair) -> u32 {
    let len = pair.len_vox;
    if (len < 0.0) {
        return 0u;
    }
    let ray = ray_dirs[pair.ray];
    let s = vec3<f32>(pair.start_x, pair.start_y, pair.start_z);
    let d = vec3<f32>(ray.dir_x, ray.dir_y, ray.dir_z);
    // The packed i8 cells, sign-extended.
    let packed = bitcast<i32>(pair.cells_steps);
    var cell = vec3<i32>((packed << 24u) >> 24u, (packed << 16u) >> 24u, (packed << 8u) >> 24u);
    // Per axis (no loop: llvmpipe caps the loop iterations of an invocation).
    let ax = axis_setup(d.x, cell.x, s.x);
    let ay = axis_setup(d.y, cell.y, s.y);
    let az = axis_setup(d.z, cell.z, s.z);
    let step = vec3<i32>(i32(ax.x), i32(ay.x), i32(az.x));
    var t_max = vec3<f32>(ax.y, ay.y, az.y);
    let t_delta = vec3<f32>(ax.z, ay.z, az.z);
    var remaining = pair.cells_steps >> 24u;
    let rgb = ray.gray * 0x010101u;
    var n = 0u;
    while (remaining > 0u) {
        if (all(cell >= vec3<i32>(0)) && all(cell < vec3<i32>(8))) {
            let c = vec3<f32>(cell) + 0.5 - s;
            let tc = c.x * d.x + c.y * d.y + c.z * d.z;
            let sdf = pair.sdf_start_m - tc * params.voxel_size_m;
            if (sdf >= -params.truncation_m) {
                let t = min(sdf, params.truncation_m) / params.truncation_m;
                let gv = voxel_base(b) + u32(cell.x) + 8u * (u32(cell.y) + 8u * u32(cell.z));
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


// Applies this pass's rays of listed block b in scan order; returns the number of updates. At
// most max_rays rays per pass, so that an invocation stays under llvmpipe's cap of 65 535 loop
// iterations (the host chooses max_rays from the longest walk).
fn apply_pass(b: u32) -> u32 {
    var n = 0u;
    let first = ray_offsets[b] + params.first_ray;
    let end = min(ray_offsets[b + 1u], first + params.max_rays);
    for (var k = first; k < end; k = k + 1u) {
        n = n + apply_ray(b, pairs[k]);
    }
    return n;
}
