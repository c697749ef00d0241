//! Sensor data handed to fusion: depth frames (from stereo, RGB-D or ground truth) and LiDAR scans.
//! Readers in `io/` and the synthetic city in `synth/` produce these; `fusion/` consumes them.

use crate::camera::{PinholeIntrinsics, WorldFromCamera};
use nalgebra::Isometry3;

/// A row-major image of `T`, `width × height`, pixel (u, v) at `data[v·width + u]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Image<T> {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Row-major pixels.
    pub data: Vec<T>,
}

impl<T: Copy> Image<T> {
    /// An image filled with `value`.
    pub fn filled(width: u32, height: u32, value: T) -> Self {
        Image {
            width,
            height,
            data: vec![value; width as usize * height as usize],
        }
    }

    /// Pixel at column `u`, row `v` (panics when out of bounds).
    #[inline]
    pub fn at(&self, u: u32, v: u32) -> T {
        self.data[v as usize * self.width as usize + u as usize]
    }

    /// Mutable pixel at column `u`, row `v`.
    #[inline]
    pub fn at_mut(&mut self, u: u32, v: u32) -> &mut T {
        &mut self.data[v as usize * self.width as usize + u as usize]
    }
}

/// Depth along the optical axis (z), metres. Invalid pixels hold NaN; readers map 0, negative
/// and infinite depths to NaN so that fusion never sees them.
pub type DepthImage = Image<f32>;

/// 8-bit RGB colour image.
pub type RgbImage = Image<[u8; 3]>;

/// 8-bit grey image.
pub type GreyImage = Image<u8>;

/// Marks every non-finite or non-positive depth as invalid (NaN); returns how many were invalid.
pub fn sanitize_depth(depth: &mut DepthImage) -> usize {
    let mut invalid = 0;
    for d in depth.data.iter_mut() {
        if !(d.is_finite() && *d > 0.0) {
            *d = f32::NAN;
            invalid += 1;
        }
    }
    invalid
}

/// One depth map with its camera, pose and optional colour image (same size as the depth).
#[derive(Clone, Debug)]
pub struct DepthFrame {
    /// Intrinsics of the depth image.
    pub intrinsics: PinholeIntrinsics,
    /// Camera pose.
    pub world_from_camera: WorldFromCamera,
    /// Depth (z) in metres, NaN where invalid.
    pub depth_m: DepthImage,
    /// Colour registered to the depth image, if any.
    pub color: Option<RgbImage>,
}

/// One LiDAR sweep: points in the sensor frame plus the sensor's pose. Rays start at the sensor
/// origin.
#[derive(Clone, Debug, Default)]
pub struct LidarScan {
    /// Pose of the sensor.
    pub world_from_sensor: Isometry3<f64>,
    /// Hit points in the sensor frame, metres.
    pub points_sensor_m: Vec<[f32; 3]>,
    /// Return intensity / reflectance in [0, 1] (KITTI) or sensor units; same length as points.
    pub intensity: Vec<f32>,
}

/// A point cloud in world coordinates (ground truth for evaluation, exports).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    /// Positions, metres (world frame).
    pub points_m: Vec<[f64; 3]>,
    /// Optional per-point colour.
    pub colors: Option<Vec<[u8; 3]>>,
}

impl PointCloud {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.points_m.len()
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.points_m.is_empty()
    }
}
