//! `denser repair`: rebuilds a lost, unreadable or rolled-back manifest from the chunk files'
//! self-describing headers, keeping each chunk's intact version of the latest commit and reporting
//! what it could not keep. Maps in a directory or on an object store.

use super::Outcome;
use anyhow::{Context, Result};
use denser::map::repair::RepairReport;
use denser::map::MapLocation;
use std::fmt;

#[derive(clap::Args)]
pub(crate) struct Args {
    /// The map (a directory or s3://bucket/prefix) whose manifest is lost, unreadable or older
    /// than its last commit.
    dir: MapLocation,
    #[arg(long, help = super::help::JSON)]
    json: bool,
}

struct Repaired {
    dir: MapLocation,
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
            "repaired {}: new manifest from each chunk's intact version of the latest commit: {} chunks, {} blocks ({} in Ω), from {} chunk files",
            self.dir,
            r.chunks,
            r.blocks,
            r.observed_voxels,
            r.files_examined
        )?;
        if let Some(p) = &r.unreadable_manifest_moved_to {
            writeln!(f, "  the old manifest was moved to {}", p.display())?;
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
        writeln!(f, "  regularization: {}", r.passes.describe())?;
        match r.frames_committed {
            Some(n) => writeln!(
                f,
                "  fusion progress: {n} frames committed (from the commit mark); `reconstruct --map` resumes after them"
            ),
            None => writeln!(
                f,
                "  fusion progress was in the lost manifest: `reconstruct --map` cannot resume this map; regularize, export and inspect work"
            ),
        }
    }
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    let report = denser::map::repair::repair_at(&a.dir)
        .with_context(|| format!("repairing map {}", a.dir))?;
    Ok(Box::new(Repaired {
        dir: a.dir,
        report,
        json: a.json,
    }))
}
