// Writes the GPU block table's changed entries (`DeviceTable::upload` in
// src/gpu/resident/table.rs): a frame changes a few hundred scattered positions, which one
// queue write per run of positions would send in as many calls; the host sends them as one
// list instead and this kernel puts each in place, before the frame's kernels read the table.
// The positions are distinct. One invocation per change. Shared files and bindings:
// src/gpu/shaders.rs.

// [0]: the changes; then per change its position and the entry's four words.
@group(0) @binding(0) var<storage, read> changes: array<u32>;
@group(0) @binding(1) var<storage, read_write> table: array<vec4<u32>>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    if (i >= changes[0]) {
        return;
    }
    let at = 1u + 5u * i;
    table[changes[at]] = vec4<u32>(changes[at + 1u], changes[at + 2u], changes[at + 3u],
        changes[at + 4u]);
}
