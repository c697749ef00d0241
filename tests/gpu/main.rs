//! The GPU kernels against their CPU twins (skipped, counted, where no adapter exists), and
//! every shader validated and reflected by naga (no GPU needed).

#[path = "../common/mod.rs"]
mod common;
#[path = "../depth_support/mod.rs"]
mod depth_support;

mod agreement;
mod band_slices;
mod compare;
mod device_alloc;
mod device_depth;
mod disparity_depth;
mod exact_f64;
mod frame_keys;
mod in_flight;
mod lidar;
mod lidar_listing;
mod mesh;
mod sgm;
mod shaders;
mod stereo;
mod street;
mod traffic;
mod tv_resident;
mod upload;
