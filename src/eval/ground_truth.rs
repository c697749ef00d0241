//! Where ground truth comes from: the LiDAR scans of a KITTI-layout sequence merged in the world
//! frame (the paper's), the scans of any other LiDAR input (a folder of scans, a ROS 2 bag), or a
//! point-cloud file (LAS/LAZ converted to metres, PLY).

use super::coverage::{CoverageBuilder, SensorCoverage};
use crate::frame::PointCloud;
use crate::io::kitti::KittiSequence;
use crate::io::sequence::{FrameRange, InputOptions, RangeInput};
use crate::{Error, Result};
use std::path::PathBuf;

/// Ground truth for evaluation.
#[derive(Clone, Debug)]
pub enum GroundTruth {
    /// All Velodyne scans of a KITTI-layout sequence (the frames given) in the world frame.
    KittiLidar {
        /// Sequence folder.
        sequence: PathBuf,
        /// Poses file, when not at the default place.
        poses: Option<PathBuf>,
        /// The scans used.
        frames: FrameRange,
    },
    /// The scans of a LiDAR input of another layout (a folder of scans, a ROS 2 bag), read as
    /// `reconstruct` reads it (the frames given).
    Scans {
        /// The input.
        input: PathBuf,
        /// How it is read (`source` is LiDAR).
        options: InputOptions,
        /// The scans used.
        frames: FrameRange,
    },
    /// A point cloud file: `.las`, `.laz` (coordinates converted to metres) or `.ply`.
    File(PathBuf),
}

impl GroundTruth {
    /// Ground truth named on the command line: a folder of scans or a ROS 2 bag (its scans in
    /// `frames`), another folder a KITTI sequence (the same), anything else a point-cloud file.
    pub fn from_path(path: PathBuf, poses: Option<PathBuf>, frames: FrameRange) -> Self {
        use crate::io::sequence::{detect_input, RangeSource};
        if detect_input(&path).is_ok_and(|k| k.lidar_or_stereo()) {
            let mut options = InputOptions::new(RangeSource::Lidar);
            options.poses = poses;
            GroundTruth::Scans {
                input: path,
                options,
                frames,
            }
        } else if path.is_dir() {
            GroundTruth::KittiLidar {
                sequence: path,
                poses,
                frames,
            }
        } else {
            GroundTruth::File(path)
        }
    }

    /// Loads the ground-truth points (world frame, metres).
    pub fn load(&self) -> Result<PointCloud> {
        Ok(self.load_with_coverage()?.0)
    }

    /// Loads the ground-truth points and, for LiDAR scans, where they could have measured
    /// ([`SensorCoverage`]; `None` for point-cloud files, which carry no sensor poses).
    pub fn load_with_coverage(&self) -> Result<(PointCloud, Option<SensorCoverage>)> {
        let mut cloud = PointCloud::default();
        match self {
            GroundTruth::KittiLidar {
                sequence,
                poses,
                frames,
            } => {
                // Sized from the scan files, the merged cloud is allocated once (grown by
                // doubling, it would briefly need up to twice its size).
                let seq = KittiSequence::open(sequence, poses.as_deref())?;
                let points: u64 = frames
                    .indices(seq.len())
                    .into_iter()
                    .filter_map(|i| seq.velodyne_path(i))
                    .filter_map(|p| std::fs::metadata(p).ok())
                    .map(|m| m.len() / crate::io::kitti::VELODYNE_POINT_BYTES as u64)
                    .sum();
                cloud.points_m.reserve_exact(points as usize);
            }
            GroundTruth::Scans { .. } => {}
            GroundTruth::File(path) => {
                let ext = path
                    .extension()
                    .and_then(|e| e.to_str())
                    .unwrap_or("")
                    .to_ascii_lowercase();
                let cloud = match ext.as_str() {
                    "las" | "laz" => crate::io::las::read_point_cloud_metres(path)?,
                    "ply" => crate::io::ply::read_ply(path)?.0,
                    _ => {
                        return Err(Error::bad_input(
                            path,
                            "ground truth must be .las, .laz or .ply",
                        ))
                    }
                };
                return Ok((cloud, None));
            }
        }
        let coverage = self.stream(|points| {
            cloud.points_m.extend_from_slice(points);
            Ok(())
        })?;
        Ok((cloud, coverage))
    }

    /// The ground-truth points (world frame, metres) handed to `f` a scan (or, for a file, a
    /// slice of at most 2²⁰ points) at a time, never all at once for scans; and, for LiDAR scans,
    /// where they could have measured. A point-cloud file is read whole first (its own size).
    pub fn stream(
        &self,
        mut f: impl FnMut(&[[f64; 3]]) -> Result<()>,
    ) -> Result<Option<SensorCoverage>> {
        let mut coverage = CoverageBuilder::default();
        let mut world = PointCloud::default();
        let mut each = |scan: &crate::frame::LidarScan| -> Result<()> {
            world.points_m.clear();
            add_scan(&mut world, scan, Some(&mut coverage));
            f(&world.points_m)
        };
        match self {
            GroundTruth::KittiLidar {
                sequence,
                poses,
                frames,
            } => {
                let seq = KittiSequence::open(sequence, poses.as_deref())?;
                for i in frames.indices(seq.len()) {
                    if seq.has_velodyne(i) {
                        each(&seq.velodyne(i)?)?;
                    }
                }
            }
            GroundTruth::Scans {
                input,
                options,
                frames,
            } => {
                let seq = crate::io::sequence::open_input(input, options, None)?;
                for i in frames.indices(seq.len()) {
                    if let RangeInput::Lidar(scan) = seq.read(i)? {
                        each(&scan)?;
                    }
                }
            }
            GroundTruth::File(_) => {
                let (cloud, _) = self.load_with_coverage()?;
                for part in cloud.points_m.chunks(1 << 20) {
                    f(part)?;
                }
                return Ok(None);
            }
        }
        Ok(coverage.build())
    }

    /// A short description for reports.
    pub fn describe(&self) -> String {
        match self {
            GroundTruth::KittiLidar {
                sequence: input,
                frames,
                poses,
            }
            | GroundTruth::Scans {
                input,
                frames,
                options: InputOptions { poses, .. },
            } => {
                let sequence = input;
                let mut which = Vec::new();
                if frames.first > 0 || frames.step > 1 {
                    which.push(format!("frames from {}", frames.first));
                }
                if frames.step > 1 {
                    which.push(format!("step {}", frames.step));
                }
                if let Some(l) = frames.last {
                    which.push(format!("before {l}"));
                }
                if let Some(p) = poses {
                    which.push(format!("poses {}", p.display()));
                }
                match which.is_empty() {
                    true => format!("LiDAR scans of {}", sequence.display()),
                    false => format!(
                        "LiDAR scans of {} ({})",
                        sequence.display(),
                        which.join(", ")
                    ),
                }
            }
            GroundTruth::File(p) => p.display().to_string(),
        }
    }
}

/// All Velodyne scans of the given frames in the world frame: the paper's ground truth.
pub fn merged_lidar(seq: &KittiSequence, frames: &[usize]) -> Result<PointCloud> {
    merge_scans(seq, frames, None)
}

/// [`merged_lidar`], adding each scan to `coverage` when given.
fn merge_scans(
    seq: &KittiSequence,
    frames: &[usize],
    mut coverage: Option<&mut CoverageBuilder>,
) -> Result<PointCloud> {
    // Sized from the scan files, the merged cloud is allocated once (grown by doubling, it would
    // briefly need up to twice its size).
    let points: u64 = frames
        .iter()
        .filter_map(|&i| seq.velodyne_path(i))
        .filter_map(|p| std::fs::metadata(p).ok())
        .map(|m| m.len() / crate::io::kitti::VELODYNE_POINT_BYTES as u64)
        .sum();
    let mut cloud = PointCloud::default();
    cloud.points_m.reserve_exact(points as usize);
    for &i in frames {
        if !seq.has_velodyne(i) {
            continue;
        }
        let scan = seq.velodyne(i)?;
        add_scan(&mut cloud, &scan, coverage.as_deref_mut());
    }
    Ok(cloud)
}

/// Adds `scan`'s points in the world frame to `cloud`, and the scan to `coverage` when given.
fn add_scan(
    cloud: &mut PointCloud,
    scan: &crate::frame::LidarScan,
    coverage: Option<&mut CoverageBuilder>,
) {
    if let Some(c) = coverage {
        c.add(scan);
    }
    let t = scan.world_from_sensor;
    cloud.points_m.extend(scan.points_sensor_m.iter().map(|p| {
        let w = t * nalgebra::Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        [w.x, w.y, w.z]
    }));
}
