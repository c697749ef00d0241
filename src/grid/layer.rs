//! The layer: the hash map from block coordinates to blocks, plus the grid parameters.
//!
//! Stages reach blocks only through a layer. Bulk updates check blocks out with
//! [`Layer::take_blocks`], work on them in parallel, and check them back in with
//! [`Layer::put_blocks`]; a pager can do the same to move blocks to disk and back without the
//! stages knowing.

use super::block::Block;
use super::index::{BlockIndex, GridParams, VoxelIndex, VOXELS_PER_BLOCK};
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// RAM bytes of a block's slot in the layer's hash table: its key, the box, one control byte.
const SLOT_BYTES: usize = std::mem::size_of::<BlockIndex>() + std::mem::size_of::<Box<Block>>() + 1;

/// RAM bytes of an occupancy tile's slot: its key, its mask, one control byte.
const TILE_SLOT_BYTES: usize = std::mem::size_of::<BlockIndex>() + 8 + 1;

/// RAM bytes of one resident block with its hash slot (regularized field not included), the unit
/// of every memory budget over resident blocks (the pager's residency, a region's working memory).
pub const BLOCK_RESIDENT_BYTES: u64 = (std::mem::size_of::<Block>() + SLOT_BYTES) as u64;

/// Block indices a stage touched, sorted and without duplicates.
pub type TouchedBlocks = Vec<BlockIndex>;

/// Hasher for [`BlockIndex`] keys: the key's `Hash` impl writes one packed `u64`; `finish` applies
/// the splitmix64 finaliser so that every bit of the hash depends on every coordinate bit.
#[derive(Default, Clone, Copy)]
pub struct BlockHasher(u64);

impl Hasher for BlockHasher {
    #[inline]
    fn finish(&self) -> u64 {
        let mut z = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        // Not used by BlockIndex; a plain FNV-1a keeps the hasher correct for any key.
        for &b in bytes {
            self.0 = (self.0 ^ b as u64).wrapping_mul(0x0100_0000_01B3);
        }
    }

    #[inline]
    fn write_u64(&mut self, v: u64) {
        self.0 = v;
    }
}

/// A block's RAM copy: its voxels, or `None` for a block whose voxels were made on the GPU
/// and are not written back yet ([`Layer::insert_unwritten`]). Such a block reads as a fresh
/// one ([`Block::new_boxed`]) and counts in [`Layer::memory_bytes`] as one; it gets memory of
/// its own when first written (the GPU tier's write-back, or any other writer).
type Stored = Option<Box<Block>>;

type BlockMap = HashMap<BlockIndex, Stored, BuildHasherDefault<BlockHasher>>;

/// What a block without voxels of its own reads as.
static FRESH: std::sync::LazyLock<Block> = std::sync::LazyLock::new(Block::default);

#[inline]
fn read(s: &Stored) -> &Block {
    s.as_deref().unwrap_or(&FRESH)
}

#[inline]
fn write(s: &mut Stored) -> &mut Block {
    s.get_or_insert_with(Block::new_boxed)
}

fn owned(s: Stored) -> Box<Block> {
    s.unwrap_or_else(Block::new_boxed)
}

/// Edge of a layer's occupancy tiles, blocks: [`Layer::occupied_tiles`] holds one 64-bit mask
/// per tile of 4³ block positions with an allocated block.
pub const TILE_EDGE: i32 = 4;

/// The tile of block `b` (its coordinates divided by [`TILE_EDGE`], rounded down) and the bit of
/// `b` in the tile's mask ([`tile_bit`]).
#[inline]
pub fn tile_of(b: BlockIndex) -> (BlockIndex, u64) {
    let t = b.0.map(|c| c.div_euclid(TILE_EDGE));
    let r = b.0.map(|c| c.rem_euclid(TILE_EDGE));
    (BlockIndex(t), tile_bit(r))
}

/// The bit, in its tile's mask, of the block at `r` (each in `0..TILE_EDGE`) from the tile's
/// first block: x fastest, then y, then z. The one statement of the masks' layout.
#[inline]
pub fn tile_bit(r: [i32; 3]) -> u64 {
    1u64 << (r[0] + TILE_EDGE * (r[1] + TILE_EDGE * r[2]))
}

/// The block at `r` (each in `0..TILE_EDGE`) from the first block of `tile`.
#[inline]
pub fn tile_block(tile: BlockIndex, r: [i32; 3]) -> BlockIndex {
    BlockIndex([
        tile.0[0] * TILE_EDGE + r[0],
        tile.0[1] * TILE_EDGE + r[1],
        tile.0[2] * TILE_EDGE + r[2],
    ])
}

/// The blocks of tile `tile` whose bits `mask` holds, in bit order.
pub fn tile_blocks(tile: BlockIndex, mask: u64) -> impl Iterator<Item = BlockIndex> {
    let e = TILE_EDGE;
    (0..64)
        .filter(move |bit| mask >> bit & 1 == 1)
        .map(move |bit| tile_block(tile, [bit % e, (bit / e) % e, bit / (e * e)]))
}

type TileMap = HashMap<BlockIndex, u64, BuildHasherDefault<BlockHasher>>;

/// Sets the bit of block `i` in `tiles`.
#[inline]
fn occupy(tiles: &mut TileMap, i: BlockIndex) {
    let (tile, bit) = tile_of(i);
    *tiles.entry(tile).or_insert(0) |= bit;
}

/// A layer of TSDF blocks.
#[derive(Clone, Debug)]
pub struct Layer {
    params: GridParams,
    blocks: BlockMap,
    /// Which positions hold a block, per tile of 4³ positions ([`tile_of`]): kept with
    /// `blocks` by every method that adds or removes one, so that a search of a region (the
    /// blocks in a camera's view) skips empty space a tile at a time.
    tiles: TileMap,
}

impl Layer {
    /// An empty layer.
    pub fn new(params: GridParams) -> Self {
        Layer {
            params,
            blocks: BlockMap::default(),
            tiles: TileMap::default(),
        }
    }

    /// Notes a block added at `i`.
    #[inline]
    fn occupy(&mut self, i: BlockIndex) {
        occupy(&mut self.tiles, i);
    }

    /// Notes the block at `i` removed.
    #[inline]
    fn vacate(&mut self, i: &BlockIndex) {
        let (tile, bit) = tile_of(*i);
        if let Some(mask) = self.tiles.get_mut(&tile) {
            *mask &= !bit;
            if *mask == 0 {
                self.tiles.remove(&tile);
            }
        }
    }

    /// Inserts into the map and the tiles.
    #[inline]
    fn put(&mut self, i: BlockIndex, b: Box<Block>) -> Option<Box<Block>> {
        let old = self.blocks.insert(i, Some(b));
        if old.is_none() {
            self.occupy(i);
        }
        old.map(owned)
    }

    /// Removes from the map and the tiles.
    #[inline]
    fn take(&mut self, i: &BlockIndex) -> Option<Box<Block>> {
        let old = self.blocks.remove(i);
        if old.is_some() {
            self.vacate(i);
        }
        old.map(owned)
    }

    /// Number of tiles of 4³ block positions holding at least one block.
    pub fn tile_count(&self) -> usize {
        self.tiles.len()
    }

    /// Each tile holding a block, with the mask of its positions that hold one ([`tile_of`],
    /// [`tile_blocks`]), in arbitrary order.
    pub fn occupied_tiles(&self) -> impl Iterator<Item = (BlockIndex, u64)> + '_ {
        self.tiles.iter().map(|(t, m)| (*t, *m))
    }

    /// The mask of tile `tile`'s positions that hold a block (0 where none does).
    #[inline]
    pub fn tile_mask(&self, tile: BlockIndex) -> u64 {
        self.tiles.get(&tile).copied().unwrap_or(0)
    }

    /// Voxel size and truncation.
    pub fn params(&self) -> GridParams {
        self.params
    }

    /// Number of allocated blocks.
    pub fn block_count(&self) -> usize {
        self.blocks.len()
    }

    /// Number of voxels in Ω over all blocks.
    pub fn observed_voxel_count(&self) -> usize {
        (self.blocks.values().flatten())
            .map(|b| b.observed_count())
            .sum()
    }

    /// The block at `index`, if allocated (and resident).
    #[inline]
    pub fn get(&self, index: &BlockIndex) -> Option<&Block> {
        self.blocks.get(index).map(read)
    }

    /// The block at `index`, mutably.
    #[inline]
    pub fn get_mut(&mut self, index: &BlockIndex) -> Option<&mut Block> {
        self.blocks.get_mut(index).map(write)
    }

    /// The block at `index`, allocating an empty one if needed.
    pub fn get_or_allocate(&mut self, index: BlockIndex) -> &mut Block {
        use std::collections::hash_map::Entry;
        match self.blocks.entry(index) {
            Entry::Occupied(e) => write(e.into_mut()),
            Entry::Vacant(e) => {
                // The entry borrows `blocks`, so the tiles are kept through the field.
                occupy(&mut self.tiles, index);
                write(e.insert(None))
            }
        }
    }

    /// Adds the block at `index`, if absent, without voxels of its own until written: a block
    /// whose voxels are on the GPU (it reads as a fresh block meanwhile).
    pub fn insert_unwritten(&mut self, index: BlockIndex) {
        use std::collections::hash_map::Entry;
        if let Entry::Vacant(e) = self.blocks.entry(index) {
            e.insert(None);
            occupy(&mut self.tiles, index);
        }
    }

    /// Whether `index` is allocated.
    pub fn contains(&self, index: &BlockIndex) -> bool {
        self.blocks.contains_key(index)
    }

    /// Decoded voxel at a global index, `None` when its block is not allocated.
    pub fn voxel(&self, v: VoxelIndex) -> Option<super::Voxel> {
        let (b, i) = BlockIndex::of_voxel(v);
        self.get(&b).map(|blk| blk.voxel(i))
    }

    /// All allocated block indices, sorted.
    pub fn indices_sorted(&self) -> Vec<BlockIndex> {
        let mut v: Vec<BlockIndex> = self.blocks.keys().copied().collect();
        v.sort_unstable();
        v
    }

    /// Iterates over the blocks in arbitrary order.
    pub fn iter_unsorted(&self) -> impl Iterator<Item = (&BlockIndex, &Block)> {
        self.blocks.iter().map(|(k, v)| (k, read(v)))
    }

    /// Checks the blocks at `indices` out of the layer (allocating missing ones), in the order
    /// given. Give them back with [`Layer::put_blocks`].
    pub fn take_blocks(&mut self, indices: &[BlockIndex]) -> Vec<(BlockIndex, Box<Block>)> {
        indices
            .iter()
            .map(|&i| (i, self.take(&i).unwrap_or_else(Block::new_boxed)))
            .collect()
    }

    /// Checks blocks (back) into the layer, replacing any with the same index.
    pub fn put_blocks(&mut self, blocks: impl IntoIterator<Item = (BlockIndex, Box<Block>)>) {
        for (i, b) in blocks {
            self.put(i, b);
        }
    }

    /// Checks blocks back in like [`Layer::put_blocks`], but drops blocks with no voxel in Ω
    /// (allocated for a band whose voxels all fell outside the image, say). Returns the indices
    /// kept, in the order given.
    pub fn put_blocks_observed(
        &mut self,
        blocks: Vec<(BlockIndex, Box<Block>)>,
    ) -> Vec<BlockIndex> {
        let mut kept = Vec::with_capacity(blocks.len());
        for (i, b) in blocks {
            if b.observed() {
                kept.push(i);
                self.put(i, b);
            }
        }
        kept
    }

    /// Updates, in parallel and in place (no check-out and check-in through the hash map),
    /// the blocks at the indices `required` (sorted, without repeats; allocating those
    /// missing, empty) and every other allocated block `select` picks; in the blocks' order,
    /// so that neighbouring blocks come one after the other, as a stage reading an image or a
    /// volume per block wants.
    /// `update` returns a result and whether to keep the block: a block not kept is dropped.
    /// Returns the updated indices, sorted, with the results and whether each was kept.
    pub fn update_in_place<R: Send>(
        &mut self,
        required: &[BlockIndex],
        select: impl Fn(&BlockIndex) -> bool + Sync,
        update: impl Fn(&BlockIndex, &mut Block) -> (R, bool) + Sync,
    ) -> Vec<(BlockIndex, R, bool)> {
        use rayon::prelude::*;
        debug_assert!(
            required.windows(2).all(|w| w[0] < w[1]),
            "required: sorted, no repeats"
        );
        let required_set = SortedSet::new(required);
        // The allocated blocks to update, by sort key.
        let mut picked: Vec<(u64, &mut Block)> = self
            .blocks
            .par_iter_mut()
            .filter(|(i, _)| select(i) || required_set.contains(i))
            .map(|(i, b)| (i.sort_key(), write(b)))
            .collect();
        picked.par_sort_unstable_by_key(|&(key, _)| key);
        // The required blocks not allocated: the sorted lists merged.
        let mut fresh: Vec<(u64, Box<Block>)> = Vec::new();
        let mut p = picked.iter().map(|(key, _)| *key).peekable();
        for key in required.iter().map(BlockIndex::sort_key) {
            while p.next_if(|&k| k < key).is_some() {}
            if p.next_if_eq(&key).is_none() {
                fresh.push((key, Block::new_boxed()));
            }
        }
        // Both, in one sorted list (`true`: fresh).
        let mut all: Vec<(u64, bool, &mut Block)> = Vec::with_capacity(picked.len() + fresh.len());
        let mut f = fresh.iter_mut().peekable();
        for (key, b) in picked {
            while let Some((k, nb)) = f.next_if(|(k, _)| *k < key) {
                all.push((*k, true, &mut **nb));
            }
            all.push((key, false, b));
        }
        all.extend(f.map(|(k, nb)| (*k, true, &mut **nb)));
        let results: Vec<(BlockIndex, R, bool, bool)> = all
            .into_par_iter()
            .map(|(key, is_fresh, b)| {
                let i = BlockIndex::from_sort_key(key);
                let (r, keep) = update(&i, b);
                (i, r, keep, is_fresh)
            })
            .collect();
        let mut fresh = fresh.into_iter();
        results
            .into_iter()
            .map(|(i, r, keep, is_fresh)| {
                if is_fresh {
                    let (_, b) = fresh.next().expect("one fresh block per fresh result");
                    if keep {
                        self.put(i, b);
                    }
                } else if !keep {
                    self.take(&i);
                }
                (i, r, keep)
            })
            .collect()
    }

    /// Removes and returns one block.
    pub fn remove(&mut self, index: &BlockIndex) -> Option<Box<Block>> {
        self.take(index)
    }

    /// Inserts one block, returning the one it replaced.
    pub fn insert(&mut self, index: BlockIndex, block: Box<Block>) -> Option<Box<Block>> {
        self.put(index, block)
    }

    /// Drops every block's regularized field (e.g. before re-regularizing with other settings).
    pub fn clear_regularized(&mut self) {
        for b in self.blocks.values_mut().flatten() {
            b.regularized = None;
        }
    }

    /// Bytes held in RAM: blocks plus the hash tables' slots (blocks: key, pointer, control
    /// byte; tiles: key, mask, control byte).
    pub fn memory_bytes(&self) -> usize {
        let blocks: usize = (self.blocks.values())
            .map(|b| {
                b.as_ref()
                    .map_or(std::mem::size_of::<Block>(), |b| b.heap_bytes())
            })
            .sum();
        blocks + self.blocks.capacity() * SLOT_BYTES + self.tiles.capacity() * TILE_SLOT_BYTES
    }

    /// RAM bytes per allocated voxel ([`Layer::memory_bytes`] / (blocks · 512)).
    pub fn bytes_per_voxel(&self) -> f64 {
        if self.blocks.is_empty() {
            return 0.0;
        }
        self.memory_bytes() as f64 / (self.blocks.len() * VOXELS_PER_BLOCK) as f64
    }
}

/// Membership in a sorted list of blocks: a 2¹⁸-bit filter of their keys' hashes, and a
/// binary search where the filter holds.
struct SortedSet<'a> {
    sorted: &'a [BlockIndex],
    bits: Vec<u64>,
}

impl<'a> SortedSet<'a> {
    const BITS_LOG2: u32 = 18;

    fn new(sorted: &'a [BlockIndex]) -> Self {
        let mut bits = vec![0u64; 1 << (Self::BITS_LOG2 - 6)];
        for i in sorted {
            let h = Self::hash(i);
            bits[h >> 6] |= 1 << (h & 63);
        }
        SortedSet { sorted, bits }
    }

    #[inline]
    fn hash(i: &BlockIndex) -> usize {
        (i.sort_key().wrapping_mul(0x9E37_79B9_7F4A_7C15) >> (64 - Self::BITS_LOG2)) as usize
    }

    #[inline]
    fn contains(&self, i: &BlockIndex) -> bool {
        let h = Self::hash(i);
        self.bits[h >> 6] & (1 << (h & 63)) != 0 && self.sorted.binary_search(i).is_ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::hash::BuildHasher;

    #[test]
    fn a_block_not_written_yet_reads_and_counts_as_a_fresh_one() {
        use crate::grid::{encode_tsdf, OMEGA_BIT};
        let params = GridParams::paper(0.1);
        let (a, b, c) = (
            BlockIndex([0, 0, 0]),
            BlockIndex([1, -2, 3]),
            BlockIndex([9, 9, 9]),
        );
        let mut lazy = Layer::new(params);
        let mut eager = Layer::new(params);
        for i in [a, b] {
            lazy.insert_unwritten(i);
            eager.insert(i, Block::new_boxed());
        }
        lazy.get_or_allocate(c)
            .store_fused(5, encode_tsdf(0.25), 3 | OMEGA_BIT, [1, 2, 3]);
        eager
            .get_or_allocate(c)
            .store_fused(5, encode_tsdf(0.25), 3 | OMEGA_BIT, [1, 2, 3]);
        // Adding again keeps what is there.
        lazy.insert_unwritten(c);
        let fresh = Block::default();
        for l in [&lazy, &eager] {
            assert_eq!(l.block_count(), 3);
            assert_eq!(l.observed_voxel_count(), 1);
            assert_eq!(l.get(&b).map(|x| x.tsdf), Some(fresh.tsdf));
            assert_eq!(l.get(&b).map(|x| x.weight_omega), Some(fresh.weight_omega));
            assert_eq!(l.tile_mask(tile_of(b).0), tile_of(b).1);
        }
        assert_eq!(lazy.memory_bytes(), eager.memory_bytes());
        assert_eq!(lazy.indices_sorted(), eager.indices_sorted());
        // Written: voxels of its own.
        lazy.get_mut(&a)
            .unwrap()
            .store_fused(7, encode_tsdf(-0.5), 2 | OMEGA_BIT, [4, 5, 6]);
        assert_eq!(lazy.get(&a).unwrap().voxel(7).weight, 2);
        assert_eq!(
            lazy.get(&b).unwrap().voxel(7).weight,
            0,
            "b still reads fresh"
        );
        // Taken out and updated in place like any other.
        assert_eq!(lazy.remove(&b).map(|x| x.tsdf), Some(fresh.tsdf));
        lazy.insert_unwritten(b);
        let updated = lazy.update_in_place(&[], |_| true, |_, blk| (blk.observed_count(), true));
        let counts: Vec<usize> = updated.iter().map(|u| u.1).collect();
        assert_eq!(counts, [1, 0, 1], "{updated:?}");
        lazy.clear_regularized();
        assert_eq!(lazy.block_count(), 3);
    }

    #[test]
    fn hash_separates_neighbours() {
        let bh = BuildHasherDefault::<BlockHasher>::default();
        let mut seen = std::collections::HashSet::new();
        for x in -8..8 {
            for y in -8..8 {
                for z in -8..8 {
                    seen.insert(bh.hash_one(BlockIndex([x, y, z])));
                }
            }
        }
        assert_eq!(seen.len(), 16 * 16 * 16);
    }

    #[test]
    fn update_in_place_allocates_selects_and_drops() {
        let mut layer = Layer::new(GridParams {
            voxel_size_m: 0.1,
            truncation_m: 1.0,
        });
        // Allocated: (0,0,0) … (9,0,0), voxel 0 of each holding the block's x as its weight.
        for x in 0..10 {
            let b = layer.get_or_allocate(BlockIndex([x, 0, 0]));
            b.weight_omega[0] = x as u8;
        }
        // Required: two allocated, three not (one of which is then not kept).
        let required = [
            BlockIndex([-3, 5, 1]),
            BlockIndex([2, 0, 0]),
            BlockIndex([4, -1, 0]),
            BlockIndex([7, 0, 0]),
            BlockIndex([11, 0, 0]),
        ];
        let calls = std::sync::atomic::AtomicUsize::new(0);
        let out = layer.update_in_place(
            &required,
            |i| i.0[0] >= 5 && i.0[1] == 0,
            |i, b| {
                calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let before = b.weight_omega[0];
                b.weight_omega[1] = 1;
                // Drop (7,0,0), which was allocated, and (4,-1,0), which was not.
                (
                    before,
                    *i != BlockIndex([7, 0, 0]) && *i != BlockIndex([4, -1, 0]),
                )
            },
        );
        let expected: Vec<BlockIndex> = [[-3, 5, 1], [2, 0, 0], [4, -1, 0]]
            .into_iter()
            .chain((5..10).map(|x| [x, 0, 0]))
            .chain([[11, 0, 0]])
            .map(BlockIndex)
            .collect();
        assert_eq!(out.iter().map(|r| r.0).collect::<Vec<_>>(), expected);
        assert_eq!(calls.into_inner(), expected.len());
        for (i, before, kept) in &out {
            // Allocated blocks were updated where they lay; fresh ones started empty.
            let x = i.0[0];
            let allocated = (0..10).contains(&x) && i.0[1] == 0;
            assert_eq!(*before, if allocated { x as u8 } else { 0 }, "{i:?}");
            assert_eq!(*kept, layer.contains(i), "{i:?}");
            if *kept {
                assert_eq!(layer.get(i).unwrap().weight_omega[1], 1);
            }
        }
        assert!(!layer.contains(&BlockIndex([7, 0, 0])));
        assert!(!layer.contains(&BlockIndex([4, -1, 0])));
        // Untouched blocks are as they were.
        assert_eq!(
            layer.get(&BlockIndex([3, 0, 0])).unwrap().weight_omega[1],
            0
        );
        assert_eq!(layer.block_count(), 10 - 1 + 2);
    }

    #[test]
    fn take_and_put_round_trip() {
        let mut layer = Layer::new(GridParams {
            voxel_size_m: 0.1,
            truncation_m: 1.0,
        });
        layer
            .get_or_allocate(BlockIndex([1, 2, 3]))
            .fuse(5, 0.25, None);
        let taken = layer.take_blocks(&[BlockIndex([1, 2, 3]), BlockIndex([0, 0, 0])]);
        assert_eq!(layer.block_count(), 0);
        assert!(taken[0].1.omega(5));
        layer.put_blocks(taken);
        assert_eq!(
            layer.indices_sorted(),
            vec![BlockIndex([0, 0, 0]), BlockIndex([1, 2, 3])]
        );
        assert_eq!(layer.observed_voxel_count(), 1);
    }

    /// The tiles recomputed from the layer's blocks, sorted.
    fn tiles_of_blocks(layer: &Layer) -> Vec<(BlockIndex, u64)> {
        let mut tiles: HashMap<BlockIndex, u64> = HashMap::new();
        for (i, _) in layer.iter_unsorted() {
            let (t, bit) = tile_of(*i);
            *tiles.entry(t).or_default() |= bit;
        }
        let mut v: Vec<_> = tiles.into_iter().collect();
        v.sort_unstable();
        v
    }

    #[test]
    fn occupancy_tiles_follow_every_change_of_the_blocks() {
        // Every method that adds or removes blocks, on coordinates of both signs: the tiles are
        // those of the blocks after each step, and each tile's blocks are where its mask says.
        let mut layer = Layer::new(GridParams::paper(0.1));
        let mut rng = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move |n: i32| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng % n as u64) as i32 - n / 2
        };
        let mut some = |count: usize| -> Vec<BlockIndex> {
            let mut v: Vec<BlockIndex> = (0..count)
                .map(|_| BlockIndex([next(24), next(24), next(24)]))
                .collect();
            v.sort_unstable();
            v.dedup();
            v
        };
        for step in 0..60 {
            let keys = some(40);
            match step % 6 {
                0 => keys.iter().for_each(|k| {
                    layer.get_or_allocate(*k);
                }),
                1 => keys.iter().for_each(|k| drop(layer.remove(k))),
                2 => {
                    let taken = layer.take_blocks(&keys);
                    assert_eq!(tiles_of_blocks(&layer), sorted_tiles(&layer));
                    layer.put_blocks(taken.into_iter().step_by(2));
                }
                3 => drop(layer.update_in_place(&keys, |i| i.0[0] > 0, |i, _| ((), i.0[1] > 0))),
                4 => keys
                    .iter()
                    .for_each(|k| drop(layer.insert(*k, Block::new_boxed()))),
                _ => {
                    let taken = layer.take_blocks(&keys);
                    layer.put_blocks_observed(taken);
                }
            }
            assert_eq!(tiles_of_blocks(&layer), sorted_tiles(&layer), "step {step}");
        }
        assert!(layer.block_count() > 100, "{} blocks", layer.block_count());
        let mut from_tiles: Vec<BlockIndex> = (layer.occupied_tiles())
            .flat_map(|(t, m)| tile_blocks(t, m))
            .collect();
        from_tiles.sort_unstable();
        assert_eq!(from_tiles, layer.indices_sorted());
        for (t, m) in layer.occupied_tiles() {
            assert_eq!(layer.tile_mask(t), m);
        }
    }

    fn sorted_tiles(layer: &Layer) -> Vec<(BlockIndex, u64)> {
        let mut v: Vec<_> = layer.occupied_tiles().collect();
        v.sort_unstable();
        v
    }
}
