// What lidar_count.wgsl and lidar_list.wgsl share: `visit(key, k)` of shared/lidar_traverse.wgsl
// finding each block crossed among the listed ones (lidar_listed.wgsl) and handing its listed
// index to `visit_listed(b, k)`, which the kernel defines. Follows shared/lidar_traverse.wgsl
// and shared/block_hash.wgsl.

// Listed block b's position (x, y, z, unused).
@group(0) @binding(4) var<storage, read> block_keys: array<vec4<i32>>;
// The listed blocks' table (lidar_listed.wgsl): listed index + 1, 0 where empty.
@group(0) @binding(5) var<storage, read> listed: array<u32>;
// Per listed block: its rays counted (lidar_count.wgsl) or written so far (lidar_list.wgsl).
@group(0) @binding(6) var<storage, read_write> fill: array<atomic<u32>>;

const NOT_LISTED: u32 = 0xffffffffu;

// The listed index of the block at `key`, NOT_LISTED where it is not listed.
fn listed_index(key: vec3<i32>) -> u32 {
    let mask = scan[23];
    var h = block_hash(key) & mask;
    for (var probes = 0u; probes <= mask; probes++) {
        let e = listed[h];
        if (e == 0u) {
            return NOT_LISTED;
        }
        if (all(block_keys[e - 1u].xyz == key)) {
            return e - 1u;
        }
        h = (h + 1u) & mask;
    }
    return NOT_LISTED;
}

// Finds the block at `key` among the listed ones and calls `visit_listed(b, k)`, or counts it
// as not listed.
fn visit(key: vec3<i32>, k: u32) {
    let b = listed_index(key);
    if (b == NOT_LISTED) {
        atomicAdd(&counters[1], 1u);
        return;
    }
    visit_listed(b, k);
}
