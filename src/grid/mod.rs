//! The Hashing Voxel Grid (HVG): an unbounded grid of 8×8×8-voxel blocks, allocated only near
//! observed surfaces and found through a hash of their integer block coordinates
//! (Nießner et al. 2013; DENSER Sec. III-A).
//!
//! Data only: the plain [`Block`] (structure of arrays), the index maths ([`BlockIndex`],
//! [`VoxelIndex`], [`GridParams`]) and the [`Layer`] that owns the blocks. Algorithms (fusion,
//! regularization, meshing, paging) take a layer as an argument and report the blocks they touched.
//!
//! Units and normalisation: the stored TSDF `f` is the truncated signed distance divided by the
//! truncation `μ`, so `f ∈ [−1, 1]` (positive in front of the surface, in free space), quantised to
//! `i16` with a step of `1/32767` (0.03 mm at μ = 1 m). Weights count observations, capped at
//! [`MAX_WEIGHT`] like InfiniTAM's `maxW`, so that old observations fade at a bounded rate.

mod block;
mod index;
mod layer;
mod residency;

pub(crate) use block::fused_lane;
pub use block::{decode_tsdf, encode_tsdf, Block, Voxel, MAX_WEIGHT, OMEGA_BIT};
pub use index::{
    floor_i64, linear_index, local_coords, round_i64, BlockIndex, GridParams, VoxelIndex,
    VOXELS_PER_BLOCK, VOXELS_PER_SIDE,
};
pub use layer::{
    tile_bit, tile_block, tile_blocks, tile_of, BlockHasher, Layer, TouchedBlocks,
    BLOCK_RESIDENT_BYTES, TILE_EDGE,
};
pub use residency::{eviction_order, EvictionCandidate};
