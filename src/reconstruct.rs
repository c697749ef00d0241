//! The [`Reconstructor`]: a thin object that owns a [`Layer`] and wires fusion, regularisation and
//! meshing, keeping per-stage timings and work counters. It holds no I/O: the CLI's pipelines feed
//! it frames from readers, stereo or the synthetic city, and evaluate what it returns.

use crate::frame::{DepthFrame, LidarScan};
use crate::fusion::{
    integrate_depth, integrate_lidar_plan, DepthFusionParams, FusionStats, LidarFusionParams,
    LidarPlan,
};
use crate::gpu::{GpuContext, ResidentMap, ResidentOptions, ResidentStats};
use crate::grid::{GridParams, Layer, TouchedBlocks, VOXELS_PER_BLOCK};
use crate::mesh::{extract_mesh, Field, Mesh};
use crate::regularize::{regularize_layer, RegionPlan, RegularizeStats, TvParams, TvProblem};
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Instant;

/// Everything that parameterises a reconstruction.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReconstructionConfig {
    /// Voxel size and truncation μ.
    pub grid: GridParams,
    /// TV regulariser.
    pub tv: TvParams,
    /// Depth-map fusion options.
    #[serde(skip, default)]
    pub depth_fusion: DepthFusionParams,
    /// LiDAR fusion options.
    #[serde(skip, default)]
    pub lidar_fusion: LidarFusionParams,
}

impl ReconstructionConfig {
    /// The paper's settings for a voxel size (10 cm → μ 1.0 m, λ 0.8; 20 cm → μ 1.6 m, λ 0.4).
    pub fn paper(voxel_size_m: f32) -> Self {
        ReconstructionConfig {
            grid: GridParams::paper(voxel_size_m),
            tv: TvParams::paper(voxel_size_m),
            depth_fusion: DepthFusionParams::default(),
            lidar_fusion: LidarFusionParams::default(),
        }
    }
}

/// Wall-clock seconds and work per stage.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StageTimings {
    /// Seconds spent producing depth frames or scans (reading files, stereo matching).
    pub input_s: f64,
    /// Seconds spent fusing.
    pub fusion_s: f64,
    /// Frames or scans fused.
    pub frames_fused: usize,
    /// Voxel updates applied by fusion.
    pub voxel_updates: usize,
    /// Seconds spent regularising.
    pub regularize_s: f64,
    /// Voxel-iterations of the regulariser (Ω voxels × iterations).
    pub voxel_iterations: u64,
    /// Seconds spent in marching cubes.
    pub mesh_s: f64,
}

impl StageTimings {
    /// Mean fusion time per frame, milliseconds.
    pub fn fusion_ms_per_frame(&self) -> f64 {
        1e3 * self.fusion_s / self.frames_fused.max(1) as f64
    }

    /// Voxel updates per second during fusion.
    pub fn voxel_updates_per_s(&self) -> f64 {
        self.voxel_updates as f64 / self.fusion_s.max(1e-12)
    }

    /// Regulariser throughput, voxel-iterations per second.
    pub fn voxel_iterations_per_s(&self) -> f64 {
        self.voxel_iterations as f64 / self.regularize_s.max(1e-12)
    }
}

/// Owns the map and runs the in-memory stages.
pub struct Reconstructor {
    config: ReconstructionConfig,
    layer: Layer,
    timings: StageTimings,
    gpu: Option<Arc<GpuContext>>,
    /// Blocks resident on the GPU between depth frames (created at the first GPU frame).
    resident: Option<ResidentMap>,
    gpu_options: ResidentOptions,
}

impl std::fmt::Debug for Reconstructor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reconstructor")
            .field("config", &self.config)
            .field("blocks", &self.layer.block_count())
            .field("timings", &self.timings)
            .field("gpu", &self.gpu.as_ref().map(|g| g.describe()))
            .field("resident", &self.resident_stats())
            .finish()
    }
}

impl Reconstructor {
    /// A reconstructor with an empty map.
    pub fn new(config: ReconstructionConfig) -> crate::Result<Self> {
        config.grid.validate()?;
        config.tv.validate()?;
        Ok(Reconstructor {
            layer: Layer::new(config.grid),
            config,
            timings: StageTimings::default(),
            gpu: None,
            resident: None,
            gpu_options: ResidentOptions::default(),
        })
    }

    /// Runs depth and LiDAR fusion and regularisation on `gpu` (`None`: on the CPU); meshing
    /// stays on the CPU. Depth fusion on the GPU keeps the blocks it fuses resident on the device
    /// between frames ([`ResidentMap`]): the layer is current only after
    /// [`Reconstructor::sync_gpu`] (which [`Reconstructor::regularize`] calls, as do the
    /// pipelines before meshing). Call before fusing; a resident map from an earlier GPU is
    /// written back first.
    pub fn set_gpu(&mut self, gpu: Option<Arc<GpuContext>>) {
        if let Some(mut r) = self.resident.take() {
            if let Err(e) = r.flush_all(&mut self.layer) {
                tracing::error!("writing the GPU-resident blocks back failed: {e}");
            }
        }
        self.gpu = gpu;
    }

    /// Size limits of the GPU block pool (used when the first GPU frame creates it).
    pub fn set_gpu_options(&mut self, options: ResidentOptions) {
        self.gpu_options = options;
    }

    /// Copies the blocks the GPU updated back into the layer (they stay resident). Returns how
    /// many blocks were copied; 0 without a GPU. The time counts as fusion time.
    pub fn sync_gpu(&mut self) -> crate::Result<usize> {
        let t = Instant::now();
        let n = match self.resident.as_mut() {
            Some(r) => r.sync(&mut self.layer)?,
            None => 0,
        };
        self.timings.fusion_s += t.elapsed().as_secs_f64();
        Ok(n)
    }

    /// Counters of the GPU-resident blocks, when depth fusion ran on a GPU.
    pub fn resident_stats(&self) -> Option<ResidentStats> {
        self.resident.as_ref().map(|r| r.stats())
    }

    /// The GPU in use, if any.
    pub fn gpu(&self) -> Option<&GpuContext> {
        self.gpu.as_deref()
    }

    /// The configuration.
    pub fn config(&self) -> &ReconstructionConfig {
        &self.config
    }

    /// The map in RAM (see [`Reconstructor::sync_gpu`] when fusing on the GPU).
    pub fn layer(&self) -> &Layer {
        &self.layer
    }

    /// The map, mutably.
    pub fn layer_mut(&mut self) -> &mut Layer {
        &mut self.layer
    }

    /// Timings so far.
    pub fn timings(&self) -> &StageTimings {
        &self.timings
    }

    /// Adds time spent producing input (reading, stereo) to the timings.
    pub fn add_input_time(&mut self, seconds: f64) {
        self.timings.input_s += seconds;
    }

    fn record(&mut self, started: Instant, stats: FusionStats) {
        self.timings.fusion_s += started.elapsed().as_secs_f64();
        self.timings.frames_fused += 1;
        self.timings.voxel_updates += stats.voxel_updates;
    }

    /// Fuses a depth frame (on the GPU when one is set); returns the blocks it touched.
    pub fn fuse_depth(&mut self, frame: &DepthFrame) -> crate::Result<TouchedBlocks> {
        let t = Instant::now();
        let params = &self.config.depth_fusion;
        let (touched, stats) = match &self.gpu {
            Some(gpu) => {
                if self.resident.is_none() {
                    self.resident = Some(ResidentMap::new(
                        gpu.clone(),
                        self.config.grid,
                        self.gpu_options,
                    )?);
                }
                let resident = self.resident.as_mut().expect("just set");
                resident.integrate_depth(&mut self.layer, frame, params)?
            }
            None => integrate_depth(&mut self.layer, frame, params),
        };
        self.record(t, stats);
        Ok(touched)
    }

    /// Fuses a LiDAR scan (on the GPU when one is set, per call); returns the blocks it
    /// touched. Blocks of the scan resident on the GPU are written back first.
    pub fn fuse_lidar(&mut self, scan: &LidarScan) -> crate::Result<TouchedBlocks> {
        let t = Instant::now();
        let plan = LidarPlan::new(&self.config.grid, scan, &self.config.lidar_fusion);
        if let Some(r) = self.resident.as_mut() {
            r.flush_blocks(&mut self.layer, &plan.blocks())?;
        }
        let (touched, stats) = match &self.gpu {
            Some(gpu) => crate::gpu::integrate_lidar_gpu(gpu, &mut self.layer, &plan)?,
            None => integrate_lidar_plan(&mut self.layer, &plan),
        };
        self.record(t, stats);
        Ok(touched)
    }

    /// Regularises the whole map (one global solve), on the GPU when one is set. A map too large
    /// for one GPU binding is solved on the GPU in regions of 32³ blocks with the exact halo (the
    /// same result), or, when a region does not fit either, on the CPU; each with a message.
    pub fn regularize(&mut self) -> crate::Result<RegularizeStats> {
        self.sync_gpu()?;
        let t = Instant::now();
        let gpu_result = match &self.gpu {
            Some(gpu) => self.regularize_gpu(gpu.clone())?,
            None => None,
        };
        let (_, stats) = match gpu_result {
            Some(r) => r,
            None => regularize_layer(&mut self.layer, &self.config.tv)?,
        };
        self.timings.regularize_s += t.elapsed().as_secs_f64();
        self.timings.voxel_iterations += stats.omega_voxels as u64 * stats.iterations as u64;
        Ok(stats)
    }

    /// The GPU part of [`Reconstructor::regularize`]: `None` when the map does not fit.
    fn regularize_gpu(
        &mut self,
        gpu: Arc<GpuContext>,
    ) -> crate::Result<Option<(TouchedBlocks, RegularizeStats)>> {
        let tv = self.config.tv;
        let e = match crate::gpu::regularize_layer_gpu(&gpu, &mut self.layer, &tv) {
            Err(e @ crate::Error::GpuCapacity { .. }) => e,
            other => return other.map(Some),
        };
        let plan = RegionPlan::exact(32, tv.iterations);
        eprintln!("regularisation: {e}; solving on the GPU in regions of 32³ blocks");
        let blocks = self.layer.indices_sorted();
        let mut problem = TvProblem::gather(&self.layer, &blocks);
        let energy_before = problem.energy(tv.lambda);
        match crate::gpu::regularize_regions_gpu(&gpu, &mut self.layer, &tv, &plan) {
            Ok(_) => {}
            Err(e @ crate::Error::GpuCapacity { .. }) => {
                eprintln!("regularisation: {e}; solving on the CPU instead");
                return Ok(None);
            }
            Err(e) => return Err(e),
        }
        // The energy of the stored result (quantised u), as the global path reports it.
        let (u, _, _) = problem.state_mut();
        for (k, index) in blocks.iter().enumerate() {
            if let Some(block) = self.layer.get(index) {
                for i in 0..VOXELS_PER_BLOCK {
                    u[k * VOXELS_PER_BLOCK + i] = block.regularized_or_raw(i);
                }
            }
        }
        let stats = RegularizeStats {
            blocks: blocks.len(),
            omega_voxels: problem.omega_count(),
            iterations: tv.iterations,
            energy_before,
            energy_after: problem.energy(tv.lambda),
        };
        Ok(Some((blocks, stats)))
    }

    /// Marching cubes over the whole map.
    pub fn mesh(&mut self, field: Field) -> Mesh {
        let t = Instant::now();
        let mesh = extract_mesh(&self.layer, field, None);
        self.timings.mesh_s += t.elapsed().as_secs_f64();
        mesh
    }
}
