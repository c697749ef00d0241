//! The map store: `manifest.dmf` plus `chunks/*.dchk` (layout in `formats/`), in a local
//! directory or under an object-store prefix (`s3://bucket/prefix`) through the storage seam
//! [`super::files::MapFiles`]; every line here is the same for both.
//!
//! Writes are crash-safe by construction: a chunk file is written under a temporary name, fsynced
//! and renamed to a name that has never been used (its sequence number); it becomes part of the
//! map only when a manifest naming it is committed the same way. Files superseded by a commit are
//! deleted after it (once no reader has the map open). A killed run therefore leaves the last
//! committed manifest and every file it names untouched; files written after it are orphans,
//! ignored by readers and removed when the map is next opened for writing.
//!
//! One writer per map ([`super::lock`]): [`MapStore::create`] and [`MapStore::open`] hold the
//! map's writer lock until dropped; a second writer is refused with [`Error::MapLocked`].
//! [`MapStore::open_read_only`] never locks out writers and never deletes.
//!
//! Every read checks the file against the manifest entry that names it ([`MapStore::read_entry`]),
//! so a file swapped for another (with valid checksums) is an error naming the chunk, never data.
//! A directory with chunk files but no manifest is refused by every opener; [`super::repair`]
//! rebuilds the manifest.

use super::codec::{
    decode_chunk, decode_header_with_origin, encode_chunk_v4_reusing, ChunkHeader, ChunkOrigin,
    DecodedChunk, PreviousFrames, CHUNK_HEADER_V2_BYTES, DEFAULT_ZSTD_LEVEL, FLAG_HAS_REGULARIZED,
    NO_PARAMS,
};
use super::files::{Conditional, MapFiles, ObjectBytes, ObjectVersion, ReaderHold, WriterHold};
use super::layout::{
    CHUNKS_DIR, COMMIT_MARK, INCOMPLETE_MARK, MANIFEST_FILE, MANIFEST_NEXT, MANIFEST_NEXT_TMP,
    MANIFEST_TMP,
};
use super::location::MapLocation;
use super::manifest::{
    chunk_file_name, decode_manifest, encode_manifest, new_map_id, parse_chunk_file_name,
    ChunkEntry, Manifest, ManifestHeader, ENTRY_HAS_REGULARIZED, FRAMES_UNKNOWN,
};
use super::ChunkIndex;
use crate::error::{Error, Result};
use crate::grid::{Block, BlockIndex, GridParams, VOXELS_PER_BLOCK};
use crate::regularize::TvParams;
use std::path::{Path, PathBuf};
use std::sync::Arc;

pub use super::files::write_atomically;

mod cache;
mod chunk_io;
mod cleanup;
mod manifest_io;
mod open;

use manifest_io::{
    check_commit_mark, chunk_object, commit_mark_text, lost_manifest, read_next_manifest_bytes,
    refuse_incomplete, require_manifest,
};
pub use manifest_io::{
    count_chunk_files, count_chunk_objects, read_commit_mark, read_commit_mark_frames,
    read_commit_marks, read_manifest, read_manifest_at, CommitMarks,
};

use cache::ChunkCache;
pub use cache::DEFAULT_OBJECT_CACHE_BYTES;
pub use chunk_io::{read_chunk_file, read_chunk_object, ChunkWriter};
pub use cleanup::check_latest;
use cleanup::check_latest_with;

/// How a [`MapStore`] was opened.
#[derive(Debug)]
enum Access {
    /// Holds the map's writer lock or lease (released when dropped): may commit and delete.
    Writer(Box<dyn WriterHold>),
    /// A reader (or a view): never commits, never deletes; its hold (released when dropped)
    /// keeps the files its manifest names.
    Reader(#[allow(dead_code)] Box<dyn ReaderHold>),
}

/// A map opened for writing ([`MapStore::create`], [`MapStore::open`]: one writer per map, see
/// [`super::lock`] and [`super::s3`]) or for reading ([`MapStore::open_read_only`]), in a local
/// directory or on an object store ([`MapStore::open_at`] and friends take a [`MapLocation`]).
#[derive(Debug)]
pub struct MapStore {
    files: Arc<dyn MapFiles>,
    /// The map's location as a path (an `s3://` URL for object stores), for messages.
    dir: PathBuf,
    /// The manifest as it will be committed next (committed entries plus recorded writes).
    manifest: Manifest,
    /// The committed manifest's version (compare-and-swap on object stores); `None` before the
    /// first commit.
    manifest_version: Option<ObjectVersion>,
    /// Files superseded since the last commit: deletable once the next commit lands.
    superseded: Vec<String>,
    /// Files no committed manifest names any more, waiting for readers.
    deferred: Vec<String>,
    zstd_level: i32,
    access: Access,
    cache: Option<Arc<ChunkCache>>,
    /// The commit generation stamped into the chunk files this store's writers write
    /// ([`ChunkOrigin::commit_gen`]): the next commit's for a writer, the manifest's own for a
    /// reader (a shard), shared with every [`ChunkWriter`] and advanced by each commit.
    commit_gen: Arc<std::sync::atomic::AtomicU64>,
}

/// A chunk file written but not yet committed: what [`MapStore::record`] needs.
#[derive(Clone, Copy, Debug)]
pub struct WrittenChunk {
    /// The chunk.
    pub chunk: ChunkIndex,
    /// Its manifest entry.
    pub entry: ChunkEntry,
}

/// Totals of a map, as `denser inspect` prints them.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct MapSummary {
    /// Chunks.
    pub chunks: usize,
    /// Blocks.
    pub blocks: u64,
    /// Allocated voxels (blocks · 512).
    pub voxels: u64,
    /// Voxels in Ω.
    pub observed_voxels: u64,
    /// Bytes of all chunk files the manifest names (kept files of the last complete pass included).
    pub bytes_on_disk: u64,
    /// Chunks whose current file carries a regularized field (of whichever pass: see
    /// [`Manifest::pass_status`]).
    pub regularized_chunks: usize,
}

impl MapSummary {
    /// Bytes on disk per allocated voxel.
    pub fn bytes_per_voxel(&self) -> f64 {
        if self.voxels == 0 {
            0.0
        } else {
            self.bytes_on_disk as f64 / self.voxels as f64
        }
    }
}

/// What a writer found in `chunks/` when it opened the map (see [`MapStore::open`]).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct OpenCleanup {
    /// Files removed: written after the last commit by a writer that died (names).
    pub removed_uncommitted: Vec<String>,
    /// Files removed: versions superseded by a committed manifest (names).
    pub removed_superseded: Vec<String>,
    /// Superseded versions left because a reader has the map open (deleted later).
    pub waiting_for_readers: usize,
    /// Files left alone because nothing proves they are this map's leftovers: name and why.
    pub left_alone: Vec<String>,
    /// Files of regularization shards kept for adoption (their plan is open, `formats/shards.md`).
    pub shard_files_kept: usize,
}

impl MapStore {
    /// The map's objects (the storage seam).
    pub fn files(&self) -> &Arc<dyn MapFiles> {
        &self.files
    }

    /// Where the map lives.
    pub fn location(&self) -> &MapLocation {
        self.files.location()
    }

    /// RAM for chunk files read from an object store (least recently used out first; 0 turns
    /// the cache off). Local maps have no cache: the kernel's page cache serves them.
    pub fn set_cache_budget(&mut self, bytes: u64) {
        if self.files.deletes_after_s().is_some() {
            self.cache = (bytes > 0).then(|| Arc::new(ChunkCache::new(bytes)));
        }
    }

    /// Chunk-cache hits and misses so far (object stores).
    pub fn cache_stats(&self) -> (u64, u64) {
        self.cache.as_ref().map_or((0, 0), |c| c.stats())
    }

    /// Whether this store holds the writer lock.
    pub fn is_writer(&self) -> bool {
        matches!(self.access, Access::Writer(_))
    }

    fn file_path(&self, c: ChunkIndex, seq: u64) -> PathBuf {
        self.files.path(&chunk_object(c, seq))
    }

    /// The map's directory (for an object store, its `s3://bucket/prefix` URL as a path: use
    /// [`MapStore::files`] to reach its objects).
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The grid parameters the map was made with.
    pub fn grid(&self) -> GridParams {
        GridParams {
            voxel_size_m: self.manifest.header.voxel_size_m,
            truncation_m: self.manifest.header.truncation_m,
        }
    }

    /// Chunk edge, blocks.
    pub fn chunk_blocks(&self) -> u32 {
        self.manifest.header.chunk_blocks
    }

    /// The manifest as it will next be committed.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// Mutable job-progress fields of the manifest (frames, regularization pass); committed by the
    /// next [`MapStore::commit`].
    pub fn header_mut(&mut self) -> &mut ManifestHeader {
        &mut self.manifest.header
    }

    /// Whether the map holds chunk `c`.
    pub fn contains(&self, c: ChunkIndex) -> bool {
        self.manifest.chunks.contains_key(&c)
    }

    /// Every chunk of the map, sorted.
    pub fn chunk_indices(&self) -> Vec<ChunkIndex> {
        self.manifest.chunks.keys().copied().collect()
    }

    /// Path (or URL) of the file holding chunk `c` (if any).
    pub fn chunk_path(&self, c: ChunkIndex) -> Option<PathBuf> {
        self.manifest
            .chunks
            .get(&c)
            .map(|e| self.file_path(c, e.file_seq))
    }

    /// Reserves a never-used file sequence number.
    pub fn allocate_seq(&mut self) -> u64 {
        let s = self.manifest.header.next_file_seq;
        self.manifest.header.next_file_seq += 1;
        s
    }

    /// A writer that encodes and writes chunk files on any thread (see [`ChunkWriter::write`]).
    pub fn writer(&self) -> ChunkWriter {
        let h = &self.manifest.header;
        ChunkWriter {
            files: self.files.clone(),
            grid: self.grid(),
            chunk_blocks: self.chunk_blocks(),
            zstd_level: self.zstd_level,
            map_id: h.map_id,
            pass: (h.reg_pass, h.reg_params),
            commit_gen: self.commit_gen.clone(),
        }
    }

    /// Reads chunk `c` and checks it against its manifest entry (see [`MapStore::read_entry`]);
    /// `Ok(None)` when the map does not hold it.
    pub fn read_chunk(&self, c: ChunkIndex) -> Result<Option<DecodedChunk>> {
        match self.manifest.chunks.get(&c) {
            None => Ok(None),
            Some(e) => self.read_entry(c, e).map(Some),
        }
    }

    fn require_writer(&self, what: &str) -> Result<()> {
        if self.is_writer() {
            Ok(())
        } else {
            Err(Error::InvalidArgument(format!(
                "{}: {what} needs the map opened for writing (it was opened read-only)",
                self.dir.display()
            )))
        }
    }

    /// Records a written chunk file in the manifest (committed by the next [`MapStore::commit`]).
    /// The file it replaces is deleted after that commit — unless the pass in progress wrote the
    /// new file over the chunk's file of the last complete pass: that one is kept (see
    /// [`Manifest::kept`]) until the pass in progress completes.
    pub fn record(&mut self, w: WrittenChunk) {
        let h = self.manifest.header;
        let Some(old) = self.manifest.chunks.insert(w.chunk, w.entry) else {
            return;
        };
        if old.file_seq == w.entry.file_seq {
            return;
        }
        let keep = w.entry.reg_pass != 0
            && w.entry.reg_pass == h.reg_pass
            && h.complete_pass != 0
            && h.complete_pass != h.reg_pass
            && old.reg_pass == h.complete_pass
            && !self.manifest.kept.contains_key(&w.chunk);
        if keep {
            self.manifest.kept.insert(w.chunk, old);
        } else {
            self.superseded.push(chunk_object(w.chunk, old.file_seq));
        }
    }

    /// Encodes, writes and records chunk `c` synchronously.
    pub fn write_chunk(
        &mut self,
        c: ChunkIndex,
        blocks: &[(BlockIndex, &Block)],
        reg_pass: u32,
    ) -> Result<()> {
        self.require_writer("writing a chunk")?;
        let seq = self.allocate_seq();
        let w = self.writer().write(c, seq, blocks, reg_pass)?;
        self.record(w);
        Ok(())
    }

    /// Starts regularization pass `reg_pass + 1` with `params` (committed with the next commit)
    /// and returns its number. The last complete pass stays readable until the new one completes.
    pub fn begin_pass(&mut self, params: &TvParams) -> u32 {
        let h = &mut self.manifest.header;
        h.reg_pass += 1;
        h.reg_params = *params;
        h.reg_pass
    }

    /// Commits the manifest atomically, then deletes the files it no longer names (once no reader
    /// has the map open; until then they wait). When this commit completes the latest
    /// regularization pass, the files kept from the previous complete pass go with it.
    pub fn commit(&mut self) -> Result<()> {
        self.require_writer("committing")?;
        let h = self.manifest.header;
        if h.reg_pass > 0 && h.complete_pass != h.reg_pass && self.manifest.latest_pass_complete() {
            let hm = &mut self.manifest.header;
            hm.complete_pass = h.reg_pass;
            hm.complete_params = h.reg_params;
            let kept = std::mem::take(&mut self.manifest.kept);
            for (c, e) in kept {
                self.superseded.push(chunk_object(c, e.file_seq));
            }
        }
        if let Access::Writer(w) = &self.access {
            w.check()?;
        }
        let read_generation = self.manifest.header.generation;
        self.manifest.header.generation += 1;
        let bytes = encode_manifest(&self.manifest);
        // The commit point: the manifest being committed, whole, under a name of its own. From
        // here on a kill, a failed write or a restore of the previous manifest cannot lose this
        // commit: the next writer completes it (`open.rs`), `repair` keeps its files.
        if let Err(e) = self.files.write(MANIFEST_NEXT, &bytes) {
            self.manifest.header.generation = read_generation;
            return Err(e);
        }
        match self
            .files
            .write_if(MANIFEST_FILE, &bytes, self.manifest_version.as_ref())?
        {
            Conditional::Written(v) => {
                self.manifest_version = Some(v);
                self.commit_gen.store(
                    self.manifest.header.generation + 1,
                    std::sync::atomic::Ordering::SeqCst,
                );
            }
            Conditional::Conflict => {
                self.manifest.header.generation = read_generation;
                return Err(Error::CommitConflict {
                    map: self.dir.clone(),
                    read_generation,
                });
            }
        }
        // The generation committed, recorded apart from the manifest: an older manifest put
        // back later is then told from the latest (`layout.rs`).
        self.files
            .write(
                COMMIT_MARK,
                commit_mark_text(&self.manifest.header).as_bytes(),
            )
            .map_err(|e| {
                Error::bad_input(
                    self.files.path(COMMIT_MARK),
                    format!(
                        "generation {} was committed, but recording it here failed: {e}",
                        self.manifest.header.generation
                    ),
                )
            })?;
        self.deferred.append(&mut self.superseded);
        self.delete_deferred()
    }

    /// Deletes files no committed manifest names, once no reader can need them (local: no reader
    /// has the map open; object stores: after the retention period, through `gc/` records).
    fn delete_deferred(&mut self) -> Result<()> {
        if self.deferred.is_empty() {
            return Ok(());
        }
        let h = self.manifest.header;
        if !self.files.retire(&self.deferred, h.generation, h.map_id)? {
            tracing::debug!(
                "{}: {} superseded chunk files wait for readers to close the map",
                self.dir.display(),
                self.deferred.len()
            );
            return Ok(());
        }
        self.deferred.clear();
        Ok(())
    }

    /// Totals from the manifest (no chunk is read).
    pub fn summary(&self) -> MapSummary {
        let mut s = MapSummary::default();
        for e in self.manifest.chunks.values() {
            s.chunks += 1;
            s.blocks += e.block_count as u64;
            s.voxels += e.block_count as u64 * VOXELS_PER_BLOCK as u64;
            s.observed_voxels += e.observed_voxels as u64;
            s.bytes_on_disk += e.file_bytes;
            s.regularized_chunks += (e.flags & ENTRY_HAS_REGULARIZED != 0) as usize;
        }
        s.bytes_on_disk += self
            .manifest
            .kept
            .values()
            .map(|e| e.file_bytes)
            .sum::<u64>();
        s
    }

    /// A read-only view of the map as the last complete regularization pass left it: each chunk
    /// reads its kept file where the pass in progress rewrote it. Errors when no pass completed.
    pub fn complete_pass_view(&self) -> Result<MapStore> {
        let h = self.manifest.header;
        if h.complete_pass == 0 {
            return Err(Error::bad_input(
                &self.dir,
                "no regularization pass of this map has completed",
            ));
        }
        let mut m = self.manifest.clone();
        for (c, e) in std::mem::take(&mut m.kept) {
            m.chunks.insert(c, e);
        }
        m.header.reg_pass = h.complete_pass;
        m.header.reg_params = h.complete_params;
        let mut view = MapStore::with_files(
            self.files.clone(),
            m,
            None,
            Access::Reader(self.files.hold_readers()),
        );
        view.cache = self.cache.clone();
        Ok(view)
    }
}

impl Drop for MapStore {
    fn drop(&mut self) {
        if self.is_writer() {
            let _ = self.delete_deferred();
        }
    }
}

fn count_observed<'a>(blocks: impl Iterator<Item = &'a Block>) -> u32 {
    blocks.map(|b| b.observed_count() as u32).sum()
}
