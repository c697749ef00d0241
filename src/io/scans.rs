//! A folder of LiDAR scans with a trajectory — what a LiDAR odometry or SLAM system writes — as
//! one [`Sequence`](super::sequence::Sequence) of posed scans, so `--map`, evaluation and every
//! export take it as they take KITTI.
//!
//! # Layout
//! ```text
//! DIR/scans/<name>.pcd|.ply|.las|.laz|.bin   one scan per file, points in the sensor frame (m)
//! DIR/trajectory.tum | trajectory.txt | poses.txt   world_from_body (or --poses FILE)
//! DIR/times.txt                               optional: one time (s) per scan, in scan order
//! DIR/extrinsic.txt                           optional: body_from_sensor (or --extrinsic FILE)
//! ```
//! * Scans are ordered by the number their name holds when every name is a number
//!   (`000042.pcd`, `1317384506.40.pcd`), else by name in natural order (`s2` before `s10`). PCD (ASCII, binary, binary_compressed;
//!   fields `x y z` of any numeric type, `intensity` when present), PLY (vertex `x y z`), LAS/LAZ
//!   (coordinates in the file's units) and KITTI `.bin` (f32 `x y z reflectance`) may be mixed.
//!   Points with a non-finite coordinate (an organised cloud's holes) are dropped.
//! * A scan's pose is `world_from_body · body_from_sensor` (the extrinsic is the identity when
//!   absent). With a timed (TUM) trajectory each scan's time comes from `times.txt`, else from its
//!   name (a decimal number of seconds, or an integer of 16 or more digits: nanoseconds), and its
//!   pose is interpolated there; scans outside the trajectory's span are skipped and counted.
//!   With an untimed (KITTI) trajectory, or names that are frame numbers, scans and poses are
//!   matched by order and must be as many.
//!
//! What it does not do: motion-compensate (de-skew) a scan, or read a scan's PCD `VIEWPOINT`
//! (points are taken as they are, in the sensor frame).

use super::sequence::{RangeInput, Sequence};
use super::trajectory::{read_extrinsic, read_trajectory, Trajectory, TrajectoryFormat};
use crate::frame::LidarScan;
use crate::{Error, Result};
use nalgebra::Isometry3;
use std::path::{Path, PathBuf};

/// The scan file extensions read (lower case).
pub const SCAN_EXTENSIONS: &[&str] = &["pcd", "ply", "las", "laz", "bin"];

/// Trajectory files looked for in the folder, in this order, when `--poses` is not given.
pub const TRAJECTORY_NAMES: &[&str] = &["trajectory.tum", "trajectory.txt", "poses.txt"];

/// A folder of scans, each with its pose.
pub struct ScanFolder {
    dir: PathBuf,
    /// The scans kept (those with a pose), in order, with their `world_from_sensor`.
    scans: Vec<(PathBuf, Isometry3<f64>)>,
    trajectory_path: PathBuf,
    /// The `body_from_sensor` file (`None`: the identity).
    extrinsic_path: Option<PathBuf>,
    matching: &'static str,
    /// Scans skipped: no pose at their time.
    pub skipped_outside: usize,
}

/// Whether `dir` looks like a folder of scans (it has a `scans/` folder).
pub fn is_scan_folder(dir: &Path) -> bool {
    dir.join("scans").is_dir()
}

impl ScanFolder {
    /// Opens `dir` with the trajectory `poses` (default: the first of [`TRAJECTORY_NAMES`]) and
    /// the extrinsic `extrinsic` (default: `extrinsic.txt` when present).
    pub fn open(dir: &Path, poses: Option<&Path>, extrinsic: Option<&Path>) -> Result<ScanFolder> {
        let scans_dir = dir.join("scans");
        let files = list_scans(&scans_dir)?;
        let trajectory_path = match poses {
            Some(p) => p.to_path_buf(),
            None => TRAJECTORY_NAMES
                .iter()
                .map(|n| dir.join(n))
                .find(|p| p.is_file())
                .ok_or_else(|| {
                    Error::bad_input(
                        dir,
                        format!(
                            "a folder of scans needs a trajectory: none of {} here; name one with --poses",
                            TRAJECTORY_NAMES.join(", ")
                        ),
                    )
                })?,
        };
        let (format, trajectory) = read_trajectory(&trajectory_path)?;
        let default_extrinsic = dir.join("extrinsic.txt");
        let extrinsic_path = match extrinsic {
            Some(p) => Some(p.to_path_buf()),
            None => default_extrinsic.is_file().then_some(default_extrinsic),
        };
        let body_from_sensor = match &extrinsic_path {
            Some(p) => read_extrinsic(p)?,
            None => Isometry3::identity(),
        };
        // Scan times matter only to a timed trajectory.
        let times = match format {
            TrajectoryFormat::Tum => scan_times(dir, &files)?,
            TrajectoryFormat::Kitti => None,
        };
        if let Some((t, _)) = &times {
            warn_odd_times(&trajectory, &trajectory_path, t);
        }
        let mut scans = Vec::with_capacity(files.len());
        let mut skipped_outside = 0;
        let matching = match (format, times) {
            (TrajectoryFormat::Tum, Some((times_s, from))) => {
                for (file, t) in files.into_iter().zip(times_s) {
                    match trajectory.at(t) {
                        Some(p) => scans.push((file, p * body_from_sensor)),
                        None => skipped_outside += 1,
                    }
                }
                from
            }
            _ => {
                by_order(&trajectory, &trajectory_path, &files)?;
                scans = files
                    .into_iter()
                    .zip(trajectory.poses())
                    .map(|(f, p)| (f, p * body_from_sensor))
                    .collect();
                "by order"
            }
        };
        if skipped_outside > 0 {
            let (a, b) = trajectory.span_s().unwrap_or_default();
            tracing::warn!(
                "{}: {skipped_outside} scans lie outside the trajectory's time span ({a:.3}–{b:.3} s) and are skipped",
                scans_dir.display()
            );
        }
        if scans.is_empty() {
            return Err(Error::bad_input(
                &trajectory_path,
                format!(
                    "no scan of {} lies within the trajectory's time span",
                    scans_dir.display()
                ),
            ));
        }
        Ok(ScanFolder {
            dir: dir.to_path_buf(),
            scans,
            trajectory_path,
            extrinsic_path,
            matching,
            skipped_outside,
        })
    }

    /// `world_from_sensor` of each scan kept, in order.
    pub fn poses(&self) -> impl Iterator<Item = &Isometry3<f64>> {
        self.scans.iter().map(|(_, p)| p)
    }

    /// The file of scan `i`.
    pub fn path(&self, i: usize) -> Option<&Path> {
        self.scans.get(i).map(|(p, _)| p.as_path())
    }
}

/// Warns when a timed match looks wrong: trajectory times that are frame numbers (0, 1, 2, …:
/// what some odometry tools write in TUM files), or scans that cover a small part of the
/// trajectory's time span.
fn warn_odd_times(trajectory: &Trajectory, path: &Path, scan_times_s: &[f64]) {
    let Some((a, b)) = trajectory.span_s() else {
        return;
    };
    let integers = trajectory.len() > 2 && a == 0.0 && b == (trajectory.len() - 1) as f64;
    let (lo, hi) = scan_times_s
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &t| {
            (l.min(t), h.max(t))
        });
    if integers {
        tracing::warn!(
            "{}: the trajectory's times run 0, 1, …, {}: frame numbers rather than seconds? Each scan is posed at its own time (from times.txt or its name); a KITTI-format trajectory is matched by order instead",
            path.display(),
            trajectory.len() - 1
        );
    } else if b > a && (hi.min(b) - lo.max(a)) < 0.5 * (b - a) {
        tracing::warn!(
            "{}: the scans ({lo:.3}–{hi:.3} s) cover less than half of the trajectory's time span ({a:.3}–{b:.3} s): are both in seconds of the same clock?",
            path.display()
        );
    }
}

/// Fails unless an untimed match pairs every scan with a pose.
fn by_order(trajectory: &Trajectory, path: &Path, files: &[PathBuf]) -> Result<()> {
    if trajectory.len() != files.len() {
        return Err(Error::bad_input(
            path,
            format!(
                "{} poses for {} scans: without time stamps (a KITTI trajectory, or scans named by frame number with no times.txt) scans and poses are matched by order and must be as many",
                trajectory.len(),
                files.len()
            ),
        ));
    }
    Ok(())
}

/// Each scan's time, seconds, and where it came from: `times.txt`, or the names when every
/// name is a time stamp; `None` when neither (match by order).
fn scan_times(dir: &Path, files: &[PathBuf]) -> Result<Option<(Vec<f64>, &'static str)>> {
    let times_path = dir.join("times.txt");
    if times_path.is_file() {
        let times = super::kitti::read_times(&times_path)?;
        if times.len() != files.len() {
            return Err(Error::bad_input(
                &times_path,
                format!("{} times for {} scans", times.len(), files.len()),
            ));
        }
        return Ok(Some((times, "by time (times.txt)")));
    }
    let stamps: Option<Vec<f64>> = files.iter().map(|f| stamp_from_name(f)).collect();
    Ok(stamps.map(|s| (s, "by time (file names)")))
}

/// A time stamp in a file's name: `1317384506.40` (seconds) or an integer of 16 or more digits
/// (nanoseconds); a short integer is a frame number, not a time.
fn stamp_from_name(path: &Path) -> Option<f64> {
    let stem = path.file_stem()?.to_str()?;
    if stem.contains('.') {
        stem.parse::<f64>().ok().filter(|t| t.is_finite())
    } else if stem.len() >= 16 && stem.bytes().all(|b| b.is_ascii_digit()) {
        stem.parse::<u64>().ok().map(|ns| ns as f64 * 1e-9)
    } else {
        None
    }
}

/// The scan files of `dir`, ordered by the number their names hold (when all do), else by name.
fn list_scans(dir: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut files = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| Error::io(dir, e))?.path();
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        if SCAN_EXTENSIONS.contains(&ext.as_str()) && path.is_file() {
            files.push(path);
        }
    }
    if files.is_empty() {
        return Err(Error::bad_input(
            dir,
            format!("no scan file here (.{})", SCAN_EXTENSIONS.join(", .")),
        ));
    }
    let number = |p: &PathBuf| {
        p.file_stem()
            .and_then(|s| s.to_str())
            .and_then(|s| s.parse::<f64>().ok())
    };
    if files.iter().all(|p| number(p).is_some()) {
        files.sort_by(|a, b| number(a).unwrap().total_cmp(&number(b).unwrap()));
    } else {
        files.sort_by(|a, b| natural_cmp(&a.to_string_lossy(), &b.to_string_lossy()));
    }
    Ok(files)
}

/// Natural order: runs of digits compare as numbers (`s2` before `s10`), the rest by bytes.
fn natural_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    let (mut x, mut y) = (a.as_bytes(), b.as_bytes());
    loop {
        match (x.first(), y.first()) {
            (None, None) => return std::cmp::Ordering::Equal,
            (None, _) => return std::cmp::Ordering::Less,
            (_, None) => return std::cmp::Ordering::Greater,
            (Some(c), Some(d)) if c.is_ascii_digit() && d.is_ascii_digit() => {
                let n = x.iter().take_while(|c| c.is_ascii_digit()).count();
                let m = y.iter().take_while(|c| c.is_ascii_digit()).count();
                let (p, q) = (&x[..n], &y[..m]);
                let trim = |s: &[u8]| s.iter().position(|&c| c != b'0').map_or(0, |k| s.len() - k);
                let ord = trim(p)
                    .cmp(&trim(q))
                    .then_with(|| p[n - trim(p)..].cmp(&q[m - trim(q)..]));
                if ord != std::cmp::Ordering::Equal {
                    return ord;
                }
                (x, y) = (&x[n..], &y[m..]);
            }
            (Some(c), Some(d)) => {
                if c != d {
                    return c.cmp(d);
                }
                (x, y) = (&x[1..], &y[1..]);
            }
        }
    }
}

/// Reads one scan file (format by extension) as points in the sensor frame with intensity
/// (empty when the file has none); the pose is left to the caller.
pub fn read_scan(path: &Path) -> Result<LidarScan> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let mut scan = match ext.as_str() {
        "bin" => super::kitti::read_velodyne_bin(path)?,
        "pcd" => read_pcd(path)?,
        "ply" => cloud_scan(super::ply::read_ply(path)?.0),
        "las" | "laz" => cloud_scan(super::las::read_point_cloud(path)?),
        other => {
            return Err(Error::bad_input(
                path,
                format!(
                    "unknown scan format .{other} (expected .{})",
                    SCAN_EXTENSIONS.join(", .")
                ),
            ))
        }
    };
    drop_non_finite(&mut scan);
    Ok(scan)
}

fn cloud_scan(cloud: crate::frame::PointCloud) -> LidarScan {
    LidarScan {
        world_from_sensor: Isometry3::identity(),
        points_sensor_m: cloud
            .points_m
            .iter()
            .map(|p| [p[0] as f32, p[1] as f32, p[2] as f32])
            .collect(),
        intensity: Vec::new(),
    }
}

fn drop_non_finite(scan: &mut LidarScan) {
    let finite = |p: &[f32; 3]| p.iter().all(|v| v.is_finite());
    if scan.points_sensor_m.iter().all(finite) {
        return;
    }
    if scan.intensity.len() == scan.points_sensor_m.len() {
        let kept: Vec<([f32; 3], f32)> = scan
            .points_sensor_m
            .iter()
            .zip(&scan.intensity)
            .filter(|(p, _)| finite(p))
            .map(|(p, i)| (*p, *i))
            .collect();
        (scan.points_sensor_m, scan.intensity) = kept.into_iter().unzip();
    } else {
        scan.points_sensor_m.retain(finite);
    }
}

/// The first value of a PCD field as f64.
fn pcd_value(f: &pcd_rs::Field) -> Option<f64> {
    use pcd_rs::Field as F;
    Some(match f {
        F::I8(v) => *v.first()? as f64,
        F::I16(v) => *v.first()? as f64,
        F::I32(v) => *v.first()? as f64,
        F::I64(v) => *v.first()? as f64,
        F::U8(v) => *v.first()? as f64,
        F::U16(v) => *v.first()? as f64,
        F::U32(v) => *v.first()? as f64,
        F::U64(v) => *v.first()? as f64,
        F::F32(v) => *v.first()? as f64,
        F::F64(v) => *v.first()?,
    })
}

/// Reads a PCD file (any of its three encodings) through `pcd-rs`.
fn read_pcd(path: &Path) -> Result<LidarScan> {
    let bad = |e: pcd_rs::Error| Error::bad_input(path, format!("PCD: {e}"));
    let reader = pcd_rs::DynReader::open(path).map_err(bad)?;
    let fields = &reader.meta().field_defs;
    let find = |name: &str| fields.iter().position(|f| f.name == name);
    let (Some(x), Some(y), Some(z)) = (find("x"), find("y"), find("z")) else {
        let names: Vec<&str> = fields.iter().map(|f| f.name.as_str()).collect();
        return Err(Error::bad_input(
            path,
            format!("PCD fields {names:?} lack one of x, y, z"),
        ));
    };
    let intensity = find("intensity");
    let n = reader.meta().num_points as usize;
    let mut points = Vec::with_capacity(n);
    let mut values = Vec::with_capacity(if intensity.is_some() { n } else { 0 });
    for record in reader {
        let record = record.map_err(bad)?;
        let get = |k: usize| record.0.get(k).and_then(pcd_value).unwrap_or(f64::NAN);
        points.push([get(x) as f32, get(y) as f32, get(z) as f32]);
        if let Some(k) = intensity {
            values.push(get(k) as f32);
        }
    }
    if points.len() != n {
        return Err(Error::bad_input(
            path,
            format!(
                "truncated PCD: the header announces {n} points, {} were read",
                points.len()
            ),
        ));
    }
    Ok(LidarScan {
        world_from_sensor: Isometry3::identity(),
        points_sensor_m: points,
        intensity: values,
    })
}

impl Sequence for ScanFolder {
    fn len(&self) -> usize {
        self.scans.len()
    }
    fn read(&self, i: usize) -> Result<RangeInput> {
        let (path, pose) = self.scans.get(i).ok_or_else(|| {
            Error::bad_input(
                &self.dir,
                format!("no scan {i} (the folder has {})", self.scans.len()),
            )
        })?;
        let mut scan = read_scan(path)?;
        if scan.points_sensor_m.is_empty() {
            tracing::warn!(
                "{}: the scan holds no point; nothing to fuse",
                path.display()
            );
        }
        scan.world_from_sensor = *pose;
        Ok(RangeInput::Lidar(scan))
    }
    fn describe(&self) -> String {
        format!(
            "folder of scans {} ({} scans, poses {} from {}, {})",
            self.dir.display(),
            self.scans.len(),
            self.matching,
            self.trajectory_path.display(),
            match &self.extrinsic_path {
                Some(p) => format!("extrinsic {}", p.display()),
                None => "no extrinsic: the poses are the sensor's".to_string(),
            }
        )
    }
    fn fingerprint(&self) -> u64 {
        super::sequence::pose_digest(self.scans.len(), self.poses())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_stamps_only_when_they_look_like_times() {
        let s = |n: &str| stamp_from_name(Path::new(n));
        assert_eq!(s("1317384506.40.pcd"), Some(1317384506.40));
        assert!((s("1690000000123456789.bin").unwrap() - 1_690_000_000.123_456_7).abs() < 1e-6);
        assert_eq!(s("000042.pcd"), None);
        assert_eq!(s("scan_a.pcd"), None);
    }

    #[test]
    fn names_sort_naturally() {
        let mut v = vec!["s10.pcd", "s2.pcd", "s1.pcd", "a.pcd", "s02b.pcd"];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(v, ["a.pcd", "s1.pcd", "s2.pcd", "s02b.pcd", "s10.pcd"]);
    }

    #[test]
    fn untimed_poses_must_match_the_scans_one_to_one() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("scans")).unwrap();
        for i in [2, 10, 1] {
            let bytes: Vec<u8> = [1.0f32, 2.0, 3.0, 0.5]
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect();
            std::fs::write(dir.path().join(format!("scans/{i}.bin")), bytes).unwrap();
        }
        let line = "1 0 0 0 0 1 0 0 0 0 1 0\n";
        std::fs::write(dir.path().join("poses.txt"), line.repeat(2)).unwrap();
        let e = ScanFolder::open(dir.path(), None, None)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("2 poses for 3 scans") && e.contains("by order"),
            "{e}"
        );
        std::fs::write(dir.path().join("poses.txt"), line.repeat(3)).unwrap();
        let f = ScanFolder::open(dir.path(), None, None).unwrap();
        // Numeric names sort as numbers: 1, 2, 10.
        let names: Vec<_> = (0..3)
            .map(|i| f.path(i).unwrap().file_name().unwrap().to_owned())
            .collect();
        assert_eq!(names, ["1.bin", "2.bin", "10.bin"]);
    }
}
