//! The pieces of a map the device owns. Blocks allocated on the device
//! (`src/gpu/resident/alloc.rs`, `shaders/table_insert.wgsl`): a frame's listed blocks that the
//! GPU hash table lacks take slots from the free-slot stack and entries by compare-and-swap.
//! Against the CPU twin run in the list's order (`allocate_on_cpu`): the same blocks inserted,
//! the same slots taken, the same count left without one; and the host's copy of the table,
//! with the device's insertions applied, equals the device's table entry for entry and finds
//! every block at the device's slot. The resident blocks in view found on the device
//! (`src/fusion/visible_gpu.rs`, `shaders/table_visible.wgsl`): with the host's decisions of
//! the undecided ones, exactly the blocks `ViewFrustum::meets_block` passes.

use crate::common::{gpu, Rng};
use crate::street::street_frame;
use denser::fusion::{
    resident_in_view_on_gpu, DepthFusionParams, DepthGeometry, FrameKeys, ViewFrustum, MARGIN_PER_M,
};
use denser::gpu::resident::alloc::{allocate_on_cpu, allocate_on_gpu, take_popped};
use denser::gpu::resident::{block_hash, BlockTable};
use denser::gpu::GpuContext;
use denser::grid::{BlockIndex, GridParams};

/// Runs the allocation of `listed` on the device and on the CPU and compares them; returns
/// (blocks inserted, of which not at their hash's entry).
fn check(
    ctx: &GpuContext,
    keys: &FrameKeys,
    listed: &[BlockIndex],
    table: &BlockTable,
    free: &[u32],
    first_unsettled: usize,
) -> (usize, usize) {
    let absent = (listed[..first_unsettled].iter())
        .filter(|b| table.lookup(**b).is_none())
        .count();
    assert!(table.has_room_for(absent), "the test's table is too full");
    let (gpu, entries, top) =
        allocate_on_gpu(ctx, table, free, keys.uniforms(table.mask()), keys.words()).unwrap();
    let (mut cpu_table, mut cpu_free) = (table.clone(), free.to_vec());
    let cpu = allocate_on_cpu(&mut cpu_table, &mut cpu_free, listed, first_unsettled);
    // What does not depend on the order the device ran the blocks in.
    let inserted = |a: &denser::gpu::resident::alloc::DeviceAllocation| {
        let mut v: Vec<u32> = a.created.iter().map(|c| c.0).collect();
        v.sort_unstable();
        v
    };
    assert_eq!(
        gpu.left_without, cpu.left_without,
        "blocks left without a slot"
    );
    assert_eq!(gpu.left_without as usize, absent.saturating_sub(free.len()));
    assert_eq!(gpu.created.len(), absent.min(free.len()), "blocks inserted");
    assert_eq!(
        gpu.taken_slots(),
        cpu.taken_slots(),
        "slots taken from the stack"
    );
    if gpu.left_without == 0 {
        assert_eq!(inserted(&gpu), inserted(&cpu), "blocks inserted");
    }
    assert_eq!(
        top,
        (free.len() as u32).wrapping_sub(absent as u32),
        "stack count"
    );
    let mut host_free = free.to_vec();
    let mut popped = take_popped(&mut host_free, gpu.created.len());
    popped.sort_unstable();
    assert_eq!(popped, gpu.taken_slots());
    // The host's copy with the device's insertions applied is the device's table.
    let mut mirror = table.clone();
    gpu.apply_to(&mut mirror, listed);
    assert_eq!(mirror.entries(), &entries[..], "host copy vs device table");
    assert_eq!(mirror.len(), table.len() + gpu.created.len());
    for (i, b) in listed.iter().enumerate() {
        assert_eq!(mirror.lookup(*b), gpu.slots[i], "block {i} {b:?}");
        if let Some(s) = table.lookup(*b) {
            assert_eq!(
                gpu.slots[i],
                Some(s),
                "a block the table held keeps its slot"
            );
        }
        if i >= first_unsettled && table.lookup(*b).is_none() {
            assert_eq!(gpu.slots[i], None, "an unsettled block is only looked up");
        }
    }
    let displaced = (gpu.created.iter())
        .filter(|(i, pos)| block_hash(listed[*i as usize]) & table.mask() != *pos)
        .count();
    (gpu.created.len(), displaced)
}

/// A table holding every third of `blocks` (slots from 0 up), with tombstones of removed keys
/// in the probe sequences, and the pool's free list (top last).
fn table_and_free(blocks: &[BlockIndex], room: u32, pool: u32) -> (BlockTable, Vec<u32>) {
    let mut table = BlockTable::for_blocks(room);
    let mut used = vec![false; pool as usize];
    for (k, b) in blocks.iter().enumerate().filter(|(k, _)| k % 3 == 0) {
        let slot = (k / 3) as u32;
        table.insert(*b, slot);
        used[slot as usize] = true;
    }
    for (k, b) in blocks
        .iter()
        .enumerate()
        .filter(|(k, _)| k % 6 == 0 && k % 12 != 0)
    {
        let slot = table.remove(*b).expect("held");
        used[slot as usize] = false;
        assert_eq!(slot as usize, k / 3);
    }
    let free = (0..pool).rev().filter(|s| !used[*s as usize]).collect();
    (table, free)
}

#[test]
fn blocks_allocated_on_the_device_are_the_twins() {
    let Some(ctx) = gpu() else { return };
    let grid = GridParams::paper(0.1);
    let frame = street_frame(300.0, 0);
    let g = DepthGeometry::new(&grid, &frame);
    let origin = grid.block_of_point(frame.world_from_camera.translation.vector.into());
    let mut rng = Rng(11);
    let mut blocks: Vec<BlockIndex> = (0..5000)
        .map(|_| {
            let d = [0, 1, 2].map(|k| ((rng.uniform() - 0.5) * [300.0, 60.0, 300.0][k]) as i32);
            origin.offset(d)
        })
        .collect();
    blocks.sort_unstable();
    blocks.dedup();
    // Listed in an order other than the keys' (the device's band lists them unordered).
    let mut listed = blocks.clone();
    listed.sort_unstable_by_key(|b| block_hash(*b));
    let n = listed.len();
    let (table, free) = table_and_free(&blocks, n as u32, n as u32 + 64);
    for (case, wide, free_slots, first_unsettled) in [
        ("enough slots", false, free.len(), n - 40),
        ("wide keys", true, free.len(), n - 40),
        ("the stack runs out", false, 100, n),
        ("nothing to insert", false, free.len(), 0),
    ] {
        let mut listed = listed.clone();
        if wide {
            listed.insert(n / 2, origin.offset([0, 3000, 0]));
        }
        let keys = FrameKeys::new(&grid, &g, &listed, first_unsettled).expect("keys");
        assert_eq!(keys.is_wide(), wide);
        let free = &free[free.len() - free_slots..];
        let (inserted, displaced) = check(&ctx, &keys, &listed, &table, free, first_unsettled);
        eprintln!(
            "{case}: {} listed, {inserted} inserted, {displaced} of them probed past",
            listed.len()
        );
        if case != "nothing to insert" {
            assert!(
                displaced > 0,
                "{case}: no insertion probed past a taken entry"
            );
        }
    }
}

#[test]
fn a_crowded_small_table_takes_every_insertion_once() {
    let Some(ctx) = gpu() else { return };
    let grid = GridParams::paper(0.1);
    let frame = street_frame(0.0, 0);
    let g = DepthGeometry::new(&grid, &frame);
    let origin = grid.block_of_point(frame.world_from_camera.translation.vector.into());
    // 64 entries: 10 held, 2 of them removed (tombstones), then 20 new blocks, 28 live in
    // all: long probe sequences through taken entries and tombstones.
    let blocks: Vec<BlockIndex> = (0..28).map(|k| origin.offset([k % 4, k / 4, 0])).collect();
    let (table, free) = table_and_free(&blocks, 32, 40);
    assert_eq!(table.capacity(), 64);
    let listed: Vec<BlockIndex> = blocks.iter().rev().copied().collect();
    let keys = FrameKeys::new(&grid, &g, &listed, listed.len()).expect("keys");
    let (inserted, displaced) = check(&ctx, &keys, &listed, &table, &free, listed.len());
    eprintln!("small table: {inserted} inserted, {displaced} probed past a taken entry");
    assert!(inserted == 20 && displaced > 0);
}

#[test]
fn the_resident_blocks_in_view_found_on_the_device_are_the_hosts() {
    let Some(ctx) = gpu() else { return };
    for (voxel_m, z_m, seed) in [(0.1, 300.0, 0), (0.05, 2000.0, 1), (0.2, 40.0, 2)] {
        let grid = GridParams::paper(voxel_m);
        let frame = street_frame(z_m, seed);
        let params = DepthFusionParams::default();
        let frustum = ViewFrustum::new(&frame, &params, grid.truncation_m as f64);
        let origin = grid.block_of_point(frame.world_from_camera.translation.vector.into());
        // Blocks all around the camera, in front, behind and past the far plane.
        let reach = 2.0 * (params.max_depth_m as f64) / grid.block_size_m();
        let mut rng = Rng(seed as u64 + 20);
        let mut blocks: Vec<BlockIndex> = (0..20_000)
            .map(|_| {
                let d = [0, 1, 2].map(|k| {
                    let half = if k == 1 { 0.2 * reach } else { reach };
                    ((rng.uniform() - 0.5) * 2.0 * half) as i32
                });
                origin.offset(d)
            })
            .collect();
        blocks.sort_unstable();
        blocks.dedup();
        // Every block held but every seventh, whose entries are left as tombstones.
        let mut table = BlockTable::for_blocks(blocks.len() as u32);
        for (k, b) in blocks.iter().enumerate() {
            table.insert(*b, k as u32);
        }
        for b in blocks.iter().step_by(7) {
            table.remove(*b);
        }
        let mut truth: Vec<BlockIndex> = (blocks.iter().copied())
            .filter(|b| table.lookup(*b).is_some() && frustum.meets_block(&grid, *b))
            .collect();
        truth.sort_unstable();
        assert!(truth.len() > 100, "{} blocks in view", truth.len());
        // The kernel's margin, and one wide enough that the host decides many blocks.
        for margin_per_m in [MARGIN_PER_M, 0.02] {
            let view = resident_in_view_on_gpu(&ctx, &table, (&frustum, &grid), margin_per_m)
                .expect("kernel");
            for &pos in &view.in_view {
                let e = table.entries()[pos as usize];
                let b = BlockIndex([e[0] as i32, e[1] as i32, e[2] as i32]);
                assert!(frustum.meets_block(&grid, b), "{b:?} is not in view");
            }
            assert_eq!(
                view.blocks(&table, &frustum, &grid),
                truth,
                "margin {margin_per_m}"
            );
            eprintln!(
                "{voxel_m} m voxels, {z_m} m down the street, margin {margin_per_m}/m: {} live \
                 blocks, {} in view, {} found on the device, {} left to the host",
                table.len(),
                truth.len(),
                view.in_view.len(),
                view.undecided.len()
            );
            if margin_per_m > MARGIN_PER_M {
                assert!(
                    !view.undecided.is_empty(),
                    "the wide margin left nothing to the host"
                );
            }
        }
    }
}
