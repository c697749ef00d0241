//! The GPU tier of the map: blocks stay resident in a device pool across frames, so a frame
//! uploads only the blocks it newly needs and reads back nothing but a flag per block.
//!
//! - [`table`]: the GPU hash table ([`BlockTable`]) that maps block keys to pool slots; kernels
//!   resolve keys through its device copy.
//! - [`pool`]: the slots on the device and the copies between RAM and the pool.
//! - [`alloc`]: blocks allocated on the device (slots from a free-slot stack there, entries
//!   claimed by compare-and-swap), which the host learns afterwards and applies to its copies:
//!   a depth frame's new blocks, and a LiDAR scan's where the device makes its pairs
//!   ([`ResidentMap::make_resident_for_frame`]; the host reserves their slots and learns which
//!   block took which slot and entry when the frame or scan is collected).
//!   While such insertions are in flight the device's table holds entries the host's lacks, so
//!   the host inserts nothing itself (it collects first).
//! - [`policy`]: growing, and which blocks spill when the pool is full (the same eviction order
//!   as the RAM pager's, [`crate::grid::eviction_order`]).
//! - `late`: depth frames and LiDAR scans in flight, whose flags a later frame collects
//!   ([`ResidentMap::set_frames_in_flight`], [`ResidentMap::collect_frames`]).
//! - `behind`: blocks released before their chunks leave RAM, whose copies are collected later
//!   into the pager's layer of leaving chunks ([`ResidentMap::release_blocks_later`],
//!   [`ResidentMap::collect_released`]).
//! - [`ResidentMap`] (here) ties them together: it makes a frame's blocks resident
//!   ([`ResidentMap::make_resident`]), learns what a kernel changed (`late`: a frame's flags,
//!   collected when they arrive), and writes blocks back to the RAM [`Layer`]
//!   ([`ResidentMap::sync`], [`ResidentMap::flush_blocks`], both collecting the frames in
//!   flight first). The fusion dispatches into the pool live beside the CPU's fusion
//!   (`src/fusion/depth_gpu.rs`, `lidar_resident.rs`).
//!
//! **Write-back.** The GPU copy of a resident block is authoritative; the RAM layer holds a
//! shadow (possibly stale, an empty block for blocks created on the GPU) so that it still knows
//! every allocated block. Every voxel a kernel updates carries a mark
//! ([`crate::gpu::layout::UPDATED_BIT`]) until it is copied back with
//! [`crate::grid::Block::store_fused`], the rule `Block::fuse` itself stores voxels by (a stored
//! regularized value follows the raw one), so the shadow is exact after a write-back.
//!
//! **Overflow** is never silent: the pool grows up to `max_bytes` (and the device's binding
//! limit), then spills; a frame whose own blocks exceed the largest pool is the caller's to fuse
//! another way (the fusion dispatch uses the per-call kernel and counts it). Every grow, spill
//! and oversize frame is counted in [`ResidentStats`].
//!
//! After an error the device copy may be partly updated: drop the map without syncing; the layer
//! holds the state of the last successful sync.

pub mod alloc;
mod behind;
mod late;
mod policy;
mod pool;
mod table;

pub use pool::SLOT_BYTES;
pub use table::{block_hash, lookup_table_on_gpu, mix32, BlockTable, SLOT_EMPTY, SLOT_TOMBSTONE};

use super::context::GpuContext;
use super::kept::Kept;
use super::layout::{apply_updated, pack_block_into, GpuVoxel};
use super::readback::ReadbackRing;
use crate::grid::{Block, BlockIndex, GridParams, Layer, VOXELS_PER_BLOCK};
use crate::{Error, Result};
use pool::BlockPool;
use std::collections::HashSet;
use std::sync::Arc;
use table::DeviceTable;

/// A hash table's entries: per entry the key (x, y, z as `u32`) and the slot.
pub type TableEntries = Vec<[u32; 4]>;

/// Where a depth frame's listed blocks are as it is submitted
/// ([`ResidentMap::make_resident_for_frame`]).
#[derive(Debug, Default)]
pub(crate) struct FramePlacement {
    /// Per listed block, its slot in the host's table, or [`SLOT_EMPTY`] where the host's
    /// table lacks it (the device inserts it, or a frame in flight did): the collect reads a
    /// block's slot here rather than probing the table again (`late.rs`).
    pub slots: Vec<u32>,
    /// The free slots reserved for the blocks the device inserts, the top last.
    pub reserved: Vec<u32>,
    /// Where the kernels' results (flags, insertions) come in another order than the listed
    /// blocks' (a LiDAR scan's, in dispatch order): per result, its block's index in the list;
    /// empty where they come in the list's order.
    pub dispatch: Vec<u32>,
}

/// Size limits of a [`ResidentMap`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ResidentOptions {
    /// Slots allocated at start.
    pub initial_blocks: u32,
    /// Largest pool, bytes (4 KiB per block); also bounded by the device's binding limit.
    pub max_bytes: u64,
}

impl Default for ResidentOptions {
    fn default() -> Self {
        ResidentOptions {
            initial_blocks: 4096,
            max_bytes: 2 << 30,
        }
    }
}

/// Counters of a [`ResidentMap`].
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ResidentStats {
    /// Slots in the pool now.
    pub capacity_blocks: u32,
    /// Slots the pool may grow to.
    pub max_blocks: u32,
    /// Blocks resident now.
    pub resident_blocks: usize,
    /// Most blocks resident at once.
    pub peak_resident_blocks: usize,
    /// Frames fused.
    pub frames: u64,
    /// Blocks uploaded from RAM.
    pub blocks_uploaded: u64,
    /// Blocks new to the map, written empty into their slots on the GPU (nothing uploaded);
    /// those a depth frame or LiDAR scan inserted on the device are counted when it is
    /// collected.
    pub blocks_created: u64,
    /// Of `blocks_created`: those depth frames and LiDAR scans inserted on the device
    /// (`alloc.rs`).
    pub blocks_inserted_on_gpu: u64,
    /// Free slots reserved for the new blocks depth frames and LiDAR scans insert on the device
    /// (`alloc.rs`); those a frame in flight had inserted already take none, and are given
    /// back.
    pub slots_reserved: u64,
    /// Blocks a depth frame listed and left empty that the next frame listed again, kept in
    /// their slots for it rather than released and created again.
    pub empty_blocks_kept: u64,
    /// Blocks read back to RAM (syncs, flushes, spills).
    pub blocks_downloaded: u64,
    /// Blocks released to make room (the spill to RAM).
    pub blocks_spilled: u64,
    /// Times the pool grew.
    pub grows: u32,
    /// Frames whose own blocks exceeded the largest pool (fused by the batched path).
    pub oversize_frames: u64,
    /// Most blocks one frame listed (its working set on the GPU).
    pub largest_frame_blocks: usize,
    /// Depth frames and LiDAR scans submitted while earlier ones were still in flight
    /// (`late.rs`).
    pub frames_overlapped: u64,
    /// Blocks depth frames listed only because a frame in flight may have created them.
    pub blocks_listed_in_flight: u64,
    /// Host writes that sent the hash table's changed entries up (a queue write per run of
    /// neighbouring entries, or one for a frame's changes scattered on the device).
    pub table_writes: u64,
    /// Seconds listing each frame's blocks on the CPU (band and visible blocks).
    pub list_s: f64,
    /// Seconds making blocks resident (growing, spilling, uploading blocks and table entries).
    pub residency_s: f64,
    /// Seconds in the lookup and fusion dispatches, waiting included, and the flag readback.
    pub kernel_s: f64,
    /// Of `kernel_s`: preparing the frame's inputs (images, packed block offsets) and
    /// writing them into the kept buffers, before the submit.
    pub inputs_s: f64,
    /// Seconds copying blocks back to RAM (syncs, flushes, spills).
    pub download_s: f64,
    /// Seconds of the calling thread's CPU time ([`crate::gpu::thread_cpu_s`]) in planning
    /// depth frames (their band from the device's readback) and in the resident fusion of
    /// depth frames and LiDAR scans (listing, residency, inputs, submits, collecting earlier
    /// frames; a LiDAR scan's also the next scan's listing): the host's own share, to which
    /// waiting for the device or for the cores a software device holds adds nothing.
    pub host_cpu_s: f64,
}

/// Blocks resident on the GPU across frames, over a RAM [`Layer`] (see the module
/// documentation).
pub struct ResidentMap {
    ctx: Arc<GpuContext>,
    grid: GridParams,
    max_blocks: u32,
    pool: BlockPool,
    table: DeviceTable,
    frame: u64,
    stats: ResidentStats,
    /// The frame kernels' buffers and bind groups, kept between frames.
    kept: Kept,
    /// The staging buffers frames and scans read their flags back through.
    ring: ReadbackRing,
    /// Frames and scans whose flags have not been collected ([`late`]).
    late: late::InFlight,
    /// Released blocks whose copies have not been collected (`behind`).
    behind: behind::Behind,
    /// The LiDAR listing whose rays and table `kept` holds, and the table's entries
    /// (`src/fusion/lidar_listing.rs`).
    lidar_rays_of: Option<(u64, u32)>,
}

/// What a frame's kernels need at once ([`ResidentMap::frame_parts`]).
pub(crate) struct FrameParts<'a> {
    pub ctx: &'a GpuContext,
    pub grid: GridParams,
    /// The pool's voxels, 512 per slot.
    pub pool: &'a wgpu::Buffer,
    /// The pool's per-slot marks of blocks a frame or scan updated ([`late`]).
    pub exists: &'a wgpu::Buffer,
    /// The device's hash table and its mask.
    pub table: (&'a wgpu::Buffer, u32),
    /// The frames' kept buffers and bind groups.
    pub kept: &'a mut Kept,
    /// The staging buffers of late readbacks.
    pub ring: &'a mut ReadbackRing,
}

impl std::fmt::Debug for ResidentMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ResidentMap")
            .field("stats", &self.stats())
            .finish()
    }
}

impl ResidentMap {
    /// An empty pool on `ctx` for maps on `grid`.
    pub fn new(ctx: Arc<GpuContext>, grid: GridParams, options: ResidentOptions) -> Result<Self> {
        let device_max = ctx.max_binding_bytes() / SLOT_BYTES;
        let max_blocks = (options.max_bytes / SLOT_BYTES).min(device_max).max(1) as u32;
        let capacity = options.initial_blocks.clamp(1, max_blocks);
        let scope = crate::gpu::ErrorScopes::push(&ctx.device);
        let pool = BlockPool::new(&ctx, capacity)?;
        let table = DeviceTable::new(&ctx, table_entries(capacity));
        scope.pop("allocating the GPU block pool")?;
        Ok(ResidentMap {
            ctx,
            grid,
            max_blocks,
            pool,
            table,
            frame: 0,
            kept: Kept::default(),
            ring: ReadbackRing::default(),
            late: late::InFlight::default(),
            behind: behind::Behind::default(),
            lidar_rays_of: None,
            stats: ResidentStats {
                capacity_blocks: capacity,
                max_blocks,
                ..Default::default()
            },
        })
    }

    /// The counters.
    pub fn stats(&self) -> ResidentStats {
        ResidentStats {
            resident_blocks: self.table.host.len(),
            ..self.stats
        }
    }

    /// The GPU this map lives on.
    pub fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }

    /// The grid of the maps it holds blocks of.
    pub fn grid(&self) -> GridParams {
        self.grid
    }

    /// The most blocks the pool can hold.
    pub fn max_blocks(&self) -> u32 {
        self.max_blocks
    }

    /// The slot of a resident block (the host's table).
    pub fn slot_of(&self, b: BlockIndex) -> Option<u32> {
        self.table.host.lookup(b)
    }

    /// The pool's device buffer: 512 [`GpuVoxel`]s per slot.
    pub(crate) fn pool_buffer(&self) -> &wgpu::Buffer {
        self.pool.device_buffer()
    }

    /// Resident blocks, sorted.
    pub fn resident_blocks(&self) -> Vec<BlockIndex> {
        let mut v: Vec<BlockIndex> = self.pool.occupied().map(|(_, k, _)| k).collect();
        v.sort_unstable();
        v
    }

    /// Whether a resident block holds updates not yet copied to RAM.
    pub fn is_dirty(&self, b: BlockIndex) -> bool {
        self.slot_of(b).is_some_and(|s| self.pool.is_dirty(s))
    }

    /// Looks `keys` up in the device's copy of the table (`block_lookup.wgsl`): the GPU's view
    /// of residency, which must equal [`ResidentMap::slot_of`].
    pub fn lookup_on_gpu(&mut self, keys: &[BlockIndex]) -> Result<Vec<Option<u32>>> {
        self.stats.table_writes += self.table.upload(&self.ctx, None)? as u64;
        table::run_lookup(&self.ctx, self.table.buffer(), self.table.host.mask(), keys)
    }

    /// The host's table and the device's, read back (counted) once the host's changes went
    /// up: equal entry for entry when no frame in flight inserted blocks on the device.
    pub fn table_entries_on_host_and_gpu(&mut self) -> Result<(TableEntries, TableEntries)> {
        self.stats.table_writes += self.table.upload(&self.ctx, None)? as u64;
        let on_host = self.table.host.entries().to_vec();
        let on_gpu = self.ctx.read_back_as(self.table.buffer(), on_host.len())?;
        Ok((on_host, on_gpu))
    }

    /// What a frame's kernels need at once.
    pub(crate) fn frame_parts(&mut self) -> FrameParts<'_> {
        FrameParts {
            ctx: &self.ctx,
            grid: self.grid,
            pool: self.pool.device_buffer(),
            exists: self.pool.exists_buffer_of(),
            table: (self.table.buffer(), self.table.host.mask()),
            kept: &mut self.kept,
            ring: &mut self.ring,
        }
    }

    /// Records that `kept` holds the rays and table of LiDAR listing `listing` (its number and
    /// the table's entries; `None`: no listing's).
    pub(crate) fn set_lidar_rays_of(&mut self, listing: Option<(u64, u32)>) {
        self.lidar_rays_of = listing;
    }

    /// The LiDAR listing whose rays and table `kept` holds, forgotten (a scan uses them once).
    pub(crate) fn take_lidar_rays_of(&mut self) -> Option<(u64, u32)> {
        self.lidar_rays_of.take()
    }

    /// Counts a frame of `blocks` blocks (before any other work on it).
    pub(crate) fn begin_frame(&mut self, blocks: usize, listing_s: f64) {
        self.frame += 1;
        self.stats.frames += 1;
        self.stats.list_s += listing_s;
        self.stats.largest_frame_blocks = self.stats.largest_frame_blocks.max(blocks);
    }

    /// Counts a frame or scan about to be submitted, with `blocks` listed only because a frame
    /// in flight may have created them.
    pub(crate) fn note_listed_in_flight(&mut self, blocks: usize) {
        self.stats.blocks_listed_in_flight += blocks as u64;
        self.stats.frames_overlapped += (self.frames_in_flight() > 0) as u64;
    }

    /// Counts a frame too large for the pool (its caller fuses it another way).
    pub(crate) fn note_oversize(&mut self) {
        self.stats.oversize_frames += 1;
    }

    /// Adds host CPU time ([`ResidentStats::host_cpu_s`]).
    pub(crate) fn add_host_cpu(&mut self, seconds: f64) {
        self.stats.host_cpu_s += seconds;
    }

    /// Adds kernel time (inputs, dispatches, waiting, flag readback) to the counters, of which
    /// `inputs_s` preparing and writing the inputs.
    pub(crate) fn add_kernel_time(&mut self, seconds: f64, inputs_s: f64) {
        self.stats.kernel_s += seconds;
        self.stats.inputs_s += inputs_s;
    }

    /// Makes every block of `blocks` (no repeats, in any order; at most
    /// [`ResidentMap::max_blocks`]) resident: grows or spills ([`policy`]) to free the slots it
    /// needs, uploads the missing blocks (the layer's copy, or empty) and the changed table
    /// entries. The empty blocks are written on the device by a dispatch recorded into
    /// `encoder` (a frame's, to be submitted with its kernels before any other call on this
    /// map) or, without one, submitted alone; with `encoder`, many scattered table entries go
    /// up as one list that a dispatch recorded into it puts in place.
    pub(crate) fn make_resident(
        &mut self,
        layer: &mut Layer,
        blocks: &[BlockIndex],
        camera_m: [f64; 3],
        encoder: Option<&mut wgpu::CommandEncoder>,
    ) -> Result<()> {
        let placed = self.make_resident_inner(layer, (blocks, None), camera_m, encoder)?;
        debug_assert!(placed.reserved.is_empty());
        Ok(())
    }

    /// [`ResidentMap::make_resident`] for a depth frame whose kernels allocate its new blocks
    /// on the device (`alloc.rs`, recorded after the frame's lookup): the blocks before
    /// `first_unsettled` that neither the host's table nor the layer holds are not inserted
    /// here; as many free slots are reserved for them, written empty into `encoder`, and
    /// returned as the device's free-slot stack (the top last), with each block's slot where
    /// the host's table has it ([`FramePlacement`]). The host learns which block took which
    /// slot and entry when the frame is collected (`late.rs`). Blocks from `first_unsettled`
    /// on that the host's table lacks were inserted on the device by a frame in flight, or
    /// released since, made by no frame (the fusion kernel skips them).
    pub(crate) fn make_resident_for_frame(
        &mut self,
        layer: &mut Layer,
        (blocks, first_unsettled): (&[BlockIndex], usize),
        camera_m: [f64; 3],
        encoder: &mut wgpu::CommandEncoder,
    ) -> Result<FramePlacement> {
        let listed = (blocks, Some(first_unsettled));
        self.make_resident_inner(layer, listed, camera_m, Some(encoder))
    }

    fn make_resident_inner(
        &mut self,
        layer: &mut Layer,
        (blocks, device_inserts): (&[BlockIndex], Option<usize>),
        camera_m: [f64; 3],
        encoder: Option<&mut wgpu::CommandEncoder>,
    ) -> Result<FramePlacement> {
        let t = std::time::Instant::now();
        // Each block's slot, one probe of the host's table; of the others, those uploaded (the
        // host inserts them, at `missing_at` in `blocks`), and new ones the device inserts.
        let mut slots = self.table.host.lookup_all(blocks);
        let (mut missing, mut missing_at, mut fresh) = (Vec::new(), Vec::new(), 0usize);
        for (i, b) in blocks.iter().enumerate() {
            if slots[i] != SLOT_EMPTY {
                continue;
            }
            match device_inserts {
                Some(first_unsettled) if !layer.contains(b) => {
                    fresh += (i < first_unsettled) as usize
                }
                _ => {
                    missing.push(*b);
                    missing_at.push(i);
                }
            }
        }
        let need = missing.len() + fresh;
        let pending = self.reserved_slots();
        let collect = (pending > 0 && !missing.is_empty())
            || self.pool.free_count() < need
            || !self.table.host.has_room_for(pending + need);
        if collect && self.frames_in_flight() > 0 {
            // The host inserts only into a table it knows whole (the device's insertions
            // collected), and growing or spilling needs the host to know every block: collect
            // the frames in flight, then look again (a block they listed and no frame updated
            // is released and comes back empty, which is what it held).
            tracing::debug!(
                "collecting {} frames in flight: {} blocks from RAM ({pending} slots reserved), \
                 {need} slots needed ({} free), table {}/{} entries",
                self.frames_in_flight(),
                missing.len(),
                self.pool.free_count(),
                self.table.host.len(),
                self.table.host.capacity()
            );
            self.collect_frames(layer, true)?;
            return self.make_resident_inner(layer, (blocks, device_inserts), camera_m, encoder);
        }
        if self.pool.free_count() < need {
            let in_frame: HashSet<BlockIndex> = blocks.iter().copied().collect();
            self.make_room(layer, need, &in_frame, camera_m)?;
        }
        if !self.table.host.has_room_for(need) {
            // Tombstones fill it: rebuilt at the pool's size (the slots hold every block).
            let entries = table_entries(self.pool.capacity()).max(self.table.host.capacity());
            self.table.host.rebuild(entries);
        }
        let mut encoder = encoder;
        let uploaded = self.upload_blocks(layer, &missing, encoder.as_deref_mut())?;
        for (i, slot) in missing_at.into_iter().zip(uploaded) {
            slots[i] = slot;
        }
        let reserved = self.pool.reserve(fresh);
        self.stats.slots_reserved += reserved.len() as u64;
        if !reserved.is_empty() {
            self.pool
                .fill(&self.ctx, &reserved, empty_voxel(), encoder.as_deref_mut())?;
        }
        self.stats.table_writes += self.table.upload(&self.ctx, encoder)? as u64;
        self.stats.residency_s += t.elapsed().as_secs_f64();
        Ok(FramePlacement {
            slots,
            reserved,
            dispatch: Vec::new(),
        })
    }

    /// Frees `need` slots: grows the pool, then spills blocks outside `in_frame` to RAM.
    fn make_room(
        &mut self,
        layer: &mut Layer,
        need: usize,
        in_frame: &HashSet<BlockIndex>,
        camera_m: [f64; 3],
    ) -> Result<()> {
        if let Some(capacity) = policy::grown_capacity(&self.pool, need, self.max_blocks) {
            let old = self.pool.capacity();
            self.pool.grow(&self.ctx, capacity)?;
            self.table.host.rebuild(table_entries(capacity));
            self.stats.grows += 1;
            self.stats.capacity_blocks = capacity;
            tracing::info!(
                "GPU block pool grown from {old} to {capacity} blocks ({} MiB)",
                (capacity as u64 * SLOT_BYTES) >> 20
            );
            if self.pool.free_count() >= need {
                return Ok(());
            }
        }
        let slots = policy::spill_slots(&self.pool, &self.grid, in_frame, camera_m, need);
        self.stats.blocks_spilled += slots.len() as u64;
        self.write_back(layer, &slots, true)?;
        if self.pool.free_count() < need {
            return Err(Error::GpuCapacity {
                what: "GPU block pool (frame working set)".into(),
                needed_bytes: (need + self.table.host.len()) as u64 * SLOT_BYTES,
                limit_bytes: self.pool.capacity() as u64 * SLOT_BYTES,
            });
        }
        Ok(())
    }

    /// Gives `slot` back (its key leaves the table).
    fn release(&mut self, slot: u32) {
        if let Some(k) = self.pool.release(slot) {
            self.table.host.remove(k);
        }
    }

    /// Uploads `blocks` (absent from the pool, with room made) into free slots: the layer's
    /// copy, or an empty block. Returns their slots, in `blocks` order.
    fn upload_blocks(
        &mut self,
        layer: &Layer,
        blocks: &[BlockIndex],
        encoder: Option<&mut wgpu::CommandEncoder>,
    ) -> Result<Vec<u32>> {
        if blocks.is_empty() {
            return Ok(Vec::new());
        }
        let mut data: Vec<GpuVoxel> = Vec::with_capacity(blocks.len() * VOXELS_PER_BLOCK);
        let (mut placed, mut slots, mut fresh) = (Vec::new(), Vec::new(), Vec::new());
        for b in blocks {
            let copy = layer.get(b);
            let slot = (self.pool.occupy(*b, self.frame, copy.is_some())).expect("room was made");
            match copy {
                Some(block) => {
                    pack_block_into(block, &mut data);
                    slots.push(slot);
                }
                None => fresh.push(slot),
            }
            self.table.host.insert(*b, slot);
            placed.push(slot);
        }
        self.pool.write_slots(&self.ctx, &slots, &data);
        self.pool.fill(&self.ctx, &fresh, empty_voxel(), encoder)?;
        self.stats.blocks_uploaded += slots.len() as u64;
        self.stats.blocks_created += fresh.len() as u64;
        Ok(placed)
    }

    /// The occupied slots among `slots` whose blocks hold updates not yet copied to RAM.
    fn dirty_among(&self, slots: &[u32]) -> Vec<u32> {
        (slots.iter().copied())
            .filter(|&s| self.pool.key(s).is_some() && self.pool.is_dirty(s))
            .collect()
    }

    /// Copies the dirty ones of `slots` back into the layer, then either clears their updated
    /// marks on the GPU or, with `release`, gives the slots back. Returns how many were copied.
    fn write_back(&mut self, layer: &mut Layer, slots: &[u32], release: bool) -> Result<usize> {
        let t = std::time::Instant::now();
        let dirty = self.dirty_among(slots);
        if !dirty.is_empty() {
            let voxels = self.pool.read_slots(&self.ctx, &dirty)?;
            for (&slot, vox) in dirty.iter().zip(voxels.chunks_exact(VOXELS_PER_BLOCK)) {
                let key = self.pool.key(slot).expect("resident");
                apply_updated(layer.get_or_allocate(key), vox);
                self.pool.mark_clean(slot);
                self.pool.mark_in_layer(slot);
            }
            self.stats.blocks_downloaded += dirty.len() as u64;
            if !release {
                // The blocks stay: their marks must say again what changes after this.
                self.pool.clear_updated(&self.ctx, &dirty)?;
            }
        }
        if release {
            for &s in slots {
                self.release(s);
            }
        }
        self.stats.download_s += t.elapsed().as_secs_f64();
        Ok(dirty.len())
    }

    /// Copies every dirty block back to the layer; blocks stay resident. Returns the number of
    /// blocks copied. Call before any CPU stage reads the layer (meshing, regularization,
    /// checkpoints).
    pub fn sync(&mut self, layer: &mut Layer) -> Result<usize> {
        self.collect_frames(layer, true)?;
        let slots = self.pool.dirty_slots();
        self.write_back(layer, &slots, false)
    }

    /// Copies the resident blocks among `blocks` back to the layer (when dirty) and releases
    /// them: before the pager evicts their chunk, or before a CPU stage updates them. The frames
    /// in flight are collected first where one lists one of them.
    pub fn flush_blocks(&mut self, layer: &mut Layer, blocks: &[BlockIndex]) -> Result<usize> {
        self.collect_frames_listing(layer, blocks)?;
        let slots: Vec<u32> = blocks
            .iter()
            .filter_map(|b| self.table.host.lookup(*b))
            .collect();
        self.write_back(layer, &slots, true)
    }

    /// Copies everything back and releases every slot.
    pub fn flush_all(&mut self, layer: &mut Layer) -> Result<usize> {
        self.collect_frames(layer, true)?;
        let slots: Vec<u32> = self.pool.occupied().map(|(s, _, _)| s).collect();
        self.write_back(layer, &slots, true)
    }
}

/// Entries of the hash table of a pool of `capacity` slots: four per slot, so that a full pool
/// leaves the table a quarter full, with room for the tombstones of released blocks and for
/// the insertions of frames in flight before the host must collect them to rebuild it.
fn table_entries(capacity: u32) -> usize {
    4 * capacity as usize
}

/// The voxel every voxel of an empty block packs to.
fn empty_voxel() -> GpuVoxel {
    let mut empty = Vec::with_capacity(VOXELS_PER_BLOCK);
    pack_block_into(&Block::default(), &mut empty);
    debug_assert!(empty.iter().all(|v| *v == empty[0]));
    empty[0]
}
