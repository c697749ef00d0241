// Projective depth-map TSDF fusion into the blocks resident in the GPU pool (DENSER Sec. III-A).
// CPU twin: `integrate_depth` in src/fusion/depth.rs with `Block::fuse` (the same per-voxel
// update as fuse_depth.wgsl, shared in shared/fuse_common.wgsl). `voxels` is the whole pool
// (512 voxels per slot); `slots[b]` is listed block b's slot, resolved by block_lookup.wgsl.
// Keep in sync with `FuseUniforms`/`GpuVoxel` in src/gpu/layout.rs and src/gpu/resident.rs.
// Shared files and bindings: src/gpu/shaders.rs.

@group(0) @binding(6) var<storage, read> slots: array<u32>;
// Per listed block: 1 when any of its voxels was updated.
@group(0) @binding(7) var<storage, read_write> block_updated: array<atomic<u32>>;

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
    let b = g / 512u;
    let i = g % 512u;
    let slot = slots[b];
    if (slot >= SLOT_TOMBSTONE) {
        if (i == 0u) {
            atomicAdd(&counters[1], 1u);
        }
        return;
    }
    if (fuse_voxel(b, i, slot * 512u + i)) {
        atomicOr(&block_updated[b], 1u);
    }
}
