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
    let key = keys[k].xyz;
    let want = bitcast<vec3<u32>>(key);
    var pos = block_hash(key) & params.mask;
    var found = SLOT_EMPTY;
    for (var probe = 0u; probe <= params.mask; probe = probe + 1u) {
        let e = table[pos];
        if (e.w == SLOT_EMPTY) {
            break;
        }
        if (e.w != SLOT_TOMBSTONE && all(e.xyz == want)) {
            found = e.w;
            break;
        }
        pos = (pos + 1u) & params.mask;
    }
    slots[k] = found;
}
