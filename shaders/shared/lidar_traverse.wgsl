// What lidar_blocks.wgsl, lidar_count.wgsl and lidar_list.wgsl share: each ray's truncation
// band walked through the blocks it crosses exactly as the CPU walks it (`traverse_cells` in
// src/fusion/traverse.rs with the block as cell, from `block_ray_pairs` in
// src/fusion/lidar.rs), every operation the CPU's in the CPU's order, in exact f64
// (shared/exact_f64.wgsl), each block crossed handed to `visit(key, k)`, which the kernel
// defines (lidar_blocks.wgsl) or shared/lidar_lookup.wgsl does; and their entry point, one
// invocation per ray. Follows shared/dispatch.wgsl and shared/lidar_scan.wgsl.

// Per ray: direction and range (lidar_rays.wgsl).
@group(0) @binding(2) var<storage, read> rays_f64: array<u32>;
// [1]: rays the exact arithmetic could not walk, blocks crossed that were not listed or that
// could not be listed, or more rays than listed (never: the host walks the same).
@group(0) @binding(3) var<storage, read_write> counters: array<atomic<u32>>;

// a < b where either may be +∞ (an axis the ray does not move along).
fn less_or_inf(a: vec2<u32>, a_inf: bool, b: vec2<u32>, b_inf: bool) -> bool {
    if (a_inf) {
        return false;
    }
    return b_inf || f64_less(a, b);
}

// One axis's start of the walk (`traverse_cells`): the first boundary's t and the step in t
// between boundaries (x, y: t_max; z, w: t_delta) of the ray o + t·d from `start` (its point
// at t0) in block `cell`; the caller handles d = 0.
fn axis_start(t0: vec2<u32>, start: vec2<u32>, cell: i32, d: vec2<u32>) -> vec4<u32> {
    let size = scan_f64(24u);
    let inv_d = f64_div(vec2<u32>(0u, 0x3ff00000u), d);
    if ((d.y >> 31u) == 0u) {
        let plane = f64_mul(f64_from_i32(cell + 1), size);
        return vec4<u32>(f64_add(t0, f64_mul(f64_sub(plane, start), inv_d)), f64_mul(size, inv_d));
    }
    let plane = f64_mul(f64_from_i32(cell), size);
    let t_max = f64_add(t0, f64_mul(f64_sub(plane, start), inv_d));
    return vec4<u32>(t_max, f64_mul(f64_neg(size), inv_d));
}

// Visits, in order, every block the band of ray k crosses, as `traverse_cells` does.
fn walk_ray(k: u32) {
    let at = k * RAY_F64_WORDS;
    let d0 = vec2<u32>(rays_f64[at], rays_f64[at + 1u]);
    let d1 = vec2<u32>(rays_f64[at + 2u], rays_f64[at + 3u]);
    let d2 = vec2<u32>(rays_f64[at + 4u], rays_f64[at + 5u]);
    let range = vec2<u32>(rays_f64[at + 6u], rays_f64[at + 7u]);
    let o0 = scan_f64(0u);
    let o1 = scan_f64(2u);
    let o2 = scan_f64(4u);
    let mu = scan_f64(16u);
    let inv_block = scan_f64(26u);
    // band_m's band, its start point and the end cells.
    let t0 = f64_max(f64_sub(range, mu), vec2<u32>(0u, 0u));
    let t1 = f64_add(range, mu);
    let s0 = f64_add(o0, f64_mul(t0, d0));
    let s1 = f64_add(o1, f64_mul(t0, d1));
    let s2 = f64_add(o2, f64_mul(t0, d2));
    var cell = vec3<i32>(
        f64_floor_i32(f64_mul(s0, inv_block)),
        f64_floor_i32(f64_mul(s1, inv_block)),
        f64_floor_i32(f64_mul(s2, inv_block)),
    );
    let last = vec3<i32>(
        f64_cell_at(o0, t1, d0, inv_block),
        f64_cell_at(o1, t1, d1, inv_block),
        f64_cell_at(o2, t1, d2, inv_block),
    );
    // Per axis: t of the next boundary (x, y) and between boundaries (z, w); +∞ where d = 0.
    let inf = vec3<bool>(f64_is_zero(d0), f64_is_zero(d1), f64_is_zero(d2));
    var a0 = vec4<u32>(0u);
    var a1 = vec4<u32>(0u);
    var a2 = vec4<u32>(0u);
    if (!inf.x) {
        a0 = axis_start(t0, s0, cell.x, d0);
    }
    if (!inf.y) {
        a1 = axis_start(t0, s1, cell.y, d1);
    }
    if (!inf.z) {
        a2 = axis_start(t0, s2, cell.z, d2);
    }
    let step = vec3<i32>(
        select(1, -1, (d0.y >> 31u) == 1u),
        select(1, -1, (d1.y >> 31u) == 1u),
        select(1, -1, (d2.y >> 31u) == 1u),
    );
    let span = abs(last - cell);
    var remaining = span.x + span.y + span.z + 1;
    if (f64_status != 0u || remaining > 1024) {
        // Never for a finite scan: a band spans a few blocks.
        atomicAdd(&counters[1], 1u);
        return;
    }
    while (remaining > 0) {
        visit(cell, k);
        remaining -= 1;
        // The CPU's choice of the nearest boundary, ties to the later axis.
        var axis = 2;
        if (less_or_inf(a0.xy, inf.x, a1.xy, inf.y)) {
            if (less_or_inf(a0.xy, inf.x, a2.xy, inf.z)) {
                axis = 0;
            }
        } else if (less_or_inf(a1.xy, inf.y, a2.xy, inf.z)) {
            axis = 1;
        }
        if (axis == 0) {
            if (inf.x || f64_less(t1, a0.xy)) {
                break;
            }
            cell.x += step.x;
            a0 = vec4<u32>(f64_add(a0.xy, a0.zw), a0.zw);
        } else if (axis == 1) {
            if (inf.y || f64_less(t1, a1.xy)) {
                break;
            }
            cell.y += step.y;
            a1 = vec4<u32>(f64_add(a1.xy, a1.zw), a1.zw);
        } else {
            if (inf.z || f64_less(t1, a2.xy)) {
                break;
            }
            cell.z += step.z;
            a2 = vec4<u32>(f64_add(a2.xy, a2.zw), a2.zw);
        }
    }
    if (f64_status != 0u) {
        atomicAdd(&counters[1], 1u);
    }
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let k = flat_index(wg, num_wg, local);
    if (k < scan[20]) {
        walk_ray(k);
    }
}
