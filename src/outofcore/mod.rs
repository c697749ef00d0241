//! The out-of-core algorithms over a stored map ([`crate::map`]): fusion paged around the camera,
//! regularization region by region (sweeps, or one solve with the exact halo), regions as array
//! jobs, and maps merged. They store everything through the engine's API, and keep their own
//! records in the areas the engine reserves for them ([`crate::map::layout`]). Nothing here
//! imports the exports ([`crate::export`]) or the command line (checked by `tests/core/rooms.rs`).
//!
//! - [`pager`]: residency around the camera within a byte budget; evicted chunks are encoded and
//!   written by background workers; revisited chunks are read back.
//! - [`paged`]: a map as a [`crate::store::BlockStore`] ([`PagedStore`]): fusion through the
//!   pager, regularization region by region, surfaces through a [`SurfaceWriter`] handed in.
//! - [`region_plan`]: regions planned to a memory budget, and the counters and options every
//!   regional pass shares. A leaf: both passes below use it, neither uses the other's internals.
//! - [`regional`]: offline regularization of a stored map region by region with exact halos (and
//!   the entry point that runs a pass as [`sweeps`] by default); [`sweeps`] and [`sweep_state`]:
//!   the swept pass and its state records.
//! - [`shards`]: regions as array jobs (plans that reserve file numbers, region records,
//!   adoption).
//! - [`merge`]: several maps of one world frame combined chunk by chunk (weighted TSDF average).
//!
//! Nothing here changes voxel values beyond what the stage computes: fusing with paging gives the
//! same bits as fusing in memory, the tiled regularization the same bits as a global solve
//! (tested).

pub mod merge;
mod paged;
pub mod pager;
pub mod region_plan;
pub mod regional;
pub mod shards;
pub mod sweep_state;
pub mod sweeps;

pub use paged::{PagedStore, SurfaceCounts, SurfaceWriter};
