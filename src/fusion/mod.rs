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

mod depth;
mod lidar;
pub mod traverse;

pub(crate) use depth::usable;
pub use depth::{
    depth_frame_blocks, integrate_depth, integrate_depth_band, visible_blocks, DepthFusionParams,
    ViewFrustum,
};
pub(crate) use lidar::band_m;
pub use lidar::{
    integrate_lidar, integrate_lidar_plan, lidar_scan_blocks, LidarFusionParams, LidarPlan,
};

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
