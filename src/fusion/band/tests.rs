//! Unit tests of the band lister's private parts.

use super::*;
use crate::camera::PinholeIntrinsics;
use crate::frame::Image;
use proptest::prelude::*;

#[test]
fn skipping_listed_slices_lists_the_same_blocks() {
    // A tilted camera over a floor seen at grazing angles, a box in front of a wall
    // (discontinuities inside tiles) and holes: the listing with the skip must be the
    // listing without it, and the skip must have happened.
    let (w, h) = (320u32, 240u32);
    let k = PinholeIntrinsics {
        fx: 260.0,
        fy: 260.0,
        cx: 160.0,
        cy: 120.0,
        width: w,
        height: h,
    };
    let data = (0..w * h)
        .map(|p| {
            let (u, v) = ((p % w) as f32, (p / w) as f32);
            match () {
                _ if (u as u32 + 3 * v as u32).is_multiple_of(97) => f32::NAN,
                _ if (100.0..180.0).contains(&u) && (60.0..150.0).contains(&v) => 2.0 + 0.003 * u,
                // The floor: depth grows without bound towards the horizon (row 120).
                _ if v > 125.0 => (1.5 * 260.0 / (v - 120.0)).min(30.0),
                _ => 6.0 + 0.01 * u,
            }
        })
        .collect();
    let pose = nalgebra::Isometry3::new(
        nalgebra::Vector3::new(0.3, -1.2, 0.7),
        nalgebra::Vector3::new(0.2, 0.1, 0.05),
    );
    let frame = DepthFrame {
        intrinsics: k,
        world_from_camera: pose,
        depth_m: Image {
            width: w,
            height: h,
            data,
        },
        color: None,
    };
    let params = DepthFusionParams::default();
    for (voxel, mu) in [(0.1f32, 0.8f32), (0.05, 0.4), (0.05, 0.2)] {
        let grid = GridParams {
            voxel_size_m: voxel,
            truncation_m: mu,
        };
        let with = list_band(&grid, &frame, &params, true);
        let without = list_band(&grid, &frame, &params, false);
        assert!(with.blocks.len() > 100);
        assert_eq!(with.blocks, without.blocks, "voxel {voxel} m, μ {mu} m");
        assert_eq!(with.usable_pixels, without.usable_pixels);
        assert_eq!(without.skipped_slices, 0);
        assert!(with.skipped_slices > 100, "{} skipped", with.skipped_slices);
        let usable = frame
            .depth_m
            .data
            .iter()
            .filter(|&&d| usable(d, &params))
            .count();
        assert_eq!(with.usable_pixels, usable);
    }
}

proptest! {
    #[test]
    fn corner_box_is_the_box_of_the_eight_corners(
        origin in prop::array::uniform3(-1e4f64..1e4),
        rays in prop::array::uniform4(prop::array::uniform3(-2.0f64..2.0)),
        za in 0.0f64..60.0,
        depth in 0.0f64..5.0,
        zero in any::<bool>(),
        block_m in prop::sample::select(vec![0.8, 0.4, 0.2, 0.1, 1.0 / 3.0]),
    ) {
        // The corners one by one, as `origin + z·ray` (the listing before the ray bounds).
        let za = if zero { 0.0 } else { za };
        let zb = za + depth;
        let rays = rays.map(Vector3::from);
        let g = SliceGeometry {
            columns: [Vector3::x(), Vector3::y(), Vector3::z()],
            origin: Vector3::from(origin),
            block_m,
        };
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for z in [za, zb] {
            for ray in &rays {
                for k in 0..3 {
                    let c = g.origin[k] + z * ray[k];
                    lo[k] = lo[k].min(c);
                    hi[k] = hi[k].max(c);
                }
            }
        }
        let margin_m = 1e-6;
        let first = lo.map(|x| crate::grid::floor_i64((x - margin_m) / block_m));
        let end = hi.map(|x| crate::grid::floor_i64((x + margin_m) / block_m) + 1);
        let got = g.corner_box(&RayBounds::of(&rays), za, zb, margin_m, 1.0 / block_m);
        prop_assert_eq!(got, (first, end));
    }

    #[test]
    fn floor_div_is_the_floor_of_the_quotient(
        x in -1e6f64..1e6,
        b in prop::sample::select(vec![0.8, 0.4, 0.2, 0.1, 0.05 * 8.0, 0.3, 1.0 / 3.0]),
        k in -200_000i64..200_000,
        ulps in -3i64..=3,
    ) {
        let exact = |x: f64| crate::grid::floor_i64(x / b);
        prop_assert_eq!(floor_div(x, b, 1.0 / b), exact(x));
        // Near multiples of b, where the product and the quotient can floor apart.
        let near = f64::from_bits(((k as f64 * b).to_bits() as i64 + ulps) as u64);
        prop_assert_eq!(floor_div(near, b, 1.0 / b), exact(near));
    }
}
