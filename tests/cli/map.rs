//! The out-of-core CLI on a tiny synthetic LiDAR drive, run as a user would: `reconstruct --map`
//! killed with SIGKILL mid-run leaves a map that opens and verifies, and resuming it gives the same
//! map and meshes as an uninterrupted run; `inspect --verify` names a corrupted chunk;
//! `regularize` and `export` work on the archived map.

use std::path::Path;
use std::process::{Command, Output};

pub(crate) fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_denser"))
}

pub(crate) fn denser(args: &[&str], cwd: &Path) -> Output {
    bin()
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("run denser")
}

pub(crate) fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

pub(crate) fn ok(args: &[&str], cwd: &Path) -> String {
    let o = denser(args, cwd);
    assert!(o.status.success(), "denser {args:?} failed:\n{}", text(&o));
    text(&o)
}

pub(crate) fn reconstruct_args<'a>(map: &'a str, out: &'a str) -> Vec<&'a str> {
    vec![
        "reconstruct",
        "drive/sequences/00",
        "--depth",
        "lidar",
        "--map",
        map,
        "--out",
        out,
        "--memory-budget",
        "24MiB",
        "--chunk-blocks",
        "4",
        "--checkpoint-every",
        "2",
        "--iterations",
        "8",
        "--region-chunks",
        "1",
        "--voxel-size",
        "0.2",
        "--allow-overrun",
    ]
}

/// A synthetic LiDAR-only drive in `d/drive` of `length_m`, a scan every `spacing_m`.
pub(crate) fn lidar_drive(d: &Path, length_m: &str, spacing_m: &str) {
    ok(
        &[
            "synth",
            "--out",
            "drive",
            "--length-m",
            length_m,
            "--frame-spacing-m",
            spacing_m,
            "--lidar-only",
        ],
        d,
    );
}

pub(crate) fn map_json(map: &str, cwd: &Path) -> serde_json::Value {
    let s = ok(&["inspect", map, "--verify", "--json"], cwd);
    let start = s.find('{').expect("json");
    let end = s.rfind('}').expect("json");
    serde_json::from_str(&s[start..=end]).expect("parse")
}

#[test]
fn killed_reconstruction_resumes_to_the_same_map() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    lidar_drive(d, "120", "6");

    // The reference: one uninterrupted run.
    ok(&reconstruct_args("ref", "ref_out"), d);
    let reference = map_json("ref", d);
    assert!(
        reference["summary"]["chunks"].as_u64().expect("chunks") > 10,
        "{reference}"
    );

    // Kill a run (SIGKILL, no warning) as soon as its commit mark shows a checkpoint short of
    // the end: watching the mark, not a clock, makes the kill land mid-run on any machine.
    let total = reference["frames_committed"].as_u64().expect("frames");
    let mut resumed_once = false;
    for attempt in 0..3 {
        let _ = std::fs::remove_dir_all(d.join("killed"));
        let mut child = bin()
            .args(reconstruct_args("killed", "killed_out"))
            .current_dir(d)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("spawn");
        let files = denser::map::files::LocalFiles::new(&d.join("killed"));
        let started = std::time::Instant::now();
        let status = loop {
            if let Some(status) = child.try_wait().expect("try_wait") {
                break status; // the run ended before a mid-run commit was seen
            }
            let mark = denser::map::store::read_commit_mark_frames(&files);
            let frames = mark.ok().flatten().and_then(|(_, _, frames)| frames);
            if frames.is_some_and(|f| f > 0 && f < total)
                || started.elapsed() > std::time::Duration::from_secs(600)
            {
                let _ = Command::new("kill")
                    .args(["-9", &child.id().to_string()])
                    .status();
                break child.wait().expect("wait");
            }
            std::thread::sleep(std::time::Duration::from_millis(2));
        };
        if status.success() {
            eprintln!("attempt {attempt}: the run finished before the kill landed; again");
            continue;
        }
        assert!(
            d.join("killed/manifest.dmf").exists(),
            "killed after a commit mark, yet no manifest"
        );
        // The killed map opens and every committed chunk is intact.
        let j = map_json("killed", d);
        let committed = j["frames_committed"].as_u64().expect("frames");
        let out = ok(&reconstruct_args("killed", "killed_out"), d);
        if committed > 0 && committed < total {
            assert!(
                out.contains(&format!("resumed after {committed} committed frames")),
                "{out}"
            );
            resumed_once = true;
        }
        let resumed = map_json("killed", d);
        assert_eq!(resumed["summary"]["blocks"], reference["summary"]["blocks"]);
        assert_eq!(
            resumed["summary"]["observed_voxels"],
            reference["summary"]["observed_voxels"]
        );
        assert_eq!(resumed["frames_committed"], reference["frames_committed"]);
        for mesh in ["mesh_raw.ply", "mesh_regularized.ply"] {
            let a = std::fs::read(d.join("ref_out").join(mesh)).expect("ref mesh");
            let b = std::fs::read(d.join("killed_out").join(mesh)).expect("resumed mesh");
            assert!(
                a == b,
                "{mesh} of the resumed run differs from the uninterrupted run"
            );
        }
        if resumed_once {
            break;
        }
    }
    assert!(
        resumed_once,
        "no kill landed between two checkpoints; the test could not check resuming"
    );

    // Offline re-regularization with other parameters, then exports of the archived map.
    let out = ok(
        &[
            "regularize",
            "ref",
            "--lambda",
            "0.3",
            "--iterations",
            "5",
            "--memory-budget",
            "64MiB",
        ],
        d,
    );
    assert!(out.contains("regularization pass 2"), "{out}");
    let out = ok(&["export", "ref", "--points", "p.laz", "--regularized"], d);
    assert!(out.contains("wrote p.laz"), "{out}");
    let cloud = denser::io::las::read_point_cloud(d.join("p.laz")).expect("laz");
    assert!(cloud.points_m.len() > 1000);
    ok(
        &[
            "export",
            "ref",
            "--mesh",
            "m.ply",
            "--raw",
            "--bbox",
            "-20,-20,-20,20,20,20",
        ],
        d,
    );
    let m = denser::io::ply::read_mesh_ply(d.join("m.ply")).expect("ply");
    assert!(!m.triangles.is_empty());
    assert!(m
        .positions_m
        .iter()
        .all(|p| p.iter().all(|v| v.abs() < 21.0)));

    // A flipped byte in one chunk: inspect --verify names the file and fails.
    let chunks = d.join("ref/chunks");
    let victim = std::fs::read_dir(&chunks)
        .expect("ls")
        .next()
        .expect("a chunk")
        .expect("entry")
        .path();
    let mut bytes = std::fs::read(&victim).expect("read");
    let k = bytes.len() - 3;
    bytes[k] ^= 0x20;
    std::fs::write(&victim, bytes).expect("write");
    let o = denser(&["inspect", "ref", "--verify"], d);
    assert!(!o.status.success());
    let t = text(&o);
    let name = victim
        .file_name()
        .expect("name")
        .to_string_lossy()
        .into_owned();
    assert!(t.contains(&name) && t.contains("checksum"), "{t}");
    // Export refuses to read it silently.
    let o = denser(&["export", "ref", "--mesh", "m2.ply"], d);
    assert!(
        !o.status.success() && text(&o).contains(&name),
        "{}",
        text(&o)
    );
}

#[test]
fn map_errors_are_clear() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let o = denser(&["inspect", "nowhere"], d);
    assert!(
        !o.status.success() && text(&o).contains("nowhere/manifest.dmf"),
        "{}",
        text(&o)
    );
    let o = denser(
        &["reconstruct", "x", "--map", "m", "--memory-budget", "lots"],
        d,
    );
    assert!(
        !o.status.success() && text(&o).contains("not a size"),
        "{}",
        text(&o)
    );
}

/// Issue 15's budget and issue 14 item 5 through the binary: `reconstruct --map` refuses a budget
/// too small for regularizing one region of full chunks before it fuses anything; `regularize`
/// without `--region-chunks` plans regions to its budget and runs sweeps, and the result equals
/// the exact-halo pass's (`--sweep-iterations 0`) voxel for voxel.
#[test]
fn regularize_plans_regions_to_the_budget_and_reconstruct_checks_it_before_fusion() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    lidar_drive(d, "40", "4");
    let run = |map: &str, budget: &str, extra: &[&str]| {
        let mut a = vec![
            "reconstruct",
            "drive/sequences/00",
            "--depth",
            "lidar",
            "--map",
            map,
            "--out",
            "out",
            "--memory-budget",
            budget,
            "--voxel-size",
            "0.2",
            "--iterations",
            "16",
            "--no-eval",
        ];
        a.extend_from_slice(extra);
        denser(&a, d)
    };
    // 16³-block chunks: one full chunk with its two-block halo may need ~266 MiB.
    let t0 = std::time::Instant::now();
    let o = run("small", "64MiB", &["--chunk-blocks", "16"]);
    let t = text(&o);
    assert!(!o.status.success(), "{t}");
    assert!(
        // A 64 MiB budget leaves 48 MiB for a region (`denser::memory::data_share_bytes`).
        t.contains("over the 48 MiB a region may use")
            && t.contains("--memory-budget of at least 331 MiB")
            && t.contains("--chunk-blocks 8: up to 53 MiB"),
        "{t}"
    );
    assert!(
        !d.join("small/chunks").exists(),
        "refused before fusing: {t}"
    );
    println!("refused in {:.2} s: {t}", t0.elapsed().as_secs_f64());
    // Without --chunk-blocks the chunk edge is planned to the budget: 8 blocks (53 MiB) fit the
    // 54 MiB that a 72 MiB budget leaves for a region.
    let o = run("planned", "72MiB", &[]);
    assert!(o.status.success(), "{}", text(&o));
    let i = denser(&["inspect", "planned"], d);
    assert!(text(&i).contains("chunks of 8³ blocks"), "{}", text(&i));

    // Fused without regularizing, then regularized with a small budget, planned.
    let o = run("m", "64MiB", &["--chunk-blocks", "4", "--skip-regularize"]);
    assert!(o.status.success(), "{}", text(&o));
    copy_dir(&d.join("m"), &d.join("exact"));
    let out = ok(
        &[
            "regularize",
            "m",
            "--iterations",
            "16",
            "--memory-budget",
            "8MiB",
        ],
        d,
    );
    assert!(
        out.contains("16 iterations in 2 sweeps, regions of") && out.contains("halo 2 blocks"),
        "{out}"
    );
    assert!(!d.join("m/sweeps/s0").exists(), "state removed: {out}");
    let out = ok(
        &[
            "regularize",
            "exact",
            "--iterations",
            "16",
            "--sweep-iterations",
            "0",
            "--region-chunks",
            "1",
        ],
        d,
    );
    assert!(
        out.contains("in 1 sweep,") && out.contains("halo 3 blocks"),
        "{out}"
    );
    ok(&["export", "m", "--mesh", "swept.ply"], d);
    ok(&["export", "exact", "--mesh", "exact.ply"], d);
    let (a, b) = (
        std::fs::read(d.join("swept.ply")).expect("swept"),
        std::fs::read(d.join("exact.ply")).expect("exact"),
    );
    assert!(a.len() > 1000 && a == b, "the meshes of u differ");
}

pub(crate) fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for e in std::fs::read_dir(from).expect("ls") {
        let e = e.expect("entry");
        let target = to.join(e.file_name());
        if e.file_type().expect("type").is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), &target).expect("copy");
        }
    }
}

/// Issue 15 item 5: `--memory-budget B` bounds the process, not only the blocks it counts. The
/// stated fixed overhead: the process keeps `min(B/4, 64 MiB)` of B for itself
/// (`denser::memory::data_share_bytes`), its peak RSS stays within B + 64 MiB. Here the budget
/// binds (chunks are evicted during fusion and regions are planned to it), and the peaks of
/// `reconstruct --map` (fusion, regularization, meshes) and `regularize` are read from the
/// process's own `VmHWM`.
#[test]
fn memory_budget_bounds_the_process_peak() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    lidar_drive(d, "60", "3");
    const MIB: u64 = 1 << 20;
    let budget_mib = 32;
    let bound = (budget_mib + 64) * MIB;
    let budget = format!("{budget_mib}MiB");
    ok(
        &[
            "reconstruct",
            "drive/sequences/00",
            "--depth",
            "lidar",
            "--map",
            "m",
            "--out",
            "out",
            "--memory-budget",
            &budget,
            "--max-depth",
            "30",
            "--iterations",
            "20",
            "--no-eval",
            "--device",
            "cpu",
        ],
        d,
    );
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(d.join("out/map_report.json")).expect("map report"),
    )
    .expect("report JSON");
    let paging = &report["map"]["paging"];
    let data_share = paging["budget_bytes"].as_u64().expect("budget_bytes");
    assert_eq!(
        data_share,
        24 * MIB,
        "a quarter of 32 MiB kept for the process"
    );
    assert!(
        paging["chunks_evicted"].as_u64().unwrap() > 0,
        "the budget must bind for this test to mean anything: {paging}"
    );
    // The pager evicts down to its share; one frame's chunks may borrow the reserve, never more.
    assert!(
        paging["peak_bytes"].as_u64().unwrap() <= budget_mib * MIB,
        "{paging}"
    );
    let peak = report["peak_rss_bytes"]
        .as_u64()
        .expect("peak RSS on Linux");
    println!(
        "reconstruct --map at {budget}: peak RSS {:.1} MiB (bound {} MiB)",
        peak as f64 / MIB as f64,
        bound / MIB
    );
    assert!(peak <= bound, "peak RSS {peak} over {bound}");

    let out = ok(
        &[
            "regularize",
            "m",
            "--lambda",
            "0.7",
            "--memory-budget",
            &budget,
        ],
        d,
    );
    let mib: f64 = out
        .split("peak RSS ")
        .nth(1)
        .and_then(|s| s.split(" MiB").next())
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or_else(|| panic!("no peak RSS in: {out}"));
    println!("regularize at {budget}: peak RSS {mib} MiB");
    assert!(mib * MIB as f64 <= bound as f64, "{out}");
}
