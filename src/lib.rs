//! `denser`: dense, coloured 3D reconstruction of whole cities from a vehicle's stereo camera and
//! LiDAR, after the DENSER Cities paper, built as an out-of-core streaming tiler.
//!
//! Pipeline (module → stage): [`io`] and [`synth`] read or generate sensor data; [`depth`] turns
//! stereo pairs into depth maps; [`fusion`] integrates depth maps and LiDAR scans into the hashed
//! voxel grid ([`grid`]); [`regularize`] runs the Ω-aware TV regulariser; [`mesh`] extracts
//! coloured surfaces; [`eval`] scores them against ground truth. [`reconstruct`] drives the
//! stages over a [`store::BlockStore`] (the map in RAM, or paged through chunk files by
//! [`outofcore`]) with the stages of one [`backend::Backend`] (CPU, or GPU through [`gpu`]).
//!
//! Out of core, three rooms, each importing only from the rooms below it: [`map`], the storage
//! engine (chunk files, manifest, commits, locks, repair; it knows nothing above it);
//! [`outofcore`], the algorithms over a stored map (pager, regional and swept regularisation,
//! shards, merge); [`export`], the map's surfaces as meshes, point clouds and 3D Tiles. The rule
//! is checked by `tests/core/rooms.rs`.

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
