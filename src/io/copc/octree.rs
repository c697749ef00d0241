//! The COPC octree, built top-down with one rule at every node (see [`super`]'s documentation),
//! each node's points compressed as one LAZ chunk.

use super::{io_err, CopcStats, Cube, VoxelKey, NODE_GRID, POINT_RECORD_BYTES};
use crate::error::{Error, Result};
use laz::laszip::{ChunkTable, ChunkTableEntry};
use laz::{LasZipCompressor, LazVlr};
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// A quantised point: LAS integer coordinates and 8-bit colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Q {
    pub xyz: [i32; 3],
    pub rgb: [u8; 3],
}

/// The octree builder of [`super::write_file`]: nodes split as the module documentation says,
/// each final node's points compressed as one LAZ chunk. Final nodes wait in a batch that is
/// compressed on every thread and written in the order the nodes were made, so the file does not
/// depend on the threads.
pub(super) struct Builder {
    pub cube: Cube,
    /// The file, positioned after the reserved offset to the chunk table.
    pub out: BufWriter<std::fs::File>,
    /// The position in the file `out` writes next, bytes.
    pub pos: u64,
    pub path: PathBuf,
    pub tmp_dir: PathBuf,
    pub max_in_memory: u64,
    pub entries: Vec<(VoxelKey, u64, i32, i32)>,
    pub stats: CopcStats,
    pub next_tmp: u64,
    pub vlr: LazVlr,
    /// The LAZ chunk table: one entry per node, in file order.
    pub table: ChunkTable,
    /// Final nodes not yet compressed, and their points.
    pub pending: Vec<(VoxelKey, Vec<Q>)>,
    pub pending_points: u64,
    /// Points the batch may hold before it is compressed.
    pub flush_points: u64,
}

impl Builder {
    fn octant(&self, k: VoxelKey, q: &Q) -> (usize, usize) {
        let (lo, edge) = self.cube.node_lo_edge(k);
        let cell = edge / NODE_GRID as i64;
        let mut idx = 0usize;
        let mut oct = 0usize;
        for a in (0..3).rev() {
            let d = (q.xyz[a] as i64 - lo[a]).clamp(0, edge - 1);
            idx = idx * NODE_GRID as usize + (d / cell) as usize;
            if d >= edge / 2 {
                oct |= 1 << a;
            }
        }
        (idx, oct)
    }

    fn is_leaf(&self, k: VoxelKey) -> bool {
        // Cells below 2 integer units (2 mm) cannot separate points any more.
        (self.cube.edge >> k.level) / (NODE_GRID as i64) < 2
    }

    fn emit(&mut self, k: VoxelKey, pts: Vec<Q>) -> Result<()> {
        if pts.is_empty() {
            return Ok(());
        }
        self.stats.nodes += 1;
        self.stats.max_level = self.stats.max_level.max(k.level as u32);
        if k.level == 0 {
            self.stats.root_points = pts.len() as u64;
        }
        self.pending_points += pts.len() as u64;
        self.pending.push((k, pts));
        if self.pending_points >= self.flush_points {
            self.flush()?;
        }
        Ok(())
    }

    /// Compresses the waiting nodes, one LAZ chunk each, on every thread, and writes them in the
    /// order they were made.
    pub fn flush(&mut self) -> Result<()> {
        use rayon::prelude::*;
        let pending = std::mem::take(&mut self.pending);
        self.pending_points = 0;
        let vlr = &self.vlr;
        let path = &self.path;
        // One compressor per task, reused from node to node (building one costs more than a
        // small node's compression); each node's chunk is cut from its output.
        let compressed: Vec<Result<(VoxelKey, usize, Vec<u8>)>> = pending
            .into_par_iter()
            .map_init(
                || NodeCompressor::new(vlr),
                |c, (k, mut pts)| {
                    // Spatially coherent order compresses better.
                    pts.sort_unstable_by_key(|q| (q.xyz[2], q.xyz[1], q.xyz[0]));
                    let bytes = c.chunk(&pts).map_err(io_err(path))?;
                    Ok((k, pts.len(), bytes))
                },
            )
            .collect();
        for c in compressed {
            let (k, n, bytes) = c?;
            let size = i32::try_from(bytes.len()).map_err(|_| {
                Error::InvalidArgument(format!("{}: an octree node exceeds 2 GiB", path.display()))
            })?;
            self.out.write_all(&bytes).map_err(io_err(path))?;
            self.entries.push((k, self.pos, size, n as i32));
            self.table.push(ChunkTableEntry {
                point_count: n as u64,
                byte_count: bytes.len() as u64,
            });
            self.pos += bytes.len() as u64;
        }
        Ok(())
    }

    /// Processes node `k` whose `n` points are in spill file `file` (deleted when read).
    pub fn process(&mut self, k: VoxelKey, file: PathBuf, n: u64) -> Result<()> {
        if n <= self.max_in_memory {
            let pts = read_quantised(&file, n)?;
            std::fs::remove_file(&file).map_err(io_err(&file))?;
            self.process_memory(k, pts)
        } else {
            self.process_disk(k, file, n)
        }
    }

    fn process_memory(&mut self, k: VoxelKey, pts: Vec<Q>) -> Result<()> {
        if self.is_leaf(k) {
            return self.emit(k, pts);
        }
        let mut taken = vec![0u64; (NODE_GRID as usize).pow(3) / 64];
        let mut keep = Vec::new();
        let mut children: [Vec<Q>; 8] = Default::default();
        for q in pts {
            let (cell, oct) = self.octant(k, &q);
            let (w, b) = (cell / 64, 1u64 << (cell % 64));
            if taken[w] & b == 0 {
                taken[w] |= b;
                keep.push(q);
            } else {
                children[oct].push(q);
            }
        }
        drop(taken);
        self.emit(k, keep)?;
        for (oct, c) in children.into_iter().enumerate() {
            if !c.is_empty() {
                self.process_memory(k.child(oct), c)?;
            }
        }
        Ok(())
    }

    fn process_disk(&mut self, k: VoxelKey, file: PathBuf, n: u64) -> Result<()> {
        self.stats.streamed_nodes += 1;
        let mut taken = vec![0u64; (NODE_GRID as usize).pow(3) / 64];
        let mut keep = Vec::new();
        let mut child_paths = Vec::with_capacity(8);
        let mut child_files = Vec::with_capacity(8);
        let mut child_counts = [0u64; 8];
        for _ in 0..8 {
            let p = self.tmp_dir.join(format!("node{}.q", self.next_tmp));
            self.next_tmp += 1;
            child_files.push(BufWriter::new(
                std::fs::File::create(&p).map_err(io_err(&p))?,
            ));
            child_paths.push(p);
        }
        let leaf = self.is_leaf(k);
        let mut r = BufReader::new(std::fs::File::open(&file).map_err(io_err(&file))?);
        let mut buf = [0u8; 15];
        for _ in 0..n {
            r.read_exact(&mut buf).map_err(io_err(&file))?;
            let q = decode_q(&buf);
            let (cell, oct) = self.octant(k, &q);
            let (w, b) = (cell / 64, 1u64 << (cell % 64));
            if leaf || taken[w] & b == 0 {
                taken[w] |= b;
                keep.push(q);
            } else {
                child_files[oct]
                    .write_all(&buf)
                    .map_err(io_err(&child_paths[oct]))?;
                child_counts[oct] += 1;
            }
        }
        drop(r);
        std::fs::remove_file(&file).map_err(io_err(&file))?;
        drop(taken);
        for (f, p) in child_files.into_iter().zip(&child_paths) {
            f.into_inner().map_err(|e| Error::io(p, e.into_error()))?;
        }
        self.emit(k, keep)?;
        for oct in 0..8 {
            let p = child_paths[oct].clone();
            if child_counts[oct] == 0 {
                std::fs::remove_file(&p).map_err(io_err(&p))?;
            } else {
                self.process(k.child(oct), p, child_counts[oct])?;
            }
        }
        Ok(())
    }
}

pub(super) fn decode_q(b: &[u8; 15]) -> Q {
    let i = |k: usize| i32::from_le_bytes([b[4 * k], b[4 * k + 1], b[4 * k + 2], b[4 * k + 3]]);
    Q {
        xyz: [i(0), i(1), i(2)],
        rgb: [b[12], b[13], b[14]],
    }
}

pub(super) fn encode_q(q: &Q) -> [u8; 15] {
    let mut b = [0u8; 15];
    for a in 0..3 {
        b[4 * a..4 * a + 4].copy_from_slice(&q.xyz[a].to_le_bytes());
    }
    b[12..15].copy_from_slice(&q.rgb);
    b
}

pub(super) fn read_quantised(file: &Path, n: u64) -> Result<Vec<Q>> {
    let mut r = BufReader::new(std::fs::File::open(file).map_err(io_err(file))?);
    let mut out = Vec::with_capacity(n as usize);
    let mut buf = [0u8; 15];
    for _ in 0..n {
        r.read_exact(&mut buf).map_err(io_err(file))?;
        out.push(decode_q(&buf));
    }
    Ok(out)
}

/// LAS point format 7 record (36 bytes, `formats/copc.md`).
fn encode_point(q: &Q, out: &mut Vec<u8>) {
    out.clear();
    for a in 0..3 {
        out.extend_from_slice(&q.xyz[a].to_le_bytes());
    }
    out.extend_from_slice(&0u16.to_le_bytes()); // intensity
    out.push(0x11); // return 1 of 1
    out.push(0); // classification flags, scanner channel, scan direction, edge
    out.push(0); // classification: never classified
    out.push(0); // user data
    out.extend_from_slice(&0i16.to_le_bytes()); // scan angle
    out.extend_from_slice(&0u16.to_le_bytes()); // point source id
    out.extend_from_slice(&0f64.to_le_bytes()); // GPS time
    for c in q.rgb {
        out.extend_from_slice(&(c as u16 * 257).to_le_bytes());
    }
    debug_assert_eq!(out.len(), POINT_RECORD_BYTES);
}

/// A chunked LAZ compressor writing to memory, whose output is cut into one chunk per node (what
/// a chunked compressor writes between two chunk boundaries: each chunk starts from fresh models,
/// so a chunk's bytes do not depend on the chunks before it).
struct NodeCompressor {
    c: std::io::Result<LasZipCompressor<'static, std::io::Cursor<Vec<u8>>>>,
}

impl NodeCompressor {
    fn new(vlr: &LazVlr) -> Self {
        let c = LasZipCompressor::new(std::io::Cursor::new(Vec::new()), vlr.clone())
            .map_err(|e| std::io::Error::other(e.to_string()))
            .and_then(|mut c| c.reserve_offset_to_chunk_table().map(|()| c));
        NodeCompressor { c }
    }

    /// `pts` compressed as one LAZ chunk.
    fn chunk(&mut self, pts: &[Q]) -> std::io::Result<Vec<u8>> {
        let c = self
            .c
            .as_mut()
            .map_err(|e| std::io::Error::new(e.kind(), e.to_string()))?;
        let start = c.get_mut().position() as usize;
        let mut record = Vec::with_capacity(POINT_RECORD_BYTES);
        for q in pts {
            encode_point(q, &mut record);
            c.compress_one(&record)?;
        }
        c.finish_current_chunk()?;
        Ok(c.get_mut().get_ref()[start..].to_vec())
    }
}
