//! KITTI odometry reader: the real frames of sequence 00 in ../shared/data and small sequences
//! written here in a temp dir (round trips and every error path).

use crate::common;

use denser::frame::{GreyImage, Image, RgbImage};
use denser::io::image::{write_grey_png, write_rgb_png};
use denser::io::kitti::{
    read_poses, read_velodyne_bin, write_calib, write_poses, write_times, write_velodyne_bin,
    KittiCalib, KittiSequence,
};
use nalgebra::{Isometry3, Matrix3x4, Point3, Translation3, UnitQuaternion, Vector3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

fn real_seq() -> Option<PathBuf> {
    common::shared_data("kitti_odom00_frames000-005").map(|p| p.join("sequences/00"))
}

/// Numbers of one line of a text file, parsed independently of the library.
fn raw_numbers(path: &Path, line: usize) -> Vec<f64> {
    let text = std::fs::read_to_string(path).unwrap();
    let l = text.lines().nth(line).unwrap();
    let l = l.split_once(':').map_or(l, |(_, v)| v);
    l.split_whitespace().map(|t| t.parse().unwrap()).collect()
}

#[test]
fn real_sequence_metadata() {
    let Some(dir) = real_seq() else { return };
    let seq = KittiSequence::open(&dir, None).unwrap();
    assert_eq!(seq.len(), 6);
    assert_eq!(seq.poses().unwrap().len(), 6);
    let calib = seq.calib();
    // Published seq 00 values: fx = 718.856, grey baseline 386.1448 / 718.856 = 0.53716 m.
    let k = seq.intrinsics(0).unwrap();
    assert_eq!((k.width, k.height), (1241, 376));
    assert!((k.fx - 718.856).abs() < 1e-9 && (k.fy - 718.856).abs() < 1e-9);
    assert!((k.cx - 607.1928).abs() < 1e-9 && (k.cy - 185.2157).abs() < 1e-9);
    assert!((calib.baseline_m(0, 1) - 386.1448 / 718.856).abs() < 1e-9);
    // Colour pair: about 0.54 m (KITTI setup), cam2 about 6 cm left of cam0.
    assert!(
        (calib.baseline_m(2, 3) - 0.54).abs() < 0.01,
        "{}",
        calib.baseline_m(2, 3)
    );
    let cam2_centre_x = -calib.cam_from_cam0_translation_m(2).x;
    assert!((cam2_centre_x + 0.06).abs() < 0.005, "{cam2_centre_x}");
    // Tr is the raw file's 3x4 (orthonormal to ~1e-9).
    let tr = raw_numbers(&dir.join("calib.txt"), 4);
    let m = calib.cam0_from_velo.to_homogeneous();
    for r in 0..3 {
        for c in 0..4 {
            assert!((m[(r, c)] - tr[4 * r + c]).abs() < 1e-6);
        }
    }
    // Times and poses as in the files.
    let times = std::fs::read_to_string(dir.join("times.txt")).unwrap();
    let t5: f64 = times.lines().nth(5).unwrap().trim().parse().unwrap();
    assert_eq!(seq.time_s(5), Some(t5));
    assert_eq!(seq.time_s(6), None);
    let poses_path = dir.join("../../poses/00.txt");
    assert_eq!(seq.poses_path().unwrap().file_name().unwrap(), "00.txt");
    for i in 0..6 {
        let raw = raw_numbers(&poses_path, i);
        let m = seq.pose(i).unwrap().to_homogeneous();
        for r in 0..3 {
            for c in 0..4 {
                assert!(
                    (m[(r, c)] - raw[4 * r + c]).abs() < 1e-5,
                    "pose {i} ({r},{c})"
                );
            }
        }
    }
    // The car drives ~0.86 m per frame forward (+z of cam0).
    let z5 = seq.pose(5).unwrap().translation.z;
    assert!((3.5..5.0).contains(&z5), "{z5}");
}

#[test]
fn real_images_and_partial_streams() {
    let Some(dir) = real_seq() else { return };
    let seq = KittiSequence::open(&dir, None).unwrap();
    assert!((0..6).all(|i| seq.has_image(0, i)));
    assert!(seq.has_image(1, 0) && !seq.has_image(1, 1));
    assert!(!seq.has_image(2, 0) && !seq.has_image(3, 0));
    assert!((0..6).all(|i| seq.has_velodyne(i)));
    let left = seq.grey(0, 0).unwrap();
    let right = seq.grey(1, 0).unwrap();
    assert_eq!((left.width, left.height), (1241, 376));
    assert_eq!((right.width, right.height), (1241, 376));
    let mean = left.data.iter().map(|&v| v as f64).sum::<f64>() / left.data.len() as f64;
    assert!((20.0..230.0).contains(&mean), "mean grey {mean}");
    assert_ne!(left.data, right.data);
    let rgb = seq.color(0, 0).unwrap();
    assert!(rgb
        .data
        .iter()
        .zip(&left.data)
        .all(|(c, &g)| c == &[g, g, g]));
    let err = seq.grey(1, 1).unwrap_err().to_string();
    assert!(
        err.contains("image_1") && err.contains("000001.png"),
        "{err}"
    );
}

/// Median over every 3rd query point of the distance to its nearest reference point, capped
/// at 0.5 m (grid search).
fn median_nn_distance(reference: &[Vector3<f64>], queries: &[Vector3<f64>]) -> f64 {
    let cell = |p: &Vector3<f64>| {
        [
            (p.x / 0.5).floor() as i64,
            (p.y / 0.5).floor() as i64,
            (p.z / 0.5).floor() as i64,
        ]
    };
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, p) in reference.iter().enumerate() {
        grid.entry(cell(p)).or_default().push(i);
    }
    let mut d: Vec<f64> = queries
        .iter()
        .step_by(3)
        .map(|q| {
            let c = cell(q);
            let mut best = 0.5f64;
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        if let Some(ids) = grid.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) {
                            for &i in ids {
                                best = best.min((reference[i] - q).norm());
                            }
                        }
                    }
                }
            }
            best
        })
        .collect();
    d.sort_by(f64::total_cmp);
    d[d.len() / 2]
}

/// World points (under `world_from_sensor`) of a scan above the ground (z_velo > −1.2 m)
/// within 40 m of the sensor: poles, cars and façades, whose position depends on the pose.
fn structure_points(
    scan: &denser::frame::LidarScan,
    world_from_sensor: Isometry3<f64>,
) -> Vec<Vector3<f64>> {
    scan.points_sensor_m
        .iter()
        .filter(|p| p[2] > -1.2 && p[0] * p[0] + p[1] * p[1] < 1600.0)
        .map(|p| (world_from_sensor * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64)).coords)
        .collect()
}

#[test]
fn real_velodyne_projects_into_image_and_scans_align() {
    let Some(dir) = real_seq() else { return };
    let seq = KittiSequence::open(&dir, None).unwrap();
    // Counts from SOURCE.txt (= file size / 16; the scans hold no NaN).
    let expected = [124_668, 124_605, 124_478, 124_167, 123_969, 123_924];
    for (i, &n) in expected.iter().enumerate() {
        let scan = seq.velodyne(i).unwrap();
        assert_eq!(scan.points_sensor_m.len(), n);
        assert_eq!(scan.intensity.len(), n);
        assert!(scan.intensity.iter().all(|r| (0.0..=1.0).contains(r)));
    }
    // Project scan 0 through P0 · Tr: the points in front of the camera and within its
    // horizontal field of view must land inside the 1241x376 image (vertical FOV: the
    // HDL-64 sees from +2° to −24.8°, the camera ±14.6°), with street-scale depths, and ground
    // points (1.73 m below the LiDAR) must fall in the lower half of the image.
    let scan = seq.velodyne(0).unwrap();
    let calib = seq.calib();
    let p0 = calib.p[0];
    let mut in_front = 0;
    let mut inside = 0;
    let mut depths = Vec::new();
    let mut below = 0;
    let mut ground = 0;
    let mut ground_low = 0;
    for p in &scan.points_sensor_m {
        let x = calib.cam0_from_velo * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        if x.z <= 1.0 || (x.x / x.z).abs() > 607.0 / 718.856 {
            continue;
        }
        in_front += 1;
        let h = p0 * x.to_homogeneous();
        let (u, v) = (h.x / h.z, h.y / h.z);
        if (0.0..1241.0).contains(&u) && (0.0..376.0).contains(&v) {
            inside += 1;
            depths.push(x.z);
        } else if v >= 376.0 {
            below += 1;
        }
        if p[2] < -1.5 {
            ground += 1;
            ground_low += usize::from(v > 185.2);
        }
    }
    let frac = inside as f64 / in_front as f64;
    assert!(in_front > 15_000, "{in_front}");
    let below_frac = below as f64 / (in_front - inside) as f64;
    eprintln!("{inside}/{in_front} = {frac:.3} inside, {below_frac:.3} of the others below");
    assert!(
        frac > 0.6,
        "only {frac:.3} of {in_front} frontal points project into the image"
    );
    // The rest are the LiDAR's lower beams (down to −24.8°), below the image.
    assert!(below_frac > 0.95, "{below_frac}");
    depths.sort_by(f64::total_cmp);
    let median = depths[depths.len() / 2];
    eprintln!(
        "median depth {median} m, ground {ground_low}/{ground}, max {}",
        depths.last().unwrap()
    );
    assert!((4.0..30.0).contains(&median), "median depth {median} m");
    assert!(*depths.last().unwrap() < 120.0);
    assert!(
        ground > 1000 && ground_low as f64 > 0.99 * ground as f64,
        "{ground_low}/{ground}"
    );

    // With world_from_sensor = pose · Tr, scans 0 and 2 (1.7 m apart) overlap in the world;
    // ignoring the motion, or composing Tr on the wrong side, does not.
    let s2 = seq.velodyne(2).unwrap();
    let w0 = structure_points(&scan, scan.world_from_sensor);
    let aligned = median_nn_distance(&w0, &structure_points(&s2, s2.world_from_sensor));
    let unmoved = median_nn_distance(&w0, &structure_points(&s2, scan.world_from_sensor));
    let swapped = calib.cam0_from_velo * seq.pose(2).unwrap();
    let wrong_order = median_nn_distance(&w0, &structure_points(&s2, swapped));
    eprintln!("median NN distance scan 2 → scan 0: {aligned:.3} m posed, {unmoved:.3} m unmoved, {wrong_order:.3} m Tr·pose");
    assert!(aligned < 0.15, "median NN distance {aligned} m");
    assert!(
        unmoved > 2.0 * aligned && wrong_order > 3.0 * aligned,
        "{unmoved} {wrong_order} vs {aligned}"
    );
}

// ---------- sequences written here ----------

// KITTI's calibration files give the rotation to four decimals (−1.5708 rad), not π/2.
#[allow(clippy::approx_constant)]
fn test_calib() -> KittiCalib {
    let fx = 700.0;
    let k = |tx: f64, ty: f64, tz: f64| {
        let (cx, cy) = (320.5, 120.25);
        Matrix3x4::new(
            fx,
            0.0,
            cx,
            fx * tx + cx * tz,
            0.0,
            fx,
            cy,
            fx * ty + cy * tz,
            0.0,
            0.0,
            1.0,
            tz,
        )
    };
    KittiCalib {
        p: [
            k(0.0, 0.0, 0.0),
            k(-0.5, 0.0, 0.0),
            k(0.06, -0.001, 0.004),
            k(-0.47, 0.002, 0.005),
        ],
        cam0_from_velo: Isometry3::from_parts(
            Translation3::new(-0.01, -0.05, -0.3),
            UnitQuaternion::from_euler_angles(-1.5708, 0.001, -1.5708),
        ),
    }
}

fn test_poses(n: usize) -> Vec<Isometry3<f64>> {
    (0..n)
        .map(|i| {
            let t = i as f64;
            Isometry3::from_parts(
                Translation3::new(0.1 * t, -0.02 * t, 0.9 * t + 1234.5),
                UnitQuaternion::from_euler_angles(0.01 * t, 0.05 * t, -0.002 * t),
            )
        })
        .collect()
}

fn grey(i: usize) -> GreyImage {
    let (w, h) = (8u32, 5u32);
    Image {
        width: w,
        height: h,
        data: (0..w * h).map(|k| (k as usize * 3 + i) as u8).collect(),
    }
}

fn rgb(i: usize) -> RgbImage {
    let (w, h) = (8u32, 5u32);
    let data = (0..w * h)
        .map(|k| [k as u8, (i * 40) as u8, 255 - k as u8])
        .collect();
    Image {
        width: w,
        height: h,
        data,
    }
}

fn scan_points(i: usize) -> (Vec<[f32; 3]>, Vec<f32>) {
    let pts = (0..50)
        .map(|k| {
            [
                k as f32 * 0.5 + i as f32,
                -(k as f32),
                1.0 + 0.01 * k as f32,
            ]
        })
        .collect();
    let refl = (0..50).map(|k| k as f32 / 50.0).collect();
    (pts, refl)
}

/// Writes `<root>/sequences/07/...` and `<root>/poses/07.txt` with `n` frames.
fn write_sequence(root: &Path, n: usize) -> PathBuf {
    let seq = root.join("sequences/07");
    for sub in ["image_0", "image_1", "image_2", "velodyne"] {
        std::fs::create_dir_all(seq.join(sub)).unwrap();
    }
    std::fs::create_dir_all(root.join("poses")).unwrap();
    write_calib(seq.join("calib.txt"), &test_calib()).unwrap();
    write_times(
        seq.join("times.txt"),
        &(0..n).map(|i| 0.1 * i as f64 + 1e-4).collect::<Vec<_>>(),
    )
    .unwrap();
    write_poses(root.join("poses/07.txt"), &test_poses(n)).unwrap();
    for i in 0..n {
        write_grey_png(seq.join(format!("image_0/{i:06}.png")), &grey(i)).unwrap();
        write_rgb_png(seq.join(format!("image_2/{i:06}.png")), &rgb(i)).unwrap();
        let (p, r) = scan_points(i);
        write_velodyne_bin(seq.join(format!("velodyne/{i:06}.bin")), &p, &r).unwrap();
    }
    write_grey_png(seq.join("image_1/000000.png"), &grey(99)).unwrap();
    seq
}

#[test]
fn written_sequence_round_trips() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = write_sequence(tmp.path(), 4);
    let seq = KittiSequence::open(&dir, None).unwrap();
    assert_eq!(seq.len(), 4);
    let calib = test_calib();
    for (a, b) in seq.calib().p.iter().zip(&calib.p) {
        assert!((a - b).abs().max() < 1e-9);
    }
    assert!((seq.calib().baseline_m(0, 1) - 0.5).abs() < 1e-12);
    assert!((seq.calib().baseline_m(2, 3) - 0.53).abs() < 1e-12);
    assert!(
        (seq.calib().cam_from_cam0_translation_m(2) - Vector3::new(0.06, -0.001, 0.004)).norm()
            < 1e-12
    );
    let tr_err = seq.calib().cam0_from_velo.inverse() * calib.cam0_from_velo;
    assert!(tr_err.translation.vector.norm() < 1e-10 && tr_err.rotation.angle() < 1e-10);
    for (i, expected) in test_poses(4).iter().enumerate() {
        let e = seq.pose(i).unwrap().inverse() * expected;
        assert!(
            e.translation.vector.norm() < 1e-5 && e.rotation.angle() < 1e-8,
            "pose {i}"
        );
        assert!((seq.time_s(i).unwrap() - (0.1 * i as f64 + 1e-4)).abs() < 1e-12);
        assert_eq!(seq.grey(0, i).unwrap(), grey(i));
        assert_eq!(seq.color(2, i).unwrap(), rgb(i));
        let scan = seq.velodyne(i).unwrap();
        let (p, r) = scan_points(i);
        assert_eq!((scan.points_sensor_m, scan.intensity), (p, r));
        let expect_pose = seq.pose(i).unwrap() * calib.cam0_from_velo;
        let e = scan.world_from_sensor.inverse() * expect_pose;
        assert!(e.translation.vector.norm() < 1e-9 && e.rotation.angle() < 1e-9);
        // Camera 2's pose: its centre is 6 cm left of cam0 (in cam0's frame).
        let c2 = seq.camera_pose(2, i).unwrap();
        let offset = seq.pose(i).unwrap().inverse() * Point3::from(c2.translation.vector);
        assert!((offset.coords - Vector3::new(-0.06, 0.001, -0.004)).norm() < 1e-9);
    }
    assert!(seq.has_image(1, 0) && !seq.has_image(1, 1) && !seq.has_image(3, 0));
    assert_eq!(seq.intrinsics(2).unwrap().width, 8);
    // Explicit poses path.
    let other = tmp.path().join("other_poses.txt");
    let shifted: Vec<_> = test_poses(4)
        .iter()
        .map(|p| Translation3::new(5.0, 0.0, 0.0) * p)
        .collect();
    write_poses(&other, &shifted).unwrap();
    let seq2 = KittiSequence::open(&dir, Some(&other)).unwrap();
    assert!((seq2.pose(3).unwrap().translation.x - shifted[3].translation.x).abs() < 1e-6);
}

#[test]
fn nan_points_are_dropped_and_poses_are_orthonormalised() {
    let tmp = tempfile::tempdir().unwrap();
    let bin = tmp.path().join("000000.bin");
    let pts = [
        [1.0, 2.0, 3.0],
        [f32::NAN, 0.0, 0.0],
        [4.0, 5.0, f32::INFINITY],
        [7.0, 8.0, 9.0],
    ];
    write_velodyne_bin(&bin, &pts, &[0.1, 0.2, 0.3, 0.4]).unwrap();
    let scan = read_velodyne_bin(&bin).unwrap();
    assert_eq!(scan.points_sensor_m, vec![[1.0, 2.0, 3.0], [7.0, 8.0, 9.0]]);
    assert_eq!(scan.intensity, vec![0.1, 0.4]);

    // A rotation printed with 4 digits is snapped to an exact rotation near it.
    let r = UnitQuaternion::from_euler_angles(0.3, -0.2, 0.1);
    let m = r.to_rotation_matrix().into_inner();
    let mut line = String::new();
    for row in 0..3 {
        for c in 0..3 {
            line.push_str(&format!("{:.4} ", m[(row, c)]));
        }
        line.push_str("12.5 ");
    }
    let path = tmp.path().join("poses.txt");
    std::fs::write(&path, format!("{line}\n\n{line}\n")).unwrap();
    let poses = read_poses(&path).unwrap();
    assert_eq!(poses.len(), 2);
    let q = poses[0].rotation.to_rotation_matrix().into_inner();
    assert!((q.transpose() * q - nalgebra::Matrix3::identity()).norm() < 1e-12);
    assert!(poses[0].rotation.angle_to(&r) < 1e-3);
    assert_eq!(poses[0].translation.vector, Vector3::new(12.5, 12.5, 12.5));
}

fn open_err(dir: &Path, poses: Option<&Path>) -> String {
    KittiSequence::open(dir, poses).unwrap_err().to_string()
}

#[test]
fn missing_or_malformed_calib() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = write_sequence(tmp.path(), 2);
    let calib = dir.join("calib.txt");
    let good = std::fs::read_to_string(&calib).unwrap();

    std::fs::remove_file(&calib).unwrap();
    let e = open_err(&dir, None);
    assert!(e.contains("calib.txt"), "{e}");

    // Line 3 (P2) has 11 numbers.
    let mut lines: Vec<String> = good.lines().map(String::from).collect();
    lines[2] = lines[2].rsplit_once(' ').unwrap().0.to_string();
    std::fs::write(&calib, lines.join("\n")).unwrap();
    let e = open_err(&dir, None);
    assert!(
        e.contains("calib.txt") && e.contains("line 3") && e.contains("P2"),
        "{e}"
    );

    lines = good.lines().map(String::from).collect();
    lines[1] = lines[1].replacen("e+02", "e+0x", 1);
    std::fs::write(&calib, lines.join("\n")).unwrap();
    let e = open_err(&dir, None);
    assert!(
        e.contains("calib.txt") && e.contains("line 2") && e.contains("not a number"),
        "{e}"
    );

    lines = good.lines().map(String::from).collect();
    lines.remove(4); // Tr
    std::fs::write(&calib, lines.join("\n")).unwrap();
    let e = open_err(&dir, None);
    assert!(e.contains("calib.txt") && e.contains("Tr"), "{e}");
}

#[test]
fn pose_count_mismatch() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = write_sequence(tmp.path(), 3);
    let poses = tmp.path().join("poses/07.txt");
    // 2 poses vs 3 timestamps.
    write_poses(&poses, &test_poses(2)).unwrap();
    let e = open_err(&dir, None);
    assert!(
        e.contains("07.txt") && e.contains("mismatch") && e.contains('2') && e.contains('3'),
        "{e}"
    );
    // Without times.txt the poses decide the length; image_0/velodyne hold 3 frames.
    std::fs::remove_file(dir.join("times.txt")).unwrap();
    let e = open_err(&dir, None);
    assert!(e.contains("07.txt") && e.contains("mismatch"), "{e}");
    // With 3 poses again it opens; an explicit poses path that does not exist is an error.
    write_poses(&poses, &test_poses(3)).unwrap();
    assert_eq!(KittiSequence::open(&dir, None).unwrap().len(), 3);
    let e = open_err(&dir, Some(&tmp.path().join("nope.txt")));
    assert!(e.contains("nope.txt"), "{e}");
    // A stray frame beyond the sequence.
    write_grey_png(dir.join("image_1/000007.png"), &grey(0)).unwrap();
    let e = open_err(&dir, None);
    assert!(e.contains("000007.png"), "{e}");
}

#[test]
fn corrupt_image_and_truncated_scan() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = write_sequence(tmp.path(), 3);
    std::fs::write(
        dir.join("image_0/000001.png"),
        b"\x89PNG\r\n\x1a\nthis is not a png",
    )
    .unwrap();
    let seq = KittiSequence::open(&dir, None).unwrap();
    let e = seq.grey(0, 1).unwrap_err().to_string();
    assert!(e.contains("000001.png"), "{e}");
    assert!(seq.grey(0, 2).is_ok());

    let bin = dir.join("velodyne/000002.bin");
    let bytes = std::fs::read(&bin).unwrap();
    std::fs::write(&bin, &bytes[..bytes.len() - 5]).unwrap();
    let e = seq.velodyne(2).unwrap_err().to_string();
    assert!(
        e.contains("000002.bin") && e.contains("multiple of 16"),
        "{e}"
    );
    assert!(seq.velodyne(1).is_ok());
    let e = seq.velodyne(3).unwrap_err().to_string();
    assert!(e.contains("000003.bin"), "{e}");
}
