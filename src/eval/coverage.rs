//! Where a LiDAR could have measured: a reconstructed point is *covered* when at least one scan
//! had it within its range and its vertical field of view. Accuracy against LiDAR ground truth
//! is honest only over covered points: a facade above the sensor's upper beam has no LiDAR point
//! near it, so its distance to the nearest return measures the gap in the ground truth, not an
//! error of the reconstruction (on a 200 m synthetic stereo drive that gap turned a 19 cm median
//! into 89 cm).
//!
//! The field of view and range are read from the scans themselves: the lowest and highest
//! elevation of any return (in the sensor frame, elevation = atan2(z, √(x² + y²)), KITTI's
//! Velodyne frame: x forward, y left, z up) and the farthest return. Occlusion is not modelled:
//! a covered point may still have been hidden from every scan.

use crate::frame::LidarScan;
use nalgebra::Isometry3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// The sensor's view, as measured from its scans.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensorView {
    /// Lowest elevation of a return, degrees.
    pub elevation_min_deg: f64,
    /// Highest elevation of a return, degrees.
    pub elevation_max_deg: f64,
    /// Farthest return, metres.
    pub range_max_m: f64,
}

/// The scans' poses and view: answers whether a point was within some scan's reach.
#[derive(Clone, Debug)]
pub struct SensorCoverage {
    view: SensorView,
    sensor_from_world: Vec<Isometry3<f64>>,
    /// For each cell (`range_max_m` wide) with a scan in it or next to it: the scans whose
    /// origins lie in the 27 cells around it, the only ones that can reach a point in it.
    cells: HashMap<[i64; 3], ScanBlock>,
}

/// The scans that can reach one cell, [`SCAN_LANES`] at a time as structure of arrays (padded
/// with scans out of every range: origin at infinity), so that a point is tested against
/// several scans at once.
#[derive(Clone, Debug, Default)]
struct ScanBlock {
    lanes: Vec<ScanLanes>,
    /// Scans in the last element of `lanes`.
    used: usize,
}

/// [`SCAN_LANES`] scans.
#[derive(Clone, Copy, Debug)]
struct ScanLanes {
    /// Scan origins, world frame, metres: x, y, z.
    origin_m: [[f64; SCAN_LANES]; 3],
    /// `sensor_from_world` rotations, row-major.
    rotation: [[f64; SCAN_LANES]; 9],
    /// `sensor_from_world` translations, metres.
    translation_m: [[f64; SCAN_LANES]; 3],
}

impl ScanLanes {
    const EMPTY: ScanLanes = ScanLanes {
        origin_m: [[f64::INFINITY; SCAN_LANES]; 3],
        rotation: [[0.0; SCAN_LANES]; 9],
        translation_m: [[0.0; SCAN_LANES]; 3],
    };
}

/// Scans tested together by [`block_covers`].
const SCAN_LANES: usize = 8;

impl ScanBlock {
    fn push(&mut self, origin_m: [f64; 3], sensor_from_world: &Isometry3<f64>) {
        if self.lanes.is_empty() || self.used == SCAN_LANES {
            self.lanes.push(ScanLanes::EMPTY);
            self.used = 0;
        }
        let l = self.used;
        let lanes = self.lanes.last_mut().expect("just pushed");
        let r = sensor_from_world.rotation.to_rotation_matrix();
        for k in 0..3 {
            lanes.origin_m[k][l] = origin_m[k];
            lanes.translation_m[k][l] = sensor_from_world.translation.vector[k];
            for j in 0..3 {
                lanes.rotation[3 * k + j][l] = r[(k, j)];
            }
        }
        self.used += 1;
    }

    /// The scans, one at a time: (origin, rotation row-major, translation).
    fn scans(&self) -> impl Iterator<Item = ([f64; 3], [f64; 9], [f64; 3])> + '_ {
        self.lanes.iter().enumerate().flat_map(move |(i, lanes)| {
            let n = if i + 1 == self.lanes.len() {
                self.used
            } else {
                SCAN_LANES
            };
            (0..n).map(move |l| {
                (
                    lanes.origin_m.map(|v| v[l]),
                    lanes.rotation.map(|v| v[l]),
                    lanes.translation_m.map(|v| v[l]),
                )
            })
        })
    }
}

/// Whether a scan of `lanes` has `p` within `range_m` and between the elevation slopes `tan_lo`,
/// `tan_hi` (as [`SensorCoverage::view_test`] with slopes, for `h > 0`), in one straight loop
/// over [`SCAN_LANES`] scans at a time. `None` when no scan does by that test but one has `p` in
/// range straight above or below it (`h = 0`): the caller decides those with atan2.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512vl+avx2+avx+sse4.1",
    "x86_64+avx2+avx+sse4.1",
    "x86_64+sse4.1"
))]
fn block_covers(
    lanes: &[ScanLanes],
    p: [f64; 3],
    range_m: f64,
    tan_lo: f64,
    tan_hi: f64,
) -> Option<bool> {
    let rr = range_m * range_m;
    let mut vertical = false;
    for s in lanes {
        let (o, r, t) = (&s.origin_m, &s.rotation, &s.translation_m);
        let mut hit = false;
        for k in 0..SCAN_LANES {
            let d2 = (p[0] - o[0][k]).powi(2) + (p[1] - o[1][k]).powi(2) + (p[2] - o[2][k]).powi(2);
            let x = r[0][k] * p[0] + r[1][k] * p[1] + r[2][k] * p[2] + t[0][k];
            let y = r[3][k] * p[0] + r[4][k] * p[1] + r[5][k] * p[2] + t[1][k];
            let z = r[6][k] * p[0] + r[7][k] * p[1] + r[8][k] * p[2] + t[2][k];
            let h = (x * x + y * y).sqrt();
            let in_range = d2 <= rr;
            hit |= in_range & (h > 0.0) & (h * tan_lo <= z) & (z <= h * tan_hi);
            vertical |= in_range & (h == 0.0);
        }
        if hit {
            return Some(true);
        }
    }
    (!vertical).then_some(false)
}

/// Accumulates the view of scans one at a time (so scans need not be held together).
#[derive(Clone, Debug, Default)]
pub struct CoverageBuilder {
    view: Option<SensorView>,
    world_from_sensor: Vec<Isometry3<f64>>,
}

impl CoverageBuilder {
    /// Adds one scan (its pose, and the elevations and ranges of its returns).
    pub fn add(&mut self, scan: &LidarScan) {
        // The returns of least and greatest elevation, as (z, √(x² + y²)): elevations compare as
        // z₁·h₂ < z₂·h₁ (h ≥ 0), so atan2 is taken twice per scan, not once per return.
        let mut low: Option<(f64, f64)> = None;
        let mut high: Option<(f64, f64)> = None;
        let mut far = 0.0f64;
        for p in &scan.points_sensor_m {
            let [x, y, z] = p.map(|v| v as f64);
            let horizontal = (x * x + y * y).sqrt();
            let range = (horizontal * horizontal + z * z).sqrt();
            if !(range.is_finite() && range > 0.0) {
                continue;
            }
            if low.is_none_or(|(lz, lh)| z * lh < lz * horizontal) {
                low = Some((z, horizontal));
            }
            if high.is_none_or(|(hz, hh)| z * hh > hz * horizontal) {
                high = Some((z, horizontal));
            }
            far = far.max(range);
        }
        let degrees = |(z, h): (f64, f64)| z.atan2(h).to_degrees();
        let (lo, hi) = match (low, high) {
            (Some(l), Some(h)) => (degrees(l), degrees(h)),
            _ => (f64::INFINITY, f64::NEG_INFINITY),
        };
        self.world_from_sensor.push(scan.world_from_sensor);
        if lo <= hi {
            let v = self.view.get_or_insert(SensorView {
                elevation_min_deg: lo,
                elevation_max_deg: hi,
                range_max_m: far,
            });
            v.elevation_min_deg = v.elevation_min_deg.min(lo);
            v.elevation_max_deg = v.elevation_max_deg.max(hi);
            v.range_max_m = v.range_max_m.max(far);
        }
    }

    /// The coverage of the scans added (`None` when none had a return).
    pub fn build(self) -> Option<SensorCoverage> {
        let view = self.view?;
        let origins: Vec<[f64; 3]> = self
            .world_from_sensor
            .iter()
            .map(|t| t.translation.vector.into())
            .collect();
        let sensor_from_world: Vec<Isometry3<f64>> =
            self.world_from_sensor.iter().map(|t| t.inverse()).collect();
        let mut cells: HashMap<[i64; 3], ScanBlock> = HashMap::new();
        for (o, t) in origins.iter().zip(&sensor_from_world) {
            let c = cell(*o, view.range_max_m);
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        cells
                            .entry([c[0] + dx, c[1] + dy, c[2] + dz])
                            .or_default()
                            .push(*o, t);
                    }
                }
            }
        }
        Some(SensorCoverage {
            view,
            sensor_from_world,
            cells,
        })
    }
}

impl SensorCoverage {
    /// The measured view.
    pub fn view(&self) -> SensorView {
        self.view
    }

    /// Number of scans.
    pub fn scans(&self) -> usize {
        self.sensor_from_world.len()
    }

    /// The scans' positions in order, world frame, metres (the sensor's trajectory).
    pub fn trajectory_m(&self) -> Vec<[f64; 3]> {
        self.sensor_from_world
            .iter()
            .map(|t| t.inverse().translation.vector.into())
            .collect()
    }

    /// Whether some scan had `p` (world frame, metres) within its range and field of view.
    pub fn covers(&self, p: [f64; 3]) -> bool {
        self.covers_with(&self.view_test(), self.slopes(), p)
    }

    /// [`SensorCoverage::covers`] with the view's test and slopes built once
    /// ([`SensorCoverage::view_test`], [`SensorCoverage::slopes`]).
    fn covers_with(
        &self,
        within: &impl Fn(f64, f64) -> bool,
        slopes: Option<(f64, f64)>,
        p: [f64; 3],
    ) -> bool {
        let r = self.view.range_max_m;
        let Some(block) = self.cells.get(&cell(p, r)) else {
            return false;
        };
        let fast = slopes.and_then(|(lo, hi)| block_covers(&block.lanes, p, r, lo, hi));
        fast.unwrap_or_else(|| block_covers_exactly(block, within, p, r))
    }

    /// The tangents of the view's elevation bounds, when both are within (−90°, 90°).
    fn slopes(&self) -> Option<(f64, f64)> {
        let (lo, hi) = (
            self.view.elevation_min_deg.to_radians(),
            self.view.elevation_max_deg.to_radians(),
        );
        let right = std::f64::consts::FRAC_PI_2;
        (lo > -right && hi < right).then(|| (lo.tan(), hi.tan()))
    }

    /// Whether a point at height `z` and horizontal distance `h` (sensor frame, metres) is within
    /// the view's elevations: `lo ≤ atan2(z, h) ≤ hi`, tested as `h·tan lo ≤ z ≤ h·tan hi` (no
    /// atan2 per point and scan: uncovered points try every scan in range). The two agree but
    /// within rounding at the bounds; at `h = 0`, or a view reaching ±90°, atan2 decides.
    fn view_test(&self) -> impl Fn(f64, f64) -> bool {
        let (lo, hi) = (
            self.view.elevation_min_deg.to_radians(),
            self.view.elevation_max_deg.to_radians(),
        );
        let slopes = self.slopes();
        move |z: f64, h: f64| match slopes {
            Some((tan_lo, tan_hi)) if h > 0.0 => h * tan_lo <= z && z <= h * tan_hi,
            _ => (lo..=hi).contains(&z.atan2(h)),
        }
    }

    /// [`SensorCoverage::covers`] for every point, in parallel.
    pub fn mask(&self, points_m: &[[f64; 3]]) -> Vec<bool> {
        let (within, slopes) = (self.view_test(), self.slopes());
        points_m
            .par_iter()
            .map(|&p| self.covers_with(&within, slopes, p))
            .collect()
    }
}

/// The scans of `block` one at a time with the view test `within` (atan2 where it must): the
/// exact form behind [`block_covers`], for the points it cannot decide.
fn block_covers_exactly(
    block: &ScanBlock,
    within: &impl Fn(f64, f64) -> bool,
    p: [f64; 3],
    range_m: f64,
) -> bool {
    block.scans().any(|(o, r, t)| {
        let d2: f64 = (0..3).map(|a| (p[a] - o[a]).powi(2)).sum();
        if d2 > range_m * range_m {
            return false;
        }
        let row = |j: usize| (0..3).map(|i| r[3 * j + i] * p[i]).sum::<f64>() + t[j];
        let (x, y, z) = (row(0), row(1), row(2));
        within(z, (x * x + y * y).sqrt())
    })
}

/// The grid cell of `p` for cells `size_m` wide.
fn cell(p: [f64; 3], size_m: f64) -> [i64; 3] {
    p.map(|v| (v / size_m).floor() as i64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan_at(x: f64, elevations_deg: &[f64]) -> LidarScan {
        let points: Vec<[f32; 3]> = elevations_deg
            .iter()
            .map(|e| {
                let r = 10.0f64;
                let e = e.to_radians();
                [(r * e.cos()) as f32, 0.0, (r * e.sin()) as f32]
            })
            .collect();
        LidarScan {
            intensity: vec![0.0; points.len()],
            points_sensor_m: points,
            world_from_sensor: Isometry3::translation(x, 0.0, 0.0),
        }
    }

    #[test]
    fn a_point_above_the_upper_beam_or_out_of_range_is_not_covered() {
        let mut b = CoverageBuilder::default();
        b.add(&scan_at(0.0, &[-24.8, -10.0, 2.0]));
        b.add(&scan_at(50.0, &[-20.0, 1.0]));
        let c = b.build().expect("coverage");
        let v = c.view();
        assert!(
            (v.elevation_min_deg + 24.8).abs() < 1e-4 && (v.elevation_max_deg - 2.0).abs() < 1e-4
        );
        assert!((v.range_max_m - 10.0).abs() < 1e-4);
        // Level with the sensor, 5 m ahead: covered. 5 m ahead and 1 m up (11°): not.
        assert!(c.covers([5.0, 0.0, 0.0]));
        assert!(!c.covers([5.0, 0.0, 1.0]));
        // 5 m down at 8 m (−32°): below the lowest beam; at 20 m out it is −14°, but out of
        // range of both scans.
        assert!(!c.covers([8.0, 0.0, -5.0]));
        assert!(!c.covers([25.0, 0.0, -5.0]));
        // Near the second scan, 3 m below it at 9 m: −18°, covered by it.
        assert!(c.covers([59.0, 0.0, -3.0]));
        assert_eq!(
            c.mask(&[[5.0, 0.0, 0.0], [5.0, 0.0, 1.0]]),
            vec![true, false]
        );
        assert_eq!(c.trajectory_m()[1], [50.0, 0.0, 0.0]);
    }

    #[test]
    fn the_lane_test_agrees_with_each_pose_applied_to_the_point() {
        // Tilted, turned scans along a curved path (more than one cell and lane block apart);
        // every random point is decided as the definition says: some scan in range sees it
        // between its lowest and highest elevation (pose applied as the isometry, then atan2).
        let mut rng = crate::synth::rng::Rng::new(11, 0);
        let mut b = CoverageBuilder::default();
        let mut poses = Vec::new();
        for i in 0..21 {
            let mut scan = scan_at(0.0, &[-24.9, -3.0, 2.0]);
            let angle = i as f64 * 0.3;
            scan.world_from_sensor = Isometry3::new(
                nalgebra::Vector3::new(12.0 * i as f64, 5.0 * angle.sin(), 0.3 * angle.cos()),
                nalgebra::Vector3::new(0.05 * angle.cos(), 0.04, angle),
            );
            poses.push(scan.world_from_sensor);
            b.add(&scan);
        }
        let c = b.build().expect("coverage");
        let v = c.view();
        let (lo, hi) = (
            v.elevation_min_deg.to_radians(),
            v.elevation_max_deg.to_radians(),
        );
        let points: Vec<[f64; 3]> = (0..20_000)
            .map(|_| {
                [
                    rng.range(-20.0, 270.0),
                    rng.range(-20.0, 20.0),
                    rng.range(-8.0, 4.0),
                ]
            })
            .collect();
        let mask = c.mask(&points);
        let mut covered = 0;
        for (p, &m) in points.iter().zip(&mask) {
            let mut near_bound = false;
            let reference = poses.iter().any(|t| {
                let world = nalgebra::Point3::from(*p);
                if (world - nalgebra::Point3::from(t.translation.vector)).norm() > v.range_max_m {
                    return false;
                }
                let q = t.inverse() * world;
                let e = q.z.atan2((q.x * q.x + q.y * q.y).sqrt());
                near_bound |= (e - lo).abs() < 1e-9 || (e - hi).abs() < 1e-9;
                (lo..=hi).contains(&e)
            });
            if !near_bound {
                assert_eq!(m, reference, "{p:?}");
            }
            covered += m as usize;
        }
        assert!(covered > 2_000 && covered < 18_000, "{covered}");
    }

    #[test]
    fn the_slope_test_agrees_with_atan2_away_from_the_bounds() {
        let mut b = CoverageBuilder::default();
        b.add(&scan_at(0.0, &[-24.9, 0.0, 2.0]));
        let c = b.build().expect("coverage");
        let v = c.view();
        // The extremes found by comparing slopes are the returns' own elevations.
        assert!((v.elevation_min_deg + 24.9).abs() < 1e-5, "{v:?}");
        assert!((v.elevation_max_deg - 2.0).abs() < 1e-5, "{v:?}");
        let within = c.view_test();
        let (lo, hi) = (
            v.elevation_min_deg.to_radians(),
            v.elevation_max_deg.to_radians(),
        );
        let mut rng = crate::synth::rng::Rng::new(7, 0);
        let mut inside = 0;
        for _ in 0..100_000 {
            let (z, h) = (rng.range(-30.0, 10.0), rng.range(0.0, 60.0));
            let e = z.atan2(h);
            if (e - lo).abs() < 1e-12 || (e - hi).abs() < 1e-12 {
                continue;
            }
            let reference = (lo..=hi).contains(&e);
            assert_eq!(within(z, h), reference, "z {z} h {h}");
            inside += reference as usize;
        }
        assert!(inside > 10_000 && inside < 90_000, "{inside}");
        // Straight above or below the sensor: atan2 decides (±90°, outside this view).
        assert!(!within(1.0, 0.0) && !within(-1.0, 0.0));
    }
}
