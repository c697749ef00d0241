// A LiDAR scan's rays made on the device exactly as the CPU makes them (`rays` in
// src/fusion/lidar.rs): the range r = √((x² + y²) + z²) of each usable return p = (x, y, z) and
// its unit direction d = q · (p / r) · q⁻¹, with nalgebra's operations in nalgebra's order, in
// exact f64 (shared/exact_f64.wgsl): u = p / r, t = 2 (q⃗ × u), d = (t w + q⃗ × t) + u. Writes the
// direction and range in f64 for lidar_pairs.wgsl and the direction as f32, with the grey
// level, for the fusion (`LidarRayDir`).
// One invocation per ray. Shared files and bindings: src/gpu/shaders.rs.

@group(0) @binding(1) var<storage, read> rays_in: array<u32>;
@group(0) @binding(2) var<storage, read_write> rays_f64: array<u32>;
// LidarRayDir (shared/lidar_walk.wgsl) as 4 words: x, y, z (f32 bits), grey.
@group(0) @binding(3) var<storage, read_write> ray_dirs: array<u32>;
// [1]: rays or pairs the exact arithmetic could not make (never, for finite inputs).
@group(0) @binding(4) var<storage, read_write> counters: array<atomic<u32>>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let k = flat_index(wg, num_wg, local);
    if (k >= scan[20]) {
        return;
    }
    let at = k * RAY_WORDS;
    let x = f64_from_f32(rays_in[at]);
    let y = f64_from_f32(rays_in[at + 1u]);
    let z = f64_from_f32(rays_in[at + 2u]);
    let r = f64_sqrt(f64_add(f64_add(f64_mul(x, x), f64_mul(y, y)), f64_mul(z, z)));
    let u0 = f64_div(x, r);
    let u1 = f64_div(y, r);
    let u2 = f64_div(z, r);
    let qi = scan_f64(6u);
    let qj = scan_f64(8u);
    let qk = scan_f64(10u);
    let qw = scan_f64(12u);
    let two = vec2<u32>(0u, 0x40000000u);
    // t = (q⃗ × u) · 2, c = q⃗ × t (a × b = (a.y b.z − a.z b.y, a.z b.x − a.x b.z, a.x b.y − a.y b.x)).
    let t0 = f64_mul(f64_sub(f64_mul(qj, u2), f64_mul(qk, u1)), two);
    let t1 = f64_mul(f64_sub(f64_mul(qk, u0), f64_mul(qi, u2)), two);
    let t2 = f64_mul(f64_sub(f64_mul(qi, u1), f64_mul(qj, u0)), two);
    let c0 = f64_sub(f64_mul(qj, t2), f64_mul(qk, t1));
    let c1 = f64_sub(f64_mul(qk, t0), f64_mul(qi, t2));
    let c2 = f64_sub(f64_mul(qi, t1), f64_mul(qj, t0));
    let d0 = f64_add(f64_add(f64_mul(t0, qw), c0), u0);
    let d1 = f64_add(f64_add(f64_mul(t1, qw), c1), u1);
    let d2 = f64_add(f64_add(f64_mul(t2, qw), c2), u2);
    let out = k * RAY_F64_WORDS;
    rays_f64[out] = d0.x;
    rays_f64[out + 1u] = d0.y;
    rays_f64[out + 2u] = d1.x;
    rays_f64[out + 3u] = d1.y;
    rays_f64[out + 4u] = d2.x;
    rays_f64[out + 5u] = d2.y;
    rays_f64[out + 6u] = r.x;
    rays_f64[out + 7u] = r.y;
    ray_dirs[k * 4u] = f64_to_f32(d0);
    ray_dirs[k * 4u + 1u] = f64_to_f32(d1);
    ray_dirs[k * 4u + 2u] = f64_to_f32(d2);
    ray_dirs[k * 4u + 3u] = rays_in[at + 3u];
    if (f64_status != 0u) {
        atomicAdd(&counters[1], 1u);
    }
}
