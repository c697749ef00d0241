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
use super::sweep_state::SweepProgress;
use crate::error::{Error, Result};
use crate::map::files::MapFiles;
use crate::map::layout::SWEEPS_AREA;
use crate::map::store::MapStore;
use crate::map::ChunkIndex;
use crate::regularize::{RegionPlan, TvParams, TvProblem};
use region::{
    gather_states, problem_from_gathered, write_chunks, write_initial_states, write_states,
};
use std::collections::BTreeMap;

mod region;

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
/// Bytes of `sweeps/` at its fullest for `manifest`'s map: two parities of every chunk's state
/// file (layout in `formats/sweep-state.md`: 40 bytes of header, 24 of index and a 64-byte Ω
/// mask per block, 23 bytes per Ω voxel), plus the progress record. The state is 23 bytes per
/// Ω voxel against the chunk files' 1–2 bytes per voxel, so this is some 15–30 times the map.
pub fn scratch_bytes(manifest: &crate::map::manifest::Manifest) -> u64 {
    let state: u64 = manifest
        .chunks
        .values()
        .map(|e| 40 + 88 * e.block_count as u64 + 23 * e.observed_voxels as u64)
        .sum();
    2 * state + 4096
}

/// Refuses a swept pass up front when a local map's file system has less free space than its
/// scratch state needs ([`scratch_bytes`]), naming both figures, instead of failing on a full
/// disk part-way (nothing of the map is lost either way; this saves the hours).
fn check_scratch_space(store: &MapStore) -> Result<()> {
    let crate::map::location::MapLocation::Dir(dir) = store.files().location() else {
        return Ok(());
    };
    let need = scratch_bytes(store.manifest());
    let Some(free) = free_bytes(dir) else {
        return Ok(());
    };
    if free < need {
        let mib = |b: u64| b.div_ceil(1 << 20);
        return Err(crate::Error::bad_input(
            dir,
            format!(
                "a swept regularization pass keeps its solver state under sweeps/: about {} MiB for this map ({} MiB of chunk files), but its file system has {} MiB free; free space there, or give a --memory-budget large enough for regions with exact halos (no scratch state)",
                mib(need),
                mib(store.manifest().chunks.values().map(|e| e.file_bytes).sum()),
                mib(free)
            ),
        ));
    }
    Ok(())
}

/// Free bytes for an unprivileged writer on the file system holding `dir`.
fn free_bytes(dir: &std::path::Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c` is a NUL-terminated path and `st` a writable statvfs.
    (unsafe { libc::statvfs(c.as_ptr(), &mut st) } == 0)
        .then(|| st.f_bavail as u64 * st.f_frsize as u64)
}

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
            check_scratch_space(store)?;
            (0, 0)
        }
    };
    stats.scratch_bytes = scratch_bytes(store.manifest());
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
                write_initial_states(store, key, core)?;
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
