//! A depth frame's band slices made on the GPU (`shaders/band_slices.wgsl`) against the CPU
//! twin (`denser::fusion::band_slices`): the same slices, bit for bit, on frames that reach
//! every decision and both sides of each threshold, and so the same blocks listed from them.

use crate::common::{band_test_frame, gpu};
use crate::street::street_frame;
use denser::fusion::{
    band_slice_uniforms, band_slices, band_slices_on_gpu, blocks_of_band_slices,
    depth_frame_blocks, DepthFusionParams,
};
use denser::grid::GridParams;

/// (voxel, μ) of the grids, metres (as `tests/core/band_slices.rs`).
const GRIDS: [(f32, f32); 4] = [(0.1, 0.8), (0.05, 0.4), (0.1, 0.3), (0.05, 0.2)];

#[test]
fn band_slices_made_on_the_gpu_are_the_cpus() {
    let Some(ctx) = gpu() else { return };
    let params = DepthFusionParams::default();
    let mus: Vec<f64> = GRIDS.iter().map(|g| g.1 as f64).collect();
    for seed in 1..3 {
        let frame = band_test_frame(seed, &mus);
        for (voxel_size_m, truncation_m) in GRIDS {
            let grid = GridParams {
                voxel_size_m,
                truncation_m,
            };
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
