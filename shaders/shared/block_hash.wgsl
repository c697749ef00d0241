// The GPU block hash table: open addressing with linear probing over `vec4<u32>` entries
// (key x, y, z as two's complement, slot). CPU twin and owner: `BlockTable` in
// src/gpu/resident.rs (keep `mix32`, `block_hash`, the sentinels and the probe order in sync).
// The host inserts and removes (it decides residency) and uploads changed entries; kernels look
// blocks up. The table is at most half full (tombstones included), so probes end.

const SLOT_EMPTY: u32 = 0xffffffffu;
const SLOT_TOMBSTONE: u32 = 0xfffffffeu;

// A 32-bit integer finaliser (bijective).
fn mix32(x: u32) -> u32 {
    var h = x;
    h = h ^ (h >> 16u);
    h = h * 0x7feb352du;
    h = h ^ (h >> 15u);
    h = h * 0x846ca68bu;
    h = h ^ (h >> 16u);
    return h;
}

fn block_hash(k: vec3<i32>) -> u32 {
    let a = mix32(bitcast<u32>(k.x));
    let b = mix32(a ^ bitcast<u32>(k.y));
    return mix32(b ^ bitcast<u32>(k.z));
}
