//! `denser inspect`: a stored map's chunks, blocks, voxels and bytes, and with `--verify` its
//! checksums (exit 1 when a chunk fails).

use super::{mib, Outcome, Problems};
use anyhow::{Context, Result};
use denser::map::store::MapStore;
use denser::map::MapLocation;
use std::fmt;

#[derive(clap::Args)]
pub(crate) struct Args {
    /// Map directory or s3://bucket/prefix.
    #[arg(value_name = "MAP")]
    dir: MapLocation,
    /// Read every chunk and check its checksums against the manifest.
    #[arg(long)]
    verify: bool,
    #[arg(long, help = super::help::JSON)]
    json: bool,
}

/// An open shard plan as `inspect` reports it.
struct PlanState {
    pass: u32,
    /// Regions recorded by shards.
    recorded: usize,
    /// Regions of the plan.
    regions: u64,
    key: String,
    /// Whether the committing run would adopt them: the plan's key is still the one of the
    /// committed manifest (a stale plan's map changed after its shards read it).
    current: bool,
}

struct Inspected {
    /// Open shard plans.
    shard_plans: Vec<PlanState>,
    dir: MapLocation,
    store: MapStore,
    verified: bool,
    problems: Vec<String>,
    json: bool,
}

/// The map's extent from its chunks' bounds, metres: in the map frame and in the local z-up
/// world frame that LAS, COPC and 3D Tiles exports use (`--bbox` is given in the export's
/// frame). `None` for an empty map.
fn extent_m(store: &MapStore) -> Option<[([f64; 3], [f64; 3]); 2]> {
    use denser::export::{chunk_bounds_m, frame_bounds};
    let z_up = denser::geo::WorldFrame::local_z_up();
    let mut out: Option<[([f64; 3], [f64; 3]); 2]> = None;
    for c in store.chunk_indices() {
        let map = chunk_bounds_m(store, c);
        let world = frame_bounds(&z_up, map.0, map.1);
        let boxes = out.get_or_insert([map, world]);
        for (b, (lo, hi)) in boxes.iter_mut().zip([map, world]) {
            for a in 0..3 {
                b.0[a] = b.0[a].min(lo[a]);
                b.1[a] = b.1[a].max(hi[a]);
            }
        }
    }
    out
}

/// `x a..b, y c..d, z e..f m`.
fn describe_box((lo, hi): ([f64; 3], [f64; 3])) -> String {
    format!(
        "x {:.1}..{:.1}, y {:.1}..{:.1}, z {:.1}..{:.1} m",
        lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]
    )
}

impl fmt::Display for Inspected {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = self.store.summary();
        let extent = extent_m(&self.store);
        let h = self.store.manifest().header;
        let passes = self.store.manifest().pass_status();
        let frames = if h.frames_committed == denser::map::manifest::FRAMES_UNKNOWN {
            "unknown (repaired map: fusion cannot resume)".to_string()
        } else {
            h.frames_committed.to_string()
        };
        if self.json {
            let v = serde_json::json!({
                "summary": s,
                "bytes_per_voxel": s.bytes_per_voxel(),
                "voxel_size_m": h.voxel_size_m,
                "truncation_m": h.truncation_m,
                "chunk_blocks": h.chunk_blocks,
                "generation": h.generation,
                "frames_committed": h.frames_committed,
                "regularization_pass": h.reg_pass,
                "regularization": passes,
                "regularization_status": passes.describe(),
                "shard_plans": self.shard_plans.iter().map(|p| serde_json::json!({
                    "pass": p.pass, "regions_recorded": p.recorded, "regions": p.regions,
                    "key": p.key, "current": p.current,
                })).collect::<Vec<_>>(),
                "extent_m": extent.map(|[map, world]| serde_json::json!({
                    "map_frame": { "min": map.0, "max": map.1 },
                    "local_z_up": { "min": world.0, "max": world.1 },
                })),
                "verified": self.verified,
                "problems": self.problems,
            });
            let text = serde_json::to_string_pretty(&v).map_err(|_| fmt::Error)?;
            return writeln!(f, "{text}");
        }
        writeln!(f, "map {}", self.dir)?;
        writeln!(
            f,
            "  voxel {} m, μ {} m, chunks of {}³ blocks; generation {}, frames committed: {frames}",
            h.voxel_size_m, h.truncation_m, h.chunk_blocks, h.generation
        )?;
        if let Some([map, world]) = extent {
            writeln!(
                f,
                "  extent (chunk bounds): {} in the map frame; {} in the local z-up frame of \
                 LAS/COPC/3D Tiles exports",
                describe_box(map),
                describe_box(world)
            )?;
        }
        writeln!(f, "  regularization: {}", passes.describe())?;
        for p in &self.shard_plans {
            let (pass, done, total, key) = (p.pass, p.recorded, p.regions, &p.key);
            if !p.current {
                writeln!(
                    f,
                    "  stale shard plan {key} of pass {pass} ({done} of {total} regions recorded): the map changed after its shards read it, so none will be adopted; it is removed when a regularization pass completes"
                )?;
            } else if done == 0 {
                writeln!(
                    f,
                    "  shards of pass {pass}: none of {total} regions recorded yet (plan {key})"
                )?;
            } else {
                writeln!(
                    f,
                    "  shards of pass {pass}: {done} of {total} regions recorded (plan {key}); `denser regularize {}` with the same parameters adopts them",
                    self.dir
                )?;
            }
        }
        if !passes.is_complete() {
            for line in passes.chunks_by_pass_lines(Some(12)) {
                writeln!(f, "    {line}")?;
            }
        }
        writeln!(
            f,
            "  {} chunks ({} carry u), {} blocks, {} voxels ({} in Ω), {:.1} MiB on disk, {:.3} bytes/voxel",
            s.chunks,
            s.regularized_chunks,
            s.blocks,
            s.voxels,
            s.observed_voxels,
            mib(s.bytes_on_disk),
            s.bytes_per_voxel()
        )?;
        if self.verified {
            if self.problems.is_empty() {
                writeln!(f, "  verified: all {} chunks intact", s.chunks)?;
            }
            for p in &self.problems {
                writeln!(f, "  CORRUPT {p}")?;
            }
        }
        Ok(())
    }
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    let store =
        MapStore::open_read_only_at(&a.dir).with_context(|| format!("opening map {}", a.dir))?;
    let problems = if a.verify { store.verify() } else { Vec::new() };
    let chunks = store.summary().chunks;
    let files = store.files().clone();
    let shard_plans = denser::outofcore::shards::plans(&*files)?
        .into_iter()
        .map(|p| {
            let key = u64::from_str_radix(&p.key, 16).unwrap_or(0);
            let recorded =
                denser::outofcore::shards::recorded_regions(&*files, key).map_or(0, |v| v.len());
            let now = denser::outofcore::shards::plan_key(
                store.manifest(),
                p.pass,
                &p.params,
                p.region_chunks,
                p.halo_blocks,
            );
            PlanState {
                pass: p.pass,
                recorded,
                regions: p.regions,
                current: now == key,
                key: p.key,
            }
        })
        .collect();
    let inspected = Inspected {
        shard_plans,
        dir: a.dir,
        store,
        verified: a.verify,
        problems,
        json: a.json,
    };
    if !inspected.problems.is_empty() {
        return Err(Problems(format!(
            "{inspected}{} of {chunks} chunks failed verification",
            inspected.problems.len()
        ))
        .into());
    }
    Ok(Box::new(inspected))
}
