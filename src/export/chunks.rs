//! The chunk-level pieces every exporter shares: which chunks an export covers ([`chunks_in`],
//! boxes in a world frame), and one chunk meshed with the neighbour layer its cubes read
//! ([`mesh_chunk`]). A leaf of the exports room: the stitched outputs ([`super::export`]), the
//! shards' parts ([`super::parts`]) and the tilesets ([`super::tileset`]) build on it.

use crate::error::{Error, Result};
use crate::geo::WorldFrame;
use crate::gpu::GpuContext;
use crate::grid::{BlockIndex, Layer};
use crate::map::store::MapStore;
use crate::map::ChunkIndex;
use crate::mesh::{extract_mesh_keyed, EdgeKey, Field, GpuMesher, Mesh, SampleSource};
use std::collections::BTreeMap;
use std::sync::Arc;

/// Where chunks are meshed: on the CPU, or on a GPU by the CPU mesher's twin
/// ([`crate::mesh::extract_mesh_gpu`]: the same triangles over the same vertices, positions
/// within [`crate::mesh::POSITION_TOLERANCE_VOXELS`], equal on lavapipe).
#[derive(Clone, Debug, Default)]
pub enum Mesher {
    /// The CPU mesher.
    #[default]
    Cpu,
    /// Marching cubes on a GPU, its buffers kept from chunk to chunk.
    Gpu(GpuMesher),
}

impl Mesher {
    /// Marching cubes on `ctx`.
    pub fn gpu(ctx: Arc<GpuContext>) -> Self {
        Mesher::Gpu(GpuMesher::new(ctx))
    }

    /// The device in words ("CPU" or the adapter).
    pub fn device_name(&self) -> String {
        match self {
            Mesher::Cpu => "CPU".to_string(),
            Mesher::Gpu(mesher) => mesher.context().name(),
        }
    }
}

/// An axis-aligned box in world coordinates, metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bbox {
    /// Lower corner.
    pub min_m: [f64; 3],
    /// Upper corner.
    pub max_m: [f64; 3],
}

impl Bbox {
    /// Parses `xmin,ymin,zmin,xmax,ymax,zmax`.
    pub fn parse(s: &str) -> Result<Self> {
        let v: Vec<f64> = s
            .split(',')
            .map(|t| t.trim().parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|e| Error::InvalidArgument(format!("--bbox {s:?}: {e}")))?;
        if v.len() != 6 || (0..3).any(|a| !(v[a] <= v[a + 3])) {
            return Err(Error::InvalidArgument(format!(
                "--bbox {s:?}: expected xmin,ymin,zmin,xmax,ymax,zmax with min ≤ max"
            )));
        }
        Ok(Bbox {
            min_m: [v[0], v[1], v[2]],
            max_m: [v[3], v[4], v[5]],
        })
    }

    /// Whether `p` lies inside (bounds included).
    pub fn contains(&self, p: [f64; 3]) -> bool {
        (0..3).all(|a| p[a] >= self.min_m[a] && p[a] <= self.max_m[a])
    }

    /// Whether the box meets `[lo, hi]`.
    pub fn meets(&self, lo: [f64; 3], hi: [f64; 3]) -> bool {
        (0..3).all(|a| hi[a] >= self.min_m[a] && lo[a] <= self.max_m[a])
    }
}

/// Map-frame bounds of chunk `c`, metres.
pub fn chunk_bounds_m(store: &MapStore, c: ChunkIndex) -> ([f64; 3], [f64; 3]) {
    let chunk_m = store.grid().block_size_m() * store.chunk_blocks() as f64;
    let lo = [0, 1, 2].map(|a| c.0[a] as f64 * chunk_m);
    let hi = [0, 1, 2].map(|a| (c.0[a] + 1) as f64 * chunk_m);
    (lo, hi)
}

/// The axis-aligned box (in `frame`) of a map-frame box's eight corners.
pub fn frame_bounds(frame: &WorldFrame, lo: [f64; 3], hi: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let mut a = [f64::INFINITY; 3];
    let mut b = [f64::NEG_INFINITY; 3];
    for k in 0..8 {
        let p = [0, 1, 2].map(|d| if (k >> d) & 1 == 0 { lo[d] } else { hi[d] });
        let w = frame.to_world(p);
        for d in 0..3 {
            a[d] = a[d].min(w[d]);
            b[d] = b[d].max(w[d]);
        }
    }
    (a, b)
}

/// The chunks of `store` whose box (in `frame`) meets `bbox` (all without a box), sorted.
pub fn chunks_in(store: &MapStore, frame: &WorldFrame, bbox: Option<Bbox>) -> Vec<ChunkIndex> {
    store
        .chunk_indices()
        .into_iter()
        .filter(|c| {
            let (lo, hi) = chunk_bounds_m(store, *c);
            let (lo, hi) = frame_bounds(frame, lo, hi);
            bbox.is_none_or(|b| b.meets(lo, hi))
        })
        .collect()
}

/// Meshes chunk `c` of the map (reading the neighbour blocks its cubes need) with `mesher`: the
/// mesh in the map frame, each vertex's edge key, and the number of the chunk's own blocks.
pub fn mesh_chunk(
    store: &MapStore,
    c: ChunkIndex,
    field: Field,
    mesher: &Mesher,
) -> Result<(Mesh, Vec<EdgeKey>, usize)> {
    let cb = store.chunk_blocks();
    let mut layer = Layer::new(store.grid());
    let mut own: Vec<BlockIndex> = Vec::new();
    let hi_block = c.origin_block(cb).map(|o| o + cb as i32);
    for d in 0..8i32 {
        let off = [d & 1, (d >> 1) & 1, (d >> 2) & 1];
        let Some(dec) = store.read_chunk(c.offset(off))? else {
            continue;
        };
        for (b, block) in dec.blocks {
            if d == 0 {
                own.push(b);
                layer.insert(b, block);
            } else if (0..3).all(|a| off[a] == 0 || b.0[a] == hi_block[a]) {
                // Only the neighbour blocks touching this chunk's +faces are read by its cubes.
                layer.insert(b, block);
            }
        }
    }
    let (m, keys) = match mesher {
        Mesher::Cpu => extract_mesh_keyed(&layer, field, Some(&own)),
        Mesher::Gpu(mesher) => mesher.mesh(&layer, field, Some(&own), SampleSource::Layer)?,
    };
    Ok((m, keys, own.len()))
}

/// Runs `make(i)` for `i` in `0..n` on the thread pool, at most `lookahead` items ahead of
/// `consume`, which receives the results one by one in the order `0, 1, …, n − 1` on one of the
/// pool's threads; while the next result is not ready, that thread makes items itself. So every
/// thread of the pool stays busy, no item waits for a slower one of its batch, the output is
/// independent of the number of threads, and at most `lookahead` results exist at once. Stops at
/// the first error of `consume` (items already started finish first).
pub fn in_order<T: Send>(
    n: usize,
    lookahead: usize,
    make: impl Fn(usize) -> T + Sync,
    mut consume: impl FnMut(T) -> Result<()> + Send,
) -> Result<()> {
    let lookahead = lookahead.max(1);
    let (tx, rx) = crossbeam::channel::unbounded::<(usize, T)>();
    rayon::scope(|s| {
        let make = &make;
        let spawn = |i: usize| {
            let tx = tx.clone();
            s.spawn(move |_| {
                // The receiver outlives the scope; a send cannot fail while it waits.
                let _ = tx.send((i, make(i)));
            });
        };
        for i in 0..n.min(lookahead) {
            spawn(i);
        }
        let mut ready: BTreeMap<usize, T> = BTreeMap::new();
        for k in 0..n {
            let item = loop {
                if let Some(t) = ready.remove(&k) {
                    break t;
                }
                match rx.try_recv() {
                    Ok((i, t)) => {
                        ready.insert(i, t);
                    }
                    // Not ready: make an item here, or wait for the thread making it.
                    Err(_) => match rayon::yield_now() {
                        Some(rayon::Yield::Executed) => {}
                        _ => {
                            let (i, t) = rx.recv().expect("a sender is alive");
                            ready.insert(i, t);
                        }
                    },
                }
            };
            if k + lookahead < n {
                spawn(k + lookahead);
            }
            consume(item)?;
        }
        Ok(())
    })
}
