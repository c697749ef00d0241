//! The wgpu device the kernels run on, its compiled pipelines, and small buffer helpers
//! (upload, readback, capacity checks, error scopes). It does not choose between CPU and GPU for
//! a stage: callers do that with [`DeviceChoice`].

use super::error_scopes::ErrorScopes;
use super::timing::{KernelTimer, PASS_BYTES};
use super::traffic::{bump, GpuTraffic, TrafficCounters};
use super::upload::UploadRing;
use crate::{Error, Result};
use wgpu::util::DeviceExt;

/// Invocations per workgroup of every kernel. Keep in sync with `WORKGROUP_SIZE` in
/// `shaders/shared/dispatch.wgsl` and the kernels' `@workgroup_size`.
pub const WORKGROUP_SIZE: u32 = 64;

/// Where a command runs its fusion and regularization.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DeviceChoice {
    /// The adapter, for the stages the records show faster on its class of adapter than on the
    /// CPU (`crate::backend::GpuStages::auto_rule`: today TV, stereo and marching cubes on a hardware
    /// GPU, nothing on a software one such as lavapipe, which is slower than the CPU code,
    /// `benches/gpu.rs`); the CPU for the rest, and for everything when no adapter exists.
    #[default]
    Auto,
    /// Always the CPU.
    Cpu,
    /// The GPU; an error when no adapter exists.
    Gpu,
}

impl DeviceChoice {
    /// Opens the GPU this choice asks for: `None` for the CPU. `Gpu` logs the device on one line
    /// (`device: …`) and fails when none exists; `Auto` returns any adapter (the backend decides
    /// its stages and logs them) and falls back to the CPU, saying why, when none exists or it
    /// fails to open.
    pub fn open(self) -> Result<Option<GpuContext>> {
        match self {
            DeviceChoice::Cpu => Ok(None),
            // Which stages run on it is the backend's rule (`crate::backend::GpuStages::
            // auto_rule`): this only finds the adapter.
            DeviceChoice::Auto => match GpuContext::new() {
                Ok(c) => {
                    if c.is_none() {
                        tracing::debug!("device: no GPU adapter found, running on the CPU");
                    }
                    Ok(c)
                }
                Err(e) => {
                    tracing::warn!("device: {e}; running on the CPU");
                    Ok(None)
                }
            },
            DeviceChoice::Gpu => match GpuContext::new()? {
                Some(c) => {
                    tracing::info!("device: GPU ({})", c.describe());
                    Ok(Some(c))
                }
                None => Err(Error::Gpu(
                    "--device gpu: no GPU adapter found (install a Vulkan or GL driver, e.g. \
                     Mesa's lavapipe: tools/setup.sh)"
                        .into(),
                )),
            },
        }
    }
}

impl std::str::FromStr for DeviceChoice {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "auto" => Ok(DeviceChoice::Auto),
            "cpu" => Ok(DeviceChoice::Cpu),
            "gpu" => Ok(DeviceChoice::Gpu),
            other => Err(Error::InvalidArgument(format!(
                "device must be auto, cpu or gpu, got {other:?}"
            ))),
        }
    }
}

/// A wgpu device and queue with the kernels' pipelines.
#[derive(Debug)]
pub struct GpuContext {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    binding_cap_bytes: Option<u64>,
    /// Whether kernels may use f64 (the device has it, and [`GpuContext::without_f64`] was
    /// not called).
    f64_kernels: bool,
    /// Kernels compiled on first use or ahead ([`GpuContext::compile_kernels`]), by file name.
    pub(super) kernels: super::kernels::KernelCache,
    /// What the context has cost so far ([`GpuContext::traffic`]).
    pub(super) traffic: TrafficCounters,
    /// Kernel timing, while on ([`GpuContext::start_kernel_timing`]).
    pub(super) timer: std::sync::Mutex<Option<KernelTimer>>,
    /// The writes waiting for the next submit, and the staging memory they are written into.
    pub(super) uploads: std::sync::Mutex<UploadRing>,
}

/// Readbacks above this many bytes are copied out of the mapping by several threads: the copy
/// into fresh host memory (first touch of every page) is what a large readback costs.
const PARALLEL_COPY_BYTES: usize = 4 << 20;

impl GpuContext {
    /// Opens the first adapter wgpu finds (Vulkan or GL; `WGPU_BACKEND` and
    /// `WGPU_ADAPTER_NAME` are honoured) with the adapter's own limits, and compiles the kernels.
    /// Returns `Ok(None)` when no adapter exists; an error when one exists but fails.
    pub fn new() -> Result<Option<Self>> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = match pollster::block_on(
            instance.request_adapter(&wgpu::RequestAdapterOptions::default()),
        ) {
            Ok(a) => a,
            Err(e) => {
                tracing::debug!("no GPU adapter: {e}");
                return Ok(None);
            }
        };
        let info = adapter.get_info();
        let limits = adapter.limits();
        // Timestamp queries where the adapter has them (kernel device times; nothing else), and
        // f64 arithmetic (the kernels of `shaders::WITH_F64`).
        let wanted = wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::SHADER_F64;
        let features = adapter.features() & wanted;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("denser"),
            required_features: features,
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| Error::Gpu(format!("opening {}: {e}", info.name)))?;
        let f64_kernels = device.features().contains(wgpu::Features::SHADER_F64);
        Ok(Some(GpuContext {
            device,
            queue,
            info,
            limits,
            binding_cap_bytes: None,
            f64_kernels,
            kernels: Default::default(),
            traffic: TrafficCounters::default(),
            timer: Default::default(),
            uploads: Default::default(),
        }))
    }

    /// The adapter and its backend, for summaries: "llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan)".
    pub fn name(&self) -> String {
        format!("{} ({:?})", self.info.name, self.info.backend)
    }

    /// The first adapter wgpu finds, described without opening a device: `(name and backend,
    /// whether it is a software adapter)`, or `None` when none exists. Loading the drivers costs
    /// memory that stays mapped for the process's life (llvmpipe's LLVM, ~80 MiB): a caller that
    /// may end up on the CPU probes in a child process (`denser probe-gpu`).
    pub fn probe() -> Option<(String, bool)> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter =
            pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions::default()))
                .ok()?;
        let info = adapter.get_info();
        Some((
            format!("{}, {:?}, {:?}", info.name, info.device_type, info.backend),
            info.device_type == wgpu::DeviceType::Cpu,
        ))
    }

    /// Adapter name, type and backend, in words.
    pub fn describe(&self) -> String {
        format!(
            "{}, {:?}, {:?}",
            self.info.name, self.info.device_type, self.info.backend
        )
    }

    /// Whether the device runs f64 arithmetic in kernels (`shaders::WITH_F64`).
    pub fn has_f64(&self) -> bool {
        self.f64_kernels
    }

    /// This context with its f64 kernels left unused, as on a device without f64 (tests of
    /// the paths such a device takes).
    pub fn without_f64(mut self) -> Self {
        self.f64_kernels = false;
        self
    }

    /// Whether the adapter is a software one (wgpu's `DeviceType::Cpu`, e.g. llvmpipe).
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// The device's limits (the adapter's, requested in full).
    pub fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }

    /// The largest storage-buffer binding the kernels use, bytes: the device's (128 MiB on
    /// llvmpipe) or a smaller cap set with [`GpuContext::with_max_binding_bytes`].
    pub fn max_binding_bytes(&self) -> u64 {
        let device = self
            .limits
            .max_storage_buffer_binding_size
            .min(self.limits.max_buffer_size);
        self.binding_cap_bytes.map_or(device, |c| c.min(device))
    }

    /// Caps every storage binding at `bytes` (bounding GPU memory per call, and letting tests
    /// exercise batching and capacity errors on small inputs).
    pub fn with_max_binding_bytes(mut self, bytes: u64) -> Self {
        self.binding_cap_bytes = Some(bytes);
        self
    }

    /// Fails with [`Error::GpuCapacity`] when a binding of `bytes` does not fit.
    pub(crate) fn check_binding(&self, what: &str, bytes: u64) -> Result<()> {
        let limit = self.max_binding_bytes();
        if bytes > limit {
            return Err(Error::GpuCapacity {
                what: what.to_string(),
                needed_bytes: bytes,
                limit_bytes: limit,
            });
        }
        Ok(())
    }

    /// Workgroups `(x, y)` covering `invocations` one-wide invocations of a
    /// [`WORKGROUP_SIZE`] kernel, split over y beyond the per-dimension limit.
    pub(crate) fn workgroups_2d(&self, invocations: u64) -> Result<(u32, u32)> {
        let groups = invocations.div_ceil(WORKGROUP_SIZE as u64).max(1);
        let max = self.limits.max_compute_workgroups_per_dimension as u64;
        let x = groups.min(max);
        let y = groups.div_ceil(x);
        if y > max {
            return Err(Error::GpuCapacity {
                what: "workgroups of one dispatch".into(),
                needed_bytes: groups,
                limit_bytes: max * max,
            });
        }
        Ok((x as u32, y as u32))
    }

    /// A storage buffer initialised with `data` (at least 4 bytes, as bindings must not be
    /// empty), usable as a copy source for readback.
    pub(crate) fn storage(&self, label: &str, data: &[u8]) -> wgpu::Buffer {
        let padded;
        let contents = if data.len() < 4 {
            padded = [0u8; 4];
            &padded[..]
        } else {
            data
        };
        self.note_created(label, contents.len() as u64);
        bump(&self.traffic.upload_bytes, contents.len() as u64);
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
            })
    }

    /// A storage buffer of `bytes` (rounded up to 4) whose contents `fill` writes in place,
    /// into the buffer's mapping at creation, usable as a copy source for readback: a large
    /// upload made by several threads with no host copy of its own (wgpu moves the mapping to
    /// the device at unmap).
    pub(crate) fn storage_filled(
        &self,
        label: &str,
        bytes: u64,
        fill: impl FnOnce(wgpu::WriteOnly<'_, [u8]>),
    ) -> Result<wgpu::Buffer> {
        let size = bytes.max(4).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
        let buffer = self.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: true,
        });
        {
            let mut view = buffer
                .slice(..)
                .get_mapped_range_mut()
                .map_err(|e| Error::Gpu(format!("writing {label}: {e}")))?;
            fill(view.slice(..bytes as usize));
        }
        buffer.unmap();
        bump(&self.traffic.upload_bytes, size);
        Ok(buffer)
    }

    /// [`GpuContext::storage_filled`] of `pieces` pieces of `N` bytes, piece `k` written by
    /// `fill(k, piece)` on every core (each piece is given exactly `N` bytes to write).
    pub(crate) fn storage_by_piece<const N: usize>(
        &self,
        label: &str,
        pieces: usize,
        fill: impl Fn(usize, &mut [u8; N]) + Sync,
    ) -> Result<wgpu::Buffer> {
        self.storage_filled(label, (pieces * N) as u64, |out| {
            fill_by_piece(out, true, fill)
        })
    }

    /// A zero-filled storage buffer of `bytes` (at least 4), usable as a copy source for
    /// readback: wgpu clears it on the device, with no upload. Only the census kernels use it:
    /// on an H200 their 60 MB cost volume took 3× less time than with uploaded zeros, whereas
    /// the point-wise search's output, the TGV target and the resident flags measured slower
    /// this way (`docs/bench/gpu.md`, run 5; cause not established).
    pub(crate) fn storage_zeroed(&self, label: &str, bytes: u64) -> wgpu::Buffer {
        self.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(4).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT),
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// A bind group whose binding `k` is the whole of `buffers[k]`.
    pub(crate) fn bind_group(
        &self,
        label: &str,
        layout: &wgpu::BindGroupLayout,
        buffers: &[&wgpu::Buffer],
    ) -> wgpu::BindGroup {
        bump(&self.traffic.bind_groups_created, 1);
        tracing::trace!(label, "GPU bind group created");
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .enumerate()
            .map(|(k, b)| wgpu::BindGroupEntry {
                binding: k as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout,
            entries: &entries,
        })
    }

    /// Records one dispatch of `kernel` over `invocations` one-wide invocations (a
    /// [`WORKGROUP_SIZE`] kernel indexed with `flat_index`) into `encoder`; while kernel timing
    /// is on ([`GpuContext::start_kernel_timing`]), its pass writes timestamps at both ends.
    pub(crate) fn record_dispatch(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        kernel: &super::Kernel,
        bind: &wgpu::BindGroup,
        invocations: u64,
    ) -> Result<()> {
        let (wx, wy) = self.workgroups_2d(invocations)?;
        bump(&self.traffic.dispatches, 1);
        let mut timer = self.timer.lock().unwrap_or_else(|e| e.into_inner());
        let timestamp_writes = timer.as_mut().and_then(|t| t.pass_writes(kernel.name));
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(kernel.name),
            timestamp_writes,
        });
        pass.set_pipeline(&kernel.pipeline);
        pass.set_bind_group(0, bind, &[]);
        pass.dispatch_workgroups(wx, wy, 1);
        Ok(())
    }

    /// A uniform buffer holding `data`.
    pub(crate) fn uniform(&self, label: &str, data: &[u8]) -> wgpu::Buffer {
        self.note_created(label, data.len() as u64);
        bump(&self.traffic.upload_bytes, data.len() as u64);
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: data,
                usage: wgpu::BufferUsages::UNIFORM,
            })
    }

    /// Counts a buffer created, and names it in the trace log (`RUST_LOG=denser::gpu=trace`
    /// shows which buffers a run makes past warm-up).
    fn note_created(&self, label: &str, bytes: u64) {
        bump(&self.traffic.buffers_created, 1);
        tracing::trace!(label, bytes, "GPU buffer created");
    }

    /// A buffer as `desc` describes it (counted).
    pub(crate) fn create_buffer(&self, desc: &wgpu::BufferDescriptor) -> wgpu::Buffer {
        self.note_created(desc.label.unwrap_or("unlabelled"), desc.size);
        self.device.create_buffer(desc)
    }

    /// A command encoder labelled `label`.
    pub(crate) fn encoder(&self, label: &str) -> wgpu::CommandEncoder {
        self.device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) })
    }

    /// Submits one command buffer (counted). While kernel timing is on and the buffer has
    /// timed passes, their timestamps are resolved at its end and read back after it (a wait
    /// that [`GpuTraffic`] does not count: timing changes what it measures).
    pub(crate) fn submit(&self, mut encoder: wgpu::CommandEncoder) {
        let mut timer = self.timer.lock().unwrap_or_else(|e| e.into_inner());
        let timed = timer.as_mut().map_or(0, |t| t.resolve_into(&mut encoder));
        bump(&self.traffic.submits, 1);
        // The writes since the last submit first, in the same submit.
        let mut uploads = self.uploads.lock().unwrap_or_else(|e| e.into_inner());
        if uploads.has_pending() {
            let mut copies = self.encoder("uploads");
            uploads.record(&mut copies);
            self.queue.submit([copies.finish(), encoder.finish()]);
            uploads.submitted();
        } else {
            self.queue.submit([encoder.finish()]);
        }
        drop(uploads);
        if let (Some(t), true) = (timer.as_mut(), timed > 0) {
            self.read_timestamps(t, timed);
        }
    }

    /// Reads back the resolved timestamps of the last submit's `passes` timed passes into `t`.
    fn read_timestamps(&self, t: &mut KernelTimer, passes: u32) {
        let staging = t.staging.clone();
        let slice = staging.slice(..passes as u64 * PASS_BYTES);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| drop(tx.send(r)));
        let polled = self.device.poll(wgpu::PollType::wait_indefinitely());
        let mapped = polled.is_ok() && matches!(rx.recv(), Ok(Ok(())));
        let view = if mapped {
            slice.get_mapped_range().ok()
        } else {
            None
        };
        match view {
            Some(view) => {
                let timestamps: Vec<u64> = bytemuck::pod_collect_to_vec(&view);
                t.record(&timestamps);
            }
            None => {
                tracing::warn!("kernel timing: the timestamps of a submit could not be read");
                t.drop_pending();
            }
        }
        if mapped {
            staging.unmap();
        }
    }

    /// Blocks until the device has finished everything submitted (counted as a wait).
    pub(crate) fn wait(&self) -> Result<()> {
        bump(&self.traffic.waits, 1);
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| Error::Gpu(format!("waiting for the GPU: {e}")))
    }

    /// Blocks until the device has finished everything submitted, without counting a wait:
    /// for a test or bench that measures what a frame costs once the device has kept up with
    /// the frames before it (a real GPU does, well within a frame's time).
    pub fn wait_idle_uncounted(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| Error::Gpu(format!("waiting for the GPU: {e}")))
    }

    /// Lets the device report finished work (mapped readbacks) without waiting for any: not a
    /// wait, and not counted as one.
    pub(crate) fn poll_finished(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::Poll)
            .map(|_| ())
            .map_err(|e| Error::Gpu(format!("polling the GPU: {e}")))
    }

    /// Counts `bytes` read back from the device (a readback outside this file).
    pub(crate) fn count_readback(&self, bytes: u64) {
        bump(&self.traffic.readback_bytes, bytes);
    }

    /// What this context has cost since it was opened (see [`GpuTraffic`]).
    pub fn traffic(&self) -> GpuTraffic {
        self.traffic.snapshot()
    }

    /// The first `count` elements of a buffer, read back straight into a typed vector (one
    /// copy from the mapped staging buffer; [`GpuContext::read_back_into`] for several buffers
    /// in one submission).
    pub(crate) fn read_back_as<T: bytemuck::Pod>(
        &self,
        buffer: &wgpu::Buffer,
        count: usize,
    ) -> Result<Vec<T>> {
        // Zeroed memory comes from the system untouched (calloc): the copying threads fault its
        // pages in.
        let mut out: Vec<T> = bytemuck::zeroed_vec(count);
        self.read_back_into(&mut [(buffer, bytemuck::cast_slice_mut(&mut out))])?;
        Ok(out)
    }

    /// A fusion kernel's `count` voxels and its update counter, read back in one submission
    /// straight into typed memory.
    pub(crate) fn read_back_voxels(
        &self,
        voxels: &wgpu::Buffer,
        counter: &wgpu::Buffer,
        count: usize,
    ) -> Result<(Vec<super::layout::GpuVoxel>, u32)> {
        let mut out: Vec<super::layout::GpuVoxel> = bytemuck::zeroed_vec(count);
        let mut updates = [0u32; 1];
        self.read_back_into(&mut [
            (voxels, bytemuck::cast_slice_mut(&mut out)),
            (counter, bytemuck::cast_slice_mut(&mut updates)),
        ])?;
        Ok((out, updates[0]))
    }

    /// Appends to `encoder` copies of the first `target.len()` bytes of each buffer into the
    /// kept staging buffer of `kept`, submits it, waits, and copies each result into its target:
    /// the work and its small results in one submit and one wait, with no buffer created once
    /// the staging buffer has grown to the size the results need.
    pub(crate) fn submit_and_read_back(
        &self,
        mut encoder: wgpu::CommandEncoder,
        kept: &mut super::kept::Kept,
        buffers: &mut [(&wgpu::Buffer, &mut [u8])],
    ) -> Result<()> {
        // Each result at an offset aligned for both copying and mapping.
        let align = wgpu::MAP_ALIGNMENT.max(wgpu::COPY_BUFFER_ALIGNMENT);
        let mut offsets = Vec::with_capacity(buffers.len());
        let mut end = 0u64;
        for (_, target) in buffers.iter() {
            offsets.push(end);
            end += (target.len() as u64).next_multiple_of(align);
        }
        let staging = kept.staging(self, end.max(align));
        for ((buf, target), &at) in buffers.iter().zip(&offsets) {
            let bytes = (target.len() as u64).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
            if bytes > 0 {
                encoder.copy_buffer_to_buffer(buf, 0, &staging, at, bytes);
            }
        }
        self.submit(encoder);
        let slice = staging.slice(..end.max(align));
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| drop(tx.send(r)));
        self.wait()?;
        rx.recv()
            .map_err(|_| Error::Gpu("the readback was never mapped".into()))?
            .map_err(|e| Error::Gpu(format!("mapping the readback buffer: {e}")))?;
        {
            let view = slice
                .get_mapped_range()
                .map_err(|e| Error::Gpu(format!("reading a mapped buffer: {e}")))?;
            for ((_, target), &at) in buffers.iter_mut().zip(&offsets) {
                let at = at as usize;
                copy_into(target, &view[at..at + target.len()]);
                bump(&self.traffic.readback_bytes, target.len() as u64);
            }
        }
        staging.unmap();
        Ok(())
    }

    /// Copies the first `target.len()` bytes of each buffer into its target, in one submission
    /// (no intermediate host copy). A target may be partly written when this fails.
    /// One staging buffer per buffer, created for the call: each stays within the binding
    /// limit its source had (TV's `p` alone may fill one), where
    /// [`GpuContext::submit_and_read_back`] packs small results into one kept buffer.
    pub(crate) fn read_back_into(&self, buffers: &mut [(&wgpu::Buffer, &mut [u8])]) -> Result<()> {
        let scope = ErrorScopes::push(&self.device);
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("read_back"),
            });
        let staging: Vec<wgpu::Buffer> = buffers
            .iter()
            .map(|(buf, target)| {
                let bytes = target.len() as u64;
                let s = self.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("staging"),
                    size: bytes.max(4),
                    usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                encoder.copy_buffer_to_buffer(buf, 0, &s, 0, bytes);
                s
            })
            .collect();
        self.submit(encoder);
        let (tx, rx) = std::sync::mpsc::channel();
        for (k, s) in staging.iter().enumerate() {
            let tx = tx.clone();
            s.slice(..)
                .map_async(wgpu::MapMode::Read, move |r| drop(tx.send((k, r))));
        }
        drop(tx);
        self.wait()?;
        for (k, r) in rx.iter() {
            r.map_err(|e| Error::Gpu(format!("mapping readback buffer {k}: {e}")))?;
        }
        scope.pop("reading results back")?;
        for (s, (_, target)) in staging.iter().zip(buffers.iter_mut()) {
            let view = s
                .slice(..)
                .get_mapped_range()
                .map_err(|e| Error::Gpu(format!("reading a mapped buffer: {e}")))?;
            copy_into(target, &view[..target.len()]);
            bump(&self.traffic.readback_bytes, target.len() as u64);
            drop(view);
            s.unmap();
        }
        Ok(())
    }
}

/// `src` copied into `dst` (of the same length); a large one by several threads, each touching
/// its own pages of `dst`.
fn copy_into(dst: &mut [u8], src: &[u8]) {
    use rayon::prelude::*;
    if src.len() < PARALLEL_COPY_BYTES {
        dst.copy_from_slice(src);
        return;
    }
    dst.par_chunks_mut(1 << 20)
        .zip(src.par_chunks(1 << 20))
        .for_each(|(d, s)| d.copy_from_slice(s));
}

/// Writes `out` in pieces of `N` bytes, piece `k` by `fill(k, piece)` (each piece is given
/// exactly `N` bytes to write), on every core where `parallel`.
pub(crate) fn fill_by_piece<const N: usize>(
    out: wgpu::WriteOnly<'_, [u8]>,
    parallel: bool,
    fill: impl Fn(usize, &mut [u8; N]) + Sync,
) {
    use rayon::prelude::*;
    let (slots, _) = out.into_chunks::<N>();
    let write = |(k, slot): (usize, wgpu::WriteOnly<'_, [u8; N]>)| {
        let mut piece = [0u8; N];
        fill(k, &mut piece);
        slot.write(piece);
    };
    if parallel {
        let slots: Vec<_> = slots.into_iter().collect();
        slots.into_par_iter().enumerate().for_each(write);
    } else {
        slots.into_iter().enumerate().for_each(write);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn copy_into_equals_the_source_on_both_sides_of_the_threshold() {
        for len in [
            0,
            5,
            PARALLEL_COPY_BYTES - 1,
            PARALLEL_COPY_BYTES,
            (9 << 20) + 3,
        ] {
            let src: Vec<u8> = (0..len)
                .map(|i| (i as u32).wrapping_mul(2_654_435_761).to_le_bytes()[3])
                .collect();
            let mut dst = vec![0u8; len];
            copy_into(&mut dst, &src);
            assert_eq!(dst, src, "{len} bytes");
        }
    }
}
