//! `denser regularize`: re-regularize a stored map region by region within a memory budget
//! (seam-free, resumable), on the device `--device` chooses; with `--shard I/N` only this
//! process's share of the regions, recorded for the next plain run to adopt (array jobs).

use super::reconstruct::RegularizeLine;
use super::{mib, BudgetArgs, DeviceArgs, Outcome, TvArgs};
use anyhow::{Context, Result};
use denser::map::store::MapStore;
use denser::map::MapLocation;
use denser::outofcore::regional::{regularize_shard, MapRegularizeStats};
use denser::outofcore::shards::Shard;
use denser::outofcore::PagedStore;
use denser::reconstruct::{ReconstructionConfig, Reconstructor, RegularizeOutcome};
use denser::regularize::TvSolver;
use std::fmt;

#[derive(clap::Args)]
pub(crate) struct Args {
    /// Map directory or s3://bucket/prefix.
    #[arg(value_name = "MAP")]
    dir: MapLocation,
    #[arg(long, value_name = "I/N", help = super::help::SHARD)]
    shard: Option<String>,
    #[command(flatten)]
    tv: TvArgs,
    #[command(flatten)]
    budget: BudgetArgs,
    #[command(flatten)]
    device: DeviceArgs,
}

struct Regularized {
    outcome: RegularizeOutcome,
    device: String,
    lambda: f32,
    timings: denser::reconstruct::StageTimings,
    peak_rss_bytes: Option<u64>,
}

impl fmt::Display for Regularized {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = &self.outcome.summary;
        writeln!(
            f,
            "regularization pass {} (λ {}, {} iterations in {} {}, regions of {}³ chunks, halo {} blocks): {} regions solved, {} adopted from shards, {} already done; {} blocks written, {} solved with halos ({:.2}×)",
            s.pass,
            self.lambda,
            s.iterations,
            s.sweeps,
            if s.sweeps == 1 { "sweep" } else { "sweeps" },
            s.region_chunks,
            s.halo_blocks,
            s.regions,
            s.regions_adopted,
            s.regions_skipped.saturating_sub(s.regions_adopted),
            s.blocks,
            s.solved_blocks,
            s.solved_blocks as f64 / s.blocks.max(1) as f64
        )?;
        write!(
            f,
            "{}",
            RegularizeLine(&self.outcome, &self.device, &self.timings)
        )?;
        let scratch = match s.scratch_bytes {
            0 => String::new(),
            b => format!("; sweep state on disk ≈ {:.0} MiB at its fullest", mib(b)),
        };
        writeln!(
            f,
            "{:.2} s per million Ω voxels; largest region ≈ {} MiB; peak RSS {:.0} MiB{scratch}",
            self.outcome.seconds / (s.omega_voxels.max(1) as f64 / 1e6),
            s.peak_region_bytes >> 20,
            mib(self.peak_rss_bytes.unwrap_or(0))
        )
    }
}

struct ShardDone {
    map: MapLocation,
    shard: Shard,
    stats: MapRegularizeStats,
    lambda: f32,
    iterations: u32,
}

impl fmt::Display for ShardDone {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = &self.stats;
        writeln!(
            f,
            "shard {} of {} (pass {}, λ {}, {} iterations, halo {} blocks): {} regions solved, {} recorded or committed before, {} left to other shards; {} blocks written ({} Ω voxels), {} solved with halos, in {:.1} s",
            self.shard,
            self.map,
            s.pass,
            self.lambda,
            self.iterations,
            s.halo_blocks,
            s.regions,
            s.regions_skipped,
            s.regions_other_shards,
            s.core_blocks,
            s.core_omega_voxels,
            s.solved_blocks,
            s.seconds
        )?;
        writeln!(
            f,
            "nothing committed: run `denser regularize {}` (same parameters) once every shard has finished",
            self.map
        )
    }
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    // Freed region arrays are reused by the next region; the pass trims above the budget.
    denser::memory::keep_freed_memory();
    let mut backend = a.device.backend()?;
    if let Some(spec) = &a.shard {
        let shard = Shard::parse(spec)?;
        let mut store = MapStore::open_read_only_at(&a.dir)
            .with_context(|| format!("opening map {}", a.dir))?;
        store.set_cache_budget(a.budget.memory_budget / 4);
        let tv = a.tv.params(store.grid().voxel_size_m);
        let bar = denser::progress::bar(0, "regularizing");
        let stats = regularize_shard(
            &mut store,
            &tv,
            &a.budget.regional()?,
            shard,
            |done, total| {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
                true
            },
            |p, tv| backend.solve(p, tv),
        )
        .with_context(|| format!("regularizing shard {shard} of {}", a.dir))?;
        bar.finish_and_clear();
        return Ok(Box::new(ShardDone {
            map: a.dir,
            shard,
            stats,
            lambda: tv.lambda,
            iterations: tv.iterations,
        }));
    }
    let mut store = MapStore::open_at(&a.dir).with_context(|| format!("opening map {}", a.dir))?;
    store.set_cache_budget(a.budget.memory_budget / 4);
    let grid = store.grid();
    let mut config = ReconstructionConfig::paper(grid.voxel_size_m);
    config.grid = grid;
    config.tv = a.tv.params(grid.voxel_size_m);
    let device = backend.device_name();
    let mut rec = Reconstructor::with_store(
        config,
        Box::new(PagedStore::stored(
            store,
            a.budget.regional()?,
            denser::export::write_map_surface,
        )),
        backend,
        0,
    )?;
    let bar = denser::progress::bar(0, "regularizing");
    let outcome = rec
        .regularize_with_progress(&mut |done, total| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
            true
        })
        .with_context(|| format!("regularizing {}", a.dir))?;
    bar.finish_and_clear();
    Ok(Box::new(Regularized {
        outcome,
        device,
        lambda: config.tv.lambda,
        timings: *rec.timings(),
        peak_rss_bytes: denser::memory::peak_rss_bytes(),
    }))
}
