//! Stereo from a bag: a rectified pair of image topics (`sensor_msgs/msg/Image` or
//! `CompressedImage`) with their `CameraInfo`, matched by stamp, each pair turned into a depth
//! map by the stereo matcher and posed at the left camera's frame.
//!
//! * Topics: `--left-topic` / `--right-topic`, or the only image topics whose names hold `left`
//!   and `right`. Each image topic's calibration is the `camera_info` topic beside it
//!   (`/ns/left/image_rect[/compressed]` → `/ns/left/camera_info`).
//! * Rectified input only: the projection matrices `P` of the pair must share `fx fy cx cy` and
//!   differ by a baseline along x (`Tx = −fx·B`), as `stereo_image_proc` publishes them; raw
//!   images (`image_raw` with a non-zero distortion) are refused.
//! * A left image is paired with the right image of the same stamp (within 0.1 ms); unpaired
//!   images and pairs outside the poses' time span are skipped and counted.

use super::msg::{self, types, CameraInfo};
use super::survey::MsgRef;
use super::{Bag, BagOptions, Survey};
use crate::camera::PinholeIntrinsics;
use crate::frame::Image;
use crate::io::sequence::{pose_digest, RangeInput, Sequence};
use crate::io::stereo_depth::StereoDepth;
use crate::{Error, Result};
use nalgebra::{Isometry3, Matrix3x4};
use std::path::Path;

/// Largest stamp difference of a left and a right image paired, seconds.
const PAIR_DT_S: f64 = 1e-4;

/// A message's place: (storage file, locator).
type Place = (usize, u64);

/// What a bag's stereo input will be.
#[derive(Clone, Debug)]
pub struct StereoSelection {
    /// Left and right image topics.
    pub topics: [String; 2],
    /// Their message types.
    pub types: [String; 2],
    /// Where the poses come from.
    pub pose_source: String,
    /// The world frame.
    pub fixed_frame: String,
    /// The left camera's frame.
    pub camera_frame: String,
    /// Rectified intrinsics of the left camera.
    pub intrinsics: PinholeIntrinsics,
    /// Baseline, metres.
    pub baseline_m: f64,
    /// (left (file, locator), right (file, locator), `world_from_camera`) of each pair.
    pairs: Vec<(Place, Place, Isometry3<f64>)>,
    /// Left images.
    pub left_images: usize,
    /// Left images without a right image of their stamp.
    pub unpaired: usize,
    /// Pairs outside the poses' time span.
    pub outside: usize,
}

impl StereoSelection {
    /// Pairs that will be matched and fused.
    pub fn len(&self) -> usize {
        self.pairs.len()
    }

    /// Whether no pair will be.
    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }
}

/// The `camera_info` topic beside an image topic.
fn info_topic(image_topic: &str) -> String {
    let base = image_topic
        .strip_suffix("/compressed")
        .unwrap_or(image_topic);
    match base.rsplit_once('/') {
        Some((ns, _)) => format!("{ns}/camera_info"),
        None => "camera_info".into(),
    }
}

fn projection(info: &CameraInfo) -> Matrix3x4<f64> {
    Matrix3x4::from_row_slice(&info.p)
}

impl Survey {
    /// Whether the bag has image topics.
    pub fn has_images(&self) -> bool {
        !self.images.is_empty()
    }

    fn image_topic(
        &self,
        named: Option<&str>,
        side: &str,
        flag: &str,
    ) -> std::result::Result<String, String> {
        let kinds = [types::IMAGE, types::COMPRESSED_IMAGE];
        if named.is_some() {
            return Ok(self
                .pick(named, &kinds, flag)?
                .expect("named topics are returned"));
        }
        let all: Vec<&str> = kinds.iter().flat_map(|k| self.of_type(k)).collect();
        let sided: Vec<&str> = all.iter().copied().filter(|t| t.contains(side)).collect();
        match sided.as_slice() {
            [one] => Ok(one.to_string()),
            _ => Err(format!(
                "name the stereo pair with --left-topic and --right-topic (image topics: {})",
                if all.is_empty() {
                    "none".to_string()
                } else {
                    all.join(", ")
                }
            )),
        }
    }

    /// Chooses the stereo pair, its calibration, poses and frames, and pairs the images.
    pub fn select_stereo(
        mut self,
        opts: &BagOptions,
    ) -> std::result::Result<StereoSelection, String> {
        let left = self.image_topic(opts.left_topic.as_deref(), "left", "--left-topic")?;
        let right = self.image_topic(opts.right_topic.as_deref(), "right", "--right-topic")?;
        if left == right {
            return Err(format!(
                "--left-topic and --right-topic are the same topic {left}"
            ));
        }
        let info = |topic: &str| -> std::result::Result<CameraInfo, String> {
            let t = info_topic(topic);
            let c = self.camera_info.get(&t).cloned().ok_or_else(|| {
                format!("no sensor_msgs/msg/CameraInfo for {topic} (looked for {t}): the rectified projection P is needed")
            })?;
            if c.p.iter().all(|&v| v == 0.0) || !c.p.iter().all(|v| v.is_finite()) {
                return Err(format!(
                    "{t}: the camera is not calibrated (P is zero or not finite)"
                ));
            }
            if topic.contains("image_raw") && c.d.iter().any(|&v| v != 0.0) {
                return Err(format!(
                    "{topic} holds raw images ({} distortion, d ≠ 0): denser reads rectified pairs; rectify them first (stereo_image_proc publishes image_rect)",
                    c.distortion_model
                ));
            }
            Ok(c)
        };
        let (li, ri) = (info(&left)?, info(&right)?);
        let (pl, pr) = (projection(&li), projection(&ri));
        let same = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(1.0);
        let shared = [(0, 0), (0, 2), (1, 1), (1, 2), (1, 3), (2, 3)];
        if !shared.iter().all(|&(r, c)| same(pl[(r, c)], pr[(r, c)])) {
            return Err(format!(
                "{left} and {right} are not a rectified pair: their projections P differ beyond a baseline along x (left {:?}, right {:?})",
                li.p, ri.p
            ));
        }
        let baseline_m = crate::io::calib::projection_translation_m(&pl).x
            - crate::io::calib::projection_translation_m(&pr).x;
        if !(baseline_m.is_finite() && baseline_m > 0.0) {
            return Err(format!("the baseline from {left}'s and {right}'s P is {baseline_m} m (it must be positive: is the pair swapped?)"));
        }
        let lefts = self.images.remove(&left).unwrap_or_default();
        let rights = self.images.remove(&right).unwrap_or_default();
        let Some(first) = lefts.first() else {
            return Err(format!("topic {left} has no decodable image"));
        };
        let camera = first.frame.clone();
        let (pose_source, fixed) = self.prepare_poses(opts, &camera)?;
        let mut by_time: Vec<&MsgRef> = rights.iter().collect();
        by_time.sort_by(|a, b| a.stamp_s.total_cmp(&b.stamp_s));
        let (mut pairs, mut unpaired, mut outside) = (Vec::new(), 0, 0);
        for l in &lefts {
            let k = by_time.partition_point(|r| r.stamp_s < l.stamp_s);
            let near = [k.wrapping_sub(1), k]
                .into_iter()
                .filter_map(|j| by_time.get(j))
                .min_by(|a, b| {
                    (a.stamp_s - l.stamp_s)
                        .abs()
                        .total_cmp(&(b.stamp_s - l.stamp_s).abs())
                })
                .filter(|r| (r.stamp_s - l.stamp_s).abs() <= PAIR_DT_S);
            let Some(r) = near else {
                unpaired += 1;
                continue;
            };
            match self.tf.lookup(&fixed, &l.frame, l.stamp_s)? {
                Some(pose) => pairs.push(((l.file, l.locator), (r.file, r.locator), pose)),
                None => outside += 1,
            }
        }
        let types = [left.clone(), right.clone()].map(|t| self.topics[&t].type_name.clone());
        Ok(StereoSelection {
            intrinsics: PinholeIntrinsics {
                fx: pl[(0, 0)],
                fy: pl[(1, 1)],
                cx: pl[(0, 2)],
                cy: pl[(1, 2)],
                width: li.width,
                height: li.height,
            },
            topics: [left, right],
            types,
            pose_source,
            fixed_frame: fixed,
            camera_frame: camera,
            baseline_m,
            pairs,
            left_images: lefts.len(),
            unpaired,
            outside,
        })
    }
}

/// A bag's stereo pairs as a sequence of depth frames.
pub struct BagStereo {
    bag: Bag,
    selection: StereoSelection,
    stereo: StereoDepth,
}

impl BagStereo {
    /// Opens and surveys `path`, chooses the pair with `opts`, and warns about what is skipped;
    /// its pairs become depth frames through `stereo`.
    pub(crate) fn open(path: &Path, opts: &BagOptions, stereo: StereoDepth) -> Result<BagStereo> {
        let bag = Bag::open(path)?;
        for note in &bag.notes {
            tracing::warn!("{note}");
        }
        let selection = bag
            .survey()?
            .select_stereo(opts)
            .map_err(|m| Error::bad_input(path, m))?;
        let s = &selection;
        if s.unpaired + s.outside > 0 {
            tracing::warn!(
                "{}: of {} images on {}, {} have no right image of their stamp and {} lie outside the poses' time span: skipped",
                path.display(), s.left_images, s.topics[0], s.unpaired, s.outside
            );
        }
        if s.is_empty() {
            return Err(Error::bad_input(
                path,
                format!(
                    "none of the {} images on {} has a partner and a pose",
                    s.left_images, s.topics[0]
                ),
            ));
        }
        Ok(BagStereo {
            bag,
            selection,
            stereo,
        })
    }

    /// What was chosen.
    pub fn selection(&self) -> &StereoSelection {
        &self.selection
    }
}

impl Sequence for BagStereo {
    fn len(&self) -> usize {
        self.selection.len()
    }
    fn read(&self, i: usize) -> Result<RangeInput> {
        let s = &self.selection;
        let &(l, r, pose) = s.pairs.get(i).ok_or_else(|| {
            Error::bad_input(
                self.bag.path(),
                format!("no pair {i} (the bag has {})", s.len()),
            )
        })?;
        // Fetched in the files' order, so that one pass serves a whole drive.
        let mut order = [(0, l), (1, r)];
        order.sort_by_key(|&(_, loc)| loc);
        let mut images: [Option<image::DynamicImage>; 2] = [None, None];
        for (side, (file, locator)) in order {
            let storage = &self.bag.files[file];
            let data = storage.fetch(locator)?;
            let img = msg::image_dynamic(&s.types[side], &data).map_err(|m| {
                Error::bad_input(storage.path(), format!("pair {i}, {}: {m}", s.topics[side]))
            })?;
            images[side] = Some(img);
        }
        let [Some(left), Some(right)] = images else {
            unreachable!("both sides fetched")
        };
        let grey = |img: &image::DynamicImage| {
            let g = img.to_luma8();
            Image {
                width: g.width(),
                height: g.height(),
                data: g.into_raw(),
            }
        };
        let (gl, gr) = (grey(&left), grey(&right));
        if (gl.width, gl.height) != (gr.width, gr.height) {
            return Err(Error::bad_input(
                self.bag.path(),
                format!(
                    "pair {i}: the left image is {}×{}, the right {}×{}",
                    gl.width, gl.height, gr.width, gr.height
                ),
            ));
        }
        let mut intrinsics = s.intrinsics;
        intrinsics.width = gl.width;
        intrinsics.height = gl.height;
        let rgb = left.to_rgb8();
        let color = Image {
            width: rgb.width(),
            height: rgb.height(),
            data: rgb
                .into_raw()
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect(),
        };
        let view = (intrinsics, pose, Some(color));
        self.stereo.frame((&gl, &gr), view, s.baseline_m)
    }
    fn describe(&self) -> String {
        let s = &self.selection;
        format!(
            "ROS 2 bag {} (stereo {} + {}, {}, poses from {} in '{}')",
            self.bag.path().display(),
            s.topics[0],
            s.topics[1],
            self.stereo.name(),
            s.pose_source,
            s.fixed_frame
        )
    }
    fn fingerprint(&self) -> u64 {
        pose_digest(self.len(), self.selection.pairs.iter().map(|p| &p.2))
    }
}
