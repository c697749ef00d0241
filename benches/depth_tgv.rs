//! Census + TGV-tensor stereo per stage on a fixed KITTI-sized pair: 1241×376, 128 disparities,
//! default parameters, the piecewise-planar scene of the tests (`city_like_planes`, noise σ = 2).
//! Do not modify the scene or parameters, or results are not comparable across runs.
use criterion::{criterion_group, criterion_main, Criterion};
use denser::depth::sgm::SgmMatcher;
use denser::depth::tgv::{Regularizer, TgvMatcher, TgvParams};
use denser::depth::SgmParams;
use std::hint::black_box;

#[path = "../tests/depth_support/mod.rs"]
mod depth_support;

fn bench_tgv(c: &mut Criterion) {
    let (w, h) = (1241, 376);
    let (left, right, _) =
        depth_support::piecewise_planar_pair(w, h, &depth_support::city_like_planes(w, h), 2.0);
    let params = TgvParams {
        sgm: SgmParams {
            num_disparities: 128,
            ..SgmParams::default()
        },
        ..TgvParams::default()
    };
    let tgv = TgvMatcher::new(params).expect("valid parameters");
    let sgm = SgmMatcher::new(params.sgm).expect("valid parameters");
    let mut group = c.benchmark_group("depth_tgv");
    group.sample_size(10);
    group.bench_function("census_cost_volume_1241x376_128d", |b| {
        b.iter(|| {
            tgv.cost_volume(black_box(&left), black_box(&right))
                .expect("cost volume")
        })
    });
    let volume = tgv.cost_volume(&left, &right).expect("cost volume");
    group.bench_function("sgm_init_from_volume_1241x376_128d", |b| {
        b.iter(|| {
            sgm.estimate_from_volume(black_box(&left), black_box(&volume))
                .expect("sgm")
        })
    });
    let init = sgm.estimate_from_volume(&left, &volume).expect("sgm");
    for reg in [Regularizer::Tv, Regularizer::Tgv, Regularizer::TgvTensor] {
        let m = TgvMatcher::new(TgvParams {
            regularizer: reg,
            ..params
        })
        .expect("valid parameters");
        group.bench_function(
            format!(
                "{}_refine_{}x{}_iterations_1241x376",
                m_name(reg),
                params.outer_iterations,
                params.inner_iterations
            ),
            |b| {
                b.iter(|| {
                    m.refine(black_box(&left), black_box(&volume), black_box(&init))
                        .expect("refine")
                })
            },
        );
    }
    group.bench_function("tgv_tensor_full_frame_1241x376_128d", |b| {
        b.iter(|| {
            denser::depth::DisparityEstimator::estimate(&tgv, black_box(&left), black_box(&right))
                .expect("tgv")
        })
    });
    group.finish();
}

fn m_name(reg: Regularizer) -> &'static str {
    match reg {
        Regularizer::Tv => "tv",
        Regularizer::Tgv => "tgv",
        Regularizer::TgvTensor => "tgv_tensor",
    }
}

criterion_group!(benches, bench_tgv);
criterion_main!(benches);
