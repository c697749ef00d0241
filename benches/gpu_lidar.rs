//! LiDAR fusion on the GPU vs. the CPU: one HDL-64-like scan of the synthetic city (64 beams ×
//! 2000 azimuth steps, default `LidarConfig`) re-fused at 10 cm (μ = 1 m) into a map warmed by
//! the scans of the three frames before it. Settings are fixed: do not modify, or results are
//! not comparable. Both sides include the plan (ray listing and (block, ray) pairs, CPU) and the
//! block checkout; the GPU side adds the f64 → block-local f32 ray preparation, upload, one
//! dispatch per batch, readback and unpacking. The GPU half is skipped (with a message) where no
//! adapter exists; on lavapipe (llvmpipe) the "GPU" is the CPU, so its figure measures wgpu +
//! llvmpipe, not a GPU.
//!
//! - `fuse_lidar/cpu`: `integrate_lidar` (f64 walk, rayon over blocks).
//! - `fuse_lidar/gpu`: `LidarPlan::new` + `integrate_lidar_gpu`.
//! - `fuse_lidar/gpu_resident`: the scan through a `Reconstructor` whose blocks live on the GPU
//!   (`Backend::gpu`, warmed by one call), one scan per call: its blocks listed on the device,
//!   the listing collected (one wait), its (block, ray) pairs and walks made and applied on the
//!   device in the resident pool, the flags read back. What `reconstruct --device gpu` does
//!   per scan without frames in flight.
//! - `fuse_lidar/gpu_in_flight`: the same with frames in flight (the default of `reconstruct`):
//!   each call fuses the scan listed by the call before and records the next scan's listing
//!   into the same submit, so the figure is the steady-state time per scan of scans fused back
//!   to back.
//! - `lidar_walks/host`: the scan's walks prepared on the host (`lidar_pairs_on_cpu`: every
//!   pair's `block_local_ray`, packed), what a resident scan no longer does.
//! - `lidar_walks/gpu`: the same made on the device (`lidar_pairs_on_gpu`, exact f64; its
//!   buffers created per call and read back, so an upper bound of the resident scan's cost).

#[path = "../tests/common/mod.rs"]
mod common;

use common::bench_gpu as gpu;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use denser::backend::Backend;
use denser::frame::LidarScan;
use denser::fusion::{integrate_lidar, LidarFusionParams, LidarPlan};
use denser::fusion::{integrate_lidar_gpu, lidar_pairs_on_cpu, lidar_pairs_on_gpu};
use denser::gpu::ResidentOptions;
use denser::grid::{GridParams, Layer};
use denser::reconstruct::{ReconstructionConfig, Reconstructor};
use denser::store::MemoryStore;
use denser::synth::{City, CityConfig, LidarConfig};
use std::sync::Arc;

/// The warm map and the scan to re-fuse.
fn setup() -> (Layer, LidarScan) {
    let city = City::generate(&CityConfig {
        seed: 9,
        length_m: 260.0,
        ..Default::default()
    })
    .expect("city");
    let poses = city.frame_poses();
    let cfg = LidarConfig::default();
    let mut layer = Layer::new(GridParams::paper(0.1));
    let params = LidarFusionParams::default();
    for (k, pose) in poses.iter().enumerate().take(20).skip(17) {
        let scan = city.scan_lidar(pose, &cfg, k as u64);
        integrate_lidar(&mut layer, &scan, &params);
    }
    (layer, city.scan_lidar(&poses[20], &cfg, 20))
}

fn fuse_lidar(c: &mut Criterion) {
    let (mut layer, scan) = setup();
    let params = LidarFusionParams::default();
    let grid = layer.params();
    let plan = LidarPlan::new(&grid, &scan, &params);
    eprintln!(
        "scan: {} rays, {} (block, ray) pairs, {} blocks; warm map {} blocks",
        plan.ray_count(),
        plan.pair_count(),
        plan.blocks().len(),
        layer.block_count()
    );
    let ctx = gpu().map(Arc::new);
    let mut g = c.benchmark_group("fuse_lidar");
    g.throughput(Throughput::Elements(plan.ray_count() as u64));
    g.sample_size(10);
    g.bench_function("cpu", |b| {
        b.iter(|| integrate_lidar(&mut layer, &scan, &params))
    });
    if let Some(ctx) = &ctx {
        g.bench_function("gpu", |b| {
            b.iter(|| {
                let plan = LidarPlan::new(&grid, &scan, &params);
                integrate_lidar_gpu(ctx, &mut layer, &plan).expect("GPU")
            })
        });
    }
    if let Some(ctx) = &ctx {
        for (name, in_flight) in [("gpu_resident", false), ("gpu_in_flight", true)] {
            let mut on_gpu = resident_reconstructor(ctx, &layer, in_flight);
            on_gpu.fuse_lidar(&scan).expect("warm");
            g.bench_function(name, |b| b.iter(|| on_gpu.fuse_lidar(&scan).expect("GPU")));
            on_gpu.sync().expect("sync");
        }
    }
    g.finish();
    let mut g = c.benchmark_group("lidar_walks");
    g.throughput(Throughput::Elements(plan.pair_count() as u64));
    g.sample_size(10);
    g.bench_function("host", |b| b.iter(|| lidar_pairs_on_cpu(&grid, &plan)));
    if let Some(ctx) = &ctx {
        g.bench_function("gpu", |b| {
            b.iter(|| lidar_pairs_on_gpu(ctx, &grid, &plan).expect("GPU"))
        });
    }
    g.finish();
}

/// A reconstructor over a copy of `layer` whose blocks live on the GPU of `ctx`, fusing scans
/// with frames in flight or not (the paper's LiDAR parameters, 10 cm).
fn resident_reconstructor(
    ctx: &Arc<denser::gpu::GpuContext>,
    layer: &Layer,
    in_flight: bool,
) -> Reconstructor {
    let mut config = ReconstructionConfig::paper(layer.params().voxel_size_m);
    config.grid = layer.params();
    config.lidar_fusion = LidarFusionParams::default();
    let store = Box::new(MemoryStore::from_layer(layer.clone()));
    let backend = Backend::gpu(ctx.clone(), ResidentOptions::default());
    let mut r = Reconstructor::with_store(config, store, backend, 0).expect("reconstructor");
    r.set_frames_in_flight(in_flight).expect("frames in flight");
    r
}

criterion_group!(benches, fuse_lidar);
criterion_main!(benches);
