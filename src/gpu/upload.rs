//! Uploads through kept staging buffers. Every write of `GpuContext::write_buffer` and
//! `GpuContext::write_filled` goes into a chunk of host-visible memory that stays mapped
//! between frames, and the next submit copies it to its target on the device, before its own
//! commands (the queue writes' order and timing: what is written between two submits reaches
//! the device with the second, in the order written). Once the device has finished with a chunk
//! it is mapped again and reused, so a frame's inputs cost neither a staging buffer nor fresh
//! host memory. That is what `wgpu::Queue::write_buffer` costs per write: a staging buffer made
//! for the write and freed after it, fresh memory on a software device such as lavapipe.
//!
//! A chunk is in one of three states: mapped and open for writes, written and waiting for
//! its submit, or on its way back (its copies submitted, its mapping asked for). The first
//! write makes [`FIRST_CHUNKS`] chunks of [`CHUNK_BYTES`]; a write takes the first open chunk
//! with room, and where none has room (after a poll) it makes one of the write's size as a
//! power of two. Every chunk is a buffer created (counted). Chunks are kept up to
//! [`KEPT_BYTES`] in all; a write past that (a large TV solve's inputs) gets a chunk of its own
//! that is dropped once submitted, as the queue's staging buffer would be.

use super::context::GpuContext;
use super::readback::RING_LEN;
use super::traffic::bump;
use crate::{Error, Result};
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;

/// Size of a chunk, bytes, unless a write needs more: a 1241×376 frame's depth and colour.
pub const CHUNK_BYTES: u64 = 4 << 20;

/// Chunks made at the first write: one per submit of the frames the readback ring lets stay
/// in flight (at most two submits each), and the frame being written. The device finishes with
/// a frame's chunks before its readback is collected, so a drive makes no chunk after the first
/// write, and the count of buffers created does not depend on how far behind the device is.
pub const FIRST_CHUNKS: usize = 2 * RING_LEN + 2;

/// Bytes of chunks kept between submits at most.
pub const KEPT_BYTES: u64 = 64 << 20;

/// Where in a chunk writes start: a copy source offset the device reads at full speed.
const WRITE_ALIGN: u64 = 256;

/// Mapped, waiting for its mapping, or the mapping failed.
const MAPPED: u8 = 0;
const WAITING: u8 = 1;
const FAILED: u8 = 2;

/// The chunks and the copies written since the last submit (see the module documentation).
#[derive(Debug, Default)]
pub(crate) struct UploadRing {
    chunks: Vec<Chunk>,
    copies: Vec<PendingCopy>,
}

#[derive(Debug)]
struct Chunk {
    buffer: wgpu::Buffer,
    /// The next free byte, while mapped.
    cursor: u64,
    /// [`MAPPED`], [`WAITING`] or [`FAILED`], set by the mapping's callback.
    state: Arc<AtomicU8>,
    /// Whether writes in it wait for the next submit (then it is unmapped at that submit).
    written: bool,
    /// Whether it stays for later writes once submitted (else it is dropped then).
    kept: bool,
}

/// A write waiting for the next submit: `bytes` at `from` in a chunk, to `at` in `to`.
#[derive(Debug)]
struct PendingCopy {
    chunk: wgpu::Buffer,
    from: u64,
    to: wgpu::Buffer,
    at: u64,
    bytes: u64,
}

impl UploadRing {
    /// Writes `size` bytes (a multiple of 4) at `at` in `to`, the first `filled` of them by
    /// `fill` straight into a chunk's mapping and the rest zero; they reach the device with the
    /// next submit ([`UploadRing::record`]). Chunks are made through `ctx` (counted). `fill`
    /// must not use the context (the ring is locked while it runs).
    fn write(
        &mut self,
        ctx: &GpuContext,
        (to, at): (&wgpu::Buffer, u64),
        (size, filled): (u64, usize),
        fill: impl FnOnce(wgpu::WriteOnly<'_, [u8]>),
    ) {
        debug_assert!(size % wgpu::COPY_BUFFER_ALIGNMENT == 0 && filled as u64 <= size);
        if size == 0 {
            return;
        }
        if self.chunks.is_empty() {
            for _ in 0..FIRST_CHUNKS {
                self.make_chunk(ctx, CHUNK_BYTES);
            }
        }
        let mut fill = Some(fill);
        loop {
            (self.chunks).retain(|c| c.state.load(Ordering::Acquire) != FAILED);
            let (k, made) = match self.open_with_room(size) {
                Some(k) => (k, false),
                // Chunks the device finished with since the last look are mapped by a poll
                // (where polling fails the device is lost, and the next wait says so).
                None => match (ctx.poll_finished().ok()).and_then(|_| self.open_with_room(size)) {
                    Some(k) => (k, false),
                    None => (self.make_chunk(ctx, size), true),
                },
            };
            let chunk = &mut self.chunks[k];
            let from = chunk.cursor;
            let view = chunk.buffer.slice(from..from + size).get_mapped_range_mut();
            let Ok(mut view) = view else {
                // A chunk mapped at its creation always maps (else wgpu broke its contract).
                assert!(!made, "a new upload chunk could not be written: {view:?}");
                // Not mapped after all: never used again, and the write goes to another.
                tracing::warn!("an upload chunk could not be written: {view:?}");
                chunk.state.store(FAILED, Ordering::Release);
                continue;
            };
            let mut out = view.slice(..);
            if filled < size as usize {
                out.slice(filled..).fill(0);
            }
            (fill.take().expect("written once"))(out.into_slice(..filled));
            drop(view);
            chunk.cursor = (from + size).next_multiple_of(WRITE_ALIGN);
            chunk.written = true;
            self.copies.push(PendingCopy {
                chunk: chunk.buffer.clone(),
                from,
                to: to.clone(),
                at,
                bytes: size,
            });
            return;
        }
    }

    /// The first mapped chunk with `size` bytes free.
    fn open_with_room(&self, size: u64) -> Option<usize> {
        self.chunks.iter().position(|c| {
            c.state.load(Ordering::Acquire) == MAPPED && c.cursor + size <= c.buffer.size()
        })
    }

    /// A new mapped chunk for a write of `size` (counted by `ctx`); returns its index.
    fn make_chunk(&mut self, ctx: &GpuContext, size: u64) -> usize {
        let wanted = size.next_power_of_two().max(CHUNK_BYTES);
        let kept = self.kept_bytes() + wanted <= KEPT_BYTES;
        let buffer = ctx.create_buffer(&wgpu::BufferDescriptor {
            label: Some(if kept { "upload_chunk" } else { "upload_once" }),
            size: if kept { wanted } else { size },
            usage: wgpu::BufferUsages::MAP_WRITE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: true,
        });
        self.chunks.push(Chunk {
            buffer,
            cursor: 0,
            state: Arc::new(AtomicU8::new(MAPPED)),
            written: false,
            kept,
        });
        self.chunks.len() - 1
    }

    /// Whether writes wait for the next submit.
    pub(crate) fn has_pending(&self) -> bool {
        !self.copies.is_empty()
    }

    /// The copies of the writes since the last submit, recorded into `encoder` in the order
    /// written, and their chunks unmapped: submit `encoder` before the submit's own commands,
    /// then call [`UploadRing::submitted`].
    pub(crate) fn record(&mut self, encoder: &mut wgpu::CommandEncoder) {
        for c in self.copies.drain(..) {
            encoder.copy_buffer_to_buffer(&c.chunk, c.from, &c.to, c.at, c.bytes);
        }
        for chunk in self.chunks.iter_mut().filter(|c| c.written) {
            chunk.buffer.unmap();
        }
    }

    /// After the submit of [`UploadRing::record`]'s copies: the chunks written ask to be
    /// mapped again once the device has read them (kept ones; the others are dropped).
    pub(crate) fn submitted(&mut self) {
        self.chunks.retain(|c| c.kept || !c.written);
        for chunk in self.chunks.iter_mut().filter(|c| c.written) {
            chunk.written = false;
            chunk.cursor = 0;
            chunk.state.store(WAITING, Ordering::Release);
            let state = Arc::clone(&chunk.state);
            chunk.buffer.map_async(wgpu::MapMode::Write, .., move |r| {
                state.store(if r.is_ok() { MAPPED } else { FAILED }, Ordering::Release);
            });
        }
    }

    /// Bytes of chunks kept.
    fn kept_bytes(&self) -> u64 {
        (self.chunks.iter().filter(|c| c.kept))
            .map(|c| c.buffer.size())
            .sum()
    }
}

impl GpuContext {
    /// Writes `data` into `buffer` at `offset`, padded with zeros to a multiple of 4 bytes,
    /// through the kept staging memory (counted as an upload, padding included; it reaches the
    /// device with the next submit, before its commands: `src/gpu/upload.rs`). Nothing where
    /// `data` is empty.
    pub(crate) fn write_buffer(&self, buffer: &wgpu::Buffer, offset: u64, data: &[u8]) {
        let size = (data.len() as u64).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
        self.write_staged((buffer, offset), (size, data.len()), |mut out| {
            out.copy_from_slice(data)
        });
        bump(&self.traffic.upload_bytes, size);
    }

    /// `size` bytes at `at` in `to` through the kept staging memory, the first `filled` written
    /// by `fill` and the rest zero.
    fn write_staged(
        &self,
        to: (&wgpu::Buffer, u64),
        sizes: (u64, usize),
        fill: impl FnOnce(wgpu::WriteOnly<'_, [u8]>),
    ) {
        let mut ring = self.uploads.lock().unwrap_or_else(|e| e.into_inner());
        ring.write(self, to, sizes, fill);
    }

    /// Writes `bytes` bytes at the start of `buffer` through the kept staging memory, `fill`
    /// writing them straight into it (no copy on the host; counted as an upload; it reaches the
    /// device with the next submit). `bytes` is rounded up to the copy alignment, with zeros,
    /// and `fill` is given exactly `bytes` to write. `fill` must not use the context.
    pub(crate) fn write_filled(
        &self,
        buffer: &wgpu::Buffer,
        bytes: u64,
        fill: impl FnOnce(wgpu::WriteOnly<'_, [u8]>),
    ) -> Result<()> {
        let size = bytes.max(4).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
        if size > buffer.size() {
            return Err(Error::Gpu(format!(
                "{size} bytes do not fit the buffer written"
            )));
        }
        self.write_staged((buffer, 0), (size, bytes as usize), fill);
        bump(&self.traffic.upload_bytes, size);
        Ok(())
    }
}

/// What a test writes through the kept staging memory: `bytes` at an offset, padded with zeros
/// to a multiple of 4 (`GpuContext::write_buffer`), or at the start, padded likewise but to
/// at least 4 bytes (`GpuContext::write_filled`).
#[derive(Clone, Debug)]
pub enum TestWrite {
    At(u64, Vec<u8>),
    Filled(Vec<u8>),
}

/// Test driver: a zeroed buffer of `size` bytes written by each round's writes, one submit a
/// round (and a counted wait after every `wait_every`-th, as frames in flight are collected),
/// then read back.
pub fn written_through_ring(
    ctx: &GpuContext,
    size: u64,
    rounds: &[Vec<TestWrite>],
    wait_every: usize,
) -> Result<Vec<u8>> {
    let target = ctx.storage_zeroed("upload_test", size);
    for (k, round) in rounds.iter().enumerate() {
        for w in round {
            match w {
                TestWrite::At(at, bytes) => ctx.write_buffer(&target, *at, bytes),
                TestWrite::Filled(bytes) => {
                    let n = bytes.len() as u64;
                    ctx.write_filled(&target, n, |mut out| out.copy_from_slice(bytes))?
                }
            }
        }
        ctx.submit(ctx.encoder("upload_test"));
        if (k + 1) % wait_every.max(1) == 0 {
            ctx.wait()?;
        }
    }
    ctx.read_back_as::<u8>(&target, size as usize)
}

/// The chunks of kept staging memory `ctx` holds, and their bytes.
pub fn kept_chunks(ctx: &GpuContext) -> (usize, u64) {
    let ring = ctx.uploads.lock().unwrap_or_else(|e| e.into_inner());
    (
        ring.chunks.iter().filter(|c| c.kept).count(),
        ring.kept_bytes(),
    )
}
