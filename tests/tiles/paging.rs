//! Out of core on an analytic scene spanning many chunks: fusing through the pager with constant
//! eviction gives bit-identical voxels to fusing in memory (depth maps with revisits, and LiDAR);
//! regional regularization of the stored map equals the global in-memory solve, and without halos
//! it leaves seams; an interrupted regularization resumes to the same result; the tile-by-tile
//! export stitches into the same mesh as a whole-map extraction.

use crate::common;

use common::{orbit, vga, Rng, SphereScene};
use denser::backend::Backend;
use denser::export::{export, Bbox, ExportTarget};
use denser::fusion::{integrate_depth, integrate_lidar, DepthFusionParams, LidarFusionParams};
use denser::grid::{decode_tsdf, BlockIndex, GridParams, Layer};
use denser::map::store::MapStore;
use denser::mesh::{extract_mesh, Field};
use denser::outofcore::pager::{OverrunPolicy, PagerConfig};
use denser::outofcore::regional::{regularize_map, RegionalOptions};
use denser::outofcore::PagedStore;
use denser::reconstruct::{ReconstructionConfig, Reconstructor};
use denser::regularize::{regularize_layer, TvParams};
use denser::store::PagingSummary;

/// 5 cm voxels, chunks of 2³ blocks (0.8 m): the 2 m sphere and its floor span hundreds of chunks.
const CHUNK_BLOCKS: u32 = 2;

pub(crate) fn grid() -> GridParams {
    GridParams {
        voxel_size_m: 0.05,
        truncation_m: 0.2,
    }
}

/// An orbit that comes back to where it started (a loop): 10 views, the last two revisit the first.
fn views() -> Vec<denser::frame::DepthFrame> {
    let scene = SphereScene::standard();
    let mut rng = Rng(7);
    let k = vga();
    let mut poses = orbit(8, 3.0, -1.2, scene.center);
    poses.push(poses[0]);
    poses.push(poses[1]);
    poses
        .into_iter()
        .map(|p| scene.render(&k, p, 0.01, 6.0, &mut rng))
        .collect()
}

pub(crate) fn store_layer(store: &MapStore) -> Layer {
    let mut layer = Layer::new(store.grid());
    for c in store.chunk_indices() {
        let d = store.read_chunk(c).expect("read").expect("present");
        layer.put_blocks(d.blocks);
    }
    layer
}

pub(crate) fn assert_layers_identical(a: &Layer, b: &Layer) {
    assert_eq!(a.indices_sorted(), b.indices_sorted(), "block sets differ");
    for i in a.indices_sorted() {
        assert!(a.get(&i) == b.get(&i), "block {i:?} differs");
    }
}

/// A reconstructor over a new map in `dir` paged within `budget_bytes`, committing every
/// `checkpoint_every` frames, with the stages of `backend`.
fn paged(
    dir: &std::path::Path,
    budget_bytes: u64,
    checkpoint_every: u64,
    backend: Backend,
) -> Reconstructor {
    let store = Box::new(paged_store(dir, budget_bytes));
    Reconstructor::with_store(config(), store, backend, checkpoint_every).expect("reconstructor")
}

/// A store over a new map in `dir` on [`grid`], paged within `budget_bytes` (overruns counted,
/// not refused), regularized in regions of 2³ chunks with the exact halo.
pub(crate) fn paged_store(dir: &std::path::Path, budget_bytes: u64) -> PagedStore {
    let store = MapStore::create(dir, grid(), CHUNK_BLOCKS).expect("create");
    PagedStore::new(
        store,
        PagerConfig {
            budget_bytes,
            overrun: OverrunPolicy::Warn,
            writer_threads: 2,
        },
        RegionalOptions {
            region_chunks: 2,
            budget_bytes: 1 << 30,
            halo_blocks: None,
            sweep_iterations: None,
        },
        denser::export::write_map_surface,
    )
}

/// The paper's settings on [`grid`], with 20 TV iterations.
fn config() -> ReconstructionConfig {
    let mut config = ReconstructionConfig {
        grid: grid(),
        ..ReconstructionConfig::paper(grid().voxel_size_m)
    };
    config.tv.iterations = 20;
    config
}

/// Commits the last frames and returns the map as stored on disk, with the paging counters.
fn finish(mut rec: Reconstructor, dir: &std::path::Path) -> (MapStore, PagingSummary) {
    rec.sync().expect("final checkpoint");
    let stats = rec.summary().paging.expect("paged");
    drop(rec);
    (MapStore::open_read_only(dir).expect("open"), stats)
}

#[test]
fn paged_depth_fusion_is_bit_identical_to_in_memory() {
    let frames = views();
    let params = DepthFusionParams::default();
    let mut mem = Layer::new(grid());
    for f in &frames {
        integrate_depth(&mut mem, f, &params);
    }
    let dir = tempfile::tempdir().expect("tempdir");
    // Budget 0: after every frame, everything but the frame's own working set is evicted.
    let mut rec = paged(&dir.path().join("map"), 0, 3, Backend::cpu());
    for f in &frames {
        rec.fuse_depth(f).expect("fuse");
    }
    let (store, stats) = finish(rec, &dir.path().join("map"));
    println!("{stats:?}; {} chunks", store.chunk_indices().len());
    assert!(
        store.chunk_indices().len() > 100,
        "the scene must span many chunks"
    );
    assert!(
        stats.chunks_evicted > 100 && stats.chunks_read > 50,
        "constant eviction and revisits: {stats:?}"
    );
    assert_eq!(
        stats.budget_overruns,
        frames.len() as u64,
        "a zero budget is overrun on every frame, and says so"
    );
    assert_eq!(
        store.manifest().header.frames_committed,
        frames.len() as u64
    );
    assert_layers_identical(&mem, &store_layer(&store));
    // Reopening from disk gives the same map (after the writer closes it: one writer per map).
    drop(store);
    let reopened = MapStore::open(&dir.path().join("map")).expect("open");
    assert_layers_identical(&mem, &store_layer(&reopened));
}

#[test]
fn paged_lidar_fusion_is_bit_identical_to_in_memory() {
    let scene = SphereScene::standard();
    let mut rng = Rng(3);
    let origins = [
        [-2.5, -0.5, 0.0],
        [0.0, -0.5, -2.5],
        [2.5, -0.5, 0.0],
        [-2.5, -0.5, 0.1],
    ];
    let scans: Vec<_> = origins
        .iter()
        .map(|o| scene.lidar(*o, 32, 720, 0.01, &mut rng))
        .collect();
    let params = LidarFusionParams::default();
    let mut mem = Layer::new(grid());
    for s in &scans {
        integrate_lidar(&mut mem, s, &params);
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut rec = paged(&dir.path().join("map"), 0, 0, Backend::cpu());
    for s in &scans {
        rec.fuse_lidar(s).expect("fuse");
    }
    let (store, stats) = finish(rec, &dir.path().join("map"));
    assert!(stats.chunks_read > 10, "{stats:?}");
    assert_layers_identical(&mem, &store_layer(&store));
}

pub(crate) fn fused_store(dir: &std::path::Path) -> (Layer, MapStore) {
    let frames = views();
    let mut mem = Layer::new(grid());
    for f in &frames[..8] {
        integrate_depth(&mut mem, f, &DepthFusionParams::default());
    }
    let mut store = MapStore::create(dir, grid(), CHUNK_BLOCKS).expect("create");
    for (c, blocks) in denser::map::group_by_chunk(mem.indices_sorted(), CHUNK_BLOCKS) {
        let refs: Vec<(BlockIndex, &denser::grid::Block)> = blocks
            .iter()
            .map(|b| (*b, mem.get(b).expect("block")))
            .collect();
        store.write_chunk(c, &refs, 0).expect("write");
    }
    store.commit().expect("commit");
    (mem, store)
}

pub(crate) fn max_u_difference(a: &Layer, b: &Layer) -> (f32, usize) {
    let mut worst = 0f32;
    let mut n_off = 0;
    for i in a.indices_sorted() {
        let (ba, bb) = (a.get(&i).expect("a"), b.get(&i).expect("b"));
        let (ua, ub) = (
            ba.regularized.as_ref().expect("u in a"),
            bb.regularized.as_ref().expect("u in b"),
        );
        for v in 0..512 {
            let d = (decode_tsdf(ua[v]) - decode_tsdf(ub[v])).abs();
            worst = worst.max(d);
            n_off += (d > 1e-3) as usize;
        }
    }
    (worst, n_off)
}

#[test]
fn regional_regularization_of_the_store_equals_the_global_solve() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (mut mem, mut store) = fused_store(&dir.path().join("map"));
    let params = TvParams {
        iterations: 20,
        ..TvParams::paper(0.05)
    };
    regularize_layer(&mut mem, &params).expect("global");
    let opts = RegionalOptions {
        region_chunks: 1,
        budget_bytes: 1 << 30,
        halo_blocks: None,
        sweep_iterations: None,
    };
    let stats = regularize_map(&mut store, &params, &opts, |_, _| true).expect("regional");
    assert!(stats.regions > 100, "{stats:?}");
    assert_eq!(
        stats.halo_blocks, 3,
        "20 iterations need 21 voxels of halo: 3 blocks"
    );
    let tiled = store_layer(&store);
    let (worst, _) = max_u_difference(&mem, &tiled);
    // u is stored as i16 (step 3.05e-5); the tiled and global solves do the same arithmetic.
    println!("max |u_tiled − u_global| = {worst:e}");
    assert!(
        worst <= 1e-5,
        "tiled result differs from the global solve by {worst}"
    );
    // f, weights, colours and Ω are untouched.
    for i in mem.indices_sorted() {
        let (a, b) = (mem.get(&i).expect("a"), tiled.get(&i).expect("b"));
        assert!(a.tsdf == b.tsdf && a.weight_omega == b.weight_omega && a.color == b.color);
    }

    // Without halos, regions are solved as if evicted neighbours were outside Ω: seams.
    let dir2 = tempfile::tempdir().expect("tempdir");
    let (_, mut store2) = fused_store(&dir2.path().join("map"));
    let opts0 = RegionalOptions {
        halo_blocks: Some(0),
        sweep_iterations: None,
        ..opts
    };
    regularize_map(&mut store2, &params, &opts0, |_, _| true).expect("no halo");
    let (worst0, off0) = max_u_difference(&mem, &store_layer(&store2));
    println!("without halo: max difference {worst0}, {off0} voxels off by > 1e-3");
    assert!(
        worst0 > 1e-2 && off0 > 1000,
        "cutting regions without halos must leave seams"
    );
}

#[test]
fn interrupted_regularization_resumes_to_the_same_result() {
    let params = TvParams {
        iterations: 10,
        ..TvParams::paper(0.05)
    };
    let opts = RegionalOptions {
        region_chunks: 2,
        budget_bytes: 1 << 30,
        halo_blocks: None,
        sweep_iterations: None,
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, mut whole) = fused_store(&dir.path().join("a"));
    regularize_map(&mut whole, &params, &opts, |_, _| true).expect("whole");
    let (_, mut cut) = fused_store(&dir.path().join("b"));
    let first = regularize_map(&mut cut, &params, &opts, |done, _| done < 5).expect("first part");
    assert!(first.interrupted && first.regions == 5, "{first:?}");
    drop(cut);
    let mut reopened = MapStore::open(&dir.path().join("b")).expect("reopen");
    let second = regularize_map(&mut reopened, &params, &opts, |_, _| true).expect("resume");
    assert_eq!(
        second.pass, first.pass,
        "same parameters continue the same pass"
    );
    assert_eq!(second.regions_skipped, 5, "{second:?}");
    assert_layers_identical(&store_layer(&whole), &store_layer(&reopened));
    // Other parameters start a new pass that redoes every region.
    let other = TvParams {
        lambda: 0.3,
        ..params
    };
    let third = regularize_map(&mut reopened, &other, &opts, |_, _| true).expect("new pass");
    assert_eq!((third.pass, third.regions_skipped), (first.pass + 1, 0));
}

fn triangles_by_position(m: &denser::mesh::Mesh) -> Vec<[[u32; 3]; 3]> {
    let mut t: Vec<[[u32; 3]; 3]> = m
        .triangles
        .iter()
        .map(|t| {
            let mut v = t.map(|i| m.positions_m[i as usize].map(f32::to_bits));
            // Rotate so the smallest vertex comes first (keeps the winding).
            let k = (0..3).min_by_key(|&k| v[k]).expect("3");
            v.rotate_left(k);
            v
        })
        .collect();
    t.sort_unstable();
    t
}

#[test]
fn tiled_export_stitches_into_the_whole_map_mesh() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (mut mem, mut store) = fused_store(&dir.path().join("map"));
    let params = TvParams {
        iterations: 10,
        ..TvParams::paper(0.05)
    };
    regularize_layer(&mut mem, &params).expect("global");
    let opts = RegionalOptions {
        region_chunks: 2,
        budget_bytes: 1 << 30,
        halo_blocks: None,
        sweep_iterations: None,
    };
    regularize_map(&mut store, &params, &opts, |_, _| true).expect("regional");
    for field in [Field::Raw, Field::Regularized] {
        let whole = extract_mesh(&mem, field, None);
        let out = dir.path().join(format!("{field:?}.ply"));
        let stats = export(&store, field, None, &ExportTarget::Mesh(out.clone())).expect("export");
        let tiled = denser::io::ply::read_mesh_ply(&out).expect("read back");
        println!("{field:?}: {stats:?}");
        assert!(stats.chunks > 100 && stats.face_keys > 0);
        assert_eq!(
            tiled.positions_m.len(),
            whole.positions_m.len(),
            "no duplicate or missing vertices"
        );
        assert_eq!(tiled.triangles.len(), whole.triangles.len());
        // The same vertices (a vertex exactly on a voxel centre can come from two edges, in both).
        let sorted = |m: &denser::mesh::Mesh| {
            let mut p: Vec<[u32; 3]> = m.positions_m.iter().map(|p| p.map(f32::to_bits)).collect();
            p.sort_unstable();
            p
        };
        assert_eq!(
            sorted(&tiled),
            sorted(&whole),
            "vertices differ from the whole-map mesh"
        );
        assert_eq!(
            triangles_by_position(&tiled),
            triangles_by_position(&whole),
            "same triangles"
        );
    }
    // Points as LAZ (in the z-up world frame, formats/georef.md), within a box given in that
    // frame: every point inside, and as many as the mesh vertices inside it.
    let frame = denser::geo::WorldFrame::local_z_up();
    let bbox = Bbox::parse("-5,-5,-5,0.3,5,5").expect("bbox");
    let laz = dir.path().join("points.laz");
    let st = export(
        &store,
        Field::Regularized,
        Some(bbox),
        &ExportTarget::Points(laz.clone()),
    )
    .expect("points");
    let cloud = denser::io::las::read_point_cloud(&laz).expect("read laz");
    let whole = extract_mesh(&mem, Field::Regularized, None);
    let inside = whole
        .positions_m
        .iter()
        .filter(|p| bbox.contains(frame.to_world([p[0] as f64, p[1] as f64, p[2] as f64])))
        .count();
    assert_eq!(cloud.points_m.len() as u64, st.vertices);
    assert_eq!(cloud.points_m.len(), inside);
    let grown = Bbox {
        min_m: bbox.min_m.map(|v| v - 1e-3),
        max_m: bbox.max_m.map(|v| v + 1e-3),
    };
    assert!(
        cloud.points_m.iter().all(|p| grown.contains(*p)),
        "a point outside the box (LAS keeps 1 mm)"
    );
}

#[test]
fn gpu_tier_paged_fusion_equals_in_memory_gpu_fusion() {
    // device ↔ RAM ↔ disk: depth frames fused into a small GPU pool (spills to RAM, frames too
    // large for it take the batched path) over a pager that evicts everything it can after
    // every frame, with checkpoints and LiDAR scans (per-call GPU kernel) in between. The stored
    // map must equal fusing the same inputs in memory with the per-call GPU kernels (the same
    // per-voxel function), bit for bit.
    use denser::fusion::integrate_lidar_gpu;
    use denser::gpu::resident::SLOT_BYTES;
    use denser::gpu::ResidentOptions;
    let Some(ctx) = common::gpu() else { return };
    let ctx = std::sync::Arc::new(ctx);
    let frames = views();
    let scene = SphereScene::standard();
    let mut rng = Rng(4);
    let scans = [
        scene.lidar([-2.5, -0.5, 0.0], 32, 720, 0.01, &mut rng),
        scene.lidar([0.0, -0.5, -2.5], 32, 720, 0.01, &mut rng),
    ];
    let params = DepthFusionParams::default();
    let lidar = LidarFusionParams::default();
    let mut mem = Layer::new(grid());
    let mut cpu = Layer::new(grid());
    let dir = tempfile::tempdir().expect("tempdir");
    let backend = Backend::gpu(
        ctx.clone(),
        ResidentOptions {
            initial_blocks: 64,
            max_bytes: 1200 * SLOT_BYTES,
        },
    );
    // RAM for about 1800 blocks, the GPU for 1200: both tiers overflow (the largest frames list
    // about 2000 blocks).
    let budget = 8 << 20;
    let mut rec = paged(&dir.path().join("map"), budget, 3, backend);
    for (k, f) in frames.iter().enumerate() {
        common::fuse_depth_gpu(&ctx, &mut mem, f, &params).expect("per call");
        integrate_depth(&mut cpu, f, &params);
        rec.fuse_depth(f).expect("fuse");
        if k == 4 || k == 7 {
            let s = &scans[(k == 7) as usize];
            let plan = denser::fusion::LidarPlan::new(&grid(), s, &lidar);
            integrate_lidar_gpu(&ctx, &mut mem, &plan).expect("per call");
            integrate_lidar(&mut cpu, s, &lidar);
            rec.fuse_lidar(s).expect("lidar");
        }
    }
    let gpu_stats = rec.resident_stats().expect("GPU tier");
    let (store, stats) = finish(rec, &dir.path().join("map"));
    eprintln!("pager {stats:?}\nGPU tier {gpu_stats:?}");
    assert!(
        stats.chunks_evicted > 100 && stats.chunks_read > 50,
        "{stats:?}"
    );
    // Frames larger than the pool went through the batched path after their resident blocks
    // were written back; the others stayed resident (spills are tested in gpu_compare.rs).
    assert!(
        gpu_stats.oversize_frames > 0 && gpu_stats.oversize_frames < frames.len() as u64,
        "{gpu_stats:?}"
    );
    assert!(
        gpu_stats.blocks_uploaded + gpu_stats.blocks_created
            > gpu_stats.peak_resident_blocks as u64
    );
    let stored = store_layer(&store);
    assert_layers_identical(&mem, &stored);
    // And the CPU (f64 LiDAR walk): the same blocks; the voxels within the tolerances of
    // tests/gpu_compare.rs and tests/gpu_lidar.rs.
    assert_eq!(cpu.indices_sorted(), stored.indices_sorted());
    let differ = cpu
        .indices_sorted()
        .iter()
        .filter(|i| cpu.get(i) != stored.get(i))
        .count();
    eprintln!(
        "{differ} of {} blocks differ from CPU fusion",
        cpu.block_count()
    );
}

#[test]
fn paged_gpu_frames_stay_in_flight_and_store_the_map_of_frames_that_wait() {
    // A paged map lets the GPU's depth frames return once submitted: its store settles them
    // (`UpperTier::settle`, all but the newest frame) before chunks leave RAM and before each
    // checkpoint (all), and the GPU's copies of the blocks of chunks that leave RAM come back
    // behind the frames (`UpperTier::release_later`), the chunks held until they do. With a
    // device that keeps up, a frame never waits, and the map on disk is the one of frames
    // that each wait for theirs.
    use denser::gpu::ResidentOptions;
    let Some(ctx) = common::gpu() else { return };
    let ctx = std::sync::Arc::new(ctx);
    let frames = views();
    let dir = tempfile::tempdir().expect("tempdir");
    let checkpoint_every = 4;
    let run = |name: &str, in_flight: bool| {
        let backend = Backend::gpu(ctx.clone(), ResidentOptions::default());
        let path = dir.path().join(name);
        let mut rec = paged(&path, PAGED_GPU_BUDGET, checkpoint_every, backend);
        rec.set_frames_in_flight(in_flight).expect("in flight");
        let mut per_frame = Vec::new();
        for f in &frames {
            // The device keeps up (a real GPU does): the frame before has arrived.
            ctx.wait_idle_uncounted().expect("idle");
            let evicted = |r: &Reconstructor| r.summary().paging.expect("paged").chunks_evicted;
            let (before, evicted_before) = (ctx.traffic(), evicted(&rec));
            rec.fuse_depth(f).expect("fuse");
            per_frame.push((ctx.traffic().since(before), evicted(&rec) > evicted_before));
        }
        let (store, stats) = finish(rec, &path);
        (store_layer(&store), per_frame, stats)
    };
    let (waited, _, waited_stats) = run("waiting", false);
    let (late, per_frame, stats) = run("in_flight", true);
    eprintln!("pager, frames waiting {waited_stats:?}\npager, frames in flight {stats:?}");
    let (mut evicting, mut copied_out, mut copies_came_back) = (0, 0, 0);
    for (k, (t, evicted)) in per_frame.iter().enumerate() {
        eprintln!("frame {k}: evicted {evicted}, {t:?}");
        let checkpoint = (k as u64 + 1).is_multiple_of(checkpoint_every);
        if checkpoint || k < 2 {
            continue; // a checkpoint waits for every frame and copies the dirty blocks back
        }
        // Neither the frame's own submit nor the copies of the blocks whose chunks leave RAM
        // (a second submit, read back by a later frame: more than the flags' few KiB) are
        // waited for.
        assert_eq!(t.waits, 0, "frame {k}: {t:?}");
        assert!(t.submits <= 2, "frame {k}: {t:?}");
        evicting += *evicted as usize;
        copied_out += (t.submits == 2) as usize;
        copies_came_back += (t.readback_bytes > 64 << 10) as usize;
    }
    assert!(
        evicting >= 3 && copied_out >= 2 && copies_came_back >= 1,
        "{evicting} frames evicted, {copied_out} copied blocks out, {copies_came_back} read \
         copies back"
    );
    assert!(stats.chunks_evicted > 20, "{stats:?}");
    assert_layers_identical(&waited, &late);
}

#[test]
fn paged_and_in_memory_gpu_runs_write_the_same_meshes() {
    // The whole run on the GPU, in RAM (TV on the blocks where the GPU holds them) and through
    // a 1 MiB pager (evicted blocks written back behind the frames, TV region by region with
    // the exact halo): the same vertices and triangles in both meshes, raw and regularized (a
    // paged map's mesh is stitched chunk by chunk, so its order differs).
    use denser::gpu::ResidentOptions;
    let Some(ctx) = common::gpu() else { return };
    let ctx = std::sync::Arc::new(ctx);
    let dir = tempfile::tempdir().expect("tempdir");
    let gpu = || Backend::gpu(ctx.clone(), ResidentOptions::default());
    let mut in_memory = Reconstructor::in_memory(config(), gpu()).expect("in memory");
    let mut paged = paged(&dir.path().join("map"), PAGED_GPU_BUDGET, 4, gpu());
    for f in &views() {
        in_memory.fuse_depth(f).expect("fuse in memory");
        paged.fuse_depth(f).expect("fuse paged");
    }
    let (a, b) = (dir.path().join("in_memory"), dir.path().join("paged"));
    in_memory
        .write_results(&a, true, &mut |_, _| true)
        .expect("in memory");
    let results = paged
        .write_results(&b, true, &mut |_, _| true)
        .expect("paged");
    let regions = results.regularize.expect("regularized").summary.regions;
    let evicted = paged.summary().paging.expect("paged").chunks_evicted;
    assert!(
        regions > 10 && evicted > 20,
        "{regions} regions, {evicted} evicted"
    );
    for name in ["mesh_raw.ply", "mesh_regularized.ply"] {
        let read = |d: &std::path::Path| denser::io::ply::read_mesh_ply(d.join(name)).expect(name);
        let (m, p) = (read(&a), read(&b));
        assert!(m.triangles.len() > 1000, "{name}: {}", m.triangles.len());
        let sorted = |m: &denser::mesh::Mesh| {
            let mut v: Vec<([u32; 3], [u8; 3])> = (m.positions_m.iter())
                .zip(&m.colors)
                .map(|(p, c)| (p.map(f32::to_bits), *c))
                .collect();
            v.sort_unstable();
            v
        };
        assert!(sorted(&m) == sorted(&p), "{name}: the vertices differ");
        assert!(
            triangles_by_position(&m) == triangles_by_position(&p),
            "{name}: the triangles differ"
        );
    }
}

/// RAM for the paged GPU runs: some frames evict chunks, others fit.
const PAGED_GPU_BUDGET: u64 = 1 << 20;

#[test]
fn regional_regularization_on_the_gpu_equals_the_global_cpu_solve() {
    use denser::outofcore::regional::regularize_map_with;
    use denser::regularize::solve_gpu;
    let Some(ctx) = common::gpu() else { return };
    // All iterations at once with the exact halo, and sweeps of 7 with the state kept between.
    for sweep_iterations in [None, Some(7)] {
        let dir = tempfile::tempdir().expect("tempdir");
        let (mut mem, mut store) = fused_store(&dir.path().join("map"));
        let params = TvParams {
            iterations: 20,
            ..TvParams::paper(0.05)
        };
        regularize_layer(&mut mem, &params).expect("global");
        let opts = RegionalOptions {
            region_chunks: 4,
            budget_bytes: 1 << 30,
            halo_blocks: None,
            sweep_iterations,
        };
        let mut solves = 0;
        let stats = regularize_map_with(
            &mut store,
            &params,
            &opts,
            |_, _| true,
            |p, params| {
                solves += 1;
                solve_gpu(&ctx, p, params)
            },
        )
        .expect("regional on the GPU");
        assert_eq!(solves, stats.regions * stats.sweeps as usize);
        assert!(stats.regions > 10, "{stats:?}");
        let (worst, _) = max_u_difference(&mem, &store_layer(&store));
        // The GPU TV tolerance (tests/gpu_compare.rs): |Δu| ≤ 1e-4, plus the i16 storage step.
        eprintln!(
            "{} regions on the GPU, {} sweeps: max |u_tiled_gpu − u_global_cpu| = {worst:e}",
            stats.regions, stats.sweeps
        );
        assert!(worst <= 1.5e-4, "{worst}");
    }
}
