//! The map directory on disk: `manifest.dmf` plus `chunks/*.dchk` (layout in `formats/`).
//!
//! Writes are crash-safe by construction: a chunk file is written under a temporary name, fsynced
//! and renamed to a name that has never been used (its sequence number); it becomes part of the
//! map only when a manifest naming it is committed the same way. Files superseded by a commit are
//! deleted after it. A killed run therefore leaves the last committed manifest and every file it
//! names untouched; files written after it are orphans, ignored by readers and removed when the map
//! is next opened for writing. Reads memory-map the file and check both CRCs; any failure names
//! the file.

use super::codec::{decode_chunk, encode_chunk, ChunkHeader, DecodedChunk, DEFAULT_ZSTD_LEVEL};
use super::manifest::{
    chunk_file_name, decode_manifest, encode_manifest, parse_chunk_file_name, ChunkEntry, Manifest,
    ManifestHeader, ENTRY_HAS_REGULARIZED,
};
use super::ChunkIndex;
use crate::error::{Error, Result};
use crate::grid::{Block, BlockIndex, GridParams, VOXELS_PER_BLOCK};
use crate::regularize::TvParams;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Name of the manifest inside a map directory.
pub const MANIFEST_FILE: &str = "manifest.dmf";
/// Folder of chunk files inside a map directory.
pub const CHUNKS_DIR: &str = "chunks";

/// A map directory opened for reading and writing.
pub struct MapStore {
    dir: PathBuf,
    /// The manifest as it will be committed next (committed entries plus recorded writes).
    manifest: Manifest,
    /// Files superseded since the last commit: deleted once the next commit lands.
    superseded: Vec<PathBuf>,
    zstd_level: i32,
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
    /// Bytes of all chunk files.
    pub bytes_on_disk: u64,
    /// Chunks carrying a regularised field.
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

impl MapStore {
    /// Creates a new, empty map in `dir` (created if missing; it must not hold a map already).
    pub fn create(dir: &Path, grid: GridParams, chunk_blocks: u32) -> Result<Self> {
        grid.validate()?;
        if !(1..=256).contains(&chunk_blocks) {
            return Err(Error::InvalidArgument(format!(
                "chunk edge {chunk_blocks} blocks is outside 1..=256"
            )));
        }
        if dir.join(MANIFEST_FILE).exists() {
            return Err(Error::bad_input(
                dir,
                "already holds a map (manifest.dmf exists); open it instead",
            ));
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
                },
                chunks: Default::default(),
            },
            superseded: Vec::new(),
            zstd_level: DEFAULT_ZSTD_LEVEL,
        };
        store.commit()?;
        Ok(store)
    }

    /// Opens an existing map for reading and writing, and removes files no committed manifest names
    /// (left by a killed run).
    pub fn open(dir: &Path) -> Result<Self> {
        let store = Self::open_read_only(dir)?;
        store.remove_orphans()?;
        Ok(store)
    }

    /// Opens an existing map without touching any file.
    pub fn open_read_only(dir: &Path) -> Result<Self> {
        let path = dir.join(MANIFEST_FILE);
        let bytes = std::fs::read(&path).map_err(|e| {
            if e.kind() == std::io::ErrorKind::NotFound {
                Error::bad_input(
                    &path,
                    "no manifest here: not a denser map directory (or never committed)",
                )
            } else {
                Error::io(&path, e)
            }
        })?;
        let manifest =
            decode_manifest(&bytes).map_err(|e| Error::bad_input(&path, e.to_string()))?;
        Ok(MapStore {
            dir: dir.to_path_buf(),
            manifest,
            superseded: Vec::new(),
            zstd_level: DEFAULT_ZSTD_LEVEL,
        })
    }

    fn remove_orphans(&self) -> Result<()> {
        let chunks = self.dir.join(CHUNKS_DIR);
        let rd = std::fs::read_dir(&chunks).map_err(|e| Error::io(&chunks, e))?;
        for entry in rd {
            let entry = entry.map_err(|e| Error::io(&chunks, e))?;
            let name = entry.file_name().to_string_lossy().into_owned();
            let live = parse_chunk_file_name(&name).is_some_and(|(c, seq)| {
                self.manifest
                    .chunks
                    .get(&c)
                    .is_some_and(|e| e.file_seq == seq)
            });
            if !live && (name.ends_with(".dchk") || name.ends_with(".tmp")) {
                let p = entry.path();
                tracing::info!("removing {} (written after the last commit)", p.display());
                std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
            }
        }
        let tmp = self.dir.join(MANIFEST_FILE).with_extension("tmp");
        if tmp.exists() {
            std::fs::remove_file(&tmp).map_err(|e| Error::io(&tmp, e))?;
        }
        Ok(())
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
        self.manifest.chunks.get(&c).map(|e| {
            self.dir
                .join(CHUNKS_DIR)
                .join(chunk_file_name(c, e.file_seq))
        })
    }

    /// Reserves a never-used file sequence number.
    pub fn allocate_seq(&mut self) -> u64 {
        let s = self.manifest.header.next_file_seq;
        self.manifest.header.next_file_seq += 1;
        s
    }

    /// A writer that encodes and writes chunk files on any thread (see [`ChunkWriter::write`]).
    pub fn writer(&self) -> ChunkWriter {
        ChunkWriter {
            chunks_dir: self.dir.join(CHUNKS_DIR),
            grid: self.grid(),
            chunk_blocks: self.chunk_blocks(),
            zstd_level: self.zstd_level,
        }
    }

    /// Reads and checks chunk `c`; `Ok(None)` when the map does not hold it.
    pub fn read_chunk(&self, c: ChunkIndex) -> Result<Option<DecodedChunk>> {
        let Some(path) = self.chunk_path(c) else {
            return Ok(None);
        };
        let decoded = read_chunk_file(&path)?;
        let h = &decoded.header;
        if h.chunk != c
            || h.chunk_blocks != self.chunk_blocks()
            || h.voxel_size_m != self.manifest.header.voxel_size_m
            || h.truncation_m != self.manifest.header.truncation_m
        {
            return Err(Error::bad_input(
                &path,
                format!(
                    "chunk header ({:?}, {} blocks/edge, {} m voxels, μ {} m) does not match the manifest ({c:?}, {}, {} m, {} m)",
                    h.chunk, h.chunk_blocks, h.voxel_size_m, h.truncation_m,
                    self.chunk_blocks(), self.manifest.header.voxel_size_m, self.manifest.header.truncation_m
                ),
            ));
        }
        Ok(Some(decoded))
    }

    /// Records a written chunk file in the manifest (committed by the next [`MapStore::commit`]);
    /// the file it replaces is deleted after that commit.
    pub fn record(&mut self, w: WrittenChunk) {
        if let Some(old) = self.manifest.chunks.insert(w.chunk, w.entry) {
            if old.file_seq != w.entry.file_seq {
                self.superseded.push(
                    self.dir
                        .join(CHUNKS_DIR)
                        .join(chunk_file_name(w.chunk, old.file_seq)),
                );
            }
        }
    }

    /// Encodes, writes and records chunk `c` synchronously.
    pub fn write_chunk(
        &mut self,
        c: ChunkIndex,
        blocks: &[(BlockIndex, &Block)],
        reg_pass: u32,
    ) -> Result<()> {
        let seq = self.allocate_seq();
        let w = self.writer().write(c, seq, blocks, reg_pass)?;
        self.record(w);
        Ok(())
    }

    /// Commits the manifest atomically, then deletes the files it no longer names.
    pub fn commit(&mut self) -> Result<()> {
        self.manifest.header.generation += 1;
        let path = self.dir.join(MANIFEST_FILE);
        write_atomically(&path, &encode_manifest(&self.manifest))?;
        for p in self.superseded.drain(..) {
            if let Err(e) = std::fs::remove_file(&p) {
                if e.kind() != std::io::ErrorKind::NotFound {
                    return Err(Error::io(&p, e));
                }
            }
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
        s
    }

    /// Reads every chunk and checks it against its manifest entry; returns one line per problem
    /// (file name and what is wrong), empty when the map is sound.
    pub fn verify(&self) -> Vec<String> {
        let mut problems = Vec::new();
        for (c, e) in &self.manifest.chunks {
            let path = self
                .dir
                .join(CHUNKS_DIR)
                .join(chunk_file_name(*c, e.file_seq));
            match self.read_chunk(*c) {
                Err(err) => problems.push(err.to_string()),
                Ok(Some(d)) => {
                    let obs = count_observed(d.blocks.iter().map(|(_, b)| &**b));
                    if d.header.payload_crc32 != e.payload_crc32
                        || d.blocks.len() as u32 != e.block_count
                        || obs != e.observed_voxels
                    {
                        problems.push(format!(
                            "{}: content does not match its manifest entry (blocks {} vs {}, Ω voxels {} vs {}, crc {:#010x} vs {:#010x})",
                            path.display(), d.blocks.len(), e.block_count, obs, e.observed_voxels,
                            d.header.payload_crc32, e.payload_crc32
                        ));
                    }
                }
                Ok(None) => unreachable!("chunk listed in the manifest"),
            }
        }
        problems
    }
}

fn count_observed<'a>(blocks: impl Iterator<Item = &'a Block>) -> u32 {
    blocks.map(|b| b.observed_count() as u32).sum()
}

/// Memory-maps and decodes one chunk file; errors name the file.
pub fn read_chunk_file(path: &Path) -> Result<DecodedChunk> {
    let f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let len = f.metadata().map_err(|e| Error::io(path, e))?.len();
    if len == 0 {
        return Err(Error::bad_input(path, "empty chunk file"));
    }
    // SAFETY: chunk files are never modified in place (new versions get new names), so the
    // mapping cannot change under us while this process or another denser writes the map.
    let map = unsafe { memmap2::Mmap::map(&f) }.map_err(|e| Error::io(path, e))?;
    decode_chunk(&map).map_err(|e| Error::bad_input(path, format!("corrupted chunk: {e}")))
}

/// Encodes and writes chunk files; cheap to clone and `Send`, so background workers can own one.
#[derive(Clone, Debug)]
pub struct ChunkWriter {
    chunks_dir: PathBuf,
    grid: GridParams,
    chunk_blocks: u32,
    zstd_level: i32,
}

impl ChunkWriter {
    /// Encodes `blocks` of chunk `c` and writes them crash-safely as file number `seq` (from
    /// [`MapStore::allocate_seq`]). The result must be given to [`MapStore::record`].
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
        let bytes = encode_chunk(&header, blocks, self.zstd_level);
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
