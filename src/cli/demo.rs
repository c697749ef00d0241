//! `denser demo`: a synthetic city drive (KITTI layout, with LiDAR) reconstructed from its
//! stereo pairs (census + TGV-tensor or SGM → depth → fusion → regularization → meshes) and
//! scored against its merged LiDAR scans, as the paper does.

use super::reconstruct::{run_job, Job, Report};
use super::{help, DeviceArgs, EvaluationTable, GpuPoolArgs, Outcome, StereoArg};
use anyhow::{Context, Result};
use denser::eval::GroundTruth;
use denser::io::sequence::{FrameRange, RangeSource};
use denser::reconstruct::ReconstructionConfig;
use std::fmt;
use std::path::PathBuf;

#[derive(clap::Args)]
pub(crate) struct Args {
    #[arg(long, default_value = "out/demo", help = help::OUT)]
    out: PathBuf,
    /// Length of the drive, metres.
    #[arg(long, default_value_t = 200.0)]
    length_m: f64,
    /// Distance between frames, metres.
    #[arg(long, default_value_t = 2.0)]
    frame_spacing_m: f64,
    #[arg(long, default_value_t = 1, help = help::SEED)]
    seed: u64,
    /// Primal–dual iterations.
    #[arg(long, default_value_t = 100)]
    iterations: u32,
    #[command(flatten)]
    device: DeviceArgs,
    #[command(flatten)]
    gpu_pool: GpuPoolArgs,
    #[arg(long, alias = "stereo-method", value_enum, default_value = "tgv-tensor", help = help::METHOD)]
    method: StereoArg,
}

struct DemoOutcome {
    drive: denser::synth::DriveSummary,
    report: Report,
    total_s: f64,
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    let started = std::time::Instant::now();
    // The device first: `--device gpu` without an adapter fails before any work.
    let backend = a.device.backend_with(a.gpu_pool.options())?;
    denser::io::atomic::check_output_dir(&a.out)
        .with_context(|| format!("checking the output folder {}", a.out.display()))?;
    let drive_dir = a.out.join("drive");
    let mut drive = denser::synth::DriveConfig::default();
    drive.city.seed = a.seed;
    drive.city.length_m = a.length_m;
    drive.city.frame_spacing_m = a.frame_spacing_m;
    drive.surface = None;
    tracing::info!(
        "synthesising a {:.0} m drive into {}",
        a.length_m,
        drive_dir.display()
    );
    let summary = denser::synth::write_drive(&drive, &drive_dir, true)
        .with_context(|| format!("writing the drive to {}", drive_dir.display()))?;
    // The README's default: 10 cm voxels with the paper's μ and λ, stereo depth used up to
    // 20 m (at 0.54 m baseline a quarter-pixel disparity error is ±0.26 m there).
    let mut config = ReconstructionConfig::paper(0.1);
    config.depth_fusion.max_depth_m = 20.0;
    config.tv.iterations = a.iterations;
    let job = Job {
        input: summary.sequence_dir.clone(),
        how: Default::default(),
        out_dir: a.out.clone(),
        source: RangeSource::Stereo,
        range: FrameRange::ALL,
        config,
        stereo_method: a.method.into(),
        num_disparities: 128,
        map: None,
        regularize: true,
        ground_truth: Some(GroundTruth::KittiLidar {
            sequence: summary.sequence_dir.clone(),
            poses: None,
            frames: FrameRange::ALL,
        }),
        holdout: None,
        evaluation_notes: Vec::new(),
        earlier_timings_s: vec![(
            "synthesising the drive".into(),
            summary.build_s + summary.frames_s + summary.surface_s,
        )],
    };
    let report = run_job(&job, backend).context("running the demo")?;
    Ok(Box::new(DemoOutcome {
        drive: summary,
        report,
        total_s: started.elapsed().as_secs_f64(),
    }))
}

impl fmt::Display for DemoOutcome {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "demo: {} frames over {:.0} m, reconstructed from stereo in {:.0} s in all",
            self.drive.frames, self.drive.route_length_m, self.total_s
        )?;
        if let Some(e) = &self.report.evaluation {
            write!(f, "{}", EvaluationTable(e))?;
        }
        for p in &self.report.written {
            writeln!(f, "wrote {}", p.display())?;
        }
        writeln!(
            f,
            "synthetic drive (KITTI layout): {}",
            self.drive.sequence_dir.display()
        )
    }
}
