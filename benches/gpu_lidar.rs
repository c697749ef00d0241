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
//! - `lidar_walks/host`: the scan's walks prepared on the host (`lidar_pairs_on_cpu`: every
//!   pair's `block_local_ray`, packed), what a resident scan no longer does.
//! - `lidar_walks/gpu`: the same made on the device (`lidar_pairs_on_gpu`, exact f64; its
//!   buffers created per call and read back, so an upper bound of the resident scan's cost).

#[path = "../tests/common/mod.rs"]
mod common;

use common::bench_gpu as gpu;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use denser::frame::LidarScan;
use denser::fusion::{integrate_lidar, LidarFusionParams, LidarPlan};
use denser::fusion::{integrate_lidar_gpu, lidar_pairs_on_cpu, lidar_pairs_on_gpu};
use denser::grid::{GridParams, Layer};
use denser::synth::{City, CityConfig, LidarConfig};

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
    let ctx = gpu();
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

criterion_group!(benches, fuse_lidar);
criterion_main!(benches);
