//! `denser evaluate`: the paper's evaluation of any meshes against ground truth.

use super::{help, EvaluationTable, Outcome, RangeArgs, Written};
use anyhow::{Context, Result};
use denser::eval::tiled::{evaluate_surface_files, surface_area_m2, SurfaceFile, TiledEvaluation};
use denser::eval::{evaluate_meshes, EvaluationReport, GroundTruth};
use std::fmt;
use std::path::PathBuf;

#[derive(clap::Args)]
pub(crate) struct Args {
    #[arg(long = "mesh", required = true, help = super::help::MESH)]
    meshes: Vec<String>,
    #[arg(long, help = help::GT)]
    gt: PathBuf,
    #[arg(long, help = help::POSES)]
    poses: Option<PathBuf>,
    /// The KITTI scans used (with a sequence folder as ground truth).
    #[command(flatten)]
    range: RangeArgs,
    #[arg(long, default_value = "out", help = help::OUT)]
    out: PathBuf,
    // Without it, the ground truth and the meshes are held in RAM; with it, they are scored
    // tile by tile from scratch files within this budget (binary PLY meshes).
    #[arg(long, value_parser = super::parse_bytes, help = help::MEMORY_BUDGET, help_heading = "Out of core")]
    memory_budget: Option<u64>,
}

struct Evaluated {
    report: EvaluationReport,
    written: Vec<PathBuf>,
}

impl fmt::Display for Evaluated {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}{}",
            EvaluationTable(&self.report),
            Written(&self.written)
        )
    }
}

/// `LABEL=PATH` or `PATH` (labelled by its stem).
fn label_and_path(spec: &str) -> (String, PathBuf) {
    match spec.split_once('=') {
        Some((l, p)) => (l.to_string(), PathBuf::from(p)),
        None => {
            let p = PathBuf::from(spec);
            let stem = p
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or("mesh")
                .to_string();
            (stem, p)
        }
    }
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    denser::io::atomic::check_output_dir(&a.out)?;
    let gt = GroundTruth::from_path(a.gt.clone(), a.poses.clone(), a.range.range());
    let source = format!(
        "meshes scored by `denser evaluate`; ground truth: {}",
        gt.describe()
    );
    if let Some(budget) = a.memory_budget {
        let mut files = Vec::new();
        for spec in &a.meshes {
            let (label, mesh_path) = label_and_path(spec);
            let area_m2 = surface_area_m2(&mesh_path)
                .with_context(|| format!("reading mesh {}", mesh_path.display()))?;
            files.push(SurfaceFile {
                label,
                mesh_path,
                area_m2,
            });
        }
        let how = TiledEvaluation {
            ground_truth: &gt,
            trajectory_m: &[],
            voxels: None,
            memory_budget_bytes: budget,
            out_dir: &a.out,
        };
        let (report, written) = evaluate_surface_files(&files, &how, |points, _| {
            EvaluationReport::new(source.clone(), points)
        })
        .context("evaluating")?;
        return Ok(Box::new(Evaluated { report, written }));
    }
    let (cloud, coverage) = gt
        .load_with_coverage()
        .with_context(|| format!("loading ground truth {}", a.gt.display()))?;
    let mut meshes = Vec::new();
    for spec in &a.meshes {
        let (label, path) = label_and_path(spec);
        let mesh = denser::io::ply::read_mesh_ply(&path)
            .with_context(|| format!("reading mesh {}", path.display()))?;
        meshes.push((label, mesh));
    }
    let refs: Vec<(&str, &denser::mesh::Mesh)> =
        meshes.iter().map(|(l, m)| (l.as_str(), m)).collect();
    let mut report = EvaluationReport::new(source, cloud.len() as u64);
    let trajectory = coverage
        .as_ref()
        .map(|c| c.trajectory_m())
        .unwrap_or_default();
    let written = evaluate_meshes(
        &refs,
        cloud,
        coverage.as_ref(),
        &trajectory,
        &mut report,
        None,
        &a.out,
    )
    .context("evaluating")?;
    Ok(Box::new(Evaluated { report, written }))
}
