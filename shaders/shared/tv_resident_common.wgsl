// TV regularization of the blocks resident in the GPU pool (src/regularize/resident.rs). The
// problem's blocks are the hash table's live entries, numbered k in slot order; any numbering
// gives the same voxels, since each voxel's arithmetic reads only its own and its neighbours'
// values, and slot order keeps blocks fused together near each other in memory. Its flat arrays are those of `TvProblem` (shared/tv_common.wgsl):
// voxel g = k·512 + i. Keep `TvResidentUniforms` in sync with src/gpu/layout.rs.

struct TvResidentUniforms {
    // Hash-table entries − 1 (the capacity is a power of two).
    table_mask: u32,
    // Blocks of the problem: the table's live entries.
    block_count: u32,
    // block_count × 512.
    voxel_count: u32,
    // Slots of the pool.
    slot_count: u32,
}

const RESIDENT_VOXELS_PER_BLOCK: u32 = 512u;
// No neighbour (TvProblem's NONE).
const RESIDENT_NONE: u32 = 0xffffffffu;
// Mask bit 6: Ω (src/regularize/mod.rs); bit d and 3 + d: the forward and backward links.
const RESIDENT_OMEGA: u32 = 64u;
// Bit 23 of a pool voxel's first word: Ω (bit 7 of the weight byte at bits 16–23).
const POOL_OMEGA_BIT: u32 = 0x800000u;

@group(0) @binding(0) var<uniform> params: TvResidentUniforms;

// Voxel stride along axis d (x + 8y + 64z).
fn axis_stride(d: u32) -> u32 {
    return select(select(64u, 8u, d == 1u), 1u, d == 0u);
}
