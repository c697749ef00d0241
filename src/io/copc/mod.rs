//! Cloud-Optimized Point Cloud (COPC 1.0) writer: a LAZ 1.4 file whose points are clustered in an
//! octree, one LAZ chunk per octree node, with the node directory in a hierarchy EVLR, so viewers
//! and `laspy.CopcReader` read a region or a coarse level without decompressing the rest.
//! Byte layout: `formats/copc.md`.
//!
//! # Algorithm and memory bound
//! Points arrive one at a time ([`CopcWriter::write`]) and go straight to a spill file on disk
//! (27 bytes each: `f64` x, y, z, `u8` r, g, b), while the bounds grow. [`CopcWriter::finish`]
//! then quantises them (1 mm) and builds the octree top-down with one rule, the same at every
//! node: the node keeps the **first** point (in arrival order) of each of its 128³ grid cells;
//! every other point passes to the child octant that contains it. A node whose cell is below
//! 2 mm keeps all its points (the octree's leaves). Because the rule only depends on the order in
//! which points reach a node, the octree is the same whether a node's points are held in RAM or
//! streamed from a spill file:
//! * a node with more points than fit the budget (`memory_budget_bytes / 64` points) is processed
//!   by streaming its spill file once: the cell bitmap (128³ bits = 256 KiB) decides, kept points
//!   are collected (at most one per cell), the others are appended to eight child spill files
//!   (arrival order kept), and the parent file is deleted;
//! * a node that fits is loaded and its whole subtree built in memory, depth first.
//!
//! Each final node's points become one LAZ chunk. Final nodes wait in a batch of at most an eighth
//! of the budget's points, which is compressed on every thread (each chunk starts from fresh
//! models, so its bytes do not depend on the others) and written in the order the nodes were
//! made: the file is the same on any number of threads. So RAM holds at most the budget's points,
//! the batch, one node's kept points and a bitmap per level of recursion; disk holds at most twice
//! the cloud (one level of spill files plus their children). The hierarchy (32 bytes per node) is
//! kept in memory and written at the end, then the header is filled in.
//!
//! What it does not do: point attributes beyond position and colour (intensity 0, return 1 of 1,
//! classification 0, GPS time 0), several hierarchy pages (one page holds every node), or
//! appending to an existing file.

use crate::error::{Error, Result};
use crate::io::atomic::TempPath;
use crate::io::las::{generating_software, SYSTEM_IDENTIFIER, WRITE_SCALE_M};
use laz::laszip::{ChunkTable, ChunkTableEntry};
use laz::{LazVlr, LazVlrBuilder};
use octree::{encode_q, Builder, Q};
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

mod octree;

/// Cells per axis of a node's sampling grid (COPC's customary 128).
pub const NODE_GRID: u32 = 128;
/// Bytes of one point record in LAS point format 7.
pub const POINT_RECORD_BYTES: usize = 36;
/// LAS 1.4 header size.
const HEADER_BYTES: u64 = 375;
/// VLR header size.
const VLR_HEADER_BYTES: u64 = 54;
/// EVLR header size.
const EVLR_HEADER_BYTES: u64 = 60;
/// Bytes of a spilled point: `f64` x, y, z and `u8` r, g, b.
const SPILL_BYTES: usize = 27;
/// Bytes of RAM counted per point held in memory (record, child copies, compression buffer).
const RAM_BYTES_PER_POINT: u64 = 64;

/// Options of a COPC file.
#[derive(Clone, Debug)]
pub struct CopcOptions {
    /// OGC WKT of the coordinates' CRS (written as a WKT VLR), if known.
    pub crs_wkt: Option<String>,
    /// RAM for points while building the octree, bytes (at least 64 KiB is used).
    pub memory_budget_bytes: u64,
}

/// What [`CopcWriter::finish`] wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct CopcStats {
    /// Points written.
    pub points: u64,
    /// Octree nodes (LAZ chunks).
    pub nodes: u64,
    /// Deepest level (root = 0).
    pub max_level: u32,
    /// Points of the root node.
    pub root_points: u64,
    /// Nodes processed by streaming a spill file (0 when everything fitted in RAM).
    pub streamed_nodes: u64,
    /// File size, bytes.
    pub bytes: u64,
}

/// An octree node key (level, x, y, z), as in the COPC hierarchy.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct VoxelKey {
    /// Depth, root = 0.
    pub level: i32,
    /// Node coordinates at that depth, 0..2^level.
    pub xyz: [i32; 3],
}

impl VoxelKey {
    fn child(&self, octant: usize) -> VoxelKey {
        VoxelKey {
            level: self.level + 1,
            xyz: [0, 1, 2].map(|a| 2 * self.xyz[a] + ((octant >> a) & 1) as i32),
        }
    }
}

/// The cube of the octree in LAS integer units (exact integer arithmetic for node membership).
#[derive(Clone, Copy, Debug)]
struct Cube {
    /// Lower corner, integer units.
    lo: [i64; 3],
    /// Edge, integer units (a power of two times 128 so every node grid is integral).
    edge: i64,
}

impl Cube {
    fn node_lo_edge(&self, k: VoxelKey) -> ([i64; 3], i64) {
        let edge = self.edge >> k.level;
        ([0, 1, 2].map(|a| self.lo[a] + k.xyz[a] as i64 * edge), edge)
    }
}

/// Writes a COPC file from points given one at a time (see the module doc).
pub struct CopcWriter {
    path: PathBuf,
    tmp_dir: TempPath,
    spill: BufWriter<std::fs::File>,
    spill_path: PathBuf,
    count: u64,
    lo: [f64; 3],
    hi: [f64; 3],
    options: CopcOptions,
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> Error + '_ {
    move |e| Error::io(path, e)
}

impl CopcWriter {
    /// Starts a COPC file at `path` (written as `path` only when [`finish`](Self::finish)
    /// succeeds); spill files go to a hidden sibling folder, removed when the writer finishes
    /// or is dropped (`io::atomic`).
    pub fn create(path: &Path, options: CopcOptions) -> Result<Self> {
        let tmp_dir = TempPath::for_target(&path.with_extension("spill"));
        std::fs::create_dir_all(tmp_dir.path()).map_err(io_err(tmp_dir.path()))?;
        let spill_path = tmp_dir.path().join("input.pts");
        let spill =
            BufWriter::new(std::fs::File::create(&spill_path).map_err(io_err(&spill_path))?);
        Ok(CopcWriter {
            path: path.to_path_buf(),
            tmp_dir,
            spill,
            spill_path,
            count: 0,
            lo: [f64::INFINITY; 3],
            hi: [f64::NEG_INFINITY; 3],
            options,
        })
    }

    /// Appends a point (metres, in the file's CRS) with its sRGB colour.
    pub fn write(&mut self, p: [f64; 3], rgb: [u8; 3]) -> Result<()> {
        if p.iter().any(|v| !v.is_finite()) {
            return Err(Error::InvalidArgument(format!(
                "{}: non-finite coordinate {p:?}",
                self.path.display()
            )));
        }
        let mut rec = [0u8; SPILL_BYTES];
        for a in 0..3 {
            rec[8 * a..8 * a + 8].copy_from_slice(&p[a].to_le_bytes());
            self.lo[a] = self.lo[a].min(p[a]);
            self.hi[a] = self.hi[a].max(p[a]);
        }
        rec[24..27].copy_from_slice(&rgb);
        self.spill
            .write_all(&rec)
            .map_err(io_err(&self.spill_path))?;
        self.count += 1;
        Ok(())
    }

    /// Builds the octree, writes the file and removes the spill folder.
    pub fn finish(self) -> Result<CopcStats> {
        let CopcWriter {
            path,
            tmp_dir,
            spill,
            spill_path,
            count,
            lo,
            hi,
            options,
        } = self;
        spill
            .into_inner()
            .map_err(|e| Error::io(&spill_path, e.into_error()))?;
        let partial = TempPath::for_target(&path);
        let stats = write_file(
            partial.path(),
            tmp_dir.path(),
            &spill_path,
            count,
            lo,
            hi,
            &options,
        )?;
        drop(tmp_dir);
        partial.persist(&path)?;
        Ok(stats)
    }
}

fn vlr_header(user_id: &str, record_id: u16, len: u64, description: &str) -> Vec<u8> {
    let mut h = Vec::with_capacity(VLR_HEADER_BYTES as usize);
    h.extend_from_slice(&0u16.to_le_bytes());
    h.extend_from_slice(&fixed::<16>(user_id));
    h.extend_from_slice(&record_id.to_le_bytes());
    h.extend_from_slice(&(len as u16).to_le_bytes());
    h.extend_from_slice(&fixed::<32>(description));
    h
}

fn fixed<const N: usize>(s: &str) -> [u8; N] {
    let mut b = [0u8; N];
    let n = s.len().min(N);
    b[..n].copy_from_slice(&s.as_bytes()[..n]);
    b
}

/// The COPC info VLR payload (160 bytes).
fn copc_info(center: [f64; 3], halfsize: f64, spacing: f64, hier: (u64, u64)) -> Vec<u8> {
    let mut b = Vec::with_capacity(160);
    for v in [center[0], center[1], center[2], halfsize, spacing] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.extend_from_slice(&hier.0.to_le_bytes());
    b.extend_from_slice(&hier.1.to_le_bytes());
    b.extend_from_slice(&0f64.to_le_bytes()); // GPS time min
    b.extend_from_slice(&0f64.to_le_bytes()); // GPS time max
    b.extend_from_slice(&[0u8; 88]);
    b
}

#[allow(clippy::too_many_arguments)]
fn las_header(
    offset_to_points: u32,
    n_vlrs: u32,
    scale: f64,
    offset: [f64; 3],
    lo: [f64; 3],
    hi: [f64; 3],
    evlr_start: u64,
    points: u64,
) -> Vec<u8> {
    let mut h = Vec::with_capacity(HEADER_BYTES as usize);
    h.extend_from_slice(b"LASF");
    h.extend_from_slice(&0u16.to_le_bytes()); // file source id
                                              // Global encoding: bit 4, CRS (if any) as WKT, which LAS 1.4 requires for point format 7.
    h.extend_from_slice(&16u16.to_le_bytes());
    h.extend_from_slice(&[0u8; 16]); // GUID
    h.extend_from_slice(&[1, 4]);
    h.extend_from_slice(&fixed::<32>(SYSTEM_IDENTIFIER));
    h.extend_from_slice(&fixed::<32>(&generating_software()));
    let today = chrono::Utc::now().date_naive();
    use chrono::Datelike;
    h.extend_from_slice(&(today.ordinal() as u16).to_le_bytes());
    h.extend_from_slice(&(today.year() as u16).to_le_bytes());
    h.extend_from_slice(&(HEADER_BYTES as u16).to_le_bytes());
    h.extend_from_slice(&offset_to_points.to_le_bytes());
    h.extend_from_slice(&n_vlrs.to_le_bytes());
    h.push(7 | 0x80); // point format 7, LAZ-compressed
    h.extend_from_slice(&(POINT_RECORD_BYTES as u16).to_le_bytes());
    h.extend_from_slice(&0u32.to_le_bytes()); // legacy point count: 0 for formats ≥ 6
    h.extend_from_slice(&[0u8; 20]); // legacy points by return
    for _ in 0..3 {
        h.extend_from_slice(&scale.to_le_bytes());
    }
    for v in offset {
        h.extend_from_slice(&v.to_le_bytes());
    }
    for a in 0..3 {
        h.extend_from_slice(&hi[a].to_le_bytes());
        h.extend_from_slice(&lo[a].to_le_bytes());
    }
    h.extend_from_slice(&0u64.to_le_bytes()); // waveform data
    h.extend_from_slice(&evlr_start.to_le_bytes());
    h.extend_from_slice(&1u32.to_le_bytes()); // one EVLR: the hierarchy
    h.extend_from_slice(&points.to_le_bytes());
    h.extend_from_slice(&points.to_le_bytes()); // all points are return 1
    h.extend_from_slice(&[0u8; 14 * 8]);
    debug_assert_eq!(h.len() as u64, HEADER_BYTES);
    h
}

fn write_file(
    out: &Path,
    tmp_dir: &Path,
    spill_path: &Path,
    count: u64,
    lo: [f64; 3],
    hi: [f64; 3],
    options: &CopcOptions,
) -> Result<CopcStats> {
    let scale = WRITE_SCALE_M;
    let (lo, hi) = if count == 0 {
        ([0.0; 3], [0.0; 3])
    } else {
        (lo, hi)
    };
    let offset = [0, 1, 2].map(|a| (0.5 * (lo[a] + hi[a])).round());
    for a in 0..3 {
        let reach = (hi[a] - offset[a]).max(offset[a] - lo[a]) / scale;
        if reach >= (i32::MAX / 2) as f64 {
            return Err(Error::InvalidArgument(format!(
                "{}: extent {:.0} m along axis {a} does not fit LAS 32-bit integers at {scale} m",
                out.display(),
                hi[a] - lo[a]
            )));
        }
    }
    let quant = |v: f64, a: usize| ((v - offset[a]) / scale).round() as i32;
    // The octree cube in integer units: lower corner at the quantised minimum, edge the smallest
    // power of two times the grid that covers the largest extent.
    let qlo = [0, 1, 2].map(|a| quant(lo[a], a) as i64);
    let qhi = [0, 1, 2].map(|a| quant(hi[a], a) as i64);
    let extent = (0..3).map(|a| qhi[a] - qlo[a] + 1).max().unwrap_or(1);
    let mut edge = NODE_GRID as i64;
    while edge < extent {
        edge *= 2;
    }
    let cube = Cube { lo: qlo, edge };
    let halfsize = edge as f64 * scale / 2.0;
    let center = [0, 1, 2].map(|a| offset[a] + qlo[a] as f64 * scale + halfsize);
    let spacing = 2.0 * halfsize / NODE_GRID as f64;

    // Quantise the spill into the root's file.
    let root_file = tmp_dir.join("root.q");
    {
        let mut r = BufReader::new(std::fs::File::open(spill_path).map_err(io_err(spill_path))?);
        let mut w = BufWriter::new(std::fs::File::create(&root_file).map_err(io_err(&root_file))?);
        let mut buf = [0u8; SPILL_BYTES];
        for _ in 0..count {
            r.read_exact(&mut buf).map_err(io_err(spill_path))?;
            let f = |k: usize| f64::from_le_bytes(buf[8 * k..8 * k + 8].try_into().expect("8"));
            let q = Q {
                xyz: [quant(f(0), 0), quant(f(1), 1), quant(f(2), 2)],
                rgb: [buf[24], buf[25], buf[26]],
            };
            w.write_all(&encode_q(&q)).map_err(io_err(&root_file))?;
        }
        w.into_inner()
            .map_err(|e| Error::io(&root_file, e.into_error()))?;
    }
    std::fs::remove_file(spill_path).map_err(io_err(spill_path))?;

    // Header and VLRs: placeholders now, final values at the end.
    let laz_vlr: LazVlr = LazVlrBuilder::default()
        .with_point_format(7, 0)
        .map_err(|e| Error::bad_input(out, format!("LAZ: {e}")))?
        .with_variable_chunk_size()
        .build();
    let mut laz_bytes = Vec::new();
    laz_vlr.write_to(&mut laz_bytes).map_err(io_err(out))?;
    let wkt = options.crs_wkt.as_ref().map(|w| {
        let mut b = w.as_bytes().to_vec();
        b.push(0);
        b
    });
    let mut vlrs = Vec::new();
    let info_at = HEADER_BYTES + VLR_HEADER_BYTES;
    vlrs.extend(vlr_header("copc", 1, 160, "COPC info"));
    vlrs.extend(copc_info(center, halfsize, spacing, (0, 0)));
    vlrs.extend(vlr_header(
        "laszip encoded",
        22204,
        laz_bytes.len() as u64,
        "laz variable chunks",
    ));
    vlrs.extend(&laz_bytes);
    let mut n_vlrs = 2;
    if let Some(w) = &wkt {
        if w.len() > u16::MAX as usize {
            return Err(Error::InvalidArgument(format!(
                "{}: the CRS WKT is longer than a VLR holds",
                out.display()
            )));
        }
        vlrs.extend(vlr_header(
            "LASF_Projection",
            2112,
            w.len() as u64,
            "OGC WKT",
        ));
        vlrs.extend(w);
        n_vlrs += 1;
    }
    let offset_to_points = HEADER_BYTES + vlrs.len() as u64;
    let mut file = BufWriter::new(std::fs::File::create(out).map_err(io_err(out))?);
    file.write_all(&[0u8; HEADER_BYTES as usize])
        .and_then(|_| file.write_all(&vlrs))
        .map_err(io_err(out))?;
    // The offset to the LAZ chunk table, filled in when the table is written.
    file.write_all(&(-1i64).to_le_bytes())
        .map_err(io_err(out))?;
    let budget_points = (options.memory_budget_bytes.max(64 << 10) / RAM_BYTES_PER_POINT).max(1024);
    let mut b = Builder {
        cube,
        out: file,
        pos: offset_to_points + 8,
        path: out.to_path_buf(),
        tmp_dir: tmp_dir.to_path_buf(),
        max_in_memory: budget_points,
        entries: Vec::new(),
        stats: CopcStats {
            points: count,
            ..Default::default()
        },
        next_tmp: 0,
        vlr: laz_vlr,
        table: ChunkTable::default(),
        pending: Vec::new(),
        pending_points: 0,
        // Nodes wait for compression in batches of an eighth of the points the budget holds.
        flush_points: (budget_points / 8).max(1024),
    };
    if count > 0 {
        b.process(
            VoxelKey {
                level: 0,
                xyz: [0; 3],
            },
            root_file,
            count,
        )?;
    } else {
        std::fs::remove_file(&root_file).map_err(io_err(&root_file))?;
    }
    b.flush()?;
    let Builder {
        out: mut file,
        pos,
        vlr,
        mut table,
        mut entries,
        mut stats,
        ..
    } = b;
    // The chunk table, as a chunked LAZ compressor ends: its last (empty) chunk included.
    table.push(ChunkTableEntry::default());
    table.write_to(&mut file, &vlr).map_err(io_err(out))?;
    file.seek(SeekFrom::Start(offset_to_points))
        .and_then(|_| file.write_all(&(pos as i64).to_le_bytes()))
        .and_then(|_| file.seek(SeekFrom::End(0)))
        .map_err(io_err(out))?;
    // The hierarchy EVLR: one page with every node, sorted by key.
    entries.sort_unstable_by_key(|e| e.0);
    let evlr_start = file.stream_position().map_err(io_err(out))?;
    let page_len = 32 * entries.len() as u64;
    let mut evlr = Vec::with_capacity(EVLR_HEADER_BYTES as usize + page_len as usize);
    evlr.extend_from_slice(&0u16.to_le_bytes());
    evlr.extend_from_slice(&fixed::<16>("copc"));
    evlr.extend_from_slice(&1000u16.to_le_bytes());
    evlr.extend_from_slice(&page_len.to_le_bytes());
    evlr.extend_from_slice(&fixed::<32>("EPT hierarchy"));
    for (k, off, size, n) in &entries {
        for v in [k.level, k.xyz[0], k.xyz[1], k.xyz[2]] {
            evlr.extend_from_slice(&v.to_le_bytes());
        }
        evlr.extend_from_slice(&off.to_le_bytes());
        evlr.extend_from_slice(&size.to_le_bytes());
        evlr.extend_from_slice(&n.to_le_bytes());
    }
    file.write_all(&evlr).map_err(io_err(out))?;
    // Bounds of the quantised points as stored.
    let dq = |v: f64, a: usize| quant(v, a) as f64 * scale + offset[a];
    let blo = [0, 1, 2].map(|a| dq(lo[a], a));
    let bhi = [0, 1, 2].map(|a| dq(hi[a], a));
    let header = las_header(
        offset_to_points as u32,
        n_vlrs,
        scale,
        offset,
        blo,
        bhi,
        evlr_start,
        count,
    );
    file.seek(SeekFrom::Start(0))
        .and_then(|_| file.write_all(&header))
        .and_then(|_| file.seek(SeekFrom::Start(info_at)))
        .and_then(|_| {
            file.write_all(&copc_info(
                center,
                halfsize,
                spacing,
                (evlr_start + EVLR_HEADER_BYTES, page_len),
            ))
        })
        .map_err(io_err(out))?;
    let file = file
        .into_inner()
        .map_err(|e| Error::io(out, e.into_error()))?;
    file.sync_all().map_err(io_err(out))?;
    stats.bytes = file.metadata().map_err(io_err(out))?.len();
    Ok(stats)
}
