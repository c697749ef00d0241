//! `denser regularize`: re-regularise a stored map region by region within a memory budget
//! (seam-free, resumable), on the device `--device` chooses.

use super::reconstruct::RegularizeLine;
use super::{mib, BudgetArgs, DeviceArgs, Outcome, TvArgs};
use anyhow::{Context, Result};
use denser::reconstruct::{ReconstructionConfig, Reconstructor, RegularizeOutcome};
use denser::tiles::store::MapStore;
use denser::tiles::PagedStore;
use std::fmt;
use std::path::PathBuf;

#[derive(clap::Args)]
pub(crate) struct Args {
    /// Map directory.
    dir: PathBuf,
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
            "regularisation pass {} (λ {}, {} iterations, halo {} blocks): {} regions solved, {} already done; {} blocks written, {} solved with halos ({:.2}×)",
            s.pass,
            self.lambda,
            s.iterations,
            s.halo_blocks,
            s.regions,
            s.regions_skipped,
            s.blocks,
            s.solved_blocks,
            s.solved_blocks as f64 / s.blocks.max(1) as f64
        )?;
        write!(
            f,
            "{}",
            RegularizeLine(&self.outcome, &self.device, &self.timings)
        )?;
        writeln!(
            f,
            "{:.2} s per million Ω voxels; largest region ≈ {} MiB; peak RSS {:.0} MiB",
            self.outcome.seconds / (s.omega_voxels.max(1) as f64 / 1e6),
            s.peak_region_bytes >> 20,
            mib(self.peak_rss_bytes.unwrap_or(0))
        )
    }
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    let backend = a.device.backend()?;
    let store =
        MapStore::open(&a.dir).with_context(|| format!("opening map {}", a.dir.display()))?;
    let grid = store.grid();
    let mut config = ReconstructionConfig::paper(grid.voxel_size_m);
    config.grid = grid;
    config.tv = a.tv.params(grid.voxel_size_m);
    let device = backend.device_name();
    let mut rec = Reconstructor::with_store(
        config,
        Box::new(PagedStore::stored(store, a.budget.regional())),
        backend,
        0,
    )?;
    let bar = denser::progress::bar(0, "regularising");
    let outcome = rec
        .regularize_with_progress(&mut |done, total| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
            true
        })
        .with_context(|| format!("regularising {}", a.dir.display()))?;
    bar.finish_and_clear();
    Ok(Box::new(Regularized {
        outcome,
        device,
        lambda: config.tv.lambda,
        timings: *rec.timings(),
        peak_rss_bytes: denser::eval::peak_rss_bytes(),
    }))
}
