// A LiDAR scan's blocks listed on the device, so that the host need not walk its rays: each
// ray's band walked through the blocks it crosses (shared/lidar_traverse.wgsl, the host's walk
// exactly) and each block crossed put in a hash table keyed by its offset from the sensor's
// block (scan[28..31)), with its pairs counted. Entry h is two words: found[2h] the offset
// packed plus one (`found_word`, shared/lidar_scan.wgsl), 0 where empty, inserted by
// compare-and-swap; found[2h + 1] the block's (block, ray) pairs. lidar_found.wgsl lists the
// entries. A block whose offset does not pack, or a table too full, is counted in counters[1]
// and the host lists the scan itself. One invocation per ray. Shared files and bindings:
// src/gpu/shaders.rs.

// scan[23] + 1 entries of two words, cleared before.
@group(0) @binding(1) var<storage, read_write> found: array<atomic<u32>>;

fn visit(key: vec3<i32>, k: u32) {
    let word = found_word(key);
    if (word == 0u) {
        atomicAdd(&counters[1], 1u);
        return;
    }
    let mask = scan[23];
    var h = mix32(word) & mask;
    for (var tries = 0u; tries < FOUND_PROBES; tries++) {
        let r = atomicCompareExchangeWeak(&found[2u * h], 0u, word);
        if (r.exchanged || r.old_value == word) {
            atomicAdd(&found[2u * h + 1u], 1u);
            return;
        }
        // A weak compare-and-swap may fail without a rival: that entry is tried again.
        if (r.old_value != 0u) {
            h = (h + 1u) & mask;
        }
    }
    atomicAdd(&counters[1], 1u);
}
