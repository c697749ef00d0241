//! Scores one reconstructed mesh against an indexed ground truth: accuracy (reconstructed point →
//! nearest ground-truth point), optional completeness (ground-truth point → nearest reconstructed
//! point), surface area and sizes, gathered into a [`SurfaceReport`].

use crate::error::{Error, Result};
use crate::eval::nn::{check_mesh, surface_points, CompletenessRegion, GroundTruthIndex};
use crate::eval::report::SurfaceReport;
use crate::eval::stats::{ErrorStats, HistogramSpec};
use crate::mesh::Mesh;
use serde::{Deserialize, Serialize};

/// How a mesh is scored.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalOptions {
    /// When set, besides every vertex, points sampled on the triangles every ~`spacing` metres
    /// ([`crate::eval::sample_mesh_surface`]) are scored too; `None` scores vertices only (the
    /// paper's reconstructed surface points).
    pub surface_sample_spacing_m: Option<f64>,
    /// Which ground-truth points are scored for completeness; `None` skips completeness.
    pub completeness: Option<CompletenessRegion>,
    /// Histogram layout for both accuracy and completeness.
    pub histogram: HistogramSpec,
}

impl Default for EvalOptions {
    /// Vertices only; completeness over ground truth within 1 m of the reconstruction's bounding
    /// box; 1 cm bins up to 1 m.
    fn default() -> Self {
        EvalOptions {
            surface_sample_spacing_m: None,
            completeness: Some(CompletenessRegion::ReconstructionBounds { margin_m: 1.0 }),
            histogram: HistogramSpec::default(),
        }
    }
}

/// A scored mesh with the per-point distances behind its statistics (for pictures such as
/// [`crate::eval::plot_top_view_png`]).
#[derive(Clone, Debug)]
pub struct MeshEvaluation {
    /// The summary.
    pub report: SurfaceReport,
    /// The scored reconstructed points, world frame, metres (vertices, then surface samples).
    pub points_m: Vec<[f64; 3]>,
    /// Accuracy distance of each of `points_m` to the nearest ground-truth point, metres.
    pub accuracy_m: Vec<f32>,
}

/// Scores `mesh` against `ground_truth` (see [`evaluate_mesh_detailed`]) and keeps the summary.
pub fn evaluate_mesh(
    label: &str,
    mesh: &Mesh,
    ground_truth: &GroundTruthIndex,
    options: &EvalOptions,
) -> Result<SurfaceReport> {
    Ok(evaluate_mesh_detailed(label, mesh, ground_truth, options)?.report)
}

/// Scores `mesh` against `ground_truth`: accuracy over its vertices (plus triangle samples when
/// asked), completeness over the selected ground-truth points, surface area and counts.
/// `voxel_count` and `bytes_per_voxel` are left `None` (a mesh does not know its grid); set them
/// with [`SurfaceReport::with_voxels`].
///
/// Errors when the mesh has no vertices, a triangle names a missing vertex, a coordinate is not
/// finite, or an option is out of range. When no ground-truth point lies in the completeness
/// region, `completeness` is `None` and a warning is logged.
pub fn evaluate_mesh_detailed(
    label: &str,
    mesh: &Mesh,
    ground_truth: &GroundTruthIndex,
    options: &EvalOptions,
) -> Result<MeshEvaluation> {
    options.histogram.validate()?;
    if mesh.positions_m.is_empty() {
        return Err(Error::InvalidArgument(format!(
            "surface '{label}' has no vertices: nothing to evaluate"
        )));
    }
    check_mesh(mesh, &format!("surface '{label}'"))?;
    let points_m = surface_points(mesh, options.surface_sample_spacing_m)?;
    let t = std::time::Instant::now();
    let accuracy_m = ground_truth.nearest_distances_m(&points_m)?;
    let accuracy_s = t.elapsed().as_secs_f64();
    let accuracy = ErrorStats::from_distances(&accuracy_m, &options.histogram)?;
    let t = std::time::Instant::now();
    let mut completeness_queries = 0;
    let completeness = match &options.completeness {
        None => None,
        Some(region) => {
            let d = ground_truth.completeness_distances_m(&points_m, region)?;
            completeness_queries = d.len();
            if d.is_empty() {
                tracing::warn!(label, "no ground-truth point in the completeness region");
                None
            } else {
                Some(ErrorStats::from_owned_distances(d, &options.histogram)?)
            }
        }
    };
    tracing::info!(
        label,
        points = points_m.len(),
        // Every point: the report's scored median (where the LiDAR could see) may differ.
        median_all_points_m = accuracy.median_m,
        accuracy_s,
        completeness_queries,
        completeness_s = t.elapsed().as_secs_f64(),
        "evaluated surface"
    );
    let report = SurfaceReport {
        label: label.to_string(),
        vertices: mesh.positions_m.len() as u64,
        triangles: mesh.triangles.len() as u64,
        surface_area_m2: mesh.surface_area_m2(),
        voxel_count: None,
        bytes_per_voxel: None,
        accuracy,
        completeness,
        accuracy_unrestricted: None,
    };
    Ok(MeshEvaluation {
        report,
        points_m,
        accuracy_m,
    })
}
