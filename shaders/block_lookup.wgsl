// Resolves block keys to pool slots through the GPU hash table (one invocation per key).
// CPU twin: `BlockTable::lookup` in src/gpu/resident.rs. Keep `LookupUniforms` in sync with
// src/gpu/layout.rs. Shared files and bindings: src/gpu/shaders.rs.

struct LookupUniforms {
    key_count: u32,
    // Table capacity − 1 (the capacity is a power of two).
    mask: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: LookupUniforms;
@group(0) @binding(1) var<storage, read> table: array<vec4<u32>>;
// Block keys (xyz; w unused).
@group(0) @binding(2) var<storage, read> keys: array<vec4<i32>>;
// Slot of each key, SLOT_EMPTY when absent.
@group(0) @binding(3) var<storage, read_write> slots: array<u32>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let k = flat_index(wg, num_wg, local);
    if (k >= params.key_count) {
        return;
    }
    slots[k] = table_find(keys[k].xyz, params.mask);
}
