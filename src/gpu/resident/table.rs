//! The GPU hash table of resident blocks: open addressing with linear probing, `vec4<u32>`
//! entries (key x, y, z, slot), at most half full (tombstones included). The host owns it (it
//! decides residency) and uploads the entries it changed; kernels resolve block keys through
//! the device copy (`shaders/block_lookup.wgsl`, twin of [`BlockTable::lookup`]).

use crate::gpu::kept::Kept;
use crate::gpu::layout::LookupUniforms;
use crate::gpu::shaders;
use crate::gpu::{ErrorScopes, GpuContext};
use crate::grid::BlockIndex;
use crate::Result;

/// Table entry of an empty position (keep in sync with `shaders/shared/block_hash.wgsl`).
pub const SLOT_EMPTY: u32 = u32::MAX;
/// Table entry of a removed key (keep in sync with `shaders/shared/block_hash.wgsl`).
pub const SLOT_TOMBSTONE: u32 = u32::MAX - 1;

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

/// How many keys ahead [`BlockTable::lookup_all`] fetches home entries into the cache: enough
/// misses in flight to cover a memory access, few enough to stay in the first-level cache.
pub(super) const PROBES_AHEAD: usize = 16;

/// Asks the CPU to fetch the cache line of `item` (a hint: no effect on any result).
#[inline(always)]
pub(super) fn prefetch<T>(item: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: SSE is part of the x86_64 baseline, and a prefetch neither reads into the program
    // nor faults, whatever the address.
    unsafe {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        _mm_prefetch::<_MM_HINT_T0>((item as *const T).cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = item;
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

    #[inline]
    fn key_words(k: BlockIndex) -> [u32; 3] {
        [k.0[0] as u32, k.0[1] as u32, k.0[2] as u32]
    }

    /// The slot of `k`, probing as `block_lookup.wgsl` does.
    #[inline]
    pub fn lookup(&self, k: BlockIndex) -> Option<u32> {
        self.lookup_from(block_hash(k) & self.mask(), k)
    }

    /// The slots of `keys` ([`BlockTable::lookup`]; [`SLOT_EMPTY`] where absent). A frame's
    /// keys land all over the table, so each probe would wait on memory: the home entries of
    /// the keys [`PROBES_AHEAD`] further on are fetched into the cache meanwhile.
    pub fn lookup_all(&self, keys: &[BlockIndex]) -> Vec<u32> {
        let mask = self.mask();
        let home = |k: &BlockIndex| (block_hash(*k) & mask) as usize;
        for k in keys.iter().take(PROBES_AHEAD) {
            prefetch(&self.entries[home(k)]);
        }
        let ahead = keys
            .iter()
            .skip(PROBES_AHEAD)
            .map(Some)
            .chain(std::iter::repeat(None));
        (keys.iter().zip(ahead))
            .map(|(k, next)| {
                if let Some(next) = next {
                    prefetch(&self.entries[home(next)]);
                }
                self.lookup_from(home(k) as u32, *k).unwrap_or(SLOT_EMPTY)
            })
            .collect()
    }

    /// [`BlockTable::lookup`] of `k` from its home entry `pos`.
    #[inline]
    fn lookup_from(&self, mut pos: u32, k: BlockIndex) -> Option<u32> {
        let want = Self::key_words(k);
        let mask = self.mask();
        for _ in 0..self.entries.len() {
            let e = self.entries[pos as usize];
            if e[3] == SLOT_EMPTY {
                return None;
            }
            // The key as an array, not a slice: compared inline, not through `memcmp`.
            if [e[0], e[1], e[2]] == want && e[3] != SLOT_TOMBSTONE {
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
        let pos = self.free_entry_for(k);
        self.insert_at(pos, k, slot);
        self.note(pos);
    }

    /// Whether `more` keys can be inserted with the table at most half full (tombstones
    /// included), without a rebuild: what the host checks before the device inserts
    /// (`alloc.rs`).
    pub fn has_room_for(&self, more: usize) -> bool {
        2 * (self.live + self.tombstones + more) <= self.entries.len()
    }

    /// The entry `k` would be inserted into: the first empty entry or tombstone of its probe
    /// sequence (`k` absent, the table not full).
    pub fn free_entry_for(&self, k: BlockIndex) -> u32 {
        let mask = self.mask();
        let mut pos = block_hash(k) & mask;
        while self.entries[pos as usize][3] < SLOT_TOMBSTONE {
            pos = (pos + 1) & mask;
        }
        pos
    }

    /// Records `k → slot` at entry `pos` (empty or a tombstone): where [`BlockTable::insert`]
    /// puts it, or where the device inserted it (`table_insert.wgsl`). The change is not noted
    /// for the next upload.
    pub fn insert_at(&mut self, pos: u32, k: BlockIndex, slot: u32) {
        let e = &mut self.entries[pos as usize];
        assert!(
            e[3] >= SLOT_TOMBSTONE,
            "entry {pos} is taken: the device's table and the host's differ"
        );
        debug_assert!(slot < SLOT_TOMBSTONE);
        if e[3] == SLOT_TOMBSTONE {
            self.tombstones -= 1;
        }
        let w = Self::key_words(k);
        *e = [w[0], w[1], w[2], slot];
        self.live += 1;
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
            if [e[0], e[1], e[2]] == want && e[3] != SLOT_TOMBSTONE {
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
    pub(crate) fn take_changes(&mut self) -> Option<Vec<u32>> {
        self.changed.replace(Vec::new())
    }

    /// The raw entries (what the device copy holds after an upload).
    pub fn entries(&self) -> &[[u32; 4]] {
        &self.entries
    }
}

/// A [`BlockTable`] and its copy on the device, kept in step by uploading the entries the host
/// changed ([`DeviceTable::upload`]) before each kernel that reads it.
pub(crate) struct DeviceTable {
    /// The host's table (authoritative).
    pub(crate) host: BlockTable,
    buffer: wgpu::Buffer,
    /// The list of changed entries and the scatter's bind group ([`DeviceTable::upload`]).
    kept: Kept,
}

/// Runs of changed positions beyond which an upload with an encoder sends the changes as one
/// list and scatters them on the device (one queue write, one dispatch) rather than one queue
/// write per run.
const SCATTER_RUNS: usize = 16;

impl DeviceTable {
    /// An empty table of at least `entries` entries, uploaded whole; later uploads send only
    /// changes.
    pub(crate) fn new(ctx: &GpuContext, entries: usize) -> Self {
        let mut host = BlockTable::for_blocks((entries / 2) as u32);
        let buffer = ctx.storage("block_table", bytemuck::cast_slice(host.entries()));
        host.changed = Some(Vec::new());
        DeviceTable {
            host,
            buffer,
            kept: Kept::default(),
        }
    }

    /// The device copy (valid after [`DeviceTable::upload`]).
    pub(crate) fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// Uploads the entries changed since the last upload (everything after a rebuild): a run
    /// of neighbouring positions in one queue write; with `encoder` (a frame's, submitted after
    /// this call and before any other upload) and more than [`SCATTER_RUNS`] runs, the changes
    /// as one list (20 bytes each) that `shaders/table_scatter.wgsl` puts in place, recorded
    /// first into it. Returns the host's writes (queue writes, or a new buffer) it took.
    pub(crate) fn upload(
        &mut self,
        ctx: &GpuContext,
        encoder: Option<&mut wgpu::CommandEncoder>,
    ) -> Result<usize> {
        let Some(mut positions) = self.host.take_changes() else {
            self.buffer = ctx.storage("block_table", bytemuck::cast_slice(self.host.entries()));
            return Ok(1);
        };
        positions.sort_unstable();
        positions.dedup();
        let runs = super::pool::runs(&positions);
        match encoder {
            Some(encoder) if runs.len() > SCATTER_RUNS => {
                self.scatter(ctx, encoder, &positions)?;
                Ok(1)
            }
            _ => {
                for &(k, run) in &runs {
                    let start = positions[k] as usize;
                    let e = &self.host.entries()[start..start + run];
                    ctx.write_buffer(&self.buffer, start as u64 * 16, bytemuck::cast_slice(e));
                }
                Ok(runs.len())
            }
        }
    }

    /// Records the scatter of the entries at `positions` (distinct) into `encoder`.
    fn scatter(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        positions: &[u32],
    ) -> Result<()> {
        let mut words = Vec::with_capacity(1 + 5 * positions.len());
        words.push(positions.len() as u32);
        for &p in positions {
            words.push(p);
            words.extend(self.host.entries()[p as usize]);
        }
        let kernel = ctx.kernel(&shaders::TABLE_SCATTER)?;
        let changes = (self.kept).storage_with(ctx, "table_changes", bytemuck::cast_slice(&words));
        let bind = (self.kept).bind_group(
            ctx,
            "table_scatter",
            &kernel.layout,
            &[&changes, &self.buffer],
        );
        ctx.record_dispatch(encoder, &kernel, &bind, positions.len() as u64)
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
pub(crate) fn run_lookup(
    ctx: &GpuContext,
    buf_table: &wgpu::Buffer,
    mask: u32,
    keys: &[BlockIndex],
) -> Result<Vec<Option<u32>>> {
    if keys.is_empty() {
        return Ok(Vec::new());
    }
    let kernel = ctx.kernel(&shaders::BLOCK_LOOKUP)?;
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
    ctx.record_dispatch(&mut encoder, &kernel, &bind, keys.len() as u64)?;
    ctx.submit(encoder);
    scope.pop("looking blocks up on the GPU")?;
    let slots: Vec<u32> = ctx.read_back_as(&buf_slots, keys.len())?;
    Ok(slots
        .into_iter()
        .map(|s| (s < SLOT_TOMBSTONE).then_some(s))
        .collect())
}

/// Keys, slots (all [`SLOT_EMPTY`]) and uniforms of a `block_lookup.wgsl` dispatch.
pub(crate) fn lookup_buffers(
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
        // The batched, prefetching probe gives what one probe per key gives, absent keys too,
        // in the order asked (more keys than the prefetch distance, so both phases run).
        let mut keys: Vec<BlockIndex> = truth.keys().copied().collect();
        keys.extend((0..40).map(|i| BlockIndex([1000 + i, -i, 7])));
        let third = keys.len() / 3;
        keys.rotate_left(third);
        let one_by_one: Vec<u32> = keys
            .iter()
            .map(|k| t.lookup(*k).unwrap_or(SLOT_EMPTY))
            .collect();
        assert!(keys.len() > 2 * PROBES_AHEAD);
        assert_eq!(t.lookup_all(&keys), one_by_one);
        assert_eq!(one_by_one.iter().filter(|s| **s == SLOT_EMPTY).count(), 40);
        assert!(t.lookup_all(&[]).is_empty());
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
}
