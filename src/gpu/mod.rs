//! GPU compute with wgpu (issue 6): the TV regulariser and depth-map fusion as WGSL kernels
//! (`shaders/`), each a twin of a CPU implementation that stays the reference
//! (`src/regularize/`, `src/fusion/depth.rs`), with the same data layout and arithmetic.
//!
//! - [`GpuContext`]: adapter, device, queue and compiled pipelines; [`GpuContext::new`] returns
//!   `None` where no adapter exists (lavapipe, Mesa's software Vulkan, counts as one).
//! - [`DeviceChoice`]: the `--device auto|cpu|gpu` policy of the CLI.
//! - [`solve_gpu`] / [`regularize_layer_gpu`] / [`regularize_regions_gpu`]: Chambolle–Pock
//!   iterations on the GPU, globally or region by region (maps larger than one binding).
//! - [`integrate_depth_gpu`]: projective TSDF fusion of one depth frame on the GPU.
//! - Stereo (twin of `src/depth/`): [`TgvProblemGpu`] (TGV primal–dual iterations),
//!   [`pointwise_search_gpu`], [`census_transform_gpu`], [`cost_volume_gpu`], and the whole
//!   variational refinement [`refine_gpu`] / [`estimate_tgv_gpu`] / [`TgvMatcherGpu`].
//! - [`layout`]: `#[repr(C)]` buffer structs with WGSL twins; [`shaders`]: the assembled sources.
//!
//! What it does not do (yet): LiDAR fusion, marching cubes and paging stay on the CPU; the map
//! is not resident on the GPU between calls (every call uploads its blocks and reads them back);
//! a TV problem larger than one storage binding is an error unless solved in regions.

mod context;
mod fuse;
pub mod layout;
mod resident;
pub mod shaders;
mod stereo;
mod tv;

pub use context::{DeviceChoice, GpuContext, WORKGROUP_SIZE};
pub use fuse::integrate_depth_gpu;
pub use resident::{
    block_hash, BlockTable, ResidentMap, ResidentOptions, ResidentStats, SLOT_BYTES, SLOT_EMPTY,
    SLOT_TOMBSTONE,
};
pub use stereo::{
    census_transform_gpu, cost_volume_gpu, estimate_tgv_gpu, pointwise_search_gpu, refine_gpu,
    TgvMatcherGpu, TgvProblemGpu,
};
pub use tv::{regularize_layer_gpu, regularize_regions_gpu, solve_gpu};
