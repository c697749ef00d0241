//! Evaluation against ground truth (DENSER Sec. VI): how far reconstructed surfaces lie from the
//! ground truth, summarised and drawn as in the paper's Table I and Fig. 4.
//!
//! # What is measured
//!
//! * **Ground truth** is a point cloud in the world frame: all LiDAR scans of a drive merged with
//!   their poses (the paper), or dense samples of the exact surfaces of a synthetic scene. It is
//!   indexed once ([`GroundTruthIndex`]) in a tree whose nodes keep the tight box of their points
//!   (`box_tree`: a k-d tree's open cells would make a query a metre above a LiDAR-scanned street
//!   visit every column of ground points within a metre), after subtracting a common origin so
//!   that georeferenced coordinates keep their precision; all queries are `f64`.
//! * **Accuracy** (the paper's "error"): for every reconstructed surface point, the Euclidean
//!   distance to the *nearest ground-truth point*, metres. The reconstructed points are the mesh's
//!   vertices, optionally plus points sampled on its triangles at a given spacing
//!   ([`sample_mesh_surface`]; [`EvalOptions::surface_sample_spacing_m`]). Note that this is a
//!   point-to-point distance: where the ground truth is sparse (LiDAR rings far from the car) it
//!   includes the gap between LiDAR points, so a perfect surface does not score zero.
//! * **Completeness**: for every ground-truth point in a region ([`CompletenessRegion`]: all, the
//!   reconstruction's bounding box grown by a margin — the default, 1 m — or an explicit box), the
//!   distance to the nearest reconstructed point. It penalises holes and surfaces removed by the
//!   regularizer, which accuracy cannot see. These queries (tens of millions, mostly centimetres
//!   from the surface) are answered a grid cell at a time from the reconstructed points of the
//!   cells around it, exactly; only those farther than a few cells reach a tree.
//! * **Statistics** ([`ErrorStats`]): count, mean, RMSE, median, 75th and 90th percentiles (exact,
//!   NumPy's linear interpolation), maximum, a fixed-width histogram whose last bin collects
//!   overflow, and the mode = centre of the fullest regular bin.
//! * **Per surface** ([`SurfaceReport`]): the above plus vertex and triangle counts, surface area
//!   (m²) and, when the caller supplies them, voxel count and bytes per voxel.
//! * **Per run** ([`EvaluationReport`]): every surface (raw vs. regularized), stage timings,
//!   memory figures and parameters, as JSON and as a Markdown table with relative changes.
//! * **Pictures** ([`plot_error_histograms_png`], [`plot_top_view_png`]): overlaid histograms
//!   (x = error in m, y = fraction of points) and a top view coloured by error.
//!
//! * **Ground truth** ([`GroundTruth`]): a KITTI sequence's scans merged in the world frame, or a
//!   point-cloud file; **runs** ([`run`]): scoring labelled meshes, or a reconstruction's
//!   surfaces, into the report and pictures.
//!
//! This module does not run the reconstruction: the caller hands it meshes (or a finished
//! [`crate::reconstruct::Reconstructor`] and the surfaces it wrote).

mod box_tree;
mod coverage;
mod evaluate;
mod ground_truth;
mod nn;
mod nn_grid;
mod plot;
mod render;
mod report;
pub mod run;
mod stats;
mod stats_spill;
pub mod tiled;
mod top_view;

pub use coverage::{CoverageBuilder, SensorCoverage, SensorView};
pub use evaluate::{evaluate_mesh, evaluate_mesh_detailed, EvalOptions, MeshEvaluation};
pub use ground_truth::{merged_lidar, GroundTruth};
pub use nn::{sample_mesh_surface, surface_points, CompletenessRegion, GroundTruthIndex};
pub use plot::{error_colour, plot_error_histograms_png, UpAxis, SERIES_COLOURS, UNSCORED_GREY};
pub use report::{EvaluationReport, SurfaceReport};
pub use run::{evaluate_meshes, evaluate_reconstruction, sparse_ground_truth_note, RunFacts};
pub use stats::{percentile_of_sorted, ErrorStats, Histogram, HistogramSpec};
pub use stats_spill::{DistanceSpill, Which};
pub use top_view::{plot_top_view_png, TopView};
