// TGV's initial disparity from SGM's, pass 1 of 2 (CPU twin: `fill_from_background` in
// src/depth/tgv.rs): one invocation per row fills each pixel without a finite disparity from
// the nearest finite ones to its left and right in the row, the smaller of the two (the
// background) where there are both. Then tgv_fill_columns.wgsl. Shared files and bindings:
// src/gpu/shaders.rs.

@group(0) @binding(0) var<uniform> params: SgmFilterUniforms;
// SGM's disparities (bits).
@group(0) @binding(1) var<storage, read> sgm: array<u32>;
// The initial disparity (bits), TGV's coupling target where tgv_init.wgsl reads it.
@group(0) @binding(2) var<storage, read_write> filled: array<u32>;

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
    let row = y * w;
    // Right to left: each pixel gets its own value, or the nearest finite one to its right.
    var right = NAN_BITS;
    for (var x = w; x > 0u; x = x - 1u) {
        let v = sgm[row + x - 1u];
        if (is_finite_bits(v)) {
            right = v;
        }
        filled[row + x - 1u] = right;
    }
    // Left to right: a pixel without its own value takes the smaller of the nearest finite
    // values on either side.
    var left = NAN_BITS;
    for (var x = 0u; x < w; x = x + 1u) {
        let v = sgm[row + x];
        if (is_finite_bits(v)) {
            left = v;
            continue;
        }
        let r = filled[row + x];
        if (is_finite_bits(left)) {
            let both = is_finite_bits(r) && bitcast<f32>(r) < bitcast<f32>(left);
            filled[row + x] = select(left, r, both);
        }
    }
}
