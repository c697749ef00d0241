//! Every kind of object a map holds, who writes it, and when the engine may delete it: the one
//! place where the names and the clean-up and repair rules are stated. Names are relative to the
//! map's root (a directory, or an object-store prefix).
//!
//! | object | written by | the engine's rule |
//! |---|---|---|
//! | [`MANIFEST_FILE`] | the writer's commit ([`super::store::MapStore::commit`]) | never deleted; rebuilt by [`super::repair`] when lost |
//! | [`MANIFEST_TMP`] | a local commit before its rename | removed by the next writer at open |
//! | [`MANIFEST_NEXT`] | every commit, before the manifest: the manifest being committed | never deleted (the next commit replaces it); one generation past the manifest, a commit a kill cut short, completed by the next writer at open; further past, a rollback |
//! | [`MANIFEST_NEXT_TMP`] | a local write of [`MANIFEST_NEXT`] before its rename | removed by the next writer at open |
//! | [`COMMIT_MARK`] | every commit, after the manifest | never deleted; a manifest older than it is a rollback, refused by every opener |
//! | [`INCOMPLETE_MARK`] | a job that builds a new map over several commits (`merge`), before its first commit | removed by that job when it completes; while present every opener refuses the map, naming the job, except the job's own resume |
//! | `chunks/c_X_Y_Z_SEQ.dchk` ([`CHUNKS_DIR`]) | [`super::store::ChunkWriter`] | kept while a committed manifest names it (current or kept pass); see below |
//! | `chunks/*.tmp`, `chunks/.*.new` | a chunk write before its rename or link | removed by the next writer at open |
//! | [`LOCK_FILE`], [`READERS_LOCK_FILE`] | [`super::lock`] (local maps) | never deleted |
//! | [`LEASE_OBJECT`], `gc/*` ([`GC_FOLDER`]) | the object-store writer (`s3`) | the lease is renewed and released by its holder; deletion records are carried out when due |
//! | [`JOB_FILE`], [`LEGACY_JOB_FILE`] | `reconstruct --map` ([`super::job`]) | never deleted |
//! | `shards/…` ([`SHARDS_AREA`]) | array-job shards (`crate::outofcore::shards`) | the engine reads only the reservations ([`super::reserve`]); the owner removes its records |
//! | `sweeps/…` ([`SWEEPS_AREA`]) | swept regularization (`crate::outofcore::sweeps`) | never read or deleted by the engine; the owner removes it |
//! | `exports/…` ([`EXPORTS_AREA`]) | `export --shard` (`crate::export::parts`) | never read or deleted by the engine; the owner removes it |
//! | `not-committed/…` ([`NOT_COMMITTED_DIR`]) | [`super::repair`]: chunk files stamped after the last commit the [`COMMIT_MARK`] names, moved out of `chunks/` | never read or deleted by the engine; the user's to inspect and remove |
//! | anything else | — | reported and left alone |
//!
//! A commit writes the new manifest twice: first as [`MANIFEST_NEXT`], then as [`MANIFEST_FILE`],
//! then the [`COMMIT_MARK`]. The commit point is the first write: from then on the commit's
//! manifest exists whatever happens to `manifest.dmf`. A writer that opens a map whose
//! [`MANIFEST_NEXT`] is one generation past its manifest (of the same map, naming files that
//! exist) completes that commit before anything else (a kill between the two writes, or a restore
//! of the previous manifest after one); [`super::repair`] keeps the files of the newest commit
//! either mark shows.
//!
//! Before anything is deleted, a writer checks that its manifest is the map's latest: a
//! [`COMMIT_MARK`] of a newer generation, a [`MANIFEST_NEXT`] more than one generation newer, or
//! a chunk file of this map stamped with a commit generation past the manifest's next one
//! (format 4), means the manifest was rolled back; the map is then refused
//! ([`crate::Error::MapRolledBack`]) until `repair` rebuilds it. Readers check both marks too
//! (reading them before the manifest, so a commit in between is no false alarm).
//!
//! A chunk file the manifest does not name is deleted by a writer only when the writer can prove
//! it is this map's own leftover: its header names this map, this chunk and this file number
//! (`store/cleanup.rs`, `MapStore::header_is_ours`), and
//! - its number is at or past the committed next number (written after the last commit by a
//!   writer that died) and no open reservation holds it; or
//! - it is an older version of a chunk the manifest names (superseded), once no reader has the
//!   map open; or
//! - its number lies in a reservation its owner has closed
//!   (`MapStore::remove_unnamed_in`).
//!
//! Everything else in `chunks/` is reported and left alone. [`super::repair`] deletes nothing; it
//! rebuilds the map as of its last commit, keeping each chunk's newest intact version by (commit
//! generation, file number) among the files stamped at or before it, and moves the files stamped
//! later to [`NOT_COMMITTED_DIR`].
//!
//! The algorithms above the engine keep their own files in the areas reserved for them
//! ([`SHARDS_AREA`], [`SWEEPS_AREA`], [`EXPORTS_AREA`]), written and deleted through the same
//! seam ([`super::files::MapFiles`]); the engine never interprets them, except that a
//! **reservation** — `shards/KEY/plan.json` whose `seq_base` and `chunks` fields reserve the
//! chunk file numbers `seq_base .. seq_base + chunks` for writers other than the map's writer
//! (`formats/shards.md`) — keeps the files in its range from the writer's clean-up at open.

/// The manifest, the commit point of every write (`formats/manifest.md`).
pub const MANIFEST_FILE: &str = "manifest.dmf";
/// The temporary manifest a local commit renames (only writers make it).
pub const MANIFEST_TMP: &str = "manifest.tmp";
/// The manifest a commit is committing, written before [`MANIFEST_FILE`]: the commit point (see
/// above and `formats/manifest.md`).
pub const MANIFEST_NEXT: &str = "manifest.next.dmf";
/// The temporary [`MANIFEST_NEXT`] of a local write (only writers make it).
pub const MANIFEST_NEXT_TMP: &str = "manifest.next.tmp";
/// The generation of the map's last commit, written after each commit (`formats/manifest.md`):
/// a manifest older than it was put back by a restore or a sync, and is refused.
pub const COMMIT_MARK: &str = "last-commit";
/// The mark of a map still being built by a job of several commits (`merge`): its text names the
/// job; every opener refuses the map while it exists, except that job's resume.
pub const INCOMPLETE_MARK: &str = "incomplete";
/// Folder of chunk files (`formats/chunk.md`).
pub const CHUNKS_DIR: &str = "chunks";
/// The writer lock file of a local map.
pub const LOCK_FILE: &str = "lock";
/// The readers' lock file of a local map.
pub const READERS_LOCK_FILE: &str = "readers.lock";
/// The lease object (the object-store writer lock).
pub const LEASE_OBJECT: &str = "lock";
/// Folder of deletion records on an object store.
pub const GC_FOLDER: &str = "gc";
/// The job record (`formats/job.md`).
pub const JOB_FILE: &str = "job.djr";
/// The job record of maps made before `job.djr` (JSON, absolute input path).
pub const LEGACY_JOB_FILE: &str = "job.json";
/// Area of array-job plans (reservations) and region records (`formats/shards.md`).
pub const SHARDS_AREA: &str = "shards";
/// Area of a swept regularization pass's state and progress (`formats/sweep-state.md`).
pub const SWEEPS_AREA: &str = "sweeps";
/// Area of the chunk meshes made by `export --shard` runs.
pub const EXPORTS_AREA: &str = "exports";
/// Where `repair` moves chunk files stamped after the map's last commit (written by a run a kill
/// cut short, not part of any committed map), so that no later repair mistakes them for committed
/// ones; kept for inspection, never read or deleted by the engine.
pub const NOT_COMMITTED_DIR: &str = "not-committed";
/// Name of a reservation inside its folder `shards/KEY/`.
pub const RESERVATION_FILE: &str = "plan.json";
