//! Blocks written back behind the frames: when a pager evicts chunks, the resident blocks of
//! those chunks leave the pool without a wait. The dirty ones are copied out of the pool into a
//! staging buffer of their own ring ([`crate::gpu::readback`]) in a submit of their own, their
//! slots are given back at once (work submitted later, a new block written into a slot, reaches
//! the device after the copy), and the copies are collected a frame or more later into the
//! layer that then holds the blocks (the pager's layer of chunks waiting for them), oldest
//! release first.
//!
//! **Why this is safe.** Between the release and the collection nothing may read or change the
//! released blocks anywhere: the frames in flight that list one are collected before the
//! release (as for a flush), and the caller collects the releases before it brings a chunk of
//! theirs back or writes a checkpoint ([`ResidentMap::collect_released`] with `wait`).

use super::ResidentMap;
use crate::gpu::layout::{apply_updated, GpuVoxel};
use crate::gpu::readback::{LateReadback, ReadbackRing, RING_LEN};
use crate::grid::{BlockIndex, Layer, VOXELS_PER_BLOCK};
use crate::Result;
use std::collections::VecDeque;

/// Releases whose copies are on their way back.
#[derive(Debug, Default)]
pub(super) struct Behind {
    releases: VecDeque<Release>,
    ring: ReadbackRing,
    /// Releases collected since the caller last asked ([`ResidentMap::collect_released`]).
    collected: usize,
}

/// The dirty blocks of one release, in the order their copies come back.
#[derive(Debug)]
struct Release {
    blocks: Vec<BlockIndex>,
    readback: LateReadback,
}

impl ResidentMap {
    /// Releases the resident blocks among `blocks` (before a pager evicts their chunks) without
    /// waiting for the copies of the dirty ones (see the module documentation); returns whether
    /// copies are on their way (else the layer's blocks are current: nothing was dirty). The
    /// frames in flight are collected first where one lists one of them (into `layer`). At
    /// most [`RING_LEN`] releases are in flight: the oldest is collected into `held` (waiting,
    /// counted, where its copies have not arrived) to make room.
    pub fn release_blocks_later(
        &mut self,
        layer: &mut Layer,
        held: &mut Layer,
        blocks: &[BlockIndex],
    ) -> Result<bool> {
        self.collect_frames_listing(layer, blocks)?;
        let t = std::time::Instant::now();
        let slots: Vec<u32> = blocks
            .iter()
            .filter_map(|b| self.table.host.lookup(*b))
            .collect();
        let dirty = self.dirty_among(&slots);
        if !dirty.is_empty() {
            while self.behind.releases.len() >= RING_LEN {
                self.collect_oldest_release(held)?;
            }
            let keys = dirty.iter().map(|&s| self.pool.key(s).expect("resident"));
            let release = Release {
                blocks: keys.collect(),
                readback: (self.pool).read_slots_later(&self.ctx, &mut self.behind.ring, &dirty),
            };
            self.behind.releases.push_back(release);
            self.stats.blocks_downloaded += dirty.len() as u64;
        }
        for s in slots {
            self.release(s);
        }
        self.stats.download_s += t.elapsed().as_secs_f64();
        Ok(!dirty.is_empty())
    }

    /// Collects the releases whose copies have arrived or, with `wait`, all of them (waiting,
    /// counted, where one has not), oldest first, into `held`, which must hold their blocks
    /// (a block it lacks is allocated); returns how many releases were collected since the
    /// last call, those collected to make room included.
    pub fn collect_released(&mut self, held: &mut Layer, wait: bool) -> Result<usize> {
        if !self.behind.releases.is_empty() {
            self.ctx.poll_finished()?;
        }
        while let Some(r) = self.behind.releases.front() {
            if !wait && !r.readback.is_ready() {
                break;
            }
            self.collect_oldest_release(held)?;
        }
        Ok(std::mem::take(&mut self.behind.collected))
    }

    /// Releases whose copies have not been collected.
    pub fn releases_in_flight(&self) -> usize {
        self.behind.releases.len()
    }

    fn collect_oldest_release(&mut self, held: &mut Layer) -> Result<()> {
        let r = self.behind.releases.pop_front().expect("a release");
        let t = std::time::Instant::now();
        let mut voxels: Vec<GpuVoxel> = bytemuck::zeroed_vec(r.blocks.len() * VOXELS_PER_BLOCK);
        (r.readback).collect(&self.ctx, &mut [bytemuck::cast_slice_mut(&mut voxels)])?;
        for (b, vox) in r.blocks.iter().zip(voxels.chunks_exact(VOXELS_PER_BLOCK)) {
            apply_updated(held.get_or_allocate(*b), vox);
        }
        self.behind.collected += 1;
        self.stats.download_s += t.elapsed().as_secs_f64();
        Ok(())
    }
}
