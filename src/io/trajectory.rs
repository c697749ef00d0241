//! Trajectories for inputs that carry no poses of their own (a folder of scans, a ROS 2 bag):
//! read from a TUM or KITTI file (told apart by their shape) or gathered from a bag's messages,
//! and interpolated at each scan's time stamp; plus the sensor-to-body extrinsic file.
//!
//! # Files
//! * TUM: `t tx ty tz qx qy qz qw` per line (8 numbers; `#` comments), `world_from_body`, time in
//!   seconds. Lines may come in any order; they are sorted by time.
//! * KITTI: a 3×4 row-major `world_from_body` per line (12 numbers), no time: matched to scans by
//!   order. Rotations are snapped to the nearest rotation (as for KITTI poses).
//! * Extrinsic (`--extrinsic`): `body_from_sensor` as a 4×4 matrix (16 numbers on 4 lines, last
//!   row `0 0 0 1`) or its 3×4 top (12 numbers).
//!
//! What it does not do: extrapolate (a time outside the samples' span has no pose), smooth, or
//! fill gaps: consecutive samples are joined however far apart they are.

use super::text::{parse_numbers, read_to_string};
use crate::{Error, Result};
use nalgebra::{Isometry3, Matrix3x4, Translation3};
use std::path::Path;

/// The two trajectory files, by their shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrajectoryFormat {
    /// `t tx ty tz qx qy qz qw` per line.
    Tum,
    /// A 3×4 matrix per line, no time.
    Kitti,
}

impl TrajectoryFormat {
    /// The name in messages.
    pub fn name(self) -> &'static str {
        match self {
            TrajectoryFormat::Tum => "TUM",
            TrajectoryFormat::Kitti => "KITTI",
        }
    }
}

/// Poses of a body, in order; with times (seconds, increasing) when the source has them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trajectory {
    /// Time of each pose, seconds, non-decreasing; empty for an untimed (KITTI) trajectory.
    times_s: Vec<f64>,
    /// `world_from_body` of each sample.
    poses: Vec<Isometry3<f64>>,
}

impl Trajectory {
    /// A trajectory of timed samples (any order; sorted here, the first of equal times kept
    /// first). Non-finite times are an error the caller words: `Err(index)`.
    pub fn timed(
        mut samples: Vec<(f64, Isometry3<f64>)>,
    ) -> std::result::Result<Trajectory, usize> {
        if let Some(k) = samples.iter().position(|(t, _)| !t.is_finite()) {
            return Err(k);
        }
        samples.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (times_s, poses) = samples.into_iter().unzip();
        Ok(Trajectory { times_s, poses })
    }

    /// An untimed trajectory (poses matched to scans by order).
    pub fn untimed(poses: Vec<Isometry3<f64>>) -> Trajectory {
        Trajectory {
            times_s: Vec::new(),
            poses,
        }
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// Whether there is no pose.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Whether the poses have times.
    pub fn is_timed(&self) -> bool {
        !self.times_s.is_empty()
    }

    /// The poses in order.
    pub fn poses(&self) -> &[Isometry3<f64>] {
        &self.poses
    }

    /// First and last time, seconds (`None` when untimed or empty).
    pub fn span_s(&self) -> Option<(f64, f64)> {
        Some((*self.times_s.first()?, *self.times_s.last()?))
    }

    /// The pose at time `t_s`: a sample's own pose where `t_s` is its time exactly, else the
    /// two neighbours joined (translation linearly, rotation by slerp); `None` outside the span
    /// (or when untimed).
    pub fn at(&self, t_s: f64) -> Option<Isometry3<f64>> {
        let (first, last) = self.span_s()?;
        if !(t_s >= first && t_s <= last) {
            return None;
        }
        let k = self.times_s.partition_point(|&x| x < t_s);
        if self.times_s[k] == t_s {
            return Some(self.poses[k]);
        }
        let (t0, t1) = (self.times_s[k - 1], self.times_s[k]);
        let a = (t_s - t0) / (t1 - t0);
        let (p0, p1) = (&self.poses[k - 1], &self.poses[k]);
        let translation = p0.translation.vector.lerp(&p1.translation.vector, a);
        let rotation = p0
            .rotation
            .try_slerp(&p1.rotation, a, 1e-12)
            .unwrap_or(p0.rotation);
        Some(Isometry3::from_parts(
            Translation3::from(translation),
            rotation,
        ))
    }
}

/// Reads a trajectory file, TUM or KITTI by the count of numbers on its first data line;
/// errors name the file and line.
pub fn read_trajectory(path: &Path) -> Result<(TrajectoryFormat, Trajectory)> {
    let text = read_to_string(path)?;
    let lines: Vec<(usize, &str)> = text
        .lines()
        .enumerate()
        .map(|(k, l)| (k + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
        .collect();
    let Some(&(first_no, first)) = lines.first() else {
        return Err(Error::bad_input(path, "no pose in the trajectory file"));
    };
    let format = match parse_numbers(path, first_no, first)?.len() {
        8 => TrajectoryFormat::Tum,
        12 => TrajectoryFormat::Kitti,
        n => {
            return Err(Error::bad_input(
                path,
                format!("line {first_no}: {n} numbers; a trajectory line holds 8 (TUM: t tx ty tz qx qy qz qw) or 12 (KITTI: a 3×4 matrix)"),
            ))
        }
    };
    let mut samples = Vec::with_capacity(lines.len());
    let mut poses = Vec::with_capacity(lines.len());
    for (line_no, line) in lines {
        let v = parse_numbers(path, line_no, line)?;
        let want = if format == TrajectoryFormat::Tum {
            8
        } else {
            12
        };
        if v.len() != want {
            return Err(Error::bad_input(
                path,
                format!(
                    "line {line_no}: {} numbers where the {} trajectory's lines hold {want}",
                    v.len(),
                    format.name()
                ),
            ));
        }
        match format {
            TrajectoryFormat::Tum => {
                samples.push((v[0], super::rgbd::pose_from_tq(path, line_no, &v[1..])?))
            }
            TrajectoryFormat::Kitti => poses.push(
                super::kitti::isometry_from_3x4(&Matrix3x4::from_row_slice(&v))
                    .map_err(|m| Error::bad_input(path, format!("line {line_no}: {m}")))?,
            ),
        }
    }
    let trajectory = match format {
        TrajectoryFormat::Tum => Trajectory::timed(samples)
            .map_err(|k| Error::bad_input(path, format!("pose {} has a non-finite time", k + 1)))?,
        TrajectoryFormat::Kitti => Trajectory::untimed(poses),
    };
    Ok((format, trajectory))
}

/// Reads a `body_from_sensor` extrinsic: 16 numbers (4×4, last row `0 0 0 1`) or 12 (3×4).
pub fn read_extrinsic(path: &Path) -> Result<Isometry3<f64>> {
    let text = read_to_string(path)?;
    let mut v = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let line = line.trim();
        if !line.is_empty() && !line.starts_with('#') {
            v.extend(parse_numbers(path, k + 1, line)?);
        }
    }
    if v.len() == 16 {
        let last = [v[12], v[13], v[14], v[15]];
        if last != [0.0, 0.0, 0.0, 1.0] {
            return Err(Error::bad_input(
                path,
                format!("the 4×4 extrinsic's last row must be 0 0 0 1, found {last:?}"),
            ));
        }
        v.truncate(12);
    }
    if v.len() != 12 {
        return Err(Error::bad_input(
            path,
            format!(
                "{} numbers; an extrinsic is a 4×4 matrix (16 numbers) or its 3×4 top (12)",
                v.len()
            ),
        ));
    }
    super::kitti::isometry_from_3x4(&Matrix3x4::from_row_slice(&v))
        .map_err(|m| Error::bad_input(path, m))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    fn pose(x: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, 2.0 * x, 0.5),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
        )
    }

    #[test]
    fn samples_are_exact_and_midpoints_interpolate() {
        let tr = Trajectory::timed(vec![(2.0, pose(4.0, 0.4)), (1.0, pose(2.0, 0.2))]).unwrap();
        assert_eq!(tr.at(1.0), Some(pose(2.0, 0.2)));
        assert_eq!(tr.at(2.0), Some(pose(4.0, 0.4)));
        let mid = tr.at(1.25).unwrap();
        assert!((mid.translation.vector - Vector3::new(2.5, 5.0, 0.5)).norm() < 1e-12);
        assert!((mid.rotation.angle() - 0.25).abs() < 1e-12);
        assert_eq!(tr.at(0.999), None);
        assert_eq!(tr.at(2.001), None);
        assert_eq!(tr.at(f64::NAN), None);
    }

    #[test]
    fn files_are_told_apart_by_shape() {
        let dir = tempfile::tempdir().unwrap();
        let tum = dir.path().join("t.txt");
        std::fs::write(
            &tum,
            "# t x y z qx qy qz qw\n1.5 1 2 3 0 0 0 1\n0.5 0 0 0 0 0 0 1\n",
        )
        .unwrap();
        let (f, tr) = read_trajectory(&tum).unwrap();
        assert_eq!(f, TrajectoryFormat::Tum);
        assert_eq!(tr.span_s(), Some((0.5, 1.5)));
        let mid = tr.at(1.0).unwrap();
        assert!((mid.translation.vector - Vector3::new(0.5, 1.0, 1.5)).norm() < 1e-12);
        let kitti = dir.path().join("k.txt");
        std::fs::write(&kitti, "1 0 0 5 0 1 0 6 0 0 1 7\n").unwrap();
        let (f, tr) = read_trajectory(&kitti).unwrap();
        assert_eq!(
            (f, tr.len(), tr.is_timed()),
            (TrajectoryFormat::Kitti, 1, false)
        );
        assert_eq!(
            tr.poses()[0].translation.vector,
            Vector3::new(5.0, 6.0, 7.0)
        );
        std::fs::write(&kitti, "1 0 0 5 0 1 0 6 0 0 1 7\n1 2 3\n").unwrap();
        let e = read_trajectory(&kitti).unwrap_err().to_string();
        assert!(e.contains("k.txt") && e.contains("line 2"), "{e}");
        std::fs::write(&kitti, "1 2 3 4\n").unwrap();
        let e = read_trajectory(&kitti).unwrap_err().to_string();
        assert!(e.contains("8 (TUM") && e.contains("12 (KITTI"), "{e}");
    }

    #[test]
    fn extrinsic_takes_4x4_or_3x4() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("e.txt");
        std::fs::write(&p, "0 -1 0 1\n1 0 0 2\n0 0 1 3\n0 0 0 1\n").unwrap();
        let e = read_extrinsic(&p).unwrap();
        let x = e * nalgebra::Point3::new(1.0, 0.0, 0.0);
        assert!((x.coords - Vector3::new(1.0, 3.0, 3.0)).norm() < 1e-12);
        std::fs::write(&p, "0 -1 0 1\n1 0 0 2\n0 0 1 3\n").unwrap();
        assert_eq!(read_extrinsic(&p).unwrap(), e);
        std::fs::write(&p, "0 -1 0 1\n1 0 0 2\n0 0 1 3\n0 0 1 1\n").unwrap();
        assert!(read_extrinsic(&p)
            .unwrap_err()
            .to_string()
            .contains("last row"));
    }
}
