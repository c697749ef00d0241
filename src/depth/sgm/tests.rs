//! Unit tests of the SGM matcher's pieces.

use super::aggregate::{path_step, BIG};
use super::*;

#[test]
fn speckles_are_removed_and_large_regions_kept() {
    // 6×4 image: a 2-pixel island of 30 inside a region of 10 (20 pixels), and two NaNs.
    let nan = f32::NAN;
    #[rustfmt::skip]
    let data = vec![
        10.0, 10.0, 10.0, 10.0, 10.0, 10.0,
        10.0, 30.0, 30.5, 10.0, 10.0, nan,
        10.0, 10.0, 10.0, 10.5, 10.0, 10.0,
        10.0, 10.0, 10.0, 10.0, 10.0, nan,
    ];
    let mut img = Image {
        width: 6,
        height: 4,
        data,
    };
    assert_eq!(remove_speckles(&mut img, 2, 1.0), 2);
    assert!(img.at(1, 1).is_nan() && img.at(2, 1).is_nan());
    assert_eq!(img.at(3, 2), 10.5);
    assert_eq!(img.data.iter().filter(|v| v.is_nan()).count(), 4);
    // With a limit below the region size nothing more goes.
    assert_eq!(remove_speckles(&mut img, 19, 1.0), 0);
    assert_eq!(remove_speckles(&mut img, 20, 1.0), 20);
}

#[test]
fn median_ignores_invalid_neighbours_and_keeps_invalid_pixels() {
    let nan = f32::NAN;
    let img = Image {
        width: 3,
        height: 3,
        data: vec![1.0, 2.0, nan, 4.0, 100.0, 6.0, nan, 8.0, nan],
    };
    let m = median_filter_3x3(&img);
    // Centre: valid values {1, 2, 4, 100, 6, 8} → median of six = (4 + 6) / 2.
    assert_eq!(m.at(1, 1), 5.0);
    assert!(m.at(2, 0).is_nan() && m.at(0, 2).is_nan() && m.at(2, 2).is_nan());
    // Corner (0, 0): {1, 2, 4, 100} → (2 + 4) / 2.
    assert_eq!(m.at(0, 0), 3.0);
}

#[test]
fn sort9_sorts_every_binary_input_and_total_order_keys_round_trip() {
    // 0/1 principle: a comparator network sorting all 2⁹ binary inputs sorts everything.
    for bits in 0u32..512 {
        let mut v: [i32; 9] = std::array::from_fn(|i| ((bits >> i) & 1) as i32);
        sort9(&mut v);
        assert!(v.windows(2).all(|p| p[0] <= p[1]), "{bits:09b} → {v:?}");
    }
    let values = [-3.5f32, -0.0, 0.0, 1e-30, 2.25, -1e30, 7.0];
    for a in values {
        assert_eq!(
            from_total_order_key(total_order_key(a)).to_bits(),
            a.to_bits()
        );
        for b in values {
            assert_eq!(
                total_order_key(a).cmp(&total_order_key(b)),
                a.total_cmp(&b),
                "{a} vs {b}"
            );
        }
    }
}

#[test]
fn path_step_matches_the_recurrence() {
    // D = 4, prev L = [5, 1, 9, 20] (padded), C = [3, 0, 7, 2], P1 = 2, P2 = 6.
    let prev = [BIG, 5, 1, 9, 20, BIG];
    let cost = [3u8, 0, 7, 2];
    let mut out = [BIG; 6];
    let mut acc = [100u16; 4];
    let m = path_step::<false, u16>(&cost, &prev, 1, 2, 6, &mut out, &mut acc);
    // d0: 3 + min(5, 1+2, 1+6) − 1 = 5; d1: 0 + min(1, ..) − 1 = 0;
    // d2: 7 + min(9, 1+2, 20+2, 7) − 1 = 9; d3: 2 + min(20, 9+2, 7) − 1 = 8.
    assert_eq!(&out[1..5], &[5, 0, 9, 8]);
    assert_eq!(acc, [105, 100, 109, 108]);
    assert_eq!(m, 0);
    assert_eq!((out[0], out[5]), (BIG, BIG));
}
