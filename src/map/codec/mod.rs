//! The chunk codec: pure functions between a chunk's blocks and the bytes of a chunk file
//! (`formats/chunk.md` is the byte-level spec; keep the two in sync).
//!
//! No I/O and no residency here: [`encode_chunk`] turns blocks into bytes, [`decode_chunk`] checks
//! and turns bytes back into blocks. Decoding never panics on arbitrary input (fuzzed by a
//! property test): every length is checked before it is used, both CRCs are verified, and the
//! decompressed size is bounded by what the header's block count allows.
//!
//! Layout of the compressed payload (columnar, so zstd sees long runs of similar bytes): block
//! coordinates, block flags, weights, then the other voxel fields as byte planes over each block's
//! non-empty voxels only (empty voxels hold known defaults; a block where they do not is coded
//! densely). TSDF values are stored as the zigzag-coded difference to the previous coded voxel of
//! the block (x fastest), low bytes then high bytes; the regularized field as zigzag `u − f`.
//!
//! Format 1 (64-byte header) and format 2 (128 bytes, adding the file's **origin**
//! ([`ChunkOrigin`]: map id, file sequence number, the regularization pass that wrote `u` and its
//! parameters) so that a file can be checked against the manifest entry that names it and a lost
//! manifest can be rebuilt from the files alone) share that payload. Format 3 keeps format 2's
//! header and layout but stores every voxel field as the residual of a prediction from the
//! voxel's coded neighbours in its block and the blocks next to it ([`predict`]; `u` also from
//! the TSDF's residual), one zstd frame per part (the structured parts at level 15 at least),
//! which takes ~15 % fewer bytes. The store writes format 3 ([`encode_chunk_v3`]); all three
//! are read.

mod frames;
mod payload;
pub mod predict;

pub use frames::PreviousFrames;
pub use payload::payload_planes;

use super::ChunkIndex;
use crate::grid::{Block, BlockIndex, VOXELS_PER_BLOCK};
use crate::regularize::TvParams;

/// First 8 bytes of every chunk file.
pub const CHUNK_MAGIC: [u8; 8] = *b"DNSRCHNK";
/// Chunk format version of [`encode_chunk`] (no origin; still read).
pub const CHUNK_VERSION: u16 = 1;
/// Chunk format version with an origin and the legacy payload ([`encode_chunk_with`]; still read).
pub const CHUNK_VERSION_2: u16 = 2;
/// Chunk format version with an origin and predicted voxel fields ([`encode_chunk_v3`]; still
/// read).
pub const CHUNK_VERSION_3: u16 = 3;
/// Format 3 with the file's commit generation in its header ([`encode_chunk_v4_reusing`]); the
/// store writes this one.
pub const CHUNK_VERSION_4: u16 = 4;
/// Size of the fixed header of format 1, bytes.
pub const CHUNK_HEADER_BYTES: usize = 64;
/// Size of the fixed header of formats 2, 3 and 4, bytes.
pub const CHUNK_HEADER_V2_BYTES: usize = 128;

/// Where a chunk file comes from (format 2 only): what the store checks against the manifest
/// entry naming the file, and what `repair` rebuilds a lost manifest from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChunkOrigin {
    /// Identity of the map the file was written for (random, fixed when the map is created;
    /// 0 = unknown).
    pub map_id: u64,
    /// The file's sequence number (also in its name).
    pub file_seq: u64,
    /// The regularization pass that wrote the file's `u` (0: written by fusion, or no `u`).
    pub reg_pass: u32,
    /// That pass's parameters (all zero when `reg_pass` is 0).
    pub reg_params: TvParams,
    /// The commit generation (format 4; 0 in formats 2 and 3, "unknown"): for a file of the map's
    /// writer, the generation of the commit that names it; for a regularization shard's file,
    /// the generation of the manifest it was derived from (a later commit adopts it). Versions
    /// of a chunk order by (commit generation, file number): what `repair` keeps, and how a
    /// writer tells a rolled-back manifest from a dead writer's leftovers.
    pub commit_gen: u64,
}

/// TV parameters that are all zero: the "no pass" value stored in headers.
pub const NO_PARAMS: TvParams = TvParams {
    lambda: 0.0,
    sigma: 0.0,
    tau: 0.0,
    theta: 0.0,
    iterations: 0,
};
/// Header flag bit 0: at least one block carries a regularized field.
pub const FLAG_HAS_REGULARIZED: u16 = 1;
/// Block flag bit 0: this block carries a regularized field.
pub const BLOCK_HAS_REGULARIZED: u8 = 1;
/// zstd level used by [`encode_chunk`] (3 = zstd's default: fast, ~4–5× on TSDF blocks).
pub const DEFAULT_ZSTD_LEVEL: i32 = 3;
/// Least zstd level of format 3 for the parts other than the low bytes of the TSDF and of `u`
/// (weights, high bytes, colour, coordinates, flags): 4 % fewer bytes in all than level 3, for
/// ~5× the encode time (`docs/bench/memory.md`).
pub const STRUCTURED_ZSTD_LEVEL: i32 = 15;

/// What a chunk header says, apart from the payload.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChunkHeader {
    /// Edge of a voxel, metres (must match the map's).
    pub voxel_size_m: f32,
    /// Truncation distance μ, metres (must match the map's).
    pub truncation_m: f32,
    /// The chunk's coordinate (in chunks).
    pub chunk: ChunkIndex,
    /// Edge of a chunk, blocks (1..=256).
    pub chunk_blocks: u32,
    /// Blocks stored in this chunk.
    pub block_count: u32,
    /// Header flags ([`FLAG_HAS_REGULARIZED`]).
    pub flags: u16,
    /// Length of the payload once decompressed, bytes.
    pub payload_raw_bytes: u32,
    /// Length of the zstd payload that follows the header, bytes.
    pub payload_zstd_bytes: u32,
    /// CRC-32 (IEEE) of the zstd payload.
    pub payload_crc32: u32,
}

/// Why a chunk could not be decoded. The store adds the file name.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum CodecError {
    /// Shorter than a header, or shorter than the header says.
    #[error("truncated: {0}")]
    Truncated(String),
    /// The first 8 bytes are not `DNSRCHNK`.
    #[error("not a denser chunk file (bad magic)")]
    BadMagic,
    /// A version this build cannot read.
    #[error(
        "chunk format version {found} is not supported (this build reads versions {CHUNK_VERSION} to {CHUNK_VERSION_4})"
    )]
    UnsupportedVersion {
        /// Version found in the header.
        found: u16,
    },
    /// The header CRC does not match: the header is corrupted.
    #[error("header checksum mismatch (stored {stored:#010x}, computed {computed:#010x})")]
    HeaderChecksum {
        /// CRC stored in the file.
        stored: u32,
        /// CRC of the bytes read.
        computed: u32,
    },
    /// The payload CRC does not match: the payload is corrupted.
    #[error("payload checksum mismatch (stored {stored:#010x}, computed {computed:#010x})")]
    PayloadChecksum {
        /// CRC stored in the header.
        stored: u32,
        /// CRC of the bytes read.
        computed: u32,
    },
    /// The header or payload is self-consistent by checksum but violates the format.
    #[error("malformed: {0}")]
    Malformed(String),
}

/// Block flag bit 1: every voxel is coded (some empty voxel deviates from the defaults); without
/// it only the block's non-empty voxels (weight/Ω byte ≠ 0) carry TSDF, colour and `u`.
pub const BLOCK_DENSE: u8 = 2;

/// Bytes of the decompressed payload: `n` blocks, `coded` voxels carrying TSDF and colour, of
/// which `coded_reg` also carry `u`.
pub fn payload_raw_bytes(n: usize, coded: usize, coded_reg: usize) -> usize {
    n * (3 + 1 + VOXELS_PER_BLOCK) + coded * (2 + 3) + coded_reg * 2
}

/// Encodes `blocks` (all inside `header.chunk`, any order, no duplicates) into a complete chunk
/// file of format 1 (no origin). `header.block_count`, `flags`, payload lengths and CRC are filled
/// in here; the other header fields are taken as given.
///
/// Panics if a block lies outside the chunk or appears twice (a caller bug, not bad input).
pub fn encode_chunk(
    header: &ChunkHeader,
    blocks: &[(BlockIndex, &Block)],
    zstd_level: i32,
) -> Vec<u8> {
    encode_chunk_with(header, None, blocks, zstd_level)
}

/// [`encode_chunk`] with a choice of format: `Some(origin)` writes format 2 (128-byte header
/// carrying `origin`), `None` format 1.
pub fn encode_chunk_with(
    header: &ChunkHeader,
    origin: Option<&ChunkOrigin>,
    blocks: &[(BlockIndex, &Block)],
    zstd_level: i32,
) -> Vec<u8> {
    let version = if origin.is_some() {
        CHUNK_VERSION_2
    } else {
        CHUNK_VERSION
    };
    encode_chunk_version(header, origin, blocks, zstd_level, version, None)
}

/// Format 3: format 2's header carrying `origin`, voxel fields stored as prediction residuals.
/// What the store writes.
pub fn encode_chunk_v3(
    header: &ChunkHeader,
    origin: &ChunkOrigin,
    blocks: &[(BlockIndex, &Block)],
    zstd_level: i32,
) -> Vec<u8> {
    encode_chunk_v3_reusing(
        header,
        origin,
        blocks,
        zstd_level,
        &PreviousFrames::default(),
    )
}

/// Format 4, what the store writes: format 3 with `origin.commit_gen` in the header, copying the
/// compressed frames of `previous` (the file this one replaces) for every part that has not
/// changed.
pub fn encode_chunk_v4_reusing(
    header: &ChunkHeader,
    origin: &ChunkOrigin,
    blocks: &[(BlockIndex, &Block)],
    zstd_level: i32,
    previous: &PreviousFrames,
) -> Vec<u8> {
    encode_chunk_version(
        header,
        Some(origin),
        blocks,
        zstd_level,
        CHUNK_VERSION_4,
        Some(previous),
    )
}

/// [`encode_chunk_v3`] copying the compressed frames of `previous` (the file this one replaces)
/// for every part that has not changed, instead of compressing those parts again.
pub fn encode_chunk_v3_reusing(
    header: &ChunkHeader,
    origin: &ChunkOrigin,
    blocks: &[(BlockIndex, &Block)],
    zstd_level: i32,
    previous: &PreviousFrames,
) -> Vec<u8> {
    encode_chunk_version(
        header,
        Some(origin),
        blocks,
        zstd_level,
        CHUNK_VERSION_3,
        Some(previous),
    )
}

/// `blocks` sorted by local coordinate in `header.chunk`, with those coordinates.
///
/// Panics if a block lies outside the chunk or appears twice (a caller bug, not bad input).
pub fn local_order<'a>(
    header: &ChunkHeader,
    blocks: &[(BlockIndex, &'a Block)],
) -> Vec<([u8; 3], &'a Block)> {
    let cb = header.chunk_blocks as i32;
    let first_block = header.chunk.origin_block(header.chunk_blocks);
    let mut order: Vec<([u8; 3], &Block)> = blocks
        .iter()
        .map(|(b, blk)| {
            let l = [0, 1, 2].map(|a| b.0[a] - first_block[a]);
            assert!(
                l.iter().all(|&c| (0..cb).contains(&c)),
                "block {b:?} is outside chunk {:?}",
                header.chunk
            );
            ([l[0] as u8, l[1] as u8, l[2] as u8], *blk)
        })
        .collect();
    order.sort_unstable_by_key(|(l, _)| *l);
    assert!(
        order.windows(2).all(|w| w[0].0 != w[1].0),
        "duplicate block in chunk"
    );
    order
}

fn encode_chunk_version(
    header: &ChunkHeader,
    origin: Option<&ChunkOrigin>,
    blocks: &[(BlockIndex, &Block)],
    zstd_level: i32,
    version: u16,
    previous: Option<&PreviousFrames>,
) -> Vec<u8> {
    let order = local_order(header, blocks);
    let n = order.len();
    let n_reg = order
        .iter()
        .filter(|(_, b)| b.regularized.is_some())
        .count();
    let predicted = version >= CHUNK_VERSION_3;
    let planes = payload_planes(&order, predicted);
    let raw_len: usize = planes.iter().map(|(_, p)| p.len()).sum();
    let compress =
        |b: &[u8], level: i32| zstd::bulk::compress(b, level).expect("zstd of an in-memory buffer");
    let zstd_payload = if predicted {
        // One frame per non-empty part, so that zstd's entropy tables fit each part. The low
        // bytes of the TSDF and of `u` are noise (no level shrinks them); the other parts get at
        // least STRUCTURED_ZSTD_LEVEL.
        planes
            .iter()
            .filter(|(_, p)| !p.is_empty())
            .flat_map(|(name, p)| {
                if let Some(frame) = previous.and_then(|f| f.frame_of(p)) {
                    return frame.to_vec();
                }
                match *name {
                    "tsdf low" | "u low" => compress(p, zstd_level),
                    _ => compress(p, zstd_level.max(STRUCTURED_ZSTD_LEVEL)),
                }
            })
            .collect::<Vec<u8>>()
    } else {
        compress(
            &planes.into_iter().flat_map(|(_, p)| p).collect::<Vec<u8>>(),
            zstd_level,
        )
    };
    let h = ChunkHeader {
        block_count: n as u32,
        flags: if n_reg > 0 { FLAG_HAS_REGULARIZED } else { 0 },
        payload_raw_bytes: raw_len as u32,
        payload_zstd_bytes: zstd_payload.len() as u32,
        payload_crc32: crc32fast::hash(&zstd_payload),
        ..*header
    };
    let mut out = Vec::with_capacity(CHUNK_HEADER_V2_BYTES + zstd_payload.len());
    match origin {
        Some(o) => out.extend_from_slice(&header_with_origin(&h, o, version)),
        None => out.extend_from_slice(&encode_header(&h)),
    }
    out.extend_from_slice(&zstd_payload);
    out
}

/// The 64 header bytes of `h` in format 1 (CRC of bytes 0..60 in bytes 60..64).
pub fn encode_header(h: &ChunkHeader) -> [u8; CHUNK_HEADER_BYTES] {
    let mut b = [0u8; CHUNK_HEADER_BYTES];
    put_common(&mut b, h, CHUNK_VERSION);
    // 56..60 reserved, zero.
    let crc = crc32fast::hash(&b[0..60]);
    b[60..64].copy_from_slice(&crc.to_le_bytes());
    b
}

/// The 128 header bytes of `h` with `origin` in format 2 (CRC of bytes 0..124 in bytes 124..128).
pub fn encode_header_v2(h: &ChunkHeader, origin: &ChunkOrigin) -> [u8; CHUNK_HEADER_V2_BYTES] {
    header_with_origin(h, origin, CHUNK_VERSION_2)
}

/// The 128 header bytes of `h` with `origin` in format 3: format 2's table with version 3.
pub fn encode_header_v3(h: &ChunkHeader, origin: &ChunkOrigin) -> [u8; CHUNK_HEADER_V2_BYTES] {
    header_with_origin(h, origin, CHUNK_VERSION_3)
}

fn header_with_origin(
    h: &ChunkHeader,
    origin: &ChunkOrigin,
    version: u16,
) -> [u8; CHUNK_HEADER_V2_BYTES] {
    let mut b = [0u8; CHUNK_HEADER_V2_BYTES];
    put_common(&mut b, h, version);
    b[56..64].copy_from_slice(&origin.map_id.to_le_bytes());
    b[64..72].copy_from_slice(&origin.file_seq.to_le_bytes());
    b[72..76].copy_from_slice(&origin.reg_pass.to_le_bytes());
    let p = &origin.reg_params;
    b[76..80].copy_from_slice(&p.iterations.to_le_bytes());
    b[80..84].copy_from_slice(&p.lambda.to_le_bytes());
    b[84..88].copy_from_slice(&p.sigma.to_le_bytes());
    b[88..92].copy_from_slice(&p.tau.to_le_bytes());
    b[92..96].copy_from_slice(&p.theta.to_le_bytes());
    if version >= CHUNK_VERSION_4 {
        b[96..104].copy_from_slice(&origin.commit_gen.to_le_bytes());
    } else {
        debug_assert_eq!(
            origin.commit_gen, 0,
            "formats 2 and 3 carry no commit generation"
        );
    }
    // The rest up to 124 reserved, zero.
    let crc = crc32fast::hash(&b[0..124]);
    b[124..128].copy_from_slice(&crc.to_le_bytes());
    b
}

/// Bytes 0..56, common to all formats.
fn put_common(b: &mut [u8], h: &ChunkHeader, version: u16) {
    let len = if version == CHUNK_VERSION {
        CHUNK_HEADER_BYTES
    } else {
        CHUNK_HEADER_V2_BYTES
    };
    b[0..8].copy_from_slice(&CHUNK_MAGIC);
    b[8..10].copy_from_slice(&version.to_le_bytes());
    b[10..12].copy_from_slice(&h.flags.to_le_bytes());
    b[12..16].copy_from_slice(&(len as u32).to_le_bytes());
    b[16..20].copy_from_slice(&h.voxel_size_m.to_le_bytes());
    b[20..24].copy_from_slice(&h.truncation_m.to_le_bytes());
    for a in 0..3 {
        b[24 + 4 * a..28 + 4 * a].copy_from_slice(&h.chunk.0[a].to_le_bytes());
    }
    b[36..40].copy_from_slice(&h.chunk_blocks.to_le_bytes());
    b[40..44].copy_from_slice(&h.block_count.to_le_bytes());
    b[44..48].copy_from_slice(&h.payload_raw_bytes.to_le_bytes());
    b[48..52].copy_from_slice(&h.payload_zstd_bytes.to_le_bytes());
    b[52..56].copy_from_slice(&h.payload_crc32.to_le_bytes());
}

fn le_u16(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn le_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// Checks and parses the header at the start of `bytes` (magic, version, header CRC, ranges), of
/// either format; the origin (format 2) is dropped: see [`decode_header_with_origin`].
pub fn decode_header(bytes: &[u8]) -> Result<ChunkHeader, CodecError> {
    decode_header_with_origin(bytes).map(|(h, _)| h)
}

/// Length of the header of a file whose header decoded with `origin` (format 2) or without.
pub fn header_len(origin: Option<&ChunkOrigin>) -> usize {
    if origin.is_some() {
        CHUNK_HEADER_V2_BYTES
    } else {
        CHUNK_HEADER_BYTES
    }
}

/// [`decode_header`] returning the origin too (`None` for a format-1 file).
pub fn decode_header_with_origin(
    bytes: &[u8],
) -> Result<(ChunkHeader, Option<ChunkOrigin>), CodecError> {
    if bytes.len() < 8 || bytes[0..8] != CHUNK_MAGIC {
        if bytes.len() < 8 && CHUNK_MAGIC.starts_with(bytes) {
            return Err(CodecError::Truncated(format!(
                "{} bytes, header needs {CHUNK_HEADER_BYTES}",
                bytes.len()
            )));
        }
        return Err(CodecError::BadMagic);
    }
    if bytes.len() < 10 {
        return Err(CodecError::Truncated(format!(
            "{} bytes, header needs {CHUNK_HEADER_BYTES}",
            bytes.len()
        )));
    }
    let version = le_u16(bytes, 8);
    let len = match version {
        CHUNK_VERSION => CHUNK_HEADER_BYTES,
        CHUNK_VERSION_2 | CHUNK_VERSION_3 | CHUNK_VERSION_4 => CHUNK_HEADER_V2_BYTES,
        _ => return Err(CodecError::UnsupportedVersion { found: version }),
    };
    if bytes.len() < len {
        return Err(CodecError::Truncated(format!(
            "{} bytes, header needs {len}",
            bytes.len()
        )));
    }
    let stored = le_u32(bytes, len - 4);
    let computed = crc32fast::hash(&bytes[0..len - 4]);
    if stored != computed {
        return Err(CodecError::HeaderChecksum { stored, computed });
    }
    let header_len = le_u32(bytes, 12);
    if header_len as usize != len {
        return Err(CodecError::Malformed(format!(
            "header length {header_len}, expected {len}"
        )));
    }
    let reserved = match version {
        CHUNK_VERSION => 56..60,
        CHUNK_VERSION_4 => 104..124,
        _ => 96..124,
    };
    if bytes[reserved.clone()].iter().any(|x| *x != 0) {
        return Err(CodecError::Malformed(format!(
            "reserved header bytes {reserved:?} are not zero"
        )));
    }
    let h = ChunkHeader {
        flags: le_u16(bytes, 10),
        voxel_size_m: f32::from_le_bytes(bytes[16..20].try_into().expect("4 bytes")),
        truncation_m: f32::from_le_bytes(bytes[20..24].try_into().expect("4 bytes")),
        chunk: ChunkIndex([0, 1, 2].map(|a| le_u32(bytes, 24 + 4 * a) as i32)),
        chunk_blocks: le_u32(bytes, 36),
        block_count: le_u32(bytes, 40),
        payload_raw_bytes: le_u32(bytes, 44),
        payload_zstd_bytes: le_u32(bytes, 48),
        payload_crc32: le_u32(bytes, 52),
    };
    if h.flags & !FLAG_HAS_REGULARIZED != 0 {
        return Err(CodecError::Malformed(format!(
            "unknown header flags {:#06x}",
            h.flags
        )));
    }
    if !(h.voxel_size_m.is_finite()
        && h.voxel_size_m > 0.0
        && h.truncation_m.is_finite()
        && h.truncation_m > 0.0)
    {
        return Err(CodecError::Malformed(format!(
            "voxel size {} m / truncation {} m must be positive",
            h.voxel_size_m, h.truncation_m
        )));
    }
    if !(1..=256).contains(&h.chunk_blocks) {
        return Err(CodecError::Malformed(format!(
            "chunk edge {} blocks is outside 1..=256",
            h.chunk_blocks
        )));
    }
    let max_blocks = (h.chunk_blocks as u64).pow(3);
    if h.block_count as u64 > max_blocks {
        return Err(CodecError::Malformed(format!(
            "{} blocks in a chunk of {} blocks",
            h.block_count, max_blocks
        )));
    }
    let n = h.block_count as usize;
    let lo = payload_raw_bytes(n, 0, 0);
    let hi = payload_raw_bytes(n, n * VOXELS_PER_BLOCK, n * VOXELS_PER_BLOCK);
    if (h.payload_raw_bytes as usize) < lo || h.payload_raw_bytes as usize > hi {
        return Err(CodecError::Malformed(format!(
            "payload of {} bytes cannot hold {n} blocks",
            h.payload_raw_bytes
        )));
    }
    let origin = (version != CHUNK_VERSION).then(|| ChunkOrigin {
        map_id: u64::from_le_bytes(bytes[56..64].try_into().expect("8 bytes")),
        file_seq: u64::from_le_bytes(bytes[64..72].try_into().expect("8 bytes")),
        reg_pass: le_u32(bytes, 72),
        reg_params: TvParams {
            iterations: le_u32(bytes, 76),
            lambda: f32::from_le_bytes(bytes[80..84].try_into().expect("4 bytes")),
            sigma: f32::from_le_bytes(bytes[84..88].try_into().expect("4 bytes")),
            tau: f32::from_le_bytes(bytes[88..92].try_into().expect("4 bytes")),
            theta: f32::from_le_bytes(bytes[92..96].try_into().expect("4 bytes")),
        },
        commit_gen: if version >= CHUNK_VERSION_4 {
            u64::from_le_bytes(bytes[96..104].try_into().expect("8 bytes"))
        } else {
            0
        },
    });
    Ok((h, origin))
}

/// A decoded chunk: its header and its blocks, sorted by block index.
#[derive(Clone, PartialEq)]
pub struct DecodedChunk {
    /// The header as stored.
    pub header: ChunkHeader,
    /// The file's origin (format 2; `None` for a format-1 file).
    pub origin: Option<ChunkOrigin>,
    /// The blocks, sorted by [`BlockIndex`].
    pub blocks: Vec<(BlockIndex, Box<Block>)>,
}

/// Checks and decodes a complete chunk file of any format (header + payload; trailing bytes
/// are an error).
pub fn decode_chunk(bytes: &[u8]) -> Result<DecodedChunk, CodecError> {
    let (h, origin) = decode_header_with_origin(bytes)?;
    let predicted = le_u16(bytes, 8) >= CHUNK_VERSION_3;
    let body = &bytes[header_len(origin.as_ref())..];
    let zlen = h.payload_zstd_bytes as usize;
    if body.len() < zlen {
        return Err(CodecError::Truncated(format!(
            "payload has {} of {zlen} bytes",
            body.len()
        )));
    }
    if body.len() > zlen {
        return Err(CodecError::Malformed(format!(
            "{} bytes after the payload",
            body.len() - zlen
        )));
    }
    let computed = crc32fast::hash(body);
    if computed != h.payload_crc32 {
        return Err(CodecError::PayloadChecksum {
            stored: h.payload_crc32,
            computed,
        });
    }
    let cap = h.payload_raw_bytes as usize;
    let raw = zstd::bulk::decompress(body, cap)
        .map_err(|e| CodecError::Malformed(format!("zstd: {e}")))?;
    if raw.len() != cap {
        return Err(CodecError::Malformed(format!(
            "payload decompressed to {} bytes, header says {cap}",
            raw.len()
        )));
    }
    let n = h.block_count as usize;
    let mut at = 0usize;
    let mut take = |len: usize| -> Result<&[u8], CodecError> {
        let s = raw
            .get(at..at + len)
            .ok_or_else(|| CodecError::Malformed("payload shorter than its fields".into()))?;
        at += len;
        Ok(s)
    };
    let coords = take(3 * n)?;
    let flags = take(n)?;
    let first_block = h.chunk.origin_block(h.chunk_blocks);
    let mut blocks: Vec<(BlockIndex, Box<Block>)> = Vec::with_capacity(n);
    let mut prev: Option<[u8; 3]> = None;
    for i in 0..n {
        let l = [coords[3 * i], coords[3 * i + 1], coords[3 * i + 2]];
        if l.iter().any(|&c| c as u32 >= h.chunk_blocks) {
            return Err(CodecError::Malformed(format!(
                "block {i} at {l:?} is outside the chunk"
            )));
        }
        if prev.is_some_and(|p| p >= l) {
            return Err(CodecError::Malformed(format!(
                "block {i} at {l:?} is out of order or repeated"
            )));
        }
        prev = Some(l);
        if flags[i] & !(BLOCK_HAS_REGULARIZED | BLOCK_DENSE) != 0 {
            return Err(CodecError::Malformed(format!(
                "block {i} has unknown flags {:#04x}",
                flags[i]
            )));
        }
        let index = BlockIndex([0, 1, 2].map(|a| first_block[a] + l[a] as i32));
        blocks.push((index, Block::new_boxed()));
    }
    let n_reg = flags
        .iter()
        .filter(|f| **f & BLOCK_HAS_REGULARIZED != 0)
        .count();
    if n_reg > 0 && h.flags & FLAG_HAS_REGULARIZED == 0
        || n_reg == 0 && h.flags & FLAG_HAS_REGULARIZED != 0
    {
        return Err(CodecError::Malformed(
            "header and block flags disagree about the regularized field".into(),
        ));
    }
    let vb = VOXELS_PER_BLOCK;
    let w = take(n * vb)?;
    for (k, (_, b)) in blocks.iter_mut().enumerate() {
        b.weight_omega.copy_from_slice(&w[k * vb..(k + 1) * vb]);
    }
    let coded: Vec<usize> = blocks
        .iter()
        .zip(flags)
        .map(|((_, b), f)| {
            let m = payload::coded_mask(&b.weight_omega, f & BLOCK_DENSE != 0);
            m.iter().filter(|c| **c).count()
        })
        .collect();
    let k: usize = coded.iter().sum();
    let k_reg: usize = coded
        .iter()
        .zip(flags)
        .filter(|(_, f)| **f & BLOCK_HAS_REGULARIZED != 0)
        .map(|(c, _)| c)
        .sum();
    if cap != payload_raw_bytes(n, k, k_reg) {
        return Err(CodecError::Malformed(format!(
            "payload of {cap} bytes, {n} blocks with {k} coded voxels ({k_reg} with u) need {}",
            payload_raw_bytes(n, k, k_reg)
        )));
    }
    let rest = take(5 * k + 2 * k_reg)?;
    let locals: Vec<[u8; 3]> = coords.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    payload::read_voxel_planes(&mut blocks, &locals, flags, predicted, (k, k_reg), rest)?;
    Ok(DecodedChunk {
        header: h,
        origin,
        blocks,
    })
}
