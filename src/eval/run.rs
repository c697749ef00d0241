//! Evaluation runs: score labelled meshes against ground truth and write the paper's report
//! (`report.json`, `report.md`, the error histogram and a top view per surface), for any mesh
//! files (`denser evaluate`) or for a reconstruction's surfaces, whatever store it ran over.

use super::{
    evaluate_mesh_detailed, plot_error_histograms_png, plot_top_view_png, EvalOptions,
    EvaluationReport, GroundTruth, GroundTruthIndex, UpAxis,
};
use crate::frame::PointCloud;
use crate::mesh::{Field, Mesh};
use crate::reconstruct::{Reconstructor, RegularizeOutcome};
use crate::store::SurfaceOutput;
use crate::{Error, Result};
use std::path::{Path, PathBuf};

/// Peak resident memory of this process (Linux `VmHWM`), bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Scores labelled meshes against `ground_truth` and writes `report.json`, `report.md`,
/// `error_histogram.png` and `top_view_<label>.png` into `out_dir`. The first mesh is the
/// baseline of the relative changes. `voxels` gives (voxel count, bytes per voxel) for surfaces
/// made from a map.
pub fn evaluate_meshes(
    meshes: &[(&str, &Mesh)],
    ground_truth: &PointCloud,
    report: &mut EvaluationReport,
    voxels: Option<(u64, f64)>,
    out_dir: &Path,
) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    let t = std::time::Instant::now();
    let index = GroundTruthIndex::new(ground_truth)?;
    let options = EvalOptions::default();
    let mut written = Vec::new();
    let mut evaluations = Vec::new();
    for (label, mesh) in meshes {
        let mut e = evaluate_mesh_detailed(label, mesh, &index, &options)?;
        if let Some((count, bpv)) = voxels {
            e.report = e.report.with_voxels(count, bpv);
        }
        let top = out_dir.join(format!("top_view_{label}.png"));
        plot_top_view_png(&top, &e.points_m, &e.accuracy_m, UpAxis::NegY, 0.5, 1600)?;
        written.push(top);
        evaluations.push(e);
    }
    let series: Vec<(&str, &super::ErrorStats)> = evaluations
        .iter()
        .map(|e| (e.report.label.as_str(), &e.report.accuracy))
        .collect();
    let hist = out_dir.join("error_histogram.png");
    plot_error_histograms_png(&hist, &series, 0.5)?;
    written.push(hist);
    report
        .surfaces
        .extend(evaluations.into_iter().map(|e| e.report));
    report
        .timings_s
        .push(("evaluation".into(), t.elapsed().as_secs_f64()));
    if let Some(rss) = peak_rss_bytes() {
        report
            .memory_bytes
            .push(("peak resident (process)".into(), rss));
    }
    let json = out_dir.join("report.json");
    report.write_json(&json)?;
    let md = out_dir.join("report.md");
    report.write_markdown(&md)?;
    written.extend([json, md]);
    Ok(written)
}

/// Scores a reconstruction's surfaces (the raw one first: the baseline of the relative changes)
/// against `ground_truth` and writes the report into `out_dir`, with the run's timings, memory,
/// parameters and map size (`earlier_timings_s`: stages before the reconstruction, e.g.
/// synthesising the drive). Surfaces a paged map streamed to files are read back.
pub fn evaluate_reconstruction(
    rec: &Reconstructor,
    surfaces: &[SurfaceOutput],
    regularize: Option<&RegularizeOutcome>,
    ground_truth: &GroundTruth,
    source: &str,
    earlier_timings_s: &[(String, f64)],
    out_dir: &Path,
) -> Result<(EvaluationReport, Vec<PathBuf>)> {
    let t = std::time::Instant::now();
    let gt = ground_truth.load()?;
    let load_s = t.elapsed().as_secs_f64();
    let mut report = EvaluationReport::new(
        format!("{source}; ground truth: {}", ground_truth.describe()),
        gt.len() as u64,
    );
    let timings = rec.timings();
    report.timings_s.extend(earlier_timings_s.iter().cloned());
    report.timings_s.extend([
        (
            "input (reading, stereo matching)".to_string(),
            timings.input_s,
        ),
        ("fusion".to_string(), timings.fusion_s),
        ("paging".to_string(), timings.paging_s),
        ("regularisation".to_string(), timings.regularize_s),
        ("marching cubes (both fields)".to_string(), timings.mesh_s),
        ("loading ground truth".to_string(), load_s),
    ]);
    let summary = rec.summary();
    if summary.ram_bytes > 0 {
        report
            .memory_bytes
            .push(("voxel map (RAM)".into(), summary.ram_bytes));
    }
    if summary.disk_bytes > 0 {
        report
            .memory_bytes
            .push(("voxel map (disk)".into(), summary.disk_bytes));
    }
    let config = rec.config();
    let energy = regularize.and_then(|r| r.summary.energy);
    report.parameters = serde_json::json!({
        "voxel_size_m": config.grid.voxel_size_m,
        "truncation_m": config.grid.truncation_m,
        "tv": config.tv,
        "device": rec.backend().device_name(),
        "frames_fused": timings.frames_fused,
        "fusion_ms_per_frame": timings.fusion_ms_per_frame(),
        "voxel_updates_per_s": timings.voxel_updates_per_s(),
        "regularizer_voxel_iterations_per_s": timings.voxel_iterations_per_s(),
        "allocated_blocks": summary.blocks,
        "omega_voxels": summary.observed_voxels,
        "energy_before": energy.map(|e| e.0),
        "energy_after": energy.map(|e| e.1),
    });
    // The map's size: allocated voxels and bytes per allocated voxel (RAM, or disk when paged).
    let bytes_per_voxel = if summary.disk_bytes > 0 {
        summary.disk_bytes as f64 / summary.voxels().max(1) as f64
    } else {
        summary.ram_bytes_per_voxel
    };
    let loaded: Vec<(String, std::borrow::Cow<'_, Mesh>)> = surfaces
        .iter()
        .map(|s| {
            let label = match s.field {
                Field::Raw => "raw",
                Field::Regularized => "regularized",
            };
            let mesh = match &s.mesh {
                Some(m) => std::borrow::Cow::Borrowed(m),
                None => std::borrow::Cow::Owned(crate::io::ply::read_mesh_ply(&s.mesh_path)?),
            };
            Ok((label.to_string(), mesh))
        })
        .collect::<Result<_>>()?;
    let refs: Vec<(&str, &Mesh)> = loaded
        .iter()
        .map(|(l, m)| (l.as_str(), m.as_ref()))
        .collect();
    let written = evaluate_meshes(
        &refs,
        &gt,
        &mut report,
        Some((summary.voxels(), bytes_per_voxel)),
        out_dir,
    )?;
    Ok((report, written))
}
