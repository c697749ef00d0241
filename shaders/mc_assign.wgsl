// Marching cubes, pass 4b of 5: numbers the vertices in the order of their first corners and
// writes each one (position, colour, edge key) from its first corner; the number goes into the
// edge's hash entry for pass 5. One workgroup per meshed block, its corners taken 64 at a time,
// a prefix sum over the workgroup placing the first corners of each 64.
// Shared files and bindings: src/gpu/shaders.rs; the passes: src/mesh/gpu.rs.

@group(0) @binding(1) var<storage, read> tri_base: array<u32>;
@group(0) @binding(2) var<storage, read> vertex_base: array<u32>;
@group(0) @binding(3) var<storage, read_write> hash: array<u32>;
@group(0) @binding(4) var<storage, read> corners: array<u32>;
// Five words per vertex: x, y, z (f32 bits), colour, edge key.
@group(0) @binding(5) var<storage, read_write> vertices: array<u32>;

var<workgroup> corner_range: vec2<u32>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let b = wg.y * num_wg.x + wg.x;
    if (t == 0u) {
        if (b < params.blocks) {
            corner_range = vec2<u32>(3u * tri_base[b], 3u * tri_base[b + 1u]);
        } else {
            corner_range = vec2<u32>(0u, 0u);
        }
    }
    let range = workgroupUniformLoad(&corner_range);
    var next = 0u;
    if (b < params.blocks) {
        next = vertex_base[b];
    }
    for (var chunk = range.x; chunk < range.y; chunk = chunk + 64u) {
        let q = chunk + t;
        var first = 0u;
        var h = 0u;
        if (q < range.y) {
            h = corners[5u * q + 4u];
            first = select(0u, 1u, ~hash[3u * h + 1u] == q);
        }
        let through = inclusive_scan_64(t, first);
        if (first == 1u) {
            let id = next + through - 1u;
            for (var i = 0u; i < 4u; i = i + 1u) {
                vertices[5u * id + i] = corners[5u * q + i];
            }
            vertices[5u * id + 4u] = hash[3u * h] - 1u;
            hash[3u * h + 2u] = id;
        }
        next = next + total_64();
        workgroupBarrier();
    }
}
