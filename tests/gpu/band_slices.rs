//! A depth frame's band slices made on the GPU (`shaders/band_slices.wgsl`) against the CPU
//! twin (`denser::fusion::band_slices`): the same slices, bit for bit, on frames that reach
//! every decision and both sides of each threshold, and so the same blocks listed from them.

use crate::common::{band_test_frame, band_test_mus, gpu, BAND_GRIDS};
use crate::street::street_frame;
use denser::fusion::{
    band_slice_uniforms, band_slices, band_slices_on_gpu, blocks_of_band_slices,
    depth_frame_blocks, DepthFusionParams,
};
use denser::grid::GridParams;

#[test]
fn band_slices_made_on_the_gpu_are_the_cpus() {
    let Some(ctx) = gpu() else { return };
    let params = DepthFusionParams::default();
    let mus = band_test_mus();
    for seed in 1..3 {
        let frame = band_test_frame(seed, &mus);
        for grid in BAND_GRIDS {
            let truncation_m = grid.truncation_m;
            // The frame's threshold pairs fall on both sides of 2μ and of μ/2, and some f32
            // differences round.
            let mu = truncation_m as f64;
            let (mut gaps, mut spreads, mut rounded) = ([0usize; 2], [0usize; 2], 0);
            for (lo, hi) in threshold_pairs(&frame.depth_m.data, frame.depth_m.width as usize) {
                let (exact, f32_diff) = (hi as f64 - lo as f64, (hi - lo) as f64);
                rounded += (exact != f32_diff) as usize;
                if (f32_diff - 2.0 * mu).abs() < 1e-6 {
                    gaps[(f32_diff > 2.0 * mu) as usize] += 1;
                }
                if (exact - 0.5 * mu).abs() < 1e-6 {
                    spreads[(exact > 0.5 * mu) as usize] += 1;
                }
            }
            assert!(gaps.iter().chain(&spreads).all(|&n| n > 0) && rounded > 5);
            let cpu = band_slices(&grid, &frame, &params);
            let on_gpu = band_slices_on_gpu(&ctx, &grid, &frame.depth_m, &params).expect("kernel");
            assert_eq!(on_gpu, cpu, "seed {seed}, μ {truncation_m} m");
            let (k, pose) = (&frame.intrinsics, &frame.world_from_camera);
            let blocks = blocks_of_band_slices(&grid, k, pose, &params, &on_gpu);
            assert_eq!(blocks, depth_frame_blocks(&grid, &frame, &params));
        }
    }
    // KITTI-sized street frames, near the origin and 2 km down the road.
    let grid = GridParams::paper(0.1);
    for (z_m, seed) in [(0.0, 0), (2000.0, 1)] {
        let frame = street_frame(z_m, seed);
        let cpu = band_slices(&grid, &frame, &params);
        let on_gpu = band_slices_on_gpu(&ctx, &grid, &frame.depth_m, &params).expect("kernel");
        assert_eq!(on_gpu, cpu, "street frame at {z_m} m");
        let (k, pose) = (&frame.intrinsics, &frame.world_from_camera);
        let blocks = blocks_of_band_slices(&grid, k, pose, &params, &on_gpu);
        assert_eq!(blocks, depth_frame_blocks(&grid, &frame, &params));
        eprintln!(
            "street frame {}×{}: {} slices ({} bytes) for {} blocks",
            frame.depth_m.width,
            frame.depth_m.height,
            on_gpu.slices.len(),
            on_gpu.slices.len() * 12,
            blocks.len()
        );
    }
}

/// Pairs (lo, hi) of the tiles that hold exactly two usable depths.
fn threshold_pairs(data: &[f32], width: usize) -> Vec<(f32, f32)> {
    let height = data.len() / width;
    let mut pairs = Vec::new();
    for v0 in (0..height).step_by(8) {
        for u0 in (0..width).step_by(8) {
            let mut tile: Vec<f32> = (v0..(v0 + 8).min(height))
                .flat_map(|v| (u0..(u0 + 8).min(width)).map(move |u| data[v * width + u]))
                .filter(|d| d.is_finite() && (0.1..=40.0).contains(d))
                .collect();
            if tile.len() == 2 {
                tile.sort_by(f32::total_cmp);
                pairs.push((tile[0], tile[1]));
            }
        }
    }
    pairs
}

#[test]
fn band_slices_refuse_what_the_fixed_point_cannot_hold() {
    let grid = GridParams::paper(0.1);
    let ok = DepthFusionParams::default();
    assert!(band_slice_uniforms(&grid, &ok, 1241, 376).is_ok());
    assert!(band_slice_uniforms(&grid, &ok, 9000, 376).is_err());
    assert!(band_slice_uniforms(&grid, &ok, 0, 376).is_err());
    for (min_depth_m, max_depth_m) in [(0.0, 40.0), (0.1, f32::INFINITY), (f32::NAN, 40.0)] {
        let p = DepthFusionParams {
            min_depth_m,
            max_depth_m,
            ..ok
        };
        let err = band_slice_uniforms(&grid, &p, 1241, 376).expect_err("refused");
        assert!(err.to_string().contains("usable depths"), "{err}");
    }
    // The thresholds: μ = 0.3 m gives 2μ = 0.6, whose largest f32 below is 0.6f32 − 1 ULP.
    let g = GridParams {
        voxel_size_m: 0.1,
        truncation_m: 0.3,
    };
    let u = band_slice_uniforms(&g, &ok, 1241, 376).expect("uniforms");
    let two_mu = 2.0 * 0.3f32 as f64;
    let t = f32::from_bits((two_mu as f32).to_bits() - ((two_mu as f32) as f64 > two_mu) as u32);
    assert!(t as f64 <= two_mu && f32::from_bits(t.to_bits() + 1) as f64 > two_mu);
    let mid = (u.gap_mid[0] as u64 | (u.gap_mid[1] as u64) << 32) as f64 / (1u64 << 40) as f64;
    assert_eq!(
        mid,
        0.5 * (t as f64 + f32::from_bits(t.to_bits() + 1) as f64)
    );
}

/// The band blocks listed on the device from its slices (`shaders/band_blocks.wgsl`, f64 with
/// a margin of certainty; slices it cannot decide listed by the host) are exactly the host's
/// `depth_frame_blocks`, on the test frames, on street frames near and far from the origin,
/// and under a pose rotated about every axis kilometres out; and the device decides nearly
/// every slice itself. (The test frames' depth pairs sit at 2μ and μ/2 on purpose: a slice 4μ
/// deep is a whole number of blocks deep where μ is a multiple of a block's half, a tie the
/// device settles in the host's own f64 rounding. The host's side, slices the device left to
/// it, is exercised by the same bands with every slice, or half of them, left to the host.)
#[test]
fn band_blocks_listed_on_the_gpu_are_the_hosts() {
    use denser::fusion::{band_blocks_on_gpu, DeviceBand};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    let Some(ctx) = gpu() else { return };
    if !ctx.has_f64() {
        return crate::common::skip(&format!("{} has no f64", ctx.name()));
    }
    let params = DepthFusionParams::default();
    let mus = band_test_mus();
    let mut frames: Vec<(String, GridParams, denser::frame::DepthFrame)> = Vec::new();
    for seed in 1..3 {
        for grid in BAND_GRIDS {
            let name = format!("test frame {seed}, μ {} m", grid.truncation_m);
            frames.push((name, grid, band_test_frame(seed, &mus)));
        }
    }
    let grid = GridParams::paper(0.1);
    for (z_m, seed) in [(0.0, 0), (2000.0, 1)] {
        frames.push((format!("street at {z_m} m"), grid, street_frame(z_m, seed)));
    }
    let mut turned = street_frame(0.0, 2);
    turned.world_from_camera = Isometry3::from_parts(
        Translation3::new(1234.567, -3.21, -2345.678),
        UnitQuaternion::from_euler_angles(0.1, -0.7, 0.05),
    );
    frames.push((
        "street turned, 2.6 km out".into(),
        GridParams::paper(0.05),
        turned,
    ));
    // (slices, deferred) of the test frames and of the streets.
    let mut totals = [(0, 0); 2];
    for (name, grid, frame) in &frames {
        let band = band_blocks_on_gpu(&ctx, grid, frame, &params)
            .expect("kernel")
            .expect("f64");
        let (k, pose) = (&frame.intrinsics, &frame.world_from_camera);
        let listed = depth_frame_blocks(grid, frame, &params);
        assert!(listed.len() > 500, "{name}: {} blocks", listed.len());
        assert_eq!(band.blocks(grid, k, pose, &params), listed, "{name}");
        let slices = band_slices(grid, frame, &params);
        assert_eq!(band.usable_pixels, slices.usable_pixels, "{name}");
        let half = slices.slices.len() / 2;
        for (own, deferred) in [
            (vec![], &slices.slices[..]),
            (band.blocks.clone(), &slices.slices[..half]),
        ] {
            let left = DeviceBand {
                blocks: own,
                deferred: deferred.to_vec(),
                usable_pixels: band.usable_pixels,
            };
            assert_eq!(
                left.blocks(grid, k, pose, &params),
                listed,
                "{name}: left to the host"
            );
        }
        // The device's own blocks, each once.
        let mut own = band.blocks.clone();
        own.sort_by_key(|b| b.sort_key());
        own.dedup();
        assert_eq!(own.len(), band.blocks.len(), "{name}");
        eprintln!(
            "{name}: {} slices, {} deferred; {} blocks, {} from the device",
            slices.slices.len(),
            band.deferred.len(),
            listed.len(),
            band.blocks.len()
        );
        let t = &mut totals[name.starts_with("street") as usize];
        t.0 += slices.slices.len();
        t.1 += band.deferred.len();
    }
    for (what, (slices, deferred)) in ["test frame", "street"].into_iter().zip(totals) {
        assert!(
            deferred * 1000 <= slices,
            "{deferred} of {slices} {what} slices deferred"
        );
    }
}
