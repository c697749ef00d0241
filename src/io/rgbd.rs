//! RGB-D depth-frame sequences: the TUM RGB-D benchmark layout and the simple numbered layout
//! of slambook2 (`color/N.png`, `depth/N.pgm`, `pose.txt`).
//!
//! What it does: indexes a sequence folder at open time (lists, poses, associations) and loads
//! each [`DepthFrame`] on demand through the [`DepthSequence`] trait: depth in metres with 0 →
//! NaN, the registered colour image when there is one, a camera-to-world pose.
//!
//! What it does not do: register depth to colour (both layouts ship registered images), undistort,
//! or interpolate poses (the nearest ground-truth sample within a tolerance is taken).
//!
//! # TUM RGB-D layout (<https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats>)
//! * `rgb.txt`, `depth.txt`: lines `timestamp relative/path.png`; lines starting with `#` are
//!   comments. Timestamps are seconds (UNIX time, fractional).
//! * `groundtruth.txt`: lines `timestamp tx ty tz qx qy qz qw`, the pose of the colour camera's
//!   optical centre in the world (`world_from_camera`; x right, y down, z forward), metres.
//! * depth PNGs: 16-bit grey, 5000 units per metre (TUM), 0 = no measurement.
//! * Association: each depth frame takes the nearest-in-time pose and colour image within
//!   `max_time_diff_s` (0.02 s by default). Depth frames with no pose within the tolerance are
//!   dropped (logged); those with no colour get `color: None`.
//!
//! # Simple layout (slambook2 `ch5/rgbd`)
//! * `pose.txt`: line `k` (1-based) is `tx ty tz qx qy qz qw`, `world_from_camera` of frame `k`.
//! * `depth/k.pgm` (binary PGM, 16-bit big-endian, millimetres) or `depth/k.png` / `.tif`
//!   (16-bit single channel; any format of [`super::image::IMAGE_EXTENSIONS`]).
//! * `color/k.png` (or `.jpg`, `.ppm`, `.tif`, …): 8-bit colour registered to the depth (optional).
//! * Frame `i` of the sequence (0-based) is file number `i + first_index` (1 for slambook2).

use super::image::{read_depth_pgm_u16, read_depth_u16, read_rgb};
use super::text::{parse_n, read_to_string};
use super::DepthSequence;
use crate::camera::{PinholeIntrinsics, WorldFromCamera};
use crate::error::{Error, Result};
use crate::frame::{DepthFrame, DepthImage, RgbImage};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::path::{Path, PathBuf};

/// `tx ty tz qx qy qz qw` → isometry; the quaternion is normalised (it must be within 50 % of
/// unit length, else the line is rejected).
pub(crate) fn pose_from_tq(path: &Path, line_no: usize, v: &[f64]) -> Result<Isometry3<f64>> {
    let q = Quaternion::new(v[6], v[3], v[4], v[5]);
    let n = q.norm();
    if !(0.5..=1.5).contains(&n) {
        return Err(Error::bad_input(
            path,
            format!("line {line_no}: quaternion (qx qy qz qw) has norm {n}, not a rotation"),
        ));
    }
    Ok(Isometry3::from_parts(
        Translation3::new(v[0], v[1], v[2]),
        UnitQuaternion::from_quaternion(q),
    ))
}

/// Non-comment, non-empty lines with their 1-based numbers.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(k, l)| (k + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

/// Reads a TUM list file (`timestamp path` per line), sorted by time; paths are resolved
/// relative to the file's folder.
pub fn read_tum_list(path: impl AsRef<Path>) -> Result<Vec<(f64, PathBuf)>> {
    let path = path.as_ref();
    let base = path.parent().unwrap_or(Path::new("."));
    let text = read_to_string(path)?;
    let mut out = Vec::new();
    for (line_no, line) in data_lines(&text) {
        let mut it = line.split_whitespace();
        let (Some(t), Some(file), None) = (it.next(), it.next(), it.next()) else {
            return Err(Error::bad_input(
                path,
                format!("line {line_no}: expected 'timestamp path', found '{line}'"),
            ));
        };
        let t: f64 = t.parse().map_err(|_| {
            Error::bad_input(path, format!("line {line_no}: '{t}' is not a timestamp"))
        })?;
        out.push((t, base.join(file)));
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(out)
}

/// Reads a TUM trajectory (`timestamp tx ty tz qx qy qz qw` per line), sorted by time.
pub fn read_tum_trajectory(path: impl AsRef<Path>) -> Result<Vec<(f64, WorldFromCamera)>> {
    let path = path.as_ref();
    let text = read_to_string(path)?;
    let mut out = Vec::new();
    for (line_no, line) in data_lines(&text) {
        let v = parse_n(path, line_no, line, 8)?;
        out.push((v[0], pose_from_tq(path, line_no, &v[1..])?));
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(out)
}

/// Writes a TUM trajectory file (`timestamp tx ty tz qx qy qz qw`, 9 decimals).
pub fn write_tum_trajectory(
    path: impl AsRef<Path>,
    poses: &[(f64, WorldFromCamera)],
) -> Result<()> {
    let path = path.as_ref();
    let mut s = String::from("# timestamp tx ty tz qx qy qz qw\n");
    for (t, p) in poses {
        let q = p.rotation.quaternion();
        let tr = p.translation.vector;
        s.push_str(&format!(
            "{t:.6} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}\n",
            tr.x, tr.y, tr.z, q.i, q.j, q.k, q.w
        ));
    }
    crate::io::atomic::write_file(path, s.as_bytes())
}

/// Index of the element of sorted `times` nearest to `t`, if within `max_dt`.
fn nearest(times: &[f64], t: f64, max_dt: f64) -> Option<usize> {
    let k = times.partition_point(|&x| x < t);
    let mut best: Option<(usize, f64)> = None;
    for j in [k.wrapping_sub(1), k] {
        if let Some(&x) = times.get(j) {
            let d = (x - t).abs();
            if d <= max_dt && best.is_none_or(|(_, bd)| d < bd) {
                best = Some((j, d));
            }
        }
    }
    best.map(|(j, _)| j)
}

/// Options of a TUM RGB-D sequence.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TumOptions {
    /// Intrinsics of the (registered) depth image; width/height are replaced by each depth
    /// image's own size.
    pub intrinsics: PinholeIntrinsics,
    /// Depth PNG units per metre (5000 for TUM).
    pub depth_units_per_m: f64,
    /// Largest time difference accepted when associating depth with colour and poses, seconds.
    pub max_time_diff_s: f64,
}

impl Default for TumOptions {
    /// TUM's ROS default intrinsics (fx = fy = 525, cx = 319.5, cy = 239.5, 640×480), 5000
    /// units per metre, 0.02 s tolerance.
    fn default() -> Self {
        TumOptions {
            intrinsics: PinholeIntrinsics {
                fx: 525.0,
                fy: 525.0,
                cx: 319.5,
                cy: 239.5,
                width: 640,
                height: 480,
            },
            depth_units_per_m: 5000.0,
            max_time_diff_s: 0.02,
        }
    }
}

#[derive(Clone, Debug)]
struct TumFrame {
    time_s: f64,
    depth: PathBuf,
    rgb: Option<PathBuf>,
    world_from_camera: WorldFromCamera,
}

/// A TUM RGB-D sequence (see the module doc for the layout and association rules).
#[derive(Clone, Debug)]
pub struct TumRgbdSequence {
    dir: PathBuf,
    options: TumOptions,
    frames: Vec<TumFrame>,
}

impl TumRgbdSequence {
    /// Opens the sequence folder `dir` holding `depth.txt`, `groundtruth.txt` and (optionally)
    /// `rgb.txt`. Fails when no depth frame can be associated with a pose.
    pub fn open(dir: impl AsRef<Path>, options: TumOptions) -> Result<TumRgbdSequence> {
        let dir = dir.as_ref().to_path_buf();
        if !(options.depth_units_per_m > 0.0 && options.max_time_diff_s >= 0.0) {
            return Err(Error::InvalidArgument(format!(
                "bad TUM options {options:?}"
            )));
        }
        let depth = read_tum_list(dir.join("depth.txt"))?;
        let rgb_path = dir.join("rgb.txt");
        let rgb = if rgb_path.exists() {
            read_tum_list(&rgb_path)?
        } else {
            Vec::new()
        };
        let gt_path = dir.join("groundtruth.txt");
        let gt = read_tum_trajectory(&gt_path)?;
        let rgb_times: Vec<f64> = rgb.iter().map(|r| r.0).collect();
        let gt_times: Vec<f64> = gt.iter().map(|g| g.0).collect();
        let max_dt = options.max_time_diff_s;
        let mut frames = Vec::with_capacity(depth.len());
        let mut no_pose = 0;
        let mut no_rgb = 0;
        for (t, depth) in depth {
            let Some(g) = nearest(&gt_times, t, max_dt) else {
                no_pose += 1;
                continue;
            };
            let rgb = nearest(&rgb_times, t, max_dt).map(|k| rgb[k].1.clone());
            no_rgb += usize::from(rgb.is_none());
            frames.push(TumFrame {
                time_s: t,
                depth,
                rgb,
                world_from_camera: gt[g].1,
            });
        }
        if no_pose > 0 {
            tracing::info!(
                "{}: dropped {no_pose} depth frames with no pose within {max_dt} s",
                dir.display()
            );
        }
        if no_rgb > 0 {
            tracing::debug!(
                "{}: {no_rgb} depth frames have no colour within {max_dt} s",
                dir.display()
            );
        }
        if frames.is_empty() && no_pose > 0 {
            return Err(Error::bad_input(
                &gt_path,
                format!("none of the {no_pose} depth frames has a pose within {max_dt} s"),
            ));
        }
        Ok(TumRgbdSequence {
            dir,
            options,
            frames,
        })
    }

    /// The sequence folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Timestamp of frame `i` (its depth image), seconds.
    pub fn time_s(&self, i: usize) -> Option<f64> {
        self.frames.get(i).map(|f| f.time_s)
    }

    /// Pose of frame `i` without loading images.
    pub fn pose(&self, i: usize) -> Option<WorldFromCamera> {
        self.frames.get(i).map(|f| f.world_from_camera)
    }
}

/// Checks colour against depth size and builds the frame.
fn assemble(
    intrinsics: PinholeIntrinsics,
    world_from_camera: WorldFromCamera,
    depth_m: DepthImage,
    color: Option<(PathBuf, RgbImage)>,
) -> Result<DepthFrame> {
    let color = match color {
        Some((path, c)) => {
            if (c.width, c.height) != (depth_m.width, depth_m.height) {
                return Err(Error::bad_input(
                    path,
                    format!(
                        "colour image is {}x{} but its depth image is {}x{}",
                        c.width, c.height, depth_m.width, depth_m.height
                    ),
                ));
            }
            Some(c)
        }
        None => None,
    };
    let intrinsics = PinholeIntrinsics {
        width: depth_m.width,
        height: depth_m.height,
        ..intrinsics
    };
    Ok(DepthFrame {
        intrinsics,
        world_from_camera,
        depth_m,
        color,
    })
}

fn out_of_range(i: usize, len: usize) -> Error {
    Error::InvalidArgument(format!(
        "frame {i} is out of range (sequence has {len} frames)"
    ))
}

impl DepthSequence for TumRgbdSequence {
    fn len(&self) -> usize {
        self.frames.len()
    }

    fn pose(&self, i: usize) -> Option<WorldFromCamera> {
        TumRgbdSequence::pose(self, i)
    }

    fn frame(&self, i: usize) -> Result<DepthFrame> {
        let f = self
            .frames
            .get(i)
            .ok_or_else(|| out_of_range(i, self.frames.len()))?;
        let depth = read_depth_u16(&f.depth, self.options.depth_units_per_m)?;
        let color = match &f.rgb {
            Some(p) => Some((p.clone(), read_rgb(p)?)),
            None => None,
        };
        assemble(self.options.intrinsics, f.world_from_camera, depth, color)
    }
}

/// Options of the simple numbered RGB-D layout.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimpleRgbdOptions {
    /// Intrinsics (width/height are replaced by each depth image's size).
    pub intrinsics: PinholeIntrinsics,
    /// Depth units per metre (1000 for millimetres).
    pub depth_units_per_m: f64,
    /// File number of frame 0 (1 for slambook2).
    pub first_index: usize,
}

impl SimpleRgbdOptions {
    /// slambook2 `ch5/rgbd`: fx = 518, fy = 519, cx = 325.5, cy = 253.5 (from its `joinMap.cpp`),
    /// 640×480, millimetres, files numbered from 1.
    pub fn slambook2() -> Self {
        SimpleRgbdOptions {
            intrinsics: PinholeIntrinsics {
                fx: 518.0,
                fy: 519.0,
                cx: 325.5,
                cy: 253.5,
                width: 640,
                height: 480,
            },
            depth_units_per_m: 1000.0,
            first_index: 1,
        }
    }
}

impl Default for SimpleRgbdOptions {
    fn default() -> Self {
        Self::slambook2()
    }
}

/// A sequence in the simple numbered layout (see the module doc).
#[derive(Clone, Debug)]
pub struct SimpleRgbdSequence {
    dir: PathBuf,
    options: SimpleRgbdOptions,
    poses: Vec<WorldFromCamera>,
    depth: Vec<PathBuf>,
    color: Vec<Option<PathBuf>>,
}

impl SimpleRgbdSequence {
    /// Opens `dir`; one frame per line of `pose.txt`, each of which must have a depth file.
    pub fn open(dir: impl AsRef<Path>, options: SimpleRgbdOptions) -> Result<SimpleRgbdSequence> {
        let dir = dir.as_ref().to_path_buf();
        if !(options.depth_units_per_m > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "bad RGB-D options {options:?}"
            )));
        }
        let pose_path = dir.join("pose.txt");
        let text = read_to_string(&pose_path)?;
        let mut poses = Vec::new();
        for (line_no, line) in data_lines(&text) {
            let v = parse_n(&pose_path, line_no, line, 7)?;
            poses.push(pose_from_tq(&pose_path, line_no, &v)?);
        }
        let mut depth = Vec::with_capacity(poses.len());
        let mut color = Vec::with_capacity(poses.len());
        for i in 0..poses.len() {
            let n = i + options.first_index;
            let pgm = dir.join(format!("depth/{n}.pgm"));
            let Some(d) = super::image::find_image(&dir.join("depth"), &n.to_string()) else {
                return Err(Error::bad_input(
                    &pgm,
                    format!(
                        "missing depth image for frame {i} ({} has {} poses)",
                        pose_path.display(),
                        poses.len()
                    ),
                ));
            };
            depth.push(d);
            color.push(super::image::find_image(&dir.join("color"), &n.to_string()));
        }
        Ok(SimpleRgbdSequence {
            dir,
            options,
            poses,
            depth,
            color,
        })
    }

    /// The sequence folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Pose of frame `i` without loading images.
    pub fn pose(&self, i: usize) -> Option<WorldFromCamera> {
        self.poses.get(i).copied()
    }
}

impl DepthSequence for SimpleRgbdSequence {
    fn len(&self) -> usize {
        self.poses.len()
    }

    fn pose(&self, i: usize) -> Option<WorldFromCamera> {
        SimpleRgbdSequence::pose(self, i)
    }

    fn frame(&self, i: usize) -> Result<DepthFrame> {
        let path = self
            .depth
            .get(i)
            .ok_or_else(|| out_of_range(i, self.poses.len()))?;
        let units = self.options.depth_units_per_m;
        let is_pgm = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("pgm"));
        let depth = if is_pgm {
            read_depth_pgm_u16(path, units)?
        } else {
            read_depth_u16(path, units)?
        };
        let color = match &self.color[i] {
            Some(p) => Some((p.clone(), read_rgb(p)?)),
            None => None,
        };
        assemble(self.options.intrinsics, self.poses[i], depth, color)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_within_tolerance() {
        let t = [1.0, 2.0, 3.0];
        assert_eq!(nearest(&t, 2.01, 0.02), Some(1));
        assert_eq!(nearest(&t, 2.49, 0.6), Some(1));
        assert_eq!(nearest(&t, 2.51, 0.6), Some(2));
        assert_eq!(nearest(&t, 0.5, 0.02), None);
        assert_eq!(nearest(&t, 3.019, 0.02), Some(2));
        assert_eq!(nearest(&[], 1.0, 1.0), None);
    }
}
