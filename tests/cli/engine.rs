//! Issue 15 (items 1–4) as the issue reports them, with the real `denser` binary on a small
//! synthetic LiDAR drive: two concurrent writers (the second refused at once naming the holder,
//! the map intact and verified); a chunk file swapped for the same chunk of an older map refused by
//! `export` and `regularize`; a deleted manifest refused by every command and rebuilt by
//! `denser repair`; a killed re-regularization reported by `inspect`, refused by `export`, its
//! previous complete pass still exportable, and finished by the next run (which recovers the
//! killed run's stale lock).

use denser::map::manifest::decode_manifest;
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_denser"))
}

fn denser(args: &[&str], cwd: &Path) -> Output {
    bin()
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

fn ok(args: &[&str], cwd: &Path) -> String {
    let o = denser(args, cwd);
    assert!(o.status.success(), "denser {args:?} failed:\n{}", text(&o));
    text(&o)
}

fn fails(args: &[&str], cwd: &Path) -> String {
    let o = denser(args, cwd);
    assert!(
        !o.status.success(),
        "denser {args:?} should have failed:\n{}",
        text(&o)
    );
    text(&o)
}

/// This machine's name as the lock file records it (kept apart from the library's own function so
/// the test also builds, and fails, on code before issue 15).
fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .unwrap_or_default()
}

fn spawn(args: &[&str], cwd: &Path) -> Child {
    bin()
        .args(args)
        .current_dir(cwd)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn denser")
}

fn kill9(child: &mut Child) {
    let _ = Command::new("kill")
        .args(["-9", &child.id().to_string()])
        .status();
    let _ = child.wait();
}

fn synth(d: &Path, length_m: &str) {
    ok(
        &[
            "synth",
            "--out",
            "drive",
            "--length-m",
            length_m,
            "--frame-spacing-m",
            "6",
            "--lidar-only",
        ],
        d,
    );
}

/// `reconstruct --map` on the drive at 20 cm voxels, chunks of 8³ blocks, 4 TV iterations; `extra`
/// must give `--memory-budget` and `--checkpoint-every` (or use [`quick`]).
fn reconstruct_args<'a>(map: &'a str, out: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut v = vec![
        "reconstruct",
        "drive/sequences/00",
        "--depth",
        "lidar",
        "--map",
        map,
        "--out",
        out,
        "--chunk-blocks",
        "8",
        "--iterations",
        "4",
        "--region-chunks",
        "1",
        "--voxel-size",
        "0.2",
        "--allow-overrun",
        "--no-eval",
    ];
    v.extend_from_slice(extra);
    v
}

/// [`reconstruct_args`] with every chunk resident and one checkpoint at the end (fast).
fn quick<'a>(map: &'a str, out: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut e = vec!["--memory-budget", "256MiB", "--checkpoint-every", "0"];
    e.extend_from_slice(extra);
    reconstruct_args(map, out, &e)
}

fn map_json(map: &str, cwd: &Path) -> serde_json::Value {
    let s = ok(&["inspect", map, "--verify", "--json"], cwd);
    let start = s.find('{').expect("json");
    let end = s.rfind('}').expect("json");
    serde_json::from_str(&s[start..=end]).expect("parse")
}

fn chunk_files(map: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(map.join("chunks"))
        .expect("ls")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn manifest(map: &Path) -> Option<denser::map::manifest::Manifest> {
    decode_manifest(&std::fs::read(map.join("manifest.dmf")).ok()?).ok()
}

/// Waits until the child writer holds the map: `map/lock` names `pid`, or (code without a lock)
/// it has committed its first checkpoint. False when the child ended first.
fn wait_for_writer(map: &Path, pid: u32, child: &mut Child) -> bool {
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(60) {
        if let Ok(s) = std::fs::read_to_string(map.join("lock")) {
            if s.contains(&format!("pid={pid}\n")) {
                return true;
            }
        }
        if manifest(map).is_some_and(|m| m.header.generation >= 2) {
            return true;
        }
        if child.try_wait().expect("try_wait").is_some() {
            return false;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    false
}

#[test]
fn two_concurrent_writers_one_refused_naming_the_holder_the_map_intact() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    synth(d, "60");
    // Reference: an uninterrupted run.
    ok(&quick("ref", "ref_out", &["--skip-regularize"]), d);
    let reference = map_json("ref", d);

    // Issue 15.1: `reconstruct --checkpoint-every` running, then `regularize` on the same map.
    let writer = [
        "--skip-regularize",
        "--memory-budget",
        "24MiB",
        "--checkpoint-every",
        "2",
    ];
    let mut tested = false;
    for attempt in 0..3 {
        let _ = std::fs::remove_dir_all(d.join("m"));
        let mut first = spawn(&reconstruct_args("m", "m_out", &writer), d);
        let pid = first.id();
        if !wait_for_writer(&d.join("m"), pid, &mut first) {
            let _ = first.wait();
            continue;
        }
        let t = Instant::now();
        let second = denser(&["regularize", "m", "--iterations", "5"], d);
        let waited = t.elapsed();
        let again = denser(&reconstruct_args("m", "m_out2", &writer), d);
        let repair = denser(&["repair", "m"], d);
        // A reader meanwhile sees a committed state.
        let reader = denser(&["inspect", "m", "--verify", "--json"], d);
        let still_running = first.try_wait().expect("try_wait").is_none();
        let status = first.wait().expect("wait");
        assert!(status.success(), "the first writer must finish");
        if !still_running && second.status.success() {
            println!("attempt {attempt}: the first writer finished too early; again");
            continue;
        }
        for (what, o) in [
            ("regularize", &second),
            ("reconstruct", &again),
            ("repair", &repair),
        ] {
            let t = text(o);
            assert!(!o.status.success(), "{what} must be refused:\n{t}");
            assert!(
                t.contains("locked by another writer")
                    && t.contains(&format!("pid {pid} on host"))
                    && t.contains(&host_name())
                    && t.contains("denser reconstruct drive/sequences/00"),
                "{what}: {t}"
            );
        }
        assert!(
            waited < Duration::from_secs(3),
            "refused at once, not after waiting: {waited:?}"
        );
        assert!(reader.status.success(), "{}", text(&reader));
        tested = true;
        break;
    }
    assert!(tested, "no attempt overlapped the two writers");
    // The map is intact: verified, the same as the uninterrupted run, no orphan or missing file.
    let j = map_json("m", d);
    for k in ["chunks", "blocks", "observed_voxels"] {
        assert_eq!(j["summary"][k], reference["summary"][k], "{k}");
    }
    assert_eq!(j["frames_committed"], reference["frames_committed"]);
    let m = manifest(&d.join("m")).expect("manifest");
    assert_eq!(chunk_files(&d.join("m")).len(), m.chunks.len());
    // The writer exited cleanly: its lock file is empty, and a new writer gets the lock.
    assert_eq!(std::fs::read_to_string(d.join("m/lock")).expect("lock"), "");
    let out = ok(&["regularize", "m", "--iterations", "5"], d);
    assert!(out.contains("regularization pass 1"), "{out}");
}

#[test]
fn a_swapped_chunk_is_refused_by_export_and_regularize() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    synth(d, "60");
    ok(&quick("new", "new_out", &["--skip-regularize"]), d);
    // An older map of the same drive: its first 5 frames.
    ok(
        &quick("old", "old_out", &["--skip-regularize", "--last", "5"]),
        d,
    );
    let new = manifest(&d.join("new")).expect("new");
    let old = manifest(&d.join("old")).expect("old");
    // A chunk both maps hold with other content: copy the old file over the new one's name.
    let (c, e_old) = old
        .chunks
        .iter()
        .find(|(c, e)| {
            new.chunks.get(c).is_some_and(|n| {
                n.payload_crc32 != e.payload_crc32 && n.block_count > e.block_count
            })
        })
        .expect("a chunk that grew after frame 5");
    let e_new = new.chunks[c];
    let name = denser::map::manifest::chunk_file_name(*c, e_new.file_seq);
    std::fs::copy(
        d.join("old/chunks")
            .join(denser::map::manifest::chunk_file_name(*c, e_old.file_seq)),
        d.join("new/chunks").join(&name),
    )
    .expect("swap");
    let files_before = chunk_files(&d.join("new"));
    let expect_blocks = format!(
        "blocks {} (manifest: {})",
        e_old.block_count, e_new.block_count
    );
    let expect_crc = format!(
        "payload CRC {:#010x} (manifest: {:#010x})",
        e_old.payload_crc32, e_new.payload_crc32
    );

    for args in [
        vec!["export", "new", "--mesh", "m.ply", "--raw"],
        vec!["export", "new", "--points", "p.laz", "--raw"],
    ] {
        let t = fails(&args, d);
        assert!(
            t.contains(&name)
                && t.contains("does not match its manifest entry")
                && t.contains(&expect_blocks)
                && t.contains(&expect_crc)
                && t.contains("map id"),
            "{args:?}: {t}"
        );
        assert!(!d.join("m.ply").exists() && !d.join("p.laz").exists());
    }
    let t = fails(&["regularize", "new", "--iterations", "5"], d);
    assert!(t.contains(&name) && t.contains(&expect_blocks), "{t}");
    // The swapped chunk was not rewritten: the manifest still names the same file, and verify
    // still reports it (the regularize laundered it into "all chunks intact").
    let after = manifest(&d.join("new")).expect("manifest");
    assert_eq!(after.chunks[c], e_new);
    let o = denser(&["inspect", "new", "--verify"], d);
    let t = text(&o);
    assert!(!o.status.success() && t.contains(&name), "{t}");
    assert!(
        t.contains(&format!(
            "1 of {} chunks failed verification",
            new.chunks.len()
        )),
        "{t}"
    );
    assert!(chunk_files(&d.join("new")).contains(&name));
    // Regions solved before the failure replaced their files one for one: none lost or added.
    assert_eq!(
        chunk_files(&d.join("new")).len(),
        files_before.len(),
        "no file lost"
    );
}

#[test]
fn a_deleted_manifest_is_refused_then_repaired() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    synth(d, "60");
    ok(&quick("m", "out", &[]), d);
    let before = map_json("m", d);
    ok(&["export", "m", "--mesh", "before.ply"], d);
    std::fs::remove_file(d.join("m/manifest.dmf")).expect("rm manifest");
    let files = chunk_files(&d.join("m"));
    let n = files.len();
    // Every command refuses, naming the repair; nothing is deleted or created.
    for args in [
        vec!["inspect", "m"],
        vec!["export", "m", "--mesh", "x.ply"],
        vec!["regularize", "m"],
    ] {
        let t = fails(&args, d);
        assert!(
            t.contains("manifest is lost")
                && t.contains(&format!("{n} chunk files"))
                && t.contains("denser repair m"),
            "{args:?}: {t}"
        );
    }
    let t = fails(&quick("m", "out", &[]), d);
    assert!(t.contains("denser repair m"), "{t}");
    assert_eq!(chunk_files(&d.join("m")), files, "no chunk file deleted");
    assert!(!d.join("m/manifest.dmf").exists());

    let out = ok(&["repair", "m"], d);
    assert!(
        out.contains(&format!(
            "{} chunks, {} blocks",
            before["summary"]["chunks"], before["summary"]["blocks"]
        )),
        "{out}"
    );
    assert!(out.contains("pass 1, λ 0.4"), "{out}");
    let after = map_json("m", d);
    assert_eq!(after["summary"], before["summary"]);
    assert_eq!(after["regularization"], before["regularization"]);
    ok(&["export", "m", "--mesh", "after.ply"], d);
    assert!(
        std::fs::read(d.join("before.ply")).expect("a")
            == std::fs::read(d.join("after.ply")).expect("b"),
        "the repaired map exports the same mesh"
    );
    // The fusion cursor came back from the commit mark (the map is exactly its last commit):
    // the same job resumes, with nothing left to fuse.
    assert!(
        out.contains("fusion progress: ") && out.contains("resumes"),
        "{out}"
    );
    assert_eq!(after["frames_committed"], before["frames_committed"]);
    ok(&quick("m", "out", &[]), d);
    assert_eq!(map_json("m", d)["summary"], before["summary"]);
    // Without it (a map of denser 0.2.0: a commit mark without the cursor, no
    // `manifest.next.dmf`), fusion cannot resume: refused, the map untouched.
    std::fs::remove_file(d.join("m/manifest.dmf")).expect("rm manifest");
    std::fs::remove_file(d.join("m/manifest.next.dmf")).expect("rm the begun commit's manifest");
    let mark = std::fs::read_to_string(d.join("m/last-commit")).expect("mark");
    let old_mark: String = mark
        .lines()
        .filter(|l| !l.starts_with("frames_committed"))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(d.join("m/last-commit"), old_mark).expect("0.2.0 mark");
    let out = ok(&["repair", "m"], d);
    assert!(out.contains("cannot resume"), "{out}");
    let files = chunk_files(&d.join("m"));
    let t = fails(&quick("m", "out", &[]), d);
    assert!(
        t.contains("denser repair") && t.contains("cannot resume"),
        "{t}"
    );
    assert_eq!(chunk_files(&d.join("m")), files);
}

#[test]
fn a_killed_re_regularization_is_reported_and_refused_by_export() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    synth(d, "60");
    ok(&quick("m", "out", &[]), d); // pass 1: λ 0.4, 4 iterations
    ok(&["export", "m", "--mesh", "pass1.ply"], d);
    let n = manifest(&d.join("m")).expect("m").chunks.len();
    let regularize = [
        "regularize",
        "m",
        "--lambda",
        "0.7",
        "--iterations",
        "20",
        "--region-chunks",
        "1",
    ];
    // Kill `regularize --lambda 0.7` after its first committed region.
    let mut k = 0;
    let mut pid = 0;
    for _ in 0..3 {
        let mut child = spawn(&regularize, d);
        pid = child.id();
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(120) {
            if let Some(m) = manifest(&d.join("m")) {
                if m.header.reg_pass == 2 {
                    k = m.chunks.values().filter(|e| e.reg_pass == 2).count();
                    if k > 0 {
                        break;
                    }
                }
            }
            if child.try_wait().expect("try_wait").is_some() {
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        kill9(&mut child);
        let m = manifest(&d.join("m")).expect("m");
        k = m.chunks.values().filter(|e| e.reg_pass == 2).count();
        if k > 0 && k < n {
            break;
        }
        assert!(k < n, "the run finished before the kill: make it slower");
    }
    assert!(k > 0 && k < n, "{k} of {n}");

    // inspect reports the incomplete pass (not "n chunks (n regularized)").
    let t = ok(&["inspect", "m"], d);
    assert!(
        t.contains(&format!("pass 2, λ 0.7: {k} of {n} chunks (incomplete"))
            && t.contains("pass 1, λ 0.4 (4 iterations) complete and still readable"),
        "{t}"
    );
    assert!(t.contains(&format!("{k} chunks at pass 2, λ 0.7:")), "{t}");
    assert!(
        t.contains(&format!("{} chunks at pass 1, λ 0.4:", n - k)),
        "{t}"
    );
    let j = map_json("m", d);
    assert_eq!(j["regularization"]["done_chunks"], k);
    assert_eq!(j["regularization"]["kept_chunks"], k);

    // export --regularized refuses; the previous pass exports whole and unchanged; mixing is
    // explicit and says which chunks are which.
    let t = fails(&["export", "m", "--mesh", "x.ply"], d);
    assert!(
        t.contains(&format!("pass 2, λ 0.7: {k} of {n} chunks"))
            && t.contains("--pass 1")
            && t.contains("--allow-incomplete-pass"),
        "{t}"
    );
    assert!(!d.join("x.ply").exists());
    let t = ok(&["export", "m", "--mesh", "p1.ply", "--pass", "1"], d);
    assert!(t.contains("exporting pass 1"), "{t}");
    assert!(
        std::fs::read(d.join("pass1.ply")).expect("a")
            == std::fs::read(d.join("p1.ply")).expect("b"),
        "the last complete pass is still readable, bit for bit"
    );
    let t = ok(
        &[
            "export",
            "m",
            "--mesh",
            "mixed.ply",
            "--allow-incomplete-pass",
        ],
        d,
    );
    assert!(
        t.contains(&format!("{k} chunks at pass 2, λ 0.7: ("))
            && t.contains(&format!("{} chunks at pass 1, λ 0.4: (", n - k)),
        "{t}"
    );
    assert!(fails(&["export", "m", "--mesh", "y.ply", "--pass", "2"], d)
        .contains("cannot be exported whole"));

    // The next run recovers the killed run's lock (naming it), finishes pass 2, drops pass 1.
    let t = ok(&regularize, d);
    assert!(
        t.contains(&format!("recovered the writer lock of pid {pid}")),
        "{t}"
    );
    assert!(t.contains("regularization pass 2"), "{t}");
    let t = ok(&["inspect", "m", "--verify"], d);
    assert!(
        t.contains(&format!("pass 2, λ 0.7: {n} of {n} chunks (complete")),
        "{t}"
    );
    assert_eq!(
        chunk_files(&d.join("m")).len(),
        n,
        "pass-1 files deleted at completion"
    );
    ok(&["export", "m", "--mesh", "pass2.ply"], d);
    assert!(fails(&["export", "m", "--mesh", "z.ply", "--pass", "1"], d)
        .contains("cannot be exported whole"));
}
