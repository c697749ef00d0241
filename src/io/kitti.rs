//! KITTI odometry: calibration, poses, timestamps, rectified images and Velodyne scans.
//!
//! What it does: opens one sequence folder of the official odometry layout, validates it, and
//! loads frames on demand as the crate's types ([`GreyImage`], [`RgbImage`], [`LidarScan`]); it
//! also writes calibration, poses, times and `.bin` scans in the same format (for round trips and
//! the synthetic city).
//!
//! What it does not do: KITTI *raw* (`calib_cam_to_cam.txt`, OXTS) or tracking/object layouts,
//! undistortion (odometry images are already rectified), motion compensation of scans.
//!
//! # Layout
//! ```text
//! <root>/sequences/NN/calib.txt          P0: 12 numbers, P1:, P2:, P3:, Tr: 12 numbers
//! <root>/sequences/NN/times.txt          one timestamp (s) per line, frame i on line i+1
//! <root>/sequences/NN/image_0/000000.png grey left  (image_1: grey right)
//! <root>/sequences/NN/image_2/000000.png colour left (image_3: colour right)
//! <root>/sequences/NN/velodyne/000000.bin
//! <root>/poses/NN.txt                    12 numbers per line (absent for sequences 11–21)
//! ```
//! * `calib.txt`: lines `KEY: v0 … v11`, a 3×4 matrix row-major. `P0..P3` are the rectified
//!   projection matrices of cameras 0..3 **from the cam0 frame**: `P_i = K_i·[I | t_i]`, so a
//!   point `X` in cam0 coordinates lands at pixel `P_i·[X;1]` of camera `i`, and `t_i = K_i⁻¹·P_i[:,3]`
//!   is the translation `cam_i_from_cam0` (rotation identity after rectification). Camera `i`'s
//!   centre in cam0 coordinates is `−t_i`; for sequence 00 cam1 sits 0.537 m to the right of cam0
//!   (`t_1 = (−386.1448/718.856, 0, 0)`) and cam2 about 0.06 m to its left. `Tr` (also accepted
//!   as `Tr_velo_to_cam`) is `cam0_from_velo`: `X_cam0 = Tr·[X_velo;1]`. Other keys are ignored.
//! * `poses/NN.txt`: line `i` holds the 3×4 row-major `world_from_cam0` of frame `i`; the world
//!   frame is cam0 of frame 0 (x right, y down, z forward). Rotations are snapped to the nearest
//!   rotation (SVD) since they are printed with ~7 significant digits.
//! * `velodyne/*.bin`: little-endian `f32` quadruples `x, y, z, reflectance` per point (16
//!   bytes), sensor frame (x forward, y left, z up), metres; reflectance in [0, 1]. No header.
//! * Frame files are named by their decimal index (`000042.png`; any zero padding is accepted);
//!   images may be in any format of [`super::image::IMAGE_EXTENSIONS`] (`000042.jpg`, `.tif`, …).
//!
//! # Frame count
//! The sequence length `N` is the number of lines of `times.txt` if present, else the number of
//! poses, else the largest frame count found in `image_0..3` and `velodyne`. When both times and
//! poses exist their counts must agree. `image_0` and `velodyne`, when not empty, must hold
//! exactly `N` frames (they are the primary streams); `image_1..3` may hold any subset (the
//! shared test folder has `image_1` for frame 0 only). A frame file with index ≥ `N` is an error.

use super::image::{read_grey, read_rgb};
use super::text::{fmt_e, parse_n, read_to_string};
use crate::camera::{PinholeIntrinsics, WorldFromCamera};
use crate::error::{Error, Result};
use crate::frame::{GreyImage, LidarScan, RgbImage};
use nalgebra::{Isometry3, Matrix3, Matrix3x4, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Calibration of a KITTI odometry sequence (`calib.txt`).
#[derive(Clone, Debug, PartialEq)]
pub struct KittiCalib {
    /// Rectified projection matrices of cameras 0..3, pixels, each mapping cam0-frame points
    /// (metres, homogeneous) to homogeneous pixels of that camera.
    pub p: [Matrix3x4<f64>; 4],
    /// The LiDAR-to-cam0 transform (`Tr`): `X_cam0 = cam0_from_velo · X_velo`, metres.
    pub cam0_from_velo: Isometry3<f64>,
}

impl KittiCalib {
    /// Reads `calib.txt`; errors name the file and line.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = read_to_string(path)?;
        Self::parse(path, &text)
    }

    /// Parses the text of a `calib.txt`; `path` is only used in errors.
    pub fn parse(path: &Path, text: &str) -> Result<Self> {
        let mut p: [Option<Matrix3x4<f64>>; 4] = [None; 4];
        let mut tr: Option<(usize, Matrix3x4<f64>)> = None;
        for (k, line) in text.lines().enumerate() {
            let line_no = k + 1;
            let line = line.trim();
            if line.is_empty() {
                continue;
            }
            let Some((key, values)) = line.split_once(':') else {
                return Err(Error::bad_input(
                    path,
                    format!("line {line_no}: expected 'KEY: 12 numbers', found '{line}'"),
                ));
            };
            let slot = match key.trim() {
                "P0" => Some(0),
                "P1" => Some(1),
                "P2" => Some(2),
                "P3" => Some(3),
                _ => None,
            };
            let is_tr = matches!(key.trim(), "Tr" | "Tr_velo_to_cam" | "Tr_velo_cam");
            if slot.is_none() && !is_tr {
                continue;
            }
            let v = parse_n(path, line_no, values, 12).map_err(|e| match e {
                Error::BadInput { path, message } => Error::BadInput {
                    path,
                    message: format!("{message} (key {})", key.trim()),
                },
                other => other,
            })?;
            let m = Matrix3x4::from_row_slice(&v);
            match slot {
                Some(i) => p[i] = Some(m),
                None => tr = Some((line_no, m)),
            }
        }
        let mut out = [Matrix3x4::zeros(); 4];
        for (i, m) in p.iter().enumerate() {
            let m = m.ok_or_else(|| Error::bad_input(path, format!("missing line 'P{i}:'")))?;
            if m[(0, 0)] <= 0.0 || m[(1, 1)] <= 0.0 || (m[(2, 2)] - 1.0).abs() > 1e-6 {
                return Err(Error::bad_input(
                    path,
                    format!("P{i} is not a rectified projection matrix (need fx, fy > 0 and P[2,2] = 1)"),
                ));
            }
            out[i] = m;
        }
        let (tr_line, tr) = tr.ok_or_else(|| Error::bad_input(path, "missing line 'Tr:'"))?;
        let cam0_from_velo = isometry_from_3x4(&tr)
            .map_err(|msg| Error::bad_input(path, format!("line {tr_line}: Tr: {msg}")))?;
        Ok(KittiCalib {
            p: out,
            cam0_from_velo,
        })
    }

    /// Intrinsics of camera `cam` (0..3) for an image of `width × height` pixels.
    pub fn intrinsics(&self, cam: usize, width: u32, height: u32) -> PinholeIntrinsics {
        let p = &self.p[cam];
        PinholeIntrinsics {
            fx: p[(0, 0)],
            fy: p[(1, 1)],
            cx: p[(0, 2)],
            cy: p[(1, 2)],
            width,
            height,
        }
    }

    /// Translation `t_i = K_i⁻¹·P_i[:,3]` of camera `cam` relative to cam0, metres:
    /// `X_cam = X_cam0 + t_i` (rectified cameras share cam0's orientation).
    pub fn cam_from_cam0_translation_m(&self, cam: usize) -> Vector3<f64> {
        super::calib::projection_translation_m(&self.p[cam])
    }

    /// The rigid transform `cam_from_cam0` of camera `cam` (identity rotation, see
    /// [`Self::cam_from_cam0_translation_m`]).
    pub fn cam_from_cam0(&self, cam: usize) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.cam_from_cam0_translation_m(cam)),
            UnitQuaternion::identity(),
        )
    }

    /// The `cam_from_velo` transform of camera `cam`.
    pub fn cam_from_velo(&self, cam: usize) -> Isometry3<f64> {
        self.cam_from_cam0(cam) * self.cam0_from_velo
    }

    /// Stereo baseline in metres between a `left` and a `right` camera: the x distance between
    /// their centres, `t_left.x − t_right.x` (positive when `right` is to the right). For the
    /// grey pair (0, 1) with `tz = 0` this is `−(P1[0,3] − P0[0,3]) / fx`.
    pub fn baseline_m(&self, left: usize, right: usize) -> f64 {
        self.cam_from_cam0_translation_m(left).x - self.cam_from_cam0_translation_m(right).x
    }

    /// Writes this calibration as `calib.txt` (`%.12e`, as the official files).
    pub fn write(&self, path: impl AsRef<Path>) -> Result<()> {
        write_calib(path, self)
    }
}

/// Converts a 3×4 `[R | t]` to an isometry, snapping `R` to the nearest rotation (SVD). Fails
/// on reflections and on matrices farther than 0.01 (Frobenius) from any rotation.
pub(crate) fn isometry_from_3x4(m: &Matrix3x4<f64>) -> std::result::Result<Isometry3<f64>, String> {
    if m.iter().any(|v| !v.is_finite()) {
        return Err("non-finite value".into());
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let svd = r.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err("SVD failed".into());
    };
    let nearest = u * v_t;
    if nearest.determinant() < 0.0 {
        return Err("rotation part is a reflection (determinant < 0)".into());
    }
    let err = (nearest - r).norm();
    if err > 1e-2 {
        return Err(format!(
            "rotation part is not orthonormal (distance {err:.3e} to the nearest rotation)"
        ));
    }
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(nearest));
    Ok(Isometry3::from_parts(
        Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
        rot,
    ))
}

/// Reads a KITTI pose file: one `world_from_cam0` 3×4 row-major matrix per non-empty line.
/// Rotations are snapped to the nearest rotation; errors name the file and line.
pub fn read_poses(path: impl AsRef<Path>) -> Result<Vec<Isometry3<f64>>> {
    let path = path.as_ref();
    let text = read_to_string(path)?;
    let mut poses = Vec::new();
    for (k, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let v = parse_n(path, k + 1, line, 12)?;
        let pose = isometry_from_3x4(&Matrix3x4::from_row_slice(&v))
            .map_err(|msg| Error::bad_input(path, format!("line {}: {msg}", k + 1)))?;
        poses.push(pose);
    }
    Ok(poses)
}

/// Reads `times.txt`: one timestamp in seconds per non-empty line.
pub fn read_times(path: impl AsRef<Path>) -> Result<Vec<f64>> {
    let path = path.as_ref();
    let text = read_to_string(path)?;
    let mut times = Vec::new();
    for (k, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        times.push(parse_n(path, k + 1, line, 1)?[0]);
    }
    Ok(times)
}

fn write_text(path: &Path, text: &str) -> Result<()> {
    crate::io::atomic::write_file(path, text.as_bytes())
}

fn row_major_3x4(m: &Matrix3x4<f64>, digits: usize) -> String {
    let mut s = String::new();
    for r in 0..3 {
        for c in 0..4 {
            if !s.is_empty() {
                s.push(' ');
            }
            s.push_str(&fmt_e(m[(r, c)], digits));
        }
    }
    s
}

fn isometry_3x4(iso: &Isometry3<f64>) -> Matrix3x4<f64> {
    iso.to_homogeneous().fixed_view::<3, 4>(0, 0).into_owned()
}

/// Writes `calib.txt` with `P0..P3` and `Tr` (`%.12e`, one space between numbers).
pub fn write_calib(path: impl AsRef<Path>, calib: &KittiCalib) -> Result<()> {
    let mut s = String::new();
    for (i, p) in calib.p.iter().enumerate() {
        s.push_str(&format!("P{i}: {}\n", row_major_3x4(p, 12)));
    }
    s.push_str(&format!(
        "Tr: {}\n",
        row_major_3x4(&isometry_3x4(&calib.cam0_from_velo), 12)
    ));
    write_text(path.as_ref(), &s)
}

/// Writes a pose file, one `world_from_cam0` per line (12 numbers, `%.9e`, i.e. 1 µm at 1 km).
pub fn write_poses(path: impl AsRef<Path>, poses: &[Isometry3<f64>]) -> Result<()> {
    let mut s = String::with_capacity(poses.len() * 200);
    for pose in poses {
        s.push_str(&row_major_3x4(&isometry_3x4(pose), 9));
        s.push('\n');
    }
    write_text(path.as_ref(), &s)
}

/// Writes `times.txt`, one timestamp (seconds, `%.9e`) per line.
pub fn write_times(path: impl AsRef<Path>, times_s: &[f64]) -> Result<()> {
    let mut s = String::with_capacity(times_s.len() * 17);
    for &t in times_s {
        s.push_str(&fmt_e(t, 9));
        s.push('\n');
    }
    write_text(path.as_ref(), &s)
}

/// Writes a Velodyne `.bin`: per point `x, y, z, reflectance` as little-endian f32.
pub fn write_velodyne_bin(
    path: impl AsRef<Path>,
    points_sensor_m: &[[f32; 3]],
    reflectance: &[f32],
) -> Result<()> {
    let path = path.as_ref();
    if points_sensor_m.len() != reflectance.len() {
        return Err(Error::InvalidArgument(format!(
            "{}: {} points but {} reflectances",
            path.display(),
            points_sensor_m.len(),
            reflectance.len()
        )));
    }
    let mut bytes = Vec::with_capacity(points_sensor_m.len() * VELODYNE_POINT_BYTES);
    for (p, r) in points_sensor_m.iter().zip(reflectance) {
        for v in [p[0], p[1], p[2], *r] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    crate::io::atomic::write_file(path, &bytes)
}

/// Bytes per point of a Velodyne `.bin` scan: `x, y, z, reflectance` as little-endian `f32`.
pub const VELODYNE_POINT_BYTES: usize = 16;

/// Reads a Velodyne `.bin` scan into a [`LidarScan`] whose `world_from_sensor` is the
/// identity. Points with a non-finite coordinate are dropped (counted in a debug log); a size
/// that is not a multiple of 16 bytes is an error.
pub fn read_velodyne_bin(path: impl AsRef<Path>) -> Result<LidarScan> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    if bytes.len() % VELODYNE_POINT_BYTES != 0 {
        return Err(Error::bad_input(
            path,
            format!(
                "truncated Velodyne scan: {} bytes is not a multiple of 16 (x, y, z, reflectance as f32)",
                bytes.len()
            ),
        ));
    }
    let n = bytes.len() / VELODYNE_POINT_BYTES;
    let mut points = Vec::with_capacity(n);
    let mut intensity = Vec::with_capacity(n);
    let f = |c: &[u8], k: usize| {
        f32::from_le_bytes([c[4 * k], c[4 * k + 1], c[4 * k + 2], c[4 * k + 3]])
    };
    for c in bytes.chunks_exact(VELODYNE_POINT_BYTES) {
        let p = [f(c, 0), f(c, 1), f(c, 2)];
        if p.iter().all(|v| v.is_finite()) {
            points.push(p);
            intensity.push(f(c, 3));
        }
    }
    if points.len() < n {
        tracing::debug!(
            "{}: dropped {} non-finite points of {n}",
            path.display(),
            n - points.len()
        );
    }
    Ok(LidarScan {
        world_from_sensor: Isometry3::identity(),
        points_sensor_m: points,
        intensity,
    })
}

/// Frame files of one stream (`image_k` or `velodyne`), by frame index.
fn scan_stream(dir: &Path, exts: &[&str]) -> Result<BTreeMap<usize, PathBuf>> {
    let mut files = BTreeMap::new();
    if !dir.is_dir() {
        return Ok(files);
    }
    for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        let path = entry.path();
        let (Some(stem), Some(e)) = (path.file_stem().and_then(|s| s.to_str()), path.extension())
        else {
            continue;
        };
        if !exts.iter().any(|x| e.eq_ignore_ascii_case(x))
            || stem.is_empty()
            || !stem.bytes().all(|b| b.is_ascii_digit())
        {
            continue;
        }
        let Ok(index) = stem.parse::<usize>() else {
            continue;
        };
        if let Some(other) = files.insert(index, path.clone()) {
            return Err(Error::bad_input(
                &path,
                format!("frame {index} also exists as {}", other.display()),
            ));
        }
    }
    Ok(files)
}

/// Where the sequence length came from (for error messages).
#[derive(Clone, Debug)]
enum LenSource {
    Times(PathBuf),
    Poses(PathBuf),
    Files,
}

/// One KITTI odometry sequence, opened and validated; frames are loaded on demand.
#[derive(Clone, Debug)]
pub struct KittiSequence {
    dir: PathBuf,
    calib: KittiCalib,
    poses: Option<Vec<Isometry3<f64>>>,
    poses_path: Option<PathBuf>,
    times_s: Option<Vec<f64>>,
    images: [BTreeMap<usize, PathBuf>; 4],
    velodyne: BTreeMap<usize, PathBuf>,
    len: usize,
}

impl KittiSequence {
    /// Opens `seq_dir` (`.../sequences/NN`). Poses come from `poses` if given (the file must
    /// exist), else from `<root>/poses/NN.txt` when that file exists (`root` = the folder
    /// holding `sequences/`), else there are none. See the module doc for the frame-count rules.
    pub fn open(seq_dir: impl AsRef<Path>, poses: Option<&Path>) -> Result<KittiSequence> {
        let dir = seq_dir.as_ref().to_path_buf();
        if !dir.is_dir() {
            return Err(Error::io(
                &dir,
                std::io::Error::new(std::io::ErrorKind::NotFound, "sequence folder not found"),
            ));
        }
        let calib = KittiCalib::from_file(dir.join("calib.txt"))?;
        let poses_path = match poses {
            Some(p) => Some(p.to_path_buf()),
            None => {
                let name = dir.file_name().map(|n| n.to_os_string());
                let root = dir.parent().and_then(|s| s.parent());
                match (root, name) {
                    (Some(root), Some(name)) => {
                        let mut file = name;
                        file.push(".txt");
                        let p = root.join("poses").join(file);
                        p.is_file().then_some(p)
                    }
                    _ => None,
                }
            }
        };
        let poses = poses_path.as_deref().map(read_poses).transpose()?;
        let times_path = dir.join("times.txt");
        let times_s = if times_path.exists() {
            Some(read_times(&times_path)?)
        } else {
            None
        };
        let images = [0, 1, 2, 3].map(|k| {
            scan_stream(
                &dir.join(format!("image_{k}")),
                super::image::IMAGE_EXTENSIONS,
            )
        });
        let [i0, i1, i2, i3] = images;
        let images = [i0?, i1?, i2?, i3?];
        let velodyne = scan_stream(&dir.join("velodyne"), &["bin"])?;

        let streams: Vec<(String, &BTreeMap<usize, PathBuf>)> = images
            .iter()
            .enumerate()
            .map(|(k, m)| (format!("image_{k}"), m))
            .chain(std::iter::once(("velodyne".to_string(), &velodyne)))
            .collect();
        let (len, source) = match (&times_s, &poses, &poses_path) {
            (Some(t), Some(p), Some(pp)) => {
                if t.len() != p.len() {
                    return Err(Error::bad_input(
                        pp,
                        format!(
                            "pose count mismatch: {} poses but {} has {} timestamps",
                            p.len(),
                            times_path.display(),
                            t.len()
                        ),
                    ));
                }
                (t.len(), LenSource::Times(times_path.clone()))
            }
            (Some(t), _, _) => (t.len(), LenSource::Times(times_path.clone())),
            (None, Some(p), Some(pp)) => (p.len(), LenSource::Poses(pp.clone())),
            _ => {
                let n = streams
                    .iter()
                    .filter_map(|(_, m)| m.keys().next_back().map(|&k| k + 1))
                    .max()
                    .unwrap_or(0);
                (n, LenSource::Files)
            }
        };
        let describe = |source: &LenSource| match source {
            LenSource::Times(p) => format!("{} has {len} timestamps", p.display()),
            LenSource::Poses(p) => format!("pose count mismatch: {} has {len} poses", p.display()),
            LenSource::Files => format!("the sequence has {len} frames"),
        };
        let error_path = |fallback: &Path| match &source {
            LenSource::Poses(p) => p.clone(),
            _ => fallback.to_path_buf(),
        };
        for (name, files) in &streams {
            if let Some((&last, path)) = files.iter().next_back() {
                if last >= len {
                    return Err(Error::bad_input(
                        error_path(path),
                        format!(
                            "{name} has frame {last} ({}) but {}",
                            path.display(),
                            describe(&source)
                        ),
                    ));
                }
            }
            let primary = name == "image_0" || name == "velodyne";
            if primary && !files.is_empty() && files.len() != len {
                let folder = dir.join(name);
                return Err(Error::bad_input(
                    error_path(&folder),
                    format!(
                        "{} holds {} frames but {} (image_0 and velodyne must cover every frame)",
                        folder.display(),
                        files.len(),
                        describe(&source)
                    ),
                ));
            }
        }
        tracing::debug!(
            "KITTI {}: {len} frames, poses {}, times {}, image_0..3 {:?}, velodyne {}",
            dir.display(),
            poses.is_some(),
            times_s.is_some(),
            images.iter().map(|m| m.len()).collect::<Vec<_>>(),
            velodyne.len()
        );
        Ok(KittiSequence {
            dir,
            calib,
            poses,
            poses_path,
            times_s,
            images,
            velodyne,
            len,
        })
    }

    /// The sequence folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The calibration.
    pub fn calib(&self) -> &KittiCalib {
        &self.calib
    }

    /// Number of frames (see the module doc).
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when the sequence has no frames.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// All poses (`world_from_cam0`), when the sequence has them.
    pub fn poses(&self) -> Option<&[Isometry3<f64>]> {
        self.poses.as_deref()
    }

    /// The pose file in use, if any.
    pub fn poses_path(&self) -> Option<&Path> {
        self.poses_path.as_deref()
    }

    /// `world_from_cam0` of frame `i`; `None` without poses or when `i >= len()`.
    pub fn pose(&self, i: usize) -> Option<WorldFromCamera> {
        self.poses.as_ref().and_then(|p| p.get(i).copied())
    }

    /// `world_from_camera` of camera `cam` at frame `i` (`pose(i) · cam0_from_cam`).
    pub fn camera_pose(&self, cam: usize, i: usize) -> Option<WorldFromCamera> {
        self.pose(i)
            .map(|p| p * self.calib.cam_from_cam0(cam).inverse())
    }

    /// Timestamp of frame `i`, seconds; `None` without `times.txt` or when `i >= len()`.
    pub fn time_s(&self, i: usize) -> Option<f64> {
        self.times_s.as_ref().and_then(|t| t.get(i).copied())
    }

    /// True when camera `cam` (0..3) has an image for frame `i`.
    pub fn has_image(&self, cam: usize, i: usize) -> bool {
        self.images.get(cam).is_some_and(|m| m.contains_key(&i))
    }

    /// True when frame `i` has a Velodyne scan.
    pub fn has_velodyne(&self, i: usize) -> bool {
        self.velodyne.contains_key(&i)
    }

    /// Path of camera `cam`'s image for frame `i`, if present.
    pub fn image_path(&self, cam: usize, i: usize) -> Option<&Path> {
        self.images
            .get(cam)
            .and_then(|m| m.get(&i))
            .map(|p| p.as_path())
    }

    /// Path of frame `i`'s Velodyne scan, if present.
    pub fn velodyne_path(&self, i: usize) -> Option<&Path> {
        self.velodyne.get(&i).map(|p| p.as_path())
    }

    fn require_image(&self, cam: usize, i: usize) -> Result<&Path> {
        if cam > 3 {
            return Err(Error::InvalidArgument(format!(
                "KITTI camera index {cam} is not in 0..3"
            )));
        }
        self.image_path(cam, i).ok_or_else(|| {
            Error::io(
                self.dir.join(format!("image_{cam}/{i:06}.png")),
                std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    "no such frame in the sequence",
                ),
            )
        })
    }

    /// Width and height of camera `cam`'s images (from the first one's header).
    pub fn image_size(&self, cam: usize) -> Result<(u32, u32)> {
        let first = self
            .images
            .get(cam)
            .and_then(|m| m.values().next())
            .ok_or_else(|| {
                Error::bad_input(
                    self.dir.join(format!("image_{cam}")),
                    "no images for this camera",
                )
            })?;
        super::image::image_size(first)
    }

    /// Intrinsics of camera `cam`, sized from its first image.
    pub fn intrinsics(&self, cam: usize) -> Result<PinholeIntrinsics> {
        let (w, h) = self.image_size(cam)?;
        Ok(self.calib.intrinsics(cam, w, h))
    }

    /// Camera `cam`'s image of frame `i` as grey (colour cameras are converted to luma).
    pub fn grey(&self, cam: usize, i: usize) -> Result<GreyImage> {
        read_grey(self.require_image(cam, i)?)
    }

    /// Camera `cam`'s image of frame `i` as RGB (grey cameras are replicated to 3 channels).
    pub fn color(&self, cam: usize, i: usize) -> Result<RgbImage> {
        read_rgb(self.require_image(cam, i)?)
    }

    /// Velodyne scan of frame `i` with `world_from_sensor = pose(i) · cam0_from_velo`
    /// (intensity = reflectance). Fails when the scan or the pose is missing.
    pub fn velodyne(&self, i: usize) -> Result<LidarScan> {
        let path = self.velodyne_path(i).ok_or_else(|| {
            Error::io(
                self.dir.join(format!("velodyne/{i:06}.bin")),
                std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    "no such frame in the sequence",
                ),
            )
        })?;
        let pose = self.pose(i).ok_or_else(|| {
            Error::bad_input(
                path,
                format!(
                    "no pose for frame {i} (poses: {:?})",
                    self.poses_path.as_deref()
                ),
            )
        })?;
        let mut scan = read_velodyne_bin(path)?;
        scan.world_from_sensor = pose * self.calib.cam0_from_velo;
        Ok(scan)
    }
}

#[cfg(test)]
mod tests;
