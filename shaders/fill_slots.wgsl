// Writes one voxel value into every voxel of the listed pool slots: the empty block a slot
// holds when it is given to a block the layer does not have yet (`ResidentMap::make_resident`
// in src/gpu/resident/mod.rs), instead of uploading 4 KiB of empty voxels per block. The host
// packs the value from `Block::default()` (its CPU twin is `pack_block_into` of an empty block).
// It also clears each slot's mark of a block updated by a frame or scan (`slot_exists`, read
// by fuse_depth_resident.wgsl). One invocation per voxel. Keep `SlotFillUniforms` in sync with
// src/gpu/layout.rs. Shared files and bindings: src/gpu/shaders.rs.

struct SlotFillUniforms {
    slot_count: u32,
    _pad0: u32,
    // The voxel written (a uniform struct member of struct type would need 16-byte alignment).
    fill_tsdf_weight: u32,
    fill_color: u32,
}

@group(0) @binding(0) var<uniform> params: SlotFillUniforms;
@group(0) @binding(1) var<storage, read> slots: array<u32>;
@group(0) @binding(2) var<storage, read_write> voxels: array<GpuVoxel>;
@group(0) @binding(3) var<storage, read_write> slot_exists: array<u32>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let g = flat_index(wg, num_wg, local);
    if (g >= params.slot_count * 512u) {
        return;
    }
    let slot = slots[g / 512u];
    voxels[slot * 512u + g % 512u] = GpuVoxel(params.fill_tsdf_weight, params.fill_color);
    if (g % 512u == 0u) {
        slot_exists[slot] = 0u;
    }
}
