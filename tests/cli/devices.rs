//! One backend, chosen once (issue 11): with `--device gpu`, every stage that has a kernel runs on
//! the GPU in every command — stereo, fusion and regularization in `reconstruct` (in RAM and with
//! `--map`) and in `regularize` — and each summary line names the device it ran on. On lavapipe
//! (Mesa's Vulkan on the CPU, installed by tools/setup.sh) the kernels equal their CPU twins bit
//! for bit, so the meshes equal the CPU run's byte for byte. Skipped, counted, without an adapter.

use std::path::Path;
use std::process::{Command, Output};

fn run(args: &[&str], cwd: &Path) -> Output {
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

fn ok(args: &[&str], cwd: &Path) -> String {
    let o = run(args, cwd);
    assert!(o.status.success(), "denser {args:?} failed:\n{}", text(&o));
    text(&o)
}

/// The adapter's name as the summaries print it, or `None` (counted skip) without one.
fn gpu_name() -> Option<String> {
    match denser::gpu::GpuContext::new() {
        Ok(Some(ctx)) => Some(ctx.name()),
        _ => {
            crate::common::skip("no GPU adapter (tools/setup.sh installs lavapipe)");
            None
        }
    }
}

/// A 16 m synthetic drive in `d/drive`, a frame every 4 m.
fn synth_drive(d: &Path) {
    let args = [
        "synth",
        "--out",
        "drive",
        "--length-m",
        "16",
        "--frame-spacing-m",
        "4",
    ];
    ok(&args, d);
}

/// The settings every run here shares: 20 cm voxels, 10 TV iterations, no evaluation.
const COMMON: [&str; 7] = [
    "--voxel-size",
    "0.2",
    "--iterations",
    "10",
    "--no-eval",
    "--max-depth",
    "20",
];

/// The line of `out` that starts with `prefix`.
fn line<'a>(out: &'a str, prefix: &str) -> &'a str {
    out.lines()
        .find(|l| l.starts_with(prefix))
        .unwrap_or_else(|| panic!("no line starting {prefix:?} in:\n{out}"))
}

#[test]
fn every_stage_of_reconstruct_and_regularize_runs_on_the_gpu() {
    let Some(gpu) = gpu_name() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    synth_drive(d);
    let seq = "drive/sequences/00";
    let common = COMMON;
    // Ground-truth depth through a map directory: fusion and the regional regularization on the
    // GPU (depth fusion and TV equal their CPU twins bit for bit on lavapipe; LiDAR differs from
    // its f64 reference within the tolerance of tests/gpu/lidar.rs).
    let mut args = vec![
        "reconstruct",
        seq,
        "--depth",
        "gt",
        "--map",
        "m_gpu",
        "--out",
        "o_gpu",
    ];
    args.extend(common);
    args.extend([
        "--device",
        "gpu",
        "--memory-budget",
        "64MiB",
        "--chunk-blocks",
        "8",
    ]);
    let out = ok(&args, d);
    assert!(
        line(&out, "fused").contains(&format!(" on {gpu}:")),
        "{out}"
    );
    assert!(
        line(&out, "regularized on").starts_with(&format!("regularized on {gpu}:")),
        "{out}"
    );
    let mut args = vec![
        "reconstruct",
        seq,
        "--depth",
        "gt",
        "--map",
        "m_cpu",
        "--out",
        "o_cpu",
    ];
    args.extend(common);
    args.extend([
        "--device",
        "cpu",
        "--memory-budget",
        "64MiB",
        "--chunk-blocks",
        "8",
    ]);
    let out = ok(&args, d);
    assert!(line(&out, "fused").contains(" on CPU:"), "{out}");
    assert!(
        line(&out, "regularized on").starts_with("regularized on CPU:"),
        "{out}"
    );
    for mesh in ["mesh_raw.ply", "mesh_regularized.ply"] {
        let (g, c) = (
            std::fs::read(d.join("o_gpu").join(mesh)).expect("gpu mesh"),
            std::fs::read(d.join("o_cpu").join(mesh)).expect("cpu mesh"),
        );
        assert!(g == c, "{mesh}: the GPU map differs from the CPU map");
    }
    // LiDAR through a paged map: the scans fuse into the GPU-resident blocks (their walk is
    // the CPU's, equal on lavapipe), so the maps' meshes are the same bytes.
    for (dev, map, out_dir) in [("gpu", "ml_gpu", "ol_gpu"), ("cpu", "ml_cpu", "ol_cpu")] {
        let mut args = vec![
            "reconstruct",
            seq,
            "--depth",
            "lidar",
            "--map",
            map,
            "--out",
            out_dir,
        ];
        args.extend(common);
        args.extend([
            "--device",
            dev,
            "--memory-budget",
            "64MiB",
            "--chunk-blocks",
            "8",
        ]);
        let out = ok(&args, d);
        if dev == "gpu" {
            assert!(out.contains("GPU traffic per LiDAR scan"), "{out}");
        }
    }
    for mesh in ["mesh_raw.ply", "mesh_regularized.ply"] {
        let (g, c) = (
            std::fs::read(d.join("ol_gpu").join(mesh)).expect("gpu mesh"),
            std::fs::read(d.join("ol_cpu").join(mesh)).expect("cpu mesh"),
        );
        assert!(g == c, "{mesh}: the GPU's LiDAR map differs from the CPU's");
    }
    // Offline re-regularization of the stored map on the GPU.
    let out = ok(
        &[
            "regularize",
            "m_gpu",
            "--lambda",
            "0.5",
            "--iterations",
            "6",
            "--device",
            "gpu",
        ],
        d,
    );
    assert!(
        line(&out, "regularized on").starts_with(&format!("regularized on {gpu}:")),
        "{out}"
    );
    // Stereo in RAM: the variational matcher, fusion and regularization on the GPU.
    let mut args = vec![
        "reconstruct",
        seq,
        "--depth",
        "stereo",
        "--out",
        "st_gpu",
        "--last",
        "2",
    ];
    args.extend(common);
    args.extend(["--device", "gpu"]);
    let out = ok(&args, d);
    assert!(
        line(&out, "stereo on").starts_with(&format!("stereo on {gpu}:")),
        "{out}"
    );
    assert!(
        line(&out, "fused").contains(&format!(" on {gpu}:")),
        "{out}"
    );
    assert!(
        line(&out, "regularized on").starts_with(&format!("regularized on {gpu}:")),
        "{out}"
    );
    assert!(
        out.contains("GPU tier:"),
        "depth blocks stayed resident: {out}"
    );
}

#[test]
fn an_in_memory_run_meshes_on_the_gpu_with_the_cpu_meshes_bytes() {
    // `reconstruct` without `--map` writes its meshes from RAM: with `--device gpu` marching
    // cubes runs on the GPU (src/mesh/gpu.rs), and the files equal the CPU run's byte for byte
    // (on lavapipe every stage before it does too; tests/gpu/mesh.rs compares the mesher alone).
    let Some(gpu) = gpu_name() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    synth_drive(d);
    let run_on = |device: &str| {
        let out = format!("o_{device}");
        let mut args = vec![
            "reconstruct",
            "drive/sequences/00",
            "--depth",
            "gt",
            "--out",
            &out,
        ];
        args.extend(COMMON);
        args.extend(["--device", device, "--kernel-times"]);
        ok(&args, d)
    };
    let on_gpu = run_on("gpu");
    let on_cpu = run_on("cpu");
    // The stages' kernels compiled before the first frame; with `--kernel-times` the whole
    // run's kernels timed (where the adapter has timestamp queries), the timing changing no
    // byte of the meshes compared below. On the CPU: neither.
    assert!(
        line(&on_gpu, "GPU kernels compiled:").contains(" in "),
        "{on_gpu}"
    );
    if !on_gpu.contains("no timestamp queries") {
        for kernel in ["fuse_depth_resident", "tv_dual", "mc_emit"] {
            assert!(on_gpu.contains(&format!("| {kernel} |")), "{on_gpu}");
        }
    }
    assert!(
        !on_cpu.contains("GPU kernels compiled") && !on_cpu.contains("Device time per kernel"),
        "{on_cpu}"
    );
    assert!(
        line(&on_gpu, "meshes:").contains(&format!("(marching cubes on {gpu}, ")),
        "{on_gpu}"
    );
    assert!(
        line(&on_gpu, "GPU traffic per mesh (2):").contains("submits"),
        "{on_gpu}"
    );
    assert!(
        line(&on_cpu, "meshes:").contains("(marching cubes on CPU, "),
        "{on_cpu}"
    );
    for mesh in [
        "mesh_raw.ply",
        "mesh_regularized.ply",
        "points_regularized.ply",
    ] {
        let (g, c) = (
            std::fs::read(d.join("o_gpu").join(mesh)).expect("gpu mesh"),
            std::fs::read(d.join("o_cpu").join(mesh)).expect("cpu mesh"),
        );
        assert!(g.len() > 1000, "{mesh}: {} bytes", g.len());
        assert!(g == c, "{mesh}: the GPU mesh differs from the CPU mesh");
    }
}

#[test]
fn bench_on_the_gpu_times_each_kernel_on_the_device() {
    // `denser bench --device gpu`: after the measured passes, one more pass, a TV solve (20
    // iterations) and a mesh of each field, timed kernel by kernel with timestamp queries.
    let Some(gpu) = gpu_name() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    synth_drive(d);
    let frames = std::fs::read_dir(d.join("drive/sequences/00/depth_gt"))
        .expect("depth")
        .count();
    let bench = [
        "bench",
        "--rgbd",
        "drive/sequences/00",
        "--passes",
        "1",
        "--device",
    ];
    let out = ok(&[&bench[..], &["gpu"]].concat(), d);
    if out.contains("no timestamp queries") {
        crate::common::skip("kernel times: the adapter has no timestamp queries");
        return;
    }
    // One table per voxel size (10 and 5 cm), each naming the adapter.
    let tables = out
        .matches(&format!("Device time per kernel on {gpu}"))
        .count();
    assert_eq!(tables, 2, "{out}");
    let passes = |kernel: &str| -> Vec<usize> {
        out.lines()
            .filter(|l| l.starts_with(&format!("| {kernel} |")))
            .map(|l| {
                l.split('|')
                    .nth(2)
                    .expect("passes")
                    .trim()
                    .parse()
                    .expect("n")
            })
            .collect()
    };
    assert_eq!(passes("fuse_depth_resident"), [frames, frames], "{out}");
    assert_eq!(passes("tv_dual"), [20, 20], "{out}");
    assert_eq!(passes("mc_emit"), [2, 2], "{out}");
    assert!(out.contains("GPU traffic per depth frame: "), "{out}");
    // On the CPU: the figures, no kernel table.
    let out = ok(&[&bench[..], &["cpu"]].concat(), d);
    assert!(
        out.contains("| 5 cm |") && !out.contains("Device time per kernel"),
        "{out}"
    );
}
