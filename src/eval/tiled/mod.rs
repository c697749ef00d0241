//! The evaluation of surfaces stored as files (a paged map's meshes) within a memory budget:
//! neither the ground truth nor the surfaces nor their distances are ever held whole.
//!
//! 1. The ground truth streams scan by scan ([`GroundTruth::stream`]) into a scratch file
//!    bucketed by cubic tiles of [`TILE_M`] ([`spill`]); each surface's vertices stream from its
//!    PLY ([`crate::io::ply_stream`]) into another.
//! 2. Accuracy: the vertices of one tile at a time query the ground-truth tiles by increasing
//!    distance, each indexed when first needed and kept in a cache bounded in bytes; the answer
//!    is the exact nearest neighbour ([`nearest`]). Completeness: the same with the roles
//!    swapped, over the ground truth within the surface's bounds grown by 1 m.
//! 3. Distances go to scratch files from which the statistics are computed exactly (two
//!    sequential passes: [`crate::eval::DistanceSpill`]); the top view accumulates per pixel;
//!    the mesh pictures rasterize the triangles as they stream from the file.
//!
//! The figures equal those of [`crate::eval::evaluate_meshes`] on the same meshes (distances to
//! within the f32 rounding of the stored points, ~1 µm; percentiles of those distances; means
//! within rounding of their sums). Scratch on disk, in a hidden folder of the output folder
//! removed at the end (or by the next evaluation there, after a kill): 12 bytes per ground-truth
//! point and per vertex, 4 per distance of the surface being scored.

mod nearest;
mod spill;

use super::plot::UpAxis;
use super::render::{MeshColour, MeshPicture, MeshView};
use super::stats_spill::{DistanceSpill, Which};
use super::top_view::TopView;
use super::{EvalOptions, EvaluationReport, GroundTruth, SurfaceReport};
use crate::error::{Error, Result};
use crate::io::ply_stream::PlyMeshStream;
use spill::TileSpill;
use std::path::{Path, PathBuf};

/// Side of a tile, metres: a dense LiDAR street holds some 10⁵ points in one.
pub const TILE_M: f64 = 8.0;

/// Vertices kept to frame the mesh pictures (an even sample of a larger mesh).
const FRAMING_SAMPLE: u64 = 1 << 18;

/// Queries scored together.
const QUERY_BATCH: usize = 1 << 18;

/// A surface stored as a PLY mesh, to be scored.
#[derive(Clone, Debug)]
pub struct SurfaceFile {
    /// Its label in the report ("raw", "regularized").
    pub label: String,
    /// The mesh.
    pub mesh_path: PathBuf,
    /// Its surface area, m² (known to whoever wrote it; not recomputed from the stream).
    pub area_m2: f64,
}

/// What the streamed evaluation needs besides the surfaces.
pub struct TiledEvaluation<'a> {
    /// The ground truth.
    pub ground_truth: &'a GroundTruth,
    /// The sensor's path (world frame) drawn on the top views when the ground truth has none.
    pub trajectory_m: &'a [[f64; 3]],
    /// (voxel count, bytes per voxel) of the map the surfaces came from.
    pub voxels: Option<(u64, f64)>,
    /// RAM the evaluation may use, bytes (the index cache takes a quarter).
    pub memory_budget_bytes: u64,
    /// Where the report, the pictures and (while it runs) the scratch files go.
    pub out_dir: &'a Path,
}

/// Logs the resident set at a step of the evaluation (`--log debug`).
fn step(what: &str) {
    let rss_mib = crate::memory::rss_bytes().unwrap_or(0) >> 20;
    tracing::debug!(rss_mib, "tiled evaluation: {what}");
}

/// A surface's vertices, tiled, with what the report needs of them.
struct SpilledSurface {
    tiles: TileSpill,
    vertices: u64,
    triangles: u64,
    lo: [f64; 3],
    hi: [f64; 3],
    grey: u64,
    sample: Vec<[f64; 3]>,
}

/// `s`'s vertices tiled into `scratch/NAME.vertices` (named by the caller: a label is the
/// user's text and may hold a path).
fn spill_surface(
    s: &SurfaceFile,
    scratch: &Path,
    name: &str,
    buffered: usize,
) -> Result<SpilledSurface> {
    let stream = PlyMeshStream::open(&s.mesh_path)?;
    if stream.vertices() == 0 {
        return Err(Error::InvalidArgument(format!(
            "surface '{}' has no vertices: nothing to evaluate",
            s.label
        )));
    }
    let path = scratch.join(format!("{name}.vertices"));
    let mut tiles = TileSpill::create(&path, TILE_M, buffered)?;
    let every = stream.vertices().div_ceil(FRAMING_SAMPLE);
    let (mut lo, mut hi, mut grey, mut k) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3], 0, 0u64);
    let mut sample = Vec::new();
    stream.for_each_vertex_batch(1 << 16, |batch| {
        for (p, c) in batch {
            if p.iter().any(|v| !v.is_finite()) {
                return Err(Error::bad_input(
                    &s.mesh_path,
                    format!("vertex {k} is not finite: {p:?}"),
                ));
            }
            tiles.push(*p)?;
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
            grey += MeshColour::is_grey(c) as u64;
            if k % every == 0 {
                sample.push(*p);
            }
            k += 1;
        }
        Ok(())
    })?;
    tiles.finish()?;
    Ok(SpilledSurface {
        tiles,
        vertices: stream.vertices(),
        triangles: stream.triangles(),
        lo,
        hi,
        grey,
        sample,
    })
}

/// The surface area of a binary PLY mesh, m², read as a stream (each triangle as
/// [`crate::mesh::Mesh::surface_area_m2`] takes it).
pub fn surface_area_m2(mesh_path: &Path) -> Result<f64> {
    let mut area = 0.0;
    PlyMeshStream::open(mesh_path)?.for_each_triangle(256, |corners| {
        area += crate::mesh::triangle_area_m2(corners.map(|c| c.0.map(|v| v as f32)));
        Ok(())
    })?;
    Ok(area)
}

/// The top view's width: 1600 pixels, or fewer when its per-pixel arrays (about 19 bytes a
/// pixel, the height following the surface's aspect ratio within 1:4 and 4:1) would take more
/// than a quarter of the budget; at least 400.
fn top_view_width_px(surface: &SpilledSurface, budget_bytes: u64) -> u32 {
    let ((ri, _), (ui, _)) = UpAxis::NegY.image_axes();
    let extent = |a: usize| (surface.hi[a] - surface.lo[a]).max(1e-3);
    let aspect = (extent(ui) / extent(ri)).clamp(0.25, 4.0);
    let pixels = (budget_bytes / 4 / 19) as f64;
    ((pixels / aspect).sqrt() as u32).clamp(400, 1600)
}

/// Scores `surfaces` (the first is the baseline of the relative changes) against the ground
/// truth within `how.memory_budget_bytes`, and writes the report and pictures as
/// [`crate::eval::evaluate_meshes`] does. `make_report` receives the number of ground-truth
/// points and the seconds taken to read them, and gives the report to fill in.
pub fn evaluate_surface_files(
    surfaces: &[SurfaceFile],
    how: &TiledEvaluation<'_>,
    make_report: impl FnOnce(u64, f64) -> EvaluationReport,
) -> Result<(EvaluationReport, Vec<PathBuf>)> {
    let out_dir = how.out_dir;
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    // Scratch in a hidden folder of this process (`.evaluation-scratch.PID.partial`), removed
    // on the way out; what a killed run left there is removed first.
    let scratch_target = out_dir.join("evaluation-scratch");
    crate::io::atomic::remove_stale_partials(&scratch_target);
    let scratch = crate::io::atomic::TempPath::at(crate::io::atomic::partial_name(&scratch_target));
    std::fs::create_dir_all(scratch.path()).map_err(|e| Error::io(scratch.path(), e))?;
    let budget = how.memory_budget_bytes.max(32 << 20);
    // Points waiting in memory before they are written out (12 bytes each, plus the map entry).
    let buffered = (budget / 16 / 16) as usize;
    let t = std::time::Instant::now();
    let mut gt = TileSpill::create(&scratch.path().join("ground-truth"), TILE_M, buffered)?;
    let coverage = how.ground_truth.stream(|points| {
        for p in points {
            if p.iter().any(|v| !v.is_finite()) {
                return Err(Error::InvalidArgument(format!(
                    "a ground-truth point is not finite: {p:?}"
                )));
            }
            gt.push(*p)?;
        }
        Ok(())
    })?;
    gt.finish()?;
    if gt.len() == 0 {
        return Err(Error::InvalidArgument(
            "the ground truth holds no point".into(),
        ));
    }
    step("ground truth tiled");
    let mut report = make_report(gt.len(), t.elapsed().as_secs_f64());
    let t = std::time::Instant::now();
    let (glo, ghi) = gt.tiles().fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), (_, i)| {
            (
                [0, 1, 2].map(|a| lo[a].min(i.lo[a])),
                [0, 1, 2].map(|a| hi[a].max(i.hi[a])),
            )
        },
    );
    let options = EvalOptions::default();
    let cache_bytes = budget / 4;
    // Freed arrays (query batches, evicted tiles) go back to the kernel whenever the resident
    // set passes the budget: a run that regularized keeps freed memory in the heap.
    let mut trim = crate::memory::TrimAbove::new(budget);
    let mut written = Vec::new();
    let mut evaluations = Vec::new();
    let mut scratch_bytes = gt.bytes();
    let mut last: Option<(String, SpilledSurface)> = None;
    let bar = crate::progress::bar(surfaces.len() as u64, "evaluating");
    for (k, s) in surfaces.iter().enumerate() {
        // Scratch files by position, not label (a label is free text).
        let stem = format!("surface{k}");
        let surface = spill_surface(s, scratch.path(), &stem, buffered)?;
        let meets = (0..3).all(|a| surface.lo[a] - 1.0 <= ghi[a] && surface.hi[a] + 1.0 >= glo[a]);
        if !meets {
            return Err(Error::InvalidArgument(format!(
                "the ground truth does not overlap the surface `{}`: the surface spans {:.1?}–{:.1?} m, the ground truth {glo:.1?}–{ghi:.1?} m (another place, or another frame?)",
                s.label, surface.lo, surface.hi
            )));
        }
        let label = s.label.as_str();
        step("surface tiled");
        // Accuracy: every vertex to its nearest ground-truth point, with the top view.
        let name = format!("top_view_{label}.png");
        let top_path = out_dir.join(&name);
        trim.make_room(0);
        let mut top = TopView::new(
            &top_path,
            label,
            (surface.lo, surface.hi),
            surface.vertices,
            UpAxis::NegY,
            0.5,
            top_view_width_px(&surface, budget),
        )?;
        let accuracy_path = scratch.path().join(format!("{stem}.accuracy"));
        let mut accuracy = DistanceSpill::create(&accuracy_path)?;
        let t_acc = std::time::Instant::now();
        let counts = nearest::nearest_by_tile(
            &surface.tiles,
            &gt,
            cache_bytes,
            QUERY_BATCH,
            |_| true,
            |points, distances| {
                let mask = coverage.as_ref().map(|c| c.mask(points));
                for (i, &d) in distances.iter().enumerate() {
                    accuracy.push(d, mask.as_ref().is_none_or(|m| m[i]))?;
                }
                trim.check();
                top.add(points, distances, mask.as_deref())
            },
        )?;
        let accuracy_s = t_acc.elapsed().as_secs_f64();
        step("accuracy");
        top.finish(
            &coverage
                .as_ref()
                .map_or_else(|| how.trajectory_m.to_vec(), |c| c.trajectory_m()),
        )?;
        report.pictures.push(name);
        written.push(top_path);
        step("top view");
        let all = accuracy
            .stats(&options.histogram, Which::All)?
            .ok_or_else(|| {
                Error::InvalidArgument(format!("surface '{label}': no vertex was scored"))
            })?;
        let (accuracy_stats, unrestricted) = match &coverage {
            None => (all, None),
            Some(_) => match accuracy.stats(&options.histogram, Which::Scored)? {
                Some(scored) => (scored, Some(all)),
                None => {
                    tracing::warn!(
                        "surface `{label}`: no point lies where the LiDAR could have measured; scoring every point"
                    );
                    (all, None)
                }
            },
        };
        scratch_bytes = scratch_bytes.max(gt.bytes() + surface.tiles.bytes() + 4 * accuracy.len());
        drop(accuracy);
        // Completeness: the ground truth within the surface's bounds grown by 1 m, to the
        // nearest vertex.
        let margin = 1.0;
        let (lo, hi) = (
            surface.lo.map(|v| v - margin),
            surface.hi.map(|v| v + margin),
        );
        let inside = |p: &[f64; 3]| (0..3).all(|a| p[a] >= lo[a] && p[a] <= hi[a]);
        let mut completeness =
            DistanceSpill::create(&scratch.path().join(format!("{stem}.completeness")))?;
        let t_comp = std::time::Instant::now();
        let comp = nearest::nearest_by_tile(
            &gt,
            &surface.tiles,
            cache_bytes,
            QUERY_BATCH,
            inside,
            |_, d| {
                trim.check();
                d.iter().try_for_each(|&d| completeness.push(d, true))
            },
        )?;
        scratch_bytes =
            scratch_bytes.max(gt.bytes() + surface.tiles.bytes() + 4 * completeness.len());
        step("completeness");
        let completeness_stats = completeness.stats(&options.histogram, Which::All)?;
        if completeness_stats.is_none() {
            tracing::warn!(label, "no ground-truth point in the completeness region");
        }
        drop(completeness);
        tracing::info!(
            label,
            points = surface.vertices,
            median_all_points_m = unrestricted.as_ref().unwrap_or(&accuracy_stats).median_m,
            accuracy_s,
            accuracy_tile_loads = counts.tile_loads,
            completeness_queries = comp.queries,
            completeness_tile_loads = comp.tile_loads,
            completeness_s = t_comp.elapsed().as_secs_f64(),
            "evaluated surface (tiled)"
        );
        let mut r = SurfaceReport {
            label: label.to_string(),
            vertices: surface.vertices,
            triangles: surface.triangles,
            surface_area_m2: s.area_m2,
            voxel_count: None,
            bytes_per_voxel: None,
            accuracy: accuracy_stats,
            completeness: completeness_stats,
            accuracy_unrestricted: unrestricted,
        };
        if let Some((count, bpv)) = how.voxels {
            r = r.with_voxels(count, bpv);
        }
        evaluations.push(r);
        last = Some((label.to_string(), surface));
        bar.inc(1);
    }
    bar.finish_and_clear();
    drop(gt);
    report.coverage = coverage.as_ref().map(|c| c.view());
    super::run::plot_histogram(&mut report, &evaluations, out_dir, &mut written)?;
    // The last (regularized) surface as it looks, from above and from an oblique viewpoint.
    if let Some((label, surface)) = last.filter(|(_, s)| s.triangles > 0) {
        let path = &surfaces.last().expect("a surface").mesh_path;
        let stream = PlyMeshStream::open(path)?;
        let colour = MeshColour::for_counts(surface.grey, surface.vertices);
        for (view, name) in [(MeshView::Top, "top"), (MeshView::Oblique, "oblique")] {
            let file = format!("view_{name}_{label}.png");
            let out = out_dir.join(&file);
            let title = super::run::mesh_picture_title(&label, name, colour);
            let mut picture = MeshPicture::new(&surface.sample, UpAxis::NegY, view, colour, 1600);
            stream.for_each_triangle(256, |corners| {
                picture.add_triangle(corners.map(|c| c.0), corners.map(|c| c.1));
                Ok(())
            })?;
            picture.finish(&out, &title)?;
            step("mesh picture");
            report.pictures.push(file);
            written.push(out);
        }
    }
    report
        .memory_bytes
        .push(("evaluation scratch on disk (peak)".into(), scratch_bytes));
    let evaluation_s = t.elapsed().as_secs_f64();
    super::run::finish_report(
        &mut report,
        evaluations,
        evaluation_s,
        out_dir,
        &mut written,
    )?;
    drop(scratch);
    Ok((report, written))
}
