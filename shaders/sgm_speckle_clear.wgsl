// Speckle filter, pass 4 (shared/speckle_common.wgsl): one invocation per valid pixel removes it
// (NaN, confidence 0) when its region has at most max_size_px pixels. Shared files and
// bindings: src/gpu/shaders.rs.

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    if (i >= params.width * params.height || is_nan_bits(disparity[i])) {
        return;
    }
    if (atomicLoad(&region_size[find_root(i)]) <= params.max_size_px) {
        disparity[i] = NAN_BITS;
        confidence[i] = 0.0;
    }
}
