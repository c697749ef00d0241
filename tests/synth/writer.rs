//! The KITTI-layout writer: exact file layout, calib format, decodable images whose depth matches
//! the renderer, LiDAR binaries, PLY surface file, and byte-identical output for a seed.

use denser::synth::{
    write_drive, City, CityConfig, DriveConfig, LidarConfig, StereoRig, SurfaceSampling,
};
use std::path::Path;

fn config(seed: u64) -> DriveConfig {
    DriveConfig {
        city: CityConfig {
            seed,
            length_m: 60.0,
            frame_spacing_m: 1.0,
            max_frames: Some(3),
            ..Default::default()
        },
        rig: StereoRig::kitti().scaled(160, 48),
        lidar: Some(LidarConfig {
            azimuth_steps: 180,
            ..Default::default()
        }),
        surface: Some(SurfaceSampling {
            spacing_m: 0.5,
            max_distance_to_route_m: Some(12.0),
        }),
        ..Default::default()
    }
}

fn files(root: &Path) -> Vec<String> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(
                    p.strip_prefix(root)
                        .unwrap()
                        .to_string_lossy()
                        .replace('\\', "/"),
                );
            }
        }
    }
    out.sort();
    out
}

#[test]
fn writes_the_kitti_layout_with_exact_calib_and_decodable_files() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(5);
    let summary = write_drive(&cfg, dir.path(), false).unwrap();
    assert_eq!(summary.frames, 3);
    let mut expected = vec![
        "ground_truth/surface.ply".to_string(),
        "poses/00.txt".into(),
        "synth.json".into(),
        "sequences/00/calib.txt".into(),
        "sequences/00/times.txt".into(),
    ];
    for i in 0..3 {
        for sub in ["image_0", "image_1", "image_2", "image_3", "depth_gt"] {
            expected.push(format!("sequences/00/{sub}/{i:06}.png"));
        }
        expected.push(format!("sequences/00/velodyne/{i:06}.bin"));
    }
    expected.sort();
    assert_eq!(files(dir.path()), expected);

    // calib.txt: five lines 'NAME: ' + 12 numbers like '%.12e'.
    let calib = std::fs::read_to_string(dir.path().join("sequences/00/calib.txt")).unwrap();
    let lines: Vec<&str> = calib.lines().collect();
    assert_eq!(lines.len(), 5);
    let k = cfg.rig.intrinsics;
    for (line, name) in lines.iter().zip(["P0", "P1", "P2", "P3", "Tr"]) {
        let (head, rest) = line.split_once(": ").unwrap();
        assert_eq!(head, name);
        let toks: Vec<&str> = rest.split(' ').collect();
        assert_eq!(toks.len(), 12, "{line}");
        for t in &toks {
            let (m, e) = t.split_once('e').unwrap();
            let m = m.trim_start_matches('-');
            assert!(m.len() == 14 && m.as_bytes()[1] == b'.', "{t}");
            assert!(
                e.len() == 3 && (e.starts_with('+') || e.starts_with('-')),
                "{t}"
            );
        }
        let v: Vec<f64> = toks.iter().map(|t| t.parse().unwrap()).collect();
        if name.starts_with('P') {
            assert!(
                (v[0] - k.fx).abs() < 1e-9
                    && (v[2] - k.cx).abs() < 1e-9
                    && (v[6] - k.cy).abs() < 1e-9
            );
        }
        if name == "P1" || name == "P3" {
            assert!((v[3] + k.fx * cfg.rig.baseline_m).abs() < 1e-9, "{line}");
        }
        if name == "Tr" {
            // KITTI seq 00's velodyne→cam0 translation.
            assert!(
                (v[3] + 0.01198).abs() < 1e-4 && (v[11] + 0.29220).abs() < 1e-4,
                "{line}"
            );
        }
    }
    // Full-size rig: P1[0,3] is KITTI's −386.1448.
    let full =
        denser::synth::calib_text(&StereoRig::kitti(), &denser::synth::kitti_cam0_from_velo());
    assert!(
        full.starts_with(
            "P0: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 0.000000000000e+00"
        ),
        "{full}"
    );
    assert!(
        full.lines()
            .nth(1)
            .unwrap()
            .contains(" -3.861448000000e+02 "),
        "{full}"
    );

    let poses = std::fs::read_to_string(dir.path().join("poses/00.txt")).unwrap();
    assert_eq!(poses.lines().count(), 3);
    assert!(
        poses
            .lines()
            .next()
            .unwrap()
            .starts_with("1.000000e+00 0.000000e+00 0.000000e+00 0.000000e+00"),
        "{poses}"
    );
    let times = std::fs::read_to_string(dir.path().join("sequences/00/times.txt")).unwrap();
    assert_eq!(times, "0.000000e+00\n1.000000e-01\n2.000000e-01\n");

    // Images decode at the rig size; depth_gt holds round(256·depth) of the renderer's depth.
    let g = image::open(dir.path().join("sequences/00/image_0/000001.png")).unwrap();
    assert_eq!(
        (g.width(), g.height(), g.color()),
        (160, 48, image::ColorType::L8)
    );
    let c = image::open(dir.path().join("sequences/00/image_3/000001.png")).unwrap();
    assert_eq!(c.color(), image::ColorType::Rgb8);
    let city = City::generate(&cfg.city).unwrap();
    let frame = city.render_stereo(
        &city.frame_poses()[1],
        &cfg.rig,
        &cfg.render,
        city.frame_seed(1),
    );
    assert_eq!(g.to_luma8().into_raw(), frame.left_grey.data);
    assert_eq!(c.to_rgb8().into_raw(), frame.right_rgb.data.concat());
    let d = image::open(dir.path().join("sequences/00/depth_gt/000001.png"))
        .unwrap()
        .to_luma16();
    let mut valid = 0;
    for (i, &v) in d.as_raw().iter().enumerate() {
        let z = frame.depth_gt_m.data[i];
        assert_eq!(v, denser::synth::encode_depth_u16(z));
        if v > 0 {
            valid += 1;
            assert!((v as f32 / 256.0 - z).abs() <= 0.5 / 256.0 + 1e-6);
        }
    }
    assert!(valid > 3000, "{valid}");

    // Velodyne: float32 x y z r records.
    let bin = std::fs::read(dir.path().join("sequences/00/velodyne/000000.bin")).unwrap();
    assert_eq!(bin.len() % 16, 0);
    assert!(bin.len() / 16 > 5000);
    let scan = city.scan_lidar(
        &city.frame_poses()[0],
        cfg.lidar.as_ref().unwrap(),
        city.frame_seed(0) ^ 0x11DA,
    );
    assert_eq!(bin.len() / 16, scan.points_sensor_m.len());
    assert_eq!(
        f32::from_le_bytes(bin[0..4].try_into().unwrap()),
        scan.points_sensor_m[0][0]
    );

    // PLY: the header's count matches the binary body (27 bytes a vertex).
    let ply = std::fs::read(dir.path().join("ground_truth/surface.ply")).unwrap();
    let end = ply.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = std::str::from_utf8(&ply[..end]).unwrap();
    let n: usize = header
        .lines()
        .find(|l| l.starts_with("element vertex"))
        .unwrap()
        .split_whitespace()
        .nth(2)
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(n, summary.surface_points);
    assert!(n > 1000);
    assert_eq!(ply.len() - end, n * 27);
}

#[test]
fn two_runs_write_identical_bytes() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let mut cfg = config(8);
    cfg.surface = None;
    write_drive(&cfg, a.path(), false).unwrap();
    write_drive(&cfg, b.path(), false).unwrap();
    for f in [
        "sequences/00/image_2/000002.png",
        "sequences/00/image_1/000002.png",
        "sequences/00/depth_gt/000002.png",
        "sequences/00/velodyne/000002.bin",
        "poses/00.txt",
    ] {
        assert_eq!(
            std::fs::read(a.path().join(f)).unwrap(),
            std::fs::read(b.path().join(f)).unwrap(),
            "{f}"
        );
    }
}

#[test]
fn unwritable_output_is_reported_with_its_path() {
    let dir = tempfile::tempdir().unwrap();
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, b"x").unwrap();
    let e = write_drive(&config(1), &blocker.join("out"), false)
        .unwrap_err()
        .to_string();
    assert!(e.contains("file/out"), "{e}");
}
