//! `denser synth`: a synthetic city drive with exact ground truth, in the KITTI odometry layout.

use super::Outcome;
use anyhow::{Context, Result};
use std::fmt;
use std::path::PathBuf;

#[derive(clap::Args)]
pub(crate) struct Args {
    #[arg(long, help = super::help::OUT)]
    out: PathBuf,
    /// Length of the drive, metres.
    #[arg(long, default_value_t = 300.0)]
    length_m: f64,
    /// Drive along a KITTI trajectory (3×4 world_from_cam0 per line) at its real scale.
    #[arg(long)]
    trajectory: Option<PathBuf>,
    #[arg(long, default_value_t = 1, help = super::help::SEED)]
    seed: u64,
    /// Distance between frames, metres.
    #[arg(long, default_value_t = 0.9)]
    frame_spacing_m: f64,
    /// Keep at most this many frames.
    #[arg(long)]
    max_frames: Option<usize>,
    /// Also write dense samples of the exact scene surfaces (`ground_truth/surface.ply`) for
    /// evaluation at voxel level; without it the LiDAR scans are the ground truth, as in the paper.
    #[arg(long)]
    voxel_gt: bool,
    /// Spacing of the exact surface samples, metres (with `--voxel-gt`).
    #[arg(long, default_value_t = 0.05)]
    gt_spacing_m: f64,
    /// Do not write LiDAR scans.
    #[arg(long)]
    no_lidar: bool,
    /// Write poses, calibration and LiDAR scans only (no stereo images or depth): fast long
    /// drives for LiDAR reconstruction.
    #[arg(long, conflicts_with = "no_lidar")]
    lidar_only: bool,
}

struct Synthesised(denser::synth::DriveSummary);

impl fmt::Display for Synthesised {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = &self.0;
        writeln!(
            f,
            "wrote {} frames over {:.0} m ({} primitives, {} LiDAR points, {} ground-truth surface points) to {} in {:.1} s",
            s.frames,
            s.route_length_m,
            s.primitives,
            s.lidar_points,
            s.surface_points,
            s.sequence_dir.display(),
            s.build_s + s.frames_s + s.surface_s
        )
    }
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    denser::io::atomic::check_output_dir(&a.out)
        .with_context(|| format!("checking the output folder {}", a.out.display()))?;
    let mut config = denser::synth::DriveConfig::default();
    config.city.seed = a.seed;
    config.city.length_m = a.length_m;
    config.city.frame_spacing_m = a.frame_spacing_m;
    config.city.max_frames = a.max_frames;
    if let Some(path) = &a.trajectory {
        config.city.trajectory = Some(denser::io::kitti::read_poses(path)?);
    }
    if a.no_lidar {
        config.lidar = None;
    }
    config.images = !a.lidar_only;
    if a.voxel_gt {
        if let Some(s) = config.surface.as_mut() {
            s.spacing_m = a.gt_spacing_m;
        }
    } else {
        config.surface = None;
    }
    let summary = denser::synth::write_drive(&config, &a.out, true)
        .with_context(|| format!("writing the drive to {}", a.out.display()))?;
    Ok(Box::new(Synthesised(summary)))
}
