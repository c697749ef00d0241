//! The GPU device layer (wgpu): what every GPU stage shares, and nothing stage-specific. The
//! host code of each kernel lives beside its CPU twin, which stays the reference:
//! `src/fusion/depth_gpu.rs` and `lidar_gpu.rs` (fusion), `src/regularize/gpu.rs` (TV),
//! `src/depth/gpu.rs` (stereo); the kernels are in `shaders/`.
//!
//! - [`GpuContext`]: adapter, device, queue, the kernel cache (`kernels.rs`: compiled on first
//!   use or ahead, several at once) and buffer helpers, and the
//!   counters of what the device costs ([`GpuTraffic`]: bytes up and down, submits, waits,
//!   buffers and bind groups created, dispatches);
//!   [`GpuContext::new`] returns `None` where no adapter exists (lavapipe, Mesa's software
//!   Vulkan, counts as one). [`DeviceChoice`] is the `--device auto|cpu|gpu` policy.
//! - [`shaders`]: every kernel declared once (file, shared files, bindings), assembled at compile
//!   time; [`layout`]: the `#[repr(C)]` buffer structs with their WGSL twins.
//! - [`upload`]: every queue write goes through kept, mapped staging chunks that the next
//!   submit copies from, so a write makes no staging buffer of its own.
//! - [`resident`]: the GPU tier of the map: blocks resident in a device pool between frames,
//!   found through a GPU hash table, written back to RAM on demand.
//!
//! What it does not do: choose between CPU and GPU for a stage (`crate::backend` does, once per
//! run), or know about chunks, files or the pager.

mod context;
mod error_scopes;
pub mod exact_f64;
pub(crate) mod kept;
mod kernels;
pub mod layout;
pub(crate) mod readback;
pub mod resident;
pub mod shaders;
pub mod timing;
mod traffic;
pub mod upload;

pub use context::{DeviceChoice, GpuContext, WORKGROUP_SIZE};
pub(crate) use error_scopes::ErrorScopes;
pub(crate) use kernels::Kernel;
pub use kernels::KernelCompilation;
pub use resident::{ResidentMap, ResidentOptions, ResidentStats};
pub use timing::{thread_cpu_s, KernelTime};
pub use traffic::{GpuTraffic, StageTally};
