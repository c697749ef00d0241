//! Simulated LiDAR for the synthetic city: a Velodyne HDL-64E-like spinning scanner (64 beams
//! spread evenly from +2° to −24.9°, a full turn in `azimuth_steps` steps) mounted as in KITTI
//! (sequence 00's `Tr` velodyne→cam0), with Gaussian range noise and an intensity from the
//! surface albedo and incidence. The sweep is instantaneous (no motion during a turn) and there
//! is no ego vehicle, beam divergence or multiple return.

use super::city::City;
use super::geometry::Ray;
use super::rng::{gaussian, hash3};
use crate::camera::WorldFromCamera;
use crate::frame::LidarScan;
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;

/// KITTI odometry sequence 00's `Tr` (velodyne → cam0, row-major 3×4), from its calib.txt.
pub const KITTI_00_TR_VELO_TO_CAM: [f64; 12] = [
    4.276802385584e-04,
    -9.999672484946e-01,
    -8.084491683471e-03,
    -1.198459927713e-02,
    -7.210626507497e-03,
    8.081198471645e-03,
    -9.999413164504e-01,
    -5.403984729748e-02,
    9.999738645903e-01,
    4.859485810390e-04,
    -7.206933692422e-03,
    -2.921968648686e-01,
];

/// `cam0_from_velo` of KITTI sequence 00 (the rotation re-orthonormalised).
pub fn kitti_cam0_from_velo() -> Isometry3<f64> {
    let t = KITTI_00_TR_VELO_TO_CAM;
    let m = Matrix3::new(t[0], t[1], t[2], t[4], t[5], t[6], t[8], t[9], t[10]);
    let r = Rotation3::from_matrix_eps(&m, 1e-12, 100, Rotation3::identity());
    Isometry3::from_parts(
        Translation3::new(t[3], t[7], t[11]),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// Scanner model. The sensor frame is Velodyne's: x forward, y left, z up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LidarConfig {
    /// Number of beams (lasers).
    pub beams: u32,
    /// Elevation of the highest beam, degrees.
    pub elevation_max_deg: f64,
    /// Elevation of the lowest beam, degrees.
    pub elevation_min_deg: f64,
    /// Firing positions per turn.
    pub azimuth_steps: u32,
    /// Returns beyond this range are dropped, metres.
    pub max_range_m: f64,
    /// Returns closer than this are dropped, metres.
    pub min_range_m: f64,
    /// Standard deviation of the Gaussian range noise, metres.
    pub range_noise_sigma_m: f64,
    /// Mounting: the sensor frame in cam0's frame (KITTI's `Tr`).
    pub cam0_from_velo: Isometry3<f64>,
}

impl Default for LidarConfig {
    fn default() -> Self {
        LidarConfig {
            beams: 64,
            elevation_max_deg: 2.0,
            elevation_min_deg: -24.9,
            azimuth_steps: 2000,
            max_range_m: 120.0,
            min_range_m: 2.0,
            range_noise_sigma_m: 0.02,
            cam0_from_velo: kitti_cam0_from_velo(),
        }
    }
}

impl City {
    /// One LiDAR turn with cam0 at `world_from_cam0`; `seed` seeds the range noise. Points are
    /// in the sensor frame, ordered by azimuth step then beam (top to bottom).
    pub fn scan_lidar(
        &self,
        world_from_cam0: &WorldFromCamera,
        cfg: &LidarConfig,
        seed: u64,
    ) -> LidarScan {
        let world_from_sensor = world_from_cam0 * cfg.cam0_from_velo;
        let origin = Point3::from(world_from_sensor.translation.vector);
        let rot = world_from_sensor.rotation.to_rotation_matrix();
        let beams = cfg.beams.max(1);
        let elev: Vec<f64> = (0..beams)
            .map(|b| {
                let f = if beams == 1 {
                    0.0
                } else {
                    b as f64 / (beams - 1) as f64
                };
                (cfg.elevation_max_deg + (cfg.elevation_min_deg - cfg.elevation_max_deg) * f)
                    .to_radians()
            })
            .collect();
        let steps = cfg.azimuth_steps.max(1);
        let columns: Vec<Vec<([f32; 3], f32)>> = (0..steps)
            .into_par_iter()
            .map(|a| {
                let az = std::f64::consts::TAU * a as f64 / steps as f64;
                let mut col = Vec::with_capacity(beams as usize);
                for (b, &e) in elev.iter().enumerate() {
                    let d_sensor = Vector3::new(e.cos() * az.cos(), e.cos() * az.sin(), e.sin());
                    let d_world = rot * d_sensor;
                    let Some(h) = self.cast_within(&Ray::new(origin, d_world), cfg.max_range_m)
                    else {
                        continue;
                    };
                    if h.t < cfg.min_range_m {
                        continue;
                    }
                    let noise = cfg.range_noise_sigma_m * gaussian(hash3(seed, a as u64, b as u64));
                    let r = h.t + noise;
                    let p = d_sensor * r;
                    let cos_i = h.normal.dot(&d_world).abs();
                    let lum = 0.299 * h.albedo[0] + 0.587 * h.albedo[1] + 0.114 * h.albedo[2];
                    let intensity = (lum * (0.35 + 0.65 * cos_i as f32) * 1.6).clamp(0.0, 1.0);
                    col.push(([p.x as f32, p.y as f32, p.z as f32], intensity));
                }
                col
            })
            .collect();
        let n: usize = columns.iter().map(|c| c.len()).sum();
        let mut points = Vec::with_capacity(n);
        let mut intensity = Vec::with_capacity(n);
        for c in columns {
            for (p, i) in c {
                points.push(p);
                intensity.push(i);
            }
        }
        LidarScan {
            world_from_sensor,
            points_sensor_m: points,
            intensity,
        }
    }
}
