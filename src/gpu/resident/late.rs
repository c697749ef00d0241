//! Frames in flight: a depth frame's or a LiDAR scan's flags (which listed blocks it updated)
//! and counters come back through a ring of staging buffers ([`crate::gpu::readback`]) and
//! are collected by a later frame, so that a frame neither waits for its own kernels nor for
//! the readback. (A scan lists only its rays' blocks, which do not depend on the layer; what
//! follows is about the depth frames listed after it.)
//!
//! **What the host does not know yet.** Until a frame is collected, the layer has not learnt
//! the blocks it created, and blocks it listed but did not update are not released. A frame
//! listed meanwhile must still see every block the CPU would (the band, and the allocated
//! blocks in view): the blocks listed by frames in flight that the layer lacks
//! ([`ResidentMap::unsettled_blocks`]) are listed too when in view, and the kernel skips those
//! outside the frame's band that no frame updated (a per-slot mark on the device, set by the
//! fusion kernel and cleared when a slot is given to a new block). So a frame's result does
//! not depend on when its predecessors were collected.
//!
//! Nor has the host's table learnt the blocks a depth frame in flight inserted on the device
//! (`alloc.rs`): a later frame that lists one of them again reserves a slot for it, which the
//! device does not take (its lookup finds the block), and the host inserts nothing itself while
//! such insertions are in flight.
//!
//! **Collecting** processes frames in order ([`ResidentMap::collect_frames`]): a frame's
//! insertions on the device are applied to the host's table and pool first; updated blocks
//! become dirty and the layer learns those it lacks; a block no frame updated is released once
//! no frame in flight lists it (collected as a depth frame begins, it stays, empty, until that
//! frame is listed, which uses it again where its band holds it, rather than making it anew).
//! Everything that reads or pages the map (syncs, flushes, spills, the TV solve) collects every
//! frame first, waiting where it must (counted).

use super::alloc::{created_bytes, insertions};
use super::table::PROBES_AHEAD;
use super::{FramePlacement, ResidentMap, SLOT_EMPTY};
use crate::gpu::readback::{LateReadback, RING_LEN};
use crate::grid::{BlockHasher, BlockIndex, Layer, TouchedBlocks};
use crate::{Error, Result};
use std::collections::{HashMap, HashSet, VecDeque};
use std::hash::BuildHasherDefault;

/// A frame whose results are on their way back.
#[derive(Debug)]
pub(super) struct FrameInFlight {
    frame: u64,
    blocks: Vec<BlockIndex>,
    /// Per listed block: its slot when the frame was submitted, or `SLOT_EMPTY` where the
    /// host's table lacked it (until the collect learns the frame's insertions). A block a
    /// frame in flight lists keeps its slot until the frame is collected: blocks leave the pool
    /// only once every frame listing them is collected.
    slots: Vec<u32>,
    /// Per listed block: whether the layer lacked it when the frame was submitted (it then
    /// counts in [`InFlight::unsettled`] until the frame is collected).
    lacked: Vec<bool>,
    /// The free slots reserved for the blocks the device inserts (`alloc.rs`), the top last;
    /// its insertions come back after the flags.
    reserved: Vec<u32>,
    /// Per result (flag, insertion), its block's index in `blocks`, where they differ
    /// ([`FramePlacement::dispatch`]).
    dispatch: Vec<u32>,
    readback: LateReadback,
}

/// The frames in flight and what the host does not know yet because of them.
#[derive(Debug, Default)]
pub(super) struct InFlight {
    frames: VecDeque<FrameInFlight>,
    /// Blocks the layer lacked when a frame in flight listed them, with how many such frames.
    unsettled: HashMap<BlockIndex, u32, BuildHasherDefault<BlockHasher>>,
    /// Slots reserved for insertions on the device by frames in flight.
    reserved: usize,
    /// Whether frames may stay in flight after their call returns.
    pub(super) enabled: bool,
    /// Whether a frame or scan first collects the frames whose results have arrived (else
    /// only what the ring needs room for).
    pub(super) lazy: bool,
    /// What collected frames touched and their voxel updates, until taken.
    touched: TouchedBlocks,
    voxel_updates: usize,
    /// Whether collecting keeps the blocks no frame updated resident, in `kept_empty`, rather
    /// than releasing them (while a depth frame begins: see [`InFlight::kept_empty`]).
    keep_empty: bool,
    /// Blocks the layer lacks that frames listed and did not update, with their slots, kept
    /// (empty, as filled) while the next depth frame is listed: those it lists again are used
    /// as they are, instead of being released and made again
    /// ([`ResidentMap::release_empty_except`]).
    kept_empty: Vec<(BlockIndex, u32)>,
}

impl ResidentMap {
    /// Lets depth frames and LiDAR scans return before their results arrive (collected by
    /// later frames; see the module documentation), or not: then each waits for its own.
    pub fn set_frames_in_flight(&mut self, enabled: bool) {
        self.late.enabled = enabled;
    }

    /// Collects frames only when the readback ring is full or the map is read, not as soon as
    /// their results arrive: as with a device slower than the host, whatever its speed (tests
    /// use it to keep frames in flight on a fast device).
    pub fn set_collect_lazily(&mut self, lazy: bool) {
        self.late.lazy = lazy;
    }

    /// Whether depth frames and LiDAR scans may return before their results arrive.
    pub fn frames_in_flight_enabled(&self) -> bool {
        self.late.enabled
    }

    /// Frames and scans whose results have not been collected.
    pub fn frames_in_flight(&self) -> usize {
        self.late.frames.len()
    }

    /// Blocks the layer lacks that frames in flight listed (they may have created them),
    /// sorted.
    pub(crate) fn unsettled_blocks(&self, layer: &Layer) -> Vec<BlockIndex> {
        let mut v: Vec<BlockIndex> = (self.late.unsettled.keys())
            .filter(|b| !layer.contains(b))
            .copied()
            .collect();
        v.sort_unstable();
        v
    }

    /// Slots reserved for insertions on the device by frames in flight: while there are any,
    /// the device's table holds entries the host's lacks.
    pub(crate) fn reserved_slots(&self) -> usize {
        self.late.reserved
    }

    /// Records a submitted frame of `blocks` whose flags and counters come back in `readback`,
    /// then (with `placed.reserved`, the free-slot stack its insertions took from) the
    /// insertions. `placed.slots`: each block's slot, as
    /// [`ResidentMap::make_resident_for_frame`] gives them; empty where every block is in the
    /// host's table (a LiDAR scan's: looked up here).
    pub(crate) fn frame_submitted(
        &mut self,
        layer: &Layer,
        (blocks, placed): (Vec<BlockIndex>, FramePlacement),
        readback: LateReadback,
    ) {
        let FramePlacement {
            mut slots,
            reserved,
            dispatch,
        } = placed;
        if slots.is_empty() {
            slots = self.table.host.lookup_all(&blocks);
        }
        self.late.reserved += reserved.len();
        // A block the host's table lacks is one the layer lacks too (make_resident_for_frame
        // uploads every other); the pool knows of the others whether the layer holds them.
        let lacked: Vec<bool> = (blocks.iter().zip(&slots).enumerate())
            .map(|(i, (b, &slot))| {
                if let Some(&ahead) = slots.get(i + PROBES_AHEAD) {
                    self.pool.prefetch(ahead);
                }
                let lacked = slot == SLOT_EMPTY || !self.pool.in_layer(slot);
                debug_assert_eq!(lacked, !layer.contains(b), "{b:?} in slot {slot}");
                lacked
            })
            .collect();
        for (b, _) in blocks.iter().zip(&lacked).filter(|(_, l)| **l) {
            *self.late.unsettled.entry(*b).or_default() += 1;
        }
        self.late.frames.push_back(FrameInFlight {
            frame: self.frame,
            blocks,
            slots,
            lacked,
            reserved,
            dispatch,
            readback,
        });
    }

    /// Collects frames in flight, oldest first: those whose results have arrived or, with
    /// `wait`, all of them (waiting once, counted, for the first that has not arrived).
    pub fn collect_frames(&mut self, layer: &mut Layer, wait: bool) -> Result<()> {
        if self.late.frames.is_empty() {
            return Ok(());
        }
        self.ctx.poll_finished()?;
        while let Some(f) = self.late.frames.front() {
            if !wait && !f.readback.is_ready() {
                break;
            }
            let f = self.late.frames.pop_front().expect("a frame");
            self.collect(layer, f)?;
        }
        Ok(())
    }

    /// Collects every frame in flight but, with `keep_newest`, the one submitted last (waiting,
    /// counted, where one has not arrived), and returns what the frames collected since
    /// [`ResidentMap::take_collected`] last ran touched (left for it to take: a store pages by
    /// them, a caller is told by the next fusion call).
    pub fn settle(&mut self, layer: &mut Layer, keep_newest: bool) -> Result<TouchedBlocks> {
        if !self.late.frames.is_empty() {
            self.ctx.poll_finished()?;
        }
        self.collect_oldest_until(layer, keep_newest as usize)?;
        Ok(self.late.touched.clone())
    }

    /// Collects every frame in flight (waiting where one has not arrived) if one of them lists
    /// a block of `blocks`: before those blocks are written back and leave the pool. A frame
    /// that lists none of them neither changes nor reads them.
    pub(super) fn collect_frames_listing(
        &mut self,
        layer: &mut Layer,
        blocks: &[BlockIndex],
    ) -> Result<()> {
        let leaving: HashSet<BlockIndex> = blocks.iter().copied().collect();
        let listed =
            (self.late.frames.iter()).any(|f| f.blocks.iter().any(|b| leaving.contains(b)));
        if listed {
            self.collect_frames(layer, true)?;
        }
        Ok(())
    }

    /// Before a frame or scan is listed: collects what has arrived and makes room for it in
    /// the readback ring. With `keep_empty` (a depth frame, which calls
    /// [`ResidentMap::release_empty_except`] once listed), the blocks collected frames listed
    /// and did not update (empty, not in the layer) stay resident until then.
    pub(crate) fn begin_in_flight(&mut self, layer: &mut Layer, keep_empty: bool) -> Result<()> {
        self.late.keep_empty = keep_empty;
        let collected = self.begin_collecting(layer);
        self.late.keep_empty = false;
        collected
    }

    fn begin_collecting(&mut self, layer: &mut Layer) -> Result<()> {
        if !self.late.lazy {
            self.collect_frames(layer, false)?;
        }
        self.make_room_in_flight(layer)
    }

    /// Releases the blocks [`ResidentMap::begin_in_flight`] kept empty but those among the
    /// frame's lists `lists` (each sorted), which it lists again and uses as they are
    /// (counted). Call it before anything else reads the pool: only the frame that follows may
    /// see such blocks.
    pub(crate) fn release_empty_except(&mut self, lists: &[&[BlockIndex]]) {
        for (b, slot) in std::mem::take(&mut self.late.kept_empty) {
            if lists.iter().any(|l| l.binary_search(&b).is_ok()) {
                self.stats.empty_blocks_kept += 1;
            } else if self.pool.key(slot) == Some(b) {
                self.release(slot);
            }
        }
    }

    /// After a frame or scan was submitted: collects it (waiting) unless frames may stay in
    /// flight; returns what the frames collected since the last call touched and their voxel
    /// updates ([`ResidentMap::take_collected`]).
    pub(crate) fn end_in_flight(&mut self, layer: &mut Layer) -> Result<(TouchedBlocks, usize)> {
        if !self.late.enabled {
            self.collect_frames(layer, true)?;
        }
        Ok(self.take_collected())
    }

    /// Collects frames until fewer than the ring holds are in flight (room for one more).
    fn make_room_in_flight(&mut self, layer: &mut Layer) -> Result<()> {
        self.collect_oldest_until(layer, RING_LEN - 1)
    }

    /// Collects the oldest frames, waiting where one has not arrived, until at most `left` are
    /// in flight.
    fn collect_oldest_until(&mut self, layer: &mut Layer, left: usize) -> Result<()> {
        while self.late.frames.len() > left {
            let f = self.late.frames.pop_front().expect("a frame");
            self.collect(layer, f)?;
        }
        Ok(())
    }

    /// What the frames collected since the last call touched (frame after frame, each one's
    /// sorted) and their voxel updates.
    pub fn take_collected(&mut self) -> (TouchedBlocks, usize) {
        let touched = std::mem::take(&mut self.late.touched);
        (touched, std::mem::take(&mut self.late.voxel_updates))
    }

    fn collect(&mut self, layer: &mut Layer, mut f: FrameInFlight) -> Result<()> {
        let n = f.blocks.len();
        let mut counts = [0u32; 2];
        let mut flags: Vec<u32> = bytemuck::zeroed_vec(n);
        let mut created: Vec<u32> = match f.reserved.len() {
            0 => Vec::new(),
            k => bytemuck::zeroed_vec(created_bytes(k as u64) as usize / 4),
        };
        let mut results = vec![
            bytemuck::cast_slice_mut(&mut counts),
            bytemuck::cast_slice_mut(&mut flags),
        ];
        if !created.is_empty() {
            results.push(bytemuck::cast_slice_mut(&mut created));
        }
        f.readback.collect(&self.ctx, &mut results)?;
        if counts[1] != 0 {
            return Err(Error::Gpu(format!(
                "the GPU could not resolve {} of {n} resident blocks (or make a LiDAR scan's walks \
                 through them)",
                counts[1]
            )));
        }
        if !f.dispatch.is_empty() {
            flags = in_list_order(&flags, &f.dispatch);
        }
        if !created.is_empty() {
            let listed = (&f.blocks[..], &mut f.slots[..], &f.dispatch[..]);
            self.learn_insertions(listed, (&f.reserved, f.frame), &created)?;
        }
        let start = self.late.touched.len();
        for (i, (((b, &up), &lacked), &slot)) in (f.blocks.iter().zip(&flags).zip(&f.lacked))
            .zip(&f.slots)
            .enumerate()
        {
            if let Some(&ahead) = f.slots.get(i + PROBES_AHEAD) {
                self.pool.prefetch(ahead);
            }
            let later = lacked && self.unlist(*b);
            // Not placed at submit and not inserted by this frame: inserted by a frame
            // collected since, or by none.
            let slot = match slot {
                SLOT_EMPTY => self.table.host.lookup(*b),
                slot => Some(slot),
            };
            debug_assert_eq!(slot, self.table.host.lookup(*b), "{b:?}");
            let Some(slot) = slot else {
                // Listed only because a frame in flight may have made it; none did, and it was
                // released before this frame ran (`fuse_depth_resident.wgsl` skipped it).
                debug_assert!(lacked && up == 0, "a listed block is not resident");
                continue;
            };
            let in_layer = self.pool.in_layer(slot);
            debug_assert_eq!(in_layer, layer.contains(b), "{b:?} in slot {slot}");
            if up != 0 {
                self.pool.mark_dirty(slot);
                if !in_layer {
                    // Its voxels are on the device: RAM holds them once written back.
                    layer.insert_unwritten(*b);
                    self.pool.mark_in_layer(slot);
                }
            } else if !in_layer {
                if later {
                    // A later frame in flight lists it: it decides.
                } else if self.late.keep_empty {
                    self.late.kept_empty.push((*b, slot));
                } else {
                    self.release(slot);
                }
                continue;
            }
            self.late.touched.push(*b);
            self.pool.touch(slot, f.frame);
        }
        // Each frame's touched blocks sorted. A depth frame's come in two sorted runs (listed,
        // then unsettled), which the run-detecting stable sort merges in one pass; a scan's in
        // one (its results put in its list's order above).
        self.late.touched[start..].sort();
        self.late.voxel_updates += counts[0] as usize;
        self.stats.peak_resident_blocks =
            self.stats.peak_resident_blocks.max(self.table.host.len());
        Ok(())
    }

    /// Applies a frame's insertions on the device (its `created` words, `alloc.rs`: indices into
    /// its `blocks`, or into `dispatch` where not empty, which maps them to `blocks`) to the
    /// host's table and pool and to the frame's `slots`, and gives back the slots `reserved`
    /// for them that the device did not take (the stack's bottom).
    fn learn_insertions(
        &mut self,
        (blocks, slots, dispatch): (&[BlockIndex], &mut [u32], &[u32]),
        (reserved, frame): (&[u32], u64),
        created: &[u32],
    ) -> Result<()> {
        let (k, count, left_without) = (reserved.len(), created[0] as usize, created[1]);
        if left_without != 0 || count > k {
            return Err(Error::Gpu(format!(
                "the GPU left {left_without} new blocks without a slot ({count} inserted, {k} \
                 slots reserved)"
            )));
        }
        let (_, inserted) = insertions(created);
        for &[i, pos, slot] in &inserted {
            let i = dispatch.get(i as usize).map_or(i, |&b| b);
            let key = blocks[i as usize];
            debug_assert!(reserved[k - inserted.len()..].contains(&slot));
            self.table.host.insert_at(pos, key, slot);
            self.pool.occupy_reserved(slot, key, frame);
            slots[i as usize] = slot;
        }
        self.pool.unreserve(&reserved[..k - inserted.len()]);
        self.late.reserved -= k;
        self.stats.blocks_created += inserted.len() as u64;
        self.stats.blocks_inserted_on_gpu += inserted.len() as u64;
        Ok(())
    }

    /// Takes one listing of `b` by a frame in flight off its count; returns whether a later
    /// frame in flight lists it too.
    fn unlist(&mut self, b: BlockIndex) -> bool {
        match self.late.unsettled.get_mut(&b) {
            Some(c) if *c > 1 => {
                *c -= 1;
                true
            }
            _ => {
                self.late.unsettled.remove(&b);
                false
            }
        }
    }
}

/// `results` (one per listed block, in dispatch order) in the list's order: result `d` is block
/// `dispatch[d]`'s.
fn in_list_order(results: &[u32], dispatch: &[u32]) -> Vec<u32> {
    let mut out = vec![0; results.len()];
    for (&r, &i) in results.iter().zip(dispatch) {
        out[i as usize] = r;
    }
    out
}
