//! `denser export`: a stored map, tile by tile, to one mesh (PLY) or point cloud (PLY, LAS, LAZ),
//! stitched with no cracks or duplicate vertices.

use super::Outcome;
use anyhow::{bail, Context, Result};
use denser::mesh::Field;
use denser::tiles::export::{self, Bbox, ExportStats, ExportTarget};
use denser::tiles::store::MapStore;
use std::fmt;
use std::path::PathBuf;

#[derive(clap::Args)]
pub(crate) struct Args {
    /// Map directory.
    dir: PathBuf,
    /// Write a mesh (binary PLY).
    #[arg(long, conflicts_with = "points")]
    mesh: Option<PathBuf>,
    /// Write surface points (.ply, .las or .laz).
    #[arg(long)]
    points: Option<PathBuf>,
    /// Export the raw field f.
    #[arg(long, conflicts_with = "regularized")]
    raw: bool,
    /// Export the regularised field u (the default).
    #[arg(long)]
    regularized: bool,
    /// Only this box: xmin,ymin,zmin,xmax,ymax,zmax (metres, world frame).
    #[arg(long, allow_hyphen_values = true)]
    bbox: Option<String>,
}

struct Exported {
    path: PathBuf,
    stats: ExportStats,
}

impl fmt::Display for Exported {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = &self.stats;
        writeln!(
            f,
            "wrote {}: {} vertices, {} triangles from {} chunks ({} voxels) in {:.2} s ({:.2} s per million voxels)",
            self.path.display(),
            s.vertices,
            s.triangles,
            s.chunks,
            s.voxels,
            s.seconds,
            s.seconds / (s.voxels.max(1) as f64 / 1e6)
        )
    }
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    let store = MapStore::open_read_only(&a.dir)
        .with_context(|| format!("opening map {}", a.dir.display()))?;
    let field = if a.raw {
        Field::Raw
    } else {
        Field::Regularized
    };
    let target = match (a.mesh, a.points) {
        (Some(m), None) => ExportTarget::Mesh(m),
        (None, Some(p)) => ExportTarget::Points(p),
        _ => bail!("give --mesh OUT.ply or --points OUT.(ply|las|laz)"),
    };
    let bbox = a.bbox.as_deref().map(Bbox::parse).transpose()?;
    if field == Field::Regularized && store.summary().regularized_chunks == 0 {
        tracing::warn!(
            "{} has no regularised chunks: exporting f (run `denser regularize` first)",
            a.dir.display()
        );
    }
    let stats = export::export(&store, field, bbox, &target).context("exporting")?;
    let path = match target {
        ExportTarget::Mesh(p) | ExportTarget::Points(p) => p,
    };
    Ok(Box::new(Exported { path, stats }))
}
