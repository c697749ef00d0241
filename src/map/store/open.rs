//! Opening and creating maps: the storage seam for a location, the writer lock, the checks made
//! before anything is committed or deleted (a lost manifest, a rolled-back one, an unfinished
//! map), and the clean-up a writer does at open.

use super::*;

impl MapLocation {
    /// Opens the location's objects: a directory ([`crate::map::files::LocalFiles`]) or an
    /// object-store prefix (`S3Files`); under `DENSER_FAULT_INJECTION` (a testing hook), wrapped
    /// in [`crate::map::fault::FaultyFiles`].
    pub fn open_files(&self) -> Result<Arc<dyn MapFiles>> {
        let files = self.open_files_plain()?;
        Ok(match crate::map::fault::FaultPlan::from_env()? {
            Some(plan) => Arc::new(crate::map::fault::FaultyFiles::new(files, plan)),
            None => files,
        })
    }

    fn open_files_plain(&self) -> Result<Arc<dyn MapFiles>> {
        match self {
            MapLocation::Dir(d) => Ok(Arc::new(crate::map::files::LocalFiles::new(d))),
            #[cfg(feature = "s3")]
            MapLocation::S3 { bucket, prefix } => {
                Ok(Arc::new(crate::map::s3::S3Files::from_env(bucket, prefix)?))
            }
            #[cfg(not(feature = "s3"))]
            MapLocation::S3 { .. } => Err(Error::InvalidArgument(format!(
                "{self}: this denser was built without the `s3` feature"
            ))),
        }
    }
}

impl MapStore {
    /// Creates a new, empty map in `dir` (created if missing) and holds its writer lock. Refuses a
    /// directory that holds a map already, or chunk files without a manifest (a lost manifest:
    /// `denser repair` rebuilds it).
    pub fn create(dir: &Path, grid: GridParams, chunk_blocks: u32) -> Result<Self> {
        Self::create_at(&MapLocation::Dir(dir.to_path_buf()), grid, chunk_blocks)
    }

    /// [`MapStore::create`] at any location (a directory or `s3://bucket/prefix`).
    pub fn create_at(loc: &MapLocation, grid: GridParams, chunk_blocks: u32) -> Result<Self> {
        if let Some(dir) = loc.as_dir() {
            grid.validate()?;
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        }
        Self::create_files(loc.open_files()?, grid, chunk_blocks)
    }

    /// [`MapStore::create`] over given objects (an object store configured by the caller).
    pub fn create_files(
        files: Arc<dyn MapFiles>,
        grid: GridParams,
        chunk_blocks: u32,
    ) -> Result<Self> {
        Self::create_files_marked(files, grid, chunk_blocks, None)
    }

    /// [`MapStore::create_at`] for a job that builds the map over several commits (`merge`): the
    /// [`INCOMPLETE_MARK`] holding `job` is written before the first commit, so every opener
    /// refuses the map (naming `job`) until [`MapStore::mark_complete`] removes it; the job
    /// resumes through [`MapStore::open_incomplete_at`].
    pub fn create_incomplete_at(
        loc: &MapLocation,
        grid: GridParams,
        chunk_blocks: u32,
        job: &str,
    ) -> Result<Self> {
        if let Some(dir) = loc.as_dir() {
            grid.validate()?;
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        }
        Self::create_files_marked(loc.open_files()?, grid, chunk_blocks, Some(job))
    }

    /// Opens a map for writing as [`MapStore::open_at`] does, also when it carries an
    /// [`INCOMPLETE_MARK`]; returns the mark's text, so the job that wrote it can check that it
    /// is its own before resuming.
    pub fn open_incomplete_at(loc: &MapLocation) -> Result<(Self, Option<String>)> {
        let files = loc.open_files()?;
        let mark = files
            .read(INCOMPLETE_MARK)?
            .map(|b| String::from_utf8_lossy(&b).into_owned());
        Ok((Self::open_writer(files, true)?.0, mark))
    }

    /// Removes the [`INCOMPLETE_MARK`] once the job that builds the map has committed its last
    /// chunk: from then on the map opens as any other.
    pub fn mark_complete(&mut self) -> Result<()> {
        self.require_writer("completing a map")?;
        self.files.delete(INCOMPLETE_MARK)
    }

    fn create_files_marked(
        files: Arc<dyn MapFiles>,
        grid: GridParams,
        chunk_blocks: u32,
        incomplete: Option<&str>,
    ) -> Result<Self> {
        let loc = files.location().clone();
        grid.validate()?;
        if !(1..=256).contains(&chunk_blocks) {
            return Err(Error::InvalidArgument(format!(
                "chunk edge {chunk_blocks} blocks is outside 1..=256"
            )));
        }
        let lock = files.lock_writer()?;
        if files.exists(MANIFEST_FILE)? {
            return Err(Error::bad_input(
                loc.display_path(),
                "already holds a map (manifest.dmf exists); open it instead",
            ));
        }
        let n = count_chunk_objects(&*files);
        if n > 0 {
            return Err(lost_manifest(&*files, n));
        }
        if let Some(dir) = loc.as_dir() {
            let chunks = dir.join(CHUNKS_DIR);
            std::fs::create_dir_all(&chunks).map_err(|e| Error::io(&chunks, e))?;
        }
        if let Some(job) = incomplete {
            files.write(INCOMPLETE_MARK, job.as_bytes())?;
        }
        let mut store = MapStore::with_files(
            files,
            Manifest {
                header: ManifestHeader {
                    voxel_size_m: grid.voxel_size_m,
                    truncation_m: grid.truncation_m,
                    chunk_blocks,
                    generation: 0,
                    frames_committed: 0,
                    next_file_seq: 1,
                    reg_pass: 0,
                    reg_params: TvParams::paper(grid.voxel_size_m),
                    complete_pass: 0,
                    complete_params: NO_PARAMS,
                    map_id: new_map_id(),
                },
                chunks: Default::default(),
                kept: Default::default(),
            },
            None,
            Access::Writer(lock),
        );
        store.commit()?;
        Ok(store)
    }

    pub(super) fn with_files(
        files: Arc<dyn MapFiles>,
        manifest: Manifest,
        manifest_version: Option<ObjectVersion>,
        access: Access,
    ) -> Self {
        let cache = files
            .deletes_after_s()
            .map(|_| Arc::new(ChunkCache::new(DEFAULT_OBJECT_CACHE_BYTES)));
        let next = matches!(access, Access::Writer(_)) as u64;
        let commit_gen = Arc::new(std::sync::atomic::AtomicU64::new(
            manifest.header.generation + next,
        ));
        MapStore {
            dir: files.location().display_path(),
            files,
            manifest,
            manifest_version,
            superseded: Vec::new(),
            deferred: Vec::new(),
            zstd_level: DEFAULT_ZSTD_LEVEL,
            access,
            cache,
            commit_gen,
        }
    }

    /// Opens an existing map for reading and writing: takes the writer lock (refused at once with
    /// [`Error::MapLocked`], naming the holder, while another writer has it), then removes what a
    /// writer that died left behind — only files it can prove are that: see [`OpenCleanup`] and
    /// `formats/manifest.md`.
    pub fn open(dir: &Path) -> Result<Self> {
        Ok(Self::open_with_cleanup(dir)?.0)
    }

    /// [`MapStore::open`] at any location (a directory or `s3://bucket/prefix`).
    pub fn open_at(loc: &MapLocation) -> Result<Self> {
        Ok(Self::open_at_with_cleanup(loc)?.0)
    }

    /// [`MapStore::open`], also returning what the cleanup did.
    pub fn open_with_cleanup(dir: &Path) -> Result<(Self, OpenCleanup)> {
        Self::open_at_with_cleanup(&MapLocation::Dir(dir.to_path_buf()))
    }

    /// [`MapStore::open_at`], also returning what the cleanup did. On an object store the writer
    /// first commits once (fencing: a writer whose lease expired can no longer commit) and only
    /// then removes anything.
    pub fn open_at_with_cleanup(loc: &MapLocation) -> Result<(Self, OpenCleanup)> {
        Self::open_files_with_cleanup(loc.open_files()?)
    }

    /// [`MapStore::open_at`] over given objects (an object store configured by the caller).
    pub fn open_files(files: Arc<dyn MapFiles>) -> Result<Self> {
        Ok(Self::open_files_with_cleanup(files)?.0)
    }

    /// [`MapStore::open_at_with_cleanup`] over given objects.
    pub fn open_files_with_cleanup(files: Arc<dyn MapFiles>) -> Result<(Self, OpenCleanup)> {
        Self::open_writer(files, false)
    }

    fn open_writer(
        files: Arc<dyn MapFiles>,
        allow_incomplete: bool,
    ) -> Result<(Self, OpenCleanup)> {
        let loc = files.location().clone();
        require_manifest(&*files)?;
        if !allow_incomplete {
            refuse_incomplete(&*files)?;
        }
        let lock = files.lock_writer()?;
        if let Some(h) = lock.stale_holder() {
            tracing::warn!(
                "{loc}: recovered the writer lock of {h} which ended without releasing it (killed?)"
            );
        }
        let (manifest, version) = read_manifest_at(&*files)?;
        // The marks and the begun commit's manifest, read once for the steps below.
        let next = read_next_manifest_bytes(&*files)?;
        let mut marks = CommitMarks::of(
            read_commit_mark_frames(&*files)?,
            next.as_ref().map(|(m, _)| m),
        );
        let (manifest, version) =
            complete_begun_commit(&*files, (manifest, version), next, &mut marks)?;
        // Before anything is committed or deleted: is this manifest the map's latest?
        check_latest_with(&*files, &manifest, &marks)?;
        let mut store = MapStore::with_files(files, manifest, Some(version), Access::Writer(lock));
        let fenced = store.files.needs_fencing();
        if fenced {
            // Its commit writes the mark too.
            store.commit()?;
        }
        // A commit whose mark was not written (a kill or a failed write between the two) gets it
        // now, before anything is deleted: `repair` rebuilds the commit the mark names.
        let h = store.manifest.header;
        if !fenced && marks.mark != Some((h.map_id, h.generation, Some(h.frames_committed))) {
            store
                .files
                .write(COMMIT_MARK, commit_mark_text(&h).as_bytes())?;
        }
        let cleanup = store.remove_leftovers()?;
        if store.manifest.header.map_id == 0 {
            // A format-1 map: it gets an identity with its next commit.
            store.manifest.header.map_id = new_map_id();
        }
        Ok((store, cleanup))
    }

    /// Opens an existing map for reading. Takes no writer lock, writes and deletes nothing; the
    /// files its manifest names stay on disk while it is open (see [`crate::map::lock`]).
    pub fn open_read_only(dir: &Path) -> Result<Self> {
        Self::open_read_only_at(&MapLocation::Dir(dir.to_path_buf()))
    }

    /// [`MapStore::open_read_only`] at any location. On an object store the files of the
    /// manifest read stay for the retention period after a newer commit supersedes them.
    pub fn open_read_only_at(loc: &MapLocation) -> Result<Self> {
        Self::open_read_only_files(loc.open_files()?)
    }

    /// [`MapStore::open_read_only_at`] over given objects (an object store configured by the
    /// caller).
    pub fn open_read_only_files(files: Arc<dyn MapFiles>) -> Result<Self> {
        require_manifest(&*files)?;
        refuse_incomplete(&*files)?;
        let guard = files.hold_readers();
        // The marks before the manifest: a commit between the reads only makes the manifest newer
        // than the marks, never older. A commit begun and not completed (its writer at work, or
        // killed) leaves the manifest one generation behind the begun one: the map as committed.
        let marks = read_commit_marks(&*files)?;
        let (manifest, version) = read_manifest_at(&*files)?;
        check_commit_mark(&*files, &manifest, &marks)?;
        Ok(MapStore::with_files(
            files,
            manifest,
            Some(version),
            Access::Reader(guard),
        ))
    }

    /// A writer over a manifest rebuilt by [`crate::map::repair`] (committed by the caller, create-only).
    pub(crate) fn from_repair(
        files: Arc<dyn MapFiles>,
        lock: Box<dyn WriterHold>,
        manifest: Manifest,
    ) -> Self {
        MapStore::with_files(files, manifest, None, Access::Writer(lock))
    }
}

/// Completes a commit that was begun and not completed: when [`MANIFEST_NEXT`] holds the next
/// generation of this map (the commit point passed), the commit mark has not recorded it, and
/// every file it names exists, it becomes `manifest.dmf` and the mark records it. This is the
/// state a kill (or a failed write) between a commit's first write and its mark leaves, also
/// when the previous manifest was put back after it. Otherwise the manifest is returned as read.
/// Called by a writer, holding the lock, before anything is checked or deleted, with `next`
/// ([`read_next_manifest_bytes`]) and the map's `marks`, which it updates when it writes the mark.
fn complete_begun_commit(
    files: &dyn MapFiles,
    (manifest, version): (Manifest, ObjectVersion),
    next: Option<(Manifest, Vec<u8>)>,
    marks: &mut CommitMarks,
) -> Result<(Manifest, ObjectVersion)> {
    let Some((next, bytes)) = next else {
        return Ok((manifest, version));
    };
    let (h, n) = (manifest.header, next.header);
    let marked = marks
        .mark
        .is_some_and(|(id, g, _)| id == n.map_id && g >= n.generation);
    if n.map_id != h.map_id || n.generation != h.generation + 1 || marked {
        return Ok((manifest, version));
    }
    // Files the begun commit adds were written before it began; the files it supersedes are
    // deleted only after its mark. One missing means the begun commit is not this map's.
    for (c, e) in next.chunks.iter().chain(next.kept.iter()) {
        let name = chunk_object(*c, e.file_seq);
        if !manifest.names(*c, e.file_seq) && !files.exists(&name)? {
            tracing::warn!(
                "{}: names {}, which is missing; the commit it began is not completed",
                files.path(MANIFEST_NEXT).display(),
                files.path(&name).display()
            );
            return Ok((manifest, version));
        }
    }
    let version = match files.write_if(MANIFEST_FILE, &bytes, Some(&version))? {
        Conditional::Written(v) => v,
        Conditional::Conflict => {
            return Err(Error::CommitConflict {
                map: files.location().display_path(),
                read_generation: h.generation,
            })
        }
    };
    files.write(COMMIT_MARK, commit_mark_text(&n).as_bytes())?;
    marks.mark = Some((n.map_id, n.generation, Some(n.frames_committed)));
    let frames = if n.frames_committed == FRAMES_UNKNOWN {
        "unknown".to_string()
    } else {
        n.frames_committed.to_string()
    };
    tracing::warn!(
        "{}: completed commit {} (frames committed: {frames}), begun by a writer that stopped before recording it",
        files.location(),
        n.generation
    );
    Ok((next, version))
}
