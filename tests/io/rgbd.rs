//! RGB-D sequences: the real slambook2 frames and a TUM-layout sequence written here.

use crate::common;

use denser::frame::{DepthImage, Image, RgbImage};
use denser::io::image::{write_depth_png_u16, write_rgb_png};
use denser::io::rgbd::{
    read_tum_trajectory, write_tum_trajectory, SimpleRgbdOptions, SimpleRgbdSequence, TumOptions,
    TumRgbdSequence,
};
use denser::io::DepthSequence;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::collections::HashMap;

/// World points of every 4th pixel (both directions) with valid depth.
fn world_points(f: &denser::frame::DepthFrame) -> Vec<Vector3<f64>> {
    let mut out = Vec::new();
    for v in (0..f.depth_m.height).step_by(4) {
        for u in (0..f.depth_m.width).step_by(4) {
            let d = f.depth_m.at(u, v);
            if d.is_finite() {
                let p = f.intrinsics.unproject(u as f64, v as f64, d as f64);
                out.push((f.world_from_camera * p).coords);
            }
        }
    }
    out
}

/// Fraction of query points with a reference point within 3 cm (grid search).
fn fraction_within_3cm(reference: &[Vector3<f64>], queries: &[Vector3<f64>]) -> f64 {
    let cell = |p: &Vector3<f64>| {
        [
            (p.x / 0.1).floor() as i64,
            (p.y / 0.1).floor() as i64,
            (p.z / 0.1).floor() as i64,
        ]
    };
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, p) in reference.iter().enumerate() {
        grid.entry(cell(p)).or_default().push(i);
    }
    let near = |q: &Vector3<f64>| {
        let c = cell(q);
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dz| {
                    grid.get(&[c[0] + dx, c[1] + dy, c[2] + dz])
                        .is_some_and(|ids| ids.iter().any(|&i| (reference[i] - q).norm() < 0.03))
                })
            })
        })
    };
    queries.iter().filter(|q| near(q)).count() as f64 / queries.len() as f64
}

#[test]
fn slambook_frames() {
    let Some(dir) = common::shared_data("rgbd_5frames_slambook2") else {
        return;
    };
    let seq = SimpleRgbdSequence::open(&dir, SimpleRgbdOptions::slambook2()).unwrap();
    assert_eq!(seq.len(), 5);
    let pose_text = std::fs::read_to_string(dir.join("pose.txt")).unwrap();
    let mut frames = Vec::new();
    for i in 0..5 {
        let f = seq.frame(i).unwrap();
        assert_eq!((f.depth_m.width, f.depth_m.height), (640, 480));
        assert_eq!((f.intrinsics.fx, f.intrinsics.fy), (518.0, 519.0));
        assert_eq!((f.intrinsics.cx, f.intrinsics.cy), (325.5, 253.5));
        assert_eq!((f.intrinsics.width, f.intrinsics.height), (640, 480));
        let c = f.color.as_ref().unwrap();
        assert_eq!((c.width, c.height), (640, 480));
        // SOURCE.txt: ~32 % invalid, max ~9.8 m; indoor room depths.
        let mut valid: Vec<f32> = f
            .depth_m
            .data
            .iter()
            .copied()
            .filter(|d| d.is_finite())
            .collect();
        let invalid = 1.0 - valid.len() as f64 / (640.0 * 480.0);
        assert!(
            (0.2..0.45).contains(&invalid),
            "frame {i}: {invalid} invalid"
        );
        valid.sort_by(f32::total_cmp);
        let (lo, med, hi) = (valid[0], valid[valid.len() / 2], valid[valid.len() - 1]);
        assert!(
            lo > 0.3 && (1.0..5.0).contains(&med) && hi < 10.0,
            "frame {i}: {lo} {med} {hi}"
        );
        // Pose from the file's line i: tx ty tz qx qy qz qw.
        let v: Vec<f64> = pose_text
            .lines()
            .nth(i)
            .unwrap()
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        assert!(
            (f.world_from_camera.translation.vector - Vector3::new(v[0], v[1], v[2])).norm()
                < 1e-12
        );
        let q = f.world_from_camera.rotation;
        let dot = q.i * v[3] + q.j * v[4] + q.k * v[5] + q.w * v[6];
        assert!(dot.abs() > 1.0 - 1e-6);
        frames.push(f);
    }
    // Poses are camera-to-world: frames 3 and 4 (the closest pair) meet in the world frame; the
    // inverse convention, or ignoring the motion, does not.
    let w3 = world_points(&frames[3]);
    let mut moved = frames[4].clone();
    let aligned = fraction_within_3cm(&w3, &world_points(&moved));
    let (p3, p4) = (frames[3].world_from_camera, frames[4].world_from_camera);
    moved.world_from_camera = p3 * p4.inverse() * p3;
    let inverse = fraction_within_3cm(&w3, &world_points(&moved));
    moved.world_from_camera = p3;
    let unmoved = fraction_within_3cm(&w3, &world_points(&moved));
    eprintln!("slambook frame 4 within 3 cm of frame 3: {aligned:.3} (inverse poses {inverse:.3}, unmoved {unmoved:.3})");
    assert!(aligned > 0.4, "{aligned}");
    assert!(
        inverse < 0.1 * aligned && unmoved < 0.2 * aligned,
        "{inverse} {unmoved}"
    );
}

#[test]
fn simple_layout_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::create_dir_all(dir.join("depth")).unwrap();
    std::fs::write(dir.join("pose.txt"), "0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n").unwrap();
    let d = Image {
        width: 4,
        height: 3,
        data: vec![1000u16; 12],
    };
    denser::io::image::write_pgm_u16(dir.join("depth/1.pgm"), &d).unwrap();
    let e = SimpleRgbdSequence::open(dir, SimpleRgbdOptions::slambook2())
        .unwrap_err()
        .to_string();
    assert!(e.contains("2.pgm"), "{e}");
    denser::io::image::write_pgm_u16(dir.join("depth/2.pgm"), &d).unwrap();
    let seq = SimpleRgbdSequence::open(dir, SimpleRgbdOptions::slambook2()).unwrap();
    let f = seq.frame(1).unwrap();
    assert!(f.depth_m.data.iter().all(|&v| v == 1.0) && f.color.is_none());
    assert_eq!(f.world_from_camera.translation.x, 1.0);
    assert!(seq.frame(2).is_err());
    std::fs::write(dir.join("pose.txt"), "0 0 0 0 0 0 1\n1 0 0 0 0 0\n").unwrap();
    let e = SimpleRgbdSequence::open(dir, SimpleRgbdOptions::slambook2())
        .unwrap_err()
        .to_string();
    assert!(e.contains("pose.txt") && e.contains("line 2"), "{e}");
    std::fs::write(dir.join("pose.txt"), "0 0 0 0 0 0 0\n").unwrap();
    let e = SimpleRgbdSequence::open(dir, SimpleRgbdOptions::slambook2())
        .unwrap_err()
        .to_string();
    assert!(e.contains("pose.txt") && e.contains("quaternion"), "{e}");
}

fn depth_image(k: usize) -> DepthImage {
    let (w, h) = (16u32, 12u32);
    let data = (0..w * h)
        .map(|p| {
            if p % 7 == 0 {
                f32::NAN
            } else {
                0.5 + 0.0123 * p as f32 + 0.25 * k as f32
            }
        })
        .collect();
    Image {
        width: w,
        height: h,
        data,
    }
}

fn color_image(k: usize) -> RgbImage {
    let (w, h) = (16u32, 12u32);
    Image {
        width: w,
        height: h,
        data: (0..w * h).map(|p| [p as u8, k as u8, 7]).collect(),
    }
}

fn gt_pose(t: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(t, 2.0 * t - 1.0, 0.3),
        UnitQuaternion::from_euler_angles(0.1 * t, -0.3 * t, 0.05),
    )
}

/// A TUM folder: depth at 1.0 + k/30 s, colour 5 ms later, ground truth at 100 Hz except a
/// gap that leaves depth frame 2 without a pose within 0.02 s.
fn write_tum(dir: &std::path::Path, frames: usize) -> Vec<f64> {
    std::fs::create_dir_all(dir.join("depth")).unwrap();
    std::fs::create_dir_all(dir.join("rgb")).unwrap();
    let mut depth_txt = String::from("# depth maps\n# file: 'test'\n# timestamp filename\n");
    let mut rgb_txt = String::from("# color images\n# timestamp filename\n");
    let mut times = Vec::new();
    for k in 0..frames {
        let t = 1.0 + k as f64 / 30.0;
        times.push(t);
        let name = format!("depth/{t:.6}.png");
        write_depth_png_u16(dir.join(&name), &depth_image(k), 5000.0).unwrap();
        depth_txt.push_str(&format!("{t:.6} {name}\n"));
        let tc = t + 0.005;
        let cname = format!("rgb/{tc:.6}.png");
        write_rgb_png(dir.join(&cname), &color_image(k)).unwrap();
        rgb_txt.push_str(&format!("{tc:.6} {cname}\n"));
    }
    std::fs::write(dir.join("depth.txt"), depth_txt).unwrap();
    std::fs::write(dir.join("rgb.txt"), rgb_txt).unwrap();
    let gap = times[2];
    let gt: Vec<(f64, Isometry3<f64>)> = (0..200)
        .map(|k| 0.95 + k as f64 * 0.01)
        .filter(|t| (t - gap).abs() > 0.025)
        .map(|t| (t, gt_pose(t)))
        .collect();
    write_tum_trajectory(dir.join("groundtruth.txt"), &gt).unwrap();
    times
}

#[test]
fn tum_round_trip_and_association() {
    let tmp = tempfile::tempdir().unwrap();
    let times = write_tum(tmp.path(), 5);
    let gt = read_tum_trajectory(tmp.path().join("groundtruth.txt")).unwrap();
    let seq = TumRgbdSequence::open(tmp.path(), TumOptions::default()).unwrap();
    // Frame 2 has no pose within 0.02 s and is dropped.
    assert_eq!(seq.len(), 4);
    let kept = [0usize, 1, 3, 4];
    for (i, &k) in kept.iter().enumerate() {
        assert_eq!(seq.time_s(i), Some((times[k] * 1e6).round() / 1e6));
        let f = seq.frame(i).unwrap();
        assert_eq!(f.intrinsics.fx, 525.0);
        assert_eq!((f.intrinsics.cx, f.intrinsics.cy), (319.5, 239.5));
        assert_eq!((f.intrinsics.width, f.intrinsics.height), (16, 12));
        // Depth round trip within half a unit (0.1 mm), NaN kept invalid.
        for (a, b) in f.depth_m.data.iter().zip(&depth_image(k).data) {
            assert_eq!(a.is_nan(), b.is_nan());
            if b.is_finite() {
                assert!((a - b).abs() <= 0.5 / 5000.0 + 1e-6, "{a} {b}");
            }
        }
        assert_eq!(f.color.as_ref(), Some(&color_image(k)));
        // The pose is the nearest ground-truth sample.
        let t = seq.time_s(i).unwrap();
        let (_, nearest) = gt
            .iter()
            .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
            .unwrap();
        let e = f.world_from_camera.inverse() * nearest;
        assert!(e.translation.vector.norm() < 1e-8 && e.rotation.angle() < 1e-8);
        // And within 10 ms of the analytic trajectory.
        let e = f.world_from_camera.inverse() * gt_pose(t);
        assert!(
            e.translation.vector.norm() < 0.03,
            "{}",
            e.translation.vector.norm()
        );
        let p = f.world_from_camera * Point3::origin();
        assert!((p.z - 0.3).abs() < 1e-8);
    }
    // A wider tolerance keeps frame 2.
    let wide = TumOptions {
        max_time_diff_s: 0.05,
        ..TumOptions::default()
    };
    assert_eq!(TumRgbdSequence::open(tmp.path(), wide).unwrap().len(), 5);
    // Without rgb.txt the frames have no colour.
    std::fs::remove_file(tmp.path().join("rgb.txt")).unwrap();
    let seq = TumRgbdSequence::open(tmp.path(), TumOptions::default()).unwrap();
    assert!(seq.frame(0).unwrap().color.is_none());
}

#[test]
fn tum_errors_name_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    write_tum(tmp.path(), 3);
    let gt = tmp.path().join("groundtruth.txt");
    let mut text = std::fs::read_to_string(&gt).unwrap();
    text.push_str("2.5 1 2 3 0 0 0\n");
    let n = text.lines().count();
    std::fs::write(&gt, &text).unwrap();
    let e = TumRgbdSequence::open(tmp.path(), TumOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("groundtruth.txt") && e.contains(&format!("line {n}")),
        "{e}"
    );
    // No pose near any depth frame.
    write_tum_trajectory(&gt, &[(100.0, Isometry3::identity())]).unwrap();
    let e = TumRgbdSequence::open(tmp.path(), TumOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("groundtruth.txt") && e.contains("within"), "{e}");
    // A depth PNG that is colour.
    write_tum(tmp.path(), 3);
    let first = std::fs::read_to_string(tmp.path().join("depth.txt")).unwrap();
    let name = first
        .lines()
        .find(|l| !l.starts_with('#'))
        .unwrap()
        .split_whitespace()
        .nth(1)
        .unwrap()
        .to_string();
    write_rgb_png(tmp.path().join(&name), &color_image(0)).unwrap();
    let seq = TumRgbdSequence::open(tmp.path(), TumOptions::default()).unwrap();
    let e = seq.frame(0).unwrap_err().to_string();
    assert!(e.contains(&name) && e.contains("16-bit"), "{e}");
}
