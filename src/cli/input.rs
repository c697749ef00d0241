//! The flags that say how to read an input (`--poses`, `--extrinsic`, a bag's topics and fixed
//! frame), shared by `reconstruct` and `inspect-input`; and `inspect-input`, which lists what an
//! input holds and what `reconstruct` would use, without fusing anything.

use super::{help, Outcome};
use anyhow::{Context, Result};
use denser::io::bag::{Bag, BagOptions};
use denser::io::sequence::{detect_input, open_input, InputKind, InputOptions, RangeSource};
use std::fmt::Write;
use std::path::PathBuf;

/// How to read the input.
#[derive(clap::Args, Clone, Debug, Default)]
pub(crate) struct InputArgs {
    #[arg(long, help = help::POSES, help_heading = "Input")]
    pub poses: Option<PathBuf>,
    /// A folder of scans: the sensor's pose on the body the trajectory follows
    /// (`body_from_sensor`, a 4×4 or 3×4 matrix file) [default: extrinsic.txt in the folder,
    /// else the identity].
    #[arg(long, value_name = "FILE", help_heading = "Input")]
    pub extrinsic: Option<PathBuf>,
    /// A ROS 2 bag: the sensor_msgs/msg/PointCloud2 topic to fuse [default: the only one].
    #[arg(long, value_name = "TOPIC", help_heading = "Input")]
    pub lidar_topic: Option<String>,
    /// A ROS 2 bag: where poses come from, a tf2_msgs/msg/TFMessage, nav_msgs/msg/Odometry or
    /// geometry_msgs/msg/PoseStamped topic [default: /tf, else the only odometry or pose topic].
    #[arg(long, value_name = "TOPIC", help_heading = "Input")]
    pub pose_topic: Option<String>,
    /// A ROS 2 bag: the world frame of the map [default: the root of the transform tree above
    /// the sensor's frame].
    #[arg(long, value_name = "FRAME", help_heading = "Input")]
    pub fixed_frame: Option<String>,
    /// A ROS 2 bag with --depth stereo: the left rectified image topic (sensor_msgs/msg/Image
    /// or CompressedImage, its CameraInfo at `camera_info` beside it) [default: the only image
    /// topic whose name holds "left"].
    #[arg(long, value_name = "TOPIC", help_heading = "Input")]
    pub left_topic: Option<String>,
    /// A ROS 2 bag with --depth stereo: the right rectified image topic [default: the only
    /// image topic whose name holds "right"].
    #[arg(long, value_name = "TOPIC", help_heading = "Input")]
    pub right_topic: Option<String>,
}

impl InputArgs {
    /// The reader's options for `source`.
    pub fn options(&self, source: RangeSource) -> InputOptions {
        InputOptions {
            source,
            poses: self.poses.clone(),
            extrinsic: self.extrinsic.clone(),
            bag: BagOptions {
                lidar_topic: self.lidar_topic.clone(),
                pose_topic: self.pose_topic.clone(),
                fixed_frame: self.fixed_frame.clone(),
                left_topic: self.left_topic.clone(),
                right_topic: self.right_topic.clone(),
            },
            depth_on_device: None,
        }
    }
}

/// `denser inspect-input`.
#[derive(clap::Args)]
pub(crate) struct Args {
    /// An input as `reconstruct` takes it: a KITTI sequence, an RGB-D folder, a folder of scans
    /// or a ROS 2 bag.
    input: PathBuf,
    #[command(flatten)]
    how: InputArgs,
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    let context = || format!("inspecting {}", a.input.display());
    let kind = detect_input(&a.input).with_context(context)?;
    let mut out = format!("{}: {}\n", a.input.display(), kind.name());
    if kind == InputKind::Bag {
        let bag = Bag::open(&a.input).with_context(context)?;
        let survey = bag.survey().with_context(context)?;
        writeln!(
            out,
            "  {:.1} MiB in {} file(s)",
            survey.bytes as f64 / (1 << 20) as f64,
            bag.file_count()
        )?;
        for note in &bag.notes {
            writeln!(out, "  note: {note}")?;
        }
        for d in &survey.damage {
            writeln!(out, "  damaged: {d} (read up to there)")?;
        }
        writeln!(out, "  topics:")?;
        for (name, t) in &survey.topics {
            let bad = if t.undecodable > 0 {
                format!(" ({} undecodable)", t.undecodable)
            } else {
                String::new()
            };
            writeln!(
                out,
                "    {name:<32} {:<36} {:>7} messages{bad}",
                t.type_name, t.count
            )?;
        }
        writeln!(
            out,
            "  transforms: {}",
            denser::io::bag::tf::describe_edges(&survey.tf)
        )?;
        let opts = a.how.options(RangeSource::Lidar).bag;
        if survey.has_images() {
            // A selection consumes its survey: the stereo one takes a copy (the bag is read once).
            match survey.clone().select_stereo(&opts) {
                Ok(s) => {
                    writeln!(out, "  would match (--depth stereo): {} of {} pairs on {} + {} (frame '{}', fx {:.1} px, baseline {:.3} m)", s.len(), s.left_images, s.topics[0], s.topics[1], s.camera_frame, s.intrinsics.fx, s.baseline_m)?;
                    writeln!(
                        out,
                        "  poses: {} in fixed frame '{}'",
                        s.pose_source, s.fixed_frame
                    )?;
                }
                Err(why) => writeln!(out, "  cannot match stereo: {why}")?,
            }
        }
        match survey.select(&opts) {
            Ok(s) => {
                writeln!(
                    out,
                    "  would fuse: {} of {} scans on {} (frame '{}')",
                    s.len(),
                    s.clouds,
                    s.lidar_topic,
                    s.sensor_frame
                )?;
                writeln!(
                    out,
                    "  poses: {} in fixed frame '{}'",
                    s.pose_source, s.fixed_frame
                )?;
                if s.outside > 0 {
                    writeln!(
                        out,
                        "  skipped: {} scans outside the poses' time span",
                        s.outside
                    )?;
                }
                if s.out_of_order > 0 {
                    writeln!(
                        out,
                        "  out of time order: {} scans (fused in the bag's order)",
                        s.out_of_order
                    )?;
                }
            }
            Err(why) => writeln!(out, "  cannot fuse: {why}")?,
        }
        return Ok(Box::new(out));
    }
    let source = if kind.lidar_only() || kind == InputKind::Kitti {
        RangeSource::Lidar
    } else {
        RangeSource::GroundTruthDepth
    };
    let seq = open_input(&a.input, &a.how.options(source), None).with_context(context)?;
    writeln!(out, "  {}", seq.describe())?;
    writeln!(out, "  frames: {}", seq.len())?;
    Ok(Box::new(out))
}
