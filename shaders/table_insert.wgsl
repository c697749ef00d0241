// Blocks allocated on the device: each listed block that frame_keys.wgsl did not find in the GPU
// hash table (its slot SLOT_EMPTY) takes a slot from the free-slot stack and is inserted into
// the table, one invocation per listed block. The keys are distinct and this kernel looks
// nothing up, so no entry is read while another invocation writes it: an entry is claimed by a
// compare-and-swap of its slot word from empty (or a tombstone) to the slot, then its key words
// are stored; a later dispatch reads the whole entry. Which block gets which slot and entry
// depends on the order the invocations run in; the host learns both from `created` and applies
// them to its copy (`BlockTable::insert_at`, `ResidentMap`'s late collection), so the two stay
// equal entry for entry. The host keeps the table at most half full with every listed block
// inserted, so a probe always ends on a free entry. Host side and CPU twin:
// src/gpu/resident/alloc.rs. Shared files and bindings: src/gpu/shaders.rs.

@group(0) @binding(0) var<uniform> params: FrameKeyUniforms;
// The table's entries as words: 4k..4k+2 the key (x, y, z), 4k + 3 the slot.
@group(0) @binding(1) var<storage, read_write> table: array<atomic<u32>>;
// Per listed block: its packed offset, or three words (x, y, z) when origin.w is 3.
@group(0) @binding(2) var<storage, read> keys: array<u32>;
// Per listed block: its slot (frame_keys.wgsl's), SLOT_EMPTY where absent; set here where a
// block is inserted.
@group(0) @binding(3) var<storage, read_write> slots: array<u32>;
// The free-slot stack: [0] how many slots it holds, [1..=count] the slots, the top last.
@group(0) @binding(4) var<storage, read_write> free: array<atomic<u32>>;
// [0] blocks inserted, [1] blocks left without a slot (the stack ran out, or no entry was
// found); from [2]: per inserted block, its index in the list, its entry and its slot.
@group(0) @binding(5) var<storage, read_write> created: array<atomic<u32>>;

// Probes one invocation tries before it gives up (a half-full table needs a handful).
const MAX_PROBES: u32 = 4096u;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let b = flat_index(wg, num_wg, local);
    // Blocks from first_unsettled on are only looked up (a frame in flight may create them).
    if (b >= params.first_unsettled || b >= params.block_count || slots[b] != SLOT_EMPTY) {
        return;
    }
    // The stack's top: taken where the stack held one (a count past its length means it had
    // run out and others subtracted past zero).
    let top = atomicSub(&free[0], 1u);
    if (top == 0u || top >= arrayLength(&free)) {
        atomicAdd(&created[1], 1u);
        return;
    }
    let slot = atomicLoad(&free[top]);
    let key = params.origin.xyz + offset_of(b);
    let mask = params.mask;
    var pos = block_hash(key) & mask;
    for (var probe = 0u; probe < min(MAX_PROBES, mask + 1u); probe = probe + 1u) {
        let word = 4u * pos + 3u;
        let seen = atomicLoad(&table[word]);
        if (seen == SLOT_EMPTY || seen == SLOT_TOMBSTONE) {
            let r = atomicCompareExchangeWeak(&table[word], seen, slot);
            if (r.exchanged) {
                let k = bitcast<vec3<u32>>(key);
                atomicStore(&table[4u * pos], k.x);
                atomicStore(&table[4u * pos + 1u], k.y);
                atomicStore(&table[4u * pos + 2u], k.z);
                slots[b] = slot;
                let i = atomicAdd(&created[0], 1u);
                atomicStore(&created[2u + 3u * i], b);
                atomicStore(&created[3u + 3u * i], pos);
                atomicStore(&created[4u + 3u * i], slot);
                return;
            }
            if (r.old_value == seen) {
                // A weak compare-and-swap may fail without a rival: try the entry again.
                continue;
            }
        }
        pos = (pos + 1u) & mask;
    }
    atomicAdd(&created[1], 1u);
}
