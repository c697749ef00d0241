//! ROS 2 bags as input: a bag folder (`metadata.yaml` with `.mcap` or `.db3` files) or a single
//! `.mcap` / `.db3` file, read message by message in the files' order — never loaded whole.
//!
//! Opening a bag reads it once to survey it ([`Survey`]): the topics and their types, the
//! transform tree (`/tf_static`, `/tf`, odometry, stamped poses), and the time stamp and frame of
//! every point cloud. [`Survey::select`] then picks the LiDAR topic (`sensor_msgs/msg/
//! PointCloud2`: the only one, or `--lidar-topic`), the pose source (`/tf`, else the only
//! `nav_msgs/msg/Odometry`, else the only `geometry_msgs/msg/PoseStamped`, or `--pose-topic`)
//! and the fixed frame (the root above the scans' frame, or `--fixed-frame`), and poses each scan
//! at its header stamp; scans outside the poses' time span are skipped and counted. Fusion then
//! reads the chosen scans in a second pass ([`BagLidar`]).
//!
//! * Odometry is `header.frame_id → child_frame_id`. A stamped pose has no child frame: it is
//!   taken as the pose of the frame at the top of the scans' static chain (the body the sensor is
//!   mounted on; the sensor itself when no static transform exists).
//! * A file cut short or damaged is read up to the damage, which is reported with the file and
//!   byte offset; scans out of time order are fused in the bag's order, each at its own stamp,
//!   and counted.
//!
//! Stereo pairs (`--depth stereo`) are read by [`stereo`].
//!
//! What it does not do: ROS 1 bags; motion compensation of a scan; message types other than
//! those in [`msg::types`]; unrectified images.

mod mcap_file;
pub mod msg;
mod sqlite;
pub mod stereo;
mod survey;
pub mod tf;

use super::sequence::{pose_digest, RangeInput, Sequence};
use crate::frame::LidarScan;
use crate::{Error, Result};
use mcap_file::McapFile;
use sqlite::SqliteFile;
use std::path::{Path, PathBuf};
pub use survey::{Selection, Survey, TopicStats};

/// Where a file of a bag stopped being readable.
#[derive(Clone, Debug, PartialEq)]
pub struct Damage {
    /// The file.
    pub path: PathBuf,
    /// Bytes read when it stopped (MCAP: the damage lies in the last read, at most 64 KiB or
    /// one record before), or message bytes read (SQLite).
    pub offset: u64,
    /// What was wrong.
    pub message: String,
}

impl std::fmt::Display for Damage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: unreadable at or before byte {}: {}",
            self.path.display(),
            self.offset,
            self.message
        )
    }
}

/// One message as a pass hands it over.
pub struct Message<'a> {
    /// Topic name.
    pub topic: &'a str,
    /// ROS 2 type name (`sensor_msgs/msg/PointCloud2`).
    pub type_name: &'a str,
    /// The recorder's time, ns.
    pub log_time_ns: u64,
    /// The CDR body.
    pub data: &'a [u8],
    /// Where to fetch it again (file-specific).
    pub locator: u64,
    /// Bytes of the file read before it.
    pub offset: u64,
}

enum StorageFile {
    Mcap(Box<McapFile>),
    Sqlite(SqliteFile),
}

impl StorageFile {
    fn open(path: &Path) -> Result<StorageFile> {
        match extension(path).as_str() {
            "mcap" => Ok(StorageFile::Mcap(Box::new(McapFile::open(path)?))),
            "db3" => Ok(StorageFile::Sqlite(SqliteFile::open(path)?)),
            _ => Err(Error::bad_input(path, "not a bag file (.mcap or .db3)")),
        }
    }
    fn path(&self) -> &Path {
        match self {
            StorageFile::Mcap(f) => f.path(),
            StorageFile::Sqlite(f) => f.path(),
        }
    }
    fn scan(&self, visit: &mut dyn FnMut(Message<'_>) -> Result<()>) -> Result<Option<Damage>> {
        match self {
            StorageFile::Mcap(f) => f.scan(visit),
            StorageFile::Sqlite(f) => f.scan(visit),
        }
    }
    fn fetch(&self, locator: u64) -> Result<Vec<u8>> {
        match self {
            StorageFile::Mcap(f) => f.fetch(locator),
            StorageFile::Sqlite(f) => f.fetch(locator),
        }
    }
}

fn extension(path: &Path) -> String {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default()
}

fn storage_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file() && matches!(extension(p).as_str(), "mcap" | "db3"))
        .collect();
    // rosbag2 names split files `<bag>_0`, `<bag>_1`, …: order by that number, then by name.
    let index = |p: &PathBuf| {
        let stem = p
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let digits: String = stem
            .chars()
            .rev()
            .take_while(|c| c.is_ascii_digit())
            .collect();
        digits
            .chars()
            .rev()
            .collect::<String>()
            .parse::<u64>()
            .unwrap_or(0)
    };
    files.sort_by(|a, b| index(a).cmp(&index(b)).then_with(|| a.cmp(b)));
    files
}

/// Whether `path` is a ROS 2 bag: an `.mcap` / `.db3` file, or a folder with `metadata.yaml`
/// or such files.
pub fn is_bag(path: &Path) -> bool {
    if path.is_file() {
        matches!(extension(path).as_str(), "mcap" | "db3")
    } else {
        path.join("metadata.yaml").is_file() || !storage_files(path).is_empty()
    }
}

/// A bag: its storage files in order.
pub struct Bag {
    path: PathBuf,
    files: Vec<StorageFile>,
    /// Things the user should know about the bag itself (a missing `metadata.yaml`).
    pub notes: Vec<String>,
}

impl Bag {
    /// Opens a bag folder or a single bag file.
    pub fn open(path: &Path) -> Result<Bag> {
        let mut notes = Vec::new();
        let paths = if path.is_dir() {
            let files = storage_files(path);
            if files.is_empty() {
                return Err(Error::bad_input(
                    path,
                    "a bag folder without .mcap or .db3 files",
                ));
            }
            if !path.join("metadata.yaml").is_file() {
                notes.push(format!(
                    "{}: no metadata.yaml; reading the bag files found in the folder ({})",
                    path.display(),
                    files
                        .iter()
                        .filter_map(|f| f.file_name())
                        .map(|n| n.to_string_lossy())
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            }
            files
        } else {
            vec![path.to_path_buf()]
        };
        let files = paths
            .iter()
            .map(|p| StorageFile::open(p))
            .collect::<Result<_>>()?;
        Ok(Bag {
            path: path.to_path_buf(),
            files,
            notes,
        })
    }

    /// Storage files in the bag.
    pub fn file_count(&self) -> usize {
        self.files.len()
    }

    /// The bag's path as given.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Bytes in the bag's files.
    pub fn len_bytes(&self) -> u64 {
        self.files
            .iter()
            .map(|f| std::fs::metadata(f.path()).map_or(0, |m| m.len()))
            .sum()
    }

    /// Reads every message once and gathers what [`Survey::select`] needs.
    pub fn survey(&self) -> Result<Survey> {
        let mut s = Survey::default();
        let bar = crate::progress::bytes_bar(self.len_bytes(), "reading bag");
        let mut base = 0u64;
        for (file, storage) in self.files.iter().enumerate() {
            let damage = storage.scan(&mut |m: Message<'_>| {
                bar.set_position(base + m.offset);
                s.add(file, &m);
                Ok(())
            })?;
            if let Some(d) = damage {
                tracing::warn!("{d}; read up to there");
                s.damage.push(d);
            }
            base += std::fs::metadata(storage.path()).map_or(0, |m| m.len());
        }
        bar.finish_and_clear();
        s.bytes = base;
        Ok(s)
    }
}

/// Topics and frames named by the user (`None`: found by type).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BagOptions {
    /// `--lidar-topic`.
    pub lidar_topic: Option<String>,
    /// `--pose-topic`.
    pub pose_topic: Option<String>,
    /// `--fixed-frame`.
    pub fixed_frame: Option<String>,
    /// `--left-topic` (stereo).
    pub left_topic: Option<String>,
    /// `--right-topic` (stereo).
    pub right_topic: Option<String>,
}

/// A bag's point clouds as a sequence of posed LiDAR scans.
pub struct BagLidar {
    bag: Bag,
    selection: Selection,
}

impl BagLidar {
    /// Opens and surveys `path`, chooses with `opts`, and warns about skipped, out-of-order and
    /// damaged input.
    pub fn open(path: &Path, opts: &BagOptions) -> Result<BagLidar> {
        let bag = Bag::open(path)?;
        for note in &bag.notes {
            tracing::warn!("{note}");
        }
        let selection = bag
            .survey()?
            .select(opts)
            .map_err(|m| Error::bad_input(path, m))?;
        let s = &selection;
        if s.outside > 0 {
            tracing::warn!(
                "{}: {} of {} scans on {} lie outside the poses' time span and are skipped",
                path.display(),
                s.outside,
                s.clouds,
                s.lidar_topic
            );
        }
        if s.undecodable > 0 {
            tracing::warn!(
                "{}: {} messages on {} could not be decoded and are skipped",
                path.display(),
                s.undecodable,
                s.lidar_topic
            );
        }
        if s.out_of_order > 0 {
            tracing::warn!(
                "{}: {} scans on {} are out of time order; each is fused in the bag's order with the pose at its own stamp",
                path.display(), s.out_of_order, s.lidar_topic
            );
        }
        if s.is_empty() {
            return Err(Error::bad_input(
                path,
                format!(
                    "none of the {} scans on {} has a pose",
                    s.clouds, s.lidar_topic
                ),
            ));
        }
        Ok(BagLidar { bag, selection })
    }

    /// What was chosen.
    pub fn selection(&self) -> &Selection {
        &self.selection
    }
}

impl Sequence for BagLidar {
    fn len(&self) -> usize {
        self.selection.len()
    }
    fn read(&self, i: usize) -> Result<RangeInput> {
        let &(file, locator, pose) = self.selection.scans.get(i).ok_or_else(|| {
            Error::bad_input(
                self.bag.path(),
                format!("no scan {i} (the bag has {})", self.len()),
            )
        })?;
        let storage = &self.bag.files[file];
        let data = storage.fetch(locator)?;
        let cloud = msg::decode::<msg::PointCloud2>(&data)
            .and_then(|c| msg::cloud_points(&c))
            .map_err(|m| {
                Error::bad_input(
                    storage.path(),
                    format!("scan {i} on {}: {m}", self.selection.lidar_topic),
                )
            })?;
        Ok(RangeInput::Lidar(LidarScan {
            world_from_sensor: pose,
            points_sensor_m: cloud.0,
            intensity: cloud.1,
        }))
    }
    fn describe(&self) -> String {
        let s = &self.selection;
        format!(
            "ROS 2 bag {} (LiDAR {}, poses from {} in '{}')",
            self.bag.path().display(),
            s.lidar_topic,
            s.pose_source,
            s.fixed_frame
        )
    }
    fn fingerprint(&self) -> u64 {
        pose_digest(self.len(), self.selection.scans.iter().map(|s| &s.2))
    }
}
