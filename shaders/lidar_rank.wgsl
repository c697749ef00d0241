// Each listed block's rays put in scan order where lidar_sort.wgsl does not: blocks with at
// most SORT_MIN pairs or more than SORT_MAX (shared/lidar_offsets.wgsl; the host's listing
// bounds a block's pairs by `LOOP_BUDGET`), and those whose rays were not all written
// (counted). Each pair's place is its ray's rank among its block's rays (a ray crosses a
// block once, so the ranks are distinct). One invocation per pair. Shared files and
// bindings: src/gpu/shaders.rs.

// Per listed block: the rays lidar_list.wgsl wrote (its pairs, unless something was lost).
@group(0) @binding(2) var<storage, read> fill: array<u32>;
// Per pair: its ray, each block's in the order written.
@group(0) @binding(3) var<storage, read> unsorted_rays: array<u32>;
// Per pair: its ray, each block's in scan order (what lidar_pairs.wgsl reads).
@group(0) @binding(4) var<storage, read_write> pair_rays: array<u32>;
// [1]: blocks whose rays were not all written (never: the host walks the same).
@group(0) @binding(5) var<storage, read_write> counters: array<atomic<u32>>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    if (i >= scan[21]) {
        return;
    }
    let b = block_of_pair(i);
    let first = ray_offsets[b];
    let end = ray_offsets[b + 1u];
    if (fill[b] != end - first) {
        if (i == first) {
            atomicAdd(&counters[1], 1u);
        }
        pair_rays[i] = 0xffffffffu;
        return;
    }
    if (end - first > SORT_MIN && end - first <= SORT_MAX) {
        return;
    }
    let k = unsorted_rays[i];
    var rank = 0u;
    for (var j = first; j < end; j++) {
        rank += select(0u, 1u, unsorted_rays[j] < k);
    }
    pair_rays[first + rank] = k;
}
