//! Nearest-neighbour distances between point sets, and points taken from a mesh's surface.
//!
//! The ground truth is indexed once ([`GroundTruthIndex`], a tree of tight boxes:
//! [`crate::eval::box_tree`]) and queried in parallel (rayon). All positions are shifted by a
//! common origin (the centre of the ground truth's bounding box) before they enter an index, so
//! that georeferenced coordinates (LAS/UTM, ~10⁶ m) keep sub-millimetre precision in the `f32`
//! the indices hold; queries stay `f64` until they enter the index, and distances are returned as
//! `f32` metres.
//!
//! This module does not summarise distances ([`crate::eval::ErrorStats`]) nor read files.

use crate::error::{Error, Result};
use crate::eval::box_tree::BoxTree;
use crate::eval::nn_grid::CellGrid;
use crate::frame::PointCloud;
use crate::mesh::Mesh;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Queries handed to one rayon task at a time.
const QUERY_CHUNK: usize = 4096;

/// Queries sorted and answered together: the working memory of a query pass (about 52 bytes per
/// query of a batch: the `f64` query, its Morton key and index, the answers) stays bounded however
/// many points are scored. 2²⁰ rather than 2²¹: 52 MiB less at the evaluation's peak, no
/// measurable change in time (`docs/bench/e2e.md`).
const QUERY_BATCH: usize = 1 << 20;

/// Points stored relative to the shared origin, indexed for nearest-neighbour queries.
///
/// The points are held in `f32` relative to the shared origin (half the memory of `f64`, so more
/// of them stays in cache): a coordinate within ±4 km of the origin rounds by at most 0.25 mm
/// (2⁻²⁴ of its distance from the origin; 3 µm at 50 m). The neighbour the index finds is then
/// measured in `f64` from the `f64` query, so the distance returned is exact for the stored point.
struct PointTree {
    /// The points in a tree of tight boxes (which holds them, in its own order).
    tree: BoxTree,
    /// When built with one ([`PointTree::with_grid`]): a [`CellGrid`] over the points and the
    /// points sorted by its cells, which answer queries near the points before any tree descent.
    grid: Option<(CellGrid, Vec<[f32; 3]>)>,
}

impl PointTree {
    /// Indexes `points_local_m` (already relative to the shared origin).
    fn new(points_local_m: Vec<[f32; 3]>) -> Result<PointTree> {
        Ok(PointTree {
            tree: BoxTree::new(points_local_m)?,
            grid: None,
        })
    }

    /// The indexed points (in the tree's order).
    fn points_local_m(&self) -> &[[f32; 3]] {
        self.tree.points()
    }

    /// [`PointTree::new`] with a [`CellGrid`] in front of the tree: queries within about a cell
    /// of a point are answered by the grid, from a copy of the points sorted by cell.
    fn with_grid(points_local_m: Vec<[f32; 3]>) -> Result<PointTree> {
        let mut by_cell = points_local_m.clone();
        let grid = CellGrid::build(&mut by_cell).map(|grid| (grid, by_cell));
        let mut tree = PointTree::new(points_local_m)?;
        tree.grid = grid;
        Ok(tree)
    }

    /// Distance (metres) from each query (relative to the shared origin) to its nearest point, in
    /// the queries' order.
    fn nearest_distances_m(&self, queries_local_m: &[[f64; 3]]) -> Vec<f32> {
        let Some((grid, by_cell)) = &self.grid else {
            return self.tree_distances_m(queries_local_m);
        };
        let mut out = grid.nearest_distances_m(by_cell, queries_local_m);
        let left: Vec<u32> = (0..out.len() as u32)
            .filter(|&i| out[i as usize].is_nan())
            .collect();
        let left_queries: Vec<[f64; 3]> =
            left.iter().map(|&i| queries_local_m[i as usize]).collect();
        for (&i, d) in left.iter().zip(self.tree_distances_m(&left_queries)) {
            out[i as usize] = d;
        }
        tracing::debug!(
            queries = out.len(),
            by_tree = left.len(),
            cell_m = grid.cell_m(),
            "nearest neighbours through the cell grid"
        );
        out
    }

    /// [`PointTree::nearest_distances_m`] by the tree alone. Queries run in Morton order of their
    /// positions, each search seeded with the previous query's answer.
    fn tree_distances_m(&self, queries_local_m: &[[f64; 3]]) -> Vec<f32> {
        let order = morton_order(queries_local_m);
        let points = self.points_local_m();
        let mut sorted = vec![0.0f32; queries_local_m.len()];
        sorted
            .par_chunks_mut(QUERY_CHUNK)
            .zip(order.par_chunks(QUERY_CHUNK))
            .for_each(|(out, idx)| {
                let mut previous = None;
                for (o, &i) in out.iter_mut().zip(idx) {
                    let q = &queries_local_m[i as usize];
                    let nearest = self
                        .tree
                        .nearest(q.map(|v| v as f32), previous)
                        .expect("a point tree is never empty");
                    previous = Some(nearest);
                    *o = dist(q, &points[nearest as usize].map(f64::from)) as f32;
                }
            });
        let mut out = vec![0.0f32; queries_local_m.len()];
        for (&i, &d) in order.iter().zip(&sorted) {
            out[i as usize] = d;
        }
        out
    }
}

impl PointTree {
    /// [`PointTree::nearest_distances_m`] of the items of `items` that `keep` accepts, as
    /// `query(item)` (relative to the shared origin), in order, [`QUERY_BATCH`] items at a time:
    /// the queries are made a batch at a time, never all at once.
    fn batched_distances_m<P: Sync>(
        &self,
        items: &[P],
        keep: impl Fn(&P) -> bool + Sync,
        query: impl Fn(&P) -> [f64; 3] + Sync,
    ) -> Vec<f32> {
        // Sized once: growing by doubling would hold the old and the new array together at the
        // end (up to 3× the answers: 320 MiB for 28 M completeness queries).
        let kept = items.par_iter().filter(|p| keep(p)).count();
        let mut out = Vec::with_capacity(kept);
        for chunk in items.chunks(QUERY_BATCH) {
            let batch: Vec<[f64; 3]> = chunk.par_iter().filter(|p| keep(p)).map(&query).collect();
            out.extend(self.nearest_distances_m(&batch));
        }
        out
    }
}

/// Ground-truth points relative to the centre of their bounding box, in `f32`, with that origin
/// and the world-frame bounding box.
#[allow(clippy::type_complexity)]
fn localise(points_m: &[[f64; 3]]) -> Result<([f64; 3], ([f64; 3], [f64; 3]), Vec<[f32; 3]>)> {
    if points_m.is_empty() {
        return Err(Error::InvalidArgument(
            "the ground truth has no points".into(),
        ));
    }
    let bounds_m = bounds_of(points_m, "ground-truth")?;
    let origin_m = std::array::from_fn(|k| 0.5 * (bounds_m.0[k] + bounds_m.1[k]));
    let points_local_m = points_m
        .par_iter()
        .map(|p| narrow(sub(p, &origin_m)))
        .collect();
    Ok((origin_m, bounds_m, points_local_m))
}

/// An origin-relative position in `f32` (nearest rounding).
#[inline]
fn narrow(p: [f64; 3]) -> [f32; 3] {
    p.map(|v| v as f32)
}

/// Indices of `points` sorted along a Morton (Z-order) curve over their bounding box, 21 bits
/// per axis.
fn morton_order(points: &[[f64; 3]]) -> Vec<u32> {
    if points.is_empty() {
        return Vec::new();
    }
    let init = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    let (lo, hi) = points
        .par_iter()
        .fold(
            || init,
            |(lo, hi), p| {
                (
                    std::array::from_fn(|k| lo[k].min(p[k])),
                    std::array::from_fn(|k| hi[k].max(p[k])),
                )
            },
        )
        .reduce(
            || init,
            |a, b| {
                (
                    std::array::from_fn(|k| a.0[k].min(b.0[k])),
                    std::array::from_fn(|k| a.1[k].max(b.1[k])),
                )
            },
        );
    let cells = ((1u32 << 21) - 1) as f64;
    let scale: [f64; 3] = std::array::from_fn(|k| {
        let extent = hi[k] - lo[k];
        if extent > 0.0 {
            cells / extent
        } else {
            0.0
        }
    });
    let mut keyed: Vec<(u64, u32)> = points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let cell = |k: usize| ((p[k] - lo[k]) * scale[k]) as u64;
            let key = spread_bits(cell(0)) | spread_bits(cell(1)) << 1 | spread_bits(cell(2)) << 2;
            (key, i as u32)
        })
        .collect();
    keyed.par_sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

/// The low 21 bits of `v` moved to every third bit (bit i to bit 3i).
fn spread_bits(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | x << 32) & 0x1f_0000_0000_ffff;
    x = (x | x << 16) & 0x1f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

/// The ground-truth point cloud (LiDAR scans merged in the world frame, or dense samples of exact
/// synthetic surfaces), indexed once for any number of reconstructions.
pub struct GroundTruthIndex {
    /// Common origin subtracted from every position before it enters a tree, metres (world).
    origin_m: [f64; 3],
    /// World-frame bounding box of the ground truth, metres.
    bounds_m: ([f64; 3], [f64; 3]),
    /// The ground-truth points relative to `origin_m`, indexed (the index holds them, in its own
    /// order, for completeness queries).
    tree: PointTree,
}

impl GroundTruthIndex {
    /// Indexes the points of `cloud` (colours are ignored).
    ///
    /// Errors when the cloud is empty or holds a non-finite coordinate.
    pub fn new(cloud: &PointCloud) -> Result<GroundTruthIndex> {
        GroundTruthIndex::from_points(&cloud.points_m)
    }

    /// [`GroundTruthIndex::new`], freeing the cloud as soon as its points are copied (the index
    /// holds them in `f32`, a quarter of the cloud's size with its colours dropped).
    pub fn from_cloud(cloud: PointCloud) -> Result<GroundTruthIndex> {
        let (origin_m, bounds_m, points_local_m) = localise(&cloud.points_m)?;
        drop(cloud);
        GroundTruthIndex::build(origin_m, bounds_m, points_local_m)
    }

    /// Indexes `points_m` (world frame, metres).
    ///
    /// Errors when there are no points or a coordinate is not finite.
    pub fn from_points(points_m: &[[f64; 3]]) -> Result<GroundTruthIndex> {
        let (origin_m, bounds_m, points_local_m) = localise(points_m)?;
        GroundTruthIndex::build(origin_m, bounds_m, points_local_m)
    }

    fn build(
        origin_m: [f64; 3],
        bounds_m: ([f64; 3], [f64; 3]),
        points_local_m: Vec<[f32; 3]>,
    ) -> Result<GroundTruthIndex> {
        // No cell grid here: most accuracy queries of a raw surface lie farther from the ground
        // truth than a few of its (dense) cells, which is where the tree's tight boxes pay
        // (docs/bench/e2e.md).
        let tree = PointTree::new(points_local_m)?;
        tracing::debug!(points = tree.points_local_m().len(), "indexed ground truth");
        Ok(GroundTruthIndex {
            origin_m,
            bounds_m,
            tree,
        })
    }

    /// Number of ground-truth points.
    pub fn len(&self) -> usize {
        self.tree.points_local_m().len()
    }

    /// Always false: an index is never built over zero points.
    pub fn is_empty(&self) -> bool {
        self.tree.points_local_m().is_empty()
    }

    /// The origin subtracted from positions before queries, metres (world frame).
    pub fn origin_m(&self) -> [f64; 3] {
        self.origin_m
    }

    /// World-frame bounding box `(min, max)` of the ground truth, metres.
    pub fn bounds_m(&self) -> ([f64; 3], [f64; 3]) {
        self.bounds_m
    }

    /// Accuracy distances: for each of `points_m` (world frame, metres), the Euclidean distance to
    /// the nearest ground-truth point, metres, in input order. Queries run in parallel.
    ///
    /// Errors when a coordinate is not finite.
    pub fn nearest_distances_m(&self, points_m: &[[f64; 3]]) -> Result<Vec<f32>> {
        check_finite(points_m, "query")?;
        Ok(self
            .tree
            .batched_distances_m(points_m, |_| true, |p| sub(p, &self.origin_m)))
    }

    /// Completeness distances: for each ground-truth point selected by `region`, the distance to
    /// the nearest of `reconstructed_points_m` (world frame, metres). Builds a temporary index
    /// (with a [`CellGrid`]) over the reconstructed points. The result follows the index's order
    /// of the ground truth (spatial, not the input's), skipping points outside the region; it is
    /// empty when no ground-truth point is in the region.
    ///
    /// Errors when `reconstructed_points_m` is empty or holds a non-finite coordinate, or when
    /// the region is malformed.
    pub fn completeness_distances_m(
        &self,
        reconstructed_points_m: &[[f64; 3]],
        region: &CompletenessRegion,
    ) -> Result<Vec<f32>> {
        if reconstructed_points_m.is_empty() {
            return Err(Error::InvalidArgument(
                "completeness needs at least one reconstructed point".into(),
            ));
        }
        let recon_bounds = bounds_of(reconstructed_points_m, "reconstructed")?;
        let (lo, hi) = match *region {
            CompletenessRegion::All => ([f64::NEG_INFINITY; 3], [f64::INFINITY; 3]),
            CompletenessRegion::ReconstructionBounds { margin_m } => {
                if !(margin_m.is_finite() && margin_m >= 0.0) {
                    return Err(Error::InvalidArgument(format!(
                        "completeness margin must be finite and ≥ 0 m, got {margin_m}"
                    )));
                }
                (
                    recon_bounds.0.map(|v| v - margin_m),
                    recon_bounds.1.map(|v| v + margin_m),
                )
            }
            CompletenessRegion::Aabb { min_m, max_m } => {
                if (0..3).any(|k| !(min_m[k] <= max_m[k])) {
                    return Err(Error::InvalidArgument(format!(
                        "completeness box min {min_m:?} is not ≤ max {max_m:?}"
                    )));
                }
                (min_m, max_m)
            }
        };
        // The box rounds to f32 as the points did, so a point on a face stays inside.
        let lo_local = narrow(sub(&lo, &self.origin_m));
        let hi_local = narrow(sub(&hi, &self.origin_m));
        let inside = |p: &[f32; 3]| (0..3).all(|k| p[k] >= lo_local[k] && p[k] <= hi_local[k]);
        let gt = self.tree.points_local_m();
        if !gt.par_iter().any(inside) {
            return Ok(Vec::new());
        }
        let recon_local: Vec<[f32; 3]> = reconstructed_points_m
            .par_iter()
            .map(|p| narrow(sub(p, &self.origin_m)))
            .collect();
        let tree = PointTree::with_grid(recon_local)?;
        // Selected a batch at a time (no index of every selected point, 4 bytes per point).
        Ok(tree.batched_distances_m(gt, inside, |p| p.map(f64::from)))
    }
}

/// Which ground-truth points count for completeness (the distance from a ground-truth point to the
/// nearest reconstructed point). Ground truth usually covers more than one reconstruction saw
/// (e.g. LiDAR reaches further than stereo), so completeness is normally limited to a region.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum CompletenessRegion {
    /// Every ground-truth point.
    All,
    /// Ground-truth points inside the reconstructed points' axis-aligned bounding box grown by
    /// `margin_m` metres on every side (bounds inclusive).
    ReconstructionBounds {
        /// Growth of the box on each side, metres.
        margin_m: f64,
    },
    /// Ground-truth points inside an explicit world-frame axis-aligned box (bounds inclusive).
    Aabb {
        /// Lower corner, metres.
        min_m: [f64; 3],
        /// Upper corner, metres.
        max_m: [f64; 3],
    },
}

/// The reconstructed points scored for accuracy: every mesh vertex, followed (when
/// `sample_spacing_m` is given) by [`sample_mesh_surface`]'s points on the triangles. World frame,
/// metres.
pub fn surface_points(mesh: &Mesh, sample_spacing_m: Option<f64>) -> Result<Vec<[f64; 3]>> {
    let mut points: Vec<[f64; 3]> = mesh
        .positions_m
        .iter()
        .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
        .collect();
    if let Some(spacing_m) = sample_spacing_m {
        points.extend(sample_mesh_surface(mesh, spacing_m)?);
    }
    Ok(points)
}

/// Deterministic points on the triangles of `mesh`, metres (world frame), in triangle order.
///
/// Each triangle is split into `k²` congruent sub-triangles by dividing every edge into `k` equal
/// parts, with `k = max(1, ceil(longest edge / spacing_m))`; one point is taken at the centroid of
/// each sub-triangle. Within a triangle every point stands for the same area, and neighbouring
/// points are at most about `spacing_m` apart. Vertices are not included (see [`surface_points`]).
///
/// Errors when `spacing_m` is not a positive finite number, when a triangle names a missing
/// vertex, or when a triangle would need more than 10⁶ samples (spacing far too small).
pub fn sample_mesh_surface(mesh: &Mesh, spacing_m: f64) -> Result<Vec<[f64; 3]>> {
    if !(spacing_m.is_finite() && spacing_m > 0.0) {
        return Err(Error::InvalidArgument(format!(
            "surface sample spacing must be a positive number of metres, got {spacing_m}"
        )));
    }
    check_mesh(mesh, "mesh")?;
    let vertex = |i: u32| {
        let p = mesh.positions_m[i as usize];
        [p[0] as f64, p[1] as f64, p[2] as f64]
    };
    let per_triangle: Vec<Vec<[f64; 3]>> = mesh
        .triangles
        .par_iter()
        .map(|t| {
            let (a, b, c) = (vertex(t[0]), vertex(t[1]), vertex(t[2]));
            let longest = dist(&a, &b).max(dist(&b, &c)).max(dist(&c, &a));
            let k_f = (longest / spacing_m).ceil().max(1.0);
            if k_f > 1000.0 {
                return Err(Error::InvalidArgument(format!(
                    "triangle edge {longest:.3} m sampled every {spacing_m} m needs more than 10⁶ \
                     samples; use a larger spacing"
                )));
            }
            Ok(subtriangle_centroids(&a, &b, &c, k_f as usize))
        })
        .collect::<Result<_>>()?;
    Ok(per_triangle.into_iter().flatten().collect())
}

/// Centroids of the `k²` sub-triangles of triangle `abc` (edges divided into `k` parts).
fn subtriangle_centroids(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], k: usize) -> Vec<[f64; 3]> {
    let mut out = Vec::with_capacity(k * k);
    let kf = k as f64;
    // Barycentric lattice: vertex (i, j) = a + (i/k)(b − a) + (j/k)(c − a), i + j ≤ k.
    let point = |u: f64, v: f64| -> [f64; 3] {
        std::array::from_fn(|d| a[d] + u / kf * (b[d] - a[d]) + v / kf * (c[d] - a[d]))
    };
    for i in 0..k {
        for j in 0..(k - i) {
            // Upward sub-triangle (i,j), (i+1,j), (i,j+1): centroid at (i + 1/3, j + 1/3).
            out.push(point(i as f64 + 1.0 / 3.0, j as f64 + 1.0 / 3.0));
            // Downward sub-triangle (i+1,j), (i,j+1), (i+1,j+1), present when i + j + 2 ≤ k.
            if i + j + 2 <= k {
                out.push(point(i as f64 + 2.0 / 3.0, j as f64 + 2.0 / 3.0));
            }
        }
    }
    out
}

/// Checks every triangle index and vertex coordinate of `mesh`; errors start with `what`.
pub(crate) fn check_mesh(mesh: &Mesh, what: &str) -> Result<()> {
    let n = mesh.positions_m.len();
    if let Some((i, t)) = mesh
        .triangles
        .iter()
        .enumerate()
        .find(|(_, t)| t.iter().any(|&v| v as usize >= n))
    {
        return Err(Error::InvalidArgument(format!(
            "{what}: triangle {i} refers to vertex {t:?} but the mesh has {n} vertices"
        )));
    }
    if let Some(i) = mesh
        .positions_m
        .iter()
        .position(|p| p.iter().any(|v| !v.is_finite()))
    {
        return Err(Error::InvalidArgument(format!(
            "{what}: vertex {i} has a non-finite coordinate {:?}",
            mesh.positions_m[i]
        )));
    }
    Ok(())
}

/// Bounding box of `points`; errors (naming `what`) on a non-finite coordinate.
fn bounds_of(points: &[[f64; 3]], what: &str) -> Result<([f64; 3], [f64; 3])> {
    check_finite(points, what)?;
    let init = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    Ok(points.iter().fold(init, |(lo, hi), p| {
        (
            std::array::from_fn(|k| lo[k].min(p[k])),
            std::array::from_fn(|k| hi[k].max(p[k])),
        )
    }))
}

/// Errors (naming `what` and the index) when a coordinate is not finite.
fn check_finite(points: &[[f64; 3]], what: &str) -> Result<()> {
    match points
        .par_iter()
        .position_first(|p| p.iter().any(|v| !v.is_finite()))
    {
        Some(i) => Err(Error::InvalidArgument(format!(
            "{what} point {i} has a non-finite coordinate {:?}",
            points[i]
        ))),
        None => Ok(()),
    }
}

#[inline]
fn sub(p: &[f64; 3], o: &[f64; 3]) -> [f64; 3] {
    [p[0] - o[0], p[1] - o[1], p[2] - o[2]]
}

#[inline]
fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let d = sub(a, b);
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subtriangle_centroids_cover_the_triangle_evenly() {
        let a = [0.0, 0.0, 0.0];
        let b = [1.0, 0.0, 0.0];
        let c = [0.0, 1.0, 0.0];
        for k in 1..6 {
            let pts = subtriangle_centroids(&a, &b, &c, k);
            assert_eq!(pts.len(), k * k);
            // Mean of equal-area centroids = centroid of the triangle.
            let mean: [f64; 3] =
                std::array::from_fn(|d| pts.iter().map(|p| p[d]).sum::<f64>() / pts.len() as f64);
            assert!((mean[0] - 1.0 / 3.0).abs() < 1e-12 && (mean[1] - 1.0 / 3.0).abs() < 1e-12);
            // Every point strictly inside.
            assert!(pts
                .iter()
                .all(|p| p[0] > 0.0 && p[1] > 0.0 && p[0] + p[1] < 1.0));
        }
    }

    #[test]
    fn spread_bits_moves_bit_i_to_bit_3i() {
        assert_eq!(spread_bits(0b111), 0b1001001);
        assert_eq!(spread_bits(0b101), 0b1000001);
        assert_eq!(spread_bits(0x1f_ffff), 0x1249_2492_4924_9249);
        assert_eq!(spread_bits(1 << 20), 1 << 60);
        assert_eq!(spread_bits(1 << 21), 0, "only the low 21 bits count");
    }

    #[test]
    fn morton_order_visits_a_grid_along_the_z_curve() {
        // A 4×4×4 grid listed in reverse: the order must be a permutation visiting the cells in
        // increasing Morton key (x the lowest bit), i.e. (0,0,0), (1,0,0), (0,1,0), (1,1,0), …
        let mut pts = Vec::new();
        for x in 0..4 {
            for y in 0..4 {
                for z in 0..4 {
                    pts.push([x as f64, y as f64, z as f64]);
                }
            }
        }
        pts.reverse();
        let order = morton_order(&pts);
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..64u32).collect::<Vec<_>>());
        let cell = |i: u32| pts[i as usize].map(|v| v as u64);
        let key = |c: [u64; 3]| spread_bits(c[0]) | spread_bits(c[1]) << 1 | spread_bits(c[2]) << 2;
        assert_eq!(cell(order[0]), [0, 0, 0]);
        assert_eq!(cell(order[1]), [1, 0, 0]);
        assert_eq!(cell(order[2]), [0, 1, 0]);
        assert_eq!(cell(order[4]), [0, 0, 1]);
        assert!(order.windows(2).all(|w| key(cell(w[0])) < key(cell(w[1]))));
        assert!(morton_order(&[]).is_empty());
        assert_eq!(morton_order(&[[1.0, 2.0, 3.0]; 3]).len(), 3);
    }

    #[test]
    fn completeness_through_the_cell_grid_equals_brute_force() {
        // A reconstruction on a ground plane and a wall, georeferenced far from the origin; ground
        // truth near it (answered by the grid), a few cells off (the outer rings), and metres
        // away (left to the tree). Every distance must be the brute-force one.
        let mut rng = crate::synth::rng::Rng::new(99, 0);
        let mut rnd = || rng.f64();
        let o = [4.0e5, 5.2e6, 30.0];
        let mut recon = Vec::new();
        for _ in 0..20_000 {
            recon.push([o[0] + rnd() * 20.0, o[1] + rnd() * 20.0, o[2]]);
            recon.push([o[0] + rnd() * 20.0, o[1] + 10.0, o[2] + rnd() * 4.0]);
        }
        let gt: Vec<[f64; 3]> = (0..6000)
            .map(|i| {
                let lift = [0.02, 0.3, 0.9, 6.0][i % 4];
                [
                    o[0] + rnd() * 20.0,
                    o[1] + rnd() * 20.0,
                    o[2] + lift * rnd(),
                ]
            })
            .collect();
        let index = GroundTruthIndex::from_points(&gt).unwrap();
        let d = index
            .completeness_distances_m(&recon, &CompletenessRegion::All)
            .unwrap();
        assert_eq!(d.len(), gt.len());
        // Brute force in the index's own terms: f32 points relative to its origin.
        let origin = index.origin_m();
        let local = |p: &[f64; 3]| narrow(sub(p, &origin)).map(f64::from);
        let recon_local: Vec<[f64; 3]> = recon.iter().map(local).collect();
        // The answers follow the index's order of the ground truth, which holds the same points.
        let mut held: Vec<[f64; 3]> = index
            .tree
            .points_local_m()
            .iter()
            .map(|p| p.map(f64::from))
            .collect();
        let mut given: Vec<[f64; 3]> = gt.iter().map(local).collect();
        for v in [&mut held, &mut given] {
            v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        }
        assert_eq!(held, given);
        for (g, di) in index.tree.points_local_m().iter().zip(&d) {
            let q = g.map(f64::from);
            let brute = recon_local
                .iter()
                .map(|r| dist(r, &q))
                .fold(f64::INFINITY, f64::min);
            assert!((*di as f64 - brute).abs() < 1e-5, "{g:?}: {di} vs {brute}");
        }
    }

    #[test]
    fn nearest_distances_brute_force() {
        // Pseudo-random points; compare the tree with brute force.
        let mut s = 12345u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) * 10.0 + 5.0e5
        };
        let gt: Vec<[f64; 3]> = (0..2000).map(|_| [rnd(), rnd(), rnd()]).collect();
        let q: Vec<[f64; 3]> = (0..300).map(|_| [rnd(), rnd(), rnd()]).collect();
        let index = GroundTruthIndex::from_points(&gt).unwrap();
        let d = index.nearest_distances_m(&q).unwrap();
        for (qi, di) in q.iter().zip(&d) {
            let brute = gt.iter().map(|g| dist(g, qi)).fold(f64::INFINITY, f64::min);
            assert!((*di as f64 - brute).abs() < 1e-6, "{di} vs {brute}");
        }
    }
}
