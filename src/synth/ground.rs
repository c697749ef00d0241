//! The ground of the synthetic city: heights on a regular grid around the streets (following
//! the route's height), two triangles per active cell.

use super::geometry::Shape;
use nalgebra::Vector3;

/// Ground heights on a regular grid around the streets, two triangles per active cell.
#[derive(Clone, Debug)]
pub(super) struct GroundGrid {
    origin: [f64; 2],
    cell_m: f64,
    dims: [usize; 2],
    /// Vertex heights (y), `(dims[0] + 1) × (dims[1] + 1)`, row-major in z.
    heights: Vec<f64>,
    /// Whether each cell carries ground.
    active: Vec<bool>,
}

impl GroundGrid {
    pub(super) fn build(streets: &[Vec<Vector3<f64>>], corridor_m: f64, cell_m: f64) -> GroundGrid {
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in streets.iter().flatten() {
            lo = [lo[0].min(p.x), lo[1].min(p.z)];
            hi = [hi[0].max(p.x), hi[1].max(p.z)];
        }
        let origin = [
            ((lo[0] - corridor_m) / cell_m).floor() * cell_m - cell_m,
            ((lo[1] - corridor_m) / cell_m).floor() * cell_m - cell_m,
        ];
        let dims = [
            ((hi[0] + corridor_m - origin[0]) / cell_m).ceil() as usize + 2,
            ((hi[1] + corridor_m - origin[1]) / cell_m).ceil() as usize + 2,
        ];
        let vw = dims[0] + 1;
        let mut best = vec![(f64::INFINITY, 0.0); vw * (dims[1] + 1)];
        let reach = (corridor_m / cell_m).ceil() as i64 + 1;
        // Each vertex takes a weighted mean of the heights of the nearby centreline points, dominated
        // by the nearest (weight 1/(d² + 0.25)²): where a route revisits a place at a slightly
        // different height (GPS drift in real trajectories) the ground splits the difference.
        let mut acc = vec![(0.0f64, 0.0f64); vw * (dims[1] + 1)];
        for pts in streets {
            for w in pts.windows(2) {
                let (a, b) = (w[0], w[1]);
                let (dx, dz) = (b.x - a.x, b.z - a.z);
                let l2 = dx * dx + dz * dz;
                let i0 = (((a.x.min(b.x) - origin[0]) / cell_m).floor() as i64 - reach).max(0);
                let i1 = (((a.x.max(b.x) - origin[0]) / cell_m).ceil() as i64 + reach)
                    .min(dims[0] as i64);
                let j0 = (((a.z.min(b.z) - origin[1]) / cell_m).floor() as i64 - reach).max(0);
                let j1 = (((a.z.max(b.z) - origin[1]) / cell_m).ceil() as i64 + reach)
                    .min(dims[1] as i64);
                for j in j0..=j1 {
                    for i in i0..=i1 {
                        let (vx, vz) =
                            (origin[0] + i as f64 * cell_m, origin[1] + j as f64 * cell_m);
                        let t = if l2 > 0.0 {
                            (((vx - a.x) * dx + (vz - a.z) * dz) / l2).clamp(0.0, 1.0)
                        } else {
                            0.0
                        };
                        let dd = (vx - a.x - t * dx).powi(2) + (vz - a.z - t * dz).powi(2);
                        let vi = j as usize * vw + i as usize;
                        let y = a.y + t * (b.y - a.y);
                        if dd < best[vi].0 {
                            best[vi] = (dd, y);
                        }
                        let wgt = 1.0 / (dd + 0.25).powi(2);
                        acc[vi].0 += wgt * y;
                        acc[vi].1 += wgt;
                    }
                }
            }
        }
        let heights: Vec<f64> = acc
            .iter()
            .zip(&best)
            .map(|(a, b)| if a.1 > 0.0 { a.0 / a.1 } else { b.1 })
            .collect();
        let c2 = corridor_m * corridor_m;
        let mut active = vec![false; dims[0] * dims[1]];
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let corners = [
                    j * vw + i,
                    j * vw + i + 1,
                    (j + 1) * vw + i,
                    (j + 1) * vw + i + 1,
                ];
                active[j * dims[0] + i] = corners.iter().any(|&c| best[c].0 <= c2)
                    && corners.iter().all(|&c| best[c].0.is_finite());
            }
        }
        GroundGrid {
            origin,
            cell_m,
            dims,
            heights,
            active,
        }
    }

    /// Ground height (y) at (x, z) on the triangulated grid, if (x, z) is on an active cell.
    pub(super) fn height_at(&self, x: f64, z: f64) -> Option<f64> {
        let fx = (x - self.origin[0]) / self.cell_m;
        let fz = (z - self.origin[1]) / self.cell_m;
        if fx < 0.0 || fz < 0.0 {
            return None;
        }
        let (i, j) = (fx.floor() as usize, fz.floor() as usize);
        if i >= self.dims[0] || j >= self.dims[1] || !self.active[j * self.dims[0] + i] {
            return None;
        }
        let (u, v) = (fx - i as f64, fz - j as f64);
        let vw = self.dims[0] + 1;
        let h = |a: usize, b: usize| self.heights[(j + b) * vw + i + a];
        Some(if u >= v {
            h(0, 0) + u * (h(1, 0) - h(0, 0)) + v * (h(1, 1) - h(1, 0))
        } else {
            h(0, 0) + v * (h(0, 1) - h(0, 0)) + u * (h(1, 1) - h(0, 1))
        })
    }

    pub(super) fn triangles(&self) -> Vec<Shape> {
        let vw = self.dims[0] + 1;
        let mut out = Vec::new();
        for j in 0..self.dims[1] {
            for i in 0..self.dims[0] {
                if !self.active[j * self.dims[0] + i] {
                    continue;
                }
                let v = |a: usize, b: usize| {
                    Vector3::new(
                        self.origin[0] + (i + a) as f64 * self.cell_m,
                        self.heights[(j + b) * vw + i + a],
                        self.origin[1] + (j + b) as f64 * self.cell_m,
                    )
                };
                // Both triangles have normals pointing up (−y).
                out.push(Shape::triangle(v(0, 0), v(1, 0), v(1, 1)));
                out.push(Shape::triangle(v(0, 0), v(1, 1), v(0, 1)));
            }
        }
        out
    }
}
