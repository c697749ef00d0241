// Marching cubes, pass 3 of 5: per meshed block, how many of its triangle corners are the first
// to name their edge (the corners that create a vertex). One workgroup per block.
// Shared files and bindings: src/gpu/shaders.rs; the passes: src/mesh/gpu.rs.

@group(0) @binding(1) var<storage, read> tri_base: array<u32>;
@group(0) @binding(2) var<storage, read> hash: array<u32>;
@group(0) @binding(3) var<storage, read> corners: array<u32>;
// Zeroed by the host.
@group(0) @binding(4) var<storage, read_write> block_vertices: array<atomic<u32>>;

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
    var count = 0u;
    for (var q = 3u * tri_base[b] + t; q < 3u * tri_base[b + 1u]; q = q + 64u) {
        let h = corners[5u * q + 4u];
        if (~hash[3u * h + 1u] == q) {
            count = count + 1u;
        }
    }
    if (count > 0u) {
        atomicAdd(&block_vertices[b], count);
    }
}
