//! Generation of the synthetic city and the queries on it: streets along a route (procedural or a
//! given trajectory) with side streets, ground following the route's height, kerbs, buildings
//! with facades, parked cars, trees, lamp posts and signs, all exact primitives in one BVH.
//! `City::cast` returns the exact nearest hit with its albedo; `City::sample_surface` returns
//! exact surface samples for evaluation. Rendering and LiDAR live in `render` and `lidar`.

use super::bvh::Bvh;
use super::geometry::{Aabb, Ray, Shape, SurfaceSample};
use super::ground::GroundGrid;
use super::placement::{Builder, Footprint, Occupancy};
use super::rng::{hash2, Rng};
use super::route::{self, Route, RouteParams};
use super::streets::{GroundKind, StreetNetwork};
use super::texture::{self, FacadeParams, Rgb};
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
            // Each primitive's sample points and colours.
            type Samples = (Vec<[f64; 3]>, Vec<[u8; 3]>);
            let per_prim: Vec<Samples> = prims
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
