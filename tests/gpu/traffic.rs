//! What the GPU stages cost, from the context's counters ([`denser::gpu::GpuTraffic`]): every
//! wgpu call of the crate goes through `GpuContext` (checked here on the source, no GPU needed),
//! and a resident depth frame, a TV solve and a run's stages stay within stated bounds (on
//! lavapipe in CI: the counts do not depend on the device).

use crate::common::{self, gpu, Rng, SphereScene};
use crate::compare::{orbit_frames, random_problem};
use crate::depth_support::{city_like_planes, piecewise_planar_pair};
use crate::street::street_frame;
use denser::backend::Backend;
use denser::depth::tgv::HoleFill;
use denser::depth::{SgmParams, StereoMethod};
use denser::gpu::resident::SLOT_BYTES;
use denser::gpu::{GpuTraffic, ResidentOptions};
use denser::grid::{GridParams, VOXELS_PER_BLOCK};
use denser::reconstruct::{ReconstructionConfig, Reconstructor};
use denser::regularize::{solve_gpu, TvParams, TvProblem};
use std::path::Path;
use std::sync::Arc;

/// Raw wgpu calls that move data, submit, wait or create resources: only `GpuContext`'s own
/// methods may make them, so that its counters see everything.
const RAW_CALLS: [&str; 7] = [
    "queue.submit",
    "queue.write_buffer",
    "device.poll",
    "device.create_buffer",
    "device.create_bind_group(",
    "create_buffer_init",
    "dispatch_workgroups",
];

/// The raw calls in `source` (comment lines left out), as `line: call`.
fn raw_calls(source: &str) -> Vec<String> {
    let mut found = Vec::new();
    for (k, line) in source.lines().enumerate() {
        let code = line.split("//").next().unwrap_or("");
        for call in RAW_CALLS {
            if code.contains(call) {
                found.push(format!("{}: {call}", k + 1));
            }
        }
    }
    found
}

fn rust_files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("read src/") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn every_gpu_call_goes_through_the_context() {
    // The check itself finds a planted call and ignores a commented one.
    assert_eq!(
        raw_calls("let x = 1;\n    ctx.queue.submit([e.finish()]); // ok\n// device.poll(x)\n"),
        ["2: queue.submit"]
    );
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let context = src.join("gpu").join("context.rs");
    let mut offenders = Vec::new();
    for f in files.iter().filter(|f| **f != context) {
        let text = std::fs::read_to_string(f).expect("read");
        for hit in raw_calls(&text) {
            offenders.push(format!("{}:{hit}", f.display()));
        }
    }
    assert!(files.len() > 50, "{} files", files.len());
    assert!(
        offenders.is_empty(),
        "uncounted wgpu calls (use GpuContext's methods):\n{}",
        offenders.join("\n")
    );
}

#[test]
fn a_resident_depth_frame_after_warm_up_creates_no_buffer_and_uploads_no_new_block() {
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let grid = GridParams {
        voxel_size_m: 0.05,
        truncation_m: 0.4,
    };
    let mut config = ReconstructionConfig::paper(0.05);
    config.grid = grid;
    let mut rec = Reconstructor::in_memory(
        config,
        Backend::gpu(ctx.clone(), ResidentOptions::default()),
    )
    .expect("config");
    // Two laps of an orbit: the second lap revisits the first one's blocks.
    let frames = orbit_frames(6, 0.01);
    for f in &frames[..3] {
        ctx.wait_idle_uncounted().expect("idle");
        rec.fuse_depth(f).expect("warm-up");
    }
    let (mut checked, mut created_somewhere) = (0, false);
    for f in frames.iter().chain(&frames).skip(3) {
        // The device keeps up (a real GPU does): the frame before has arrived.
        ctx.wait_idle_uncounted().expect("idle");
        let before_stats = rec.resident_stats().expect("resident");
        let before = ctx.traffic();
        rec.fuse_depth(f).expect("fuse");
        let t = ctx.traffic().since(before);
        let stats = rec.resident_stats().expect("resident");
        let uploaded_blocks = stats.blocks_uploaded - before_stats.blocks_uploaded;
        // Created: the frame before's new blocks, learnt as this frame began (`late.rs`).
        let created_blocks = stats.blocks_created - before_stats.blocks_created;
        let reserved = stats.slots_reserved - before_stats.slots_reserved;
        let listed = stats.largest_frame_blocks as u64;
        let pixels = f.depth_m.data.len() as u64;
        eprintln!(
            "frame: {t:?}, {uploaded_blocks} blocks uploaded, {created_blocks} created, \
             ≤ {listed} listed, grows {}",
            stats.grows
        );
        if stats.grows != before_stats.grows {
            continue; // a grown pool or table is a new buffer: not the steady state
        }
        checked += 1;
        created_somewhere |= created_blocks > 0 && reserved > 0;
        // One submit: the slots reserved for new blocks are written empty on the device (one
        // more dispatch), the table's changed entries put in place there where they are
        // scattered (one more), then the lookup, the new blocks' insertion (one more) and the
        // fusion. No wait: the frame's flags and insertions come back with a later frame
        // (`src/gpu/resident/late.rs`). The table's changes (the released blocks': the new
        // ones are inserted on the device) take one host write, or a few where they lie in a
        // few runs.
        let fills = 2 * (reserved > 0) as u64;
        let table_writes = stats.table_writes - before_stats.table_writes;
        assert_eq!(t.buffers_created, 0, "{t:?}");
        assert_eq!(t.bind_groups_created, 0, "{t:?}");
        assert_eq!(t.submits, 1, "{t:?}");
        assert_eq!(t.waits, 0, "{t:?}");
        let scatters = t.dispatches - (2 + fills);
        assert!(scatters <= 1, "{t:?}");
        assert!(
            table_writes <= [16, 1][scatters as usize],
            "{table_writes} table writes"
        );
        // Up: the depth and colour images (4 and 3 bytes per pixel), a packed offset per listed
        // block (4 bytes), the blocks coming back from RAM, two slot numbers per reserved slot
        // (the fill's list and the device's stack), table entries and uniforms.
        assert!(f.color.is_some());
        let images = 7 * pixels;
        let up_bound =
            images + 4 * listed + SLOT_BYTES * uploaded_blocks + 8 * reserved + (64 << 10);
        assert!(
            t.upload_bytes <= up_bound,
            "{} > {up_bound}",
            t.upload_bytes
        );
        // The bound, where no block comes back from RAM: the images plus 64 KiB.
        if uploaded_blocks == 0 {
            assert!(t.upload_bytes <= images + (64 << 10), "{t:?}");
        }
        // Down: the frame before's counters, one flag per block it listed and its insertions
        // (12 bytes each, and two counters); no block.
        assert!(
            t.readback_bytes <= 4 * listed + 16 + 12 * created_blocks + 8,
            "{t:?}"
        );
    }
    assert!(checked >= 6, "{checked} steady frames");
    assert!(created_somewhere, "no steady frame created a block");
}

#[test]
fn a_kitti_sized_frame_uploads_its_images_and_at_most_64_kib_more() {
    // The bound at its own frame size (1241 × 376 at 10 cm): each listed block goes up
    // as a 4-byte offset (`src/fusion/depth_keys.rs`), so the thousands of blocks of a street
    // frame fit in the 64 KiB beside the depth and colour images.
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let mut rec = Reconstructor::in_memory(
        ReconstructionConfig::paper(0.1),
        Backend::gpu(ctx.clone(), ResidentOptions::default()),
    )
    .expect("config");
    let frames: Vec<_> = (0..7).map(|k| street_frame(0.8 * k as f64, k)).collect();
    let mut checked = 0;
    for (k, f) in frames.iter().enumerate() {
        ctx.wait_idle_uncounted().expect("idle");
        // (The map comes with the first frame.)
        let before_stats = rec.resident_stats().unwrap_or_default();
        let before = ctx.traffic();
        rec.fuse_depth(f).expect("fuse");
        let t = ctx.traffic().since(before);
        let stats = rec.resident_stats().expect("resident");
        let listed = stats.largest_frame_blocks as u64;
        eprintln!("street frame {k}: {t:?}, ≤ {listed} blocks listed");
        if k < 3 || stats.grows != before_stats.grows {
            continue; // warm-up: the kept buffers, the readback ring's three and the pool grow
        }
        checked += 1;
        assert_eq!(stats.blocks_uploaded, before_stats.blocks_uploaded);
        assert!(listed > 3000, "{listed} blocks: not a street");
        let images = 7 * f.depth_m.data.len() as u64;
        assert!(t.upload_bytes <= images + (64 << 10), "{t:?}");
        assert!(t.readback_bytes <= 64 << 10, "{t:?}");
        assert_eq!((t.submits, t.waits, t.buffers_created), (1, 0, 0), "{t:?}");
    }
    assert!(checked >= 3, "{checked} steady frames");
}

#[test]
fn a_sync_reads_dirty_blocks_back_and_uploads_nothing() {
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let mut config = ReconstructionConfig::paper(0.1);
    config.grid.truncation_m = 0.8;
    let mut rec = Reconstructor::in_memory(
        config,
        Backend::gpu(ctx.clone(), ResidentOptions::default()),
    )
    .expect("config");
    for f in &orbit_frames(3, 0.01) {
        rec.fuse_depth(f).expect("fuse");
    }
    let before = ctx.traffic();
    rec.sync().expect("sync");
    let t = ctx.traffic().since(before);
    let stats = rec.resident_stats().expect("resident");
    let dirty = stats.resident_blocks as u64;
    eprintln!("sync of ≤ {dirty} blocks: {t:?}");
    // The frames still in flight (at most the ring's three) are collected first: their flags,
    // insertions (at most one per listed block) and counters, and one wait. Then the blocks
    // come down once; their marks are cleared on the device (a slot list and uniforms go up,
    // not the blocks).
    let flags = 3 * (16 * stats.largest_frame_blocks as u64 + 16);
    assert!(
        t.readback_bytes > 0 && t.readback_bytes <= dirty * SLOT_BYTES + flags,
        "{t:?}"
    );
    assert!(t.upload_bytes <= 4 * dirty + 256, "{t:?}");
    assert!(t.waits == 1 || t.waits == 2, "{t:?}");
}

#[test]
fn a_tv_solve_moves_16_bytes_per_voxel_up_and_4_down() {
    let Some(ctx) = gpu() else { return };
    let params = TvParams {
        iterations: 100,
        ..TvParams::paper(0.1)
    };
    let problem = random_problem(3);
    let n = problem.masks().len() as u64;
    let blocks = problem.blocks().len() as u64;
    assert_eq!(n, blocks * VOXELS_PER_BLOCK as u64);
    let uniforms = std::mem::size_of::<denser::gpu::layout::TvUniforms>() as u64;

    let mut fresh = problem.clone();
    let before = ctx.traffic();
    solve_gpu(&ctx, &mut fresh, &params).expect("solve");
    let t = ctx.traffic().since(before);
    eprintln!("fresh, u alone: {t:?}");
    // f, w, u and the masks (4 bytes per voxel each), the neighbour table (24 bytes per block).
    assert_eq!(t.upload_bytes, 16 * n + 24 * blocks + uniforms, "{t:?}");
    assert_eq!(t.readback_bytes, 4 * n, "{t:?}");
    assert_eq!(t.waits, 1, "{t:?}");
    assert_eq!(t.dispatches, 2 * params.iterations as u64, "{t:?}");
    // 100 iterations in two submits (64 per submit), the second with the readback's copy.
    assert_eq!(t.submits, 2, "{t:?}");

    // A problem that continues (iterated, iterates kept): ū and p go up and come back.
    let mut going_on = problem.clone();
    going_on.iterate(&params);
    going_on.set_keep_iterates(true);
    let before = ctx.traffic();
    solve_gpu(&ctx, &mut going_on, &params).expect("solve");
    let t = ctx.traffic().since(before);
    assert_eq!(t.upload_bytes, 32 * n + 24 * blocks + uniforms, "{t:?}");
    assert_eq!(t.readback_bytes, 20 * n, "{t:?}");
}

#[test]
fn tv_solves_region_after_region_create_no_buffer() {
    // A backend keeps the TV solves' buffers, bind groups and staging from region to region:
    // once sized, a solve creates nothing and submits once (≤ 64 iterations), its readback's
    // copy with the iterations.
    use denser::regularize::TvSolver;
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let params = TvParams {
        iterations: 40,
        ..TvParams::paper(0.1)
    };
    let mut backend = Backend::gpu(ctx.clone(), ResidentOptions::default());
    // A smaller region after a larger one runs in the larger one's buffers.
    let large = random_problem(3);
    let small = {
        let blocks: Vec<_> = large.blocks()[..5].to_vec();
        let n = blocks.len() * VOXELS_PER_BLOCK;
        let omega = (0..n).map(|i| (i * 7919) % 20 != 0).collect();
        TvProblem::from_arrays(blocks, large.f[..n].to_vec(), large.w[..n].to_vec(), omega)
    };
    let mut counts = Vec::new();
    for (k, problem) in [&large, &small, &large].into_iter().enumerate() {
        let mut p = problem.clone();
        let before = ctx.traffic();
        backend.solve(&mut p, &params).expect("solve");
        let t = ctx.traffic().since(before);
        eprintln!("solve {k}: {t:?}");
        counts.push((t.buffers_created, t.bind_groups_created, t.submits, t.waits));
        // The same result as a solve with buffers of its own.
        let mut alone = problem.clone();
        solve_gpu(&ctx, &mut alone, &params).expect("solve");
        assert_eq!(p.u, alone.u, "solve {k}");
    }
    assert!(counts[0].0 > 0, "the first solve sizes the buffers");
    assert_eq!(counts[1..], [(0, 0, 1, 1), (0, 0, 1, 1)], "{counts:?}");
}

#[test]
fn a_run_counts_its_stages_traffic() {
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let mut config = ReconstructionConfig::paper(0.1);
    config.grid.truncation_m = 0.8;
    config.tv.iterations = 10;
    let mut rec = Reconstructor::in_memory(
        config,
        Backend::gpu(ctx.clone(), ResidentOptions::default()),
    )
    .expect("config");
    let frames = orbit_frames(3, 0.01);
    for f in &frames {
        rec.fuse_depth(f).expect("fuse");
    }
    let scene = SphereScene::standard();
    let scan = scene.lidar([0.0, -0.5, -4.5], 16, 360, 0.0, &mut Rng(3));
    rec.fuse_lidar(&scan).expect("lidar");
    rec.regularize().expect("tv");
    let g = rec.gpu_traffic().expect("on a GPU");
    eprintln!("{g:#?}");
    assert_eq!(g.depth_frames, 3);
    assert_eq!(g.lidar_scans, 1);
    assert!(g.tv_solves >= 1);
    assert!(
        g.write_backs >= 1,
        "the TV solve reads the layer after a sync"
    );
    let stages = [g.depth, g.lidar, g.tv, g.write_back]
        .into_iter()
        .fold(GpuTraffic::default(), GpuTraffic::plus);
    assert_eq!(g.total, ctx.traffic());
    for (part, whole) in [
        (stages.upload_bytes, g.total.upload_bytes),
        (stages.readback_bytes, g.total.readback_bytes),
        (stages.submits, g.total.submits),
        (stages.waits, g.total.waits),
    ] {
        assert!(part > 0 && part <= whole, "{part} of {whole}");
    }
    assert_eq!(g.stereo_pairs, 0, "no stereo in this run");
    // A CPU backend has no traffic to report.
    assert!(common::reconstructor_over(
        config,
        denser::grid::Layer::new(config.grid),
        Backend::cpu()
    )
    .gpu_traffic()
    .is_none());
}

#[test]
fn a_backends_stereo_matchers_count_each_pair() {
    // The matchers belong to the input sequence, the figures to the backend's run summary: each
    // pair's traffic reaches the backend through the tally, exactly as the context counted it.
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let backend = Backend::gpu(ctx.clone(), ResidentOptions::default());
    let (w, h) = (96, 48);
    let (left, right, _) = piecewise_planar_pair(w, h, &city_like_planes(w, h), 4.0);
    let sgm = SgmParams {
        num_disparities: 32,
        ..SgmParams::default()
    };
    let mut spent = GpuTraffic::default();
    for method in [StereoMethod::Sgm, StereoMethod::TgvTensor] {
        let m = backend
            .stereo_matcher(method, sgm, HoleFill::None)
            .expect("matcher");
        for _ in 0..2 {
            let before = ctx.traffic();
            m.estimate(&left, &right).expect("pair");
            spent = spent.plus(ctx.traffic().since(before));
        }
    }
    let g = backend.gpu_traffic().expect("on a GPU");
    assert_eq!(g.stereo_pairs, 4);
    assert_eq!(g.stereo, spent);
    // Both matchers sent their images up and read results back, in at least a submit and a
    // wait per pair.
    let pixels = (w * h) as u64;
    assert!(g.stereo.upload_bytes >= 4 * 2 * pixels, "{g:?}");
    assert!(g.stereo.submits >= 4 && g.stereo.waits >= 4, "{g:?}");
}

#[test]
fn a_placement_runs_each_stage_where_it_says() {
    // `--device auto`'s placement on a GPU: TV there, fusion on the CPU (no resident blocks, no
    // fusion traffic), with the same fused map as a CPU backend.
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let mut config = ReconstructionConfig::paper(0.1);
    config.grid.truncation_m = 0.8;
    config.tv.iterations = 10;
    let backend = Backend::gpu_for(
        ctx.clone(),
        ResidentOptions::default(),
        denser::backend::GpuStages::MEASURED_FASTER,
    );
    assert_eq!(backend.fusion_device_name(), "CPU");
    let mut rec = Reconstructor::in_memory(config, backend).expect("config");
    let mut cpu = Reconstructor::in_memory(config, Backend::cpu()).expect("config");
    for f in &orbit_frames(3, 0.01) {
        rec.fuse_depth(f).expect("fuse");
        cpu.fuse_depth(f).expect("fuse");
    }
    assert!(rec.resident_stats().is_none(), "fusion stayed on the CPU");
    for b in cpu.layer().indices_sorted() {
        assert!(cpu.layer().get(&b) == rec.layer().get(&b), "block {b:?}");
    }
    let outcome = rec.regularize().expect("tv");
    assert_eq!(outcome.devices.gpu, 1, "{:?}", outcome.devices);
    rec.mesh(denser::mesh::Field::Regularized).expect("mesh");
    let g = rec.gpu_traffic().expect("a GPU backend");
    assert_eq!((g.depth_frames, g.tv_solves, g.meshes), (0, 1, 1));
}

#[test]
fn kernels_are_timed_on_the_device_without_changing_the_counts() {
    let Some(ctx) = gpu() else { return };
    if !ctx.has_kernel_timing() {
        common::skip("kernel timing: the adapter has no timestamp queries");
        assert!(!ctx.start_kernel_timing());
        return;
    }
    let params = TvParams {
        iterations: 70,
        ..TvParams::paper(0.1)
    };
    let problem = random_problem(4);
    // Warm: the context's first write makes its kept staging memory (`src/gpu/upload.rs`).
    solve_gpu(&ctx, &mut problem.clone(), &params).expect("solve");
    let mut untimed = problem.clone();
    let before = ctx.traffic();
    solve_gpu(&ctx, &mut untimed, &params).expect("solve");
    let plain = ctx.traffic().since(before);
    assert!(ctx.kernel_times().0.is_empty(), "not timing yet");

    assert!(ctx.start_kernel_timing());
    let mut timed = problem.clone();
    let before = ctx.traffic();
    solve_gpu(&ctx, &mut timed, &params).expect("solve");
    let counted = ctx.traffic().since(before);
    let (times, missed) = ctx.kernel_times();
    eprintln!("{times:#?}, {missed} untimed; {counted:?}");
    // The same work and the same counts (timing's own waits are not counted), the same result.
    assert_eq!(counted, plain);
    assert_eq!(timed.state().0, untimed.state().0);
    // 70 iterations in two submits (64 + 6): every pass timed, by kernel.
    assert_eq!(missed, 0);
    let names: Vec<&str> = times.iter().map(|t| t.kernel).collect();
    assert_eq!(names, ["tv_dual", "tv_primal"]);
    for t in &times {
        assert_eq!(t.passes, 70, "{t:?}");
        assert!(
            t.median_us >= 0.0 && t.total_ms >= t.median_us / 1e3,
            "{t:?}"
        );
    }
    assert!(times.iter().any(|t| t.total_ms > 0.0), "{times:?}");
    ctx.stop_kernel_timing();
    assert!(ctx.kernel_times().0.is_empty());
}
