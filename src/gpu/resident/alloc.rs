//! Blocks allocated on the device: a frame's listed blocks that the GPU hash table does not hold
//! take slots from a free-slot stack on the device and are inserted into the table by
//! compare-and-swap (`shaders/table_insert.wgsl`, recorded after `frame_keys.wgsl` has looked
//! every listed block up). The host does not decide which slot or entry a block gets; it learns
//! both from the words the kernel writes (`created`) and applies them to its copies of the table
//! ([`BlockTable::insert_at`]) and of the free list ([`take_popped`]), so that its copies equal
//! the device's entry for entry.
//!
//! The free-slot stack on the device is the host's free list as words, `[count, slots…]` with
//! the top last ([`free_stack_words`]): a block pops the top, as `pool.rs`'s `occupy`
//! does. Which block gets which slot and entry depends on the order the device runs the
//! invocations in; [`allocate_on_cpu`] is the twin run in the list's order, equal to the
//! device's in everything that does not depend on that order (which blocks are inserted, which
//! slots are taken, how many blocks are left without one).
//!
//! The host keeps the table at most half full with every listed block inserted
//! ([`BlockTable::has_room_for`]) before it records an allocation, and the stack as long as the
//! frame needs; a block the kernel leaves without a slot is counted, not guessed.
//!
//! A depth frame's new blocks are allocated here (`src/fusion/depth_gpu.rs`,
//! [`super::ResidentMap::make_resident_for_frame`]): the stack is the free slots the host
//! reserved for them, written empty in the same submit, and the insertions (index, entry, slot;
//! [`insertions`]) come back with the frame's flags and are applied when it is collected
//! (`late.rs`), the slots the device did not take (blocks a frame in flight had inserted)
//! given back. A LiDAR scan's new blocks are allocated the same way where the device makes its
//! (block, ray) pairs (`src/fusion/lidar_resident.rs`): the insertion reads the keys its
//! listed blocks went up as (offsets from the sensor's block, packed as a depth frame's) after
//! `block_lookup.wgsl` has looked them up.

use super::table::{BlockTable, SLOT_TOMBSTONE};
use crate::gpu::kept::Kept;
use crate::gpu::layout::FrameKeyUniforms;
use crate::gpu::shaders;
use crate::gpu::{ErrorScopes, GpuContext};
use crate::grid::BlockIndex;
use crate::Result;

/// The free-slot stack as the device holds it: the count, then the slots, the top last.
pub fn free_stack_words(free: &[u32]) -> Vec<u32> {
    let mut words = Vec::with_capacity(free.len() + 1);
    words.push(free.len() as u32);
    words.extend_from_slice(free);
    words
}

/// What an allocation did.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeviceAllocation {
    /// Per listed block: its slot afterwards (`None`: absent and not inserted).
    pub slots: Vec<Option<u32>>,
    /// Per inserted block: its index in the list and the table entry it took.
    pub created: Vec<(u32, u32)>,
    /// Listed blocks that needed a slot and were left without one.
    pub left_without: u32,
}

impl DeviceAllocation {
    /// From the kernel's per-block slots and its `created` words.
    pub fn from_words(slots: &[u32], created: &[u32]) -> Self {
        let (left_without, inserted) = insertions(created);
        DeviceAllocation {
            slots: slots
                .iter()
                .map(|&s| (s < SLOT_TOMBSTONE).then_some(s))
                .collect(),
            created: inserted.iter().map(|&[i, pos, _]| (i, pos)).collect(),
            left_without,
        }
    }

    /// Applies the insertions to the host's copy of the table: block `keys[i]` at the entry the
    /// device gave it.
    pub fn apply_to(&self, table: &mut BlockTable, keys: &[BlockIndex]) {
        for &(i, pos) in &self.created {
            let slot = self.slots[i as usize].expect("an inserted block has a slot");
            table.insert_at(pos, keys[i as usize], slot);
        }
    }

    /// The slots the insertions took, sorted.
    pub fn taken_slots(&self) -> Vec<u32> {
        let mut v: Vec<u32> = (self.created.iter())
            .map(|&(i, _)| self.slots[i as usize].expect("an inserted block has a slot"))
            .collect();
        v.sort_unstable();
        v
    }
}

/// Removes from the host's free list the slots the device popped off its stack: the top
/// `popped` (at most the list's length). Returns them.
pub fn take_popped(free: &mut Vec<u32>, popped: usize) -> Vec<u32> {
    let keep = free.len().saturating_sub(popped);
    free.split_off(keep)
}

/// The CPU twin of `frame_keys.wgsl`'s lookup and `table_insert.wgsl`, run block after block in
/// the list's order: each block before `insert_until` that `table` does not hold takes the top
/// of `free` and the first empty entry or tombstone of its probe sequence.
pub fn allocate_on_cpu(
    table: &mut BlockTable,
    free: &mut Vec<u32>,
    keys: &[BlockIndex],
    insert_until: usize,
) -> DeviceAllocation {
    let mut out = DeviceAllocation {
        slots: keys.iter().map(|k| table.lookup(*k)).collect(),
        created: Vec::new(),
        left_without: 0,
    };
    for (i, k) in keys.iter().enumerate().take(insert_until) {
        if out.slots[i].is_some() {
            continue;
        }
        let Some(slot) = free.pop() else {
            out.left_without += 1;
            continue;
        };
        let pos = table.free_entry_for(*k);
        table.insert_at(pos, *k, slot);
        out.slots[i] = Some(slot);
        out.created.push((i as u32, pos));
    }
    out
}

/// The buffers of an allocation on the device (see `shaders/table_insert.wgsl`).
pub(crate) struct AllocBuffers<'a> {
    /// [`FrameKeyUniforms`] of the listed blocks.
    pub uniforms: &'a wgpu::Buffer,
    /// The GPU hash table.
    pub table: &'a wgpu::Buffer,
    /// The listed blocks' offset words ([`FrameKeyUniforms::origin`]'s w per block).
    pub keys: &'a wgpu::Buffer,
    /// Per listed block: its slot, as `frame_keys.wgsl` left it.
    pub slots: &'a wgpu::Buffer,
    /// The free-slot stack ([`free_stack_words`]).
    pub free: &'a wgpu::Buffer,
    /// Two counters (cleared by [`record_insert`]), then three words per inserted block (its
    /// index in the list, its entry, its slot): room for as many blocks as the stack holds
    /// ([`created_bytes`]).
    pub created: &'a wgpu::Buffer,
}

/// Bytes of the `created` buffer for at most `blocks` insertions.
pub(crate) fn created_bytes(blocks: u64) -> u64 {
    8 + 12 * blocks
}

/// The insertions of a `created` buffer's words ([`AllocBuffers::created`]): the blocks left
/// without a slot, and per inserted block its index in the list, its entry and its slot.
pub(crate) fn insertions(created: &[u32]) -> (u32, Vec<[u32; 3]>) {
    let count = created[0] as usize;
    let triples = (0..count)
        .map(|i| [created[2 + 3 * i], created[3 + 3 * i], created[4 + 3 * i]])
        .collect();
    (created[1], triples)
}

/// Records the insertion of `blocks` listed blocks, after their lookup (the caller's:
/// `frame_keys.wgsl` for a depth frame, `block_lookup.wgsl` for a LiDAR scan); the bind group
/// is kept in `kept` as `name` between calls over the same buffers.
pub(crate) fn record_insert(
    ctx: &GpuContext,
    (encoder, kept): (&mut wgpu::CommandEncoder, &mut Kept),
    (name, b): (&'static str, &AllocBuffers),
    blocks: u64,
) -> Result<()> {
    let kernel = ctx.kernel(&shaders::TABLE_INSERT)?;
    let bind = kept.bind_group(
        ctx,
        name,
        &kernel.layout,
        &[b.uniforms, b.table, b.keys, b.slots, b.free, b.created],
    );
    encoder.clear_buffer(b.created, 0, Some(8));
    ctx.record_dispatch(encoder, &kernel, &bind, blocks)
}

/// What [`allocate_on_gpu`] reads back: the allocation, the table's entries and the stack's
/// count afterwards (a count past the stack's length means blocks found it empty).
pub type AllocatedOnGpu = (DeviceAllocation, Vec<[u32; 4]>, u32);

/// The buffers of a lookup run once over copies uploaded whole ([`record_lookup_once`]).
pub(crate) struct LookupOnce {
    pub uniforms: wgpu::Buffer,
    pub table: wgpu::Buffer,
    pub keys: wgpu::Buffer,
    /// Per listed block: its slot, `SLOT_EMPTY` where absent.
    pub slots: wgpu::Buffer,
    /// Per listed block: its base (xyz; w = 1 from the first unsettled block on).
    pub bases: wgpu::Buffer,
}

/// Uploads `uniforms`, `table` whole and the listed blocks' `key_words`, and records
/// `frame_keys.wgsl` over them into a new encoder: the start of the kernels' tests against
/// their twins ([`allocate_on_gpu`], [`crate::fusion::frame_keys_on_gpu`]). Call it inside an
/// error scope.
pub(crate) fn record_lookup_once(
    ctx: &GpuContext,
    uniforms: FrameKeyUniforms,
    table: &BlockTable,
    key_words: &[u32],
) -> Result<(LookupOnce, wgpu::CommandEncoder)> {
    let n = uniforms.block_count as u64;
    let kernel = ctx.kernel(&shaders::FRAME_KEYS)?;
    let b = LookupOnce {
        uniforms: ctx.uniform("frame_key_uniforms", bytemuck::bytes_of(&uniforms)),
        table: ctx.storage("block_table", bytemuck::cast_slice(table.entries())),
        keys: ctx.storage("frame_keys", bytemuck::cast_slice(key_words)),
        slots: ctx.storage_zeroed("lookup_slots", n.max(1) * 4),
        bases: ctx.storage_zeroed("fuse_block_base", n.max(1) * 16),
    };
    let bind = ctx.bind_group(
        "frame_keys",
        &kernel.layout,
        &[&b.uniforms, &b.table, &b.keys, &b.slots, &b.bases],
    );
    let mut encoder = ctx.encoder("frame_keys");
    ctx.record_dispatch(&mut encoder, &kernel, &bind, n)?;
    Ok((b, encoder))
}

/// Looks the listed blocks up (`frame_keys.wgsl`) and allocates the absent ones
/// (`table_insert.wgsl`) on the device, in one submit, against copies of `table` and of the
/// free list `free` uploaded whole. For tests of the kernels against [`allocate_on_cpu`].
pub fn allocate_on_gpu(
    ctx: &GpuContext,
    table: &BlockTable,
    free: &[u32],
    uniforms: FrameKeyUniforms,
    key_words: &[u32],
) -> Result<AllocatedOnGpu> {
    let n = uniforms.block_count as u64;
    let scope = ErrorScopes::push(&ctx.device);
    let (lookup, mut encoder) = record_lookup_once(ctx, uniforms, table, key_words)?;
    let buf_free = ctx.storage("free_slots", bytemuck::cast_slice(&free_stack_words(free)));
    let buf_created = ctx.storage_zeroed("created_blocks", created_bytes(n));
    let buffers = AllocBuffers {
        uniforms: &lookup.uniforms,
        table: &lookup.table,
        keys: &lookup.keys,
        slots: &lookup.slots,
        free: &buf_free,
        created: &buf_created,
    };
    record_insert(
        ctx,
        (&mut encoder, &mut Kept::default()),
        ("table_insert", &buffers),
        n,
    )?;
    ctx.submit(encoder);
    scope.pop("allocating blocks on the GPU")?;
    let slots: Vec<u32> = ctx.read_back_as(&lookup.slots, n as usize)?;
    let created: Vec<u32> = ctx.read_back_as(&buf_created, 2 + 3 * n as usize)?;
    let entries: Vec<[u32; 4]> = ctx.read_back_as(&lookup.table, table.capacity())?;
    let top: Vec<u32> = ctx.read_back_as(&buf_free, 1)?;
    Ok((
        DeviceAllocation::from_words(&slots, &created),
        entries,
        top[0],
    ))
}
