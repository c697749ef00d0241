// Projective depth-map TSDF fusion into the blocks resident in the GPU pool (DENSER Sec. III-A).
// CPU twin: `integrate_depth` in src/fusion/depth.rs with `Block::fuse` (the same per-voxel
// update as fuse_depth.wgsl, shared in shared/fuse_common.wgsl). `voxels` is the whole pool
// (512 voxels per slot); `slots[b]` and `block_base[b]` are listed block b's slot and base,
// resolved by frame_keys.wgsl.
// Keep in sync with `FuseUniforms`/`GpuVoxel` in src/gpu/layout.rs and src/gpu/resident.rs.
// Shared files and bindings: src/gpu/shaders.rs.

@group(0) @binding(6) var<storage, read> slots: array<u32>;
// Per listed block: 1 when any of its voxels was updated.
@group(0) @binding(7) var<storage, read_write> block_updated: array<atomic<u32>>;
// Per pool slot: 1 once a depth frame updated its block (cleared by fill_slots.wgsl when the
// slot is given to a new block). A listed block whose base has w != 0 (listed only because a
// frame still in flight may have created it, src/gpu/resident/late.rs) is fused only if so
// (and skipped where the table lacks it): the CPU lists such a block only once it exists.
@group(0) @binding(8) var<storage, read_write> slot_exists: array<atomic<u32>>;

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
    let unsettled = block_base[b].w != 0.0;
    if (slot >= SLOT_TOMBSTONE) {
        // An unsettled block no table holds was made by no frame (the host collected the
        // frames that listed it and released it): nothing to fuse. Any other is an error.
        if (i == 0u && !unsettled) {
            atomicAdd(&counters[1], 1u);
        }
        return;
    }
    if (unsettled && atomicLoad(&slot_exists[slot]) == 0u) {
        return;
    }
    if (fuse_voxel(b, i, slot * 512u + i)) {
        atomicOr(&block_updated[b], 1u);
        atomicOr(&slot_exists[slot], 1u);
    }
}
