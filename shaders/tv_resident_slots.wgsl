// Places each live entry of the GPU hash table at its pool slot: `slot_entry[slot]` = (key,
// slot + 1), 0 in the w of a free slot (the buffer is cleared first), so that
// tv_resident_list.wgsl can number the blocks in slot order. Shared files and bindings:
// src/gpu/shaders.rs.

@group(0) @binding(1) var<storage, read> table: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read_write> slot_entry: array<vec4<u32>>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let e = flat_index(wg, num_wg, local);
    if (e > params.table_mask) {
        return;
    }
    let entry = table[e];
    if (entry.w < SLOT_TOMBSTONE && entry.w < params.slot_count) {
        slot_entry[entry.w] = vec4<u32>(entry.xyz, entry.w + 1u);
    }
}
