//! The solver state a swept regularization pass keeps between sweeps (`formats/sweep-state.md`):
//! one file per chunk and sweep parity holding, for each of the chunk's blocks, its Ω voxels'
//! stored TSDF and weight and the Chambolle–Pock state `u`, `ū`, `p` (f32), behind a block index
//! so that a halo read takes only the blocks it needs (each block record has its own CRC); and a
//! small progress record saying which step of the pass finished for how many regions.
//!
//! Pure codecs: no I/O here ([`super::sweeps`] reads and writes through
//! [`crate::map::files::MapFiles`]). Voxels outside Ω are not stored: the solver never reads or
//! changes them ([`crate::regularize::TvProblem`]'s link bits need both voxels in Ω).

use crate::error::{Error, Result};
use crate::grid::{BlockIndex, VOXELS_PER_BLOCK};
use std::path::Path;

/// Magic of a state file.
pub const STATE_MAGIC: [u8; 4] = *b"DSW1";
/// Format version of state files this build reads and writes.
pub const STATE_VERSION: u16 = 1;
/// Bytes of a state file's fixed header.
pub const STATE_HEADER_BYTES: usize = 40;
/// Bytes of one block-index entry.
pub const STATE_ENTRY_BYTES: usize = 24;
/// Bytes of a block record per Ω voxel: TSDF `i16`, weight `u8`, `u`, `ū`, `p_x`, `p_y`, `p_z`.
pub const STATE_BYTES_PER_OMEGA_VOXEL: usize = 2 + 1 + 5 * 4;
/// Bytes of a block record's Ω bit mask.
pub const STATE_MASK_BYTES: usize = VOXELS_PER_BLOCK / 8;

/// Magic of the progress record.
pub const PROGRESS_MAGIC: [u8; 4] = *b"DSP1";
/// Format version of the progress record.
pub const PROGRESS_VERSION: u16 = 1;

/// One block's state as stored: its Ω voxels in voxel order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BlockState {
    /// Ω bit per voxel (bit `i % 64` of word `i / 64`).
    pub omega: [u64; 8],
    /// Stored TSDF (`grid::encode_tsdf` units) of the Ω voxels.
    pub tsdf: Vec<i16>,
    /// Observation count of the Ω voxels.
    pub weight: Vec<u8>,
    /// Primal variable.
    pub u: Vec<f32>,
    /// Over-relaxed primal variable.
    pub ubar: Vec<f32>,
    /// Dual variable, three components.
    pub p: [Vec<f32>; 3],
}

impl BlockState {
    /// Number of Ω voxels.
    pub fn omega_count(&self) -> usize {
        self.omega.iter().map(|w| w.count_ones() as usize).sum()
    }

    /// Whether voxel `i` is in Ω.
    pub fn in_omega(&self, i: usize) -> bool {
        self.omega[i / 64] >> (i % 64) & 1 != 0
    }

    /// Bytes of the record.
    pub fn record_bytes(&self) -> usize {
        STATE_MASK_BYTES + self.tsdf.len() * STATE_BYTES_PER_OMEGA_VOXEL
    }

    fn encode(&self, out: &mut Vec<u8>) {
        for w in self.omega {
            out.extend_from_slice(&w.to_le_bytes());
        }
        for v in &self.tsdf {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&self.weight);
        for plane in [&self.u, &self.ubar, &self.p[0], &self.p[1], &self.p[2]] {
            for v in plane.iter() {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
    }

    /// The state of a record [`checked_record`] returned with its Ω mask.
    fn decode(b: &[u8], omega: [u64; 8]) -> Self {
        let mut s = BlockState {
            omega,
            ..Default::default()
        };
        let n = s.omega_count();
        let mut at = STATE_MASK_BYTES;
        s.tsdf = b[at..at + 2 * n]
            .chunks_exact(2)
            .map(|c| i16::from_le_bytes([c[0], c[1]]))
            .collect();
        at += 2 * n;
        s.weight = b[at..at + n].to_vec();
        at += n;
        let mut plane = || {
            let v: Vec<f32> = b[at..at + 4 * n]
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            at += 4 * n;
            v
        };
        s.u = plane();
        s.ubar = plane();
        s.p = [plane(), plane(), plane()];
        s
    }
}

/// What a state file's header says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StateHeader {
    /// The pass's key ([`super::sweeps`]): state of another pass or map is never read.
    pub key: u64,
    /// The chunk.
    pub chunk: [i32; 3],
    /// The step whose result this is (0: the initial state).
    pub step: u32,
    /// Number of blocks.
    pub block_count: u32,
}

/// Encodes a chunk's state file from its blocks (sorted by index).
pub fn encode_state(header: &StateHeader, blocks: &[(BlockIndex, BlockState)]) -> Vec<u8> {
    let records: usize = blocks.iter().map(|(_, s)| s.record_bytes()).sum();
    let index: Vec<BlockIndex> = blocks.iter().map(|(b, _)| *b).collect();
    encode_state_with(header, &index, records, |k, out| blocks[k].1.encode(out))
}

/// [`encode_state`] with each block's record written by `record(k, out)` (appending block
/// `blocks[k]`'s record to `out`); `records_bytes`: their total length, if known (0 otherwise).
pub fn encode_state_with(
    header: &StateHeader,
    blocks: &[BlockIndex],
    records_bytes: usize,
    mut record: impl FnMut(usize, &mut Vec<u8>),
) -> Vec<u8> {
    let records = records_bytes;
    let table = STATE_HEADER_BYTES + blocks.len() * STATE_ENTRY_BYTES;
    let mut out = Vec::with_capacity(table + records);
    out.extend_from_slice(&STATE_MAGIC);
    out.extend_from_slice(&STATE_VERSION.to_le_bytes());
    out.extend_from_slice(&[0, 0]);
    out.extend_from_slice(&header.key.to_le_bytes());
    for a in header.chunk {
        out.extend_from_slice(&a.to_le_bytes());
    }
    out.extend_from_slice(&header.step.to_le_bytes());
    out.extend_from_slice(&(blocks.len() as u32).to_le_bytes());
    out.extend_from_slice(&[0; 4]); // the header CRC, below
    let mut body = Vec::with_capacity(records);
    for (k, b) in blocks.iter().enumerate() {
        let offset = (table + body.len()) as u64;
        let start = body.len();
        record(k, &mut body);
        let crc = crc32fast::hash(&body[start..]);
        for a in b.0 {
            out.extend_from_slice(&a.to_le_bytes());
        }
        out.extend_from_slice(&(offset as u32).to_le_bytes());
        out.extend_from_slice(&crc.to_le_bytes());
        out.extend_from_slice(&((body.len() - start) as u32).to_le_bytes());
    }
    let crc = crc32fast::hash(&[&out[..36], &out[STATE_HEADER_BYTES..]].concat());
    out[36..40].copy_from_slice(&crc.to_le_bytes());
    out.extend_from_slice(&body);
    out
}

/// A state file's header and block index, checked; `path` names the file in errors.
pub struct StateIndex {
    /// The header.
    pub header: StateHeader,
    /// Per block: index, byte range of its record, CRC-32 of the record.
    pub entries: Vec<(BlockIndex, std::ops::Range<usize>, u32)>,
}

/// Reads and checks a state file's header and block index.
pub fn decode_state_index(path: &Path, b: &[u8]) -> Result<StateIndex> {
    let bad = |m: String| Error::bad_input(path, m);
    if b.len() < STATE_HEADER_BYTES || b[..4] != STATE_MAGIC {
        return Err(bad("not a denser sweep state file (bad magic)".into()));
    }
    let le32 = |at: usize| u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]);
    let version = u16::from_le_bytes([b[4], b[5]]);
    if version != STATE_VERSION {
        return Err(bad(format!(
            "sweep state version {version}, this denser reads version {STATE_VERSION}"
        )));
    }
    let key = u64::from_le_bytes(b[8..16].try_into().map_err(|_| bad("short".into()))?);
    let chunk = [le32(16) as i32, le32(20) as i32, le32(24) as i32];
    let step = le32(28);
    let count = le32(32) as usize;
    let table = STATE_HEADER_BYTES + count * STATE_ENTRY_BYTES;
    if b.len() < table {
        return Err(bad(format!(
            "sweep state file is {} bytes, its index of {count} blocks needs {table}",
            b.len()
        )));
    }
    let crc = crc32fast::hash(&[&b[..36], &b[STATE_HEADER_BYTES..table]].concat());
    if crc != le32(36) {
        return Err(bad(
            "sweep state header checksum mismatch (corrupted)".into()
        ));
    }
    let mut entries = Vec::with_capacity(count);
    for k in 0..count {
        let at = STATE_HEADER_BYTES + k * STATE_ENTRY_BYTES;
        let index = BlockIndex([le32(at) as i32, le32(at + 4) as i32, le32(at + 8) as i32]);
        let (offset, crc, len) = (
            le32(at + 12) as usize,
            le32(at + 16),
            le32(at + 20) as usize,
        );
        if offset < table || offset + len > b.len() {
            return Err(bad(format!(
                "sweep state block {:?}: record {offset}..{} outside the file of {} bytes",
                index.0,
                offset + len,
                b.len()
            )));
        }
        entries.push((index, offset..offset + len, crc));
    }
    Ok(StateIndex {
        header: StateHeader {
            key,
            chunk,
            step,
            block_count: count as u32,
        },
        entries,
    })
}

/// The record `entry` of state file `b` (read from `path`) with its Ω mask, checked: its CRC,
/// then a length that matches the mask.
fn checked_record<'a>(
    path: &Path,
    b: &'a [u8],
    entry: (&BlockIndex, &std::ops::Range<usize>, u32),
) -> Result<(&'a [u8], [u64; 8])> {
    let rec = &b[entry.1.clone()];
    let bad = |m: &str| Error::bad_input(path, format!("sweep state block {:?}: {m}", entry.0 .0));
    if crc32fast::hash(rec) != entry.2 {
        return Err(bad("checksum mismatch (corrupted)"));
    }
    if rec.len() < STATE_MASK_BYTES {
        return Err(bad("record shorter than its Ω mask"));
    }
    let mut omega = [0u64; 8];
    for (k, w) in omega.iter_mut().enumerate() {
        *w = u64::from_le_bytes(rec[8 * k..8 * k + 8].try_into().expect("8 bytes"));
    }
    let n: usize = omega.iter().map(|w| w.count_ones() as usize).sum();
    if rec.len() != STATE_MASK_BYTES + n * STATE_BYTES_PER_OMEGA_VOXEL {
        return Err(bad("record length does not match its Ω mask"));
    }
    Ok((rec, omega))
}

/// Decodes one block record of a state file (checked against its CRC).
pub fn decode_block_state(
    path: &Path,
    b: &[u8],
    entry: &(BlockIndex, std::ops::Range<usize>, u32),
) -> Result<BlockState> {
    let (rec, omega) = checked_record(path, b, (&entry.0, &entry.1, entry.2))?;
    Ok(BlockState::decode(rec, omega))
}

/// One block's 512-voxel slices of a solver's arrays (voxel `i` of the block at index `i`).
pub struct DenseBlock<'a> {
    /// Raw TSDF f.
    pub f: &'a mut [f32],
    /// Data weight w.
    pub w: &'a mut [f32],
    /// Ω.
    pub omega: &'a mut [bool],
    /// Primal variable u.
    pub u: &'a mut [f32],
    /// Relaxed primal variable ū.
    pub ubar: &'a mut [f32],
    /// Dual variable p (x, y, z).
    pub p: [&'a mut [f32]; 3],
}

/// Decodes the record `entry` of state file `b` (read from `path`) into `out`: its Ω voxels
/// get their stored values, the others are left as they are. Checks the record's CRC and length.
pub fn decode_block_into(
    path: &Path,
    b: &[u8],
    entry: (&BlockIndex, &std::ops::Range<usize>, u32),
    out: DenseBlock,
) -> Result<()> {
    let (rec, omega) = checked_record(path, b, entry)?;
    let idx = omega_voxels(&omega);
    let n = idx.len();
    let (tsdf, rest) = rec[STATE_MASK_BYTES..].split_at(2 * n);
    let (weight, rest) = rest.split_at(n);
    for (c, &i) in tsdf.chunks_exact(2).zip(&idx) {
        out.f[i] = crate::grid::decode_tsdf(i16::from_le_bytes([c[0], c[1]]));
        out.omega[i] = true;
    }
    for (v, &i) in weight.iter().zip(&idx) {
        out.w[i] = *v as f32;
    }
    let [px, py, pz] = out.p;
    for (k, plane) in [out.u, out.ubar, px, py, pz].into_iter().enumerate() {
        for (c, &i) in rest[4 * n * k..4 * n * (k + 1)].chunks_exact(4).zip(&idx) {
            plane[i] = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        }
    }
    Ok(())
}

/// The voxels an Ω mask of a block holds, in order.
fn omega_voxels(mask: &[u64; 8]) -> Vec<usize> {
    let mut idx = Vec::with_capacity(VOXELS_PER_BLOCK);
    for (k, &word) in mask.iter().enumerate() {
        let mut w = word;
        while w != 0 {
            idx.push(64 * k + w.trailing_zeros() as usize);
            w &= w - 1;
        }
    }
    idx
}

/// Appends the record of a block given as its 512-voxel slices (read-only [`DenseBlock`]): the
/// voxels where `omega` holds, with f and w stored as the map stores them (`encode_tsdf`, a
/// byte), which gives back exactly the values [`decode_block_into`] read.
pub fn encode_dense_record(
    out: &mut Vec<u8>,
    omega: impl Fn(usize) -> bool,
    fields: [&[f32]; 4],
    p: [&[f32]; 3],
) {
    let [f, w, u, ubar] = fields;
    let mut mask = [0u64; 8];
    for i in 0..VOXELS_PER_BLOCK {
        if omega(i) {
            mask[i / 64] |= 1 << (i % 64);
        }
    }
    let idx = omega_voxels(&mask);
    let n = idx.len();
    let start = out.len();
    out.resize(
        start + STATE_MASK_BYTES + n * STATE_BYTES_PER_OMEGA_VOXEL,
        0,
    );
    let rec = &mut out[start..];
    for (c, w) in rec.chunks_exact_mut(8).zip(mask) {
        c.copy_from_slice(&w.to_le_bytes());
    }
    let (tsdf, rest) = rec[STATE_MASK_BYTES..].split_at_mut(2 * n);
    let (weight, rest) = rest.split_at_mut(n);
    for (c, &i) in tsdf.chunks_exact_mut(2).zip(&idx) {
        c.copy_from_slice(&crate::grid::encode_tsdf(f[i]).to_le_bytes());
    }
    for (c, &i) in weight.iter_mut().zip(&idx) {
        *c = w[i] as u8;
    }
    for (plane, out) in [u, ubar, p[0], p[1], p[2]]
        .into_iter()
        .zip(rest.chunks_exact_mut(4 * n.max(1)))
    {
        for (c, &i) in out.chunks_exact_mut(4).zip(&idx) {
            c.copy_from_slice(&plane[i].to_le_bytes());
        }
    }
}

/// How far a swept pass has come (`sweeps/progress.dsp`, a bincode 2 payload behind a header).
#[derive(Clone, Debug, PartialEq, bincode::Encode, bincode::Decode)]
pub struct SweepProgress {
    /// Key of the pass (map, pass number, parameters, region edge, iterations per sweep).
    pub key: u64,
    /// The chunk table the pass started from: index and file number of every chunk.
    pub chunks: Vec<([i32; 3], u64)>,
    /// Steps finished for every region (0: none; step 0 writes the initial state, step `s ≥ 1`
    /// runs sweep `s`).
    pub steps_done: u32,
    /// Regions (in the pass's order) finished of the step under way.
    pub regions_done: u32,
}

impl SweepProgress {
    /// The record's file bytes.
    pub fn encode(&self) -> Vec<u8> {
        crate::map::record::encode(PROGRESS_MAGIC, PROGRESS_VERSION, self)
    }

    /// Decodes file bytes; `path` names the file in errors.
    pub fn decode(path: &Path, b: &[u8]) -> Result<Self> {
        crate::map::record::decode(
            path,
            b,
            PROGRESS_MAGIC,
            PROGRESS_VERSION,
            "sweep progress record",
            "sweep progress",
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn state_files_round_trip_and_refuse_corruption() {
        let mut s = BlockState::default();
        for i in [0usize, 5, 63, 64, 300, 511] {
            s.omega[i / 64] |= 1 << (i % 64);
            s.tsdf.push(i as i16 - 200);
            s.weight.push((i % 127) as u8);
            s.u.push(i as f32 * 0.5);
            s.ubar.push(-(i as f32));
            s.p[0].push(0.25);
            s.p[1].push(-0.75);
            s.p[2].push(i as f32 / 512.0);
        }
        let blocks = vec![
            (BlockIndex([-1, 2, 3]), s.clone()),
            (BlockIndex([0, 2, 3]), BlockState::default()),
        ];
        let h = StateHeader {
            key: 0x1234_5678_9abc_def0,
            chunk: [-1, 0, 0],
            step: 3,
            block_count: 2,
        };
        let bytes = encode_state(&h, &blocks);
        let p = Path::new("x.dsws");
        let idx = decode_state_index(p, &bytes).expect("index");
        assert_eq!(idx.header, h);
        assert_eq!(idx.entries.len(), 2);
        for (e, (b, want)) in idx.entries.iter().zip(&blocks) {
            assert_eq!(e.0, *b);
            assert_eq!(&decode_block_state(p, &bytes, e).expect("block"), want);
        }
        // A flipped bit in a record is found by that record's CRC only.
        let mut bad = bytes.clone();
        let at = idx.entries[0].1.start + STATE_MASK_BYTES + 3;
        bad[at] ^= 1;
        let idx2 = decode_state_index(p, &bad).expect("index intact");
        assert!(decode_block_state(p, &bad, &idx2.entries[0]).is_err());
        // A flipped bit in the index is found by the header CRC.
        let mut bad = bytes.clone();
        bad[STATE_HEADER_BYTES + 1] ^= 1;
        assert!(decode_state_index(p, &bad).is_err());
        assert!(decode_state_index(p, &bytes[..10]).is_err());
        let pr = SweepProgress {
            key: 7,
            chunks: vec![([1, 2, 3], 9)],
            steps_done: 4,
            regions_done: 2,
        };
        assert_eq!(
            SweepProgress::decode(p, &pr.encode()).expect("progress"),
            pr
        );
        let mut b = pr.encode();
        b[13] ^= 1;
        assert!(SweepProgress::decode(p, &b).is_err());
    }

    /// A record written from a solver's dense slices decodes (both ways) to the same state, and
    /// decoding into dense slices gives back what [`BlockState`] holds: f and w through the
    /// map's quantisation exactly.
    #[test]
    fn dense_records_round_trip() {
        let n = VOXELS_PER_BLOCK;
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let omega: Vec<bool> = (0..n).map(|_| next() % 3 != 0).collect();
        let mut fields = [(); 4].map(|_| vec![0.0f32; n]);
        let mut p = [(); 3].map(|_| vec![0.0f32; n]);
        for i in (0..n).filter(|i| omega[*i]) {
            fields[0][i] = crate::grid::decode_tsdf(((next() % 65535) as i32 - 32767) as i16);
            fields[1][i] = (next() % 256) as f32;
            for v in fields[2..].iter_mut().chain(p.iter_mut()) {
                v[i] = f32::from_bits(next() as u32 & 0x3fff_ffff) - 1.0;
            }
        }
        let mut rec = Vec::new();
        encode_dense_record(
            &mut rec,
            |i| omega[i],
            [&fields[0], &fields[1], &fields[2], &fields[3]],
            [&p[0], &p[1], &p[2]],
        );
        let h = StateHeader {
            key: 1,
            chunk: [0, 0, 0],
            step: 1,
            block_count: 1,
        };
        let b = BlockIndex([3, -4, 5]);
        let file = encode_state_with(&h, &[b], rec.len(), |_, out| out.extend_from_slice(&rec));
        let path = Path::new("s.dsws");
        let idx = decode_state_index(path, &file).expect("index");
        let e = &idx.entries[0];
        let state = decode_block_state(path, &file, e).expect("record");
        assert_eq!(state.omega_count(), omega.iter().filter(|o| **o).count());
        let [mut f, mut w, mut u, mut ubar] = [(); 4].map(|_| vec![7.0f32; n]);
        let mut om = vec![false; n];
        let mut q = [(); 3].map(|_| vec![7.0f32; n]);
        let [qx, qy, qz] = &mut q;
        let out = DenseBlock {
            f: &mut f,
            w: &mut w,
            omega: &mut om,
            u: &mut u,
            ubar: &mut ubar,
            p: [qx, qy, qz],
        };
        decode_block_into(path, &file, (&e.0, &e.1, e.2), out).expect("dense");
        assert_eq!(om, omega);
        let mut k = 0;
        for i in 0..n {
            let got = [f[i], w[i], u[i], ubar[i], q[0][i], q[1][i], q[2][i]];
            if !omega[i] {
                assert!(
                    got.iter().all(|v| *v == 7.0),
                    "voxel {i} outside Ω untouched"
                );
                continue;
            }
            let want = [
                fields[0][i],
                fields[1][i],
                fields[2][i],
                fields[3][i],
                p[0][i],
                p[1][i],
                p[2][i],
            ];
            assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "voxel {i}");
            assert_eq!(crate::grid::decode_tsdf(state.tsdf[k]), fields[0][i]);
            assert_eq!(state.weight[k] as f32, fields[1][i]);
            assert_eq!(state.u[k].to_bits(), fields[2][i].to_bits());
            k += 1;
        }
        // A corrupted record is refused by the dense decoder too.
        let mut bad = file.clone();
        bad[e.1.start + STATE_MASK_BYTES] ^= 4;
        let out = DenseBlock {
            f: &mut f,
            w: &mut w,
            omega: &mut om,
            u: &mut u,
            ubar: &mut ubar,
            p: q.each_mut().map(|v| v.as_mut_slice()),
        };
        assert!(decode_block_into(path, &bad, (&e.0, &e.1, e.2), out).is_err());
    }

    /// Every stored TSDF value survives decoding to f32 and encoding back: the state files
    /// store f as the map does.
    #[test]
    fn tsdf_quantisation_round_trips() {
        use crate::grid::{decode_tsdf, encode_tsdf};
        for q in -32767i16..=32767 {
            assert_eq!(encode_tsdf(decode_tsdf(q)), q);
        }
    }
}
