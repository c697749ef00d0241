// Each listed block's first pair from the counts of lidar_count.wgsl: the exclusive prefix sum
// of the counts in dispatch order, and the total (one offset more). The host lists the blocks
// by decreasing count and sizes the passes by its own counts, so the counts are checked: they
// must not increase and must sum to the host's pairs. One workgroup: each invocation sums a
// run of counts, the runs' sums are scanned (shared/workgroup_scan.wgsl), then each run is
// written. Shared files and bindings: src/gpu/shaders.rs.

// Per listed block: its pairs counted.
@group(0) @binding(1) var<storage, read> fill: array<u32>;
// Per listed block: its first pair; one more: the pairs.
@group(0) @binding(2) var<storage, read_write> offsets: array<u32>;
// [1]: counts that are not the host's (never: the host walks the same).
@group(0) @binding(3) var<storage, read_write> counters: array<atomic<u32>>;

@compute @workgroup_size(64)
fn main(@builtin(local_invocation_index) local: u32) {
    let n = scan[22];
    let per = (n + 63u) / 64u;
    let first = min(local * per, n);
    let end = min(first + per, n);
    var sum = 0u;
    var bad = 0u;
    for (var b = first; b < end; b++) {
        sum += fill[b];
        if (b > 0u && fill[b] > fill[b - 1u]) {
            bad += 1u;
        }
    }
    var before = inclusive_scan_64(local, sum) - sum;
    for (var b = first; b < end; b++) {
        offsets[b] = before;
        before += fill[b];
    }
    if (local == 63u) {
        offsets[n] = before;
        if (before != scan[21]) {
            bad += 1u;
        }
    }
    if (bad != 0u) {
        atomicAdd(&counters[1], bad);
    }
}
