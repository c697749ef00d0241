// SGM's right-image winners (CPU twin: `winner` in src/depth/aggregate/select.rs): for right
// pixel xr of row y, the slice k of the smallest S(xr + min_disparity + k, k) over the left
// pixels inside the image, ties to the smaller slice; NO_SLICE where none. One invocation per
// right pixel; stored at y·width + (width − 1 − xr), the CPU's order. Shared files and bindings:
// src/gpu/shaders.rs.

@group(0) @binding(0) var<uniform> params: SgmSelectUniforms;
@group(0) @binding(1) var<storage, read> sums: array<u32>;
@group(0) @binding(2) var<storage, read_write> right_k: array<u32>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    let w = params.width;
    if (i >= w * params.height) {
        return;
    }
    let y = i / w;
    let xr = i % w;
    let nd = params.num_disparities;
    var best = NO_SLICE + 1u;
    var best_k = NO_SLICE;
    for (var k = 0u; k < nd; k = k + 1u) {
        let x = i32(xr) + params.min_disparity_px + i32(k);
        if (x >= 0 && x < i32(w)) {
            let v = sum_at((y * w + u32(x)) * nd + k);
            if (v < best) {
                best = v;
                best_k = k;
            }
        }
    }
    right_k[y * w + (w - 1u - xr)] = best_k;
}
