// Speckle filter, pass 1 (shared/speckle_common.wgsl): one invocation per row points every
// valid pixel at the first pixel of its run (the maximal horizontal run of connected valid
// pixels), marks invalid pixels with NONE and clears the region sizes. Shared files and
// bindings: src/gpu/shaders.rs.

const NONE: u32 = 0xffffffffu;

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
    var start = y * w;
    var previous = NAN_BITS;
    for (var x = 0u; x < w; x = x + 1u) {
        let i = y * w + x;
        let d = disparity[i];
        atomicStore(&region_size[i], 0u);
        if (is_nan_bits(d)) {
            atomicStore(&parent[i], NONE);
        } else {
            if (!joined(previous, d)) {
                start = i;
            }
            atomicStore(&parent[i], start);
        }
        previous = d;
    }
}
