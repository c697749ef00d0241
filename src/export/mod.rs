//! Tile-by-tile export of a stored map to one mesh (PLY), one point cloud (PLY, LAS, LAZ, COPC)
//! or a 3D Tiles tileset ([`tileset`]): the exports room, above the storage engine
//! ([`crate::map`]) and the out-of-core solvers ([`crate::outofcore`]), which never import it.
//!
//! - [`export`], [`export_with`]: one stitched output of the whole map or a box;
//!   [`write_map_surface`], the [`crate::outofcore::SurfaceWriter`] a paged store is handed.
//! - `chunks`: the chunk-level pieces every exporter shares (coverage, one chunk's mesh).
//! - [`parts`]: chunk meshes made by `export --shard` array tasks, stored in the map.
//! - [`tileset`]: the map as a 3D Tiles 1.1 tileset with levels of detail.
//!
//! Chunks are meshed one at a time, each with the one-voxel layer it reads from its +x/+y/+z
//! neighbours, so memory holds at most eight chunks plus the vertices on chunk faces. Marching
//! cubes keys vertices by cube edge ([`EdgeKey`]); a vertex can be shared by cubes of two chunks
//! only when its edge lies on a chunk face, so only those keys are remembered across chunks, and
//! the stitched mesh has neither cracks nor duplicate vertices at chunk borders (tested against a
//! whole-map extraction). Vertices and faces stream to temporary files that are joined under the
//! PLY header at the end; the output appears under its name only when complete (`io::atomic`).
//!
//! # Frames
//! Coordinates leave in the output's [`WorldFrame`] (`formats/georef.md`): PLY keeps the map frame
//! (x right, y down, z forward; `f32`, byte-identical to earlier versions) unless a frame is given,
//! and is then written with `double` coordinates; LAS, LAZ, COPC and 3D Tiles always use a world
//! frame, the local z-up frame by default. `--bbox` is in the output's frame.

mod chunks;
pub mod parts;
pub mod tileset;

pub use chunks::{chunk_bounds_m, chunks_in, frame_bounds, mesh_chunk, Bbox, Mesher};

use crate::error::{Error, Result};
use crate::geo::WorldFrame;
use crate::grid::VOXELS_PER_SIDE;
use crate::io::atomic::{PendingFile, TempPath};
use crate::io::copc::{CopcOptions, CopcStats, CopcWriter};
use crate::io::las::LasPointWriter;
use crate::map::store::MapStore;
use crate::map::ChunkIndex;
use crate::mesh::{EdgeKey, Field};
use crate::outofcore::SurfaceCounts;
use std::collections::HashMap;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// What an export wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ExportStats {
    /// Chunks meshed.
    pub chunks: usize,
    /// Vertices (or points) written.
    pub vertices: u64,
    /// Triangles written (0 for point clouds).
    pub triangles: u64,
    /// Surface area of the triangles written, m² (0 for point clouds and tilesets).
    pub area_m2: f64,
    /// Voxels (blocks · 512) in the chunks meshed.
    pub voxels: u64,
    /// Vertex keys remembered on chunk faces at the end (the stitching state).
    pub face_keys: usize,
    /// Wall time, seconds.
    pub seconds: f64,
    /// COPC octree figures (COPC outputs only).
    pub copc: Option<CopcStats>,
    /// Tileset figures (3D Tiles outputs only).
    pub tileset: Option<tileset::TilesetStats>,
}

/// How to export: which field, which part, which frame, how much RAM.
#[derive(Clone, Debug)]
pub struct ExportOptions {
    /// The TSDF to mesh.
    pub field: Field,
    /// Keep only this box (output frame): triangles by centroid, points by position.
    pub bbox: Option<Bbox>,
    /// Output frame; `None`: the format's default (map frame for PLY, local z-up otherwise).
    pub frame: Option<WorldFrame>,
    /// RAM for outputs that need more than a chunk at a time (the COPC octree), bytes.
    pub memory_budget_bytes: u64,
    /// Chunk meshes made by `export --shard` runs ([`parts`]): taken from there instead
    /// of meshed again.
    pub parts: Option<std::sync::Arc<parts::ExportParts>>,
    /// Where the chunks are meshed (`export --device`).
    pub mesher: Mesher,
}

impl ExportOptions {
    /// Where its chunk meshes come from: its parts, else its mesher.
    pub fn source(&self) -> parts::ChunkSource<'_> {
        parts::ChunkSource {
            parts: self.parts.as_deref(),
            mesher: &self.mesher,
        }
    }

    /// `field`, everything, default frame, 1 GiB.
    pub fn new(field: Field) -> Self {
        ExportOptions {
            field,
            bbox: None,
            frame: None,
            memory_budget_bytes: 1 << 30,
            parts: None,
            mesher: Mesher::Cpu,
        }
    }
}

/// Output of [`export`].
#[derive(Clone, Debug, PartialEq)]
pub enum ExportTarget {
    /// A binary PLY mesh (vertices with colour, triangles).
    Mesh(PathBuf),
    /// Surface points (mesh vertices) as PLY, LAS, LAZ or COPC (`*.copc.laz`), chosen by the name.
    Points(PathBuf),
    /// A 3D Tiles 1.1 tileset in this folder ([`tileset`]).
    Tiles(PathBuf),
}

/// Whether a file name asks for COPC (`*.copc.laz`, any case).
pub fn is_copc_path(path: &Path) -> bool {
    path.file_name()
        .map(|n| {
            n.to_string_lossy()
                .to_ascii_lowercase()
                .ends_with(".copc.laz")
        })
        .unwrap_or(false)
}

/// A window of chunks: two per thread, fewer when [`chunks_fitting`] holds fewer. The meshing
/// runs at most two windows ahead of the stitching.
fn meshing_window(store: &MapStore, chunks: &[ChunkIndex], budget_bytes: u64) -> usize {
    chunks_fitting(store, chunks, budget_bytes)
        .min(2 * rayon::current_num_threads())
        .max(1)
}

/// How many meshings of the map's largest chunk (its blocks and a neighbour's decoded at once,
/// `u` included, and the mesh: 6 KiB a block) a quarter of `budget_bytes` holds; at least one.
fn chunks_fitting(store: &MapStore, chunks: &[ChunkIndex], budget_bytes: u64) -> usize {
    let largest = chunks
        .iter()
        .filter_map(|c| store.manifest().chunks.get(c))
        .map(|e| e.block_count as u64)
        .max()
        .unwrap_or(0);
    let per_chunk = (2 * largest * (crate::grid::BLOCK_RESIDENT_BYTES + 6 * 1024)).max(1);
    (budget_bytes / 4 / per_chunk).max(1) as usize
}

/// Whether a vertex on this edge can be shared with a cube of another chunk.
fn on_chunk_face(key: &EdgeKey, chunk_voxels: i64) -> bool {
    let (v, axis) = (key.0 .0, key.1 as usize);
    (0..3).any(|b| b != axis && v[b].rem_euclid(chunk_voxels) == 0)
}

enum Sink {
    Ply {
        vertices: BufWriter<std::fs::File>,
        faces: BufWriter<std::fs::File>,
        tmp_v: TempPath,
        tmp_f: TempPath,
    },
    Las(LasPointWriter),
    Copc(CopcWriter),
}

/// Exports `field` of the stored map tile by tile (all chunks, or those meeting `bbox`; with a box,
/// triangles are kept when their centroid is inside, points when inside), in the format's
/// default frame (see the module doc).
pub fn export(
    store: &MapStore,
    field: Field,
    bbox: Option<Bbox>,
    target: &ExportTarget,
) -> Result<ExportStats> {
    let mut o = ExportOptions::new(field);
    o.bbox = bbox;
    export_with(store, &o, target)
}

/// The surfaces of a stored map as a paged store writes them at the end of a run (the
/// [`crate::outofcore::SurfaceWriter`] handed to [`crate::outofcore::PagedStore`]): `field`
/// meshed into a binary PLY at `mesh_path` and, with `points_path`, its vertices as a point cloud.
pub fn write_map_surface(
    store: &MapStore,
    field: Field,
    mesh_path: &Path,
    points_path: Option<&Path>,
) -> Result<SurfaceCounts> {
    let mesh = export(
        store,
        field,
        None,
        &ExportTarget::Mesh(mesh_path.to_path_buf()),
    )?;
    if let Some(p) = points_path {
        export(store, field, None, &ExportTarget::Points(p.to_path_buf()))?;
    }
    Ok(SurfaceCounts {
        vertices: mesh.vertices,
        triangles: mesh.triangles,
        area_m2: mesh.area_m2,
    })
}

/// Exports the stored map tile by tile with `options` (see [`export`] and the module doc).
pub fn export_with(
    store: &MapStore,
    options: &ExportOptions,
    target: &ExportTarget,
) -> Result<ExportStats> {
    let t0 = std::time::Instant::now();
    // Leftovers of an export that was killed (temporary files and folders of a dead process).
    let target_path = match target {
        ExportTarget::Mesh(p) | ExportTarget::Points(p) | ExportTarget::Tiles(p) => p,
    };
    crate::io::atomic::remove_stale_partials(target_path);
    let (path, mesh) = match target {
        ExportTarget::Mesh(p) => (p.clone(), true),
        ExportTarget::Points(p) => (p.clone(), false),
        ExportTarget::Tiles(dir) => {
            let frame = options.frame.clone().unwrap_or_else(WorldFrame::local_z_up);
            let st = tileset::write_tileset_with(
                store,
                options.field,
                options.bbox,
                &frame,
                dir,
                options.source(),
                options.memory_budget_bytes,
            )?;
            return Ok(ExportStats {
                chunks: st.leaf_tiles,
                vertices: st.leaf_vertices,
                triangles: st.leaf_triangles,
                area_m2: 0.0,
                voxels: st.voxels,
                face_keys: 0,
                seconds: t0.elapsed().as_secs_f64(),
                copc: None,
                tileset: Some(st),
            });
        }
    };
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if mesh && ext != "ply" {
        return Err(Error::InvalidArgument(format!(
            "{}: meshes are written as .ply",
            path.display()
        )));
    }
    if !mesh && !matches!(ext.as_str(), "ply" | "las" | "laz") {
        return Err(Error::InvalidArgument(format!(
            "{}: points are written as .ply, .las, .laz or .copc.laz",
            path.display()
        )));
    }
    let frame = match &options.frame {
        Some(f) => f.clone(),
        None if ext == "ply" => WorldFrame::map(),
        None => WorldFrame::local_z_up(),
    };
    // PLY in the map frame keeps its f32 layout; any other frame is written as double.
    let ply_f64 = !frame.is_map_frame();
    let bbox = options.bbox;
    let field = options.field;
    let chunks = chunks_in(store, &frame, bbox);
    let mut sink = if ext == "ply" {
        // Vertices and faces stream to temporaries joined under the header at the end.
        let tmp_v = TempPath::for_target(&path.with_extension("vertices"));
        let tmp_f = TempPath::for_target(&path.with_extension("faces"));
        let open = |p: &Path| -> Result<BufWriter<std::fs::File>> {
            Ok(BufWriter::new(
                std::fs::File::create(p).map_err(|e| Error::io(p, e))?,
            ))
        };
        Sink::Ply {
            vertices: open(tmp_v.path())?,
            faces: open(tmp_f.path())?,
            tmp_v,
            tmp_f,
        }
    } else if is_copc_path(&path) {
        Sink::Copc(CopcWriter::create(
            &path,
            CopcOptions {
                crs_wkt: frame.crs.as_ref().map(|c| c.wkt.clone()),
                memory_budget_bytes: options.memory_budget_bytes,
            },
        )?)
    } else {
        // Offset at the centre of the map's chunks: every point is within ±2 147 km of it.
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for c in &chunks {
            let (l, h) = chunk_bounds_m(store, *c);
            let (l, h) = frame_bounds(&frame, l, h);
            for a in 0..3 {
                lo[a] = lo[a].min(l[a]);
                hi[a] = hi[a].max(h[a]);
            }
        }
        let offset = if chunks.is_empty() {
            frame.to_world([0.0; 3]).map(f64::round)
        } else {
            [0, 1, 2].map(|a| (0.5 * (lo[a] + hi[a])).round())
        };
        let wkt = frame.crs.as_ref().map(|c| c.wkt.as_str());
        Sink::Las(LasPointWriter::create(&path, offset, true, wkt)?)
    };
    let cb = store.chunk_blocks();
    let chunk_voxels = cb as i64 * VOXELS_PER_SIDE as i64;
    let mut face_ids: HashMap<EdgeKey, u32> = HashMap::new();
    let mut stats = ExportStats::default();
    let mut next_id: u64 = 0;
    let bar = crate::progress::bar(chunks.len() as u64, "exporting");
    // Chunks are meshed on every thread, at most two windows ahead of the stitching, which takes
    // them one by one in their sorted order: the output is byte for byte the single-threaded one.
    let window = meshing_window(store, &chunks, options.memory_budget_bytes / 2);
    let source = options.source();
    let mesh_chunk = |k: usize| source.mesh(store, chunks[k], field);
    chunks::in_order(chunks.len(), 2 * window, mesh_chunk, |meshed| {
        let (m, keys, own) = meshed?;
        stats.voxels += own as u64 * 512;
        let world: Vec<[f64; 3]> = m
            .positions_m
            .iter()
            .map(|p| frame.to_world([p[0] as f64, p[1] as f64, p[2] as f64]))
            .collect();
        // Keep triangles (and the vertices they use) inside the box.
        let keep_tri: Vec<bool> = m
            .triangles
            .iter()
            .map(|t| {
                bbox.is_none_or(|b| {
                    let cen = [0, 1, 2]
                        .map(|a| t.iter().map(|&i| world[i as usize][a]).sum::<f64>() / 3.0);
                    b.contains(cen)
                })
            })
            .collect();
        let mut used = vec![!mesh; m.positions_m.len()];
        if mesh {
            for (t, k) in m.triangles.iter().zip(&keep_tri) {
                if *k {
                    for &i in t {
                        used[i as usize] = true;
                    }
                }
            }
        }
        let mut ids = vec![u32::MAX; m.positions_m.len()];
        for (i, key) in keys.iter().enumerate() {
            if !used[i] {
                continue;
            }
            let pw = world[i];
            if !mesh && bbox.is_some_and(|b| !b.contains(pw)) {
                continue;
            }
            let shared = on_chunk_face(key, chunk_voxels);
            if shared {
                if let Some(&id) = face_ids.get(key) {
                    ids[i] = id;
                    continue;
                }
            }
            if next_id >= i32::MAX as u64 {
                return Err(Error::InvalidArgument(format!(
                    "{}: more than 2^31 vertices; export a --bbox at a time",
                    path.display()
                )));
            }
            let id = next_id as u32;
            next_id += 1;
            ids[i] = id;
            if shared {
                face_ids.insert(*key, id);
            }
            let color = m.colors[i];
            match &mut sink {
                Sink::Ply {
                    vertices, tmp_v, ..
                } => {
                    let written = if ply_f64 {
                        let mut rec = [0u8; 27];
                        for a in 0..3 {
                            rec[8 * a..8 * a + 8].copy_from_slice(&pw[a].to_le_bytes());
                        }
                        rec[24..27].copy_from_slice(&color);
                        vertices.write_all(&rec)
                    } else {
                        let p = m.positions_m[i];
                        let mut rec = [0u8; 15];
                        for a in 0..3 {
                            rec[4 * a..4 * a + 4].copy_from_slice(&p[a].to_le_bytes());
                        }
                        rec[12..15].copy_from_slice(&color);
                        vertices.write_all(&rec)
                    };
                    written.map_err(|e| Error::io(tmp_v.path(), e))?;
                }
                Sink::Las(w) => w.write(pw, Some(color))?,
                Sink::Copc(w) => w.write(pw, color)?,
            }
        }
        if mesh {
            if let Sink::Ply { faces, tmp_f, .. } = &mut sink {
                for (t, k) in m.triangles.iter().zip(&keep_tri) {
                    if !*k {
                        continue;
                    }
                    let mut rec = [3u8; 13];
                    for j in 0..3 {
                        rec[1 + 4 * j..5 + 4 * j]
                            .copy_from_slice(&(ids[t[j] as usize] as i32).to_le_bytes());
                    }
                    faces
                        .write_all(&rec)
                        .map_err(|e| Error::io(tmp_f.path(), e))?;
                    stats.triangles += 1;
                    stats.area_m2 +=
                        crate::mesh::triangle_area_m2(t.map(|i| m.positions_m[i as usize]));
                }
            }
        }
        stats.chunks += 1;
        bar.inc(1);
        Ok(())
    })?;
    bar.finish_and_clear();
    stats.vertices = next_id;
    stats.face_keys = face_ids.len();
    match sink {
        Sink::Las(w) => w.close()?,
        Sink::Copc(w) => {
            // The COPC writer renames its own partial file.
            stats.copc = Some(w.finish()?);
            stats.seconds = t0.elapsed().as_secs_f64();
            return Ok(stats);
        }
        Sink::Ply {
            vertices,
            faces,
            tmp_v,
            tmp_f,
        } => {
            let flush = |w: BufWriter<std::fs::File>, p: &Path| -> Result<()> {
                w.into_inner()
                    .map_err(|e| Error::io(p, e.into_error()))?
                    .sync_all()
                    .map_err(|e| Error::io(p, e))
            };
            flush(vertices, tmp_v.path())?;
            flush(faces, tmp_f.path())?;
            let mut out = PendingFile::create(&path)?;
            let coord = if ply_f64 { "double" } else { "float" };
            let mut header = format!(
                "ply\nformat binary_little_endian 1.0\ncomment written by denser export\nelement vertex {}\nproperty {coord} x\nproperty {coord} y\nproperty {coord} z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n",
                stats.vertices
            );
            if ply_f64 {
                header = header.replace(
                    "comment written by denser export\n",
                    "comment written by denser export\ncomment frame: world (see formats/georef.md)\n",
                );
            }
            if mesh {
                header.push_str(&format!(
                    "element face {}\nproperty list uchar int vertex_indices\n",
                    stats.triangles
                ));
            }
            header.push_str("end_header\n");
            out.write_all(header.as_bytes())
                .map_err(|e| Error::io(&path, e))?;
            for p in [&tmp_v, &tmp_f] {
                if std::ptr::eq(p, &tmp_f) && !mesh {
                    continue;
                }
                let mut f = std::fs::File::open(p.path()).map_err(|e| Error::io(p.path(), e))?;
                std::io::copy(&mut f, &mut out).map_err(|e| Error::io(&path, e))?;
            }
            out.commit()?;
        }
    }
    stats.seconds = t0.elapsed().as_secs_f64();
    Ok(stats)
}
