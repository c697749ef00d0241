//! Out of core: the map as a directory of compressed chunk files, paged around the camera.
//!
//! - [`codec`]: pure chunk encoder/decoder (`formats/chunk.md`).
//! - [`manifest`]: the map's manifest, the commit point of every write (`formats/manifest.md`).
//! - [`store`]: the map: crash-safe chunk writes (new file, fsync, rename), reads checked against
//!   the manifest entry, checkpoints that commit a manifest, verification.
//! - [`files`]: the storage seam under the store: a local directory ([`files::LocalFiles`]) or an
//!   object-store prefix (`s3`: `s3://bucket/prefix`, conditional writes, a lease, a chunk cache).
//! - [`shards`]: regions and exports as array jobs (plans, region records, adoption).
//! - [`merge`]: several maps of one world frame combined chunk by chunk (weighted TSDF average).
//! - [`lock`]: one writer per map (an advisory lock naming its holder), readers that never lose
//!   the files their manifest names.
//! - [`repair`]: rebuilds a lost manifest from the chunk files' self-describing headers.
//! - [`pager`]: residency around the camera within a byte budget; evicted chunks are encoded and
//!   written by background workers; revisited chunks are read back.
//! - [`regional`]: offline regularisation of a stored map region by region with exact halos.
//! - [`export`]: tile-by-tile export of meshes and point clouds (PLY, LAS, LAZ, COPC) in a world
//!   frame; [`tileset`]: the map as a 3D Tiles tileset with levels of detail.
//!
//! A chunk is a cube of `chunk_blocks`³ blocks (default 16³ = 128³ voxels). Nothing here changes
//! voxel values: fusing with paging gives the same bits as fusing in memory (tested).

pub mod codec;
pub mod export;
pub mod files;
pub mod job;
pub mod lock;
pub mod manifest;
pub mod merge;
mod paged;
pub mod pager;
pub mod parts;
mod record;
pub mod region_plan;
pub mod regional;
pub mod repair;
#[cfg(feature = "s3")]
pub mod s3;
pub mod shards;
pub mod store;
pub mod sweep_state;
pub mod sweeps;
pub mod tileset;

pub use files::MapLocation;

pub use paged::PagedStore;

use crate::grid::BlockIndex;
use serde::{Deserialize, Serialize};

/// Default edge of a chunk, blocks.
pub const DEFAULT_CHUNK_BLOCKS: u32 = 16;

/// Integer coordinate of a chunk: block `b` lies in chunk `floor(b / chunk_blocks)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct ChunkIndex(pub [i32; 3]);

impl ChunkIndex {
    /// The chunk holding block `b`.
    pub fn of_block(b: BlockIndex, chunk_blocks: u32) -> Self {
        let c = chunk_blocks as i32;
        ChunkIndex([
            b.0[0].div_euclid(c),
            b.0[1].div_euclid(c),
            b.0[2].div_euclid(c),
        ])
    }

    /// The smallest block index inside this chunk.
    pub fn origin_block(&self, chunk_blocks: u32) -> [i32; 3] {
        let c = chunk_blocks as i32;
        [self.0[0] * c, self.0[1] * c, self.0[2] * c]
    }

    /// Whether block `b` lies in this chunk.
    pub fn contains(&self, b: BlockIndex, chunk_blocks: u32) -> bool {
        Self::of_block(b, chunk_blocks) == *self
    }

    /// The chunk `d` chunks away.
    pub fn offset(&self, d: [i32; 3]) -> Self {
        ChunkIndex([self.0[0] + d[0], self.0[1] + d[1], self.0[2] + d[2]])
    }
}

/// Groups block indices by chunk (chunks sorted, blocks sorted within each).
pub fn group_by_chunk(
    blocks: impl IntoIterator<Item = BlockIndex>,
    chunk_blocks: u32,
) -> std::collections::BTreeMap<ChunkIndex, Vec<BlockIndex>> {
    let mut m: std::collections::BTreeMap<ChunkIndex, Vec<BlockIndex>> = Default::default();
    for b in blocks {
        m.entry(ChunkIndex::of_block(b, chunk_blocks))
            .or_default()
            .push(b);
    }
    for v in m.values_mut() {
        v.sort_unstable();
    }
    m
}
