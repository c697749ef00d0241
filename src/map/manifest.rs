//! The map manifest: which chunk file holds each chunk, and how far the jobs that wrote the map got
//! (`formats/manifest.md` is the byte-level spec; keep the two in sync).
//!
//! The manifest is the map's commit point. Chunk files are never overwritten: every write creates a
//! new file named by a sequence number, and a chunk's new version counts only once a manifest that
//! names it has been committed (written to a temporary file, fsynced, renamed over `manifest.dmf`).
//! A run killed at any moment therefore leaves the previous manifest and every file it names intact.
//! Pure encode/decode functions; the I/O lives in [`super::store`].
//!
//! Format 2 (written by this build; format 1 is still read) adds the map's identity, the last
//! *complete* regularization pass beside the pass in progress, and a second table of **kept**
//! files: for each chunk that the pass in progress has already rewritten, the file it had in the
//! last complete pass, so that pass stays readable until the new one completes.

use super::ChunkIndex;
use crate::regularize::TvParams;
use std::collections::BTreeMap;

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

/// First 8 bytes of a manifest.
pub const MANIFEST_MAGIC: [u8; 8] = *b"DNSRMANI";
/// Manifest format version written by this build.
pub const MANIFEST_VERSION: u16 = 2;
/// The previous manifest format version, still read (a v1 map opens; its next commit writes v2).
pub const MANIFEST_VERSION_1: u16 = 1;
/// `frames_committed` of a manifest rebuilt by `repair`: the fusion cursor was lost with the old
/// manifest, so fusion cannot resume (`reconstruct --map` refuses: more frames than the job has).
pub const FRAMES_UNKNOWN: u64 = u64::MAX;
/// Fixed header size, bytes.
pub const MANIFEST_HEADER_BYTES: usize = 128;
/// Size of one chunk entry, bytes.
pub const MANIFEST_ENTRY_BYTES: usize = 48;
/// Entry flag bit 0: the chunk file carries a regularized field.
pub const ENTRY_HAS_REGULARIZED: u32 = 1;

/// One chunk as the manifest records it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChunkEntry {
    /// Blocks in the chunk file.
    pub block_count: u32,
    /// Voxels in Ω in the chunk.
    pub observed_voxels: u32,
    /// Flags ([`ENTRY_HAS_REGULARIZED`]).
    pub flags: u32,
    /// Sequence number of the chunk file (its name, see [`chunk_file_name`]).
    pub file_seq: u64,
    /// Size of the chunk file, bytes.
    pub file_bytes: u64,
    /// The chunk file's payload CRC-32 (as in its header): `inspect --verify` compares them.
    pub payload_crc32: u32,
    /// The regularization pass that wrote this chunk's `u` (0: never regularized).
    pub reg_pass: u32,
}

/// Map-wide settings and job progress.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ManifestHeader {
    /// Voxel edge, metres.
    pub voxel_size_m: f32,
    /// Truncation μ, metres.
    pub truncation_m: f32,
    /// Chunk edge, blocks.
    pub chunk_blocks: u32,
    /// Incremented by every commit.
    pub generation: u64,
    /// Frames of the source sequence whose updates every listed chunk contains (resume cursor).
    pub frames_committed: u64,
    /// The next chunk file sequence number (file names are never reused).
    pub next_file_seq: u64,
    /// Latest regularization pass started (0: none); chunks with `reg_pass` equal to it are done,
    /// and it is complete when every chunk is.
    pub reg_pass: u32,
    /// Parameters of the latest pass (meaningful when `reg_pass > 0`).
    pub reg_params: TvParams,
    /// The last pass that completed (0: none). Equal to `reg_pass` unless a newer pass is in
    /// progress; then [`Manifest::kept`] holds its files of the chunks the newer pass rewrote.
    pub complete_pass: u32,
    /// Parameters of the last complete pass (meaningful when `complete_pass > 0`).
    pub complete_params: TvParams,
    /// The map's identity (random, fixed at creation; 0 = unknown: a format-1 map not yet
    /// written by this build). Chunk files of format 2 carry it.
    pub map_id: u64,
}

/// A whole manifest: header and entries sorted by chunk.
#[derive(Clone, Debug, PartialEq)]
pub struct Manifest {
    /// Settings and progress.
    pub header: ManifestHeader,
    /// Every committed chunk: its current file.
    pub chunks: BTreeMap<ChunkIndex, ChunkEntry>,
    /// Files of the last complete pass (`header.complete_pass`) of the chunks that the pass in
    /// progress has rewritten (empty when no pass is in progress). Every key is in `chunks`.
    pub kept: BTreeMap<ChunkIndex, ChunkEntry>,
}

impl Manifest {
    /// Whether file `seq` of chunk `c` is one this manifest names (current or kept).
    pub fn names(&self, c: ChunkIndex, seq: u64) -> bool {
        [&self.chunks, &self.kept]
            .iter()
            .any(|m| m.get(&c).is_some_and(|e| e.file_seq == seq))
    }

    /// Whether the latest regularization pass has reached every chunk (true when none started).
    pub fn latest_pass_complete(&self) -> bool {
        self.header.reg_pass == 0
            || self
                .chunks
                .values()
                .all(|e| e.reg_pass == self.header.reg_pass)
    }

    /// The entry of chunk `c` as the last complete pass left it: its kept file if the pass in
    /// progress rewrote it, else its current file.
    pub fn complete_pass_entry(&self, c: ChunkIndex) -> Option<&ChunkEntry> {
        self.kept.get(&c).or_else(|| self.chunks.get(&c))
    }

    /// Where regularization stands: the latest pass and how many chunks it reached, the last
    /// complete pass, and the chunks by the pass that wrote their current file.
    pub fn pass_status(&self) -> PassStatus {
        let h = &self.header;
        let mut by_pass: BTreeMap<u32, Vec<ChunkIndex>> = BTreeMap::new();
        for (c, e) in &self.chunks {
            by_pass.entry(e.reg_pass).or_default().push(*c);
        }
        PassStatus {
            pass: h.reg_pass,
            params: h.reg_params,
            done_chunks: by_pass.get(&h.reg_pass).map_or(0, Vec::len),
            total_chunks: self.chunks.len(),
            complete_pass: h.complete_pass,
            complete_params: h.complete_params,
            kept_chunks: self.kept.len(),
            chunks_at_pass: by_pass.iter().map(|(p, v)| (*p, v.len())).collect(),
            by_pass,
        }
    }
}

/// Where a map's regularization stands ([`Manifest::pass_status`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PassStatus {
    /// The latest pass started (0: never regularized).
    pub pass: u32,
    /// Its parameters.
    pub params: TvParams,
    /// Chunks whose current file that pass wrote.
    pub done_chunks: usize,
    /// Chunks of the map.
    pub total_chunks: usize,
    /// The last complete pass (0: none), readable in full until the latest pass completes.
    pub complete_pass: u32,
    /// Its parameters.
    pub complete_params: TvParams,
    /// Chunks whose file of the last complete pass is kept beside the newer one.
    pub kept_chunks: usize,
    /// How many chunks each pass wrote the current file of (pass 0: fusion).
    pub chunks_at_pass: BTreeMap<u32, usize>,
    /// The chunks themselves, sorted, by pass.
    #[serde(skip)]
    pub by_pass: BTreeMap<u32, Vec<ChunkIndex>>,
}

impl PassStatus {
    /// Whether the latest pass reached every chunk (true for a map never regularized).
    pub fn is_complete(&self) -> bool {
        self.pass == 0 || self.done_chunks == self.total_chunks
    }

    /// One line: "pass 3, λ 0.7: 64 of 164 chunks (incomplete); pass 2, λ 0.8 complete and
    /// still readable", "pass 2, λ 0.8: 164 of 164 chunks (complete)", or "not regularized".
    pub fn describe(&self) -> String {
        if self.pass == 0 {
            return "not regularized".into();
        }
        let mut s = format!(
            "pass {}, λ {}: {} of {} chunks ({}, {} iterations)",
            self.pass,
            self.params.lambda,
            self.done_chunks,
            self.total_chunks,
            if self.is_complete() {
                "complete"
            } else {
                "incomplete"
            },
            self.params.iterations
        );
        if !self.is_complete() && self.complete_pass > 0 && self.complete_pass != self.pass {
            s.push_str(&format!(
                "; pass {}, λ {} ({} iterations) complete and still readable",
                self.complete_pass, self.complete_params.lambda, self.complete_params.iterations
            ));
        }
        s
    }

    /// Which chunks are which: one line per pass that wrote current files, with their chunks
    /// (the first `limit` of each, or all).
    pub fn chunks_by_pass_lines(&self, limit: Option<usize>) -> Vec<String> {
        self.by_pass
            .iter()
            .rev()
            .map(|(p, cs)| {
                let shown = limit.unwrap_or(cs.len()).min(cs.len());
                let mut list: Vec<String> = cs[..shown]
                    .iter()
                    .map(|c| format!("({},{},{})", c.0[0], c.0[1], c.0[2]))
                    .collect();
                if shown < cs.len() {
                    list.push(format!("… and {} more", cs.len() - shown));
                }
                let what = if *p == 0 {
                    "not regularized since fusion".to_string()
                } else if *p == self.pass {
                    format!("pass {p}, λ {}", self.params.lambda)
                } else if *p == self.complete_pass {
                    format!("pass {p}, λ {}", self.complete_params.lambda)
                } else {
                    format!("pass {p} (abandoned)")
                };
                format!("{} chunks at {what}: {}", cs.len(), list.join(" "))
            })
            .collect()
    }
}

/// File name (inside `chunks/`) of chunk `c`'s file with sequence number `seq`.
pub fn chunk_file_name(c: ChunkIndex, seq: u64) -> String {
    format!("c_{}_{}_{}_{:012}.dchk", c.0[0], c.0[1], c.0[2], seq)
}

/// Parses a name made by [`chunk_file_name`].
pub fn parse_chunk_file_name(name: &str) -> Option<(ChunkIndex, u64)> {
    let stem = name.strip_prefix("c_")?.strip_suffix(".dchk")?;
    let parts: Vec<&str> = stem.split('_').collect();
    if parts.len() != 4 {
        return None;
    }
    let c = [
        parts[0].parse().ok()?,
        parts[1].parse().ok()?,
        parts[2].parse().ok()?,
    ];
    Some((ChunkIndex(c), parts[3].parse().ok()?))
}

/// Why a manifest could not be decoded (the store adds the file name).
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ManifestError {
    /// Not a manifest.
    #[error("not a denser manifest (bad magic)")]
    BadMagic,
    /// A version this build cannot read.
    #[error("manifest version {0} is not supported (this build reads version {MANIFEST_VERSION})")]
    UnsupportedVersion(u16),
    /// Shorter than its header says.
    #[error("truncated: {0}")]
    Truncated(String),
    /// A checksum mismatch.
    #[error("{0} checksum mismatch")]
    Checksum(&'static str),
    /// Checksums match but the content breaks the format.
    #[error("malformed: {0}")]
    Malformed(String),
}

fn put_u32(b: &mut [u8], at: usize, v: u32) {
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
}
fn put_u64(b: &mut [u8], at: usize, v: u64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}
fn get_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}
fn get_u64(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}
fn get_f32(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

fn put_entry(out: &mut [u8], at: usize, c: &ChunkIndex, e: &ChunkEntry) {
    for a in 0..3 {
        put_u32(out, at + 4 * a, c.0[a] as u32);
    }
    put_u32(out, at + 12, e.block_count);
    put_u32(out, at + 16, e.observed_voxels);
    put_u32(out, at + 20, e.flags);
    put_u64(out, at + 24, e.file_seq);
    put_u64(out, at + 32, e.file_bytes);
    put_u32(out, at + 40, e.payload_crc32);
    put_u32(out, at + 44, e.reg_pass);
}

fn get_entry(b: &[u8], at: usize) -> (ChunkIndex, ChunkEntry) {
    let c = ChunkIndex([0, 1, 2].map(|a| get_u32(b, at + 4 * a) as i32));
    let e = ChunkEntry {
        block_count: get_u32(b, at + 12),
        observed_voxels: get_u32(b, at + 16),
        flags: get_u32(b, at + 20),
        file_seq: get_u64(b, at + 24),
        file_bytes: get_u64(b, at + 32),
        payload_crc32: get_u32(b, at + 40),
        reg_pass: get_u32(b, at + 44),
    };
    (c, e)
}

fn put_params(out: &mut [u8], at: usize, p: &TvParams) {
    put_u32(out, at, p.iterations);
    put_u32(out, at + 4, p.lambda.to_bits());
    put_u32(out, at + 8, p.sigma.to_bits());
    put_u32(out, at + 12, p.tau.to_bits());
    put_u32(out, at + 16, p.theta.to_bits());
}

fn get_params(b: &[u8], at: usize) -> TvParams {
    TvParams {
        iterations: get_u32(b, at),
        lambda: get_f32(b, at + 4),
        sigma: get_f32(b, at + 8),
        tau: get_f32(b, at + 12),
        theta: get_f32(b, at + 16),
    }
}

/// Encodes a manifest in format 2: header, entries sorted by chunk, kept entries sorted by chunk,
/// CRC of both tables.
pub fn encode_manifest(m: &Manifest) -> Vec<u8> {
    let h = &m.header;
    let n = m.chunks.len() + m.kept.len();
    let mut out = vec![0u8; MANIFEST_HEADER_BYTES + n * MANIFEST_ENTRY_BYTES + 4];
    out[0..8].copy_from_slice(&MANIFEST_MAGIC);
    out[8..10].copy_from_slice(&MANIFEST_VERSION.to_le_bytes());
    // 10..12 flags: zero.
    put_u32(&mut out, 12, MANIFEST_HEADER_BYTES as u32);
    put_u32(&mut out, 16, h.voxel_size_m.to_bits());
    put_u32(&mut out, 20, h.truncation_m.to_bits());
    put_u32(&mut out, 24, h.chunk_blocks);
    put_u32(&mut out, 28, m.chunks.len() as u32);
    put_u64(&mut out, 32, h.generation);
    put_u64(&mut out, 40, h.frames_committed);
    put_u64(&mut out, 48, h.next_file_seq);
    put_u32(&mut out, 56, h.reg_pass);
    put_params(&mut out, 60, &h.reg_params);
    put_u32(&mut out, 80, h.complete_pass);
    put_params(&mut out, 84, &h.complete_params);
    put_u64(&mut out, 104, h.map_id);
    put_u32(&mut out, 112, m.kept.len() as u32);
    // 116..124 reserved: zero.
    let crc = crc32fast::hash(&out[0..124]);
    put_u32(&mut out, 124, crc);
    let mut at = MANIFEST_HEADER_BYTES;
    for (c, e) in m.chunks.iter().chain(&m.kept) {
        put_entry(&mut out, at, c, e);
        at += MANIFEST_ENTRY_BYTES;
    }
    let crc = crc32fast::hash(&out[MANIFEST_HEADER_BYTES..at]);
    put_u32(&mut out, at, crc);
    out
}

/// Checks and decodes a manifest of format 2 or 1 (a format-1 manifest reads as format 2 with
/// no kept files and map id 0; its pass counts as complete when every chunk is at it).
pub fn decode_manifest(b: &[u8]) -> Result<Manifest, ManifestError> {
    if b.len() < 8 || b[0..8] != MANIFEST_MAGIC {
        return Err(ManifestError::BadMagic);
    }
    if b.len() < MANIFEST_HEADER_BYTES {
        return Err(ManifestError::Truncated(format!(
            "{} bytes, header needs {MANIFEST_HEADER_BYTES}",
            b.len()
        )));
    }
    let version = u16::from_le_bytes([b[8], b[9]]);
    if version != MANIFEST_VERSION && version != MANIFEST_VERSION_1 {
        return Err(ManifestError::UnsupportedVersion(version));
    }
    if get_u32(b, 124) != crc32fast::hash(&b[0..124]) {
        return Err(ManifestError::Checksum("header"));
    }
    let reserved = if version == MANIFEST_VERSION_1 {
        80..124
    } else {
        116..124
    };
    if b[10..12] != [0, 0] || b[reserved].iter().any(|x| *x != 0) {
        return Err(ManifestError::Malformed(
            "flags or reserved bytes are not zero".into(),
        ));
    }
    if get_u32(b, 12) as usize != MANIFEST_HEADER_BYTES {
        return Err(ManifestError::Malformed(format!(
            "header length {}",
            get_u32(b, 12)
        )));
    }
    let v2 = version == MANIFEST_VERSION;
    let header = ManifestHeader {
        voxel_size_m: get_f32(b, 16),
        truncation_m: get_f32(b, 20),
        chunk_blocks: get_u32(b, 24),
        generation: get_u64(b, 32),
        frames_committed: get_u64(b, 40),
        next_file_seq: get_u64(b, 48),
        reg_pass: get_u32(b, 56),
        reg_params: get_params(b, 60),
        complete_pass: if v2 { get_u32(b, 80) } else { 0 },
        complete_params: if v2 {
            get_params(b, 84)
        } else {
            crate::map::codec::NO_PARAMS
        },
        map_id: if v2 { get_u64(b, 104) } else { 0 },
    };
    if !(header.voxel_size_m > 0.0
        && header.truncation_m > 0.0
        && (1..=256).contains(&header.chunk_blocks))
    {
        return Err(ManifestError::Malformed(format!(
            "voxel size {} m, truncation {} m, chunk edge {} blocks",
            header.voxel_size_m, header.truncation_m, header.chunk_blocks
        )));
    }
    if header.complete_pass > header.reg_pass {
        return Err(ManifestError::Malformed(format!(
            "complete pass {} is newer than the latest pass {}",
            header.complete_pass, header.reg_pass
        )));
    }
    let n = get_u32(b, 28) as usize;
    let k = if v2 { get_u32(b, 112) as usize } else { 0 };
    let need =
        MANIFEST_HEADER_BYTES as u64 + (n as u64 + k as u64) * MANIFEST_ENTRY_BYTES as u64 + 4;
    if (b.len() as u64) < need {
        return Err(ManifestError::Truncated(format!(
            "{} bytes, {n} entries and {k} kept files need {need}",
            b.len()
        )));
    }
    if b.len() as u64 > need {
        return Err(ManifestError::Malformed(format!(
            "{} bytes after the entries",
            b.len() as u64 - need
        )));
    }
    let end = MANIFEST_HEADER_BYTES + (n + k) * MANIFEST_ENTRY_BYTES;
    if get_u32(b, end) != crc32fast::hash(&b[MANIFEST_HEADER_BYTES..end]) {
        return Err(ManifestError::Checksum("entries"));
    }
    let mut tables: [BTreeMap<ChunkIndex, ChunkEntry>; 2] = [BTreeMap::new(), BTreeMap::new()];
    for (t, (first, count)) in [(0usize, n), (n, k)].into_iter().enumerate() {
        let mut prev: Option<ChunkIndex> = None;
        for j in first..first + count {
            let (c, e) = get_entry(b, MANIFEST_HEADER_BYTES + j * MANIFEST_ENTRY_BYTES);
            let what = if t == 0 { "entry" } else { "kept entry" };
            if prev.is_some_and(|p| p >= c) {
                return Err(ManifestError::Malformed(format!(
                    "{what} {} ({c:?}) out of order or repeated",
                    j - first
                )));
            }
            prev = Some(c);
            if e.file_seq >= header.next_file_seq || e.file_seq == 0 {
                return Err(ManifestError::Malformed(format!(
                    "{what} {} names file {} but sequence numbers run from 1 to {}",
                    j - first,
                    e.file_seq,
                    header.next_file_seq - 1
                )));
            }
            if t == 1 {
                match tables[0].get(&c) {
                    Some(cur) if cur.file_seq != e.file_seq => {}
                    _ => {
                        return Err(ManifestError::Malformed(format!(
                            "kept entry {} ({c:?}) has no distinct current file",
                            j - first
                        )))
                    }
                }
            }
            tables[t].insert(c, e);
        }
    }
    let [chunks, kept] = tables;
    let mut m = Manifest {
        header,
        chunks,
        kept,
    };
    if !v2 && m.header.reg_pass > 0 && m.latest_pass_complete() {
        m.header.complete_pass = m.header.reg_pass;
        m.header.complete_params = m.header.reg_params;
    }
    Ok(m)
}
