//! The seam between the stages and where blocks live: a [`BlockStore`] holds the map and makes
//! resident, in a RAM [`Layer`], every block a frame may update; the [`Reconstructor`] drives
//! fusion, regularization and meshing over any store, so an in-memory run and a `--map` run share
//! every line above this trait.
//!
//! - [`MemoryStore`]: the whole map is one layer in RAM; nothing to page, commits are no-ops.
//! - [`crate::outofcore::PagedStore`]: the map is a directory of chunk files; blocks are paged in
//!   around the camera within a byte budget, commits are checkpoints a killed run resumes from,
//!   regularization runs region by region with exact halos, meshes are exported tile by tile.
//!
//! A tier above RAM (the GPU's resident blocks) may hold newer copies of blocks than the layer;
//! stores call its [`UpperTier`] hooks before blocks leave RAM and before they read the layer
//! whole, so every tier reads current blocks. This module knows nothing of the GPU.
//!
//! [`Reconstructor`]: crate::reconstruct::Reconstructor

use crate::fusion::DepthPlan;
use crate::grid::{BlockIndex, GridParams, Layer, VOXELS_PER_BLOCK};
use crate::mesh::{extract_mesh, Field, Mesh};
use crate::regularize::{regularize_layer_by, TvParams, TvSolver};
use crate::Result;
use std::path::Path;

/// A tier above RAM whose copies of blocks may be newer than the layer's (the GPU's resident
/// blocks, `crate::backend::Backend`).
pub trait UpperTier {
    /// Writes `blocks` back into `layer` and forgets them: they are about to leave RAM.
    fn release(&mut self, layer: &mut Layer, blocks: &[BlockIndex]) -> Result<()>;
    /// As [`UpperTier::release`], but the newer copies may arrive later: returns whether they
    /// will (else they are in `layer` now). They are then collected by
    /// [`UpperTier::collect_released`] into `held`, the layer the store moves the leaving
    /// blocks to meanwhile; to make room for this release, older ones may be collected into
    /// `held` here. Nothing may read or page in the blocks until their release is collected.
    fn release_later(
        &mut self,
        layer: &mut Layer,
        _held: &mut Layer,
        blocks: &[BlockIndex],
    ) -> Result<bool> {
        self.release(layer, blocks).map(|()| false)
    }
    /// Writes into `held` the copies of the releases begun by [`UpperTier::release_later`]
    /// that have arrived or, with `wait`, of all of them (waiting where it must); returns how
    /// many releases were collected since the last call (oldest first), those collected to
    /// make room included.
    fn collect_released(&mut self, _held: &mut Layer, _wait: bool) -> Result<usize> {
        Ok(0)
    }
    /// Writes every changed block back into `layer` (blocks stay): the layer is about to be
    /// read whole (a checkpoint, regularization, meshing).
    fn sync(&mut self, layer: &mut Layer) -> Result<()>;
    /// Collects the frames still in flight on the tier (fusion calls that returned before the
    /// device ran them), but, with `keep_newest`, the one submitted last, waiting where it must,
    /// and returns the blocks touched by the frames collected since a fusion call last returned
    /// its touched blocks (the next call returns them too): a store marks them changed before it
    /// evicts blocks (keeping the newest frame's blocks, which may stay in flight) or makes a
    /// checkpoint (all). The layer then holds every block the collected frames created.
    fn settle(&mut self, _layer: &mut Layer, _keep_newest: bool) -> Result<Vec<BlockIndex>> {
        Ok(Vec::new())
    }
    /// Marching cubes over every block of `layer` (synced) on the tier's device: the CPU
    /// mesher unless the tier's device has a twin.
    fn mesh(&mut self, layer: &Layer, field: Field) -> Result<Mesh> {
        Ok(extract_mesh(layer, field, None))
    }
}

/// No tier above RAM.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoUpperTier;

impl UpperTier for NoUpperTier {
    fn release(&mut self, _: &mut Layer, _: &[BlockIndex]) -> Result<()> {
        Ok(())
    }
    fn sync(&mut self, _: &mut Layer) -> Result<()> {
        Ok(())
    }
}

/// What a store's regularization did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RegularizeSummary {
    /// Blocks written with a regularized field.
    pub blocks: usize,
    /// Ω voxels written.
    pub omega_voxels: u64,
    /// Iterations run.
    pub iterations: u32,
    /// Energy before and after, where the store computes it (in memory: the whole map).
    pub energy: Option<(f64, f64)>,
    /// Regions solved (1 for a global solve).
    pub regions: usize,
    /// Regions found already done (a resumed pass over a stored map).
    pub regions_skipped: usize,
    /// Blocks solved, halos included (≥ `blocks`; the ratio is the halo's cost).
    pub solved_blocks: usize,
    /// Halo thickness, blocks (0 for a global solve).
    pub halo_blocks: i32,
    /// Largest estimated working memory of one region, bytes (0 in memory).
    pub peak_region_bytes: u64,
    /// Pass number written into a stored map's manifest (0 in memory).
    pub pass: u32,
    /// Regions adopted from `regularize --shard` runs (stored maps).
    pub regions_adopted: usize,
    /// Sweeps the iterations were split into (regional: 1 with the exact halo), 0 when global.
    pub sweeps: u32,
    /// Region edge, chunks (regional), 0 when global.
    pub region_chunks: u32,
    /// Scratch state on disk of a swept pass at its fullest, bytes (0 otherwise).
    pub scratch_bytes: u64,
}

/// What writing a surface produced.
#[derive(Clone, Debug)]
pub struct SurfaceOutput {
    /// The field meshed.
    pub field: Field,
    /// The mesh file written.
    pub mesh_path: std::path::PathBuf,
    /// The point file written, if asked for.
    pub points_path: Option<std::path::PathBuf>,
    /// Vertices written.
    pub vertices: u64,
    /// Triangles written.
    pub triangles: u64,
    /// Surface area, m².
    pub area_m2: f64,
    /// The mesh itself, when the store had it in memory anyway (an in-memory map); a paged map
    /// streams its mesh to the file and leaves this `None`.
    pub mesh: Option<Mesh>,
    /// Seconds meshing and writing.
    pub seconds: f64,
}

/// Counters of a store that pages blocks between RAM and disk.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct PagingSummary {
    /// Bytes of blocks the store may keep in RAM (resident plus being written).
    pub budget_bytes: u64,
    /// Largest resident + in-flight bytes seen after a frame's eviction.
    pub peak_bytes: u64,
    /// Chunks evicted from RAM.
    pub chunks_evicted: u64,
    /// Chunk files written (evictions and checkpoints).
    pub chunks_written: u64,
    /// Bytes of chunk files written.
    pub bytes_written: u64,
    /// Chunks read back (revisits, loops, resumes).
    pub chunks_read: u64,
    /// Frames whose working set alone exceeded the budget.
    pub budget_overruns: u64,
}

/// Totals of a map, wherever it lives.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct StoreSummary {
    /// Allocated blocks.
    pub blocks: u64,
    /// Voxels in Ω.
    pub observed_voxels: u64,
    /// Bytes in RAM per allocated voxel now (resident blocks).
    pub ram_bytes_per_voxel: f64,
    /// Bytes of the resident blocks in RAM.
    pub ram_bytes: u64,
    /// Bytes on disk (0 in memory).
    pub disk_bytes: u64,
    /// Paging counters of this run (`None` in memory).
    pub paging: Option<PagingSummary>,
}

impl StoreSummary {
    /// Allocated voxels (blocks · 512).
    pub fn voxels(&self) -> u64 {
        self.blocks * VOXELS_PER_BLOCK as u64
    }
}

/// Where the map's blocks live (see the module documentation).
pub trait BlockStore {
    /// Voxel size and truncation of the map.
    fn grid(&self) -> GridParams;

    /// The resident blocks: the whole map in memory, the working set of a paged map.
    fn layer(&self) -> &Layer;

    /// The resident blocks, mutably (fusion updates them).
    fn layer_mut(&mut self) -> &mut Layer;

    /// Whether every block of the map stays in [`BlockStore::layer`] for the store's life (an
    /// in-memory map): a tier above RAM may then keep its copies through a regularization, and
    /// regularize them where they are ([`TvSolver::solve_in_place`]). A store that pages blocks
    /// during a regularization says false, and the tier is emptied first. Either kind lets
    /// frames stay in flight on the tier: a store that pages settles them
    /// ([`UpperTier::settle`]) before blocks leave RAM and before a checkpoint.
    fn holds_whole_map(&self) -> bool {
        false
    }

    /// Frames already committed to the store when it was opened (where a run resumes).
    fn frames_committed(&self) -> u64;

    /// Makes resident every block a depth frame with `plan` may update: its band and every
    /// existing block in its view frustum. A store that evicted blocks whose newer copies
    /// `tier` has not yet sent back ([`UpperTier::release_later`]) collects them first where
    /// the frame needs their chunks.
    fn prepare_depth(&mut self, plan: &DepthPlan, tier: &mut dyn UpperTier) -> Result<()>;

    /// Makes resident the sorted `blocks` (a LiDAR scan's band), as
    /// [`BlockStore::prepare_depth`].
    fn prepare_blocks(&mut self, blocks: &[BlockIndex], tier: &mut dyn UpperTier) -> Result<()>;

    /// After a frame that updated `touched` (sorted; with frames in flight on `tier`, what the
    /// frames collected since the last call touched), with the camera at `camera_m`: records
    /// the changes and may evict blocks to stay within a budget (`tier` settled and its copies
    /// written back first).
    fn finish_frame(
        &mut self,
        touched: &[BlockIndex],
        camera_m: [f64; 3],
        tier: &mut dyn UpperTier,
    ) -> Result<()>;

    /// Makes everything fused so far durable, as `frames_fused` frames (a checkpoint a killed
    /// run resumes from). `tier` is synced first.
    fn commit(&mut self, frames_fused: u64, tier: &mut dyn UpperTier) -> Result<()>;

    /// Regularizes the whole map with `solver` (`progress(done, total)` after each region;
    /// returning false stops early, what was done is kept). A tier above RAM holds no blocks
    /// the layer lacks, and none with changes not in the layer (the caller syncs it first, and
    /// empties it unless [`BlockStore::holds_whole_map`]).
    fn regularize(
        &mut self,
        params: &TvParams,
        solver: &mut dyn TvSolver,
        progress: &mut dyn FnMut(usize, usize) -> bool,
    ) -> Result<RegularizeSummary>;

    /// Meshes `field` into a binary PLY at `mesh_path` and, with `points_path`, its vertices as
    /// a point cloud (PLY, LAS or LAZ by extension). `tier` is synced first.
    fn write_surface(
        &mut self,
        field: Field,
        mesh_path: &Path,
        points_path: Option<&Path>,
        tier: &mut dyn UpperTier,
    ) -> Result<SurfaceOutput>;

    /// Totals of the map.
    fn summary(&self) -> StoreSummary;
}

/// A solver that runs its iterations in chunks of [`PROGRESS_ITERATIONS`], reporting
/// `(iterations done, iterations)` of the current solve after each: the same result (the
/// solver's state carries over between calls, its iterates kept until the last chunk), a
/// progress bar for a long global solve. A solver for which a split costs a round trip of the
/// state ([`TvSolver::prefers_whole_solves`], a GPU) gets the solve whole, reported at its end.
struct Chunked<'a> {
    inner: &'a mut dyn TvSolver,
    progress: &'a mut dyn FnMut(usize, usize) -> bool,
}

/// Iterations between two progress reports of an in-memory regularization.
const PROGRESS_ITERATIONS: u32 = 25;

impl TvSolver for Chunked<'_> {
    fn solve(
        &mut self,
        problem: &mut crate::regularize::TvProblem,
        params: &TvParams,
    ) -> Result<()> {
        if self.inner.prefers_whole_solves() {
            self.inner.solve(problem, params)?;
            (self.progress)(params.iterations as usize, params.iterations as usize);
            return Ok(());
        }
        // The caller's wish for the iterates holds for the last chunk; the others continue.
        let keep = problem.keeps_iterates();
        let mut done = 0;
        while done < params.iterations {
            let k = PROGRESS_ITERATIONS.min(params.iterations - done);
            problem.set_keep_iterates(keep || done + k < params.iterations);
            let solved = self.inner.solve(
                problem,
                &TvParams {
                    iterations: k,
                    ..*params
                },
            );
            problem.set_keep_iterates(keep);
            solved?;
            done += k;
            (self.progress)(done as usize, params.iterations as usize);
        }
        Ok(())
    }

    fn prefers_whole_solves(&self) -> bool {
        self.inner.prefers_whole_solves()
    }

    fn max_voxels(&self) -> Option<usize> {
        self.inner.max_voxels()
    }

    /// One solve where the blocks are, reported at its end.
    fn solve_in_place(
        &mut self,
        layer: &mut Layer,
        params: &TvParams,
    ) -> Result<
        Option<(
            crate::grid::TouchedBlocks,
            crate::regularize::RegularizeStats,
        )>,
    > {
        let done = self.inner.solve_in_place(layer, params)?;
        if done.is_some() {
            (self.progress)(params.iterations as usize, params.iterations as usize);
        }
        Ok(done)
    }
}

/// RAM the in-memory path needs per allocated block for the whole run: the block with a
/// regularized field (8 B/voxel and its hash slot) and the regularizer's arrays over it
/// (`outofcore::regional::SOLVER_BYTES_PER_VOXEL`, 30 B/voxel), bytes.
pub const MEMORY_RUN_BYTES_PER_BLOCK: u64 = (VOXELS_PER_BLOCK as u64) * (8 + 30) + 32;

/// The whole map in one RAM [`Layer`].
#[derive(Clone, Debug)]
pub struct MemoryStore {
    layer: Layer,
    limit_bytes: Option<u64>,
}

impl MemoryStore {
    /// An empty map on `grid`.
    pub fn new(grid: GridParams) -> Self {
        MemoryStore {
            layer: Layer::new(grid),
            limit_bytes: None,
        }
    }

    /// A store over an existing layer.
    pub fn from_layer(layer: Layer) -> Self {
        MemoryStore {
            layer,
            limit_bytes: None,
        }
    }

    /// Stops fusion with an error once the run would need more than `bytes` of RAM to fuse,
    /// regularize and mesh the map ([`MEMORY_RUN_BYTES_PER_BLOCK`] per block), before the
    /// machine runs out: the map belongs in a map directory then.
    pub fn with_limit(mut self, bytes: u64) -> Self {
        self.limit_bytes = Some(bytes);
        self
    }

    /// The layer.
    pub fn into_layer(self) -> Layer {
        self.layer
    }
}

impl BlockStore for MemoryStore {
    fn grid(&self) -> GridParams {
        self.layer.params()
    }

    fn layer(&self) -> &Layer {
        &self.layer
    }

    fn layer_mut(&mut self) -> &mut Layer {
        &mut self.layer
    }

    fn holds_whole_map(&self) -> bool {
        true
    }

    fn frames_committed(&self) -> u64 {
        0
    }

    fn prepare_depth(&mut self, _: &DepthPlan, _: &mut dyn UpperTier) -> Result<()> {
        Ok(())
    }

    fn prepare_blocks(&mut self, _: &[BlockIndex], _: &mut dyn UpperTier) -> Result<()> {
        Ok(())
    }

    fn finish_frame(&mut self, _: &[BlockIndex], _: [f64; 3], _: &mut dyn UpperTier) -> Result<()> {
        let Some(limit) = self.limit_bytes else {
            return Ok(());
        };
        let blocks = self.layer.block_count() as u64;
        let need = blocks * MEMORY_RUN_BYTES_PER_BLOCK;
        if need > limit {
            return Err(crate::Error::InvalidArgument(format!(
                "the map in RAM has grown to {blocks} blocks: fusing, regularizing and meshing it in memory would need about {} MiB, more than the {} MiB available; stream it through a map directory instead (--map DIR --memory-budget B)",
                need >> 20,
                limit >> 20
            )));
        }
        Ok(())
    }

    fn commit(&mut self, _: u64, tier: &mut dyn UpperTier) -> Result<()> {
        tier.sync(&mut self.layer)
    }

    fn regularize(
        &mut self,
        params: &TvParams,
        solver: &mut dyn TvSolver,
        progress: &mut dyn FnMut(usize, usize) -> bool,
    ) -> Result<RegularizeSummary> {
        let mut chunked = Chunked {
            inner: solver,
            progress,
        };
        let (blocks, stats) = regularize_layer_by(&mut self.layer, params, &mut chunked)?;
        Ok(RegularizeSummary {
            blocks: blocks.len(),
            omega_voxels: stats.omega_voxels as u64,
            iterations: stats.iterations,
            energy: stats.energy,
            regions: 1,
            solved_blocks: blocks.len(),
            ..Default::default()
        })
    }

    fn write_surface(
        &mut self,
        field: Field,
        mesh_path: &Path,
        points_path: Option<&Path>,
        tier: &mut dyn UpperTier,
    ) -> Result<SurfaceOutput> {
        tier.sync(&mut self.layer)?;
        let t = std::time::Instant::now();
        let mesh = tier.mesh(&self.layer, field)?;
        crate::io::ply::write_mesh_ply(mesh_path, &mesh)?;
        if let Some(p) = points_path {
            crate::io::write_point_cloud(p, &mesh.to_point_cloud())?;
        }
        Ok(SurfaceOutput {
            field,
            mesh_path: mesh_path.to_path_buf(),
            points_path: points_path.map(Path::to_path_buf),
            vertices: mesh.positions_m.len() as u64,
            triangles: mesh.triangles.len() as u64,
            area_m2: mesh.surface_area_m2(),
            mesh: Some(mesh),
            seconds: t.elapsed().as_secs_f64(),
        })
    }

    fn summary(&self) -> StoreSummary {
        StoreSummary {
            blocks: self.layer.block_count() as u64,
            observed_voxels: self.layer.observed_voxel_count() as u64,
            ram_bytes_per_voxel: self.layer.bytes_per_voxel(),
            ram_bytes: self.layer.memory_bytes() as u64,
            disk_bytes: 0,
            paging: None,
        }
    }
}
