// The blocks lidar_blocks.wgsl found, listed: each occupied entry's packed offset and pair
// count written at a place taken by an atomic counter (counters[2]: the blocks), in whatever
// order the invocations ran; the host sorts them. One invocation per table entry. Shared
// files and bindings: src/gpu/shaders.rs.

// lidar_blocks.wgsl's table: per entry, the offset packed plus one (0: empty), and the pairs.
@group(0) @binding(1) var<storage, read> found: array<u32>;
// Per block found: its packed offset and its pairs.
@group(0) @binding(2) var<storage, read_write> found_list: array<u32>;
// [2]: blocks found.
@group(0) @binding(3) var<storage, read_write> counters: array<atomic<u32>>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let h = flat_index(wg, num_wg, local);
    if (h > scan[23]) {
        return;
    }
    let word = found[2u * h];
    if (word == 0u) {
        return;
    }
    let at = atomicAdd(&counters[2], 1u);
    found_list[2u * at] = word - 1u;
    found_list[2u * at + 1u] = found[2u * h + 1u];
}
