//! A job's input as one [`Sequence`] of range inputs, whatever the layout: KITTI odometry with
//! LiDAR scans, ground-truth depth or depth from its stereo pairs; TUM RGB-D; numbered RGB-D; a
//! folder of scans with a trajectory ([`super::scans`]); a ROS 2 bag ([`super::bag`]).
//! [`for_each_input`] is the one loop every command reads frames with (in order, one at a time,
//! timing each, with a progress bar), so nothing is held beyond the current frame.
//!
//! What it does not do: fuse, or choose a stereo matcher (the caller passes one, built for its
//! device).

use super::kitti::KittiSequence;
use super::rgbd::{SimpleRgbdOptions, SimpleRgbdSequence, TumOptions, TumRgbdSequence};
use super::stereo_depth::StereoDepth;
use super::DepthSequence;
use crate::depth::DisparityEstimator;
use crate::frame::{DepthFrame, Image, LidarScan};
use crate::{Error, Result};
use std::path::Path;

/// The layouts `denser reconstruct` understands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputKind {
    /// KITTI odometry: a `sequences/NN` folder with `calib.txt`.
    Kitti,
    /// TUM RGB-D: `depth.txt`, `rgb.txt`, `groundtruth.txt`.
    Tum,
    /// Numbered RGB-D frames: `depth/N.pgm|png`, `color/N.png`, `pose.txt`.
    SimpleRgbd,
    /// A folder of LiDAR scans (`scans/`) with a trajectory.
    ScanFolder,
    /// A ROS 2 bag: a folder with `metadata.yaml` and `.mcap` / `.db3` files, or one such file.
    Bag,
}

impl InputKind {
    /// The layout in words.
    pub fn name(self) -> &'static str {
        match self {
            InputKind::Kitti => "KITTI odometry",
            InputKind::Tum => "TUM RGB-D",
            InputKind::SimpleRgbd => "numbered RGB-D",
            InputKind::ScanFolder => "folder of scans",
            InputKind::Bag => "ROS 2 bag",
        }
    }

    /// Whether the layout holds LiDAR scans only (no `--depth gt` or `stereo`).
    pub fn lidar_only(self) -> bool {
        matches!(self, InputKind::ScanFolder)
    }

    /// Whether the layout holds LiDAR scans, stereo pairs or both (a bag: no `--depth gt`).
    pub fn lidar_or_stereo(self) -> bool {
        matches!(self, InputKind::ScanFolder | InputKind::Bag)
    }
}

/// Recognises the layout of `dir`.
pub fn detect_input(dir: &Path) -> Result<InputKind> {
    if dir.is_file() && super::bag::is_bag(dir) {
        return Ok(InputKind::Bag);
    }
    if !dir.exists() {
        return Err(Error::bad_input(
            dir,
            "no such file or folder (not a directory, .mcap or .db3 file)",
        ));
    }
    if !dir.is_dir() {
        return Err(Error::bad_input(
            dir,
            "not a folder, .mcap or .db3 file (expected a KITTI sequence, an RGB-D folder, a folder of scans or a ROS 2 bag)",
        ));
    }
    if dir.join("calib.txt").is_file() {
        Ok(InputKind::Kitti)
    } else if dir.join("depth.txt").is_file() {
        Ok(InputKind::Tum)
    } else if dir.join("pose.txt").is_file() && dir.join("depth").is_dir() {
        Ok(InputKind::SimpleRgbd)
    } else if super::scans::is_scan_folder(dir) {
        Ok(InputKind::ScanFolder)
    } else if super::bag::is_bag(dir) {
        Ok(InputKind::Bag)
    } else {
        Err(Error::bad_input(
            dir,
            "unrecognised layout: expected calib.txt (KITTI odometry), depth.txt (TUM RGB-D), pose.txt with depth/ (simple RGB-D), scans/ (a folder of scans) or metadata.yaml / .mcap / .db3 files (a ROS 2 bag)",
        ))
    }
}

/// Where range data comes from for a KITTI-layout sequence (RGB-D layouts always give depth).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RangeSource {
    /// Velodyne scans.
    Lidar,
    /// Ground-truth depth maps (`depth_gt/`, written by `denser synth`).
    GroundTruthDepth,
    /// Depth from the stereo pair (image_0/image_1).
    Stereo,
}

impl RangeSource {
    /// The CLI name (`--depth`): `lidar`, `gt`, `stereo`.
    pub fn as_str(self) -> &'static str {
        match self {
            RangeSource::Lidar => "lidar",
            RangeSource::GroundTruthDepth => "gt",
            RangeSource::Stereo => "stereo",
        }
    }
}

impl std::fmt::Display for RangeSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for RangeSource {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "lidar" => Ok(RangeSource::Lidar),
            "gt" => Ok(RangeSource::GroundTruthDepth),
            "stereo" => Ok(RangeSource::Stereo),
            other => Err(Error::InvalidArgument(format!(
                "range source must be lidar, gt or stereo, got {other:?}"
            ))),
        }
    }
}

/// One range measurement, ready to fuse.
pub enum RangeInput {
    /// A depth map with pose (RGB-D, ground-truth depth, or stereo).
    Depth(DepthFrame),
    /// A LiDAR scan with pose.
    Lidar(LidarScan),
    /// A depth map with pose whose depths stay on the GPU where a matcher made them
    /// ([`InputOptions::depth_on_device`]).
    DeviceDepth(Box<crate::fusion::DeviceDepthFrame>),
}

/// Which frames of a sequence a job uses: `first..last` (to the end when `last` is `None`),
/// every `step`-th.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FrameRange {
    /// First frame (0-based).
    pub first: usize,
    /// One past the last frame; `None` for all.
    pub last: Option<usize>,
    /// Use every n-th frame (0 counts as 1).
    pub step: usize,
}

impl FrameRange {
    /// Every frame.
    pub const ALL: FrameRange = FrameRange {
        first: 0,
        last: None,
        step: 1,
    };

    /// The frame indices of a sequence of `len` frames, in order (clamped to the sequence).
    pub fn indices(&self, len: usize) -> Vec<usize> {
        let end = self.last.unwrap_or(len).min(len);
        (self.first.min(len)..end)
            .step_by(self.step.max(1))
            .collect()
    }

    /// [`FrameRange::indices`] for a job: an error when the range is malformed (step 0, an
    /// empty `first..last`) or selects no frame of the `len` frames of `what`.
    pub fn select(&self, len: usize, what: &str) -> Result<Vec<usize>> {
        if self.step == 0 {
            return Err(Error::InvalidArgument(
                "--step 0: the frame step must be at least 1".into(),
            ));
        }
        if let Some(last) = self.last {
            if last <= self.first {
                return Err(Error::InvalidArgument(format!(
                    "--first {} --last {last}: the range is empty (--last is one past the last frame)",
                    self.first
                )));
            }
        }
        let frames = self.indices(len);
        if frames.is_empty() {
            return Err(Error::InvalidArgument(format!(
                "frames from {} to {} select none of the {len} frames of {what}",
                self.first,
                self.last.map_or("the end".to_string(), |l| l.to_string())
            )));
        }
        Ok(frames)
    }
}

/// A random-access sequence of range inputs.
pub trait Sequence {
    /// Number of frames.
    fn len(&self) -> usize;

    /// Whether there are no frames.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Reads (for stereo: computes) frame `i`.
    fn read(&self, i: usize) -> Result<RangeInput>;

    /// The sequence in words, for reports ("KITTI sequence … (LiDAR)").
    fn describe(&self) -> String;

    /// A digest of what identifies the data (frame count and poses), independent of where the
    /// files are: a resumed map compares it to refuse other data.
    fn fingerprint(&self) -> u64;
}

/// How to read an input beyond its layout: the range source and the files and names the user
/// gave.
#[derive(Clone, Debug, PartialEq)]
pub struct InputOptions {
    /// `--depth`.
    pub source: RangeSource,
    /// `--poses`: KITTI poses, or a folder of scans' trajectory.
    pub poses: Option<std::path::PathBuf>,
    /// `--extrinsic`: a folder of scans' `body_from_sensor`.
    pub extrinsic: Option<std::path::PathBuf>,
    /// `--lidar-topic`, `--pose-topic`, `--fixed-frame` for a bag.
    pub bag: super::bag::BagOptions,
    /// Where a GPU matcher's depths may stay on the device, the fusion they are for (the
    /// grid and the fusion parameters their band slices are made for): a KITTI-layout stereo
    /// sequence then gives [`RangeInput::DeviceDepth`].
    pub depth_on_device: Option<(crate::grid::GridParams, crate::fusion::DepthFusionParams)>,
}

impl InputOptions {
    /// `source` with every other option at its default.
    pub fn new(source: RangeSource) -> InputOptions {
        InputOptions {
            source,
            poses: None,
            extrinsic: None,
            bag: Default::default(),
            depth_on_device: None,
        }
    }
}

/// Opens `input` (layout detected) as a sequence of `source` inputs; `stereo` is the matcher
/// for [`RangeSource::Stereo`] (ignored otherwise). KITTI poses come from `poses` or their
/// default place. RGB-D layouts give depth whatever `source` says.
pub fn open_sequence(
    input: &Path,
    source: RangeSource,
    poses: Option<&Path>,
    stereo: Option<Box<dyn DisparityEstimator>>,
) -> Result<Box<dyn Sequence>> {
    let mut opts = InputOptions::new(source);
    opts.poses = poses.map(Path::to_path_buf);
    open_input(input, &opts, stereo)
}

/// [`open_sequence`] with every input option: a folder of scans and a bag give LiDAR scans
/// (any other `source` is refused).
pub fn open_input(
    input: &Path,
    opts: &InputOptions,
    stereo: Option<Box<dyn DisparityEstimator>>,
) -> Result<Box<dyn Sequence>> {
    let (source, poses) = (opts.source, opts.poses.as_deref());
    let kind = detect_input(input)?;
    if kind.lidar_only() && source != RangeSource::Lidar {
        return Err(Error::bad_input(
            input,
            format!(
                "a {} gives LiDAR scans only: use --depth lidar, not --depth {source}",
                kind.name()
            ),
        ));
    }
    if kind == InputKind::Bag && source == RangeSource::GroundTruthDepth {
        return Err(Error::bad_input(
            input,
            "a ROS 2 bag gives LiDAR scans or stereo pairs: use --depth lidar or --depth stereo",
        ));
    }
    Ok(match kind {
        InputKind::ScanFolder => Box::new(super::scans::ScanFolder::open(
            input,
            poses,
            opts.extrinsic.as_deref(),
        )?),
        InputKind::Bag if source == RangeSource::Stereo => Box::new(
            super::bag::stereo::BagStereo::open(input, &opts.bag, stereo_depth(stereo, opts)?)?,
        ),
        InputKind::Bag => Box::new(super::bag::BagLidar::open(input, &opts.bag)?),
        InputKind::Kitti => {
            let seq = KittiSequence::open(input, poses)?;
            match source {
                RangeSource::Lidar => Box::new(KittiLidar(seq)),
                RangeSource::GroundTruthDepth => Box::new(KittiGtDepth(seq)),
                RangeSource::Stereo => Box::new(KittiStereo {
                    seq: with_stereo_images(seq)?,
                    stereo: stereo_depth(stereo, opts)?,
                }),
            }
        }
        InputKind::Tum => Box::new(Rgbd {
            dir: input.to_path_buf(),
            seq: Box::new(TumRgbdSequence::open(input, TumOptions::default())?),
        }),
        InputKind::SimpleRgbd => Box::new(Rgbd {
            dir: input.to_path_buf(),
            seq: Box::new(SimpleRgbdSequence::open(
                input,
                SimpleRgbdOptions::slambook2(),
            )?),
        }),
    })
}

/// `seq`, when it has stereo images (some frames in `image_0` and `image_1`); else an error that
/// says so and what to use instead (a LiDAR-only drive has none).
fn with_stereo_images(seq: KittiSequence) -> Result<KittiSequence> {
    for cam in ["image_0", "image_1"] {
        let dir = seq.dir().join(cam);
        let any = std::fs::read_dir(&dir).is_ok_and(|mut d| d.next().is_some());
        if !any {
            return Err(Error::bad_input(
                dir,
                "no stereo images here (a LiDAR-only drive?): use --depth lidar",
            ));
        }
    }
    Ok(seq)
}

/// Reads `frames` of `seq` after the first `skip` of them (already fused by a resumed run), in
/// order, and hands each to `sink` with the seconds spent producing it; a progress bar counts
/// them.
pub fn for_each_input(
    seq: &dyn Sequence,
    frames: &[usize],
    skip: usize,
    mut sink: impl FnMut(RangeInput, f64) -> Result<()>,
) -> Result<()> {
    let bar = crate::progress::bar(frames.len() as u64, "fusing");
    bar.inc(skip.min(frames.len()) as u64);
    for &i in frames.iter().skip(skip) {
        let t = std::time::Instant::now();
        let input = seq.read(i)?;
        sink(input, t.elapsed().as_secs_f64())?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(())
}

/// FNV-1a over the frame count and every pose's matrix (f64 bits).
pub(crate) fn pose_digest<'a>(
    len: usize,
    poses: impl Iterator<Item = &'a nalgebra::Isometry3<f64>>,
) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
        }
    };
    eat(&(len as u64).to_le_bytes());
    for p in poses {
        for v in p.to_homogeneous().iter() {
            eat(&v.to_bits().to_le_bytes());
        }
    }
    h
}

fn kitti_fingerprint(seq: &KittiSequence) -> u64 {
    pose_digest(seq.len(), seq.poses().unwrap_or(&[]).iter())
}

fn kitti_pose(seq: &KittiSequence, i: usize) -> Result<nalgebra::Isometry3<f64>> {
    seq.pose(i)
        .ok_or_else(|| Error::bad_input(seq.dir(), format!("no pose for frame {i}")))
}

/// Colour for a depth frame of cam0: `image_2` where the colour camera coincides with cam0
/// (synthetic drives), else none.
fn kitti_color(seq: &KittiSequence, i: usize) -> Result<Option<Image<[u8; 3]>>> {
    if seq.has_image(2, i) && seq.calib().cam_from_cam0_translation_m(2).norm() < 1e-6 {
        Ok(Some(seq.color(2, i)?))
    } else {
        Ok(None)
    }
}

/// KITTI Velodyne scans.
struct KittiLidar(KittiSequence);

impl Sequence for KittiLidar {
    fn len(&self) -> usize {
        self.0.len()
    }
    fn read(&self, i: usize) -> Result<RangeInput> {
        let scan = self.0.velodyne(i)?;
        if scan.points_sensor_m.is_empty() {
            tracing::warn!(
                "{}: the scan of frame {i} holds no point; nothing to fuse",
                self.0.velodyne_path(i).unwrap_or(self.0.dir()).display()
            );
        }
        Ok(RangeInput::Lidar(scan))
    }
    fn describe(&self) -> String {
        format!("KITTI sequence {} (LiDAR)", self.0.dir().display())
    }
    fn fingerprint(&self) -> u64 {
        kitti_fingerprint(&self.0)
    }
}

/// Ground-truth depth of a synthetic drive (`depth_gt/NNNNNN.png`, 16-bit, depth·256, 0
/// invalid, in the left grey camera), coloured from `image_2` when it coincides with cam0.
struct KittiGtDepth(KittiSequence);

impl Sequence for KittiGtDepth {
    fn len(&self) -> usize {
        self.0.len()
    }
    fn read(&self, i: usize) -> Result<RangeInput> {
        let seq = &self.0;
        let path = seq.dir().join("depth_gt").join(format!("{i:06}.png"));
        if !path.is_file() {
            return Err(Error::bad_input(&path, "no ground-truth depth for this frame (only synthetic drives written by `denser synth` have depth_gt/)"));
        }
        let depth_m = super::image::read_depth_png_u16(&path, 256.0)?;
        let mut intrinsics = seq.intrinsics(0)?;
        intrinsics.width = depth_m.width;
        intrinsics.height = depth_m.height;
        Ok(RangeInput::Depth(DepthFrame {
            intrinsics,
            world_from_camera: kitti_pose(seq, i)?,
            depth_m,
            color: kitti_color(seq, i)?,
        }))
    }
    fn describe(&self) -> String {
        format!(
            "KITTI sequence {} (ground-truth depth)",
            self.0.dir().display()
        )
    }
    fn fingerprint(&self) -> u64 {
        kitti_fingerprint(&self.0)
    }
}

/// The stereo input's matcher `stereo` (required) with where `opts` sends its depths.
fn stereo_depth(
    stereo: Option<Box<dyn DisparityEstimator>>,
    opts: &InputOptions,
) -> Result<StereoDepth> {
    let estimator = stereo
        .ok_or_else(|| Error::InvalidArgument("stereo input needs a stereo matcher".into()))?;
    Ok(StereoDepth::new(estimator, opts.depth_on_device))
}

/// Depth from a KITTI-layout sequence's rectified grey pair (image_0, image_1), `z = fx·B/d`.
/// Colour comes from image_2 where the colour camera coincides with cam0 (synthetic drives);
/// otherwise the grey value is used as colour.
struct KittiStereo {
    seq: KittiSequence,
    stereo: StereoDepth,
}

impl Sequence for KittiStereo {
    fn len(&self) -> usize {
        self.seq.len()
    }
    fn read(&self, i: usize) -> Result<RangeInput> {
        let seq = &self.seq;
        let left = seq.grey(0, i)?;
        let right = seq.grey(1, i)?;
        let mut intrinsics = seq.intrinsics(0)?;
        intrinsics.width = left.width;
        intrinsics.height = left.height;
        let baseline_m = seq.calib().baseline_m(0, 1);
        if !(baseline_m.is_finite() && baseline_m > 0.0) {
            return Err(Error::bad_input(
                seq.dir().join("calib.txt"),
                format!("stereo baseline P0→P1 must be positive, got {baseline_m} m"),
            ));
        }
        let color = match kitti_color(seq, i)? {
            Some(c) => c,
            None => Image {
                width: left.width,
                height: left.height,
                data: left.data.iter().map(|&g| [g; 3]).collect(),
            },
        };
        let view = (intrinsics, kitti_pose(seq, i)?, Some(color));
        self.stereo.frame((&left, &right), view, baseline_m)
    }
    fn describe(&self) -> String {
        format!(
            "KITTI sequence {} (stereo, {})",
            self.seq.dir().display(),
            self.stereo.name()
        )
    }
    fn fingerprint(&self) -> u64 {
        kitti_fingerprint(&self.seq)
    }
}

/// An RGB-D sequence (TUM or numbered layout).
struct Rgbd {
    dir: std::path::PathBuf,
    seq: Box<dyn DepthSequence>,
}

impl Sequence for Rgbd {
    fn len(&self) -> usize {
        self.seq.len()
    }
    fn read(&self, i: usize) -> Result<RangeInput> {
        Ok(RangeInput::Depth(self.seq.frame(i)?))
    }
    fn describe(&self) -> String {
        format!("RGB-D sequence {}", self.dir.display())
    }
    fn fingerprint(&self) -> u64 {
        let poses: Vec<_> = (0..self.seq.len())
            .filter_map(|i| self.seq.pose(i))
            .collect();
        pose_digest(self.seq.len(), poses.iter())
    }
}
