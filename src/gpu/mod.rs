//! GPU compute with wgpu (issue 6): the TV regulariser, depth-map and LiDAR fusion and the
//! stereo matcher as WGSL kernels (`shaders/`), each a twin of a CPU implementation that stays
//! the reference (`src/regularize/`, `src/fusion/`, `src/depth/`), and the GPU tier of the map.
//!
//! - [`GpuContext`]: adapter, device, queue and compiled pipelines; [`GpuContext::new`] returns
//!   `None` where no adapter exists (lavapipe, Mesa's software Vulkan, counts as one).
//! - [`DeviceChoice`]: the `--device auto|cpu|gpu` policy of the CLI.
//! - [`solve_gpu`] / [`regularize_layer_gpu`] / [`regularize_regions_gpu`]: Chambolle–Pock
//!   iterations on the GPU, globally or region by region (maps larger than one binding).
//! - [`integrate_depth_gpu`]: projective TSDF fusion of one depth frame on the GPU (blocks
//!   uploaded per call).
//! - [`ResidentMap`]: the GPU tier — depth blocks resident in a device pool across frames,
//!   found through a GPU hash table ([`BlockTable`]), spilling to RAM, written back on demand.
//! - [`integrate_lidar_gpu`]: ray-wise TSDF fusion of one LiDAR scan on the GPU (f32 walk in
//!   block-local voxel coordinates); [`integrate_lidar_f32`] is its CPU twin.
//! - Stereo (twin of `src/depth/`): [`TgvProblemGpu`] (TGV primal–dual iterations),
//!   [`pointwise_search_gpu`], [`census_transform_gpu`], [`cost_volume_gpu`], and the whole
//!   variational refinement [`refine_gpu`] / [`estimate_tgv_gpu`] / [`TgvMatcherGpu`].
//! - [`layout`]: `#[repr(C)]` buffer structs with WGSL twins; [`shaders`]: the assembled sources.
//!
//! What it does not do (yet): marching cubes stays on the CPU, and so does listing a frame's
//! blocks; LiDAR and TV upload their blocks per call; a TV problem larger than one storage
//! binding is an error unless solved in regions.

mod context;
mod fuse;
pub mod layout;
mod lidar;
mod resident;
pub mod shaders;
mod stereo;
mod tv;

pub use context::{DeviceChoice, GpuContext, WORKGROUP_SIZE};
pub use fuse::integrate_depth_gpu;
pub use lidar::{block_local_ray, integrate_lidar_f32, integrate_lidar_gpu, walk_block_ray};
pub use resident::{
    block_hash, lookup_table_on_gpu, BlockTable, ResidentMap, ResidentOptions, ResidentStats,
    SLOT_BYTES, SLOT_EMPTY, SLOT_TOMBSTONE,
};
pub use stereo::{
    census_transform_gpu, cost_volume_gpu, estimate_tgv_gpu, pointwise_search_gpu, refine_gpu,
    TgvMatcherGpu, TgvProblemGpu,
};
pub use tv::{regularize_layer_gpu, regularize_regions_gpu, solve_gpu};
