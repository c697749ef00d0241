//! Exact nearest-neighbour distances between two tiled point sets ([`TileSpill`]s), one query
//! tile at a time, in bounded memory.
//!
//! For a batch of queries from one tile, the target tiles are visited in ascending distance of
//! their tight boxes from the query tile's box; a target tile is opened (indexed as a
//! [`BoxTree`], kept in a cache bounded in bytes) only for the queries whose best distance so far
//! exceeds their distance to its box, and the visit stops when no unvisited box comes closer than
//! the worst best distance of the batch. Every target point that could be nearer than the answer
//! lies in a visited tile, so the answer is the exact nearest neighbour, however far it is (a
//! surface with no ground truth within kilometres visits every tile).

use super::spill::{TileKey, TileSpill};
use crate::error::Result;
use crate::eval::box_tree::BoxTree;
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Arc;

/// Queries handed to one rayon task at a time.
const QUERY_CHUNK: usize = 4096;

/// Approximate bytes of a [`BoxTree`] per point (the point, 12 bytes, and its share of nodes).
const TREE_BYTES_PER_POINT: u64 = 17;

/// Indexed target tiles, the least recently used dropped beyond a byte budget.
struct TreeCache<'a> {
    spill: &'a TileSpill,
    max_bytes: u64,
    trees: HashMap<TileKey, (Arc<BoxTree>, u64, u64)>,
    bytes: u64,
    clock: u64,
    /// Tiles read and indexed (a tile dropped and needed again counts again).
    loads: u64,
}

impl<'a> TreeCache<'a> {
    fn get(&mut self, key: TileKey) -> Result<Arc<BoxTree>> {
        self.clock += 1;
        if let Some(e) = self.trees.get_mut(&key) {
            e.2 = self.clock;
            return Ok(e.0.clone());
        }
        let tree = Arc::new(BoxTree::new(self.spill.load(&key)?)?);
        let bytes = tree.points().len() as u64 * TREE_BYTES_PER_POINT;
        while self.bytes + bytes > self.max_bytes && !self.trees.is_empty() {
            let oldest = *self
                .trees
                .iter()
                .min_by_key(|(_, e)| e.2)
                .expect("not empty")
                .0;
            let (_, b, _) = self.trees.remove(&oldest).expect("listed");
            self.bytes -= b;
        }
        self.loads += 1;
        self.bytes += bytes;
        self.trees.insert(key, (tree.clone(), bytes, self.clock));
        Ok(tree)
    }
}

/// What a pass did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct PassCounts {
    /// Queries answered.
    pub queries: u64,
    /// Target tiles read and indexed.
    pub tile_loads: u64,
}

/// Squared distance from `p` to the box `[lo, hi]` (0 inside).
fn box_distance2(p: &[f64; 3], lo: &[f64; 3], hi: &[f64; 3]) -> f64 {
    (0..3)
        .map(|a| {
            let d = (lo[a] - p[a]).max(p[a] - hi[a]).max(0.0);
            d * d
        })
        .sum()
}

/// Squared distance between two boxes (0 when they meet).
fn boxes_distance2(alo: &[f64; 3], ahi: &[f64; 3], blo: &[f64; 3], bhi: &[f64; 3]) -> f64 {
    (0..3)
        .map(|a| {
            let d = (blo[a] - ahi[a]).max(alo[a] - bhi[a]).max(0.0);
            d * d
        })
        .sum()
}

/// For every point of `queries` that `keep` accepts, the distance (metres) to the nearest point of
/// `targets` (which must not be empty), handed to `emit` with the points (world frame, metres) a
/// batch of at most `batch` queries at a time, tile by tile in the queries' tile order. Indexed
/// target tiles are kept up to `cache_bytes`.
pub(crate) fn nearest_by_tile(
    queries: &TileSpill,
    targets: &TileSpill,
    cache_bytes: u64,
    batch: usize,
    keep: impl Fn(&[f64; 3]) -> bool + Sync,
    mut emit: impl FnMut(&[[f64; 3]], &[f32]) -> Result<()>,
) -> Result<PassCounts> {
    let mut cache = TreeCache {
        spill: targets,
        max_bytes: cache_bytes,
        trees: HashMap::new(),
        bytes: 0,
        clock: 0,
        loads: 0,
    };
    let target_boxes: Vec<(TileKey, [f64; 3], [f64; 3])> =
        targets.tiles().map(|(k, t)| (*k, t.lo, t.hi)).collect();
    let mut counts = PassCounts::default();
    for key in queries.keys() {
        let info = queries.info(&key).expect("a listed tile");
        // Target tiles by distance from this tile's box, nearest first (ties by key).
        let mut order: Vec<(f64, TileKey)> = target_boxes
            .iter()
            .map(|(k, lo, hi)| (boxes_distance2(&info.lo, &info.hi, lo, hi), *k))
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let corner = queries.corner_m(key);
        let points: Vec<[f64; 3]> = queries
            .load(&key)?
            .into_iter()
            .map(|o| [0, 1, 2].map(|a| corner[a] + o[a] as f64))
            .filter(|p| keep(p))
            .collect();
        for q in points.chunks(batch.max(1)) {
            let mut best2 = vec![f64::INFINITY; q.len()];
            let mut worst = f64::INFINITY;
            for &(d2, ukey) in &order {
                if d2 >= worst {
                    break;
                }
                let u = targets.info(&ukey).expect("a listed tile");
                let open: Vec<u32> = (0..q.len() as u32)
                    .filter(|&i| best2[i as usize] > box_distance2(&q[i as usize], &u.lo, &u.hi))
                    .collect();
                if open.is_empty() {
                    continue;
                }
                let tree = cache.get(ukey)?;
                let c = targets.corner_m(ukey);
                let found: Vec<f64> = open
                    .par_chunks(QUERY_CHUNK)
                    .flat_map_iter(|idx| {
                        let mut hint = None;
                        let tree = &tree;
                        idx.iter()
                            .map(move |&i| {
                                let p = &q[i as usize];
                                let local = [0, 1, 2].map(|a| (p[a] - c[a]) as f32);
                                let n = tree.nearest(local, hint).expect("a tile has points");
                                hint = Some(n);
                                let t = tree.points()[n as usize];
                                (0..3)
                                    .map(|a| {
                                        let d = p[a] - (c[a] + t[a] as f64);
                                        d * d
                                    })
                                    .sum::<f64>()
                            })
                            .collect::<Vec<_>>()
                    })
                    .collect();
                for (&i, d2) in open.iter().zip(found) {
                    let b = &mut best2[i as usize];
                    *b = b.min(d2);
                }
                worst = best2.iter().copied().fold(0.0, f64::max);
            }
            let distances: Vec<f32> = best2.iter().map(|d2| d2.sqrt() as f32).collect();
            counts.queries += q.len() as u64;
            emit(q, &distances)?;
        }
    }
    counts.tile_loads = cache.loads;
    Ok(counts)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(targets: &[[f64; 3]], q: &[f64; 3]) -> f64 {
        targets
            .iter()
            .map(|t| (0..3).map(|a| (t[a] - q[a]).powi(2)).sum::<f64>())
            .fold(f64::INFINITY, f64::min)
            .sqrt()
    }

    #[test]
    fn tiled_distances_equal_brute_force_near_far_and_with_a_tiny_cache() {
        let dir = tempfile::tempdir().unwrap();
        let mut x = 99u64;
        let mut rnd = || {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        // Targets in two clusters 300 m apart; queries near them, between them and far away.
        let mut targets = Vec::new();
        for i in 0..4000 {
            let base = if i % 2 == 0 { 0.0 } else { 300.0 };
            targets.push([base + 20.0 * rnd(), 5.0 * rnd(), 20.0 * rnd() - 10.0]);
        }
        let mut queries = Vec::new();
        for _ in 0..2000 {
            queries.push([20.0 * rnd(), 5.0 * rnd() + 0.1, 20.0 * rnd() - 10.0]);
        }
        for _ in 0..50 {
            queries.push([150.0 + 40.0 * rnd(), 50.0 * rnd(), 1000.0 * rnd()]);
        }
        for cache in [1u64, 1 << 30] {
            let mut t = TileSpill::create(&dir.path().join("t"), 8.0, 333).unwrap();
            let mut s = TileSpill::create(&dir.path().join("q"), 8.0, 100_000).unwrap();
            targets.iter().for_each(|p| t.push(*p).unwrap());
            queries.iter().for_each(|p| s.push(*p).unwrap());
            t.finish().unwrap();
            s.finish().unwrap();
            let mut answered = 0;
            let keep = |p: &[f64; 3]| p[1] < 40.0;
            let counts = nearest_by_tile(&s, &t, cache, 97, keep, |pts, d| {
                assert!(pts.len() <= 97);
                for (p, &d) in pts.iter().zip(d) {
                    assert!(keep(p));
                    let want = brute(&targets, p);
                    assert!(
                        (d as f64 - want).abs() <= 1e-5 * want.max(1.0),
                        "{d} {want}"
                    );
                    answered += 1;
                }
                Ok(())
            })
            .unwrap();
            let kept = queries.iter().filter(|p| keep(p)).count();
            assert_eq!((answered, counts.queries), (kept, kept as u64));
            assert!(counts.tile_loads > 0);
        }
    }
}
