// Marching cubes, pass 5 of 5: each triangle corner's vertex number, from its edge's hash entry.
// One invocation per corner.
// Shared files and bindings: src/gpu/shaders.rs; the passes: src/mesh/gpu.rs.

@group(0) @binding(1) var<storage, read> hash: array<u32>;
@group(0) @binding(2) var<storage, read> corners: array<u32>;
@group(0) @binding(3) var<storage, read_write> triangles: array<u32>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let q = flat_index(wg, num_wg, local);
    if (q >= params.corner_count) {
        return;
    }
    triangles[q] = hash[3u * corners[5u * q + 4u] + 2u];
}
