// The GPU variational matcher's occlusion test (CPU twin: `occluded` in src/depth/tgv.rs): one
// invocation per row walks it from the right and flags a pixel whose match x − u lies more than
// the tolerance right of the leftmost match of the pixels to its right (hidden behind them in
// the right image). The flag (1 or 0) goes where tgv_invalidate.wgsl reads it. Shared files and
// bindings: src/gpu/shaders.rs.

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let y = flat_index(wg, num_wg, local);
    let w = params.width;
    if (y >= params.height) {
        return;
    }
    // The CPU starts from +∞; the first pixel is never occluded.
    var first = true;
    var min_r = 0.0;
    for (var x = w; x > 0u; x = x - 1u) {
        let i = y * w + x - 1u;
        let xr = f32(x - 1u) - primal[3u * i];
        disparity[i] = select(0u, 1u, !first && xr > min_r + params.occlusion_tolerance_px);
        min_r = select(min(min_r, xr), xr, first);
        first = false;
    }
}
