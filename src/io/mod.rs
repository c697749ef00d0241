//! Readers and writers for sensor data and results: KITTI odometry, TUM RGB-D and the simple
//! RGB-D layout, LAS/LAZ, PLY.
pub mod pfm;
