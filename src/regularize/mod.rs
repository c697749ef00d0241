//! Ω-aware TV regularisation of the fused TSDF (DENSER Sec. III-B, III-C).
