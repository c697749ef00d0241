//! Stereo kernels vs. their CPU twins (`src/gpu/stereo.rs` vs `src/depth/`) per stage, on the
//! fixed KITTI-sized pair of `benches/depth_tgv.rs`: 1241×376, 128 disparities, default
//! parameters, the piecewise-planar scene of the tests (`city_like_planes`, noise σ = 2). Do
//! not modify the scene or parameters, or results are not comparable across runs. The GPU half
//! is skipped (with a message) where no adapter exists; on lavapipe (llvmpipe) the "GPU" is the
//! CPU, so those figures measure wgpu + llvmpipe, not a GPU.
//!
//! - `census_cost/{cpu,gpu}`: census of both images and the Hamming cost volume (GPU: upload
//!   the images, three dispatches, read back the 60 MB volume).
//! - `pointwise/{cpu,gpu}`: one decoupling search at θ = 0.2 over the 5×5-averaged costs, from
//!   the SGM disparity (both include the CPU window averaging; GPU: upload of the 119 MB sums).
//! - `tgv_iterate_50/{cpu,gpu}`: 50 TGV-tensor primal–dual iterations at θ = 0.2 (GPU: upload
//!   of the problem, 100 dispatches, readback of u).
//! - `refine/{cpu,gpu}`: the whole refinement (4 rounds × 10 iterations) from the SGM map.
//! - `sgm/{cpu,gpu}`: the SGM matcher on the pair (GPU: `SgmMatcherGpu`, upload of the images,
//!   the cost volume, paths and selection on the device, the selection's 16 bytes per pixel read
//!   back and finished, filters on the CPU).

#[path = "../tests/common/mod.rs"]
mod common;

use common::bench_gpu as gpu;

#[path = "../tests/depth_support/mod.rs"]
mod depth_support;

use criterion::{criterion_group, criterion_main, Criterion};
use denser::depth::sgm::SgmMatcher;
use denser::depth::tgv::{decoupling_search, TgvMatcher, TgvParams, TgvProblem};
use denser::depth::SgmParams;
use denser::depth::{
    cost_volume_gpu, pointwise_search_gpu, refine_gpu, DisparityEstimator, SgmMatcherGpu,
    TgvProblemGpu,
};
use std::hint::black_box;

fn bench_stereo(c: &mut Criterion) {
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
    let ctx = gpu();
    let volume = tgv.cost_volume(&left, &right).expect("cost volume");
    let init = sgm.estimate_from_volume(&left, &volume).expect("sgm");
    let u0 = denser::depth::tgv::fill_from_background(&init.disparity_px, 0.0);
    let theta = 0.2;

    let mut g = c.benchmark_group("census_cost");
    g.sample_size(10);
    g.bench_function("cpu", |b| {
        b.iter(|| {
            tgv.cost_volume(black_box(&left), black_box(&right))
                .expect("volume")
        })
    });
    if let Some(ctx) = &ctx {
        g.bench_function("gpu", |b| {
            b.iter(|| {
                cost_volume_gpu(ctx, &left, &right, &params.sgm.census, 0, 128).expect("volume")
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("pointwise");
    g.sample_size(10);
    g.bench_function("cpu", |b| {
        b.iter(|| decoupling_search(&volume, 5, black_box(&u0), params.lambda, theta).expect("a"))
    });
    if let Some(ctx) = &ctx {
        g.bench_function("gpu", |b| {
            b.iter(|| {
                pointwise_search_gpu(ctx, &volume, 5, black_box(&u0), params.lambda, theta)
                    .expect("a")
            })
        });
    }
    g.finish();

    let a = decoupling_search(&volume, 5, &u0, params.lambda, theta).expect("a");
    let tensors = denser::depth::tgv::diffusion_tensors(&left, params.gamma, params.beta);
    let problem = TgvProblem::new(
        &u0,
        w as usize,
        h as usize,
        params.regularizer,
        params.alpha1,
        params.alpha2,
        tensors,
    )
    .expect("problem");
    let mut g = c.benchmark_group("tgv_iterate_50");
    g.sample_size(10);
    g.bench_function("cpu", |b| {
        b.iter_batched(
            || problem.clone(),
            |mut p| p.iterate(&a, theta, 50).expect("iterate"),
            criterion::BatchSize::LargeInput,
        )
    });
    if let Some(ctx) = &ctx {
        g.bench_function("gpu", |b| {
            b.iter(|| {
                let mut p = TgvProblemGpu::upload(ctx, &problem).expect("upload");
                p.iterate(&a, theta, 50).expect("iterate");
                p.u().expect("u")
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("refine");
    g.sample_size(10);
    g.bench_function("cpu", |b| {
        b.iter(|| tgv.refine(&left, &volume, &init).expect("refine"))
    });
    if let Some(ctx) = &ctx {
        g.bench_function("gpu", |b| {
            b.iter(|| refine_gpu(ctx, &tgv, &left, &volume, &init).expect("refine"))
        });
    }
    g.finish();

    let mut g = c.benchmark_group("sgm");
    g.sample_size(10);
    g.bench_function("cpu", |b| {
        b.iter(|| {
            sgm.estimate(black_box(&left), black_box(&right))
                .expect("sgm")
        })
    });
    if let Some(ctx) = ctx {
        let gpu_sgm = SgmMatcherGpu::new(std::sync::Arc::new(ctx), sgm.clone());
        g.bench_function("gpu", |b| {
            b.iter(|| {
                gpu_sgm
                    .estimate(black_box(&left), black_box(&right))
                    .expect("sgm")
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench_stereo);
criterion_main!(benches);
