//! The map on disk: chunk and manifest formats, crash safety, paging, regional regularization,
//! and the exports (LAS/LAZ in a world frame, COPC, 3D Tiles) checked by independent readers.

#[path = "../common/mod.rs"]
mod common;

mod engine;
mod export_formats;
mod format;
mod format_v3;
mod paging;
#[cfg(feature = "s3")]
mod scaleout;
mod survives;
mod sweeps;
mod write_behind;
