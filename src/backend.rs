//! The device a run computes on, chosen once (from `--device`), and every stage's implementation
//! on it: a [`Backend`] owns depth and LiDAR fusion, the GPU tier's write-back (the
//! [`UpperTier`] a store calls before blocks leave RAM), the TV solver with its fallbacks, and the
//! stereo matcher. Every command takes its stages from one backend, so no stage can silently run
//! elsewhere than the user asked.
//!
//! On a GPU:
//! - depth frames are fused into blocks resident on the device between frames ([`ResidentMap`],
//!   created at the first depth frame);
//! - LiDAR scans by the per-call LiDAR kernel, after their resident blocks are written back;
//! - TV: the whole map in one solve when it fits one storage binding, else regions with the
//!   exact halo on the GPU, and a region too large even for that on the CPU (each counted in
//!   [`TvDevices`], and named in the summary);
//! - stereo: census cost, point-wise search and TGV iterations (SGM stays on the CPU).
//!
//! Errors are never swallowed: a failed write-back is an error of the call that needed it.

use crate::depth::tgv::HoleFill;
use crate::depth::SgmParams;
use crate::depth::{DisparityEstimator, StereoMethod, TgvMatcherGpu};
use crate::frame::DepthFrame;
use crate::fusion::{
    integrate_depth_plan, integrate_depth_resident, integrate_lidar_gpu, integrate_lidar_plan,
    DepthFusionParams, DepthPlan, FusionStats, LidarPlan,
};
use crate::gpu::{DeviceChoice, GpuContext, ResidentMap, ResidentOptions, ResidentStats};
use crate::grid::{BlockIndex, Layer, TouchedBlocks};
use crate::regularize::{solve_gpu, CpuSolver, TvParams, TvProblem, TvSolver};
use crate::store::UpperTier;
use crate::{Error, Result};
use std::sync::Arc;

/// How many TV solves (global or per region) ran on each device.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct TvDevices {
    /// Solves on the GPU.
    pub gpu: usize,
    /// Solves on the CPU (all of them on a CPU backend; on a GPU backend, problems too large
    /// for one storage binding).
    pub cpu: usize,
}

/// The device of a run and the state its stages keep on it (see the module documentation).
pub struct Backend {
    gpu: Option<Arc<GpuContext>>,
    resident: Option<ResidentMap>,
    resident_options: ResidentOptions,
    tv: TvDevices,
}

impl std::fmt::Debug for Backend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Backend")
            .field("device", &self.device_name())
            .field("resident", &self.resident_stats())
            .field("tv", &self.tv)
            .finish()
    }
}

impl Backend {
    /// Every stage on the CPU.
    pub fn cpu() -> Self {
        Backend {
            gpu: None,
            resident: None,
            resident_options: ResidentOptions::default(),
            tv: TvDevices::default(),
        }
    }

    /// Every stage that has a kernel on `ctx`; depth blocks stay resident within `options`.
    pub fn gpu(ctx: Arc<GpuContext>, options: ResidentOptions) -> Self {
        Backend {
            gpu: Some(ctx),
            resident_options: options,
            ..Backend::cpu()
        }
    }

    /// The backend `choice` asks for ([`DeviceChoice::open`]).
    pub fn open(choice: DeviceChoice, options: ResidentOptions) -> Result<Self> {
        Ok(match choice.open()? {
            Some(ctx) => Backend::gpu(Arc::new(ctx), options),
            None => Backend::cpu(),
        })
    }

    /// The device in words, for summaries: "CPU" or the adapter, e.g. "llvmpipe (LLVM 15.0.6,
    /// 256 bits) (Vulkan)".
    pub fn device_name(&self) -> String {
        match &self.gpu {
            Some(ctx) => ctx.name(),
            None => "CPU".to_string(),
        }
    }

    /// The GPU, if the backend has one.
    pub fn gpu_context(&self) -> Option<&Arc<GpuContext>> {
        self.gpu.as_ref()
    }

    /// Counters of the GPU-resident blocks, once a depth frame was fused on a GPU.
    pub fn resident_stats(&self) -> Option<ResidentStats> {
        self.resident.as_ref().map(|r| r.stats())
    }

    /// Where the TV solves of this run went.
    pub fn tv_devices(&self) -> TvDevices {
        self.tv
    }

    /// Fuses one depth frame planned by `plan` into `layer` (resident on a GPU: call
    /// [`UpperTier::sync`] before reading the layer whole).
    pub fn fuse_depth(
        &mut self,
        layer: &mut Layer,
        frame: &DepthFrame,
        params: &DepthFusionParams,
        plan: &DepthPlan,
    ) -> Result<(TouchedBlocks, FusionStats)> {
        let Some(ctx) = &self.gpu else {
            return Ok(integrate_depth_plan(layer, frame, params, plan));
        };
        if self.resident.is_none() {
            self.resident = Some(ResidentMap::new(
                ctx.clone(),
                layer.params(),
                self.resident_options,
            )?);
        }
        let resident = self.resident.as_mut().expect("just created");
        integrate_depth_resident(resident, layer, frame, params, plan)
    }

    /// Fuses one LiDAR scan planned by `plan` into `layer`; blocks of the scan resident on the
    /// GPU are written back first.
    pub fn fuse_lidar(
        &mut self,
        layer: &mut Layer,
        plan: &LidarPlan,
    ) -> Result<(TouchedBlocks, FusionStats)> {
        if let Some(r) = self.resident.as_mut() {
            r.flush_blocks(layer, &plan.blocks())?;
        }
        match &self.gpu {
            Some(ctx) => integrate_lidar_gpu(ctx, layer, plan),
            None => Ok(integrate_lidar_plan(layer, plan)),
        }
    }

    /// Writes every GPU-resident block back and releases them all (the GPU holds nothing
    /// after this).
    pub fn flush_all(&mut self, layer: &mut Layer) -> Result<usize> {
        match self.resident.as_mut() {
            Some(r) => r.flush_all(layer),
            None => Ok(0),
        }
    }

    /// A matcher for `method` with `fill` hole filling: the variational methods run on the GPU
    /// when the backend has one; SGM on the CPU. `sgm`: the SGM parameters (SGM's, and those of
    /// the variational methods' initialisation), the disparity range included.
    pub fn stereo_matcher(
        &self,
        method: StereoMethod,
        sgm: SgmParams,
        fill: HoleFill,
    ) -> Result<Box<dyn DisparityEstimator>> {
        match (method.tgv_matcher(sgm, fill)?, &self.gpu) {
            (Some(m), Some(ctx)) => Ok(Box::new(TgvMatcherGpu::new(ctx.clone(), m))),
            (Some(m), None) => Ok(Box::new(m)),
            (None, _) => method.estimator_with_fill(sgm, fill),
        }
    }

    /// The device each stereo method runs on with this backend.
    pub fn stereo_device(&self, method: StereoMethod) -> String {
        if method.is_variational() {
            self.device_name()
        } else {
            "CPU".to_string()
        }
    }
}

impl UpperTier for Backend {
    fn release(&mut self, layer: &mut Layer, blocks: &[BlockIndex]) -> Result<()> {
        match self.resident.as_mut() {
            Some(r) => r.flush_blocks(layer, blocks).map(|_| ()),
            None => Ok(()),
        }
    }

    fn sync(&mut self, layer: &mut Layer) -> Result<()> {
        match self.resident.as_mut() {
            Some(r) => r.sync(layer).map(|_| ()),
            None => Ok(()),
        }
    }
}

impl TvSolver for Backend {
    /// On the GPU when the problem fits one storage binding, else (or on a CPU backend) on the
    /// CPU; counted in [`Backend::tv_devices`].
    fn solve(&mut self, problem: &mut TvProblem, params: &TvParams) -> Result<()> {
        if let Some(ctx) = &self.gpu {
            match solve_gpu(ctx, problem, params) {
                Ok(()) => {
                    self.tv.gpu += 1;
                    return Ok(());
                }
                Err(e @ Error::GpuCapacity { .. }) => {
                    tracing::warn!("{e}; solving this region on the CPU");
                }
                Err(e) => return Err(e),
            }
        }
        self.tv.cpu += 1;
        CpuSolver.solve(problem, params)
    }

    fn max_voxels(&self) -> Option<usize> {
        self.gpu
            .as_ref()
            .map(|ctx| (ctx.max_binding_bytes() / 12) as usize)
    }
}
