//! TV and meshing over the blocks resident on the GPU (issue 34 items 4 and 5).
//!
//! TV (`denser::regularize::regularize_resident`): the problem made on the device from the pool
//! and the hash table equals the one the host gathers, so the result equals the gathered GPU
//! solve's bit for bit (the same kernels on the same arrays) and the CPU's within the GPU's
//! tolerance (`compare.rs`: 4 steps of i16); only new blocks go up, and the stored result,
//! 2 bytes per voxel, comes down in one submit. Marching cubes (`SampleSource::Resident`): the
//! samples made from the pool equal the host's packing, so the mesh is the same.

use crate::common::{fuse_depth_resident, gpu, orbit, reconstructor_over, vga, Rng, SphereScene};
use crate::compare::worst_u_step;
use denser::backend::Backend;
use denser::fusion::DepthFusionParams;
use denser::gpu::{ResidentMap, ResidentOptions};
use denser::grid::{BlockIndex, GridParams, Layer, VOXELS_PER_BLOCK};
use denser::mesh::{extract_mesh_gpu, extract_mesh_gpu_from, Field, GpuMesher, SampleSource};
use denser::regularize::{regularize_layer, regularize_layer_gpu, regularize_resident, TvParams};
use std::sync::Arc;

/// The grid of every test here: 5 cm voxels.
const GRID: GridParams = GridParams {
    voxel_size_m: 0.05,
    truncation_m: 0.4,
};

/// The sphere scene fused into a resident map that starts small (so it grows) over `layer`.
fn fused_resident(ctx: &Arc<denser::gpu::GpuContext>, grid: GridParams) -> (ResidentMap, Layer) {
    let options = ResidentOptions {
        initial_blocks: 64,
        ..ResidentOptions::default()
    };
    let mut map = ResidentMap::new(ctx.clone(), grid, options).expect("pool");
    let mut layer = Layer::new(grid);
    let scene = SphereScene::standard();
    let mut rng = Rng(5);
    for pose in orbit(5, 3.0, -1.2, scene.center) {
        let frame = scene.render(&vga(), pose, 0.01, 6.0, &mut rng);
        fuse_depth_resident(&mut map, &mut layer, &frame, &DepthFusionParams::default())
            .expect("resident fusion");
    }
    (map, layer)
}

#[test]
fn tv_over_the_resident_blocks_equals_the_gathered_solve() {
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let grid = GRID;
    let params = TvParams::paper(0.05);
    for flushed_share in [0usize, 3] {
        let (mut map, mut layer) = fused_resident(&ctx, grid);
        // The host's copy, current: what the gathered solves start from.
        map.sync(&mut layer).expect("sync");
        let blocks = layer.indices_sorted();
        // Some blocks back in RAM only: the solve must bring them up again, and only them.
        let flushed: Vec<BlockIndex> = blocks
            .iter()
            .copied()
            .enumerate()
            .filter(|(k, _)| flushed_share > 0 && k % flushed_share == 0)
            .map(|(_, b)| b)
            .collect();
        map.flush_blocks(&mut layer, &flushed).expect("flush");
        let (mut on_cpu, mut gathered) = (layer.clone(), layer.clone());
        let (_, cpu_stats) = regularize_layer(&mut on_cpu, &params).expect("CPU");
        regularize_layer_gpu(&ctx, &mut gathered, &params).expect("gathered GPU solve");

        let before = ctx.traffic();
        let (touched, stats) = regularize_resident(&mut map, &mut layer, &params)
            .expect("resident solve")
            .expect("the layer fits the pool");
        let t = ctx.traffic().since(before);

        assert_eq!(touched, blocks);
        assert_eq!(stats.omega_voxels, cpu_stats.omega_voxels);
        assert_eq!(stats.energy, None);
        assert_eq!(
            map.resident_blocks(),
            blocks,
            "every block resident after the solve"
        );
        assert_eq!(worst_u_step(&layer, &gathered, &blocks), 0);
        let worst = worst_u_step(&layer, &on_cpu, &blocks);
        let voxels = (blocks.len() * VOXELS_PER_BLOCK) as u64;
        eprintln!(
            "{} blocks ({} flushed), {} Ω voxels: worst |Δu| against the CPU {worst} steps; \
             {t:?}",
            blocks.len(),
            flushed.len(),
            stats.omega_voxels
        );
        assert!(worst <= 4, "{worst} steps");
        assert!(stats.omega_voxels > 50_000);
        // Up: the flushed blocks (4 KiB each), their table entries and the uniforms.
        let new_blocks = flushed.len() as u64;
        assert!(
            t.upload_bytes <= new_blocks * (4096 + 16) + (64 << 10),
            "{t:?} with {new_blocks} blocks brought up"
        );
        // Down: the stored result (2 bytes per voxel), the keys and two counters.
        assert!(
            t.readback_bytes <= 2 * voxels + 16 * blocks.len() as u64 + 64,
            "{t:?}"
        );
        assert_eq!((t.submits, t.waits), (1, 1), "{t:?}");

        // A second solve, on the same blocks: nothing uploaded but uniforms.
        let before = ctx.traffic();
        regularize_resident(&mut map, &mut layer, &params)
            .expect("second solve")
            .expect("fits");
        let t = ctx.traffic().since(before);
        assert!(t.upload_bytes <= 1024, "{t:?}");
        assert_eq!(worst_u_step(&layer, &gathered, &blocks), 0);
    }
}

#[test]
fn tv_over_the_resident_blocks_declines_what_it_cannot_hold() {
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let grid = GRID;
    let params = TvParams::paper(0.05);
    let (map, mut layer) = fused_resident(&ctx, grid);
    let max_blocks = layer.block_count() as u64 - 1;
    // A pool too small for the layer: declined, nothing changed.
    let options = ResidentOptions {
        initial_blocks: 16,
        max_bytes: max_blocks * denser::gpu::resident::SLOT_BYTES,
    };
    drop(map);
    let mut small = ResidentMap::new(ctx.clone(), grid, options).expect("pool");
    let untouched = layer.clone();
    let declined = regularize_resident(&mut small, &mut layer, &params).expect("no error");
    assert!(declined.is_none());
    assert_eq!(layer.indices_sorted(), untouched.indices_sorted());
    assert!(layer
        .iter_unsorted()
        .all(|(k, b)| b.regularized.is_none() && Some(b) == untouched.get(k)));
}

#[test]
fn a_gpu_run_regularizes_its_resident_blocks_in_place() {
    // The reconstructor's own path: fused on the GPU, then regularized where the blocks are
    // (one GPU solve, no gathered problem), equal to the CPU run within the tolerance.
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let grid = GRID;
    let mut config = denser::reconstruct::ReconstructionConfig::paper(0.05);
    config.grid = grid;
    let mut on_gpu = reconstructor_over(
        config,
        Layer::new(grid),
        Backend::gpu(ctx.clone(), ResidentOptions::default()),
    );
    let mut on_cpu = reconstructor_over(config, Layer::new(grid), Backend::cpu());
    let scene = SphereScene::standard();
    let mut rng = Rng(5);
    for pose in orbit(4, 3.0, -1.2, scene.center) {
        let frame = scene.render(&vga(), pose, 0.01, 6.0, &mut rng);
        on_gpu.fuse_depth(&frame).expect("GPU frame");
        on_cpu.fuse_depth(&frame).expect("CPU frame");
    }
    let (g, c) = (
        on_gpu.regularize().expect("GPU"),
        on_cpu.regularize().expect("CPU"),
    );
    assert_eq!((g.devices.gpu, g.devices.cpu), (1, 0), "{:?}", g.devices);
    assert_eq!(g.summary.energy, None, "no problem gathered on the host");
    assert_eq!(g.summary.omega_voxels, c.summary.omega_voxels);
    let (lg, lc) = (on_gpu.layer(), on_cpu.layer());
    let blocks = lc.indices_sorted();
    assert_eq!(lg.indices_sorted(), blocks);
    let worst = worst_u_step(lg, lc, &blocks);
    eprintln!("{} blocks: worst |Δu| {worst} steps", blocks.len());
    assert!(worst <= 4, "{worst} steps");
}

#[test]
fn marching_cubes_from_the_resident_pool_equals_the_uploaded_samples() {
    // The mesher's samples made on the device from the pool (`SampleSource::Resident`) are the
    // host's packing bit for bit, so the meshes are the same values; only slots (and, for the
    // regularized field, its 2-byte values) go up. A batch with a block not resident falls
    // back to the host's packing.
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let grid = GRID;
    let (mut map, mut layer) = fused_resident(&ctx, grid);
    map.sync(&mut layer).expect("sync");
    regularize_resident(&mut map, &mut layer, &TvParams::paper(0.05))
        .expect("TV")
        .expect("fits");
    let blocks = layer.block_count() as u64;
    for (field, most_per_block) in [(Field::Raw, 256u64), (Field::Regularized, 1024 + 256)] {
        let before = ctx.traffic();
        let host = extract_mesh_gpu(&ctx, &layer, field, None).expect("host samples");
        let packed = ctx.traffic().since(before);
        let before = ctx.traffic();
        let source = SampleSource::Resident(&map);
        let device = extract_mesh_gpu_from(&ctx, &layer, field, None, source).expect("pool");
        let t = ctx.traffic().since(before);
        eprintln!(
            "{field:?}, {blocks} blocks, {} triangles: up {} B packed, {} B from the pool",
            host.0.triangles.len(),
            packed.upload_bytes,
            t.upload_bytes
        );
        assert!(!host.0.triangles.is_empty());
        assert_eq!(device, host, "{field:?}");
        assert!(packed.upload_bytes >= 4096 * blocks, "{packed:?}");
        assert!(
            t.upload_bytes <= most_per_block * blocks + (64 << 10),
            "{t:?}"
        );
    }
    // A kept mesher (issue 34): its meshes from the pool after its first create no buffer,
    // only the bind group over the pool (not kept: a grow of the tier replaces the pool).
    let mesher = GpuMesher::new(ctx.clone());
    let source = SampleSource::Resident(&map);
    let first = mesher
        .mesh(&layer, Field::Regularized, None, source)
        .expect("first");
    let before = ctx.traffic();
    let again = mesher
        .mesh(&layer, Field::Regularized, None, source)
        .expect("again");
    let t = ctx.traffic().since(before);
    assert_eq!(again, first);
    let created = (t.buffers_created, t.bind_groups_created);
    assert_eq!((created, t.submits, t.waits), ((0, 1), 3, 3), "{t:?}");
    // One block back in RAM only: its batch's samples are packed on the host, the same mesh.
    let first = layer.indices_sorted()[0];
    map.flush_blocks(&mut layer, &[first]).expect("flush");
    let host = extract_mesh_gpu(&ctx, &layer, Field::Raw, None).expect("host samples");
    let mixed = extract_mesh_gpu_from(&ctx, &layer, Field::Raw, None, SampleSource::Resident(&map))
        .expect("mixed");
    assert_eq!(mixed, host);
}
