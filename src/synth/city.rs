//! Generation of the synthetic city and the queries on it: streets along a route (procedural or a
//! given trajectory) with side streets, ground following the route's height, kerbs, buildings
//! with facades, parked cars, trees, lamp posts and signs, all exact primitives in one BVH.
//! `City::cast` returns the exact nearest hit with its albedo; `City::sample_surface` returns
//! exact surface samples for evaluation. Rendering and LiDAR live in `render` and `lidar`.

use super::bvh::Bvh;
use super::geometry::{Aabb, Ray, Shape, SurfaceSample};
use super::rng::{hash2, Rng};
use super::route::{self, Route, RouteParams};
use super::streets::{GroundKind, StreetNetwork};
use super::texture::{self, FacadeParams, Rgb, WallStyle};
use crate::error::{Error, Result};
use crate::frame::PointCloud;
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;
use std::collections::HashMap;

/// What to build and how to drive through it.
#[derive(Clone, Debug)]
pub struct CityConfig {
    /// Seed of everything random (layout, textures); the same seed gives the same bytes.
    pub seed: u64,
    /// Length of the drive, metres: of the procedural route, or how far to follow `trajectory`.
    pub length_m: f64,
    /// Camera poses (`world_from_cam0`, KITTI convention) to drive along at their real scale; the
    /// streets are laid around them. `None`: a procedural route with turns, junctions and a loop.
    pub trajectory: Option<Vec<Isometry3<f64>>>,
    /// Distance between consecutive frames, metres (KITTI at 10 Hz: about 0.8–1.0 m). With a
    /// trajectory, poses are kept at least this far apart (0 keeps them all).
    pub frame_spacing_m: f64,
    /// Keep at most this many frames.
    pub max_frames: Option<usize>,
    /// Height of cam0 above the road, metres (KITTI: 1.65).
    pub camera_height_m: f64,
    /// The car drives this far right of the road centreline (the centre of the right lane), metres.
    pub lane_offset_m: f64,
    /// Half width of the carriageway (two lanes plus parking strips), metres.
    pub road_half_width_m: f64,
    /// Pavement (sidewalk) width beyond the kerb, metres.
    pub pavement_width_m: f64,
    /// Ground is modelled up to this distance from a street centreline, metres.
    pub corridor_m: f64,
    /// Mean distance between side streets along the route, metres.
    pub side_street_spacing_m: f64,
}

impl Default for CityConfig {
    fn default() -> Self {
        CityConfig {
            seed: 0,
            length_m: 300.0,
            trajectory: None,
            frame_spacing_m: 0.9,
            max_frames: None,
            camera_height_m: 1.65,
            lane_offset_m: 1.75,
            road_half_width_m: 5.6,
            pavement_width_m: 3.8,
            corridor_m: 40.0,
            side_street_spacing_m: 90.0,
        }
    }
}

/// Surface appearance of a primitive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Material {
    /// Ground: asphalt with lane markings, paving or grass, decided by the street layout.
    Ground,
    /// Kerb stones (concrete).
    Kerb,
    /// A building: facade on the walls, roof on top.
    Facade(FacadeParams),
    /// Rough stone, roofs and cornices of the given colour.
    Stone {
        /// Base colour (linear RGB).
        colour: Rgb,
    },
    /// Car paint.
    Paint {
        /// Paint colour (linear RGB).
        colour: Rgb,
    },
    /// Car windows.
    CarGlass,
    /// Tyres.
    Tyre,
    /// Tree crown.
    Foliage {
        /// Leaf colour (linear RGB).
        colour: Rgb,
    },
    /// Tree trunk.
    Bark,
    /// Painted metal (poles, lamps).
    Metal {
        /// Colour (linear RGB).
        colour: Rgb,
    },
}

/// One primitive of the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Primitive {
    /// Exact geometry.
    pub shape: Shape,
    /// Index into [`City::materials`].
    pub material: u32,
}

/// The nearest intersection of a ray with the city.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter (in multiples of the ray's direction).
    pub t: f64,
    /// Hit point, metres (world frame).
    pub point: Point3<f64>,
    /// Outward unit normal of the surface (not flipped towards the ray).
    pub normal: Vector3<f64>,
    /// Surface albedo, linear RGB in [0, 1].
    pub albedo: Rgb,
    /// Index of the primitive hit in [`City::primitives`].
    pub primitive: u32,
}

/// A building's footprint in the x–z plane: a rectangle turned about y.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    /// Centre (x, z), metres.
    pub center: [f64; 2],
    /// Half extents along the local axes (along the street, across it), metres.
    pub half_m: [f64; 2],
    /// Unit direction (x, z) of the first local axis.
    pub axis: [f64; 2],
}

impl Footprint {
    /// Horizontal distance from (x, z) to the rectangle (0 inside), metres.
    pub fn distance(&self, x: f64, z: f64) -> f64 {
        let (dx, dz) = (x - self.center[0], z - self.center[1]);
        let u = (dx * self.axis[0] + dz * self.axis[1]).abs() - self.half_m[0];
        let v = (-dx * self.axis[1] + dz * self.axis[0]).abs() - self.half_m[1];
        (u.max(0.0).powi(2) + v.max(0.0).powi(2)).sqrt()
    }

    fn corners(&self) -> [[f64; 2]; 4] {
        let (a, b) = (self.axis, [-self.axis[1], self.axis[0]]);
        let mut out = [[0.0; 2]; 4];
        for (k, (su, sv)) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
            .into_iter()
            .enumerate()
        {
            out[k] = [
                self.center[0] + a[0] * su * self.half_m[0] + b[0] * sv * self.half_m[1],
                self.center[1] + a[1] * su * self.half_m[0] + b[1] * sv * self.half_m[1],
            ];
        }
        out
    }

    /// Separating-axis overlap test of two rectangles (touching counts as overlap).
    fn overlaps(&self, o: &Footprint) -> bool {
        let (ca, cb) = (self.corners(), o.corners());
        for ax in [
            self.axis,
            [-self.axis[1], self.axis[0]],
            o.axis,
            [-o.axis[1], o.axis[0]],
        ] {
            let proj = |c: &[[f64; 2]; 4]| {
                c.iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                        let d = p[0] * ax[0] + p[1] * ax[1];
                        (lo.min(d), hi.max(d))
                    })
            };
            let (a, b) = (proj(&ca), proj(&cb));
            if a.1 < b.0 || b.1 < a.0 {
                return false;
            }
        }
        true
    }

    /// Points covering the rectangle about `step` apart (corners and edges included).
    fn cover(&self, step: f64) -> Vec<[f64; 2]> {
        let nu = (2.0 * self.half_m[0] / step).ceil() as usize;
        let nv = (2.0 * self.half_m[1] / step).ceil() as usize;
        let mut out = Vec::with_capacity((nu + 1) * (nv + 1));
        for i in 0..=nu {
            for j in 0..=nv {
                let su = (i as f64 / nu as f64 * 2.0 - 1.0) * self.half_m[0];
                let sv = (j as f64 / nv as f64 * 2.0 - 1.0) * self.half_m[1];
                out.push([
                    self.center[0] + self.axis[0] * su - self.axis[1] * sv,
                    self.center[1] + self.axis[1] * su + self.axis[0] * sv,
                ]);
            }
        }
        out
    }
}

/// Ground heights on a regular grid around the streets, two triangles per active cell.
#[derive(Clone, Debug)]
struct GroundGrid {
    origin: [f64; 2],
    cell_m: f64,
    dims: [usize; 2],
    /// Vertex heights (y), `(dims[0] + 1) × (dims[1] + 1)`, row-major in z.
    heights: Vec<f64>,
    /// Whether each cell carries ground.
    active: Vec<bool>,
}

impl GroundGrid {
    fn build(streets: &[Vec<Vector3<f64>>], corridor_m: f64, cell_m: f64) -> GroundGrid {
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
    fn height_at(&self, x: f64, z: f64) -> Option<f64> {
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

    fn triangles(&self) -> Vec<Shape> {
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

/// A 2D occupancy hash of placed footprints and round obstacles, to keep objects apart.
#[derive(Default)]
struct Occupancy {
    cells: HashMap<(i64, i64), Vec<usize>>,
    items: Vec<Occupant>,
}

#[derive(Clone, Copy)]
enum Occupant {
    Rect(Footprint),
    Circle([f64; 2], f64),
}

impl Occupancy {
    const CELL: f64 = 24.0;

    fn bounds(o: &Occupant) -> ([f64; 2], [f64; 2]) {
        match o {
            Occupant::Rect(f) => {
                let c = f.corners();
                let lo = [
                    c.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min),
                    c.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min),
                ];
                let hi = [
                    c.iter().map(|p| p[0]).fold(f64::NEG_INFINITY, f64::max),
                    c.iter().map(|p| p[1]).fold(f64::NEG_INFINITY, f64::max),
                ];
                (lo, hi)
            }
            Occupant::Circle(c, r) => ([c[0] - r, c[1] - r], [c[0] + r, c[1] + r]),
        }
    }

    fn keys(lo: [f64; 2], hi: [f64; 2]) -> impl Iterator<Item = (i64, i64)> {
        let (i0, i1) = (
            (lo[0] / Self::CELL).floor() as i64,
            (hi[0] / Self::CELL).floor() as i64,
        );
        let (j0, j1) = (
            (lo[1] / Self::CELL).floor() as i64,
            (hi[1] / Self::CELL).floor() as i64,
        );
        (i0..=i1).flat_map(move |i| (j0..=j1).map(move |j| (i, j)))
    }

    fn collides(&self, o: &Occupant) -> bool {
        let (lo, hi) = Self::bounds(o);
        Self::keys(lo, hi).any(|k| {
            self.cells.get(&k).is_some_and(|v| {
                v.iter().any(|&i| match (o, &self.items[i]) {
                    (Occupant::Rect(a), Occupant::Rect(b)) => a.overlaps(b),
                    (Occupant::Rect(f), Occupant::Circle(c, r))
                    | (Occupant::Circle(c, r), Occupant::Rect(f)) => f.distance(c[0], c[1]) < *r,
                    (Occupant::Circle(a, ra), Occupant::Circle(b, rb)) => {
                        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt() < ra + rb
                    }
                })
            })
        })
    }

    fn insert(&mut self, o: Occupant) {
        let (lo, hi) = Self::bounds(&o);
        let idx = self.items.len();
        self.items.push(o);
        for k in Self::keys(lo, hi) {
            self.cells.entry(k).or_default().push(idx);
        }
    }
}

/// The generated city: primitives, materials, BVH, street layout and the camera poses.
#[derive(Clone, Debug)]
pub struct City {
    prims: Vec<Primitive>,
    materials: Vec<Material>,
    bvh: Bvh,
    streets: StreetNetwork,
    ground: GroundGrid,
    poses: Vec<Isometry3<f64>>,
    buildings: Vec<Footprint>,
    seed: u64,
}

/// Options of [`City::sample_surface`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceSampling {
    /// Spacing of the samples on each surface, metres.
    pub spacing_m: f64,
    /// Keep samples within this horizontal distance of a camera position, metres (`None`: all).
    pub max_distance_to_route_m: Option<f64>,
}

impl Default for SurfaceSampling {
    fn default() -> Self {
        SurfaceSampling {
            spacing_m: 0.1,
            max_distance_to_route_m: Some(30.0),
        }
    }
}

/// Scene builder state.
struct Builder {
    prims: Vec<Primitive>,
    materials: Vec<Material>,
}

impl Builder {
    fn material(&mut self, m: Material) -> u32 {
        self.materials.push(m);
        (self.materials.len() - 1) as u32
    }

    fn add(&mut self, shape: Shape, material: u32) {
        self.prims.push(Primitive { shape, material });
    }
}

const PAINTS: [Rgb; 8] = [
    [0.8, 0.8, 0.8],
    [0.45, 0.46, 0.48],
    [0.03, 0.03, 0.035],
    [0.5, 0.04, 0.03],
    [0.05, 0.12, 0.4],
    [0.06, 0.18, 0.1],
    [0.22, 0.22, 0.23],
    [0.6, 0.5, 0.3],
];

const WALLS: [Rgb; 8] = [
    [0.62, 0.55, 0.45],
    [0.7, 0.68, 0.62],
    [0.5, 0.28, 0.2],
    [0.55, 0.42, 0.32],
    [0.45, 0.47, 0.5],
    [0.72, 0.6, 0.42],
    [0.6, 0.62, 0.58],
    [0.4, 0.22, 0.16],
];

impl City {
    /// Builds the city and the camera poses for `config`.
    pub fn generate(config: &CityConfig) -> Result<City> {
        let spacing_ok = config.frame_spacing_m > 0.0
            || (config.trajectory.is_some() && config.frame_spacing_m == 0.0);
        if !(config.length_m > 0.0) || !spacing_ok {
            return Err(Error::InvalidArgument(format!(
                "length_m ({}) and frame_spacing_m ({}) must be positive (a spacing of 0 keeps every pose of a trajectory)",
                config.length_m, config.frame_spacing_m
            )));
        }
        if config.lane_offset_m.abs() + 1.0 > config.road_half_width_m
            || config.road_half_width_m < 4.0
        {
            return Err(Error::InvalidArgument(format!(
                "road_half_width_m ({}) must be at least 4 m and leave room beside the lane offset ({})",
                config.road_half_width_m, config.lane_offset_m
            )));
        }
        let params = RouteParams {
            seed: config.seed,
            length_m: config.length_m,
            frame_spacing_m: config.frame_spacing_m,
            camera_height_m: config.camera_height_m,
            lane_offset_m: config.lane_offset_m,
            max_frames: config.max_frames,
        };
        let route = match &config.trajectory {
            Some(t) => route::along_trajectory(t, &params)?,
            None => route::procedural(&params),
        };
        Ok(Self::build(config, route))
    }

    fn build(cfg: &CityConfig, route: Route) -> City {
        let hw = cfg.road_half_width_m;
        let pave = cfg.pavement_width_m;
        let mut rng = Rng::new(cfg.seed, 0xC17);
        let main = route.centreline;
        let streets = Self::with_side_streets(main, cfg, &mut rng);
        let net = StreetNetwork::new(streets, hw, pave, hw + pave + 8.0);
        let ground = GroundGrid::build(&net.streets, cfg.corridor_m, 4.0);
        let mut b = Builder {
            prims: Vec::new(),
            materials: Vec::new(),
        };
        let ground_mat = b.material(Material::Ground);
        for t in ground.triangles() {
            b.add(t, ground_mat);
        }
        let gy = |x: f64, z: f64| ground.height_at(x, z);
        let mut occ = Occupancy::default();
        let mut buildings = Vec::new();
        Self::place_kerbs(&net, &gy, &mut b);
        for street in 0..net.streets.len() {
            for side in [-1.0, 1.0] {
                Self::place_buildings(
                    &net,
                    &gy,
                    street,
                    side,
                    cfg,
                    &mut rng,
                    &mut b,
                    &mut occ,
                    &mut buildings,
                );
            }
        }
        for street in 0..net.streets.len() {
            for side in [-1.0, 1.0] {
                Self::place_street_furniture(&net, &gy, street, side, &mut rng, &mut b, &mut occ);
                Self::place_cars(&net, &gy, street, side, &mut rng, &mut b, &mut occ);
            }
        }
        let bounds: Vec<Aabb> = b.prims.iter().map(|p| p.shape.aabb()).collect();
        let bvh = Bvh::build(&bounds);
        // Store primitives in leaf order so leaves read contiguous memory.
        let prims: Vec<Primitive> = bvh.order.iter().map(|&i| b.prims[i as usize]).collect();
        let mut bvh = bvh;
        bvh.order = (0..prims.len() as u32).collect();
        tracing::debug!(
            primitives = prims.len(),
            nodes = bvh.node_count(),
            "synthetic city built"
        );
        City {
            prims,
            materials: b.materials,
            bvh,
            streets: net,
            ground,
            poses: route.poses,
            buildings,
            seed: cfg.seed,
        }
    }

    /// Adds perpendicular side streets along the route (junctions), avoiding other streets.
    fn with_side_streets(
        main: Vec<Vector3<f64>>,
        cfg: &CityConfig,
        rng: &mut Rng,
    ) -> Vec<Vec<Vector3<f64>>> {
        let hw = cfg.road_half_width_m;
        let mut streets = vec![main];
        let main_net = StreetNetwork::new(streets.clone(), hw, cfg.pavement_width_m, 60.0);
        let len = main_net.street_length(0);
        let mut s = 40.0 + rng.range(0.0, cfg.side_street_spacing_m);
        while s < len - 30.0 {
            let Some((p, d)) = main_net.point_at(0, s) else {
                break;
            };
            let sides: &[f64] = match rng.index(3) {
                0 => &[1.0],
                1 => &[-1.0],
                _ => &[1.0, -1.0],
            };
            for &side in sides {
                let length = rng.range(35.0, 60.0);
                // Right of travel is (d.z, −d.x).
                let dir = [d[1] * side, -d[0] * side];
                let pts: Vec<Vector3<f64>> = (0..=(length / 2.0) as usize)
                    .map(|k| {
                        Vector3::new(
                            p.x + dir[0] * 2.0 * k as f64,
                            p.y,
                            p.z + dir[1] * 2.0 * k as f64,
                        )
                    })
                    .collect();
                // Beyond the junction the stub must keep clear of every other street.
                let clear = pts
                    .iter()
                    .filter(|q| ((q.x - p.x).powi(2) + (q.z - p.z).powi(2)).sqrt() > 2.5 * hw)
                    .all(|q| {
                        streets.iter().all(|st| {
                            st.windows(2)
                                .all(|w| seg_dist(q.x, q.z, &w[0], &w[1]) > 3.0 * hw)
                        })
                    });
                if clear {
                    streets.push(pts);
                }
            }
            s += cfg.side_street_spacing_m * rng.range(0.6, 1.4);
        }
        streets
    }

    fn place_kerbs(net: &StreetNetwork, gy: &dyn Fn(f64, f64) -> Option<f64>, b: &mut Builder) {
        let hw = net.half_width_m;
        let mat = b.material(Material::Kerb);
        for sg in &net.segments {
            for side in [-1.0, 1.0] {
                let right = [sg.dir[1], -sg.dir[0]];
                let off = side * (hw + 0.125);
                let mid = [
                    (sg.a.x + sg.b.x) * 0.5 + right[0] * off,
                    (sg.a.z + sg.b.z) * 0.5 + right[1] * off,
                ];
                let f = Footprint {
                    center: mid,
                    half_m: [sg.len * 0.5 + 0.01, 0.125],
                    axis: sg.dir,
                };
                if f.corners()
                    .iter()
                    .any(|c| net.distance(c[0], c[1]) < hw - 0.01)
                {
                    continue;
                }
                let Some(g) = gy(mid[0], mid[1]) else {
                    continue;
                };
                // 12 cm above the road, sunk 0.3 m into the ground.
                let (top, bottom) = (g - 0.12, g + 0.3);
                b.add(
                    Shape::Box {
                        center: Vector3::new(mid[0], 0.5 * (top + bottom), mid[1]),
                        half_m: Vector3::new(f.half_m[0], 0.5 * (bottom - top), 0.125),
                        axis: sg.dir,
                    },
                    mat,
                );
            }
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn place_buildings(
        net: &StreetNetwork,
        gy: &dyn Fn(f64, f64) -> Option<f64>,
        street: usize,
        side: f64,
        cfg: &CityConfig,
        rng: &mut Rng,
        b: &mut Builder,
        occ: &mut Occupancy,
        out: &mut Vec<Footprint>,
    ) {
        let hw = net.half_width_m;
        let len = net.street_length(street);
        let mut s = rng.range(0.0, 4.0);
        while s < len {
            let width = rng.range(7.0, 22.0);
            let depth = rng.range(9.0, 16.0);
            let setback = hw
                + cfg.pavement_width_m
                + if rng.chance(0.6) {
                    0.0
                } else {
                    rng.range(0.5, 2.5)
                };
            let Some((p, d)) = net.point_at(street, s + 0.5 * width) else {
                break;
            };
            let right = [d[1] * side, -d[0] * side];
            let c = [
                p.x + right[0] * (setback + 0.5 * depth),
                p.z + right[1] * (setback + 0.5 * depth),
            ];
            let fp = Footprint {
                center: c,
                half_m: [0.5 * width, 0.5 * depth],
                axis: d,
            };
            let cover = fp.cover(2.0);
            let heights: Vec<Option<f64>> = cover.iter().map(|q| gy(q[0], q[1])).collect();
            let ok = cover
                .iter()
                .all(|q| net.distance(q[0], q[1]) >= hw + cfg.pavement_width_m - 0.5)
                && heights.iter().all(|h| h.is_some())
                && !occ.collides(&Occupant::Rect(fp));
            if !ok {
                s += 2.0;
                continue;
            }
            let (g_low, g_high) = heights
                .iter()
                .flatten()
                .fold((f64::NEG_INFINITY, f64::INFINITY), |(lo, hi), &h| {
                    (lo.max(h), hi.min(h))
                });
            let tall = rng.chance(0.15);
            let height = if tall {
                rng.range(20.0, 34.0)
            } else {
                rng.range(6.0, 18.0)
            };
            let style = match rng.index(10) {
                0..=3 => WallStyle::Plaster,
                4..=6 => WallStyle::Brick,
                _ => WallStyle::Panel,
            };
            let wall = WALLS[rng.index(WALLS.len())];
            let floor_h = rng.range(2.9, 3.6);
            let bay = rng.range(2.4, 3.8);
            let params = FacadeParams {
                wall,
                style,
                floor_height_m: floor_h,
                bay_width_m: bay,
                window_width_m: rng.range(0.9, (bay - 0.8).max(1.0)),
                window_height_m: rng.range(1.3, 1.9),
                ground_y_m: g_high,
                side_windows: rng.chance(0.3),
                shop: rng.chance(0.4),
                seed: rng.next_u64(),
            };
            let mat = b.material(Material::Facade(params));
            let top = g_high - height;
            let bottom = g_low + 1.0;
            b.add(
                Shape::Box {
                    center: Vector3::new(c[0], 0.5 * (top + bottom), c[1]),
                    half_m: Vector3::new(0.5 * width, 0.5 * (bottom - top), 0.5 * depth),
                    axis: d,
                },
                mat,
            );
            if rng.chance(0.5) {
                // A cornice slab around the roof line.
                let stone = b.material(Material::Stone {
                    colour: texture::scale(wall, 0.8),
                });
                b.add(
                    Shape::Box {
                        center: Vector3::new(c[0], top + 0.2, c[1]),
                        half_m: Vector3::new(0.5 * width + 0.25, 0.2, 0.5 * depth + 0.25),
                        axis: d,
                    },
                    stone,
                );
            }
            if rng.chance(0.25) && height > 8.0 {
                // A set-back upper storey.
                let h2 = rng.range(2.8, 3.5);
                let upper = Material::Facade(FacadeParams {
                    ground_y_m: top,
                    shop: false,
                    ..params
                });
                let um = b.material(upper);
                let inner = [c[0] + right[0] * 1.5, c[1] + right[1] * 1.5];
                b.add(
                    Shape::Box {
                        center: Vector3::new(inner[0], top - 0.5 * h2, inner[1]),
                        half_m: Vector3::new(0.5 * width - 1.0, 0.5 * h2, 0.5 * depth - 1.5),
                        axis: d,
                    },
                    um,
                );
            }
            occ.insert(Occupant::Rect(Footprint {
                half_m: [fp.half_m[0] + 0.3, fp.half_m[1] + 0.3],
                ..fp
            }));
            out.push(fp);
            s += width
                + if rng.chance(0.25) {
                    rng.range(2.0, 8.0)
                } else {
                    0.0
                };
        }
    }

    fn place_street_furniture(
        net: &StreetNetwork,
        gy: &dyn Fn(f64, f64) -> Option<f64>,
        street: usize,
        side: f64,
        rng: &mut Rng,
        b: &mut Builder,
        occ: &mut Occupancy,
    ) {
        let hw = net.half_width_m;
        let len = net.street_length(street);
        let bark = b.material(Material::Bark);
        let pole = b.material(Material::Metal {
            colour: [0.22, 0.23, 0.22],
        });
        let lamp = b.material(Material::Metal {
            colour: [0.75, 0.74, 0.68],
        });
        // Trees.
        let mut s = rng.range(2.0, 12.0);
        while s < len {
            let step = rng.range(9.0, 20.0);
            let Some((p, d)) = net.point_at(street, s) else {
                break;
            };
            s += step;
            if !rng.chance(0.7) {
                continue;
            }
            let l = hw + net.pavement_m * rng.range(0.55, 0.75);
            let right = [d[1] * side, -d[0] * side];
            let c = [p.x + right[0] * l, p.z + right[1] * l];
            let crown_r = rng.range(1.6, 2.6);
            if net.distance(c[0], c[1]) < hw + 1.0
                || occ.collides(&Occupant::Circle(c, 0.6))
                || occ.collides(&Occupant::Circle(c, crown_r))
            {
                continue;
            }
            let Some(g) = gy(c[0], c[1]) else { continue };
            let trunk_h = rng.range(2.3, 3.6);
            b.add(
                Shape::Cylinder {
                    center_xz: c,
                    y_min: g - trunk_h - 0.5,
                    y_max: g + 0.2,
                    radius_m: rng.range(0.12, 0.2),
                },
                bark,
            );
            let colour = [
                rng.range(0.05, 0.1) as f32,
                rng.range(0.14, 0.22) as f32,
                rng.range(0.03, 0.07) as f32,
            ];
            let leaves = b.material(Material::Foliage { colour });
            let centre = Vector3::new(c[0], g - trunk_h - 0.7 * crown_r, c[1]);
            for _ in 0..rng.index(5) + 5 {
                let off = Vector3::new(
                    rng.range(-1.0, 1.0),
                    rng.range(-0.8, 0.6),
                    rng.range(-1.0, 1.0),
                ) * (0.55 * crown_r);
                let r = crown_r * rng.range(0.45, 0.75);
                let radii = Vector3::new(
                    r * rng.range(0.8, 1.2),
                    r * rng.range(0.7, 1.0),
                    r * rng.range(0.8, 1.2),
                );
                b.add(
                    Shape::Ellipsoid {
                        center: centre + off,
                        radii_m: radii,
                    },
                    leaves,
                );
            }
            occ.insert(Occupant::Circle(c, 0.6));
        }
        // Lamp posts, with an arm over the road.
        let mut s = rng.range(5.0, 25.0);
        while s < len {
            let Some((p, d)) = net.point_at(street, s) else {
                break;
            };
            s += rng.range(22.0, 34.0);
            let right = [d[1] * side, -d[0] * side];
            let l = hw + 0.5;
            let c = [p.x + right[0] * l, p.z + right[1] * l];
            if net.distance(c[0], c[1]) < hw + 0.3 || occ.collides(&Occupant::Circle(c, 0.5)) {
                continue;
            }
            let Some(g) = gy(c[0], c[1]) else { continue };
            let h = rng.range(6.0, 7.5);
            b.add(
                Shape::Cylinder {
                    center_xz: c,
                    y_min: g - h,
                    y_max: g + 0.2,
                    radius_m: 0.075,
                },
                pole,
            );
            let arm = 1.4;
            let ac = [c[0] - right[0] * 0.5 * arm, c[1] - right[1] * 0.5 * arm];
            b.add(
                Shape::Box {
                    center: Vector3::new(ac[0], g - h + 0.15, ac[1]),
                    half_m: Vector3::new(0.04, 0.04, 0.5 * arm),
                    axis: d,
                },
                pole,
            );
            let lc = [c[0] - right[0] * arm, c[1] - right[1] * arm];
            b.add(
                Shape::Box {
                    center: Vector3::new(lc[0], g - h + 0.22, lc[1]),
                    half_m: Vector3::new(0.15, 0.08, 0.28),
                    axis: d,
                },
                lamp,
            );
            occ.insert(Occupant::Circle(c, 0.5));
        }
        // Traffic signs on thin poles.
        let mut s = rng.range(10.0, 60.0);
        while s < len {
            let Some((p, d)) = net.point_at(street, s) else {
                break;
            };
            s += rng.range(30.0, 80.0);
            let right = [d[1] * side, -d[0] * side];
            let l = hw + 0.4;
            let c = [p.x + right[0] * l, p.z + right[1] * l];
            if net.distance(c[0], c[1]) < hw + 0.3 || occ.collides(&Occupant::Circle(c, 0.4)) {
                continue;
            }
            let Some(g) = gy(c[0], c[1]) else { continue };
            b.add(
                Shape::Cylinder {
                    center_xz: c,
                    y_min: g - 2.8,
                    y_max: g + 0.2,
                    radius_m: 0.035,
                },
                pole,
            );
            let colours: [Rgb; 3] = [[0.6, 0.04, 0.03], [0.04, 0.12, 0.5], [0.8, 0.8, 0.75]];
            let sign = b.material(Material::Metal {
                colour: colours[rng.index(3)],
            });
            // The plate faces along the street.
            b.add(
                Shape::Box {
                    center: Vector3::new(c[0] + d[0] * 0.05, g - 2.5, c[1] + d[1] * 0.05),
                    half_m: Vector3::new(0.015, 0.3, 0.3),
                    axis: d,
                },
                sign,
            );
            occ.insert(Occupant::Circle(c, 0.4));
        }
    }

    fn place_cars(
        net: &StreetNetwork,
        gy: &dyn Fn(f64, f64) -> Option<f64>,
        street: usize,
        side: f64,
        rng: &mut Rng,
        b: &mut Builder,
        occ: &mut Occupancy,
    ) {
        let hw = net.half_width_m;
        let len = net.street_length(street);
        let tyre = b.material(Material::Tyre);
        let glass = b.material(Material::CarGlass);
        let mut s = rng.range(3.0, 10.0);
        while s < len - 3.0 {
            let length = rng.range(3.8, 4.8);
            let width = rng.range(1.7, 1.9);
            let Some((p, d)) = net.point_at(street, s + 0.5 * length) else {
                break;
            };
            let gap = rng.range(0.8, 2.5);
            if !rng.chance(0.55) {
                s += length + gap;
                continue;
            }
            let right = [d[1] * side, -d[0] * side];
            let l = hw - 0.25 - 0.5 * width;
            let c = [p.x + right[0] * l, p.z + right[1] * l];
            let fp = Footprint {
                center: c,
                half_m: [0.5 * length, 0.5 * width],
                axis: d,
            };
            let clear = fp
                .cover(0.8)
                .iter()
                .all(|q| net.distance(q[0], q[1]) >= 3.6)
                && !occ.collides(&Occupant::Rect(fp));
            let Some(g) = gy(c[0], c[1]) else { break };
            if !clear {
                s += 2.0;
                continue;
            }
            let paint = b.material(Material::Paint {
                colour: PAINTS[rng.index(PAINTS.len())],
            });
            let (hl, hwid) = (0.5 * length, 0.5 * width);
            let ax = [d[0], d[1]];
            let at = |u: f64, v: f64, y: f64| {
                Vector3::new(
                    c[0] + ax[0] * u - ax[1] * v,
                    y,
                    c[1] + ax[1] * u + ax[0] * v,
                )
            };
            // Wheels, body, cabin (shifted towards the rear), bumpers.
            for (u, v) in [(-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)] {
                b.add(
                    Shape::Box {
                        center: at(u * (hl - 0.75), v * (hwid - 0.12), g - 0.32),
                        half_m: Vector3::new(0.32, 0.32, 0.11),
                        axis: ax,
                    },
                    tyre,
                );
            }
            b.add(
                Shape::Box {
                    center: at(0.0, 0.0, g - 0.66),
                    half_m: Vector3::new(hl, 0.34, hwid),
                    axis: ax,
                },
                paint,
            );
            let rear = side * rng.range(0.1, 0.4);
            b.add(
                Shape::Box {
                    center: at(-rear, 0.0, g - 1.0 - 0.24),
                    half_m: Vector3::new(hl * 0.52, 0.24, hwid - 0.1),
                    axis: ax,
                },
                glass,
            );
            b.add(
                Shape::Box {
                    center: at(-rear, 0.0, g - 1.48 - 0.02),
                    half_m: Vector3::new(hl * 0.48, 0.03, hwid - 0.14),
                    axis: ax,
                },
                paint,
            );
            occ.insert(Occupant::Rect(fp));
            s += length + gap;
        }
    }

    /// Camera poses of the drive (`world_from_cam0`), in driving order.
    pub fn frame_poses(&self) -> &[Isometry3<f64>] {
        &self.poses
    }

    /// All primitives (leaf order of the BVH; a [`Hit::primitive`] indexes this slice).
    pub fn primitives(&self) -> &[Primitive] {
        &self.prims
    }

    /// All materials ([`Primitive::material`] indexes this slice).
    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    /// Footprints of the buildings.
    pub fn building_footprints(&self) -> &[Footprint] {
        &self.buildings
    }

    /// The seed the city was built from.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Ground height (y, metres; y points down) at (x, z), where the city has ground.
    pub fn ground_height(&self, x: f64, z: f64) -> Option<f64> {
        self.ground.height_at(x, z)
    }

    /// Nearest hit along `ray` with `t ∈ (0, ∞)`, with its albedo; `None` for sky.
    pub fn cast(&self, ray: &Ray) -> Option<Hit> {
        self.cast_within(ray, f64::INFINITY)
    }

    /// Nearest hit with `t < t_max`.
    pub fn cast_within(&self, ray: &Ray, t_max: f64) -> Option<Hit> {
        let mut normal = Vector3::zeros();
        let (t, prim) = self.bvh.closest(ray, t_max, |i, tm| {
            let (t, n) = self.prims[i as usize].shape.intersect(ray, 1e-9, tm)?;
            normal = n;
            Some(t)
        })?;
        // `normal` belongs to the last accepted (closest) hit.
        let point = ray.at(t);
        Some(Hit {
            t,
            point,
            normal,
            albedo: self.albedo_at(prim, &point, &normal),
            primitive: prim,
        })
    }

    /// Nearest hit by testing every primitive (no BVH): the oracle for tests.
    pub fn cast_brute_force(&self, ray: &Ray) -> Option<Hit> {
        let mut best: Option<(f64, Vector3<f64>, u32)> = None;
        for (i, p) in self.prims.iter().enumerate() {
            if let Some((t, n)) = p
                .shape
                .intersect(ray, 1e-9, best.map_or(f64::INFINITY, |b| b.0))
            {
                best = Some((t, n, i as u32));
            }
        }
        best.map(|(t, n, i)| {
            let point = ray.at(t);
            Hit {
                t,
                point,
                normal: n,
                albedo: self.albedo_at(i, &point, &n),
                primitive: i,
            }
        })
    }

    /// True when anything blocks `ray` for `t ∈ (0, t_max)`.
    pub fn occluded(&self, ray: &Ray, t_max: f64) -> bool {
        self.bvh.any(ray, t_max, |i, tm| {
            self.prims[i as usize]
                .shape
                .intersect(ray, 1e-9, tm)
                .is_some()
        })
    }

    /// Distance from `p` to the nearest primitive surface within `search_m`, metres (infinity
    /// when none is that close). See [`Shape::distance_to_surface`] for its exactness.
    pub fn distance_to_surface(&self, p: &Point3<f64>, search_m: f64) -> f64 {
        let q = Aabb {
            min: [p.x - search_m, p.y - search_m, p.z - search_m],
            max: [p.x + search_m, p.y + search_m, p.z + search_m],
        };
        let mut best = f64::INFINITY;
        self.bvh.visit_overlapping(&q, |i| {
            best = best.min(self.prims[i as usize].shape.distance_to_surface(p))
        });
        best
    }

    /// True when `p` is strictly inside a solid primitive by more than `margin_m`.
    pub fn inside_solid(&self, p: &Point3<f64>, margin_m: f64) -> bool {
        let mut inside = false;
        self.bvh.visit_containing(p, |i| {
            inside |= self.prims[i as usize].shape.contains(p, margin_m)
        });
        inside
    }

    /// Albedo (linear RGB) of primitive `prim` at surface point `p` with outward normal `n`.
    pub fn albedo_at(&self, prim: u32, p: &Point3<f64>, n: &Vector3<f64>) -> Rgb {
        let pr = &self.prims[prim as usize];
        let w = [p.x, p.y, p.z];
        let seed = self.seed;
        match self.materials[pr.material as usize] {
            Material::Ground => self.ground_albedo(w),
            Material::Kerb => texture::rough(w, [0.42, 0.41, 0.39], 5.0, 0.2, seed ^ 61),
            Material::Facade(f) => {
                if n.y < -0.5 {
                    return texture::rough(w, [0.16, 0.15, 0.15], 2.0, 0.3, seed ^ 62);
                }
                let Shape::Box {
                    center,
                    half_m,
                    axis,
                } = pr.shape
                else {
                    return f.wall;
                };
                let q = Shape::box_local(&center, axis, &p.coords);
                let h = f.ground_y_m - p.y;
                // Faces with a local-z normal run along the street (windows); local-x faces are the sides.
                if (q.z.abs() - half_m.z).abs() < (q.x.abs() - half_m.x).abs() {
                    let u = if q.z > 0.0 {
                        q.x + half_m.x
                    } else {
                        half_m.x - q.x
                    };
                    texture::facade(&f, u, 2.0 * half_m.x, h, true, (q.z > 0.0) as u64, w)
                } else {
                    let u = if q.x > 0.0 {
                        half_m.z - q.z
                    } else {
                        q.z + half_m.z
                    };
                    texture::facade(
                        &f,
                        u,
                        2.0 * half_m.z,
                        h,
                        f.side_windows,
                        2 + (q.x > 0.0) as u64,
                        w,
                    )
                }
            }
            Material::Stone { colour } => texture::rough(w, colour, 3.0, 0.25, seed ^ 63),
            Material::Paint { colour } => {
                // A darker band at the sills and a faint sheen gradient.
                texture::scale(colour, 0.9 + 0.1 * (-n.y).max(0.0))
            }
            Material::CarGlass => {
                let Shape::Box {
                    center,
                    half_m,
                    axis,
                } = pr.shape
                else {
                    return [0.05; 3];
                };
                let q = Shape::box_local(&center, axis, &p.coords);
                // Pillars at the ends and the middle of the glasshouse.
                let pillar = (q.x.abs() > half_m.x - 0.12) || q.x.abs() < 0.06 || n.y < -0.5;
                if pillar {
                    [0.08, 0.08, 0.09]
                } else {
                    texture::mix(
                        [0.03, 0.04, 0.05],
                        [0.2, 0.23, 0.27],
                        (half_m.y - q.y) / (2.0 * half_m.y),
                    )
                }
            }
            Material::Tyre => [0.03, 0.03, 0.03],
            Material::Foliage { colour } => {
                texture::foliage(w, colour, seed ^ 64 ^ pr.material as u64)
            }
            Material::Bark => texture::rough(w, [0.16, 0.12, 0.09], 6.0, 0.35, seed ^ 65),
            Material::Metal { colour } => colour,
        }
    }

    fn ground_albedo(&self, w: [f64; 3]) -> Rgb {
        let seed = self.seed;
        match self.streets.classify(w[0], w[2]) {
            GroundKind::Road { s, l, junction } => {
                let base = texture::asphalt(w, seed);
                if junction {
                    return base;
                }
                let dash = s.rem_euclid(9.0) < 3.0;
                let centre = l.abs() < 0.06 && dash;
                let edge = (l.abs() - 3.5).abs() < 0.07;
                if centre || edge {
                    let wear = texture::value_noise3([w[0] * 3.0, 0.0, w[2] * 3.0], seed ^ 71);
                    texture::mix(base, [0.7, 0.7, 0.68], 0.6 + 0.4 * wear)
                } else {
                    base
                }
            }
            GroundKind::Kerb => [0.4, 0.4, 0.38],
            GroundKind::Pavement { s, l } => texture::paving(s, l, w, seed),
            GroundKind::Verge => texture::verge(w, seed),
        }
    }

    /// Dense exact samples of the city's surfaces (metres, world frame) with their albedo as
    /// sRGB colour: every primitive sampled at `spacing_m`, minus samples under the ground,
    /// inside another solid, or farther than `max_distance_to_route_m` from every camera.
    /// Sorted by primitive, then by position on it.
    pub fn sample_surface(&self, opts: &SurfaceSampling) -> PointCloud {
        let mut cloud = PointCloud {
            points_m: Vec::new(),
            colors: Some(Vec::new()),
        };
        self.sample_surface_chunks(opts, 4096, |pts, cols| {
            cloud.points_m.extend_from_slice(pts);
            if let Some(c) = cloud.colors.as_mut() {
                c.extend_from_slice(cols);
            }
            Ok(())
        })
        .unwrap_or(());
        cloud
    }

    /// Streams the samples of [`City::sample_surface`] to `sink` in chunks of about
    /// `prims_per_chunk` primitives (bounded memory), in the same order.
    pub fn sample_surface_chunks<F>(
        &self,
        opts: &SurfaceSampling,
        prims_per_chunk: usize,
        mut sink: F,
    ) -> Result<()>
    where
        F: FnMut(&[[f64; 3]], &[[u8; 3]]) -> Result<()>,
    {
        let near = RouteIndex::new(&self.poses, opts.max_distance_to_route_m);
        for chunk in self
            .prims
            .chunks(prims_per_chunk.max(1))
            .enumerate()
            .collect::<Vec<_>>()
        {
            let (ci, prims) = chunk;
            let base = ci * prims_per_chunk.max(1);
            let per_prim: Vec<(Vec<[f64; 3]>, Vec<[u8; 3]>)> = prims
                .par_iter()
                .enumerate()
                .map(|(k, pr)| {
                    let id = (base + k) as u32;
                    let mut samples: Vec<SurfaceSample> = Vec::new();
                    pr.shape.sample_surface(opts.spacing_m, &mut samples);
                    let is_ground =
                        matches!(self.materials[pr.material as usize], Material::Ground);
                    let mut pts = Vec::new();
                    let mut cols = Vec::new();
                    for (p, n) in samples {
                        if !near.contains(p.x, p.z) {
                            continue;
                        }
                        if !is_ground
                            && self
                                .ground
                                .height_at(p.x, p.z)
                                .is_some_and(|g| p.y > g + 1e-6)
                        {
                            continue;
                        }
                        if self.inside_solid(&p, 1e-6) {
                            continue;
                        }
                        pts.push([p.x, p.y, p.z]);
                        cols.push(super::render::albedo_to_srgb(self.albedo_at(id, &p, &n)));
                    }
                    (pts, cols)
                })
                .collect();
            let (mut pts, mut cols) = (Vec::new(), Vec::new());
            for (p, c) in per_prim {
                pts.extend(p);
                cols.extend(c);
            }
            sink(&pts, &cols)?;
        }
        Ok(())
    }

    /// Deterministic per-frame noise seed for frame `index`.
    pub fn frame_seed(&self, index: usize) -> u64 {
        hash2(self.seed, index as u64 ^ 0xF4A3E)
    }
}

/// Horizontal distance from (x, z) to segment a–b.
fn seg_dist(x: f64, z: f64, a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let (dx, dz) = (b.x - a.x, b.z - a.z);
    let l2 = dx * dx + dz * dz;
    let t = if l2 > 0.0 {
        (((x - a.x) * dx + (z - a.z) * dz) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    ((x - a.x - t * dx).powi(2) + (z - a.z - t * dz).powi(2)).sqrt()
}

/// "Is (x, z) within `d` of a camera?" on a hash grid of camera positions.
struct RouteIndex {
    d: Option<f64>,
    cells: HashMap<(i64, i64), Vec<[f64; 2]>>,
}

impl RouteIndex {
    fn new(poses: &[Isometry3<f64>], d: Option<f64>) -> Self {
        let mut cells: HashMap<(i64, i64), Vec<[f64; 2]>> = HashMap::new();
        if let Some(d) = d {
            for p in poses {
                let t = p.translation.vector;
                cells
                    .entry(((t.x / d).floor() as i64, (t.z / d).floor() as i64))
                    .or_default()
                    .push([t.x, t.z]);
            }
        }
        RouteIndex { d, cells }
    }

    fn contains(&self, x: f64, z: f64) -> bool {
        let Some(d) = self.d else { return true };
        let (i, j) = ((x / d).floor() as i64, (z / d).floor() as i64);
        (i - 1..=i + 1).any(|a| {
            (j - 1..=j + 1).any(|b| {
                self.cells.get(&(a, b)).is_some_and(|v| {
                    v.iter()
                        .any(|c| (c[0] - x).powi(2) + (c[1] - z).powi(2) <= d * d)
                })
            })
        })
    }
}
