// A LiDAR scan's (block, ray) pairs made on the device exactly as the CPU makes them
// (`block_local_ray` in src/fusion/lidar_gpu.rs, then `GpuLidarPair::pack`): the ray's
// truncation band clipped to the block by slabs, widened by a voxel at either end, its end
// cells, start point, signed distance and length, every operation the CPU's in the CPU's
// order, in exact f64 (shared/exact_f64.wgsl). One invocation per pair; the pairs are the
// listed blocks' (in dispatch order, `ray_offsets`), each block's rays in scan order.
// Shared files and bindings: src/gpu/shaders.rs.

// Per ray: direction and range (lidar_rays.wgsl).
@group(0) @binding(2) var<storage, read> rays_f64: array<u32>;
// Each pair's ray (lidar_rank.wgsl): each listed block's rays in scan order.
@group(0) @binding(3) var<storage, read> pair_rays: array<u32>;
// Listed block b's position (x, y, z, unused).
@group(0) @binding(4) var<storage, read> block_keys: array<vec4<i32>>;
// LidarPair (shared/lidar_walk.wgsl) as 7 words.
@group(0) @binding(5) var<storage, read_write> pairs: array<u32>;
// [1]: pairs the exact arithmetic could not make, or that do not pack (never: see
// `GpuLidarPair::pack`).
@group(0) @binding(6) var<storage, read_write> counters: array<atomic<u32>>;

// Cells a walk visits at most (`MAX_WALK_STEPS` in src/fusion/lidar_device.rs): the passes
// are sized by it.
const MAX_WALK_STEPS: i32 = 49;

// The slab of one axis narrows [lo, hi] (x: lo, y: hi) as the CPU's loop does.
fn clip_axis(band: vec4<u32>, corner: vec2<u32>, size: vec2<u32>, o: vec2<u32>, d: vec2<u32>)
    -> vec4<u32> {
    if (f64_is_zero(d)) {
        return band;
    }
    let ta = f64_div(f64_sub(corner, o), d);
    let tb = f64_div(f64_sub(f64_add(corner, size), o), d);
    let lo = f64_max(band.xy, f64_min(ta, tb));
    let hi = f64_min(band.zw, f64_max(ta, tb));
    return vec4<u32>(lo, hi);
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    if (i >= scan[21]) {
        return;
    }
    let key = block_keys[block_of_pair(i)];
    let k = pair_rays[i];
    let at = k * RAY_F64_WORDS;
    let d0 = vec2<u32>(rays_f64[at], rays_f64[at + 1u]);
    let d1 = vec2<u32>(rays_f64[at + 2u], rays_f64[at + 3u]);
    let d2 = vec2<u32>(rays_f64[at + 4u], rays_f64[at + 5u]);
    let range = vec2<u32>(rays_f64[at + 6u], rays_f64[at + 7u]);
    let o0 = scan_f64(0u);
    let o1 = scan_f64(2u);
    let o2 = scan_f64(4u);
    let vs = scan_f64(14u);
    let mu = scan_f64(16u);
    let inv_cell = scan_f64(18u);
    // The block's size (voxel size × 8) and low corner (index × size), band_m's band.
    let size = f64_mul(vs, vec2<u32>(0u, 0x40200000u));
    let c0 = f64_mul(f64_from_i32(key.x), size);
    let c1 = f64_mul(f64_from_i32(key.y), size);
    let c2 = f64_mul(f64_from_i32(key.z), size);
    let t0 = f64_max(f64_sub(range, mu), vec2<u32>(0u, 0u));
    let t1 = f64_add(range, mu);
    var band = vec4<u32>(t0, t1);
    band = clip_axis(band, c0, size, o0, d0);
    band = clip_axis(band, c1, size, o1, d1);
    band = clip_axis(band, c2, size, o2, d2);
    let ta = f64_max(f64_sub(band.xy, vs), t0);
    let tb = f64_min(f64_add(band.zw, vs), t1);
    let pa0 = f64_add(o0, f64_mul(ta, d0));
    let pa1 = f64_add(o1, f64_mul(ta, d1));
    let pa2 = f64_add(o2, f64_mul(ta, d2));
    let first = vec3<i32>(
        f64_floor_i32(f64_mul(pa0, inv_cell)),
        f64_floor_i32(f64_mul(pa1, inv_cell)),
        f64_floor_i32(f64_mul(pa2, inv_cell)),
    );
    let last = vec3<i32>(
        f64_cell_at(o0, tb, d0, inv_cell),
        f64_cell_at(o1, tb, d1, inv_cell),
        f64_cell_at(o2, tb, d2, inv_cell),
    );
    let span = abs(last - first);
    var steps = span.x + span.y + span.z + 1;
    if (f64_less(tb, ta)) {
        steps = 0;
    }
    let cell = first - key.xyz * 8;
    let out = i * 7u;
    pairs[out] = f64_to_f32(f64_div(f64_sub(pa0, c0), vs));
    pairs[out + 1u] = f64_to_f32(f64_div(f64_sub(pa1, c1), vs));
    pairs[out + 2u] = f64_to_f32(f64_div(f64_sub(pa2, c2), vs));
    pairs[out + 3u] = f64_to_f32(f64_sub(range, ta));
    pairs[out + 4u] = f64_to_f32(f64_div(f64_sub(tb, ta), vs));
    let fits = all(cell >= vec3<i32>(-128)) && all(cell <= vec3<i32>(127))
        && steps <= MAX_WALK_STEPS;
    if (fits) {
        let c = vec3<u32>(cell) & vec3<u32>(0xffu);
        pairs[out + 5u] = c.x | (c.y << 8u) | (c.z << 16u) | (u32(steps) << 24u);
    } else {
        // Nothing to walk; counted as not made.
        pairs[out + 5u] = 0u;
    }
    pairs[out + 6u] = k;
    if (f64_status != 0u || !fits) {
        atomicAdd(&counters[1], 1u);
    }
}
