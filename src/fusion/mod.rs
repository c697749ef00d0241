//! Fusion of depth maps and LiDAR scans into the hashed voxel grid (DENSER Sec. III-A).
//!
//! Each integrator runs in two phases, so that a pager can make blocks resident in between:
//! 1. `*_blocks(...)` lists (sorted) the blocks the observation touches: those crossed by the
//!    truncation band `[d − μ, d + μ]` around every measured point (it reads nothing from the
//!    layer); for depth maps also [`visible_blocks`], the allocated blocks in the view frustum,
//!    which receive the update too (as InfiniTAM), so free space observed later carves stale or
//!    outlier surfaces.
//! 2. `integrate_*(layer, ...)` allocates those blocks, checks them out of the layer, updates their
//!    voxels in parallel (rayon, one task per block, so no two tasks share a voxel) and checks them
//!    back in. It returns the touched blocks.
//!
//! The update is the paper's running average: for a voxel with signed distance `u_SDF` to the
//! measured surface along the viewing direction, if `u_SDF ≥ −μ` then
//! `f ← (min(u_SDF, μ)/μ + w·f)/(w + 1)`, `w ← w + 1` (capped, see [`crate::grid::MAX_WEIGHT`]),
//! colour likewise, and the voxel joins Ω. For depth maps `u_SDF = d(x, y) − z_c` (projective, as
//! the paper); for LiDAR `u_SDF = r − t` with `r` the range of the hit and `t` the voxel centre's
//! position along the ray, and only voxels the ray traverses inside the band are updated.
//! Neither integrator carves free space outside the band (blocks are allocated only near surfaces).

mod band;
mod band_blocks_gpu;
mod band_gpu;
mod depth;
mod depth_block;
mod depth_device;
mod depth_gpu;
mod depth_keys;
mod lidar;
mod lidar_device;
mod lidar_gpu;
mod lidar_listing;
mod lidar_resident;
pub mod traverse;
mod visible_gpu;

pub use band::{
    band_slices, blocks_of_band_slices, depth_frame_blocks, depth_frame_blocks_exact, BandSlice,
    BandSlices, BAND_SLICE_MAX_SIDE_PX, BAND_TILE_PX,
};
pub use band_blocks_gpu::{band_blocks_on_gpu, certainty_margin_m, DeviceBand};
pub use band_gpu::{band_slice_uniforms, band_slices_on_gpu};
pub use depth::{
    integrate_depth, integrate_depth_plan, visible_blocks, visible_blocks_by_scan,
    visible_blocks_in, DepthFusionParams, DepthGeometry, DepthPlan, ViewFrustum,
};
pub use depth_device::{CameraView, DeviceDepthFrame, DeviceDepthKept};
pub use depth_gpu::{
    frame_keys_on_gpu, integrate_depth_gpu, integrate_depth_resident,
    integrate_device_depth_resident, ResolvedKeys,
};
pub use depth_keys::{pack_offset, unpack_offset, FrameKeys, OFFSET_BITS};
pub(crate) use lidar::band_m;
pub use lidar::{
    integrate_lidar, integrate_lidar_plan, integrate_lidar_reference, lidar_scan_blocks,
    LidarFusionParams, LidarPlan,
};
pub use lidar_device::{lidar_pairs_on_cpu, lidar_pairs_on_gpu, MAX_WALK_STEPS};
pub use lidar_gpu::{block_local_ray, integrate_lidar_gpu, walk_block_ray};
pub(crate) use lidar_listing::{
    begin_lidar_listing, finish_lidar_listing, LidarListings, PendingLidarPlan,
};
pub(crate) use lidar_resident::fuse_lidar_then_list;
pub use lidar_resident::integrate_lidar_resident;
pub use visible_gpu::{resident_in_view_on_gpu, visible_words, ResidentInView, MARGIN_PER_M};

/// Work counters of one integration call.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FusionStats {
    /// Blocks checked out and updated.
    pub blocks: usize,
    /// Voxel updates applied (a voxel hit by two rays counts twice).
    pub voxel_updates: usize,
    /// Measurements used (valid pixels or LiDAR points).
    pub measurements: usize,
}

/// Checks the blocks at `indices` out of `layer` (allocating missing ones), lets `update` change
/// them and report its voxel updates, and checks back in the blocks that are now observed. When
/// `update` fails, puts back exactly what was there (dropping the blocks allocated here), so the
/// layer is unchanged: how the GPU paths, which write blocks only after a whole readback,
/// keep a failed call from losing or half-writing data.
pub(crate) fn update_checked_out(
    layer: &mut crate::grid::Layer,
    indices: &[crate::grid::BlockIndex],
    measurements: usize,
    update: impl FnOnce(
        &mut [(crate::grid::BlockIndex, Box<crate::grid::Block>)],
    ) -> crate::Result<usize>,
) -> crate::Result<(crate::grid::TouchedBlocks, FusionStats)> {
    let existed: Vec<bool> = indices.iter().map(|b| layer.contains(b)).collect();
    let mut taken = layer.take_blocks(indices);
    match update(&mut taken) {
        Ok(voxel_updates) => {
            let touched = layer.put_blocks_observed(taken);
            let stats = FusionStats {
                blocks: touched.len(),
                voxel_updates,
                measurements,
            };
            Ok((touched, stats))
        }
        Err(e) => {
            layer.put_blocks(
                taken
                    .into_iter()
                    .zip(existed)
                    .filter_map(|(b, was)| was.then_some(b)),
            );
            Err(e)
        }
    }
}
