//! Sparse disparity ground truth from range points (e.g. a KITTI Velodyne scan transformed into
//! the left rectified camera frame).
//!
//! Each point in front of the camera is projected to its nearest pixel; where several land on
//! the same pixel the nearest (smallest z) wins, as in a z-buffer. Its disparity is
//! `d = fx · B / z`. Pixels no point reaches are NaN. Does not densify or check for points seen
//! by the LiDAR but occluded in the camera (KITTI's own ground truth removes those by hand).

use crate::camera::PinholeIntrinsics;
use crate::frame::Image;
use nalgebra::Point3;

/// Disparity image (pixels, NaN where no point projects) of `points_cam0` (metres, left camera
/// frame: x right, y down, z forward) for a rectified pair with `baseline_m` and the left camera
/// `intrinsics` (the image has `intrinsics.width × intrinsics.height` pixels).
pub fn disparity_from_points(
    points_cam0: &[[f64; 3]],
    intrinsics: &PinholeIntrinsics,
    baseline_m: f64,
) -> Image<f32> {
    let w = intrinsics.width;
    let h = intrinsics.height;
    let mut depth = Image::filled(w, h, f64::INFINITY);
    for p in points_cam0 {
        if !(p[2] > 0.0) || !p.iter().all(|c| c.is_finite()) {
            continue;
        }
        let Some((u, v)) = intrinsics.project(&Point3::new(p[0], p[1], p[2])) else {
            continue;
        };
        let (u, v) = (u.round(), v.round());
        if u < 0.0 || v < 0.0 || u >= w as f64 || v >= h as f64 {
            continue;
        }
        let z = depth.at_mut(u as u32, v as u32);
        if p[2] < *z {
            *z = p[2];
        }
    }
    let fb = intrinsics.fx * baseline_m;
    Image {
        width: w,
        height: h,
        data: depth
            .data
            .iter()
            .map(|&z| {
                if z.is_finite() {
                    (fb / z) as f32
                } else {
                    f32::NAN
                }
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_point_wins_and_disparity_is_fb_over_z() {
        let k = PinholeIntrinsics {
            fx: 100.0,
            fy: 100.0,
            cx: 4.0,
            cy: 3.0,
            width: 8,
            height: 6,
        };
        let b = 0.5;
        let points = [
            [0.0, 0.0, 10.0],  // → (4, 3), d = 5
            [0.0, 0.0, 5.0],   // same pixel, nearer → d = 10
            [0.2, -0.1, 10.0], // → (6, 2), d = 5
            [0.0, 0.0, -3.0],  // behind
            [5.0, 0.0, 1.0],   // outside the image
        ];
        let d = disparity_from_points(&points, &k, b);
        assert_eq!(d.at(4, 3), 10.0);
        assert_eq!(d.at(6, 2), 5.0);
        assert_eq!(d.data.iter().filter(|v| v.is_finite()).count(), 2);
    }
}
