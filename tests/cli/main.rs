//! The `denser` binary run as a user would, in fresh temporary folders.

#[path = "../common/mod.rs"]
mod common;
#[path = "../depth_support/mod.rs"]
mod depth_support;

mod basics;
mod budgets;
mod devices;
mod engine;
mod faults;
mod map;
mod outputs;
mod random_ops;
#[cfg(feature = "s3")]
mod scaleout;
mod stereo;
mod survives;
