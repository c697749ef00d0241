//! `denser stereo` and `denser stereo-eval` run as the real binary in fresh temporary folders:
//! a rendered pair with exact disparity goes in, the PFM that comes out is scored by the test and
//! by `stereo-eval` (which must agree), depth follows `z = f·B/d`, and bad input is named.
use crate::depth_support;

use denser::depth::{evaluate_disparity, StereoMetrics};
use denser::io::image::write_grey_png;
use denser::io::pfm::{read_pfm, write_pfm};
use std::path::Path;
use std::process::{Command, Output};

fn denser(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_denser"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("run denser")
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// KITTI-style calib.txt with fx = 500 px and a 0.5 m baseline (P1[0][3] = −fx·B).
const CALIB: &str = "P0: 500 0 100 0 0 500 40 0 0 0 1 0\n\
P1: 500 0 100 -250 0 500 40 0 0 0 1 0\n\
P2: 500 0 100 0 0 500 40 0 0 0 1 0\n\
P3: 500 0 100 -250 0 500 40 0 0 0 1 0\n\
Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n";

#[test]
fn stereo_writes_a_pfm_that_stereo_eval_scores() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let (w, h) = (200u32, 80u32);
    let (left, right, gt) = depth_support::planar_pair(w, h, 12.0, 0.02, 0.0, 5);
    write_grey_png(d.join("l.png"), &left).unwrap();
    write_grey_png(d.join("r.png"), &right).unwrap();
    std::fs::write(d.join("calib.txt"), CALIB).unwrap();
    // Ground truth with the left margin unknown (no match there), as a Middlebury PFM.
    let mut gt_known = gt.clone();
    for y in 0..h {
        for x in 0..24 {
            *gt_known.at_mut(x, y) = f32::NAN;
        }
    }
    write_pfm(d.join("gt.pfm"), &gt_known).unwrap();
    for method in ["sgm", "tgv-tensor"] {
        let o = denser(
            &[
                "stereo",
                "l.png",
                "r.png",
                "--out",
                "disp.pfm",
                "--method",
                method,
                "--num-disparities",
                "24",
                "--calib",
                "calib.txt",
                "--depth-out",
                "depth.png",
            ],
            d,
        );
        assert!(o.status.success(), "{}", text(&o));
        let pred = read_pfm(d.join("disp.pfm")).unwrap();
        assert_eq!((pred.width, pred.height), (w, h));
        // The false-colour picture beside it: black exactly where there is no disparity, and
        // the summary says what each file holds.
        let colour = denser::io::image::read_rgb(d.join("disp.png")).unwrap();
        assert_eq!((colour.width, colour.height), (w, h));
        for (c, p) in colour.data.iter().zip(&pred.data) {
            assert_eq!(*c == [0, 0, 0], !p.is_finite(), "{method}: {c:?} for {p}");
        }
        let t = text(&o);
        assert!(
            t.contains("false colour") && t.contains("depth_m = value / 256"),
            "{t}"
        );
        let m = evaluate_disparity(&pred, &gt_known, None).unwrap();
        eprintln!("{method}: {m:?}");
        assert!(
            m.epe_px < 0.15 && m.bad1_pct < 3.0 && m.density_pct > 95.0,
            "{method}: {m:?}"
        );
        // Depth: z = fx·B/d = 250/d metres, stored as value/256.
        let depth = denser::io::image::read_png_u16(d.join("depth.png")).unwrap();
        let (x, y) = (150, 40);
        let dp = pred.at(x, y);
        assert!(dp.is_finite());
        let z = depth.at(x, y) as f64 / 256.0;
        assert!(
            (z - 250.0 / dp as f64).abs() < 1.0 / 256.0 + 1e-9,
            "z {z} vs {}",
            250.0 / dp
        );
        // stereo-eval agrees with the library and writes the same numbers as JSON.
        let o = denser(
            &["stereo-eval", "gt.pfm", "disp.pfm", "--json", "m.json"],
            d,
        );
        assert!(o.status.success(), "{}", text(&o));
        let t = text(&o);
        assert!(
            t.contains(&format!("| bad-2.0 % | {:.2} |", m.bad2_pct)),
            "{t}"
        );
        assert!(t.contains(&format!("| EPE px | {:.3} |", m.epe_px)), "{t}");
        let json: StereoMetrics =
            serde_json::from_str(&std::fs::read_to_string(d.join("m.json")).unwrap()).unwrap();
        assert_eq!(json, m);
    }
    // --dense keeps every pixel whose match lies inside the right image.
    let o = denser(
        &[
            "stereo",
            "l.png",
            "r.png",
            "--out",
            "dense.pfm",
            "--num-disparities",
            "24",
            "--dense",
        ],
        d,
    );
    assert!(o.status.success(), "{}", text(&o));
    let dense = read_pfm(d.join("dense.pfm")).unwrap();
    let m = evaluate_disparity(&dense, &gt_known, None).unwrap();
    assert_eq!(m.density_pct, 100.0, "{m:?}");
    assert!(m.epe_px < 0.15, "{m:?}");
}

#[test]
fn stereo_eval_counts_missing_predictions_as_errors_and_reads_kitti_png() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    // 4×1: GT 10, 20, 30, unknown; prediction 10.5, missing, 34, 7.
    let gt = denser::frame::Image {
        width: 4,
        height: 1,
        data: vec![10.0, 20.0, 30.0, f32::NAN],
    };
    let pred = denser::frame::Image {
        width: 4,
        height: 1,
        data: vec![10.5, f32::NAN, 34.0, 7.0],
    };
    denser::depth::disparity_io::write_kitti_disparity_png(d.join("gt.png"), &gt).unwrap();
    write_pfm(d.join("pred.pfm"), &pred).unwrap();
    let o = denser(
        &["stereo-eval", "gt.png", "pred.pfm", "--json", "m.json"],
        d,
    );
    assert!(o.status.success(), "{}", text(&o));
    let m: StereoMetrics =
        serde_json::from_str(&std::fs::read_to_string(d.join("m.json")).unwrap()).unwrap();
    assert_eq!(m.gt_pixels, 3);
    // bad-2: missing + |34 − 30| → 2 of 3; bad-1 the same; D1 (> 3 px and > 5 %): 2 of 3.
    assert!((m.bad2_pct - 200.0 / 3.0).abs() < 1e-9, "{m:?}");
    assert!((m.d1_pct - 200.0 / 3.0).abs() < 1e-9, "{m:?}");
    assert!((m.epe_px - 2.25).abs() < 1e-6, "{m:?}");
    assert!((m.density_pct - 200.0 / 3.0).abs() < 1e-9, "{m:?}");
}

#[test]
fn stereo_commands_name_missing_and_mismatched_files() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let (left, right, gt) = depth_support::planar_pair(40, 20, 3.0, 0.0, 0.0, 1);
    write_grey_png(d.join("l.png"), &left).unwrap();
    write_grey_png(d.join("r.png"), &right).unwrap();
    let o = denser(&["stereo", "l.png", "nope_right.png", "--out", "x.pfm"], d);
    assert!(!o.status.success());
    assert!(text(&o).contains("nope_right.png"), "{}", text(&o));
    let o = denser(&["stereo-eval", "missing_gt.pfm", "x.pfm"], d);
    assert!(!o.status.success());
    assert!(text(&o).contains("missing_gt.pfm"), "{}", text(&o));
    // Size mismatch names the prediction.
    write_pfm(d.join("gt.pfm"), &gt).unwrap();
    write_pfm(
        d.join("small.pfm"),
        &denser::frame::Image {
            width: 3,
            height: 2,
            data: vec![1.0; 6],
        },
    )
    .unwrap();
    let o = denser(&["stereo-eval", "gt.pfm", "small.pfm"], d);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("small.pfm") && text(&o).contains("3×2"),
        "{}",
        text(&o)
    );
    // Depth without a calibration, and an unknown method.
    let o = denser(
        &[
            "stereo",
            "l.png",
            "r.png",
            "--out",
            "x.pfm",
            "--depth-out",
            "z.png",
        ],
        d,
    );
    assert!(!o.status.success());
    assert!(text(&o).contains("--calib"), "{}", text(&o));
    let o = denser(
        &[
            "stereo", "l.png", "r.png", "--out", "x.pfm", "--method", "elas",
        ],
        d,
    );
    assert!(!o.status.success());
    assert!(
        text(&o).contains("elas") && text(&o).contains("tgv-tensor"),
        "{}",
        text(&o)
    );
}

#[test]
fn stereo_on_the_gpu_writes_the_cpu_disparities() {
    // `--device gpu` runs census cost and refinement on the GPU (lavapipe counts); skipped where
    // no adapter exists. Tolerance as in tests/gpu_stereo.rs: > 0.1 px on ≤ 0.5 % of pixels.
    if denser::gpu::GpuContext::new().ok().flatten().is_none() {
        crate::common::skip("no GPU adapter (tools/setup.sh installs lavapipe)");
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let (w, h) = (160u32, 60u32);
    let (left, right, _) = depth_support::planar_pair(w, h, 10.0, 0.03, 0.01, 9);
    write_grey_png(d.join("l.png"), &left).unwrap();
    write_grey_png(d.join("r.png"), &right).unwrap();
    // `denser stereo` on `device` with `method`, the disparity file it wrote.
    let run = |method: &str, device: &str| {
        let out = format!("{method}_{device}.pfm");
        let o = denser(
            &[
                "stereo",
                "l.png",
                "r.png",
                "--out",
                &out,
                "--method",
                method,
                "--num-disparities",
                "24",
                "--device",
                device,
            ],
            d,
        );
        assert!(o.status.success(), "{}", text(&o));
        if device == "gpu" {
            assert!(text(&o).contains("device: GPU"), "{}", text(&o));
        }
        d.join(out)
    };
    let maps: Vec<_> = ["cpu", "gpu"]
        .map(|device| read_pfm(run("tgv-tensor", device)).unwrap())
        .into();
    let (cpu, gpu) = (&maps[0], &maps[1]);
    let same_validity = cpu
        .data
        .iter()
        .zip(&gpu.data)
        .filter(|(c, g)| c.is_finite() == g.is_finite())
        .count();
    let far = cpu
        .data
        .iter()
        .zip(&gpu.data)
        .filter(|(c, g)| c.is_finite() && g.is_finite() && (*c - *g).abs() > 0.1)
        .count();
    let valid = cpu.data.iter().filter(|c| c.is_finite()).count();
    eprintln!(
        "CPU vs GPU: {valid} valid, validity equal on {same_validity} of {}, {far} differ by > 0.1 px",
        cpu.data.len()
    );
    assert!(valid > cpu.data.len() / 2);
    assert!(same_validity as f64 >= 0.995 * cpu.data.len() as f64);
    assert!(far as f64 <= 0.005 * cpu.data.len() as f64);
    // SGM: its aggregation and selection on the GPU in integers, finished as the CPU does: the
    // same file.
    let files = ["cpu", "gpu"].map(|device| std::fs::read(run("sgm", device)).expect("pfm"));
    assert!(
        files[0] == files[1],
        "SGM's disparities differ between the devices"
    );
}

/// Issue 13: `denser stereo left.jpg right.jpg` said "The image format Jpeg is not supported".
/// A rendered pair saved as JPEG (quality 95) and as TIFF gives the disparities the PNG pair gives.
#[test]
fn stereo_reads_a_jpeg_and_a_tiff_pair() {
    use image::codecs::jpeg::JpegEncoder;
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let (w, h) = (200u32, 80u32);
    let (left, right, gt) = depth_support::planar_pair(w, h, 12.0, 0.02, 0.0, 5);
    let mut gt_known = gt.clone();
    for y in 0..h {
        for x in 0..24 {
            *gt_known.at_mut(x, y) = f32::NAN;
        }
    }
    for (img, name) in [(&left, "l"), (&right, "r")] {
        let buf = image::GrayImage::from_raw(w, h, img.data.clone()).unwrap();
        let mut f = std::fs::File::create(d.join(format!("{name}.jpg"))).unwrap();
        JpegEncoder::new_with_quality(&mut f, 95)
            .encode_image(&buf)
            .unwrap();
        buf.save_with_format(d.join(format!("{name}.tif")), image::ImageFormat::Tiff)
            .unwrap();
    }
    for (l, r) in [("l.jpg", "r.jpg"), ("l.tif", "r.tif")] {
        let o = denser(
            &[
                "stereo",
                l,
                r,
                "--out",
                "disp.pfm",
                "--method",
                "sgm",
                "--num-disparities",
                "24",
            ],
            d,
        );
        assert!(o.status.success(), "{l}: {}", text(&o));
        let pred = read_pfm(d.join("disp.pfm")).unwrap();
        assert_eq!((pred.width, pred.height), (w, h));
        let m = evaluate_disparity(&pred, &gt_known, None).unwrap();
        eprintln!("{l}: {m:?}");
        assert!(
            m.epe_px < 0.3 && m.bad2_pct < 3.0 && m.density_pct > 90.0,
            "{l}: {m:?}"
        );
    }
}

/// `--sgm-paths`, `--sgm-lr-max-diff` and `--sgm-uniqueness` set the SGM parameters: each
/// combination gives, bit for bit, the library's matcher with those parameters (no flag: the
/// defaults); bad values are refused by name.
#[test]
fn stereo_sgm_flags_select_the_library_parameters() {
    use denser::depth::sgm::{SgmMatcher, SgmParams, SgmPaths};
    use denser::depth::DisparityEstimator;
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let (left, right, _) = depth_support::planar_pair(120, 50, 9.0, 0.03, 0.01, 7);
    write_grey_png(d.join("l.png"), &left).unwrap();
    write_grey_png(d.join("r.png"), &right).unwrap();
    let run = |extra: &[&str]| {
        let mut args = vec![
            "stereo", "l.png", "r.png", "--out", "d.pfm", "--method", "sgm",
        ];
        args.extend_from_slice(&["--num-disparities", "20"]);
        args.extend_from_slice(extra);
        let o = denser(&args, d);
        assert!(o.status.success(), "{}", text(&o));
        read_pfm(d.join("d.pfm")).unwrap()
    };
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let defaults = SgmParams {
        num_disparities: 20,
        ..SgmParams::default()
    };
    let mut valid = Vec::new();
    for (flags, params) in [
        (
            &["--sgm-paths", "4"][..],
            SgmParams {
                paths: SgmPaths::Four,
                ..defaults
            },
        ),
        (
            &["--sgm-paths", "5"],
            SgmParams {
                paths: SgmPaths::Five,
                ..defaults
            },
        ),
        (
            &["--sgm-paths", "8"],
            SgmParams {
                paths: SgmPaths::Eight,
                ..defaults
            },
        ),
        (&[], defaults),
        (
            &[
                "--sgm-paths",
                "5",
                "--sgm-lr-max-diff",
                "2",
                "--sgm-uniqueness",
                "0",
            ],
            SgmParams {
                paths: SgmPaths::Five,
                lr_max_diff_px: Some(2),
                uniqueness_ratio: 0.0,
                ..defaults
            },
        ),
        (
            &["--sgm-lr-max-diff", "off", "--sgm-uniqueness", "0.2"],
            SgmParams {
                lr_max_diff_px: None,
                uniqueness_ratio: 0.2,
                ..defaults
            },
        ),
    ] {
        let flag = flags.join(" ");
        let got = run(flags);
        let want = SgmMatcher::new(params)
            .unwrap()
            .estimate(&left, &right)
            .unwrap();
        // PFM stores invalid as inf, the matcher NaN.
        let want: Vec<f32> = want
            .disparity_px
            .data
            .iter()
            .map(|&v| if v.is_nan() { f32::INFINITY } else { v })
            .collect();
        let got: Vec<f32> = got
            .data
            .iter()
            .map(|&v| if v.is_finite() { v } else { f32::INFINITY })
            .collect();
        assert_eq!(bits(&got), bits(&want), "{flag}");
        valid.push(got.iter().filter(|v| v.is_finite()).count());
    }
    // The looser tests keep more pixels than the defaults (so the flags reached the matcher).
    assert!(valid[4] > valid[1] && valid[5] > valid[3], "{valid:?}");
    let o = denser(
        &[
            "stereo",
            "l.png",
            "r.png",
            "--out",
            "x.pfm",
            "--sgm-paths",
            "6",
        ],
        d,
    );
    assert!(!o.status.success());
    assert!(
        text(&o).contains("expected 4, 5 or 8 paths"),
        "{}",
        text(&o)
    );
    for (flag, value, says) in [
        (
            "--sgm-lr-max-diff",
            "two",
            "expected a number of pixels or `off`",
        ),
        (
            "--sgm-uniqueness",
            "1.5",
            "uniqueness_ratio must be in [0, 1)",
        ),
    ] {
        let o = denser(
            &["stereo", "l.png", "r.png", "--out", "x.pfm", flag, value],
            d,
        );
        assert!(!o.status.success(), "{flag} {value}");
        assert!(text(&o).contains(says), "{flag} {value}: {}", text(&o));
    }
}
