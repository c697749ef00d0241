//! The survey pass over a bag: topics and their types, the transform tree, every sensor
//! message's stamp and place; then the choice of the LiDAR topic, pose source and fixed frame,
//! and each scan's pose ([`Survey::select`]).

use super::msg::{self, types};
use super::tf::{self, TfTree};
use super::{BagOptions, Damage, Message};
use nalgebra::Isometry3;
use std::collections::BTreeMap;

/// Messages of one topic.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TopicStats {
    /// ROS 2 type name.
    pub type_name: String,
    /// Messages.
    pub count: u64,
    /// Messages that could not be decoded (of the types `denser` reads).
    pub undecodable: u64,
}

/// A sensor message (point cloud, image), not yet read.
#[derive(Clone, Debug)]
pub(super) struct MsgRef {
    pub(super) stamp_s: f64,
    pub(super) frame: String,
    pub(super) file: usize,
    pub(super) locator: u64,
}

/// A pose sample of an odometry or stamped-pose topic: time, parent, child (`None`: the body).
type PoseSample = (f64, String, Option<String>, Isometry3<f64>);

/// What one pass over a bag found.
#[derive(Clone, Default)]
pub struct Survey {
    /// Topics by name.
    pub topics: BTreeMap<String, TopicStats>,
    /// `/tf_static` and `/tf` (every `TFMessage` topic: static when its name ends in
    /// `tf_static`).
    pub tf: TfTree,
    pub(super) poses: BTreeMap<String, Vec<PoseSample>>,
    pub(super) clouds: BTreeMap<String, Vec<MsgRef>>,
    pub(super) images: BTreeMap<String, Vec<MsgRef>>,
    /// The first camera calibration of each `CameraInfo` topic.
    pub(super) camera_info: BTreeMap<String, msg::CameraInfo>,
    /// Files that could not be read to their end.
    pub damage: Vec<Damage>,
    /// Bytes of the bag.
    pub bytes: u64,
}

fn frame_name(id: &str) -> String {
    id.trim_start_matches('/').to_string()
}

impl Survey {
    pub(super) fn add(&mut self, file: usize, m: &Message<'_>) {
        if !self.topics.contains_key(m.topic) {
            let stats = TopicStats {
                type_name: m.type_name.to_string(),
                ..Default::default()
            };
            self.topics.insert(m.topic.to_string(), stats);
        }
        if let Some(stats) = self.topics.get_mut(m.topic) {
            stats.count += 1;
        }
        let ok =
            match m.type_name {
                types::TF => msg::decode::<msg::TfMessage>(m.data).map(|tf| {
                    let fixed = m.topic.ends_with("tf_static");
                    for t in &tf.transforms {
                        let (parent, child) = (
                            frame_name(&t.header.frame_id),
                            frame_name(&t.child_frame_id),
                        );
                        match t.transform.isometry() {
                            Some(iso) if fixed => self.tf.add_static(&parent, &child, iso),
                            Some(iso) => self.tf.add_moving(
                                &parent,
                                &child,
                                t.header.stamp.ns() as f64 * 1e-9,
                                iso,
                            ),
                            None => self.tf.conflicts += 1,
                        }
                    }
                }),
                types::ODOMETRY => msg::decode::<msg::Odometry>(m.data).map(|o| {
                    let child = Some(frame_name(&o.child_frame_id)).filter(|c| !c.is_empty());
                    self.add_pose(m, &o.header, child, &o.pose)
                }),
                types::POSE_STAMPED => msg::decode::<msg::PoseStamped>(m.data)
                    .map(|p| self.add_pose(m, &p.header, None, &p.pose)),
                types::POINT_CLOUD2 => msg::decode::<msg::Header>(m.data)
                    .map(|h| add_ref(&mut self.clouds, m, file, &h)),
                types::IMAGE | types::COMPRESSED_IMAGE => msg::decode::<msg::Header>(m.data)
                    .map(|h| add_ref(&mut self.images, m, file, &h)),
                types::CAMERA_INFO if !self.camera_info.contains_key(m.topic) => {
                    msg::decode::<msg::CameraInfo>(m.data).map(|c| {
                        self.camera_info.insert(m.topic.to_string(), c);
                    })
                }
                _ => Ok(()),
            };
        if ok.is_err() {
            if let Some(s) = self.topics.get_mut(m.topic) {
                s.undecodable += 1;
            }
        }
    }

    /// A pose sample of an odometry or stamped-pose message (`child`: `None` for the body).
    fn add_pose(
        &mut self,
        m: &Message<'_>,
        header: &msg::Header,
        child: Option<String>,
        pose: &msg::Transform,
    ) {
        if let Some(iso) = pose.isometry() {
            let t = stamp_s(header.stamp, m.log_time_ns);
            let parent = frame_name(&header.frame_id);
            let samples = self.poses.entry(m.topic.to_string()).or_default();
            samples.push((t, parent, child, iso));
        }
    }

    /// Topics of `type_name`.
    pub(super) fn of_type(&self, type_name: &str) -> Vec<&str> {
        self.topics
            .iter()
            .filter(|(_, s)| s.type_name == type_name)
            .map(|(t, _)| t.as_str())
            .collect()
    }

    pub(super) fn topic_list(&self) -> String {
        let list: Vec<String> = self
            .topics
            .iter()
            .map(|(t, s)| format!("{t} ({})", s.type_name))
            .collect();
        if list.is_empty() {
            "none".into()
        } else {
            list.join(", ")
        }
    }

    /// The one topic of `type_name`, `named` when given (checked to exist and be of that type).
    pub(super) fn pick(
        &self,
        named: Option<&str>,
        type_names: &[&str],
        flag: &str,
    ) -> std::result::Result<Option<String>, String> {
        if let Some(t) = named {
            return match self.topics.get(t) {
                None => Err(format!(
                    "{flag} {t}: the bag has no such topic (topics: {})",
                    self.topic_list()
                )),
                Some(s) if !type_names.contains(&s.type_name.as_str()) => Err(format!(
                    "{flag} {t}: the topic is {}, not {}",
                    s.type_name,
                    type_names.join(" or ")
                )),
                Some(_) => Ok(Some(t.to_string())),
            };
        }
        for ty in type_names {
            match self.of_type(ty).as_slice() {
                [] => {}
                [one] => return Ok(Some(one.to_string())),
                many => {
                    return Err(format!(
                        "several {ty} topics ({}): name one with {flag}",
                        many.join(", ")
                    ))
                }
            }
        }
        Ok(None)
    }

    /// Joins the pose topic to the transform tree and finds the fixed frame above `sensor`:
    /// (where the poses come from, the fixed frame).
    pub(super) fn prepare_poses(
        &mut self,
        opts: &BagOptions,
        sensor: &str,
    ) -> std::result::Result<(String, String), String> {
        let has_moving_tf = self.tf.edges().any(|(_, _, moving)| moving);
        let pose_topic = match &opts.pose_topic {
            Some(_) => self.pick(
                opts.pose_topic.as_deref(),
                &[types::TF, types::ODOMETRY, types::POSE_STAMPED],
                "--pose-topic",
            )?,
            None if has_moving_tf => None,
            None => Some(
                self.pick(
                    None,
                    &[types::ODOMETRY, types::POSE_STAMPED],
                    "--pose-topic",
                )?
                .ok_or_else(|| {
                    format!(
                        "no poses: no /tf, {} or {} topic (topics: {})",
                        types::ODOMETRY,
                        types::POSE_STAMPED,
                        self.topic_list()
                    )
                })?,
            ),
        };
        // Odometry and stamped poses join the tree as moving edges above the body.
        let body = self
            .tf
            .chain(sensor)
            .last()
            .cloned()
            .unwrap_or_else(|| sensor.to_string());
        let pose_source = match pose_topic
            .as_ref()
            .and_then(|t| self.poses.remove(t).map(|p| (t, p)))
        {
            Some((topic, samples)) => {
                for (t, parent, child, iso) in samples {
                    self.tf
                        .add_moving(&parent, child.as_deref().unwrap_or(&body), t, iso);
                }
                format!("{topic} ({})", self.topics[topic].type_name)
            }
            None => "/tf".to_string(),
        };
        self.tf.finish();
        let chain = self.tf.chain(sensor);
        let fixed = match &opts.fixed_frame {
            Some(f) if !chain.contains(f) => {
                return Err(format!(
                    "--fixed-frame {f}: not above the sensor's frame '{sensor}' (its chain: {})",
                    chain.join(" → ")
                ))
            }
            Some(f) => f.clone(),
            None => chain.last().cloned().unwrap_or_default(),
        };
        if !self.tf.moves(sensor) {
            let hint = if chain.len() == 1 {
                format!(" No transform names '{sensor}' as its child: is /tf_static missing?")
            } else {
                String::new()
            };
            return Err(format!(
                "no moving transform above the sensor's frame '{sensor}' (its chain: {}; transforms: {}).{hint}",
                chain.join(" → "),
                tf::describe_edges(&self.tf)
            ));
        }
        Ok((pose_source, fixed))
    }

    /// Chooses the LiDAR topic, poses and frames, and poses every scan; errors say what is
    /// missing and which flag names it.
    pub fn select(mut self, opts: &BagOptions) -> std::result::Result<Selection, String> {
        let lidar = self
            .pick(
                opts.lidar_topic.as_deref(),
                &[types::POINT_CLOUD2],
                "--lidar-topic",
            )?
            .ok_or_else(|| {
                format!(
                    "no {} topic (topics: {})",
                    types::POINT_CLOUD2,
                    self.topic_list()
                )
            })?;
        let clouds = self.clouds.remove(&lidar).unwrap_or_default();
        let undecodable = self.topics.get(&lidar).map_or(0, |t| t.undecodable);
        let Some(first) = clouds.first() else {
            return Err(format!("topic {lidar} has no decodable point cloud"));
        };
        let sensor = first.frame.clone();
        let (pose_source, fixed) = self.prepare_poses(opts, &sensor)?;
        let mut scans = Vec::with_capacity(clouds.len());
        let (mut outside, mut out_of_order) = (0usize, 0usize);
        let mut last = f64::NEG_INFINITY;
        for c in &clouds {
            if c.stamp_s < last {
                out_of_order += 1;
            }
            last = last.max(c.stamp_s);
            match self.tf.lookup(&fixed, &c.frame, c.stamp_s)? {
                Some(pose) => scans.push((c.file, c.locator, pose)),
                None => outside += 1,
            }
        }
        Ok(Selection {
            lidar_topic: lidar,
            pose_source,
            fixed_frame: fixed,
            sensor_frame: sensor,
            scans,
            clouds: clouds.len(),
            outside,
            out_of_order,
            undecodable,
        })
    }
}

/// Records where a sensor message is, and its stamp and frame.
fn add_ref(
    refs: &mut BTreeMap<String, Vec<MsgRef>>,
    m: &Message<'_>,
    file: usize,
    header: &msg::Header,
) {
    refs.entry(m.topic.to_string()).or_default().push(MsgRef {
        stamp_s: stamp_s(header.stamp, m.log_time_ns),
        frame: frame_name(&header.frame_id),
        file,
        locator: m.locator,
    });
}

pub(super) fn stamp_s(t: msg::Time, log_time_ns: u64) -> f64 {
    let ns = t.ns();
    if ns > 0 {
        ns as f64 * 1e-9
    } else {
        log_time_ns as f64 * 1e-9
    }
}

/// What a bag's LiDAR input will be.
#[derive(Clone, Debug)]
pub struct Selection {
    /// The point cloud topic.
    pub lidar_topic: String,
    /// Where the poses come from (`/tf`, or a topic with its type).
    pub pose_source: String,
    /// The world frame.
    pub fixed_frame: String,
    /// The first scan's frame.
    pub sensor_frame: String,
    /// (file, locator, `world_from_sensor`) of each scan with a pose, in the bag's order.
    pub(super) scans: Vec<(usize, u64, Isometry3<f64>)>,
    /// Point clouds on the topic.
    pub clouds: usize,
    /// Clouds skipped: outside the poses' time span.
    pub outside: usize,
    /// Clouds stamped earlier than one before them.
    pub out_of_order: usize,
    /// Messages on the topic whose header could not be decoded (skipped).
    pub undecodable: u64,
}

impl Selection {
    /// Scans that will be fused.
    pub fn len(&self) -> usize {
        self.scans.len()
    }

    /// Whether no scan will be fused.
    pub fn is_empty(&self) -> bool {
        self.scans.is_empty()
    }
}
