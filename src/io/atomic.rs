//! Outputs appear under their final name only when complete. Every file `denser` writes for a
//! user goes through here: it is written under a temporary name beside its target (a hidden
//! `.NAME.PID.partial.EXT`, same folder so the final rename is atomic, same extension so writers
//! that choose a format by extension still do), flushed, fsynced and renamed into place; a
//! failure (a full disk, a size limit, a bug) removes the temporary file and leaves whatever was
//! under the final name before untouched.
//!
//! Every temporary path is also recorded in a process-wide list until it is committed or
//! dropped, so that a signal handler ([`remove_pending`], installed by the CLI for SIGINT and
//! SIGTERM) can remove them before the process exits: an interrupted run leaves no debris. A
//! `SIGKILL` cannot be handled; its leftovers carry the `.partial` mark and the dead pid.

use crate::error::{Error, Result};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Temporary paths not yet committed or removed, for [`remove_pending`].
static PENDING: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn register(p: &Path) {
    if let Ok(mut v) = PENDING.lock() {
        v.push(p.to_path_buf());
    }
}

fn unregister(p: &Path) {
    if let Ok(mut v) = PENDING.lock() {
        if let Some(k) = v.iter().position(|q| q == p) {
            v.swap_remove(k);
        }
    }
}

/// Removes every temporary file and folder still pending (called from a signal handler just
/// before the process exits). Returns how many were removed.
pub fn remove_pending() -> usize {
    remove_pending_where(|_| true)
}

/// Removes the pending temporary files and folders for which `which` holds (the rest stay
/// pending). Returns how many were removed.
fn remove_pending_where(which: impl Fn(&Path) -> bool) -> usize {
    let list = match PENDING.lock() {
        Ok(mut v) => {
            let (chosen, kept) = std::mem::take(&mut *v).into_iter().partition(|p| which(p));
            *v = kept;
            chosen
        }
        Err(_) => return 0,
    };
    list.iter()
        .filter(|p| {
            if p.is_dir() {
                std::fs::remove_dir_all(p).is_ok()
            } else {
                std::fs::remove_file(p).is_ok()
            }
        })
        .count()
}

/// The temporary name of `target`: `.NAME.PID.partial[.EXT]` in the same folder.
pub fn partial_name(target: &Path) -> PathBuf {
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "output".into());
    let ext = target
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    let tmp = format!(".{name}.{}.partial{ext}", std::process::id());
    match target.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir.join(tmp),
        _ => PathBuf::from(tmp),
    }
}

/// Removes what killed runs (`SIGKILL`, a power loss) left beside `target`: hidden
/// `.NAME.PID.partial[.EXT]` files and folders ([`partial_name`]) of `target` or of a sibling
/// temporary of it (`target` with another extension: a COPC spill folder, a mesh's vertex
/// stream, a replaced tileset), whose process `PID` no longer runs. A live process's files are
/// never touched. Returns the paths removed.
pub fn remove_stale_partials(target: &Path) -> Vec<PathBuf> {
    let Some(name) = target.file_name().map(|n| n.to_string_lossy().into_owned()) else {
        return Vec::new();
    };
    let stem = target
        .file_stem()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| name.clone());
    let dir = match target.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Vec::new();
    };
    let mut removed = Vec::new();
    for e in entries.flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        let Some(rest) = n.strip_prefix('.') else {
            continue;
        };
        let Some(at) = rest.find(".partial") else {
            continue;
        };
        let Some((of, pid)) = rest[..at].rsplit_once('.') else {
            continue;
        };
        let Ok(pid) = pid.parse::<u32>() else {
            continue;
        };
        let ours = of == name || of.starts_with(&format!("{stem}."));
        if !ours || pid == std::process::id() || process_alive(pid) {
            continue;
        }
        let p = e.path();
        let gone = if p.is_dir() {
            std::fs::remove_dir_all(&p).is_ok()
        } else {
            std::fs::remove_file(&p).is_ok()
        };
        if gone {
            tracing::info!("removed {} (left by a stopped run, pid {pid})", p.display());
            removed.push(p);
        }
    }
    removed
}

/// Whether process `pid` runs (or exists but belongs to another user).
fn process_alive(pid: u32) -> bool {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    // SAFETY: kill with signal 0 sends nothing; it only checks that the process exists.
    let r = unsafe { libc::kill(pid, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
}

/// A temporary path that belongs to this process until [`TempPath::persist`] renames it into
/// place; dropped unpersisted, it is removed (file or folder). For writers that need a path
/// rather than a `Write` (the LAS crate, a tileset folder).
#[derive(Debug)]
pub struct TempPath {
    path: PathBuf,
}

impl TempPath {
    /// A registered temporary path for `target` ([`partial_name`]); nothing is created.
    pub fn for_target(target: &Path) -> Self {
        Self::at(partial_name(target))
    }

    /// A registered temporary path at exactly `path`.
    pub fn at(path: PathBuf) -> Self {
        register(&path);
        TempPath { path }
    }

    /// The path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Renames the temporary file or folder to `target` (replacing a file there) and forgets it.
    pub fn persist(self, target: &Path) -> Result<()> {
        std::fs::rename(&self.path, target).map_err(|e| Error::io(target, e))?;
        fsync_parent(target);
        unregister(&self.path);
        std::mem::forget(self);
        Ok(())
    }
}

impl Drop for TempPath {
    fn drop(&mut self) {
        if self.path.is_dir() {
            let _ = std::fs::remove_dir_all(&self.path);
        } else {
            let _ = std::fs::remove_file(&self.path);
        }
        unregister(&self.path);
    }
}

fn fsync_parent(p: &Path) {
    // Directory fsync makes the rename durable on Linux; other systems may refuse: ignore that.
    let dir = p.parent().filter(|d| !d.as_os_str().is_empty());
    if let Ok(f) = std::fs::File::open(dir.unwrap_or(Path::new("."))) {
        let _ = f.sync_all();
    }
}

/// A file being written under its temporary name (see the module documentation): write to it,
/// then [`PendingFile::commit`]; dropped uncommitted, the temporary file is removed.
#[derive(Debug)]
pub struct PendingFile {
    target: PathBuf,
    temp: TempPath,
    out: BufWriter<std::fs::File>,
}

impl PendingFile {
    /// Starts writing `target`.
    pub fn create(target: &Path) -> Result<Self> {
        let temp = TempPath::for_target(target);
        let file = std::fs::File::create(temp.path()).map_err(|e| Error::io(target, e))?;
        Ok(PendingFile {
            target: target.to_path_buf(),
            temp,
            out: BufWriter::with_capacity(1 << 20, file),
        })
    }

    /// The final path.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Flushes, fsyncs and renames the file into place.
    pub fn commit(self) -> Result<()> {
        let PendingFile { target, temp, out } = self;
        let file = out
            .into_inner()
            .map_err(|e| Error::io(&target, e.into_error()))?;
        file.sync_all().map_err(|e| Error::io(&target, e))?;
        drop(file);
        temp.persist(&target)
    }
}

impl Write for PendingFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.out.write(buf)
    }
    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        self.out.write_all(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }
}

/// Writes `bytes` to `target` through a [`PendingFile`]. I/O errors name `target`.
pub fn write_file(target: impl AsRef<Path>, bytes: &[u8]) -> Result<()> {
    let target = target.as_ref();
    let mut f = PendingFile::create(target)?;
    f.write_all(bytes).map_err(|e| Error::io(target, e))?;
    f.commit()
}

/// Checks that files can be created in `dir` (creating it if missing) before any work starts: a
/// `dir` that is a file, read-only or unreachable is an error naming it.
pub fn check_output_dir(dir: &Path) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        return Err(Error::bad_input(
            dir,
            "the output folder exists and is not a folder",
        ));
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let probe = TempPath::at(dir.join(format!(".denser-write-probe.{}", std::process::id())));
    std::fs::write(probe.path(), b"probe").map_err(|e| Error::io(dir, e))?;
    drop(probe);
    Ok(())
}

/// Checks that `file` can be written (its folder exists or can be made, it is not a folder)
/// before any work starts.
pub fn check_output_file(file: &Path) -> Result<()> {
    if file.is_dir() {
        return Err(Error::bad_input(file, "is a folder, expected a file name"));
    }
    match file.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => check_output_dir(dir),
        _ => check_output_dir(Path::new(".")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commit_renames_and_drop_removes() {
        let dir = tempfile::tempdir().expect("tempdir");
        let target = dir.path().join("out.ply");
        std::fs::write(&target, b"old").expect("old");
        {
            let mut f = PendingFile::create(&target).expect("create");
            f.write_all(b"half").expect("write");
            // Dropped without commit: the old file stays, no temporary remains.
        }
        assert_eq!(std::fs::read(&target).expect("read"), b"old");
        assert_eq!(std::fs::read_dir(dir.path()).expect("ls").count(), 1);
        write_file(&target, b"new").expect("write");
        assert_eq!(std::fs::read(&target).expect("read"), b"new");
        assert_eq!(std::fs::read_dir(dir.path()).expect("ls").count(), 1);
        // What a signal handler removes. The list is process-wide and other tests write at the
        // same time: only this folder's temporaries are removed here.
        let t = TempPath::for_target(&dir.path().join("x.laz"));
        assert!(t.path().to_string_lossy().ends_with(".partial.laz"));
        std::fs::write(t.path(), b"x").expect("write");
        let removed = remove_pending_where(|p| p.starts_with(dir.path()));
        assert_eq!(removed, 1);
        assert!(!t.path().exists());
        std::mem::forget(t);
    }

    #[test]
    fn a_file_where_a_folder_is_expected_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let f = dir.path().join("file");
        std::fs::write(&f, b"").expect("write");
        assert!(check_output_dir(&f).is_err());
        assert!(check_output_file(&f.join("x.ply")).is_err());
        check_output_dir(&dir.path().join("new/sub")).expect("creatable");
    }
}
