//! A KITTI-sized depth frame of an analytic street, for the GPU tier's per-frame figures at the
//! size the issue states them (1241 × 376 pixels, KITTI's intrinsics, 10 cm voxels).

use denser::camera::PinholeIntrinsics;
use denser::frame::{DepthFrame, Image};
use nalgebra::Isometry3;

/// Camera height above the road, metres.
const CAMERA_HEIGHT_M: f64 = 1.65;
/// Facades to either side of the camera, metres.
const FACADE_M: f64 = 7.0;
/// A wall closing the street ahead, metres (beyond the fusion's 40 m: unusable).
const END_M: f64 = 60.0;

/// The frame seen `z_m` metres down the street (camera axes: x right, y down, z ahead): the
/// road, two facades and the street's end, with a texture that depends on `seed`.
pub fn street_frame(z_m: f64, seed: u32) -> DepthFrame {
    let k = PinholeIntrinsics {
        fx: 718.856,
        fy: 718.856,
        cx: 607.19,
        cy: 185.22,
        width: 1241,
        height: 376,
    };
    let mut depth_m = Image::filled(k.width, k.height, f32::NAN);
    let mut color = Image::filled(k.width, k.height, [0u8; 3]);
    for v in 0..k.height {
        for u in 0..k.width {
            let (x, y) = ((u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy);
            let mut t = END_M;
            if y > 0.0 {
                t = t.min(CAMERA_HEIGHT_M / y);
            }
            if x != 0.0 {
                t = t.min(FACADE_M / x.abs());
            }
            *depth_m.at_mut(u, v) = t as f32;
            let g = ((u * 7 + v * 13 + seed * 31) % 251) as u8;
            *color.at_mut(u, v) = [g, g / 2, 255 - g];
        }
    }
    DepthFrame {
        intrinsics: k,
        world_from_camera: Isometry3::translation(0.0, 0.0, z_m),
        depth_m,
        color: Some(color),
    }
}
