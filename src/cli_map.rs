//! The out-of-core subcommands of the `denser` CLI: `regularize`, `export`, `inspect`, `repair`,
//! and the `--map` options of `reconstruct`.

use anyhow::{bail, Context, Result};
use clap::Args;
use denser::mesh::Field;
use denser::regularize::TvParams;
use denser::tiles::{export, regional, store::MapStore};
use std::path::PathBuf;

/// Parses a byte size: `1GiB`, `512MiB`, `64M` (binary), `2GB` (decimal), or plain bytes.
pub fn parse_bytes(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let n: f64 = num
        .parse()
        .map_err(|_| format!("{s:?} is not a size (e.g. 1GiB, 512MiB, 2GB)"))?;
    let mul: f64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "k" | "kib" => 1024.0,
        "m" | "mib" => 1024f64.powi(2),
        "g" | "gib" => 1024f64.powi(3),
        "t" | "tib" => 1024f64.powi(4),
        "kb" => 1e3,
        "mb" => 1e6,
        "gb" => 1e9,
        "tb" => 1e12,
        u => {
            return Err(format!(
                "{s:?}: unknown unit {u:?} (use KiB, MiB, GiB, KB, MB, GB)"
            ))
        }
    };
    if !(n.is_finite() && n >= 0.0) {
        return Err(format!("{s:?} is not a size"));
    }
    Ok((n * mul).round() as u64)
}

/// `--map` options of `reconstruct`.
#[derive(Args, Clone)]
pub struct StreamArgs {
    /// Stream the map through this directory of compressed chunk files (created, or resumed when
    /// it holds a map of the same job) instead of keeping it in RAM.
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// Memory budget for resident voxel blocks with --map (e.g. 1GiB, 512MiB).
    #[arg(long, default_value = "1GiB", value_parser = parse_bytes)]
    pub memory_budget: u64,
    /// Chunk edge in blocks (a chunk is one file; 16 blocks = 12.8 m at 10 cm voxels).
    #[arg(long, default_value_t = denser::tiles::DEFAULT_CHUNK_BLOCKS)]
    pub chunk_blocks: u32,
    /// Commit a resumable checkpoint every this many frames (0: only at the end).
    #[arg(long, default_value_t = 50)]
    pub checkpoint_every: u64,
    /// Regularisation region edge, chunks (bigger regions spend less on halos, need more memory).
    #[arg(long, default_value_t = 2)]
    pub region_chunks: u32,
    /// Go on (with a warning) when one frame needs more than the budget, instead of stopping.
    #[arg(long)]
    pub allow_overrun: bool,
    /// With --map: fuse (and export the raw mesh) only; regularise later with `denser regularize`.
    #[arg(long)]
    pub skip_regularize: bool,
}

#[derive(Args)]
pub struct RegularizeArgs {
    /// Map directory.
    pub dir: PathBuf,
    /// TV data weight λ (default: the paper's for the map's voxel size).
    #[arg(long)]
    pub lambda: Option<f32>,
    /// Primal–dual iterations.
    #[arg(long, default_value_t = 100)]
    pub iterations: u32,
    /// Region edge, chunks (bigger regions spend less on halos, need more memory).
    #[arg(long, default_value_t = 2)]
    pub region_chunks: u32,
    /// Memory budget of one region (e.g. 1GiB).
    #[arg(long, default_value = "1GiB", value_parser = parse_bytes)]
    pub memory_budget: u64,
    /// Where regions are solved: a region too large for one GPU buffer is solved on the CPU
    /// (counted and reported).
    #[arg(long, value_enum, default_value = "auto")]
    pub device: crate::DeviceArg,
}

#[derive(Args)]
pub struct ExportArgs {
    /// Map directory.
    pub dir: PathBuf,
    /// Write a mesh (binary PLY).
    #[arg(long, conflicts_with = "points")]
    pub mesh: Option<PathBuf>,
    /// Write surface points (.ply, .las or .laz).
    #[arg(long)]
    pub points: Option<PathBuf>,
    /// Export the raw field f.
    #[arg(long, conflicts_with = "regularized")]
    pub raw: bool,
    /// Export the regularised field u (the default).
    #[arg(long)]
    pub regularized: bool,
    /// Only this box: xmin,ymin,zmin,xmax,ymax,zmax (metres, world frame).
    #[arg(long, allow_hyphen_values = true)]
    pub bbox: Option<String>,
    /// Export the regularised field even though the latest regularisation pass has not reached
    /// every chunk (chunks of different passes mixed; the chunks of each pass are listed).
    #[arg(long, conflicts_with = "raw")]
    pub allow_incomplete_pass: bool,
    /// Export the regularised field of this pass: the latest, or the last complete one while a
    /// newer pass is incomplete (its files are kept until the newer pass completes).
    #[arg(long, conflicts_with_all = ["raw", "allow_incomplete_pass"])]
    pub pass: Option<u32>,
}

#[derive(Args)]
pub struct RepairArgs {
    /// Map directory whose manifest is lost or unreadable.
    pub dir: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

#[derive(Args)]
pub struct InspectArgs {
    /// Map directory.
    pub dir: PathBuf,
    /// Read every chunk and check its checksums against the manifest.
    #[arg(long)]
    pub verify: bool,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn regularize(a: RegularizeArgs) -> Result<()> {
    let mut store =
        MapStore::open(&a.dir).with_context(|| format!("opening map {}", a.dir.display()))?;
    let mut params = TvParams::paper(store.grid().voxel_size_m);
    if let Some(l) = a.lambda {
        params.lambda = l;
    }
    params.iterations = a.iterations;
    let voxels = store.summary().observed_voxels;
    let gpu = denser::gpu::DeviceChoice::from(a.device).open()?;
    let (mut on_gpu, mut on_cpu) = (0usize, 0usize);
    let solve = |p: &mut denser::regularize::TvProblem| -> denser::Result<()> {
        if let Some(ctx) = &gpu {
            match denser::gpu::solve_gpu(ctx, p, &params) {
                Ok(()) => {
                    on_gpu += 1;
                    return Ok(());
                }
                Err(e @ denser::Error::GpuCapacity { .. }) => {
                    tracing::warn!("{e}; solving this region on the CPU");
                }
                Err(e) => return Err(e),
            }
        }
        p.solve(&params);
        on_cpu += 1;
        Ok(())
    };
    let bar = denser::progress::bar(0, "regularising");
    let stats = regional::regularize_map_with(
        &mut store,
        &params,
        &regional::RegionalOptions {
            region_chunks: a.region_chunks,
            budget_bytes: a.memory_budget,
            halo_blocks: None,
        },
        |done, total| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
            true
        },
        solve,
    )
    .with_context(|| format!("regularising {}", a.dir.display()))?;
    bar.finish_and_clear();
    if gpu.is_some() {
        println!("regions solved on the GPU: {on_gpu}, on the CPU (too large for it): {on_cpu}");
    }
    println!(
        "regularisation pass {} (λ {}, {} iterations, halo {} blocks): {} regions solved, {} already done; {} blocks written, {} solved with halos ({:.2}×)",
        stats.pass, params.lambda, params.iterations, stats.halo_blocks, stats.regions, stats.regions_skipped,
        stats.core_blocks, stats.solved_blocks,
        stats.solved_blocks as f64 / stats.core_blocks.max(1) as f64
    );
    println!(
        "{:.1} s, {:.2} s per million Ω voxels; largest region ≈ {} MiB; peak RSS {} MiB",
        stats.seconds,
        stats.seconds / (stats.core_omega_voxels.max(1) as f64 / 1e6),
        stats.peak_region_bytes >> 20,
        denser::pipeline::peak_rss_bytes().unwrap_or(0) >> 20
    );
    let _ = voxels;
    Ok(())
}

pub fn export(a: ExportArgs) -> Result<()> {
    let store = MapStore::open_read_only(&a.dir)
        .with_context(|| format!("opening map {}", a.dir.display()))?;
    let field = if a.raw {
        Field::Raw
    } else {
        Field::Regularized
    };
    let target = match (a.mesh, a.points) {
        (Some(m), None) => export::ExportTarget::Mesh(m),
        (None, Some(p)) => export::ExportTarget::Points(p),
        _ => bail!("give --mesh OUT.ply or --points OUT.(ply|las|laz)"),
    };
    let bbox = a.bbox.as_deref().map(export::Bbox::parse).transpose()?;
    let status = store.manifest().pass_status();
    let store = match a.pass {
        Some(p) if p == status.pass && status.is_complete() => store,
        Some(p) if p == status.complete_pass && p > 0 => {
            println!(
                "exporting pass {p} (λ {}), the last complete one",
                status.complete_params.lambda
            );
            store.complete_pass_view()?
        }
        Some(p) => bail!(
            "{}: pass {p} cannot be exported whole; {}",
            a.dir.display(),
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
                    "{}: regularisation {}. Finish it with `denser regularize {} --lambda {} --iterations {}`{previous}, or mix the passes with --allow-incomplete-pass",
                    a.dir.display(),
                    status.describe(),
                    a.dir.display(),
                    status.params.lambda,
                    status.params.iterations
                );
            }
            println!(
                "exporting an incomplete regularisation ({}):",
                status.describe()
            );
            for line in status.chunks_by_pass_lines(None) {
                println!("  {line}");
            }
            store
        }
        None => store,
    };
    if field == Field::Regularized && store.summary().regularized_chunks == 0 {
        tracing::warn!(
            "{} has no regularised chunks: exporting f (run `denser regularize` first)",
            a.dir.display()
        );
    }
    let stats = export::export(&store, field, bbox, &target).context("exporting")?;
    let path = match &target {
        export::ExportTarget::Mesh(p) | export::ExportTarget::Points(p) => p,
    };
    println!(
        "wrote {}: {} vertices, {} triangles from {} chunks ({} voxels) in {:.2} s ({:.2} s per million voxels)",
        path.display(),
        stats.vertices,
        stats.triangles,
        stats.chunks,
        stats.voxels,
        stats.seconds,
        stats.seconds / (stats.voxels.max(1) as f64 / 1e6)
    );
    Ok(())
}

pub fn inspect(a: InspectArgs) -> Result<()> {
    let store = MapStore::open_read_only(&a.dir)
        .with_context(|| format!("opening map {}", a.dir.display()))?;
    let s = store.summary();
    let h = store.manifest().header;
    let passes = store.manifest().pass_status();
    let frames = if h.frames_committed == denser::tiles::manifest::FRAMES_UNKNOWN {
        "unknown (repaired map: fusion cannot resume)".to_string()
    } else {
        h.frames_committed.to_string()
    };
    let problems = if a.verify { store.verify() } else { Vec::new() };
    if a.json {
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
            "verified": a.verify,
            "problems": problems,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!("map {}", a.dir.display());
        println!(
            "  voxel {} m, μ {} m, chunks of {}³ blocks; generation {}, frames committed: {frames}",
            h.voxel_size_m, h.truncation_m, h.chunk_blocks, h.generation
        );
        println!("  regularisation: {}", passes.describe());
        if !passes.is_complete() {
            for line in passes.chunks_by_pass_lines(Some(12)) {
                println!("    {line}");
            }
        }
        println!(
            "  {} chunks ({} carry u), {} blocks, {} voxels ({} in Ω), {:.1} MiB on disk, {:.3} bytes/voxel",
            s.chunks,
            s.regularized_chunks,
            s.blocks,
            s.voxels,
            s.observed_voxels,
            s.bytes_on_disk as f64 / (1u64 << 20) as f64,
            s.bytes_per_voxel()
        );
        if a.verify {
            if problems.is_empty() {
                println!("  verified: all {} chunks intact", s.chunks);
            }
            for p in &problems {
                println!("  CORRUPT {p}");
            }
        }
    }
    if !problems.is_empty() {
        bail!(
            "{} of {} chunks failed verification",
            problems.len(),
            s.chunks
        );
    }
    Ok(())
}

pub fn repair(a: RepairArgs) -> Result<()> {
    let r = denser::tiles::repair::repair(&a.dir)
        .with_context(|| format!("repairing map {}", a.dir.display()))?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
        return Ok(());
    }
    println!(
        "repaired {}: new manifest from the newest intact version of each chunk: {} chunks, {} blocks ({} in Ω), from {} chunk files",
        a.dir.display(),
        r.chunks,
        r.blocks,
        r.observed_voxels,
        r.files_examined
    );
    if let Some(p) = &r.unreadable_manifest_moved_to {
        println!("  the unreadable manifest was moved to {}", p.display());
    }
    for l in &r.older_versions_used {
        println!("  older version: {l}");
    }
    for l in &r.not_kept {
        println!("  not kept: {l}");
    }
    for l in &r.notes {
        println!("  note: {l}");
    }
    println!("  regularisation: {}", r.passes.describe());
    println!(
        "  fusion progress was in the lost manifest: `reconstruct --map` cannot resume this map; regularize, export and inspect work"
    );
    Ok(())
}
