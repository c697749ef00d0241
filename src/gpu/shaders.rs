//! WGSL sources, assembled from `shaders/` at compile time. WGSL has no `#include`: each kernel is
//! its shared files (`shaders/shared/`) followed by its own file, concatenated here; this list is
//! what the naga validation test (`tests/gpu_shaders.rs`) checks.

/// One kernel: a label and the assembled WGSL source.
#[derive(Clone, Copy, Debug)]
pub struct ShaderSource {
    /// The kernel's file under `shaders/`.
    pub file: &'static str,
    /// Shared files prepended, in order.
    pub shared: &'static [&'static str],
    /// The assembled source.
    pub source: &'static str,
}

/// TV dual step.
pub const TV_DUAL: ShaderSource = ShaderSource {
    file: "tv_dual.wgsl",
    shared: &["shared/dispatch.wgsl", "shared/tv_common.wgsl"],
    source: concat!(
        include_str!("../../shaders/shared/dispatch.wgsl"),
        include_str!("../../shaders/shared/tv_common.wgsl"),
        include_str!("../../shaders/tv_dual.wgsl")
    ),
};

/// TV primal step and relaxation.
pub const TV_PRIMAL: ShaderSource = ShaderSource {
    file: "tv_primal.wgsl",
    shared: &["shared/dispatch.wgsl", "shared/tv_common.wgsl"],
    source: concat!(
        include_str!("../../shaders/shared/dispatch.wgsl"),
        include_str!("../../shaders/shared/tv_common.wgsl"),
        include_str!("../../shaders/tv_primal.wgsl")
    ),
};

/// Depth-map fusion over uploaded blocks.
pub const FUSE_DEPTH: ShaderSource = ShaderSource {
    file: "fuse_depth.wgsl",
    shared: &[
        "shared/dispatch.wgsl",
        "shared/rounding.wgsl",
        "shared/voxel_fuse.wgsl",
        "shared/fuse_common.wgsl",
    ],
    source: concat!(
        include_str!("../../shaders/shared/dispatch.wgsl"),
        include_str!("../../shaders/shared/rounding.wgsl"),
        include_str!("../../shaders/shared/voxel_fuse.wgsl"),
        include_str!("../../shaders/shared/fuse_common.wgsl"),
        include_str!("../../shaders/fuse_depth.wgsl")
    ),
};

/// Depth-map fusion into the blocks resident in the GPU pool.
pub const FUSE_DEPTH_RESIDENT: ShaderSource = ShaderSource {
    file: "fuse_depth_resident.wgsl",
    shared: &[
        "shared/dispatch.wgsl",
        "shared/rounding.wgsl",
        "shared/voxel_fuse.wgsl",
        "shared/fuse_common.wgsl",
        "shared/block_hash.wgsl",
    ],
    source: concat!(
        include_str!("../../shaders/shared/dispatch.wgsl"),
        include_str!("../../shaders/shared/rounding.wgsl"),
        include_str!("../../shaders/shared/voxel_fuse.wgsl"),
        include_str!("../../shaders/shared/fuse_common.wgsl"),
        include_str!("../../shaders/shared/block_hash.wgsl"),
        include_str!("../../shaders/fuse_depth_resident.wgsl")
    ),
};

/// Block keys to pool slots through the GPU hash table.
pub const BLOCK_LOOKUP: ShaderSource = ShaderSource {
    file: "block_lookup.wgsl",
    shared: &["shared/dispatch.wgsl", "shared/block_hash.wgsl"],
    source: concat!(
        include_str!("../../shaders/shared/dispatch.wgsl"),
        include_str!("../../shaders/shared/block_hash.wgsl"),
        include_str!("../../shaders/block_lookup.wgsl")
    ),
};

/// LiDAR fusion (ray-wise, inside the truncation band) over uploaded blocks.
pub const FUSE_LIDAR: ShaderSource = ShaderSource {
    file: "fuse_lidar.wgsl",
    shared: &[
        "shared/dispatch.wgsl",
        "shared/rounding.wgsl",
        "shared/voxel_fuse.wgsl",
    ],
    source: concat!(
        include_str!("../../shaders/shared/dispatch.wgsl"),
        include_str!("../../shaders/shared/rounding.wgsl"),
        include_str!("../../shaders/shared/voxel_fuse.wgsl"),
        include_str!("../../shaders/fuse_lidar.wgsl")
    ),
};

/// TGV stereo dual step (`p` with the tensor, `q`).
pub const TGV_DUAL: ShaderSource = ShaderSource {
    file: "tgv_dual.wgsl",
    shared: &["shared/dispatch.wgsl", "shared/tgv_common.wgsl"],
    source: concat!(
        include_str!("../../shaders/shared/dispatch.wgsl"),
        include_str!("../../shaders/shared/tgv_common.wgsl"),
        include_str!("../../shaders/tgv_dual.wgsl")
    ),
};

/// TGV stereo primal step (`u` with the coupling, `v`) and over-relaxation.
pub const TGV_PRIMAL: ShaderSource = ShaderSource {
    file: "tgv_primal.wgsl",
    shared: &["shared/dispatch.wgsl", "shared/tgv_common.wgsl"],
    source: concat!(
        include_str!("../../shaders/shared/dispatch.wgsl"),
        include_str!("../../shaders/shared/tgv_common.wgsl"),
        include_str!("../../shaders/tgv_primal.wgsl")
    ),
};

/// Point-wise search of the stereo decoupling.
pub const TGV_POINTWISE: ShaderSource = ShaderSource {
    file: "tgv_pointwise.wgsl",
    shared: &["shared/dispatch.wgsl"],
    source: concat!(
        include_str!("../../shaders/shared/dispatch.wgsl"),
        include_str!("../../shaders/tgv_pointwise.wgsl")
    ),
};

/// Census transform.
pub const CENSUS: ShaderSource = ShaderSource {
    file: "census.wgsl",
    shared: &["shared/dispatch.wgsl"],
    source: concat!(
        include_str!("../../shaders/shared/dispatch.wgsl"),
        include_str!("../../shaders/census.wgsl")
    ),
};

/// Census cost volume (Hamming distances).
pub const CENSUS_COST: ShaderSource = ShaderSource {
    file: "census_cost.wgsl",
    shared: &["shared/dispatch.wgsl"],
    source: concat!(
        include_str!("../../shaders/shared/dispatch.wgsl"),
        include_str!("../../shaders/census_cost.wgsl")
    ),
};

/// Every kernel (one per line, so additions merge cleanly).
pub const ALL: &[ShaderSource] = &[
    // TV regularisation.
    TV_DUAL,
    TV_PRIMAL,
    // Fusion.
    FUSE_DEPTH,
    FUSE_DEPTH_RESIDENT,
    FUSE_LIDAR,
    // The GPU hash table.
    BLOCK_LOOKUP,
    // Stereo.
    TGV_DUAL,
    TGV_PRIMAL,
    TGV_POINTWISE,
    CENSUS,
    CENSUS_COST,
    // (new kernels go above this line)
];
