// The scan's listed blocks as the host sends them (its offset from the sensor's block packed in
// one word, `pack_offset` in src/fusion/depth_keys.rs, or its position in three where an
// offset does not pack) made positions, and put in a hash table of their own (open addressing,
// linear probing, `block_hash` of shared/block_hash.wgsl), so that the walks
// (shared/lidar_traverse.wgsl) find a block's place in dispatch order from its position:
// entry = listed index + 1 (0: empty, the buffer cleared before), inserted by
// compare-and-swap. Lookups find the one entry of a key whatever order the inserts ran in.
// Where the device listed the scan (lidar_blocks.wgsl), each block's pairs are read from the
// listing's table, so lidar_count.wgsl need not walk the rays again.
// One invocation per listed block. Shared files and bindings: src/gpu/shaders.rs.

// Per listed block: its packed offset, or three words (x, y, z) where scan[31] is 3.
@group(0) @binding(1) var<storage, read> sent_keys: array<u32>;
// Listed block b's position (x, y, z, unused), for the lookup and the walks.
@group(0) @binding(2) var<storage, read_write> block_keys: array<vec4<i32>>;
// At most half full: a power of two of entries, mask scan[23].
@group(0) @binding(3) var<storage, read_write> listed: array<atomic<u32>>;
// [1]: blocks not inserted (never: the table has room for twice the blocks), or not in the
// listing's table.
@group(0) @binding(4) var<storage, read_write> counters: array<atomic<u32>>;
// lidar_blocks.wgsl's table where it listed the scan (scan[32] entries), unread else.
@group(0) @binding(5) var<storage, read> found: array<u32>;
// Per listed block: its pairs, from the listing's table (where scan[32] is not 0; else
// lidar_count.wgsl counts them).
@group(0) @binding(6) var<storage, read_write> fill: array<u32>;

// Listed block b's pairs as the listing counted them, found in its table by `key`.
fn listing_count(b: u32, key: vec3<i32>) {
    let word = found_word(key);
    let mask = scan[32] - 1u;
    var h = mix32(word) & mask;
    for (var probes = 0u; word != 0u && probes < FOUND_PROBES; probes++) {
        let e = found[2u * h];
        if (e == word) {
            fill[b] = found[2u * h + 1u];
            return;
        }
        if (e == 0u) {
            break;
        }
        h = (h + 1u) & mask;
    }
    fill[b] = 0u;
    atomicAdd(&counters[1], 1u);
}

// Listed block b's position from the words sent.
fn sent_key(b: u32) -> vec3<i32> {
    if (scan[31] == 1u) {
        let w = sent_keys[b];
        let origin = bitcast<vec3<i32>>(vec3<u32>(scan[28], scan[29], scan[30]));
        return origin + vec3<i32>(
            bitcast<i32>(w << 21u) >> 21u,
            bitcast<i32>(w << 11u) >> 22u,
            bitcast<i32>(w) >> 21u,
        );
    }
    let k = 3u * b;
    return bitcast<vec3<i32>>(vec3<u32>(sent_keys[k], sent_keys[k + 1u], sent_keys[k + 2u]));
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let b = flat_index(wg, num_wg, local);
    if (b >= scan[22]) {
        return;
    }
    let key = sent_key(b);
    block_keys[b] = vec4<i32>(key, 0);
    if (scan[32] != 0u) {
        listing_count(b, key);
    }
    let mask = scan[23];
    var h = block_hash(key) & mask;
    // A weak compare-and-swap may fail without a rival: that position is tried again.
    for (var tries = 0u; tries <= 4u * mask + 4u; tries++) {
        let r = atomicCompareExchangeWeak(&listed[h], 0u, b + 1u);
        if (r.exchanged) {
            return;
        }
        if (r.old_value != 0u) {
            h = (h + 1u) & mask;
        }
    }
    atomicAdd(&counters[1], 1u);
}
