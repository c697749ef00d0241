//! A bounding volume hierarchy over primitive bounds, built with the binned surface-area
//! heuristic (Wald 2007, "On fast construction of SAH-based bounding volume hierarchies"), and
//! traversed front-to-back with an explicit stack. It only orders and prunes primitives: the
//! caller supplies the exact primitive test as a closure.

use super::geometry::{Aabb, Ray};
use nalgebra::Point3;

/// Most primitives in a leaf.
const MAX_LEAF: usize = 4;
/// SAH bins per split.
const BINS: usize = 16;

/// One node: a leaf (`count > 0`, primitives `first..first + count` of [`Bvh::order`]) or an
/// inner node (`count == 0`, children `first` and `first + 1`).
#[derive(Clone, Copy, Debug)]
struct Node {
    bounds: Aabb,
    first: u32,
    count: u32,
}

/// The hierarchy. Primitive indices refer to the slice of bounds it was built from.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    nodes: Vec<Node>,
    /// Primitive indices in leaf order.
    pub order: Vec<u32>,
}

/// Traversal stacks hold at most one entry per level (plus one), so the builder makes every node
/// at this depth a leaf, however many primitives it holds: the fixed 128-entry stacks below can
/// never overflow (a degenerate scene gets slower, never wrong).
const MAX_DEPTH: usize = 120;

impl Bvh {
    /// Builds the hierarchy over the primitives' bounds.
    pub fn build(bounds: &[Aabb]) -> Bvh {
        let mut order: Vec<u32> = (0..bounds.len() as u32).collect();
        let centroids: Vec<[f64; 3]> = bounds.iter().map(|b| b.centroid()).collect();
        let mut nodes = Vec::with_capacity(2 * bounds.len() / MAX_LEAF + 1);
        if bounds.is_empty() {
            return Bvh { nodes, order };
        }
        nodes.push(Node {
            bounds: Aabb::empty(),
            first: 0,
            count: 0,
        });
        // Work list of (node index, start, end, depth).
        let mut work = vec![(0usize, 0usize, bounds.len(), 0usize)];
        while let Some((ni, start, end, depth)) = work.pop() {
            let mut nb = Aabb::empty();
            let mut cb = Aabb::empty();
            for &i in &order[start..end] {
                nb = nb.union(&bounds[i as usize]);
                cb.grow(centroids[i as usize]);
            }
            nodes[ni].bounds = nb;
            let n = end - start;
            let split = if n <= MAX_LEAF || depth >= MAX_DEPTH {
                None
            } else {
                Self::find_split(&order[start..end], bounds, &centroids, &cb, nb.area())
            };
            let Some((axis, pos)) = split else {
                if n <= MAX_LEAF || depth >= MAX_DEPTH || !Self::can_median_split(&cb) {
                    nodes[ni].first = start as u32;
                    nodes[ni].count = n as u32;
                    continue;
                }
                // SAH declined but the leaf is too big: split at the median of the widest axis.
                let axis = Self::widest(&cb);
                order[start..end].sort_unstable_by(|&a, &b| {
                    centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
                });
                let mid = start + n / 2;
                Self::push_children(&mut nodes, &mut work, ni, (start, mid, end), depth + 1);
                continue;
            };
            let slice = &mut order[start..end];
            let mut left = 0;
            for k in 0..slice.len() {
                if centroids[slice[k] as usize][axis] < pos {
                    slice.swap(k, left);
                    left += 1;
                }
            }
            let mid = if left == 0 || left == n {
                start + n / 2
            } else {
                start + left
            };
            Self::push_children(&mut nodes, &mut work, ni, (start, mid, end), depth + 1);
        }
        Bvh { nodes, order }
    }

    fn push_children(
        nodes: &mut Vec<Node>,
        work: &mut Vec<(usize, usize, usize, usize)>,
        ni: usize,
        (start, mid, end): (usize, usize, usize),
        depth: usize,
    ) {
        let li = nodes.len();
        nodes.push(Node {
            bounds: Aabb::empty(),
            first: 0,
            count: 0,
        });
        nodes.push(Node {
            bounds: Aabb::empty(),
            first: 0,
            count: 0,
        });
        nodes[ni].first = li as u32;
        nodes[ni].count = 0;
        work.push((li, start, mid, depth));
        work.push((li + 1, mid, end, depth));
    }

    fn widest(cb: &Aabb) -> usize {
        let d = [
            cb.max[0] - cb.min[0],
            cb.max[1] - cb.min[1],
            cb.max[2] - cb.min[2],
        ];
        if d[0] >= d[1] && d[0] >= d[2] {
            0
        } else if d[1] >= d[2] {
            1
        } else {
            2
        }
    }

    fn can_median_split(cb: &Aabb) -> bool {
        (0..3).any(|k| cb.max[k] > cb.min[k])
    }

    /// Best binned-SAH split (axis, centroid threshold), or `None` when a leaf is cheaper.
    // `axis` indexes the centroid bounds and every centroid.
    #[allow(clippy::needless_range_loop)]
    fn find_split(
        idx: &[u32],
        bounds: &[Aabb],
        centroids: &[[f64; 3]],
        cb: &Aabb,
        parent_area: f64,
    ) -> Option<(usize, f64)> {
        let mut best: Option<(f64, usize, f64)> = None;
        for axis in 0..3 {
            let (lo, hi) = (cb.min[axis], cb.max[axis]);
            if hi - lo < 1e-12 {
                continue;
            }
            let scale = BINS as f64 / (hi - lo);
            let mut bins = [(Aabb::empty(), 0usize); BINS];
            for &i in idx {
                let b = (((centroids[i as usize][axis] - lo) * scale) as usize).min(BINS - 1);
                bins[b].0 = bins[b].0.union(&bounds[i as usize]);
                bins[b].1 += 1;
            }
            let mut right_area = [0.0; BINS];
            let mut right_count = [0usize; BINS];
            let (mut acc, mut cnt) = (Aabb::empty(), 0);
            for b in (1..BINS).rev() {
                acc = acc.union(&bins[b].0);
                cnt += bins[b].1;
                right_area[b] = acc.area();
                right_count[b] = cnt;
            }
            let (mut acc, mut cnt) = (Aabb::empty(), 0);
            for b in 0..BINS - 1 {
                acc = acc.union(&bins[b].0);
                cnt += bins[b].1;
                if cnt == 0 || right_count[b + 1] == 0 {
                    continue;
                }
                let cost = acc.area() * cnt as f64 + right_area[b + 1] * right_count[b + 1] as f64;
                if best.is_none_or(|(c, _, _)| cost < c) {
                    best = Some((cost, axis, lo + (b + 1) as f64 / scale));
                }
            }
        }
        let (cost, axis, pos) = best?;
        // Traversal step costs about one primitive test.
        let split_cost = 1.0 + cost / parent_area.max(1e-300);
        (split_cost < idx.len() as f64 || idx.len() > 4 * MAX_LEAF).then_some((axis, pos))
    }

    /// Nearest hit: `test(primitive, t_max)` returns the primitive's hit parameter below `t_max`.
    /// Returns `(t, primitive)` of the closest hit within `[0, t_max)`.
    #[inline]
    pub fn closest<F: FnMut(u32, f64) -> Option<f64>>(
        &self,
        ray: &Ray,
        mut t_max: f64,
        mut test: F,
    ) -> Option<(f64, u32)> {
        if self.nodes.is_empty() {
            return None;
        }
        let o = [ray.origin.x, ray.origin.y, ray.origin.z];
        let inv = [
            1.0 / ray.direction.x,
            1.0 / ray.direction.y,
            1.0 / ray.direction.z,
        ];
        let mut best = None;
        let mut stack = [0u32; 128];
        let mut sp = 0usize;
        self.nodes[0].bounds.hit(&o, &inv, t_max)?;
        let mut node = 0u32;
        loop {
            let n = &self.nodes[node as usize];
            if n.count > 0 {
                for &p in &self.order[n.first as usize..(n.first + n.count) as usize] {
                    if let Some(t) = test(p, t_max) {
                        if t < t_max {
                            t_max = t;
                            best = Some((t, p));
                        }
                    }
                }
            } else {
                let (a, b) = (n.first, n.first + 1);
                let ha = self.nodes[a as usize].bounds.hit(&o, &inv, t_max);
                let hb = self.nodes[b as usize].bounds.hit(&o, &inv, t_max);
                match (ha, hb) {
                    (Some(ta), Some(tb)) => {
                        let (near, far) = if ta <= tb { (a, b) } else { (b, a) };
                        if sp < stack.len() {
                            stack[sp] = far;
                            sp += 1;
                        }
                        node = near;
                        continue;
                    }
                    (Some(_), None) => {
                        node = a;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = b;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            // Pop, skipping nodes now beyond the best hit.
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                node = stack[sp];
                if self.nodes[node as usize]
                    .bounds
                    .hit(&o, &inv, t_max)
                    .is_some()
                {
                    break;
                }
            }
        }
    }

    /// True as soon as `test(primitive, t_max)` reports a hit for any primitive along the ray
    /// within `[0, t_max)` (shadow rays: no ordering, early exit).
    #[inline]
    pub fn any<F: FnMut(u32, f64) -> bool>(&self, ray: &Ray, t_max: f64, mut test: F) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        let o = [ray.origin.x, ray.origin.y, ray.origin.z];
        let inv = [
            1.0 / ray.direction.x,
            1.0 / ray.direction.y,
            1.0 / ray.direction.z,
        ];
        let mut stack = [0u32; 128];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let n = &self.nodes[stack[sp] as usize];
            if n.bounds.hit(&o, &inv, t_max).is_none() {
                continue;
            }
            if n.count > 0 {
                for &p in &self.order[n.first as usize..(n.first + n.count) as usize] {
                    if test(p, t_max) {
                        return true;
                    }
                }
            } else if sp + 2 <= stack.len() {
                stack[sp] = n.first + 1;
                stack[sp + 1] = n.first;
                sp += 2;
            }
        }
        false
    }

    /// Calls `visit(primitive)` for every primitive whose bounds contain `p`.
    pub fn visit_containing<F: FnMut(u32)>(&self, p: &Point3<f64>, mut visit: F) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = vec![0u32];
        while let Some(ni) = stack.pop() {
            let n = &self.nodes[ni as usize];
            if !n.bounds.contains(p) {
                continue;
            }
            if n.count > 0 {
                for &i in &self.order[n.first as usize..(n.first + n.count) as usize] {
                    visit(i);
                }
            } else {
                stack.push(n.first);
                stack.push(n.first + 1);
            }
        }
    }

    /// Calls `visit(primitive)` for every primitive whose bounds overlap `query`.
    pub fn visit_overlapping<F: FnMut(u32)>(&self, query: &Aabb, mut visit: F) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = vec![0u32];
        while let Some(ni) = stack.pop() {
            let n = &self.nodes[ni as usize];
            if (0..3).any(|k| n.bounds.min[k] > query.max[k] || n.bounds.max[k] < query.min[k]) {
                continue;
            }
            if n.count > 0 {
                for &i in &self.order[n.first as usize..(n.first + n.count) as usize] {
                    visit(i);
                }
            } else {
                stack.push(n.first);
                stack.push(n.first + 1);
            }
        }
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }
}

#[cfg(test)]
mod depth_tests {
    use super::*;

    fn depth(bvh: &Bvh, node: usize) -> usize {
        let n = &bvh.nodes[node];
        if n.count > 0 {
            1
        } else {
            1 + depth(bvh, n.first as usize).max(depth(bvh, n.first as usize + 1))
        }
    }

    #[test]
    fn degenerate_scenes_stay_within_the_stack() {
        // Boxes at exponentially growing distances invite a chain-shaped tree.
        let bounds: Vec<Aabb> = (0..2000)
            .map(|k| {
                let x = 1.02f64.powi(k);
                Aabb {
                    min: [x, 0.0, 0.0],
                    max: [x + 1e-3, 1.0, 1.0],
                }
            })
            .collect();
        let bvh = Bvh::build(&bounds);
        assert!(depth(&bvh, 0) <= MAX_DEPTH + 1, "depth {}", depth(&bvh, 0));
        // Every box is still found: the nearest along +x from the origin is box 0, and from
        // just past box k it is box k + 1.
        for k in [0usize, 500, 1000, 1200] {
            let start = if k == 0 {
                -1.0
            } else {
                1.02f64.powi(k as i32) + 2e-3
            };
            let ray = Ray::new(
                nalgebra::Point3::new(start, 0.5, 0.5),
                nalgebra::Vector3::new(1.0, 0.0, 0.0),
            );
            let inv = [1.0, f64::INFINITY, f64::INFINITY];
            let o = [start, 0.5, 0.5];
            let hit = bvh.closest(&ray, f64::INFINITY, |p, t_max| {
                bounds[p as usize].hit(&o, &inv, t_max)
            });
            let want = if k == 0 { 0 } else { k + 1 };
            assert_eq!(hit.map(|h| h.1), Some(want as u32), "from box {k}");
        }
    }
}
