//! k-d tree throughput of the evaluation: building the ground-truth index over ~1M points and
//! nearest-neighbour queries (points/s), as `denser evaluate` runs them.
//!
//! Scene (do not modify, or results are not comparable): ground truth = 1 048 576 points on a
//! 1024 × 1024 grid with 5 cm spacing on a gently curved surface at UTM-like coordinates
//! (500 km, 5000 km); queries = 100 000 points scattered 0–2 cm ("near"), 0–20 cm ("above") or
//! 0–2 m ("far", as a raw surface's floaters lie from LiDAR) above that surface. The cost of a
//! query grows with its distance relative to the point spacing, so all three are measured.
//!
//! Run: `cargo bench --bench eval_nn`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use denser::eval::GroundTruthIndex;
use std::hint::black_box;

const ORIGIN: [f64; 3] = [500_000.0, 30.0, 5_000_000.0];

fn height(x: f64, z: f64) -> f64 {
    0.5 * (x * 0.1).sin() + 0.3 * (z * 0.07).cos()
}

fn ground_truth() -> Vec<[f64; 3]> {
    let mut pts = Vec::with_capacity(1024 * 1024);
    for i in 0..1024 {
        for k in 0..1024 {
            let (x, z) = (i as f64 * 0.05, k as f64 * 0.05);
            pts.push([ORIGIN[0] + x, ORIGIN[1] + height(x, z), ORIGIN[2] + z]);
        }
    }
    pts
}

fn queries(n: usize, max_offset_m: f64) -> Vec<[f64; 3]> {
    let mut s = 42u64;
    let mut next = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n)
        .map(|_| {
            let (x, z) = (next() * 51.2, next() * 51.2);
            [
                ORIGIN[0] + x,
                ORIGIN[1] + height(x, z) + max_offset_m * next(),
                ORIGIN[2] + z,
            ]
        })
        .collect()
}

fn bench_nn(c: &mut Criterion) {
    let gt = ground_truth();

    let mut build = c.benchmark_group("eval_nn_build");
    build.sample_size(10);
    build.throughput(Throughput::Elements(gt.len() as u64));
    build.bench_function("ground_truth_index_1M", |b| {
        b.iter(|| GroundTruthIndex::from_points(black_box(&gt)).unwrap())
    });
    build.finish();

    let index = GroundTruthIndex::from_points(&gt).unwrap();
    let mut query = c.benchmark_group("eval_nn_query");
    query.sample_size(10);
    for (name, max_offset_m) in [
        ("near_0-2cm", 0.02),
        ("above_0-20cm", 0.2),
        ("far_0-2m", 2.0),
    ] {
        let q = queries(100_000, max_offset_m);
        query.throughput(Throughput::Elements(q.len() as u64));
        query.bench_with_input(BenchmarkId::new("nearest_one_1M_gt", name), &q, |b, q| {
            b.iter(|| index.nearest_distances_m(black_box(q)).unwrap())
        });
    }
    query.finish();
}

criterion_group!(benches, bench_nn);
criterion_main!(benches);
