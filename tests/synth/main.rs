//! The synthetic city: geometry, rendering, LiDAR and the KITTI-layout writer.

#[path = "../common/mod.rs"]
mod common;

mod city;
mod writer;
