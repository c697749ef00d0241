//! The [`Reconstructor`]: one driver of fusion, regularization and meshing over any
//! [`BlockStore`] (the map in RAM, or a map directory paged around the camera) with the stages
//! of one [`Backend`] (CPU or GPU, chosen once). It keeps per-stage timings and work counters,
//! commits checkpoints every so many frames, and holds no I/O of its own: callers feed it
//! frames (`crate::io::sequence`) and score what it writes (`crate::eval::run`).

use crate::backend::{Backend, TvDevices};
use crate::frame::{DepthFrame, LidarScan};
use crate::fusion::{DepthFusionParams, DepthPlan, FusionStats, LidarFusionParams};
use crate::fusion::{DeviceDepthFrame, PendingLidarPlan};
use crate::gpu::ResidentStats;
use crate::grid::{GridParams, Layer, TouchedBlocks};
use crate::io::sequence::{for_each_input, RangeInput, Sequence};
use crate::mesh::{Field, Mesh};
use crate::regularize::TvParams;
use crate::store::{
    BlockStore, MemoryStore, RegularizeSummary, StoreSummary, SurfaceOutput, UpperTier as _,
};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

/// Everything that parameterises a reconstruction.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReconstructionConfig {
    /// Voxel size and truncation μ.
    pub grid: GridParams,
    /// TV regularizer.
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
    /// Seconds spent producing depth frames or scans (reading files, stereo matching, and
    /// waiting for a pair matched on the GPU when its frame is fused).
    pub input_s: f64,
    /// Seconds spent fusing (planning and updating blocks).
    pub fusion_s: f64,
    /// Seconds the store spent making blocks resident, evicting and committing (0 in RAM).
    pub paging_s: f64,
    /// Frames or scans fused in this run.
    pub frames_fused: usize,
    /// Voxel updates applied by fusion.
    pub voxel_updates: usize,
    /// Seconds spent regularizing.
    pub regularize_s: f64,
    /// Voxel-iterations of the regularizer (Ω voxels × iterations).
    pub voxel_iterations: u64,
    /// Seconds spent in marching cubes and writing surfaces.
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

    /// Regularizer throughput, voxel-iterations per second.
    pub fn voxel_iterations_per_s(&self) -> f64 {
        self.voxel_iterations as f64 / self.regularize_s.max(1e-12)
    }
}

/// What [`Reconstructor::regularize`] did, and where.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct RegularizeOutcome {
    /// The store's counters.
    pub summary: RegularizeSummary,
    /// Solves per device in this run.
    pub devices: TvDevices,
    /// Seconds.
    pub seconds: f64,
}

/// What [`Reconstructor::write_results`] wrote.
#[derive(Clone, Debug)]
pub struct Results {
    /// The raw surface, then the regularized one (when regularized).
    pub surfaces: Vec<SurfaceOutput>,
    /// The regularization, when it ran.
    pub regularize: Option<RegularizeOutcome>,
}

impl Results {
    /// Every file written (meshes, then points).
    pub fn files(&self) -> Vec<std::path::PathBuf> {
        self.surfaces
            .iter()
            .flat_map(|s| std::iter::once(s.mesh_path.clone()).chain(s.points_path.clone()))
            .collect()
    }
}

/// Drives the stages over a store (see the module documentation).
pub struct Reconstructor {
    config: ReconstructionConfig,
    store: Box<dyn BlockStore>,
    backend: Backend,
    timings: StageTimings,
    /// Frames in the map: those committed before this run plus those fused since.
    frames_total: u64,
    /// `frames_total` at the last [`Reconstructor::sync`].
    frames_synced: u64,
    checkpoint_every: u64,
    /// Sensor position of every frame fused in this run, world frame, metres.
    trajectory_m: Vec<[f64; 3]>,
    /// The LiDAR scan whose blocks a GPU is listing, fused by the next call
    /// ([`Reconstructor::fuse_lidar`]).
    pending_lidar: Option<PendingLidarPlan>,
    /// The GPU depth frame whose band is coming back, fused by the next call
    /// ([`Reconstructor::fuse_input`]).
    pending_depth: Option<Box<DeviceDepthFrame>>,
}

impl std::fmt::Debug for Reconstructor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reconstructor")
            .field("config", &self.config)
            .field("store", &self.store.summary())
            .field("backend", &self.backend)
            .field("timings", &self.timings)
            .finish()
    }
}

impl Reconstructor {
    /// A reconstructor over an empty map in RAM, every stage on the CPU.
    pub fn new(config: ReconstructionConfig) -> crate::Result<Self> {
        Self::in_memory(config, Backend::cpu())
    }

    /// A reconstructor over an empty map in RAM with the stages of `backend`.
    pub fn in_memory(config: ReconstructionConfig, backend: Backend) -> crate::Result<Self> {
        Self::with_store(config, Box::new(MemoryStore::new(config.grid)), backend, 0)
    }

    /// A reconstructor over `store` (its grid must be `config.grid`), committing a checkpoint
    /// every `checkpoint_every` frames (0: only when asked). Fusion continues after the frames
    /// the store already holds ([`Reconstructor::frames_committed`]).
    pub fn with_store(
        config: ReconstructionConfig,
        store: Box<dyn BlockStore>,
        backend: Backend,
        checkpoint_every: u64,
    ) -> crate::Result<Self> {
        config.grid.validate()?;
        config.tv.validate()?;
        if store.grid() != config.grid {
            return Err(crate::Error::InvalidArgument(format!(
                "the map's grid {:?} differs from the reconstruction's {:?}",
                store.grid(),
                config.grid
            )));
        }
        let frames_total = store.frames_committed();
        let mut backend = backend;
        // Frames return once submitted; a store that pages settles them before blocks leave
        // RAM and before its checkpoints (`UpperTier::settle`).
        backend.set_frames_in_flight(true);
        Ok(Reconstructor {
            config,
            store,
            backend,
            timings: StageTimings::default(),
            frames_total,
            frames_synced: frames_total,
            checkpoint_every,
            trajectory_m: Vec::new(),
            pending_lidar: None,
            pending_depth: None,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &ReconstructionConfig {
        &self.config
    }

    /// The stages' device.
    pub fn backend(&self) -> &Backend {
        &self.backend
    }

    /// The store.
    pub fn store(&self) -> &dyn BlockStore {
        self.store.as_ref()
    }

    /// Takes the store out (e.g. a paged map to inspect after the run; after
    /// [`Reconstructor::sync`], which fuses a LiDAR scan still being listed).
    pub fn into_store(self) -> Box<dyn BlockStore> {
        self.store
    }

    /// The resident blocks (the whole map in RAM), current after [`Reconstructor::sync`].
    pub fn layer(&self) -> &Layer {
        self.store.layer()
    }

    /// Timings so far.
    pub fn timings(&self) -> &StageTimings {
        &self.timings
    }

    /// Frames the store held when this run began (where a resumed run continues).
    pub fn frames_committed(&self) -> u64 {
        self.store.frames_committed()
    }

    /// The sensor's position at every frame fused in this run, in order, world frame, metres.
    pub fn trajectory_m(&self) -> &[[f64; 3]] {
        &self.trajectory_m
    }

    /// Frames in the map (committed before this run plus fused since).
    pub fn frames_total(&self) -> u64 {
        self.frames_total
    }

    /// Counters of the GPU-resident blocks, when depth frames were fused on a GPU.
    pub fn resident_stats(&self) -> Option<ResidentStats> {
        self.backend.resident_stats()
    }

    /// What the stages cost the GPU so far, per stage (`None` on the CPU).
    pub fn gpu_traffic(&self) -> Option<crate::backend::StageTraffic> {
        self.backend.gpu_traffic()
    }

    /// Totals of the map.
    pub fn summary(&self) -> StoreSummary {
        self.store.summary()
    }

    /// Adds time spent producing input (reading, stereo) to the timings.
    pub fn add_input_time(&mut self, seconds: f64) {
        self.timings.input_s += seconds;
    }

    /// Fuses one input of a sequence.
    pub fn fuse(&mut self, input: &RangeInput) -> crate::Result<TouchedBlocks> {
        match input {
            RangeInput::Depth(f) => self.fuse_depth(f),
            RangeInput::DeviceDepth(f) => self.fuse_device_depth(f),
            RangeInput::Lidar(s) => self.fuse_lidar(s),
        }
    }

    /// [`Reconstructor::fuse`], taking the input: with frames in flight on the GPU that made
    /// a depth frame on the device (see [`Reconstructor::set_frames_in_flight`]), the frame
    /// waits here while its band comes back and the host reads the next input, and is fused
    /// by the next call (or whatever else comes next: another input,
    /// [`Reconstructor::sync`], a mesh), so that no call waits for the band of its own pair;
    /// [`Reconstructor::frames_total`] counts it then. A depth frame from the host goes to
    /// that GPU first where it fuses in flight ([`Backend::depth_to_device`]): its band is
    /// listed there, not by the host.
    pub fn fuse_input(&mut self, input: RangeInput) -> crate::Result<TouchedBlocks> {
        let input = match input {
            RangeInput::Depth(frame) => {
                let t = Instant::now();
                let fusion = (&self.config.grid, &self.config.depth_fusion);
                let sent = self.backend.depth_to_device(frame, fusion)?;
                self.timings.fusion_s += t.elapsed().as_secs_f64();
                match sent {
                    Ok(on_device) => RangeInput::DeviceDepth(Box::new(on_device)),
                    Err(frame) => RangeInput::Depth(frame),
                }
            }
            input => input,
        };
        match input {
            RangeInput::DeviceDepth(frame) if self.backend.fuses_depth_in_flight(&frame) => {
                let mut touched = self.finish_lidar()?;
                if let Some(earlier) = self.pending_depth.take() {
                    // Where the device keeps up (the earlier frame's band is back), the frame's
                    // listing rides in the earlier's fusion submit: one submit a frame. Where it
                    // is behind, the listing goes first, alone, so that the next call waits for
                    // it (if at all) and not for the earlier's fusion too.
                    if !earlier.band_arrived()? {
                        self.backend.submit_device_depth(&frame);
                    }
                    touched.extend(self.fuse_device_depth_now(&earlier, Some(&frame))?);
                }
                self.backend.submit_device_depth(&frame);
                self.pending_depth = Some(frame);
                Ok(touched)
            }
            input => self.fuse(&input),
        }
    }

    /// Fuses the inputs still in flight ([`Reconstructor::fuse_input`],
    /// [`Reconstructor::fuse_lidar`]), in the order they came; returns the blocks they touched.
    fn finish_pending(&mut self) -> crate::Result<TouchedBlocks> {
        // A scan pending came before the frame: fuse_planned fuses it first.
        let mut touched = self.finish_pending_depth()?;
        touched.extend(self.finish_lidar()?);
        Ok(touched)
    }

    /// Fuses `frames` of `seq` in order, after the ones the store already holds (a resumed
    /// map continues where it stopped), then [`Reconstructor::sync`]s.
    pub fn fuse_sequence(&mut self, seq: &dyn Sequence, frames: &[usize]) -> crate::Result<()> {
        let done = self.frames_committed();
        if done > frames.len() as u64 {
            return Err(crate::Error::InvalidArgument(format!(
                "the map has {done} frames committed but the job has only {}",
                frames.len()
            )));
        }
        if done > 0 {
            tracing::info!("resuming after {done} committed frames");
        }
        for_each_input(seq, frames, done as usize, |input, seconds| {
            self.add_input_time(seconds);
            self.fuse_input(input).map(|_| ())
        })?;
        self.sync()
    }

    /// Lets GPU depth frames and LiDAR scans return before the device has run them (on by
    /// default): a frame's touched blocks then come back with a later call, and the layer
    /// learns its blocks at the latest with [`Reconstructor::sync`] (a paged map's store
    /// settles the frames before it evicts or checkpoints). Off, each call waits for its own
    /// frame and returns what it touched.
    pub fn set_frames_in_flight(&mut self, enabled: bool) -> crate::Result<()> {
        if !enabled {
            self.sync()?;
        }
        self.backend.set_frames_in_flight(enabled);
        Ok(())
    }

    /// Fuses a depth frame; returns the blocks it touched (with frames in flight on a GPU, see
    /// [`Reconstructor::set_frames_in_flight`], those of the frames whose results arrived).
    pub fn fuse_depth(&mut self, frame: &DepthFrame) -> crate::Result<TouchedBlocks> {
        let mut touched = self.finish_pending_depth()?;
        touched.extend(self.fuse_planned(
            |grid, params| Ok(DepthPlan::new(grid, frame, params)),
            |backend, layer, params, plan| backend.fuse_depth(layer, frame, params, plan),
        )?);
        Ok(touched)
    }

    /// Fuses the depth frame in flight, if any ([`Reconstructor::fuse_input`]).
    fn finish_pending_depth(&mut self) -> crate::Result<TouchedBlocks> {
        match self.pending_depth.take() {
            Some(frame) => self.fuse_device_depth_now(&frame, None),
            None => Ok(Vec::new()),
        }
    }

    /// Fuses a depth frame whose depths are on the GPU ([`DeviceDepthFrame`]), planned from its
    /// band slices: where the backend fuses on that GPU, from the depths where they are (only
    /// the colour goes up), else from the depths read back. The same map as
    /// [`Reconstructor::fuse_depth`] with the frame's depths.
    pub fn fuse_device_depth(&mut self, frame: &DeviceDepthFrame) -> crate::Result<TouchedBlocks> {
        let mut touched = self.finish_pending_depth()?;
        touched.extend(self.fuse_device_depth_now(frame, None)?);
        Ok(touched)
    }

    /// [`Reconstructor::fuse_device_depth`] of `frame` alone; the work `next` holds unsubmitted
    /// rides in its submit ([`Backend::fuse_device_depth`]).
    fn fuse_device_depth_now(
        &mut self,
        frame: &DeviceDepthFrame,
        next: Option<&DeviceDepthFrame>,
    ) -> crate::Result<TouchedBlocks> {
        // Waiting for a pair's band is waiting for its matching (input time); for a host
        // frame's, for its listing (fusion time).
        let t = Instant::now();
        self.backend.collect_device_band(frame)?;
        let waited_s = t.elapsed().as_secs_f64();
        match frame.matched() {
            true => self.timings.input_s += waited_s,
            false => self.timings.fusion_s += waited_s,
        }
        self.fuse_planned(
            |grid, params| frame.plan(grid, params),
            |backend, layer, params, plan| {
                backend.fuse_device_depth(layer, (frame, next), params, plan)
            },
        )
    }

    /// A depth frame's fusion: `plan` it, make its blocks resident, `fuse` it, record it.
    fn fuse_planned(
        &mut self,
        plan: impl FnOnce(&GridParams, &DepthFusionParams) -> crate::Result<DepthPlan>,
        fuse: impl FnOnce(
            &mut Backend,
            &mut Layer,
            &DepthFusionParams,
            &DepthPlan,
        ) -> crate::Result<(TouchedBlocks, FusionStats)>,
    ) -> crate::Result<TouchedBlocks> {
        let mut touched = self.finish_lidar()?;
        let t = Instant::now();
        let plan = plan(&self.config.grid, &self.config.depth_fusion)?;
        let planned_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        self.store.prepare_depth(&plan, &mut self.backend)?;
        self.timings.paging_s += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let layer = self.store.layer_mut();
        let (frame, stats) = fuse(&mut self.backend, layer, &self.config.depth_fusion, &plan)?;
        self.timings.fusion_s += planned_s + t.elapsed().as_secs_f64();
        self.after_frame(plan.camera_m, &frame, stats)?;
        touched.extend(frame);
        Ok(touched)
    }

    /// Fuses a LiDAR scan; returns the blocks it touched (as [`Reconstructor::fuse_depth`]).
    /// With frames in flight on a GPU ([`Reconstructor::set_frames_in_flight`]) the scan's
    /// blocks are listed on the device while the host goes on, and the scan is fused by the next
    /// call (or whatever else comes next: a depth frame, [`Reconstructor::sync`], a mesh), so
    /// that no call waits for its own listing; [`Reconstructor::frames_total`] counts it then.
    pub fn fuse_lidar(&mut self, scan: &LidarScan) -> crate::Result<TouchedBlocks> {
        self.backend.compile_lidar_kernels()?;
        let mut touched = self.finish_pending_depth()?;
        if !self.backend.lists_lidar_in_flight() {
            let t = Instant::now();
            let pending = self.begin_lidar(scan)?;
            touched.extend(self.fuse_lidar_plan(pending, None, t.elapsed().as_secs_f64())?);
            return Ok(touched);
        }
        match self.pending_lidar.take() {
            Some(earlier) => touched.extend(self.fuse_lidar_plan(earlier, Some(scan), 0.0)?),
            None => {
                let t = Instant::now();
                self.pending_lidar = Some(self.begin_lidar(scan)?);
                self.timings.fusion_s += t.elapsed().as_secs_f64();
            }
        }
        Ok(touched)
    }

    /// Fuses the LiDAR scan whose blocks are being listed, if any (see
    /// [`Reconstructor::fuse_lidar`]); returns the blocks it touched.
    fn finish_lidar(&mut self) -> crate::Result<TouchedBlocks> {
        match self.pending_lidar.take() {
            Some(pending) => self.fuse_lidar_plan(pending, None, 0.0),
            None => Ok(Vec::new()),
        }
    }

    /// Begins the plan of `scan` (on a GPU: its listing submitted).
    fn begin_lidar(&mut self, scan: &LidarScan) -> crate::Result<PendingLidarPlan> {
        let layer = self.store.layer();
        let params = &self.config.lidar_fusion;
        let pending = (self.backend).begin_lidar_plan(layer, scan, params)?;
        warn_without_returns(&pending, scan, params);
        Ok(pending)
    }

    /// Fuses the scan of `pending` (`begun_s` seconds spent beginning it), beginning the plan of
    /// `next` with the scan's fusion (on a GPU, its listing in the fusion's submit).
    fn fuse_lidar_plan(
        &mut self,
        pending: PendingLidarPlan,
        next: Option<&LidarScan>,
        begun_s: f64,
    ) -> crate::Result<TouchedBlocks> {
        let t = Instant::now();
        let plan = self.backend.finish_lidar_plan(pending)?;
        let planned_s = begun_s + t.elapsed().as_secs_f64();
        let t = Instant::now();
        self.store
            .prepare_blocks(&plan.blocks(), &mut self.backend)?;
        self.timings.paging_s += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let params = &self.config.lidar_fusion;
        let layer = self.store.layer_mut();
        let next = next.map(|scan| (scan, params));
        let (touched, stats, pending) = (self.backend).fuse_lidar_then_begin(layer, &plan, next)?;
        if let (Some((scan, params)), Some(pending)) = (next, &pending) {
            warn_without_returns(pending, scan, params);
        }
        self.pending_lidar = pending;
        self.timings.fusion_s += planned_s + t.elapsed().as_secs_f64();
        self.after_frame(plan.origin_m(), &touched, stats)?;
        Ok(touched)
    }

    fn after_frame(
        &mut self,
        camera_m: [f64; 3],
        touched: &[crate::grid::BlockIndex],
        stats: FusionStats,
    ) -> crate::Result<()> {
        self.timings.frames_fused += 1;
        self.timings.voxel_updates += stats.voxel_updates;
        self.trajectory_m.push(camera_m);
        self.frames_total += 1;
        let t = Instant::now();
        self.store
            .finish_frame(touched, camera_m, &mut self.backend)?;
        if self.checkpoint_every > 0 && self.frames_total.is_multiple_of(self.checkpoint_every) {
            self.store.commit(self.frames_total, &mut self.backend)?;
        }
        self.timings.paging_s += t.elapsed().as_secs_f64();
        Ok(())
    }

    /// Makes every frame fused so far durable (a checkpoint of a paged map) and the resident
    /// layer current (GPU blocks written back). The time counts as fusion (the GPU's write-back)
    /// and paging (the checkpoint).
    pub fn sync(&mut self) -> crate::Result<()> {
        self.finish_pending()?;
        let t = Instant::now();
        self.store.commit(self.frames_total, &mut self.backend)?;
        self.frames_synced = self.frames_total;
        self.timings.paging_s += t.elapsed().as_secs_f64();
        // Depth frames still in flight were collected by the commit's sync.
        self.timings.voxel_updates += self.backend.take_late_voxel_updates();
        Ok(())
    }

    /// Regularizes the whole map with the backend's solver (`progress(done, total)` after each
    /// region; returning false stops early, what was done is kept).
    pub fn regularize_with_progress(
        &mut self,
        progress: &mut dyn FnMut(usize, usize) -> bool,
    ) -> crate::Result<RegularizeOutcome> {
        self.sync()?;
        let before = self.backend.tv_devices();
        let t = Instant::now();
        let tv = self.config.tv;
        // A store that pages during the solve must find no copies on the GPU; an in-memory map
        // keeps them there, to be regularized where they are (`TvSolver::solve_in_place`).
        if !self.store.holds_whole_map() {
            self.backend.flush_all(self.store.layer_mut())?;
        }
        let summary = self.store.regularize(&tv, &mut self.backend, progress);
        self.backend.release_tv_buffers();
        let summary = summary?;
        let seconds = t.elapsed().as_secs_f64();
        self.timings.regularize_s += seconds;
        self.timings.voxel_iterations += summary.omega_voxels * summary.iterations as u64;
        let after = self.backend.tv_devices();
        Ok(RegularizeOutcome {
            summary,
            devices: TvDevices {
                gpu: after.gpu - before.gpu,
                cpu: after.cpu - before.cpu,
            },
            seconds,
        })
    }

    /// [`Reconstructor::regularize_with_progress`] without a progress report.
    pub fn regularize(&mut self) -> crate::Result<RegularizeOutcome> {
        self.regularize_with_progress(&mut |_, _| true)
    }

    /// Meshes `field` into `mesh_path` (binary PLY), and its vertices into `points_path`.
    pub fn write_surface(
        &mut self,
        field: Field,
        mesh_path: &Path,
        points_path: Option<&Path>,
    ) -> crate::Result<SurfaceOutput> {
        self.finish_pending()?;
        let t = Instant::now();
        let out = self
            .store
            .write_surface(field, mesh_path, points_path, &mut self.backend)?;
        self.timings.mesh_s += t.elapsed().as_secs_f64();
        Ok(out)
    }

    /// The outputs of a reconstruction in `out_dir` (created): `mesh_raw.ply`, then, unless
    /// `regularize` is false, the regularization and `mesh_regularized.ply` with its vertices
    /// as `points_regularized.ply`.
    pub fn write_results(
        &mut self,
        out_dir: &Path,
        regularize: bool,
        progress: &mut dyn FnMut(usize, usize) -> bool,
    ) -> crate::Result<Results> {
        std::fs::create_dir_all(out_dir).map_err(|e| crate::Error::io(out_dir, e))?;
        // Every frame fused so far committed first: a paged map's fusion ends with the raw mesh.
        let pending = self.pending_lidar.is_some() || self.pending_depth.is_some();
        if self.frames_synced != self.frames_total || pending {
            self.sync()?;
        }
        let mut surfaces =
            vec![self.write_surface(Field::Raw, &out_dir.join("mesh_raw.ply"), None)?];
        let regularize = if regularize {
            // The raw mesh is on disk: not held beside the regularizer's arrays (an evaluation
            // reads it back, as it does a paged map's), and the allocator's pages it and marching
            // cubes used handed back (measured on a 200 m drive: 420 MiB resident but free).
            surfaces[0].mesh = None;
            crate::memory::release_free_memory();
            let r = self.regularize_with_progress(progress)?;
            surfaces.push(self.write_surface(
                Field::Regularized,
                &out_dir.join("mesh_regularized.ply"),
                Some(&out_dir.join("points_regularized.ply")),
            )?);
            Some(r)
        } else {
            None
        };
        Ok(Results {
            surfaces,
            regularize,
        })
    }

    /// Marching cubes over the resident layer (the whole map in RAM), on the backend's device
    /// for meshing; blocks still on a GPU are synced first.
    pub fn mesh(&mut self, field: Field) -> crate::Result<Mesh> {
        self.sync()?;
        let t = Instant::now();
        let mesh = self.backend.mesh(self.store.layer(), field)?;
        self.timings.mesh_s += t.elapsed().as_secs_f64();
        Ok(mesh)
    }
}

/// Warns where a scan of points has no return in range (nothing to fuse).
fn warn_without_returns(pending: &PendingLidarPlan, scan: &LidarScan, params: &LidarFusionParams) {
    if pending.ray_count() == 0 && !scan.points_sensor_m.is_empty() {
        tracing::warn!(
            "a LiDAR scan of {} points has no return between {} and {} m: nothing fused",
            scan.points_sensor_m.len(),
            params.min_range_m,
            params.max_range_m
        );
    }
}
