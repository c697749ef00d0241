//! A depth frame's band as slices (`denser::fusion::band_slices`, what the tile lister decides
//! from the depths) and the blocks listed from them (`blocks_of_band_slices`, what it decides
//! from the pose): together exactly `depth_frame_blocks`. The GPU twin of the slices is checked
//! in `tests/gpu/band_slices.rs`.

use crate::common::{band_test_frame, band_test_mus, BAND_GRIDS};
use denser::fusion::{
    band_slices, blocks_of_band_slices, depth_frame_blocks, BandSlice, DepthFusionParams,
    BAND_TILE_PX,
};

#[test]
fn blocks_of_a_frames_band_slices_are_its_listed_blocks() {
    let mus = band_test_mus();
    let params = DepthFusionParams::default();
    for seed in 1..4 {
        let frame = band_test_frame(seed, &mus);
        let (w, h) = (frame.depth_m.width as usize, frame.depth_m.height as usize);
        let tiles = w.div_ceil(BAND_TILE_PX) * h.div_ceil(BAND_TILE_PX);
        let usable = frame
            .depth_m
            .data
            .iter()
            .filter(|&&d| d.is_finite() && d >= params.min_depth_m && d <= params.max_depth_m)
            .count();
        for grid in BAND_GRIDS {
            let truncation_m = grid.truncation_m;
            let slices = band_slices(&grid, &frame, &params);
            let (k, pose) = (&frame.intrinsics, &frame.world_from_camera);
            let blocks = blocks_of_band_slices(&grid, k, pose, &params, &slices);
            let listed = depth_frame_blocks(&grid, &frame, &params);
            assert!(listed.len() > 500, "{} blocks", listed.len());
            assert_eq!(blocks, listed, "seed {seed}, μ {truncation_m} m");
            assert_eq!(slices.usable_pixels, usable);
            // Quadrants and depth ranges both made more slices than tiles.
            let quadrants = slices.slices.iter().filter(|s| s.u[1] - s.u[0] < 7).count();
            assert!(slices.slices.len() > tiles && quadrants > 100, "{slices:?}");
            for s in &slices.slices {
                assert_eq!(BandSlice::unpack(s.pack()), *s);
                assert!(s.lo_m <= s.hi_m && s.u[0] <= s.u[1] && s.v[0] <= s.v[1]);
            }
        }
    }
}
