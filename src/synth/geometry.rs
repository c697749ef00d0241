//! Exact primitives of the synthetic city: rays, axis-aligned bounds, and the shapes the city is
//! built from (triangles, boxes turned about the vertical axis, axis-aligned ellipsoids and
//! vertical cylinders), each with ray intersection, distance to its surface, an inside test and a
//! regular surface sampling. Does not know about materials or the acceleration structure.
//!
//! World frame: KITTI's (cam0 of frame 0): x right, y down, z forward. "Vertical" is the y axis.

use nalgebra::{Point3, Vector3};

/// A ray `origin + t·direction`, `t ≥ 0`. The direction need not be unit length: `t` is measured in
/// multiples of it (a camera ray with direction `(x, y, 1)` in the camera frame has `t` = depth).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Start point, metres (world frame).
    pub origin: Point3<f64>,
    /// Direction (world frame), any non-zero length.
    pub direction: Vector3<f64>,
}

impl Ray {
    /// A ray from `origin` along `direction`.
    pub fn new(origin: Point3<f64>, direction: Vector3<f64>) -> Self {
        Ray { origin, direction }
    }

    /// The point at parameter `t`.
    #[inline]
    pub fn at(&self, t: f64) -> Point3<f64> {
        self.origin + self.direction * t
    }
}

/// An axis-aligned bounding box, metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Minimum corner.
    pub min: [f64; 3],
    /// Maximum corner.
    pub max: [f64; 3],
}

impl Aabb {
    /// The empty box (union identity).
    pub fn empty() -> Self {
        Aabb {
            min: [f64::INFINITY; 3],
            max: [f64::NEG_INFINITY; 3],
        }
    }

    /// Grows the box to contain `p`.
    pub fn grow(&mut self, p: [f64; 3]) {
        for ((lo, hi), v) in self.min.iter_mut().zip(&mut self.max).zip(p) {
            *lo = lo.min(v);
            *hi = hi.max(v);
        }
    }

    /// Union of two boxes.
    pub fn union(&self, o: &Aabb) -> Aabb {
        let mut r = *self;
        r.grow(o.min);
        r.grow(o.max);
        r
    }

    /// Centre of the box.
    pub fn centroid(&self) -> [f64; 3] {
        [
            0.5 * (self.min[0] + self.max[0]),
            0.5 * (self.min[1] + self.max[1]),
            0.5 * (self.min[2] + self.max[2]),
        ]
    }

    /// Surface area, m² (0 for the empty box).
    pub fn area(&self) -> f64 {
        let d = [
            self.max[0] - self.min[0],
            self.max[1] - self.min[1],
            self.max[2] - self.min[2],
        ];
        if d[0] < 0.0 || d[1] < 0.0 || d[2] < 0.0 {
            return 0.0;
        }
        2.0 * (d[0] * d[1] + d[1] * d[2] + d[2] * d[0])
    }

    /// True when `p` lies inside or on the box.
    #[inline]
    pub fn contains(&self, p: &Point3<f64>) -> bool {
        (0..3).all(|k| p[k] >= self.min[k] && p[k] <= self.max[k])
    }

    /// Entry parameter of the ray (given `1/direction`) if it meets the box within `[0, t_max]`.
    #[inline]
    pub fn hit(&self, origin: &[f64; 3], inv_dir: &[f64; 3], t_max: f64) -> Option<f64> {
        let mut t0 = 0.0f64;
        let mut t1 = t_max;
        for k in 0..3 {
            let a = (self.min[k] - origin[k]) * inv_dir[k];
            let b = (self.max[k] - origin[k]) * inv_dir[k];
            let (lo, hi) = if a < b { (a, b) } else { (b, a) };
            // NaN (0·∞) leaves the bounds unchanged, as wanted for rays in a slab's plane.
            if lo > t0 {
                t0 = lo;
            }
            if hi < t1 {
                t1 = hi;
            }
        }
        if t0 <= t1 {
            Some(t0)
        } else {
            None
        }
    }
}

/// One exact geometric primitive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// Triangle `v0, v0 + e1, v0 + e2`; its normal is `normalize(e1 × e2)`.
    Triangle {
        /// First vertex, metres.
        v0: Vector3<f64>,
        /// Second vertex minus the first, metres.
        e1: Vector3<f64>,
        /// Third vertex minus the first, metres.
        e2: Vector3<f64>,
    },
    /// A box turned about the vertical (y) axis: local x axis = `(axis[0], 0, axis[1])`, local y =
    /// world y, local z = local x × y = `(-axis[1], 0, axis[0])`.
    Box {
        /// Centre, metres.
        center: Vector3<f64>,
        /// Half extents along the local axes, metres.
        half_m: Vector3<f64>,
        /// Unit direction of the local x axis in the world x–z plane.
        axis: [f64; 2],
    },
    /// An axis-aligned ellipsoid (a sphere when the radii are equal).
    Ellipsoid {
        /// Centre, metres.
        center: Vector3<f64>,
        /// Semi-axes along world x, y, z, metres.
        radii_m: Vector3<f64>,
    },
    /// A solid vertical cylinder with caps: centre line `x = center_xz[0], z = center_xz[1]`,
    /// `y ∈ [y_min, y_max]`.
    Cylinder {
        /// Axis position in the x–z plane, metres.
        center_xz: [f64; 2],
        /// Smallest y (the top, since y points down), metres.
        y_min: f64,
        /// Largest y (the bottom), metres.
        y_max: f64,
        /// Radius, metres.
        radius_m: f64,
    },
}

/// A surface point with its outward unit normal.
pub type SurfaceSample = (Point3<f64>, Vector3<f64>);

impl Shape {
    /// A triangle from three vertices.
    pub fn triangle(a: Vector3<f64>, b: Vector3<f64>, c: Vector3<f64>) -> Shape {
        Shape::Triangle {
            v0: a,
            e1: b - a,
            e2: c - a,
        }
    }

    /// An axis-aligned box from its corners.
    pub fn aabox(min: Vector3<f64>, max: Vector3<f64>) -> Shape {
        Shape::Box {
            center: (min + max) * 0.5,
            half_m: (max - min) * 0.5,
            axis: [1.0, 0.0],
        }
    }

    /// Local axes of a box (x, z) in the world.
    #[inline]
    fn box_axes(axis: [f64; 2]) -> (Vector3<f64>, Vector3<f64>) {
        (
            Vector3::new(axis[0], 0.0, axis[1]),
            Vector3::new(-axis[1], 0.0, axis[0]),
        )
    }

    /// A box point in its local frame.
    #[inline]
    pub fn box_local(center: &Vector3<f64>, axis: [f64; 2], p: &Vector3<f64>) -> Vector3<f64> {
        let (ax, az) = Self::box_axes(axis);
        let d = p - center;
        Vector3::new(d.dot(&ax), d.y, d.dot(&az))
    }

    /// Bounding box.
    pub fn aabb(&self) -> Aabb {
        let mut b = Aabb::empty();
        match *self {
            Shape::Triangle { v0, e1, e2 } => {
                for p in [v0, v0 + e1, v0 + e2] {
                    b.grow([p.x, p.y, p.z]);
                }
            }
            Shape::Box {
                center,
                half_m,
                axis,
            } => {
                let ex = axis[0].abs() * half_m.x + axis[1].abs() * half_m.z;
                let ez = axis[1].abs() * half_m.x + axis[0].abs() * half_m.z;
                b.grow([center.x - ex, center.y - half_m.y, center.z - ez]);
                b.grow([center.x + ex, center.y + half_m.y, center.z + ez]);
            }
            Shape::Ellipsoid { center, radii_m } => {
                b.grow((center - radii_m).into());
                b.grow((center + radii_m).into());
            }
            Shape::Cylinder {
                center_xz,
                y_min,
                y_max,
                radius_m,
            } => {
                b.grow([center_xz[0] - radius_m, y_min, center_xz[1] - radius_m]);
                b.grow([center_xz[0] + radius_m, y_max, center_xz[1] + radius_m]);
            }
        }
        b
    }

    /// Nearest intersection with `t ∈ (t_min, t_max)`: the parameter and the outward unit normal
    /// (for a triangle, its oriented normal; solids hit from inside report the exit point).
    pub fn intersect(&self, ray: &Ray, t_min: f64, t_max: f64) -> Option<(f64, Vector3<f64>)> {
        let o = ray.origin.coords;
        let d = ray.direction;
        match *self {
            Shape::Triangle { v0, e1, e2 } => {
                let pv = d.cross(&e2);
                let det = e1.dot(&pv);
                if det.abs() < 1e-14 {
                    return None;
                }
                let inv = 1.0 / det;
                let tv = o - v0;
                let u = tv.dot(&pv) * inv;
                if !(0.0..=1.0).contains(&u) {
                    return None;
                }
                let qv = tv.cross(&e1);
                let v = d.dot(&qv) * inv;
                if v < 0.0 || u + v > 1.0 {
                    return None;
                }
                let t = e2.dot(&qv) * inv;
                (t > t_min && t < t_max).then(|| (t, e1.cross(&e2).normalize()))
            }
            Shape::Box {
                center,
                half_m,
                axis,
            } => {
                let (ax, az) = Self::box_axes(axis);
                let rel = o - center;
                let ol = [rel.dot(&ax), rel.y, rel.dot(&az)];
                let dl = [d.dot(&ax), d.y, d.dot(&az)];
                let h = [half_m.x, half_m.y, half_m.z];
                let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
                let (mut k0, mut k1) = (0usize, 0usize);
                for k in 0..3 {
                    if dl[k].abs() < 1e-300 {
                        if ol[k].abs() > h[k] {
                            return None;
                        }
                        continue;
                    }
                    let inv = 1.0 / dl[k];
                    let a = (-h[k] - ol[k]) * inv;
                    let b = (h[k] - ol[k]) * inv;
                    let (lo, hi) = if a < b { (a, b) } else { (b, a) };
                    if lo > t0 {
                        t0 = lo;
                        k0 = k;
                    }
                    if hi < t1 {
                        t1 = hi;
                        k1 = k;
                    }
                }
                if t0 > t1 {
                    return None;
                }
                let (t, k, sign) = if t0 > t_min {
                    (t0, k0, -dl[k0].signum())
                } else {
                    (t1, k1, dl[k1].signum())
                };
                if t <= t_min || t >= t_max {
                    return None;
                }
                let n = match k {
                    0 => ax * sign,
                    1 => Vector3::new(0.0, sign, 0.0),
                    _ => az * sign,
                };
                Some((t, n))
            }
            Shape::Ellipsoid { center, radii_m } => {
                let os = (o - center).component_div(&radii_m);
                let ds = d.component_div(&radii_m);
                let a = ds.dot(&ds);
                let b = os.dot(&ds);
                let c = os.dot(&os) - 1.0;
                let disc = b * b - a * c;
                if disc < 0.0 {
                    return None;
                }
                let sq = disc.sqrt();
                // Numerically stable roots.
                let q = if b > 0.0 { -(b + sq) } else { -b + sq };
                let (mut r0, mut r1) = if q != 0.0 { (q / a, c / q) } else { (0.0, 0.0) };
                if r0 > r1 {
                    std::mem::swap(&mut r0, &mut r1);
                }
                let t = if r0 > t_min { r0 } else { r1 };
                if t <= t_min || t >= t_max {
                    return None;
                }
                let p = o + d * t - center;
                let n = p
                    .component_div(&radii_m.component_mul(&radii_m))
                    .normalize();
                Some((t, n))
            }
            Shape::Cylinder {
                center_xz,
                y_min,
                y_max,
                radius_m,
            } => {
                let mut best: Option<(f64, Vector3<f64>)> = None;
                let mut consider = |t: f64, n: Vector3<f64>| {
                    if t > t_min && t < t_max && best.is_none_or(|(bt, _)| t < bt) {
                        best = Some((t, n));
                    }
                };
                let (ox, oz) = (o.x - center_xz[0], o.z - center_xz[1]);
                let a = d.x * d.x + d.z * d.z;
                if a > 1e-300 {
                    let b = ox * d.x + oz * d.z;
                    let c = ox * ox + oz * oz - radius_m * radius_m;
                    let disc = b * b - a * c;
                    if disc >= 0.0 {
                        let sq = disc.sqrt();
                        for t in [(-b - sq) / a, (-b + sq) / a] {
                            let y = o.y + d.y * t;
                            if y >= y_min && y <= y_max {
                                let n = Vector3::new(ox + d.x * t, 0.0, oz + d.z * t) / radius_m;
                                consider(t, n);
                            }
                        }
                    }
                }
                if d.y.abs() > 1e-300 {
                    for (y, ny) in [(y_min, -1.0), (y_max, 1.0)] {
                        let t = (y - o.y) / d.y;
                        let (px, pz) = (ox + d.x * t, oz + d.z * t);
                        if px * px + pz * pz <= radius_m * radius_m {
                            consider(t, Vector3::new(0.0, ny, 0.0));
                        }
                    }
                }
                best
            }
        }
    }

    /// Distance from `p` to the surface, metres. Exact for triangles, boxes, cylinders and
    /// spheres; for a non-spherical ellipsoid a first-order estimate, accurate near the surface.
    pub fn distance_to_surface(&self, p: &Point3<f64>) -> f64 {
        let p = p.coords;
        match *self {
            Shape::Triangle { v0, e1, e2 } => {
                (p - closest_on_triangle(&p, &v0, &(v0 + e1), &(v0 + e2))).norm()
            }
            Shape::Box {
                center,
                half_m,
                axis,
            } => {
                let q = Self::box_local(&center, axis, &p);
                let e = q.abs() - half_m;
                if e.x <= 0.0 && e.y <= 0.0 && e.z <= 0.0 {
                    -e.max()
                } else {
                    e.map(|v| v.max(0.0)).norm()
                }
            }
            Shape::Ellipsoid { center, radii_m } => {
                let q = p - center;
                if radii_m.x == radii_m.y && radii_m.y == radii_m.z {
                    return (q.norm() - radii_m.x).abs();
                }
                let f = q.component_div(&radii_m);
                let g = q.component_div(&radii_m.component_mul(&radii_m));
                let fl = f.norm();
                let gl = g.norm();
                if gl < 1e-12 {
                    return radii_m.min();
                }
                // f(p) = |q/r| − 1 has gradient (q/r²)/|q/r|; distance ≈ f / |∇f|.
                ((fl - 1.0) * fl / gl).abs()
            }
            Shape::Cylinder {
                center_xz,
                y_min,
                y_max,
                radius_m,
            } => {
                let rho = ((p.x - center_xz[0]).powi(2) + (p.z - center_xz[1]).powi(2)).sqrt();
                let dr = rho - radius_m;
                let dy = (y_min - p.y).max(p.y - y_max);
                if dr <= 0.0 && dy <= 0.0 {
                    (-dr).min(-dy)
                } else {
                    (dr.max(0.0).powi(2) + dy.max(0.0).powi(2)).sqrt()
                }
            }
        }
    }

    /// True when `p` is strictly inside the solid by more than `margin_m` (triangles are not
    /// solids: always false).
    pub fn contains(&self, p: &Point3<f64>, margin_m: f64) -> bool {
        match *self {
            Shape::Triangle { .. } => false,
            Shape::Box {
                center,
                half_m,
                axis,
            } => {
                let q = Self::box_local(&center, axis, &p.coords);
                q.x.abs() < half_m.x - margin_m
                    && q.y.abs() < half_m.y - margin_m
                    && q.z.abs() < half_m.z - margin_m
            }
            Shape::Ellipsoid { center, radii_m } => {
                let shrunk = radii_m.map(|r| (r - margin_m).max(0.0));
                if shrunk.min() <= 0.0 {
                    return false;
                }
                (p.coords - center).component_div(&shrunk).norm_squared() < 1.0
            }
            Shape::Cylinder {
                center_xz,
                y_min,
                y_max,
                radius_m,
            } => {
                let r = radius_m - margin_m;
                let rho2 = (p.x - center_xz[0]).powi(2) + (p.z - center_xz[1]).powi(2);
                r > 0.0 && rho2 < r * r && p.y > y_min + margin_m && p.y < y_max - margin_m
            }
        }
    }

    /// Regular samples of the surface about `spacing_m` apart, with outward normals. Box faces
    /// whose normal points down (+y, the underside) are skipped: they face the ground.
    pub fn sample_surface(&self, spacing_m: f64, out: &mut Vec<SurfaceSample>) {
        let sp = spacing_m.max(1e-3);
        match *self {
            Shape::Triangle { v0, e1, e2 } => {
                let n = e1.cross(&e2).normalize();
                let n1 = (e1.norm() / sp).ceil().max(1.0) as usize;
                let n2 = (e2.norm() / sp).ceil().max(1.0) as usize;
                for i in 0..n1 {
                    let a = (i as f64 + 0.5) / n1 as f64;
                    for j in 0..n2 {
                        let b = (j as f64 + 0.5) / n2 as f64;
                        if a + b <= 1.0 {
                            out.push((Point3::from(v0 + e1 * a + e2 * b), n));
                        }
                    }
                }
            }
            Shape::Box {
                center,
                half_m,
                axis,
            } => {
                let (ax, az) = Self::box_axes(axis);
                let ay = Vector3::y();
                let axes = [ax, ay, az];
                let h = [half_m.x, half_m.y, half_m.z];
                for k in 0..3 {
                    for sign in [-1.0, 1.0] {
                        if k == 1 && sign > 0.0 {
                            continue;
                        }
                        let (i, j) = ((k + 1) % 3, (k + 2) % 3);
                        let ni = (2.0 * h[i] / sp).ceil().max(1.0) as usize;
                        let nj = (2.0 * h[j] / sp).ceil().max(1.0) as usize;
                        let c = center + axes[k] * (sign * h[k]);
                        for a in 0..ni {
                            let s = ((a as f64 + 0.5) / ni as f64 * 2.0 - 1.0) * h[i];
                            for b in 0..nj {
                                let t = ((b as f64 + 0.5) / nj as f64 * 2.0 - 1.0) * h[j];
                                out.push((
                                    Point3::from(c + axes[i] * s + axes[j] * t),
                                    axes[k] * sign,
                                ));
                            }
                        }
                    }
                }
            }
            Shape::Ellipsoid { center, radii_m } => {
                let rmax = radii_m.max();
                let rings = ((std::f64::consts::PI * rmax / sp).ceil() as usize).max(2);
                for i in 0..rings {
                    let theta = (i as f64 + 0.5) / rings as f64 * std::f64::consts::PI;
                    let count =
                        ((std::f64::consts::TAU * rmax * theta.sin() / sp).ceil() as usize).max(1);
                    for j in 0..count {
                        let phi = (j as f64 + 0.5) / count as f64 * std::f64::consts::TAU;
                        let u = Vector3::new(
                            theta.sin() * phi.cos(),
                            theta.cos(),
                            theta.sin() * phi.sin(),
                        );
                        let q = u.component_mul(&radii_m);
                        let n = q
                            .component_div(&radii_m.component_mul(&radii_m))
                            .normalize();
                        out.push((Point3::from(center + q), n));
                    }
                }
            }
            Shape::Cylinder {
                center_xz,
                y_min,
                y_max,
                radius_m,
            } => {
                let around = ((std::f64::consts::TAU * radius_m / sp).ceil() as usize).max(6);
                let along = ((y_max - y_min) / sp).ceil().max(1.0) as usize;
                for j in 0..around {
                    let phi = (j as f64 + 0.5) / around as f64 * std::f64::consts::TAU;
                    let n = Vector3::new(phi.cos(), 0.0, phi.sin());
                    for i in 0..along {
                        let y = y_min + (i as f64 + 0.5) / along as f64 * (y_max - y_min);
                        let p = Point3::new(
                            center_xz[0] + radius_m * n.x,
                            y,
                            center_xz[1] + radius_m * n.z,
                        );
                        out.push((p, n));
                    }
                }
                let rings = (radius_m / sp).ceil().max(1.0) as usize;
                for i in 0..rings {
                    let r = (i as f64 + 0.5) / rings as f64 * radius_m;
                    let count = ((std::f64::consts::TAU * r / sp).ceil() as usize).max(1);
                    for j in 0..count {
                        let phi = (j as f64 + 0.5) / count as f64 * std::f64::consts::TAU;
                        let p = Point3::new(
                            center_xz[0] + r * phi.cos(),
                            y_min,
                            center_xz[1] + r * phi.sin(),
                        );
                        out.push((p, -Vector3::y()));
                    }
                }
            }
        }
    }
}

/// Closest point on triangle `abc` to `p` (Ericson, Real-Time Collision Detection, 5.1.5).
fn closest_on_triangle(
    p: &Vector3<f64>,
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
) -> Vector3<f64> {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return *a;
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return *b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return *c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

#[cfg(test)]
mod tests;
