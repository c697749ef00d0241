//! `denser`: dense, coloured 3D reconstruction of whole cities from a vehicle's stereo camera and
//! LiDAR, after the DENSER Cities paper, built as an out-of-core streaming tiler.
//!
//! Pipeline (module → stage): [`io`] and [`synth`] read or generate sensor data; [`depth`] turns
//! stereo pairs into depth maps; [`fusion`] integrates depth maps and LiDAR scans into the hashed
//! voxel grid ([`grid`]); [`regularize`] runs the Ω-aware TV regularizer; [`mesh`] extracts
//! coloured surfaces; [`eval`] scores them against ground truth. [`reconstruct`] drives the
//! stages over a [`store::BlockStore`] (the map in RAM, or paged through chunk files by
//! [`outofcore`]) with the stages of one [`backend::Backend`] (CPU, or GPU through [`gpu`]).
//!
//! Out of core, three rooms, each importing only from the rooms below it: [`map`], the storage
//! engine (chunk files, manifest, commits, locks, repair; it knows nothing above it);
//! [`outofcore`], the algorithms over a stored map (pager, regional and swept regularization,
//! shards, merge); [`export`], the map's surfaces as meshes, point clouds and 3D Tiles. The rule
//! is checked by `tests/core/rooms.rs`.
//!
//! # Example: fuse, regularize, mesh
//!
//! A wall 2 m in front of a camera, seen in three noisy depth frames, fused at 5 cm into a map
//! in RAM, regularized and meshed on the CPU (`Backend::open(DeviceChoice::Auto, …)` would place
//! the stages as `--device auto` does):
//!
//! ```
//! use denser::backend::Backend;
//! use denser::camera::PinholeIntrinsics;
//! use denser::frame::{DepthFrame, Image};
//! use denser::mesh::Field;
//! use denser::reconstruct::{ReconstructionConfig, Reconstructor};
//! use nalgebra::Isometry3;
//!
//! # fn main() -> denser::Result<()> {
//! let intrinsics = PinholeIntrinsics {
//!     fx: 300.0, fy: 300.0, cx: 159.5, cy: 119.5, width: 320, height: 240,
//! };
//! let mut rec = Reconstructor::in_memory(ReconstructionConfig::paper(0.05), Backend::cpu())?;
//! for (k, x_m) in [-0.1, 0.0, 0.1].into_iter().enumerate() {
//!     // Depth along the optical axis (z), NaN where invalid; a few millimetres of noise.
//!     let mut depth_m = Image::filled(320, 240, 2.0f32);
//!     for (i, d) in depth_m.data.iter_mut().enumerate() {
//!         *d += 0.004 * (((i * 7 + k * 13) % 11) as f32 / 10.0 - 0.5);
//!     }
//!     let frame = DepthFrame {
//!         intrinsics,
//!         world_from_camera: Isometry3::translation(x_m, 0.0, 0.0),
//!         depth_m,
//!         color: None,
//!     };
//!     rec.fuse_depth(&frame)?;
//! }
//! let raw = rec.mesh(Field::Raw)?;
//! // The raw surface is the wall, 2 m away, within the noise.
//! assert!(raw.positions_m.iter().all(|p| (p[2] - 2.0).abs() < 0.005));
//! let outcome = rec.regularize()?;
//! assert!(outcome.summary.omega_voxels > 0);
//! let regularized = rec.mesh(Field::Regularized)?;
//! // Regularized: the wall again (the rim of the observed patch moves by a few centimetres).
//! let mut off_m: Vec<f32> = regularized.positions_m.iter().map(|p| (p[2] - 2.0).abs()).collect();
//! off_m.sort_by(f32::total_cmp);
//! assert!(off_m[off_m.len() / 2] < 0.01);
//! # Ok(())
//! # }
//! ```

// Validation writes `!(x > 0.0)` on purpose: NaN fails it, where `x <= 0.0` would let NaN
// through.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod backend;
pub mod camera;
pub mod depth;
pub mod error;
pub mod eval;
pub mod export;
pub mod frame;
pub mod fusion;
pub mod geo;
pub mod gpu;
pub mod grid;
pub mod io;
pub mod map;
pub mod memory;
pub mod mesh;
pub mod outofcore;
pub mod progress;
pub mod reconstruct;
pub mod regularize;
pub mod store;
pub mod synth;

pub use error::{Error, Result};
