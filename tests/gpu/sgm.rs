//! SGM on the GPU against its CPU twin (issue 35 item 1): the summed path costs `S` of
//! `shaders/sgm_paths.wgsl` equal `aggregate_paths`'s in every path mode, with and without the
//! adaptive P2; the disparities and confidences of `shaders/sgm_select.wgsl` (its divisions
//! rounded in integers) equal `select_disparities`'s for every sub-pixel fit, with and without
//! its window, the uniqueness test and the left–right check; the median and speckle filters
//! and the fill of TGV's initial disparity equal the CPU's on maps made to catch them out; and
//! `SgmMatcherGpu` (everything on the GPU) gives the CPU matcher's disparities and confidences.
//! Bit for bit on every device (src/depth/gpu/sgm.rs). On the generated pair, an odd-sized crop
//! of it, Middlebury 2014 Motorcycle (quarter size) and KITTI 00 frame 0 (cropped, to keep
//! lavapipe's time down), the real pairs skipped when `../shared/data` is absent.

use crate::common;
use crate::depth_support::{city_like_planes, piecewise_planar_pair};
use common::gpu;
use denser::depth::sgm::{
    aggregate_paths, median_filter_3x3, remove_speckles, select_disparities, SgmPaths, SubpixelFit,
};
use denser::depth::tgv::fill_from_background;
use denser::depth::{
    aggregate_paths_gpu, fill_from_background_gpu, filter_disparities_gpu, select_disparities_gpu,
    DisparityEstimator, SgmMatcher, SgmMatcherGpu, SgmParams, GPU_SGM_MAX_DISPARITIES,
};
use denser::frame::{GreyImage, Image};
use denser::gpu::GpuContext;
use std::sync::Arc;

/// The `x0..x0 + w`, `y0..y0 + h` part of `img`.
fn crop(img: &GreyImage, (x0, y0, w, h): (usize, usize, usize, usize)) -> GreyImage {
    Image {
        width: w as u32,
        height: h as u32,
        data: (y0..y0 + h)
            .flat_map(|y| img.data[y * img.width as usize + x0..][..w].to_vec())
            .collect(),
    }
}

/// `S` on both devices for every path mode, with and without the adaptive P2.
fn check_sums(ctx: &GpuContext, what: &str, left: &GreyImage, right: &GreyImage, nd: usize) {
    for paths in [SgmPaths::Four, SgmPaths::Five, SgmPaths::Eight] {
        for scale in [None, Some(16)] {
            let params = SgmParams {
                num_disparities: nd,
                paths,
                p2_intensity_scale: scale,
                ..SgmParams::default()
            };
            let m = SgmMatcher::new(params).expect("params");
            let volume = m.cost_volume(left, right).expect("volume");
            let cpu = aggregate_paths(&volume, left, &params).expect("CPU");
            let gpu = aggregate_paths_gpu(ctx, &volume, left, &params).expect("GPU");
            assert_eq!(cpu.len(), gpu.len(), "{what}");
            if let Some(k) = (0..cpu.len()).find(|&k| cpu[k] != gpu[k]) {
                let differ = (0..cpu.len()).filter(|&k| cpu[k] != gpu[k]).count();
                let pixel = k / nd;
                panic!(
                    "{what}, {paths:?}, scale {scale:?}: {differ} of {} sums differ; first at pixel ({}, {}) slice {}: CPU {} GPU {}",
                    cpu.len(),
                    pixel % left.width as usize,
                    pixel / left.width as usize,
                    k % nd,
                    cpu[k],
                    gpu[k]
                );
            }
        }
    }
}

/// The first pixel where `a` and `b` differ in any bit (NaN included), or `None`.
fn agree(a: &[f32], b: &[f32]) -> Option<usize> {
    (0..a.len()).find(|&k| a[k].to_bits() != b[k].to_bits())
}

/// The selection on both devices over the same sums, for each fit and rule.
fn check_selection(ctx: &GpuContext, what: &str, left: &GreyImage, right: &GreyImage, nd: usize) {
    let base = SgmParams {
        num_disparities: nd,
        ..SgmParams::default()
    };
    let variants = [
        base,
        SgmParams {
            subpixel: SubpixelFit::Parabola,
            subpixel_cost_window: 0,
            ..base
        },
        SgmParams {
            subpixel: SubpixelFit::None,
            uniqueness_ratio: 0.0,
            lr_max_diff_px: None,
            ..base
        },
        SgmParams {
            subpixel: SubpixelFit::Equiangular,
            subpixel_cost_window: 0,
            lr_max_diff_px: Some(2),
            min_disparity_px: -3,
            ..base
        },
    ];
    for params in variants {
        let m = SgmMatcher::new(params).expect("params");
        let volume = m.cost_volume(left, right).expect("volume");
        let sums = aggregate_paths(&volume, left, &params).expect("sums");
        let (w, h) = (left.width, left.height);
        let (dc, cc) = select_disparities(&sums, Some(&volume), w, h, &params).expect("CPU");
        let (dg, cg) = select_disparities_gpu(ctx, &sums, &volume, &params).expect("GPU");
        for (name, a, b) in [("disparity", &dc, &dg), ("confidence", &cc, &cg)] {
            if let Some(k) = agree(&a.data, &b.data) {
                panic!(
                    "{what}, {params:?}: {name} at pixel ({}, {}): CPU {} GPU {}",
                    k % w as usize,
                    k / w as usize,
                    a.data[k],
                    b.data[k]
                );
            }
        }
    }
}

/// The whole matcher on both devices: equal disparities and confidences (NaN where invalid).
fn check_matcher(
    ctx: &Arc<GpuContext>,
    what: &str,
    left: &GreyImage,
    right: &GreyImage,
    nd: usize,
) {
    check_matcher_with(
        ctx,
        what,
        (left, right),
        SgmParams {
            num_disparities: nd,
            ..SgmParams::default()
        },
    );
}

/// [`check_matcher`] with `params`.
fn check_matcher_with(
    ctx: &Arc<GpuContext>,
    what: &str,
    (left, right): (&GreyImage, &GreyImage),
    params: SgmParams,
) {
    let m = SgmMatcher::new(params).expect("params");
    let cpu = m.estimate(left, right).expect("CPU");
    let gpu = SgmMatcherGpu::new(ctx.clone(), m)
        .estimate(left, right)
        .expect("GPU");
    let valid = cpu.disparity_px.data.iter().filter(|d| !d.is_nan()).count();
    assert!(
        valid > cpu.disparity_px.data.len() / 4,
        "{what}: {valid} valid pixels"
    );
    let (dc, dg) = (&cpu.disparity_px.data, &gpu.disparity_px.data);
    assert_eq!(agree(dc, dg), None, "{what}: disparities differ");
    let conf = |d: &denser::depth::DisparityMap| d.confidence.clone().expect("confidence").data;
    assert_eq!(
        agree(&conf(&cpu), &conf(&gpu)),
        None,
        "{what}: confidences differ"
    );
}

#[test]
fn sgm_on_the_gpu_equals_the_cpu_matcher() {
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let (w, h) = (200, 100);
    let (left, right, _) = piecewise_planar_pair(w, h, &city_like_planes(w, h), 4.0);
    check_sums(&ctx, "generated", &left, &right, 48);
    check_selection(&ctx, "generated", &left, &right, 48);
    // Odd sizes: paths of one pixel, bytes and halves packed across words, odd slice counts.
    let odd = (3, 2, 37, 5);
    check_sums(&ctx, "37×5 crop", &crop(&left, odd), &crop(&right, odd), 13);
    check_selection(&ctx, "37×5 crop", &crop(&left, odd), &crop(&right, odd), 13);
    check_matcher(&ctx, "generated", &left, &right, 48);
    // Each filter alone, a large speckle size, the parabola fit and five paths.
    let base = SgmParams {
        num_disparities: 48,
        ..SgmParams::default()
    };
    for params in [
        SgmParams {
            median_filter: false,
            speckle_max_size_px: 400,
            ..base
        },
        SgmParams {
            speckle_max_size_px: 0,
            subpixel: SubpixelFit::Parabola,
            subpixel_cost_window: 0,
            paths: SgmPaths::Five,
            ..base
        },
    ] {
        check_matcher_with(&ctx, "generated", (&left, &right), params);
    }
    if let Some(dir) = common::shared_data("middlebury2014_motorcycle_Q_sttr/trainingQ/Motorcycle")
    {
        let read = |f: &str| denser::io::image::read_grey(dir.join(f)).expect("read image");
        let (l, r) = (read("im0.png"), read("im1.png"));
        check_sums(&ctx, "Motorcycle", &l, &r, 64);
        check_selection(&ctx, "Motorcycle", &l, &r, 64);
        check_matcher(&ctx, "Motorcycle", &l, &r, 64);
    }
    if let Some(dir) = common::shared_data("kitti_odom00_frames000-005/sequences/00") {
        let read = |f: &str| denser::io::image::read_grey(dir.join(f)).expect("read image");
        let part = (400, 120, 400, 200);
        let (l, r) = (
            crop(&read("image_0/000000.png"), part),
            crop(&read("image_1/000000.png"), part),
        );
        check_sums(&ctx, "KITTI 00/0 crop", &l, &r, 128);
        check_matcher(&ctx, "KITTI 00/0 crop", &l, &r, 128);
    }
    // Beyond what a workgroup holds: the aggregation is refused on the device (the matcher
    // then aggregates on the CPU, the same result).
    let many = SgmParams {
        num_disparities: GPU_SGM_MAX_DISPARITIES + 8,
        ..SgmParams::default()
    };
    let small = crop(&left, (0, 0, 300.min(w as usize), 4));
    let volume = SgmMatcher::new(many)
        .expect("params")
        .cost_volume(&small, &small)
        .expect("volume");
    assert!(aggregate_paths_gpu(&ctx, &volume, &small, &many).is_err());
}

#[test]
fn sgm_on_the_gpu_sends_the_images_up_and_the_disparities_down() {
    // The cost volume and S stay on the device: up go the two images (1 byte per pixel each)
    // and uniforms, down the disparities and confidences (8 bytes per pixel; before, the
    // selection's four words came down and were filtered on the CPU); one submit (census, costs,
    // paths, selection and the read-back copy) and one wait. After the first pair nothing is
    // created: every buffer and bind group is kept.
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let (w, h) = (200, 100);
    let (left, right, _) = piecewise_planar_pair(w, h, &city_like_planes(w, h), 4.0);
    let m = SgmMatcherGpu::new(
        ctx.clone(),
        SgmMatcher::new(SgmParams {
            num_disparities: 48,
            ..SgmParams::default()
        })
        .expect("params"),
    );
    m.estimate(&left, &right).expect("warm-up");
    let before = ctx.traffic();
    m.estimate(&left, &right).expect("GPU");
    let t = ctx.traffic().since(before);
    let pixels = (w * h) as u64;
    eprintln!("{pixels} pixels: {t:?}");
    assert!(t.upload_bytes <= 2 * pixels + (64 << 10), "{t:?}");
    assert!(t.readback_bytes <= 8 * pixels, "{t:?}");
    assert!(t.submits == 1 && t.waits == 1, "{t:?}");
    assert!(
        t.buffers_created == 0 && t.bind_groups_created == 0,
        "{t:?}"
    );
}

/// A `w` × `h` disparity map made to catch the filters out, and its confidence (0 where the
/// disparity is NaN): sloped planes and steps, NaN holes and columns, speckles of 1 to ~150
/// pixels, neighbours differing by exactly the speckle threshold (1.0) and by just over it,
/// and a one-pixel-wide serpentine region winding over the whole image (long union–find
/// chains).
fn speckled_map(w: u32, h: u32, seed: u64) -> (Image<f32>, Image<f32>) {
    let mut state = seed | 1;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let (wu, hu) = (w as usize, h as usize);
    let mut d = Image::filled(w, h, f32::NAN);
    for y in 0..hu {
        for x in 0..wu {
            // Sixteenths: steps of exactly 1.0 and of 1.0625 between bands.
            let band = (x / 7) as f32 * if (y / 9) % 2 == 0 { 1.0 } else { 1.0625 };
            d.data[y * wu + x] = 20.0 + band + (y as f32) / 64.0;
        }
    }
    // Holes, a NaN column and speckles.
    for _ in 0..(wu * hu / 40) {
        let i = (next() % (wu * hu) as u64) as usize;
        d.data[i] = f32::NAN;
    }
    if wu > 5 {
        for y in 0..hu {
            d.data[y * wu + 5] = f32::NAN;
        }
    }
    for _ in 0..(wu * hu / 300).max(1) {
        let (x0, y0) = (next() % w as u64, next() % h as u64);
        let (sw, sh) = (1 + next() % 12, 1 + next() % 12);
        let v = 90.0 + (next() % 64) as f32 / 16.0;
        for y in y0..(y0 + sh).min(h as u64) {
            for x in x0..(x0 + sw).min(w as u64) {
                d.data[(y * w as u64 + x) as usize] = v;
            }
        }
    }
    // A serpentine: rows 2, 6, 10, … in the right third, joined at alternate ends.
    if wu >= 12 && hu >= 8 {
        let (x0, x1) = (2 * wu / 3, wu - 1);
        for y in 0..hu {
            for x in x0..=x1 {
                let row_of_snake = y % 4 == 2;
                let link = (y % 8 == 3 || y % 8 == 4 || y % 8 == 5) && x == x1
                    || (y % 8 == 7 || y % 8 == 0 || y % 8 == 1) && x == x0 && y > 2;
                d.data[y * wu + x] = if row_of_snake || link {
                    150.0 + (x as f32) / 1024.0
                } else {
                    f32::NAN
                };
            }
        }
    }
    let c = Image {
        width: w,
        height: h,
        data: d
            .data
            .iter()
            .map(|v| {
                if v.is_nan() {
                    0.0
                } else {
                    0.25 + v.fract() / 2.0
                }
            })
            .collect(),
    };
    (d, c)
}

#[test]
fn sgm_filters_and_the_initial_fill_on_the_gpu_equal_the_cpu() {
    let Some(ctx) = gpu() else { return };
    let base = SgmParams::default();
    let variants = [
        base,
        SgmParams {
            median_filter: false,
            ..base
        },
        SgmParams {
            speckle_max_size_px: 0,
            ..base
        },
        SgmParams {
            speckle_max_size_px: 5000,
            speckle_max_diff_px: 0.25,
            ..base
        },
        SgmParams {
            speckle_max_size_px: 1,
            speckle_max_diff_px: 2.0,
            median_filter: false,
            ..base
        },
    ];
    let (mut removed, mut kept_px) = (0usize, 0usize);
    for (k, (w, h)) in [(173, 97), (640, 240), (1, 50), (50, 1), (2, 2)]
        .into_iter()
        .enumerate()
    {
        let (d, c) = speckled_map(w, h, 7 + k as u64);
        for params in variants {
            let mut want = if params.median_filter {
                median_filter_3x3(&d)
            } else {
                d.clone()
            };
            let n = remove_speckles(
                &mut want,
                params.speckle_max_size_px,
                params.speckle_max_diff_px,
            );
            let want_c: Vec<f32> = (c.data.iter().zip(&want.data))
                .map(|(&c, d)| if d.is_nan() { 0.0 } else { c })
                .collect();
            let got = filter_disparities_gpu(&ctx, &d, &c, &params).expect("GPU");
            let what = format!("{w}×{h}, {params:?}");
            assert_eq!(agree(&want.data, &got.disparity_px.data), None, "{what}");
            let got_c = got.confidence.expect("confidence").data;
            assert_eq!(agree(&want_c, &got_c), None, "{what}: confidence");
            removed += n;
            kept_px += want.data.iter().filter(|v| !v.is_nan()).count();
        }
        for fallback in [0.0, -3.0] {
            let want = fill_from_background(&d, fallback);
            let got = fill_from_background_gpu(&ctx, &d, fallback).expect("GPU");
            assert_eq!(agree(&want, &got), None, "fill of {w}×{h}");
        }
    }
    // Nothing valid: the fallback everywhere.
    let empty = Image::filled(9, 4, f32::NAN);
    let got = fill_from_background_gpu(&ctx, &empty, 2.5).expect("GPU");
    assert!(got.iter().all(|&v| v == 2.5), "{got:?}");
    eprintln!("{removed} pixels removed as speckles, {kept_px} kept");
    assert!(removed > 5_000 && kept_px > 200_000, "{removed} {kept_px}");
}
