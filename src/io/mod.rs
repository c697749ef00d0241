//! Readers and writers for sensor data and results: KITTI odometry ([`kitti`]), TUM RGB-D and
//! the simple slambook-style RGB-D layout ([`rgbd`]), ROS 2 bags ([`bag`]), folders of scans
//! with a trajectory ([`scans`], [`trajectory`]), LAS/LAZ point clouds ([`las`]), COPC
//! ([`copc`]), binary glTF ([`glb`]), PLY meshes
//! and point clouds ([`ply`]) and image files ([`image`]).
//!
//! What it does: turns files into the crate's in-memory types ([`crate::frame`],
//! [`crate::mesh::Mesh`]) and back, validating as it goes; every error names the file (and the
//! line, for text formats). Each submodule documents its byte layout.
//!
//! What it does not do: resampling, undistortion, interpolation of poses, or any processing of
//! the data beyond unit conversion and the frame conventions documented per format.

pub mod atomic;
pub mod bag;
pub mod calib;
pub mod copc;
pub mod glb;
pub mod image;
pub mod kitti;
pub mod las;
pub mod pfm;
pub mod ply;
pub mod ply_stream;
pub mod rgbd;
pub mod scans;
pub mod sequence;
mod stereo_depth;
mod text;
pub mod trajectory;

use crate::error::Result;
use crate::frame::DepthFrame;

/// A random-access sequence of posed depth frames (RGB-D datasets, stereo depth caches).
pub trait DepthSequence {
    /// Number of frames.
    fn len(&self) -> usize;

    /// True when there are no frames.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Loads frame `i` (0-based): depth in metres (NaN invalid), intrinsics, pose, colour.
    /// Fails for `i >= len()` or when a file cannot be read.
    fn frame(&self, i: usize) -> Result<DepthFrame>;

    /// The pose of frame `i` without loading its images (`None` past the end).
    fn pose(&self, i: usize) -> Option<crate::camera::WorldFromCamera>;
}

/// Writes `cloud` as PLY, LAS or LAZ, chosen by the extension of `path`.
pub fn write_point_cloud(
    path: impl AsRef<std::path::Path>,
    cloud: &crate::frame::PointCloud,
) -> Result<()> {
    let path = path.as_ref();
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "ply" => ply::write_points_ply(path, cloud),
        "las" | "laz" => las::write_point_cloud(path, cloud),
        _ => Err(crate::Error::InvalidArgument(format!(
            "{}: points are written as .ply, .las or .laz",
            path.display()
        ))),
    }
}
