// Marching cubes, pass 1 of 5: the triangles of each meshed block, summed into `block_counts`
// (zeroed by the host). One workgroup per block, one invocation per row of 8 cubes.
// Shared files and bindings: src/gpu/shaders.rs; the passes: src/mesh/gpu.rs.

@group(0) @binding(4) var<storage, read_write> block_counts: array<atomic<u32>>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let b = wg.y * num_wg.x + wg.x;
    if (b >= params.blocks) {
        return;
    }
    let place = params.first_block + b;
    let y = t % 8u;
    let z = t / 8u;
    var count = 0u;
    for (var x = 0u; x < 8u; x = x + 1u) {
        count = count + triangle_count(cube_case(place, x, y, z));
    }
    if (count > 0u) {
        atomicAdd(&block_counts[b], count);
    }
}
