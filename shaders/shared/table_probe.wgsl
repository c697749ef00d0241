// A probe of the GPU hash table (shared/block_hash.wgsl) for one key: the kernel that includes
// this file declares `table: array<vec4<u32>>`. Twin of `BlockTable::lookup` in
// src/gpu/resident/table.rs (the same probe order).

// The slot of block `key` in a table of `mask + 1` entries, or SLOT_EMPTY when absent.
fn table_find(key: vec3<i32>, mask: u32) -> u32 {
    let want = bitcast<vec3<u32>>(key);
    var pos = block_hash(key) & mask;
    for (var probe = 0u; probe <= mask; probe = probe + 1u) {
        let e = table[pos];
        if (e.w == SLOT_EMPTY) {
            return SLOT_EMPTY;
        }
        if (e.w != SLOT_TOMBSTONE && all(e.xyz == want)) {
            return e.w;
        }
        pos = (pos + 1u) & mask;
    }
    return SLOT_EMPTY;
}
