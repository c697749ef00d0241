//! Offline regularization of a stored map, region by region, within a memory budget, resumable.
//!
//! A region is a cube of `region_chunks`³ chunks (by default the largest whose working memory fits
//! the budget, [`super::region_plan`]). By default the pass runs as sweeps ([`super::sweeps`]):
//! every region `K` iterations at a time with a halo of `K + 1` voxels, the solver state kept in
//! the map between sweeps. Otherwise (`sweep_iterations: None`, and always for shards) each region
//! is solved with all iterations at once together with every stored block within
//! [`RegionPlan::exact_halo_blocks`] of it (read from the neighbouring chunk files). Either way
//! only the region's own chunks are written back (new files carrying `u`), and the result equals
//! one global in-memory solve of the same iterations (tested: bit for bit), seams included.
//!
//! Progress is part of the manifest: a pass number and its parameters in the header, and per chunk
//! the pass that wrote it. The manifest is committed after every region, so a killed run resumes
//! with the first region not committed; a run with other parameters starts a new pass. Until a
//! new pass reaches every chunk, the files of the last complete pass stay on disk and in the
//! manifest ([`crate::map::manifest::Manifest::kept`]), so that pass remains readable whole.
//!
//! Sharding ([`regularize_shard`], `formats/shards.md`) is a thin layer over the same loop: which
//! regions this process solves (its share, `k mod N`), and how a region's result is recorded —
//! committed to the manifest by the one writer, or, by a shard, written as create-only chunk files
//! with reserved numbers and a region record that the writer's next run adopts
//! ([`super::shards::adopt`]) before it solves what no shard recorded.

pub use super::region_plan::{
    check_budget_up_front, plan_region_chunks, MapRegularizeStats, RegionCosts, RegionalOptions,
};
use super::region_plan::{region_of, region_over_budget, resolve};
use super::shards::{self, Shard, ShardPlan};
use crate::error::Result;
use crate::grid::{Block, BlockIndex, Layer};
use crate::map::files::ObjectBytes;
use crate::map::store::MapStore;
use crate::map::ChunkIndex;
use crate::regularize::{RegionPlan, TvParams, TvProblem};
use std::collections::BTreeMap;

/// Regularizes every chunk of `store` with `params`, regions of `region_chunks`³ chunks, keeping
/// each region's working memory under `budget_bytes` (an error says so when one region does not
/// fit: use smaller regions). `progress(done, total)` is called after each region; returning
/// false stops the run there (everything done so far is committed, a later call resumes).
pub fn regularize_map(
    store: &mut MapStore,
    params: &TvParams,
    options: &RegionalOptions,
    progress: impl FnMut(usize, usize) -> bool,
) -> Result<MapRegularizeStats> {
    regularize_map_with(store, params, options, progress, |p, params| {
        p.solve(params);
        Ok(())
    })
}

/// [`regularize_map`] with another solver for each region's problem (it must run
/// `params.iterations` Chambolle–Pock iterations from the gathered state): a
/// [`crate::regularize::TvSolver`] of the run's backend, for one.
pub fn regularize_map_with(
    store: &mut MapStore,
    params: &TvParams,
    options: &RegionalOptions,
    progress: impl FnMut(usize, usize) -> bool,
    solve: impl FnMut(&mut TvProblem, &TvParams) -> Result<()>,
) -> Result<MapRegularizeStats> {
    params.validate()?;
    let t0 = std::time::Instant::now();
    let h = store.manifest().header;
    // Same parameters as the latest pass: continue it (a resumed run, or chunks fused since).
    // Other parameters: a new pass, recorded with its first committed region. The last complete
    // pass stays readable (kept files) until the new one reaches every chunk.
    let (pass, new_pass) = if h.reg_pass > 0 && h.reg_params == *params {
        (h.reg_pass, false)
    } else {
        (store.begin_pass(params), true)
    };
    let halo = options
        .halo_blocks
        .unwrap_or_else(|| RegionPlan::exact_halo_blocks(params.iterations))
        .max(0);
    let mut solve = solve;
    let mut progress = progress;
    let result = (|| {
        // Shards solve with the exact halo: their records are adopted under that plan's key. (A
        // budget too small for the exact halo's regions had no shards: sweeps go on without.)
        let exact = match resolve(store, options, halo, false, false) {
            Err(e) if options.sweep_iterations.is_none() => return Err(e),
            r => r,
        };
        let adopted = match &exact {
            Ok(exact) => {
                let key =
                    shards::plan_key(store.manifest(), pass, params, exact.region_chunks, halo);
                let r = exact.region_chunks as i32;
                shards::adopt(store, key, |c| region_of(c, r))?
            }
            Err(_) => Default::default(),
        };
        if adopted.regions > 0 {
            tracing::info!(
                "{}: adopted {} regions ({} chunk files) solved by shards",
                store.dir().display(),
                adopted.regions,
                adopted.chunks
            );
            store.commit()?;
        }
        let all_done = store.manifest().chunks.values().all(|e| e.reg_pass == pass);
        let swept = options
            .sweep_iterations
            .filter(|k| *k < params.iterations && adopted.regions == 0 && !all_done);
        let mut stats = match swept {
            Some(k) => {
                let options =
                    resolve(store, options, RegionPlan::exact_halo_blocks(k), true, true)?;
                let run = super::sweeps::SweptPass {
                    params,
                    region_chunks: options.region_chunks,
                    sweep_iterations: k,
                    budget_bytes: options.budget_bytes,
                    pass,
                };
                let mut stats =
                    super::sweeps::regularize_swept(store, &run, &mut progress, &mut solve)?;
                stats.region_chunks = options.region_chunks;
                stats
            }
            None => {
                // The plan consulted above is the one run: say so (the same plan again).
                exact?;
                let exact = resolve(store, options, halo, false, true)?;
                let mut mode = Mode::Commit;
                let mut stats = regularize_pass(
                    store,
                    params,
                    &exact,
                    pass,
                    new_pass,
                    &mut progress,
                    &mut solve,
                    &mut mode,
                )?;
                stats.sweeps = 1;
                stats.region_chunks = exact.region_chunks;
                stats
            }
        };
        stats.regions_adopted = adopted.regions;
        if store.manifest().latest_pass_complete() {
            let removed = shards::close_plans(store)?;
            if removed > 0 {
                tracing::info!("removed {removed} shard files no manifest names");
            }
        }
        Ok(stats)
    })();
    let stopped = result.as_ref().map_or(true, |s| s.interrupted);
    if stopped && new_pass && store.manifest().header.reg_pass == pass {
        // Nothing of the new pass may have been committed: forget it unless a region was.
        let committed = store.manifest().chunks.values().any(|e| e.reg_pass == pass);
        if !committed {
            let hm = store.header_mut();
            hm.reg_pass = h.reg_pass;
            hm.reg_params = h.reg_params;
        }
    }
    result.map(|mut stats| {
        stats.seconds = t0.elapsed().as_secs_f64();
        stats
    })
}

/// How solved regions are recorded: committed by the map's writer, or written by a shard.
// One value per run: the size difference between the variants costs nothing.
#[allow(clippy::large_enum_variant)]
enum Mode {
    /// Write the region's chunks and commit the manifest (the map's one writer).
    Commit,
    /// A shard: solve only its share, write create-only files with the plan's numbers and a
    /// region record; never commit.
    Shard {
        shard: Shard,
        plan: ShardPlan,
        key: u64,
        seqs: BTreeMap<ChunkIndex, u64>,
        recorded: std::collections::HashSet<[i32; 3]>,
    },
}

/// Regularizes this process's share of the regions of `store` (opened read-only: no lock, no
/// commit) as shard `shard` of an array job: each region is written as create-only chunk files
/// with the numbers the pass's plan reserves, then a region record (`formats/shards.md`). Regions
/// already committed at the pass, or recorded by any shard, are skipped, so a killed shard is
/// simply run again. A plain [`regularize_map`] afterwards adopts every record, solves what is
/// missing and commits the pass.
pub fn regularize_shard(
    store: &mut MapStore,
    params: &TvParams,
    options: &RegionalOptions,
    shard: Shard,
    progress: impl FnMut(usize, usize) -> bool,
    solve: impl FnMut(&mut TvProblem, &TvParams) -> Result<()>,
) -> Result<MapRegularizeStats> {
    params.validate()?;
    let t0 = std::time::Instant::now();
    let h = store.manifest().header;
    let (pass, new_pass) = if h.reg_pass > 0 && h.reg_params == *params {
        (h.reg_pass, false)
    } else {
        // In memory only: shards never commit; the pass is recorded by the committing run.
        (store.begin_pass(params), true)
    };
    let halo = options
        .halo_blocks
        .unwrap_or_else(|| RegionPlan::exact_halo_blocks(params.iterations))
        .max(0);
    let options = &resolve(store, options, halo, false, true)?;
    let r = options.region_chunks as i32;
    let key = shards::plan_key(store.manifest(), pass, params, options.region_chunks, halo);
    let regions: std::collections::BTreeSet<[i32; 3]> = store
        .chunk_indices()
        .into_iter()
        .map(|c| region_of(c, r))
        .collect();
    let want = shards::plan_for(
        store.manifest(),
        key,
        pass,
        params,
        options.region_chunks,
        halo,
        regions.len(),
    );
    let files = store.files().clone();
    let plan = shards::ensure_plan(&*files, &want, key)?;
    let seqs = shards::reserved_seqs(store.manifest(), &plan);
    let recorded = shards::recorded_regions(&*files, key)?
        .into_iter()
        .collect();
    let mut mode = Mode::Shard {
        shard,
        plan,
        key,
        seqs,
        recorded,
    };
    let mut stats = regularize_pass(
        store, params, options, pass, new_pass, progress, solve, &mut mode,
    )?;
    stats.seconds = t0.elapsed().as_secs_f64();
    Ok(stats)
}

/// The regions of pass `pass` (begun by the caller; `new_pass` when not yet committed).
#[allow(clippy::too_many_arguments)]
fn regularize_pass(
    store: &mut MapStore,
    params: &TvParams,
    options: &RegionalOptions,
    pass: u32,
    new_pass: bool,
    mut progress: impl FnMut(usize, usize) -> bool,
    mut solve: impl FnMut(&mut TvProblem, &TvParams) -> Result<()>,
    mode: &mut Mode,
) -> Result<MapRegularizeStats> {
    let cb = store.chunk_blocks() as i32;
    let r = options.region_chunks as i32;
    let all_done = |s: &MapStore| s.manifest().chunks.values().all(|e| e.reg_pass == pass);
    let halo = options
        .halo_blocks
        .unwrap_or_else(|| RegionPlan::exact_halo_blocks(params.iterations))
        .max(0);
    let mut stats = MapRegularizeStats {
        pass,
        halo_blocks: halo,
        ..Default::default()
    };
    if all_done(store) {
        if matches!(mode, Mode::Commit)
            && (new_pass || store.manifest().header.complete_pass != pass)
        {
            store.commit()?;
        }
        return Ok(stats);
    }
    let mut regions: BTreeMap<[i32; 3], Vec<ChunkIndex>> = BTreeMap::new();
    for c in store.chunk_indices() {
        regions.entry(region_of(c, r)).or_default().push(c);
    }
    let total = regions.len();
    let reach = (halo + cb - 1) / cb; // chunks of halo around a region
                                      // Freed region arrays stay in the heap for the next region, unless that passes the budget.
    let mut trim =
        crate::memory::TrimAbove::new(crate::memory::budget_for_data_bytes(options.budget_bytes));
    for (k, (key, core)) in regions.iter().enumerate() {
        trim.check();
        if let Mode::Shard {
            shard, recorded, ..
        } = mode
        {
            // Not this shard's, or recorded by a shard already: counted, not solved.
            if !shard.owns(k) {
                stats.regions_other_shards += 1;
                continue;
            }
            if recorded.contains(key) {
                stats.regions_skipped += 1;
                continue;
            }
        }
        let region_t0 = std::time::Instant::now();
        if core
            .iter()
            .all(|c| store.manifest().chunks[c].reg_pass == pass)
        {
            stats.regions_skipped += 1;
            if !progress(k + 1, total) {
                stats.interrupted = true;
                break;
            }
            continue;
        }
        let lo = [0, 1, 2].map(|a| key[a] * r * cb - halo);
        let hi = [0, 1, 2].map(|a| (key[a] + 1) * r * cb - 1 + halo);
        let mut layer = Layer::new(store.grid());
        let mut gathered: Vec<BlockIndex> = Vec::new();
        let mut core_blocks: BTreeMap<ChunkIndex, Vec<BlockIndex>> = BTreeMap::new();
        // The core chunks' files as read, whose unchanged parts the rewrite copies.
        let mut core_files: BTreeMap<ChunkIndex, ObjectBytes> = BTreeMap::new();
        let c_lo = [0, 1, 2].map(|a| key[a] * r - reach);
        let c_hi = [0, 1, 2].map(|a| key[a] * r + r - 1 + reach);
        for cz in c_lo[2]..=c_hi[2] {
            for cy in c_lo[1]..=c_hi[1] {
                for cx in c_lo[0]..=c_hi[0] {
                    let c = ChunkIndex([cx, cy, cz]);
                    let Some((d, file)) = store.read_chunk_bytes(c)? else {
                        continue;
                    };
                    let is_core = region_of(c, r) == *key;
                    if is_core {
                        core_files.insert(c, file);
                    }
                    for (b, block) in d.blocks {
                        if (0..3).all(|a| b.0[a] >= lo[a] && b.0[a] <= hi[a]) {
                            if is_core {
                                core_blocks.entry(c).or_default().push(b);
                            }
                            gathered.push(b);
                            layer.insert(b, block);
                        }
                    }
                }
            }
            let bytes = gathered.len() as u64 * RegionCosts::of(false).per_block;
            if bytes > options.budget_bytes {
                return Err(region_over_budget(*key, halo, bytes, options.budget_bytes));
            }
        }
        let bytes = gathered.len() as u64 * RegionCosts::of(false).per_block;
        stats.peak_region_bytes = stats.peak_region_bytes.max(bytes);
        let mut problem = TvProblem::gather(&layer, &gathered);
        problem.limit_updates_to_reach(
            (
                [0, 1, 2].map(|a| key[a] * r * cb),
                [0, 1, 2].map(|a| (key[a] + 1) * r * cb - 1),
            ),
            params.iterations,
        );
        solve(&mut problem, params)?;
        let core_list: Vec<BlockIndex> = core_blocks.values().flatten().copied().collect();
        problem.scatter(&mut layer, &core_list);
        stats.solved_blocks += problem.blocks().len();
        let region_solved = problem.blocks().len() as u64;
        drop(problem);
        if let Mode::Shard {
            shard,
            plan,
            key: plan_key,
            seqs,
            ..
        } = mode
        {
            let writer = store.writer();
            let mut files = Vec::new();
            let mut omega = 0u64;
            for (c, blocks) in &core_blocks {
                let refs: Vec<(BlockIndex, &Block)> = blocks
                    .iter()
                    .map(|b| (*b, layer.get(b).expect("gathered block")))
                    .collect();
                let w = writer.write_once(*c, seqs[c], &refs, pass, core_files.get(c))?;
                omega += w.entry.observed_voxels as u64;
                stats.core_blocks += refs.len();
                files.push(shards::RecordedFile {
                    chunk: c.0,
                    file_seq: w.entry.file_seq,
                    file_bytes: w.entry.file_bytes,
                    block_count: w.entry.block_count,
                    observed_voxels: w.entry.observed_voxels,
                    flags: w.entry.flags,
                    payload_crc32: w.entry.payload_crc32,
                });
            }
            stats.core_omega_voxels += omega;
            let holder = crate::map::lock::LockHolder::current();
            shards::write_record(
                &**store.files(),
                *plan_key,
                &shards::RegionRecord {
                    format: shards::RECORD_FORMAT.into(),
                    version: 1,
                    key: plan.key.clone(),
                    region: *key,
                    pass,
                    files,
                    solved_blocks: region_solved,
                    omega_voxels: omega,
                    seconds: region_t0.elapsed().as_secs_f64(),
                    shard: shard.to_string(),
                    host: holder.host,
                    pid: holder.pid,
                },
            )?;
            stats.regions += 1;
            if !progress(k + 1, total) {
                stats.interrupted = k + 1 < total;
                break;
            }
            continue;
        }
        for (c, blocks) in &core_blocks {
            let refs: Vec<(BlockIndex, &Block)> = blocks
                .iter()
                .map(|b| (*b, layer.get(b).expect("gathered block")))
                .collect();
            stats.core_omega_voxels += refs
                .iter()
                .map(|(_, b)| b.observed_count() as u64)
                .sum::<u64>();
            stats.core_blocks += refs.len();
            match core_files.get(c) {
                Some(previous) => store.rewrite_chunk(*c, &refs, pass, previous)?,
                None => store.write_chunk(*c, &refs, pass)?,
            }
        }
        store.commit()?;
        stats.regions += 1;
        if !progress(k + 1, total) {
            stats.interrupted = k + 1 < total;
            break;
        }
    }
    Ok(stats)
}
