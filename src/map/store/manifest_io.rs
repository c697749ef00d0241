//! The manifest and chunk files as objects of a map: their names, counting them, reading the
//! committed manifest, and the errors for a map whose manifest is missing or lost.

use super::*;

/// Chunk files (`*.dchk`) in `dir/chunks`, by name (0 when the folder is missing).
pub fn count_chunk_files(dir: &Path) -> usize {
    count_chunk_objects(&crate::map::files::LocalFiles::new(dir))
}

/// Chunk files (`*.dchk`) under the map's `chunks/` (0 when there are none, or on an error).
pub fn count_chunk_objects(files: &dyn MapFiles) -> usize {
    files.list(CHUNKS_DIR).map_or(0, |v| {
        v.iter().filter(|o| o.name.ends_with(".dchk")).count()
    })
}

pub(super) fn chunk_object(c: ChunkIndex, seq: u64) -> String {
    format!("{CHUNKS_DIR}/{}", chunk_file_name(c, seq))
}

/// Refuses a map without a manifest: a lost manifest (chunk files present) names the repair
/// command; an empty location is "not a map".
pub(super) fn require_manifest(files: &dyn MapFiles) -> Result<()> {
    if files.exists(MANIFEST_FILE)? {
        return Ok(());
    }
    if let Some(holder) = files.writer_holding() {
        // A writer is creating the map (it commits its first manifest in a moment).
        return Err(Error::MapLocked {
            dir: files.location().display_path(),
            holder,
        });
    }
    Err(missing_manifest(files))
}

fn missing_manifest(files: &dyn MapFiles) -> Error {
    // A location that cannot even be listed (an S3 bucket that does not exist, no permission)
    // says so, rather than "no manifest here".
    if let Err(e) = files.list(CHUNKS_DIR) {
        let loc = files.location();
        return Error::bad_input(
            files.path(MANIFEST_FILE),
            format!("cannot open {loc}: listing it failed (does the bucket exist, and may these credentials read it?): {e}"),
        );
    }
    match count_chunk_objects(files) {
        0 => Error::bad_input(
            files.path(MANIFEST_FILE),
            "no manifest here: not a denser map directory (or never committed)",
        ),
        n => lost_manifest(files, n),
    }
}

pub(super) fn lost_manifest(files: &dyn MapFiles, n: usize) -> Error {
    let loc = files.location();
    Error::bad_input(
        files.path(MANIFEST_FILE),
        format!(
            "missing, but {} holds {n} chunk files: the map's manifest is lost. Nothing was changed; run `denser repair {loc}` to rebuild it from the chunk files",
            files.path(CHUNKS_DIR).display(),
        ),
    )
}

/// Reads and decodes `dir/manifest.dmf`; errors name the file.
pub fn read_manifest(dir: &Path) -> Result<Manifest> {
    read_manifest_at(&crate::map::files::LocalFiles::new(dir)).map(|(m, _)| m)
}

/// Reads and decodes the map's manifest with its version; errors name the object.
pub fn read_manifest_at(files: &dyn MapFiles) -> Result<(Manifest, ObjectVersion)> {
    let Some((bytes, version)) = files.read_versioned(MANIFEST_FILE)? else {
        return Err(missing_manifest(files));
    };
    let m = decode_manifest(&bytes).map_err(|e| {
        Error::bad_input(
            files.path(MANIFEST_FILE),
            format!(
                "{e}; run `denser repair {}` to rebuild it from the chunk files",
                files.location()
            ),
        )
    })?;
    Ok((m, version))
}

/// The text of the commit mark ([`super::super::layout::COMMIT_MARK`]) for `h`.
pub(super) fn commit_mark_text(h: &ManifestHeader) -> String {
    format!(
        "denser last commit\nmap_id {:016x}\ngeneration {}\nframes_committed {}\n",
        h.map_id, h.generation, h.frames_committed
    )
}

/// The commit mark's map id and generation; `None` when there is none (a map made before the
/// mark existed) or it cannot be parsed (reported: a damaged mark is no evidence).
pub fn read_commit_mark(files: &dyn MapFiles) -> Result<Option<(u64, u64)>> {
    Ok(read_commit_mark_frames(files)?.map(|(id, gen, _)| (id, gen)))
}

/// [`read_commit_mark`] with the frames the last commit had fused, where the mark records them
/// (marks written before it did have none): what `repair` restores as the fusion cursor when it
/// rebuilds exactly that commit's map.
pub fn read_commit_mark_frames(files: &dyn MapFiles) -> Result<Option<(u64, u64, Option<u64>)>> {
    let Some(bytes) = files.read(COMMIT_MARK)? else {
        return Ok(None);
    };
    let text = String::from_utf8_lossy(&bytes);
    let field = |key: &str| {
        text.lines()
            .find_map(|l| l.strip_prefix(key).map(str::trim).map(str::to_string))
    };
    let id = field("map_id ").and_then(|v| u64::from_str_radix(&v, 16).ok());
    let gen = field("generation ").and_then(|v| v.parse::<u64>().ok());
    let frames = field("frames_committed ").and_then(|v| v.parse::<u64>().ok());
    match (text.starts_with("denser last commit"), id, gen) {
        (true, Some(id), Some(gen)) => Ok(Some((id, gen, frames))),
        _ => {
            tracing::warn!(
                "{}: not a commit mark this denser reads; ignored",
                files.path(COMMIT_MARK).display()
            );
            Ok(None)
        }
    }
}

/// What a map records of its commits beside `manifest.dmf`, each as (map id, generation, frames
/// committed where recorded): the commit mark (the last commit recorded complete) and the
/// manifest of the last commit begun ([`MANIFEST_NEXT`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CommitMarks {
    /// The commit mark ([`COMMIT_MARK`]).
    pub mark: Option<(u64, u64, Option<u64>)>,
    /// The manifest a commit wrote before `manifest.dmf` ([`MANIFEST_NEXT`]).
    pub next: Option<(u64, u64, Option<u64>)>,
}

impl CommitMarks {
    /// The marks of the commit mark `mark` and the begun commit's manifest `next`.
    pub(super) fn of(mark: Option<(u64, u64, Option<u64>)>, next: Option<&Manifest>) -> Self {
        let next = next.map(|m| {
            let h = m.header;
            let frames = (h.frames_committed != FRAMES_UNKNOWN).then_some(h.frames_committed);
            (h.map_id, h.generation, frames)
        });
        CommitMarks { mark, next }
    }

    /// The newest generation of map `id` known to have committed, with the object that shows it:
    /// the mark's, or the one before the begun commit's (a commit begins after the previous one
    /// completed).
    fn committed(&self, id: u64) -> Option<(u64, &'static str)> {
        let mark = self.mark.filter(|m| m.0 == id).map(|m| (m.1, COMMIT_MARK));
        let next = self
            .next
            .filter(|m| m.0 == id && m.1 > 0)
            .map(|m| (m.1 - 1, MANIFEST_NEXT));
        mark.into_iter().chain(next).max_by_key(|g| g.0)
    }

    /// The newest commit begun of map `id` (of any map for `None`): the mark's or the begun
    /// commit's, whichever is newer. Every file such a commit names was written before it began,
    /// so [`crate::map::repair`] rebuilds the map as of it.
    pub fn begun(&self, id: Option<u64>) -> Option<(u64, u64, Option<u64>)> {
        [self.mark, self.next]
            .into_iter()
            .flatten()
            .filter(|m| id.is_none_or(|i| i == m.0))
            .max_by_key(|m| m.1)
    }
}

/// The map's [`CommitMarks`]. A [`MANIFEST_NEXT`] that does not decode is no evidence (reported).
pub fn read_commit_marks(files: &dyn MapFiles) -> Result<CommitMarks> {
    let mark = read_commit_mark_frames(files)?;
    Ok(CommitMarks::of(mark, read_next_manifest(files)?.as_ref()))
}

/// The manifest of the last commit begun ([`MANIFEST_NEXT`]), with its bytes; `None` when there
/// is none or it does not decode (reported: a damaged one is no evidence).
pub(super) fn read_next_manifest_bytes(
    files: &dyn MapFiles,
) -> Result<Option<(Manifest, Vec<u8>)>> {
    let Some(bytes) = files.read(MANIFEST_NEXT)? else {
        return Ok(None);
    };
    match decode_manifest(&bytes) {
        Ok(m) => Ok(Some((m, bytes.to_vec()))),
        Err(e) => {
            tracing::warn!("{}: {e}; ignored", files.path(MANIFEST_NEXT).display());
            Ok(None)
        }
    }
}

fn read_next_manifest(files: &dyn MapFiles) -> Result<Option<Manifest>> {
    Ok(read_next_manifest_bytes(files)?.map(|(m, _)| m))
}

/// An error when the commit mark, or the manifest of a commit begun, shows that this map
/// committed a generation newer than `m`'s.
pub(super) fn check_commit_mark(
    files: &dyn MapFiles,
    m: &Manifest,
    marks: &CommitMarks,
) -> Result<()> {
    match marks.committed(m.header.map_id) {
        Some((gen, what)) if gen > m.header.generation => Err(Error::MapRolledBack {
            map: files.location().display_path(),
            manifest_generation: m.header.generation,
            newer_generation: gen,
            evidence: if what == COMMIT_MARK {
                format!("{} records it", files.path(what).display())
            } else {
                format!(
                    "{} holds generation {}, begun after it",
                    files.path(what).display(),
                    gen + 1
                )
            },
        }),
        _ => Ok(()),
    }
}

/// Refuses a map that carries an [`INCOMPLETE_MARK`]: a job that builds it over several commits
/// (`merge`) has not finished; what is committed so far is not the map it was asked for.
pub(super) fn refuse_incomplete(files: &dyn MapFiles) -> Result<()> {
    match files.read(INCOMPLETE_MARK)? {
        None => Ok(()),
        Some(b) => Err(Error::bad_input(
            files.location().display_path(),
            format!(
                "an unfinished map ({}): the job that builds it was stopped before it completed. Every command refuses it; run the same job again to resume it (or delete the map)",
                String::from_utf8_lossy(&b).lines().next().unwrap_or("").trim()
            ),
        )),
    }
}
