//! The storage engine: a map as named objects (a directory or an object-store prefix), chunk
//! files committed by a manifest, one writer at a time, crash-safe, verified on every read.
//!
//! The engine knows nothing of the algorithms above it ([`crate::outofcore`], [`crate::export`]):
//! no module here imports from them (checked by `tests/core/rooms.rs`). Its public API is
//!
//! - **open**: [`store::MapStore::create`], [`store::MapStore::open`] (one writer, the lock),
//!   [`store::MapStore::open_read_only`] (readers that never lose the files their manifest names);
//! - **read a chunk, verified**: [`store::MapStore::read_chunk`] (header, entry and payload CRC
//!   checked against the manifest entry);
//! - **write chunk versions**: [`store::ChunkWriter`] (new file, fsync, rename; create-only
//!   where another process may write the same name) and [`store::MapStore::record`];
//! - **commit**: [`store::MapStore::commit`] (the manifest, the only commit point);
//! - **list what is provably this writer's own**: the clean-up at open (`store/cleanup.rs`) and
//!   [`repair`], under the rules of [`layout`], the one place that names every kind of object a
//!   map holds, who writes it, and when the engine may delete it.
//!
//! Modules:
//! - [`layout`]: every object name of a map, the areas reserved for the algorithms above
//!   (shard records, sweep state, export parts), file-number reservations, and the clean-up and
//!   repair rule of each kind of file.
//! - [`reserve`]: reading the file-number reservations of array jobs.
//! - [`codec`]: pure chunk encoder/decoder (`formats/chunk.md`).
//! - [`manifest`]: the map's manifest, the commit point of every write (`formats/manifest.md`).
//! - [`store`]: the map: crash-safe chunk writes (new file, fsync, rename), reads checked against
//!   the manifest entry, checkpoints that commit a manifest, verification.
//! - [`files`]: the storage seam under the store: a local directory ([`files::LocalFiles`]) or an
//!   object-store prefix (`s3`: `s3://bucket/prefix`, conditional writes, a lease, a chunk cache);
//!   [`location`] names and opens either.
//! - [`lock`]: one writer per map (an advisory lock naming its holder), readers that never lose
//!   the files their manifest names.
//! - [`record`]: the versioned, checksummed record codec (job record, sweep progress).
//! - [`job`]: the job record a resumed run must match (`formats/job.md`).
//! - [`repair`]: rebuilds a lost manifest from the chunk files' self-describing headers.
//! - [`fault`]: fault injection under the seam (a failing or crashing operation), for the crash
//!   suite.
//!
//! A chunk is a cube of `chunk_blocks`³ blocks (default 16³ = 128³ voxels). Nothing here changes
//! voxel values.

pub mod codec;
pub mod fault;
pub mod files;
pub mod job;
pub mod layout;
pub mod location;
pub mod lock;
pub mod manifest;
pub(crate) mod record;
pub mod repair;
pub mod reserve;
#[cfg(feature = "s3")]
pub mod s3;
pub mod store;

pub use location::MapLocation;

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
