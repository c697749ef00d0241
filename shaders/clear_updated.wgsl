// Clears the updated mark (bit 24 of `tsdf_weight`, UPDATED_BIT in src/gpu/layout.rs) of every
// voxel of the listed pool slots, once the host has copied those blocks back to RAM
// (`ResidentMap::write_back` in src/gpu/resident/mod.rs): the marks then say again which voxels
// changed since the last write-back. One invocation per voxel. Keep `SlotListUniforms` in sync
// with src/gpu/layout.rs. Shared files and bindings: src/gpu/shaders.rs.

struct SlotListUniforms {
    slot_count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

const UPDATED_MARK: u32 = 0x1000000u;

@group(0) @binding(0) var<uniform> params: SlotListUniforms;
@group(0) @binding(1) var<storage, read> slots: array<u32>;
@group(0) @binding(2) var<storage, read_write> voxels: array<GpuVoxel>;

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
    let v = slots[g / 512u] * 512u + g % 512u;
    voxels[v].tsdf_weight = voxels[v].tsdf_weight & ~UPDATED_MARK;
}
