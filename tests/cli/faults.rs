//! The crash suite (issue 36 item 7), as storage engines that users trust test themselves
//! (SQLite's crash and I/O-error tests): a scripted `reconstruct --map` → `regularize` (swept and
//! sharded) → `merge` → `export --shard` run on a tiny synthetic LiDAR drive, each step
//! interrupted at its Nth map operation by `DENSER_FAULT_INJECTION` (`crash@N`: the operation cut
//! short and the process dead from there; `error@N`: the operation fails with "no space left"),
//! for every N of the step (or a stated sample). After each interruption:
//!
//! 1. every map the step touched opens and verifies (`inspect --verify`), or is refused with the
//!    reason a user can act on (an unfinished merge; a map not yet created);
//! 2. no committed block is lost (the block count never falls below the state before the step);
//! 3. the same command run again completes, and its output is byte for byte the output of the
//!    uninterrupted step.

use super::map::{bin, copy_dir, text};
use std::path::{Path, PathBuf};
use std::process::Output;

/// Runs `denser args` in `cwd`, with `DENSER_FAULT_INJECTION` set to `fault` when given.
pub(super) fn run(args: &[String], cwd: &Path, fault: Option<&str>) -> Output {
    let mut c = bin();
    c.args(args).current_dir(cwd);
    c.env_remove("DENSER_FAULT_INJECTION");
    if let Some(f) = fault {
        c.env("DENSER_FAULT_INJECTION", f);
    }
    c.output().expect("run denser")
}

pub(super) fn ok(args: &[String], cwd: &Path) -> String {
    let o = run(args, cwd, None);
    assert!(o.status.success(), "denser {args:?} failed:\n{}", text(&o));
    text(&o)
}

pub(super) fn args(s: &str) -> Vec<String> {
    s.split_whitespace().map(str::to_string).collect()
}

/// The map operations an uninterrupted run of `a` makes (it must succeed).
fn operations(a: &[String], cwd: &Path) -> u64 {
    let o = run(a, cwd, Some("count"));
    let t = text(&o);
    assert!(o.status.success(), "denser {a:?} failed:\n{t}");
    t.lines()
        .find_map(|l| {
            l.strip_prefix("DENSER_FAULT_INJECTION: ")
                .and_then(|r| r.split_whitespace().next())
                .and_then(|n| n.parse().ok())
        })
        .unwrap_or_else(|| panic!("no operation count in:\n{t}"))
}

/// Blocks of `map` after `inspect --verify` passed; `None` when the map is refused with one of
/// `refusals` (the only acceptable reasons), a panic otherwise.
pub(super) fn verified_blocks(
    map: &str,
    cwd: &Path,
    refusals: &[&str],
    context: &str,
) -> Option<u64> {
    let o = run(&args(&format!("inspect {map} --verify --json")), cwd, None);
    let t = text(&o);
    if !o.status.success() {
        assert!(
            refusals.iter().any(|r| t.contains(r)),
            "{context}: {map} neither opens and verifies nor is refused for an accepted reason:\n{t}"
        );
        return None;
    }
    let start = t.find('{').expect("json");
    let end = t.rfind('}').expect("json");
    let v: serde_json::Value = serde_json::from_str(&t[start..=end]).expect("json");
    assert_eq!(
        v["problems"].as_array().map(Vec::len),
        Some(0),
        "{context}: {t}"
    );
    v["summary"]["blocks"].as_u64()
}

/// The crash points of a step with `total` operations: all of them up to 12 and the last 6,
/// and every `stride`-th in between (CI's time; `DENSER_FAULTS_ALL=1` runs every one).
fn points(total: u64, stride: u64) -> Vec<u64> {
    let all = std::env::var_os("DENSER_FAULTS_ALL").is_some();
    (1..=total)
        .filter(|n| all || *n <= 12 || *n + 6 > total || n % stride == 0)
        .collect()
}

/// One step of the script: from the maps in `before` (copied into a fresh folder per run), the
/// command `step`, then `finish` (commands after it that the check needs, run plainly), then the
/// output `output` compared with the uninterrupted run's.
struct Step<'a> {
    name: &'a str,
    before: &'a Path,
    maps: &'a [&'a str],
    step: Vec<String>,
    finish: Vec<Vec<String>>,
    output: &'a str,
    refusals: &'a [&'a str],
}

/// Runs `s` uninterrupted (the reference), then interrupted at every chosen point with `fault`;
/// returns the number of interrupted runs checked.
fn exercise(s: &Step, work: &Path, fault: &str, stride: u64) -> usize {
    let reference = work.join(format!("{}_reference", s.name));
    copy_dir(s.before, &reference);
    let blocks_before: Vec<Option<u64>> = s
        .maps
        .iter()
        .map(|m| {
            reference
                .join(m)
                .join("manifest.dmf")
                .exists()
                .then(|| verified_blocks(m, &reference, &[], "before").expect("before"))
        })
        .collect();
    let total = operations(&s.step, &reference);
    for f in &s.finish {
        ok(f, &reference);
    }
    let want = std::fs::read(reference.join(s.output)).expect("reference output");
    let mut checked = 0;
    for n in points(total, stride) {
        let d = work.join(format!("{}_{fault}_{n}", s.name));
        copy_dir(s.before, &d);
        let context = format!("{} interrupted by {fault}@{n} of {total}", s.name);
        let o = run(&s.step, &d, Some(&format!("{fault}@{n}")));
        let out = text(&o);
        assert!(
            !out.contains("panicked"),
            "{context}: the process panicked:\n{out}"
        );
        for (m, before) in s.maps.iter().zip(&blocks_before) {
            let now = verified_blocks(m, &d, s.refusals, &context);
            if let (Some(b), Some(now)) = (before, now) {
                assert!(now >= *b, "{context}: {m} lost blocks ({b} → {now})");
            }
        }
        if !o.status.success() {
            let resumed = run(&s.step, &d, None);
            assert!(
                resumed.status.success(),
                "{context}: running the step again failed:\n{}",
                text(&resumed)
            );
        }
        for f in &s.finish {
            ok(f, &d);
        }
        let got = std::fs::read(d.join(s.output)).expect("output");
        assert!(
            got == want,
            "{context}: the output differs from the uninterrupted run's"
        );
        std::fs::remove_dir_all(&d).expect("clean");
        checked += 1;
    }
    std::fs::remove_dir_all(&reference).expect("clean");
    eprintln!(
        "crash suite: {} {fault}: {checked} of {total} operations interrupted and checked",
        s.name
    );
    checked
}

/// `reconstruct --map` of the drive in `root`: 2 MiB, so that the pager evicts chunks while it
/// fuses, checkpoints every two scans.
pub(super) fn fuse(root: &Path) -> String {
    format!(
        "reconstruct {} --depth lidar --memory-budget 2MiB --chunk-blocks 4 --checkpoint-every 2 --voxel-size 0.2 --allow-overrun --skip-regularize --no-eval --max-depth 10",
        root.join("drive/sequences/00").display()
    )
}

/// A folder holding the tiny drive and the states between the steps.
struct Script {
    _dir: tempfile::TempDir,
    root: PathBuf,
}

impl Script {
    fn new() -> Self {
        let dir = tempfile::tempdir().expect("tempdir");
        let root = dir.path().to_path_buf();
        ok(
            &args("synth --out drive --length-m 14 --frame-spacing-m 4 --lidar-only"),
            &root,
        );
        Script { _dir: dir, root }
    }

    /// A state folder `name` with the maps `from` holds plus the commands `cmds` run in it.
    fn state(&self, name: &str, from: Option<&str>, cmds: &[String]) -> PathBuf {
        let d = self.root.join(name);
        std::fs::create_dir_all(&d).expect("mkdir");
        if let Some(f) = from {
            copy_dir(&self.root.join(f), &d);
        }
        for c in cmds {
            ok(&args(c), &d);
        }
        d
    }
}

#[test]
fn every_interrupted_map_operation_leaves_a_map_that_resumes_to_the_same_bytes() {
    let s = Script::new();
    let work = s.root.join("runs");
    std::fs::create_dir_all(&work).expect("mkdir");
    let empty = s.state("empty", None, &[]);
    let fused = s.state(
        "fused",
        None,
        &[
            format!("{} --map a --out oa", fuse(&s.root)),
            format!("{} --map b --out ob --first 2", fuse(&s.root)),
        ],
    );
    let sharded = s.state(
        "sharded",
        Some("fused"),
        &[
            "regularize a --iterations 4 --shard 0/2".into(),
            "regularize a --iterations 4 --shard 1/2".into(),
        ],
    );
    let merged = s.state(
        "merged",
        Some("fused"),
        &[
            "merge a b --out m".into(),
            "regularize m --iterations 4".into(),
        ],
    );
    let not_yet = ["no manifest here", "not a denser map"];
    let unfinished = ["unfinished map"];
    let steps = [
        Step {
            name: "reconstruct",
            before: &empty,
            maps: &["a"],
            step: args(&format!("{} --map a --out oa", fuse(&s.root))),
            finish: vec![args("export a --raw --mesh raw.ply")],
            output: "raw.ply",
            refusals: &not_yet,
        },
        Step {
            name: "regularize_swept",
            before: &fused,
            maps: &["a"],
            step: args("regularize a --iterations 6 --sweep-iterations 2 --region-chunks 1"),
            finish: vec![args("export a --mesh u.ply")],
            output: "u.ply",
            refusals: &[],
        },
        Step {
            name: "regularize_shard",
            before: &fused,
            maps: &["a"],
            step: args("regularize a --iterations 4 --shard 1/2"),
            finish: vec![
                args("regularize a --iterations 4 --shard 0/2"),
                args("regularize a --iterations 4"),
                args("export a --mesh u.ply"),
            ],
            output: "u.ply",
            refusals: &[],
        },
        Step {
            name: "regularize_adopting",
            before: &sharded,
            maps: &["a"],
            step: args("regularize a --iterations 4"),
            finish: vec![args("export a --mesh u.ply")],
            output: "u.ply",
            refusals: &[],
        },
        Step {
            name: "merge",
            before: &fused,
            maps: &["a", "b", "m"],
            step: args("merge a b --out m"),
            finish: vec![args("export m --raw --mesh m.ply")],
            output: "m.ply",
            refusals: &["unfinished map", "no manifest here", "not a denser map"],
        },
        Step {
            name: "export_shard",
            before: &merged,
            maps: &["m"],
            step: args("export m --mesh parts.ply --shard 0/2"),
            finish: vec![
                args("export m --mesh parts.ply --shard 1/2"),
                args("export m --mesh parts.ply"),
            ],
            output: "parts.ply",
            refusals: &unfinished,
        },
    ];
    let mut crash = 0;
    let mut error = 0;
    for step in &steps {
        crash += exercise(step, &work, "crash", 3);
        error += exercise(step, &work, "error", 7);
    }
    eprintln!("crash suite: {crash} crash points and {error} I/O-error points checked");
    assert!(crash > 100 && error > 50, "{crash} {error}");
}
