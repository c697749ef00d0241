//! The job record of a map (`job.djr` beside the manifest, `formats/job.md`): what made the map
//! (range source, frames, grid, stereo settings, and a fingerprint of the input data), so that a
//! resumed `reconstruct --map` refuses to continue a map made from other data or settings and
//! says which fields differ. It stores no absolute path: the input is identified by its
//! fingerprint (frame count and poses), so a moved dataset still resumes; its path relative to
//! the map is kept for the user.
//!
//! The record is a fixed header (magic `DJR1`, format version, payload length), a bincode 2
//! payload and a CRC-32, written atomically. Maps made before it carry `job.json`; it is read,
//! checked and replaced by a `job.djr` on the first resume.

use super::files::write_atomically;
use super::layout::{JOB_FILE, LEGACY_JOB_FILE};
use crate::{Error, Result};
use std::path::{Path, PathBuf};

/// Magic bytes at offset 0.
pub const JOB_MAGIC: [u8; 4] = *b"DJR1";
/// Current format version.
pub const JOB_VERSION: u16 = 1;

/// What made a map (see the module documentation).
#[derive(Clone, Debug, PartialEq, bincode::Encode, bincode::Decode)]
pub struct JobRecord {
    /// Range source: `lidar`, `gt`, `stereo` (KITTI layouts) or `rgbd`.
    pub source: String,
    /// Frame count and poses of the input ([`crate::io::sequence::Sequence::fingerprint`]).
    pub input_fingerprint: u64,
    /// Frames in the input sequence.
    pub input_frames: u64,
    /// First frame used.
    pub first_frame: u64,
    /// One past the last frame used (`None`: to the end).
    pub last_frame: Option<u64>,
    /// Every n-th frame.
    pub frame_step: u64,
    /// Voxel edge, metres.
    pub voxel_size_m: f32,
    /// Truncation μ, metres.
    pub truncation_m: f32,
    /// Depths beyond this were ignored, metres.
    pub max_depth_m: f32,
    /// Stereo matcher (`sgm`, `tv`, `tgv`, `tgv-tensor`; empty when not stereo).
    pub stereo_method: String,
    /// Disparities searched (0 when not stereo).
    pub num_disparities: u32,
    /// Informational: the input folder relative to the map directory when expressible, else
    /// its name.
    pub input_hint: String,
    /// Informational: the `denser` version that created the map.
    pub created_by: String,
}

impl JobRecord {
    /// The fields that differ between `self` (stored) and `other` (this run), as
    /// `name: stored → now`, ignoring the informational ones.
    pub fn differences(&self, other: &JobRecord) -> Vec<String> {
        let mut d = Vec::new();
        let mut cmp = |name: &str, a: String, b: String| {
            if a != b {
                d.push(format!("{name}: {a} → {b}"));
            }
        };
        cmp("source", self.source.clone(), other.source.clone());
        cmp(
            "input (frame count and poses)",
            format!(
                "{} frames, digest {:016x}",
                self.input_frames, self.input_fingerprint
            ),
            format!(
                "{} frames, digest {:016x}",
                other.input_frames, other.input_fingerprint
            ),
        );
        cmp(
            "first frame",
            self.first_frame.to_string(),
            other.first_frame.to_string(),
        );
        cmp(
            "last frame",
            format!("{:?}", self.last_frame),
            format!("{:?}", other.last_frame),
        );
        cmp(
            "frame step",
            self.frame_step.to_string(),
            other.frame_step.to_string(),
        );
        cmp(
            "voxel size (m)",
            self.voxel_size_m.to_string(),
            other.voxel_size_m.to_string(),
        );
        cmp(
            "truncation (m)",
            self.truncation_m.to_string(),
            other.truncation_m.to_string(),
        );
        cmp(
            "max depth (m)",
            self.max_depth_m.to_string(),
            other.max_depth_m.to_string(),
        );
        cmp(
            "stereo method",
            self.stereo_method.clone(),
            other.stereo_method.clone(),
        );
        cmp(
            "disparities",
            self.num_disparities.to_string(),
            other.num_disparities.to_string(),
        );
        d
    }

    /// The record's file bytes (`formats/job.md`).
    pub fn encode(&self) -> Vec<u8> {
        super::record::encode(JOB_MAGIC, JOB_VERSION, self)
    }

    /// Decodes file bytes; `path` names the file in errors.
    pub fn decode(path: &Path, b: &[u8]) -> Result<Self> {
        super::record::decode(path, b, JOB_MAGIC, JOB_VERSION, "job record", "job record")
    }

    /// Writes the record into `map_dir` (atomically).
    pub fn write(&self, map_dir: &Path) -> Result<()> {
        write_atomically(&map_dir.join(JOB_FILE), &self.encode())
    }

    /// The record stored in `map_dir`, if any (a legacy `job.json` is converted, with its
    /// absolute input path checked against `input` since it has no fingerprint).
    pub fn read(map_dir: &Path, input: &Path) -> Result<Option<Self>> {
        let path = map_dir.join(JOB_FILE);
        match std::fs::read(&path) {
            Ok(b) => return Self::decode(&path, &b).map(Some),
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(Error::io(&path, e)),
            Err(_) => {}
        }
        let legacy = map_dir.join(LEGACY_JOB_FILE);
        match std::fs::read(&legacy) {
            Ok(b) => LegacyRecord::parse(&legacy, &b)?
                .check_input(&legacy, input)
                .map(Some),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(Error::io(&legacy, e)),
        }
    }

    /// Writes the record into the map at any location (atomically).
    pub fn write_at(&self, files: &dyn super::files::MapFiles) -> Result<()> {
        match files.location().as_dir() {
            Some(dir) => self.write(dir),
            None => files.write(JOB_FILE, &self.encode()),
        }
    }

    /// [`JobRecord::check_or_write`] for a map at any location (object stores have no legacy
    /// `job.json`).
    pub fn check_or_write_at(
        &self,
        files: &dyn super::files::MapFiles,
        input: &Path,
        frames_committed: u64,
    ) -> Result<()> {
        if let Some(dir) = files.location().as_dir() {
            return self.check_or_write(dir, input, frames_committed);
        }
        let path = files.path(JOB_FILE);
        match files.read_versioned(JOB_FILE)? {
            None if frames_committed > 0 => Err(missing_record(path, frames_committed)),
            None => self.write_at(files),
            Some((b, _)) => {
                let stored = Self::decode(&path, &b)?;
                let diff = stored.differences(self);
                if diff.is_empty() {
                    Ok(())
                } else {
                    Err(Error::bad_input(
                        path,
                        format!(
                            "this map was made by another job; use a new --map, or rerun with the map's settings. Differences (map → this run): {}",
                            diff.join("; ")
                        ),
                    ))
                }
            }
        }
    }

    /// Checks a resumed run against the record of `map_dir`: an error naming every field that
    /// differs, so the user can fix the command or use a new map. An absent record is written
    /// when the map holds no committed frame (`frames_committed`), and refused otherwise: the
    /// run could not tell whether it continues the same job (issue 36).
    pub fn check_or_write(
        &self,
        map_dir: &Path,
        input: &Path,
        frames_committed: u64,
    ) -> Result<()> {
        match Self::read(map_dir, input)? {
            None if frames_committed > 0 => {
                Err(missing_record(map_dir.join(JOB_FILE), frames_committed))
            }
            None => self.write(map_dir),
            Some(mut stored) => {
                if stored.input_fingerprint == 0 {
                    // Converted from job.json: the input was checked by path.
                    stored.input_fingerprint = self.input_fingerprint;
                    stored.input_frames = self.input_frames;
                }
                let diff = stored.differences(self);
                if !diff.is_empty() {
                    return Err(Error::bad_input(
                        map_dir.join(JOB_FILE),
                        format!(
                            "this map was made by another job; use a new --map folder, or rerun with the map's settings. Differences (map → this run): {}",
                            diff.join("; ")
                        ),
                    ));
                }
                if !map_dir.join(JOB_FILE).exists() {
                    self.write(map_dir)?;
                    let legacy = map_dir.join(LEGACY_JOB_FILE);
                    std::fs::remove_file(&legacy).map_err(|e| Error::io(&legacy, e))?;
                }
                Ok(())
            }
        }
    }
}

/// The refusal of a resume whose map lost its job record.
fn missing_record(path: PathBuf, frames_committed: u64) -> Error {
    Error::bad_input(
        path,
        format!(
            "missing, but the map holds {frames_committed} committed frames: without the record of the job that fused them, a resumed run cannot check that it is the same job (input, range, step, grid, depth limit). Restore the file from a backup, or reconstruct into a new --map folder; regularize, export and inspect still work"
        ),
    )
}

/// The input folder as seen from `map_dir` (`../data/seq00`), or its own path when the two
/// share no root.
pub fn relative_hint(map_dir: &Path, input: &Path) -> String {
    let (Ok(map), Ok(input_abs)) = (std::fs::canonicalize(map_dir), std::fs::canonicalize(input))
    else {
        return input.display().to_string();
    };
    let common = map
        .components()
        .zip(input_abs.components())
        .take_while(|(a, b)| a == b)
        .count();
    if common == 0 {
        return input.display().to_string();
    }
    let mut rel = PathBuf::new();
    for _ in map.components().skip(common) {
        rel.push("..");
    }
    for c in input_abs.components().skip(common) {
        rel.push(c);
    }
    rel.display().to_string()
}

/// `job.json` of maps made before `job.djr`.
#[derive(serde::Deserialize)]
struct LegacyRecord {
    input: String,
    source: String,
    frames: Option<(usize, usize)>,
    frame_step: usize,
    voxel_size_m: f32,
    truncation_m: f32,
    max_depth_m: f32,
    stereo: String,
    num_disparities: usize,
}

impl LegacyRecord {
    fn parse(path: &Path, b: &[u8]) -> Result<Self> {
        serde_json::from_slice(b).map_err(|e| Error::bad_input(path, format!("job record: {e}")))
    }

    /// The record as a [`JobRecord`] with no fingerprint, after checking that `input` is the
    /// folder it names.
    fn check_input(self, path: &Path, input: &Path) -> Result<JobRecord> {
        let now = std::fs::canonicalize(input).unwrap_or_else(|_| input.to_path_buf());
        if Path::new(&self.input) != now {
            return Err(Error::bad_input(
                path,
                format!(
                    "this map was made from {}, not {}; use a new --map folder",
                    self.input,
                    now.display()
                ),
            ));
        }
        let source = match self.source.as_str() {
            "Lidar" => "lidar",
            "GroundTruthDepth" => "gt",
            "Stereo" => "stereo",
            other => {
                return Err(Error::bad_input(
                    path,
                    format!("unknown range source {other:?}"),
                ))
            }
        };
        let (first, last) = self.frames.unwrap_or((0, usize::MAX));
        Ok(JobRecord {
            source: source.to_string(),
            input_fingerprint: 0,
            input_frames: 0,
            first_frame: first as u64,
            last_frame: (last != usize::MAX).then_some(last as u64),
            frame_step: self.frame_step as u64,
            voxel_size_m: self.voxel_size_m,
            truncation_m: self.truncation_m,
            max_depth_m: self.max_depth_m,
            stereo_method: self.stereo,
            num_disparities: self.num_disparities as u32,
            input_hint: self.input,
            created_by: "denser (before job.djr)".into(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record() -> JobRecord {
        JobRecord {
            source: "lidar".into(),
            input_fingerprint: 0x1234_5678_9abc_def0,
            input_frames: 101,
            first_frame: 0,
            last_frame: Some(50),
            frame_step: 1,
            voxel_size_m: 0.1,
            truncation_m: 1.0,
            max_depth_m: 40.0,
            stereo_method: String::new(),
            num_disparities: 0,
            input_hint: "../drive/sequences/00".into(),
            created_by: "denser 0.1.0".into(),
        }
    }

    #[test]
    fn round_trips_and_rejects_damage() {
        let r = record();
        let b = r.encode();
        assert_eq!(&b[..4], b"DJR1");
        assert_eq!(
            JobRecord::decode(Path::new("job.djr"), &b).expect("decodes"),
            r
        );
        for k in [0, 5, 12, b.len() - 1] {
            let mut bad = b.clone();
            bad[k] ^= 0x40;
            assert!(
                JobRecord::decode(Path::new("job.djr"), &bad).is_err(),
                "byte {k}"
            );
        }
        assert!(JobRecord::decode(Path::new("job.djr"), &b[..b.len() - 1]).is_err());
    }

    #[test]
    fn differences_name_fields_and_ignore_hints() {
        let a = record();
        let mut b = record();
        b.input_hint = "/elsewhere".into();
        b.created_by = "denser 9".into();
        assert!(a.differences(&b).is_empty());
        b.voxel_size_m = 0.2;
        b.last_frame = None;
        let d = a.differences(&b);
        assert_eq!(d.len(), 2, "{d:?}");
        assert!(d[0].starts_with("last frame") && d[1].starts_with("voxel size"));
    }
}
