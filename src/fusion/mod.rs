//! Fusion of depth maps and LiDAR scans into the hashed voxel grid (DENSER Sec. III-A).
