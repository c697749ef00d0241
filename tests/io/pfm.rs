//! PFM codec: golden bytes, round trips, the real Middlebury ground truth, and bad input.
use crate::common;

use denser::frame::Image;
use denser::io::pfm::{decode_pfm, encode_pfm, read_pfm, write_pfm};
use std::path::Path;

/// A 2×2 image [[1, NaN], [−2.5, 0.5]] (rows top-down) in the Middlebury convention.
fn golden() -> Vec<u8> {
    let mut b = b"Pf\n2 2\n-1\n".to_vec();
    // Bottom row first: −2.5, 0.5; then the top row: 1, +inf.
    for v in [-2.5f32, 0.5, 1.0, f32::INFINITY] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b
}

#[test]
fn encode_matches_golden_bytes() {
    let img = Image {
        width: 2,
        height: 2,
        data: vec![1.0, f32::NAN, -2.5, 0.5],
    };
    let mut out = Vec::new();
    encode_pfm(&img, &mut out);
    assert_eq!(out, golden());
}

#[test]
fn decode_golden_bytes_maps_inf_to_nan() {
    let img = decode_pfm(&golden(), Path::new("golden.pfm")).unwrap();
    assert_eq!((img.width, img.height), (2, 2));
    assert_eq!(img.data[0], 1.0);
    assert!(img.data[1].is_nan());
    assert_eq!(&img.data[2..], &[-2.5, 0.5]);
}

#[test]
fn decode_big_endian_and_crlf_whitespace() {
    let mut b = b"Pf\r\n3 1\r\n1.0\n".to_vec();
    for v in [1.5f32, f32::NEG_INFINITY, 7.0] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    let img = decode_pfm(&b, Path::new("be.pfm")).unwrap();
    assert_eq!(img.data[0], 1.5);
    assert!(img.data[1].is_nan());
    assert_eq!(img.data[2], 7.0);
}

#[test]
fn file_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("d.pfm");
    let w = 13;
    let h = 7;
    let data: Vec<f32> = (0..w * h)
        .map(|i| {
            if i % 5 == 0 {
                f32::NAN
            } else {
                i as f32 * 0.37 - 3.0
            }
        })
        .collect();
    let img = Image {
        width: w as u32,
        height: h as u32,
        data,
    };
    write_pfm(&path, &img).unwrap();
    let back = read_pfm(&path).unwrap();
    assert_eq!((back.width, back.height), (img.width, img.height));
    for (a, b) in img.data.iter().zip(&back.data) {
        assert!(a == b || (a.is_nan() && b.is_nan()), "{a} vs {b}");
    }
}

#[test]
fn bad_input_names_the_file() {
    let p = Path::new("broken.pfm");
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (b"P5\n2 2\n255\n".to_vec(), "magic"),
        (b"PF\n2 2\n-1\n".to_vec(), "colour"),
        (b"Pf\n2 x\n-1\n".to_vec(), "height"),
        (b"Pf\n2 2\n0\n".to_vec(), "scale"),
        (b"Pf\n2 2\n-1x".to_vec(), "scale"),
        (b"Pf\n2 2\n-1".to_vec(), "truncated"),
        (b"Pf\n2 2".to_vec(), "truncated"),
        (golden()[..golden().len() - 3].to_vec(), "truncated"),
    ];
    for (bytes, what) in cases {
        let err = decode_pfm(&bytes, p).unwrap_err().to_string();
        assert!(
            err.contains("broken.pfm") && err.contains(what),
            "{err} (expected `{what}`)"
        );
    }
    let missing = read_pfm("/nonexistent/dir/x.pfm").unwrap_err().to_string();
    assert!(missing.contains("/nonexistent/dir/x.pfm"), "{missing}");
}

#[test]
fn reads_middlebury_ground_truth() {
    let Some(dir) = common::shared_data("middlebury2014_motorcycle_Q_sttr/trainingQ/Motorcycle")
    else {
        return;
    };
    let gt = read_pfm(dir.join("disp0GT.pfm")).unwrap();
    assert_eq!((gt.width, gt.height), (741, 497));
    let valid: Vec<f32> = gt.data.iter().copied().filter(|d| d.is_finite()).collect();
    let share = valid.len() as f64 / gt.data.len() as f64;
    // SOURCE.txt: 97.9 % valid, 9.2..62.9 px.
    assert!((share - 0.979).abs() < 0.005, "valid share {share}");
    let min = valid.iter().copied().fold(f32::INFINITY, f32::min);
    let max = valid.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    assert!(
        (min - 9.2).abs() < 0.1 && (max - 62.9).abs() < 0.1,
        "range {min}..{max}"
    );
    // Re-encoding the real file keeps every valid value and every invalid pixel.
    let mut out = Vec::new();
    encode_pfm(&gt, &mut out);
    let again = decode_pfm(&out, Path::new("again.pfm")).unwrap();
    for (a, b) in gt.data.iter().zip(&again.data) {
        assert!(a == b || (a.is_nan() && b.is_nan()));
    }
}
