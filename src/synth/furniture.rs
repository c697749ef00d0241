//! Street furniture and parked cars of the synthetic city: trees, lamp posts and signs along
//! the pavements, cars along the kerbs, each kept clear of what is already placed.

use super::city::{City, Material};
use super::geometry::Shape;
use super::placement::{Builder, Footprint, Occupancy, Occupant, PAINTS};
use super::rng::Rng;
use super::streets::StreetNetwork;
use super::texture::Rgb;
use nalgebra::Vector3;

impl City {
    pub(super) fn place_street_furniture(
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

    pub(super) fn place_cars(
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
}
