//! The device a run computes on, chosen once (from `--device`), and every stage's implementation
//! on it: a [`Backend`] owns depth and LiDAR fusion, the GPU tier's write-back (the
//! [`UpperTier`] a store calls before blocks leave RAM), the TV solver with its fallbacks, and the
//! stereo matcher. Every command takes its stages from one backend, so no stage can silently run
//! elsewhere than the user asked.
//!
//! On a GPU:
//! - depth frames are fused into blocks resident on the device between frames ([`ResidentMap`],
//!   created at the first depth frame);
//! - LiDAR scans into the same resident blocks;
//! - TV: on the resident blocks where the store holds the whole map, else the whole map in one
//!   solve when it fits one storage binding, else regions with the exact halo on the GPU, and a
//!   region too large even for that on the CPU (each counted in [`TvDevices`], and named in the
//!   summary);
//! - stereo: SGM and the variational matchers (`stages`: which stages `--device auto` places
//!   there).
//!
//! Errors are never swallowed: a failed write-back is an error of the call that needed it.

use crate::depth::tgv::HoleFill;
use crate::depth::SgmParams;
use crate::depth::{DisparityEstimator, SgmMatcher, SgmMatcherGpu, StereoMethod, TgvMatcherGpu};
use crate::frame::DepthFrame;
use crate::fusion::{
    integrate_depth_plan, integrate_depth_resident, integrate_device_depth_resident,
    DepthFusionParams, DepthPlan, DeviceDepthFrame, DeviceDepthKept, FusionStats, LidarListings,
};
use crate::gpu::kept::Kept;
use crate::gpu::{
    DeviceChoice, GpuContext, GpuTraffic, ResidentMap, ResidentOptions, ResidentStats, StageTally,
};
use crate::grid::{BlockIndex, GridParams, Layer, TouchedBlocks};
use crate::mesh::{extract_mesh, Field, GpuMesher, Mesh, SampleSource};
use crate::regularize::{
    regularize_resident, solve_gpu_kept, CpuSolver, RegularizeStats, TvParams, TvProblem, TvSolver,
};
use crate::store::UpperTier;
use crate::{Error, Result};
use std::sync::Arc;

mod lidar;
mod stages;
pub use stages::{AdapterClass, GpuStages, Stage, StageRecord, RECORDED_FASTER};

/// How many TV solves (global or per region) ran on each device.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct TvDevices {
    /// Solves on the GPU.
    pub gpu: usize,
    /// Solves on the CPU (all of them on a CPU backend; on a GPU backend, problems too large
    /// for one storage binding).
    pub cpu: usize,
}

/// What a run's stages cost the GPU ([`GpuTraffic`] per stage, with the number of calls to
/// divide by): the figures the run summary and `report.json` give per frame, scan and solve.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct StageTraffic {
    /// Depth frames fused on the GPU.
    pub depth_frames: u64,
    /// Their traffic (residency, lookup, fusion, flags).
    pub depth: GpuTraffic,
    /// LiDAR scans fused on the GPU.
    pub lidar_scans: u64,
    /// Their traffic (resident blocks written back first included).
    pub lidar: GpuTraffic,
    /// TV solves on the GPU (global or per region).
    pub tv_solves: u64,
    /// Their traffic.
    pub tv: GpuTraffic,
    /// Write-backs of resident blocks to RAM before the CPU or the pager reads them.
    pub write_backs: u64,
    /// Their traffic.
    pub write_back: GpuTraffic,
    /// Stereo pairs matched on the GPU.
    pub stereo_pairs: u64,
    /// Their traffic (census, costs, SGM and, for the variational methods, the refinement).
    pub stereo: GpuTraffic,
    /// Meshes extracted on the GPU.
    pub meshes: u64,
    /// Their traffic.
    pub mesh: GpuTraffic,
    /// Everything the context did, the stages above, stereo and set-up included.
    pub total: GpuTraffic,
}

/// The device of a run and the state its stages keep on it (see the module documentation).
pub struct Backend {
    gpu: Option<Arc<GpuContext>>,
    stages: GpuStages,
    resident: Option<ResidentMap>,
    resident_options: ResidentOptions,
    /// Whether depth frames may return before their results arrive (a map held whole in RAM).
    frames_in_flight: bool,
    tv: TvDevices,
    traffic: StageTraffic,
    /// The traffic of the stereo matchers made by [`Backend::stereo_matcher`].
    stereo_tally: StageTally,
    /// The TV solves' buffers, kept from region to region ([`Backend::release_tv_buffers`]).
    tv_kept: Kept,
    /// The GPU mesher, its buffers kept from mesh to mesh (made at the first mesh).
    mesher: Option<GpuMesher>,
    /// What listing LiDAR scans on the GPU keeps between scans ([`Backend::plan_lidar`]).
    lidar_listings: LidarListings,
    /// What listing host depth frames on the GPU keeps between frames
    /// ([`Backend::depth_to_device`]).
    host_depths: DeviceDepthKept,
}

/// The GPU traffic of `work` added to `into` (nothing without a GPU).
fn counted<T>(
    ctx: Option<&Arc<GpuContext>>,
    into: &mut GpuTraffic,
    calls: &mut u64,
    work: impl FnOnce() -> T,
) -> T {
    let Some(ctx) = ctx else { return work() };
    *calls += 1;
    added(ctx, into, work)
}

/// The GPU traffic of `work` added to `into`, as part of calls counted elsewhere (a depth
/// frame's upload and band, counted with its fusion).
fn added<T>(ctx: &GpuContext, into: &mut GpuTraffic, work: impl FnOnce() -> T) -> T {
    let before = ctx.traffic();
    let out = work();
    *into = into.plus(ctx.traffic().since(before));
    out
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
            stages: GpuStages::ALL,
            resident_options: ResidentOptions::default(),
            frames_in_flight: false,
            tv: TvDevices::default(),
            traffic: StageTraffic::default(),
            stereo_tally: StageTally::default(),
            tv_kept: Kept::default(),
            mesher: None,
            lidar_listings: LidarListings::default(),
            host_depths: DeviceDepthKept::default(),
        }
    }

    /// Every stage that has a kernel on `ctx`; fusion's blocks stay resident within `options`.
    pub fn gpu(ctx: Arc<GpuContext>, options: ResidentOptions) -> Self {
        Backend::gpu_for(ctx, options, GpuStages::ALL)
    }

    /// The stages `stages` names on `ctx`, the others on the CPU.
    pub fn gpu_for(ctx: Arc<GpuContext>, options: ResidentOptions, stages: GpuStages) -> Self {
        Backend {
            gpu: Some(ctx),
            stages,
            resident_options: options,
            ..Backend::cpu()
        }
    }

    /// The backend `choice` asks for ([`DeviceChoice::open`]): with `Auto` on a hardware GPU,
    /// the stages measured faster there ([`GpuStages::MEASURED_FASTER`]); with `Gpu`, every
    /// stage that has a kernel.
    /// The kernels of its GPU stages are compiled before it is returned, together
    /// ([`GpuContext::kernel_compilation`] says how long that took), so that no stage's time
    /// holds a compilation.
    pub fn open(choice: DeviceChoice, options: ResidentOptions) -> Result<Self> {
        let backend = Backend::open_uncompiled(choice, options)?;
        if let Some(ctx) = &backend.gpu {
            let mut kernels = backend.stages.kernels();
            // The band's blocks are listed on the device (stereo pairs, host depth frames)
            // where it has f64.
            if ctx.has_f64() && (backend.stages.fusion || backend.stages.stereo) {
                kernels.extend(crate::gpu::shaders::WITH_F64);
            }
            // A kernel two stages use (the band's slices) compiled once.
            kernels.sort_by_key(|k| k.file);
            kernels.dedup_by_key(|k| k.file);
            ctx.compile_kernels(&kernels)?;
        }
        Ok(backend)
    }

    fn open_uncompiled(choice: DeviceChoice, options: ResidentOptions) -> Result<Self> {
        Ok(match (choice, choice.open()?) {
            (_, None) => Backend::cpu(),
            (DeviceChoice::Auto, Some(ctx)) => {
                let class = AdapterClass::of(ctx.is_software());
                let stages = GpuStages::auto_rule(class, RECORDED_FASTER);
                if stages.any() {
                    tracing::info!(
                        "device: GPU ({}) for {} (recorded faster there), the CPU for the \
                         others (--device gpu puts every stage on the GPU)",
                        ctx.describe(),
                        stages.describe()
                    );
                    Backend::gpu_for(Arc::new(ctx), options, stages)
                } else {
                    // The summary names each stage's device: the probe's answer is a detail.
                    tracing::debug!(
                        "device: {} ({class:?} adapter): no stage is recorded faster on one than \
                         on the CPU, running on the CPU (--device gpu uses it anyway)",
                        ctx.describe()
                    );
                    Backend::cpu()
                }
            }
            (_, Some(ctx)) => Backend::gpu_for(Arc::new(ctx), options, GpuStages::ALL),
        })
    }

    /// The GPU, for a stage placed there.
    fn gpu_if(&self, on_gpu: bool) -> Option<&Arc<GpuContext>> {
        self.gpu.as_ref().filter(|_| on_gpu)
    }

    /// Whether a GPU matcher's depths can stay on the device for the fusion: stereo and depth
    /// fusion both run on this backend's GPU.
    pub fn keeps_depth_on_device(&self) -> bool {
        self.gpu.is_some() && self.stages.stereo && self.stages.fusion
    }

    /// The device in words, for summaries: "CPU" or the adapter, e.g. "llvmpipe (LLVM 15.0.6,
    /// 256 bits) (Vulkan)".
    pub fn device_name(&self) -> String {
        match &self.gpu {
            Some(ctx) => ctx.name(),
            None => "CPU".to_string(),
        }
    }

    /// Where fusion runs, in words ("CPU" or the adapter).
    pub fn fusion_device_name(&self) -> String {
        match self.gpu_if(self.stages.fusion) {
            Some(ctx) => ctx.name(),
            None => "CPU".to_string(),
        }
    }

    /// The GPU, if the backend has one.
    pub fn gpu_context(&self) -> Option<&Arc<GpuContext>> {
        self.gpu.as_ref()
    }

    /// The GPU meshing runs on, if it runs on one.
    pub fn mesh_context(&self) -> Option<&Arc<GpuContext>> {
        self.gpu_if(self.stages.mesh)
    }

    /// Counters of the GPU-resident blocks, once a depth frame was fused on a GPU.
    pub fn resident_stats(&self) -> Option<ResidentStats> {
        self.resident.as_ref().map(|r| r.stats())
    }

    /// What the stages of this run cost the GPU so far (`None` on the CPU).
    pub fn gpu_traffic(&self) -> Option<StageTraffic> {
        let (stereo_pairs, stereo) = self.stereo_tally.get();
        self.gpu.as_ref().map(|ctx| StageTraffic {
            total: ctx.traffic(),
            stereo_pairs,
            stereo,
            ..self.traffic
        })
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
        let Some(ctx) = self.gpu.clone().filter(|_| self.stages.fusion) else {
            return Ok(integrate_depth_plan(layer, frame, params, plan));
        };
        let options = (self.resident_options, self.frames_in_flight);
        let resident = Self::resident_map(&mut self.resident, options, &ctx, layer)?;
        let t = &mut self.traffic;
        counted(Some(&ctx), &mut t.depth, &mut t.depth_frames, || {
            integrate_depth_resident(resident, layer, frame, params, plan)
        })
    }

    /// [`Backend::fuse_depth`] for a frame whose depths are on the GPU: fused where they are
    /// when this backend fuses on that GPU, else read back (counted) and fused as a host frame.
    /// The work `next` holds unsubmitted (the following frame's listing,
    /// [`DeviceDepthFrame::from_depths`]) rides in this frame's submit on that GPU: one submit
    /// a frame.
    pub fn fuse_device_depth(
        &mut self,
        layer: &mut Layer,
        (frame, next): (&DeviceDepthFrame, Option<&DeviceDepthFrame>),
        params: &DepthFusionParams,
        plan: &DepthPlan,
    ) -> Result<(TouchedBlocks, FusionStats)> {
        let same_device = |ctx: &Arc<GpuContext>| Arc::ptr_eq(ctx, frame.context());
        let gpu = self
            .gpu
            .clone()
            .filter(|c| self.stages.fusion && same_device(c));
        let Some(ctx) = gpu else {
            let host = frame.read_back(frame.context())?;
            return self.fuse_depth(layer, &host, params, plan);
        };
        let options = (self.resident_options, self.frames_in_flight);
        let resident = Self::resident_map(&mut self.resident, options, &ctx, layer)?;
        let next = next.filter(|n| Arc::ptr_eq(n.context(), &ctx));
        let riding = next.and_then(DeviceDepthFrame::take_unsubmitted);
        let (riding, arm) = riding.map(|held| held.into_parts()).unzip();
        let t = &mut self.traffic;
        let fused = counted(Some(&ctx), &mut t.depth, &mut t.depth_frames, || {
            integrate_device_depth_resident(resident, layer, frame, params, (plan, riding))
        })?;
        if let Some(arm) = arm {
            arm.submitted();
        }
        Ok(fused)
    }

    /// Collects the band of `frame` ([`DeviceDepthFrame::collect_band`]): its readback,
    /// submitted with the stereo pair, counts as the pair's traffic, or with the depth frame's
    /// upload ([`Backend::depth_to_device`]) as the frame's.
    pub fn collect_device_band(&mut self, frame: &DeviceDepthFrame) -> Result<()> {
        if frame.matched() {
            return (self.stereo_tally).add(frame.context(), || frame.collect_band());
        }
        added(frame.context(), &mut self.traffic.depth, || {
            frame.collect_band()
        })
    }

    /// A depth frame from the host sent to the GPU that fuses it, where frames are in flight
    /// there ([`DeviceDepthFrame::from_depths`]): its depths go up once, its band is listed on
    /// the device and comes back late, and the frame is fused from there as a matched pair is,
    /// so the host walks none of its pixels. The frame back, untouched, where this backend
    /// fuses on the CPU, waits for each frame, or the device cannot list its band. The upload
    /// and listing count as the frame's depth traffic.
    pub fn depth_to_device(
        &mut self,
        frame: DepthFrame,
        (grid, params): (&GridParams, &DepthFusionParams),
    ) -> Result<std::result::Result<DeviceDepthFrame, DepthFrame>> {
        let gpu = self.gpu.clone().filter(|_| self.frames_in_flight);
        let ctx = match gpu.filter(|_| self.stages.fusion) {
            Some(ctx) if DeviceDepthFrame::can_list(&frame, grid, params) => ctx,
            _ => return Ok(Err(frame)),
        };
        let kept = &mut self.host_depths;
        added(&ctx, &mut self.traffic.depth, || {
            DeviceDepthFrame::from_depths(&ctx, (grid, params), frame, kept).map(Ok)
        })
    }

    /// Submits the work a frame on the device still holds (no fusion's submit took it),
    /// counted as the pair's where a matcher made it, else as the frame's.
    pub fn submit_device_depth(&mut self, frame: &DeviceDepthFrame) {
        if frame.matched() {
            return (self.stereo_tally).add(frame.context(), || frame.submit_now());
        }
        added(frame.context(), &mut self.traffic.depth, || {
            frame.submit_now()
        })
    }

    /// Whether `frame` is fused in flight ([`crate::reconstruct::Reconstructor::fuse_input`]):
    /// frames in flight, on the GPU its depths are on.
    pub(crate) fn fuses_depth_in_flight(&self, frame: &DeviceDepthFrame) -> bool {
        let same = |ctx: &Arc<GpuContext>| Arc::ptr_eq(ctx, frame.context());
        self.frames_in_flight && self.stages.fusion && self.gpu.as_ref().is_some_and(same)
    }

    /// The GPU-resident blocks over `layer` in `resident`, opened on `ctx` with `options` by
    /// the first frame or scan fused there (with frames in flight when `in_flight`).
    fn resident_map<'a>(
        resident: &'a mut Option<ResidentMap>,
        (options, in_flight): (ResidentOptions, bool),
        ctx: &Arc<GpuContext>,
        layer: &Layer,
    ) -> Result<&'a mut ResidentMap> {
        if resident.is_none() {
            let mut map = ResidentMap::new(ctx.clone(), layer.params(), options)?;
            map.set_frames_in_flight(in_flight);
            *resident = Some(map);
        }
        Ok(resident.as_mut().expect("just opened"))
    }

    /// Lets GPU depth frames return before their results arrive, collected by later frames, the
    /// next sync or [`UpperTier::settle`] (`src/gpu/resident/late.rs`). Off by default: each
    /// frame waits for its own.
    pub fn set_frames_in_flight(&mut self, enabled: bool) {
        self.frames_in_flight = enabled;
        if let Some(r) = self.resident.as_mut() {
            r.set_frames_in_flight(enabled);
        }
    }

    /// The voxel updates of depth frames collected outside a fusion call (by a sync), since
    /// the last call: a frame in flight reports its updates when collected.
    pub fn take_late_voxel_updates(&mut self) -> usize {
        self.resident.as_mut().map_or(0, |r| r.take_collected().1)
    }

    /// Gives back the buffers the TV solves kept from region to region (sized for the largest
    /// region): after a regularization.
    pub fn release_tv_buffers(&mut self) {
        self.tv_kept = Kept::default();
    }

    /// Writes every GPU-resident block back and releases them all (the GPU holds nothing
    /// after this).
    pub fn flush_all(&mut self, layer: &mut Layer) -> Result<usize> {
        self.write_back(|r| r.flush_all(layer))
    }

    /// Runs `work` on the GPU-resident blocks, if any, its traffic counted as a write-back.
    fn write_back<T: Default>(
        &mut self,
        work: impl FnOnce(&mut ResidentMap) -> Result<T>,
    ) -> Result<T> {
        let Some(r) = self.resident.as_mut() else {
            return Ok(T::default());
        };
        let t = &mut self.traffic;
        counted(
            self.gpu.as_ref(),
            &mut t.write_back,
            &mut t.write_backs,
            || work(r),
        )
    }

    /// [`Backend::write_back`], counted only where `busy` says the tier has work in flight.
    fn write_back_if<T: Default>(
        &mut self,
        busy: impl FnOnce(&ResidentMap) -> bool,
        work: impl FnOnce(&mut ResidentMap) -> Result<T>,
    ) -> Result<T> {
        match &mut self.resident {
            Some(r) if !busy(r) => work(r),
            _ => self.write_back(work),
        }
    }

    /// A matcher for `method` with `fill` hole filling, on the GPU when the backend runs stereo
    /// there (SGM: its cost volume and path aggregation; the variational methods: all but
    /// SGM's selection and the invalidation). `sgm`: the SGM parameters (SGM's, and those of
    /// the variational methods' initialisation), the disparity range included.
    pub fn stereo_matcher(
        &self,
        method: StereoMethod,
        sgm: SgmParams,
        fill: HoleFill,
    ) -> Result<Box<dyn DisparityEstimator>> {
        match (
            method.tgv_matcher(sgm, fill)?,
            self.gpu_if(self.stages.stereo),
        ) {
            (Some(m), Some(ctx)) => Ok(Box::new(
                TgvMatcherGpu::new(ctx.clone(), m).counting_into(self.stereo_tally.clone()),
            )),
            (Some(m), None) => Ok(Box::new(m)),
            (None, Some(ctx)) => Ok(Box::new(
                SgmMatcherGpu::new(ctx.clone(), SgmMatcher::new(sgm)?)
                    .counting_into(self.stereo_tally.clone()),
            )),
            (None, None) => method.estimator_with_fill(sgm, fill),
        }
    }

    /// The device the stereo methods run on with this backend (every method: see
    /// [`Backend::stereo_matcher`]).
    pub fn stereo_device(&self) -> String {
        if let Some(ctx) = self.gpu_if(self.stages.stereo) {
            ctx.name()
        } else {
            "CPU".to_string()
        }
    }
}

impl UpperTier for Backend {
    fn release(&mut self, layer: &mut Layer, blocks: &[BlockIndex]) -> Result<()> {
        self.write_back(|r| r.flush_blocks(layer, blocks).map(|_| ()))
    }

    /// The copies of the GPU's dirty blocks come back through a ring of staging buffers
    /// ([`ResidentMap::release_blocks_later`]).
    fn release_later(
        &mut self,
        layer: &mut Layer,
        held: &mut Layer,
        blocks: &[BlockIndex],
    ) -> Result<bool> {
        self.write_back(|r| r.release_blocks_later(layer, held, blocks))
    }

    /// Counted as a write-back where releases are in flight.
    fn collect_released(&mut self, held: &mut Layer, wait: bool) -> Result<usize> {
        let busy = |r: &ResidentMap| r.releases_in_flight() > 0;
        self.write_back_if(busy, |r| r.collect_released(held, wait))
    }

    fn sync(&mut self, layer: &mut Layer) -> Result<()> {
        self.write_back(|r| r.sync(layer).map(|_| ()))
    }

    /// Collects the GPU's frames in flight (counted as a write-back, where frames are in
    /// flight: their flags come back).
    fn settle(&mut self, layer: &mut Layer, keep_newest: bool) -> Result<Vec<BlockIndex>> {
        let busy = |r: &ResidentMap| r.frames_in_flight() > 0;
        self.write_back_if(busy, |r| r.settle(layer, keep_newest))
    }

    /// On the GPU when meshing is placed there (the CPU mesher's twin), else on the CPU.
    fn mesh(&mut self, layer: &Layer, field: Field) -> Result<Mesh> {
        let Some(ctx) = self.gpu_if(self.stages.mesh).cloned() else {
            return Ok(extract_mesh(layer, field, None));
        };
        // Where fusion left the blocks on the GPU (synced with the layer by the store before it
        // meshes), their samples are made there.
        let source = self
            .resident
            .as_ref()
            .map_or(SampleSource::Layer, SampleSource::Resident);
        let mesher = (self.mesher).get_or_insert_with(|| GpuMesher::new(ctx.clone()));
        let t = &mut self.traffic;
        counted(Some(&ctx), &mut t.mesh, &mut t.meshes, || {
            mesher
                .mesh(layer, field, None, source)
                .map(|(mesh, _)| mesh)
        })
    }
}

impl TvSolver for Backend {
    /// On the GPU when the problem fits one storage binding, else (or on a CPU backend) on the
    /// CPU; counted in [`Backend::tv_devices`].
    fn solve(&mut self, problem: &mut TvProblem, params: &TvParams) -> Result<()> {
        if let Some(ctx) = self.gpu.as_ref().filter(|_| self.stages.tv) {
            let t = &mut self.traffic;
            let solved = counted(Some(ctx), &mut t.tv, &mut t.tv_solves, || {
                solve_gpu_kept(ctx, &mut self.tv_kept, problem, params)
            });
            match solved {
                Ok(()) => {
                    self.tv.gpu += 1;
                    return Ok(());
                }
                Err(e @ Error::GpuCapacity { .. }) => {
                    // Refused before any work: not a GPU solve.
                    self.traffic.tv_solves -= 1;
                    tracing::warn!("{e}; solving this region on the CPU");
                }
                Err(e) => return Err(e),
            }
        }
        self.tv.cpu += 1;
        CpuSolver.solve(problem, params)
    }

    fn prefers_whole_solves(&self) -> bool {
        self.gpu_if(self.stages.tv).is_some()
    }

    fn max_voxels(&self) -> Option<usize> {
        self.gpu_if(self.stages.tv)
            .map(|ctx| (ctx.max_binding_bytes() / 12) as usize)
    }

    /// Where fusion left the blocks on the GPU (`regularize_resident`), when TV runs there and
    /// they fit; counted in [`Backend::tv_devices`] as one GPU solve.
    fn solve_in_place(
        &mut self,
        layer: &mut Layer,
        params: &TvParams,
    ) -> Result<Option<(TouchedBlocks, RegularizeStats)>> {
        let (Some(ctx), Some(map)) = (self.gpu_if(self.stages.tv).cloned(), &mut self.resident)
        else {
            return Ok(None);
        };
        let t = &mut self.traffic;
        let done = counted(Some(&ctx), &mut t.tv, &mut t.tv_solves, || {
            regularize_resident(map, layer, params)
        })?;
        if done.is_some() {
            self.tv.gpu += 1;
        } else {
            self.traffic.tv_solves -= 1;
        }
        Ok(done)
    }
}

#[cfg(test)]
mod tests;
