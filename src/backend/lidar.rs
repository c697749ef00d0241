//! The LiDAR stage of a [`Backend`]: a scan's plan (its blocks listed on the GPU where the GPU
//! fuses, `src/fusion/lidar_listing.rs`) and its fusion, the next scan's listing riding in the
//! scan's fusion submit where a caller fuses scans one call late.

use super::{counted, Backend};
use crate::frame::LidarScan;
use crate::fusion::{
    begin_lidar_listing, finish_lidar_listing, fuse_lidar_then_list, integrate_lidar_plan,
    FusionStats, LidarFusionParams, LidarPlan, PendingLidarPlan,
};
use crate::gpu::shaders::{self, ShaderSource};
use crate::grid::{Layer, TouchedBlocks};
use crate::Result;

/// The kernels that list a scan's blocks and make its rays and pairs on the device, besides
/// the fusion's own (compiled when the GPU opens, [`super::GpuStages::kernels`]).
const LIDAR_KERNELS: [&ShaderSource; 10] = [
    &shaders::LIDAR_RAYS,
    &shaders::LIDAR_BLOCKS,
    &shaders::LIDAR_FOUND,
    &shaders::LIDAR_LISTED,
    &shaders::LIDAR_COUNT,
    &shaders::LIDAR_PREFIX,
    &shaders::LIDAR_LIST,
    &shaders::LIDAR_SORT,
    &shaders::LIDAR_RANK,
    &shaders::LIDAR_PAIRS,
];

impl Backend {
    /// Compiles the kernels a LiDAR scan runs on the GPU, where the GPU fuses, together (on
    /// several threads) and ahead of the first scan, so that its time does not hold their
    /// compilation (counted in [`crate::gpu::GpuContext::kernel_compilation`]); nothing once
    /// they are. Not done when the GPU opens: a run of depth frames never needs them.
    pub(crate) fn compile_lidar_kernels(&self) -> Result<()> {
        match self.gpu.as_ref().filter(|_| self.stages.fusion) {
            Some(ctx) => ctx.compile_kernels(&LIDAR_KERNELS),
            None => Ok(()),
        }
    }

    /// Plans the fusion of LiDAR scan `scan` into `layer`: where the GPU fuses, its blocks
    /// listed on the GPU (`src/fusion/lidar_listing.rs`, the rays left there for
    /// [`Backend::fuse_lidar`]), else on the host ([`LidarPlan::new`]); the same plan either
    /// way. The listing's traffic counts as the scan's.
    pub fn plan_lidar(
        &mut self,
        layer: &Layer,
        scan: &LidarScan,
        params: &LidarFusionParams,
    ) -> Result<LidarPlan> {
        let pending = self.begin_lidar_plan(layer, scan, params)?;
        self.finish_lidar_plan(pending)
    }

    /// Whether [`Backend::begin_lidar_plan`] lists scans on a GPU with their results read back
    /// late (frames in flight), so that a caller gains by finishing a scan's plan a call later.
    pub(crate) fn lists_lidar_in_flight(&self) -> bool {
        self.gpu.is_some() && self.stages.fusion && self.frames_in_flight
    }

    /// [`Backend::plan_lidar`] begun: where the GPU fuses, the listing submitted and not waited
    /// for; [`Backend::finish_lidar_plan`] collects it (after any other GPU work, but before
    /// the next scan's listing: the rays and the table are kept once).
    pub(crate) fn begin_lidar_plan(
        &mut self,
        layer: &Layer,
        scan: &LidarScan,
        params: &LidarFusionParams,
    ) -> Result<PendingLidarPlan> {
        let grid = layer.params();
        let Some(ctx) = self.gpu.clone().filter(|_| self.stages.fusion) else {
            return Ok(PendingLidarPlan::Planned(LidarPlan::new(
                &grid, scan, params,
            )));
        };
        let options = (self.resident_options, self.frames_in_flight);
        let resident = Self::resident_map(&mut self.resident, options, &ctx, layer)?;
        let plan = LidarPlan::rays_only(&grid, scan, params);
        let listings = &mut self.lidar_listings;
        let mut calls = 0;
        counted(Some(&ctx), &mut self.traffic.lidar, &mut calls, || {
            begin_lidar_listing(resident, listings, plan)
        })
    }

    /// The plan [`Backend::begin_lidar_plan`] began (see there).
    pub(crate) fn finish_lidar_plan(&mut self, pending: PendingLidarPlan) -> Result<LidarPlan> {
        let listing = match pending {
            PendingLidarPlan::Planned(plan) => return Ok(plan),
            PendingLidarPlan::Listing(listing) => *listing,
        };
        let ctx = listing.context().clone();
        let listings = &mut self.lidar_listings;
        let mut calls = 0;
        let listed = counted(Some(&ctx), &mut self.traffic.lidar, &mut calls, || {
            finish_lidar_listing(listings, listing)
        })?;
        // A plan the device could not list lists its pairs on the host when asked.
        Ok(listed.unwrap_or_else(|plan| plan))
    }

    /// Fuses one LiDAR scan planned by `plan` into `layer` (on a GPU, into the blocks resident
    /// there, as depth frames are: call [`crate::store::UpperTier::sync`] before reading the
    /// layer whole).
    pub fn fuse_lidar(
        &mut self,
        layer: &mut Layer,
        plan: &LidarPlan,
    ) -> Result<(TouchedBlocks, FusionStats)> {
        let (touched, stats, _) = self.fuse_lidar_then_begin(layer, plan, None)?;
        Ok((touched, stats))
    }

    /// [`Backend::fuse_lidar`], then [`Backend::begin_lidar_plan`] of `next` (a scan and its
    /// parameters), whose pending plan it returns: on a GPU that fuses, the next scan's listing
    /// recorded into the scan's fusion submit, so that a scan fused a call late costs one submit.
    pub(crate) fn fuse_lidar_then_begin(
        &mut self,
        layer: &mut Layer,
        plan: &LidarPlan,
        next: Option<(&LidarScan, &LidarFusionParams)>,
    ) -> Result<(TouchedBlocks, FusionStats, Option<PendingLidarPlan>)> {
        let Some(ctx) = self.gpu.clone().filter(|_| self.stages.fusion) else {
            let (touched, stats) = integrate_lidar_plan(layer, plan);
            let next = next.map(|(scan, params)| self.begin_lidar_plan(layer, scan, params));
            return Ok((touched, stats, next.transpose()?));
        };
        let grid = layer.params();
        let next = next.map(|(scan, params)| LidarPlan::rays_only(&grid, scan, params));
        let options = (self.resident_options, self.frames_in_flight);
        let resident = Self::resident_map(&mut self.resident, options, &ctx, layer)?;
        let (t, listings) = (&mut self.traffic, &mut self.lidar_listings);
        counted(Some(&ctx), &mut t.lidar, &mut t.lidar_scans, || {
            fuse_lidar_then_list(resident, layer, plan, next.map(|p| (listings, p)))
        })
    }
}
