//! `denser repair`: rebuilds a lost or unreadable manifest from the chunk files' self-describing
//! headers, keeping the newest intact version of each chunk and reporting what it could not keep.

use super::Outcome;
use anyhow::{Context, Result};
use denser::map::repair::RepairReport;
use std::fmt;
use std::path::PathBuf;

#[derive(clap::Args)]
pub(crate) struct Args {
    /// Map directory whose manifest is lost or unreadable.
    dir: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

struct Repaired {
    dir: PathBuf,
    report: RepairReport,
    json: bool,
}

impl fmt::Display for Repaired {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let r = &self.report;
        if self.json {
            let text = serde_json::to_string_pretty(r).map_err(|_| fmt::Error)?;
            return writeln!(f, "{text}");
        }
        writeln!(
            f,
            "repaired {}: new manifest from the newest intact version of each chunk: {} chunks, {} blocks ({} in Ω), from {} chunk files",
            self.dir.display(),
            r.chunks,
            r.blocks,
            r.observed_voxels,
            r.files_examined
        )?;
        if let Some(p) = &r.unreadable_manifest_moved_to {
            writeln!(f, "  the unreadable manifest was moved to {}", p.display())?;
        }
        for l in &r.older_versions_used {
            writeln!(f, "  older version: {l}")?;
        }
        for l in &r.not_kept {
            writeln!(f, "  not kept: {l}")?;
        }
        for l in &r.notes {
            writeln!(f, "  note: {l}")?;
        }
        writeln!(f, "  regularisation: {}", r.passes.describe())?;
        writeln!(
            f,
            "  fusion progress was in the lost manifest: `reconstruct --map` cannot resume this map; regularize, export and inspect work"
        )
    }
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    let report = denser::map::repair::repair(&a.dir)
        .with_context(|| format!("repairing map {}", a.dir.display()))?;
    Ok(Box::new(Repaired {
        dir: a.dir,
        report,
        json: a.json,
    }))
}
