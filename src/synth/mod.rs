//! The synthetic city: procedural scenes with exact ground truth, rendered as KITTI-layout drives.
