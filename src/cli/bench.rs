//! `denser bench`: fusion, regularization and marching-cubes throughput on real RGB-D frames (or
//! any depth sequence `--rgbd` names, e.g. a synthetic drive's ground-truth depth), at 10 cm and
//! 5 cm voxels with μ = 8 voxels (Open3D's default, so `tools/bench_open3d.py` runs the same
//! settings); marching cubes as the median of three meshes after a first one. Frames are loaded
//! once; each pass re-fuses all of them. With `--device gpu`, every stage with a kernel runs on
//! the GPU, and where the adapter has timestamp queries one more pass, TV solve and mesh are
//! timed kernel by kernel on the device (after the measured ones: timing adds a wait per
//! submit).

use super::Outcome;
use anyhow::{Context, Result};
use denser::io::sequence::{open_sequence, RangeInput, RangeSource};
use denser::mesh::Field;
use denser::reconstruct::{ReconstructionConfig, Reconstructor};
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub(crate) struct Args {
    /// Numbered RGB-D folder (default: ../shared/data/rgbd_5frames_slambook2), or any depth
    /// sequence (a `denser synth` drive's `sequences/00` fuses its ground-truth depth).
    #[arg(long)]
    rgbd: Option<PathBuf>,
    /// Passes over the frames per voxel size.
    #[arg(long, default_value_t = 10)]
    passes: usize,
    #[arg(long, default_value_t = 10.0, help = super::help::MAX_DEPTH_M)]
    max_depth_m: f32,
    #[arg(long, value_enum, default_value = "cpu", help = super::help::DEVICE, help_heading = "Device")]
    device: super::DeviceArg,
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    let dir = a.rgbd.unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/rgbd_5frames_slambook2")
    });
    let device = super::DeviceArgs { device: a.device };
    let table = bench_rgbd(&dir, a.passes, a.max_depth_m, device)
        .with_context(|| format!("benchmarking on {}", dir.display()))?;
    Ok(Box::new(table))
}

/// The Markdown table of the benchmark (one row per voxel size).
fn bench_rgbd(
    dir: &Path,
    passes: usize,
    max_depth_m: f32,
    device: super::DeviceArgs,
) -> denser::Result<String> {
    let seq = open_sequence(dir, RangeSource::GroundTruthDepth, None, None)?;
    let frames: Vec<_> = (0..seq.len())
        .map(|i| match seq.read(i)? {
            RangeInput::Depth(f) => Ok(f),
            RangeInput::DeviceDepth(f) => f.read_back(f.context()),
            RangeInput::Lidar(_) => Err(denser::Error::bad_input(dir, "expected depth frames")),
        })
        .collect::<denser::Result<_>>()?;
    let mut out = String::from(
        "| voxel | μ | median ms/frame | M voxel updates/s | blocks | bytes/voxel | TV M voxel-it/s | MC ms (median of 3) |\n|---|---|---|---|---|---|---|---|\n",
    );
    let mut kernels = String::new();
    for voxel in [0.10f32, 0.05] {
        let mut config = ReconstructionConfig::paper(voxel);
        config.grid.truncation_m = 8.0 * voxel;
        config.depth_fusion.max_depth_m = max_depth_m;
        config.tv.iterations = 20;
        let mut rec = Reconstructor::in_memory(config, device.backend()?)?;
        let mut times = Vec::new();
        let before = *rec.timings();
        for _ in 0..passes.max(1) {
            for f in &frames {
                let t = std::time::Instant::now();
                rec.fuse_depth(f)?;
                times.push(t.elapsed().as_secs_f64());
            }
        }
        let fused = *rec.timings();
        let updates = fused.voxel_updates - before.voxel_updates;
        let total: f64 = times.iter().sum();
        times.sort_by(f64::total_cmp);
        let median_ms = 1e3 * times[times.len() / 2];
        let summary = rec.summary();
        rec.regularize()?;
        // One mesh to warm up (kernels, allocator, sync), then the median of three.
        rec.mesh(Field::Regularized)?;
        let mut mc = Vec::new();
        for _ in 0..3 {
            let t = std::time::Instant::now();
            rec.mesh(Field::Regularized)?;
            mc.push(1e3 * t.elapsed().as_secs_f64());
        }
        mc.sort_by(f64::total_cmp);
        let mc_ms = mc[1];
        out.push_str(&format!(
            "| {:.0} cm | {:.2} m | {:.2} | {:.1} | {} | {:.2} | {:.1} | {:.1} |\n",
            voxel * 100.0,
            config.grid.truncation_m,
            median_ms,
            updates as f64 / total / 1e6,
            summary.blocks,
            summary.ram_bytes_per_voxel,
            rec.timings().voxel_iterations_per_s() / 1e6,
            mc_ms
        ));
        if let Some(table) = kernel_times(&mut rec, &frames, voxel)? {
            kernels.push_str(&table);
        }
    }
    Ok(out + &kernels)
}

/// The kernels timed on `ctx` since timing started, as a Markdown table (by kernel name), with
/// the adapter and the passes not timed; stops the timing.
pub(crate) fn kernel_table(ctx: &denser::gpu::GpuContext) -> String {
    let (times, untimed) = ctx.kernel_times();
    ctx.stop_kernel_timing();
    let mut out = format!(
        "Device time per kernel on {} (timestamp queries; {untimed} passes not timed):\n\n\
         | kernel | passes | median µs | total ms |\n|---|---|---|---|\n",
        ctx.name()
    );
    for t in &times {
        out.push_str(&format!(
            "| {} | {} | {:.1} | {:.2} |\n",
            t.kernel, t.passes, t.median_us, t.total_ms
        ));
    }
    out
}

/// On a GPU backend whose adapter has timestamp queries: one more fusion pass over `frames`, a
/// TV solve and a mesh of each field timed kernel by kernel, as a Markdown table with the
/// traffic of a depth frame; `None` otherwise.
fn kernel_times(
    rec: &mut Reconstructor,
    frames: &[denser::frame::DepthFrame],
    voxel: f32,
) -> denser::Result<Option<String>> {
    let Some(ctx) = rec.backend().gpu_context().cloned() else {
        return Ok(None);
    };
    if !ctx.start_kernel_timing() {
        return Ok(Some(format!(
            "\n{}: no timestamp queries on this adapter, kernels not timed\n",
            ctx.name()
        )));
    }
    let before = rec.gpu_traffic().unwrap_or_default();
    for f in frames {
        rec.fuse_depth(f)?;
    }
    let after = rec.gpu_traffic().unwrap_or_default();
    rec.regularize()?;
    rec.mesh(Field::Raw)?;
    rec.mesh(Field::Regularized)?;
    let table = kernel_table(&ctx);
    let frames_timed = after.depth_frames - before.depth_frames;
    let mut out = format!(
        "\nKernel device times at {:.0} cm (one pass over the {} frames, one TV solve, a mesh \
         of each field):\n\n{table}",
        voxel * 100.0,
        frames.len()
    );
    let per_frame = after.depth.since(before.depth);
    out.push_str(&format!(
        "\nGPU traffic per depth frame: {}\n",
        per_frame.describe_per(frames_timed)
    ));
    Ok(Some(out))
}
