//! The storage seam under [`super::store::MapStore`]: where a map's objects live.
//!
//! A map is a handful of named objects — `manifest.dmf`, `job.djr`, `chunks/c_X_Y_Z_SEQ.dchk`,
//! the writer's `lock`, the shard records under `shards/` and the deletion records under `gc/` —
//! addressed by names relative to the map's root. [`MapFiles`] is the small set of operations the
//! store needs on them, with two implementations:
//!
//! - [`LocalFiles`]: a directory. Exactly the guarantees the store always had on disk: every
//!   write goes to a temporary file, is fsynced and renamed, then the folder fsynced; chunk reads
//!   are memory-mapped; one writer by `flock` on `MAP/lock`, readers by a shared `flock` on
//!   `MAP/readers.lock` that writers test before deleting ([`super::lock`]).
//! - `S3Files` (feature `s3`, [`super::s3`]): an S3 bucket and prefix through the `object_store`
//!   crate. There is no `flock` there: the manifest is committed by compare-and-swap on its
//!   e-tag (create-only for the first), chunk files are created only if absent, the writer holds a
//!   lease object with an expiry, and deletions wait a retention period (`formats/shards.md`).
//!
//! Everything above this trait — manifest, entry checks, passes, cleanup rules, shards — is the
//! same code for both.

use super::location::MapLocation;
use crate::error::{Error, Result};
use std::ops::Range;
use std::path::{Path, PathBuf};

/// An object's version as its store reports it (the e-tag and, where versioning is on, the
/// version id): what a compare-and-swap compares. Local directories have none.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ObjectVersion {
    /// HTTP e-tag.
    pub e_tag: Option<String>,
    /// Object version id.
    pub version: Option<String>,
}

/// One object found by [`MapFiles::list`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Listed {
    /// Name relative to the folder listed.
    pub name: String,
    /// Size, bytes.
    pub size: u64,
    /// Last modification, seconds since the Unix epoch.
    pub modified_unix_s: u64,
}

/// Bytes read from a map: memory-mapped (local files) or owned (downloaded).
pub enum ObjectBytes {
    /// A read-only mapping of an immutable file.
    Mapped(memmap2::Mmap),
    /// Bytes in memory.
    Owned(std::sync::Arc<Vec<u8>>),
}

impl std::ops::Deref for ObjectBytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            ObjectBytes::Mapped(m) => m,
            ObjectBytes::Owned(v) => v,
        }
    }
}

/// Outcome of a conditional write.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Conditional {
    /// Written; the object's new version.
    Written(ObjectVersion),
    /// Not written: the object exists (create-only) or changed since the given version.
    Conflict,
}

/// What a writer holds while it writes a map ([`MapFiles::lock_writer`]).
pub trait WriterHold: Send + Sync + std::fmt::Debug {
    /// The record of a holder that ended without releasing (a stale lock or an expired lease).
    fn stale_holder(&self) -> Option<String>;
    /// An error when the hold was lost (a lease taken over after it expired): commits stop.
    fn check(&self) -> Result<()>;
}

/// What a reader holds while its manifest's files must stay ([`MapFiles::hold_readers`]).
pub trait ReaderHold: Send + Sync + std::fmt::Debug {}

/// The operations a map store needs on its objects (see the module documentation). Names are
/// relative to the map's root, with `/` between folders.
pub trait MapFiles: Send + Sync + std::fmt::Debug {
    /// Where the map lives.
    fn location(&self) -> &MapLocation;

    /// The full name of object `name`, for messages (`/maps/a/chunks/…`, `s3://b/p/chunks/…`).
    fn path(&self, name: &str) -> PathBuf;

    /// Whether object `name` exists.
    fn exists(&self, name: &str) -> Result<bool>;

    /// Whole object, `None` when absent.
    fn read(&self, name: &str) -> Result<Option<ObjectBytes>>;

    /// Whole object and its version, `None` when absent.
    fn read_versioned(&self, name: &str) -> Result<Option<(Vec<u8>, ObjectVersion)>>;

    /// Bytes `range` of an object (fewer at its end); an error when absent.
    fn read_range(&self, name: &str, range: Range<u64>) -> Result<Vec<u8>>;

    /// Writes an object whole, replacing it (atomically: readers see the old or the new one).
    fn write(&self, name: &str, bytes: &[u8]) -> Result<()>;

    /// Writes an object only if `prev` is its current version (`None`: only if it is absent).
    fn write_if(
        &self,
        name: &str,
        bytes: &[u8],
        prev: Option<&ObjectVersion>,
    ) -> Result<Conditional>;

    /// Writes a chunk version under a name never used before. Local: temporary file, fsync,
    /// rename (as always); object stores: create-only, so no committed file is ever replaced,
    /// not even by a writer whose lease expired.
    fn write_chunk(&self, name: &str, bytes: &[u8]) -> Result<()>;

    /// The objects directly in `folder` (`""`: the root), sorted by name; empty when absent.
    fn list(&self, folder: &str) -> Result<Vec<Listed>>;

    /// Every object below `folder` (names relative to it, with `/`), sorted.
    fn list_recursive(&self, folder: &str) -> Result<Vec<Listed>>;

    /// Deletes an object (nothing when absent).
    fn delete(&self, name: &str) -> Result<()>;

    /// Takes the map's writer lock (`flock`) or lease, or fails with [`Error::MapLocked`].
    fn lock_writer(&self) -> Result<Box<dyn WriterHold>>;

    /// Whether another writer holds the map now (for a map being created), as a description.
    fn writer_holding(&self) -> Option<String>;

    /// A reader's hold: the files its manifest names stay until it is dropped (local: shared
    /// `flock`; object stores: nothing, deletions wait [`MapFiles::deletes_after_s`] instead).
    fn hold_readers(&self) -> Box<dyn ReaderHold>;

    /// Deletes `names` (files no committed manifest names any more) if no reader can still need
    /// them now; `Ok(false)` when they must wait (a local reader is open). Object stores record
    /// them in `gc/` and delete them after [`MapFiles::deletes_after_s`]: `Ok(true)`.
    fn retire(&self, names: &[String], generation: u64, map_id: u64) -> Result<bool>;

    /// Seconds a superseded file is kept for readers (object stores); `None` for local
    /// directories, where readers' locks decide.
    fn deletes_after_s(&self) -> Option<u64>;

    /// Whether a new writer must commit once before it deletes anything: on object stores a
    /// writer whose lease expired may still be running, and a commit makes its next
    /// compare-and-swap fail (fencing).
    fn needs_fencing(&self) -> bool;

    /// Writes an object only if it is absent (create-only): `Ok(false)` when it exists.
    fn write_new(&self, name: &str, bytes: &[u8]) -> Result<bool>;
}

/// A map directory on a local file system.
#[derive(Debug)]
pub struct LocalFiles {
    dir: PathBuf,
    location: MapLocation,
}

impl LocalFiles {
    /// The map in `dir`.
    pub fn new(dir: &Path) -> Self {
        LocalFiles {
            dir: dir.to_path_buf(),
            location: MapLocation::Dir(dir.to_path_buf()),
        }
    }

    /// The directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn full(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }
}

fn fsync_dir(dir: &Path) {
    // Directory fsync makes renames durable on Linux; other systems may refuse: ignore that.
    if let Ok(f) = std::fs::File::open(dir) {
        let _ = f.sync_all();
    }
}

/// Writes `bytes` to `path` atomically: temporary file in the same folder, fsync, rename, fsync
/// of the folder.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let tmp = path.with_extension("tmp");
    {
        let mut f = std::fs::File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
        f.write_all(bytes).map_err(|e| Error::io(&tmp, e))?;
        f.sync_all().map_err(|e| Error::io(&tmp, e))?;
    }
    std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))?;
    fsync_dir(path.parent().unwrap_or(Path::new(".")));
    Ok(())
}

fn modified_s(m: &std::fs::Metadata) -> u64 {
    m.modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_secs())
}

#[derive(Debug)]
struct LocalWriter(super::lock::WriterLock);

impl WriterHold for LocalWriter {
    fn stale_holder(&self) -> Option<String> {
        self.0.stale.as_ref().map(|h| h.describe())
    }
    fn check(&self) -> Result<()> {
        self.0.check()
    }
}

#[derive(Debug)]
struct LocalReader(#[allow(dead_code)] super::lock::ReaderGuard);

impl ReaderHold for LocalReader {}

impl MapFiles for LocalFiles {
    fn location(&self) -> &MapLocation {
        &self.location
    }

    fn path(&self, name: &str) -> PathBuf {
        self.full(name)
    }

    fn exists(&self, name: &str) -> Result<bool> {
        Ok(self.full(name).exists())
    }

    fn read(&self, name: &str) -> Result<Option<ObjectBytes>> {
        let path = self.full(name);
        let f = match std::fs::File::open(&path) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(Error::io(&path, e)),
        };
        let len = f.metadata().map_err(|e| Error::io(&path, e))?.len();
        if len == 0 {
            return Ok(Some(ObjectBytes::Owned(Default::default())));
        }
        // SAFETY: chunk files are never modified in place (new versions get new names) and other
        // objects are replaced by rename, so the mapping cannot change under us.
        let map = unsafe { memmap2::Mmap::map(&f) }.map_err(|e| Error::io(&path, e))?;
        Ok(Some(ObjectBytes::Mapped(map)))
    }

    fn read_versioned(&self, name: &str) -> Result<Option<(Vec<u8>, ObjectVersion)>> {
        let path = self.full(name);
        match std::fs::read(&path) {
            Ok(b) => Ok(Some((b, ObjectVersion::default()))),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(Error::io(&path, e)),
        }
    }

    fn read_range(&self, name: &str, range: Range<u64>) -> Result<Vec<u8>> {
        use std::io::{Read, Seek, SeekFrom};
        let path = self.full(name);
        let mut f = std::fs::File::open(&path).map_err(|e| Error::io(&path, e))?;
        f.seek(SeekFrom::Start(range.start))
            .map_err(|e| Error::io(&path, e))?;
        let mut out = Vec::with_capacity((range.end - range.start) as usize);
        f.take(range.end - range.start)
            .read_to_end(&mut out)
            .map_err(|e| Error::io(&path, e))?;
        Ok(out)
    }

    fn write(&self, name: &str, bytes: &[u8]) -> Result<()> {
        let path = self.full(name);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
        }
        write_atomically(&path, bytes)
    }

    fn write_if(
        &self,
        name: &str,
        bytes: &[u8],
        prev: Option<&ObjectVersion>,
    ) -> Result<Conditional> {
        // One writer per directory (flock): the version cannot have changed under it. Create-only
        // is still honoured.
        if prev.is_none() {
            return Ok(if self.write_new(name, bytes)? {
                Conditional::Written(ObjectVersion::default())
            } else {
                Conditional::Conflict
            });
        }
        self.write(name, bytes)?;
        Ok(Conditional::Written(ObjectVersion::default()))
    }

    fn write_chunk(&self, name: &str, bytes: &[u8]) -> Result<()> {
        write_atomically(&self.full(name), bytes)
    }

    fn write_new(&self, name: &str, bytes: &[u8]) -> Result<bool> {
        use std::io::Write;
        let path = self.full(name);
        let parent = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        std::fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, e))?;
        // A unique temporary name: concurrent creators of the same object do not share it.
        let tmp = parent.join(format!(
            ".{}.{}.{}.new",
            path.file_name().map_or("x".into(), |n| n.to_string_lossy()),
            std::process::id(),
            super::manifest::new_map_id()
        ));
        {
            let mut f = std::fs::File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
            f.write_all(bytes).map_err(|e| Error::io(&tmp, e))?;
            f.sync_all().map_err(|e| Error::io(&tmp, e))?;
        }
        // link(2) fails when the name exists: create-only, atomically.
        let linked = std::fs::hard_link(&tmp, &path);
        let _ = std::fs::remove_file(&tmp);
        match linked {
            Ok(()) => {
                fsync_dir(&parent);
                Ok(true)
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(false),
            Err(e) => Err(Error::io(&path, e)),
        }
    }

    fn list(&self, folder: &str) -> Result<Vec<Listed>> {
        let dir = self.full(folder);
        let rd = match std::fs::read_dir(&dir) {
            Ok(rd) => rd,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(e) => return Err(Error::io(&dir, e)),
        };
        let mut out = Vec::new();
        for entry in rd {
            let entry = entry.map_err(|e| Error::io(&dir, e))?;
            let Ok(m) = entry.metadata() else { continue };
            if !m.is_file() {
                continue;
            }
            out.push(Listed {
                name: entry.file_name().to_string_lossy().into_owned(),
                size: m.len(),
                modified_unix_s: modified_s(&m),
            });
        }
        out.sort_by(|a, b| a.name.cmp(&b.name));
        Ok(out)
    }

    fn list_recursive(&self, folder: &str) -> Result<Vec<Listed>> {
        fn walk(base: &Path, rel: &str, out: &mut Vec<Listed>) -> Result<()> {
            let dir = base.join(rel);
            let rd = match std::fs::read_dir(&dir) {
                Ok(rd) => rd,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
                Err(e) => return Err(Error::io(&dir, e)),
            };
            for entry in rd {
                let entry = entry.map_err(|e| Error::io(&dir, e))?;
                let Ok(m) = entry.metadata() else { continue };
                let name = entry.file_name().to_string_lossy().into_owned();
                let r = if rel.is_empty() {
                    name
                } else {
                    format!("{rel}/{name}")
                };
                if m.is_dir() {
                    walk(base, &r, out)?;
                } else if m.is_file() {
                    out.push(Listed {
                        name: r,
                        size: m.len(),
                        modified_unix_s: modified_s(&m),
                    });
                }
            }
            Ok(())
        }
        let mut out = Vec::new();
        walk(&self.full(folder), "", &mut out)?;
        out.sort_by(|a, b| a.name.cmp(&b.name));
        Ok(out)
    }

    fn delete(&self, name: &str) -> Result<()> {
        let p = self.full(name);
        match std::fs::remove_file(&p) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
            Err(e) => return Err(Error::io(&p, e)),
        }
        // Folders of records (shards/KEY/regions, exports/KEY) go with their last object, as
        // prefixes do on an object store; `chunks/` and the map's root stay.
        let keep = [self.dir.clone(), self.dir.join(super::layout::CHUNKS_DIR)];
        let mut dir = p.parent().map(Path::to_path_buf);
        while let Some(d) = dir {
            if keep.contains(&d) || !d.starts_with(&self.dir) || std::fs::remove_dir(&d).is_err() {
                break;
            }
            dir = d.parent().map(Path::to_path_buf);
        }
        Ok(())
    }

    fn lock_writer(&self) -> Result<Box<dyn WriterHold>> {
        Ok(Box::new(LocalWriter(super::lock::WriterLock::acquire(
            &self.dir,
        )?)))
    }

    fn writer_holding(&self) -> Option<String> {
        super::lock::writer_holding(&self.dir)
    }

    fn hold_readers(&self) -> Box<dyn ReaderHold> {
        Box::new(LocalReader(super::lock::ReaderGuard::acquire(&self.dir)))
    }

    fn retire(&self, names: &[String], _generation: u64, _map_id: u64) -> Result<bool> {
        if names.is_empty() {
            return Ok(true);
        }
        let Some(_readers) = super::lock::readers_exclusive(&self.dir) else {
            return Ok(false);
        };
        for n in names {
            self.delete(n)?;
        }
        Ok(true)
    }

    fn deletes_after_s(&self) -> Option<u64> {
        None
    }

    fn needs_fencing(&self) -> bool {
        false
    }
}
