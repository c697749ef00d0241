//! Readers and writers: images, KITTI, LAS/LAZ, PLY, RGB-D layouts, disparity files and PFM.

#[path = "../common/mod.rs"]
mod common;

mod disparity;
mod image;
mod kitti;
mod las;
mod pfm;
mod ply;
mod recorded;
mod rgbd;
