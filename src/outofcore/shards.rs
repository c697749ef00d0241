//! Regions as an array job: the records that let many processes regularize one map without a
//! lock or a commit, and the committing run adopt their results (`formats/shards.md`).
//!
//! A `regularize --shard I/N` process reads the committed manifest, works out the pass exactly as
//! the committing run will (same parameters as the latest pass: continue it; else the next
//! pass), and names that work by a **plan key**: a hash of the map's identity, the pass and its
//! parameters, the region layout and every chunk's committed file. The first shard creates the
//! plan object `shards/<key>/plan.json` (create-only), which reserves file numbers
//! `seq_base + rank(chunk)` for the pass's chunk files, `seq_base` lying [`SHARD_SEQ_GAP`] above
//! the manifest's next number so no writer of that generation reaches them. Each region a shard
//! solves is written as those files (create-only) and then a **region record**
//! `shards/<key>/regions/r_X_Y_Z.json` (create-only) naming each file with its size, blocks, Ω
//! voxels and payload CRC. A shard killed midway leaves files without a record: rerun, it finds
//! them (create-only) and records them.
//!
//! The plain `regularize` (the only committer) computes the same key, checks every record
//! against the files' headers (ranged reads), records them in its manifest, sets the next
//! sequence number past the plan's range, commits once, solves the regions no record covers, and
//! when the pass completes removes the plans with the files of theirs that no manifest names.
//! While a plan exists, writers opening the map leave the files in its range alone.

use crate::error::{Error, Result};
use crate::map::codec::{decode_header_with_origin, CHUNK_HEADER_V2_BYTES, FLAG_HAS_REGULARIZED};
use crate::map::files::MapFiles;
use crate::map::layout::{CHUNKS_DIR, RESERVATION_FILE, SHARDS_AREA};
use crate::map::manifest::{chunk_file_name, ChunkEntry, Manifest, ENTRY_HAS_REGULARIZED};
use crate::map::reserve::{reservation_name, reservation_objects, Reservation};
use crate::map::store::{MapStore, WrittenChunk};
use crate::map::ChunkIndex;
use crate::regularize::TvParams;
use std::collections::BTreeMap;
use std::ops::Range;

/// Distance between the manifest's next file number and a plan's first reserved number.
pub const SHARD_SEQ_GAP: u64 = 1 << 32;
/// `format` of a plan object.
pub const PLAN_FORMAT: &str = "denser-shard-plan";
/// `format` of a region record.
pub const RECORD_FORMAT: &str = "denser-region-done";

/// Which share of the work this process does: items `k` with `k mod count == index`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// This shard, `0..count`.
    pub index: u32,
    /// Shards in the job.
    pub count: u32,
}

/// The engines' environment variables that carry an array task's index, in the order read.
pub const SHARD_INDEX_VARIABLES: [&str; 3] = [
    "JOB_COMPLETION_INDEX",
    "SLURM_ARRAY_TASK_ID",
    "AWS_BATCH_JOB_ARRAY_INDEX",
];

impl Shard {
    /// Parses `I/N` (0 ≤ I < N), or `auto/N` with the index from the array engine's environment
    /// (`JOB_COMPLETION_INDEX` for Kubernetes Indexed Jobs, `SLURM_ARRAY_TASK_ID` minus
    /// `SLURM_ARRAY_TASK_MIN` when set, `AWS_BATCH_JOB_ARRAY_INDEX`).
    pub fn parse(s: &str) -> Result<Self> {
        Self::parse_with_env(s, |k| std::env::var(k).ok())
    }

    /// [`Shard::parse`] with the environment given as a function (for tests).
    pub fn parse_with_env(s: &str, env: impl Fn(&str) -> Option<String>) -> Result<Self> {
        let bad = |why: &str| {
            Error::InvalidArgument(format!("--shard {s:?}: {why} (expected I/N or auto/N)"))
        };
        let (i, n) = s.split_once('/').ok_or_else(|| bad("no '/'"))?;
        let count: u32 = n.trim().parse().map_err(|_| bad("N is not a number"))?;
        if count == 0 {
            return Err(bad("N must be at least 1"));
        }
        let index: u32 = if i.trim() == "auto" {
            let (var, value) = SHARD_INDEX_VARIABLES
                .iter()
                .find_map(|v| env(v).map(|x| (*v, x)))
                .ok_or_else(|| {
                    bad(&format!(
                        "auto: none of {} is set",
                        SHARD_INDEX_VARIABLES.join(", ")
                    ))
                })?;
            let mut k: i64 = value
                .trim()
                .parse()
                .map_err(|_| bad(&format!("{var}={value:?} is not a number")))?;
            if var == "SLURM_ARRAY_TASK_ID" {
                if let Some(min) =
                    env("SLURM_ARRAY_TASK_MIN").and_then(|m| m.trim().parse::<i64>().ok())
                {
                    k -= min;
                }
            }
            u32::try_from(k).map_err(|_| bad(&format!("{var}={value} gives index {k}")))?
        } else {
            i.trim().parse().map_err(|_| bad("I is not a number"))?
        };
        if index >= count {
            return Err(bad(&format!("index {index} is not below {count}")));
        }
        Ok(Shard { index, count })
    }

    /// Whether item `k` (a region's or a chunk's position in sorted order) is this shard's.
    pub fn owns(&self, k: usize) -> bool {
        k % self.count as usize == self.index as usize
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// The plan of a sharded pass (`shards/<key>/plan.json`, `formats/shards.md`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ShardPlan {
    /// [`PLAN_FORMAT`].
    pub format: String,
    /// 1.
    pub version: u32,
    /// The plan key, 16 hex digits.
    pub key: String,
    /// The map's id, 16 hex digits.
    pub map_id: String,
    /// The pass the shards write.
    pub pass: u32,
    /// Its parameters.
    pub params: TvParams,
    /// Region edge, chunks.
    pub region_chunks: u32,
    /// Halo, blocks.
    pub halo_blocks: i32,
    /// First reserved file number: chunk of rank `r` (sorted order) gets `seq_base + r`.
    pub seq_base: u64,
    /// Chunks of the map (reserved numbers: `seq_base .. seq_base + chunks`).
    pub chunks: u64,
    /// Regions of the pass.
    pub regions: u64,
    /// When the first shard created it, seconds since the Unix epoch.
    pub created_unix_s: u64,
    /// Who created it (host, pid, command).
    pub created_by: String,
}

impl ShardPlan {
    /// The file numbers it reserves.
    pub fn reserved(&self) -> Range<u64> {
        Reservation {
            seq_base: self.seq_base,
            chunks: self.chunks,
        }
        .range()
    }
}

/// One chunk file a region record names.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct RecordedFile {
    /// Chunk coordinate.
    pub chunk: [i32; 3],
    /// File number (its name).
    pub file_seq: u64,
    /// Size, bytes.
    pub file_bytes: u64,
    /// Blocks.
    pub block_count: u32,
    /// Voxels in Ω.
    pub observed_voxels: u32,
    /// Manifest entry flags (bit 0: carries `u`).
    pub flags: u32,
    /// Payload CRC-32, as in the file's header.
    pub payload_crc32: u32,
}

/// A region solved by a shard (`shards/<key>/regions/r_X_Y_Z.json`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RegionRecord {
    /// [`RECORD_FORMAT`].
    pub format: String,
    /// 1.
    pub version: u32,
    /// The plan key.
    pub key: String,
    /// Region coordinate (chunk coordinate divided by the region edge, rounded down).
    pub region: [i32; 3],
    /// Pass written.
    pub pass: u32,
    /// Its chunk files, sorted by chunk.
    pub files: Vec<RecordedFile>,
    /// Blocks solved, halo included.
    pub solved_blocks: u64,
    /// Ω voxels written.
    pub omega_voxels: u64,
    /// Seconds the region took.
    pub seconds: f64,
    /// Which shard (`I/N`).
    pub shard: String,
    /// Host and process id of the shard.
    pub host: String,
    /// Process id.
    pub pid: u32,
}

fn fnv(h: &mut u64, bytes: &[u8]) {
    for b in bytes {
        *h ^= *b as u64;
        *h = h.wrapping_mul(0x100_0000_01b3);
    }
}

/// The plan key of `pass` with `params` over the committed chunks of `m` (FNV-1a 64 over the
/// map id, the pass, the parameters' bits, region edge, halo, and every entry's chunk and file
/// number, in order): equal for every process that read the same manifest and asked for the same
/// work, different as soon as a chunk's file changes.
pub fn plan_key(m: &Manifest, pass: u32, params: &TvParams, region_chunks: u32, halo: i32) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    fnv(&mut h, &m.header.map_id.to_le_bytes());
    fnv(&mut h, &pass.to_le_bytes());
    for v in [
        params.lambda.to_bits(),
        params.sigma.to_bits(),
        params.tau.to_bits(),
        params.theta.to_bits(),
        params.iterations,
        region_chunks,
        halo as u32,
    ] {
        fnv(&mut h, &v.to_le_bytes());
    }
    for (c, e) in &m.chunks {
        for a in c.0 {
            fnv(&mut h, &a.to_le_bytes());
        }
        fnv(&mut h, &e.file_seq.to_le_bytes());
    }
    h
}

fn plan_name(key: u64) -> String {
    reservation_name(&format!("{key:016x}"))
}

fn record_name(key: u64, region: [i32; 3]) -> String {
    format!(
        "{SHARDS_AREA}/{key:016x}/regions/r_{}_{}_{}.json",
        region[0], region[1], region[2]
    )
}

fn parse_json<T: serde::de::DeserializeOwned>(
    files: &dyn MapFiles,
    name: &str,
) -> Result<Option<T>> {
    let Some((b, _)) = files.read_versioned(name)? else {
        return Ok(None);
    };
    serde_json::from_slice(&b)
        .map(Some)
        .map_err(|e| Error::bad_input(files.path(name), format!("not a valid record: {e}")))
}

/// Every plan under `shards/` (unreadable ones are reported and skipped).
pub fn plans(files: &dyn MapFiles) -> Result<Vec<ShardPlan>> {
    let mut out = Vec::new();
    for name in reservation_objects(files)? {
        match parse_json::<ShardPlan>(files, &name) {
            Ok(Some(p)) if p.format == PLAN_FORMAT => out.push(p),
            Ok(_) => {}
            Err(e) => tracing::warn!("{e}"),
        }
    }
    Ok(out)
}

/// Creates the plan of `key` (create-only) or reads the one a shard created first; an error when
/// an existing plan disagrees (it cannot, unless written by another version).
pub fn ensure_plan(files: &dyn MapFiles, want: &ShardPlan, key: u64) -> Result<ShardPlan> {
    let name = plan_name(key);
    let text = serde_json::to_vec_pretty(want)
        .map_err(|e| Error::InvalidArgument(format!("plan: {e}")))?;
    if files.write_new(&name, &text)? {
        return Ok(want.clone());
    }
    let Some(p) = parse_json::<ShardPlan>(files, &name)? else {
        return Err(Error::bad_input(files.path(&name), "vanished while read"));
    };
    if p.seq_base != want.seq_base || p.chunks != want.chunks || p.pass != want.pass {
        return Err(Error::bad_input(
            files.path(&name),
            format!(
                "plan disagrees with this shard's (file numbers from {} for {} chunks, pass {}; this shard: {}, {}, {})",
                p.seq_base, p.chunks, p.pass, want.seq_base, want.chunks, want.pass
            ),
        ));
    }
    Ok(p)
}

/// The plan this process would make for `pass` over the manifest `m`.
pub fn plan_for(
    m: &Manifest,
    key: u64,
    pass: u32,
    params: &TvParams,
    region_chunks: u32,
    halo: i32,
    regions: usize,
) -> ShardPlan {
    ShardPlan {
        format: PLAN_FORMAT.into(),
        version: 1,
        key: format!("{key:016x}"),
        map_id: format!("{:016x}", m.header.map_id),
        pass,
        params: *params,
        region_chunks,
        halo_blocks: halo,
        seq_base: m.header.next_file_seq + SHARD_SEQ_GAP,
        chunks: m.chunks.len() as u64,
        regions: regions as u64,
        created_unix_s: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs()),
        created_by: crate::map::lock::LockHolder::current().describe(),
    }
}

/// The reserved file number of each chunk: `seq_base + rank`.
pub fn reserved_seqs(m: &Manifest, plan: &ShardPlan) -> BTreeMap<ChunkIndex, u64> {
    m.chunks
        .keys()
        .enumerate()
        .map(|(r, c)| (*c, plan.seq_base + r as u64))
        .collect()
}

/// Regions recorded as done under `key`.
pub fn recorded_regions(files: &dyn MapFiles, key: u64) -> Result<Vec<[i32; 3]>> {
    let folder = format!("{SHARDS_AREA}/{key:016x}/regions");
    Ok(files
        .list(&folder)?
        .iter()
        .filter_map(|o| {
            let stem = o.name.strip_prefix("r_")?.strip_suffix(".json")?;
            let v: Vec<i32> = stem.split('_').filter_map(|t| t.parse().ok()).collect();
            (v.len() == 3).then(|| [v[0], v[1], v[2]])
        })
        .collect())
}

/// Writes a region record (create-only; a record already there from another run of the same
/// region is kept).
pub fn write_record(files: &dyn MapFiles, key: u64, rec: &RegionRecord) -> Result<()> {
    let text = serde_json::to_vec_pretty(rec)
        .map_err(|e| Error::InvalidArgument(format!("record: {e}")))?;
    files.write_new(&record_name(key, rec.region), &text)?;
    Ok(())
}

/// What the committing run took from the shards.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Adopted {
    /// Regions whose records were adopted.
    pub regions: usize,
    /// Chunk files adopted.
    pub chunks: usize,
    /// Records refused, one line each (the region is solved again).
    pub refused: Vec<String>,
}

/// Checks one recorded file against its header (a ranged read of 128 bytes) and the plan.
/// The manifest entry a recorded file becomes once adopted into `pass`.
fn entry_of(f: &RecordedFile, pass: u32) -> ChunkEntry {
    ChunkEntry {
        block_count: f.block_count,
        observed_voxels: f.observed_voxels,
        flags: f.flags,
        file_seq: f.file_seq,
        file_bytes: f.file_bytes,
        payload_crc32: f.payload_crc32,
        reg_pass: pass,
    }
}

fn check_file(
    store: &MapStore,
    plan: &ShardPlan,
    seqs: &BTreeMap<ChunkIndex, u64>,
    f: &RecordedFile,
) -> std::result::Result<(), String> {
    let c = ChunkIndex(f.chunk);
    if seqs.get(&c) != Some(&f.file_seq) {
        return Err(format!(
            "chunk {:?} file {} is not the number the plan reserves for it",
            f.chunk, f.file_seq
        ));
    }
    let name = format!("{CHUNKS_DIR}/{}", chunk_file_name(c, f.file_seq));
    let files = store.files();
    let head = files
        .read_range(&name, 0..CHUNK_HEADER_V2_BYTES as u64)
        .map_err(|e| e.to_string())?;
    let (h, origin) = decode_header_with_origin(&head).map_err(|e| format!("{name}: {e}"))?;
    let o = origin.ok_or_else(|| format!("{name}: chunk format 1 carries no origin"))?;
    let size = h.payload_zstd_bytes as u64 + head.len().min(CHUNK_HEADER_V2_BYTES) as u64;
    let has_u = h.flags & FLAG_HAS_REGULARIZED != 0;
    let ok = h.chunk == c
        && h.block_count == f.block_count
        && h.payload_crc32 == f.payload_crc32
        && has_u == (f.flags & ENTRY_HAS_REGULARIZED != 0)
        && o.file_seq == f.file_seq
        && o.reg_pass == plan.pass
        && o.map_id == store.manifest().header.map_id
        && size == f.file_bytes
        && h.chunk_blocks == store.chunk_blocks();
    if ok {
        Ok(())
    } else {
        Err(format!("{name}: header does not match the record"))
    }
}

/// Adopts the region records of the plan `key` into `store`'s manifest (committed by the
/// caller): every record whose files all check out, covering every chunk of its region.
pub fn adopt(
    store: &mut MapStore,
    key: u64,
    region_of: impl Fn(ChunkIndex) -> [i32; 3],
) -> Result<Adopted> {
    let mut out = Adopted::default();
    let files = store.files().clone();
    let Some(plan) = parse_json::<ShardPlan>(&*files, &plan_name(key))? else {
        return Ok(out);
    };
    let seqs = reserved_seqs(store.manifest(), &plan);
    let mut by_region: BTreeMap<[i32; 3], Vec<ChunkIndex>> = BTreeMap::new();
    for c in store.chunk_indices() {
        by_region.entry(region_of(c)).or_default().push(c);
    }
    let mut max_seq = 0;
    for region in recorded_regions(&*files, key)? {
        let name = record_name(key, region);
        let rec = match parse_json::<RegionRecord>(&*files, &name) {
            Ok(Some(r)) => r,
            Ok(None) => continue,
            Err(e) => {
                out.refused.push(e.to_string());
                continue;
            }
        };
        let core = by_region.get(&region).cloned().unwrap_or_default();
        let named: Vec<ChunkIndex> = rec.files.iter().map(|f| ChunkIndex(f.chunk)).collect();
        let mut why = None;
        if rec.key != plan.key || rec.pass != plan.pass || rec.region != region {
            why = Some("belongs to another plan or region".to_string());
        } else if named != core {
            why = Some(format!(
                "names {} chunk files, the region has {} chunks",
                named.len(),
                core.len()
            ));
        } else {
            for f in &rec.files {
                // The header against the record and the plan, then the whole file read as the
                // engine reads a committed one (both CRCs, the payload decoded, every field
                // against the entry): a flipped payload byte refuses the region, which is then
                // solved again, before anything it would supersede is deleted (issue 36).
                let verified = check_file(store, &plan, &seqs, f).and_then(|()| {
                    store
                        .read_entry(ChunkIndex(f.chunk), &entry_of(f, plan.pass))
                        .map(|_| ())
                        .map_err(|e| e.to_string())
                });
                if let Err(e) = verified {
                    why = Some(e);
                    break;
                }
            }
        }
        if let Some(why) = why {
            out.refused
                .push(format!("{}: {why}", files.path(&name).display()));
            continue;
        }
        for f in &rec.files {
            max_seq = max_seq.max(f.file_seq);
            store.record(WrittenChunk {
                chunk: ChunkIndex(f.chunk),
                entry: entry_of(f, plan.pass),
            });
            out.chunks += 1;
        }
        out.regions += 1;
    }
    if out.regions > 0 {
        let h = store.header_mut();
        h.next_file_seq = h
            .next_file_seq
            .max(plan.seq_base + plan.chunks)
            .max(max_seq + 1);
    }
    for r in &out.refused {
        tracing::warn!("shard record refused (its region is solved again): {r}");
    }
    Ok(out)
}

/// Removes every plan of the map with its records and the files in its range that the manifest
/// does not name (the engine's rule: [`MapStore::remove_unnamed_in`]), once the pass is
/// complete. Returns how many files were removed.
pub fn close_plans(store: &MapStore) -> Result<usize> {
    let files = store.files().clone();
    let mut removed = 0;
    for plan in &plans(&*files)? {
        removed += store.remove_unnamed_in(plan.reserved())?;
        let folder = format!("{SHARDS_AREA}/{}", plan.key);
        for o in files.list_recursive(&folder)? {
            if o.name != RESERVATION_FILE {
                files.delete(&format!("{folder}/{}", o.name))?;
            }
        }
        files.delete(&reservation_name(&plan.key))?;
    }
    Ok(removed)
}
