//! A LiDAR scan's blocks listed on the GPU (`Backend::plan_lidar`,
//! `src/fusion/lidar_listing.rs`: `shaders/lidar_blocks.wgsl` and `lidar_found.wgsl`) against
//! the host's listing (`LidarPlan::new`): the same blocks and pair counts; the scans fused from
//! such plans equal those fused from the host's, the host never walking a ray nor making its
//! direction; what a scan costs, listing and fusion together, once warm; and a `Reconstructor`
//! that lists each scan while the host goes on (frames in flight) leaves the map of one that
//! waits, waiting for nothing itself. Skips where no GPU adapter exists.

use crate::common::gpu;
use crate::compare::orbit_frames;
use crate::lidar::{assert_layers_identical, dense_scan, fuse_resident, sphere_scans_from};
use crate::lidar::{GRIDS, OFFSETS, ORIGINS, ORIGINS_ON_GRID, PARAMS};
use denser::backend::Backend;
use denser::frame::LidarScan;
use denser::fusion::LidarPlan;
use denser::gpu::ResidentOptions;
use denser::grid::{GridParams, Layer};
use denser::reconstruct::{ReconstructionConfig, Reconstructor};
use std::sync::Arc;

/// The sphere scans from `origins` and the dense one, `offset_m` away.
fn scans(origins: &[[f64; 3]; 3], offset_m: [f64; 3]) -> Vec<LidarScan> {
    let mut scans = sphere_scans_from(origins, offset_m);
    scans.push(dense_scan(origins[0], offset_m));
    scans
}

/// How many places `a` and `b` differ in.
fn differ<T: PartialEq>(a: &[T], b: &[T]) -> usize {
    a.iter().zip(b).filter(|(x, y)| x != y).count()
}

fn assert_same_plan(what: &str, device: &LidarPlan, host: &LidarPlan) {
    let (blocks, want_blocks) = (device.blocks(), host.blocks());
    let (counts, want_counts) = (device.pairs_per_block(), host.pairs_per_block());
    assert_eq!(
        (blocks.len(), differ(&blocks, &want_blocks)),
        (want_blocks.len(), 0),
        "{what}: blocks (how many, how many differ)"
    );
    assert_eq!(
        differ(&counts, &want_counts),
        0,
        "{what}: blocks whose pairs differ"
    );
    assert_eq!(device.pair_count(), host.pair_count(), "{what}");
    assert_eq!(device.ray_count(), host.ray_count(), "{what}");
}

#[test]
fn device_listed_lidar_plans_equal_the_hosts() {
    // Near the origin and kilometres from it, sensors in general position and on voxel corners
    // (rays exactly in voxel faces), both grids: the device lists the host's blocks with the
    // host's pair counts, and the host walks no ray.
    let Some(ctx) = gpu() else { return };
    let mut backend = Backend::gpu(Arc::new(ctx), ResidentOptions::default());
    let mut checked = (0, 0);
    for (grid, offset, origins) in [
        (GRIDS[0], OFFSETS[0], &ORIGINS),
        (GRIDS[1], OFFSETS[1], &ORIGINS),
        (GRIDS[0], OFFSETS[1], &ORIGINS_ON_GRID),
    ] {
        let layer = Layer::new(grid);
        for (k, scan) in scans(origins, offset).iter().enumerate() {
            let device = backend.plan_lidar(&layer, scan, &PARAMS).expect("listing");
            assert!(device.listed_on_device(), "scan {k} listed on the device");
            let what = format!("scan {k}, offset {offset:?}");
            assert_same_plan(&what, &device, &LidarPlan::new(&grid, scan, &PARAMS));
            assert!(!device.host_walked(), "{what}: the host walked");
            assert!(!device.host_made_rays(), "{what}: the host made the rays");
            checked.0 += device.blocks().len();
            checked.1 += device.pair_count();
        }
        // A backend keeps one grid's pool.
        backend = Backend::gpu(
            backend.gpu_context().expect("GPU").clone(),
            Default::default(),
        );
    }
    eprintln!(
        "device-listed: {} blocks, {} pairs, all the host's",
        checked.0, checked.1
    );
    // Blocks farther than 512 blocks from the sensor's do not pack: the host lists the scan.
    let fine = GridParams {
        voxel_size_m: 0.004,
        truncation_m: 0.02,
    };
    let far = sphere_scans_from(&ORIGINS, OFFSETS[0]).remove(0);
    let mut backend = Backend::gpu(
        backend.gpu_context().expect("GPU").clone(),
        Default::default(),
    );
    let plan = backend
        .plan_lidar(&Layer::new(fine), &far, &PARAMS)
        .expect("listing");
    assert!(!plan.listed_on_device(), "returns beyond 512 blocks");
    assert_same_plan("far returns", &plan, &LidarPlan::new(&fine, &far, &PARAMS));
}

#[test]
fn device_listed_scans_fuse_as_host_listed_ones_and_cost_their_rays() {
    // Two rounds of the sphere scans through the backend (listing on the device, then fusion
    // into its pool) give the voxels and touched blocks of the same scans fused from the host's
    // plans, bit for bit, with the host never walking a ray. Once warm (the second round) a scan
    // sends its rays once (16 bytes each) and at most 64 KiB besides, reads back its blocks
    // (8 bytes each, the listing's readback sized a quarter over the last scan's) and a flag
    // per block, in at most two submits and two waits: the listing's, and the fusion's for its
    // own results, as frames in flight are off here (a third submit and wait where the scan has
    // more blocks than the readback was sized for), creating nothing.
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let grid = GRIDS[0];
    let mut all = sphere_scans_from(&ORIGINS, OFFSETS[1]);
    all.extend(sphere_scans_from(&ORIGINS, OFFSETS[1]));
    let (want, want_touched, _, _) = fuse_resident(&ctx, grid, &all, ResidentOptions::default());
    let mut backend = Backend::gpu(ctx.clone(), ResidentOptions::default());
    let mut layer = Layer::new(grid);
    let mut touched = Vec::new();
    let mut last_blocks = 0u64;
    for (k, scan) in all.iter().enumerate() {
        let before = ctx.traffic();
        let plan = backend.plan_lidar(&layer, scan, &PARAMS).expect("listing");
        let (t, _) = backend.fuse_lidar(&mut layer, &plan).expect("fusion");
        let traffic = ctx.traffic().since(before);
        assert!(plan.listed_on_device() && !plan.host_walked(), "scan {k}");
        assert!(!plan.host_made_rays(), "scan {k}: the host made the rays");
        touched.push(t);
        let (rays, blocks) = (plan.ray_count() as u64, plan.blocks().len() as u64);
        eprintln!("scan {k}: {rays} rays, {blocks} blocks: {traffic:?}");
        let guess = last_blocks + last_blocks / 4 + 256;
        last_blocks = blocks;
        if k < 3 {
            continue;
        }
        let more = u64::from(blocks > guess);
        assert!(
            traffic.upload_bytes <= 16 * rays + (64 << 10),
            "{traffic:?}"
        );
        let down = 8 * blocks.max(guess) + 4 * blocks + (4 << 10);
        assert!(traffic.readback_bytes <= down, "{traffic:?}");
        assert!(traffic.submits <= 2 + more, "{traffic:?}");
        assert!(traffic.waits <= 2 + more, "{traffic:?}");
        let created = (traffic.buffers_created, traffic.bind_groups_created);
        assert_eq!(created, (0, 0), "{traffic:?}");
    }
    backend.flush_all(&mut layer).expect("write-back");
    assert_eq!(touched, want_touched, "touched blocks per scan");
    assert_layers_identical("device-listed vs host-listed", &want, &layer);
}

#[test]
fn scans_listed_while_the_host_goes_on_leave_the_map_of_scans_that_wait() {
    // With frames in flight (a `Reconstructor`'s default) each `fuse_lidar` fuses the scan
    // before its scan, whose listing it collects, and lists its scan; a depth frame or a sync
    // fuses the scan still listed first. Three rounds of the sphere scans, a depth frame and a
    // sync among them: the map of scans that each wait for their own listing, bit for bit. A
    // device that keeps up (idle before each call, as a real GPU is well within a scan's time)
    // is waited for by no call once warm (the third round's), except to read again the blocks of
    // a scan with more than its readback was sized for; each call sends the rays of its scan
    // once and at most 64 KiB besides, in one submit (the fusion of the scan before with the
    // listing of its scan recorded after it; two before 2026-11-30), creating nothing.
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let mut config = ReconstructionConfig::paper(0.1);
    config.grid = GRIDS[0];
    config.lidar_fusion = PARAMS;
    let round = sphere_scans_from(&ORIGINS, OFFSETS[0]);
    let blocks: Vec<u64> = (round.iter())
        .map(|s| LidarPlan::new(&config.grid, s, &PARAMS).blocks().len() as u64)
        .collect();
    let frame = &orbit_frames(1, 0.01)[0];
    // Scan k of the round, or (`None`) the depth frame, or a sync (`Some(usize::MAX)`).
    let mut calls: Vec<Option<usize>> = vec![Some(0), Some(1), Some(2), Some(0), None, Some(1)];
    calls.extend([Some(usize::MAX), Some(2), Some(0), Some(1), Some(2)]);
    let run = |in_flight: bool| {
        let backend = Backend::gpu(ctx.clone(), ResidentOptions::default());
        let mut rec = Reconstructor::in_memory(config, backend).expect("config");
        rec.set_frames_in_flight(in_flight).expect("in flight");
        let mut costs = Vec::new();
        for call in &calls {
            ctx.wait_idle_uncounted().expect("idle");
            let (before, frames) = (ctx.traffic(), rec.frames_total());
            match call {
                Some(usize::MAX) => rec.sync().expect("sync"),
                Some(k) => drop(rec.fuse_lidar(&round[*k]).expect("scan")),
                None => drop(rec.fuse_depth(frame).expect("frame")),
            }
            costs.push((ctx.traffic().since(before), rec.frames_total() - frames));
        }
        rec.sync().expect("sync");
        assert_eq!(
            rec.frames_total(),
            calls.len() as u64 - 1,
            "all but the sync"
        );
        (rec.layer().clone(), costs)
    };
    let (waited, _) = run(false);
    let (flying, costs) = run(true);
    assert_layers_identical("scans in flight vs scans that wait", &waited, &flying);
    // The frames each call fused: a scan's call fuses the scan before it, if any.
    let fused: Vec<u64> = costs.iter().map(|c| c.1).collect();
    assert_eq!(fused, [0, 1, 1, 1, 2, 0, 1, 0, 1, 1, 1]);
    let mut last_listed = None;
    for (k, (call, (t, _))) in calls.iter().zip(&costs).enumerate() {
        eprintln!("call {k} ({call:?}): {t:?}");
        let Some(scan) = call.filter(|&s| s < round.len()) else {
            continue;
        };
        let listed = last_listed.replace(scan);
        if k < 8 {
            continue; // warming up
        }
        // The scan before, collected here: a second readback where it has more blocks than
        // a quarter over the one listed before it, and 256.
        let before = listed.expect("a scan before");
        let last = blocks[(before + 2) % 3];
        let more = u64::from(blocks[before] > last + last / 4 + 256);
        let rays = LidarPlan::new(&config.grid, &round[scan], &PARAMS).ray_count() as u64;
        assert!(t.upload_bytes <= 16 * rays + (64 << 10), "{t:?}");
        assert_eq!((t.submits, t.waits), (1 + more, more), "{t:?}");
        assert_eq!((t.buffers_created, t.bind_groups_created), (0, 0), "{t:?}");
    }
}
