// Each listed block's rays put in scan order, as the CPU orders its pairs (`block_ray_pairs` in
// src/fusion/lidar.rs sorts them by block, then ray): lidar_list.wgsl wrote them in whatever
// order its invocations ran. One workgroup per listed block sorts its rays in workgroup memory
// (a bitonic network over the next power of two, padded with the largest word); a block with
// at most SORT_MIN or more than SORT_MAX pairs (shared/lidar_offsets.wgsl), or whose rays were
// not all written, is left to lidar_rank.wgsl.
// Shared files and bindings: src/gpu/shaders.rs.

// Per listed block: the rays lidar_list.wgsl wrote.
@group(0) @binding(2) var<storage, read> fill: array<u32>;
// Per pair: its ray, each block's in the order written.
@group(0) @binding(3) var<storage, read> unsorted_rays: array<u32>;
// Per pair: its ray, each block's in scan order (what lidar_pairs.wgsl reads).
@group(0) @binding(4) var<storage, read_write> pair_rays: array<u32>;

var<workgroup> sorting: array<u32, SORT_MAX>;
var<workgroup> sort_count: u32;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let b = wg.y * num_wg.x + wg.x;
    if (local == 0u) {
        var n = 0u;
        if (b < scan[22]) {
            let m = ray_offsets[b + 1u] - ray_offsets[b];
            if (m > SORT_MIN && m <= SORT_MAX && fill[b] == m) {
                n = m;
            }
        }
        sort_count = n;
    }
    let n = workgroupUniformLoad(&sort_count);
    if (n == 0u) {
        return;
    }
    let first = ray_offsets[b];
    var size = 1u;
    while (size < n) {
        size = size << 1u;
    }
    for (var i = local; i < size; i += WORKGROUP_SIZE) {
        sorting[i] = select(0xffffffffu, unsorted_rays[first + i], i < n);
    }
    workgroupBarrier();
    // Element i is compared with i ^ j by the invocation holding the smaller of the two.
    for (var k = 2u; k <= size; k = k << 1u) {
        for (var j = k >> 1u; j > 0u; j = j >> 1u) {
            for (var i = local; i < size; i += WORKGROUP_SIZE) {
                let l = i ^ j;
                if (l > i) {
                    let a = sorting[i];
                    let c = sorting[l];
                    if ((a > c) == ((i & k) == 0u)) {
                        sorting[i] = c;
                        sorting[l] = a;
                    }
                }
            }
            workgroupBarrier();
        }
    }
    for (var i = local; i < n; i += WORKGROUP_SIZE) {
        pair_rays[first + i] = sorting[i];
    }
}
