//! Camera models and poses shared by every stage.
//!
//! Poses are `world_from_camera` rigid transforms (`nalgebra::Isometry3<f64>`), camera frame as in
//! OpenCV/KITTI: x right, y down, z forward (the optical axis). Depth is the z coordinate in the
//! camera frame (not the ray length).

use nalgebra::{Isometry3, Point3, Vector3};
use serde::{Deserialize, Serialize};

/// A rigid transform taking points from the camera (or sensor) frame to the world frame.
pub type WorldFromCamera = Isometry3<f64>;

/// Pinhole intrinsics of a rectified image, in pixels. Pixel (u, v) has its centre at (u, v):
/// `u = fx·x/z + cx`, `v = fy·y/z + cy`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PinholeIntrinsics {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl PinholeIntrinsics {
    /// Projects a point in the camera frame to continuous pixel coordinates; `None` behind the camera.
    #[inline]
    pub fn project(&self, p_camera: &Point3<f64>) -> Option<(f64, f64)> {
        if p_camera.z <= 1e-9 {
            return None;
        }
        Some((
            self.fx * p_camera.x / p_camera.z + self.cx,
            self.fy * p_camera.y / p_camera.z + self.cy,
        ))
    }

    /// The point at depth `depth_m` (z) through pixel (u, v), in the camera frame.
    #[inline]
    pub fn unproject(&self, u: f64, v: f64, depth_m: f64) -> Point3<f64> {
        Point3::new(
            (u - self.cx) / self.fx * depth_m,
            (v - self.cy) / self.fy * depth_m,
            depth_m,
        )
    }

    /// Direction (not normalised, z = 1) of the ray through pixel (u, v), camera frame.
    #[inline]
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
}
