//! Buffer structs shared with the WGSL kernels: `#[repr(C)]` + bytemuck, each with a WGSL twin
//! that says "keep in sync with src/gpu/layout.rs". Field order, sizes and padding must match
//! WGSL's uniform/storage layout rules (a `vec4<f32>` is 16-byte aligned; structs are padded to
//! a multiple of 16 bytes in uniform buffers). [`WGSL_STRUCTS`] lists them for the test that
//! compares their sizes with naga's reflection of the shaders.

use crate::grid::{Block, VOXELS_PER_BLOCK};
use bytemuck::{Pod, Zeroable};

/// Uniforms of `shaders/tv_dual.wgsl` and `shaders/tv_primal.wgsl` (WGSL twin: `TvUniforms` in
/// `shaders/shared/tv_common.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TvUniforms {
    /// Dual step σ.
    pub sigma: f32,
    /// Primal step τ.
    pub tau: f32,
    /// Data weight λ.
    pub lambda: f32,
    /// Relaxation θ.
    pub theta: f32,
    /// Number of voxels in the flat arrays (blocks × 512).
    pub voxel_count: u32,
    /// Padding to 32 bytes.
    pub pad: [u32; 3],
}

/// Uniforms of the kernels of TV over the resident blocks, `shaders/tv_resident_*.wgsl` (WGSL
/// twin: `TvResidentUniforms` in `shaders/shared/tv_resident_common.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct TvResidentUniforms {
    /// Hash-table entries − 1 (the capacity is a power of two).
    pub table_mask: u32,
    /// Blocks of the problem (the table's live entries).
    pub block_count: u32,
    /// `block_count` × 512.
    pub voxel_count: u32,
    /// Slots of the pool.
    pub slot_count: u32,
}

/// Uniforms of `shaders/fuse_depth.wgsl` (WGSL twin: `FuseUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct FuseUniforms {
    /// Camera-frame step of one voxel along world x (xyz), metres; w unused.
    pub axis_x: [f32; 4],
    /// Camera-frame step of one voxel along world y, metres.
    pub axis_y: [f32; 4],
    /// Camera-frame step of one voxel along world z, metres.
    pub axis_z: [f32; 4],
    /// Focal length x, pixels.
    pub fx: f32,
    /// Focal length y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Truncation μ, metres.
    pub mu: f32,
    /// 1/μ, 1/metres.
    pub inv_mu: f32,
    /// Voxels in this batch (blocks × 512).
    pub voxel_count: u32,
    /// 1 to fuse colour, 0 to keep it.
    pub use_color: u32,
    /// Nearest usable depth, metres ([`crate::fusion::DepthFusionParams`]).
    pub min_depth_m: f32,
    /// Farthest usable depth, metres.
    pub max_depth_m: f32,
}

/// Uniforms of `shaders/fuse_lidar.wgsl` (WGSL twin: `LidarUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct LidarUniforms {
    /// Blocks in this batch (one invocation each).
    pub block_count: u32,
    /// Truncation μ, metres.
    pub truncation_m: f32,
    /// Voxel edge, metres.
    pub voxel_size_m: f32,
    /// This pass applies rays `first_ray ..` of each block (counted from the block's first).
    pub first_ray: u32,
    /// At most this many rays per block in this pass.
    pub max_rays: u32,
    /// Padding to 32 bytes.
    pub pad: [u32; 3],
}

/// One (block, ray) pair of LiDAR fusion in the block's own frame: block-local voxel
/// coordinates (voxel `(x, y, z)` of the block covers `[x, x + 1) × [y, y + 1) × [z, z + 1)`),
/// so f32 keeps its precision at any distance from the world origin. Built in f64 on the CPU by
/// [`crate::fusion::block_local_ray`] and walked by [`crate::fusion::walk_block_ray`]; it goes
/// to the device as a [`GpuLidarPair`] (its own values) and the ray's [`GpuRayDir`] (shared by
/// the ray's pairs), which `shaders/shared/lidar_walk.wgsl` puts back together.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuLidarRay {
    /// Where the walk starts, block-local voxel coordinates.
    pub start_vox: [f32; 3],
    /// Unit direction of the ray (world axes, which are the block's).
    pub dir: [f32; 3],
    /// Signed distance to the return at the start point (range − distance along the ray),
    /// metres.
    pub sdf_start_m: f32,
    /// Length of the walk, voxels (negative: nothing to walk).
    pub len_vox: f32,
    /// The block-local cell the walk starts in, decided in f64 as the reference walk decides
    /// it (so a ray running exactly in a voxel face starts on the same side).
    pub start_cell: [i32; 3],
    /// Cells the walk visits at most: the Manhattan distance between its end cells (in f64),
    /// plus one, as the reference walk bounds itself.
    pub steps: u32,
    /// Grey level of the return (0–255).
    pub gray: u32,
}

/// A LiDAR ray's direction and grey level, once per ray (16 bytes; WGSL twin: `LidarRayDir` in
/// `shaders/shared/lidar_walk.wgsl`): the part of a [`GpuLidarRay`] its pairs share.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuRayDir {
    /// Unit direction (world axes), as [`GpuLidarRay::dir`].
    pub dir: [f32; 3],
    /// Grey level of the return (0–255).
    pub gray: u32,
}

/// A (block, ray) pair's own part of a [`GpuLidarRay`] (28 bytes; WGSL twin: `LidarPair` in
/// `shaders/shared/lidar_walk.wgsl`): the start, the signed distance there and the walk's
/// length, the start cell and step count packed in one word (three i8 and a u8), and the index
/// of the ray's [`GpuRayDir`]. Lossless: [`GpuLidarPair::unpack`] gives the ray back.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuLidarPair {
    /// As [`GpuLidarRay::start_vox`].
    pub start_vox: [f32; 3],
    /// As [`GpuLidarRay::sdf_start_m`].
    pub sdf_start_m: f32,
    /// As [`GpuLidarRay::len_vox`].
    pub len_vox: f32,
    /// Bytes 0–2: the start cell's x, y, z (i8); byte 3: the step count (u8).
    pub cells_steps: u32,
    /// Index of the ray's [`GpuRayDir`].
    pub ray: u32,
}

impl GpuLidarPair {
    /// `ray`'s own values, with `ray_index` its direction's index; `None` when its start cell
    /// or step count does not fit the packed word (a walk within one voxel of its block has
    /// cells in −2..=9 and at most 49 steps, so this does not happen for
    /// [`crate::fusion::block_local_ray`]'s pairs).
    pub fn pack(ray: &GpuLidarRay, ray_index: u32) -> Option<Self> {
        let cell = |a: usize| i8::try_from(ray.start_cell[a]).ok().map(|c| c as u8 as u32);
        let steps = u8::try_from(ray.steps).ok()? as u32;
        Some(GpuLidarPair {
            start_vox: ray.start_vox,
            sdf_start_m: ray.sdf_start_m,
            len_vox: ray.len_vox,
            cells_steps: cell(0)? | cell(1)? << 8 | cell(2)? << 16 | steps << 24,
            ray: ray_index,
        })
    }

    /// The [`GpuLidarRay`] this pair and its ray's `dir` make.
    pub fn unpack(&self, dir: &GpuRayDir) -> GpuLidarRay {
        let cell = |a: u32| (self.cells_steps >> (8 * a)) as u8 as i8 as i32;
        GpuLidarRay {
            start_vox: self.start_vox,
            dir: dir.dir,
            sdf_start_m: self.sdf_start_m,
            len_vox: self.len_vox,
            start_cell: [cell(0), cell(1), cell(2)],
            steps: self.cells_steps >> 24,
            gray: dir.gray,
        }
    }
}

/// Uniforms of `shaders/block_lookup.wgsl` (WGSL twin: `LookupUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct LookupUniforms {
    /// Keys to look up.
    pub key_count: u32,
    /// Hash-table capacity − 1 (the capacity is a power of two).
    pub mask: u32,
    /// Padding to 16 bytes.
    pub pad: [u32; 2],
}

/// Uniforms of `shaders/frame_keys.wgsl` (WGSL twin: `FrameKeyUniforms` there): a depth frame's
/// listed blocks as offsets from its origin block, and the affine map from an offset to the
/// block's base in 96-bit fixed point ([`crate::fusion::FrameKeys`] builds it).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct FrameKeyUniforms {
    /// The origin block's key (xyz); w: words per key (1 packed, 3 wide).
    pub origin: [i32; 4],
    /// Per camera axis c, the origin block's base coordinate in units of 2⁻⁶⁴ m, two's
    /// complement, as three 32-bit words (least significant first; w unused).
    pub base: [[u32; 4]; 3],
    /// Per world axis k and camera axis c (`steps[3k + c]`), the camera-frame step of one block
    /// along k, in the same fixed point.
    pub steps: [[u32; 4]; 9],
    /// Listed blocks.
    pub block_count: u32,
    /// Hash-table capacity − 1 (the capacity is a power of two).
    pub mask: u32,
    /// Blocks from this index on are fused only where a frame created them (base w = 1).
    pub first_unsettled: u32,
    /// Padding to a multiple of 16 bytes.
    pub pad: u32,
}

/// Uniforms of `shaders/band_slices.wgsl` (WGSL twin: `BandSliceUniforms` there): the image,
/// the usable depths' bits, and the band's thresholds in 64-bit fixed point (units of 2⁻⁴⁰ m,
/// least significant word first; `src/fusion/band_gpu.rs` derives them).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct BandSliceUniforms {
    /// Image width, height (pixels), tiles per row and tiles.
    pub size: [u32; 4],
    /// Bits of the least and the greatest usable depth (positive f32).
    pub usable_bits: [u32; 2],
    /// Slices the output holds.
    pub capacity: u32,
    /// 1 where a difference equal to `gap_mid` rounds to the f32 above 2μ.
    pub gap_tie_up: u32,
    /// Midpoint between the largest f32 ≤ 2μ and the next f32.
    pub gap_mid: [u32; 2],
    /// ⌊μ/2 · 2⁴⁰⌋.
    pub spread: [u32; 2],
}

/// Uniforms of `shaders/disparity_depth.wgsl` (WGSL twin: `DisparityDepthUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct DisparityDepthUniforms {
    /// Pixels.
    pub pixels: u32,
    /// f·B = M · 2^fb_exp.
    pub fb_exp: i32,
    /// M's low and high words (53 bits, the top one set).
    pub fb_words: [u32; 2],
}

/// Uniforms of `shaders/clear_updated.wgsl` (WGSL twin: `SlotListUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct SlotListUniforms {
    /// Slots listed.
    pub slot_count: u32,
    /// Padding to 16 bytes.
    pub pad: [u32; 3],
}

/// Uniforms of `shaders/fill_slots.wgsl` (WGSL twin: `SlotFillUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct SlotFillUniforms {
    /// Slots listed.
    pub slot_count: u32,
    /// Padding.
    pub pad: u32,
    /// The value written into every voxel of the listed slots ([`GpuVoxel`]'s two words).
    pub fill_tsdf_weight: u32,
    /// Its colour word.
    pub fill_color: u32,
}

/// Uniforms of `shaders/tgv_dual.wgsl` and `shaders/tgv_primal.wgsl` (WGSL twin: `TgvUniforms`
/// in `shaders/shared/tgv_common.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TgvUniforms {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// 1 for TV (`v ≡ 0`, no `q`), 0 for TGV.
    pub tv: u32,
    /// 1: `tgv_init.wgsl` also writes identity tensors (read by no other kernel).
    pub identity_tensors: u32,
    /// Dual step σ.
    pub sigma: f32,
    /// Primal step τ.
    pub tau: f32,
    /// α₁ (bound of `p`).
    pub alpha1: f32,
    /// α₂ (bound of `q`).
    pub alpha2: f32,
    /// τ/θ, the proximal weight of the coupling term.
    pub coupling: f32,
    /// Padding to 48 bytes.
    pub pad1: [u32; 3],
}

/// Uniforms of `shaders/tgv_pointwise.wgsl` (WGSL twin: `PointwiseUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PointwiseUniforms {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Disparity slices of the cost volume.
    pub num_disparities: u32,
    /// Bytes per packed cost: 1 (raw `u8` census costs) or 2 (`u16` window sums).
    pub cost_bytes: u32,
    /// Stride of `u` in its buffer: 1 (a plain array) or 3 (the TGV primal `[u, v1, v2]`).
    pub u_stride: u32,
    /// λ, per census bit.
    pub lambda: f32,
    /// θ of this round.
    pub theta: f32,
    /// Search reach `√(2θλ·C_max)`, pixels (computed on the CPU, as there).
    pub reach: f32,
    /// Disparity of slice 0, pixels.
    pub min_disparity_px: f32,
    /// Padding to 48 bytes.
    pub pad: [u32; 3],
}

/// Uniforms of `shaders/census.wgsl` (WGSL twin: `CensusUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct CensusUniforms {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Census window width, pixels (odd).
    pub window_width: u32,
    /// Census window height, pixels (odd).
    pub window_height: u32,
    /// 1 for the ternary census, 0 for the binary one.
    pub ternary: u32,
    /// Ternary similarity threshold, grey levels.
    pub threshold: u32,
    /// `u32` words per signature (2 per `u64` word of the CPU's `CensusImage`).
    pub words: u32,
    /// Padding to 32 bytes.
    pub pad: u32,
}

/// Uniforms of `shaders/census_cost.wgsl` (WGSL twin: `CostUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct CostUniforms {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Disparity slices.
    pub num_disparities: u32,
    /// Disparity of slice 0, pixels.
    pub min_disparity_px: i32,
    /// Cost where the right pixel is outside the image (the signature's bits).
    pub max_cost: u32,
    /// `u32` words per signature.
    pub words: u32,
    /// Entries of the volume (`width · height · num_disparities`).
    pub entries: u32,
    /// Padding to 32 bytes.
    pub pad: u32,
}

/// One voxel as the fusion kernel reads and writes it (WGSL twin: `GpuVoxel` in
/// `shaders/fuse_depth.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct GpuVoxel {
    /// Bits 0–15: quantised TSDF (`i16`); bits 16–23: weight and Ω (the block's packed byte);
    /// bit 24: [`UPDATED_BIT`], set by the kernel.
    pub tsdf_weight: u32,
    /// Colour `r | g << 8 | b << 16`.
    pub color: u32,
}

/// Set in [`GpuVoxel::tsdf_weight`] by the kernel when it updated the voxel.
pub const UPDATED_BIT: u32 = 1 << 24;

impl GpuVoxel {
    /// Packs a block's voxel fields.
    #[inline]
    pub fn pack(tsdf: i16, weight_omega: u8, color: [u8; 3]) -> Self {
        GpuVoxel {
            tsdf_weight: (tsdf as u16 as u32) | ((weight_omega as u32) << 16),
            color: pack_rgb(color),
        }
    }

    /// The quantised TSDF.
    #[inline]
    pub fn tsdf(&self) -> i16 {
        (self.tsdf_weight & 0xffff) as u16 as i16
    }

    /// The packed weight and Ω byte.
    #[inline]
    pub fn weight_omega(&self) -> u8 {
        ((self.tsdf_weight >> 16) & 0xff) as u8
    }

    /// Whether the kernel updated this voxel.
    #[inline]
    pub fn updated(&self) -> bool {
        self.tsdf_weight & UPDATED_BIT != 0
    }

    /// The colour.
    #[inline]
    pub fn rgb(&self) -> [u8; 3] {
        [
            (self.color & 0xff) as u8,
            ((self.color >> 8) & 0xff) as u8,
            ((self.color >> 16) & 0xff) as u8,
        ]
    }
}

/// Uniforms of `shaders/tgv_tensors.wgsl` (WGSL twin: `TensorUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TensorUniforms {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Edge weight γ.
    pub gamma: f32,
    /// Edge exponent β.
    pub beta: f32,
    /// Padding to 32 bytes.
    pub pad: [u32; 4],
}

/// Uniforms of `shaders/tgv_cost_at.wgsl` (WGSL twin: `CostAtUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct CostAtUniforms {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Disparity slices.
    pub num_disparities: u32,
    /// Disparity of slice 0, pixels.
    pub min_disparity_px: f32,
}

/// Uniforms of `shaders/cost_window.wgsl` (WGSL twin: `WindowUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct WindowUniforms {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Disparity slices.
    pub num_disparities: u32,
    /// Window radius, pixels.
    pub radius: u32,
    /// Entries of the volume.
    pub entries: u32,
    /// Padding to 32 bytes.
    pub pad: [u32; 3],
}

/// Uniforms of `shaders/mc_samples.wgsl` (WGSL twin: `McSampleUniforms` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct McSampleUniforms {
    /// Upload places.
    pub places: u32,
    /// 1: the regularized field's values, uploaded; 0: the pool's raw TSDF.
    pub regularized: u32,
    /// Padding to 16 bytes.
    pub pad: [u32; 2],
}

/// Uniforms of the marching-cubes kernels (WGSL twin: `McUniforms` in
/// `shaders/shared/mc_uniforms.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct McUniforms {
    /// Meshed blocks in the dispatch.
    pub blocks: u32,
    /// Upload place of the dispatch's first meshed block.
    pub first_block: u32,
    /// Triangle corners in the dispatch.
    pub corner_count: u32,
    /// Hash table entries − 1 (a power of two − 1).
    pub table_mask: u32,
    /// Words per sign case in the triangle table.
    pub table_stride: u32,
    /// Voxel edge, metres.
    pub voxel_size_m: f32,
    /// Padding to 32 bytes.
    pub pad: [u32; 2],
}

/// Uniforms of `shaders/sgm_paths.wgsl` (WGSL twin: `SgmPathUniforms` there): SGM's path
/// aggregation, every direction in one dispatch.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct SgmPathUniforms {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Disparity slices.
    pub num_disparities: u32,
    /// P1.
    pub p1: u32,
    /// P2.
    pub p2: u32,
    /// Intensity scale of the adaptive P2; 0: P2 throughout.
    pub p2_scale: u32,
    /// Directions in `dirs`.
    pub directions: u32,
    /// Path lines of all directions (one workgroup each).
    pub lines: u32,
    /// Per direction: its step `dx`, `dy` (pixels, each −1, 0 or 1), its first line and its
    /// number of lines.
    pub dirs: [[i32; 4]; 8],
}

/// Uniforms of `shaders/sgm_right.wgsl` and `shaders/sgm_select.wgsl` (WGSL twin:
/// `SgmSelectUniforms` in `shaders/shared/sgm_select_common.wgsl`): SGM's winner selection.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct SgmSelectUniforms {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Disparity slices.
    pub num_disparities: u32,
    /// Disparity of slice 0, pixels.
    pub min_disparity_px: i32,
    /// Sub-pixel fit: 0 none, 1 parabola, 2 equiangular.
    pub subpixel: u32,
    /// Radius of the raw costs' window of the fit; 0: the fit reads S.
    pub radius: u32,
    /// Largest left–right difference, slices; `0xffff`: no check.
    pub lr_max_diff: u32,
    /// `1 − uniqueness_ratio` as the CPU computes it (f32); 1: no uniqueness test.
    pub uniqueness_factor: f32,
}

/// Uniforms of SGM's post-filters and of the fill of TGV's initial disparity
/// (`shaders/sgm_median.wgsl`, `sgm_speckle_*.wgsl`, `tgv_fill_*.wgsl`; WGSL twin:
/// `SgmFilterUniforms` in `shaders/shared/sgm_filter_common.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct SgmFilterUniforms {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Speckle regions of at most this many pixels are removed.
    pub max_size_px: u32,
    /// Neighbours differing by at most this much belong to one speckle region, pixels.
    pub max_diff_px: f32,
    /// The fill's value where a column has no disparity, pixels.
    pub fallback_px: f32,
    /// Padding to 32 bytes.
    pub pad: [u32; 3],
}

/// Uniforms of the GPU variational matcher's invalidation (`shaders/tgv_occluded.wgsl`,
/// `shaders/tgv_invalidate.wgsl`; WGSL twin: `InvalidateUniforms` in
/// `shaders/shared/tgv_invalidate_common.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct InvalidateUniforms {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Disparity slices of the cost volume.
    pub num_disparities: u32,
    /// Disparity of slice 0, pixels.
    pub min_disparity_px: f32,
    /// Hole filling: 0 none, 1 visible, 2 all.
    pub hole_fill: u32,
    /// Occlusion tolerance, pixels.
    pub occlusion_tolerance_px: f32,
    /// `max_cost_fraction · max_cost` as the CPU computes it.
    pub max_bits: f32,
    /// The census's bits: the largest cost.
    pub max_cost: u32,
}

/// Every buffer struct the kernels share with the host: its WGSL name and the size of its Rust
/// twin, bytes. `tests/gpu.rs` checks each against the size naga computes for the WGSL struct
/// (and that every struct a kernel binds is listed here).
pub const WGSL_STRUCTS: &[(&str, usize)] = &[
    ("TvUniforms", std::mem::size_of::<TvUniforms>()),
    (
        "TvResidentUniforms",
        std::mem::size_of::<TvResidentUniforms>(),
    ),
    ("FuseUniforms", std::mem::size_of::<FuseUniforms>()),
    ("GpuVoxel", std::mem::size_of::<GpuVoxel>()),
    ("LookupUniforms", std::mem::size_of::<LookupUniforms>()),
    ("FrameKeyUniforms", std::mem::size_of::<FrameKeyUniforms>()),
    (
        "BandSliceUniforms",
        std::mem::size_of::<BandSliceUniforms>(),
    ),
    (
        "DisparityDepthUniforms",
        std::mem::size_of::<DisparityDepthUniforms>(),
    ),
    ("SlotListUniforms", std::mem::size_of::<SlotListUniforms>()),
    ("SlotFillUniforms", std::mem::size_of::<SlotFillUniforms>()),
    ("LidarUniforms", std::mem::size_of::<LidarUniforms>()),
    ("LidarPair", std::mem::size_of::<GpuLidarPair>()),
    ("LidarRayDir", std::mem::size_of::<GpuRayDir>()),
    ("TgvUniforms", std::mem::size_of::<TgvUniforms>()),
    (
        "PointwiseUniforms",
        std::mem::size_of::<PointwiseUniforms>(),
    ),
    ("CensusUniforms", std::mem::size_of::<CensusUniforms>()),
    ("CostUniforms", std::mem::size_of::<CostUniforms>()),
    ("McUniforms", std::mem::size_of::<McUniforms>()),
    ("McSampleUniforms", std::mem::size_of::<McSampleUniforms>()),
    ("WindowUniforms", std::mem::size_of::<WindowUniforms>()),
    ("TensorUniforms", std::mem::size_of::<TensorUniforms>()),
    ("CostAtUniforms", std::mem::size_of::<CostAtUniforms>()),
    ("SgmPathUniforms", std::mem::size_of::<SgmPathUniforms>()),
    (
        "SgmSelectUniforms",
        std::mem::size_of::<SgmSelectUniforms>(),
    ),
    (
        "SgmFilterUniforms",
        std::mem::size_of::<SgmFilterUniforms>(),
    ),
    (
        "InvalidateUniforms",
        std::mem::size_of::<InvalidateUniforms>(),
    ),
];

/// Appends `block`'s 512 voxels, packed, to `out` (the layout every fusion kernel reads).
pub(crate) fn pack_block_into(block: &Block, out: &mut Vec<GpuVoxel>) {
    out.extend(
        (0..VOXELS_PER_BLOCK)
            .map(|i| GpuVoxel::pack(block.tsdf[i], block.weight_omega[i], block.color[i])),
    );
}

/// Writes back into `block` the voxels a kernel marked updated in `voxels` (its 512, read back),
/// with [`Block::store_fused`], as `Block::fuse` stores them.
pub(crate) fn apply_updated(block: &mut Block, voxels: &[GpuVoxel]) {
    for (i, v) in voxels.iter().enumerate() {
        if !v.updated() {
            continue;
        }
        block.store_fused(i, v.tsdf(), v.weight_omega(), v.rgb());
    }
}

/// Packs an RGB triple as `r | g << 8 | b << 16`.
#[inline]
pub fn pack_rgb(c: [u8; 3]) -> u32 {
    c[0] as u32 | ((c[1] as u32) << 8) | ((c[2] as u32) << 16)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voxel_packing_round_trips() {
        for (t, wo, c) in [
            (-32767i16, 0x80u8 | 127, [255u8, 0, 7]),
            (0, 0, [0, 0, 0]),
            (12345, 0x85, [1, 2, 3]),
            (-1, 0xff, [255, 255, 255]),
        ] {
            let v = GpuVoxel::pack(t, wo, c);
            assert_eq!((v.tsdf(), v.weight_omega(), v.rgb()), (t, wo, c));
            assert!(!v.updated());
        }
    }
}
