// Shared by the marching-cubes kernels that read the uploaded samples (mc_count, mc_emit):
// bindings 1-3 and a cube's sign case.
// CPU twin: `mesh_block` in src/mesh/marching_cubes.rs; host side and buffer layouts:
// src/mesh/gpu.rs (keep `McUniforms` in sync with src/gpu/layout.rs).
//
// Blocks are numbered by their place in the upload (`samples`): the meshed blocks first, in the
// order the CPU mesher visits them, then the neighbours they read corners from. A dispatch
// covers the meshed blocks first_block .. first_block + blocks, one workgroup of 64 invocations
// per block, invocation t holding the row of 8 cubes (y, z) = (t % 8, t / 8): the CPU's order
// of cubes is the invocations' order, then x.

// No block there.
const NO_BLOCK: u32 = 0xffffffffu;
// Bit 24 of a sample's second word: the voxel is in Ω with weight > 0.
const VALID_BIT: u32 = 0x1000000u;

// Two words per voxel, 512 voxels per uploaded block: the field value (f32 bits) and
// r | g << 8 | b << 16 | valid << 24.
@group(0) @binding(1) var<storage, read> samples: array<u32>;
// Eight words per meshed block: the upload places of the block offset by corner c's offset
// (c & 1, (c >> 1) & 1, (c >> 2) & 1), NO_BLOCK where there is none.
@group(0) @binding(2) var<storage, read> neighbours: array<u32>;
// The triangle table: per sign case, its triangle count then 3 edge ids per triangle.
@group(0) @binding(3) var<storage, read> table: array<u32>;

// The lower corner of each of the 12 edges (`EDGES` in src/mesh/tables.rs; edge e runs along
// axis e / 4).
const EDGE_LOWER = array<u32, 12>(0u, 2u, 4u, 6u, 0u, 1u, 4u, 5u, 0u, 1u, 2u, 3u);

// Upload place and voxel of the sample at block-local coordinates (x, y, z) ∈ [0, 8]³ of
// meshed block `b`; the place is NO_BLOCK where that block does not exist.
fn locate(b: u32, x: u32, y: u32, z: u32) -> vec2<u32> {
    let nb = (x >> 3u) | ((y >> 3u) << 1u) | ((z >> 3u) << 2u);
    let place = neighbours[8u * b + nb];
    return vec2<u32>(place, (x & 7u) + 8u * ((y & 7u) + 8u * (z & 7u)));
}

// The two words of a sample (value bits, colour and valid bit); an invalid sample where there is
// no block.
fn sample_at(at: vec2<u32>) -> vec2<u32> {
    if (at.x == NO_BLOCK) {
        return vec2<u32>(0u, 0u);
    }
    let i = 2u * (at.x * 512u + at.y);
    return vec2<u32>(samples[i], samples[i + 1u]);
}

// The sign case of the cube at (x, y, z) of meshed block `b` (bit c: corner c negative), or 0
// when a corner is not valid (such cubes are not meshed).
fn cube_case(b: u32, x: u32, y: u32, z: u32) -> u32 {
    var case_bits = 0u;
    for (var c = 0u; c < 8u; c = c + 1u) {
        let s = sample_at(locate(b, x + (c & 1u), y + ((c >> 1u) & 1u), z + ((c >> 2u) & 1u)));
        if ((s.y & VALID_BIT) == 0u) {
            return 0u;
        }
        if (bitcast<f32>(s.x) < 0.0) {
            case_bits = case_bits | (1u << c);
        }
    }
    return case_bits;
}

// Triangles of sign case `c`.
fn triangle_count(c: u32) -> u32 {
    return table[c * params.table_stride];
}
