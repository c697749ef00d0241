//! The library in one program: a short synthetic LiDAR drive written in the KITTI odometry
//! layout, read back as a sequence, fused into a map in RAM, regularized, meshed, written as PLY
//! and scored against scans that were not fused — what `denser reconstruct --depth lidar
//! --holdout 2` does, through the API.
//!
//! ```sh
//! cargo run --release --example library -- /tmp/denser-library
//! ```

use denser::backend::Backend;
use denser::eval::{evaluate_meshes, EvaluationReport, GroundTruth};
use denser::io::sequence::{open_sequence, FrameRange, RangeSource};
use denser::mesh::Field;
use denser::reconstruct::{ReconstructionConfig, Reconstructor};
use denser::synth::{write_drive, DriveConfig};
use std::path::PathBuf;

fn main() -> denser::Result<()> {
    let out = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("denser-library"));

    // 1. Input: 30 m of a synthetic street, LiDAR only, in the KITTI layout.
    let mut drive = DriveConfig {
        images: false,
        surface: None,
        ..Default::default()
    };
    drive.city.length_m = 30.0;
    let written = write_drive(&drive, &out.join("drive"), false)?;
    let seq = open_sequence(&written.sequence_dir, RangeSource::Lidar, None, None)?;

    // 2. Fuse the even frames into a map in RAM (10 cm voxels, the paper's μ and λ), on the
    //    device `--device auto` would choose.
    let backend = Backend::open(
        denser::gpu::DeviceChoice::Auto,
        denser::gpu::ResidentOptions::default(),
    )?;
    let mut rec = Reconstructor::in_memory(ReconstructionConfig::paper(0.1), backend)?;
    let fused: Vec<usize> = (0..seq.len()).step_by(2).collect();
    rec.fuse_sequence(seq.as_ref(), &fused)?;

    // 3. Regularize and mesh both fields.
    let outcome = rec.regularize()?;
    let raw = rec.mesh(Field::Raw)?;
    let regularized = rec.mesh(Field::Regularized)?;
    std::fs::create_dir_all(&out).map_err(|e| denser::Error::io(&out, e))?;
    denser::io::ply::write_mesh_ply(out.join("mesh_regularized.ply"), &regularized)?;

    // 4. Score both against the odd frames' scans, which fusion never saw.
    let held_out = GroundTruth::KittiLidar {
        sequence: written.sequence_dir.clone(),
        poses: None,
        frames: FrameRange {
            first: 1,
            last: None,
            step: 2,
        },
    };
    let (points, coverage) = held_out.load_with_coverage()?;
    let mut report = EvaluationReport::new("library example", points.len() as u64);
    evaluate_meshes(
        &[("raw", &raw), ("regularized", &regularized)],
        points,
        coverage.as_ref(),
        &[],
        &mut report,
        None,
        &out.join("evaluation"),
    )?;
    println!(
        "{} frames fused of {}; {} Ω voxels regularized on {}",
        fused.len(),
        seq.len(),
        outcome.summary.omega_voxels,
        rec.backend().device_name()
    );
    for s in &report.surfaces {
        println!(
            "{:<12} accuracy median {:.3} m, p75 {:.3} m against held-out scans; area {:.0} m²",
            s.label, s.accuracy.median_m, s.accuracy.p75_m, s.surface_area_m2
        );
    }
    println!("wrote {}", out.display());
    Ok(())
}
