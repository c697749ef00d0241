//! Depth from disparity on the GPU (`shaders/disparity_depth.wgsl`) against the CPU's
//! `disparity_to_depth` (an f64 quotient cast to f32): bit for bit, on disparities of every
//! kind and on ones whose quotients fall next to the midpoints between two f32 depths.

use crate::common::{gpu, Rng};
use denser::depth::{
    disparity_depth_uniforms, disparity_to_depth, disparity_to_depth_gpu, DisparityMap,
};
use denser::frame::Image;

#[test]
fn depth_from_disparity_on_the_gpu_is_the_cpus() {
    let Some(ctx) = gpu() else { return };
    let mut rng = Rng(11);
    // (f, B): KITTI's, exact powers of two, and large and odd products.
    for (fx_px, baseline_m) in [
        (718.856, 0.537_165_7),
        (16.0, 0.5),
        (2_000.3, 511.7),
        (525.0, 0.075),
    ] {
        let fb = fx_px * baseline_m;
        let mut data: Vec<f32> = vec![
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            -3.5,
            f32::MIN_POSITIVE,
            f32::from_bits(1),
            f32::from_bits(0x007f_ffff),
            1e-30,
            f32::MAX,
            1.0,
            0.5,
            255.75,
        ];
        // Disparities from matchers: quarter pixels and sub-pixel fits.
        data.extend((0..20_000).map(|_| (rng.uniform() * 256.0) as f32));
        data.extend((0..20_000).map(|_| (rng.uniform() * 4.0).exp2() as f32 * 0.25));
        // Quotients next to the midpoint between two f32 depths, where the two roundings
        // decide: d = f·B / (z + ½ ULP) and its neighbours.
        for _ in 0..20_000 {
            let z = (1.0 + 79.0 * rng.uniform()) as f32;
            let mid = z as f64 + 0.5 * (f32::from_bits(z.to_bits() + 1) - z) as f64;
            let d = (fb / mid) as f32;
            for k in -2i32..=2 {
                data.push(f32::from_bits(d.to_bits().wrapping_add_signed(k)));
            }
        }
        let n = data.len() as u32;
        let map = DisparityMap {
            disparity_px: Image {
                width: n,
                height: 1,
                data,
            },
            confidence: None,
        };
        let cpu = disparity_to_depth(&map, fx_px, baseline_m);
        let on_gpu = disparity_to_depth_gpu(&ctx, &map, fx_px, baseline_m).expect("kernel");
        let differing = cpu
            .data
            .iter()
            .zip(&on_gpu.data)
            .enumerate()
            .filter(|(_, (a, b))| a.to_bits() != b.to_bits())
            .map(|(i, (a, b))| (map.disparity_px.data[i], *a, *b))
            .take(5)
            .collect::<Vec<_>>();
        assert!(
            differing.is_empty(),
            "f·B {fb}: (d, CPU, GPU) {differing:?}"
        );
        // Where f·B is no f32, an f32 division would not do: it differs from the CPU's depth.
        let fb32 = fb as f32;
        let f32_off = map
            .disparity_px
            .data
            .iter()
            .zip(&cpu.data)
            .filter(|(d, z)| d.is_finite() && **d > 0.0 && (fb32 / **d).to_bits() != z.to_bits())
            .count();
        assert!(f32_off > 100 || fb32 as f64 == fb, "f·B {fb}: {f32_off}");
        // NaN in, NaN out; the least subnormal disparity gives an infinite depth, as the cast.
        assert!(on_gpu.data[0].is_nan() && on_gpu.data[7].is_infinite());
    }
}

#[test]
fn depth_from_disparity_refuses_products_out_of_range() {
    assert!(disparity_depth_uniforms(10, 718.856, 0.54).is_ok());
    for (f, b) in [(7.9, 1.0), (-718.0, 0.54), (f64::NAN, 0.54), (1e31, 1e1)] {
        let err = disparity_depth_uniforms(10, f, b).expect_err("refused");
        assert!(err.to_string().contains("f·B"), "{err}");
    }
}
