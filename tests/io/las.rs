//! LAS/LAZ reading and writing: the real PDAL test files and round trips written here.

use crate::common;

use denser::frame::PointCloud;
use denser::io::las::{
    linear_units_m, read_point_cloud, read_point_cloud_metres, write_point_cloud,
};
use std::path::Path;

/// The first point of an uncompressed LAS 1.0–1.3 file (point format 2 or 3), decoded by hand
/// from the public header layout: (x, y, z) in file units and the 16-bit RGB.
fn first_point_by_hand(path: &Path) -> ([f64; 3], [u16; 3]) {
    let b = std::fs::read(path).unwrap();
    let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
    let f64_at = |o: usize| f64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    let i32_at = |o: usize| i32::from_le_bytes(b[o..o + 4].try_into().unwrap());
    let u16_at = |o: usize| u16::from_le_bytes(b[o..o + 2].try_into().unwrap());
    assert_eq!(&b[..4], b"LASF");
    let start = u32_at(96) as usize;
    let format = b[104];
    let scale = [f64_at(131), f64_at(139), f64_at(147)];
    let offset = [f64_at(155), f64_at(163), f64_at(171)];
    let xyz = [0, 1, 2].map(|k| i32_at(start + 4 * k) as f64 * scale[k] + offset[k]);
    let rgb_at = match format {
        2 => start + 20,
        3 => start + 28,
        f => panic!("format {f}"),
    };
    (xyz, [0, 1, 2].map(|k| u16_at(rgb_at + 2 * k)))
}

#[test]
fn autzen_trim() {
    let Some(dir) = common::shared_data("las_autzen_pdal") else {
        return;
    };
    let path = dir.join("autzen_trim.las");
    let cloud = read_point_cloud(&path).unwrap();
    assert_eq!(cloud.len(), 110_000);
    let colors = cloud.colors.as_ref().unwrap();
    assert_eq!(colors.len(), 110_000);
    let (xyz, rgb) = first_point_by_hand(&path);
    for (got, want) in cloud.points_m[0].iter().zip(xyz) {
        assert!((got - want).abs() < 1e-9);
    }
    let shift = if rgb.iter().all(|&c| c <= 255) { 0 } else { 8 };
    assert_eq!(colors[0], rgb.map(|c| (c >> shift) as u8));
    let distinct: std::collections::HashSet<_> = colors.iter().collect();
    assert!(distinct.len() > 1000, "{} distinct colours", distinct.len());
    // Extent (SOURCE.txt): ~1177 x 563 x 114 international feet.
    let ext = |k: usize| {
        let v = cloud.points_m.iter().map(|p| p[k]);
        v.clone().fold(f64::MIN, f64::max) - v.fold(f64::MAX, f64::min)
    };
    assert!(
        (ext(0) - 1177.0).abs() < 5.0 && (ext(1) - 563.0).abs() < 5.0,
        "{} {}",
        ext(0),
        ext(1)
    );
    // Declared units: international feet; in metres the extent is ~359 x 172 m.
    let units = linear_units_m(&path).unwrap();
    eprintln!("autzen_trim units: {units:?}");
    let (h, v) = units.expect("autzen_trim declares its units");
    assert_eq!(h, 0.3048);
    assert!(v == 0.3048 || v == 1200.0 / 3937.0 || v == 1.0);
    let m = read_point_cloud_metres(&path).unwrap();
    assert!((m.points_m[0][0] - xyz[0] * 0.3048).abs() < 1e-6);
    assert!((m.points_m[0][1] - xyz[1] * 0.3048).abs() < 1e-6);
    assert!((m.points_m[0][2] - xyz[2] * v).abs() < 1e-6);
}

#[test]
fn other_pdal_files() {
    let Some(dir) = common::shared_data("las_autzen_pdal") else {
        return;
    };
    for (name, n) in [
        ("sample_c.las", 14_408),
        ("warsaw_small.las", 3_000),
        ("autzen-utm.las", 1_065),
    ] {
        let path = dir.join(name);
        let cloud = read_point_cloud(&path).unwrap();
        assert_eq!(cloud.len(), n, "{name}");
        let (xyz, _) = first_point_by_hand(&path);
        for (got, want) in cloud.points_m[0].iter().zip(xyz) {
            assert!((got - want).abs() < 1e-9, "{name}");
        }
        assert!(cloud
            .points_m
            .iter()
            .all(|p| p.iter().all(|v| v.is_finite())));
    }
}

fn max_error(a: &PointCloud, b: &PointCloud) -> f64 {
    assert_eq!(a.len(), b.len());
    a.points_m
        .iter()
        .zip(&b.points_m)
        .map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).abs()).fold(0.0, f64::max))
        .fold(0.0, f64::max)
}

/// A UTM-like cloud: large coordinates, sub-millimetre fractions, colours.
fn synthetic_cloud(n: usize, with_color: bool) -> PointCloud {
    let points_m = (0..n)
        .map(|i| {
            let t = i as f64;
            [
                500_000.0 + 0.123_456_7 * t,
                5_400_000.0 - 0.098_765_4 * t,
                120.0 + (t * 0.37).sin() * 30.0,
            ]
        })
        .collect();
    let colors = with_color.then(|| {
        (0..n)
            .map(|i| [i as u8, (i * 7) as u8, 255 - i as u8])
            .collect()
    });
    PointCloud { points_m, colors }
}

#[test]
fn round_trip_las_and_laz() {
    let tmp = tempfile::tempdir().unwrap();
    for name in ["c.las", "c.laz", "C.LAZ"] {
        let cloud = synthetic_cloud(5_000, true);
        let path = tmp.path().join(name);
        write_point_cloud(&path, &cloud).unwrap();
        let back = read_point_cloud(&path).unwrap();
        let err = max_error(&cloud, &back);
        assert!(err <= 0.0005 + 1e-9, "{name}: {err} m");
        assert_eq!(back.colors, cloud.colors, "{name}");
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[..4], b"LASF");
        // LAS 1.4, point format 7 (RGB) with bit 7 set when compressed (LAZ).
        assert_eq!((bytes[24], bytes[25]), (1, 4), "{name}");
        let compressed = name.to_lowercase().ends_with(".laz");
        assert_eq!(bytes[104], 7 | if compressed { 0x80 } else { 0 }, "{name}");
    }
    let plain = tmp.path().join("plain.las");
    let cloud = synthetic_cloud(100, false);
    write_point_cloud(&plain, &cloud).unwrap();
    let back = read_point_cloud(&plain).unwrap();
    assert!(back.colors.is_none());
    assert!(max_error(&cloud, &back) <= 0.0005 + 1e-9);
    assert_eq!(std::fs::read(&plain).unwrap()[104], 6);
    // Empty clouds are valid files.
    let empty = tmp.path().join("empty.laz");
    write_point_cloud(&empty, &PointCloud::default()).unwrap();
    assert!(read_point_cloud(&empty).unwrap().is_empty());
}

#[test]
fn real_file_round_trip_through_laz() {
    let Some(dir) = common::shared_data("las_autzen_pdal") else {
        return;
    };
    let cloud = read_point_cloud_metres(dir.join("autzen_trim.las")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("autzen_m.laz");
    write_point_cloud(&path, &cloud).unwrap();
    let back = read_point_cloud(&path).unwrap();
    assert!(max_error(&cloud, &back) <= 0.0005 + 1e-9);
    assert_eq!(back.colors, cloud.colors);
}

#[test]
fn bad_files_name_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let bad = tmp.path().join("not_a_cloud.las");
    std::fs::write(
        &bad,
        b"hello, this is not a LAS file at all, but long enough to hold a header?",
    )
    .unwrap();
    let e = read_point_cloud(&bad).unwrap_err().to_string();
    assert!(e.contains("not_a_cloud.las"), "{e}");
    let e = read_point_cloud(tmp.path().join("missing.las"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.las"), "{e}");
    let wide = PointCloud {
        points_m: vec![[0.0, 0.0, 0.0], [5e6, 0.0, 0.0]],
        colors: None,
    };
    let e = write_point_cloud(tmp.path().join("wide.las"), &wide)
        .unwrap_err()
        .to_string();
    assert!(e.contains("wide.las") && e.contains("extent"), "{e}");
}

#[test]
fn truncated_las_is_an_error() {
    let tmp = tempfile::tempdir().unwrap();
    // A real file when present, otherwise one written here.
    let src = match common::shared_data("las_autzen_pdal") {
        Some(dir) => dir.join("sample_c.las"),
        None => {
            let p = tmp.path().join("src.las");
            write_point_cloud(&p, &synthetic_cloud(2_000, true)).unwrap();
            p
        }
    };
    let bytes = std::fs::read(&src).unwrap();
    for (name, keep) in [
        ("cut_points.las", bytes.len() * 2 / 3),
        ("cut_header.las", 150),
    ] {
        let cut = tmp.path().join(name);
        std::fs::write(&cut, &bytes[..keep]).unwrap();
        let e = read_point_cloud(&cut).unwrap_err().to_string();
        assert!(e.contains(name) && e.contains("truncated"), "{e}");
        eprintln!("{e}");
    }
    // Compressed: cut a LAZ in the middle of its chunks.
    let laz = tmp.path().join("full.laz");
    write_point_cloud(&laz, &synthetic_cloud(60_000, true)).unwrap();
    let bytes = std::fs::read(&laz).unwrap();
    let cut = tmp.path().join("cut.laz");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let e = read_point_cloud(&cut).unwrap_err().to_string();
    assert!(e.contains("cut.laz") && e.contains("truncated"), "{e}");
    eprintln!("{e}");
}
