//! `denser merge`: maps of the same grid and world frame (drives, or slices of one drive fused
//! on different machines) combined chunk by chunk into a new map: weighted TSDF and colour
//! average, Ω as the union, `u` dropped (regularize the result).

use super::{mib, parse_bytes, Outcome};
use anyhow::{Context, Result};
use denser::map::MapLocation;
use denser::outofcore::merge::{merge, MergeStats};
use std::fmt;

#[derive(clap::Args)]
pub(crate) struct Args {
    /// Input maps (directories or s3://bucket/prefix), same voxel size, μ and chunk edge.
    #[arg(value_name = "MAP", required = true, num_args = 1..)]
    inputs: Vec<MapLocation>,
    #[arg(long, value_name = "MAP", help = super::help::OUT)]
    out: MapLocation,
    #[arg(long, default_value = "1GiB", value_parser = parse_bytes, help = super::help::MEMORY_BUDGET)]
    memory_budget: u64,
}

struct Merged {
    out: MapLocation,
    stats: MergeStats,
}

impl fmt::Display for Merged {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = &self.stats;
        writeln!(
            f,
            "merged {} maps into {}: {} chunks, {} blocks ({} in more than one input, averaged), {} voxels in Ω, in {:.1} s; largest chunk working set {:.1} MiB",
            s.inputs,
            self.out,
            s.chunks,
            s.blocks,
            s.shared_blocks,
            s.observed_voxels,
            s.seconds,
            mib(s.peak_chunk_bytes)
        )?;
        if s.chunks_resumed > 0 {
            writeln!(
                f,
                "resumed a stopped merge: {} chunks it had committed were kept",
                s.chunks_resumed
            )?;
        }
        writeln!(
            f,
            "not regularized: run `denser regularize {}` (or shard it with --shard I/N)",
            self.out
        )
    }
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    let stats = merge(&a.inputs, &a.out, a.memory_budget)
        .with_context(|| format!("merging into {}", a.out))?;
    Ok(Box::new(Merged { out: a.out, stats }))
}
