// Shared by the marching-cubes kernels: their uniforms (binding 0). Keep `McUniforms` in sync
// with src/gpu/layout.rs; host side: src/mesh/gpu.rs.

struct McUniforms {
    // Meshed blocks in this dispatch, and the upload place of the first.
    blocks: u32,
    first_block: u32,
    // Triangle corners in this dispatch (3 per triangle).
    corner_count: u32,
    // Hash table entries − 1 (a power of two − 1).
    table_mask: u32,
    // Words per case in `table`: the case's triangle count, then 3 edges per triangle.
    table_stride: u32,
    voxel_size_m: f32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: McUniforms;
