//! Exact nearest neighbours of queries that lie close to a point set, answered one grid cell at a
//! time.
//!
//! The points are sorted by the cubic cell (edge [`CellGrid::cell_m`]) they fall in. The queries
//! of one cell share their candidates: the points of the 3 × 3 × 3 cells around it, gathered once
//! into structure-of-arrays buffers and compared with every query of the cell in one straight
//! loop that vectorises. A query is answered when its nearest candidate is closer than the
//! gathered block's boundary: any point outside the block is at least that far, so the candidate
//! is the nearest point of the whole set. The queries left open gather the next ring of cells
//! (5³, then 7³ cells, gathered anew); those still open after [`MAX_RING`] rings (far from every point) are left
//! unanswered, for the caller's tree.
//!
//! Completeness queries (ground-truth points against a reconstruction) are mostly within a few
//! centimetres of a surface: on the 200 m drive most of them are answered here, without a tree
//! descent each (`docs/bench/e2e.md`).

use multiversion::multiversion;
use rayon::prelude::*;

/// Mean number of points per occupied cell the cell size is chosen for: about 27 × this / 3
/// candidates per query on a surface (a surface crosses about a third of the 27 cells).
const TARGET_POINTS_PER_CELL: f64 = 12.0;

/// At most this many points are counted to choose the cell size.
const SIZE_SAMPLE: usize = 1 << 21;

/// Bits per axis of a cell key.
const KEY_BITS: u32 = 21;

/// Added to a cell coordinate so that the key's field is never negative.
const KEY_OFFSET: i64 = 1 << (KEY_BITS - 1);

/// Rings of cells searched around a query's cell before it is left to the tree: ring r answers
/// queries whose nearest point is within about r cells.
const MAX_RING: i64 = 3;

/// Lanes of the candidate loop: candidates are padded to a multiple of this.
const LANES: usize = 16;

/// Marks a query answered by nothing (left to the caller).
pub(crate) const UNANSWERED: f32 = f32::NAN;

/// Occupied cells of a cell-sorted point set (12 bytes per occupied cell).
///
/// Keys hold x in their lowest bits, so the cells x − r ..= x + r of one row (fixed y, z) are
/// neighbours in key order and their points one contiguous range: a block of cells is gathered
/// as (2r + 1)² ranges, each found by one binary search.
pub(crate) struct CellGrid {
    /// Cell edge, metres.
    cell_m: f64,
    /// Keys of the occupied cells, ascending.
    keys: Vec<u64>,
    /// `starts[i]..starts[i + 1]`: the points of cell `keys[i]` in the sorted array.
    starts: Vec<u32>,
}

/// Per-task buffers of the candidates of one cell (structure of arrays, padded to [`LANES`]).
#[derive(Default)]
struct Candidates {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    /// Positions (in the cell's query list) of the queries not answered yet.
    open: Vec<usize>,
}

impl CellGrid {
    /// Chooses a cell size for `points`, sorts them by cell (in place) and indexes the occupied
    /// cells. `None` (points
    /// unchanged) when the set is empty or spans more cells than a key holds.
    pub(crate) fn build(points: &mut [[f32; 3]]) -> Option<CellGrid> {
        let cell_m = choose_cell_m(points)?;
        let inv = 1.0 / cell_m;
        // Keys computed once per point, not once per comparison (three `floor`s each).
        points.par_sort_by_cached_key(|p| key_of(cell_of(p, inv)).unwrap_or(u64::MAX));
        let (mut keys, mut starts) = (Vec::new(), Vec::new());
        for (i, p) in points.iter().enumerate() {
            let key = key_of(cell_of(p, inv))?;
            if keys.last() != Some(&key) {
                keys.push(key);
                starts.push(i as u32);
            }
        }
        starts.push(points.len() as u32);
        keys.shrink_to_fit();
        starts.shrink_to_fit();
        Some(CellGrid {
            cell_m,
            keys,
            starts,
        })
    }

    /// Cell edge, metres.
    pub(crate) fn cell_m(&self) -> f64 {
        self.cell_m
    }

    /// Distance (metres) from each of `queries` to its nearest of `points` (the array this grid
    /// was built over), in the queries' order; [`UNANSWERED`] (NaN) where the nearest point may
    /// lie more than [`MAX_RING`] cells from the query's cell. The distance is measured in `f64` from the
    /// query to the `f32` point that is nearest in `f32` arithmetic, as the tree measures it.
    pub(crate) fn nearest_distances_m(
        &self,
        points: &[[f32; 3]],
        queries: &[[f64; 3]],
    ) -> Vec<f32> {
        let inv = 1.0 / self.cell_m;
        let mut keyed: Vec<(u64, u32)> = queries
            .par_iter()
            .enumerate()
            .map(|(i, q)| (key_of(cell_of64(q, inv)).unwrap_or(u64::MAX), i as u32))
            .collect();
        keyed.par_sort_unstable();
        let mut sorted = vec![UNANSWERED; queries.len()];
        // One task per query cell, each with its slice of the output.
        let mut tasks = Vec::new();
        let mut rest: &mut [f32] = &mut sorted;
        let mut start = 0;
        while start < keyed.len() {
            let key = keyed[start].0;
            let end = start + keyed[start..].partition_point(|&(k, _)| k == key);
            let (out, tail) = rest.split_at_mut(end - start);
            rest = tail;
            tasks.push((out, &keyed[start..end]));
            start = end;
        }
        tasks
            .into_par_iter()
            .for_each_init(Candidates::default, |buf, (out, cell_queries)| {
                self.answer_cell(points, queries, cell_queries, out, buf)
            });
        let mut answered = vec![UNANSWERED; queries.len()];
        for (&(_, i), &d) in keyed.iter().zip(&sorted) {
            answered[i as usize] = d;
        }
        answered
    }

    /// Answers the queries `cell_queries` (one cell's, as `(key, index into queries)`) into `out`.
    fn answer_cell(
        &self,
        points: &[[f32; 3]],
        queries: &[[f64; 3]],
        cell_queries: &[(u64, u32)],
        out: &mut [f32],
        buf: &mut Candidates,
    ) {
        let key = cell_queries[0].0;
        if key == u64::MAX {
            return;
        }
        let cell = cell_of_key(key);
        let h = self.cell_m;
        // Room for the rounding of a point's cell and of the f32 comparison.
        let margin_m = 1e-3 * h;
        let open = &mut buf.open;
        open.clear();
        open.extend(0..cell_queries.len());
        for ring in 1..=MAX_RING {
            // Gather the block of cells within Chebyshev distance `ring`, row by row.
            buf.x.clear();
            buf.y.clear();
            buf.z.clear();
            let x_lo = (cell[0] - ring).max(-KEY_OFFSET);
            let x_hi = (cell[0] + ring).min(KEY_OFFSET - 1);
            for dz in -ring..=ring {
                for dy in -ring..=ring {
                    let (Some(lo), Some(hi)) = (
                        key_of([x_lo, cell[1] + dy, cell[2] + dz]),
                        key_of([x_hi, cell[1] + dy, cell[2] + dz]),
                    ) else {
                        continue;
                    };
                    let first = self.keys.partition_point(|&k| k < lo);
                    let mut last = first;
                    while last < self.keys.len() && self.keys[last] <= hi {
                        last += 1;
                    }
                    let range = self.starts[first] as usize..self.starts[last] as usize;
                    for p in &points[range] {
                        buf.x.push(p[0]);
                        buf.y.push(p[1]);
                        buf.z.push(p[2]);
                    }
                }
            }
            if buf.x.is_empty() {
                continue;
            }
            let padded = buf.x.len().next_multiple_of(LANES);
            for v in [&mut buf.x, &mut buf.y, &mut buf.z] {
                v.resize(padded, f32::INFINITY);
            }
            // The block spans cells cell − ring ..= cell + ring on every axis.
            let r = ring as f64;
            let lo: [f64; 3] = std::array::from_fn(|k| (cell[k] as f64 - r) * h);
            let hi: [f64; 3] = std::array::from_fn(|k| (cell[k] as f64 + r + 1.0) * h);
            open.retain(|&n| {
                let q = queries[cell_queries[n].1 as usize];
                let j = nearest_candidate(&buf.x, &buf.y, &buf.z, q.map(|v| v as f32));
                let p = [buf.x[j] as f64, buf.y[j] as f64, buf.z[j] as f64];
                let d =
                    ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt();
                let boundary_m = (0..3)
                    .map(|k| (q[k] - lo[k]).min(hi[k] - q[k]))
                    .fold(f64::INFINITY, f64::min);
                let answered = d < boundary_m - margin_m;
                if answered {
                    out[n] = d as f32;
                }
                !answered
            });
            if open.is_empty() {
                break;
            }
        }
    }
}

/// Index of the candidate nearest to `q` (squared distance in `f32`; ties go to the lowest
/// index). The slices have equal lengths, a multiple of [`LANES`], and at least one finite point.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512vl+avx2+avx+sse4.1",
    "x86_64+avx2+avx+sse4.1",
    "x86_64+sse4.1"
))]
fn nearest_candidate(x: &[f32], y: &[f32], z: &[f32], q: [f32; 3]) -> usize {
    let mut best = [f32::INFINITY; LANES];
    let mut arg = [0u32; LANES];
    for (c, ((x, y), z)) in x
        .chunks_exact(LANES)
        .zip(y.chunks_exact(LANES))
        .zip(z.chunks_exact(LANES))
        .enumerate()
    {
        for l in 0..LANES {
            let (dx, dy, dz) = (x[l] - q[0], y[l] - q[1], z[l] - q[2]);
            let d = dx * dx + dy * dy + dz * dz;
            let better = d < best[l];
            best[l] = if better { d } else { best[l] };
            arg[l] = if better {
                (c * LANES + l) as u32
            } else {
                arg[l]
            };
        }
    }
    let mut j = 0;
    for l in 1..LANES {
        if best[l] < best[j] || (best[l] == best[j] && arg[l] < arg[j]) {
            j = l;
        }
    }
    arg[j] as usize
}

/// A cell size for `points`: the mean number of points per occupied cell near
/// [`TARGET_POINTS_PER_CELL`], refined from 10 cm assuming points on surfaces (count ∝ edge²).
/// Large sets are counted on an evenly strided sample of at most [`SIZE_SAMPLE`] points (which
/// undercounts the occupied cells a little, so the size errs small); the size only sets the
/// speed, never the answers. `None` when there are no points or the set spans more cells than
/// a key holds.
fn choose_cell_m(points: &[[f32; 3]]) -> Option<f64> {
    if points.is_empty() {
        return None;
    }
    let stride = points.len().div_ceil(SIZE_SAMPLE);
    let mut cell_m = 0.1f64;
    for _ in 0..3 {
        let inv = 1.0 / cell_m;
        let mut keys: Vec<u64> = points
            .par_iter()
            .step_by(stride)
            .map(|p| key_of(cell_of(p, inv)).unwrap_or(u64::MAX))
            .collect();
        if keys.contains(&u64::MAX) {
            // Too wide for the key at this size: grow until it fits (or give up).
            cell_m *= 8.0;
            if cell_m > 1e4 {
                return None;
            }
            continue;
        }
        keys.par_sort_unstable();
        keys.dedup();
        let per_cell = points.len() as f64 / keys.len() as f64;
        let factor = (TARGET_POINTS_PER_CELL / per_cell).sqrt().clamp(0.25, 4.0);
        if (0.8..1.25).contains(&factor) {
            break;
        }
        cell_m *= factor;
    }
    // The final size must hold every point.
    let inv = 1.0 / cell_m;
    points
        .par_iter()
        .all(|p| key_of(cell_of(p, inv)).is_some())
        .then_some(cell_m)
}

/// Cell of a point (`floor(coordinate / cell)` per axis, in `f64`).
#[inline]
fn cell_of(p: &[f32; 3], inv_cell: f64) -> [i64; 3] {
    cell_of64(&p.map(f64::from), inv_cell)
}

#[inline]
fn cell_of64(p: &[f64; 3], inv_cell: f64) -> [i64; 3] {
    p.map(|v| (v * inv_cell).floor() as i64)
}

/// Key of a cell: its coordinates offset by [`KEY_OFFSET`] in [`KEY_BITS`] bits each, or `None`
/// outside the key's range.
#[inline]
fn key_of(cell: [i64; 3]) -> Option<u64> {
    let mut key = 0u64;
    for (k, &c) in cell.iter().enumerate() {
        let v = c + KEY_OFFSET;
        if !(0..1 << KEY_BITS).contains(&v) {
            return None;
        }
        key |= (v as u64) << (KEY_BITS * k as u32);
    }
    Some(key)
}

/// Inverse of [`key_of`].
#[inline]
fn cell_of_key(key: u64) -> [i64; 3] {
    std::array::from_fn(|k| {
        ((key >> (KEY_BITS * k as u32)) & ((1 << KEY_BITS) - 1)) as i64 - KEY_OFFSET
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute_force_m(points: &[[f32; 3]], q: &[f64; 3]) -> f64 {
        points
            .iter()
            .map(|p| {
                (0..3)
                    .map(|k| (q[k] - p[k] as f64).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn keys_round_trip_and_refuse_what_they_cannot_hold() {
        for cell in [[0, 0, 0], [-1, 2, -3], [KEY_OFFSET - 1, -KEY_OFFSET, 17]] {
            assert_eq!(cell_of_key(key_of(cell).unwrap()), cell);
        }
        assert_eq!(key_of([KEY_OFFSET, 0, 0]), None);
        assert_eq!(key_of([0, -KEY_OFFSET - 1, 0]), None);
    }

    #[test]
    fn answers_equal_brute_force_and_far_queries_stay_unanswered() {
        // Points on two planes (a street and a wall) plus scattered points; queries near the
        // surfaces, on cell boundaries, and far away.
        let mut rng = crate::synth::rng::Rng::new(7, 0);
        let mut r = || rng.f64();
        let mut points: Vec<[f32; 3]> = Vec::new();
        for _ in 0..6000 {
            points.push([(r() * 20.0 - 10.0) as f32, (r() * 20.0 - 10.0) as f32, 0.0]);
            points.push([(r() * 20.0 - 10.0) as f32, 3.0, (r() * 5.0) as f32]);
        }
        for _ in 0..200 {
            points.push([
                (r() * 20.0 - 10.0) as f32,
                (r() * 20.0 - 10.0) as f32,
                (r() * 5.0) as f32,
            ]);
        }
        let original = points.clone();
        let grid = CellGrid::build(&mut points).expect("a grid");
        let mut sorted_original = original.clone();
        sorted_original.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let mut sorted_points = points.clone();
        sorted_points.sort_by(|a, b| a.partial_cmp(b).unwrap());
        assert_eq!(
            sorted_points, sorted_original,
            "build only reorders the points"
        );
        let h = grid.cell_m();
        assert!(h > 0.01 && h < 5.0, "cell {h} m");
        let mut queries: Vec<[f64; 3]> = (0..3000)
            .map(|_| [r() * 20.0 - 10.0, r() * 20.0 - 10.0, r() * 2.0 - 1.0])
            .collect();
        // On cell faces and corners, and far from everything.
        queries.extend((0..200).map(|i| [(i % 7) as f64 * h, 3.0 + (i % 5) as f64 * h, 2.0 * h]));
        queries.extend((0..50).map(|i| [i as f64, 50.0, -40.0]));
        let d = grid.nearest_distances_m(&points, &queries);
        let mut answered = 0;
        for (q, &di) in queries.iter().zip(&d) {
            let brute = brute_force_m(&original, q);
            if di.is_nan() {
                let reach = MAX_RING as f64 * h;
                assert!(
                    brute > reach - 1e-3 * h,
                    "{q:?} unanswered at {brute} m, cell {h} m"
                );
            } else {
                answered += 1;
                assert!((di as f64 - brute).abs() < 1e-6, "{q:?}: {di} vs {brute}");
            }
        }
        assert!(
            answered > 2500,
            "only {answered} of {} answered",
            queries.len()
        );
        assert!(d[queries.len() - 50..].iter().all(|v| v.is_nan()));
    }

    #[test]
    fn an_empty_set_has_no_grid() {
        assert!(CellGrid::build(&mut []).is_none());
    }
}
