//! Evaluation outputs: JSON/Markdown reports and the PNG pictures, checked by decoding them.

use denser::eval::{
    error_colour, plot_error_histograms_png, plot_top_view_png, ErrorStats, EvaluationReport,
    HistogramSpec, SurfaceReport, UpAxis, SERIES_COLOURS,
};
use denser::Error;

use crate::common;

/// Deterministic distances: `n` values spread evenly over `[centre − half, centre + half]`.
fn spread(n: usize, centre: f32, half: f32) -> Vec<f32> {
    (0..n)
        .map(|i| centre - half + 2.0 * half * (i as f32 + 0.5) / n as f32)
        .collect()
}

fn stats(d: &[f32]) -> ErrorStats {
    ErrorStats::from_distances(
        d,
        &HistogramSpec {
            bin_width_m: 0.01,
            max_m: 0.5,
        },
    )
    .unwrap()
}

fn surface(label: &str, d: &[f32], area: f64, voxels: u64) -> SurfaceReport {
    SurfaceReport {
        label: label.into(),
        vertices: d.len() as u64,
        triangles: 2 * d.len() as u64,
        surface_area_m2: area,
        voxel_count: None,
        bytes_per_voxel: None,
        accuracy: stats(d),
        completeness: Some(stats(&spread(100, 0.2, 0.1))),
        accuracy_unrestricted: None,
    }
    .with_voxels(voxels, 12.0)
}

fn sample_report() -> EvaluationReport {
    let mut r = EvaluationReport::new("synthetic | test scene", 123_456);
    // raw: median 0.10; regularized: median 0.062 → −38 %.
    r.surfaces
        .push(surface("raw", &spread(1001, 0.10, 0.05), 1000.0, 2_000_000));
    r.surfaces.push(surface(
        "regularized",
        &spread(1001, 0.062, 0.03),
        680.0,
        2_000_000,
    ));
    r.timings_s = vec![("fusion".into(), 1.5), ("regularize".into(), 2.25)];
    r.memory_bytes = vec![("peak resident".into(), 512 * 1024 * 1024)];
    r.parameters = serde_json::json!({ "voxel_size_m": 0.1, "lambda": 0.8 });
    r
}

#[test]
fn json_round_trip_and_markdown_table() {
    let dir = tempfile::tempdir().unwrap();
    let report = sample_report();
    let json = dir.path().join("report.json");
    report.write_json(&json).unwrap();
    assert_eq!(EvaluationReport::read_json(&json).unwrap(), report);

    let md = report.to_markdown();
    let row = |name: &str| {
        md.lines()
            .find(|l| l.starts_with(&format!("| {name} |")))
            .unwrap_or_else(|| panic!("no row {name} in\n{md}"))
            .to_string()
    };
    assert!(
        md.contains("| metric | raw | regularized | regularized vs raw |"),
        "{md}"
    );
    assert!(md.contains("synthetic \\| test scene"), "pipe escaped");
    assert_eq!(
        row("accuracy median (m)"),
        "| accuracy median (m) | 0.100 | 0.062 | \u{2212}38 % |"
    );
    assert_eq!(
        row("surface area (m²)"),
        "| surface area (m²) | 1000.0 | 680.0 | \u{2212}32 % |"
    );
    assert_eq!(row("voxels"), "| voxels | 2000000 | 2000000 | 0 % |");
    assert_eq!(
        row("voxel memory (MiB)"),
        "| voxel memory (MiB) | 22.9 | 22.9 | 0 % |"
    );
    assert_eq!(
        row("completeness median (m)"),
        "| completeness median (m) | 0.200 | 0.200 | 0 % |"
    );
    assert!(md.contains("| regularize | 2.250 |") && md.contains("| **total** | **3.750** |"));
    assert!(md.contains("| peak resident | 512.0 |"));
    assert!(md.contains("\"voxel_size_m\": 0.1"));

    let md_path = dir.path().join("report.md");
    report.write_markdown(&md_path).unwrap();
    assert_eq!(std::fs::read_to_string(&md_path).unwrap(), md);
}

#[test]
fn unknown_fields_show_a_dash() {
    let mut r = sample_report();
    r.surfaces[1].voxel_count = None;
    r.surfaces[1].completeness = None;
    let md = r.to_markdown();
    assert!(md.contains("| voxels | 2000000 | — | — |"), "{md}");
    assert!(
        md.contains("| completeness median (m) | 0.200 | — | — |"),
        "{md}"
    );
}

#[test]
fn bad_report_files_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let garbage = dir.path().join("garbage.json");
    std::fs::write(&garbage, b"{\"source\": 3}").unwrap();
    match EvaluationReport::read_json(&garbage) {
        Err(Error::BadInput { path, message }) => {
            assert_eq!(path, garbage);
            assert!(message.contains("not an evaluation report"), "{message}");
        }
        other => panic!("expected BadInput, got {other:?}"),
    }
    let missing = dir.path().join("no/such/dir/report.json");
    match sample_report().write_json(&missing) {
        Err(Error::Io { path, .. }) => assert_eq!(path, missing),
        other => panic!("expected Io, got {other:?}"),
    }
    let e = plot_error_histograms_png(&missing, &[("a", &stats(&[0.1]))], 0.5).unwrap_err();
    assert!(e.to_string().contains("no/such/dir/report.json"), "{e}");
}

/// Copies a picture to `$DENSER_EVAL_PNG_DIR` (when set) so that a person can look at it.
fn keep(path: &std::path::Path) {
    if let Some(dir) = std::env::var_os("DENSER_EVAL_PNG_DIR") {
        let dest = std::path::Path::new(&dir).join(path.file_name().unwrap());
        std::fs::copy(path, dest).unwrap();
    }
}

/// Mean column of the pixels equal to `c`, and their number.
fn mean_x_of(img: &image::RgbImage, c: [u8; 3], x_max: u32) -> (f64, usize) {
    let (mut s, mut n) = (0.0, 0usize);
    for (x, _, p) in img.enumerate_pixels() {
        if x < x_max && p.0 == c {
            s += x as f64;
            n += 1;
        }
    }
    (s / n.max(1) as f64, n)
}

#[test]
fn histogram_png_overlays_series() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("hist.png");
    let raw = stats(&spread(5000, 0.25, 0.1));
    let reg = stats(&spread(5000, 0.08, 0.04));
    plot_error_histograms_png(&path, &[("raw", &raw), ("regularized", &reg)], 0.5).unwrap();
    keep(&path);
    let img = image::open(&path).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (1000, 600));
    // Both series are drawn in their colours (outline and legend swatch).
    assert!(mean_x_of(&img, SERIES_COLOURS[0], 1000).1 > 300);
    assert!(mean_x_of(&img, SERIES_COLOURS[1], 1000).1 > 300);
    // Filled bars are pale tints, below the legend: raw (red, errors 0.15–0.35 m) lies right of
    // regularized (blue, 0.04–0.12 m).
    let tinted = |red: bool| {
        let (mut sx, mut n) = (0.0f64, 0usize);
        for (x, y, p) in img.enumerate_pixels() {
            let [r, g, b] = p.0.map(i32::from);
            let pale = r.min(g).min(b) > 150;
            let hit = if red {
                r > b + 20 && r > g + 20
            } else {
                b > r + 20 && b > g + 5
            };
            if y > 150 && pale && hit {
                sx += x as f64;
                n += 1;
            }
        }
        (sx / n.max(1) as f64, n)
    };
    let ((raw_x, raw_n), (reg_x, reg_n)) = (tinted(true), tinted(false));
    assert!(
        raw_n > 10_000 && reg_n > 10_000,
        "tinted pixels: raw {raw_n}, reg {reg_n}"
    );
    // x pixel ≈ 100 + 1760·error: raw centre 0.25 m → ~540, regularized 0.08 m → ~240.
    assert!(
        (raw_x - 540.0).abs() < 30.0 && (reg_x - 240.0).abs() < 30.0,
        "{raw_x} {reg_x}"
    );
    // Text and axes: plenty of dark pixels.
    let dark = img.pixels().filter(|p| p.0.iter().all(|&v| v < 80)).count();
    assert!(dark > 2000, "dark pixels {dark}");
}

#[test]
fn top_view_png_colours_and_orientation() {
    // KITTI-style frame (y down): a 10 m × 5 m patch on the x–z plane at y = 1.7. Error 0 for
    // x < 5 (blue), max for x ≥ 5 (red), and mid-scale (yellow) in the strip z > 4 of the left half.
    let mut points = Vec::new();
    let mut errors = Vec::new();
    for i in 0..200 {
        for k in 0..100 {
            let (x, z) = (i as f64 * 0.05, k as f64 * 0.05);
            points.push([x, 1.7, z]);
            errors.push(if x >= 5.0 {
                0.5
            } else if z > 4.0 {
                0.25
            } else {
                0.0
            });
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("top.png");
    plot_top_view_png(
        &path,
        "test",
        &points,
        &errors,
        None,
        &[],
        UpAxis::NegY,
        0.5,
        900,
    )
    .unwrap();
    keep(&path);
    let img = image::open(&path).unwrap().to_rgb8();
    let (w, h) = img.dimensions();
    assert_eq!(w, 900);
    let map_w = w - 140; // the colour bar panel is on the right
    let (blue, red, yellow) = (error_colour(0.0), error_colour(1.0), error_colour(0.5));
    let mut bbox = (u32::MAX, u32::MAX, 0u32, 0u32);
    let (mut n_blue, mut n_red, mut n_yellow) = (0usize, 0usize, 0usize);
    let (mut blue_y, mut yellow_y) = (0.0f64, 0.0f64);
    for (x, y, p) in img.enumerate_pixels() {
        if x >= map_w {
            continue;
        }
        let c = p.0;
        if c == blue || c == red || c == yellow {
            bbox = (bbox.0.min(x), bbox.1.min(y), bbox.2.max(x), bbox.3.max(y));
        }
        if c == blue {
            n_blue += 1;
            blue_y += y as f64;
        } else if c == red {
            n_red += 1;
        } else if c == yellow {
            n_yellow += 1;
            yellow_y += y as f64;
        }
    }
    let (bw, bh) = ((bbox.2 - bbox.0 + 1) as f64, (bbox.3 - bbox.1 + 1) as f64);
    // Equal scale: the 10 m × 5 m patch keeps its 2:1 aspect ratio.
    assert!(
        (bw / bh - 2.0).abs() < 0.05,
        "patch {bw}×{bh} px in a {w}×{h} image"
    );
    // Splatting leaves (almost) no holes: the three colours fill the patch.
    let filled = (n_blue + n_red + n_yellow) as f64 / (bw * bh);
    assert!(filled > 0.97, "filled fraction {filled}");
    // Left half blue (+ yellow strip), right half red: areas 0.4 : 0.5 : 0.1 of the patch.
    let total = (n_blue + n_red + n_yellow) as f64;
    assert!(
        (n_red as f64 / total - 0.5).abs() < 0.03,
        "red {n_red}/{total}"
    );
    assert!(
        (n_yellow as f64 / total - 0.1).abs() < 0.03,
        "yellow {n_yellow}/{total}"
    );
    let (blue_x, _) = mean_x_of(&img, blue, map_w);
    let (red_x, _) = mean_x_of(&img, red, map_w);
    assert!(red_x > blue_x, "+x is to the right");
    // +z (KITTI forward) is up the image: the z > 4 strip is above (smaller row) the blue area.
    assert!(
        yellow_y / (n_yellow as f64) < blue_y / (n_blue as f64),
        "+z points up the image"
    );
    // The colour bar shows the whole colormap.
    let bar_has = |c: [u8; 3]| {
        img.enumerate_pixels().any(|(x, _, p)| {
            x >= map_w
                && p.0
                    .iter()
                    .zip(c)
                    .all(|(&a, b)| (a as i32 - b as i32).abs() <= 4)
        })
    };
    assert!(bar_has(blue) && bar_has(red) && bar_has(yellow));
}

#[test]
fn plots_reject_bad_arguments() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("x.png");
    let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 1.0]];
    // Points, errors, colour range and size; everything else valid.
    let rejects = |points: &[[f64; 3]], errors: &[f32], max_error_m: f64, size_px: u32| {
        plot_top_view_png(
            &path,
            "test",
            points,
            errors,
            None,
            &[],
            UpAxis::NegY,
            max_error_m,
            size_px,
        )
        .is_err()
    };
    assert!(rejects(&p, &[0.1], 0.5, 800));
    assert!(rejects(&p, &[0.1, f32::NAN], 0.5, 800));
    assert!(rejects(&p, &[0.1, 0.2], 0.0, 800));
    assert!(rejects(&p, &[0.1, 0.2], 0.5, 10));
    assert!(rejects(&[], &[], 0.5, 800));
    assert!(plot_error_histograms_png(&path, &[], 0.5).is_err());
    assert!(!path.exists());
}

#[test]
fn pictures_of_real_aerial_lidar() {
    // GT: autzen_trim.las (110k aerial points, international feet, UTM-like coordinates).
    // "Reconstructions": every 4th point lifted by a deterministic pseudo-random δ ∈ [0, 3) ft
    // ("raw") and δ/3 ("regularized"); the distance to the nearest GT point is at most δ.
    let Some(dir) = common::shared_data("las_autzen_pdal") else {
        return;
    };
    let mut reader = las::Reader::from_path(dir.join("autzen_trim.las")).unwrap();
    let gt: Vec<[f64; 3]> = reader
        .read_all()
        .unwrap()
        .points()
        .map(|p| p.map(|p| [p.x, p.y, p.z]))
        .collect::<Result<_, _>>()
        .unwrap();
    let index = denser::eval::GroundTruthIndex::from_points(&gt).unwrap();
    let mut seed = 7u64;
    let mut next = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let deltas: Vec<f64> = gt
        .iter()
        .step_by(4)
        .map(|_| 3.0 * next() * next())
        .collect();
    let lifted = |scale: f64| -> Vec<[f64; 3]> {
        gt.iter()
            .step_by(4)
            .zip(&deltas)
            .map(|(p, d)| [p[0], p[1], p[2] + scale * d])
            .collect()
    };
    let (raw_pts, reg_pts) = (lifted(1.0), lifted(1.0 / 3.0));
    let raw_d = index.nearest_distances_m(&raw_pts).unwrap();
    let reg_d = index.nearest_distances_m(&reg_pts).unwrap();
    for ((r, g), d) in raw_d.iter().zip(&reg_d).zip(&deltas) {
        assert!(*r as f64 <= d + 1e-4 && *g as f64 <= d / 3.0 + 1e-4);
    }
    let spec = HistogramSpec {
        bin_width_m: 0.05,
        max_m: 3.0,
    };
    let raw = ErrorStats::from_distances(&raw_d, &spec).unwrap();
    let reg = ErrorStats::from_distances(&reg_d, &spec).unwrap();
    assert!(reg.median_m < raw.median_m);

    let out = tempfile::tempdir().unwrap();
    let hist = out.path().join("autzen_hist.png");
    plot_error_histograms_png(&hist, &[("raw", &raw), ("regularized", &reg)], 2.0).unwrap();
    keep(&hist);
    let top = out.path().join("autzen_top.png");
    plot_top_view_png(
        &top,
        "test",
        &raw_pts,
        &raw_d,
        None,
        &[],
        UpAxis::PosZ,
        1.5,
        1000,
    )
    .unwrap();
    keep(&top);
    let img = image::open(&top).unwrap().to_rgb8();
    assert_eq!(img.width(), 1000);
    // Most of the map is covered by coloured points (the trimmed tile is nearly rectangular).
    let coloured = img
        .pixels()
        .filter(|p| p.0[0].abs_diff(p.0[1]) > 40 || p.0[2] > 140)
        .count();
    assert!(
        coloured as f64 > 0.3 * (img.width() * img.height()) as f64,
        "{coloured}"
    );
}

#[test]
fn top_view_greys_unscored_points_and_draws_the_trajectory() {
    // A 10 m × 5 m patch: the left half scored (error 0), the right half not; the sensor drove
    // along x at z = 2.5 m across the whole patch.
    let mut points = Vec::new();
    let mut scored = Vec::new();
    for i in 0..200 {
        for k in 0..100 {
            let (x, z) = (i as f64 * 0.05, k as f64 * 0.05);
            points.push([x, 1.7, z]);
            scored.push(x < 5.0);
        }
    }
    let errors = vec![0.0f32; points.len()];
    let trajectory: Vec<[f64; 3]> = (0..=10).map(|i| [i as f64, 0.0, 2.5]).collect();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("top.png");
    plot_top_view_png(
        &path,
        "test",
        &points,
        &errors,
        Some(&scored),
        &trajectory,
        UpAxis::NegY,
        0.5,
        900,
    )
    .unwrap();
    let img = image::open(&path).unwrap().to_rgb8();
    let map_w = img.width() - 140;
    let (mut blue, mut grey, mut black_rows) = (Vec::new(), Vec::new(), Vec::new());
    for (x, y, p) in img.enumerate_pixels() {
        if x >= map_w {
            continue;
        }
        if p.0 == error_colour(0.0) {
            blue.push(x);
        } else if p.0 == denser::eval::UNSCORED_GREY {
            grey.push(x);
        } else if p.0 == [0, 0, 0] {
            black_rows.push(y);
        }
    }
    assert!(
        blue.len() > 1000 && grey.len() > 1000,
        "{} {}",
        blue.len(),
        grey.len()
    );
    // Scored points on the left, unscored on the right (as many of each: equal halves). A few
    // grey pixels elsewhere are the axes' anti-aliased text.
    blue.sort_unstable();
    grey.sort_unstable();
    let (blue_mid, grey_mid) = (blue[blue.len() / 2], grey[grey.len() / 2]);
    let split = *blue.last().unwrap();
    let grey_right = grey.iter().filter(|&&x| x >= split).count();
    assert!(
        blue_mid < grey_mid,
        "blue median x {blue_mid}, grey {grey_mid}"
    );
    assert!(
        grey_right * 10 > grey.len() * 9,
        "{grey_right} of {} grey pixels right of {split}",
        grey.len()
    );
    let ratio = blue.len() as f64 / grey.len() as f64;
    assert!(
        (0.8..1.25).contains(&ratio),
        "blue {} vs grey {}",
        blue.len(),
        grey.len()
    );
    // The trajectory: a horizontal black line (one row ± 1 px) across the map, more than the
    // axes' tick marks alone draw.
    black_rows.sort_unstable();
    let mid = black_rows[black_rows.len() / 2];
    let on_line = black_rows.iter().filter(|&&y| y.abs_diff(mid) <= 1).count();
    assert!(on_line > 400, "{on_line} black pixels on row {mid}");
}
