//! Laying out the synthetic city: side streets, kerbs, buildings with facades, street furniture
//! and parked cars along the streets, kept apart by an occupancy hash. The primitives go into a
//! [`Builder`]; [`City`] (in `city.rs`) builds its BVH from them.

use super::city::{City, CityConfig, Material, Primitive};
use super::geometry::Shape;
use super::rng::Rng;
use super::streets::StreetNetwork;
use super::texture::{self, FacadeParams, Rgb, WallStyle};
use nalgebra::Vector3;
use std::collections::HashMap;

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
    pub(super) fn cover(&self, step: f64) -> Vec<[f64; 2]> {
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

/// A 2D occupancy hash of placed footprints and round obstacles, to keep objects apart.
#[derive(Default)]
pub(super) struct Occupancy {
    cells: HashMap<(i64, i64), Vec<usize>>,
    items: Vec<Occupant>,
}

#[derive(Clone, Copy)]
pub(super) enum Occupant {
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

    pub(super) fn collides(&self, o: &Occupant) -> bool {
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

    pub(super) fn insert(&mut self, o: Occupant) {
        let (lo, hi) = Self::bounds(&o);
        let idx = self.items.len();
        self.items.push(o);
        for k in Self::keys(lo, hi) {
            self.cells.entry(k).or_default().push(idx);
        }
    }
}

/// Scene builder state.
pub(super) struct Builder {
    pub(super) prims: Vec<Primitive>,
    pub(super) materials: Vec<Material>,
}

impl Builder {
    pub(super) fn material(&mut self, m: Material) -> u32 {
        self.materials.push(m);
        (self.materials.len() - 1) as u32
    }

    pub(super) fn add(&mut self, shape: Shape, material: u32) {
        self.prims.push(Primitive { shape, material });
    }
}

pub(super) const PAINTS: [Rgb; 8] = [
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
    /// Adds perpendicular side streets along the route (junctions), avoiding other streets.
    pub(super) fn with_side_streets(
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

    pub(super) fn place_kerbs(
        net: &StreetNetwork,
        gy: &dyn Fn(f64, f64) -> Option<f64>,
        b: &mut Builder,
    ) {
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
    pub(super) fn place_buildings(
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
