// TGV's initial disparity from SGM's, pass 2 of 2 (after tgv_fill_rows.wgsl; CPU twin:
// `fill_from_background` in src/depth/tgv.rs): one invocation per column fills each pixel still
// without a finite value from the nearest one above it, or else with the fallback (the smallest
// disparity searched). Shared files and bindings: src/gpu/shaders.rs.

@group(0) @binding(0) var<uniform> params: SgmFilterUniforms;
@group(0) @binding(1) var<storage, read> sgm: array<u32>;
@group(0) @binding(2) var<storage, read_write> filled: array<u32>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let x = flat_index(wg, num_wg, local);
    let w = params.width;
    if (x >= w) {
        return;
    }
    var last = NAN_BITS;
    for (var y = 0u; y < params.height; y = y + 1u) {
        let i = y * w + x;
        let v = filled[i];
        if (is_finite_bits(v)) {
            last = v;
        } else if (is_finite_bits(last)) {
            filled[i] = last;
        } else {
            filled[i] = bitcast<u32>(params.fallback_px);
        }
    }
}
