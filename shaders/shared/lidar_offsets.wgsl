// What the pair kernels (lidar_list.wgsl, lidar_rank.wgsl, lidar_pairs.wgsl) share besides the
// scan: each listed block's pairs, in dispatch order. Follows shared/lidar_scan.wgsl.

// A listed block's rays are put in scan order by lidar_sort.wgsl (in workgroup memory) where it
// has more than SORT_MIN and at most SORT_MAX pairs, else by lidar_rank.wgsl (each ray's rank
// counted: cheap for a few rays, and the only way for a crowded block).
const SORT_MIN: u32 = 256u;
const SORT_MAX: u32 = 2048u;

// Listed block b's pairs: ray_offsets[b] .. ray_offsets[b + 1] (one offset more: the pairs).
@group(0) @binding(1) var<storage, read> ray_offsets: array<u32>;

// The listed block whose pairs hold pair i.
fn block_of_pair(i: u32) -> u32 {
    var lo = 0u;
    var hi = scan[22];
    // ray_offsets[lo] ≤ i < ray_offsets[hi].
    while (hi - lo > 1u) {
        let mid = (lo + hi) / 2u;
        if (ray_offsets[mid] <= i) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    return lo;
}
