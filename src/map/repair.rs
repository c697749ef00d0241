//! Rebuilding a lost or unreadable manifest from the chunk files alone (`denser repair MAP`).
//!
//! Chunk files are self-describing: the header of every file (format 2, `formats/chunk.md`) names
//! its chunk, grid, map, sequence number and the regularization pass (with its parameters) that
//! wrote its `u`. [`repair`] reads and checks every file in `chunks/` (both CRCs and the whole
//! payload), keeps for each chunk the **newest intact version** — the largest (commit generation,
//! file number) that decodes: the commit generation of format-4 headers orders a regularization
//! shard's files (numbered far above the writer's) below any later commit, and files without one
//! (formats 1–3) count as generation 0 — and writes a new manifest naming those, committed past
//! every generation the files and the commit marks show. The map is rebuilt as of its last commit
//! begun: where the commit mark, or the manifest of a commit begun (`manifest.next.dmf`, whose
//! files were all written before it), of this map names it, files stamped with a later
//! generation (written after it by a run a kill cut short) are not part of any committed map and
//! are reported, not kept; they are moved to `not-committed/` (so that no later repair, once the map's generations
//! pass their stamps, takes them for committed files). Files whose grid (voxel size, μ, chunk edge)
//! or map id disagree with the majority are not kept, nor are damaged files; each is reported with
//! the reason. The regularization state is rebuilt from the kept files: the latest pass and its
//! parameters, and — where the chunks that pass did not reach all stand at one older pass and the
//! others still have an intact file of it — that older pass as the last complete one, with those
//! files kept. Nothing is deleted: files not kept stay where they are (the next writer removes
//! older versions of chunks the manifest names; the rest it reports and leaves), except those
//! written after the last commit, which move to `not-committed/`.
//!
//! How many frames of the reconstruct job the map holds (the fusion cursor) is not in the chunk
//! files. The commit marks record it with every commit; when the rebuilt map is exactly the marked
//! commit (every kept file stamped at or before its generation, none replaced by an older version
//! because the newest was damaged), the cursor is restored from it and `reconstruct --map` resumes
//! (a manifest rolled back or deleted after a clean commit). Otherwise the new manifest says
//! "unknown" ([`FRAMES_UNKNOWN`]), which `reconstruct --map` refuses to resume; regularize,
//! export and inspect work. Format-1 files carry no pass: they count as unregularized.

use super::codec::{
    decode_header_with_origin, ChunkHeader, ChunkOrigin, CHUNK_HEADER_V2_BYTES,
    FLAG_HAS_REGULARIZED,
};
use super::files::{LocalFiles, MapFiles};
use super::layout::{CHUNKS_DIR, COMMIT_MARK, MANIFEST_FILE, MANIFEST_NEXT, NOT_COMMITTED_DIR};
use super::manifest::{
    new_map_id, parse_chunk_file_name, ChunkEntry, Manifest, ManifestHeader, PassStatus,
    ENTRY_HAS_REGULARIZED, FRAMES_UNKNOWN,
};
use super::store::{
    check_latest, read_chunk_object, read_commit_marks, read_manifest_at, MapStore,
};
use super::ChunkIndex;
use crate::error::{Error, Result};
use crate::regularize::TvParams;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

/// The commit generation in the header of chunk object `name` (0 when it has none or cannot be
/// read).
fn header_commit_gen(files: &dyn MapFiles, name: &str) -> u64 {
    files
        .read_range(name, 0..CHUNK_HEADER_V2_BYTES as u64)
        .ok()
        .and_then(|head| decode_header_with_origin(&head).ok())
        .and_then(|(_, o)| o)
        .map_or(0, |o| o.commit_gen)
}

/// Moves object `from` to `to` (kept for inspection): a rename in a directory, a copy and a
/// delete on an object store. Returns where it went.
fn move_aside(files: &dyn MapFiles, from: &str, to: &str) -> Result<PathBuf> {
    let from_path = files.path(from);
    match files.location().as_dir() {
        Some(dir) => {
            let to_path = dir.join(to);
            if let Some(parent) = to_path.parent() {
                std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
            }
            std::fs::rename(&from_path, &to_path).map_err(|e| Error::io(&from_path, e))?;
        }
        None => {
            let bytes = files
                .read(from)?
                .ok_or_else(|| Error::bad_input(&from_path, "vanished while being moved aside"))?;
            files.write(to, &bytes)?;
            files.delete(from)?;
        }
    }
    Ok(files.path(to))
}

/// What [`repair`] did.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RepairReport {
    /// Where an unreadable manifest was moved (kept for inspection), if there was one.
    pub unreadable_manifest_moved_to: Option<PathBuf>,
    /// Chunk files examined (`*.dchk`).
    pub files_examined: usize,
    /// Chunks in the new manifest.
    pub chunks: usize,
    /// Blocks in the new manifest.
    pub blocks: u64,
    /// Voxels in Ω in the new manifest.
    pub observed_voxels: u64,
    /// Chunks kept at an older version because their newest file could not be kept, one line each.
    pub older_versions_used: Vec<String>,
    /// Files not kept, one line each: name and why.
    pub not_kept: Vec<String>,
    /// Notes about the rebuilt state (passes, grid), one line each.
    pub notes: Vec<String>,
    /// The map id of the new manifest.
    pub map_id: u64,
    /// The regularization state of the new manifest.
    pub passes: PassStatus,
    /// Frames of the reconstruct job the new manifest records as fused (restored from the commit
    /// mark); `None`: unknown, so `reconstruct --map` cannot resume the map.
    pub frames_committed: Option<u64>,
}

/// One intact chunk file.
#[derive(Clone, Debug)]
struct Candidate {
    chunk: ChunkIndex,
    seq: u64,
    name: String,
    header: ChunkHeader,
    origin: Option<ChunkOrigin>,
    entry: ChunkEntry,
}

type GridKey = (u32, u32, u32);

fn grid_key(h: &ChunkHeader) -> GridKey {
    (
        h.voxel_size_m.to_bits(),
        h.truncation_m.to_bits(),
        h.chunk_blocks,
    )
}

/// Rebuilds `dir/manifest.dmf` from the chunk files, holding the map's writer lock. Refuses a map
/// whose manifest is intact and the latest (`inspect --verify` checks such a map); an unreadable
/// manifest is moved aside to `manifest.dmf.unreadable-<unix seconds>` first, and a rolled-back
/// one (older than the commit mark or than chunk files of this map, `layout.rs`) to
/// `manifest.dmf.rolled-back-<generation>`.
pub fn repair(dir: &Path) -> Result<RepairReport> {
    if !dir.join(CHUNKS_DIR).is_dir() {
        return Err(Error::bad_input(
            dir,
            "has no chunks/ folder: not a denser map, nothing to rebuild from",
        ));
    }
    repair_files(std::sync::Arc::new(LocalFiles::new(dir)))
}

/// [`repair`] at any location (a directory or `s3://bucket/prefix`).
pub fn repair_at(loc: &super::location::MapLocation) -> Result<RepairReport> {
    match loc.as_dir() {
        Some(dir) => repair(dir),
        None => repair_files(loc.open_files()?),
    }
}

/// [`repair`] over given objects. On an object store the manifest is moved aside by a copy and
/// a delete, and the rebuilt one is committed create-only under the writer's lease.
pub fn repair_files(files: std::sync::Arc<dyn MapFiles>) -> Result<RepairReport> {
    let loc = files.location().clone();
    if let Some(holder) = files.writer_holding() {
        return Err(Error::MapLocked {
            dir: loc.display_path(),
            holder,
        });
    }
    let mut names: Vec<String> = files
        .list(CHUNKS_DIR)?
        .into_iter()
        .map(|o| o.name)
        .collect();
    if names.is_empty() && !files.exists(MANIFEST_FILE)? {
        return Err(Error::bad_input(
            loc.display_path(),
            "has no chunk files and no manifest: not a denser map, nothing to rebuild from",
        ));
    }
    let lock = files.lock_writer()?;
    let mut moved = None;
    // The header of a rolled-back manifest (its grid and map id stand when no chunk file does).
    let mut rolled_back: Option<ManifestHeader> = None;
    let mut notes = Vec::new();
    // The newest commit generation any evidence shows: the rebuilt manifest commits past it.
    let marks = read_commit_marks(&*files)?;
    let mut newest_generation = marks.begun(None).map_or(0, |(_, g, _)| g);
    if files.exists(MANIFEST_FILE)? {
        match read_manifest_at(&*files) {
            Ok((m, _)) => {
                let evidence = match check_latest(&*files, &m) {
                    Ok(()) => None,
                    Err(Error::MapRolledBack { evidence, .. }) => Some(evidence),
                    Err(other) => return Err(other),
                };
                let Some(evidence) = evidence else {
                    return Err(Error::bad_input(
                        files.path(MANIFEST_FILE),
                        format!(
                            "is intact (generation {}, {} chunks): nothing to repair; `denser inspect {} --verify` checks the chunk files",
                            m.header.generation,
                            m.chunks.len(),
                            loc
                        ),
                    ));
                };
                newest_generation = newest_generation.max(m.header.generation);
                rolled_back = Some(m.header);
                let to = format!("{MANIFEST_FILE}.rolled-back-{}", m.header.generation);
                notes.push(format!(
                    "the manifest (generation {}) was older than the map ({evidence}); moved to {} and rebuilt from the chunk files",
                    m.header.generation,
                    files.path(&to).display()
                ));
                moved = Some(move_aside(&*files, MANIFEST_FILE, &to)?);
            }
            Err(e) => {
                let secs = std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0, |d| d.as_secs());
                let to = format!("{MANIFEST_FILE}.unreadable-{secs}");
                tracing::warn!("{e}; moving it to {}", files.path(&to).display());
                moved = Some(move_aside(&*files, MANIFEST_FILE, &to)?);
            }
        }
    }
    names.sort();
    let mut not_kept = Vec::new();
    let mut candidates: Vec<Candidate> = Vec::new();
    let mut max_seq = 0u64;
    // Newest file of each chunk by (commit generation, number), intact or not.
    let mut versions: Vec<(ChunkIndex, (u64, u64), String)> = Vec::new();
    let mut after_commit: Vec<String> = Vec::new();
    let mut failed: HashMap<String, String> = HashMap::new();
    let mut files_examined = 0;
    for name in names {
        let stem = name
            .strip_suffix(".tmp")
            .map_or(name.clone(), |s| format!("{s}.dchk"));
        let Some((c, seq)) = parse_chunk_file_name(&stem) else {
            not_kept.push(format!("{name}: not a chunk file name"));
            continue;
        };
        max_seq = max_seq.max(seq);
        if name.ends_with(".tmp") {
            not_kept.push(format!("{name}: temporary file (an unfinished write)"));
            continue;
        }
        files_examined += 1;
        let object = format!("{CHUNKS_DIR}/{name}");
        let key = (header_commit_gen(&*files, &object), seq);
        newest_generation = newest_generation.max(key.0);
        versions.push((c, key, name.clone()));
        let (d, bytes) = match read_chunk_object(&*files, &object) {
            Ok(d) => d,
            Err(e) => {
                let why = match &e {
                    Error::BadInput { message, .. } => message.clone(),
                    other => other.to_string(),
                };
                not_kept.push(format!("{name}: {why}"));
                failed.insert(name, why);
                continue;
            }
        };
        let mut bad = None;
        if d.header.chunk != c {
            bad = Some(format!(
                "its header says chunk {:?}, its name {:?}",
                d.header.chunk.0, c.0
            ));
        } else if let Some(o) = d.origin.filter(|o| o.file_seq != seq) {
            bad = Some(format!(
                "its header says file number {}, its name {seq}",
                o.file_seq
            ));
        }
        if let Some(why) = bad {
            not_kept.push(format!("{name}: {why}"));
            failed.insert(name, why);
            continue;
        }
        let observed: u32 = d
            .blocks
            .iter()
            .map(|(_, b)| b.observed_count() as u32)
            .sum();
        let reg_pass = d.origin.map_or(0, |o| o.reg_pass);
        candidates.push(Candidate {
            chunk: c,
            seq,
            name,
            header: d.header,
            origin: d.origin,
            entry: ChunkEntry {
                block_count: d.header.block_count,
                observed_voxels: observed,
                flags: if d.header.flags & FLAG_HAS_REGULARIZED != 0 {
                    ENTRY_HAS_REGULARIZED
                } else {
                    0
                },
                file_seq: seq,
                file_bytes: bytes,
                payload_crc32: d.header.payload_crc32,
                reg_pass,
            },
        });
    }
    if candidates.is_empty() && files_examined == 0 {
        if let Some(h) = rolled_back {
            // A map whose last commit held no chunk yet, rolled back: rebuilt empty, with the
            // rolled-back manifest's grid and identity and the commit mark's fusion cursor.
            let frames = match marks.begun(Some(h.map_id)) {
                Some((_, _, Some(f))) => f,
                _ => FRAMES_UNKNOWN,
            };
            let manifest = Manifest {
                header: ManifestHeader {
                    generation: newest_generation,
                    frames_committed: frames,
                    next_file_seq: h.next_file_seq.max(max_seq + 1),
                    ..h
                },
                chunks: BTreeMap::new(),
                kept: BTreeMap::new(),
            };
            let passes = manifest.pass_status();
            let mut store = MapStore::from_repair(files, lock, manifest);
            store.commit()?;
            return Ok(RepairReport {
                unreadable_manifest_moved_to: moved,
                files_examined,
                chunks: 0,
                blocks: 0,
                observed_voxels: 0,
                older_versions_used: Vec::new(),
                not_kept,
                notes,
                map_id: h.map_id,
                passes,
                frames_committed: (frames != FRAMES_UNKNOWN).then_some(frames),
            });
        }
    }
    if candidates.is_empty() {
        return Err(Error::bad_input(
            files.path(CHUNKS_DIR),
            format!(
                "no intact chunk file among {files_examined}: nothing to rebuild a manifest from"
            ),
        ));
    }
    // The map's grid and identity: the majority of the intact files.
    let mut grids: BTreeMap<GridKey, usize> = BTreeMap::new();
    for k in &candidates {
        *grids.entry(grid_key(&k.header)).or_default() += 1;
    }
    let (&grid, _) = grids
        .iter()
        .max_by_key(|(k, n)| (**n, **k))
        .expect("a candidate");
    let mut ids: BTreeMap<u64, usize> = BTreeMap::new();
    for k in &candidates {
        if let Some(o) = k.origin.filter(|o| o.map_id != 0) {
            *ids.entry(o.map_id).or_default() += 1;
        }
    }
    let map_id = ids.iter().max_by_key(|(k, n)| (**n, **k)).map(|(k, _)| *k);
    if ids.len() > 1 {
        notes.push(format!(
            "chunk files of {} maps are mixed here; kept those of map {:016x} (the most files)",
            ids.len(),
            map_id.unwrap_or(0)
        ));
    }
    let (voxel_size_m, truncation_m, chunk_blocks) =
        (f32::from_bits(grid.0), f32::from_bits(grid.1), grid.2);
    candidates.retain(|k| {
        if grid_key(&k.header) != grid {
            let why = format!(
                "voxel {} m, μ {} m, chunk edge {} disagree with the map's {voxel_size_m} m, {truncation_m} m, {chunk_blocks}",
                k.header.voxel_size_m, k.header.truncation_m, k.header.chunk_blocks
            );
            not_kept.push(format!("{}: {why}", k.name));
            failed.insert(k.name.clone(), why);
            return false;
        }
        if let (Some(o), Some(id)) = (k.origin, map_id) {
            if o.map_id != 0 && o.map_id != id {
                let why = format!("belongs to another map (id {:016x}, this map's is {id:016x})", o.map_id);
                not_kept.push(format!("{}: {why}", k.name));
                failed.insert(k.name.clone(), why);
                return false;
            }
        }
        true
    });
    // The map is rebuilt as of its last commit begun: where the commit mark or the manifest of a
    // commit begun ([`MANIFEST_NEXT`]) of this map names it, files stamped with a later
    // generation were written after it (a checkpoint or pass a kill cut short) and are not part
    // of any committed map. They are reported and moved aside below.
    let mark = map_id.and_then(|id| marks.begun(Some(id)));
    let evidence = match mark {
        Some((_, g, _)) if marks.next.is_some_and(|n| Some(n.0) == map_id && n.1 == g) => {
            files.path(MANIFEST_NEXT)
        }
        _ => files.path(COMMIT_MARK),
    };
    let last_commit = mark.map(|(_, g, _)| g);
    if let Some(g) = last_commit {
        // Every file stamped later, intact or not (moved below, once the new manifest commits).
        for (_, (stamped, _), name) in &versions {
            if *stamped > g {
                not_kept.push(format!(
                    "{name}: written after the last commit (generation {g}, recorded in {}): not part of the committed map; moved to {NOT_COMMITTED_DIR}/",
                    evidence.display()
                ));
                after_commit.push(name.clone());
            }
        }
        candidates.retain(|k| k.origin.map_or(0, |o| o.commit_gen) <= g);
    }
    // The newest file of each chunk by (commit generation, number) that belongs to the committed
    // map, intact or not.
    let mut newest_name: HashMap<ChunkIndex, ((u64, u64), String)> = HashMap::new();
    for (c, key, name) in versions {
        if last_commit.is_some_and(|g| key.0 > g) {
            continue;
        }
        let newest = newest_name.entry(c).or_insert((key, name.clone()));
        if key > newest.0 {
            *newest = (key, name);
        }
    }
    // Newest intact version of each chunk; older ones stay candidates for the complete pass.
    let mut by_chunk: BTreeMap<ChunkIndex, Vec<Candidate>> = BTreeMap::new();
    for k in candidates {
        by_chunk.entry(k.chunk).or_default().push(k);
    }
    let mut older_versions_used = Vec::new();
    let mut chunks = BTreeMap::new();
    for (c, v) in by_chunk.iter_mut() {
        // By commit generation, then number: a shard's file (numbered far above the writer's,
        // stamped with the manifest it was derived from) never beats a later commit's.
        v.sort_by_key(|k| std::cmp::Reverse((k.origin.map_or(0, |o| o.commit_gen), k.seq)));
        let primary = &v[0];
        if let Some(((_, seq), name)) = newest_name.get(c) {
            if *seq != primary.seq {
                older_versions_used.push(format!(
                    "chunk ({},{},{}): newest file {name} could not be kept ({}); kept {} (pass {})",
                    c.0[0],
                    c.0[1],
                    c.0[2],
                    failed.get(name).map_or("unreadable", String::as_str),
                    primary.name,
                    primary.entry.reg_pass
                ));
            }
        }
        chunks.insert(*c, primary.entry);
    }
    // Regularization passes, from the kept files' origins.
    let mut params: BTreeMap<u32, TvParams> = BTreeMap::new();
    let mut disagreeing: BTreeMap<u32, usize> = BTreeMap::new();
    for v in by_chunk.values() {
        for k in v {
            if let Some(o) = k.origin.filter(|o| o.reg_pass > 0) {
                let p = params.entry(o.reg_pass).or_insert(o.reg_params);
                if *p != o.reg_params {
                    *disagreeing.entry(o.reg_pass).or_default() += 1;
                }
            }
        }
    }
    for (pass, n) in disagreeing {
        notes.push(format!(
            "{n} files of pass {pass} record other parameters than {:?}; the pass keeps those",
            params[&pass]
        ));
    }
    let latest = chunks.values().map(|e| e.reg_pass).max().unwrap_or(0);
    let mut complete = 0;
    let mut kept = BTreeMap::new();
    if chunks.values().all(|e| e.reg_pass == latest) {
        complete = latest;
    } else {
        let older: std::collections::BTreeSet<u32> = chunks
            .values()
            .map(|e| e.reg_pass)
            .filter(|p| *p != latest)
            .collect();
        if older.len() == 1 && *older.first().expect("one") > 0 {
            let c_pass = *older.first().expect("one");
            let mut missing = Vec::new();
            for (c, v) in &by_chunk {
                if v[0].entry.reg_pass == latest {
                    match v.iter().find(|k| k.entry.reg_pass == c_pass) {
                        Some(k) => {
                            kept.insert(*c, k.entry);
                        }
                        None => missing.push(*c),
                    }
                }
            }
            if missing.is_empty() {
                complete = c_pass;
            } else {
                kept.clear();
                notes.push(format!(
                    "pass {c_pass} cannot be kept readable: {} chunks rewritten by pass {latest} have no intact file of it (e.g. {:?})",
                    missing.len(),
                    missing[0].0
                ));
            }
        } else {
            notes.push(format!(
                "the chunks pass {latest} did not reach stand at passes {older:?}: no complete pass to keep"
            ));
        }
    }
    // The fusion cursor: the commit mark's, when the map rebuilt is exactly that commit's (every
    // kept file stamped at or before it, none replaced by an older version); else unknown.
    let frames_committed = match mark {
        Some((_, _, Some(frames))) if older_versions_used.is_empty() => frames,
        _ => FRAMES_UNKNOWN,
    };
    let fallback = TvParams::paper(voxel_size_m);
    let header = ManifestHeader {
        voxel_size_m,
        truncation_m,
        chunk_blocks,
        generation: newest_generation,
        frames_committed,
        next_file_seq: max_seq + 1,
        reg_pass: latest,
        reg_params: params.get(&latest).copied().unwrap_or(fallback),
        complete_pass: complete,
        complete_params: params
            .get(&complete)
            .copied()
            .unwrap_or(super::codec::NO_PARAMS),
        map_id: map_id.unwrap_or_else(new_map_id),
    };
    if by_chunk
        .values()
        .any(|v| v[0].origin.is_none() && v[0].entry.flags & ENTRY_HAS_REGULARIZED != 0)
    {
        notes.push(
            "some kept files are of chunk format 1 and carry u of an unknown pass: they count as not regularized".into(),
        );
    }
    let manifest = Manifest {
        header,
        chunks,
        kept,
    };
    let passes = manifest.pass_status();
    // Out of `chunks/` before the new manifest commits past their stamps, so that no later
    // repair takes them for committed files (a repair cut short moves the rest next time).
    for name in &after_commit {
        move_aside(
            &*files,
            &format!("{CHUNKS_DIR}/{name}"),
            &format!("{NOT_COMMITTED_DIR}/{name}"),
        )?;
    }
    let mut store = MapStore::from_repair(files, lock, manifest);
    store.commit()?;
    let s = store.summary();
    Ok(RepairReport {
        unreadable_manifest_moved_to: moved,
        files_examined,
        chunks: s.chunks,
        blocks: s.blocks,
        observed_voxels: s.observed_voxels,
        older_versions_used,
        not_kept,
        notes,
        map_id: store.manifest().header.map_id,
        passes,
        frames_committed: (frames_committed != FRAMES_UNKNOWN).then_some(frames_committed),
    })
}
