//! Who may touch a map directory: one writer at a time, any number of readers.
//!
//! - **Writers** (every command that commits a manifest or deletes a file: `reconstruct --map`,
//!   `regularize`, `repair`) hold an exclusive advisory lock (`flock`, through `std::fs::File`'s
//!   locking) on `MAP/lock` for as long as their [`super::store::MapStore`] lives, and write who
//!   they are into it (pid, host, command line, start time). A second writer is refused at once
//!   with [`Error::MapLocked`] naming the holder. The kernel drops the lock when the holder's
//!   process dies, however it dies, so a stale lock needs no cleaning: the next writer gets it and
//!   finds the dead holder's record still in the file (a clean exit empties it), which it reports.
//! - **Readers** (`inspect`, `export`) never take the writer lock and never delete anything. They
//!   hold a shared lock on `MAP/readers.lock` for their whole life. A writer deletes a file that a
//!   committed manifest named (a superseded chunk version) only while it holds that lock
//!   exclusively, which it only tries (never waits for); while a reader is open the files wait,
//!   and are deleted by a later commit, the writer's exit or the next writer. So a reader's
//!   manifest (read after its lock is taken) names files that stay on disk until it closes.
//!
//! These are advisory `flock` locks: they bind `denser` processes (of this build or later) on one
//! machine's local file system; on NFS Linux maps them to POSIX byte-range locks.

use super::layout::{LOCK_FILE, READERS_LOCK_FILE};
use crate::error::{Error, Result};
use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

/// Who holds (or held) a map's writer lock, as recorded in the lock file.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LockHolder {
    /// Process id.
    pub pid: u32,
    /// Host name.
    pub host: String,
    /// Command line.
    pub command: String,
    /// When the lock was taken, seconds since the Unix epoch.
    pub since_unix_s: u64,
}

fn now_unix_s() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// This machine's host name (`/proc/sys/kernel/hostname`, else `$HOSTNAME`).
pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "unknown host".into())
}

impl LockHolder {
    /// This process.
    pub fn current() -> Self {
        let mut args = std::env::args();
        let program = args
            .next()
            .map(|a| {
                Path::new(&a)
                    .file_name()
                    .map_or(a.clone(), |n| n.to_string_lossy().into_owned())
            })
            .unwrap_or_default();
        let mut command = std::iter::once(program)
            .chain(args)
            .collect::<Vec<_>>()
            .join(" ");
        if command.len() > 1000 {
            let mut cut = 1000;
            while !command.is_char_boundary(cut) {
                cut -= 1;
            }
            command.truncate(cut);
            command.push('…');
        }
        LockHolder {
            pid: std::process::id(),
            host: host_name(),
            command: command.replace('\n', " "),
            since_unix_s: now_unix_s(),
        }
    }

    /// The lock file's text: `key=value` lines.
    pub fn encode(&self) -> String {
        format!(
            "pid={}\nhost={}\nsince_unix_s={}\ncommand={}\n",
            self.pid, self.host, self.since_unix_s, self.command
        )
    }

    /// Parses [`LockHolder::encode`]'s text; `None` when empty or unreadable.
    pub fn parse(s: &str) -> Option<Self> {
        let mut h = LockHolder::default();
        let mut any = false;
        for line in s.lines() {
            let Some((k, v)) = line.split_once('=') else {
                continue;
            };
            any = true;
            match k {
                "pid" => h.pid = v.parse().ok()?,
                "host" => h.host = v.to_string(),
                "since_unix_s" => h.since_unix_s = v.parse().unwrap_or(0),
                "command" => h.command = v.to_string(),
                _ => {}
            }
        }
        (any && h.pid != 0).then_some(h)
    }

    /// "pid 4242 on host h (`denser regularize m`), for 12 s".
    pub fn describe(&self) -> String {
        let this = if self.pid == std::process::id() && self.host == host_name() {
            ", this process"
        } else {
            ""
        };
        format!(
            "pid {} on host {}{this} (`{}`), for {} s",
            self.pid,
            self.host,
            self.command,
            now_unix_s().saturating_sub(self.since_unix_s)
        )
    }
}

/// The exclusive writer lock of a map directory, held until dropped.
#[derive(Debug)]
pub struct WriterLock {
    file: File,
    path: PathBuf,
    /// The record of a holder that died without releasing the lock (a stale lock, recovered).
    pub stale: Option<LockHolder>,
}

impl WriterLock {
    /// Takes the writer lock of `dir` (which must exist) or fails at once with
    /// [`Error::MapLocked`] naming the holder.
    pub fn acquire(dir: &Path) -> Result<Self> {
        let path = dir.join(LOCK_FILE);
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| Error::io(&path, e))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                return Err(Error::MapLocked {
                    dir: dir.to_path_buf(),
                    holder: read_holder(&path)
                        .map_or("a writer that is starting or stopping".into(), |h| {
                            h.describe()
                        }),
                })
            }
            Err(TryLockError::Error(e)) => {
                return Err(Error::bad_input(
                    &path,
                    format!(
                        "cannot lock the map for writing ({e}); the file system must support flock"
                    ),
                ))
            }
        }
        let mut old = String::new();
        let _ = file.read_to_string(&mut old);
        let stale = LockHolder::parse(&old);
        let io = |e| Error::io(&path, e);
        file.set_len(0).map_err(io)?;
        file.rewind().map_err(io)?;
        file.write_all(LockHolder::current().encode().as_bytes())
            .map_err(io)?;
        file.flush().map_err(io)?;
        Ok(WriterLock { file, path, stale })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// An error unless the lock file at its path is still the file this writer locked: a lock
    /// file removed (or replaced) while held lets a second writer lock a new file at the same
    /// path, so a writer checks before every commit (issue 36).
    pub fn check(&self) -> Result<()> {
        use std::os::unix::fs::MetadataExt;
        let lost = |why: String| Error::LockLost {
            path: self.path.clone(),
            why,
        };
        let held = self.file.metadata().map_err(|e| Error::io(&self.path, e))?;
        match std::fs::metadata(&self.path) {
            Ok(now) if now.dev() == held.dev() && now.ino() == held.ino() => Ok(()),
            Ok(_) => Err(lost("the lock file was replaced by another file".into())),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                Err(lost("the lock file was removed".into()))
            }
            Err(e) => Err(Error::io(&self.path, e)),
        }
    }
}

impl Drop for WriterLock {
    fn drop(&mut self) {
        // An empty file tells the next writer that this one released the lock cleanly.
        let _ = self.file.set_len(0);
        let _ = self.file.unlock();
    }
}

/// The holder recorded in a lock file. A holder that just took the lock may not have written
/// its record yet: retry briefly.
fn read_holder(path: &Path) -> Option<LockHolder> {
    for _ in 0..10 {
        if let Some(h) = std::fs::read_to_string(path)
            .ok()
            .and_then(|s| LockHolder::parse(&s))
        {
            return Some(h);
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    None
}

/// Whether another process (or handle) holds the writer lock of `dir`, tested without creating or
/// changing anything: `Some(holder)` (as [`LockHolder::describe`] words it) when it does. Only for
/// directories without a manifest (a map being created): the test holds the lock for an instant,
/// which could refuse a writer starting at that very moment.
pub fn writer_holding(dir: &Path) -> Option<String> {
    let path = dir.join(LOCK_FILE);
    let file = File::open(&path).ok()?;
    match file.try_lock_shared() {
        Err(TryLockError::WouldBlock) => Some(
            read_holder(&path).map_or("a writer that is starting or stopping".into(), |h| {
                h.describe()
            }),
        ),
        _ => None,
    }
}

/// A reader's shared lock on `MAP/readers.lock`, held until dropped. Without one (a map in a
/// folder this user cannot write, or a file system without locks) the reader runs unguarded.
#[derive(Debug)]
pub struct ReaderGuard {
    _file: Option<File>,
}

impl ReaderGuard {
    /// Takes a shared lock on the readers' lock file of `dir`, waiting while a writer deletes
    /// superseded files (milliseconds).
    pub fn acquire(dir: &Path) -> Self {
        let path = dir.join(READERS_LOCK_FILE);
        let file = File::open(&path).or_else(|_| {
            OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
        });
        let file = match file {
            Ok(f) => f,
            Err(e) => {
                tracing::debug!("{}: {e}; reading without a reader lock", path.display());
                return ReaderGuard { _file: None };
            }
        };
        match file.lock_shared() {
            Ok(()) => ReaderGuard { _file: Some(file) },
            Err(e) => {
                tracing::debug!("{}: {e}; reading without a reader lock", path.display());
                ReaderGuard { _file: None }
            }
        }
    }
}

/// The readers' lock of `dir` held exclusively, if no reader holds it now (never waits). While the
/// returned file is open no reader can open the map, so files that committed manifests no longer
/// name can be deleted.
pub fn readers_exclusive(dir: &Path) -> Option<File> {
    let path = dir.join(READERS_LOCK_FILE);
    let file = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .ok()?;
    file.try_lock().ok().map(|()| file)
}
