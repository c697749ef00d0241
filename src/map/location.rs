//! Where a map lives: a local directory or an object-store prefix ([`MapLocation`]), parsed from
//! what the user typed. Plain data: [`MapLocation::open_files`] (in `store/`, above both sides of
//! the seam) picks the implementation, so [`super::files`] and `s3` do not import each other.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// Where a map lives: a local directory or an object-store prefix.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MapLocation {
    /// A directory on a local (or network) file system.
    Dir(PathBuf),
    /// `s3://bucket/prefix`: objects `prefix/manifest.dmf`, `prefix/chunks/…` in `bucket`.
    S3 {
        /// The bucket.
        bucket: String,
        /// The key prefix, without leading or trailing `/` (may be empty).
        prefix: String,
    },
}

impl MapLocation {
    /// Parses `s3://bucket/prefix` (an object store) or anything else as a directory path.
    pub fn parse(s: &str) -> Result<Self> {
        if let Some(rest) = s.strip_prefix("s3://") {
            let (bucket, prefix) = rest.split_once('/').unwrap_or((rest, ""));
            if bucket.is_empty() {
                return Err(Error::InvalidArgument(format!(
                    "{s:?}: an object-store map is s3://BUCKET/PREFIX"
                )));
            }
            let prefix = prefix.trim_matches('/');
            // Object keys have no relative segments: `s3://city/../x` was written under the
            // literal key `%2E%2E/x` (issue 36).
            if let Some(bad) = (!prefix.is_empty())
                .then(|| prefix.split('/'))
                .into_iter()
                .flatten()
                .find(|seg| seg.is_empty() || *seg == "." || *seg == "..")
            {
                return Err(Error::InvalidArgument(format!(
                    "{s:?}: an object-store prefix has no {} segments (object keys are not paths); name the prefix as it is stored",
                    if bad.is_empty() { "empty" } else { "'.' or '..'" }
                )));
            }
            return Ok(MapLocation::S3 {
                bucket: bucket.to_string(),
                prefix: prefix.to_string(),
            });
        }
        if s.contains("://") {
            return Err(Error::InvalidArgument(format!(
                "{s:?}: unknown map address (give a directory or s3://bucket/prefix)"
            )));
        }
        Ok(MapLocation::Dir(PathBuf::from(s)))
    }

    /// The local directory, if this is one.
    pub fn as_dir(&self) -> Option<&Path> {
        match self {
            MapLocation::Dir(d) => Some(d),
            MapLocation::S3 { .. } => None,
        }
    }

    /// The location as a path, for messages: the directory, or `s3://bucket/prefix`.
    pub fn display_path(&self) -> PathBuf {
        PathBuf::from(self.to_string())
    }
}

impl From<&Path> for MapLocation {
    fn from(p: &Path) -> Self {
        MapLocation::Dir(p.to_path_buf())
    }
}

impl std::fmt::Display for MapLocation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MapLocation::Dir(d) => write!(f, "{}", d.display()),
            MapLocation::S3 { bucket, prefix } if prefix.is_empty() => write!(f, "s3://{bucket}"),
            MapLocation::S3 { bucket, prefix } => write!(f, "s3://{bucket}/{prefix}"),
        }
    }
}

impl std::str::FromStr for MapLocation {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        MapLocation::parse(s)
    }
}
