//! The block pool: one storage buffer of block slots (512 [`GpuVoxel`]s, 4 KiB each) and the
//! host's record of each slot ([`SlotRecord`]: its block, whether the RAM layer holds it,
//! whether the GPU changed it since the last write-back, the frame that last used it), with the
//! copies between RAM and the pool. It decides nothing:
//! the resident map ([`super::ResidentMap`]) chooses what to upload, and [`super::policy`] what
//! to spill.

use crate::gpu::kept::Kept;
use crate::gpu::layout::{GpuVoxel, SlotFillUniforms, SlotListUniforms};
use crate::gpu::readback::{LateReadback, ReadbackRing};
use crate::gpu::shaders;
use crate::gpu::{ErrorScopes, GpuContext};
use crate::grid::{BlockIndex, VOXELS_PER_BLOCK};
use crate::Result;

/// Bytes of one block slot in the pool.
pub const SLOT_BYTES: u64 = (VOXELS_PER_BLOCK * std::mem::size_of::<GpuVoxel>()) as u64;

/// The host's record of one slot: 32 bytes, so that a frame's bookkeeping reads one cache line
/// per block, not one per field.
#[derive(Clone, Copy, Debug, Default)]
struct SlotRecord {
    /// The block it holds.
    key: Option<BlockIndex>,
    /// The frame that last used it (the spill order).
    last_used: u64,
    /// Whether it holds changes not yet written back to RAM.
    dirty: bool,
    /// Whether the RAM layer holds its block (a copy, or a shadow the write-back fills): false
    /// for a block made on the GPU that no frame has updated yet. The twin of
    /// `layer.contains(key)` while the block is resident, since every change of the layer's
    /// blocks while resident goes through the map (blocks leave RAM only after they leave the
    /// pool); `late.rs` asserts it in debug builds.
    in_layer: bool,
}

impl SlotRecord {
    fn occupied(key: BlockIndex, last_used: u64, in_layer: bool) -> Self {
        SlotRecord {
            key: Some(key),
            last_used,
            dirty: false,
            in_layer,
        }
    }
}

/// Slots on the device and the host's record of them.
pub(crate) struct BlockPool {
    buffer: wgpu::Buffer,
    /// Per slot: 1 once a depth frame or LiDAR scan updated its block since the slot was given
    /// to it (`resident/late.rs`), 4 bytes each.
    exists: wgpu::Buffer,
    capacity: u32,
    slots: Vec<SlotRecord>,
    free: Vec<u32>,
    /// The gather, staging and slot-list buffers of the copies, kept between calls.
    kept: Kept,
}

impl BlockPool {
    /// A pool of `capacity` empty slots.
    pub(crate) fn new(ctx: &GpuContext, capacity: u32) -> Result<Self> {
        Ok(BlockPool {
            buffer: Self::buffer(ctx, capacity)?,
            exists: Self::exists_buffer(ctx, capacity),
            capacity,
            slots: vec![SlotRecord::default(); capacity as usize],
            free: (0..capacity).rev().collect(),
            kept: Kept::default(),
        })
    }

    fn buffer(ctx: &GpuContext, capacity: u32) -> Result<wgpu::Buffer> {
        let bytes = capacity as u64 * SLOT_BYTES;
        ctx.check_binding("GPU block pool (4 KiB per block)", bytes)?;
        Ok(ctx.create_buffer(&wgpu::BufferDescriptor {
            label: Some("block_pool"),
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        }))
    }

    /// The device buffer (all slots).
    pub(crate) fn device_buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// The per-slot marks of blocks a frame or scan updated (see the field).
    pub(crate) fn exists_buffer_of(&self) -> &wgpu::Buffer {
        &self.exists
    }

    /// A zeroed mark per slot.
    fn exists_buffer(ctx: &GpuContext, capacity: u32) -> wgpu::Buffer {
        ctx.create_buffer(&wgpu::BufferDescriptor {
            label: Some("slot_exists"),
            size: capacity as u64 * 4,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Slots in the pool.
    pub(crate) fn capacity(&self) -> u32 {
        self.capacity
    }

    /// Free slots.
    pub(crate) fn free_count(&self) -> usize {
        self.free.len()
    }

    /// The block in `slot`, if any.
    pub(crate) fn key(&self, slot: u32) -> Option<BlockIndex> {
        self.slots[slot as usize].key
    }

    /// Occupied slots with their blocks and last use, in slot order.
    pub(crate) fn occupied(&self) -> impl Iterator<Item = (u32, BlockIndex, u64)> + '_ {
        (self.slots.iter().enumerate())
            .filter_map(|(s, r)| r.key.map(|k| (s as u32, k, r.last_used)))
    }

    /// Whether `slot` holds changes not yet written back to RAM.
    pub(crate) fn is_dirty(&self, slot: u32) -> bool {
        self.slots[slot as usize].dirty
    }

    /// Slots holding changes not yet written back, in slot order.
    pub(crate) fn dirty_slots(&self) -> Vec<u32> {
        (0..self.capacity)
            .filter(|&s| self.slots[s as usize].dirty)
            .collect()
    }

    /// Records that the GPU changed `slot` (it will be written back).
    pub(crate) fn mark_dirty(&mut self, slot: u32) {
        self.slots[slot as usize].dirty = true;
    }

    /// Records that `slot` now equals its RAM copy.
    pub(crate) fn mark_clean(&mut self, slot: u32) {
        self.slots[slot as usize].dirty = false;
    }

    /// Asks the CPU to fetch `slot`'s record into the cache, where `slot` is a slot (a loop
    /// over a frame's slots calls it for the slot it reads some iterations later).
    pub(crate) fn prefetch(&self, slot: u32) {
        if let Some(record) = self.slots.get(slot as usize) {
            super::table::prefetch(record);
        }
    }

    /// Whether the RAM layer holds the block in `slot` ([`SlotRecord::in_layer`]).
    pub(crate) fn in_layer(&self, slot: u32) -> bool {
        self.slots[slot as usize].in_layer
    }

    /// Records that the RAM layer now holds the block in `slot`.
    pub(crate) fn mark_in_layer(&mut self, slot: u32) {
        self.slots[slot as usize].in_layer = true;
    }

    /// Records a use of `slot` in frame `frame`.
    pub(crate) fn touch(&mut self, slot: u32, frame: u64) {
        self.slots[slot as usize].last_used = frame;
    }

    /// Takes a free slot for `key` (clean, used in `frame`; `in_layer`: whether the RAM layer
    /// holds it); `None` when the pool is full.
    pub(crate) fn occupy(&mut self, key: BlockIndex, frame: u64, in_layer: bool) -> Option<u32> {
        let slot = self.free.pop()?;
        self.slots[slot as usize] = SlotRecord::occupied(key, frame, in_layer);
        Some(slot)
    }

    /// Takes the top `count` free slots (at most the free ones) for the device to give to
    /// blocks it inserts (`alloc.rs`), in the list's order, the top last: the device's stack.
    pub(crate) fn reserve(&mut self, count: usize) -> Vec<u32> {
        let keep = self.free.len().saturating_sub(count);
        self.free.split_off(keep)
    }

    /// Gives reserved `slot` to `key` (clean, used in `frame`, not in the RAM layer): the
    /// device inserted it there.
    pub(crate) fn occupy_reserved(&mut self, slot: u32, key: BlockIndex, frame: u64) {
        debug_assert!(self.slots[slot as usize].key.is_none());
        self.slots[slot as usize] = SlotRecord::occupied(key, frame, false);
    }

    /// Gives back reserved slots the device did not take, in their order (the top last).
    pub(crate) fn unreserve(&mut self, slots: &[u32]) {
        self.free.extend_from_slice(slots);
    }

    /// Gives `slot` back; returns the block it held.
    pub(crate) fn release(&mut self, slot: u32) -> Option<BlockIndex> {
        let key = self.slots[slot as usize].key?;
        self.slots[slot as usize] = SlotRecord::default();
        self.free.push(slot);
        Some(key)
    }

    /// Reallocates the pool with `capacity` slots, keeping every block in its slot; new slots go
    /// under the old free ones, lowest first.
    pub(crate) fn grow(&mut self, ctx: &GpuContext, capacity: u32) -> Result<()> {
        if capacity <= self.capacity {
            return Ok(());
        }
        let scope = ErrorScopes::push(&ctx.device);
        let buffer = Self::buffer(ctx, capacity)?;
        let exists = Self::exists_buffer(ctx, capacity);
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("grow_pool"),
            });
        encoder.copy_buffer_to_buffer(
            &self.buffer,
            0,
            &buffer,
            0,
            self.capacity as u64 * SLOT_BYTES,
        );
        encoder.copy_buffer_to_buffer(&self.exists, 0, &exists, 0, self.capacity as u64 * 4);
        ctx.submit(encoder);
        scope.pop("growing the GPU block pool")?;
        self.buffer = buffer;
        self.exists = exists;
        let old = self.capacity;
        self.capacity = capacity;
        self.slots.resize(capacity as usize, SlotRecord::default());
        let mut free: Vec<u32> = (old..capacity).rev().collect();
        free.append(&mut self.free);
        self.free = free;
        Ok(())
    }

    /// Writes `data` (512 voxels per slot, in `slots` order) into the pool: one queue write per
    /// run of consecutive slots, reaching the device with the next submit (no buffer created).
    pub(crate) fn write_slots(&self, ctx: &GpuContext, slots: &[u32], data: &[GpuVoxel]) {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        for (k, run) in runs(slots) {
            let from = k * SLOT_BYTES as usize;
            ctx.write_buffer(
                &self.buffer,
                slots[k] as u64 * SLOT_BYTES,
                &bytes[from..from + run * SLOT_BYTES as usize],
            );
        }
    }

    /// Reads `slots` back (512 voxels per slot, in `slots` order): gathered on the device into a
    /// kept buffer, copied through a kept staging buffer, one submit and one wait.
    pub(crate) fn read_slots(&mut self, ctx: &GpuContext, slots: &[u32]) -> Result<Vec<GpuVoxel>> {
        if slots.is_empty() {
            return Ok(Vec::new());
        }
        let bytes = slots.len() as u64 * SLOT_BYTES;
        ctx.check_binding("block readback", bytes)?;
        let scope = ErrorScopes::push(&ctx.device);
        let gather = self.kept.scratch(ctx, "pool_gather", bytes);
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("pool_download"),
            });
        for (k, run) in runs(slots) {
            encoder.copy_buffer_to_buffer(
                &self.buffer,
                slots[k] as u64 * SLOT_BYTES,
                &gather,
                k as u64 * SLOT_BYTES,
                run as u64 * SLOT_BYTES,
            );
        }
        let mut out: Vec<GpuVoxel> = bytemuck::zeroed_vec(slots.len() * VOXELS_PER_BLOCK);
        ctx.submit_and_read_back(
            encoder,
            &mut self.kept,
            &mut [(&gather, bytemuck::cast_slice_mut(&mut out))],
        )?;
        scope.pop("reading blocks back from the GPU pool")?;
        Ok(out)
    }

    /// Starts reading `slots` back (512 voxels per slot, in `slots` order): copied from the pool
    /// into the next staging buffer of `ring` in a submit of their own, collected later
    /// ([`LateReadback::collect`]). Work submitted after this call (a new block written into
    /// one of the slots) reaches the device after the copies.
    pub(crate) fn read_slots_later(
        &self,
        ctx: &GpuContext,
        ring: &mut ReadbackRing,
        slots: &[u32],
    ) -> LateReadback {
        let runs: Vec<(u64, u64)> = runs(slots)
            .into_iter()
            .map(|(k, run)| (slots[k] as u64 * SLOT_BYTES, run as u64 * SLOT_BYTES))
            .collect();
        let encoder = ctx.encoder("pool_download_later");
        ring.submit_runs(ctx, encoder, &self.buffer, &runs)
    }

    /// Writes `fill` into every voxel of `slots` on the device (`shaders/fill_slots.wgsl`): the
    /// empty block of slots given to blocks the layer does not have, 4 bytes up per slot
    /// instead of the block; also clears their marks of blocks a depth frame updated. Recorded
    /// into `encoder` (a frame's, submitted with it) or, without one, submitted alone; nothing
    /// waits for it.
    pub(crate) fn fill(
        &mut self,
        ctx: &GpuContext,
        slots: &[u32],
        fill: GpuVoxel,
        encoder: Option<&mut wgpu::CommandEncoder>,
    ) -> Result<()> {
        let uniforms = SlotFillUniforms {
            slot_count: slots.len() as u32,
            pad: 0,
            fill_tsdf_weight: fill.tsdf_weight,
            fill_color: fill.color,
        };
        let u = bytemuck::bytes_of(&uniforms);
        self.over_slots(
            ctx,
            &shaders::FILL_SLOTS,
            u,
            slots,
            "writing empty blocks on the GPU",
            Some(encoder),
        )
    }

    /// Clears the updated marks of every voxel of `slots` on the device
    /// (`shaders/clear_updated.wgsl`): after their blocks were copied back, instead of uploading
    /// the copies again. Reaches the device with this submit; nothing waits for it.
    pub(crate) fn clear_updated(&mut self, ctx: &GpuContext, slots: &[u32]) -> Result<()> {
        let uniforms = SlotListUniforms {
            slot_count: slots.len() as u32,
            pad: [0; 3],
        };
        let u = bytemuck::bytes_of(&uniforms);
        self.over_slots(
            ctx,
            &shaders::CLEAR_UPDATED,
            u,
            slots,
            "clearing updated marks on the GPU",
            None,
        )
    }

    /// Runs `kernel` (bindings: `uniforms`, the slot list, the pool) with one invocation per
    /// voxel of `slots`, in its own submit through kept buffers; nothing waits for it. Errors
    /// say what it was `doing`.
    fn over_slots(
        &mut self,
        ctx: &GpuContext,
        kernel: &shaders::ShaderSource,
        uniforms: &[u8],
        slots: &[u32],
        doing: &str,
        fill_into: Option<Option<&mut wgpu::CommandEncoder>>,
    ) -> Result<()> {
        if slots.is_empty() {
            return Ok(());
        }
        let k = ctx.kernel(kernel)?;
        let scope = ErrorScopes::push(&ctx.device);
        let name = k.name;
        let buf_uniforms = self.kept.uniform_with(ctx, name, uniforms);
        // Each kernel its own slot list: a fill recorded into a frame's encoder is not submitted
        // yet when a clear writes its list.
        let fill = fill_into.is_some();
        let list = if fill { "fill_slot_list" } else { "slot_list" };
        let buf_slots = (self.kept).storage_with(ctx, list, bytemuck::cast_slice(slots));
        let (pool, exists) = (&self.buffer, &self.exists);
        let buffers: &[&wgpu::Buffer] = if fill {
            &[&buf_uniforms, &buf_slots, pool, exists]
        } else {
            &[&buf_uniforms, &buf_slots, pool]
        };
        let bind = self.kept.bind_group(ctx, name, &k.layout, buffers);
        let invocations = slots.len() as u64 * VOXELS_PER_BLOCK as u64;
        match fill_into.flatten() {
            Some(encoder) => ctx.record_dispatch(encoder, &k, &bind, invocations)?,
            None => {
                let mut encoder = ctx.encoder(name);
                ctx.record_dispatch(&mut encoder, &k, &bind, invocations)?;
                ctx.submit(encoder);
            }
        }
        scope.pop(doing)
    }
}

/// Runs of consecutive values in `values`: (start position, length).
pub(crate) fn runs(values: &[u32]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut k = 0;
    while k < values.len() {
        let mut len = 1;
        while k + len < values.len() && values[k + len] == values[k] + len as u32 {
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
    fn runs_split_at_gaps() {
        assert_eq!(runs(&[3, 4, 5, 9, 10, 2]), vec![(0, 3), (3, 2), (5, 1)]);
        assert!(runs(&[]).is_empty());
    }
}
