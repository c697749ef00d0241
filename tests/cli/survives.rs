//! A map survives its users (issue 36): the defects a hostile tester found, reproduced through the
//! binary, each now refused with a message that names the file or the parameter, and nothing of
//! the map lost or changed.

use super::map::{copy_dir, denser, lidar_drive, map_json, ok, reconstruct_args, text};
use std::path::Path;

/// A small finished map `m` in `d` (three scans fused, not regularized), with its drive.
fn small_map(d: &Path) {
    lidar_drive(d, "30", "6");
    let mut args = reconstruct_args("m", "o");
    args.extend(["--last", "3", "--skip-regularize", "--no-eval"]);
    ok(&args, d);
}

/// Item 4: with `job.djr` deleted, a run with other settings "resumed after N committed frames",
/// mixing two jobs, and wrote a new record over the evidence.
#[test]
fn a_resume_without_its_job_record_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    small_map(d);
    let before = map_json("m", d);
    assert_eq!(before["frames_committed"].as_u64(), Some(3), "{before}");
    std::fs::remove_file(d.join("m/job.djr")).expect("lose the job record");
    let mut args = reconstruct_args("m", "o2");
    args.extend([
        "--step",
        "2",
        "--max-depth",
        "20",
        "--skip-regularize",
        "--no-eval",
    ]);
    let o = denser(&args, d);
    let out = text(&o);
    assert!(!o.status.success(), "resumed without a job record:\n{out}");
    assert!(
        out.contains("job.djr") && out.contains("missing") && out.contains("3 committed frames"),
        "{out}"
    );
    assert!(
        !d.join("m/job.djr").exists(),
        "a record was written over the evidence"
    );
    let after = map_json("m", d);
    assert_eq!(after["summary"], before["summary"]);
    assert_eq!(after["frames_committed"], before["frames_committed"]);
}

/// Item 5: `regularize --lambda inf` committed a pass whose mesh had no vertex.
#[test]
fn non_finite_or_overflowing_lambda_is_refused_before_any_pass() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    small_map(d);
    let before = map_json("m", d);
    for lambda in ["inf", "1e30", "NaN"] {
        let o = denser(
            &["regularize", "m", "--lambda", lambda, "--iterations", "4"],
            d,
        );
        let out = text(&o);
        assert!(!o.status.success(), "--lambda {lambda} accepted:\n{out}");
        assert!(out.contains("λ ≤ 1e6"), "--lambda {lambda}: {out}");
    }
    let after = map_json("m", d);
    assert_eq!(after["regularization"], before["regularization"]);
    assert_eq!(
        after["generation"], before["generation"],
        "nothing committed"
    );
}

/// Item 5: `merge M M --out X` doubled every weight (and so would a copy of M, which has M's
/// identity).
#[test]
fn merge_refuses_a_map_given_twice() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    small_map(d);
    copy_dir(&d.join("m"), &d.join("m_copy"));
    for inputs in [["m", "m"], ["m", "m_copy"]] {
        let o = denser(&["merge", inputs[0], inputs[1], "--out", "x"], d);
        let out = text(&o);
        assert!(!o.status.success(), "merge {inputs:?} accepted:\n{out}");
        assert!(
            out.contains("same map") && out.contains("double every weight"),
            "{out}"
        );
        assert!(
            !d.join("x/manifest.dmf").exists(),
            "an output map was created"
        );
    }
}

/// Item 5: an origin outside its CRS wrote `null` into tileset.json's transform.
#[test]
fn a_georeference_outside_its_crs_is_refused_before_any_output() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    small_map(d);
    for (georef, word) in [
        ("EPSG:32632@1e12,5335000,500", "easting"),
        ("EPSG:32632@691000,5e8,500", "northing"),
        ("EPSG:32632@691000,-5335000,500", "northing"),
    ] {
        let o = denser(
            &["export", "m", "--raw", "--tiles", "t", "--georef", georef],
            d,
        );
        let out = text(&o);
        assert!(!o.status.success(), "{georef} accepted:\n{out}");
        assert!(out.contains(word), "{georef}: {out}");
        assert!(
            !d.join("t/tileset.json").exists(),
            "{georef}: a tileset was written"
        );
    }
}

/// Item 7: `export --tiles DIR` over an existing tileset deleted a user's other files in DIR, and
/// a killed export's `.NAME.PID.partial` files and COPC spill folders stayed for good. Now an
/// export never replaces a folder holding files it does not write, and removes what dead
/// exports left beside its target (never a live process's).
#[test]
fn exports_delete_only_their_own_files_and_clean_up_after_killed_ones() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    small_map(d);
    ok(&["export", "m", "--raw", "--tiles", "t"], d);
    let tileset = std::fs::read(d.join("t/tileset.json")).expect("tileset");
    std::fs::write(d.join("t/notes.txt"), "mine").expect("a user's file");
    let o = denser(&["export", "m", "--raw", "--tiles", "t"], d);
    let out = text(&o);
    assert!(
        !o.status.success(),
        "replaced a folder with a user's file:\n{out}"
    );
    assert!(
        out.contains("notes.txt") && out.contains("new folder"),
        "{out}"
    );
    assert_eq!(std::fs::read(d.join("t/notes.txt")).expect("kept"), b"mine");
    assert_eq!(
        std::fs::read(d.join("t/tileset.json")).expect("kept"),
        tileset
    );
    std::fs::remove_file(d.join("t/notes.txt")).expect("rm");
    ok(&["export", "m", "--raw", "--tiles", "t"], d);

    // Leftovers of a dead process (a finished child's pid) and of a live one (this test's).
    let mut child = std::process::Command::new("true").spawn().expect("spawn");
    let dead_pid = child.id();
    child.wait().expect("wait");
    let live_pid = std::process::id();
    let stale = [
        format!(".mesh.ply.{dead_pid}.partial.ply"),
        format!(".mesh.vertices.{dead_pid}.partial.vertices"),
        format!(".p.copc.spill.{dead_pid}.partial.spill"),
    ];
    for s in &stale[..2] {
        std::fs::write(d.join(s), "partial").expect("leftover");
    }
    std::fs::create_dir_all(d.join(&stale[2])).expect("spill folder");
    std::fs::write(d.join(&stale[2]).join("input.pts"), "x").expect("spill");
    let live = format!(".mesh.ply.{live_pid}.partial.ply");
    let unrelated = format!(".other.ply.{dead_pid}.partial.ply");
    std::fs::write(d.join(&live), "running").expect("live");
    std::fs::write(d.join(&unrelated), "another output's").expect("unrelated");
    ok(&["export", "m", "--raw", "--mesh", "mesh.ply"], d);
    ok(&["export", "m", "--raw", "--points", "p.copc.laz"], d);
    for s in &stale {
        assert!(!d.join(s).exists(), "{s} left");
    }
    assert!(d.join(&live).exists(), "a live process's file was removed");
    assert!(
        d.join(&unrelated).exists(),
        "another output's leftover was removed"
    );
}
