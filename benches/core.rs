//! Criterion benchmarks of the core stages on the analytic scene (a sphere above a floor, rendered
//! at 640×480 by `tests/common`). Settings are fixed: do not modify, or results are not comparable.

#[path = "../tests/common/mod.rs"]
mod common;

use common::{orbit, vga, Rng, SphereScene};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use denser::fusion::{integrate_depth, integrate_lidar, DepthFusionParams, LidarFusionParams};
use denser::grid::{GridParams, Layer};
use denser::mesh::{extract_mesh, Field};
use denser::regularize::{TvParams, TvProblem};

fn scene_frames() -> Vec<denser::frame::DepthFrame> {
    let scene = SphereScene {
        center: [0.0, 0.0, 0.0],
        radius: 1.0,
        floor_y: 1.0,
    };
    let mut rng = Rng(1);
    orbit(8, 3.0, -1.2, scene.center)
        .into_iter()
        .map(|p| scene.render(&vga(), p, 0.005, 8.0, &mut rng))
        .collect()
}

fn fusion(c: &mut Criterion) {
    let frames = scene_frames();
    let mut g = c.benchmark_group("fuse_depth_640x480");
    g.throughput(Throughput::Elements(1));
    for (voxel, trunc) in [(0.10f32, 0.8f32), (0.05, 0.4)] {
        let grid = GridParams {
            voxel_size_m: voxel,
            truncation_m: trunc,
        };
        // Warm map: all frames fused once, then time re-fusing frame 0 (blocks exist, as mid-drive).
        let mut layer = Layer::new(grid);
        for f in &frames {
            integrate_depth(&mut layer, f, &DepthFusionParams::default());
        }
        g.bench_with_input(
            BenchmarkId::new("voxel_cm", (voxel * 100.0).round() as u32),
            &grid,
            |b, _| {
                b.iter(|| integrate_depth(&mut layer, &frames[0], &DepthFusionParams::default()))
            },
        );
    }
    g.finish();
}

fn lidar(c: &mut Criterion) {
    let scene = SphereScene {
        center: [0.0, 0.0, 0.0],
        radius: 1.0,
        floor_y: 1.0,
    };
    let scan = scene.lidar([-3.0, -0.5, -1.0], 64, 2000, 0.01, &mut Rng(3));
    let grid = GridParams {
        voxel_size_m: 0.1,
        truncation_m: 1.0,
    };
    let mut layer = Layer::new(grid);
    let params = LidarFusionParams {
        min_range_m: 0.5,
        max_range_m: 80.0,
    };
    let mut g = c.benchmark_group("fuse_lidar_hdl64_like");
    g.throughput(Throughput::Elements(scan.points_sensor_m.len() as u64));
    g.bench_function("voxel_10cm", |b| {
        b.iter(|| integrate_lidar(&mut layer, &scan, &params))
    });
    g.finish();
}

fn regularize_and_mesh(c: &mut Criterion) {
    let frames = scene_frames();
    let grid = GridParams {
        voxel_size_m: 0.05,
        truncation_m: 0.4,
    };
    let mut layer = Layer::new(grid);
    for f in &frames {
        integrate_depth(&mut layer, f, &DepthFusionParams::default());
    }
    let blocks = layer.indices_sorted();
    let problem = TvProblem::gather(&layer, &blocks);
    let voxels = problem.omega_count() as u64;
    let params = TvParams {
        iterations: 10,
        ..TvParams::paper(0.1)
    };
    let mut g = c.benchmark_group("regularize");
    g.throughput(Throughput::Elements(voxels * params.iterations as u64));
    g.sample_size(10);
    g.bench_function("tv_10_iterations_voxel_iterations", |b| {
        b.iter_batched(
            || problem.clone(),
            |mut p| p.solve(&params),
            criterion::BatchSize::LargeInput,
        )
    });
    g.finish();
    let mut g = c.benchmark_group("marching_cubes");
    g.throughput(Throughput::Elements(layer.block_count() as u64));
    g.sample_size(10);
    g.bench_function("raw_blocks", |b| {
        b.iter(|| extract_mesh(&layer, Field::Raw, None))
    });
    g.finish();
}

criterion_group!(benches, fusion, lidar, regularize_and_mesh);
criterion_main!(benches);
