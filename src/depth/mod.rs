//! Depth maps from rectified stereo pairs.
