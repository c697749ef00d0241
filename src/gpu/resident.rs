//! The GPU tier of the map: blocks stay resident in a device pool across frames, so a frame
//! uploads only the blocks it newly needs and reads back nothing but a flag per block.
//!
//! - **Pool.** One storage buffer of `capacity` block slots (512 [`GpuVoxel`]s, 4 KiB each).
//! - **Hash table.** [`BlockTable`]: open addressing with linear probing, `vec4<u32>` entries
//!   (key x, y, z, slot), at most half full (tombstones included). The host owns it (it decides
//!   residency: allocation, eviction) and uploads the entries it changed; kernels resolve block
//!   keys through the device copy (`shaders/block_lookup.wgsl`, twin of [`BlockTable::lookup`]).
//! - **Fusion.** [`ResidentMap::integrate_depth`]: the frame's blocks are listed on the CPU
//!   exactly as [`crate::fusion::integrate_depth`] lists them; missing ones are uploaded (from the
//!   RAM layer, or empty) into free slots; `block_lookup` resolves the list to slots and
//!   `fuse_depth_resident` updates the voxels in place (the per-voxel update is
//!   `shaders/shared/fuse_common.wgsl`, shared with the non-resident kernel, so the results equal
//!   [`crate::gpu::integrate_depth_gpu`]'s). A counter of keys the table could not resolve
//!   must stay 0 (checked every frame: an inconsistent table is an error, never a silent loss).
//! - **Write-back to RAM.** The GPU copy of a resident block is authoritative; the RAM layer holds
//!   a shadow (possibly stale, an empty block for blocks created on the GPU) so that it still
//!   knows every allocated block. [`ResidentMap::sync`] copies dirty blocks back (exactly:
//!   voxels the GPU updated also reset a stored regularised value, as `Block::fuse` does);
//!   [`ResidentMap::flush_blocks`] copies back and releases (the pager's hook before it evicts
//!   a chunk from RAM, and before any CPU stage touches those blocks).
//! - **Overflow.** When a frame needs more slots than are free, the pool first grows (doubling,
//!   up to `max_bytes` and the device's binding limit), then spills: the least recently used
//!   blocks outside the frame, farthest from the camera first, are written back to RAM and
//!   released. A frame whose own blocks exceed the largest pool is fused by the non-resident
//!   batched path instead (counted in [`ResidentStats::oversize_frames`], with a warning). Every
//!   grow, spill and fallback is counted; none is silent.
//!
//! After an error the device copy may be partly updated: drop the map without syncing; the layer
//! holds the state of the last successful sync.

use super::context::{ErrorScopes, GpuContext, READ, READ_WRITE, UNIFORM};
use super::fuse::{block_base, frame_uniforms, pixel_words};
use super::layout::{pack_block_into, FuseUniforms, GpuVoxel, LookupUniforms, UPDATED_BIT};
use super::shaders;
use crate::frame::DepthFrame;
use crate::fusion::{depth_frame_blocks, usable, visible_blocks, DepthFusionParams, FusionStats};
use crate::grid::{Block, BlockIndex, GridParams, Layer, TouchedBlocks, VOXELS_PER_BLOCK};
use crate::{Error, Result};
use std::collections::HashSet;
use std::sync::Arc;

/// Bytes of one block slot in the pool.
pub const SLOT_BYTES: u64 = (VOXELS_PER_BLOCK * std::mem::size_of::<GpuVoxel>()) as u64;
/// Table entry of an empty position (keep in sync with `shaders/shared/block_hash.wgsl`).
pub const SLOT_EMPTY: u32 = u32::MAX;
/// Table entry of a removed key (keep in sync with `shaders/shared/block_hash.wgsl`).
pub const SLOT_TOMBSTONE: u32 = u32::MAX - 1;

const LOOKUP_BINDINGS: [wgpu::BufferBindingType; 4] = [UNIFORM, READ, READ, READ_WRITE];
const FUSE_RESIDENT_BINDINGS: [wgpu::BufferBindingType; 8] = [
    UNIFORM, READ, READ, READ, READ_WRITE, READ_WRITE, READ, READ_WRITE,
];

/// A 32-bit integer finaliser (bijective); twin of `mix32` in `shaders/shared/block_hash.wgsl`.
#[inline]
pub fn mix32(x: u32) -> u32 {
    let mut h = x;
    h ^= h >> 16;
    h = h.wrapping_mul(0x7feb_352d);
    h ^= h >> 15;
    h = h.wrapping_mul(0x846c_a68b);
    h ^= h >> 16;
    h
}

/// Hash of a block key; twin of `block_hash` in `shaders/shared/block_hash.wgsl`.
#[inline]
pub fn block_hash(k: BlockIndex) -> u32 {
    let a = mix32(k.0[0] as u32);
    let b = mix32(a ^ k.0[1] as u32);
    mix32(b ^ k.0[2] as u32)
}

/// The host's copy of the GPU block hash table (see the module documentation).
#[derive(Clone, Debug)]
pub struct BlockTable {
    entries: Vec<[u32; 4]>,
    live: usize,
    tombstones: usize,
    /// Positions changed since the last upload (`None`: upload everything).
    changed: Option<Vec<u32>>,
}

impl BlockTable {
    /// An empty table for up to `blocks` live keys (capacity a power of two ≥ 2·blocks).
    pub fn for_blocks(blocks: u32) -> Self {
        let capacity = (2 * blocks as usize).next_power_of_two().max(64);
        BlockTable {
            entries: vec![[0, 0, 0, SLOT_EMPTY]; capacity],
            live: 0,
            tombstones: 0,
            changed: None,
        }
    }

    /// Entries (a power of two).
    pub fn capacity(&self) -> usize {
        self.entries.len()
    }

    /// Live keys.
    pub fn len(&self) -> usize {
        self.live
    }

    /// Whether no key is live.
    pub fn is_empty(&self) -> bool {
        self.live == 0
    }

    /// Capacity − 1 (the probe mask).
    pub fn mask(&self) -> u32 {
        (self.entries.len() - 1) as u32
    }

    fn key_words(k: BlockIndex) -> [u32; 3] {
        k.0.map(|c| c as u32)
    }

    /// The slot of `k`, probing as `block_lookup.wgsl` does.
    pub fn lookup(&self, k: BlockIndex) -> Option<u32> {
        let want = Self::key_words(k);
        let mask = self.mask();
        let mut pos = block_hash(k) & mask;
        for _ in 0..self.entries.len() {
            let e = self.entries[pos as usize];
            if e[3] == SLOT_EMPTY {
                return None;
            }
            if e[3] != SLOT_TOMBSTONE && e[..3] == want {
                return Some(e[3]);
            }
            pos = (pos + 1) & mask;
        }
        None
    }

    fn note(&mut self, pos: u32) {
        if let Some(c) = self.changed.as_mut() {
            c.push(pos);
        }
    }

    /// Inserts `k → slot`; `k` must be absent. Rebuilds (dropping tombstones) first when the
    /// table would pass half full.
    pub fn insert(&mut self, k: BlockIndex, slot: u32) {
        debug_assert!(self.lookup(k).is_none());
        debug_assert!(slot < SLOT_TOMBSTONE);
        if 2 * (self.live + self.tombstones + 1) > self.entries.len() {
            let capacity = if 2 * (self.live + 1) > self.entries.len() / 2 {
                self.entries.len() * 2
            } else {
                self.entries.len()
            };
            self.rebuild(capacity);
        }
        let mask = self.mask();
        let mut pos = block_hash(k) & mask;
        loop {
            let e = &mut self.entries[pos as usize];
            if e[3] == SLOT_EMPTY || e[3] == SLOT_TOMBSTONE {
                if e[3] == SLOT_TOMBSTONE {
                    self.tombstones -= 1;
                }
                let w = Self::key_words(k);
                *e = [w[0], w[1], w[2], slot];
                self.live += 1;
                self.note(pos);
                return;
            }
            pos = (pos + 1) & mask;
        }
    }

    /// Removes `k`, returning its slot.
    pub fn remove(&mut self, k: BlockIndex) -> Option<u32> {
        let want = Self::key_words(k);
        let mask = self.mask();
        let mut pos = block_hash(k) & mask;
        for _ in 0..self.entries.len() {
            let e = &mut self.entries[pos as usize];
            if e[3] == SLOT_EMPTY {
                return None;
            }
            if e[3] != SLOT_TOMBSTONE && e[..3] == want {
                let slot = e[3];
                e[3] = SLOT_TOMBSTONE;
                self.live -= 1;
                self.tombstones += 1;
                self.note(pos);
                return Some(slot);
            }
            pos = (pos + 1) & mask;
        }
        None
    }

    /// Re-inserts every live key into `capacity` entries (a power of two); the whole table is
    /// uploaded next.
    pub fn rebuild(&mut self, capacity: usize) {
        let capacity = capacity.next_power_of_two().max(64);
        let old = std::mem::replace(&mut self.entries, vec![[0, 0, 0, SLOT_EMPTY]; capacity]);
        self.live = 0;
        self.tombstones = 0;
        self.changed = None;
        for e in old {
            if e[3] < SLOT_TOMBSTONE {
                let k = BlockIndex([e[0] as i32, e[1] as i32, e[2] as i32]);
                let mask = self.mask();
                let mut pos = block_hash(k) & mask;
                while self.entries[pos as usize][3] != SLOT_EMPTY {
                    pos = (pos + 1) & mask;
                }
                self.entries[pos as usize] = e;
                self.live += 1;
            }
        }
    }

    /// The changed positions since the last call (`None`: everything), and resets the record.
    fn take_changes(&mut self) -> Option<Vec<u32>> {
        self.changed.replace(Vec::new())
    }

    /// The raw entries (what the device copy holds after an upload).
    pub fn entries(&self) -> &[[u32; 4]] {
        &self.entries
    }
}

/// Looks `keys` up in a copy of `table` uploaded whole (`block_lookup.wgsl`): the GPU twin of
/// [`BlockTable::lookup`].
pub fn lookup_table_on_gpu(
    ctx: &GpuContext,
    table: &BlockTable,
    keys: &[BlockIndex],
) -> Result<Vec<Option<u32>>> {
    let buf_table = ctx.storage("block_table", bytemuck::cast_slice(table.entries()));
    run_lookup(ctx, &buf_table, table.mask(), keys)
}

/// Runs `block_lookup.wgsl` over `keys` against the device table `buf_table`.
fn run_lookup(
    ctx: &GpuContext,
    buf_table: &wgpu::Buffer,
    mask: u32,
    keys: &[BlockIndex],
) -> Result<Vec<Option<u32>>> {
    if keys.is_empty() {
        return Ok(Vec::new());
    }
    let kernel = ctx.kernel(&shaders::BLOCK_LOOKUP, &LOOKUP_BINDINGS)?;
    let scope = ErrorScopes::push(&ctx.device);
    let (buf_keys, buf_slots, buf_uniforms) = lookup_buffers(ctx, mask, keys)?;
    let bind = ctx.bind_group(
        "block_lookup",
        &kernel.layout,
        &[&buf_uniforms, buf_table, &buf_keys, &buf_slots],
    );
    let mut encoder = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("block_lookup"),
        });
    ctx.record_dispatch(&mut encoder, &kernel.pipeline, &bind, keys.len() as u64)?;
    ctx.queue.submit([encoder.finish()]);
    scope.pop("looking blocks up on the GPU")?;
    let out = ctx.read_back(&[(&buf_slots, keys.len() as u64 * 4)])?;
    let slots: Vec<u32> = bytemuck::pod_collect_to_vec(&out[0]);
    Ok(slots
        .into_iter()
        .map(|s| (s < SLOT_TOMBSTONE).then_some(s))
        .collect())
}

/// Keys, slots (all [`SLOT_EMPTY`]) and uniforms of a `block_lookup.wgsl` dispatch.
fn lookup_buffers(
    ctx: &GpuContext,
    mask: u32,
    keys: &[BlockIndex],
) -> Result<(wgpu::Buffer, wgpu::Buffer, wgpu::Buffer)> {
    ctx.check_binding("block keys (16 bytes per block)", keys.len() as u64 * 16)?;
    let words: Vec<[i32; 4]> = keys.iter().map(|k| [k.0[0], k.0[1], k.0[2], 0]).collect();
    let buf_keys = ctx.storage("lookup_keys", bytemuck::cast_slice(&words));
    let buf_slots = ctx.storage(
        "lookup_slots",
        bytemuck::cast_slice(&vec![SLOT_EMPTY; keys.len()]),
    );
    let uniforms = LookupUniforms {
        key_count: keys.len() as u32,
        mask,
        pad: [0; 2],
    };
    let buf_uniforms = ctx.uniform("lookup_uniforms", bytemuck::bytes_of(&uniforms));
    Ok((buf_keys, buf_slots, buf_uniforms))
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
    /// Blocks uploaded (from RAM or fresh).
    pub blocks_uploaded: u64,
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
    /// Seconds listing each frame's blocks on the CPU (band and visible blocks).
    pub list_s: f64,
    /// Seconds making blocks resident (growing, spilling, uploading blocks and table entries).
    pub residency_s: f64,
    /// Seconds in the lookup and fusion dispatches, waiting included, and the flag readback.
    pub kernel_s: f64,
    /// Seconds copying blocks back to RAM (syncs, flushes, spills).
    pub download_s: f64,
}

/// Blocks resident on the GPU across frames, over a RAM [`Layer`] (see the module
/// documentation).
pub struct ResidentMap {
    ctx: Arc<GpuContext>,
    grid: GridParams,
    capacity: u32,
    max_blocks: u32,
    pool: wgpu::Buffer,
    table: BlockTable,
    table_buf: wgpu::Buffer,
    slot_key: Vec<Option<BlockIndex>>,
    free: Vec<u32>,
    dirty: Vec<bool>,
    last_used: Vec<u64>,
    frame: u64,
    stats: ResidentStats,
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
        let table = BlockTable::for_blocks(max_blocks.min(capacity.saturating_mul(2)));
        let scope = ErrorScopes::push(&ctx.device);
        let pool = Self::pool_buffer(&ctx, capacity)?;
        let table_buf = ctx.storage("block_table", bytemuck::cast_slice(table.entries()));
        scope.pop("allocating the GPU block pool")?;
        let mut map = ResidentMap {
            ctx,
            grid,
            capacity,
            max_blocks,
            pool,
            table,
            table_buf,
            slot_key: vec![None; capacity as usize],
            free: (0..capacity).rev().collect(),
            dirty: vec![false; capacity as usize],
            last_used: vec![0; capacity as usize],
            frame: 0,
            stats: ResidentStats::default(),
        };
        map.table.changed = Some(Vec::new());
        map.stats.capacity_blocks = capacity;
        map.stats.max_blocks = max_blocks;
        Ok(map)
    }

    fn pool_buffer(ctx: &GpuContext, capacity: u32) -> Result<wgpu::Buffer> {
        let bytes = capacity as u64 * SLOT_BYTES;
        ctx.check_binding("GPU block pool (4 KiB per block)", bytes)?;
        Ok(ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("block_pool"),
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        }))
    }

    /// The counters.
    pub fn stats(&self) -> ResidentStats {
        ResidentStats {
            resident_blocks: self.table.len(),
            ..self.stats
        }
    }

    /// The GPU this map lives on.
    pub fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }

    /// The slot of a resident block (the host's table).
    pub fn slot_of(&self, b: BlockIndex) -> Option<u32> {
        self.table.lookup(b)
    }

    /// Resident blocks, sorted.
    pub fn resident_blocks(&self) -> Vec<BlockIndex> {
        let mut v: Vec<BlockIndex> = self.slot_key.iter().flatten().copied().collect();
        v.sort_unstable();
        v
    }

    /// Whether a resident block holds updates not yet copied to RAM.
    pub fn is_dirty(&self, b: BlockIndex) -> bool {
        self.table.lookup(b).is_some_and(|s| self.dirty[s as usize])
    }

    /// Uploads the table entries changed since the last upload.
    fn upload_table(&mut self) {
        match self.table.take_changes() {
            None => {
                self.table_buf = self
                    .ctx
                    .storage("block_table", bytemuck::cast_slice(self.table.entries()));
            }
            Some(mut positions) => {
                positions.sort_unstable();
                positions.dedup();
                // Contiguous runs in one write each.
                let mut k = 0;
                while k < positions.len() {
                    let start = positions[k];
                    let mut end = start;
                    while k + 1 < positions.len() && positions[k + 1] == end + 1 {
                        k += 1;
                        end += 1;
                    }
                    let e = &self.table.entries()[start as usize..=end as usize];
                    self.ctx.queue.write_buffer(
                        &self.table_buf,
                        start as u64 * 16,
                        bytemuck::cast_slice(e),
                    );
                    k += 1;
                }
            }
        }
    }

    /// Looks `keys` up in the device's copy of the table (`block_lookup.wgsl`): the GPU's view
    /// of residency, which must equal [`ResidentMap::slot_of`].
    pub fn lookup_on_gpu(&mut self, keys: &[BlockIndex]) -> Result<Vec<Option<u32>>> {
        self.upload_table();
        run_lookup(&self.ctx, &self.table_buf, self.table.mask(), keys)
    }

    /// Fuses one depth frame, like [`crate::fusion::integrate_depth`]: the blocks crossed by its
    /// truncation band plus the allocated blocks in view, updated on the GPU in place.
    pub fn integrate_depth(
        &mut self,
        layer: &mut Layer,
        frame: &DepthFrame,
        params: &DepthFusionParams,
    ) -> Result<(TouchedBlocks, FusionStats)> {
        let t = std::time::Instant::now();
        let band = depth_frame_blocks(&layer.params(), frame, params);
        self.stats.list_s += t.elapsed().as_secs_f64();
        self.integrate_depth_band(layer, frame, params, band)
    }

    /// [`ResidentMap::integrate_depth`] with the band's blocks already listed (as
    /// [`crate::fusion::integrate_depth_band`]).
    pub fn integrate_depth_band(
        &mut self,
        layer: &mut Layer,
        frame: &DepthFrame,
        params: &DepthFusionParams,
        band: TouchedBlocks,
    ) -> Result<(TouchedBlocks, FusionStats)> {
        if layer.params() != self.grid {
            return Err(Error::InvalidArgument(
                "resident GPU map and layer have different grids".into(),
            ));
        }
        let t = std::time::Instant::now();
        let mut blocks = band;
        blocks.extend(visible_blocks(layer, frame, params));
        blocks.sort_unstable();
        blocks.dedup();
        self.stats.list_s += t.elapsed().as_secs_f64();
        self.frame += 1;
        self.stats.frames += 1;
        self.stats.largest_frame_blocks = self.stats.largest_frame_blocks.max(blocks.len());
        if blocks.is_empty() {
            return Ok((Vec::new(), FusionStats::default()));
        }
        let measurements = frame
            .depth_m
            .data
            .iter()
            .filter(|&&d| usable(d, params))
            .count();
        let camera: [f64; 3] = frame.world_from_camera.translation.vector.into();
        if blocks.len() > self.max_blocks as usize {
            // The frame alone exceeds the largest pool: give its resident blocks back to RAM and
            // fuse it in batches.
            self.stats.oversize_frames += 1;
            tracing::warn!(
                "frame needs {} blocks, more than the GPU pool's {} (raise the GPU memory \
                 budget); fusing it in batches",
                blocks.len(),
                self.max_blocks
            );
            self.flush_blocks(layer, &blocks)?;
            return super::integrate_depth_gpu(&self.ctx, layer, frame, params);
        }
        let in_frame: HashSet<BlockIndex> = blocks.iter().copied().collect();
        let missing: Vec<BlockIndex> = blocks
            .iter()
            .copied()
            .filter(|b| self.table.lookup(*b).is_none())
            .collect();
        let t = std::time::Instant::now();
        self.make_room(layer, missing.len(), &in_frame, camera)?;
        self.upload_blocks(layer, &missing)?;
        self.upload_table();
        self.stats.residency_s += t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let (updated, voxel_updates) = self.run_fusion(&blocks, frame, params)?;
        self.stats.kernel_s += t.elapsed().as_secs_f64();
        // Book-keeping: the layer learns the blocks created on the GPU; blocks the frame did not
        // update and the layer never had are released.
        let mut touched = Vec::with_capacity(blocks.len());
        for (b, up) in blocks.iter().zip(&updated) {
            let slot = self.table.lookup(*b).expect("resident");
            let in_layer = layer.contains(b);
            if *up {
                self.dirty[slot as usize] = true;
                if !in_layer {
                    layer.insert(*b, Block::new_boxed());
                }
                touched.push(*b);
            } else if in_layer {
                touched.push(*b);
            } else {
                self.release(slot);
                continue;
            }
            self.last_used[slot as usize] = self.frame;
        }
        self.stats.peak_resident_blocks = self.stats.peak_resident_blocks.max(self.table.len());
        let stats = FusionStats {
            blocks: touched.len(),
            voxel_updates,
            measurements,
        };
        Ok((touched, stats))
    }

    /// Frees `need` slots: grows the pool, then spills blocks outside `in_frame` to RAM.
    fn make_room(
        &mut self,
        layer: &mut Layer,
        need: usize,
        in_frame: &HashSet<BlockIndex>,
        camera: [f64; 3],
    ) -> Result<()> {
        if self.free.len() >= need {
            return Ok(());
        }
        if self.capacity < self.max_blocks {
            let wanted = self.capacity as usize + need - self.free.len();
            let mut cap = self.capacity as usize;
            while cap < wanted {
                cap *= 2;
            }
            self.grow(cap.min(self.max_blocks as usize) as u32)?;
            if self.free.len() >= need {
                return Ok(());
            }
        }
        // Spill: least recently used first, then farthest from the camera; an eighth of the
        // pool beyond what is needed, so spills come in batches.
        let block_m = self.grid.block_size_m();
        let mut candidates: Vec<(u64, i64, BlockIndex, u32)> = self
            .slot_key
            .iter()
            .enumerate()
            .filter_map(|(s, k)| k.map(|k| (s as u32, k)))
            .filter(|(_, k)| !in_frame.contains(k))
            .map(|(s, k)| {
                let d2: f64 = (0..3)
                    .map(|a| ((k.0[a] as f64 + 0.5) * block_m - camera[a]).powi(2))
                    .sum();
                (self.last_used[s as usize], -(d2 as i64), k, s)
            })
            .collect();
        candidates.sort_unstable();
        let count = (need - self.free.len() + self.capacity as usize / 8).min(candidates.len());
        let slots: Vec<u32> = candidates[..count].iter().map(|c| c.3).collect();
        self.stats.blocks_spilled += slots.len() as u64;
        self.download(layer, &slots, true)?;
        if self.free.len() < need {
            return Err(Error::GpuCapacity {
                what: "GPU block pool (frame working set)".into(),
                needed_bytes: (need + self.table.len()) as u64 * SLOT_BYTES,
                limit_bytes: self.capacity as u64 * SLOT_BYTES,
            });
        }
        Ok(())
    }

    /// Reallocates the pool with `capacity` slots, keeping every resident block in its slot.
    fn grow(&mut self, capacity: u32) -> Result<()> {
        if capacity <= self.capacity {
            return Ok(());
        }
        let scope = ErrorScopes::push(&self.ctx.device);
        let pool = Self::pool_buffer(&self.ctx, capacity)?;
        let mut encoder = self
            .ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("grow_pool"),
            });
        encoder.copy_buffer_to_buffer(&self.pool, 0, &pool, 0, self.capacity as u64 * SLOT_BYTES);
        self.ctx.queue.submit([encoder.finish()]);
        scope.pop("growing the GPU block pool")?;
        tracing::info!(
            "GPU block pool grown from {} to {} blocks ({} MiB)",
            self.capacity,
            capacity,
            (capacity as u64 * SLOT_BYTES) >> 20
        );
        self.pool = pool;
        let old = self.capacity;
        self.capacity = capacity;
        self.slot_key.resize(capacity as usize, None);
        self.dirty.resize(capacity as usize, false);
        self.last_used.resize(capacity as usize, 0);
        // New slots go under the old free ones, lowest first.
        let mut new_free: Vec<u32> = (old..capacity).rev().collect();
        new_free.append(&mut self.free);
        self.free = new_free;
        self.table.rebuild(2 * capacity as usize);
        self.stats.grows += 1;
        self.stats.capacity_blocks = capacity;
        Ok(())
    }

    /// Gives `slot` back (its key leaves the table).
    fn release(&mut self, slot: u32) {
        if let Some(k) = self.slot_key[slot as usize].take() {
            self.table.remove(k);
            self.dirty[slot as usize] = false;
            self.free.push(slot);
        }
    }

    /// Uploads `blocks` (absent from the pool) into free slots: the layer's copy, or an empty
    /// block.
    fn upload_blocks(&mut self, layer: &Layer, blocks: &[BlockIndex]) -> Result<()> {
        if blocks.is_empty() {
            return Ok(());
        }
        let mut empty = Vec::with_capacity(VOXELS_PER_BLOCK);
        pack_block_into(&Block::default(), &mut empty);
        let mut data: Vec<GpuVoxel> = Vec::with_capacity(blocks.len() * VOXELS_PER_BLOCK);
        let mut slots = Vec::with_capacity(blocks.len());
        for b in blocks {
            let slot = self.free.pop().expect("room was made");
            match layer.get(b) {
                Some(block) => pack_block_into(block, &mut data),
                None => data.extend_from_slice(&empty),
            }
            self.slot_key[slot as usize] = Some(*b);
            self.dirty[slot as usize] = false;
            self.last_used[slot as usize] = self.frame;
            self.table.insert(*b, slot);
            slots.push(slot);
        }
        self.write_slots(&slots, &data, "uploading blocks to the GPU pool")?;
        self.stats.blocks_uploaded += blocks.len() as u64;
        Ok(())
    }

    /// Writes `data` (512 voxels per slot, in `slots` order) into the pool: one staging buffer,
    /// one copy per run of consecutive slots.
    fn write_slots(&self, slots: &[u32], data: &[GpuVoxel], doing: &str) -> Result<()> {
        let scope = ErrorScopes::push(&self.ctx.device);
        let staging = self.ctx.storage("pool_upload", bytemuck::cast_slice(data));
        let mut encoder = self
            .ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("pool_upload"),
            });
        for (k, run) in runs(slots) {
            encoder.copy_buffer_to_buffer(
                &staging,
                k as u64 * SLOT_BYTES,
                &self.pool,
                slots[k] as u64 * SLOT_BYTES,
                run as u64 * SLOT_BYTES,
            );
        }
        self.ctx.queue.submit([encoder.finish()]);
        scope.pop(doing)
    }

    /// Resolves `blocks` to slots on the GPU and fuses the frame into them. Returns, per block,
    /// whether any voxel was updated, and the number of voxel updates.
    fn run_fusion(
        &mut self,
        blocks: &[BlockIndex],
        frame: &DepthFrame,
        params: &DepthFusionParams,
    ) -> Result<(Vec<bool>, usize)> {
        let ctx = self.ctx.clone();
        let n = blocks.len() as u64;
        let voxel_count = n * VOXELS_PER_BLOCK as u64;
        if voxel_count > u32::MAX as u64 {
            return Err(Error::GpuCapacity {
                what: "voxels of one dispatch".into(),
                needed_bytes: voxel_count,
                limit_bytes: u32::MAX as u64,
            });
        }
        let (uniforms, camera_from_world) = frame_uniforms(&self.grid, frame, params);
        let uniforms = FuseUniforms {
            voxel_count: voxel_count as u32,
            ..uniforms
        };
        ctx.check_binding(
            "depth image (4 bytes per pixel)",
            frame.depth_m.data.len() as u64 * 4,
        )?;
        ctx.check_binding("block bases (16 bytes per block)", n * 16)?;
        let bases: Vec<[f32; 4]> = blocks
            .iter()
            .map(|b| block_base(&self.grid, &camera_from_world, *b))
            .collect();
        let pixels = pixel_words(frame, params);
        let lookup = ctx.kernel(&shaders::BLOCK_LOOKUP, &LOOKUP_BINDINGS)?;
        let fuse = ctx.kernel(&shaders::FUSE_DEPTH_RESIDENT, &FUSE_RESIDENT_BINDINGS)?;
        let scope = ErrorScopes::push(&ctx.device);
        let (buf_keys, buf_slots, buf_lookup) = lookup_buffers(&ctx, self.table.mask(), blocks)?;
        let buf_uniforms = ctx.uniform("fuse_uniforms", bytemuck::bytes_of(&uniforms));
        let buf_bases = ctx.storage("fuse_block_base", bytemuck::cast_slice(&bases));
        let buf_depth = ctx.storage("fuse_depth", bytemuck::cast_slice(&frame.depth_m.data));
        let buf_pixel = ctx.storage("fuse_pixel", bytemuck::cast_slice(&pixels));
        let buf_counters = ctx.storage("fuse_counters", bytemuck::cast_slice(&[0u32; 4]));
        let buf_updated = ctx.storage("block_updated", bytemuck::cast_slice(&vec![0u32; n as _]));
        let bind_lookup = ctx.bind_group(
            "block_lookup",
            &lookup.layout,
            &[&buf_lookup, &self.table_buf, &buf_keys, &buf_slots],
        );
        let bind_fuse = ctx.bind_group(
            "fuse_depth_resident",
            &fuse.layout,
            &[
                &buf_uniforms,
                &buf_bases,
                &buf_depth,
                &buf_pixel,
                &self.pool,
                &buf_counters,
                &buf_slots,
                &buf_updated,
            ],
        );
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("fuse_depth_resident"),
            });
        ctx.record_dispatch(&mut encoder, &lookup.pipeline, &bind_lookup, n)?;
        ctx.record_dispatch(&mut encoder, &fuse.pipeline, &bind_fuse, voxel_count)?;
        ctx.queue.submit([encoder.finish()]);
        scope.pop("running the resident fusion kernel")?;
        let out = ctx.read_back(&[(&buf_counters, 8), (&buf_updated, n * 4)])?;
        let counters: Vec<u32> = bytemuck::pod_collect_to_vec(&out[0]);
        if counters[1] != 0 {
            return Err(Error::Gpu(format!(
                "the GPU hash table could not resolve {} of {} resident blocks",
                counters[1], n
            )));
        }
        let flags: Vec<u32> = bytemuck::pod_collect_to_vec(&out[1]);
        Ok((
            flags.iter().map(|&f| f != 0).collect(),
            counters[0] as usize,
        ))
    }

    /// Reads `slots` back into the layer (dirty ones only), then either clears their updated
    /// bits on the GPU or, with `release`, gives the slots back.
    fn download(&mut self, layer: &mut Layer, slots: &[u32], release: bool) -> Result<usize> {
        let t = std::time::Instant::now();
        let n = self.download_inner(layer, slots, release)?;
        self.stats.download_s += t.elapsed().as_secs_f64();
        Ok(n)
    }

    fn download_inner(&mut self, layer: &mut Layer, slots: &[u32], release: bool) -> Result<usize> {
        let dirty: Vec<u32> = slots
            .iter()
            .copied()
            .filter(|&s| self.slot_key[s as usize].is_some() && self.dirty[s as usize])
            .collect();
        if !dirty.is_empty() {
            let bytes = dirty.len() as u64 * SLOT_BYTES;
            self.ctx.check_binding("block readback", bytes)?;
            let scope = ErrorScopes::push(&self.ctx.device);
            let gather = self.ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("pool_download"),
                size: bytes,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut encoder =
                self.ctx
                    .device
                    .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                        label: Some("pool_download"),
                    });
            for (k, run) in runs(&dirty) {
                encoder.copy_buffer_to_buffer(
                    &self.pool,
                    dirty[k] as u64 * SLOT_BYTES,
                    &gather,
                    k as u64 * SLOT_BYTES,
                    run as u64 * SLOT_BYTES,
                );
            }
            self.ctx.queue.submit([encoder.finish()]);
            scope.pop("gathering blocks for readback")?;
            let out = self.ctx.read_back(&[(&gather, bytes)])?;
            let mut voxels: Vec<GpuVoxel> = bytemuck::pod_collect_to_vec(&out[0]);
            for (k, &slot) in dirty.iter().enumerate() {
                let key = self.slot_key[slot as usize].expect("resident");
                let block = layer.get_or_allocate(key);
                let vox = &mut voxels[k * VOXELS_PER_BLOCK..(k + 1) * VOXELS_PER_BLOCK];
                for (i, v) in vox.iter_mut().enumerate() {
                    block.tsdf[i] = v.tsdf();
                    block.weight_omega[i] = v.weight_omega();
                    block.color[i] = v.rgb();
                    if v.updated() {
                        // As Block::fuse: the raw field changed, a stored regularised value
                        // follows it.
                        if let Some(u) = block.regularized.as_mut() {
                            u[i] = block.tsdf[i];
                        }
                        v.tsdf_weight &= !UPDATED_BIT;
                    }
                }
                self.dirty[slot as usize] = false;
            }
            self.stats.blocks_downloaded += dirty.len() as u64;
            if !release {
                self.write_slots(&dirty, &voxels, "clearing updated bits")?;
            }
        }
        if release {
            for &s in slots {
                self.release(s);
            }
        }
        Ok(dirty.len())
    }

    /// Copies every dirty block back to the layer; blocks stay resident. Returns the number of
    /// blocks copied. Call before any CPU stage reads the layer (meshing, regularisation,
    /// checkpoints).
    pub fn sync(&mut self, layer: &mut Layer) -> Result<usize> {
        let slots: Vec<u32> = (0..self.capacity)
            .filter(|&s| self.dirty[s as usize])
            .collect();
        self.download(layer, &slots, false)
    }

    /// Copies the resident blocks among `blocks` back to the layer (when dirty) and releases
    /// them: before the pager evicts their chunk, or before a CPU stage updates them.
    pub fn flush_blocks(&mut self, layer: &mut Layer, blocks: &[BlockIndex]) -> Result<usize> {
        let slots: Vec<u32> = blocks
            .iter()
            .filter_map(|b| self.table.lookup(*b))
            .collect();
        self.download(layer, &slots, true)
    }

    /// Copies everything back and releases every slot.
    pub fn flush_all(&mut self, layer: &mut Layer) -> Result<usize> {
        let slots: Vec<u32> = (0..self.capacity)
            .filter(|&s| self.slot_key[s as usize].is_some())
            .collect();
        self.download(layer, &slots, true)
    }
}

/// Runs of consecutive values in `slots`: (start position, length).
fn runs(slots: &[u32]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut k = 0;
    while k < slots.len() {
        let mut len = 1;
        while k + len < slots.len() && slots[k + len] == slots[k] + len as u32 {
            len += 1;
        }
        out.push((k, len));
        k += len;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_finds_what_it_holds_through_removals_and_rebuilds() {
        let mut t = BlockTable::for_blocks(32);
        let mut truth = std::collections::HashMap::new();
        let mut rng = 12345u64;
        for step in 0..5000u32 {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let k = BlockIndex([
                ((rng >> 33) % 17) as i32 - 8,
                ((rng >> 45) % 9) as i32 - 4,
                ((rng >> 53) % 5) as i32 - 2_000_000,
            ]);
            if let Some(slot) = truth.remove(&k) {
                assert_eq!(t.remove(k), Some(slot));
            } else {
                t.insert(k, step);
                truth.insert(k, step);
            }
            assert!(2 * (t.live + t.tombstones) <= t.capacity());
        }
        assert_eq!(t.len(), truth.len());
        for (k, s) in &truth {
            assert_eq!(t.lookup(*k), Some(*s));
        }
        assert_eq!(t.lookup(BlockIndex([1000, 0, 0])), None);
    }

    #[test]
    fn hash_spreads_a_neighbourhood() {
        let mut seen = std::collections::HashSet::new();
        for z in 0..16 {
            for y in 0..16 {
                for x in 0..16 {
                    seen.insert(block_hash(BlockIndex([x, y, z])) & 4095);
                }
            }
        }
        // A uniform hash puts 4096 keys into about 4096·(1 − 1/e) ≈ 2589 of 4096 buckets.
        assert!(seen.len() > 2450, "{}", seen.len());
    }

    #[test]
    fn runs_split_at_gaps() {
        assert_eq!(runs(&[3, 4, 5, 9, 10, 2]), vec![(0, 3), (3, 2), (5, 1)]);
        assert!(runs(&[]).is_empty());
    }
}
