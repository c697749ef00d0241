//! Rendering throughput of the synthetic city at KITTI resolution (1241×376).
//!
//! Fixed scene, do not modify or results are not comparable: seed 7, procedural route of 400 m,
//! frame 40, default `RenderOptions` (shadows on, 1 ray per pixel), default HDL-64E-like LiDAR.
//! `cargo bench --bench synth_render`

use criterion::{criterion_group, criterion_main, Criterion};
use denser::synth::{City, CityConfig, LidarConfig, RenderOptions, StereoRig};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let city = City::generate(&CityConfig {
        seed: 7,
        length_m: 400.0,
        ..Default::default()
    })
    .expect("city");
    let pose = city.frame_poses()[40];
    let rig = StereoRig::kitti();
    let opts = RenderOptions::default();
    let lidar = LidarConfig::default();
    let mut g = c.benchmark_group("synth");
    g.sample_size(10);
    g.bench_function("stereo_pair_1241x376_with_depth", |b| {
        b.iter(|| black_box(city.render_stereo(&pose, &rig, &opts, 1)))
    });
    g.bench_function("lidar_hdl64_scan", |b| {
        b.iter(|| black_box(city.scan_lidar(&pose, &lidar, 1)))
    });
    g.bench_function("frame_stereo_plus_lidar", |b| {
        b.iter(|| {
            let f = city.render_stereo(&pose, &rig, &opts, 1);
            let s = city.scan_lidar(&pose, &lidar, 1);
            black_box((f, s))
        })
    });
    g.bench_function("city_build_400m", |b| {
        b.iter(|| {
            black_box(
                City::generate(&CityConfig {
                    seed: 7,
                    length_m: 400.0,
                    ..Default::default()
                })
                .expect("city"),
            )
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
