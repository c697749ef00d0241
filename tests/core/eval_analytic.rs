//! Accuracy and completeness against analytic scenes (planes, a sphere) whose distances are known
//! exactly, plus a real aerial LiDAR file with large georeferenced coordinates.

use crate::common;

use denser::eval::{
    evaluate_mesh, evaluate_mesh_detailed, sample_mesh_surface, CompletenessRegion, EvalOptions,
    GroundTruthIndex, HistogramSpec,
};
use denser::frame::PointCloud;
use denser::mesh::Mesh;

/// Ground truth: the plane y = `y` sampled on a square grid of `spacing` over
/// `[x0, x1] × [z0, z1]` (grid points at x0 + i·spacing).
fn plane_samples(x0: f64, x1: f64, z0: f64, z1: f64, y: f64, spacing: f64) -> PointCloud {
    let nx = ((x1 - x0) / spacing).round() as usize;
    let nz = ((z1 - z0) / spacing).round() as usize;
    let mut points_m = Vec::with_capacity((nx + 1) * (nz + 1));
    for i in 0..=nx {
        for k in 0..=nz {
            points_m.push([x0 + i as f64 * spacing, y, z0 + k as f64 * spacing]);
        }
    }
    PointCloud {
        points_m,
        colors: None,
    }
}

/// A grid mesh of the plane y = `y` over `[x0, x1] × [z0, z1]` with square cells of `cell`,
/// two triangles per cell.
fn plane_mesh(x0: f64, x1: f64, z0: f64, z1: f64, y: f64, cell: f64) -> Mesh {
    let nx = ((x1 - x0) / cell).round() as u32;
    let nz = ((z1 - z0) / cell).round() as u32;
    let mut mesh = Mesh::default();
    for i in 0..=nx {
        for k in 0..=nz {
            mesh.positions_m.push([
                (x0 + i as f64 * cell) as f32,
                y as f32,
                (z0 + k as f64 * cell) as f32,
            ]);
            mesh.colors.push([200, 200, 200]);
        }
    }
    let id = |i: u32, k: u32| i * (nz + 1) + k;
    for i in 0..nx {
        for k in 0..nz {
            mesh.triangles.push([id(i, k), id(i, k + 1), id(i + 1, k)]);
            mesh.triangles
                .push([id(i + 1, k), id(i, k + 1), id(i + 1, k + 1)]);
        }
    }
    mesh
}

/// `n` nearly uniform points on the sphere of radius `r` about the origin (Fibonacci lattice).
fn sphere_samples(r: f64, n: usize) -> PointCloud {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let points_m = (0..n)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let rho = (1.0 - y * y).sqrt();
            let phi = golden * i as f64;
            [r * rho * phi.cos(), r * y, r * rho * phi.sin()]
        })
        .collect();
    PointCloud {
        points_m,
        colors: None,
    }
}

/// A UV sphere mesh of radius `r` with `stacks` latitude bands and `slices` longitude sectors.
fn sphere_mesh(r: f64, stacks: u32, slices: u32) -> Mesh {
    let mut mesh = Mesh::default();
    for s in 0..=stacks {
        let theta = std::f64::consts::PI * s as f64 / stacks as f64;
        for l in 0..slices {
            let phi = 2.0 * std::f64::consts::PI * l as f64 / slices as f64;
            mesh.positions_m.push([
                (r * theta.sin() * phi.cos()) as f32,
                (r * theta.cos()) as f32,
                (r * theta.sin() * phi.sin()) as f32,
            ]);
            mesh.colors.push([255, 255, 255]);
        }
    }
    let id = |s: u32, l: u32| s * slices + (l % slices);
    for s in 0..stacks {
        for l in 0..slices {
            mesh.triangles.push([id(s, l), id(s + 1, l), id(s, l + 1)]);
            mesh.triangles
                .push([id(s, l + 1), id(s + 1, l), id(s + 1, l + 1)]);
        }
    }
    mesh
}

#[test]
fn plane_offset_by_5_5_cm_has_exact_median_and_mode() {
    // GT grid every 2 cm; mesh vertices every 10 cm on the same grid, 5.5 cm above: every vertex
    // sits exactly above a GT point, so each distance is 0.055 m (up to f32 vertex rounding).
    let gt = plane_samples(-3.0, 3.0, -3.0, 3.0, 0.0, 0.02);
    let index = GroundTruthIndex::new(&gt).unwrap();
    assert_eq!(index.len(), 301 * 301);
    let mesh = plane_mesh(-2.0, 2.0, -2.0, 2.0, 0.055, 0.1);
    let options = EvalOptions {
        completeness: None,
        ..EvalOptions::default()
    };
    let report = evaluate_mesh("offset", &mesh, &index, &options).unwrap();
    let a = &report.accuracy;
    assert_eq!(a.count, 41 * 41);
    assert!((a.median_m - 0.055).abs() < 1e-6, "median {}", a.median_m);
    assert!((a.p90_m - 0.055).abs() < 1e-6);
    assert!((a.max_m - 0.055).abs() < 1e-6);
    assert!(
        (a.mode_m.unwrap() - 0.055).abs() < 1e-9,
        "mode {:?}",
        a.mode_m
    );
    assert_eq!(a.histogram.counts[5], 41 * 41);
    assert!((report.surface_area_m2 - 16.0).abs() < 1e-4);
    assert_eq!(report.triangles, 2 * 40 * 40);
    assert!(report.completeness.is_none());
}

#[test]
fn plane_offset_diagonally_matches_pythagoras() {
    // Mesh shifted by (1 cm, 5 cm, 1 cm): the nearest GT point is 1 cm away along x and z, so the
    // distance is sqrt(0.01² + 0.05² + 0.01²) for every vertex.
    let gt = plane_samples(-3.0, 3.0, -3.0, 3.0, 0.0, 0.02);
    let index = GroundTruthIndex::new(&gt).unwrap();
    let mut mesh = plane_mesh(-2.0, 2.0, -2.0, 2.0, 0.05, 0.1);
    for p in &mut mesh.positions_m {
        p[0] += 0.01;
        p[2] += 0.01;
    }
    let report = evaluate_mesh("diag", &mesh, &index, &EvalOptions::default()).unwrap();
    let expected = (0.01f64.powi(2) * 2.0 + 0.05f64.powi(2)).sqrt();
    assert!(
        (report.accuracy.median_m - expected).abs() < 2e-6,
        "{}",
        report.accuracy.median_m
    );
    assert!((report.accuracy.mean_m - expected).abs() < 2e-6);
}

#[test]
fn sphere_offset_by_5_cm_has_median_5_cm() {
    // GT: 1M points on a sphere of radius 5 m; mesh: a fine UV sphere of radius 5.05 m. Each
    // vertex is 5 cm above the GT surface; the nearest GT sample adds the in-surface gap h, at most
    // the lattice's covering radius (hexagonal spacing a, covering radius a/√3; 20 % slack for the
    // Fibonacci lattice), so every distance lies in [0.05, sqrt(0.05² + h_max²)].
    let n = 1_000_000;
    let gt = sphere_samples(5.0, n);
    let index = GroundTruthIndex::new(&gt).unwrap();
    let area_per_point = 4.0 * std::f64::consts::PI * 25.0 / n as f64;
    let spacing = (2.0 * area_per_point / 3f64.sqrt()).sqrt();
    let h_max = 1.2 * spacing / 3f64.sqrt();
    let hi = (0.05f64.powi(2) + h_max.powi(2)).sqrt();
    assert!(hi < 0.052, "oracle bound {hi}");

    let mesh = sphere_mesh(5.05, 120, 240);
    let options = EvalOptions {
        completeness: None,
        ..EvalOptions::default()
    };
    let report = evaluate_mesh("sphere", &mesh, &index, &options).unwrap();
    let a = &report.accuracy;
    assert!(
        a.median_m >= 0.05 - 1e-5 && a.median_m <= hi,
        "median {} (≤ {hi})",
        a.median_m
    );
    assert!(
        a.max_m >= 0.05 - 1e-5 && a.max_m <= hi,
        "max {} (≤ {hi})",
        a.max_m
    );
    assert!(
        (a.mode_m.unwrap() - 0.055).abs() < 1e-9,
        "mode {:?}",
        a.mode_m
    );
    // Area of a fine UV sphere approaches 4πr² from below.
    let exact = 4.0 * std::f64::consts::PI * 5.05f64.powi(2);
    assert!(report.surface_area_m2 < exact && report.surface_area_m2 > 0.998 * exact);

    // Scoring triangle samples too: a flat triangle of the 1.5° × 1.5° tessellation lies inside the
    // 5.05 m sphere by at most its sagitta r(1 − cos(1.5°·√2/2)) < 1 mm.
    let sampled = EvalOptions {
        surface_sample_spacing_m: Some(0.05),
        ..options
    };
    let detailed = evaluate_mesh_detailed("sphere+samples", &mesh, &index, &sampled).unwrap();
    assert!(detailed.points_m.len() > 2 * mesh.positions_m.len());
    assert_eq!(detailed.accuracy_m.len(), detailed.points_m.len());
    let m = detailed.report.accuracy.median_m;
    assert!(m > 0.049 && m <= hi, "median with samples {m}");
}

#[test]
fn completeness_of_half_covered_plane() {
    // GT covers x ∈ [−2, 2]; the mesh (on the plane itself) covers x ∈ [−2, 0]. A GT point at
    // x > 0 is x metres from the mesh's edge; points with x ≤ 0 lie (almost) on the mesh.
    let gt = plane_samples(-2.0, 2.0, -2.0, 2.0, 0.0, 0.02);
    let index = GroundTruthIndex::new(&gt).unwrap();
    let mesh = plane_mesh(-2.0, 0.0, -2.0, 2.0, 0.0, 0.1);
    let fine = EvalOptions {
        surface_sample_spacing_m: Some(0.01),
        completeness: Some(CompletenessRegion::All),
        histogram: HistogramSpec {
            bin_width_m: 0.01,
            max_m: 3.0,
        },
    };
    let report = evaluate_mesh("half", &mesh, &index, &fine).unwrap();
    let c = report.completeness.as_ref().unwrap();
    assert_eq!(c.count, gt.len() as u64);
    // Half the mass near 0, the other half uniform on (0, 2] → p75 = 1.0, max = 2.0.
    assert!((c.p75_m - 1.0).abs() < 0.02, "p75 {}", c.p75_m);
    // (+ ≤ 3 mm: the mesh's edge x = 0 has vertices only every 10 cm, samples lie just inside.)
    assert!(c.max_m >= 2.0 - 1e-6 && c.max_m < 2.003, "max {}", c.max_m);
    // Covered part: distances below the sample spacing; ~51 % of points have x ≤ 0.
    let covered = c.fraction_below(0.01);
    assert!((covered - 101.0 / 201.0).abs() < 0.01, "covered {covered}");
    // Accuracy is perfect: every reconstructed point is on the GT plane, within the grid gap.
    assert!(report.accuracy.max_m < 0.0142, "{}", report.accuracy.max_m);

    // Limited to the reconstruction's box grown by 0.51 m: GT columns x ≤ 0.5 (the margin avoids
    // a tie at the rounded grid position 0.5) → at most ~0.5 m away.
    let near = EvalOptions {
        completeness: Some(CompletenessRegion::ReconstructionBounds { margin_m: 0.51 }),
        ..fine
    };
    let c = evaluate_mesh("half", &mesh, &index, &near)
        .unwrap()
        .completeness
        .unwrap();
    assert_eq!(c.count, 126 * 201, "GT columns x ≤ 0.5 m");
    assert!(c.max_m >= 0.5 - 1e-6 && c.max_m < 0.503, "max {}", c.max_m);

    // Explicit box over the uncovered half only: columns x = 0.50 … 2.00 → median 1.25 (+ ≤ 3 mm).
    let uncovered = EvalOptions {
        completeness: Some(CompletenessRegion::Aabb {
            min_m: [0.49, -1.0, -2.0],
            max_m: [2.0, 1.0, 2.0],
        }),
        ..fine
    };
    let c = evaluate_mesh("half", &mesh, &index, &uncovered)
        .unwrap()
        .completeness
        .unwrap();
    assert_eq!(c.count, 76 * 201);
    assert!(
        c.median_m >= 1.25 - 1e-6 && c.median_m < 1.253,
        "median {}",
        c.median_m
    );

    // A box with no GT point: completeness is absent, accuracy still computed.
    let empty = EvalOptions {
        completeness: Some(CompletenessRegion::Aabb {
            min_m: [10.0, 10.0, 10.0],
            max_m: [11.0, 11.0, 11.0],
        }),
        ..fine
    };
    assert!(evaluate_mesh("half", &mesh, &index, &empty)
        .unwrap()
        .completeness
        .is_none());
}

#[test]
fn surface_samples_are_deterministic_and_area_uniform() {
    let mesh = plane_mesh(0.0, 1.0, 0.0, 1.0, 0.0, 0.5);
    let a = sample_mesh_surface(&mesh, 0.1).unwrap();
    let b = sample_mesh_surface(&mesh, 0.1).unwrap();
    assert_eq!(a, b);
    // 8 triangles with a longest edge of 0.5·√2 ≈ 0.707 m → k = 8 → 64 samples each.
    assert_eq!(a.len(), 8 * 64);
    // Area-uniform: the samples' mean is the square's centre.
    let mean_x = a.iter().map(|p| p[0]).sum::<f64>() / a.len() as f64;
    let mean_z = a.iter().map(|p| p[2]).sum::<f64>() / a.len() as f64;
    assert!((mean_x - 0.5).abs() < 1e-9 && (mean_z - 0.5).abs() < 1e-9);
    assert!(a.iter().all(|p| p[1] == 0.0 && (0.0..=1.0).contains(&p[0])));
}

#[test]
fn large_coordinates_keep_sub_millimetre_precision() {
    // A UTM-like plane at (500 km, 100 m, 5000 km) every 1 cm; queries 2 mm above grid points.
    let (ox, oy, oz) = (500_000.0, 100.0, 5_000_000.0);
    let mut gt = plane_samples(0.0, 2.0, 0.0, 2.0, 0.0, 0.01);
    for p in &mut gt.points_m {
        *p = [p[0] + ox, p[1] + oy, p[2] + oz];
    }
    let index = GroundTruthIndex::new(&gt).unwrap();
    let queries: Vec<[f64; 3]> = (0..100)
        .map(|i| {
            [
                ox + 0.01 * i as f64,
                oy + 0.002,
                oz + 0.01 * (i % 50) as f64,
            ]
        })
        .collect();
    let d = index.nearest_distances_m(&queries).unwrap();
    assert!(
        d.iter().all(|&d| (d as f64 - 0.002).abs() < 1e-7),
        "{:?}",
        &d[..5]
    );
}

#[test]
fn bad_meshes_and_options_are_rejected_with_reasons() {
    let gt = plane_samples(0.0, 1.0, 0.0, 1.0, 0.0, 0.1);
    let index = GroundTruthIndex::new(&gt).unwrap();
    let options = EvalOptions::default();

    let e = evaluate_mesh("empty", &Mesh::default(), &index, &options)
        .unwrap_err()
        .to_string();
    assert!(e.contains("'empty'") && e.contains("no vertices"), "{e}");

    let mut broken = plane_mesh(0.0, 1.0, 0.0, 1.0, 0.0, 0.5);
    broken.triangles.push([0, 1, 99]);
    let e = evaluate_mesh("broken", &broken, &index, &options)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("surface 'broken': triangle 8") && e.contains("9 vertices"),
        "{e}"
    );

    let mut nan = plane_mesh(0.0, 1.0, 0.0, 1.0, 0.0, 0.5);
    nan.positions_m[3][1] = f32::NAN;
    let e = evaluate_mesh("nan", &nan, &index, &options)
        .unwrap_err()
        .to_string();
    assert!(e.contains("vertex 3"), "{e}");

    let ok = plane_mesh(0.0, 1.0, 0.0, 1.0, 0.0, 0.5);
    assert!(sample_mesh_surface(&ok, 0.0).is_err());
    assert!(sample_mesh_surface(&ok, 1e-5)
        .unwrap_err()
        .to_string()
        .contains("larger spacing"));
    let bad_hist = EvalOptions {
        histogram: HistogramSpec {
            bin_width_m: -1.0,
            max_m: 1.0,
        },
        ..options
    };
    assert!(evaluate_mesh("h", &ok, &index, &bad_hist).is_err());
    let bad_margin = EvalOptions {
        completeness: Some(CompletenessRegion::ReconstructionBounds { margin_m: f64::NAN }),
        ..options
    };
    assert!(evaluate_mesh("m", &ok, &index, &bad_margin).is_err());

    assert!(GroundTruthIndex::new(&PointCloud::default()).is_err());
    let e = GroundTruthIndex::from_points(&[[0.0, 0.0, 0.0], [f64::INFINITY, 0.0, 0.0]])
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("ground-truth point 1"), "{e}");
}

#[test]
fn real_aerial_lidar_with_georeferenced_coordinates() {
    // autzen_trim.las: 110k aerial LiDAR points at ~(637 000, 850 000) (international feet; the
    // unit does not matter here). GT = every point; queries = every 50th point lifted by 0.1.
    let Some(dir) = common::shared_data("las_autzen_pdal") else {
        return;
    };
    let path = dir.join("autzen_trim.las");
    let mut reader = las::Reader::from_path(&path).unwrap();
    let data = reader.read_all().unwrap();
    let points_m: Vec<[f64; 3]> = data
        .points()
        .map(|p| p.map(|p| [p.x, p.y, p.z]))
        .collect::<Result<_, _>>()
        .unwrap();
    assert!(points_m.len() > 100_000);
    assert!(points_m[0][0] > 100_000.0, "coordinates are georeferenced");
    let index = GroundTruthIndex::from_points(&points_m).unwrap();

    // The index holds the points in f32 relative to the centre of their box: each coordinate
    // rounds by at most 2⁻²⁴ of its distance from the centre, so a GT point is found within
    // √3 of that of itself, and any distance is off by at most twice it (the stored neighbour
    // may be a point that rounding brought closer).
    let (lo, hi) = index.bounds_m();
    let half_extent = (0..3).map(|k| 0.5 * (hi[k] - lo[k])).fold(0.0, f64::max);
    let rounding = 3f64.sqrt() * half_extent * 2f64.powi(-24);
    assert!(rounding < 1e-4, "{rounding}");
    let self_d = index.nearest_distances_m(&points_m[..5000]).unwrap();
    assert!(self_d.iter().all(|&d| d as f64 <= rounding), "{rounding}");

    // Lifted queries against brute force.
    let queries: Vec<[f64; 3]> = points_m
        .iter()
        .step_by(50)
        .map(|p| [p[0], p[1], p[2] + 0.1])
        .collect();
    let d = index.nearest_distances_m(&queries).unwrap();
    for (q, &di) in queries.iter().zip(&d).step_by(10) {
        let brute = points_m
            .iter()
            .map(|p| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt())
            .fold(f64::INFINITY, f64::min);
        assert!(
            (di as f64 - brute).abs() < 2.0 * rounding + 1e-6,
            "tree {di} vs brute force {brute}"
        );
    }
    assert!(d.iter().all(|&d| d as f64 <= 0.1 + 2.0 * rounding + 1e-6));
}

#[test]
fn a_sparse_ground_truth_is_said_to_be_one() {
    // A dense plane mesh scored against the same plane sampled every 2 cm (dense) and in lines
    // 1 m apart (a scan's rings): only the second earns the warning.
    let mesh = plane_mesh(-3.0, 3.0, -3.0, 3.0, 0.0, 0.05);
    let options = EvalOptions {
        surface_sample_spacing_m: Some(0.02),
        completeness: Some(CompletenessRegion::All),
        histogram: HistogramSpec {
            bin_width_m: 0.01,
            max_m: 3.0,
        },
    };
    let dense = plane_samples(-3.0, 3.0, -3.0, 3.0, 0.0, 0.02);
    let report = evaluate_mesh(
        "dense",
        &mesh,
        &GroundTruthIndex::new(&dense).unwrap(),
        &options,
    )
    .unwrap();
    assert_eq!(denser::eval::sparse_ground_truth_note(&report), None);
    let mut rings = PointCloud::default();
    for line in -3..=3 {
        for k in 0..=600 {
            rings
                .points_m
                .push([-3.0 + k as f64 * 0.01, 0.0, line as f64]);
        }
    }
    let report = evaluate_mesh(
        "rings",
        &mesh,
        &GroundTruthIndex::new(&rings).unwrap(),
        &options,
    )
    .unwrap();
    let note = denser::eval::sparse_ground_truth_note(&report).expect("a warning");
    assert!(
        note.contains("too sparse") && note.contains("rings surface"),
        "{note}"
    );
    // The accuracy median of a plane against lines 1 m apart is a quarter metre.
    assert!(
        (report.accuracy.median_m - 0.25).abs() < 0.02,
        "{}",
        report.accuracy.median_m
    );
}
