//! The map directory on disk: `manifest.dmf` plus `chunks/*.dchk` (layout in `formats/`).
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
    decode_chunk, decode_header_with_origin, encode_chunk_with, ChunkHeader, ChunkOrigin,
    DecodedChunk, CHUNK_HEADER_V2_BYTES, DEFAULT_ZSTD_LEVEL, FLAG_HAS_REGULARIZED, NO_PARAMS,
};
use super::lock::{readers_exclusive, ReaderGuard, WriterLock};
use super::manifest::{
    chunk_file_name, decode_manifest, encode_manifest, parse_chunk_file_name, ChunkEntry, Manifest,
    ManifestHeader, ENTRY_HAS_REGULARIZED,
};
use super::ChunkIndex;
use crate::error::{Error, Result};
use crate::grid::{Block, BlockIndex, GridParams, VOXELS_PER_BLOCK};
use crate::regularize::TvParams;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// Name of the manifest inside a map directory.
pub const MANIFEST_FILE: &str = "manifest.dmf";
/// Folder of chunk files inside a map directory.
pub const CHUNKS_DIR: &str = "chunks";

/// How a [`MapStore`] was opened.
#[derive(Debug)]
enum Access {
    /// Holds the map's writer lock (released when dropped): may commit and delete.
    Writer(#[allow(dead_code)] WriterLock),
    /// A reader (or a view): never commits, never deletes; its shared lock (released when
    /// dropped) keeps the files its manifest names on disk.
    Reader(#[allow(dead_code)] ReaderGuard),
}

/// A map directory opened for writing ([`MapStore::create`], [`MapStore::open`]: one writer per
/// map, see [`super::lock`]) or for reading ([`MapStore::open_read_only`]).
#[derive(Debug)]
pub struct MapStore {
    dir: PathBuf,
    /// The manifest as it will be committed next (committed entries plus recorded writes).
    manifest: Manifest,
    /// Files superseded since the last commit: deletable once the next commit lands.
    superseded: Vec<PathBuf>,
    /// Files no committed manifest names any more, waiting for readers to close.
    deferred: Vec<PathBuf>,
    zstd_level: i32,
    access: Access,
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
    /// Chunks whose current file carries a regularised field (of whichever pass: see
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
}

fn fsync_dir(dir: &Path) -> Result<()> {
    // Directory fsync makes renames durable on Linux; other systems may refuse: ignore that.
    if let Ok(f) = std::fs::File::open(dir) {
        let _ = f.sync_all();
    }
    Ok(())
}

/// Writes `bytes` to `path` atomically: temporary file in the same folder, fsync, rename, fsync
/// of the folder.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("tmp");
    {
        let mut f = std::fs::File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
        f.write_all(bytes).map_err(|e| Error::io(&tmp, e))?;
        f.sync_all().map_err(|e| Error::io(&tmp, e))?;
    }
    std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))?;
    fsync_dir(path.parent().unwrap_or(Path::new(".")))
}

/// A fresh random map identity (never 0).
pub fn new_map_id() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u32(std::process::id());
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    h.finish().max(1)
}

/// Chunk files (`*.dchk`) in `dir/chunks`, by name (0 when the folder is missing).
pub fn count_chunk_files(dir: &Path) -> usize {
    std::fs::read_dir(dir.join(CHUNKS_DIR)).map_or(0, |rd| {
        rd.filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().ends_with(".dchk"))
            .count()
    })
}

/// Refuses a directory without a manifest: a lost manifest (chunk files present) names the
/// repair command; an empty one is "not a map".
fn require_manifest(dir: &Path) -> Result<()> {
    let path = dir.join(MANIFEST_FILE);
    if path.exists() {
        return Ok(());
    }
    if let Some(holder) = super::lock::writer_holding(dir) {
        // A writer is creating the map (it commits its first manifest in a moment).
        return Err(Error::MapLocked {
            dir: dir.to_path_buf(),
            holder,
        });
    }
    let n = count_chunk_files(dir);
    if n > 0 {
        return Err(lost_manifest(dir, n));
    }
    Err(Error::bad_input(
        &path,
        "no manifest here: not a denser map directory (or never committed)",
    ))
}

fn lost_manifest(dir: &Path, n: usize) -> Error {
    Error::bad_input(
        dir.join(MANIFEST_FILE),
        format!(
            "missing, but {} holds {n} chunk files: the map's manifest is lost. Nothing was changed; run `denser repair {}` to rebuild it from the chunk files",
            dir.join(CHUNKS_DIR).display(),
            dir.display()
        ),
    )
}

/// Reads and decodes `dir/manifest.dmf`; errors name the file.
pub fn read_manifest(dir: &Path) -> Result<Manifest> {
    let path = dir.join(MANIFEST_FILE);
    let bytes = std::fs::read(&path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            match count_chunk_files(dir) {
                0 => Error::bad_input(
                    &path,
                    "no manifest here: not a denser map directory (or never committed)",
                ),
                n => lost_manifest(dir, n),
            }
        } else {
            Error::io(&path, e)
        }
    })?;
    decode_manifest(&bytes).map_err(|e| {
        Error::bad_input(
            &path,
            format!(
                "{e}; run `denser repair {}` to rebuild it from the chunk files",
                dir.display()
            ),
        )
    })
}

impl MapStore {
    /// Creates a new, empty map in `dir` (created if missing) and holds its writer lock. Refuses a
    /// directory that holds a map already, or chunk files without a manifest (a lost manifest:
    /// `denser repair` rebuilds it).
    pub fn create(dir: &Path, grid: GridParams, chunk_blocks: u32) -> Result<Self> {
        grid.validate()?;
        if !(1..=256).contains(&chunk_blocks) {
            return Err(Error::InvalidArgument(format!(
                "chunk edge {chunk_blocks} blocks is outside 1..=256"
            )));
        }
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let lock = WriterLock::acquire(dir)?;
        if dir.join(MANIFEST_FILE).exists() {
            return Err(Error::bad_input(
                dir,
                "already holds a map (manifest.dmf exists); open it instead",
            ));
        }
        let n = count_chunk_files(dir);
        if n > 0 {
            return Err(lost_manifest(dir, n));
        }
        let chunks = dir.join(CHUNKS_DIR);
        std::fs::create_dir_all(&chunks).map_err(|e| Error::io(&chunks, e))?;
        let mut store = MapStore {
            dir: dir.to_path_buf(),
            manifest: Manifest {
                header: ManifestHeader {
                    voxel_size_m: grid.voxel_size_m,
                    truncation_m: grid.truncation_m,
                    chunk_blocks,
                    generation: 0,
                    frames_committed: 0,
                    next_file_seq: 1,
                    reg_pass: 0,
                    reg_params: TvParams::paper(grid.voxel_size_m),
                    complete_pass: 0,
                    complete_params: NO_PARAMS,
                    map_id: new_map_id(),
                },
                chunks: Default::default(),
                kept: Default::default(),
            },
            superseded: Vec::new(),
            deferred: Vec::new(),
            zstd_level: DEFAULT_ZSTD_LEVEL,
            access: Access::Writer(lock),
        };
        store.commit()?;
        Ok(store)
    }

    /// Opens an existing map for reading and writing: takes the writer lock (refused at once with
    /// [`Error::MapLocked`], naming the holder, while another writer has it), then removes what a
    /// writer that died left behind — only files it can prove are that: see [`OpenCleanup`] and
    /// `formats/manifest.md`.
    pub fn open(dir: &Path) -> Result<Self> {
        Ok(Self::open_with_cleanup(dir)?.0)
    }

    /// [`MapStore::open`], also returning what the cleanup did.
    pub fn open_with_cleanup(dir: &Path) -> Result<(Self, OpenCleanup)> {
        require_manifest(dir)?;
        let lock = WriterLock::acquire(dir)?;
        if let Some(h) = &lock.stale {
            tracing::warn!(
                "{}: recovered the writer lock of {} which ended without releasing it (killed?)",
                dir.display(),
                h.describe()
            );
        }
        let manifest = read_manifest(dir)?;
        let mut store = MapStore {
            dir: dir.to_path_buf(),
            manifest,
            superseded: Vec::new(),
            deferred: Vec::new(),
            zstd_level: DEFAULT_ZSTD_LEVEL,
            access: Access::Writer(lock),
        };
        let cleanup = store.remove_leftovers()?;
        if store.manifest.header.map_id == 0 {
            // A format-1 map: it gets an identity with its next commit.
            store.manifest.header.map_id = new_map_id();
        }
        Ok((store, cleanup))
    }

    /// Opens an existing map for reading. Takes no writer lock, writes and deletes nothing; the
    /// files its manifest names stay on disk while it is open (see [`super::lock`]).
    pub fn open_read_only(dir: &Path) -> Result<Self> {
        require_manifest(dir)?;
        let guard = ReaderGuard::acquire(dir);
        let manifest = read_manifest(dir)?;
        Ok(MapStore {
            dir: dir.to_path_buf(),
            manifest,
            superseded: Vec::new(),
            deferred: Vec::new(),
            zstd_level: DEFAULT_ZSTD_LEVEL,
            access: Access::Reader(guard),
        })
    }

    /// A writer over a manifest rebuilt by [`super::repair`] (committed by the caller).
    pub(crate) fn from_repair(dir: &Path, lock: WriterLock, manifest: Manifest) -> Self {
        MapStore {
            dir: dir.to_path_buf(),
            manifest,
            superseded: Vec::new(),
            deferred: Vec::new(),
            zstd_level: DEFAULT_ZSTD_LEVEL,
            access: Access::Writer(lock),
        }
    }

    /// Whether this store holds the writer lock.
    pub fn is_writer(&self) -> bool {
        matches!(self.access, Access::Writer(_))
    }

    fn file_path(&self, c: ChunkIndex, seq: u64) -> PathBuf {
        self.dir.join(CHUNKS_DIR).join(chunk_file_name(c, seq))
    }

    /// Whether the header of chunk file `path` says it is file `seq` of chunk `c` of this map
    /// (format 1 files carry no origin: their name is all there is).
    fn header_is_ours(&self, path: &Path, c: ChunkIndex, seq: u64) -> bool {
        let mut head = [0u8; CHUNK_HEADER_V2_BYTES];
        let Ok(mut f) = std::fs::File::open(path) else {
            return false;
        };
        let mut n = 0;
        while n < head.len() {
            match f.read(&mut head[n..]) {
                Ok(0) => break,
                Ok(k) => n += k,
                Err(_) => return false,
            }
        }
        let Ok((h, origin)) = decode_header_with_origin(&head[..n]) else {
            return false;
        };
        // A map without an identity (format 1) cannot tell its files from others by id.
        let id = self.manifest.header.map_id;
        h.chunk == c && origin.is_none_or(|o| o.file_seq == seq && (id == 0 || o.map_id == id))
    }

    /// The writer's cleanup at open: `*.tmp` chunk files and `manifest.tmp` (only writers make
    /// them), chunk files numbered at or after the committed next sequence number (allocated after
    /// the last commit by a writer that died), and older versions of chunks the manifest names
    /// (superseded; only while no reader is open). Everything else is reported and left alone.
    fn remove_leftovers(&mut self) -> Result<OpenCleanup> {
        let mut out = OpenCleanup::default();
        let chunks = self.dir.join(CHUNKS_DIR);
        let rd = std::fs::read_dir(&chunks).map_err(|e| Error::io(&chunks, e))?;
        let next = self.manifest.header.next_file_seq;
        let mut superseded = Vec::new();
        let mut names: Vec<String> = Vec::new();
        for entry in rd {
            let entry = entry.map_err(|e| Error::io(&chunks, e))?;
            names.push(entry.file_name().to_string_lossy().into_owned());
        }
        names.sort();
        for name in names {
            let p = chunks.join(&name);
            let (stem, tmp) = if let Some(s) = name.strip_suffix(".tmp") {
                (format!("{s}.dchk"), true)
            } else {
                (name.clone(), false)
            };
            let Some((c, seq)) = parse_chunk_file_name(&stem) else {
                out.left_alone
                    .push(format!("{name}: not a chunk file name"));
                continue;
            };
            let named = |m: &std::collections::BTreeMap<ChunkIndex, ChunkEntry>| {
                m.get(&c).is_some_and(|e| e.file_seq == seq)
            };
            if named(&self.manifest.chunks) || named(&self.manifest.kept) {
                if tmp {
                    out.left_alone
                        .push(format!("{name}: temporary file of a committed version"));
                }
                continue;
            }
            if tmp {
                // Only a writer makes these, and no other writer is alive.
                remove(&p)?;
                out.removed_uncommitted.push(name);
                continue;
            }
            let current = self.manifest.chunks.get(&c).map(|e| e.file_seq);
            if seq >= next {
                if self.header_is_ours(&p, c, seq) {
                    remove(&p)?;
                    out.removed_uncommitted.push(name);
                } else {
                    out.left_alone.push(format!(
                        "{name}: numbered after the last commit but its header is not this map's file {seq} of chunk {:?}",
                        c.0
                    ));
                }
            } else if current.is_some_and(|cur| seq < cur) {
                if self.header_is_ours(&p, c, seq) {
                    superseded.push(name);
                } else {
                    out.left_alone.push(format!(
                        "{name}: an older version by its name, but its header is not this map's file {seq} of chunk {:?}",
                        c.0
                    ));
                }
            } else {
                out.left_alone.push(format!(
                    "{name}: not named by the manifest, and nothing proves it is a leftover of this map"
                ));
            }
        }
        if !superseded.is_empty() {
            if let Some(_readers) = readers_exclusive(&self.dir) {
                for name in superseded {
                    remove(&chunks.join(&name))?;
                    out.removed_superseded.push(name);
                }
            } else {
                out.waiting_for_readers = superseded.len();
                self.deferred
                    .extend(superseded.iter().map(|n| chunks.join(n)));
            }
        }
        let tmp = self.dir.join(MANIFEST_FILE).with_extension("tmp");
        if tmp.exists() {
            remove(&tmp)?;
        }
        if !out.removed_uncommitted.is_empty() {
            tracing::info!(
                "{}: removed {} chunk files written after the last commit by a writer that stopped",
                self.dir.display(),
                out.removed_uncommitted.len()
            );
        }
        for l in &out.left_alone {
            tracing::warn!("{}: left alone: {l}", chunks.display());
        }
        Ok(out)
    }

    /// The map's directory.
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

    /// Mutable job-progress fields of the manifest (frames, regularisation pass); committed by the
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

    /// Path of the file holding chunk `c` (if any).
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
            chunks_dir: self.dir.join(CHUNKS_DIR),
            grid: self.grid(),
            chunk_blocks: self.chunk_blocks(),
            zstd_level: self.zstd_level,
            map_id: h.map_id,
            pass: (h.reg_pass, h.reg_params),
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

    /// Reads the file `e` names for chunk `c` and checks it: both CRCs, then against the entry and
    /// the manifest — file size, chunk coordinate, chunk edge, voxel size, μ, block count, payload
    /// CRC, whether it carries `u`, voxels in Ω, and (format-2 files) the map id, the file sequence
    /// number and the regularisation pass. Any mismatch is an error naming the file, the chunk and
    /// every field that differs: a file replaced by another one (an older version, the same chunk
    /// of another map) is never read as if it were the committed one.
    pub fn read_entry(&self, c: ChunkIndex, e: &ChunkEntry) -> Result<DecodedChunk> {
        let path = self.file_path(c, e.file_seq);
        let (d, len) = read_chunk_file_len(&path)?;
        let h = &d.header;
        let m = &self.manifest.header;
        let mut diff: Vec<String> = Vec::new();
        let mut field = |name: &str, file: String, want: String| {
            if file != want {
                diff.push(format!("{name} {file} (manifest: {want})"));
            }
        };
        field("chunk", format!("{:?}", h.chunk.0), format!("{:?}", c.0));
        field(
            "size",
            format!("{len} bytes"),
            format!("{} bytes", e.file_bytes),
        );
        field(
            "chunk edge",
            h.chunk_blocks.to_string(),
            m.chunk_blocks.to_string(),
        );
        field(
            "voxel size",
            format!("{} m", h.voxel_size_m),
            format!("{} m", m.voxel_size_m),
        );
        field(
            "μ",
            format!("{} m", h.truncation_m),
            format!("{} m", m.truncation_m),
        );
        field(
            "blocks",
            h.block_count.to_string(),
            e.block_count.to_string(),
        );
        field(
            "payload CRC",
            format!("{:#010x}", h.payload_crc32),
            format!("{:#010x}", e.payload_crc32),
        );
        field(
            "carries u",
            (h.flags & FLAG_HAS_REGULARIZED != 0).to_string(),
            (e.flags & ENTRY_HAS_REGULARIZED != 0).to_string(),
        );
        if let Some(o) = &d.origin {
            field(
                "file number",
                o.file_seq.to_string(),
                e.file_seq.to_string(),
            );
            if o.map_id != 0 && m.map_id != 0 {
                field(
                    "map id",
                    format!("{:016x}", o.map_id),
                    format!("{:016x}", m.map_id),
                );
            }
            field("pass", o.reg_pass.to_string(), e.reg_pass.to_string());
        }
        if h.block_count == e.block_count {
            let obs = count_observed(d.blocks.iter().map(|(_, b)| &**b));
            field("Ω voxels", obs.to_string(), e.observed_voxels.to_string());
        }
        if !diff.is_empty() {
            return Err(Error::bad_input(
                &path,
                format!(
                    "chunk {:?} does not match its manifest entry: {}; the file was replaced (an older version, or another map's) and is not read",
                    c.0,
                    diff.join(", ")
                ),
            ));
        }
        Ok(d)
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
            self.superseded.push(self.file_path(w.chunk, old.file_seq));
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

    /// Starts regularisation pass `reg_pass + 1` with `params` (committed with the next commit)
    /// and returns its number. The last complete pass stays readable until the new one completes.
    pub fn begin_pass(&mut self, params: &TvParams) -> u32 {
        let h = &mut self.manifest.header;
        h.reg_pass += 1;
        h.reg_params = *params;
        h.reg_pass
    }

    /// Commits the manifest atomically, then deletes the files it no longer names (once no reader
    /// has the map open; until then they wait). When this commit completes the latest
    /// regularisation pass, the files kept from the previous complete pass go with it.
    pub fn commit(&mut self) -> Result<()> {
        self.require_writer("committing")?;
        let h = self.manifest.header;
        if h.reg_pass > 0 && h.complete_pass != h.reg_pass && self.manifest.latest_pass_complete() {
            let hm = &mut self.manifest.header;
            hm.complete_pass = h.reg_pass;
            hm.complete_params = h.reg_params;
            let kept = std::mem::take(&mut self.manifest.kept);
            for (c, e) in kept {
                self.superseded.push(self.file_path(c, e.file_seq));
            }
        }
        self.manifest.header.generation += 1;
        let path = self.dir.join(MANIFEST_FILE);
        write_atomically(&path, &encode_manifest(&self.manifest))?;
        self.deferred.append(&mut self.superseded);
        self.delete_deferred()
    }

    /// Deletes files no committed manifest names, if no reader has the map open.
    fn delete_deferred(&mut self) -> Result<()> {
        if self.deferred.is_empty() {
            return Ok(());
        }
        let Some(_readers) = readers_exclusive(&self.dir) else {
            tracing::debug!(
                "{}: {} superseded chunk files wait for readers to close the map",
                self.dir.display(),
                self.deferred.len()
            );
            return Ok(());
        };
        for p in std::mem::take(&mut self.deferred) {
            remove(&p)?;
        }
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

    /// A read-only view of the map as the last complete regularisation pass left it: each chunk
    /// reads its kept file where the pass in progress rewrote it. Errors when no pass completed.
    pub fn complete_pass_view(&self) -> Result<MapStore> {
        let h = self.manifest.header;
        if h.complete_pass == 0 {
            return Err(Error::bad_input(
                &self.dir,
                "no regularisation pass of this map has completed",
            ));
        }
        let mut m = self.manifest.clone();
        for (c, e) in std::mem::take(&mut m.kept) {
            m.chunks.insert(c, e);
        }
        m.header.reg_pass = h.complete_pass;
        m.header.reg_params = h.complete_params;
        Ok(MapStore {
            dir: self.dir.clone(),
            manifest: m,
            superseded: Vec::new(),
            deferred: Vec::new(),
            zstd_level: self.zstd_level,
            access: Access::Reader(ReaderGuard::acquire(&self.dir)),
        })
    }

    /// Reads every file the manifest names (current and kept) and checks it as
    /// [`MapStore::read_entry`] does; returns one line per problem (file name and what is wrong),
    /// empty when the map is sound.
    pub fn verify(&self) -> Vec<String> {
        let mut problems = Vec::new();
        for (c, e) in &self.manifest.chunks {
            if let Err(err) = self.read_entry(*c, e) {
                problems.push(err.to_string());
            }
        }
        for (c, e) in &self.manifest.kept {
            if let Err(err) = self.read_entry(*c, e) {
                problems.push(format!(
                    "{err} (kept file of complete pass {})",
                    self.manifest.header.complete_pass
                ));
            }
        }
        problems
    }
}

impl Drop for MapStore {
    fn drop(&mut self) {
        if self.is_writer() {
            let _ = self.delete_deferred();
        }
    }
}

fn remove(p: &Path) -> Result<()> {
    match std::fs::remove_file(p) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(p, e)),
    }
}

fn count_observed<'a>(blocks: impl Iterator<Item = &'a Block>) -> u32 {
    blocks.map(|b| b.observed_count() as u32).sum()
}

/// Memory-maps and decodes one chunk file (either format); errors name the file. Checks only
/// the file itself: [`MapStore::read_chunk`] also checks it against the manifest.
pub fn read_chunk_file(path: &Path) -> Result<DecodedChunk> {
    read_chunk_file_len(path).map(|(d, _)| d)
}

fn read_chunk_file_len(path: &Path) -> Result<(DecodedChunk, u64)> {
    let f = std::fs::File::open(path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            Error::bad_input(
                path,
                "chunk file named by the manifest is missing (deleted by hand?); `inspect --verify` lists every problem",
            )
        } else {
            Error::io(path, e)
        }
    })?;
    let len = f.metadata().map_err(|e| Error::io(path, e))?.len();
    if len == 0 {
        return Err(Error::bad_input(path, "empty chunk file"));
    }
    // SAFETY: chunk files are never modified in place (new versions get new names), so the
    // mapping cannot change under us while this process or another denser writes the map.
    let map = unsafe { memmap2::Mmap::map(&f) }.map_err(|e| Error::io(path, e))?;
    let d =
        decode_chunk(&map).map_err(|e| Error::bad_input(path, format!("corrupted chunk: {e}")))?;
    Ok((d, len))
}

/// Encodes and writes chunk files; cheap to clone and `Send`, so background workers can own one.
#[derive(Clone, Debug)]
pub struct ChunkWriter {
    chunks_dir: PathBuf,
    grid: GridParams,
    chunk_blocks: u32,
    zstd_level: i32,
    map_id: u64,
    /// The latest regularisation pass and its parameters when the writer was made.
    pass: (u32, TvParams),
}

impl ChunkWriter {
    /// Encodes `blocks` of chunk `c` and writes them crash-safely as file number `seq` (from
    /// [`MapStore::allocate_seq`]), in chunk format 2 with its origin (this map, `seq`,
    /// `reg_pass` and that pass's parameters). The result must be given to [`MapStore::record`].
    pub fn write(
        &self,
        c: ChunkIndex,
        seq: u64,
        blocks: &[(BlockIndex, &Block)],
        reg_pass: u32,
    ) -> Result<WrittenChunk> {
        let header = ChunkHeader {
            voxel_size_m: self.grid.voxel_size_m,
            truncation_m: self.grid.truncation_m,
            chunk: c,
            chunk_blocks: self.chunk_blocks,
            block_count: 0,
            flags: 0,
            payload_raw_bytes: 0,
            payload_zstd_bytes: 0,
            payload_crc32: 0,
        };
        let origin = ChunkOrigin {
            map_id: self.map_id,
            file_seq: seq,
            reg_pass,
            reg_params: if reg_pass != 0 && reg_pass == self.pass.0 {
                self.pass.1
            } else {
                NO_PARAMS
            },
        };
        let bytes = encode_chunk_with(&header, Some(&origin), blocks, self.zstd_level);
        let path = self.chunks_dir.join(chunk_file_name(c, seq));
        write_atomically(&path, &bytes)?;
        let has_reg = blocks.iter().any(|(_, b)| b.regularized.is_some());
        Ok(WrittenChunk {
            chunk: c,
            entry: ChunkEntry {
                block_count: blocks.len() as u32,
                observed_voxels: count_observed(blocks.iter().map(|(_, b)| *b)),
                flags: if has_reg { ENTRY_HAS_REGULARIZED } else { 0 },
                file_seq: seq,
                file_bytes: bytes.len() as u64,
                payload_crc32: u32::from_le_bytes(bytes[52..56].try_into().expect("header")),
                reg_pass,
            },
        })
    }
}
