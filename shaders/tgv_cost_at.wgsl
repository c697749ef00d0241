// The end of the GPU variational matcher: each pixel's disparity u and its census cost at u
// rounded to the nearest slice, gathered where the cost volume was made, so that the host's
// invalidation needs neither the volume nor the TGV state (CPU twin: `costs_at_disparities` in
// src/depth/tgv.rs). The slice is the CPU's for every finite u (shared/cost_slice.wgsl; a
// non-finite u, which TGV never makes and the host skips, gives some slice in range). One
// invocation per 4 pixels: their u (bits) at out[i], their 4 costs packed in one word at
// out[n + i / 4]. Keep CostAtUniforms in sync with src/gpu/layout.rs.
// Shared files and bindings: src/gpu/shaders.rs.

struct CostAtUniforms {
    width: u32,
    height: u32,
    num_disparities: u32,
    min_disparity_px: f32,
}

@group(0) @binding(0) var<uniform> params: CostAtUniforms;
// Costs of pixel i, slice k at byte i·num_disparities + k, 4 per word.
@group(0) @binding(1) var<storage, read> volume: array<u32>;
// The TGV primal [u, v1, v2] per pixel.
@group(0) @binding(2) var<storage, read> primal: array<f32>;
@group(0) @binding(3) var<storage, read_write> out: array<u32>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let word = flat_index(wg, num_wg, local);
    let n = params.width * params.height;
    if (word >= (n + 3u) / 4u) {
        return;
    }
    var packed = 0u;
    for (var b = 0u; b < 4u; b++) {
        let i = word * 4u + b;
        if (i < n) {
            let u = primal[3u * i];
            out[i] = bitcast<u32>(u);
            let j = i * params.num_disparities + slice_of(u, params.min_disparity_px, params.num_disparities);
            packed |= packed_byte(volume[j >> 2u], j) << (8u * b);
        }
    }
    out[n + word] = packed;
}
