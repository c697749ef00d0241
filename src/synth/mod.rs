//! The synthetic city: procedural scenes with exact ground truth, rendered as KITTI-layout drives.
//!
//! A city ([`City`]) is generated deterministically from a [`CityConfig`]: streets along a
//! procedural route (turns, side-street junctions and a loop) or along a given trajectory at its
//! real scale (e.g. KITTI sequence 00's poses), with textured asphalt and lane markings, kerbs and
//! pavements, buildings with facades and windows, parked cars, trees with irregular crowns, lamp
//! posts, signs, and sky (no surface). Everything is an exact primitive ([`Shape`]) in a BVH,
//! so that ray casts, depths, LiDAR returns and surface samples are exact.
//!
//! World frame = KITTI's: cam0 of the first frame, x right, y **down**, z forward; the road lies
//! at y ≈ +1.65 m below the first camera.
//!
//! - [`City::cast`]: nearest hit with albedo; [`City::render_stereo`]: a rectified stereo pair
//!   with sensor noise and the left camera's exact depth; [`City::scan_lidar`]: an HDL-64E-like
//!   scan; [`City::sample_surface`]: dense exact surface samples.
//! - [`write_drive`]: the whole drive in the KITTI odometry layout, streamed frame by frame.
//!
//! Not here: reading KITTI drives (`io`), stereo matching (`depth`), evaluation (`eval`).

mod bvh;
mod city;
mod furniture;
mod geometry;
mod ground;
mod lidar;
mod placement;
mod render;
pub(crate) mod rng;
mod route;
mod streets;
mod texture;
mod writer;

pub use city::{City, CityConfig, Hit, Material, Primitive, SurfaceSampling};
pub use geometry::{Aabb, Ray, Shape};
pub use lidar::{kitti_cam0_from_velo, LidarConfig, KITTI_00_TR_VELO_TO_CAM};
pub use placement::Footprint;
pub use render::{albedo_to_srgb, luma, RenderOptions, StereoFrame, StereoRig};
pub use texture::{FacadeParams, Rgb, WallStyle};
pub use writer::{
    calib_text, encode_depth_u16, format_sci, write_drive, DriveConfig, DriveSummary,
};
