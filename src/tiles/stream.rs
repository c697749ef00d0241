//! Fusion through the pager: each frame pages in every chunk it can update, fuses into the resident
//! layer, marks what it touched, then evicts down to the budget around the camera.
//!
//! Working set of a depth frame: the chunks of its truncation band ([`depth_frame_blocks`]) plus
//! every existing chunk whose bounding sphere meets the view frustum ([`ViewFrustum`], the same
//! monotone test that picks the allocated blocks a frame carves), so every block the in-memory
//! fusion would update is resident. A LiDAR scan needs only the chunks of its band. Hence fusing
//! through the pager gives bit-identical voxels to fusing into one [`Layer`](crate::grid::Layer).
//!
//! **GPU tier.** With [`StreamingFusion::with_gpu`], depth frames are fused into blocks resident
//! on the GPU ([`ResidentMap`]): device ↔ RAM ↔ disk. The GPU holds a subset of the RAM-resident
//! blocks (the most recently used, around the camera, within its own budget); before the pager
//! evicts a chunk from RAM the GPU writes that chunk's blocks back and releases them, before a
//! checkpoint it writes back every block it changed, and before a LiDAR scan (fused per call by
//! the GPU LiDAR kernel) it releases the scan's blocks. So every tier below sees current blocks when it reads them.

use super::pager::{Pager, PagerStats};
use super::store::MapStore;
use super::{group_by_chunk, ChunkIndex};
use crate::error::Result;
use crate::frame::{DepthFrame, LidarScan};
use crate::fusion::{
    depth_frame_blocks, integrate_depth_band, integrate_lidar_plan, DepthFusionParams, FusionStats,
    LidarFusionParams, LidarPlan, ViewFrustum,
};
use crate::gpu::{ResidentMap, ResidentStats};
use crate::grid::TouchedBlocks;
use std::collections::HashSet;

/// Fusion into a paged map.
pub struct StreamingFusion {
    pager: Pager,
    depth_params: DepthFusionParams,
    lidar_params: LidarFusionParams,
    frames_fused: u64,
    checkpoint_every: u64,
    /// Seconds in fusion proper (the same work as in-memory fusion).
    pub fusion_s: f64,
    /// Seconds paging in and evicting (reads, waits, bookkeeping).
    pub paging_s: f64,
    /// Voxel updates so far.
    pub voxel_updates: usize,
    /// The GPU tier, when depth frames are fused on a GPU.
    gpu: Option<ResidentMap>,
}

impl StreamingFusion {
    /// Fusion through `pager`, committing a checkpoint every `checkpoint_every` frames (0: only at
    /// the end). `frames_fused` starts at the store's committed count (a resumed run).
    pub fn new(
        pager: Pager,
        depth_params: DepthFusionParams,
        lidar_params: LidarFusionParams,
        checkpoint_every: u64,
    ) -> Self {
        let frames_fused = pager.store().manifest().header.frames_committed;
        StreamingFusion {
            pager,
            depth_params,
            lidar_params,
            frames_fused,
            checkpoint_every,
            fusion_s: 0.0,
            paging_s: 0.0,
            voxel_updates: 0,
            gpu: None,
        }
    }

    /// Fuses depth frames on the GPU into blocks resident in `map` (the GPU tier above the
    /// pager's RAM). The map's grid must be the store's.
    pub fn with_gpu(mut self, map: ResidentMap) -> Self {
        self.gpu = Some(map);
        self
    }

    /// Counters of the GPU tier, if any.
    pub fn gpu_stats(&self) -> Option<ResidentStats> {
        self.gpu.as_ref().map(|g| g.stats())
    }

    /// Frames fused (including those of earlier, committed runs).
    pub fn frames_fused(&self) -> u64 {
        self.frames_fused
    }

    /// The pager.
    pub fn pager(&self) -> &Pager {
        &self.pager
    }

    fn after_frame(
        &mut self,
        camera: [f64; 3],
        keep: &HashSet<ChunkIndex>,
        touched: &TouchedBlocks,
    ) -> Result<()> {
        let t = std::time::Instant::now();
        self.pager.mark_dirty(touched);
        let gpu = &mut self.gpu;
        self.pager
            .evict_to_budget_with(camera, keep, &mut |layer, blocks| match gpu.as_mut() {
                Some(g) => g.flush_blocks(layer, blocks).map(|_| ()),
                None => Ok(()),
            })?;
        self.frames_fused += 1;
        if self.checkpoint_every > 0 && self.frames_fused % self.checkpoint_every == 0 {
            if let Some(g) = self.gpu.as_mut() {
                g.sync(self.pager.layer_mut())?;
            }
            self.pager.checkpoint(self.frames_fused)?;
        }
        self.paging_s += t.elapsed().as_secs_f64();
        Ok(())
    }

    /// Fuses one depth frame.
    pub fn fuse_depth(&mut self, frame: &DepthFrame) -> Result<(TouchedBlocks, FusionStats)> {
        let t = std::time::Instant::now();
        let grid = self.pager.store().grid();
        let cb = self.pager.chunk_blocks();
        let band = depth_frame_blocks(&grid, frame, &self.depth_params);
        let t_band = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let mut keep: HashSet<ChunkIndex> = group_by_chunk(band.iter().copied(), cb)
            .into_keys()
            .collect();
        let frustum = ViewFrustum::new(frame, &self.depth_params, grid.truncation_m as f64);
        let chunk_m = grid.block_size_m() * cb as f64;
        let radius = 0.5 * chunk_m * 3f64.sqrt();
        for c in self.pager.known_chunks() {
            let centre = [0, 1, 2].map(|a| (c.0[a] as f64 + 0.5) * chunk_m);
            if frustum.meets_sphere(centre, radius) {
                keep.insert(c);
            }
        }
        let mut list: Vec<ChunkIndex> = keep.iter().copied().collect();
        list.sort_unstable();
        self.pager.page_in(&list)?;
        self.paging_s += t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let (touched, stats) = match self.gpu.as_mut() {
            Some(g) => {
                g.integrate_depth_band(self.pager.layer_mut(), frame, &self.depth_params, band)?
            }
            None => integrate_depth_band(self.pager.layer_mut(), frame, &self.depth_params, band),
        };
        self.fusion_s += t.elapsed().as_secs_f64() + t_band;
        self.voxel_updates += stats.voxel_updates;
        let camera: [f64; 3] = frame.world_from_camera.translation.vector.into();
        self.after_frame(camera, &keep, &touched)?;
        Ok((touched, stats))
    }

    /// Fuses one LiDAR scan.
    pub fn fuse_lidar(&mut self, scan: &LidarScan) -> Result<(TouchedBlocks, FusionStats)> {
        let t = std::time::Instant::now();
        let grid = self.pager.store().grid();
        let plan = LidarPlan::new(&grid, scan, &self.lidar_params);
        let t_plan = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let keep: HashSet<ChunkIndex> = group_by_chunk(plan.blocks(), self.pager.chunk_blocks())
            .into_keys()
            .collect();
        let mut list: Vec<ChunkIndex> = keep.iter().copied().collect();
        list.sort_unstable();
        self.pager.page_in(&list)?;
        if let Some(g) = self.gpu.as_mut() {
            g.flush_blocks(self.pager.layer_mut(), &plan.blocks())?;
        }
        self.paging_s += t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let (touched, stats) = match self.gpu.as_ref() {
            Some(g) => crate::gpu::integrate_lidar_gpu(g.context(), self.pager.layer_mut(), &plan)?,
            None => integrate_lidar_plan(self.pager.layer_mut(), &plan),
        };
        self.fusion_s += t.elapsed().as_secs_f64() + t_plan;
        self.voxel_updates += stats.voxel_updates;
        let camera: [f64; 3] = scan.world_from_sensor.translation.vector.into();
        self.after_frame(camera, &keep, &touched)?;
        Ok((touched, stats))
    }

    /// Final checkpoint: every chunk written and committed. Returns the store and the counters.
    pub fn finish(mut self) -> Result<(MapStore, PagerStats)> {
        let frames = self.frames_fused;
        if let Some(g) = self.gpu.as_mut() {
            g.flush_all(self.pager.layer_mut())?;
        }
        self.pager.finish(frames)
    }
}
