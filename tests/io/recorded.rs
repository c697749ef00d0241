//! Inputs users record (issue 38): folders of scans with a trajectory and ROS 2 bags, written by
//! independent writers (`tools/make_input_fixtures.py`: rosbags, pypcd4, plyfile, laspy) from
//! the real KITTI frames, read by `denser` and fused; each map is compared with the map fused
//! from the same frames in the KITTI layout.
//!
//! Stated tolerances: the fixtures' poses are the KITTI poses snapped to rotations by numpy and
//! printed with 17 digits, so a scan's world points differ from the KITTI reader's by float64
//! rounding (1.5e-13 m measured) and ASCII PCD's 10 decimals (5.8e-11 m): those maps are
//! identical, voxel for voxel. LAS/LAZ quantise coordinates to 1e-5 m: the same blocks, about
//! 1e-4 of the voxels with another weight or Ω and TSDFs up to 10 quanta apart (measured on 3
//! KITTI frames; the test allows 5e-4 and 32).

use crate::common::{shared_data, skip};
use denser::backend::Backend;
use denser::io::sequence::{
    open_input, open_sequence, InputOptions, RangeInput, RangeSource, Sequence,
};
use denser::reconstruct::{ReconstructionConfig, Reconstructor};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

const FRAMES: usize = 3;

/// The fixtures, made once per test process (`None`: skipped, with the reason printed).
fn fixtures() -> Option<&'static Path> {
    static DIR: OnceLock<Option<PathBuf>> = OnceLock::new();
    let dir = DIR.get_or_init(|| {
        let seq = shared_data("kitti_odom00_frames000-005")?.join("sequences/00");
        // One copy under target/ (the script rewrites it on every run).
        let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("recorded-inputs");
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/make_input_fixtures.py");
        let run = std::process::Command::new("python3")
            .arg(&script)
            .arg(&seq)
            .arg(&out)
            .args(["--frames", &FRAMES.to_string()])
            .output();
        match run {
            Ok(o) if o.status.success() => Some(out),
            Ok(o) => {
                let why = String::from_utf8_lossy(&o.stderr);
                assert_eq!(o.status.code(), Some(3), "the fixture script failed: {why}");
                skip(&format!("fixtures not made: {}", why.trim()));
                None
            }
            Err(e) => {
                skip(&format!("python3 cannot run ({e}): fixtures not made"));
                None
            }
        }
    });
    if dir.is_none() {
        skip("no fixtures (see the first SKIPPED line of this binary)");
    }
    dir.as_deref()
}

fn kitti_reference() -> Box<dyn Sequence> {
    let seq = shared_data("kitti_odom00_frames000-005")
        .unwrap()
        .join("sequences/00");
    open_sequence(&seq, RangeSource::Lidar, None, None).unwrap()
}

fn fuse(seq: &dyn Sequence) -> denser::grid::Layer {
    let mut rec =
        Reconstructor::in_memory(ReconstructionConfig::paper(0.1), Backend::cpu()).unwrap();
    let frames: Vec<usize> = (0..seq.len()).collect();
    rec.fuse_sequence(seq, &frames).unwrap();
    rec.layer().clone()
}

/// Largest point distance (world frame) between two reads of the same scans, metres.
fn world_point_gap_m(a: &dyn Sequence, b: &dyn Sequence) -> f64 {
    assert_eq!(a.len(), b.len(), "{} vs {}", a.describe(), b.describe());
    let mut worst = 0.0f64;
    for i in 0..a.len() {
        let (RangeInput::Lidar(sa), RangeInput::Lidar(sb)) =
            (a.read(i).unwrap(), b.read(i).unwrap())
        else {
            panic!("not LiDAR");
        };
        assert_eq!(
            sa.points_sensor_m.len(),
            sb.points_sensor_m.len(),
            "scan {i}: point count"
        );
        for (p, q) in sa.points_sensor_m.iter().zip(&sb.points_sensor_m) {
            let wp =
                sa.world_from_sensor * nalgebra::Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            let wq =
                sb.world_from_sensor * nalgebra::Point3::new(q[0] as f64, q[1] as f64, q[2] as f64);
            worst = worst.max((wp - wq).norm());
        }
    }
    worst
}

/// Same blocks; returns (voxels compared, voxels whose weight or Ω differs, largest TSDF
/// difference in quanta).
fn map_difference(a: &denser::grid::Layer, b: &denser::grid::Layer) -> (usize, usize, i32) {
    assert_eq!(
        a.indices_sorted(),
        b.indices_sorted(),
        "the maps hold different blocks"
    );
    let (mut n, mut differ, mut worst) = (0, 0, 0);
    for idx in a.indices_sorted() {
        let (x, y) = (a.get(&idx).unwrap(), b.get(&idx).unwrap());
        for k in 0..x.tsdf.len() {
            n += 1;
            if x.weight_omega[k] != y.weight_omega[k] {
                differ += 1;
            } else if x.weight_omega[k] & 0x7f > 0 {
                worst = worst.max((x.tsdf[k] as i32 - y.tsdf[k] as i32).abs());
            }
        }
    }
    (n, differ, worst)
}

fn open(dir: &Path, opts: &InputOptions) -> Box<dyn Sequence> {
    open_input(dir, opts, None).unwrap_or_else(|e| panic!("{}: {e:#}", dir.display()))
}

fn reference() -> &'static (Vec<usize>, denser::grid::Layer) {
    static R: OnceLock<(Vec<usize>, denser::grid::Layer)> = OnceLock::new();
    R.get_or_init(|| {
        let seq = kitti_reference();
        // The first FRAMES frames of the KITTI layout.
        let frames: Vec<usize> = (0..FRAMES).collect();
        let mut rec =
            Reconstructor::in_memory(ReconstructionConfig::paper(0.1), Backend::cpu()).unwrap();
        rec.fuse_sequence(seq.as_ref(), &frames).unwrap();
        (frames, rec.layer().clone())
    })
}

/// Checks one input form against the KITTI layout: points within `gap_m`, same blocks, TSDF
/// within `quanta` and at most `differ_share` of voxels with another weight or Ω.
fn check_form(seq: &dyn Sequence, gap_m: f64, quanta: i32, differ_share: f64) {
    let kitti = kitti_reference();
    struct First<'a>(&'a dyn Sequence);
    impl Sequence for First<'_> {
        fn len(&self) -> usize {
            FRAMES
        }
        fn read(&self, i: usize) -> denser::Result<RangeInput> {
            self.0.read(i)
        }
        fn describe(&self) -> String {
            self.0.describe()
        }
        fn fingerprint(&self) -> u64 {
            0
        }
    }
    let gap = world_point_gap_m(&First(kitti.as_ref()), seq);
    assert!(
        gap <= gap_m,
        "{}: world points {gap:e} m apart",
        seq.describe()
    );
    let (n, differ, worst) = map_difference(&reference().1, &fuse(seq));
    let share = differ as f64 / n as f64;
    eprintln!("{}: points ≤ {gap:.1e} m apart; {n} voxels, {differ} of other weight/Ω, TSDF ≤ {worst} quanta", seq.describe());
    assert!(
        share <= differ_share && worst <= quanta,
        "{}: {differ} of {n} voxels differ, TSDF up to {worst} quanta",
        seq.describe()
    );
}

#[test]
fn folders_of_scans_fuse_as_the_kitti_layout() {
    let Some(fx) = fixtures() else { return };
    let lidar = InputOptions::new(RangeSource::Lidar);
    for (form, gap_m, quanta, share) in [
        ("bin", 1e-9, 0, 0.0),
        ("pcd_binary", 1e-9, 0, 0.0),
        ("pcd_binary_compressed", 1e-9, 0, 0.0),
        ("ply", 1e-9, 0, 0.0),
        ("pcd_ascii", 1e-9, 1, 1e-5),
        ("las", 2e-5, 32, 5e-4),
        ("laz", 2e-5, 32, 5e-4),
    ] {
        let dir = fx.join(format!("scans_{form}"));
        // TUM trajectory with times.txt (the folder's default), then KITTI poses by order.
        let seq = open(&dir, &lidar);
        assert!(
            seq.describe().contains("by time (times.txt)"),
            "{}",
            seq.describe()
        );
        check_form(seq.as_ref(), gap_m, quanta, share);
        if form == "bin" {
            let mut by_order = lidar.clone();
            by_order.poses = Some(dir.join("poses_kitti.txt"));
            let seq = open(&dir, &by_order);
            assert!(seq.describe().contains("by order"), "{}", seq.describe());
            check_form(seq.as_ref(), gap_m, quanta, share);
            // Without the extrinsic the scans sit at the body's pose: another map.
            std::fs::rename(dir.join("extrinsic.txt"), dir.join("x.txt")).unwrap();
            let bare = open(&dir, &lidar);
            std::fs::rename(dir.join("x.txt"), dir.join("extrinsic.txt")).unwrap();
            assert!(world_point_gap_m(seq.as_ref(), bare.as_ref()) > 0.1);
        }
    }
    // Time stamps from the file names, poses interpolated at them: the names round the stamps
    // to the microsecond (the trajectory has them to 0.1 µs), which moves a pose by up to
    // 1 µs × the car's speed (≈ 10 m/s).
    let seq = open(&fx.join("scans_stamped"), &lidar);
    assert!(seq.describe().contains("file names"), "{}", seq.describe());
    check_form(seq.as_ref(), 2e-5, 32, 5e-4);
}

#[test]
fn bags_fuse_as_the_kitti_layout() {
    let Some(fx) = fixtures() else { return };
    let lidar = InputOptions::new(RangeSource::Lidar);
    for (bag, pose_source) in [
        ("bag_mcap", "/tf"),
        ("bag_sqlite", "/odom (nav_msgs/msg/Odometry)"),
        ("bag_pose_stamped", "/pose (geometry_msgs/msg/PoseStamped)"),
        ("bag_double", "/tf"),
        ("bag_no_metadata", "/tf"),
    ] {
        let seq = open(&fx.join(bag), &lidar);
        assert!(seq.describe().contains(pose_source), "{}", seq.describe());
        assert_eq!(seq.len(), FRAMES, "{}", seq.describe());
        if bag == "bag_double" {
            // Organised as 2 rows: an odd scan loses its last point; compare the points only.
            let kitti = kitti_reference();
            let RangeInput::Lidar(s) = seq.read(0).unwrap() else {
                panic!()
            };
            let RangeInput::Lidar(k) = kitti.read(0).unwrap() else {
                panic!()
            };
            let n = k.points_sensor_m.len() / 2 * 2;
            assert_eq!(s.points_sensor_m, k.points_sensor_m[..n]);
            continue;
        }
        check_form(seq.as_ref(), 1e-9, 0, 0.0);
    }
    // A single .mcap file is a bag too.
    let file = fx.join("bag_mcap/bag_mcap.mcap");
    assert_eq!(open(&file, &lidar).len(), FRAMES);
}

fn open_err(dir: &Path, opts: &InputOptions) -> String {
    match open_input(dir, opts, None) {
        Ok(s) => panic!("{} opened: {}", dir.display(), s.describe()),
        Err(e) => format!("{e:#}"),
    }
}

#[test]
fn damaged_and_odd_bags_say_what_is_wrong() {
    let Some(fx) = fixtures() else { return };
    let lidar = InputOptions::new(RangeSource::Lidar);
    // No /tf_static: the scans' frame hangs from nothing.
    let e = open_err(&fx.join("bag_no_tf_static"), &lidar);
    assert!(
        e.contains("velodyne") && e.contains("/tf_static missing"),
        "{e}"
    );
    // A topic of the wrong type, and one that does not exist.
    let mut wrong = lidar.clone();
    wrong.bag.lidar_topic = Some("/tf".into());
    let e = open_err(&fx.join("bag_mcap"), &wrong);
    assert!(
        e.contains("--lidar-topic /tf")
            && e.contains("tf2_msgs/msg/TFMessage")
            && e.contains("PointCloud2"),
        "{e}"
    );
    wrong.bag.lidar_topic = Some("/nope".into());
    let e = open_err(&fx.join("bag_mcap"), &wrong);
    assert!(
        e.contains("no such topic") && e.contains("/points (sensor_msgs/msg/PointCloud2)"),
        "{e}"
    );
    // A fixed frame that is not above the scans.
    let mut frame = lidar.clone();
    frame.bag.fixed_frame = Some("odom".into());
    let e = open_err(&fx.join("bag_mcap"), &frame);
    assert!(
        e.contains("--fixed-frame odom") && e.contains("velodyne → base_link → map"),
        "{e}"
    );
    // A cut file: read up to the damage, the scans before it fused.
    let cut = open(&fx.join("bag_cut"), &lidar);
    let whole = open(&fx.join("bag_mcap"), &lidar);
    assert!(
        !cut.is_empty() && cut.len() < whole.len(),
        "cut {} whole {}",
        cut.len(),
        whole.len()
    );
    for i in 0..cut.len() {
        let (RangeInput::Lidar(a), RangeInput::Lidar(b)) =
            (cut.read(i).unwrap(), whole.read(i).unwrap())
        else {
            panic!()
        };
        assert_eq!(
            (a.points_sensor_m, a.world_from_sensor),
            (b.points_sensor_m, b.world_from_sensor)
        );
    }
    // Damaged bytes. The fixture's writer stores no chunk CRCs (rosbags writes 0: "not
    // computed"), so a flipped byte inside compressed data cannot always be seen; what is checked
    // there is that nothing panics and a scan either reads or fails naming the file. A damaged
    // record length is always seen: the file is read up to that record.
    let original = std::fs::read(fx.join("bag_mcap/bag_mcap.mcap")).unwrap();
    let chunks = mcap_chunk_offsets(&original);
    assert_eq!(chunks.len(), FRAMES, "one chunk per scan in this fixture");
    let damaged = std::env::temp_dir().join(format!("denser-damaged-{}.mcap", std::process::id()));
    let mut bytes = original.clone();
    bytes[chunks[1] + 8] = 0x7f; // the second chunk's length's top byte: ~2^62 bytes
    std::fs::write(&damaged, &bytes).unwrap();
    let seq = open(&damaged, &lidar);
    assert_eq!(seq.len(), 1, "{}", seq.describe());
    let bag = denser::io::bag::Bag::open(&damaged).unwrap();
    let survey = bag.survey().unwrap();
    let d = &survey.damage[0];
    // The offset is where reading stopped: within the read-ahead (64 KiB) past the record.
    assert!(
        (chunks[1]..chunks[1] + (128 << 10)).contains(&(d.offset as usize)),
        "{d}"
    );
    assert!(
        d.to_string().contains("denser-damaged") && d.message.contains("length"),
        "{d}"
    );
    let mut bytes = original.clone();
    bytes[chunks[2] + 600_000] ^= 0x5a; // inside the third chunk's zstd data
    std::fs::write(&damaged, &bytes).unwrap();
    match open_input(&damaged, &lidar, None) {
        Ok(seq) => {
            for i in 0..seq.len() {
                if let Err(e) = seq.read(i) {
                    assert!(e.to_string().contains("denser-damaged"), "{e}");
                }
            }
        }
        Err(e) => assert!(e.to_string().contains("denser-damaged"), "{e}"),
    }
    std::fs::remove_file(&damaged).unwrap();
    // Scans out of time order: counted, each with its own pose.
    let unordered =
        denser::io::bag::BagLidar::open(&fx.join("bag_unordered"), &Default::default()).unwrap();
    assert_eq!(unordered.selection().out_of_order, 1);
    let poses: Vec<_> = (0..FRAMES)
        .map(|i| match unordered.read(i).unwrap() {
            RangeInput::Lidar(s) => s.world_from_sensor,
            _ => panic!(),
        })
        .collect();
    let expected: Vec<_> = [0, 2, 1]
        .iter()
        .map(|&i| match whole.read(i).unwrap() {
            RangeInput::Lidar(s) => s.world_from_sensor,
            _ => panic!(),
        })
        .collect();
    assert_eq!(poses, expected);
    // Stereo from a bag without images, and ground-truth depth from any bag, are refused.
    let sgm = || denser::depth::StereoMethod::Sgm.estimator(32).unwrap();
    let e = match open_input(
        &fx.join("bag_mcap"),
        &InputOptions::new(RangeSource::Stereo),
        Some(sgm()),
    ) {
        Ok(_) => panic!("stereo opened on a LiDAR bag"),
        Err(e) => e.to_string(),
    };
    assert!(
        e.contains("--left-topic and --right-topic (image topics: none)"),
        "{e}"
    );
    let e = open_err(
        &fx.join("bag_mcap"),
        &InputOptions::new(RangeSource::GroundTruthDepth),
    );
    assert!(e.contains("use --depth lidar or --depth stereo"), "{e}");
}

#[test]
fn reconstruct_and_inspect_input_take_a_bag() {
    let Some(fx) = fixtures() else { return };
    let bin = env!("CARGO_BIN_EXE_denser");
    let bag = fx.join("bag_sqlite");
    let out = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let o = std::process::Command::new(bin).args(args).output().unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
        (o.status.success(), text)
    };
    let (ok, text) = run(&["inspect-input", bag.to_str().unwrap()]);
    assert!(ok, "{text}");
    for line in [
        "ROS 2 bag",
        "/odom",
        "nav_msgs/msg/Odometry",
        &format!("would fuse: {FRAMES} of {FRAMES} scans on /points (frame 'velodyne')"),
        "fixed frame 'map'",
    ] {
        assert!(text.contains(line), "{line:?} missing from:\n{text}");
    }
    let (ok, text) = run(&[
        "inspect-input",
        bag.to_str().unwrap(),
        "--pose-topic",
        "/points",
    ]);
    assert!(ok, "{text}");
    assert!(
        text.contains(
            "cannot fuse: --pose-topic /points: the topic is sensor_msgs/msg/PointCloud2"
        ),
        "{text}"
    );
    let dir = out.path().join("run");
    let (ok, text) = run(&[
        "reconstruct",
        bag.to_str().unwrap(),
        "--out",
        dir.to_str().unwrap(),
        "--no-eval",
        "--iterations",
        "5",
    ]);
    assert!(ok, "{text}");
    let mesh = denser::io::ply::read_mesh_ply(dir.join("mesh_regularized.ply")).unwrap();
    assert!(
        mesh.triangles.len() > 10_000,
        "{} triangles",
        mesh.triangles.len()
    );
    // A folder of scans is scored against its own scans by default, as KITTI is; with --holdout
    // against the scans left out.
    let scans = fx.join("scans_bin");
    let dir = out.path().join("scans");
    let (ok, text) = run(&[
        "reconstruct",
        scans.to_str().unwrap(),
        "--out",
        dir.to_str().unwrap(),
        "--iterations",
        "5",
        "--holdout",
        "3",
    ]);
    assert!(ok, "{text}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    let gt = report["source"].as_str().unwrap_or_default().to_string();
    assert!(
        gt.contains("LiDAR scans of") && gt.contains("scans_bin") && gt.contains("step 3"),
        "{report}"
    );
}

/// Stereo pairs of a synthetic drive as `Image` and `CompressedImage` bags: the same depth maps
/// and the same map as the drive's KITTI layout (the bag's images are the same grey PNGs, its
/// `CameraInfo` holds `calib.txt`'s P0 and P1, its `/tf` the drive's poses).
#[test]
fn stereo_bags_match_the_kitti_layout() {
    if fixtures().is_none() {
        return;
    }
    let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("recorded-stereo");
    let _ = std::fs::remove_dir_all(&root);
    let mut drive = denser::synth::DriveConfig {
        surface: None,
        ..Default::default()
    };
    drive.city.length_m = 3.0;
    let written = denser::synth::write_drive(&drive, &root.join("drive"), false).unwrap();
    let out = root.join("fixtures");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/make_input_fixtures.py");
    let o = std::process::Command::new("python3")
        .arg(&script)
        .arg(&written.sequence_dir)
        .arg(&out)
        .args(["--frames", "2"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let sgm = || denser::depth::StereoMethod::Sgm.estimator(48).unwrap();
    let kitti = open_sequence(
        &written.sequence_dir,
        RangeSource::Stereo,
        None,
        Some(sgm()),
    )
    .unwrap();
    let mut stereo = InputOptions::new(RangeSource::Stereo);
    for bag in ["bag_stereo", "bag_stereo_compressed"] {
        let seq = open_input(&out.join(bag), &stereo, Some(sgm())).unwrap();
        assert_eq!(seq.len(), 2, "{}", seq.describe());
        for i in 0..2 {
            let (RangeInput::Depth(a), RangeInput::Depth(b)) =
                (kitti.read(i).unwrap(), seq.read(i).unwrap())
            else {
                panic!("not depth");
            };
            assert_eq!(a.intrinsics, b.intrinsics, "{bag} frame {i}");
            let same_nan = a
                .depth_m
                .data
                .iter()
                .zip(&b.depth_m.data)
                .all(|(x, y)| x == y || (x.is_nan() && y.is_nan()));
            assert!(same_nan, "{bag} frame {i}: depth maps differ");
            let gap = (a.world_from_camera.translation.vector
                - b.world_from_camera.translation.vector)
                .norm();
            assert!(gap < 1e-9, "{bag} frame {i}: poses {gap} m apart");
        }
    }
    // Raw (unrectified) images are refused, saying what to do.
    let e = match open_input(&out.join("bag_stereo_raw"), &stereo, Some(sgm())) {
        Ok(_) => panic!("raw images opened"),
        Err(e) => e.to_string(),
    };
    assert!(
        e.contains("/stereo/left/image_raw holds raw images") && e.contains("rectify"),
        "{e}"
    );
    // Topics named by flag, one of them wrong.
    stereo.bag.left_topic = Some("/stereo/left/camera_info".into());
    let e = match open_input(&out.join("bag_stereo"), &stereo, Some(sgm())) {
        Ok(_) => panic!("opened"),
        Err(e) => e.to_string(),
    };
    assert!(
        e.contains(
            "--left-topic /stereo/left/camera_info: the topic is sensor_msgs/msg/CameraInfo"
        ),
        "{e}"
    );
}

/// Byte offsets of the chunk records (opcode 0x06) of an MCAP file, walking its records.
fn mcap_chunk_offsets(b: &[u8]) -> Vec<usize> {
    let mut at = 8; // the magic
    let mut out = Vec::new();
    while at + 9 <= b.len() {
        let op = b[at];
        let len = u64::from_le_bytes(b[at + 1..at + 9].try_into().unwrap()) as usize;
        if op == 0x06 {
            out.push(at);
        }
        if op == 0x0f {
            break; // the footer
        }
        at += 9 + len;
    }
    out
}
