//! Merging maps of the same world frame (`denser merge A B … --out M`): drives, or slices of one
//! long drive, fused on different machines and combined chunk by chunk.
//!
//! Every voxel is the weighted running average of the inputs, as fusion would have left it had
//! it seen their observations one after the other: `f = Σ wᵢ fᵢ / Σ wᵢ`, colour likewise, weight
//! `min(Σ wᵢ, 127)` (fusion's cap), Ω the union. The regularized field `u` is dropped: the merged
//! map needs a new regularization pass. Only one chunk of every input is in memory at a time.
//!
//! What differs from fusing all frames into one map (`formats/shards.md` gives the measured
//! figures): depth fusion carves free space in every *allocated* block a frame sees, so a frame of
//! drive B, fused after drive A, also updates A's blocks in front of B's surfaces. Fused apart, B
//! never sees A's blocks: a block only A allocated keeps A's values where B would have carved it.
//! LiDAR fusion updates only voxels within μ of a return and carves nothing, so there the merge
//! differs from sequential fusion only by rounding (one quantised average instead of a chain of
//! them) and by the weight cap, which sequential fusion reaches earlier.

use crate::error::{Error, Result};
use crate::grid::{decode_tsdf, encode_tsdf, Block, BlockIndex, MAX_WEIGHT, OMEGA_BIT};
use crate::map::store::MapStore;
use crate::map::MapLocation;
use std::collections::BTreeMap;

/// What [`merge`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct MergeStats {
    /// Input maps.
    pub inputs: usize,
    /// Chunks written.
    pub chunks: usize,
    /// Blocks written.
    pub blocks: u64,
    /// Blocks present in more than one input (averaged).
    pub shared_blocks: u64,
    /// Voxels in Ω in the output.
    pub observed_voxels: u64,
    /// Largest decoded working set of one chunk (all inputs), bytes.
    pub peak_chunk_bytes: u64,
    /// Chunks a stopped run of the same merge had committed already (a resumed run).
    pub chunks_resumed: usize,
    /// Wall time, seconds.
    pub seconds: f64,
}

/// Combines voxel `i` of `add` into `acc` (weighted average; see the module doc).
pub fn merge_voxel(acc: &mut Block, add: &Block, i: usize) {
    let (wa, wb) = (acc.weight(i) as f32, add.weight(i) as f32);
    let omega = (acc.weight_omega[i] | add.weight_omega[i]) & OMEGA_BIT;
    if wb == 0.0 {
        acc.weight_omega[i] = (acc.weight_omega[i] & !OMEGA_BIT) | omega;
        return;
    }
    if wa == 0.0 {
        acc.tsdf[i] = add.tsdf[i];
        acc.color[i] = add.color[i];
        acc.weight_omega[i] = (add.weight_omega[i] & !OMEGA_BIT) | omega;
        return;
    }
    let w = wa + wb;
    let f = (wa * decode_tsdf(acc.tsdf[i]) + wb * decode_tsdf(add.tsdf[i])) / w;
    let (ca, cb) = (acc.color[i], add.color[i]);
    let color =
        std::array::from_fn(|k| ((wa * ca[k] as f32 + wb * cb[k] as f32) / w).round() as u8);
    acc.tsdf[i] = encode_tsdf(f);
    acc.color[i] = color;
    acc.weight_omega[i] = (w as u32).min(MAX_WEIGHT as u32) as u8 | omega;
}

/// Merges the maps at `inputs` (same voxel size, μ and chunk edge, else an error naming the
/// map that differs) into a new map at `out`, one chunk at a time; a chunk whose decoded blocks
/// from all inputs exceed `budget_bytes` is an error. Commits every 256 chunks and at the end.
///
/// All or nothing for its users: the output carries an incomplete mark naming the merge (its
/// inputs' identities and generations) until the last commit, so every command refuses a map a
/// stopped merge left; the same merge run again resumes it (chunks already committed are kept),
/// and a merge of other inputs, or of these inputs after they changed, is refused.
pub fn merge(inputs: &[MapLocation], out: &MapLocation, budget_bytes: u64) -> Result<MergeStats> {
    let t0 = std::time::Instant::now();
    if inputs.is_empty() {
        return Err(Error::InvalidArgument(
            "merge needs at least one input map".into(),
        ));
    }
    let maps: Vec<MapStore> = inputs
        .iter()
        .map(MapStore::open_read_only_at)
        .collect::<Result<_>>()?;
    // A map given twice (or a copy of one: same identity) would count every observation twice.
    for (j, m) in maps.iter().enumerate() {
        for (i, earlier) in maps[..j].iter().enumerate() {
            let id = m.manifest().header.map_id;
            let same_id = id != 0 && id == earlier.manifest().header.map_id;
            if same_id || inputs[i] == inputs[j] {
                return Err(Error::bad_input(
                    m.dir(),
                    format!(
                        "is the same map as input {} ({}{}): merging a map with itself would double every weight",
                        i + 1,
                        earlier.dir().display(),
                        if same_id { format!(", map id {id:016x}") } else { String::new() }
                    ),
                ));
            }
        }
    }
    let first = &maps[0];
    let (grid, cb) = (first.grid(), first.chunk_blocks());
    for m in &maps[1..] {
        let g = m.grid();
        if g.voxel_size_m != grid.voxel_size_m
            || g.truncation_m != grid.truncation_m
            || m.chunk_blocks() != cb
        {
            return Err(Error::bad_input(
                m.dir(),
                format!(
                    "cannot be merged with {}: voxel {} m, μ {} m, chunks of {} blocks against {} m, {} m, {} (maps must share the grid; the world frame is the caller's to ensure)",
                    first.dir().display(),
                    g.voxel_size_m,
                    g.truncation_m,
                    m.chunk_blocks(),
                    grid.voxel_size_m,
                    grid.truncation_m,
                    cb
                ),
            ));
        }
    }
    let mut all: std::collections::BTreeSet<crate::map::ChunkIndex> = Default::default();
    for m in &maps {
        all.extend(m.chunk_indices());
    }
    let job = format!(
        "denser merge of {} maps: {}",
        maps.len(),
        maps.iter()
            .map(|m| {
                let h = m.manifest().header;
                format!("{:016x}@{}", h.map_id, h.generation)
            })
            .collect::<Vec<_>>()
            .join(" ")
    );
    let out_files = out.open_files()?;
    let mut store = if out_files.exists(crate::map::layout::MANIFEST_FILE)? {
        match MapStore::open_incomplete_at(out)? {
            (s, Some(mark)) if mark.trim() == job => s,
            (_, Some(mark)) => {
                return Err(Error::bad_input(
                    out.display_path(),
                    format!(
                        "holds an unfinished merge of other inputs ({}), or of these inputs before they changed; delete it and merge again",
                        mark.trim()
                    ),
                ))
            }
            (_, None) => {
                return Err(Error::bad_input(
                    out.display_path(),
                    "already holds a map (manifest.dmf exists); merge into a new location",
                ))
            }
        }
    } else {
        MapStore::create_incomplete_at(out, grid, cb, &job)?
    };
    drop(out_files);
    let mut stats = MergeStats {
        inputs: maps.len(),
        ..Default::default()
    };
    let bar = crate::progress::bar(all.len() as u64, "merging");
    for (k, c) in all.iter().enumerate() {
        if store.contains(*c) {
            // Committed by a stopped run of this merge: its chunks are final.
            stats.chunks_resumed += 1;
            bar.inc(1);
            continue;
        }
        let mut blocks: BTreeMap<BlockIndex, Box<Block>> = BTreeMap::new();
        let mut bytes = 0u64;
        for m in &maps {
            let Some(d) = m.read_chunk(*c)? else { continue };
            bytes += d.blocks.len() as u64 * std::mem::size_of::<Block>() as u64;
            if bytes > budget_bytes {
                return Err(Error::InvalidArgument(format!(
                    "chunk {:?} of the inputs needs {} MiB decoded, over the {} MiB budget; raise --memory-budget",
                    c.0,
                    bytes >> 20,
                    budget_bytes >> 20
                )));
            }
            for (b, mut block) in d.blocks {
                block.regularized = None;
                match blocks.get_mut(&b) {
                    None => {
                        blocks.insert(b, block);
                    }
                    Some(acc) => {
                        stats.shared_blocks += 1;
                        for i in 0..crate::grid::VOXELS_PER_BLOCK {
                            merge_voxel(acc, &block, i);
                        }
                    }
                }
            }
        }
        stats.peak_chunk_bytes = stats.peak_chunk_bytes.max(bytes);
        let refs: Vec<(BlockIndex, &Block)> = blocks.iter().map(|(b, x)| (*b, &**x)).collect();
        stats.blocks += refs.len() as u64;
        stats.observed_voxels += refs
            .iter()
            .map(|(_, b)| b.observed_count() as u64)
            .sum::<u64>();
        if !refs.is_empty() {
            store.write_chunk(*c, &refs, 0)?;
            stats.chunks += 1;
        }
        if (k + 1) % 256 == 0 {
            store.commit()?;
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    store.commit()?;
    store.mark_complete()?;
    stats.seconds = t0.elapsed().as_secs_f64();
    Ok(stats)
}
