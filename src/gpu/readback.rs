//! Readbacks that arrive later: a frame copies its small results (counters, flags) into one of
//! a ring of kept staging buffers at the end of its own submit and asks for it to be mapped,
//! then goes on without waiting. A later frame (or anything that needs the results) collects
//! it: [`LateReadback::is_ready`] after [`GpuContext::poll_finished`] says whether the device
//! got there, and [`LateReadback::collect`] copies it out, waiting (one counted wait) only if
//! it did not.

use super::context::GpuContext;
use super::kept::Kept;
use crate::{Error, Result};
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::Arc;

/// Staging buffers in the ring: frames in flight before the oldest must be collected.
pub(crate) const RING_LEN: usize = 3;

/// Smallest staging buffer of the ring, bytes: the flags of 16 k blocks, so that the ring's
/// buffers are made in the first frames and not again as frames list more blocks.
const MIN_RING_BYTES: u64 = 64 << 10;

const RING_NAMES: [&str; RING_LEN] = ["late_readback_0", "late_readback_1", "late_readback_2"];

/// Not yet mapped, mapped, the mapping failed, or the work that fills it not yet submitted.
const WAITING: u8 = 0;
const MAPPED: u8 = 1;
const FAILED: u8 = 2;
const UNSUBMITTED: u8 = 3;

/// The ring's staging buffers, kept between frames (grown, counted, when a frame needs more).
#[derive(Debug, Default)]
pub(crate) struct ReadbackRing {
    kept: Kept,
    next: usize,
    /// Per staging buffer: whether a readback not yet collected (nor dropped) holds it. A
    /// submit that comes to a held one takes a buffer of its own (created, counted) instead.
    held: [Arc<AtomicBool>; RING_LEN],
}

/// Results on their way back from the device (see the module documentation).
#[derive(Debug)]
pub(crate) struct LateReadback {
    staging: wgpu::Buffer,
    /// Per result: its offset in `staging` and its length, bytes.
    parts: Vec<(u64, usize)>,
    mapped_bytes: u64,
    state: Arc<AtomicU8>,
    /// Set once the results were copied out and the buffer unmapped.
    collected: bool,
    /// The ring's mark that this readback holds its staging buffer, cleared when it is dropped.
    held: Arc<AtomicBool>,
}

impl ReadbackRing {
    /// Appends to `encoder` copies of the first `lens[k]` bytes of `buffers[k]` into the next
    /// staging buffer of the ring, submits it and asks for the staging buffer to be mapped.
    /// A caller that keeps at most [`RING_LEN`] of these uncollected at once creates no buffer
    /// once the ring's are made (a staging buffer is reused by the call `RING_LEN` later where
    /// its readback was collected or dropped by then).
    pub(crate) fn submit(
        &mut self,
        ctx: &GpuContext,
        mut encoder: wgpu::CommandEncoder,
        buffers: &[(&wgpu::Buffer, usize)],
    ) -> LateReadback {
        let readback = self.record(ctx, &mut encoder, buffers);
        submit_then_map(ctx, encoder, readback)
    }

    /// As [`ReadbackRing::submit`] with one result: the `runs` of `src` (each `(offset,
    /// bytes)`, multiples of 4) laid end to end.
    pub(crate) fn submit_runs(
        &mut self,
        ctx: &GpuContext,
        encoder: wgpu::CommandEncoder,
        src: &wgpu::Buffer,
        runs: &[(u64, u64)],
    ) -> LateReadback {
        let total: u64 = runs.iter().map(|(_, bytes)| bytes).sum();
        let mut encoder = encoder;
        let copies = |encoder: &mut wgpu::CommandEncoder, staging: &wgpu::Buffer, parts: &[_]| {
            let (mut at, _): (u64, usize) = parts[0];
            for &(offset, bytes) in runs {
                encoder.copy_buffer_to_buffer(src, offset, staging, at, bytes);
                at += bytes;
            }
        };
        let readback = self.record_copies(ctx, &mut encoder, &[total as usize], copies);
        submit_then_map(ctx, encoder, readback)
    }

    /// As [`ReadbackRing::submit`], but only recorded: the copies go into `encoder`, which the
    /// caller submits with other work (one submit instead of two), then calls
    /// [`LateReadback::submitted`]. Collecting it before then is an error, not a wait.
    pub(crate) fn record(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        buffers: &[(&wgpu::Buffer, usize)],
    ) -> LateReadback {
        let lens: Vec<usize> = buffers.iter().map(|(_, len)| *len).collect();
        self.record_copies(ctx, encoder, &lens, |encoder, staging, parts| {
            for ((buf, len), (at, _)) in buffers.iter().zip(parts) {
                let bytes = (*len as u64).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
                if bytes > 0 {
                    encoder.copy_buffer_to_buffer(buf, 0, staging, *at, bytes);
                }
            }
        })
    }

    /// Lays results of `lens` bytes out in the next staging buffer and records `copies` into
    /// `encoder` (given the staging buffer and each result's offset and length); the readback
    /// waits for [`LateReadback::submitted`].
    fn record_copies(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        lens: &[usize],
        copies: impl FnOnce(&mut wgpu::CommandEncoder, &wgpu::Buffer, &[(u64, usize)]),
    ) -> LateReadback {
        let align = wgpu::MAP_ALIGNMENT.max(wgpu::COPY_BUFFER_ALIGNMENT);
        let mut parts = Vec::with_capacity(lens.len());
        let mut end = 0u64;
        for len in lens {
            parts.push((end, *len));
            end += (*len as u64).next_multiple_of(align);
        }
        let mapped_bytes = end.max(align);
        let usage = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
        let slot = self.next;
        self.next = (slot + 1) % RING_LEN;
        let (staging, held) = if self.held[slot].swap(true, Ordering::AcqRel) {
            // Still held by a readback more than a ring behind: this one gets its own buffer.
            let staging = ctx.create_buffer(&wgpu::BufferDescriptor {
                label: Some("late_readback_spare"),
                size: mapped_bytes,
                usage,
                mapped_at_creation: false,
            });
            (staging, Arc::new(AtomicBool::new(true)))
        } else {
            let bytes = mapped_bytes.max(MIN_RING_BYTES);
            let staging = (self.kept).buffer(ctx, RING_NAMES[slot], bytes, usage);
            (staging, self.held[slot].clone())
        };
        copies(encoder, &staging, &parts);
        LateReadback {
            staging,
            parts,
            mapped_bytes,
            state: Arc::new(AtomicU8::new(UNSUBMITTED)),
            collected: false,
            held,
        }
    }
}

/// Submits `encoder`, which holds `readback`'s copies, and asks for its staging buffer to be
/// mapped.
fn submit_then_map(
    ctx: &GpuContext,
    encoder: wgpu::CommandEncoder,
    readback: LateReadback,
) -> LateReadback {
    ctx.submit(encoder);
    readback.submitted();
    readback
}

/// What asks for a recorded readback's staging buffer to be mapped once the work that fills it
/// was submitted ([`LateReadback::arm`]), for whoever submits that work.
#[derive(Debug)]
pub(crate) struct ReadbackArm {
    staging: wgpu::Buffer,
    mapped_bytes: u64,
    state: Arc<AtomicU8>,
}

impl ReadbackArm {
    /// Asks for the staging buffer to be mapped, once the work that fills it was submitted
    /// (a readback [`ReadbackRing::record`]ed); nothing the second time.
    pub(crate) fn submitted(&self) {
        let state = &self.state;
        if (state.compare_exchange(UNSUBMITTED, WAITING, Ordering::AcqRel, Ordering::Acquire))
            .is_err()
        {
            return;
        }
        let signal = state.clone();
        (self.staging.slice(..self.mapped_bytes)).map_async(wgpu::MapMode::Read, move |r| {
            signal.store(if r.is_ok() { MAPPED } else { FAILED }, Ordering::Release);
        });
    }
}

impl LateReadback {
    /// What asks for the staging buffer to be mapped ([`ReadbackArm::submitted`]).
    pub(crate) fn arm(&self) -> ReadbackArm {
        ReadbackArm {
            staging: self.staging.clone(),
            mapped_bytes: self.mapped_bytes,
            state: self.state.clone(),
        }
    }

    /// [`ReadbackArm::submitted`] of this readback.
    pub(crate) fn submitted(&self) {
        self.arm().submitted()
    }

    /// Whether the results have arrived (as of the last poll of the device).
    pub(crate) fn is_ready(&self) -> bool {
        matches!(self.state.load(Ordering::Acquire), MAPPED | FAILED)
    }

    /// Copies result `k` into `targets[k]` (each as long as the result), waiting for the device
    /// first (one counted wait) when the results have not arrived.
    pub(crate) fn collect(mut self, ctx: &GpuContext, targets: &mut [&mut [u8]]) -> Result<()> {
        if self.state.load(Ordering::Acquire) == UNSUBMITTED {
            return Err(Error::Gpu(
                "a readback was collected before the work that fills it was submitted".into(),
            ));
        }
        if !self.is_ready() {
            ctx.wait()?;
        }
        if self.state.load(Ordering::Acquire) != MAPPED {
            return Err(Error::Gpu(
                "mapping a frame's readback buffer failed".into(),
            ));
        }
        {
            let slice = self.staging.slice(..self.mapped_bytes);
            let view = slice
                .get_mapped_range()
                .map_err(|e| Error::Gpu(format!("reading a mapped buffer: {e}")))?;
            for (target, &(at, len)) in targets.iter_mut().zip(&self.parts) {
                let at = at as usize;
                target.copy_from_slice(&view[at..at + len]);
                ctx.count_readback(len as u64);
            }
        }
        self.staging.unmap();
        self.collected = true;
        Ok(())
    }
}

impl Drop for LateReadback {
    /// A readback dropped uncollected (an error on the way) unmaps its buffer, cancelling a
    /// pending mapping, so that the ring can use the buffer again.
    fn drop(&mut self) {
        if !self.collected && self.state.load(Ordering::Acquire) != UNSUBMITTED {
            self.staging.unmap();
        }
        self.held.store(false, Ordering::Release);
    }
}
