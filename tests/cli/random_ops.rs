//! Randomised operation sequences on one map (issue 36 item 7), as FoundationDB's simulation tests
//! its storage: from a fixed seed, a sequence of what users and machines do to a map — a writer
//! killed at a random map operation (`crash@N`) or failing one (`error@N`: a full disk), a real
//! SIGKILL at a random moment, an older manifest copied over the current one (a restore), a byte of
//! a chunk file flipped (and put back, as from a backup), a second writer started while one runs —
//! interleaved with `reconstruct --map` and swept `regularize` runs. After every operation:
//!
//! 1. the map opens and verifies (`inspect --verify`), or is refused for a reason a user can act on
//!    (a rolled-back manifest: then `repair` must restore a map that verifies; a flipped byte: the
//!    corrupted file is named by `inspect`, `regularize` and `export`, which change nothing);
//! 2. no committed block is lost (the block count never falls);
//! 3. no process panics, and of two writers at once one is refused naming the lock, or both finish.
//!
//! At the end the drive is fused to completion and regularized with parameters no step used; the
//! raw and regularized meshes must equal, byte for byte, those of an uninterrupted run (a repaired
//! rollback included: `repair` restores the last commit and its fusion cursor) — unless a repair
//! said it could not restore the cursor, after which `reconstruct` must refuse to resume and the
//! map must still verify.
//!
//! CI runs the seeds in `SEEDS`; `DENSER_RANDOM_OPS_SEEDS=A-B` runs seeds A to B
//! (`docs/bench/faults.md` records a longer run).

use super::faults::{args, fuse, ok, run, verified_blocks};
use super::map::{bin, map_json, text};
use std::path::Path;

/// The seeds CI runs.
const SEEDS: [u64; 5] = [1, 2, 3, 4, 5];
/// Operations per sequence.
const OPERATIONS: usize = 20;

/// xorshift64*: a small deterministic generator (the sequence of a seed never changes).
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// A number in `0..n`.
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n.max(1)
    }
}

/// What the sequence knows of the map between operations.
struct State {
    /// Blocks of the last verified map (never to fall).
    blocks: u64,
    /// A copy of the manifest of an earlier verified state (for a rollback).
    old_manifest: Option<Vec<u8>>,
    /// A repair could not restore the fusion cursor: fusion cannot resume.
    cursor_lost: bool,
}

/// The seeds to run: `DENSER_RANDOM_OPS_SEEDS=A-B` or `A`, else [`SEEDS`].
fn seeds() -> Vec<u64> {
    let Ok(v) = std::env::var("DENSER_RANDOM_OPS_SEEDS") else {
        return SEEDS.to_vec();
    };
    let parse = |s: &str| {
        s.trim()
            .parse::<u64>()
            .expect("DENSER_RANDOM_OPS_SEEDS: A-B or A")
    };
    match v.split_once('-') {
        Some((a, b)) => (parse(a)..=parse(b)).collect(),
        None => vec![parse(&v)],
    }
}

fn regularize_cmd(lambda: &str) -> String {
    format!("regularize a --iterations 6 --lambda {lambda} --sweep-iterations 2 --region-chunks 1")
}

/// Checks the invariants after an operation: the map verifies (a rolled-back manifest is refused
/// and repaired first), and it lost no block.
fn check(d: &Path, st: &mut State, context: &str) {
    if !d.join("a/manifest.dmf").exists() {
        assert_eq!(
            st.blocks, 0,
            "{context}: the manifest of a committed map is gone"
        );
        return;
    }
    let Some(blocks) = verified_blocks("a", d, &["older than the map's last commit"], context)
    else {
        // A rollback: refused with the choice to repair, which restores the latest commit.
        let o = run(&args("repair a"), d, None);
        let out = text(&o);
        assert!(o.status.success(), "{context}: repair failed:\n{out}");
        eprintln!("{context}: repair said:\n{out}");
        // The fusion cursor comes back from the commit mark unless the last commit's files were
        // damaged (then fusion cannot resume, and says so).
        if out.contains("cannot resume") {
            st.cursor_lost = true;
        }
        let blocks = verified_blocks("a", d, &[], context).expect("repaired map verifies");
        assert!(
            blocks >= st.blocks,
            "{context}: repair lost blocks ({} → {blocks})",
            st.blocks
        );
        st.blocks = blocks;
        return;
    };
    assert!(
        blocks >= st.blocks,
        "{context}: blocks fell ({} → {blocks})",
        st.blocks
    );
    st.blocks = blocks;
}

/// Runs one sequence of `seed` in `d` on the drive in `root`; returns the operations' names.
fn sequence(seed: u64, d: &Path, root: &Path, reference: &[(String, Vec<u8>)]) -> Vec<String> {
    let mut rng = Rng::new(seed);
    let mut st = State {
        blocks: 0,
        old_manifest: None,
        cursor_lost: false,
    };
    let recon = format!("{} --map a --out oa", fuse(root));
    let mut done = Vec::new();
    for step in 0..OPERATIONS {
        let exists = d.join("a/manifest.dmf").exists();
        let op = if exists { rng.below(7) } else { 0 };
        let lambda = ["0.2", "0.3"][rng.below(2) as usize];
        let writer = if rng.below(2) == 0 || !exists {
            recon.clone()
        } else {
            regularize_cmd(lambda)
        };
        let name = match op {
            // A writer interrupted at a random map operation (or finishing, when N is past its
            // last), by a crash or by a full disk.
            0..=2 => {
                let fault = if rng.below(3) == 0 { "error" } else { "crash" };
                let n = 1 + rng.below(60);
                let o = run(&args(&writer), d, Some(&format!("{fault}@{n}")));
                let out = text(&o);
                assert!(!out.contains("panicked"), "seed {seed}: panicked:\n{out}");
                format!("{} {fault}@{n}", writer.split(' ').next().unwrap_or(""))
            }
            // A real SIGKILL after a random delay.
            3 => {
                let mut c = bin();
                c.args(args(&writer)).current_dir(d);
                c.env_remove("DENSER_FAULT_INJECTION");
                c.stdout(std::process::Stdio::null());
                c.stderr(std::process::Stdio::null());
                let mut child = c.spawn().expect("spawn");
                let ms = rng.below(400);
                std::thread::sleep(std::time::Duration::from_millis(ms));
                let _ = child.kill();
                child.wait().expect("wait");
                format!("SIGKILL after {ms} ms")
            }
            // An older manifest copied over the current one (a restore from a backup).
            4 => match &st.old_manifest {
                Some(old) if *old != std::fs::read(d.join("a/manifest.dmf")).expect("read") => {
                    std::fs::write(d.join("a/manifest.dmf"), old).expect("roll back");
                    "rollback".to_string()
                }
                _ => "rollback (none older)".to_string(),
            },
            // One byte of a chunk file flipped: named and refused, then put back.
            5 => {
                // A file the manifest names (others are leftovers no command reads).
                let m = std::fs::read(d.join("a/manifest.dmf")).expect("manifest");
                let m = denser::map::manifest::decode_manifest(&m).expect("decode");
                let files: Vec<_> = m
                    .chunks
                    .iter()
                    .map(|(c, e)| {
                        d.join("a/chunks")
                            .join(denser::map::manifest::chunk_file_name(*c, e.file_seq))
                    })
                    .collect();
                let Some(f) = files.get(rng.below(files.len() as u64) as usize).cloned() else {
                    done.push("flip (no chunk yet)".into());
                    continue;
                };
                let good = std::fs::read(&f).expect("read");
                let mut bad = good.clone();
                // Past the 64-byte header: a payload byte.
                let at = 64 + rng.below(good.len().saturating_sub(64) as u64) as usize;
                bad[at] ^= 0x5a;
                std::fs::write(&f, &bad).expect("corrupt");
                let name = f.file_name().expect("name").to_string_lossy().to_string();
                for cmd in [
                    "inspect a --verify",
                    &regularize_cmd("0.25"),
                    "export a --raw --mesh x.ply",
                ] {
                    let o = run(&args(cmd), d, None);
                    let out = text(&o);
                    assert!(
                        !o.status.success() && out.contains(&name) && !out.contains("panicked"),
                        "seed {seed}: `{cmd}` on a flipped byte of {name}:\n{out}"
                    );
                }
                std::fs::write(&f, &good).expect("put back");
                format!("flip byte {at} of {name}")
            }
            // A second writer while one runs: refused naming the lock, or both finish.
            _ => {
                let mut c = bin();
                c.args(args(&regularize_cmd(lambda))).current_dir(d);
                c.env_remove("DENSER_FAULT_INJECTION");
                let first = c.output_async();
                std::thread::sleep(std::time::Duration::from_millis(rng.below(100)));
                let second = run(&args(&regularize_cmd("0.2")), d, None);
                let first = first.join().expect("first writer");
                for o in [&first, &second] {
                    let out = text(o);
                    assert!(
                        o.status.success() || out.contains("lock"),
                        "seed {seed}: a writer failed for another reason than the lock:\n{out}"
                    );
                }
                "two writers".to_string()
            }
        };
        let context = format!("seed {seed} step {step} ({name}) after {done:?}");
        check(d, &mut st, &context);
        // The fusion cursor and blocks after it, for the record of a failing sequence.
        let name = if d.join("a/manifest.dmf").exists() {
            let j = map_json("a", d);
            format!(
                "{name} → frames {}, blocks {}",
                j["frames_committed"], j["summary"]["blocks"]
            )
        } else {
            name
        };
        // A backup of the manifest: the first one, sometimes a newer one.
        if (st.old_manifest.is_none() || rng.below(4) == 0) && d.join("a/manifest.dmf").exists() {
            st.old_manifest = Some(std::fs::read(d.join("a/manifest.dmf")).expect("read"));
        }
        done.push(name);
    }
    // Finish: fuse the drive to its end, then a pass with parameters no step used.
    let context = format!("seed {seed} finishing after {done:?}");
    let o = run(&args(&recon), d, None);
    if st.cursor_lost {
        let out = text(&o);
        assert!(
            o.status.success() || out.contains("cannot resume"),
            "{context}: {out}"
        );
        check(d, &mut st, &context);
        done.push("final meshes not compared: the fusion cursor was lost".into());
        return done;
    }
    assert!(o.status.success(), "{context}: {}", text(&o));
    ok(&args(&regularize_cmd("0.45")), d);
    for (mesh, want) in reference {
        let field = if mesh == "raw.ply" {
            "--raw"
        } else {
            "--regularized"
        };
        ok(&args(&format!("export a {field} --mesh {mesh}")), d);
        let got = std::fs::read(d.join(mesh)).expect("mesh");
        assert!(
            got == *want,
            "{context}: {mesh} differs from the uninterrupted run's"
        );
    }
    done.push("final meshes equal the uninterrupted run's".into());
    done
}

/// Output of a spawned process, collected on another thread.
trait OutputAsync {
    fn output_async(self) -> std::thread::JoinHandle<std::process::Output>;
}

impl OutputAsync for std::process::Command {
    fn output_async(mut self) -> std::thread::JoinHandle<std::process::Output> {
        std::thread::spawn(move || self.output().expect("run denser"))
    }
}

#[test]
fn random_sequences_of_kills_rollbacks_corruption_and_writers_lose_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    // DENSER_RANDOM_OPS_KEEP=1 keeps the folders of a failing sequence for a look.
    let kept;
    let root = if std::env::var_os("DENSER_RANDOM_OPS_KEEP").is_some() {
        kept = dir.keep();
        eprintln!("random operations: kept in {}", kept.display());
        kept.as_path()
    } else {
        dir.path()
    };
    ok(
        &args("synth --out drive --length-m 14 --frame-spacing-m 4 --lidar-only"),
        root,
    );
    // The uninterrupted run.
    let refd = root.join("reference");
    std::fs::create_dir_all(&refd).expect("mkdir");
    ok(&args(&format!("{} --map a --out oa", fuse(root))), &refd);
    ok(&args(&regularize_cmd("0.45")), &refd);
    let mut reference = Vec::new();
    for (mesh, field) in [("raw.ply", "--raw"), ("u.ply", "--regularized")] {
        ok(&args(&format!("export a {field} --mesh {mesh}")), &refd);
        reference.push((
            mesh.to_string(),
            std::fs::read(refd.join(mesh)).expect("mesh"),
        ));
    }
    for seed in seeds() {
        let d = root.join(format!("seed_{seed}"));
        std::fs::create_dir_all(&d).expect("mkdir");
        let done = sequence(seed, &d, root, &reference);
        eprintln!("random operations: seed {seed}: {done:?}");
        std::fs::remove_dir_all(&d).expect("clean");
    }
}
