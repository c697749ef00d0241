// Encodes the resident TV problem's result as the blocks store it: per voxel `encode_tsdf(u)`
// in Ω, the raw TSDF elsewhere (CPU twin: `TvProblem::scatter`), two i16 per word, block k's
// 512 values at words k·256 …, so that only these 2 bytes per voxel come back. Shared files
// and bindings: src/gpu/shaders.rs.

@group(0) @binding(1) var<storage, read> listed: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> pool: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read> mask: array<u32>;
@group(0) @binding(4) var<storage, read> u: array<f32>;
@group(0) @binding(5) var<storage, read_write> stored: array<u32>;

// `encode_tsdf` (src/grid/block.rs): round_half_away(clamp(x, −1, 1) · 32767), NaN → 0.
fn encode_tsdf(x: f32) -> u32 {
    if (is_nan_bits(bitcast<u32>(x))) {
        return 0u;
    }
    let q = i32(round_half_away(clamp(x, -1.0, 1.0) * 32767.0));
    return bitcast<u32>(q) & 0xffffu;
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let j = flat_index(wg, num_wg, local);
    if (2u * j >= params.voxel_count) {
        return;
    }
    var word = 0u;
    for (var h = 0u; h < 2u; h = h + 1u) {
        let g = 2u * j + h;
        var q = 0u;
        if ((mask[g] & RESIDENT_OMEGA) != 0u) {
            q = encode_tsdf(u[g]);
        } else {
            let k = g / RESIDENT_VOXELS_PER_BLOCK;
            let i = g % RESIDENT_VOXELS_PER_BLOCK;
            q = pool[listed[k].w * RESIDENT_VOXELS_PER_BLOCK + i].x & 0xffffu;
        }
        word = word | (q << (16u * h));
    }
    stored[j] = word;
}
