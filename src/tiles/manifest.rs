//! The map manifest: which chunk file holds each chunk, and how far the jobs that wrote the map got
//! (`formats/manifest.md` is the byte-level spec; keep the two in sync).
//!
//! The manifest is the map's commit point. Chunk files are never overwritten: every write creates a
//! new file named by a sequence number, and a chunk's new version counts only once a manifest that
//! names it has been committed (written to a temporary file, fsynced, renamed over `manifest.dmf`).
//! A run killed at any moment therefore leaves the previous manifest and every file it names intact.
//! Pure encode/decode functions; the I/O lives in [`super::store`].

use super::ChunkIndex;
use crate::regularize::TvParams;
use std::collections::BTreeMap;

/// First 8 bytes of a manifest.
pub const MANIFEST_MAGIC: [u8; 8] = *b"DNSRMANI";
/// Manifest format version written by this build.
pub const MANIFEST_VERSION: u16 = 1;
/// Fixed header size, bytes.
pub const MANIFEST_HEADER_BYTES: usize = 128;
/// Size of one chunk entry, bytes.
pub const MANIFEST_ENTRY_BYTES: usize = 48;
/// Entry flag bit 0: the chunk file carries a regularised field.
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
    /// The regularisation pass that wrote this chunk's `u` (0: never regularised).
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
    /// Current regularisation pass (0: none started); chunks with `reg_pass` equal to it are done.
    pub reg_pass: u32,
    /// Parameters of the current regularisation pass (meaningful when `reg_pass > 0`).
    pub reg_params: TvParams,
}

/// A whole manifest: header and entries sorted by chunk.
#[derive(Clone, Debug, PartialEq)]
pub struct Manifest {
    /// Settings and progress.
    pub header: ManifestHeader,
    /// Every committed chunk.
    pub chunks: BTreeMap<ChunkIndex, ChunkEntry>,
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

/// Encodes a manifest: header, entries sorted by chunk, CRC of the entries.
pub fn encode_manifest(m: &Manifest) -> Vec<u8> {
    let h = &m.header;
    let mut out = vec![0u8; MANIFEST_HEADER_BYTES + m.chunks.len() * MANIFEST_ENTRY_BYTES + 4];
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
    put_u32(&mut out, 60, h.reg_params.iterations);
    put_u32(&mut out, 64, h.reg_params.lambda.to_bits());
    put_u32(&mut out, 68, h.reg_params.sigma.to_bits());
    put_u32(&mut out, 72, h.reg_params.tau.to_bits());
    put_u32(&mut out, 76, h.reg_params.theta.to_bits());
    // 80..124 reserved: zero.
    let crc = crc32fast::hash(&out[0..124]);
    put_u32(&mut out, 124, crc);
    let mut at = MANIFEST_HEADER_BYTES;
    for (c, e) in &m.chunks {
        for a in 0..3 {
            put_u32(&mut out, at + 4 * a, c.0[a] as u32);
        }
        put_u32(&mut out, at + 12, e.block_count);
        put_u32(&mut out, at + 16, e.observed_voxels);
        put_u32(&mut out, at + 20, e.flags);
        put_u64(&mut out, at + 24, e.file_seq);
        put_u64(&mut out, at + 32, e.file_bytes);
        put_u32(&mut out, at + 40, e.payload_crc32);
        put_u32(&mut out, at + 44, e.reg_pass);
        at += MANIFEST_ENTRY_BYTES;
    }
    let crc = crc32fast::hash(&out[MANIFEST_HEADER_BYTES..at]);
    put_u32(&mut out, at, crc);
    out
}

/// Checks and decodes a manifest.
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
    if version != MANIFEST_VERSION {
        return Err(ManifestError::UnsupportedVersion(version));
    }
    if get_u32(b, 124) != crc32fast::hash(&b[0..124]) {
        return Err(ManifestError::Checksum("header"));
    }
    if b[10..12] != [0, 0] || b[80..124].iter().any(|x| *x != 0) {
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
    let header = ManifestHeader {
        voxel_size_m: get_f32(b, 16),
        truncation_m: get_f32(b, 20),
        chunk_blocks: get_u32(b, 24),
        generation: get_u64(b, 32),
        frames_committed: get_u64(b, 40),
        next_file_seq: get_u64(b, 48),
        reg_pass: get_u32(b, 56),
        reg_params: TvParams {
            iterations: get_u32(b, 60),
            lambda: get_f32(b, 64),
            sigma: get_f32(b, 68),
            tau: get_f32(b, 72),
            theta: get_f32(b, 76),
        },
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
    let n = get_u32(b, 28) as usize;
    let need = MANIFEST_HEADER_BYTES as u64 + n as u64 * MANIFEST_ENTRY_BYTES as u64 + 4;
    if (b.len() as u64) < need {
        return Err(ManifestError::Truncated(format!(
            "{} bytes, {n} entries need {need}",
            b.len()
        )));
    }
    if b.len() as u64 > need {
        return Err(ManifestError::Malformed(format!(
            "{} bytes after the entries",
            b.len() as u64 - need
        )));
    }
    let end = MANIFEST_HEADER_BYTES + n * MANIFEST_ENTRY_BYTES;
    if get_u32(b, end) != crc32fast::hash(&b[MANIFEST_HEADER_BYTES..end]) {
        return Err(ManifestError::Checksum("entries"));
    }
    let mut chunks = BTreeMap::new();
    let mut prev: Option<ChunkIndex> = None;
    for k in 0..n {
        let at = MANIFEST_HEADER_BYTES + k * MANIFEST_ENTRY_BYTES;
        let c = ChunkIndex([0, 1, 2].map(|a| get_u32(b, at + 4 * a) as i32));
        if prev.is_some_and(|p| p >= c) {
            return Err(ManifestError::Malformed(format!(
                "entry {k} ({c:?}) out of order or repeated"
            )));
        }
        prev = Some(c);
        let e = ChunkEntry {
            block_count: get_u32(b, at + 12),
            observed_voxels: get_u32(b, at + 16),
            flags: get_u32(b, at + 20),
            file_seq: get_u64(b, at + 24),
            file_bytes: get_u64(b, at + 32),
            payload_crc32: get_u32(b, at + 40),
            reg_pass: get_u32(b, at + 44),
        };
        if e.file_seq >= header.next_file_seq {
            return Err(ManifestError::Malformed(format!(
                "entry {k} names file {} but the next sequence number is {}",
                e.file_seq, header.next_file_seq
            )));
        }
        chunks.insert(c, e);
    }
    Ok(Manifest { header, chunks })
}
