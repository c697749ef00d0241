//! `denser bench`: fusion, regularization and marching-cubes throughput on real RGB-D frames (or
//! any depth sequence `--rgbd` names, e.g. a synthetic drive's ground-truth depth), at 10 cm and
//! 5 cm voxels with μ = 8 voxels (Open3D's default, so `tools/bench_open3d.py` runs the same
//! settings). Frames are loaded once; each pass re-fuses all of them.

use super::Outcome;
use anyhow::{Context, Result};
use denser::backend::Backend;
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
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    let dir = a.rgbd.unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/rgbd_5frames_slambook2")
    });
    let table = bench_rgbd(&dir, a.passes, a.max_depth_m)
        .with_context(|| format!("benchmarking on {}", dir.display()))?;
    Ok(Box::new(table))
}

/// The Markdown table of the benchmark (one row per voxel size).
fn bench_rgbd(dir: &Path, passes: usize, max_depth_m: f32) -> denser::Result<String> {
    let seq = open_sequence(dir, RangeSource::GroundTruthDepth, None, None)?;
    let frames: Vec<_> = (0..seq.len())
        .map(|i| match seq.read(i)? {
            RangeInput::Depth(f) => Ok(f),
            RangeInput::Lidar(_) => Err(denser::Error::bad_input(dir, "expected depth frames")),
        })
        .collect::<denser::Result<_>>()?;
    let mut out = String::from(
        "| voxel | μ | median ms/frame | M voxel updates/s | blocks | bytes/voxel | TV M voxel-it/s | MC ms |\n|---|---|---|---|---|---|---|---|\n",
    );
    for voxel in [0.10f32, 0.05] {
        let mut config = ReconstructionConfig::paper(voxel);
        config.grid.truncation_m = 8.0 * voxel;
        config.depth_fusion.max_depth_m = max_depth_m;
        config.tv.iterations = 20;
        let mut rec = Reconstructor::in_memory(config, Backend::cpu())?;
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
        let t = std::time::Instant::now();
        rec.mesh(Field::Regularized)?;
        let mc_ms = 1e3 * t.elapsed().as_secs_f64();
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
    }
    Ok(out)
}
