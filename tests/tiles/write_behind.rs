//! The contract of a tier above RAM whose copies of evicted blocks come back later
//! (`UpperTier::release_later`), on the CPU: a stand-in "device" owns the newest copy of every
//! block it holds (the layer keeps empty shadows, as with the GPU's blocks), forgets the blocks
//! a release names, and hands their copies back only when collected. Whatever the timing, the
//! chunk files end up holding the device's blocks, a chunk the camera comes back to is read
//! back with them, and nothing is lost.

use crate::paging::{assert_layers_identical, grid, paged_store, store_layer};
use denser::grid::{Block, BlockIndex, Layer};
use denser::map::store::MapStore;
use denser::outofcore::pager::{OverrunPolicy, PagerConfig};
use denser::store::{BlockStore, UpperTier};
use denser::Result;
use std::collections::{HashMap, HashSet, VecDeque};

/// The stand-in device (see the module documentation).
#[derive(Default)]
struct LateDevice {
    blocks: HashMap<BlockIndex, Block>,
    /// Blocks changed since they came up or were last synced (only these are copied back).
    dirty: HashSet<BlockIndex>,
    /// Per release in flight, its blocks' copies.
    releases: VecDeque<Vec<(BlockIndex, Block)>>,
    /// Releases collected since the store last asked.
    collected: usize,
    /// Releases begun, and those the store had to wait for.
    begun: usize,
    waited: usize,
}

impl LateDevice {
    /// Fuses `value` into voxel `k` of `b` on the device; a block it lacks comes up from the
    /// layer first (a chunk read back from disk), or starts empty.
    fn fuse(&mut self, layer: &mut Layer, b: BlockIndex, k: usize, value: f32) {
        let block = self
            .blocks
            .entry(b)
            .or_insert_with(|| layer.get(&b).cloned().unwrap_or_default());
        block.fuse(k % 512, value, Some([k as u8, 7, 9]));
        self.dirty.insert(b);
        // The layer knows the block, not its newest voxels.
        layer.get_or_allocate(b);
    }

    fn deliver_oldest(&mut self, held: &mut Layer) {
        for (b, block) in self.releases.pop_front().expect("a release") {
            *held.get_or_allocate(b) = block;
        }
        self.collected += 1;
    }
}

impl UpperTier for LateDevice {
    fn release(&mut self, _: &mut Layer, _: &[BlockIndex]) -> Result<()> {
        unreachable!("the store releases later")
    }

    fn release_later(
        &mut self,
        _: &mut Layer,
        held: &mut Layer,
        blocks: &[BlockIndex],
    ) -> Result<bool> {
        // Room for three releases in flight, as the GPU's ring.
        while self.releases.len() >= 3 {
            self.deliver_oldest(held);
            self.waited += 1;
        }
        let copies: Vec<(BlockIndex, Block)> = (blocks.iter())
            .filter_map(|b| self.blocks.remove(b).map(|block| (*b, block)))
            .filter(|(b, _)| self.dirty.remove(b))
            .collect();
        if copies.is_empty() {
            return Ok(false);
        }
        self.releases.push_back(copies);
        self.begun += 1;
        Ok(true)
    }

    /// Without `wait`, the copies of every release but the newest have arrived.
    fn collect_released(&mut self, held: &mut Layer, wait: bool) -> Result<usize> {
        let keep = if wait { 0 } else { 1 };
        while self.releases.len() > keep {
            self.waited += wait as usize;
            self.deliver_oldest(held);
        }
        Ok(std::mem::take(&mut self.collected))
    }

    fn sync(&mut self, layer: &mut Layer) -> Result<()> {
        for b in self.dirty.drain() {
            *layer.get_or_allocate(b) = self.blocks[&b].clone();
        }
        Ok(())
    }
}

#[test]
fn evicted_blocks_whose_copies_come_later_reach_the_chunk_files() {
    let dir = tempfile::tempdir().expect("tempdir");
    // RAM for about 40 blocks: the window of 24 blocks below evicts after most frames.
    let budget = 40 * denser::grid::BLOCK_RESIDENT_BYTES;
    let mut store = paged_store(&dir.path().join("map"), budget);
    let mut device = LateDevice::default();
    let mut truth = Layer::new(grid());
    // A window of 6×2×2 blocks drives along x and back (frames 30..: a revisit of every chunk
    // it left), with a checkpoint every 7 frames.
    let frames = 60;
    for k in 0..frames {
        let x0 = if k < 30 { k } else { 59 - k } as i32;
        let blocks: Vec<BlockIndex> = (0..6)
            .flat_map(|x| (0..2).flat_map(move |y| (0..2).map(move |z| BlockIndex([x0 + x, y, z]))))
            .collect();
        let mut sorted = blocks.clone();
        sorted.sort_unstable();
        store.prepare_blocks(&sorted, &mut device).expect("prepare");
        for (n, b) in sorted.iter().enumerate() {
            let value = ((k * 31 + n) % 17) as f32 / 17.0 - 0.5;
            device.fuse(store.layer_mut(), *b, k + n, value);
            truth
                .get_or_allocate(*b)
                .fuse((k + n) % 512, value, Some([(k + n) as u8, 7, 9]));
        }
        let camera_m = [(x0 as f64 + 3.0) * 0.4, 0.4, 0.4];
        store
            .finish_frame(&sorted, camera_m, &mut device)
            .expect("finish frame");
        if k % 7 == 6 {
            store.commit(k as u64 + 1, &mut device).expect("commit");
        }
    }
    store
        .commit(frames as u64, &mut device)
        .expect("last commit");
    let stats = store.pager_stats();
    eprintln!(
        "{stats:?}; {} releases begun, {} waited for",
        device.begun, device.waited
    );
    assert!(
        stats.chunks_evicted > 20 && stats.chunks_read > 10,
        "{stats:?}"
    );
    // Releases came back without a wait but where a checkpoint or a revisit needed them.
    assert!(
        device.begun >= 10 && device.waited < device.begun,
        "{} releases, {} waited for",
        device.begun,
        device.waited
    );
    let map = store.into_map().expect("map");
    assert_layers_identical(&truth, &store_layer(&map));
}

#[test]
fn a_chunk_waiting_for_its_copies_is_neither_paged_in_nor_checkpointed() {
    use denser::outofcore::pager::Pager;
    let dir = tempfile::tempdir().expect("tempdir");
    let store = MapStore::create(&dir.path().join("map"), grid(), 2).expect("create");
    let config = PagerConfig {
        overrun: OverrunPolicy::Warn,
        ..PagerConfig::with_budget(1)
    };
    let mut pager = Pager::new(store, config);
    let b = BlockIndex([0, 0, 0]);
    pager
        .page_in(&[denser::map::ChunkIndex([0, 0, 0])])
        .expect("page in");
    pager.layer_mut().get_or_allocate(b).fuse(0, 0.25, None);
    pager.mark_dirty(&[b]);
    let keep = Default::default();
    pager
        .evict_to_budget_with([0.0; 3], &keep, &mut |_, _, _| Ok(true))
        .expect("evict");
    assert_eq!(pager.held_releases(), 1);
    let err = pager
        .page_in(&[denser::map::ChunkIndex([0, 0, 0])])
        .unwrap_err();
    assert!(
        err.to_string().contains("waits for the GPU's copies"),
        "{err}"
    );
    let err = pager.checkpoint(1).unwrap_err();
    assert!(err.to_string().contains("before the GPU's copies"), "{err}");
    // Once the copies came, the chunk goes to its file and comes back with them.
    pager
        .held_layer_mut()
        .get_or_allocate(b)
        .fuse(1, -0.5, None);
    pager.complete_held(1).expect("complete");
    pager.checkpoint(1).expect("checkpoint");
    pager
        .page_in(&[denser::map::ChunkIndex([0, 0, 0])])
        .expect("page in");
    let back = pager.layer().get(&b).expect("read back");
    assert!(
        back.weight(0) == 1 && back.weight(1) == 1,
        "{:?}",
        back.voxel(1)
    );
}
