//! The pipeline on the real data in ../shared/data (skipped when absent): KITTI seq 00 LiDAR
//! fusion scored against its own scans, RGB-D fusion of the slambook2 frames, and the baseline
//! stereo matcher on KITTI frame 0 scored against the LiDAR scan projected into image_0.

use crate::common;

use denser::depth::{disparity_from_points, evaluate_disparity, StereoMethod};
use denser::eval::{evaluate_reconstruction, GroundTruth, RunFacts};
use denser::io::kitti::KittiSequence;
use denser::io::sequence::{detect_input, open_sequence, FrameRange, InputKind, RangeSource};
use denser::mesh::Field;
use denser::reconstruct::{ReconstructionConfig, Reconstructor};

/// Every frame of `input` fused in RAM on the CPU.
fn fuse(input: &std::path::Path, config: ReconstructionConfig) -> Reconstructor {
    let seq = open_sequence(input, RangeSource::Lidar, None, None).expect("sequence");
    let mut rec = Reconstructor::new(config).expect("config");
    rec.fuse_sequence(seq.as_ref(), &FrameRange::ALL.indices(seq.len()))
        .expect("fusion");
    rec
}

#[test]
fn kitti_lidar_fusion_against_its_scans() {
    let Some(root) = common::shared_data("kitti_odom00_frames000-005") else {
        return;
    };
    let seq_dir = root.join("sequences/00");
    let out = tempfile::tempdir().expect("tempdir");
    let mut config = ReconstructionConfig::paper(0.2);
    config.tv.iterations = 50;
    let mut rec = fuse(&seq_dir, config);
    assert_eq!(rec.timings().frames_fused, 6);
    let results = rec
        .write_results(out.path(), true, &mut |_, _| true)
        .expect("meshes");
    let gt = GroundTruth::KittiLidar {
        sequence: seq_dir,
        poses: None,
        frames: FrameRange::ALL,
    };
    let (report, _) = evaluate_reconstruction(
        &RunFacts::of(&rec),
        &results.surfaces,
        results.regularize.as_ref(),
        &gt,
        "KITTI 00 frames 0-5 LiDAR",
        &[],
        out.path(),
    )
    .expect("evaluation");
    let (raw, reg) = (&report.surfaces[0], &report.surfaces[1]);
    eprintln!(
        "KITTI LiDAR 20 cm: raw median {:.3} p75 {:.3} area {:.0}; regularized median {:.3} p75 {:.3} area {:.0}; {} GT points",
        raw.accuracy.median_m, raw.accuracy.p75_m, raw.surface_area_m2, reg.accuracy.median_m, reg.accuracy.p75_m, reg.surface_area_m2, report.ground_truth_points
    );
    assert!(report.ground_truth_points > 700_000);
    assert!(raw.triangles > 50_000, "{} triangles", raw.triangles);
    // Surfaces fused from the scans lie within a voxel (0.2 m) of them; measured 0.112 m raw,
    // 0.091 m regularized (point-to-point distances include the LiDAR's own point spacing).
    assert!(
        raw.accuracy.median_m < 0.2 && reg.accuracy.median_m < raw.accuracy.median_m,
        "{} / {}",
        raw.accuracy.median_m,
        reg.accuracy.median_m
    );
    assert!(reg.surface_area_m2 < raw.surface_area_m2);
    for f in [
        "mesh_raw.ply",
        "mesh_regularized.ply",
        "report.json",
        "report.md",
        "error_histogram.png",
    ] {
        assert!(out.path().join(f).is_file(), "{f}");
    }
}

#[test]
fn rgbd_frames_fuse_into_a_coloured_mesh() {
    let Some(dir) = common::shared_data("rgbd_5frames_slambook2") else {
        return;
    };
    assert_eq!(detect_input(&dir).expect("layout"), InputKind::SimpleRgbd);
    let out = tempfile::tempdir().expect("tempdir");
    let mut config = ReconstructionConfig::paper(0.05);
    config.grid.truncation_m = 0.2;
    config.tv.iterations = 30;
    let mut rec = fuse(&dir, config);
    assert_eq!(rec.timings().frames_fused, 5);
    let mesh = rec.mesh(Field::Raw).expect("mesh");
    eprintln!(
        "RGB-D: {} blocks, {} triangles, {:.1} m²",
        rec.layer().block_count(),
        mesh.triangles.len(),
        mesh.surface_area_m2()
    );
    assert!(mesh.triangles.len() > 20_000);
    // A room: the surface spans metres, and the colours are not all one value.
    assert!(mesh.surface_area_m2() > 5.0);
    let distinct: std::collections::HashSet<[u8; 3]> = mesh.colors.iter().copied().collect();
    assert!(distinct.len() > 1000, "{} distinct colours", distinct.len());
    let results = rec
        .write_results(out.path(), true, &mut |_, _| true)
        .expect("write");
    assert_eq!(results.files().len(), 3);
    assert!(results.files().iter().all(|p| p.is_file()));
}

#[test]
fn sgm_on_kitti_frame0_against_projected_lidar() {
    let Some(root) = common::shared_data("kitti_odom00_frames000-005") else {
        return;
    };
    let seq = KittiSequence::open(root.join("sequences/00"), None).expect("sequence");
    let (left, right) = (
        seq.grey(0, 0).expect("image_0"),
        seq.grey(1, 0).expect("image_1"),
    );
    let k = seq.intrinsics(0).expect("intrinsics");
    let baseline = seq.calib().baseline_m(0, 1);
    let scan = seq.velodyne(0).expect("scan");
    let cam0_from_velo = seq.calib().cam_from_velo(0);
    let points: Vec<[f64; 3]> = scan
        .points_sensor_m
        .iter()
        .map(|p| {
            let c = cam0_from_velo * nalgebra::Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            [c.x, c.y, c.z]
        })
        .collect();
    let gt = disparity_from_points(&points, &k, baseline);
    let pred = StereoMethod::Sgm
        .estimator(128)
        .expect("sgm")
        .estimate(&left, &right)
        .expect("disparity");
    let m = evaluate_disparity(&pred.disparity_px, &gt, None).expect("metrics");
    eprintln!(
        "KITTI 00 frame 0, SGM vs projected LiDAR: D1 {:.1} %, EPE {:.2} px, density {:.1} %, bad-3 {:.1} % over {} LiDAR pixels",
        m.d1_pct, m.epe_px, m.density_pct, m.bad3_pct, m.gt_pixels
    );
    assert!(m.gt_pixels > 10_000);
    assert!(m.density_pct > 70.0, "density {}", m.density_pct);
    // Measured D1 29.2 %, EPE 2.25 px. The projected scan is unfiltered: LiDAR points hidden
    // from the camera (it sits 0.27 m lower and 0.08 m ahead) leak into gaps between foreground
    // points and count as errors.
    assert!(m.d1_pct < 35.0, "D1 {}", m.d1_pct);
    assert!(m.epe_px < 3.0, "EPE {}", m.epe_px);
}
