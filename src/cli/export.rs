//! `denser export`: a stored map, tile by tile, to one mesh (PLY), point cloud (PLY, LAS, LAZ,
//! COPC) or 3D Tiles tileset, stitched with no cracks or duplicate vertices, in the map frame or
//! a z-up world frame (`--georef`, `formats/georef.md`).

use super::Outcome;
use anyhow::{bail, Context, Result};
use denser::export::{self, Bbox, ExportOptions, ExportStats, ExportTarget};
use denser::geo::WorldFrame;
use denser::map::store::MapStore;
use denser::map::MapLocation;
use denser::mesh::Field;
use std::fmt;
use std::path::PathBuf;

#[derive(clap::Args)]
pub(crate) struct Args {
    /// Map directory or s3://bucket/prefix.
    #[arg(value_name = "MAP")]
    dir: MapLocation,
    #[arg(long, conflicts_with_all = ["points", "tiles"], help = super::help::MESH)]
    mesh: Option<PathBuf>,
    /// Write surface points (.ply, .las, .laz, or COPC as .copc.laz).
    #[arg(long, conflicts_with = "tiles")]
    points: Option<PathBuf>,
    /// Write a 3D Tiles 1.1 tileset (tileset.json and one GLB per tile) into this folder.
    #[arg(long)]
    tiles: Option<PathBuf>,
    /// Export the raw field f.
    #[arg(long, conflicts_with = "regularized")]
    raw: bool,
    /// Export the regularized field u (the default).
    #[arg(long)]
    regularized: bool,
    /// Only this box: xmin,ymin,zmin,xmax,ymax,zmax (metres, in the output's frame: the map frame
    /// for PLY without --georef/--world-frame, else the world frame).
    #[arg(long, allow_hyphen_values = true)]
    bbox: Option<String>,
    /// Georeference: EPSG:<code>@<x>,<y>,<z>[,<heading_deg>] (the map origin in that CRS and the
    /// compass heading of the map's forward axis), or a file holding a 4×4 world_from_map matrix
    /// (and optionally EPSG:<code>). See formats/georef.md.
    #[arg(long)]
    georef: Option<String>,
    /// Write PLY in the local z-up world frame (LAS/LAZ/COPC/3D Tiles always use it).
    #[arg(long)]
    world_frame: bool,
    #[arg(long, default_value = "1GiB", value_parser = super::parse_bytes, help = super::help::MEMORY_BUDGET)]
    memory_budget: u64,
    /// Export the regularized field even though the latest regularization pass has not reached
    /// every chunk (chunks of different passes mixed; the chunks of each pass are listed).
    #[arg(long, conflicts_with = "raw")]
    allow_incomplete_pass: bool,
    /// Export the regularized field of this pass: the latest, or the last complete one while a
    /// newer pass is incomplete (its files are kept until the newer pass completes).
    #[arg(long, conflicts_with_all = ["raw", "allow_incomplete_pass"])]
    pass: Option<u32>,
    #[arg(long, value_name = "I/N", help = super::help::SHARD)]
    shard: Option<String>,
    // `cpu` by default: chunk by chunk, GPU meshing is not yet measured faster than the CPU's
    // (whole in-memory layers are: docs/bench/gpu.md run 14).
    #[arg(long, value_enum, default_value = "cpu", help = super::help::DEVICE, help_heading = "Device")]
    device: super::DeviceArg,
}

struct PartWritten {
    map: MapLocation,
    shard: denser::outofcore::shards::Shard,
    stats: denser::export::parts::PartStats,
}

impl fmt::Display for PartWritten {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = &self.stats;
        writeln!(
            f,
            "export shard {} of {}: meshed {} chunks ({} vertices, {} triangles) into {} ({} bytes) in {:.2} s",
            self.shard, self.map, s.chunks, s.vertices, s.triangles, s.object, s.bytes, s.seconds
        )?;
        writeln!(
            f,
            "run the same export without --shard once every shard has finished: it writes the output from the parts"
        )
    }
}

struct Exported {
    path: PathBuf,
    /// Points, not a mesh: the summary counts points.
    points: bool,
    stats: ExportStats,
    /// Which regularization pass was exported, when not simply the latest complete one.
    notes: Vec<String>,
}

impl fmt::Display for Exported {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for n in &self.notes {
            writeln!(f, "{n}")?;
        }
        let s = &self.stats;
        if let Some(t) = &s.tileset {
            return writeln!(
                f,
                "wrote {}: {} tiles in {} levels ({} full-resolution: {} vertices, {} triangles; root {} triangles), {} bytes of GLB, from {} voxels in {:.2} s",
                self.path.join("tileset.json").display(),
                t.tiles,
                t.levels,
                t.leaf_tiles,
                t.leaf_vertices,
                t.leaf_triangles,
                t.root_triangles,
                t.glb_bytes,
                t.voxels,
                s.seconds
            );
        }
        let content = if self.points {
            format!("{} points", s.vertices)
        } else {
            format!("{} vertices, {} triangles", s.vertices, s.triangles)
        };
        writeln!(
            f,
            "wrote {}: {content} from {} chunks ({} voxels) in {:.2} s ({:.2} s per million voxels)",
            self.path.display(),
            s.chunks,
            s.voxels,
            s.seconds,
            s.seconds / (s.voxels.max(1) as f64 / 1e6)
        )?;
        if let Some(c) = &s.copc {
            writeln!(
                f,
                "COPC octree: {} nodes, {} levels, {} points at the root; {} nodes streamed from disk; {} bytes",
                c.nodes,
                c.max_level + 1,
                c.root_points,
                c.streamed_nodes,
                c.bytes
            )?;
        }
        Ok(())
    }
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    let mut store =
        MapStore::open_read_only_at(&a.dir).with_context(|| format!("opening map {}", a.dir))?;
    store.set_cache_budget(a.memory_budget / 4);
    let field = if a.raw {
        Field::Raw
    } else {
        Field::Regularized
    };
    let points = a.points.is_some();
    let target = match (a.mesh, a.points, a.tiles) {
        (Some(m), None, None) => ExportTarget::Mesh(m),
        (None, Some(p), None) => ExportTarget::Points(p),
        (None, None, Some(t)) => ExportTarget::Tiles(t),
        _ => bail!("give --mesh OUT.ply, --points OUT.(ply|las|laz|copc.laz) or --tiles DIR"),
    };
    let mut notes = Vec::new();
    let status = store.manifest().pass_status();
    let store = match a.pass {
        Some(p) if p == status.pass && status.is_complete() => store,
        Some(p) if p == status.complete_pass && p > 0 => {
            notes.push(format!(
                "exporting pass {p} (λ {}), the last complete one",
                status.complete_params.lambda
            ));
            store.complete_pass_view()?
        }
        Some(p) => bail!(
            "{}: pass {p} cannot be exported whole; {}",
            a.dir,
            status.describe()
        ),
        None if field == Field::Regularized && !status.is_complete() => {
            if !a.allow_incomplete_pass {
                let previous = if status.complete_pass > 0 {
                    format!(
                        ", export the last complete pass with --pass {}",
                        status.complete_pass
                    )
                } else {
                    String::new()
                };
                bail!(
                    "{}: regularization {}. Finish it with `denser regularize {} --lambda {} --iterations {}`{previous}, or mix the passes with --allow-incomplete-pass",
                    a.dir,
                    status.describe(),
                    a.dir,
                    status.params.lambda,
                    status.params.iterations
                );
            }
            notes.push(format!(
                "exporting an incomplete regularization ({}):",
                status.describe()
            ));
            notes.extend(
                status
                    .chunks_by_pass_lines(None)
                    .into_iter()
                    .map(|l| format!("  {l}")),
            );
            store
        }
        None => store,
    };
    let mut options = ExportOptions::new(field);
    let device = super::DeviceArgs { device: a.device };
    let backend = device.backend().context("opening the device")?;
    if let Some(ctx) = backend.mesh_context() {
        options.mesher = export::Mesher::gpu(ctx.clone());
        notes.push(format!("meshing the chunks on {}", ctx.name()));
    }
    options.bbox = a.bbox.as_deref().map(Bbox::parse).transpose()?;
    options.memory_budget_bytes = a.memory_budget;
    options.frame = match (&a.georef, a.world_frame) {
        (Some(g), _) => Some(WorldFrame::parse(g).context("reading --georef")?),
        (None, true) => Some(WorldFrame::local_z_up()),
        (None, false) => None,
    };
    if matches!(target, ExportTarget::Tiles(_)) && a.georef.is_none() {
        tracing::warn!(
            "no --georef: the tileset is in the map's local z-up frame with no placement on the \
             globe, so a globe viewer (Cesium, Google Earth) draws it at the Earth's centre; give \
             --georef EPSG:<code>@E,N,H to place it (formats/georef.md)"
        );
    }
    if field == Field::Regularized && store.summary().regularized_chunks == 0 {
        tracing::warn!(
            "{} has no regularized chunks: exporting f (run `denser regularize` first)",
            a.dir
        );
    }
    if let Some(spec) = &a.shard {
        let shard = denser::outofcore::shards::Shard::parse(spec)?;
        let frame = match (&options.frame, &target) {
            (Some(f), _) => f.clone(),
            (None, ExportTarget::Mesh(p) | ExportTarget::Points(p))
                if p.extension().is_some_and(|e| e.eq_ignore_ascii_case("ply")) =>
            {
                WorldFrame::map()
            }
            (None, _) => WorldFrame::local_z_up(),
        };
        let chunks = export::chunks_in(&store, &frame, options.bbox);
        let stats =
            denser::export::parts::write_part(&store, field, &chunks, shard, &options.mesher)
                .with_context(|| format!("export shard {shard} of {}", a.dir))?;
        return Ok(Box::new(PartWritten {
            map: a.dir,
            shard,
            stats,
        }));
    }
    match &target {
        ExportTarget::Tiles(dir) => denser::io::atomic::check_output_dir(
            dir.parent()
                .filter(|p| !p.as_os_str().is_empty())
                .unwrap_or(std::path::Path::new(".")),
        )?,
        ExportTarget::Mesh(p) | ExportTarget::Points(p) => {
            denser::io::atomic::check_output_file(p)?
        }
    }
    let parts = denser::export::parts::ExportParts::load(&store, field)
        .context("reading the export shards' parts")?
        .map(std::sync::Arc::new);
    if let Some(p) = &parts {
        notes.push(format!(
            "{} chunk meshes taken from {} export shard parts",
            p.chunks(),
            p.parts
        ));
    }
    options.parts = parts.clone();
    let stats = export::export_with(&store, &options, &target).context("exporting")?;
    if let Some(p) = &parts {
        p.remove_all().context("removing the export parts")?;
    }
    let path = match target {
        ExportTarget::Mesh(p) | ExportTarget::Points(p) | ExportTarget::Tiles(p) => p,
    };
    Ok(Box::new(Exported {
        path,
        points,
        stats,
        notes,
    }))
}
