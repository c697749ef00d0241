//! Census + SGM on a KITTI-sized pair: 1241×376, 128 disparities, default parameters, random
//! texture with a slanted-plane disparity (5–60 px). Do not modify the scene or parameters, or
//! results are not comparable across runs.
use criterion::{criterion_group, criterion_main, Criterion};
use denser::depth::sgm::{SgmMatcher, SgmParams};
use denser::depth::DisparityEstimator;
use std::hint::black_box;

#[path = "../tests/depth_support/mod.rs"]
mod depth_support;

fn bench_sgm(c: &mut Criterion) {
    let (left, right, _) = depth_support::planar_pair(1241, 376, 5.0, 0.03, 0.05, 1);
    let matcher = SgmMatcher::new(SgmParams {
        num_disparities: 128,
        ..SgmParams::default()
    })
    .expect("valid parameters");
    let mut group = c.benchmark_group("depth_sgm");
    group.sample_size(10);
    group.bench_function("sgm_1241x376_128d", |b| {
        b.iter(|| {
            matcher
                .estimate(black_box(&left), black_box(&right))
                .expect("matching succeeds")
        })
    });
    let volume = matcher.cost_volume(&left, &right).expect("cost volume");
    group.bench_function("census_cost_volume_1241x376_128d", |b| {
        b.iter(|| {
            matcher
                .cost_volume(black_box(&left), black_box(&right))
                .expect("cost volume")
        })
    });
    group.bench_function("aggregate_8_paths_1241x376_128d", |b| {
        b.iter(|| {
            denser::depth::sgm::aggregate_paths(black_box(&volume), &left, &matcher.params)
                .expect("aggregation")
        })
    });
    group.finish();
}

criterion_group!(benches, bench_sgm);
criterion_main!(benches);
