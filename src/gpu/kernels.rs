//! Kernel compilation: each kernel's bind-group layout and pipeline, built from its
//! [`ShaderSource`] on first use ([`GpuContext::kernel`]) or ahead of a run, several at once
//! ([`GpuContext::compile_kernels`]), and cached by file name for the life of the context. A
//! driver may take tens of milliseconds per pipeline; compiling a run's kernels together,
//! before its first frame, keeps that out of the stages' times and runs the compilations on
//! several threads.

use super::shaders::ShaderSource;
use super::GpuContext;
use crate::{Error, Result};
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// A compiled kernel: its bind-group layout and pipeline.
#[derive(Debug)]
pub(crate) struct Kernel {
    /// The kernel's file name without `.wgsl`, naming it in device-time reports.
    pub(crate) name: &'static str,
    pub(crate) layout: wgpu::BindGroupLayout,
    pub(crate) pipeline: wgpu::ComputePipeline,
}

/// The compiled kernels of a context and what compiling them cost.
#[derive(Debug, Default)]
pub(crate) struct KernelCache {
    compiled: Mutex<HashMap<&'static str, Arc<Kernel>>>,
    /// Kernels compiled so far.
    count: AtomicU64,
    /// Wall time the callers waited for compilation, in nanoseconds.
    wait_ns: AtomicU64,
}

/// Kernels compiled by a context and the wall time spent waiting for them.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct KernelCompilation {
    /// Kernels compiled.
    pub kernels: u64,
    /// Wall time the callers waited for compilation (kernels compiled together count once).
    pub seconds: f64,
}

impl GpuContext {
    /// The kernel `src` (bindings as [`ShaderSource::bindings`] declares them), compiled on
    /// first use and cached (by file name) for the life of the context. Compilation errors
    /// become [`Error::Gpu`].
    pub(crate) fn kernel(&self, src: &ShaderSource) -> Result<Arc<Kernel>> {
        if let Some(k) = self.cached(src)? {
            return Ok(k);
        }
        let t = Instant::now();
        let k = self.compile(src)?;
        add_ns(&self.kernels.wait_ns, t);
        Ok(k)
    }

    /// Compiles the kernels of `sources` not compiled yet, each on its own thread (a driver
    /// compiles pipelines on the calling thread), and waits for them; where all are compiled,
    /// nothing (no thread spawned). The first error is returned; the kernels that compiled stay
    /// cached.
    pub fn compile_kernels(&self, sources: &[&ShaderSource]) -> Result<()> {
        let mut missing = Vec::with_capacity(sources.len());
        for &src in sources {
            if self.cached(src)?.is_none() {
                missing.push(src);
            }
        }
        if missing.is_empty() {
            return Ok(());
        }
        let t = Instant::now();
        let results: Vec<Result<()>> = std::thread::scope(|s| {
            let handles: Vec<_> = missing
                .iter()
                .map(|&src| s.spawn(move || self.kernel_uncounted(src)))
                .collect();
            handles
                .into_iter()
                .map(|h| {
                    h.join()
                        .unwrap_or_else(|_| Err(Error::Gpu("a kernel compilation panicked".into())))
                })
                .collect()
        });
        add_ns(&self.kernels.wait_ns, t);
        results.into_iter().collect()
    }

    /// How many kernels this context compiled and how long its callers waited for them.
    pub fn kernel_compilation(&self) -> KernelCompilation {
        KernelCompilation {
            kernels: self.kernels.count.load(Ordering::Relaxed),
            seconds: self.kernels.wait_ns.load(Ordering::Relaxed) as f64 * 1e-9,
        }
    }

    fn kernel_uncounted(&self, src: &ShaderSource) -> Result<()> {
        match self.cached(src)? {
            Some(_) => Ok(()),
            None => self.compile(src).map(drop),
        }
    }

    fn cached(&self, src: &ShaderSource) -> Result<Option<Arc<Kernel>>> {
        let cache = self.kernels.compiled.lock().map_err(|_| poisoned())?;
        Ok(cache.get(src.file).cloned())
    }

    /// Compiles `src` (outside the cache's lock, so that several compile at once) and caches
    /// it; where another thread cached it meanwhile, that one is kept.
    fn compile(&self, src: &ShaderSource) -> Result<Arc<Kernel>> {
        // Error scopes are per thread in wgpu: each compiling thread has its own.
        let scope = super::ErrorScopes::push(&self.device);
        let types: Vec<wgpu::BufferBindingType> = src.bindings.iter().map(|b| b.wgpu()).collect();
        let layout = bind_group_layout(&self.device, src.file, &types);
        let pipeline = compute_pipeline(&self.device, src, &layout);
        scope.pop(&format!("compiling {}", src.file))?;
        let name = src.file.strip_suffix(".wgsl").unwrap_or(src.file);
        let k = Arc::new(Kernel {
            name,
            layout,
            pipeline,
        });
        let mut cache = self.kernels.compiled.lock().map_err(|_| poisoned())?;
        let kept = cache.entry(src.file).or_insert_with(|| {
            self.kernels.count.fetch_add(1, Ordering::Relaxed);
            k
        });
        Ok(kept.clone())
    }
}

fn poisoned() -> Error {
    Error::Gpu("kernel cache poisoned".into())
}

fn add_ns(counter: &AtomicU64, since: Instant) {
    counter.fetch_add(since.elapsed().as_nanos() as u64, Ordering::Relaxed);
}

fn layout_entry(binding: u32, ty: wgpu::BufferBindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A compute bind-group layout whose binding `k` has type `types[k]`.
fn bind_group_layout(
    device: &wgpu::Device,
    label: &str,
    types: &[wgpu::BufferBindingType],
) -> wgpu::BindGroupLayout {
    let entries: Vec<wgpu::BindGroupLayoutEntry> = types
        .iter()
        .enumerate()
        .map(|(k, &ty)| layout_entry(k as u32, ty))
        .collect();
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &entries,
    })
}

/// The compute pipeline of kernel `src` (entry point `main`) over one bind group `layout`.
fn compute_pipeline(
    device: &wgpu::Device,
    src: &ShaderSource,
    layout: &wgpu::BindGroupLayout,
) -> wgpu::ComputePipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(src.file),
        source: wgpu::ShaderSource::Wgsl(src.source.into()),
    });
    let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(src.file),
        bind_group_layouts: &[Some(layout)],
        immediate_size: 0,
    });
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(src.file),
        layout: Some(&pl),
        module: &module,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    })
}
