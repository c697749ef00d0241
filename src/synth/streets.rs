//! The street network of the synthetic city: road centrelines as polylines (world x–z, with the
//! ground height in y), a uniform grid over their segments for fast nearest-segment queries, and
//! the classification of a ground point into road (with lane coordinates), kerb, pavement or
//! verge. Does not build geometry; `city` places objects with these queries.

use nalgebra::Vector3;

/// One centreline segment.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Segment {
    /// Start point (x, ground y, z), metres.
    pub a: Vector3<f64>,
    /// End point, metres.
    pub b: Vector3<f64>,
    /// Arc length at `a` along its street, metres.
    pub s0: f64,
    /// Length in the x–z plane, metres.
    pub len: f64,
    /// Unit tangent in the x–z plane.
    pub dir: [f64; 2],
}

/// The nearest centreline point to a query.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Nearest {
    /// Segment index.
    pub seg: u32,
    /// Arc length along the street, metres.
    pub s: f64,
    /// Signed lateral offset, metres, positive to the right of the direction of travel.
    pub l: f64,
    /// Horizontal distance to the centreline, metres.
    pub dist: f64,
}

/// What the ground is at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum GroundKind {
    /// Carriageway; `junction` when another street's carriageway crosses here.
    Road { s: f64, l: f64, junction: bool },
    /// The strip under the kerb stones.
    Kerb,
    /// Pavement (sidewalk) in street coordinates.
    Pavement { s: f64, l: f64 },
    /// Grass or soil away from the streets.
    Verge,
}

/// Streets plus a grid over their segments.
#[derive(Clone, Debug)]
pub(crate) struct StreetNetwork {
    /// Centreline polylines, one per street, points (x, ground y, z).
    pub streets: Vec<Vec<Vector3<f64>>>,
    /// All segments, street by street.
    pub segments: Vec<Segment>,
    /// Street index of each segment.
    pub segment_street: Vec<u32>,
    /// Half width of the carriageway, metres.
    pub half_width_m: f64,
    /// Width of the pavement beyond the kerb, metres.
    pub pavement_m: f64,
    /// Queries find every segment within this horizontal distance, metres.
    pub reach_m: f64,
    origin: [f64; 2],
    cell_m: f64,
    dims: [usize; 2],
    cells: Vec<Vec<u32>>,
}

impl StreetNetwork {
    /// Builds the network; every query finds all segments within `reach_m`.
    pub(crate) fn new(
        streets: Vec<Vec<Vector3<f64>>>,
        half_width_m: f64,
        pavement_m: f64,
        reach_m: f64,
    ) -> Self {
        let mut segments = Vec::new();
        let mut segment_street = Vec::new();
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for (si, pts) in streets.iter().enumerate() {
            let mut s = 0.0;
            for w in pts.windows(2) {
                let (a, b) = (w[0], w[1]);
                let len = ((b.x - a.x).powi(2) + (b.z - a.z).powi(2)).sqrt();
                if len < 1e-9 {
                    continue;
                }
                segments.push(Segment {
                    a,
                    b,
                    s0: s,
                    len,
                    dir: [(b.x - a.x) / len, (b.z - a.z) / len],
                });
                segment_street.push(si as u32);
                s += len;
                for p in [a, b] {
                    lo = [lo[0].min(p.x), lo[1].min(p.z)];
                    hi = [hi[0].max(p.x), hi[1].max(p.z)];
                }
            }
        }
        let cell_m = 8.0;
        if segments.is_empty() {
            lo = [0.0; 2];
            hi = [0.0; 2];
        }
        let origin = [lo[0] - reach_m - cell_m, lo[1] - reach_m - cell_m];
        let dims = [
            (((hi[0] - origin[0] + reach_m) / cell_m).ceil() as usize + 2),
            (((hi[1] - origin[1] + reach_m) / cell_m).ceil() as usize + 2),
        ];
        let mut cells = vec![Vec::new(); dims[0] * dims[1]];
        for (i, sg) in segments.iter().enumerate() {
            let x0 = ((sg.a.x.min(sg.b.x) - reach_m - origin[0]) / cell_m)
                .floor()
                .max(0.0) as usize;
            let x1 = (((sg.a.x.max(sg.b.x) + reach_m - origin[0]) / cell_m).floor() as usize)
                .min(dims[0] - 1);
            let z0 = ((sg.a.z.min(sg.b.z) - reach_m - origin[1]) / cell_m)
                .floor()
                .max(0.0) as usize;
            let z1 = (((sg.a.z.max(sg.b.z) + reach_m - origin[1]) / cell_m).floor() as usize)
                .min(dims[1] - 1);
            for zi in z0..=z1 {
                for xi in x0..=x1 {
                    cells[zi * dims[0] + xi].push(i as u32);
                }
            }
        }
        StreetNetwork {
            streets,
            segments,
            segment_street,
            half_width_m,
            pavement_m,
            reach_m,
            origin,
            cell_m,
            dims,
            cells,
        }
    }

    /// Segments that may lie within `reach_m` of (x, z).
    #[inline]
    fn candidates(&self, x: f64, z: f64) -> &[u32] {
        let xi = ((x - self.origin[0]) / self.cell_m).floor();
        let zi = ((z - self.origin[1]) / self.cell_m).floor();
        if xi < 0.0 || zi < 0.0 || xi as usize >= self.dims[0] || zi as usize >= self.dims[1] {
            return &[];
        }
        &self.cells[zi as usize * self.dims[0] + xi as usize]
    }

    /// Projection of (x, z) on segment `i`.
    #[inline]
    fn project(&self, i: u32, x: f64, z: f64) -> Nearest {
        let sg = &self.segments[i as usize];
        let (dx, dz) = (x - sg.a.x, z - sg.a.z);
        let t = ((dx * sg.dir[0] + dz * sg.dir[1]) / sg.len).clamp(0.0, 1.0);
        let (px, pz) = (
            sg.a.x + (sg.b.x - sg.a.x) * t,
            sg.a.z + (sg.b.z - sg.a.z) * t,
        );
        let dist = ((x - px).powi(2) + (z - pz).powi(2)).sqrt();
        // Right of travel: (dir.z, −dir.x) in (x, z).
        let l = dx * sg.dir[1] - dz * sg.dir[0];
        Nearest {
            seg: i,
            s: sg.s0 + t * sg.len,
            l: if l >= 0.0 { dist } else { -dist },
            dist,
        }
    }

    /// The nearest centreline point within `reach_m`, if any.
    pub(crate) fn nearest(&self, x: f64, z: f64) -> Option<Nearest> {
        let mut best: Option<Nearest> = None;
        for &i in self.candidates(x, z) {
            let n = self.project(i, x, z);
            if n.dist <= self.reach_m && best.is_none_or(|b| n.dist < b.dist) {
                best = Some(n);
            }
        }
        best
    }

    /// Horizontal distance from (x, z) to the nearest centreline, or infinity beyond `reach_m`.
    pub(crate) fn distance(&self, x: f64, z: f64) -> f64 {
        self.nearest(x, z).map_or(f64::INFINITY, |n| n.dist)
    }

    /// What the ground is at (x, z).
    pub(crate) fn classify(&self, x: f64, z: f64) -> GroundKind {
        let Some(n) = self.nearest(x, z) else {
            return GroundKind::Verge;
        };
        let hw = self.half_width_m;
        if n.dist < hw {
            let d0 = self.segments[n.seg as usize].dir;
            let junction = self.candidates(x, z).iter().any(|&i| {
                let sg = &self.segments[i as usize];
                (sg.dir[0] * d0[0] + sg.dir[1] * d0[1]).abs() < 0.8
                    && self.project(i, x, z).dist < hw
            });
            GroundKind::Road {
                s: n.s,
                l: n.l,
                junction,
            }
        } else if n.dist < hw + 0.3 {
            GroundKind::Kerb
        } else if n.dist < hw + self.pavement_m {
            GroundKind::Pavement { s: n.s, l: n.l }
        } else {
            GroundKind::Verge
        }
    }

    /// Point (x, ground y, z) and unit tangent (x, z) at arc length `s` along street `street`.
    pub(crate) fn point_at(&self, street: usize, s: f64) -> Option<(Vector3<f64>, [f64; 2])> {
        let segs: Vec<&Segment> = self
            .segments
            .iter()
            .zip(&self.segment_street)
            .filter(|(_, &st)| st as usize == street)
            .map(|(sg, _)| sg)
            .collect();
        let last = segs.last()?;
        let sg = segs.iter().find(|sg| s <= sg.s0 + sg.len).unwrap_or(last);
        let t = ((s - sg.s0) / sg.len).clamp(0.0, 1.0);
        Some((sg.a + (sg.b - sg.a) * t, sg.dir))
    }

    /// Length of street `street`, metres.
    pub(crate) fn street_length(&self, street: usize) -> f64 {
        self.segments
            .iter()
            .zip(&self.segment_street)
            .filter(|(_, &st)| st as usize == street)
            .map(|(sg, _)| sg.len)
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn straight_street_classification() {
        let pts = vec![Vector3::new(0.0, 1.65, 0.0), Vector3::new(0.0, 1.65, 100.0)];
        let net = StreetNetwork::new(vec![pts], 5.6, 3.8, 14.0);
        // Travel is +z, so +x is to the right.
        match net.classify(2.0, 50.0) {
            GroundKind::Road { s, l, junction } => {
                assert!((s - 50.0).abs() < 1e-12 && (l - 2.0).abs() < 1e-12 && !junction)
            }
            k => panic!("{k:?}"),
        }
        assert_eq!(net.classify(-5.7, 50.0), GroundKind::Kerb);
        assert!(matches!(
            net.classify(-7.0, 50.0),
            GroundKind::Pavement { .. }
        ));
        assert_eq!(net.classify(-12.0, 50.0), GroundKind::Verge);
        assert_eq!(net.classify(40.0, 50.0), GroundKind::Verge);
        assert!((net.distance(3.0, -4.0) - 5.0).abs() < 1e-12);
        let (p, d) = net.point_at(0, 30.0).unwrap();
        assert!((p.z - 30.0).abs() < 1e-12 && d == [0.0, 1.0]);
    }

    #[test]
    fn crossing_streets_make_a_junction() {
        let a = vec![
            Vector3::new(0.0, 1.65, -50.0),
            Vector3::new(0.0, 1.65, 50.0),
        ];
        let b = vec![
            Vector3::new(-50.0, 1.65, 0.0),
            Vector3::new(50.0, 1.65, 0.0),
        ];
        let net = StreetNetwork::new(vec![a, b], 5.6, 3.8, 14.0);
        assert!(matches!(
            net.classify(1.0, 1.0),
            GroundKind::Road { junction: true, .. }
        ));
        assert!(matches!(
            net.classify(1.0, 20.0),
            GroundKind::Road {
                junction: false,
                ..
            }
        ));
    }
}
