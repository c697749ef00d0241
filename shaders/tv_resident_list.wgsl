// Numbers the resident blocks in slot order as the blocks of a TV problem: block k is the k-th
// occupied slot, `listed[k]` its key and slot, `block_of_slot[slot] = k`. One workgroup;
// invocation t takes a run of consecutive slots (as mc_scan.wgsl). CPU twin: the block list of
// `TvProblem::gather` (sorted there, in slot order here: the same problem, numbered
// otherwise). Shared files and bindings: src/gpu/shaders.rs.

// Per slot: (key, slot + 1), w = 0 for a free slot (tv_resident_slots.wgsl).
@group(0) @binding(1) var<storage, read> slot_entry: array<vec4<u32>>;
// Per block k: its key (x, y, z as two's complement) and its pool slot.
@group(0) @binding(2) var<storage, read_write> listed: array<vec4<u32>>;
// Per pool slot: its block k (entries of free slots are not written).
@group(0) @binding(3) var<storage, read_write> block_of_slot: array<u32>;
// [0]: the blocks listed (the host checks it against its own count).
@group(0) @binding(4) var<storage, read_write> counters: array<u32>;

@compute @workgroup_size(64)
fn main(@builtin(local_invocation_index) t: u32) {
    let n = params.slot_count;
    let per = (n + 63u) / 64u;
    let start = min(t * per, n);
    let end = min(start + per, n);
    var occupied = 0u;
    for (var s = start; s < end; s = s + 1u) {
        occupied = occupied + select(0u, 1u, slot_entry[s].w != 0u);
    }
    var k = inclusive_scan_64(t, occupied) - occupied;
    for (var s = start; s < end; s = s + 1u) {
        let e = slot_entry[s];
        if (e.w != 0u) {
            if (k < params.block_count) {
                listed[k] = vec4<u32>(e.xyz, s);
                block_of_slot[s] = k;
            }
            k = k + 1u;
        }
    }
    if (t == 63u) {
        counters[0] = k;
    }
}
