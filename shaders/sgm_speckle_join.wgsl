// Speckle filter, pass 2 (shared/speckle_common.wgsl): one invocation per pixel below the first
// row joins its run with the run above where the two pixels are connected, unless the pixels to
// their left already joined the same two runs. Shared files and bindings: src/gpu/shaders.rs.

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    let w = params.width;
    if (i < w || i >= w * params.height) {
        return;
    }
    let d = disparity[i];
    let up = disparity[i - w];
    if (!joined(d, up)) {
        return;
    }
    if (i % w > 0u) {
        let left = disparity[i - 1u];
        let up_left = disparity[i - w - 1u];
        // Both left pixels in the same runs as these two, and joined to each other: done there.
        if (joined(left, d) && joined(up_left, up) && joined(left, up_left)) {
            return;
        }
    }
    unite(i, i - w);
}
