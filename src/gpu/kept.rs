//! Buffers and bind groups a stage keeps between calls, by name, so that a frame creates nothing
//! once the first frames have sized them: a buffer grows (to the next power of two, never
//! shrinking) when a call needs more, and a bind group is rebuilt only when one of its buffers
//! is not the one it was built over. Inputs are written into kept buffers through the queue
//! ([`GpuContext::write_buffer`]); small results come back through a kept staging buffer
//! ([`GpuContext::submit_and_read_back`]).

use super::context::GpuContext;
use std::collections::HashMap;

/// Smallest kept buffer, bytes.
const MIN_KEPT_BYTES: u64 = 256;

/// A stage's kept buffers and bind groups (see the module documentation).
#[derive(Debug, Default)]
pub(crate) struct Kept {
    buffers: HashMap<&'static str, wgpu::Buffer>,
    binds: HashMap<&'static str, (Vec<wgpu::Buffer>, wgpu::BindGroup)>,
}

impl Kept {
    /// The kept buffer `name`, at least `bytes` long with `usage` (created, or replaced by a
    /// larger one, when it is smaller; the contents of a replaced buffer are not copied).
    pub(crate) fn buffer(
        &mut self,
        ctx: &GpuContext,
        name: &'static str,
        bytes: u64,
        usage: wgpu::BufferUsages,
    ) -> wgpu::Buffer {
        if let Some(b) = self.buffers.get(name) {
            if b.size() >= bytes && b.usage() == usage {
                return b.clone();
            }
        }
        // Grown to a power of two, but never past the largest binding where the need itself
        // fits (the whole buffer is bound; a need past it fails where the caller checks it).
        let limit = ctx.max_binding_bytes();
        let size = bytes
            .max(MIN_KEPT_BYTES)
            .next_power_of_two()
            .min(limit.max(bytes))
            .next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
        let b = ctx.create_buffer(&wgpu::BufferDescriptor {
            label: Some(name),
            size,
            usage,
            mapped_at_creation: false,
        });
        self.buffers.insert(name, b.clone());
        b
    }

    /// The kept storage buffer `name` holding `data` at its start (written through the queue;
    /// it reaches the device with the next submit).
    pub(crate) fn storage_with(
        &mut self,
        ctx: &GpuContext,
        name: &'static str,
        data: &[u8],
    ) -> wgpu::Buffer {
        let b = self.buffer(ctx, name, data.len() as u64, STORAGE);
        ctx.write_buffer(&b, 0, data);
        b
    }

    /// The kept storage buffer `name` with `bytes` bytes at its start written by `fill` straight
    /// into the kept staging memory ([`GpuContext::write_filled`]).
    pub(crate) fn storage_filled(
        &mut self,
        ctx: &GpuContext,
        name: &'static str,
        bytes: u64,
        fill: impl FnOnce(wgpu::WriteOnly<'_, [u8]>),
    ) -> crate::Result<wgpu::Buffer> {
        let b = self.buffer(ctx, name, bytes.max(4), STORAGE);
        ctx.write_filled(&b, bytes, fill)?;
        Ok(b)
    }

    /// The kept storage buffer `name` holding `pieces` pieces of `N` bytes, piece `k` written by
    /// `fill(k, piece)` straight into the kept staging memory: on every core, unless the caller
    /// is a thread of the pool already (the staging memory is locked while `fill` runs, and a
    /// pool thread waiting there for its pieces could take up a job that writes to it too).
    pub(crate) fn storage_by_piece<const N: usize>(
        &mut self,
        ctx: &GpuContext,
        name: &'static str,
        pieces: usize,
        fill: impl Fn(usize, &mut [u8; N]) + Sync,
    ) -> crate::Result<wgpu::Buffer> {
        let parallel = rayon::current_thread_index().is_none();
        self.storage_filled(ctx, name, (pieces * N) as u64, |out| {
            super::context::fill_by_piece(out, parallel, fill)
        })
    }

    /// The kept uniform buffer `name` holding `data`.
    pub(crate) fn uniform_with(
        &mut self,
        ctx: &GpuContext,
        name: &'static str,
        data: &[u8],
    ) -> wgpu::Buffer {
        let usage = wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST;
        let b = self.buffer(ctx, name, data.len() as u64, usage);
        ctx.write_buffer(&b, 0, data);
        b
    }

    /// The kept storage buffer `name` of at least `bytes`, contents unspecified (a kernel
    /// writes it, or the caller clears it in its encoder).
    pub(crate) fn scratch(
        &mut self,
        ctx: &GpuContext,
        name: &'static str,
        bytes: u64,
    ) -> wgpu::Buffer {
        self.buffer(ctx, name, bytes, STORAGE)
    }

    /// The kept storage buffer `name` holding the first `bytes` of `source` (a multiple of 4),
    /// copied on the device in `encoder` (nothing goes up).
    pub(crate) fn storage_copied(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        name: &'static str,
        (source, bytes): (&wgpu::Buffer, u64),
    ) -> wgpu::Buffer {
        let b = self.buffer(ctx, name, bytes.max(4), STORAGE);
        encoder.copy_buffer_to_buffer(source, 0, &b, 0, bytes);
        b
    }

    /// The kept staging buffer for readbacks of up to `bytes`.
    pub(crate) fn staging(&mut self, ctx: &GpuContext, bytes: u64) -> wgpu::Buffer {
        let usage = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
        self.buffer(ctx, "readback_staging", bytes, usage)
    }

    /// The kept bind group `name` over `buffers` (binding `k` the whole of `buffers[k]`),
    /// rebuilt when any buffer differs from the last call's.
    pub(crate) fn bind_group(
        &mut self,
        ctx: &GpuContext,
        name: &'static str,
        layout: &wgpu::BindGroupLayout,
        buffers: &[&wgpu::Buffer],
    ) -> wgpu::BindGroup {
        if let Some((over, bind)) = self.binds.get(name) {
            if over.len() == buffers.len() && over.iter().zip(buffers).all(|(a, b)| a == *b) {
                return bind.clone();
            }
        }
        let bind = ctx.bind_group(name, layout, buffers);
        let over = buffers.iter().map(|b| (*b).clone()).collect();
        self.binds.insert(name, (over, bind.clone()));
        bind
    }
}

/// Uniforms that change between the dispatches of one submit: their variants written once as a
/// table (a kept storage buffer), and variant `k` copied on the device into the bound uniform
/// buffer before the dispatches that read it ([`UniformTable::select`]). A queue write would
/// not do: every queue write lands before the submit, so the last one would serve every
/// dispatch.
pub(crate) struct UniformTable {
    table: wgpu::Buffer,
    uniforms: wgpu::Buffer,
    entry_bytes: u64,
}

impl Kept {
    /// The kept uniform buffer `uniforms_name` (holding `variants[0]`) with the kept table
    /// `table_name` of `variants` (at least one).
    pub(crate) fn uniform_table<T: bytemuck::Pod>(
        &mut self,
        ctx: &GpuContext,
        (table_name, uniforms_name): (&'static str, &'static str),
        variants: &[T],
    ) -> UniformTable {
        let table = self.storage_with(ctx, table_name, bytemuck::cast_slice(variants));
        let uniforms = self.uniform_with(ctx, uniforms_name, bytemuck::bytes_of(&variants[0]));
        UniformTable {
            table,
            uniforms,
            entry_bytes: std::mem::size_of::<T>() as u64,
        }
    }
}

impl UniformTable {
    /// The uniform buffer the kernels bind.
    pub(crate) fn uniforms(&self) -> &wgpu::Buffer {
        &self.uniforms
    }

    /// Records the copy of variant `k` into the uniform buffer.
    pub(crate) fn select(&self, encoder: &mut wgpu::CommandEncoder, k: usize) {
        let at = k as u64 * self.entry_bytes;
        encoder.copy_buffer_to_buffer(&self.table, at, &self.uniforms, 0, self.entry_bytes);
    }
}

const STORAGE: wgpu::BufferUsages = wgpu::BufferUsages::STORAGE
    .union(wgpu::BufferUsages::COPY_SRC)
    .union(wgpu::BufferUsages::COPY_DST);

/// Buffers lent to holders that outlive a call (a depth frame read ahead of its fusion) and
/// handed back when the holder drops them ([`Pooled`]), so that a steady stream of holders
/// creates no buffer once the pool holds as many as are alive at once. Clones share the pool.
#[derive(Debug, Clone, Default)]
pub(crate) struct BufferPool {
    free: std::sync::Arc<std::sync::Mutex<Vec<wgpu::Buffer>>>,
}

/// A buffer lent by a [`BufferPool`], handed back when dropped.
#[derive(Debug)]
pub(crate) struct Pooled {
    buffer: wgpu::Buffer,
    pool: BufferPool,
}

impl BufferPool {
    /// A storage buffer of at least `bytes` (a multiple of 4) holding the first `bytes` of
    /// `source`, copied on the device in `encoder`: a free one of the pool where one is large
    /// enough, else one created.
    pub(crate) fn copy_of(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        label: &'static str,
        (source, bytes): (&wgpu::Buffer, u64),
    ) -> Pooled {
        let lent = {
            let mut free = self.free.lock().unwrap_or_else(|e| e.into_inner());
            let at = free.iter().position(|b| b.size() >= bytes);
            at.map(|k| free.swap_remove(k))
        };
        let buffer = lent.unwrap_or_else(|| {
            ctx.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes.max(4),
                usage: STORAGE,
                mapped_at_creation: false,
            })
        });
        if bytes > 0 {
            encoder.copy_buffer_to_buffer(source, 0, &buffer, 0, bytes);
        }
        Pooled {
            buffer,
            pool: self.clone(),
        }
    }
}

impl Pooled {
    /// The buffer lent.
    pub(crate) fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }
}

impl Drop for Pooled {
    fn drop(&mut self) {
        // Holders drop the buffer once the work over it is submitted: that work comes before
        // any later holder's in queue order, so the next holder may overwrite it.
        let mut free = self.pool.free.lock().unwrap_or_else(|e| e.into_inner());
        free.push(self.buffer.clone());
    }
}
