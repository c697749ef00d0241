//! The whole job within `--memory-budget` (issue "A map survives its users", item 6): a refused
//! budget suggests one that works, and `reconstruct --map` evaluates its surfaces out of core
//! with the figures of the in-memory evaluation of the same meshes (`denser evaluate`).

use super::map::{denser, lidar_drive, ok, text};

const MIB: u64 = 1 << 20;

fn reconstruct(budget_mib: u64, map: &str, out: &str, eval: bool) -> Vec<String> {
    let mut a: Vec<String> = [
        "reconstruct",
        "drive/sequences/00",
        "--depth",
        "lidar",
        "--map",
        map,
        "--out",
        out,
        "--memory-budget",
        &format!("{budget_mib}MiB"),
        "--max-depth",
        "30",
        "--iterations",
        "10",
        "--device",
        "cpu",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    if !eval {
        a.push("--no-eval".into());
    }
    a
}

/// Following the suggestion of each refusal reaches a budget that runs, in at most three steps;
/// before, each suggestion was refused again a MiB or two higher (16 → 19 → 38 → 42 → 44 → …).
#[test]
fn a_refused_budget_suggests_one_that_works() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    lidar_drive(d, "60", "2");
    let mut budget = 8u64;
    let mut tried = Vec::new();
    for step in 0..=3 {
        let args = reconstruct(budget, &format!("m{step}"), &format!("o{step}"), false);
        let args: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
        let o = denser(&args, d);
        tried.push(budget);
        if o.status.success() {
            assert!(
                step > 0,
                "8 MiB must be refused for this test to mean anything"
            );
            return;
        }
        let t = text(&o);
        let at_least = t
            .split("at least ")
            .nth(1)
            .and_then(|s| s.split(" MiB").next())
            .and_then(|n| n.trim().parse::<u64>().ok())
            .unwrap_or_else(|| panic!("no suggested budget in:\n{t}"));
        assert!(at_least > budget, "{t}");
        budget = at_least;
    }
    panic!("budgets tried {tried:?}: the last suggestion was refused too");
}

fn number(v: &serde_json::Value, path: &[&str]) -> f64 {
    let mut x = v;
    for p in path {
        x = &x[*p];
    }
    x.as_f64()
        .unwrap_or_else(|| panic!("{path:?} is not a number: {x}"))
}

/// `reconstruct --map` scores its surfaces from their files, tile by tile, within the budget:
/// the report's figures equal those of `denser evaluate` (the ground truth and meshes in RAM) on
/// the same meshes, and the process stays within B + 64 MiB with the evaluation.
#[test]
fn a_map_run_evaluates_out_of_core_with_the_in_memory_figures() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    lidar_drive(d, "60", "2");
    let budget_mib = 48;
    let args = reconstruct(budget_mib, "m", "out", true);
    let args: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
    let log = ok(&args, d);
    assert!(log.contains("evaluated surface (tiled)"), "{log}");
    let json = |file: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(d.join(file)).expect(file)).expect(file)
    };
    let tiled = json("out/report.json");
    let map_report = json("out/map_report.json");
    let peak = map_report["peak_rss_bytes"].as_u64().expect("peak RSS");
    println!(
        "reconstruct --map with evaluation at {budget_mib} MiB: peak RSS {:.1} MiB",
        peak as f64 / MIB as f64
    );
    assert!(peak <= (budget_mib + 64) * MIB, "peak RSS {peak}");
    // No scratch left behind.
    let leftovers: Vec<_> = std::fs::read_dir(d.join("out"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".partial"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    // `denser evaluate` of the same meshes, in RAM (the oracle) and tile by tile with
    // `--memory-budget` (the same out-of-core path for any mesh files).
    let evaluate = |out: &str, budget: &[&str]| -> serde_json::Value {
        let mut args = vec![
            "evaluate",
            "--mesh",
            "raw=out/mesh_raw.ply",
            "--mesh",
            "regularized=out/mesh_regularized.ply",
            "--gt",
            "drive/sequences/00",
            "--out",
            out,
        ];
        args.extend(budget);
        ok(&args, d);
        json(&format!("{out}/report.json"))
    };
    let whole = evaluate("whole", &[]);
    assert_same_figures(&tiled, &whole);
    let budgeted = evaluate("budgeted", &["--memory-budget", "48MiB"]);
    assert_same_figures(&budgeted, &whole);
    let pictures = |v: &serde_json::Value| v["pictures"].as_array().unwrap().len();
    assert_eq!(pictures(&tiled), pictures(&whole));
    for p in tiled["pictures"].as_array().unwrap() {
        let f = d.join("out").join(p.as_str().unwrap());
        assert!(std::fs::metadata(&f).unwrap().len() > 10_000, "{f:?}");
    }
}

/// The figures of two reports of the same meshes: `a` scored tile by tile, `b` in memory.
fn assert_same_figures(tiled: &serde_json::Value, whole: &serde_json::Value) {
    assert_eq!(tiled["ground_truth_points"], whole["ground_truth_points"]);
    for s in 0..2 {
        let (a, b) = (&tiled["surfaces"][s], &whole["surfaces"][s]);
        assert_eq!(a["label"], b["label"]);
        for k in ["vertices", "triangles"] {
            assert_eq!(a[k], b[k], "{k}");
        }
        let area = |v: &serde_json::Value| number(v, &["surface_area_m2"]);
        assert!((area(a) - area(b)).abs() <= 1e-6 * area(b), "area");
        for stats in ["accuracy", "accuracy_unrestricted", "completeness"] {
            assert!(
                b[stats].is_object(),
                "{stats} missing in the in-memory report"
            );
            // The completeness region's faces: a ground-truth point within a µm of one may fall
            // either side (rounded relative to its tile, or to the cloud's centre).
            let count = |v: &serde_json::Value| v[stats]["count"].as_i64().unwrap();
            assert!(
                (count(a) - count(b)).abs() <= count(b) / 100_000,
                "{stats} count: tiled {}, in memory {}",
                count(a),
                count(b)
            );
            // Distances to within the f32 rounding of the stored points (a few µm); a point
            // more or less on the region's face (metres from the surface) moves the mean by
            // its share.
            let moved_points = (count(a) - count(b)).abs() as f64 / count(b) as f64;
            for k in ["median_m", "p75_m", "p90_m", "mean_m", "rmse_m", "max_m"] {
                let (x, y) = (number(&a[stats], &[k]), number(&b[stats], &[k]));
                assert!(
                    (x - y).abs() <= 1e-5 + 100.0 * moved_points * y.abs(),
                    "{stats} {k}: tiled {x}, in memory {y}"
                );
            }
            let counts = |v: &serde_json::Value| -> Vec<i64> {
                v["histogram"]["counts"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|c| c.as_i64().unwrap())
                    .collect()
            };
            let moved: i64 = counts(&a[stats])
                .iter()
                .zip(counts(&b[stats]))
                .map(|(x, y)| (x - y).abs())
                .sum();
            let n = a[stats]["count"].as_i64().unwrap();
            assert!(
                moved * 10_000 <= n,
                "{stats}: {moved} of {n} distances changed bins"
            );
        }
    }
}
