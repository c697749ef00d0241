//! Writes a synthetic drive to disk in the KITTI odometry layout, streamed frame by frame:
//!
//! ```text
//! OUT/sequences/00/image_0/NNNNNN.png   left grey            OUT/sequences/00/calib.txt  P0..P3, Tr
//! OUT/sequences/00/image_1/NNNNNN.png   right grey           OUT/sequences/00/times.txt  seconds
//! OUT/sequences/00/image_2/NNNNNN.png   left colour          OUT/poses/00.txt            world_from_cam0 3×4
//! OUT/sequences/00/image_3/NNNNNN.png   right colour         OUT/ground_truth/surface.ply exact surface samples
//! OUT/sequences/00/velodyne/NNNNNN.bin  float32 x y z r      OUT/synth.json              what was generated
//! OUT/sequences/00/depth_gt/NNNNNN.png  uint16 depth·256 (0 = invalid), left camera, like KITTI depth
//! ```
//!
//! The synthetic colour cameras coincide with the grey ones, so `P2 = P0` and `P3 = P1`. One frame
//! is rendered (rayon inside the frame), handed to an encoder thread through a channel of two
//! slots, written and dropped: memory does not grow with the drive. Does not read drives back
//! (that is `io`).

use super::city::{City, CityConfig, SurfaceSampling};
use super::lidar::{kitti_cam0_from_velo, LidarConfig};
use super::render::{RenderOptions, StereoFrame, StereoRig};
use crate::error::{Error, Result};
use crate::frame::LidarScan;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ExtendedColorType, ImageEncoder};
use nalgebra::Isometry3;
use serde::Serialize;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Everything that defines a written drive.
#[derive(Clone, Debug)]
pub struct DriveConfig {
    /// The city and route.
    pub city: CityConfig,
    /// Camera rig (KITTI's by default).
    pub rig: StereoRig,
    /// Rendering settings.
    pub render: RenderOptions,
    /// LiDAR model; `None` writes no velodyne scans.
    pub lidar: Option<LidarConfig>,
    /// Ground-truth surface sampling; `None` writes no surface file.
    pub surface: Option<SurfaceSampling>,
    /// Time between frames, seconds (KITTI: about 0.1).
    pub frame_period_s: f64,
    /// Render and write the stereo images and ground-truth depth (false: poses, calibration and
    /// LiDAR only, for long LiDAR drives).
    pub images: bool,
}

impl Default for DriveConfig {
    fn default() -> Self {
        DriveConfig {
            city: CityConfig::default(),
            rig: StereoRig::kitti(),
            render: RenderOptions::default(),
            lidar: Some(LidarConfig::default()),
            surface: Some(SurfaceSampling::default()),
            frame_period_s: 0.1,
            images: true,
        }
    }
}

/// What [`write_drive`] produced.
#[derive(Clone, Debug, Serialize)]
pub struct DriveSummary {
    /// The output root.
    pub out_dir: PathBuf,
    /// `OUT/sequences/00`.
    pub sequence_dir: PathBuf,
    /// Number of frames written.
    pub frames: usize,
    /// Distance driven (sum of distances between frames), metres.
    pub route_length_m: f64,
    /// Primitives in the city.
    pub primitives: usize,
    /// LiDAR points over all scans.
    pub lidar_points: usize,
    /// Points in the ground-truth surface file.
    pub surface_points: usize,
    /// Seed of the city.
    pub seed: u64,
    /// Time to build the city, seconds.
    pub build_s: f64,
    /// Time to render and write all frames, seconds.
    pub frames_s: f64,
    /// Time to sample and write the ground-truth surface, seconds.
    pub surface_s: f64,
}

/// Formats like C's `%.{digits}e` (e.g. `7.188560000000e+02`), as KITTI's text files do.
pub fn format_sci(x: f64, digits: usize) -> String {
    let s = format!("{:.*e}", digits, x);
    let (mant, exp) = s.split_once('e').unwrap_or((&s, "0"));
    let e: i32 = exp.parse().unwrap_or(0);
    format!("{}e{}{:02}", mant, if e < 0 { '-' } else { '+' }, e.abs())
}

fn row12(m: &[f64; 12], digits: usize) -> String {
    m.iter()
        .map(|v| format_sci(*v, digits))
        .collect::<Vec<_>>()
        .join(" ")
}

fn pose_row(p: &Isometry3<f64>) -> [f64; 12] {
    let h = p.to_homogeneous();
    let mut r = [0.0; 12];
    for i in 0..3 {
        for j in 0..4 {
            r[i * 4 + j] = h[(i, j)];
        }
    }
    r
}

/// The text of KITTI's `calib.txt` for `rig` and the LiDAR mounting `cam0_from_velo`.
pub fn calib_text(rig: &StereoRig, cam0_from_velo: &Isometry3<f64>) -> String {
    let k = &rig.intrinsics;
    let p0 = [
        k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
    ];
    let mut p1 = p0;
    p1[3] = -k.fx * rig.baseline_m;
    let mut out = String::new();
    for (name, m) in [
        ("P0", p0),
        ("P1", p1),
        ("P2", p0),
        ("P3", p1),
        ("Tr", pose_row(cam0_from_velo)),
    ] {
        out.push_str(&format!("{}: {}\n", name, row12(&m, 12)));
    }
    out
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> Error + '_ {
    move |e| Error::io(path, e)
}

fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    bytes: &[u8],
    color: ExtendedColorType,
) -> Result<()> {
    let mut w = crate::io::atomic::PendingFile::create(path)?;
    PngEncoder::new_with_quality(&mut w, CompressionType::Fast, FilterType::Adaptive)
        .write_image(bytes, width, height, color)
        .map_err(|e| Error::io(path, std::io::Error::other(e)))?;
    w.commit()
}

/// Depth in metres to KITTI's 16-bit encoding: `round(depth·256)`, 0 for invalid or beyond 255.99 m.
pub fn encode_depth_u16(depth_m: f32) -> u16 {
    if depth_m.is_finite() && depth_m > 0.0 {
        let v = (depth_m as f64 * 256.0).round();
        if (1.0..=65535.0).contains(&v) {
            return v as u16;
        }
    }
    0
}

fn write_frame(
    seq: &Path,
    index: usize,
    frame: Option<&StereoFrame>,
    scan: Option<&LidarScan>,
) -> Result<()> {
    let name = format!("{index:06}");
    if let Some(frame) = frame {
        write_images(seq, &name, frame)?;
    }
    if let Some(scan) = scan {
        let path = seq.join("velodyne").join(format!("{name}.bin"));
        let mut bytes = Vec::with_capacity(scan.points_sensor_m.len() * 16);
        for (p, i) in scan.points_sensor_m.iter().zip(&scan.intensity) {
            for v in [p[0], p[1], p[2], *i] {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
        crate::io::atomic::write_file(&path, &bytes)?;
    }
    Ok(())
}

fn write_images(seq: &Path, name: &str, frame: &StereoFrame) -> Result<()> {
    let (w, h) = (frame.left_grey.width, frame.left_grey.height);
    write_png(
        &seq.join("image_0").join(format!("{name}.png")),
        w,
        h,
        &frame.left_grey.data,
        ExtendedColorType::L8,
    )?;
    write_png(
        &seq.join("image_1").join(format!("{name}.png")),
        w,
        h,
        &frame.right_grey.data,
        ExtendedColorType::L8,
    )?;
    write_png(
        &seq.join("image_2").join(format!("{name}.png")),
        w,
        h,
        bytemuck::cast_slice(&frame.left_rgb.data),
        ExtendedColorType::Rgb8,
    )?;
    write_png(
        &seq.join("image_3").join(format!("{name}.png")),
        w,
        h,
        bytemuck::cast_slice(&frame.right_rgb.data),
        ExtendedColorType::Rgb8,
    )?;
    let depth: Vec<u16> = frame
        .depth_gt_m
        .data
        .iter()
        .map(|&d| encode_depth_u16(d))
        .collect();
    write_png(
        &seq.join("depth_gt").join(format!("{name}.png")),
        w,
        h,
        bytemuck::cast_slice(&depth),
        ExtendedColorType::L16,
    )
}

/// Writes a binary little-endian PLY of the city's surface samples (x, y, z as double, colour as
/// uchar), streaming primitive chunks and patching the vertex count at the end. Returns the count.
fn write_surface_ply(city: &City, opts: &SurfaceSampling, path: &Path) -> Result<usize> {
    let f = File::create(path).map_err(io_err(path))?;
    let mut w = BufWriter::new(f);
    let head = "ply\nformat binary_little_endian 1.0\ncomment denser synthetic city: exact surface samples, world frame = cam0 of frame 0 (y down)\n";
    let count_line = |n: usize| format!("element vertex {n:>20}\n");
    let tail = "property double x\nproperty double y\nproperty double z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n";
    w.write_all(head.as_bytes()).map_err(io_err(path))?;
    let count_at = head.len() as u64;
    w.write_all(count_line(0).as_bytes())
        .map_err(io_err(path))?;
    w.write_all(tail.as_bytes()).map_err(io_err(path))?;
    let mut n = 0usize;
    city.sample_surface_chunks(opts, 2048, |pts, cols| {
        let mut buf = Vec::with_capacity(pts.len() * 27);
        for (p, c) in pts.iter().zip(cols) {
            for v in p {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            buf.extend_from_slice(c);
        }
        n += pts.len();
        w.write_all(&buf).map_err(io_err(path))
    })?;
    w.seek(SeekFrom::Start(count_at)).map_err(io_err(path))?;
    w.write_all(count_line(n).as_bytes())
        .map_err(io_err(path))?;
    w.flush().map_err(io_err(path))?;
    Ok(n)
}

/// Generates the city of `config.city` and writes the drive under `out_dir` (created if needed);
/// see the module docs for the layout. `progress` shows a progress bar on a terminal.
pub fn write_drive(config: &DriveConfig, out_dir: &Path, progress: bool) -> Result<DriveSummary> {
    let t0 = Instant::now();
    let city = City::generate(&config.city)?;
    let build_s = t0.elapsed().as_secs_f64();
    let seq = out_dir.join("sequences").join("00");
    for sub in ["image_0", "image_1", "image_2", "image_3", "depth_gt"] {
        std::fs::create_dir_all(seq.join(sub)).map_err(io_err(&seq.join(sub)))?;
    }
    if config.lidar.is_some() {
        std::fs::create_dir_all(seq.join("velodyne")).map_err(io_err(&seq.join("velodyne")))?;
    }
    let poses_dir = out_dir.join("poses");
    std::fs::create_dir_all(&poses_dir).map_err(io_err(&poses_dir))?;
    let poses = city.frame_poses().to_vec();
    let velo = config
        .lidar
        .map_or_else(kitti_cam0_from_velo, |l| l.cam0_from_velo);
    let calib = seq.join("calib.txt");
    std::fs::write(&calib, calib_text(&config.rig, &velo)).map_err(io_err(&calib))?;
    let times_path = seq.join("times.txt");
    let times: String = (0..poses.len())
        .map(|i| format_sci(i as f64 * config.frame_period_s, 6) + "\n")
        .collect();
    std::fs::write(&times_path, times).map_err(io_err(&times_path))?;
    let poses_path = poses_dir.join("00.txt");
    let pose_text: String = poses
        .iter()
        .map(|p| row12(&pose_row(p), 6) + "\n")
        .collect();
    std::fs::write(&poses_path, pose_text).map_err(io_err(&poses_path))?;

    let t1 = Instant::now();
    let bar = if progress {
        crate::progress::bar(poses.len() as u64, "synth")
    } else {
        indicatif::ProgressBar::hidden()
    };
    type Job = (usize, Option<StereoFrame>, Option<LidarScan>);
    let (tx, rx) = std::sync::mpsc::sync_channel::<Job>(2);
    let seq_w = seq.clone();
    let writer = std::thread::spawn(move || -> Result<usize> {
        let mut lidar_points = 0;
        for (i, frame, scan) in rx {
            write_frame(&seq_w, i, frame.as_ref(), scan.as_ref())?;
            lidar_points += scan.map_or(0, |s| s.points_sensor_m.len());
        }
        Ok(lidar_points)
    });
    for (i, pose) in poses.iter().enumerate() {
        let seed = city.frame_seed(i);
        let frame = config
            .images
            .then(|| city.render_stereo(pose, &config.rig, &config.render, seed));
        let scan = config
            .lidar
            .map(|l| city.scan_lidar(pose, &l, seed ^ 0x11DA));
        if tx.send((i, frame, scan)).is_err() {
            break; // The writer stopped on an error; join it below to report it.
        }
        bar.inc(1);
    }
    drop(tx);
    let lidar_points = writer
        .join()
        .map_err(|_| Error::InvalidArgument("the frame writer thread panicked".into()))??;
    bar.finish_and_clear();
    let frames_s = t1.elapsed().as_secs_f64();

    let t2 = Instant::now();
    let surface_points = match &config.surface {
        Some(s) => {
            let dir = out_dir.join("ground_truth");
            std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
            write_surface_ply(&city, s, &dir.join("surface.ply"))?
        }
        None => 0,
    };
    let summary = DriveSummary {
        out_dir: out_dir.to_path_buf(),
        sequence_dir: seq,
        frames: poses.len(),
        route_length_m: poses
            .windows(2)
            .map(|w| (w[1].translation.vector - w[0].translation.vector).norm())
            .sum(),
        primitives: city.primitives().len(),
        lidar_points,
        surface_points,
        seed: config.city.seed,
        build_s,
        frames_s,
        surface_s: t2.elapsed().as_secs_f64(),
    };
    let json_path = out_dir.join("synth.json");
    let json = serde_json::to_string_pretty(&summary)
        .map_err(|e| Error::io(&json_path, std::io::Error::other(e)))?;
    std::fs::write(&json_path, json).map_err(io_err(&json_path))?;
    tracing::info!(
        frames = summary.frames,
        seconds = frames_s,
        "synthetic drive written to {}",
        out_dir.display()
    );
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sci_format_matches_c() {
        assert_eq!(format_sci(718.856, 12), "7.188560000000e+02");
        assert_eq!(format_sci(0.0, 12), "0.000000000000e+00");
        assert_eq!(format_sci(-0.0011308870, 6), "-1.130887e-03");
        assert_eq!(format_sci(0.1036, 6), "1.036000e-01");
    }

    #[test]
    fn depth_encoding_is_kitti_like() {
        assert_eq!(encode_depth_u16(1.0), 256);
        assert_eq!(encode_depth_u16(f32::NAN), 0);
        assert_eq!(encode_depth_u16(300.0), 0);
        assert_eq!(encode_depth_u16(-1.0), 0);
    }
}
