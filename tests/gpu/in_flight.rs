//! Depth frames in flight (`src/gpu/resident/late.rs`): a frame that returns before its results
//! arrive leaves the map exactly as a frame that waits for them, whenever its predecessors are
//! collected, through grows and spills, and a LiDAR scan or a sync in between.

use crate::common::{fuse_depth_resident, gpu, Rng, SphereScene};
use crate::compare::orbit_frames;
use denser::frame::{DepthFrame, LidarScan};
use denser::fusion::{integrate_lidar_resident, DepthFusionParams, LidarFusionParams, LidarPlan};
use denser::gpu::resident::{SLOT_BYTES, SLOT_TOMBSTONE};
use denser::gpu::{GpuContext, ResidentMap, ResidentOptions, ResidentStats};
use denser::grid::{GridParams, Layer};
use std::sync::Arc;

const GRID: GridParams = GridParams {
    voxel_size_m: 0.05,
    truncation_m: 0.4,
};

/// Fuses `frames` into a fresh map with `options`, frames in flight or not; `idle_every` > 0
/// lets the device finish (uncounted) before every `idle_every`-th frame, and the frames that
/// arrived be collected early; otherwise they are collected when the ring is full (as with a
/// slow device, so that frames overlap whatever the device's speed). Syncs at the end.
fn fuse(
    ctx: &Arc<GpuContext>,
    frames: &[DepthFrame],
    options: ResidentOptions,
    (in_flight, idle_every): (bool, usize),
) -> (Layer, ResidentStats, usize) {
    let mut layer = Layer::new(GRID);
    let mut map = ResidentMap::new(ctx.clone(), GRID, options).expect("pool");
    map.set_frames_in_flight(in_flight);
    map.set_collect_lazily(idle_every == 0);
    let params = DepthFusionParams::default();
    let mut updates = 0;
    for (k, f) in frames.iter().enumerate() {
        if idle_every > 0 && k % idle_every == 0 {
            ctx.wait_idle_uncounted().expect("idle");
        }
        let (_, stats) = fuse_depth_resident(&mut map, &mut layer, f, &params).expect("fuse");
        updates += stats.voxel_updates;
        assert!(map.frames_in_flight() <= 3, "the ring holds three frames");
    }
    map.sync(&mut layer).expect("sync");
    assert_eq!(map.frames_in_flight(), 0);
    // The frames the sync collected.
    updates += map.take_collected().1;
    // The frames' new blocks were inserted on the device, in entries and slots of its choosing:
    // the host learnt every one, and its table equals the device's entry for entry.
    let (on_host, on_gpu) = map.table_entries_on_host_and_gpu().expect("tables");
    assert!(
        on_host == on_gpu,
        "the host's table and the device's differ"
    );
    let live = on_host.iter().filter(|e| e[3] < SLOT_TOMBSTONE).count();
    assert_eq!(live, map.stats().resident_blocks);
    (layer, map.stats(), updates)
}

/// Whether two layers hold the same blocks, bit for bit.
fn same_layers(a: &Layer, b: &Layer) -> bool {
    a.indices_sorted() == b.indices_sorted()
        && a.indices_sorted().iter().all(|i| a.get(i) == b.get(i))
}

#[test]
fn frames_in_flight_leave_the_map_of_frames_that_wait() {
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let frames = orbit_frames(12, 0.01);
    let roomy = ResidentOptions {
        initial_blocks: 8192,
        max_bytes: 1 << 30,
    };
    let (waited, s0, updates0) = fuse(&ctx, &frames, roomy, (false, 0));
    eprintln!("each frame waits: {s0:?}");
    assert_eq!(s0.frames_overlapped, 0);
    // The device inserted every new block, in a slot the host had reserved for it: with no
    // frame in flight the host knows every block, so it reserved exactly as many.
    assert!(s0.blocks_created > 0 && s0.blocks_uploaded == 0, "{s0:?}");
    assert_eq!(s0.slots_reserved, s0.blocks_created);
    // Frames submitted back to back: a frame lists blocks its predecessors, still in flight,
    // may have created (the kernel fuses those only where one did).
    let (flying, s1, updates1) = fuse(&ctx, &frames, roomy, (true, 0));
    eprintln!("in flight: {s1:?}");
    assert!(
        same_layers(&waited, &flying),
        "frames in flight changed the map"
    );
    assert!(s1.frames_overlapped > 0, "{s1:?}");
    assert!(s1.blocks_listed_in_flight > 0, "{s1:?}");
    // A frame listed while its predecessors were in flight reserved slots for blocks they had
    // inserted already; the device gave those blocks none, and the host took the slots back.
    assert!(s1.slots_reserved > s1.blocks_created, "{s1:?}");
    // Released blocks: the map holds as many as the waiting run's.
    assert_eq!(s1.resident_blocks, s0.resident_blocks);
    // Every frame's updates were counted once, by a later frame or the sync.
    assert!(updates0 > 0);
    assert_eq!(updates1, updates0);
    // The device finishing some frames before the next one arrives: the same map again.
    let (idle, s2, _) = fuse(&ctx, &frames, roomy, (true, 2));
    eprintln!("idle every second frame: {s2:?}");
    assert!(same_layers(&waited, &idle));
    // A pool that grows from 64 slots and then spills: growing or spilling collects first.
    let tight = ResidentOptions {
        initial_blocks: 64,
        max_bytes: (s0.largest_frame_blocks as u64 + 64) * SLOT_BYTES,
    };
    let (spilled, s3, _) = fuse(&ctx, &frames, tight, (true, 0));
    eprintln!("in flight, tight pool: {s3:?}");
    assert!(s3.grows > 0 && s3.blocks_spilled > 0, "{s3:?}");
    assert!(
        same_layers(&waited, &spilled),
        "spilling in flight changed the map"
    );
}

#[test]
fn lidar_scans_in_flight_between_depth_frames_leave_the_same_map() {
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let frames = orbit_frames(6, 0.01);
    let scene = SphereScene::standard();
    let mut rng = Rng(7);
    let scans: Vec<LidarScan> = [[0.0, -0.5, -4.5], [3.0, -0.5, -3.0], [-3.5, -0.5, 1.0]]
        .iter()
        .map(|o| scene.lidar(*o, 32, 720, 0.0, &mut rng))
        .collect();
    let run = |in_flight: bool| {
        let mut layer = Layer::new(GRID);
        let options = ResidentOptions::default();
        let mut map = ResidentMap::new(ctx.clone(), GRID, options).expect("pool");
        map.set_frames_in_flight(in_flight);
        map.set_collect_lazily(true);
        let (depth, lidar) = (DepthFusionParams::default(), LidarFusionParams::default());
        let mut touched = Vec::new();
        // Frame, scan, frame, frame, scan, …: a scan's new blocks are listed by the frames
        // after it while it is in flight.
        for (k, f) in frames.iter().enumerate() {
            let (t, _) = fuse_depth_resident(&mut map, &mut layer, f, &depth).expect("frame");
            touched.extend(t);
            if k % 2 == 0 {
                let plan = LidarPlan::new(&GRID, &scans[k / 2], &lidar);
                let (t, _) = integrate_lidar_resident(&mut map, &mut layer, &plan).expect("scan");
                touched.extend(t);
            }
        }
        map.sync(&mut layer).expect("sync");
        touched.extend(map.take_collected().0);
        touched.sort_unstable();
        touched.dedup();
        (layer, map.stats(), touched)
    };
    let (waited, s0, touched0) = run(false);
    let (flying, s1, touched1) = run(true);
    eprintln!("each waits: {s0:?}\nin flight: {s1:?}");
    assert!(s1.frames_overlapped > 0, "{s1:?}");
    assert!(
        same_layers(&waited, &flying),
        "scans in flight changed the map"
    );
    // What the calls and the sync reported touched is the same set.
    assert_eq!(touched0, touched1);
    assert_eq!(touched0, waited.indices_sorted());
}

#[test]
fn released_blocks_come_back_later_though_new_blocks_took_their_slots() {
    // A pager's eviction (`ResidentMap::release_blocks_later`): the blocks leave the pool at
    // once and their copies come back later, while the next frames fill the freed slots. The
    // copies collected must be the blocks as they were when released (as a sync then gives).
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let frames = orbit_frames(12, 0.01);
    let options = ResidentOptions {
        initial_blocks: 8192,
        max_bytes: 1 << 30,
    };
    let params = DepthFusionParams::default();
    let (first, next) = frames.split_at(6);
    let mut reference = Layer::new(GRID);
    let mut map = ResidentMap::new(ctx.clone(), GRID, options).expect("pool");
    for f in first {
        fuse_depth_resident(&mut map, &mut reference, f, &params).expect("fuse");
    }
    map.sync(&mut reference).expect("sync");
    let mut layer = Layer::new(GRID);
    let mut map = ResidentMap::new(ctx.clone(), GRID, options).expect("pool");
    for f in first {
        fuse_depth_resident(&mut map, &mut layer, f, &params).expect("fuse");
    }
    let blocks = map.resident_blocks();
    let slots: std::collections::HashSet<u32> =
        blocks.iter().filter_map(|b| map.slot_of(*b)).collect();
    let mut held = Layer::new(GRID);
    let later = map
        .release_blocks_later(&mut layer, &mut held, &blocks)
        .expect("release");
    assert!(later && map.releases_in_flight() == 1 && map.resident_blocks().is_empty());
    // The pager moves the leaving blocks out of its layer (their shadows are stale).
    held.put_blocks(layer.take_blocks(&blocks));
    for f in next {
        fuse_depth_resident(&mut map, &mut layer, f, &params).expect("fuse");
    }
    let reused = (map.resident_blocks().iter())
        .filter(|b| map.slot_of(**b).is_some_and(|s| slots.contains(&s)))
        .count();
    assert!(reused > 100, "{reused} freed slots taken by new blocks");
    assert_eq!(map.collect_released(&mut held, true).expect("collect"), 1);
    assert_eq!(map.releases_in_flight(), 0);
    assert!(
        same_layers(&held, &reference),
        "the copies differ from the blocks released"
    );
}
