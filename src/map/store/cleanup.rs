//! Checking the files against the manifest: `verify`, and the writer's cleanup at open (which
//! files in `chunks/` a writer can prove are its own leftovers and removes, which it reports and
//! leaves alone).

use super::*;

impl MapStore {
    /// Whether the header of chunk file `name` says it is file `seq` of chunk `c` of this map
    /// (format 1 files carry no origin: their name is all there is). Reads the header only.
    fn header_is_ours(&self, name: &str, c: ChunkIndex, seq: u64) -> bool {
        let Ok(head) = self.files.read_range(name, 0..CHUNK_HEADER_V2_BYTES as u64) else {
            return false;
        };
        let Ok((h, origin)) = decode_header_with_origin(&head) else {
            return false;
        };
        // A map without an identity (format 1) cannot tell its files from others by id.
        let id = self.manifest.header.map_id;
        h.chunk == c && origin.is_none_or(|o| o.file_seq == seq && (id == 0 || o.map_id == id))
    }

    /// The writer's cleanup at open: `*.tmp` chunk files, `manifest.tmp` and `manifest.next.tmp`
    /// (only writers make them), chunk files numbered at or after the committed next sequence number (allocated after
    /// the last commit by a writer that died) unless a shard plan still open reserves their
    /// numbers, and older versions of chunks the manifest names (superseded; only while no reader
    /// can need them). Everything else is reported and left alone.
    pub(super) fn remove_leftovers(&mut self) -> Result<OpenCleanup> {
        let mut out = OpenCleanup::default();
        let listed = self.files.list(CHUNKS_DIR)?;
        let next = self.manifest.header.next_file_seq;
        let reserved = crate::map::reserve::reservations(&*self.files)?;
        let mut superseded = Vec::new();
        for obj in listed {
            let name = obj.name;
            let p = format!("{CHUNKS_DIR}/{name}");
            let (stem, tmp) = if let Some(s) = name.strip_suffix(".tmp") {
                (format!("{s}.dchk"), true)
            } else {
                (name.clone(), false)
            };
            let Some((c, seq)) = parse_chunk_file_name(&stem) else {
                if name.starts_with('.') && name.ends_with(".new") {
                    // A create-only write that died before its link (LocalFiles::write_new).
                    self.files.delete(&p)?;
                    out.removed_uncommitted.push(name);
                    continue;
                }
                out.left_alone
                    .push(format!("{name}: not a chunk file name"));
                continue;
            };
            if self.manifest.names(c, seq) {
                if tmp {
                    out.left_alone
                        .push(format!("{name}: temporary file of a committed version"));
                }
                continue;
            }
            if tmp {
                // Only a writer makes these, and no other writer is alive.
                self.files.delete(&p)?;
                out.removed_uncommitted.push(name);
                continue;
            }
            if reserved.iter().any(|r| r.contains(&seq)) {
                // A regularization shard's result, waiting for the committing run to adopt it.
                out.shard_files_kept += 1;
                continue;
            }
            let current = self.manifest.chunks.get(&c).map(|e| e.file_seq);
            if seq >= next {
                if self.header_is_ours(&p, c, seq) {
                    self.files.delete(&p)?;
                    out.removed_uncommitted.push(name);
                } else {
                    out.left_alone.push(format!(
                        "{name}: numbered after the last commit but its header is not this map's file {seq} of chunk {:?}",
                        c.0
                    ));
                }
            } else if current.is_some_and(|cur| seq < cur) {
                if self.header_is_ours(&p, c, seq) {
                    superseded.push(name);
                } else {
                    out.left_alone.push(format!(
                        "{name}: an older version by its name, but its header is not this map's file {seq} of chunk {:?}",
                        c.0
                    ));
                }
            } else {
                out.left_alone.push(format!(
                    "{name}: not named by the manifest, and nothing proves it is a leftover of this map"
                ));
            }
        }
        if !superseded.is_empty() {
            let names: Vec<String> = superseded
                .iter()
                .map(|n| format!("{CHUNKS_DIR}/{n}"))
                .collect();
            let h = self.manifest.header;
            if self.files.retire(&names, h.generation, h.map_id)? {
                out.removed_superseded = superseded;
            } else {
                out.waiting_for_readers = superseded.len();
                self.deferred.extend(names);
            }
        }
        if self.location().as_dir().is_some() {
            self.files.delete(MANIFEST_TMP)?;
            self.files.delete(MANIFEST_NEXT_TMP)?;
        }
        if !out.removed_uncommitted.is_empty() {
            tracing::info!(
                "{}: removed {} chunk files written after the last commit by a writer that stopped",
                self.dir.display(),
                out.removed_uncommitted.len()
            );
        }
        for l in &out.left_alone {
            tracing::warn!("{}: left alone: {l}", self.files.path(CHUNKS_DIR).display());
        }
        Ok(out)
    }

    /// Removes the chunk files numbered in `range` (a reservation its owner has closed,
    /// [`crate::map::layout`]) that the manifest does not name, each only after its header proves
    /// it is this map's file of that number. Returns how many were removed.
    pub fn remove_unnamed_in(&self, range: std::ops::Range<u64>) -> Result<usize> {
        let mut removed = 0;
        for o in self.files.list(CHUNKS_DIR)? {
            let Some((c, seq)) = parse_chunk_file_name(&o.name) else {
                continue;
            };
            if !range.contains(&seq) {
                continue;
            }
            let name = format!("{CHUNKS_DIR}/{}", o.name);
            if !self.manifest.names(c, seq) && self.header_is_ours(&name, c, seq) {
                self.files.delete(&name)?;
                removed += 1;
            }
        }
        Ok(removed)
    }

    /// Reads every file the manifest names (current and kept) and checks it as
    /// [`MapStore::read_entry`] does; returns one line per problem (file name and what is wrong),
    /// empty when the map is sound.
    pub fn verify(&self) -> Vec<String> {
        let mut problems = Vec::new();
        for (c, e) in &self.manifest.chunks {
            if let Err(err) = self.read_entry(*c, e) {
                problems.push(err.to_string());
            }
        }
        for (c, e) in &self.manifest.kept {
            if let Err(err) = self.read_entry(*c, e) {
                problems.push(format!(
                    "{err} (kept file of complete pass {})",
                    self.manifest.header.complete_pass
                ));
            }
        }
        problems
    }
}

/// An error ([`Error::MapRolledBack`]) when manifest `m` is not the latest of its map: the commit
/// mark records a newer generation, a commit begun after a newer one ([`MANIFEST_NEXT`]), or a chunk file of this map that `m` does not name carries a
/// commit generation past `m`'s generation + 1 (written after a commit `m` does not know). Reads
/// the mark and the headers of the files numbered at or after `m`'s next number only (the
/// files written after `m`, which a writer's clean-up would delete). Writers check this before
/// anything is committed or deleted, and `repair` to tell a rolled-back manifest from an intact
/// one.
pub fn check_latest(files: &dyn MapFiles, m: &Manifest) -> Result<()> {
    check_latest_with(files, m, &read_commit_marks(files)?)
}

/// [`check_latest`] with the map's marks already read.
pub(super) fn check_latest_with(
    files: &dyn MapFiles,
    m: &Manifest,
    marks: &CommitMarks,
) -> Result<()> {
    check_commit_mark(files, m, marks)?;
    let h = m.header;
    let mut newest: Option<(u64, String)> = None;
    for obj in files.list(CHUNKS_DIR)? {
        let Some((c, seq)) = parse_chunk_file_name(&obj.name) else {
            continue;
        };
        if seq < h.next_file_seq || m.names(c, seq) {
            continue;
        }
        let p = format!("{CHUNKS_DIR}/{}", obj.name);
        let Ok(head) = files.read_range(&p, 0..CHUNK_HEADER_V2_BYTES as u64) else {
            continue;
        };
        let Ok((hd, Some(o))) = decode_header_with_origin(&head) else {
            continue;
        };
        let ours = hd.chunk == c && o.file_seq == seq && (h.map_id == 0 || o.map_id == h.map_id);
        if ours
            && o.commit_gen > h.generation + 1
            && newest.as_ref().is_none_or(|(g, _)| o.commit_gen > *g)
        {
            newest = Some((o.commit_gen, p));
        }
    }
    match newest {
        None => Ok(()),
        // A file stamped `gen` was written once commit `gen − 1` had happened.
        Some((gen, name)) => Err(Error::MapRolledBack {
            map: files.location().display_path(),
            manifest_generation: h.generation,
            newer_generation: gen - 1,
            evidence: format!("{} was written after it", files.path(&name).display()),
        }),
    }
}
