// Point-wise search of the quadratic decoupling (CPU twin: pointwise_search in
// src/depth/tgv.rs): a(x) = argmin_k λ·C(x, k) + (u(x) − d_k)²/(2θ) over the slices within the
// reach, then a parabola through the winner's neighbours (offset clamped to ±0.5). Integer
// costs and the CPU's f32 operations in the same order. Keep PointwiseUniforms in sync with
// src/gpu/layout.rs. Shared files and bindings: src/gpu/shaders.rs.

struct PointwiseUniforms {
    width: u32,
    height: u32,
    num_disparities: u32,
    // 1: raw u8 census costs, 4 per word; 2: u16 window sums, 2 per word.
    cost_bytes: u32,
    // Stride of u in `u_values`: 1, or 3 for the TGV primal [u, v1, v2].
    u_stride: u32,
    lambda: f32,
    theta: f32,
    // √(2θλ·C_max), computed on the CPU.
    reach: f32,
    min_disparity_px: f32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> params: PointwiseUniforms;
// Costs of pixel i, slice k at entry i·num_disparities + k, packed little-endian.
@group(0) @binding(1) var<storage, read> costs: array<u32>;
// Window pixel count per pixel (the divisor of the sums; 1 for raw costs).
@group(0) @binding(2) var<storage, read> counts: array<u32>;
// The current disparity u, pixels.
@group(0) @binding(3) var<storage, read> u_values: array<f32>;
// The result a, pixels.
@group(0) @binding(4) var<storage, read_write> a_out: array<f32>;

// The data cost C(i, k), bits (the CPU's DataCost::at).
fn cost(i: u32, k: u32) -> f32 {
    let j = i * params.num_disparities + k;
    var c: u32;
    if (params.cost_bytes == 2u) {
        c = (costs[j >> 1u] >> ((j & 1u) * 16u)) & 0xffffu;
    } else {
        c = packed_byte(costs[j >> 2u], j);
    }
    return f32(c) / f32(counts[i]);
}

fn energy(i: u32, k: u32, uk: f32) -> f32 {
    let d = f32(k) - uk;
    return params.lambda * cost(i, k) + d * d / (2.0 * params.theta);
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    if (i >= params.width * params.height) {
        return;
    }
    let nd = params.num_disparities;
    let last = f32(nd - 1u);
    let uk = u_values[i * params.u_stride] - params.min_disparity_px;
    // Clamped in f32 first: the CPU's saturating `as usize` then `min(nd − 1)`.
    let k0 = u32(min(max(floor(uk - params.reach), 0.0), last));
    let k1 = u32(min(max(ceil(uk + params.reach), 0.0), last));
    // The CPU starts from +∞; its first comparison always takes k0 (energies are finite).
    var best = k0;
    var best_e = energy(i, k0, uk);
    for (var k = k0 + 1u; k <= k1; k = k + 1u) {
        let e = energy(i, k, uk);
        if (e < best_e) {
            best_e = e;
            best = k;
        }
    }
    var d = f32(best);
    if (best > 0u && best + 1u < nd) {
        let em = energy(i, best - 1u, uk);
        let ep = energy(i, best + 1u, uk);
        let denom = em - 2.0 * best_e + ep;
        if (denom > 1e-9) {
            d = d + clamp(0.5 * (em - ep) / denom, -0.5, 0.5);
        }
    }
    a_out[i] = d + params.min_disparity_px;
}
