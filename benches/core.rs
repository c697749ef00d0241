//! Criterion benchmarks of the core stages on the analytic scene (a sphere above a floor, rendered
//! at 640×480 by `tests/common`), plus the TV regularizer on the problems of issue 14: a dense,
//! all-Ω 128³ volume (the one `tools/bench_skimage_tv.py` gives scikit-image) and the sparse,
//! Ω-masked map of a synthetic LiDAR drive. Settings are fixed: do not modify, or results are
//! not comparable.

#[path = "../tests/common/mod.rs"]
mod common;

use common::{orbit, vga, Rng, SphereScene};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use denser::fusion::{integrate_depth, integrate_lidar, DepthFusionParams, LidarFusionParams};
use denser::fusion::{visible_blocks_by_scan, visible_blocks_in, ViewFrustum};
use denser::grid::{BlockIndex, VOXELS_PER_BLOCK};
use denser::grid::{GridParams, Layer};
use denser::mesh::{extract_mesh, Field};
use denser::regularize::{TvParams, TvProblem};
use denser::synth::{City, CityConfig, LidarConfig};

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

/// splitmix64, as `tools/bench_skimage_tv.py`.
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The dense 128³ problem of `tools/bench_skimage_tv.py` (same formula; computed in f64, stored
/// as f32): a sphere of radius 40 voxels, f = clamp((r − 40)/10, −1, 1) + uniform noise in
/// [−0.1, 0.1), every voxel in Ω with w = 1, as 16³ blocks.
fn dense_tv_volume() -> TvProblem {
    const SIDE: usize = 128;
    let blocks_per_side = (SIDE / 8) as i32;
    let mut blocks = Vec::new();
    for x in 0..blocks_per_side {
        for y in 0..blocks_per_side {
            for z in 0..blocks_per_side {
                blocks.push(BlockIndex([x, y, z]));
            }
        }
    }
    blocks.sort_unstable();
    let n = blocks.len() * VOXELS_PER_BLOCK;
    let mut f = vec![0.0f32; n];
    let c = (SIDE as f64 - 1.0) / 2.0;
    for (k, b) in blocks.iter().enumerate() {
        for i in 0..VOXELS_PER_BLOCK {
            let l = denser::grid::local_coords(i);
            let [x, y, z] = [0, 1, 2].map(|a| b.0[a] as usize * 8 + l[a]);
            let r =
                ((x as f64 - c).powi(2) + (y as f64 - c).powi(2) + (z as f64 - c).powi(2)).sqrt();
            let index = (x + SIDE * (y + SIDE * z)) as u64;
            let noise = (splitmix64(index) >> 40) as f64 / (1u64 << 24) as f64;
            f[k * VOXELS_PER_BLOCK + i] =
                (((r - 40.0) / 10.0).clamp(-1.0, 1.0) + 0.2 * (noise - 0.5)) as f32;
        }
    }
    TvProblem::from_arrays(blocks, f, vec![1.0; n], vec![true; n])
}

/// The dense problem against scikit-image (λ = 0.8 ⇔ its weight 1.25; 50 iterations).
fn tv_dense(c: &mut Criterion) {
    let problem = dense_tv_volume();
    let params = TvParams {
        iterations: 50,
        ..TvParams::paper(0.1)
    };
    let mut solved = problem.clone();
    solved.solve(&params);
    eprintln!(
        "tv_dense_128: {} voxels, energy {:.1} -> {:.1} after {} iterations (λ = {})",
        problem.omega_count(),
        problem.energy(params.lambda),
        solved.energy(params.lambda),
        params.iterations,
        params.lambda
    );
    let mut g = c.benchmark_group("tv_dense_128");
    g.throughput(Throughput::Elements(
        problem.omega_count() as u64 * params.iterations as u64,
    ));
    g.sample_size(10);
    g.bench_function("50_iterations_voxel_iterations", |b| {
        b.iter_batched(
            || problem.clone(),
            |mut p| p.solve(&params),
            criterion::BatchSize::LargeInput,
        )
    });
    // The voxel-by-voxel solver before issue 14 (same bits), side by side.
    g.bench_function("reference_50_iterations_voxel_iterations", |b| {
        b.iter_batched(
            || problem.clone(),
            |mut p| {
                for _ in 0..params.iterations {
                    p.iterate_reference(&params)
                }
            },
            criterion::BatchSize::LargeInput,
        )
    });
    g.finish();
}

/// The sparse, Ω-masked map of a synthetic LiDAR drive: 30 scans of a 260 m city (seed 9) at
/// 10 cm, μ = 1 m; throughput in Ω voxel-iterations, as `denser` reports it.
fn tv_drive(c: &mut Criterion) {
    let city = City::generate(&CityConfig {
        seed: 9,
        length_m: 260.0,
        ..Default::default()
    })
    .expect("city");
    let cfg = LidarConfig::default();
    let mut layer = Layer::new(GridParams::paper(0.1));
    let params = LidarFusionParams::default();
    for (k, pose) in city.frame_poses().iter().enumerate().take(30) {
        let scan = city.scan_lidar(pose, &cfg, k as u64);
        integrate_lidar(&mut layer, &scan, &params);
    }
    let blocks = layer.indices_sorted();
    let problem = TvProblem::gather(&layer, &blocks);
    let tv = TvParams {
        iterations: 10,
        ..TvParams::paper(0.1)
    };
    eprintln!(
        "tv_drive: {} blocks, {} voxels in Ω ({:.0} % of the blocks' voxels)",
        blocks.len(),
        problem.omega_count(),
        100.0 * problem.omega_count() as f64 / (blocks.len() * VOXELS_PER_BLOCK) as f64
    );
    let mut g = c.benchmark_group("tv_drive_lidar_10cm");
    g.throughput(Throughput::Elements(
        problem.omega_count() as u64 * tv.iterations as u64,
    ));
    g.sample_size(10);
    g.bench_function("10_iterations_omega_voxel_iterations", |b| {
        b.iter_batched(
            || problem.clone(),
            |mut p| p.solve(&tv),
            criterion::BatchSize::LargeInput,
        )
    });
    // The voxel-by-voxel solver before issue 14 (same bits), side by side.
    g.bench_function("reference_10_iterations_omega_voxel_iterations", |b| {
        b.iter_batched(
            || problem.clone(),
            |mut p| {
                for _ in 0..tv.iterations {
                    p.iterate_reference(&tv)
                }
            },
            criterion::BatchSize::LargeInput,
        )
    });
    g.finish();
}

/// The allocated blocks in view of a KITTI-sized frame halfway down a 2 km street held in RAM
/// (10 cm voxels; a road slab and two facades, 140 blocks per 0.8 m of street): the layer's
/// every block tested, against the frustum's box of blocks looked up.
fn visible_blocks(c: &mut Criterion) {
    let grid = GridParams::paper(0.1);
    let mut layer = Layer::new(grid);
    for z in 0..2500 {
        for x in -12..13 {
            for y in [2, 3] {
                layer.get_or_allocate(BlockIndex([x, y, z]));
            }
        }
        for x in [-12, -11, -10, 10, 11, 12] {
            for y in -12..3 {
                layer.get_or_allocate(BlockIndex([x, y, z]));
            }
        }
    }
    let frame = denser::frame::DepthFrame {
        intrinsics: denser::camera::PinholeIntrinsics {
            fx: 718.856,
            fy: 718.856,
            cx: 607.19,
            cy: 185.22,
            width: 1241,
            height: 376,
        },
        world_from_camera: nalgebra::Isometry3::translation(0.0, 0.0, 1000.0),
        depth_m: denser::frame::Image::filled(1241, 376, 10.0),
        color: None,
    };
    let frustum = ViewFrustum::new(&frame, &DepthFusionParams::default(), 0.8);
    assert_eq!(
        visible_blocks_in(&layer, &frustum),
        visible_blocks_by_scan(&layer, &frustum)
    );
    let mut g = c.benchmark_group("visible_blocks_2km_street");
    g.bench_function(format!("scan_{}_blocks", layer.block_count()), |b| {
        b.iter(|| visible_blocks_by_scan(&layer, &frustum))
    });
    g.bench_function("frustum_box", |b| {
        b.iter(|| visible_blocks_in(&layer, &frustum))
    });
    g.finish();
}

criterion_group!(
    benches,
    fusion,
    lidar,
    regularize_and_mesh,
    tv_dense,
    tv_drive,
    visible_blocks
);
criterion_main!(benches);
