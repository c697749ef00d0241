//! GPU kernels vs. their CPU twins (issue 6), on the analytic sphere scene of `benches/core.rs`.
//! Settings are fixed: do not modify, or results are not comparable. The GPU half is skipped
//! (with a message) where no adapter exists. On lavapipe (llvmpipe) the "GPU" is the CPU, so
//! those figures measure wgpu + llvmpipe overhead, not a GPU.
//!
//! - `tv_10_iterations/{cpu,gpu}`: 10 Chambolle–Pock iterations over every block of the fused
//!   map at 5 cm (GPU: upload, 20 dispatches, readback of u, ū, p).
//! - `tv_10_iterations/gpu_resident`: the same solve over the blocks resident on the GPU
//!   (`regularize_resident`: the problem made on the device from the pool, 10 iterations, the
//!   stored result, 2 bytes per voxel, read back into the layer).
//! - `fuse_depth_640x480/{cpu,gpu}`: re-fusing frame 0 into the warm 5 cm map (GPU: pack, upload,
//!   one dispatch, readback, unpack; block listing on the CPU in both).
//! - `fuse_depth_640x480/gpu_resident`: the same with the blocks resident on the GPU
//!   (`ResidentMap`, warmed by one call: block listing on the CPU, depth image upload, hash
//!   lookup + fusion dispatch, readback of one flag per block; no voxel traffic).
//! - `fuse_depth_640x480/gpu_in_flight`: the same with frames in flight
//!   (`ResidentMap::set_frames_in_flight`): a frame returns once submitted and its flags are
//!   collected by a later one, so the figure is the steady-state time per frame of frames
//!   submitted back to back (the readback ring holds three; a fourth waits for the first).
//! - `band_listing_1241x376/{cpu,gpu_blocks}`: a KITTI-sized street frame's band blocks at
//!   10 cm (`tests/gpu/street.rs`): listed on the CPU from the depths (`depth_frame_blocks`),
//!   or on the GPU (the depths uploaded, the slices made and the blocks listed there, 4 bytes
//!   per block read back, `band_blocks_on_gpu`; a device with f64 only) and their set made on
//!   the host (`DeviceBand::blocks`): the host's listing step against the device's.
//! - `host_share_1241x376/*`: what the host still does per frame of the GPU tier, on the host
//!   alone (no device needed): a street frame at 10 cm after four frames fused at 1 m steps;
//!   `visible_blocks` (the layer's allocated blocks in view, `visible_blocks_in`),
//!   `band_and_visible` (those merged with the band, `DepthPlan::blocks_with`), `frame_keys`
//!   (the listed blocks packed as 4-byte offsets, `FrameKeys::new`), `table_lookups` (each
//!   listed block looked up in the host's mirror of the GPU hash table), `table_inserts` (the
//!   listed blocks new to the map inserted into it by the host) and `device_inserts_applied`
//!   (the same blocks' entries, given by an allocation on the device, applied to it:
//!   `DeviceAllocation::apply_to`).
//! - `marching_cubes/{cpu,gpu}`: the raw field of the fused 5 cm map meshed whole (GPU: the
//!   samples packed and uploaded, five passes, the mesh read back and joined; the same mesh).
//! - `marching_cubes/gpu_resident`: the same with the blocks resident on the GPU (the samples
//!   made there from the pool: `SampleSource::Resident`).

#[path = "../tests/common/mod.rs"]
mod common;
#[path = "../tests/gpu/street.rs"]
mod street;

use common::bench_gpu as gpu;

use common::{fuse_depth_gpu, fuse_depth_resident};
use common::{orbit, vga, Rng, SphereScene};
use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use denser::fusion::{integrate_depth, DepthFusionParams};
use denser::gpu::{ResidentMap, ResidentOptions};
use denser::grid::{GridParams, Layer};
use denser::mesh::SampleSource;
use denser::mesh::{extract_mesh_gpu, extract_mesh_gpu_from, extract_mesh_keyed, Field, GpuMesher};
use denser::regularize::{regularize_resident, solve_gpu};
use denser::regularize::{TvParams, TvProblem};
use std::sync::Arc;

fn scene_layer() -> (Layer, Vec<denser::frame::DepthFrame>) {
    let scene = SphereScene::standard();
    let mut rng = Rng(1);
    let frames: Vec<_> = orbit(8, 3.0, -1.2, scene.center)
        .into_iter()
        .map(|p| scene.render(&vga(), p, 0.005, 8.0, &mut rng))
        .collect();
    let grid = GridParams {
        voxel_size_m: 0.05,
        truncation_m: 0.4,
    };
    let mut layer = Layer::new(grid);
    for f in &frames {
        integrate_depth(&mut layer, f, &DepthFusionParams::default());
    }
    (layer, frames)
}

fn tv(c: &mut Criterion) {
    let (layer, _) = scene_layer();
    let problem = TvProblem::gather(&layer, &layer.indices_sorted());
    let params = TvParams {
        iterations: 10,
        ..TvParams::paper(0.1)
    };
    let ctx = gpu();
    let mut g = c.benchmark_group("tv_10_iterations");
    g.throughput(Throughput::Elements(
        problem.omega_count() as u64 * params.iterations as u64,
    ));
    g.sample_size(10);
    g.bench_function("cpu", |b| {
        b.iter_batched(
            || problem.clone(),
            |mut p| p.solve(&params),
            criterion::BatchSize::LargeInput,
        )
    });
    if let Some(ctx) = ctx {
        g.bench_function("gpu", |b| {
            b.iter_batched(
                || problem.clone(),
                |mut p| solve_gpu(&ctx, &mut p, &params).expect("GPU solve"),
                criterion::BatchSize::LargeInput,
            )
        });
        let (mut map, mut layer) = resident(Arc::new(ctx), &layer);
        g.bench_function("gpu_resident", |b| {
            b.iter(|| {
                regularize_resident(&mut map, &mut layer, &params)
                    .expect("GPU solve")
                    .expect("the map fits the pool")
            })
        });
    }
    g.finish();
}

/// A copy of `layer` with every block resident on the GPU (brought up by a first TV solve of
/// one iteration).
fn resident(ctx: Arc<denser::gpu::GpuContext>, layer: &Layer) -> (ResidentMap, Layer) {
    let mut map = ResidentMap::new(ctx, layer.params(), ResidentOptions::default()).expect("pool");
    let mut layer = layer.clone();
    let one = TvParams {
        iterations: 1,
        ..TvParams::paper(0.1)
    };
    regularize_resident(&mut map, &mut layer, &one)
        .expect("GPU solve")
        .expect("the map fits the pool");
    (map, layer)
}

fn fusion(c: &mut Criterion) {
    let (mut layer, frames) = scene_layer();
    let ctx = gpu();
    let params = DepthFusionParams::default();
    let mut g = c.benchmark_group("fuse_depth_640x480");
    g.throughput(Throughput::Elements(1));
    g.sample_size(10);
    g.bench_function("cpu", |b| {
        b.iter(|| integrate_depth(&mut layer, &frames[0], &params))
    });
    if let Some(ctx) = ctx {
        g.bench_function("gpu", |b| {
            b.iter(|| fuse_depth_gpu(&ctx, &mut layer, &frames[0], &params).expect("GPU"))
        });
        let ctx = Arc::new(ctx);
        let mut map =
            ResidentMap::new(ctx, layer.params(), ResidentOptions::default()).expect("pool");
        fuse_depth_resident(&mut map, &mut layer, &frames[0], &params).expect("warm");
        g.bench_function("gpu_resident", |b| {
            b.iter(|| fuse_depth_resident(&mut map, &mut layer, &frames[0], &params).expect("GPU"))
        });
        map.set_frames_in_flight(true);
        g.bench_function("gpu_in_flight", |b| {
            b.iter(|| fuse_depth_resident(&mut map, &mut layer, &frames[0], &params).expect("GPU"))
        });
        map.sync(&mut layer).expect("sync");
    }
    g.finish();
}

fn band_listing(c: &mut Criterion) {
    use denser::fusion::{band_blocks_on_gpu, depth_frame_blocks};
    let frame = street::street_frame(0.0, 0);
    let grid = GridParams::paper(0.1);
    let params = DepthFusionParams::default();
    let ctx = gpu();
    let mut g = c.benchmark_group("band_listing_1241x376");
    g.throughput(Throughput::Elements(1));
    g.sample_size(10);
    g.bench_function("cpu", |b| {
        b.iter(|| depth_frame_blocks(&grid, &frame, &params))
    });
    match ctx {
        Some(ctx) if ctx.has_f64() => {
            let (k, pose) = (&frame.intrinsics, &frame.world_from_camera);
            g.bench_function("gpu_blocks", |b| {
                b.iter(|| {
                    let band = band_blocks_on_gpu(&ctx, &grid, &frame, &params).expect("GPU");
                    band.expect("f64").blocks(&grid, k, pose, &params)
                })
            });
            // The host's share of a band listed on the device: the blocks read back (and the
            // slices the device left) made the sorted band, with the device idle.
            let band = band_blocks_on_gpu(&ctx, &grid, &frame, &params).expect("GPU");
            let band = band.expect("f64");
            g.bench_function("gpu_blocks_host_share", |b| {
                b.iter(|| band.blocks(&grid, k, pose, &params))
            });
        }
        Some(ctx) => eprintln!(
            "SKIPPED band_listing_1241x376/gpu_blocks: {} has no f64",
            ctx.name()
        ),
        None => {}
    }
    g.finish();
}

fn marching_cubes(c: &mut Criterion) {
    let (layer, _) = scene_layer();
    let ctx = gpu();
    let mut g = c.benchmark_group("marching_cubes");
    g.throughput(Throughput::Elements(layer.block_count() as u64));
    g.sample_size(10);
    g.bench_function("cpu", |b| {
        b.iter(|| extract_mesh_keyed(&layer, Field::Raw, None))
    });
    if let Some(ctx) = ctx {
        g.bench_function("gpu", |b| {
            b.iter(|| extract_mesh_gpu(&ctx, &layer, Field::Raw, None).expect("GPU"))
        });
        let ctx = Arc::new(ctx);
        // A mesher keeping its buffers from mesh to mesh, as `reconstruct` and `export` mesh.
        let mesher = GpuMesher::new(ctx.clone());
        g.bench_function("gpu_kept", |b| {
            b.iter(|| {
                mesher
                    .mesh(&layer, Field::Raw, None, SampleSource::Layer)
                    .expect("GPU")
            })
        });
        let (map, layer) = resident(ctx.clone(), &layer);
        g.bench_function("gpu_resident", |b| {
            b.iter(|| {
                let source = SampleSource::Resident(&map);
                extract_mesh_gpu_from(&ctx, &layer, Field::Raw, None, source).expect("GPU")
            })
        });
        g.bench_function("gpu_resident_kept", |b| {
            b.iter(|| {
                let source = SampleSource::Resident(&map);
                mesher.mesh(&layer, Field::Raw, None, source).expect("GPU")
            })
        });
    }
    g.finish();
}

/// The host's share of a resident depth frame on the GPU, with no device: what the host still
/// does per frame once the band is listed on the device.
fn host_share(c: &mut Criterion) {
    use denser::fusion::{DepthPlan, FrameKeys};
    use denser::gpu::resident::alloc::allocate_on_cpu;
    use denser::gpu::resident::BlockTable;
    use denser::grid::BlockIndex;
    let grid = GridParams::paper(0.1);
    let params = DepthFusionParams::default();
    let mut layer = Layer::new(grid);
    for i in 0..4 {
        integrate_depth(&mut layer, &street::street_frame(i as f64, i), &params);
    }
    let frame = street::street_frame(4.0, 4);
    let plan = DepthPlan::new(&grid, &frame, &params);
    let blocks = plan.blocks_with(&layer, &[]);
    let mut table = BlockTable::for_blocks(layer.block_count() as u32 * 2);
    for (slot, (b, _)) in layer.iter_unsorted().enumerate() {
        table.insert(*b, slot as u32);
    }
    eprintln!(
        "layer {} blocks in {} tiles, band {}, listed {}",
        layer.block_count(),
        layer.tile_count(),
        plan.band.len(),
        blocks.len()
    );
    let mut g = c.benchmark_group("host_share_1241x376");
    g.sample_size(20);
    g.bench_function("visible_blocks", |b| {
        b.iter(|| denser::fusion::visible_blocks_in(&layer, &plan.frustum))
    });
    g.bench_function("band_and_visible", |b| {
        b.iter(|| plan.blocks_with(&layer, &[]))
    });
    g.bench_function("frame_keys", |b| {
        b.iter(|| FrameKeys::new(&grid, &plan.geometry, &blocks, blocks.len()).unwrap())
    });
    g.bench_function("table_lookups", |b| {
        b.iter(|| blocks.iter().filter_map(|k| table.lookup(*k)).count())
    });
    // The listed blocks new to the map: the host inserts them into its table today; with the
    // allocation on the device, it applies the entries the device gave them.
    let fresh: Vec<BlockIndex> = (blocks.iter().copied())
        .filter(|k| table.lookup(*k).is_none())
        .collect();
    let first_free = table.len() as u32;
    let mut free: Vec<u32> = (first_free..first_free + fresh.len() as u32)
        .rev()
        .collect();
    let mut allocated = table.clone();
    let device = allocate_on_cpu(&mut allocated, &mut free, &fresh, fresh.len());
    eprintln!("{} listed blocks new to the map", fresh.len());
    g.bench_function("table_inserts", |b| {
        b.iter_batched_ref(
            || table.clone(),
            |t| (fresh.iter().enumerate()).for_each(|(i, k)| t.insert(*k, first_free + i as u32)),
            BatchSize::LargeInput,
        )
    });
    g.bench_function("device_inserts_applied", |b| {
        b.iter_batched_ref(
            || table.clone(),
            |t| device.apply_to(t, &fresh),
            BatchSize::LargeInput,
        )
    });
    g.finish();
}

criterion_group!(
    benches,
    tv,
    fusion,
    band_listing,
    marching_cubes,
    host_share
);
criterion_main!(benches);
