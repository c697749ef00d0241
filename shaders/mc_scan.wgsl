// Marching cubes, pass 4a of 5: the exclusive prefix sum of the blocks' vertex counts, with the
// total at the end (`bases` has blocks + 1 entries). One workgroup; invocation t sums a run of
// consecutive blocks.
// Shared files and bindings: src/gpu/shaders.rs; the passes: src/mesh/gpu.rs.

@group(0) @binding(1) var<storage, read> counts: array<u32>;
@group(0) @binding(2) var<storage, read_write> bases: array<u32>;

@compute @workgroup_size(64)
fn main(@builtin(local_invocation_index) t: u32) {
    let n = params.blocks;
    let per = (n + 63u) / 64u;
    let start = min(t * per, n);
    let end = min(start + per, n);
    var total = 0u;
    for (var i = start; i < end; i = i + 1u) {
        total = total + counts[i];
    }
    var base = inclusive_scan_64(t, total) - total;
    for (var i = start; i < end; i = i + 1u) {
        bases[i] = base;
        base = base + counts[i];
    }
    if (t == 63u) {
        bases[n] = base;
    }
}
