//! Evaluation runs: score labelled meshes against ground truth and write the paper's report
//! (`report.json`, `report.md`, the error histogram and a top view per surface), for any mesh
//! files (`denser evaluate`) or for a reconstruction's surfaces, whatever store it ran over.

use super::render::{render_mesh_png, MeshColour, MeshView};
use super::{
    evaluate_mesh_detailed, plot_error_histograms_png, plot_top_view_png, EvalOptions,
    EvaluationReport, GroundTruth, GroundTruthIndex, SensorCoverage, SurfaceReport, UpAxis,
};
use crate::frame::PointCloud;
use crate::grid::GridParams;
use crate::memory::peak_rss_bytes;
use crate::mesh::{Field, Mesh};
use crate::reconstruct::{Reconstructor, RegularizeOutcome, StageTimings};
use crate::regularize::TvParams;
use crate::store::{StoreSummary, SurfaceOutput};
use crate::{Error, Result};
use std::path::{Path, PathBuf};

/// The axis-aligned bounds of `points`, `None` when empty.
fn bounds<'a>(points: impl Iterator<Item = [f64; 3]> + 'a) -> Option<([f64; 3], [f64; 3])> {
    points.fold(None, |acc, p| {
        let (mut lo, mut hi) = acc.unwrap_or((p, p));
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
        Some((lo, hi))
    })
}

/// Fails when a non-empty surface lies entirely away from the ground truth (their bounding boxes,
/// the surface's grown by 1 m, do not meet): scoring it would report the distance between two
/// unrelated places (a wrong file, a wrong frame) as an error statistic.
fn check_overlap(meshes: &[(&str, &Mesh)], ground_truth: &PointCloud) -> Result<()> {
    let Some((glo, ghi)) = bounds(ground_truth.points_m.iter().copied()) else {
        return Err(Error::InvalidArgument(
            "the ground truth holds no point".into(),
        ));
    };
    for (label, mesh) in meshes {
        let pts = mesh
            .positions_m
            .iter()
            .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64]);
        let Some((lo, hi)) = bounds(pts) else {
            continue;
        };
        let meets = (0..3).all(|a| lo[a] - 1.0 <= ghi[a] && hi[a] + 1.0 >= glo[a]);
        if !meets {
            return Err(Error::InvalidArgument(format!(
                "the ground truth does not overlap the surface `{label}`: the surface spans {lo:.1?}–{hi:.1?} m, the ground truth {glo:.1?}–{ghi:.1?} m (another place, or another frame?)"
            )));
        }
    }
    Ok(())
}

/// Scores labelled meshes against `ground_truth` and writes `report.json`, `report.md`,
/// `error_histogram.png` and `top_view_<label>.png` into `out_dir`. The first mesh is the
/// baseline of the relative changes. `voxels` gives (voxel count, bytes per voxel) for surfaces
/// made from a map.
///
/// With `coverage` (LiDAR ground truth), accuracy is scored only over the points some scan could
/// have measured ([`SensorCoverage`]) and the unrestricted figure is kept beside it; the top view
/// draws the unscored points grey and `trajectory_m` (the sensor's path) as a line.
pub fn evaluate_meshes(
    meshes: &[(&str, &Mesh)],
    ground_truth: PointCloud,
    coverage: Option<&SensorCoverage>,
    trajectory_m: &[[f64; 3]],
    report: &mut EvaluationReport,
    voxels: Option<(u64, f64)>,
    out_dir: &Path,
) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    check_overlap(meshes, &ground_truth)?;
    let t = std::time::Instant::now();
    let index = GroundTruthIndex::from_cloud(ground_truth)?;
    let options = EvalOptions::default();
    let mut written = Vec::new();
    let mut evaluations = Vec::new();
    let bar = crate::progress::bar(meshes.len() as u64, "evaluating");
    for (label, mesh) in meshes {
        let mut e = evaluate_mesh_detailed(label, mesh, &index, &options)?;
        if let Some((count, bpv)) = voxels {
            e.report = e.report.with_voxels(count, bpv);
        }
        let t_mask = std::time::Instant::now();
        let mask = coverage.map(|c| c.mask(&e.points_m));
        tracing::debug!(
            label,
            seconds = t_mask.elapsed().as_secs_f64(),
            "coverage mask"
        );
        if let Some(mask) = &mask {
            let scored: Vec<f32> = e
                .accuracy_m
                .iter()
                .zip(mask)
                .filter_map(|(d, &m)| m.then_some(*d))
                .collect();
            if scored.is_empty() {
                tracing::warn!(
                    "surface `{label}`: no point lies where the LiDAR could have measured; scoring every point"
                );
            } else {
                let all = std::mem::replace(
                    &mut e.report.accuracy,
                    super::ErrorStats::from_distances(&scored, &options.histogram)?,
                );
                e.report.accuracy_unrestricted = Some(all);
            }
        }
        let name = format!("top_view_{label}.png");
        let top = out_dir.join(&name);
        plot_top_view_png(
            &top,
            label,
            &e.points_m,
            &e.accuracy_m,
            mask.as_deref(),
            trajectory_m,
            UpAxis::NegY,
            0.5,
            1600,
        )?;
        report.pictures.push(name);
        written.push(top);
        // Only the summary is needed from here on: the points and their distances (~100 MiB for
        // a 4 M-vertex surface) are freed before the next surface is scored.
        evaluations.push(e.report);
        bar.inc(1);
    }
    bar.finish_and_clear();
    report.coverage = coverage.map(|c| c.view());
    plot_histogram(report, &evaluations, out_dir, &mut written)?;
    // The last (regularized) surface as it looks, from above and from an oblique viewpoint.
    if let Some((label, mesh)) = meshes.last().filter(|(_, m)| !m.triangles.is_empty()) {
        for (view, name) in [(MeshView::Top, "top"), (MeshView::Oblique, "oblique")] {
            let file = format!("view_{name}_{label}.png");
            let path = out_dir.join(&file);
            let colour = MeshColour::for_mesh(mesh);
            let title = mesh_picture_title(label, name, colour);
            render_mesh_png(&path, mesh, UpAxis::NegY, view, colour, 1600, &title)?;
            report.pictures.push(file);
            written.push(path);
        }
    }
    finish_report(
        report,
        evaluations,
        t.elapsed().as_secs_f64(),
        out_dir,
        &mut written,
    )?;
    Ok(written)
}

/// The error histogram of `evaluations` (accuracy), first of the report's pictures.
pub(crate) fn plot_histogram(
    report: &mut EvaluationReport,
    evaluations: &[SurfaceReport],
    out_dir: &Path,
    written: &mut Vec<PathBuf>,
) -> Result<()> {
    let series: Vec<(&str, &super::ErrorStats)> = evaluations
        .iter()
        .map(|r| (r.label.as_str(), &r.accuracy))
        .collect();
    let hist = out_dir.join("error_histogram.png");
    plot_error_histograms_png(&hist, &series, 0.5)?;
    report.pictures.insert(0, "error_histogram.png".into());
    written.push(hist);
    Ok(())
}

/// Adds the scored surfaces, the sparse-ground-truth note, the evaluation's time and the peak
/// RSS to `report`, and writes `report.json` and `report.md` into `out_dir`.
pub(crate) fn finish_report(
    report: &mut EvaluationReport,
    evaluations: Vec<SurfaceReport>,
    evaluation_s: f64,
    out_dir: &Path,
    written: &mut Vec<PathBuf>,
) -> Result<()> {
    report.surfaces.extend(evaluations);
    if let Some(note) = report.surfaces.last().and_then(sparse_ground_truth_note) {
        tracing::warn!("{note}");
        report.notes.push(note);
    }
    report.timings_s.push(("evaluation".into(), evaluation_s));
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
    Ok(())
}

/// The title of a mesh picture: the surface, the view and, when coloured by height, the key.
pub(crate) fn mesh_picture_title(label: &str, view: &str, colour: MeshColour) -> String {
    match colour {
        MeshColour::Own => format!("{label} mesh, {view} view"),
        MeshColour::Height => format!(
            "{label} mesh, {view} view, coloured by height (blue low, red high; the input had no colour)"
        ),
    }
}

/// What the report of a reconstruction says about the run itself, taken from its
/// [`Reconstructor`] so that the map can be freed before the ground truth is loaded (the
/// evaluation's memory then adds to the surfaces', not to the map's).
#[derive(Clone, Debug)]
pub struct RunFacts {
    /// The run's stage timings.
    pub timings: StageTimings,
    /// The map's totals.
    pub summary: StoreSummary,
    /// Voxel size and truncation.
    pub grid: GridParams,
    /// The regularizer's parameters.
    pub tv: TvParams,
    /// Where the stages ran ("CPU" or the adapter's name).
    pub device: String,
    /// The sensor's path, metres (world frame).
    pub trajectory_m: Vec<[f64; 3]>,
    /// The run's `--memory-budget` when it had one (a paged map): surfaces stored as files are
    /// then scored tile by tile within it ([`crate::eval::tiled`]).
    pub memory_budget_bytes: Option<u64>,
}

impl RunFacts {
    /// The facts of `rec`'s run so far.
    pub fn of(rec: &Reconstructor) -> RunFacts {
        RunFacts {
            timings: *rec.timings(),
            summary: rec.summary(),
            grid: rec.config().grid,
            tv: rec.config().tv,
            device: rec.backend().device_name(),
            trajectory_m: rec.trajectory_m().to_vec(),
            memory_budget_bytes: None,
        }
    }

    /// These facts with the run's memory budget.
    pub fn with_memory_budget(mut self, bytes: Option<u64>) -> RunFacts {
        self.memory_budget_bytes = bytes;
        self
    }
}

/// Scores a reconstruction's surfaces (the raw one first: the baseline of the relative changes)
/// against `ground_truth` and writes the report into `out_dir`, with the run's timings, memory,
/// parameters and map size (`earlier_timings_s`: stages before the reconstruction, e.g.
/// synthesising the drive). Surfaces a paged map streamed to files are scored from the files
/// tile by tile within [`RunFacts::memory_budget_bytes`] when it is set
/// ([`crate::eval::tiled`]), else read back whole.
pub fn evaluate_reconstruction(
    run: &RunFacts,
    surfaces: &[SurfaceOutput],
    regularize: Option<&RegularizeOutcome>,
    ground_truth: &GroundTruth,
    source: &str,
    earlier_timings_s: &[(String, f64)],
    out_dir: &Path,
) -> Result<(EvaluationReport, Vec<PathBuf>)> {
    // Surfaces a paged map streamed to files are scored from the files, within the budget.
    if let Some(budget) = run
        .memory_budget_bytes
        .filter(|_| surfaces.iter().all(|s| s.mesh.is_none()))
    {
        let files: Vec<super::tiled::SurfaceFile> = surfaces
            .iter()
            .map(|s| super::tiled::SurfaceFile {
                label: surface_label(s.field).to_string(),
                mesh_path: s.mesh_path.clone(),
                area_m2: s.area_m2,
            })
            .collect();
        let how = super::tiled::TiledEvaluation {
            ground_truth,
            trajectory_m: &run.trajectory_m,
            voxels: Some(map_voxels(&run.summary)),
            memory_budget_bytes: budget,
            out_dir,
        };
        return super::tiled::evaluate_surface_files(&files, &how, |points, load_s| {
            run_report(
                run,
                regularize,
                ground_truth,
                source,
                earlier_timings_s,
                points,
                load_s,
            )
        });
    }
    let t = std::time::Instant::now();
    let (gt, coverage) = ground_truth.load_with_coverage()?;
    let load_s = t.elapsed().as_secs_f64();
    let report = run_report(
        run,
        regularize,
        ground_truth,
        source,
        earlier_timings_s,
        gt.len() as u64,
        load_s,
    );
    let loaded: Vec<(String, std::borrow::Cow<'_, Mesh>)> = surfaces
        .iter()
        .map(|s| {
            let mesh = match &s.mesh {
                Some(m) => std::borrow::Cow::Borrowed(m),
                None => std::borrow::Cow::Owned(crate::io::ply::read_mesh_ply(&s.mesh_path)?),
            };
            Ok((surface_label(s.field).to_string(), mesh))
        })
        .collect::<Result<_>>()?;
    let refs: Vec<(&str, &Mesh)> = loaded
        .iter()
        .map(|(l, m)| (l.as_str(), m.as_ref()))
        .collect();
    let trajectory = match &coverage {
        Some(c) => c.trajectory_m(),
        None => run.trajectory_m.clone(),
    };
    let mut report = report;
    let written = evaluate_meshes(
        &refs,
        gt,
        coverage.as_ref(),
        &trajectory,
        &mut report,
        Some(map_voxels(&run.summary)),
        out_dir,
    )?;
    Ok((report, written))
}

/// A surface's label in the report.
fn surface_label(field: Field) -> &'static str {
    match field {
        Field::Raw => "raw",
        Field::Regularized => "regularized",
    }
}

/// The map's size: allocated voxels and bytes per allocated voxel (RAM, or disk when paged).
fn map_voxels(summary: &StoreSummary) -> (u64, f64) {
    let bytes_per_voxel = if summary.disk_bytes > 0 {
        summary.disk_bytes as f64 / summary.voxels().max(1) as f64
    } else {
        summary.ram_bytes_per_voxel
    };
    (summary.voxels(), bytes_per_voxel)
}

/// The report of a reconstruction before its surfaces are scored: source, timings, memory and
/// parameters.
fn run_report(
    run: &RunFacts,
    regularize: Option<&RegularizeOutcome>,
    ground_truth: &GroundTruth,
    source: &str,
    earlier_timings_s: &[(String, f64)],
    ground_truth_points: u64,
    load_s: f64,
) -> EvaluationReport {
    let mut report = EvaluationReport::new(
        format!("{source}; ground truth: {}", ground_truth.describe()),
        ground_truth_points,
    );
    let timings = &run.timings;
    report.timings_s.extend(earlier_timings_s.iter().cloned());
    report.timings_s.extend([
        (
            "input (reading, stereo matching)".to_string(),
            timings.input_s,
        ),
        ("fusion".to_string(), timings.fusion_s),
        ("paging".to_string(), timings.paging_s),
        ("regularization".to_string(), timings.regularize_s),
        ("marching cubes (both fields)".to_string(), timings.mesh_s),
        ("loading ground truth".to_string(), load_s),
    ]);
    let summary = run.summary;
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
    let energy = regularize.and_then(|r| r.summary.energy);
    report.parameters = serde_json::json!({
        "voxel_size_m": run.grid.voxel_size_m,
        "truncation_m": run.grid.truncation_m,
        "tv": run.tv,
        "device": run.device,
        "frames_fused": timings.frames_fused,
        "fusion_ms_per_frame": timings.fusion_ms_per_frame(),
        "voxel_updates_per_s": timings.voxel_updates_per_s(),
        "regularizer_voxel_iterations_per_s": timings.voxel_iterations_per_s(),
        "allocated_blocks": summary.blocks,
        "omega_voxels": summary.observed_voxels,
        "energy_before": energy.map(|e| e.0),
        "energy_after": energy.map(|e| e.1),
    });
    report
}

/// A warning when the ground truth looks too sparse to score `surface`: most of the surface lies
/// much farther from any ground-truth point (accuracy) than the ground truth lies from the
/// surface (completeness), as when one LiDAR scan, whose rings are decimetres to metres apart,
/// scores a dense mesh. Thresholds: accuracy median over 5 cm and over 2.5× the completeness
/// median.
pub fn sparse_ground_truth_note(surface: &super::report::SurfaceReport) -> Option<String> {
    let accuracy = surface.accuracy.median_m;
    let completeness = surface.completeness.as_ref()?.median_m;
    (accuracy > 0.05 && accuracy > 2.5 * completeness).then(|| {
        format!(
            "The {} surface lies farther from the ground truth than the ground truth lies from it \
             (accuracy median {:.1} cm, completeness median {:.1} cm): the ground truth may be \
             too sparse to score this surface (one scan's rings are decimetres to metres apart), \
             or parts of the surface were never seen by it; the accuracy figures then measure \
             its spacing as much as the surface's error.",
            surface.label,
            accuracy * 100.0,
            completeness * 100.0
        )
    })
}
