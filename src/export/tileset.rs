//! A stored map as a 3D Tiles 1.1 tileset: one GLB per tile, coarser levels of detail for far
//! views, `tileset.json` with bounding boxes and geometric errors. Layout: `formats/3dtiles.md`.
//!
//! # Tiles and levels
//! Level 0 tiles are the map's chunks, meshed at full resolution exactly as `export --mesh` meshes
//! them (same triangles; each tile is its own GLB, so vertices on chunk faces appear in both
//! neighbours). A level-`k` tile covers 2×2×2 level-`k−1` tiles (key = (chunk index − lowest
//! chunk index) `>> k`); its content
//! is the union of its children's meshes simplified by **vertex clustering** (Rossignac & Borrel,
//! 1993) on a grid of `2^k` voxels aligned with the tiles: every vertex in a cell becomes the
//! cell's mean position and colour, triangles whose corners fall in fewer than three cells
//! vanish, duplicates are dropped. A tile therefore holds at most ~128³ cells at every level, and
//! its geometric error is the cell diagonal `√3 · 2^k · voxel` (0 for level 0). The root is the
//! first level whose single tile covers every chunk. Cracks between neighbouring coarse tiles are
//! at most one cell wide, below the error the viewer accepts when it shows that level.
//!
//! # Memory
//! Tiles are built depth first, children before parents; a parent's cluster grid absorbs each
//! child's mesh as soon as it is written, so RAM holds one chunk's mesh plus one cluster grid per
//! level of the path (each bounded by its tile's ~128³ cells) and the tile tree (boxes and names,
//! ~100 bytes per tile), never the whole map.
//!
//! # Frames
//! Content is in the local z-up frame (metres), written to GLB as glTF's y-up (`x, z, −y`), which
//! viewers turn back to z-up. With a georeference the root tile's `transform` places the local
//! frame: ECEF for a UTM or geocentric CRS ([`WorldFrame::ecef_from_local`]), the given
//! world-from-local transform for a local one.

use super::chunks::{chunk_bounds_m, chunks_in, frame_bounds, Bbox};
use crate::error::{Error, Result};
use crate::geo::WorldFrame;
use crate::io::atomic::TempPath;
use crate::io::glb::encode_glb;
use crate::map::store::MapStore;
use crate::map::ChunkIndex;
use crate::mesh::{Field, Mesh};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;

/// What [`write_tileset`] wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct TilesetStats {
    /// Tiles with content, all levels.
    pub tiles: usize,
    /// Level-0 (full-resolution) tiles with content.
    pub leaf_tiles: usize,
    /// Levels (root level + 1).
    pub levels: u32,
    /// Vertices in level-0 tiles.
    pub leaf_vertices: u64,
    /// Triangles in level-0 tiles.
    pub leaf_triangles: u64,
    /// Triangles in the root tile.
    pub root_triangles: u64,
    /// Voxels (blocks · 512) of the chunks meshed.
    pub voxels: u64,
    /// Bytes of all GLB files.
    pub glb_bytes: u64,
}

/// One tile of the tree, kept until `tileset.json` is written.
struct TileNode {
    level: u32,
    key: [i32; 3],
    /// Bounding box in the local z-up frame, metres.
    lo: [f64; 3],
    hi: [f64; 3],
    geometric_error_m: f64,
    content: Option<String>,
    children: Vec<TileNode>,
}

/// Vertex-clustering accumulator on a grid of `cell_m` (map frame).
struct Clusters {
    cell_m: f64,
    index: HashMap<[i64; 3], u32>,
    sum: Vec<([f64; 3], [u32; 3], u32)>,
    triangles: BTreeSet<[u32; 3]>,
    ordered: Vec<[u32; 3]>,
}

impl Clusters {
    fn new(cell_m: f64) -> Self {
        Clusters {
            cell_m,
            index: HashMap::new(),
            sum: Vec::new(),
            triangles: BTreeSet::new(),
            ordered: Vec::new(),
        }
    }

    fn add(&mut self, m: &Mesh) {
        let ids: Vec<u32> = m
            .positions_m
            .iter()
            .zip(&m.colors)
            .map(|(p, c)| {
                let key = [0, 1, 2].map(|a| (p[a] as f64 / self.cell_m).floor() as i64);
                let next = self.sum.len() as u32;
                let id = *self.index.entry(key).or_insert(next);
                if id == next {
                    self.sum.push(([0.0; 3], [0; 3], 0));
                }
                let s = &mut self.sum[id as usize];
                for a in 0..3 {
                    s.0[a] += p[a] as f64;
                    s.1[a] += c[a] as u32;
                }
                s.2 += 1;
                id
            })
            .collect();
        for t in &m.triangles {
            let v = t.map(|i| ids[i as usize]);
            if v[0] == v[1] || v[1] == v[2] || v[0] == v[2] {
                continue;
            }
            let mut k = v;
            k.sort_unstable();
            if self.triangles.insert(k) {
                self.ordered.push(v);
            }
        }
    }

    /// The simplified mesh (map frame); unused clusters are dropped.
    fn finish(self) -> Mesh {
        let mut remap = vec![u32::MAX; self.sum.len()];
        let mut out = Mesh::default();
        for t in &self.ordered {
            let mut tri = [0u32; 3];
            for (j, &i) in t.iter().enumerate() {
                if remap[i as usize] == u32::MAX {
                    remap[i as usize] = out.positions_m.len() as u32;
                    let (p, c, n) = self.sum[i as usize];
                    let n = n as f64;
                    out.positions_m.push([0, 1, 2].map(|a| (p[a] / n) as f32));
                    out.colors
                        .push([0, 1, 2].map(|a| (c[a] as f64 / n).round() as u8));
                }
                tri[j] = remap[i as usize];
            }
            out.triangles.push(tri);
        }
        out
    }
}

struct Writer<'a> {
    store: &'a MapStore,
    source: super::parts::ChunkSource<'a>,
    field: Field,
    bbox: Option<Bbox>,
    frame: &'a WorldFrame,
    /// Local z-up frame (what tile content and boxes use).
    local: WorldFrame,
    dir: &'a Path,
    /// Children of each (level, key), sorted.
    children: BTreeMap<(u32, [i32; 3]), Vec<[i32; 3]>>,
    voxel_m: f64,
    /// Chunk index of tile key 0.
    origin: [i32; 3],
    /// Level-1 subtrees built at once (each meshes its up to eight chunks at once).
    concurrent: usize,
}

/// A built tile and its content mesh (map frame), if it has one, and its subtree's counts.
type Built = (Option<(TileNode, Mesh)>, TilesetStats);

impl TilesetStats {
    /// Adds the counts of a subtree built after the ones already counted.
    fn absorb(&mut self, s: &TilesetStats) {
        self.tiles += s.tiles;
        self.leaf_tiles += s.leaf_tiles;
        self.leaf_vertices += s.leaf_vertices;
        self.leaf_triangles += s.leaf_triangles;
        self.voxels += s.voxels;
        self.glb_bytes += s.glb_bytes;
        if s.tiles > 0 {
            // The last tile written so far.
            self.root_triangles = s.root_triangles;
        }
    }
}

fn shift(c: [i32; 3], k: u32) -> [i32; 3] {
    c.map(|v| v >> k)
}

impl Writer<'_> {
    /// The full-resolution mesh of the chunk of level-0 key `key`, and its own blocks.
    fn chunk_mesh(&self, key: [i32; 3]) -> Result<(Mesh, usize)> {
        let c = ChunkIndex([0, 1, 2].map(|a| key[a] + self.origin[a]));
        let (m, _, own) = self.source.mesh(self.store, c, self.field)?;
        Ok((m, own))
    }

    /// Builds tile (level, key) and its subtree; returns the tile, its content mesh (map frame)
    /// for the parent's clustering, and the subtree's counts. The chunks under a level-1 tile are
    /// meshed and written as level-0 tiles on every thread, and so are up to `self.concurrent`
    /// level-1 subtrees under a level-2 tile; each tile is then built from its children in their
    /// sorted order, so the tileset does not depend on the threads.
    fn build(&self, level: u32, key: [i32; 3]) -> Result<Built> {
        let mut stats = TilesetStats::default();
        let (mesh, mut lo, mut hi, children) = if level == 0 {
            let (m, own) = self.chunk_mesh(key)?;
            stats.voxels += own as u64 * 512;
            let m = self.crop(m);
            if m.triangles.is_empty() {
                return Ok((None, stats));
            }
            let (lo, hi) = self.local_bounds(&m);
            (m, lo, hi, Vec::new())
        } else {
            let cell_m = self.voxel_m * (1u64 << level) as f64;
            let mut clusters = Clusters::new(cell_m);
            let mut nodes = Vec::new();
            let mut lo = [f64::INFINITY; 3];
            let mut hi = [f64::NEG_INFINITY; 3];
            let kids = self
                .children
                .get(&(level, key))
                .cloned()
                .unwrap_or_default();
            let group = match level {
                1 => kids.len().max(1),
                2 => self.concurrent,
                _ => 1,
            };
            for batch in kids.chunks(group) {
                let built: Vec<Result<Built>> = if batch.len() > 1 {
                    use rayon::prelude::*;
                    batch
                        .par_iter()
                        .map(|k| self.build(level - 1, *k))
                        .collect()
                } else {
                    batch.iter().map(|k| self.build(level - 1, *k)).collect()
                };
                for b in built {
                    let (tile, s) = b?;
                    stats.absorb(&s);
                    let Some((node, m)) = tile else { continue };
                    clusters.add(&m);
                    drop(m);
                    for a in 0..3 {
                        lo[a] = lo[a].min(node.lo[a]);
                        hi[a] = hi[a].max(node.hi[a]);
                    }
                    nodes.push(node);
                }
            }
            if nodes.is_empty() {
                return Ok((None, stats));
            }
            (clusters.finish(), lo, hi, nodes)
        };
        // Never a degenerate box.
        for a in 0..3 {
            if hi[a] - lo[a] < 1e-3 {
                lo[a] -= 5e-4;
                hi[a] += 5e-4;
            }
        }
        let name = format!("tiles/{level}/{}_{}_{}.glb", key[0], key[1], key[2]);
        let content = if mesh.triangles.is_empty() {
            None
        } else {
            let glb = self.glb(&mesh)?;
            let path = self.dir.join(&name);
            std::fs::create_dir_all(path.parent().expect("tiles/level"))
                .map_err(|e| Error::io(&path, e))?;
            // Inside the folder being built: it appears whole (write_tileset).
            std::fs::write(&path, &glb).map_err(|e| Error::io(&path, e))?;
            stats.tiles += 1;
            stats.glb_bytes += glb.len() as u64;
            if level == 0 {
                stats.leaf_tiles += 1;
                stats.leaf_vertices += mesh.positions_m.len() as u64;
                stats.leaf_triangles += mesh.triangles.len() as u64;
            }
            stats.root_triangles = mesh.triangles.len() as u64;
            Some(name)
        };
        let geometric_error_m = if level == 0 {
            0.0
        } else {
            3f64.sqrt() * self.voxel_m * (1u64 << level) as f64
        };
        let node = TileNode {
            level,
            key,
            lo,
            hi,
            geometric_error_m,
            content,
            children,
        };
        Ok((Some((node, mesh)), stats))
    }

    /// Drops triangles whose centroid (output frame) is outside the box, and unused vertices.
    fn crop(&self, m: Mesh) -> Mesh {
        let Some(b) = self.bbox else { return m };
        let mut out = Mesh::default();
        let mut remap = vec![u32::MAX; m.positions_m.len()];
        for t in &m.triangles {
            let cen = [0, 1, 2].map(|a| {
                t.iter()
                    .map(|&i| {
                        let p = m.positions_m[i as usize];
                        self.frame.to_world([p[0] as f64, p[1] as f64, p[2] as f64])[a]
                    })
                    .sum::<f64>()
                    / 3.0
            });
            if !b.contains(cen) {
                continue;
            }
            let tri = t.map(|i| {
                if remap[i as usize] == u32::MAX {
                    remap[i as usize] = out.positions_m.len() as u32;
                    out.positions_m.push(m.positions_m[i as usize]);
                    out.colors.push(m.colors[i as usize]);
                }
                remap[i as usize]
            });
            out.triangles.push(tri);
        }
        out
    }

    fn local_bounds(&self, m: &Mesh) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in &m.positions_m {
            let q = self.local.to_world([p[0] as f64, p[1] as f64, p[2] as f64]);
            for a in 0..3 {
                lo[a] = lo[a].min(q[a]);
                hi[a] = hi[a].max(q[a]);
            }
        }
        (lo, hi)
    }

    fn glb(&self, m: &Mesh) -> Result<Vec<u8>> {
        // Local z-up (x, y, z) → glTF y-up (x, z, −y).
        let pos: Vec<[f32; 3]> = m
            .positions_m
            .iter()
            .map(|p| {
                let q = self.local.to_world([p[0] as f64, p[1] as f64, p[2] as f64]);
                [q[0] as f32, q[2] as f32, -q[1] as f32]
            })
            .collect();
        encode_glb(&pos, &m.colors, &m.triangles)
    }
}

fn box_json(lo: [f64; 3], hi: [f64; 3]) -> serde_json::Value {
    let c = [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]));
    let h = [0, 1, 2].map(|a| 0.5 * (hi[a] - lo[a]));
    serde_json::json!({"box": [c[0], c[1], c[2], h[0], 0.0, 0.0, 0.0, h[1], 0.0, 0.0, 0.0, h[2]]})
}

fn node_json(n: &TileNode) -> serde_json::Value {
    let mut v = serde_json::json!({
        "boundingVolume": box_json(n.lo, n.hi),
        "geometricError": n.geometric_error_m,
    });
    if let Some(uri) = &n.content {
        v["content"] = serde_json::json!({"uri": uri});
    }
    if !n.children.is_empty() {
        v["children"] = n.children.iter().map(node_json).collect();
    }
    let _ = (n.level, n.key);
    v
}

/// Writes the tileset of `field` (chunks meeting `bbox`, a box in `frame`) into folder `dir`:
/// `dir/tileset.json` and `dir/tiles/<level>/<x>_<y>_<z>.glb`. `frame` decides the root
/// transform (see the module doc); content stays in the local z-up frame.
pub fn write_tileset(
    store: &MapStore,
    field: Field,
    bbox: Option<Bbox>,
    frame: &WorldFrame,
    dir: &Path,
) -> Result<TilesetStats> {
    let budget = super::ExportOptions::new(field).memory_budget_bytes;
    let source = super::parts::ChunkSource {
        parts: None,
        mesher: &super::Mesher::Cpu,
    };
    write_tileset_with(store, field, bbox, frame, dir, source, budget)
}

/// [`write_tileset`] taking the full-resolution chunk meshes from `source` (`export --shard`
/// parts where they hold them, else meshed on its device), within `memory_budget_bytes`
/// (`--memory-budget`).
pub fn write_tileset_with(
    store: &MapStore,
    field: Field,
    bbox: Option<Bbox>,
    frame: &WorldFrame,
    dir: &Path,
    source: super::parts::ChunkSource,
    memory_budget_bytes: u64,
) -> Result<TilesetStats> {
    // The tileset is built in a hidden sibling folder and swapped in when complete, so `dir`
    // holds a whole tileset or what it held before (io::atomic). It may only replace a tileset.
    if dir.exists() {
        if !dir.is_dir() {
            return Err(Error::bad_input(dir, "exists and is not a folder"));
        }
        let empty = std::fs::read_dir(dir)
            .map_err(|e| Error::io(dir, e))?
            .next()
            .is_none();
        if !empty && !dir.join("tileset.json").is_file() {
            return Err(Error::bad_input(
                dir,
                "is not empty and holds no tileset.json: refusing to replace it with a tileset",
            ));
        }
        // Replacing the folder deletes everything in it: only a tileset this export would write
        // may be replaced (issue 36: other files of the user's in DIR were deleted).
        if let Some(foreign) = foreign_entry(dir)? {
            return Err(Error::bad_input(
                dir,
                format!(
                    "holds {}, which a tileset export does not write: refusing to replace the folder (that would delete it); export into a new folder, or move that file out",
                    foreign.display()
                ),
            ));
        }
    }
    let build = TempPath::for_target(dir);
    std::fs::create_dir_all(build.path()).map_err(|e| Error::io(dir, e))?;
    let stats = build_tileset(
        store,
        field,
        bbox,
        frame,
        build.path(),
        source,
        memory_budget_bytes,
    )?;
    if dir.exists() {
        let previous = TempPath::for_target(&dir.with_extension("previous"));
        std::fs::rename(dir, previous.path()).map_err(|e| Error::io(dir, e))?;
        build.persist(dir)?;
        drop(previous);
    } else {
        build.persist(dir)?;
    }
    Ok(stats)
}

/// The first entry of `dir` that is not part of a tileset as [`write_tileset`] writes it
/// (`tileset.json`, `tiles/<level>/<x>_<y>_<z>.glb`), if any.
fn foreign_entry(dir: &Path) -> Result<Option<std::path::PathBuf>> {
    let ls = |d: &Path| -> Result<Vec<std::fs::DirEntry>> {
        let mut v: Vec<_> = std::fs::read_dir(d)
            .map_err(|e| Error::io(d, e))?
            .flatten()
            .collect();
        v.sort_by_key(|e| e.file_name());
        Ok(v)
    };
    let tile_name = |n: &str| {
        n.strip_suffix(".glb").is_some_and(|s| {
            let parts: Vec<&str> = s.split('_').collect();
            parts.len() == 3 && parts.iter().all(|p| p.parse::<i64>().is_ok())
        })
    };
    for e in ls(dir)? {
        let n = e.file_name().to_string_lossy().into_owned();
        let p = e.path();
        match n.as_str() {
            "tileset.json" if p.is_file() => {}
            "tiles" if p.is_dir() => {
                for level in ls(&p)? {
                    let lp = level.path();
                    if !lp.is_dir() || level.file_name().to_string_lossy().parse::<u32>().is_err() {
                        return Ok(Some(lp));
                    }
                    for t in ls(&lp)? {
                        if !t.path().is_file() || !tile_name(&t.file_name().to_string_lossy()) {
                            return Ok(Some(t.path()));
                        }
                    }
                }
            }
            _ => return Ok(Some(p)),
        }
    }
    Ok(None)
}

/// [`write_tileset`] into the empty folder `dir`.
fn build_tileset(
    store: &MapStore,
    field: Field,
    bbox: Option<Bbox>,
    frame: &WorldFrame,
    dir: &Path,
    source: super::parts::ChunkSource,
    memory_budget_bytes: u64,
) -> Result<TilesetStats> {
    let chunks = chunks_in(store, frame, bbox);
    // Tile keys count from the lowest chunk index, so halving always reaches one root tile
    // (arithmetic shifts of −1 and 0 would never meet).
    let origin = [0, 1, 2].map(|a| chunks.iter().map(|c| c.0[a]).min().unwrap_or(0));
    // The tree: children per (level, key), up to the level where one key remains.
    let mut children: BTreeMap<(u32, [i32; 3]), Vec<[i32; 3]>> = BTreeMap::new();
    let mut level_keys: BTreeSet<[i32; 3]> = chunks
        .iter()
        .map(|c| [0, 1, 2].map(|a| c.0[a] - origin[a]))
        .collect();
    let mut root_level = 0u32;
    while level_keys.len() > 1 {
        root_level += 1;
        let mut up = BTreeSet::new();
        for k in &level_keys {
            let p = shift(*k, 1);
            children.entry((root_level, p)).or_default().push(*k);
            up.insert(p);
        }
        level_keys = up;
    }
    let w = Writer {
        store,
        source,
        field,
        bbox,
        frame,
        local: WorldFrame::local_z_up(),
        dir,
        children,
        voxel_m: store.grid().voxel_size_m as f64,
        origin,
        // A level-1 subtree meshes up to eight chunks at once.
        concurrent: (super::chunks_fitting(store, &chunks, memory_budget_bytes) / 8)
            .clamp(1, rayon::current_num_threads()),
    };
    let mut stats = TilesetStats {
        levels: root_level + 1,
        ..Default::default()
    };
    let root_key = level_keys.iter().next().copied();
    let root = match root_key {
        Some(k) => {
            let (tile, s) = w.build(root_level, k)?;
            stats.absorb(&s);
            tile.map(|(n, _)| n)
        }
        None => None,
    };
    if root.is_none() {
        stats.root_triangles = 0;
    }
    let mut root_json = match &root {
        Some(n) => node_json(n),
        None => {
            // An empty map: a valid tileset with an empty root around the origin.
            let (lo, hi) = match chunks.first() {
                Some(c) => frame_bounds(
                    &WorldFrame::local_z_up(),
                    chunk_bounds_m(store, *c).0,
                    chunk_bounds_m(store, *c).1,
                ),
                None => ([-0.5; 3], [0.5; 3]),
            };
            serde_json::json!({"boundingVolume": box_json(lo, hi), "geometricError": 0.0})
        }
    };
    root_json["refine"] = serde_json::json!("REPLACE");
    let transform = if frame.crs.is_some() {
        frame.ecef_from_local()
    } else if frame != &WorldFrame::local_z_up() && !frame.is_map_frame() {
        Some(frame.world_from_local())
    } else {
        None
    };
    if let Some(m) = transform {
        // Column-major, as 3D Tiles stores matrices.
        let cols: Vec<f64> = (0..4)
            .flat_map(|c| (0..4).map(move |r| m[(r, c)]))
            .collect();
        root_json["transform"] = serde_json::json!(cols);
    }
    let root_error = root.as_ref().map_or(0.0, |n| n.geometric_error_m);
    let mut extras = serde_json::json!({
        "frame": "local z-up: x = map z (forward), y = -map x (left), z = -map y (up), metres",
        "voxel_size_m": store.grid().voxel_size_m,
        "field": format!("{field:?}"),
    });
    if let Some(crs) = &frame.crs {
        extras["crs_epsg"] = serde_json::json!(crs.epsg);
    }
    let tileset = serde_json::json!({
        "asset": {"version": "1.1", "generator": format!("denser {}", env!("CARGO_PKG_VERSION")), "extras": extras},
        "geometricError": (2.0 * root_error).max(store.grid().voxel_size_m as f64),
        "root": root_json,
    });
    let path = dir.join("tileset.json");
    let text = serde_json::to_vec_pretty(&tileset)
        .map_err(|e| Error::InvalidArgument(format!("tileset.json: {e}")))?;
    std::fs::write(&path, &text).map_err(|e| Error::io(&path, e))?;
    Ok(stats)
}
