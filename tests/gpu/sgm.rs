//! SGM on the GPU against its CPU twin (issue 35 item 1): the summed path costs `S` of
//! `shaders/sgm_paths.wgsl` equal `aggregate_paths`'s in every path mode, with and without the
//! adaptive P2; the selection of `shaders/sgm_select.wgsl`, finished on the host, equals
//! `select_disparities`'s for every sub-pixel fit, with and without its window, the uniqueness
//! test and the left–right check; and `SgmMatcherGpu` (everything but the median and speckle
//! filters on the GPU) gives the CPU matcher's disparities and confidences. Bit for bit on every
//! device: the device computes integers only (src/depth/gpu/sgm.rs). On the generated pair, an
//! odd-sized crop of it, Middlebury 2014 Motorcycle (quarter size) and KITTI 00 frame 0
//! (cropped, to keep lavapipe's time down), the real pairs skipped when `../shared/data` is
//! absent.

use crate::common;
use crate::depth_support::{city_like_planes, piecewise_planar_pair};
use common::gpu;
use denser::depth::sgm::{aggregate_paths, select_disparities, SgmPaths, SubpixelFit};
use denser::depth::{
    aggregate_paths_gpu, select_disparities_gpu, DisparityEstimator, SgmMatcher, SgmMatcherGpu,
    SgmParams, GPU_SGM_MAX_DISPARITIES,
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
    let m = SgmMatcher::new(SgmParams {
        num_disparities: nd,
        ..SgmParams::default()
    })
    .expect("params");
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
    // and uniforms, down the selection's four words per pixel; one submit (census, costs,
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
    assert!(t.readback_bytes <= 16 * pixels, "{t:?}");
    assert!(t.submits == 1 && t.waits == 1, "{t:?}");
    assert!(
        t.buffers_created == 0 && t.bind_groups_created == 0,
        "{t:?}"
    );
}
