// Projective depth-map TSDF fusion over a list of uploaded blocks (DENSER Sec. III-A).
// CPU twin: `integrate_depth` in src/fusion/depth.rs with `Block::fuse` in src/grid/block.rs.
// Buffer layouts: keep in sync with `FuseUniforms`, `GpuVoxel` and `PIXEL_VALID` in
// src/gpu/layout.rs. One invocation per voxel; `voxels` holds the listed blocks in list order.
// Shared files and bindings: src/gpu/shaders.rs.

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let g = flat_index(wg, num_wg, local);
    if (g >= params.voxel_count) {
        return;
    }
    fuse_voxel(g / 512u, g % 512u, g);
}
