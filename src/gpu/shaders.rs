//! WGSL sources, assembled from `shaders/` at compile time (WGSL has no `#include`): each kernel,
//! declared once with [`kernel!`], is its shared files (`shaders/shared/`, in order) followed by
//! its own file, with the types of its bindings in order, from which the host builds its layout.
//! `tests/gpu/shaders.rs` checks them, and the sizes of the buffer structs, against what naga
//! reflects from the shader, and that every `.wgsl` file is part of some kernel.

/// The type of one buffer binding of a kernel (group 0, bindings numbered from 0).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Binding {
    /// `var<uniform>`.
    Uniform,
    /// `var<storage, read>`.
    Read,
    /// `var<storage, read_write>`.
    ReadWrite,
}

impl Binding {
    /// The wgpu binding type.
    pub fn wgpu(self) -> wgpu::BufferBindingType {
        match self {
            Binding::Uniform => wgpu::BufferBindingType::Uniform,
            Binding::Read => wgpu::BufferBindingType::Storage { read_only: true },
            Binding::ReadWrite => wgpu::BufferBindingType::Storage { read_only: false },
        }
    }
}

/// One kernel: its file, shared files, bindings and the assembled WGSL source.
#[derive(Clone, Copy, Debug)]
pub struct ShaderSource {
    /// The kernel's file under `shaders/`.
    pub file: &'static str,
    /// Shared files prepended, in order.
    pub shared: &'static [&'static str],
    /// Binding `k` of group 0 has type `bindings[k]`.
    pub bindings: &'static [Binding],
    /// The assembled source.
    pub source: &'static str,
}

/// Declares a kernel once: `kernel!("file.wgsl", ["shared/a.wgsl", …], [Uniform, Read, …])`.
macro_rules! kernel {
    ($file:literal, [$($shared:literal),* $(,)?], [$($binding:ident),* $(,)?]) => {
        ShaderSource {
            file: $file,
            shared: &[$($shared),*],
            bindings: &[$(Binding::$binding),*],
            source: concat!(
                $(include_str!(concat!("../../shaders/", $shared)),)*
                include_str!(concat!("../../shaders/", $file))
            ),
        }
    };
}

/// TV dual step.
pub const TV_DUAL: ShaderSource = kernel!(
    "tv_dual.wgsl",
    ["shared/dispatch.wgsl", "shared/tv_common.wgsl"],
    [Uniform, Read, Read, Read, Read, ReadWrite, ReadWrite, ReadWrite]
);

/// TV primal step and relaxation.
pub const TV_PRIMAL: ShaderSource = kernel!(
    "tv_primal.wgsl",
    ["shared/dispatch.wgsl", "shared/tv_common.wgsl"],
    [Uniform, Read, Read, Read, Read, ReadWrite, ReadWrite, ReadWrite]
);

/// TV over the resident blocks: the hash table's live entries placed at their slots.
pub const TV_RESIDENT_SLOTS: ShaderSource = kernel!(
    "tv_resident_slots.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/block_hash.wgsl",
        "shared/tv_resident_common.wgsl"
    ],
    [Uniform, Read, ReadWrite]
);

/// TV over the resident blocks: the occupied slots numbered as the problem's blocks.
pub const TV_RESIDENT_LIST: ShaderSource = kernel!(
    "tv_resident_list.wgsl",
    [
        "shared/workgroup_scan.wgsl",
        "shared/tv_resident_common.wgsl"
    ],
    [Uniform, Read, ReadWrite, ReadWrite, ReadWrite]
);

/// TV over the resident blocks: the neighbour table, through the GPU hash table.
pub const TV_RESIDENT_LINKS: ShaderSource = kernel!(
    "tv_resident_links.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/block_hash.wgsl",
        "shared/table_probe.wgsl",
        "shared/tv_resident_common.wgsl"
    ],
    [Uniform, Read, Read, Read, ReadWrite]
);

/// TV over the resident blocks: f, w and the Ω and link masks from the pool's voxels.
pub const TV_RESIDENT_GATHER: ShaderSource = kernel!(
    "tv_resident_gather.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/exact_div.wgsl",
        "shared/tv_resident_common.wgsl"
    ],
    [Uniform, Read, Read, Read, ReadWrite, ReadWrite, ReadWrite, ReadWrite]
);

/// TV over the resident blocks: the result encoded as the blocks store it (2 bytes per voxel).
pub const TV_RESIDENT_ENCODE: ShaderSource = kernel!(
    "tv_resident_encode.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/rounding.wgsl",
        "shared/float_bits.wgsl",
        "shared/tv_resident_common.wgsl"
    ],
    [Uniform, Read, Read, Read, Read, ReadWrite]
);

/// Depth-map fusion over uploaded blocks.
pub const FUSE_DEPTH: ShaderSource = kernel!(
    "fuse_depth.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/rounding.wgsl",
        "shared/float_bits.wgsl",
        "shared/packed_bytes.wgsl",
        "shared/voxel_fuse.wgsl",
        "shared/fuse_common.wgsl"
    ],
    [Uniform, Read, Read, Read, ReadWrite, ReadWrite]
);

/// Depth-map fusion into the blocks resident in the GPU pool.
pub const FUSE_DEPTH_RESIDENT: ShaderSource = kernel!(
    "fuse_depth_resident.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/rounding.wgsl",
        "shared/float_bits.wgsl",
        "shared/packed_bytes.wgsl",
        "shared/voxel_fuse.wgsl",
        "shared/fuse_common.wgsl",
        "shared/block_hash.wgsl"
    ],
    [Uniform, Read, Read, Read, ReadWrite, ReadWrite, Read, ReadWrite, ReadWrite]
);

/// Block keys to pool slots through the GPU hash table.
pub const BLOCK_LOOKUP: ShaderSource = kernel!(
    "block_lookup.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/block_hash.wgsl",
        "shared/table_probe.wgsl"
    ],
    [Uniform, Read, Read, ReadWrite]
);

/// A depth frame's listed blocks from their packed offsets: slots and bases.
pub const FRAME_KEYS: ShaderSource = kernel!(
    "frame_keys.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/block_hash.wgsl",
        "shared/table_probe.wgsl",
        "shared/frame_key.wgsl"
    ],
    [Uniform, Read, Read, ReadWrite, ReadWrite]
);

/// Listed blocks absent from the GPU hash table given slots and inserted (after [`FRAME_KEYS`]).
pub const TABLE_INSERT: ShaderSource = kernel!(
    "table_insert.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/block_hash.wgsl",
        "shared/frame_key.wgsl"
    ],
    [Uniform, ReadWrite, Read, ReadWrite, ReadWrite, ReadWrite]
);

/// The resident blocks in view, one invocation per entry of the GPU hash table.
pub const TABLE_VISIBLE: ShaderSource = kernel!(
    "table_visible.wgsl",
    ["shared/dispatch.wgsl", "shared/block_hash.wgsl"],
    [Read, Read, ReadWrite, ReadWrite, ReadWrite]
);

/// A depth frame's band blocks listed from its slices, per slice (f64; in [`WITH_F64`]).
pub const BAND_BLOCKS: ShaderSource = kernel!(
    "band_blocks.wgsl",
    ["shared/dispatch.wgsl", "shared/exact_f64.wgsl"],
    [Read, Read, Read, ReadWrite, ReadWrite, ReadWrite]
);

/// The band blocks' set as a list, one invocation per slot (f64 parameters; in [`WITH_F64`]).
pub const BAND_BLOCKS_KEYS: ShaderSource = kernel!(
    "band_blocks_keys.wgsl",
    ["shared/dispatch.wgsl"],
    [Read, ReadWrite, ReadWrite, ReadWrite]
);

/// A depth frame's band slices, one invocation per 8×8-pixel tile.
pub const BAND_SLICES: ShaderSource = kernel!(
    "band_slices.wgsl",
    ["shared/dispatch.wgsl"],
    [Uniform, Read, ReadWrite, ReadWrite, ReadWrite]
);

/// Depth from disparity, one invocation per pixel (the CPU's f64 quotient, in integers).
pub const DISPARITY_DEPTH: ShaderSource = kernel!(
    "disparity_depth.wgsl",
    ["shared/dispatch.wgsl", "shared/float_bits.wgsl"],
    [Uniform, Read, ReadWrite]
);

/// Writes the block table's changed entries, sent as one list.
pub const TABLE_SCATTER: ShaderSource = kernel!(
    "table_scatter.wgsl",
    ["shared/dispatch.wgsl"],
    [Read, ReadWrite]
);

/// Writes the empty block into listed pool slots given to new blocks.
pub const FILL_SLOTS: ShaderSource = kernel!(
    "fill_slots.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/rounding.wgsl",
        "shared/voxel_fuse.wgsl"
    ],
    [Uniform, Read, ReadWrite, ReadWrite]
);

/// Clears the updated marks of listed pool slots after a write-back.
pub const CLEAR_UPDATED: ShaderSource = kernel!(
    "clear_updated.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/rounding.wgsl",
        "shared/voxel_fuse.wgsl"
    ],
    [Uniform, Read, ReadWrite]
);

/// LiDAR fusion (ray-wise, inside the truncation band) over uploaded blocks.
pub const FUSE_LIDAR: ShaderSource = kernel!(
    "fuse_lidar.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/rounding.wgsl",
        "shared/voxel_fuse.wgsl",
        "shared/lidar_walk.wgsl"
    ],
    [Uniform, Read, Read, ReadWrite, ReadWrite, Read]
);

/// LiDAR fusion (ray-wise, inside the truncation band) into the blocks resident in the pool.
pub const FUSE_LIDAR_RESIDENT: ShaderSource = kernel!(
    "fuse_lidar_resident.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/rounding.wgsl",
        "shared/voxel_fuse.wgsl",
        "shared/lidar_walk.wgsl",
        "shared/block_hash.wgsl"
    ],
    [Uniform, Read, Read, ReadWrite, ReadWrite, Read, ReadWrite, Read, ReadWrite]
);

/// A LiDAR scan's rays made on the device in exact f64 (the CPU's directions, bit for bit).
pub const LIDAR_RAYS: ShaderSource = kernel!(
    "lidar_rays.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/exact_f64.wgsl",
        "shared/lidar_scan.wgsl"
    ],
    [Read, Read, ReadWrite, ReadWrite, ReadWrite]
);

/// A LiDAR scan's blocks found on the device, with their pairs (the CPU's walk, exact).
pub const LIDAR_BLOCKS: ShaderSource = kernel!(
    "lidar_blocks.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/exact_f64.wgsl",
        "shared/lidar_scan.wgsl",
        "shared/block_hash.wgsl",
        "shared/lidar_traverse.wgsl"
    ],
    [Read, ReadWrite, Read, ReadWrite]
);

/// The blocks `LIDAR_BLOCKS` found, listed from its table.
pub const LIDAR_FOUND: ShaderSource = kernel!(
    "lidar_found.wgsl",
    ["shared/dispatch.wgsl", "shared/lidar_scan.wgsl"],
    [Read, Read, ReadWrite, ReadWrite]
);

/// A LiDAR scan's listed blocks made positions and put in a hash table of their own.
pub const LIDAR_LISTED: ShaderSource = kernel!(
    "lidar_listed.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/lidar_scan.wgsl",
        "shared/block_hash.wgsl"
    ],
    [Read, Read, ReadWrite, ReadWrite, ReadWrite, Read, ReadWrite]
);

/// A LiDAR scan's (block, ray) pairs counted per block on the device (the CPU's walk, exact).
pub const LIDAR_COUNT: ShaderSource = kernel!(
    "lidar_count.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/exact_f64.wgsl",
        "shared/lidar_scan.wgsl",
        "shared/lidar_offsets.wgsl",
        "shared/block_hash.wgsl",
        "shared/lidar_traverse.wgsl",
        "shared/lidar_lookup.wgsl"
    ],
    [Read, Read, Read, ReadWrite, Read, Read, ReadWrite]
);

/// Each listed block's first pair from the counts (one workgroup).
pub const LIDAR_PREFIX: ShaderSource = kernel!(
    "lidar_prefix.wgsl",
    ["shared/lidar_scan.wgsl", "shared/workgroup_scan.wgsl"],
    [Read, Read, ReadWrite, ReadWrite]
);

/// A LiDAR scan's (block, ray) pairs listed on the device (the CPU's walk, exact).
pub const LIDAR_LIST: ShaderSource = kernel!(
    "lidar_list.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/exact_f64.wgsl",
        "shared/lidar_scan.wgsl",
        "shared/lidar_offsets.wgsl",
        "shared/block_hash.wgsl",
        "shared/lidar_traverse.wgsl",
        "shared/lidar_lookup.wgsl"
    ],
    [Read, Read, Read, ReadWrite, Read, Read, ReadWrite, ReadWrite]
);

/// Each listed block's rays sorted in workgroup memory (the CPU's order of the pairs).
pub const LIDAR_SORT: ShaderSource = kernel!(
    "lidar_sort.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/lidar_scan.wgsl",
        "shared/lidar_offsets.wgsl"
    ],
    [Read, Read, Read, Read, ReadWrite]
);

/// The rays of the blocks `LIDAR_SORT` leaves put in scan order by rank.
pub const LIDAR_RANK: ShaderSource = kernel!(
    "lidar_rank.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/lidar_scan.wgsl",
        "shared/lidar_offsets.wgsl"
    ],
    [Read, Read, Read, Read, ReadWrite, ReadWrite]
);

/// A LiDAR scan's (block, ray) pairs made on the device in exact f64 (the CPU's, bit for bit).
pub const LIDAR_PAIRS: ShaderSource = kernel!(
    "lidar_pairs.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/exact_f64.wgsl",
        "shared/lidar_scan.wgsl",
        "shared/lidar_offsets.wgsl"
    ],
    [Read, Read, Read, Read, Read, ReadWrite, ReadWrite]
);

/// The exact f64 operations on test cases (`crate::gpu::exact_f64`).
pub const EXACT_F64_CHECK: ShaderSource = kernel!(
    "exact_f64_check.wgsl",
    ["shared/dispatch.wgsl", "shared/exact_f64.wgsl"],
    [Read, ReadWrite]
);

/// TGV stereo dual step (`p` with the tensor, `q`).
pub const TGV_DUAL: ShaderSource = kernel!(
    "tgv_dual.wgsl",
    ["shared/dispatch.wgsl", "shared/tgv_common.wgsl"],
    [Uniform, ReadWrite, Read, ReadWrite, ReadWrite, ReadWrite]
);

/// A fresh TGV problem's state from its initial disparity, on the device.
pub const TGV_INIT: ShaderSource = kernel!(
    "tgv_init.wgsl",
    ["shared/dispatch.wgsl", "shared/tgv_common.wgsl"],
    [Uniform, ReadWrite, Read, ReadWrite, ReadWrite, ReadWrite]
);

/// TGV stereo primal step (`u` with the coupling, `v`) and over-relaxation.
pub const TGV_PRIMAL: ShaderSource = kernel!(
    "tgv_primal.wgsl",
    ["shared/dispatch.wgsl", "shared/tgv_common.wgsl"],
    [Uniform, ReadWrite, Read, ReadWrite, ReadWrite, ReadWrite]
);

/// Point-wise search of the stereo decoupling.
pub const TGV_POINTWISE: ShaderSource = kernel!(
    "tgv_pointwise.wgsl",
    ["shared/dispatch.wgsl", "shared/packed_bytes.wgsl"],
    [Uniform, Read, Read, Read, ReadWrite]
);

/// Census transform.
pub const CENSUS: ShaderSource = kernel!(
    "census.wgsl",
    ["shared/dispatch.wgsl", "shared/packed_bytes.wgsl"],
    [Uniform, Read, ReadWrite]
);

/// Census cost volume (Hamming distances).
pub const CENSUS_COST: ShaderSource = kernel!(
    "census_cost.wgsl",
    ["shared/dispatch.wgsl"],
    [Uniform, Read, Read, ReadWrite]
);

/// TGV-tensor's diffusion tensors from the left image, on the device.
pub const TGV_TENSORS: ShaderSource = kernel!(
    "tgv_tensors.wgsl",
    ["shared/dispatch.wgsl", "shared/packed_bytes.wgsl"],
    [Uniform, Read, ReadWrite]
);

/// Census costs summed over a window, on the device.
pub const COST_WINDOW: ShaderSource = kernel!(
    "cost_window.wgsl",
    ["shared/dispatch.wgsl", "shared/packed_bytes.wgsl"],
    [Uniform, Read, ReadWrite, ReadWrite]
);

/// The GPU variational matcher's disparities and their census costs, for the invalidation.
pub const TGV_COST_AT: ShaderSource = kernel!(
    "tgv_cost_at.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/packed_bytes.wgsl",
        "shared/rounding.wgsl",
        "shared/cost_slice.wgsl"
    ],
    [Uniform, Read, Read, ReadWrite]
);

/// The GPU variational matcher's occlusion flags, per row.
pub const TGV_OCCLUDED: ShaderSource = kernel!(
    "tgv_occluded.wgsl",
    ["shared/dispatch.wgsl", "shared/tgv_invalidate_common.wgsl"],
    [Uniform, Read, Read, Read, Read, ReadWrite, ReadWrite]
);

/// The GPU variational matcher's invalidation and confidences.
pub const TGV_INVALIDATE: ShaderSource = kernel!(
    "tgv_invalidate.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/packed_bytes.wgsl",
        "shared/rounding.wgsl",
        "shared/cost_slice.wgsl",
        "shared/exact_div.wgsl",
        "shared/float_bits.wgsl",
        "shared/tgv_invalidate_common.wgsl"
    ],
    [Uniform, Read, Read, Read, Read, ReadWrite, ReadWrite]
);

/// SGM's path aggregation along one direction, into the summed costs S.
pub const SGM_PATHS: ShaderSource = kernel!(
    "sgm_paths.wgsl",
    ["shared/packed_bytes.wgsl"],
    [Uniform, Read, Read, ReadWrite]
);

/// SGM's right-image winners (the left–right check's), from S.
pub const SGM_RIGHT: ShaderSource = kernel!(
    "sgm_right.wgsl",
    ["shared/dispatch.wgsl", "shared/sgm_select_common.wgsl"],
    [Uniform, Read, ReadWrite]
);

/// SGM's winner selection: each pixel's disparity and confidence, from S.
pub const SGM_SELECT: ShaderSource = kernel!(
    "sgm_select.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/packed_bytes.wgsl",
        "shared/exact_div.wgsl",
        "shared/float_bits.wgsl",
        "shared/sgm_select_common.wgsl"
    ],
    [Uniform, Read, Read, Read, ReadWrite, ReadWrite]
);

/// SGM's 3×3 median over valid neighbours.
pub const SGM_MEDIAN: ShaderSource = kernel!(
    "sgm_median.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/float_bits.wgsl",
        "shared/sgm_filter_common.wgsl"
    ],
    [Uniform, Read, ReadWrite]
);

/// Declares a pass of SGM's speckle filter (they share their bindings).
macro_rules! speckle_pass {
    ($file:literal) => {
        kernel!(
            $file,
            [
                "shared/dispatch.wgsl",
                "shared/float_bits.wgsl",
                "shared/sgm_filter_common.wgsl",
                "shared/speckle_common.wgsl"
            ],
            [Uniform, ReadWrite, ReadWrite, ReadWrite, ReadWrite]
        )
    };
}

/// Speckle filter, pass 1: runs of connected pixels per row.
pub const SGM_SPECKLE_RUNS: ShaderSource = speckle_pass!("sgm_speckle_runs.wgsl");

/// Speckle filter, pass 2: the runs of consecutive rows joined.
pub const SGM_SPECKLE_JOIN: ShaderSource = speckle_pass!("sgm_speckle_join.wgsl");

/// Speckle filter, pass 3: region sizes.
pub const SGM_SPECKLE_COUNT: ShaderSource = speckle_pass!("sgm_speckle_count.wgsl");

/// Speckle filter, pass 4: small regions removed.
pub const SGM_SPECKLE_CLEAR: ShaderSource = speckle_pass!("sgm_speckle_clear.wgsl");

/// TGV's initial disparity from SGM's, pass 1: holes filled along rows.
pub const TGV_FILL_ROWS: ShaderSource = kernel!(
    "tgv_fill_rows.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/float_bits.wgsl",
        "shared/sgm_filter_common.wgsl"
    ],
    [Uniform, Read, ReadWrite]
);

/// TGV's initial disparity from SGM's, pass 2: along columns, then the fallback.
pub const TGV_FILL_COLUMNS: ShaderSource = kernel!(
    "tgv_fill_columns.wgsl",
    [
        "shared/dispatch.wgsl",
        "shared/float_bits.wgsl",
        "shared/sgm_filter_common.wgsl"
    ],
    [Uniform, Read, ReadWrite]
);

/// Marching cubes, pass 0 over resident blocks: the samples made from the GPU pool.
pub const MC_SAMPLES: ShaderSource = kernel!(
    "mc_samples.wgsl",
    ["shared/dispatch.wgsl", "shared/exact_div.wgsl"],
    [Uniform, Read, Read, Read, ReadWrite]
);

/// Marching cubes, pass 1: triangles per meshed block.
pub const MC_COUNT: ShaderSource = kernel!(
    "mc_count.wgsl",
    ["shared/mc_uniforms.wgsl", "shared/mc_cubes.wgsl"],
    [Uniform, Read, Read, Read, ReadWrite]
);

/// Marching cubes, pass 2: every triangle corner's vertex and edge entry.
pub const MC_EMIT: ShaderSource = kernel!(
    "mc_emit.wgsl",
    [
        "shared/mc_uniforms.wgsl",
        "shared/mc_cubes.wgsl",
        "shared/block_hash.wgsl",
        "shared/workgroup_scan.wgsl"
    ],
    [Uniform, Read, Read, Read, Read, Read, ReadWrite, ReadWrite]
);

/// Marching cubes, pass 3: vertices created per meshed block.
pub const MC_FIRST: ShaderSource = kernel!(
    "mc_first.wgsl",
    ["shared/mc_uniforms.wgsl"],
    [Uniform, Read, Read, Read, ReadWrite]
);

/// Marching cubes, pass 4a: the blocks' first vertex numbers.
pub const MC_SCAN: ShaderSource = kernel!(
    "mc_scan.wgsl",
    ["shared/mc_uniforms.wgsl", "shared/workgroup_scan.wgsl"],
    [Uniform, Read, ReadWrite]
);

/// Marching cubes, pass 4b: the vertices, numbered in the CPU mesher's order.
pub const MC_ASSIGN: ShaderSource = kernel!(
    "mc_assign.wgsl",
    ["shared/mc_uniforms.wgsl", "shared/workgroup_scan.wgsl"],
    [Uniform, Read, Read, ReadWrite, Read, ReadWrite]
);

/// Marching cubes, pass 5: the triangles' vertex numbers.
pub const MC_LINK: ShaderSource = kernel!(
    "mc_link.wgsl",
    ["shared/dispatch.wgsl", "shared/mc_uniforms.wgsl"],
    [Uniform, Read, Read, ReadWrite]
);

/// The kernels that need f64 ([`crate::gpu::GpuContext::has_f64`]), compiled apart from [`ALL`].
pub const WITH_F64: &[ShaderSource] = &[BAND_BLOCKS, BAND_BLOCKS_KEYS];

/// Every kernel without f64 (one per line, so additions merge cleanly).
pub const ALL: &[ShaderSource] = &[
    // TV regularization.
    TV_DUAL,
    TV_PRIMAL,
    TV_RESIDENT_SLOTS,
    TV_RESIDENT_LIST,
    TV_RESIDENT_LINKS,
    TV_RESIDENT_GATHER,
    TV_RESIDENT_ENCODE,
    // Fusion.
    FUSE_DEPTH,
    FUSE_DEPTH_RESIDENT,
    FUSE_LIDAR,
    FUSE_LIDAR_RESIDENT,
    LIDAR_RAYS,
    LIDAR_BLOCKS,
    LIDAR_FOUND,
    LIDAR_LISTED,
    LIDAR_COUNT,
    LIDAR_PREFIX,
    LIDAR_LIST,
    LIDAR_SORT,
    LIDAR_RANK,
    LIDAR_PAIRS,
    EXACT_F64_CHECK,
    // The GPU hash table and pool.
    BLOCK_LOOKUP,
    FRAME_KEYS,
    TABLE_INSERT,
    TABLE_VISIBLE,
    BAND_SLICES,
    DISPARITY_DEPTH,
    CLEAR_UPDATED,
    FILL_SLOTS,
    TABLE_SCATTER,
    // Stereo.
    TGV_DUAL,
    TGV_PRIMAL,
    TGV_INIT,
    TGV_POINTWISE,
    CENSUS,
    CENSUS_COST,
    COST_WINDOW,
    TGV_TENSORS,
    TGV_COST_AT,
    TGV_OCCLUDED,
    TGV_INVALIDATE,
    SGM_PATHS,
    SGM_RIGHT,
    SGM_SELECT,
    SGM_MEDIAN,
    SGM_SPECKLE_RUNS,
    SGM_SPECKLE_JOIN,
    SGM_SPECKLE_COUNT,
    SGM_SPECKLE_CLEAR,
    TGV_FILL_ROWS,
    TGV_FILL_COLUMNS,
    // Marching cubes.
    MC_SAMPLES,
    MC_COUNT,
    MC_EMIT,
    MC_FIRST,
    MC_SCAN,
    MC_ASSIGN,
    MC_LINK,
];
