//! [`PagedStore`]: a map directory as a [`BlockStore`]. Fusion runs on the pager's resident
//! layer; before each frame the store pages in every chunk the frame can update, after it the
//! pager evicts down to the budget around the camera; commits are the pager's checkpoints.
//! Regularization runs region by region with exact halos over the chunk files, and surfaces are
//! exported tile by tile, so memory stays bounded by the budget whatever the map's size.
//!
//! Working set of a depth frame: the chunks of its truncation band plus every existing chunk
//! whose bounding sphere meets the view frustum (the plan's [`crate::fusion::ViewFrustum`], the
//! same monotone test that picks the allocated blocks a frame carves), so every block in-memory
//! fusion would update is resident. A LiDAR scan needs only the chunks of its band. Hence
//! fusing through the pager gives bit-identical voxels to fusing into one in-memory layer.
//!
//! Surfaces are written by the exporter, a room above this one ([`crate::export`]): whoever opens
//! a paged store hands one in as a [`SurfaceWriter`], so nothing here imports it.

use super::pager::{Pager, PagerConfig, PagerStats};
use super::regional::{regularize_map_with, RegionalOptions};
use crate::error::{Error, Result};
use crate::fusion::DepthPlan;
use crate::grid::{BlockIndex, GridParams, Layer};
use crate::map::store::MapStore;
use crate::map::{group_by_chunk, ChunkIndex};
use crate::mesh::Field;
use crate::regularize::{TvParams, TvSolver};
use crate::store::{
    BlockStore, PagingSummary, RegularizeSummary, StoreSummary, SurfaceOutput, UpperTier,
};
use std::collections::HashSet;
use std::path::Path;

/// What a [`SurfaceWriter`] wrote: the mesh's size.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SurfaceCounts {
    /// Vertices written.
    pub vertices: u64,
    /// Triangles written.
    pub triangles: u64,
    /// Surface area, m².
    pub area_m2: f64,
}

/// Writes `field` of a stored map tile by tile as a binary PLY mesh at the first path and, with
/// the second, its vertices as a point cloud (PLY, LAS or LAZ by extension). The exporter
/// ([`crate::export::write_map_surface`]) lives in a room above the solvers, so whoever opens a
/// [`PagedStore`] hands it in.
pub type SurfaceWriter = fn(&MapStore, Field, &Path, Option<&Path>) -> Result<SurfaceCounts>;

// One per open map: the size of the largest variant does not matter.
#[allow(clippy::large_enum_variant)]
enum State {
    /// Fusing: blocks paged around the camera.
    Paging(Box<Pager>),
    /// Every chunk written and committed; no blocks resident.
    Stored(MapStore),
    /// A failure while switching states left no usable map handle.
    Failed,
}

/// A map directory seen as a [`BlockStore`] (see the module documentation).
pub struct PagedStore {
    state: State,
    grid: GridParams,
    regional: RegionalOptions,
    frames_at_open: u64,
    frames_last_commit: u64,
    keep: HashSet<ChunkIndex>,
    pager_stats: PagerStats,
    budget_bytes: u64,
    empty: Layer,
    surfaces: SurfaceWriter,
}

impl PagedStore {
    /// Fusion into `store` through a pager with `pager` settings; later regularization uses
    /// `regional`, surfaces are written by `surfaces`.
    pub fn new(
        store: MapStore,
        pager: PagerConfig,
        regional: RegionalOptions,
        surfaces: SurfaceWriter,
    ) -> Self {
        let grid = store.grid();
        let frames = store.manifest().header.frames_committed;
        PagedStore {
            state: State::Paging(Box::new(Pager::new(store, pager))),
            grid,
            regional,
            frames_at_open: frames,
            frames_last_commit: frames,
            keep: HashSet::new(),
            pager_stats: PagerStats::default(),
            budget_bytes: pager.budget_bytes,
            empty: Layer::new(grid),
            surfaces,
        }
    }

    /// A stored map, to regularize or export (no fusion: frames cannot be added).
    pub fn stored(store: MapStore, regional: RegionalOptions, surfaces: SurfaceWriter) -> Self {
        let grid = store.grid();
        let frames = store.manifest().header.frames_committed;
        PagedStore {
            state: State::Stored(store),
            grid,
            regional,
            frames_at_open: frames,
            frames_last_commit: frames,
            keep: HashSet::new(),
            pager_stats: PagerStats::default(),
            budget_bytes: regional.budget_bytes,
            empty: Layer::new(grid),
            surfaces,
        }
    }

    /// The pager's counters (of the whole run, once fusion finished).
    pub fn pager_stats(&self) -> PagerStats {
        match &self.state {
            State::Paging(p) => p.stats(),
            _ => self.pager_stats,
        }
    }

    /// The map on disk, once fusion is finished ([`PagedStore::finish_paging`]).
    pub fn map(&self) -> Option<&MapStore> {
        match &self.state {
            State::Stored(s) => Some(s),
            _ => None,
        }
    }

    /// Ends fusion: a final checkpoint of the frames committed last, the writer threads stopped.
    /// Nothing happens when fusion already ended.
    pub fn finish_paging(&mut self) -> Result<&mut MapStore> {
        if let State::Paging(_) = self.state {
            let State::Paging(pager) = std::mem::replace(&mut self.state, State::Failed) else {
                unreachable!()
            };
            let (store, stats) = pager.finish(self.frames_last_commit)?;
            self.pager_stats = stats;
            crate::memory::release_free_memory();
            // Regularization next: its regions reuse freed arrays (bounded by its trims).
            crate::memory::keep_freed_memory();
            self.state = State::Stored(store);
        }
        match &mut self.state {
            State::Stored(s) => Ok(s),
            _ => Err(Error::InvalidArgument(
                "the map store failed earlier in this run".into(),
            )),
        }
    }

    /// The map, finished ([`PagedStore::finish_paging`]).
    pub fn into_map(mut self) -> Result<MapStore> {
        self.finish_paging()?;
        match self.state {
            State::Stored(s) => Ok(s),
            _ => unreachable!("finish_paging leaves a stored map"),
        }
    }

    fn pager(&mut self) -> Result<&mut Pager> {
        match &mut self.state {
            State::Paging(p) => Ok(p),
            _ => Err(Error::InvalidArgument(
                "this map is open for regularization or export only: fusion has ended".into(),
            )),
        }
    }

    fn page_in(&mut self, keep: HashSet<ChunkIndex>, tier: &mut dyn UpperTier) -> Result<()> {
        let mut list: Vec<ChunkIndex> = keep.iter().copied().collect();
        list.sort_unstable();
        let pager = self.pager()?;
        if pager.holds_any(&list) {
            // A chunk evicted a frame or two ago comes back: its blocks' copies first.
            complete_releases(pager, tier, true)?;
        }
        pager.page_in(&list)?;
        self.keep = keep;
        Ok(())
    }
}

/// Sends to the writers the evicted chunks whose blocks' copies `tier` sent back (all of them,
/// waiting where they have not come, with `wait`).
fn complete_releases(pager: &mut Pager, tier: &mut dyn UpperTier, wait: bool) -> Result<()> {
    let done = tier.collect_released(pager.held_layer_mut(), wait)?;
    pager.complete_held(done)
}

/// Settles the frames in flight on `tier` ([`UpperTier::settle`], all but the newest with
/// `keep_newest`) and marks the chunks they touched dirty.
fn settle(pager: &mut Pager, tier: &mut dyn UpperTier, keep_newest: bool) -> Result<()> {
    let late = tier.settle(pager.layer_mut(), keep_newest)?;
    pager.mark_dirty(&late);
    Ok(())
}

impl BlockStore for PagedStore {
    fn grid(&self) -> GridParams {
        self.grid
    }

    fn layer(&self) -> &Layer {
        match &self.state {
            State::Paging(p) => p.layer(),
            _ => &self.empty,
        }
    }

    fn layer_mut(&mut self) -> &mut Layer {
        match &mut self.state {
            State::Paging(p) => p.layer_mut(),
            _ => &mut self.empty,
        }
    }

    fn frames_committed(&self) -> u64 {
        self.frames_at_open
    }

    fn prepare_depth(&mut self, plan: &DepthPlan, tier: &mut dyn UpperTier) -> Result<()> {
        let grid = self.grid;
        let pager = self.pager()?;
        let cb = pager.chunk_blocks();
        let mut keep: HashSet<ChunkIndex> = group_by_chunk(plan.band.iter().copied(), cb)
            .into_keys()
            .collect();
        let chunk_m = grid.block_size_m() * cb as f64;
        let radius = 0.5 * chunk_m * 3f64.sqrt();
        for c in pager.known_chunks() {
            let centre = [0, 1, 2].map(|a| (c.0[a] as f64 + 0.5) * chunk_m);
            if plan.frustum.meets_sphere(centre, radius) {
                keep.insert(c);
            }
        }
        self.page_in(keep, tier)
    }

    fn prepare_blocks(&mut self, blocks: &[BlockIndex], tier: &mut dyn UpperTier) -> Result<()> {
        let cb = self.pager()?.chunk_blocks();
        let keep = group_by_chunk(blocks.iter().copied(), cb)
            .into_keys()
            .collect();
        self.page_in(keep, tier)
    }

    fn finish_frame(
        &mut self,
        touched: &[BlockIndex],
        camera_m: [f64; 3],
        tier: &mut dyn UpperTier,
    ) -> Result<()> {
        let keep = std::mem::take(&mut self.keep);
        let pager = self.pager()?;
        pager.mark_dirty(touched);
        if pager.needs_eviction(&keep)? {
            // Blocks leave RAM: the frames still in flight on the tier land first, so that the
            // chunks they changed are written and the blocks they created go with their chunk.
            // This frame's blocks lie in `keep`, which stays: it may stay in flight.
            settle(pager, tier, true)?;
        }
        // The GPU's copies of the leaving blocks come back a frame or more later: their chunks
        // wait in the pager's held layer until then.
        pager.evict_to_budget_with(camera_m, &keep, &mut |layer, held, blocks| {
            tier.release_later(layer, held, blocks)
        })?;
        complete_releases(pager, tier, false)
    }

    fn commit(&mut self, frames_fused: u64, tier: &mut dyn UpperTier) -> Result<()> {
        if !matches!(self.state, State::Paging(_)) && frames_fused == self.frames_last_commit {
            // Fusion ended with these frames committed: nothing new to make durable.
            return Ok(());
        }
        let pager = self.pager()?;
        settle(pager, tier, false)?;
        complete_releases(pager, tier, true)?;
        tier.sync(pager.layer_mut())?;
        pager.checkpoint(frames_fused)?;
        self.frames_last_commit = frames_fused;
        Ok(())
    }

    fn regularize(
        &mut self,
        params: &TvParams,
        solver: &mut dyn TvSolver,
        progress: &mut dyn FnMut(usize, usize) -> bool,
    ) -> Result<RegularizeSummary> {
        let options = self.regional;
        let store = self.finish_paging()?;
        let s = regularize_map_with(store, params, &options, progress, |p, params| {
            solver.solve(p, params)
        })?;
        Ok(RegularizeSummary {
            blocks: s.core_blocks,
            omega_voxels: s.core_omega_voxels,
            iterations: params.iterations,
            energy: None,
            regions: s.regions,
            regions_skipped: s.regions_skipped,
            solved_blocks: s.solved_blocks,
            halo_blocks: s.halo_blocks,
            peak_region_bytes: s.peak_region_bytes,
            pass: s.pass,
            regions_adopted: s.regions_adopted,
            sweeps: s.sweeps,
            region_chunks: s.region_chunks,
            scratch_bytes: s.scratch_bytes,
        })
    }

    fn write_surface(
        &mut self,
        field: Field,
        mesh_path: &Path,
        points_path: Option<&Path>,
        tier: &mut dyn UpperTier,
    ) -> Result<SurfaceOutput> {
        if let State::Paging(p) = &mut self.state {
            settle(p, tier, false)?;
            complete_releases(p, tier, true)?;
            tier.sync(p.layer_mut())?;
        }
        let surfaces = self.surfaces;
        let store = self.finish_paging()?;
        let t = std::time::Instant::now();
        let mesh = surfaces(store, field, mesh_path, points_path)?;
        Ok(SurfaceOutput {
            field,
            mesh_path: mesh_path.to_path_buf(),
            points_path: points_path.map(Path::to_path_buf),
            vertices: mesh.vertices,
            triangles: mesh.triangles,
            area_m2: mesh.area_m2,
            mesh: None,
            seconds: t.elapsed().as_secs_f64(),
        })
    }

    fn summary(&self) -> StoreSummary {
        let (map, layer) = match &self.state {
            State::Paging(p) => (Some(p.store()), p.layer()),
            State::Stored(s) => (Some(s), &self.empty),
            State::Failed => (None, &self.empty),
        };
        let disk = map.map(|m| m.summary()).unwrap_or_default();
        let p = self.pager_stats();
        StoreSummary {
            blocks: disk.blocks,
            observed_voxels: disk.observed_voxels,
            ram_bytes_per_voxel: layer.bytes_per_voxel(),
            ram_bytes: layer.memory_bytes() as u64,
            disk_bytes: disk.bytes_on_disk,
            paging: Some(PagingSummary {
                budget_bytes: self.budget_bytes,
                peak_bytes: p.peak_bytes,
                chunks_evicted: p.chunks_evicted,
                chunks_written: p.chunks_written,
                bytes_written: p.bytes_written,
                chunks_read: p.chunks_read,
                budget_overruns: p.budget_overruns,
            }),
        }
    }
}
