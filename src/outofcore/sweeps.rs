//! Swept regional regularization: every region `K` iterations at a time, the solver state kept
//! in the map's store between sweeps, so a region needs a halo of `K + 1` voxels (one block at
//! `K = 7`, two at the default `K = 15`) instead of `iterations + 1`.
//!
//! Why it equals the global solve: one Chambolle–Pock iteration changes a voxel from values at
//! most one voxel away (see [`RegionPlan::exact_halo_blocks`]), and only the gathered set's outer
//! layer is wrong from the start (its links to ungathered neighbours are cut). A region that
//! starts sweep `s` from the state (u, ū, p) every voxel had after sweep `s − 1` therefore ends
//! it with its own voxels exactly in the global solve's state after sweep `s`, provided every
//! region of sweep `s` reads the state of sweep `s − 1`: sweep `s` writes parity `s mod 2`
//! (`sweeps/sP/…`) and reads the other, never what a neighbour still reads. The arithmetic per
//! voxel does not depend on which blocks are gathered, so the result is bit-identical to the
//! global solve before quantisation (tested).
//!
//! Steps of a pass, each over every region in order: step 0 writes each chunk's initial state
//! from its chunk file (u = ū = f, p = 0); steps 1 … S−1 run sweeps of `K` iterations and write
//! state; step S runs the last sweep (the remaining iterations) and writes the region's chunk
//! files with `u`, committing the manifest per region exactly as the exact-halo pass does (the
//! last complete pass stays readable until the new one is whole). A progress record
//! (`sweeps/progress.dsp`) is written at the end of each step and at most once a second within
//! one, so a killed run resumes at most a second of regions before where it stopped (redoing a
//! region of a step rewrites the same state from the same input); a record of another pass,
//! parameters or chunk table is discarded with the state. The state files are removed when the
//! pass completes.
//! Layouts: `formats/sweep-state.md`.

use super::region_plan::{
    region_of, region_over_budget, MapRegularizeStats, SWEEP_BYTES_PER_BLOCK,
    SWEEP_BYTES_PER_CORE_BLOCK, SWEEP_BYTES_PER_CORE_OMEGA_VOXEL, SWEEP_BYTES_PER_OMEGA_VOXEL,
};
use super::sweep_state::{
    decode_block_into, decode_state_index, encode_dense_record, encode_state, encode_state_with,
    BlockState, DenseBlock, StateHeader, SweepProgress, STATE_BYTES_PER_OMEGA_VOXEL,
    STATE_MASK_BYTES,
};
use crate::error::{Error, Result};
use crate::grid::{decode_tsdf, Block, BlockIndex, Layer, VOXELS_PER_BLOCK};
use crate::map::files::MapFiles;
use crate::map::files::ObjectBytes;
use crate::map::layout::SWEEPS_AREA;
use crate::map::store::MapStore;
use crate::map::ChunkIndex;
use crate::regularize::{RegionPlan, TvParams, TvProblem};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// The progress record's name, in the area the engine reserves for swept passes.
fn progress_file() -> String {
    format!("{SWEEPS_AREA}/progress.dsp")
}
/// Least time between two writes of the progress record within a step.
const PROGRESS_INTERVAL: std::time::Duration = std::time::Duration::from_secs(1);
/// Iterations per sweep by default: a halo of `K + 1 = 16` voxels, two blocks. Measured against
/// 7 (one block, 15 sweeps) and 23 (three blocks, 5 sweeps) on a 200 m street: 1.8–2.0× the
/// global solve's CPU time against 2.5× and 2.6× (`docs/bench/regularize.md`; measured before
/// halo rings stopped updating early, which favours wider halos: not measured again since).
pub const DEFAULT_SWEEP_ITERATIONS: u32 = 15;

/// Writes a state file of parity `step mod 2` over the one of two steps before, in place: not
/// atomic and not fsynced on local disks. Safe because nothing reads it before the step that
/// writes it is over: a region redone after a kill rewrites it whole from the other parity,
/// which that step never touches, and a file torn by a power loss fails its CRC (the sweeps then
/// start again). In place rather than through a new file and a rename: creating and renaming
/// ~2000 files per pass was ~7 % of its CPU time (`docs/bench/regularize.md`).
fn write_state_file(files: &dyn MapFiles, name: &str, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let Some(dir) = files.location().as_dir() else {
        return files.write(name, bytes);
    };
    let path = dir.join(name);
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(|e| Error::io(&path, e))?;
    f.write_all(bytes)
        .and_then(|()| f.set_len(bytes.len() as u64))
        .map_err(|e| Error::io(&path, e))
}

/// Writes scratch state: atomically (temporary name, rename) but not fsynced on local disks —
/// a killed process leaves whole files, and after a power loss a torn one fails its CRC.
fn write_scratch(files: &dyn MapFiles, name: &str, bytes: &[u8]) -> Result<()> {
    let Some(dir) = files.location().as_dir() else {
        return files.write(name, bytes);
    };
    let path = dir.join(name);
    let tmp = path.with_extension("tmp");
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    std::fs::write(&tmp, bytes).map_err(|e| Error::io(&tmp, e))?;
    std::fs::rename(&tmp, &path).map_err(|e| Error::io(&path, e))
}

fn state_name(parity: u32, c: ChunkIndex) -> String {
    let [x, y, z] = c.0;
    format!("{SWEEPS_AREA}/s{parity}/c_{x}_{y}_{z}.dsws")
}

fn fnv(h: &mut u64, bytes: &[u8]) {
    for b in bytes {
        *h ^= *b as u64;
        *h = h.wrapping_mul(0x100_0000_01b3);
    }
}

/// The key of a swept pass: map, pass, parameters, region edge and iterations per sweep.
fn pass_key(store: &MapStore, pass: u32, params: &TvParams, region_chunks: u32, k: u32) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    fnv(&mut h, b"sweeps");
    fnv(&mut h, &store.manifest().header.map_id.to_le_bytes());
    for v in [
        pass,
        params.lambda.to_bits(),
        params.sigma.to_bits(),
        params.tau.to_bits(),
        params.theta.to_bits(),
        params.iterations,
        region_chunks,
        k,
    ] {
        fnv(&mut h, &v.to_le_bytes());
    }
    h
}

/// Removes every object under `sweeps/`.
pub fn remove_state(files: &dyn MapFiles) -> Result<usize> {
    let listed = files.list_recursive(SWEEPS_AREA)?;
    for o in &listed {
        files.delete(&format!("{SWEEPS_AREA}/{}", o.name))?;
    }
    Ok(listed.len())
}

/// Where a swept pass resumes: the progress record if it belongs to this pass and chunk table.
fn resume_point(
    store: &MapStore,
    key: u64,
    pass: u32,
    last_step: u32,
) -> Result<Option<SweepProgress>> {
    let files = store.files();
    let Some(bytes) = files.read(&progress_file())? else {
        return Ok(None);
    };
    let rec = SweepProgress::decode(&files.path(&progress_file()), &bytes)?;
    if rec.key != key || rec.chunks.len() != store.manifest().chunks.len() {
        return Ok(None);
    }
    // A chunk may only have changed by the last step's own writes.
    let same = rec.chunks.iter().all(|(c, seq)| {
        store
            .manifest()
            .chunks
            .get(&ChunkIndex(*c))
            .is_some_and(|e| {
                e.file_seq == *seq || (rec.steps_done == last_step && e.reg_pass == pass)
            })
    });
    Ok(same.then_some(rec))
}

/// One block's initial state: u = ū = f on Ω, p = 0.
fn initial_state(block: &Block) -> BlockState {
    let mut s = BlockState::default();
    for i in 0..VOXELS_PER_BLOCK {
        if block.omega(i) {
            s.omega[i / 64] |= 1 << (i % 64);
            s.tsdf.push(block.tsdf[i]);
            s.weight.push(block.weight(i));
            let f = decode_tsdf(block.tsdf[i]);
            s.u.push(f);
            s.ubar.push(f);
        }
    }
    let n = s.tsdf.len();
    s.p = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    s
}

/// The stored blocks one region of a sweep gathers (its own and its halo's), sorted by index,
/// with the state files their records are in.
struct Gathered {
    files: Vec<(std::path::PathBuf, ObjectBytes)>,
    blocks: Vec<GatheredBlock>,
}

/// One gathered block: where its record is, and whether it is the region's own.
struct GatheredBlock {
    index: BlockIndex,
    file: usize,
    record: std::ops::Range<usize>,
    crc: u32,
    core: bool,
}

impl GatheredBlock {
    /// Its Ω voxels, as its record's length says (checked when it is decoded).
    fn omega_voxels(&self) -> u64 {
        (self.record.len().saturating_sub(STATE_MASK_BYTES) / STATE_BYTES_PER_OMEGA_VOXEL) as u64
    }
}

/// The problem over the gathered blocks, each record decoded straight into the solver's arrays,
/// for `iterations` iterations keeping the blocks in `core` (lowest and highest block index):
/// halo blocks are updated only while they can still reach the core
/// ([`TvProblem::limit_updates_to_reach`]).
fn problem_from_gathered(
    g: &Gathered,
    core: ([i32; 3], [i32; 3]),
    iterations: u32,
) -> Result<TvProblem> {
    let vb = VOXELS_PER_BLOCK;
    let n = g.blocks.len() * vb;
    let [mut f, mut w, mut u, mut ubar] = [(); 4].map(|_| vec![0.0f32; n]);
    let mut omega = vec![false; n];
    let mut p = vec![0.0f32; 3 * n];
    let (px, rest) = p.split_at_mut(n);
    let (py, pz) = rest.split_at_mut(n);
    // Decoded on a worker of the pool, so that the loop's tasks start there rather than with a
    // wake-up from outside (the arrays stay allocated by the calling thread).
    rayon::scope(|_| {
        f.par_chunks_mut(vb)
            .zip(w.par_chunks_mut(vb))
            .zip(omega.par_chunks_mut(vb))
            .zip(u.par_chunks_mut(vb))
            .zip(ubar.par_chunks_mut(vb))
            .zip(px.par_chunks_mut(vb))
            .zip(py.par_chunks_mut(vb))
            .zip(pz.par_chunks_mut(vb))
            .zip(g.blocks.par_iter())
            .try_for_each(|((((((((f, w), omega), u), ubar), px), py), pz), b)| {
                let (path, bytes) = &g.files[b.file];
                let out = DenseBlock {
                    f,
                    w,
                    omega,
                    u,
                    ubar,
                    p: [px, py, pz],
                };
                decode_block_into(path, bytes, (&b.index, &b.record, b.crc), out)
            })
    })?;
    let blocks = g.blocks.iter().map(|b| b.index).collect();
    let mut problem = TvProblem::from_state(blocks, [f, w, u, ubar], omega, p);
    problem.limit_updates_to_reach(core, iterations);
    Ok(problem)
}

/// Appends to `out` the state record of the problem's block slot `slot`.
fn encode_slot(problem: &TvProblem, slot: usize, out: &mut Vec<u8>) {
    let vb = VOXELS_PER_BLOCK;
    let (u, ubar, p) = problem.state();
    let n = u.len();
    let r = slot * vb..(slot + 1) * vb;
    let mask = &problem.masks()[r.clone()];
    encode_dense_record(
        out,
        |i| mask[i] & TvProblem::OMEGA_BIT != 0,
        [
            &problem.f[r.clone()],
            &problem.w[r.clone()],
            &u[r.clone()],
            &ubar[r.clone()],
        ],
        [0, 1, 2].map(|d| &p[d * n + r.start..d * n + r.end]),
    );
}

/// What [`regularize_swept`] needs beside the store.
pub(super) struct SweptPass<'a> {
    /// The solve's parameters (all iterations).
    pub params: &'a TvParams,
    /// Region edge, chunks.
    pub region_chunks: u32,
    /// Iterations per sweep.
    pub sweep_iterations: u32,
    /// Working-memory bound of one region, bytes.
    pub budget_bytes: u64,
    /// The pass number (begun by the caller).
    pub pass: u32,
}

/// Runs pass `run.pass` as sweeps (see the module documentation). `solve(problem, params)` runs
/// `params.iterations` iterations from the problem's state.
pub(super) fn regularize_swept(
    store: &mut MapStore,
    run: &SweptPass,
    progress: &mut dyn FnMut(usize, usize) -> bool,
    solve: &mut dyn FnMut(&mut TvProblem, &TvParams) -> Result<()>,
) -> Result<MapRegularizeStats> {
    let params = run.params;
    let k_iter = run.sweep_iterations.clamp(1, params.iterations.max(1));
    let sweeps = params.iterations.div_ceil(k_iter);
    let cb = store.chunk_blocks() as i32;
    let r = run.region_chunks as i32;
    let halo = RegionPlan::exact_halo_blocks(k_iter);
    let reach = (halo + cb - 1) / cb;
    let pass = run.pass;
    let key = pass_key(store, pass, params, run.region_chunks, k_iter);
    let mut stats = MapRegularizeStats {
        pass,
        halo_blocks: halo,
        sweeps,
        ..Default::default()
    };
    let mut regions: BTreeMap<[i32; 3], Vec<ChunkIndex>> = BTreeMap::new();
    for c in store.chunk_indices() {
        regions.entry(region_of(c, r)).or_default().push(c);
    }
    let files = store.files().clone();
    let resume = resume_point(store, key, pass, sweeps)?;
    // A resumed run whose state cannot be read (a file torn by a power loss: state is not
    // fsynced) starts the sweeps again, once.
    let mut may_restart = resume.is_some();
    let (mut step, mut skip) = match resume {
        Some(rec) => {
            tracing::info!(
                "{}: resuming the swept pass at step {} of {}, region {} of {}",
                store.dir().display(),
                rec.steps_done,
                sweeps,
                rec.regions_done,
                regions.len()
            );
            (rec.steps_done, rec.regions_done as usize)
        }
        None => {
            remove_state(&*files)?;
            (0, 0)
        }
    };
    let chunks: Vec<([i32; 3], u64)> = store
        .manifest()
        .chunks
        .iter()
        .map(|(c, e)| (c.0, e.file_seq))
        .collect();
    let record = |steps_done: u32, regions_done: usize| -> Result<()> {
        let rec = SweepProgress {
            key,
            chunks: chunks.clone(),
            steps_done,
            regions_done: regions_done as u32,
        };
        write_scratch(&*files, &progress_file(), &rec.encode())
    };
    let total = regions.len() * (sweeps as usize + 1);
    let mut block_iterations = 0u64;
    // Freed region arrays stay in the heap for the next region, unless that passes the budget.
    let mut trim =
        crate::memory::TrimAbove::new(crate::memory::budget_for_data_bytes(run.budget_bytes));
    let mut last_record = std::time::Instant::now();
    while step <= sweeps {
        let mut restart = false;
        for (k, (rkey, core)) in regions.iter().enumerate().skip(skip) {
            trim.check();
            let t0 = std::time::Instant::now();
            if step == 0 {
                for c in core {
                    let Some(d) = store.read_chunk(*c)? else {
                        continue;
                    };
                    let states: Vec<(BlockIndex, BlockState)> = d
                        .blocks
                        .par_iter()
                        .map(|(b, block)| (*b, initial_state(block)))
                        .collect();
                    let h = StateHeader {
                        key,
                        chunk: c.0,
                        step: 0,
                        block_count: states.len() as u32,
                    };
                    write_state_file(&*files, &state_name(0, *c), &encode_state(&h, &states))?;
                }
            } else if step == sweeps
                && core
                    .iter()
                    .all(|c| store.manifest().chunks[c].reg_pass == pass)
            {
                stats.regions_skipped += 1;
            } else {
                let iterations = if step < sweeps {
                    k_iter
                } else {
                    params.iterations - k_iter * (sweeps - 1)
                };
                let lo = [0, 1, 2].map(|a| rkey[a] * r * cb - halo);
                let hi = [0, 1, 2].map(|a| (rkey[a] + 1) * r * cb - 1 + halo);
                let gathered = gather_states(
                    store,
                    key,
                    step,
                    [0, 1, 2].map(|a| rkey[a] * r - reach),
                    [0, 1, 2].map(|a| rkey[a] * r + r - 1 + reach),
                    (lo, hi),
                    |c| region_of(c, r) == *rkey,
                );
                // Gathered, checked against the budget and decoded; a state file that cannot be
                // read (torn by a power loss) restarts the sweeps once.
                let built = gathered.and_then(|g| {
                    // The plan's bound ([`super::regional::RegionCosts`]) with the real counts.
                    let mut bytes = 0u64;
                    for b in &g.blocks {
                        let omega = b.omega_voxels();
                        bytes += SWEEP_BYTES_PER_BLOCK + omega * SWEEP_BYTES_PER_OMEGA_VOXEL;
                        if b.core {
                            bytes += SWEEP_BYTES_PER_CORE_BLOCK
                                + omega * SWEEP_BYTES_PER_CORE_OMEGA_VOXEL;
                        }
                    }
                    if bytes > run.budget_bytes {
                        return Err(region_over_budget(*rkey, halo, bytes, run.budget_bytes));
                    }
                    stats.peak_region_bytes = stats.peak_region_bytes.max(bytes);
                    trim.make_room(bytes);
                    let core = (
                        [0, 1, 2].map(|a| rkey[a] * r * cb),
                        [0, 1, 2].map(|a| (rkey[a] + 1) * r * cb - 1),
                    );
                    let problem = problem_from_gathered(&g, core, iterations)?;
                    Ok((g.blocks, problem))
                });
                let (blocks, mut problem) = match built {
                    Err(e @ Error::BadInput { .. }) if may_restart => {
                        tracing::warn!("{e}; starting the sweeps of pass {pass} again");
                        restart = true;
                        break;
                    }
                    other => other?,
                };
                solve(
                    &mut problem,
                    &TvParams {
                        iterations,
                        ..*params
                    },
                )?;
                block_iterations += blocks.len() as u64 * iterations as u64;
                if step < sweeps {
                    rayon::scope(|_| write_states(&*files, &problem, &blocks, key, step, store))?;
                } else {
                    write_chunks(store, &problem, &blocks, pass, &mut stats)?;
                    store.commit()?;
                    stats.regions += 1;
                }
            }
            // The progress record is rewritten at most every PROGRESS_INTERVAL (and at the end
            // of each step, below): a killed run redoes the regions since, which rewrite the
            // same state from the same input.
            let last = k + 1 == regions.len();
            if last || last_record.elapsed() >= PROGRESS_INTERVAL {
                record(step, k + 1)?;
                last_record = std::time::Instant::now();
            }
            tracing::debug!(
                "step {step}/{sweeps} region {rkey:?}: {:.3} s",
                t0.elapsed().as_secs_f64()
            );
            let done = step as usize * regions.len() + k + 1;
            if !progress(done, total) {
                record(step, k + 1)?;
                stats.interrupted = done < total;
                stats.solved_blocks = (block_iterations / params.iterations.max(1) as u64) as usize;
                return Ok(stats);
            }
        }
        skip = 0;
        if restart {
            may_restart = false;
            remove_state(&*files)?;
            step = 0;
            continue;
        }
        step += 1;
        if step <= sweeps {
            record(step, 0)?;
        }
    }
    stats.solved_blocks = (block_iterations / params.iterations.max(1) as u64) as usize;
    remove_state(&*files)?;
    Ok(stats)
}

/// Indexes the state of step `step − 1` of every stored block in `bounds` (blocks) from the
/// chunks `c_lo ..= c_hi`, marking the blocks of chunks `is_core` says are the region's; the
/// records are decoded by [`problem_from_gathered`].
fn gather_states(
    store: &MapStore,
    key: u64,
    step: u32,
    c_lo: [i32; 3],
    c_hi: [i32; 3],
    bounds: ([i32; 3], [i32; 3]),
    is_core: impl Fn(ChunkIndex) -> bool,
) -> Result<Gathered> {
    let files = store.files();
    let (lo, hi) = bounds;
    let mut out = Gathered {
        files: Vec::new(),
        blocks: Vec::new(),
    };
    for cz in c_lo[2]..=c_hi[2] {
        for cy in c_lo[1]..=c_hi[1] {
            for cx in c_lo[0]..=c_hi[0] {
                let c = ChunkIndex([cx, cy, cz]);
                if !store.contains(c) {
                    continue;
                }
                let name = state_name((step - 1) % 2, c);
                let path = files.path(&name);
                let Some(bytes) = files.read(&name)? else {
                    return Err(Error::bad_input(
                        &path,
                        format!(
                            "the state of step {} is missing (a map changed under a swept pass?); delete {SWEEPS_AREA}/ to restart the pass",
                            step - 1
                        ),
                    ));
                };
                let index = decode_state_index(&path, &bytes)?;
                let h = index.header;
                // Name only what differs (issue 36: a swapped file read "another pass (key K),
                // expected key K").
                let mut differs = Vec::new();
                if h.key != key {
                    differs.push(format!(
                        "it belongs to another pass (key {:016x}, this pass {key:016x})",
                        h.key
                    ));
                }
                if h.chunk != c.0 {
                    differs.push(format!(
                        "it holds chunk {:?}, not {:?} (a file copied from another chunk?)",
                        h.chunk, c.0
                    ));
                }
                if h.step != step - 1 {
                    differs.push(format!(
                        "it is the state after step {}, not {}",
                        h.step,
                        step - 1
                    ));
                }
                if !differs.is_empty() {
                    return Err(Error::bad_input(
                        &path,
                        format!(
                            "not the state this sweep needs: {}; delete {SWEEPS_AREA}/ to restart the pass",
                            differs.join("; ")
                        ),
                    ));
                }
                let core = is_core(c);
                let file = out.files.len();
                out.blocks.extend(
                    index
                        .entries
                        .into_iter()
                        .filter(|(b, _, _)| (0..3).all(|a| b.0[a] >= lo[a] && b.0[a] <= hi[a]))
                        .map(|(index, record, crc)| GatheredBlock {
                            index,
                            file,
                            record,
                            crc,
                            core,
                        }),
                );
                out.files.push((path, bytes));
            }
        }
    }
    out.blocks.sort_unstable_by_key(|b| b.index);
    Ok(out)
}

/// Writes the state of the region's own blocks after step `step`, one file per chunk; the
/// problem's slots are the positions in `blocks`.
fn write_states(
    files: &dyn MapFiles,
    problem: &TvProblem,
    blocks: &[GatheredBlock],
    key: u64,
    step: u32,
    store: &MapStore,
) -> Result<()> {
    let cb = store.chunk_blocks();
    let mut by_chunk: BTreeMap<ChunkIndex, Vec<(BlockIndex, usize, u64)>> = BTreeMap::new();
    for (slot, b) in blocks.iter().enumerate().filter(|(_, b)| b.core) {
        by_chunk
            .entry(ChunkIndex::of_block(b.index, cb))
            .or_default()
            .push((b.index, slot, b.omega_voxels()));
    }
    let encoded: Vec<(ChunkIndex, Vec<u8>)> = by_chunk
        .into_par_iter()
        .map(|(c, list)| {
            let h = StateHeader {
                key,
                chunk: c.0,
                step,
                block_count: list.len() as u32,
            };
            let index: Vec<BlockIndex> = list.iter().map(|(b, _, _)| *b).collect();
            let bytes: u64 = list
                .iter()
                .map(|(_, _, o)| (STATE_MASK_BYTES as u64) + o * STATE_BYTES_PER_OMEGA_VOXEL as u64)
                .sum();
            let file = encode_state_with(&h, &index, bytes as usize, |k, out| {
                encode_slot(problem, list[k].1, out)
            });
            (c, file)
        })
        .collect();
    for (c, bytes) in encoded {
        write_state_file(files, &state_name(step % 2, c), &bytes)?;
    }
    Ok(())
}

/// The last step: the region's chunk files with `u`, written (the caller commits).
fn write_chunks(
    store: &mut MapStore,
    problem: &TvProblem,
    blocks: &[GatheredBlock],
    pass: u32,
    stats: &mut MapRegularizeStats,
) -> Result<()> {
    let cb = store.chunk_blocks();
    let mut chunks: Vec<ChunkIndex> = blocks
        .iter()
        .filter(|b| b.core)
        .map(|b| ChunkIndex::of_block(b.index, cb))
        .collect();
    chunks.dedup();
    chunks.sort_unstable();
    chunks.dedup();
    for c in chunks {
        let Some((d, previous)) = store.read_chunk_bytes(c)? else {
            continue;
        };
        let mut layer = Layer::new(store.grid());
        let list: Vec<BlockIndex> = d.blocks.iter().map(|(b, _)| *b).collect();
        layer.put_blocks(d.blocks);
        problem.scatter(&mut layer, &list);
        let refs: Vec<(BlockIndex, &Block)> = list
            .iter()
            .filter_map(|b| layer.get(b).map(|x| (*b, x)))
            .collect();
        stats.core_omega_voxels += refs
            .iter()
            .map(|(_, b)| b.observed_count() as u64)
            .sum::<u64>();
        stats.core_blocks += refs.len();
        // Only `u` and the block flags change: the other parts keep their compressed frames.
        store.rewrite_chunk(c, &refs, pass, &previous)?;
    }
    Ok(())
}
