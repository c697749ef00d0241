// Speckle filter, pass 3 (shared/speckle_common.wgsl): one invocation per valid pixel adds one
// to its region's size, at the region's root. Shared files and bindings: src/gpu/shaders.rs.

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
    atomicAdd(&region_size[find_root(i)], 1u);
}
