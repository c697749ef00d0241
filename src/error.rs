//! The library's error type. Every variant that concerns a file names the file; the CLI adds
//! context with `anyhow` and prints the whole chain once.

use std::path::{Path, PathBuf};

/// Errors returned by the `denser` library.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The operating system refused an I/O operation on `path`.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory involved.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A file was read but its content is wrong (malformed, truncated, inconsistent).
    #[error("{path}: {message}")]
    BadInput {
        /// The offending file.
        path: PathBuf,
        /// What is wrong with it, in words a user can act on.
        message: String,
    },
    /// Another writer holds the map's lock (`MAP/lock`): one writer per map at a time.
    #[error("{dir}: the map is locked by another writer: {holder}; wait for it to finish (inspect and export may run meanwhile)")]
    MapLocked {
        /// The map directory.
        dir: PathBuf,
        /// Who holds the lock (pid, host, command line, for how long), as its lock file says.
        holder: String,
    },
    /// An object store refused or failed a request on `path` (`s3://bucket/prefix/…`).
    #[error("{path}: object store: {message}")]
    Storage {
        /// The object (or map) involved, as a URL.
        path: PathBuf,
        /// The store's error, in its words.
        message: String,
    },
    /// Another writer committed the map's manifest after this writer read it: this writer's
    /// commit was refused (compare-and-swap) and nothing it wrote is named by the manifest.
    #[error("{map}: the map was committed by another writer since this one read it (generation {read_generation}); this writer's commit was refused and nothing it wrote was committed: reopen the map and run again")]
    CommitConflict {
        /// The map.
        map: PathBuf,
        /// The generation this writer had read.
        read_generation: u64,
    },
    /// A writer's lock file was removed or replaced while it held the lock: another writer may
    /// have been admitted, so this one stops before its next commit.
    #[error("{path}: {why} while this writer held the lock; another writer may have been admitted, so this one stopped before committing (what it committed earlier is intact)")]
    LockLost {
        /// The lock file.
        path: PathBuf,
        /// What happened to it.
        why: String,
    },
    /// The manifest is older than the map's last commit (an older copy put back by a restore or a
    /// sync): opening it would name deleted files and delete newer ones, so nothing is done.
    #[error("{map}: the manifest (generation {manifest_generation}) is older than the map's last commit (generation {newer_generation}: {evidence}); it was replaced by an older copy (a restore from a backup or a sync tool?). Nothing was changed or deleted. Run `denser repair {map}` to rebuild the manifest from the chunk files (the older one is kept beside it)")]
    MapRolledBack {
        /// The map.
        map: PathBuf,
        /// The generation of the manifest found.
        manifest_generation: u64,
        /// The newest generation the map shows evidence of.
        newer_generation: u64,
        /// Where that evidence is.
        evidence: String,
    },
    /// A parameter or argument is out of its valid range.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// The GPU (wgpu) failed: no adapter when one was required, a validation or out-of-memory
    /// error, a lost device.
    #[error("GPU: {0}")]
    Gpu(String),
    /// Work does not fit the GPU's limits (a storage binding larger than the device allows,
    /// 128 MiB on llvmpipe) and was not split.
    #[error("GPU capacity: {what} needs {needed_bytes} but the device allows {limit_bytes}")]
    GpuCapacity {
        /// What did not fit.
        what: String,
        /// Size needed (bytes, or a count where `what` says so).
        needed_bytes: u64,
        /// The device's limit, same unit.
        limit_bytes: u64,
    },
}

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }

    /// A content error in `path`.
    pub fn bad_input(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Error::BadInput {
            path: path.as_ref().to_path_buf(),
            message: message.into(),
        }
    }
}

/// Result alias for the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;
