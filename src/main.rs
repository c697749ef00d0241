//! The `denser` command line. Each subcommand is a thin wrapper over the library; errors are
//! printed once, with their chain, and the exit code is non-zero.

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand, ValueEnum};
use denser::pipeline::{self, RangeSource, ReconstructJob};
use denser::reconstruct::ReconstructionConfig;
use std::path::PathBuf;

mod cli_map;

#[derive(Parser)]
#[command(
    name = "denser",
    version,
    about = "Dense, coloured 3D city reconstruction from stereo and LiDAR (DENSER Cities)"
)]
struct Cli {
    /// Log level (error, warn, info, debug, trace); RUST_LOG overrides it.
    #[arg(long, global = true, default_value = "info")]
    log: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Fuse a sequence (KITTI odometry, TUM RGB-D or simple RGB-D), regularise, mesh and report.
    Reconstruct(ReconstructArgs),
    /// Print fusion, regularisation and meshing throughput on real RGB-D frames.
    Bench(BenchArgs),
    /// Synthesise a short city drive, reconstruct it from stereo, regularise, mesh and evaluate.
    Demo(DemoArgs),
    /// Score meshes against ground truth (distance to the nearest ground-truth point, as the paper).
    Evaluate(EvaluateArgs),
    /// Generate a synthetic city drive with exact ground truth, in the KITTI odometry layout.
    Synth(SynthArgs),
    /// Re-regularise a stored map region by region within a memory budget (resumable).
    Regularize(cli_map::RegularizeArgs),
    /// Convert a stored map, tile by tile, to one mesh (PLY) or point cloud (PLY, LAS, LAZ).
    Export(cli_map::ExportArgs),
    /// Summarise a stored map (chunks, blocks, voxels, bytes) and verify its checksums.
    Inspect(cli_map::InspectArgs),
    /// Rebuild a lost or unreadable map manifest from the chunk files (newest intact versions).
    Repair(cli_map::RepairArgs),
    /// Disparity (and depth) of one rectified stereo pair, written as Middlebury PFM.
    Stereo(StereoArgs),
    /// Score a disparity map against ground truth (bad-1/2/3, D1, EPE, density).
    StereoEval(StereoEvalArgs),
}

#[derive(Args)]
struct StereoArgs {
    /// Left (reference) image (PNG; colour is converted to grey).
    left: PathBuf,
    /// Right image.
    right: PathBuf,
    /// Disparity output: PFM (float32, rows bottom-up, inf = invalid).
    #[arg(long)]
    out: PathBuf,
    /// Calibration for depth: KITTI odometry or Middlebury 2014 `calib.txt`.
    #[arg(long)]
    calib: Option<PathBuf>,
    /// Depth output: 16-bit PNG, depth_m = value / 256, 0 = invalid (needs --calib).
    #[arg(long)]
    depth_out: Option<PathBuf>,
    /// Matcher: sgm, tv, tgv, tgv-tensor.
    #[arg(long, default_value = "tgv-tensor")]
    method: String,
    /// Disparity search range from 0, pixels.
    #[arg(long, default_value_t = 128)]
    num_disparities: usize,
    /// tv/tgv/tgv-tensor: keep occluded and poorly matching pixels (dense output for benchmarks
    /// that count missing pixels as errors).
    #[arg(long)]
    dense: bool,
    /// Where tv/tgv/tgv-tensor run their census cost and refinement (SGM stays on the CPU).
    #[arg(long, value_enum, default_value = "auto")]
    device: DeviceArg,
}

#[derive(Args)]
struct StereoEvalArgs {
    /// Ground-truth disparity: Middlebury PFM (inf = unknown) or KITTI 16-bit PNG (value/256, 0 = unknown).
    gt: PathBuf,
    /// Predicted disparity, same formats (missing = NaN/inf/0 counts as an error).
    pred: PathBuf,
    /// Optional Middlebury-style mask PNG: only pixels of value 255 are scored.
    #[arg(long)]
    mask: Option<PathBuf>,
    /// Also write the scores as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Args)]
struct SynthArgs {
    /// Output root (gets `sequences/00/...`, `poses/00.txt`, `ground_truth/surface.ply`).
    #[arg(long)]
    out: PathBuf,
    /// Length of the drive, metres.
    #[arg(long, default_value_t = 300.0)]
    length_m: f64,
    /// Drive along a KITTI trajectory (3×4 world_from_cam0 per line) at its real scale.
    #[arg(long)]
    trajectory: Option<PathBuf>,
    /// Seed of the city (same seed, same bytes).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Distance between frames, metres.
    #[arg(long, default_value_t = 0.9)]
    frame_spacing_m: f64,
    /// Keep at most this many frames.
    #[arg(long)]
    max_frames: Option<usize>,
    /// Also write dense samples of the exact scene surfaces (`ground_truth/surface.ply`) for
    /// evaluation at voxel level; without it the LiDAR scans are the ground truth, as in the paper.
    #[arg(long)]
    voxel_gt: bool,
    /// Spacing of the exact surface samples, metres (with `--voxel-gt`).
    #[arg(long, default_value_t = 0.05)]
    gt_spacing_m: f64,
    /// Do not write LiDAR scans.
    #[arg(long)]
    no_lidar: bool,
    /// Write poses, calibration and LiDAR scans only (no stereo images or depth): fast long
    /// drives for LiDAR reconstruction.
    #[arg(long, conflicts_with = "no_lidar")]
    lidar_only: bool,
}

#[derive(Clone, Copy, ValueEnum)]
enum DepthArg {
    /// Velodyne scans.
    Lidar,
    /// Ground-truth depth maps of a synthetic drive.
    Gt,
    /// Stereo matching on the image pairs.
    Stereo,
}

/// Where depth fusion and regularisation run.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub(crate) enum DeviceArg {
    /// A hardware GPU when wgpu finds one, else the CPU (one line says which).
    Auto,
    /// The CPU.
    Cpu,
    /// The GPU, software adapters (lavapipe) included; an error when no adapter exists.
    Gpu,
}

impl From<DeviceArg> for denser::gpu::DeviceChoice {
    fn from(d: DeviceArg) -> Self {
        match d {
            DeviceArg::Auto => denser::gpu::DeviceChoice::Auto,
            DeviceArg::Cpu => denser::gpu::DeviceChoice::Cpu,
            DeviceArg::Gpu => denser::gpu::DeviceChoice::Gpu,
        }
    }
}

/// Map and regulariser parameters shared by subcommands.
#[derive(Args, Clone)]
struct MapArgs {
    /// Voxel edge, metres (paper: 0.10 or 0.20).
    #[arg(long, default_value_t = 0.1)]
    voxel_size: f32,
    /// Truncation μ, metres (default: the paper's, 1.0 at 10 cm and 1.6 at 20 cm, else 10 voxels).
    #[arg(long)]
    truncation: Option<f32>,
    /// TV data weight λ (default: the paper's, 0.8 at 10 cm, 0.4 at 20 cm).
    #[arg(long)]
    lambda: Option<f32>,
    /// Primal–dual iterations.
    #[arg(long, default_value_t = 100)]
    iterations: u32,
    /// Ignore depths beyond this, metres.
    #[arg(long, default_value_t = 40.0)]
    max_depth: f32,
}

impl MapArgs {
    fn config(&self) -> ReconstructionConfig {
        let mut c = ReconstructionConfig::paper(self.voxel_size);
        if let Some(t) = self.truncation {
            c.grid.truncation_m = t;
        }
        if let Some(l) = self.lambda {
            c.tv.lambda = l;
        }
        c.tv.iterations = self.iterations;
        c.depth_fusion.max_depth_m = self.max_depth;
        c.lidar_fusion.max_range_m = self.max_depth.max(c.lidar_fusion.max_range_m);
        c
    }
}

#[derive(Args)]
struct ReconstructArgs {
    /// Sequence folder: KITTI `sequences/NN`, TUM RGB-D, or numbered RGB-D (`pose.txt`, `depth/`).
    input: PathBuf,
    /// Output folder.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Range source for KITTI-layout input.
    #[arg(long, value_enum, default_value = "lidar")]
    depth: DepthArg,
    /// KITTI poses file (default: `<root>/poses/NN.txt`).
    #[arg(long)]
    poses: Option<PathBuf>,
    /// First frame.
    #[arg(long, default_value_t = 0)]
    first: usize,
    /// One past the last frame (default: all).
    #[arg(long)]
    last: Option<usize>,
    /// Use every n-th frame.
    #[arg(long, default_value_t = 1)]
    step: usize,
    /// Ground truth for the report: a .las/.laz/.ply file, or a KITTI sequence folder whose scans
    /// are merged (default for KITTI-layout input: its own scans, as the paper).
    #[arg(long)]
    gt: Option<PathBuf>,
    /// Skip the evaluation.
    #[arg(long)]
    no_eval: bool,
    /// Stereo matcher (with `--depth stereo`): tgv-tensor (the paper's), tgv, tv, sgm.
    #[arg(long, default_value = "tgv-tensor")]
    method: String,
    /// Disparity search range, pixels (128 sees down to ~3 m on KITTI).
    #[arg(long, default_value_t = 128)]
    num_disparities: usize,
    /// Where depth fusion and regularisation run (LiDAR fusion and meshing use the CPU).
    #[arg(long, value_enum, default_value = "auto")]
    device: DeviceArg,
    /// Largest GPU block pool (4 KiB per block; bounded by the device's largest buffer). Depth
    /// blocks stay on the GPU between frames; beyond this they spill to RAM.
    #[arg(long, default_value = "2GiB", value_parser = cli_map::parse_bytes)]
    gpu_memory_budget: u64,
    #[command(flatten)]
    map: MapArgs,
    #[command(flatten)]
    stream: cli_map::StreamArgs,
}

#[derive(Args)]
struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "out/demo")]
    out: PathBuf,
    /// Length of the drive, metres.
    #[arg(long, default_value_t = 200.0)]
    length_m: f64,
    /// Distance between frames, metres.
    #[arg(long, default_value_t = 2.0)]
    frame_spacing_m: f64,
    /// Seed of the city.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Primal–dual iterations.
    #[arg(long, default_value_t = 100)]
    iterations: u32,
    /// Where depth fusion and regularisation run.
    #[arg(long, value_enum, default_value = "auto")]
    device: DeviceArg,
    /// Stereo matcher: tgv-tensor (the paper's), tgv, tv, sgm.
    #[arg(long, default_value = "tgv-tensor")]
    stereo_method: String,
}

#[derive(Args)]
struct EvaluateArgs {
    /// Meshes to score, as `LABEL=PATH.ply` or `PATH.ply` (label = file stem); the first is the
    /// baseline for relative changes.
    #[arg(long = "mesh", required = true)]
    meshes: Vec<String>,
    /// Ground truth: .las/.laz/.ply, or a KITTI sequence folder (its scans, merged in the world frame).
    #[arg(long)]
    gt: PathBuf,
    /// KITTI poses file, when not at `<root>/poses/NN.txt`.
    #[arg(long)]
    poses: Option<PathBuf>,
    /// First KITTI scan.
    #[arg(long, default_value_t = 0)]
    first: usize,
    /// One past the last KITTI scan.
    #[arg(long)]
    last: Option<usize>,
    /// Use every n-th KITTI scan.
    #[arg(long, default_value_t = 1)]
    step: usize,
    /// Output folder for report.json, report.md and the pictures.
    #[arg(long, default_value = "out")]
    out: PathBuf,
}

#[derive(Args)]
struct BenchArgs {
    /// Numbered RGB-D folder (default: ../shared/data/rgbd_5frames_slambook2).
    #[arg(long)]
    rgbd: Option<PathBuf>,
    /// Passes over the frames per voxel size.
    #[arg(long, default_value_t = 10)]
    passes: usize,
}

/// Mesa's Vulkan drivers print "XDG_RUNTIME_DIR is invalid or not set" to stderr when probed
/// without one (servers, containers, CI). Give them a private directory before any thread starts.
fn ensure_runtime_dir() {
    if std::env::var_os("XDG_RUNTIME_DIR").is_some() {
        return;
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::{DirBuilderExt, PermissionsExt};
        let user = std::env::var("USER").unwrap_or_else(|_| "user".into());
        let dir = std::env::temp_dir().join(format!("denser-runtime-{user}"));
        let _ = std::fs::DirBuilder::new().mode(0o700).create(&dir);
        // Use it only if it is private.
        if let Ok(m) = std::fs::metadata(&dir) {
            let private = m.is_dir() && m.permissions().mode() & 0o077 == 0;
            if private {
                std::env::set_var("XDG_RUNTIME_DIR", &dir);
            }
        }
    }
}

fn main() {
    ensure_runtime_dir();
    let cli = Cli::parse();
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(&cli.log));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        .init();
    let result = match cli.command {
        Command::Reconstruct(a) => reconstruct(a),
        Command::Bench(a) => bench(a),
        Command::Synth(a) => synth(a),
        Command::Evaluate(a) => evaluate(a),
        Command::Demo(a) => demo(a),
        Command::Regularize(a) => cli_map::regularize(a),
        Command::Export(a) => cli_map::export(a),
        Command::Inspect(a) => cli_map::inspect(a),
        Command::Repair(a) => cli_map::repair(a),
        Command::Stereo(a) => stereo(a),
        Command::StereoEval(a) => stereo_eval(a),
    };
    if let Err(e) = result {
        eprintln!("error: {e}");
        for cause in e.chain().skip(1) {
            eprintln!("  caused by: {cause}");
        }
        std::process::exit(1);
    }
}

fn reconstruct(a: ReconstructArgs) -> Result<()> {
    let job = ReconstructJob {
        input: a.input.clone(),
        poses: a.poses,
        out_dir: a.out.clone(),
        source: match a.depth {
            DepthArg::Lidar => RangeSource::Lidar,
            DepthArg::Gt => RangeSource::GroundTruthDepth,
            DepthArg::Stereo => RangeSource::Stereo,
        },
        config: a.map.config(),
        frames: Some((a.first, a.last.unwrap_or(usize::MAX))),
        frame_step: a.step,
        stereo_method: a.method.parse()?,
        num_disparities: a.num_disparities,
        device: a.device.into(),
        gpu_budget_bytes: a.gpu_memory_budget,
    };
    if let Some(dir) = &a.stream.map {
        return reconstruct_streamed(&job, dir, &a.stream);
    }
    let rec = pipeline::fuse_input(&job)
        .with_context(|| format!("reconstructing {}", a.input.display()))?;
    let outcome = pipeline::finish(rec, &a.out)
        .with_context(|| format!("writing results to {}", a.out.display()))?;
    let t = outcome.reconstructor.timings();
    println!(
        "fused {} frames: {:.1} ms/frame, {:.2} M voxel updates/s; {} blocks, {} voxels in Ω, {:.2} bytes/voxel",
        t.frames_fused,
        t.fusion_ms_per_frame(),
        t.voxel_updates_per_s() / 1e6,
        outcome.reconstructor.layer().block_count(),
        outcome.observed_voxels,
        outcome.reconstructor.layer().bytes_per_voxel()
    );
    println!(
        "regularised: {} iterations, {:.1} M voxel-iterations/s, energy {:.4e} → {:.4e}",
        outcome.regularize_stats.iterations,
        t.voxel_iterations_per_s() / 1e6,
        outcome.regularize_stats.energy_before,
        outcome.regularize_stats.energy_after
    );
    println!(
        "meshes: raw {} triangles, {:.1} m²; regularised {} triangles, {:.1} m²",
        outcome.raw.triangles.len(),
        outcome.raw.surface_area_m2(),
        outcome.regularized.triangles.len(),
        outcome.regularized.surface_area_m2()
    );
    for p in &outcome.written {
        println!("wrote {}", p.display());
    }
    if a.no_eval {
        return Ok(());
    }
    let kind = pipeline::detect_input(&a.input)?;
    let gt = match (&a.gt, kind) {
        (Some(p), _) => Some(ground_truth_arg(
            p,
            job.poses.clone(),
            job.frames,
            job.frame_step,
        )),
        (None, pipeline::InputKind::Kitti) => Some(pipeline::GroundTruth::KittiLidar {
            sequence: a.input.clone(),
            poses: job.poses.clone(),
            frames: job.frames,
            step: job.frame_step,
        }),
        (None, _) => None,
    };
    let Some(gt) = gt else {
        println!(
            "no ground truth for {} (pass --gt): evaluation skipped",
            a.input.display()
        );
        return Ok(());
    };
    let (report, written) = pipeline::evaluate_outcome(
        &outcome,
        &gt,
        &format!("{} ({:?})", a.input.display(), job.source),
        &a.out,
    )
    .context("evaluating")?;
    print_summary(&report);
    for p in written {
        println!("wrote {}", p.display());
    }
    Ok(())
}

fn reconstruct_streamed(
    job: &ReconstructJob,
    dir: &std::path::Path,
    s: &cli_map::StreamArgs,
) -> Result<()> {
    let map = pipeline::MapJob {
        dir: dir.to_path_buf(),
        budget_bytes: s.memory_budget,
        chunk_blocks: s.chunk_blocks,
        checkpoint_every: s.checkpoint_every,
        region_chunks: s.region_chunks,
        overrun: if s.allow_overrun {
            denser::tiles::pager::OverrunPolicy::Warn
        } else {
            denser::tiles::pager::OverrunPolicy::Error
        },
        export_meshes: true,
        regularize: !s.skip_regularize,
    };
    let o = pipeline::reconstruct_map(job, &map).with_context(|| {
        format!(
            "reconstructing {} into map {}",
            job.input.display(),
            dir.display()
        )
    })?;
    let new_frames = o.frames_fused - o.resumed_from_frame;
    if o.resumed_from_frame > 0 {
        println!("resumed after {} committed frames", o.resumed_from_frame);
    }
    println!(
        "fused {} frames: fusion {:.1} ms/frame, paging {:.1} ms/frame ({:.1} % of fusion), input {:.1} ms/frame",
        new_frames,
        1e3 * o.fusion_s / new_frames.max(1) as f64,
        1e3 * o.paging_s / new_frames.max(1) as f64,
        100.0 * o.paging_s / o.fusion_s.max(1e-9),
        1e3 * o.input_s / new_frames.max(1) as f64
    );
    println!(
        "pager: budget {} MiB, peak {:.1} MiB resident+writing, {} chunks evicted, {} written ({:.1} MiB), {} read back, {} over budget",
        s.memory_budget >> 20,
        o.pager.peak_bytes as f64 / (1u64 << 20) as f64,
        o.pager.chunks_evicted,
        o.pager.chunks_written,
        o.pager.bytes_written as f64 / (1u64 << 20) as f64,
        o.pager.chunks_read,
        o.pager.budget_overruns
    );
    if let Some(g) = &o.gpu {
        println!(
            "GPU tier: pool {} blocks (max {}), peak {} resident, {} uploaded, {} read back, {} spilled to RAM, {} grows, {} oversize frames",
            g.capacity_blocks,
            g.max_blocks,
            g.peak_resident_blocks,
            g.blocks_uploaded,
            g.blocks_downloaded,
            g.blocks_spilled,
            g.grows,
            g.oversize_frames
        );
        let per = |s: f64| 1e3 * s / g.frames.max(1) as f64;
        println!(
            "GPU tier per frame: listing blocks (CPU) {:.1} ms, residency {:.1} ms, kernels {:.1} ms, write-back {:.1} ms",
            per(g.list_s),
            per(g.residency_s),
            per(g.kernel_s),
            per(g.download_s)
        );
    }
    println!(
        "map: {} chunks, {} blocks, {} voxels ({} in Ω), {:.1} MiB on disk, {:.3} bytes/voxel on disk",
        o.summary.chunks,
        o.summary.blocks,
        o.summary.voxels,
        o.summary.observed_voxels,
        o.summary.bytes_on_disk as f64 / (1u64 << 20) as f64,
        o.summary.bytes_per_voxel()
    );
    if o.regularize.pass == 0 {
        println!(
            "regularisation skipped (run `denser regularize {}`)",
            dir.display()
        );
    } else {
        println!(
            "regularised {} regions ({} already done) in {:.1} s: {:.2} s per million Ω voxels",
            o.regularize.regions,
            o.regularize.regions_skipped,
            o.regularize.seconds,
            o.regularize.seconds / (o.regularize.core_omega_voxels.max(1) as f64 / 1e6)
        );
    }
    for (p, e) in &o.exports {
        println!(
            "wrote {} ({} vertices, {} triangles, {:.2} s)",
            p.display(),
            e.vertices,
            e.triangles,
            e.seconds
        );
    }
    if let Some(rss) = o.peak_rss_bytes {
        println!("peak RSS {:.1} MiB", rss as f64 / (1u64 << 20) as f64);
    }
    let report = job.out_dir.join("map_report.json");
    std::fs::create_dir_all(&job.out_dir)?;
    std::fs::write(&report, serde_json::to_string_pretty(&o)?)
        .with_context(|| format!("writing {}", report.display()))?;
    println!("wrote {}", report.display());
    Ok(())
}

fn ground_truth_arg(
    path: &std::path::Path,
    poses: Option<PathBuf>,
    frames: Option<(usize, usize)>,
    step: usize,
) -> pipeline::GroundTruth {
    if path.is_dir() {
        pipeline::GroundTruth::KittiLidar {
            sequence: path.to_path_buf(),
            poses,
            frames,
            step,
        }
    } else {
        pipeline::GroundTruth::File(path.to_path_buf())
    }
}

/// Prints the paper's table (median, 75th percentile, mode, area) for each surface.
fn print_summary(report: &denser::eval::EvaluationReport) {
    println!(
        "{:<12} {:>10} {:>10} {:>10} {:>12} {:>12}",
        "surface", "median m", "p75 m", "mode m", "area m²", "complete m"
    );
    for s in &report.surfaces {
        println!(
            "{:<12} {:>10.4} {:>10.4} {:>10} {:>12.1} {:>12}",
            s.label,
            s.accuracy.median_m,
            s.accuracy.p75_m,
            s.accuracy
                .mode_m
                .map_or("-".to_string(), |m| format!("{m:.4}")),
            s.surface_area_m2,
            s.completeness
                .as_ref()
                .map_or("-".to_string(), |c| format!("{:.4}", c.median_m))
        );
    }
    if let (Some(a), Some(b)) = (report.surfaces.first(), report.surfaces.get(1)) {
        let rel = |x: f64, y: f64| 100.0 * (y - x) / x.max(1e-12);
        println!(
            "{} vs {}: median {:+.0} %, p75 {:+.0} %, area {:+.0} %",
            b.label,
            a.label,
            rel(a.accuracy.median_m, b.accuracy.median_m),
            rel(a.accuracy.p75_m, b.accuracy.p75_m),
            rel(a.surface_area_m2, b.surface_area_m2)
        );
    }
}

fn evaluate(a: EvaluateArgs) -> Result<()> {
    let gt = ground_truth_arg(
        &a.gt,
        a.poses.clone(),
        Some((a.first, a.last.unwrap_or(usize::MAX))),
        a.step,
    );
    let cloud = gt
        .load()
        .with_context(|| format!("loading ground truth {}", a.gt.display()))?;
    let mut meshes = Vec::new();
    for spec in &a.meshes {
        let (label, path) = match spec.split_once('=') {
            Some((l, p)) => (l.to_string(), PathBuf::from(p)),
            None => {
                let p = PathBuf::from(spec);
                (
                    p.file_stem()
                        .and_then(|s| s.to_str())
                        .unwrap_or("mesh")
                        .to_string(),
                    p,
                )
            }
        };
        let mesh = denser::io::ply::read_mesh_ply(&path)
            .with_context(|| format!("reading mesh {}", path.display()))?;
        meshes.push((label, mesh));
    }
    let refs: Vec<(&str, &denser::mesh::Mesh)> =
        meshes.iter().map(|(l, m)| (l.as_str(), m)).collect();
    let mut report = denser::eval::EvaluationReport::new(
        format!(
            "meshes scored by `denser evaluate`; ground truth: {}",
            gt.describe()
        ),
        cloud.len() as u64,
    );
    let written = pipeline::evaluate_meshes(&refs, &cloud, &mut report, None, &a.out)
        .context("evaluating")?;
    print_summary(&report);
    for p in written {
        println!("wrote {}", p.display());
    }
    Ok(())
}

fn bench(a: BenchArgs) -> Result<()> {
    let dir = a.rgbd.unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/rgbd_5frames_slambook2")
    });
    let report = pipeline::bench_rgbd(&dir, a.passes)
        .with_context(|| format!("benchmarking on {}", dir.display()))?;
    println!("{report}");
    Ok(())
}

fn synth(a: SynthArgs) -> Result<()> {
    let mut config = denser::synth::DriveConfig::default();
    config.city.seed = a.seed;
    config.city.length_m = a.length_m;
    config.city.frame_spacing_m = a.frame_spacing_m;
    config.city.max_frames = a.max_frames;
    if let Some(path) = &a.trajectory {
        config.city.trajectory = Some(denser::io::kitti::read_poses(path)?);
    }
    if a.no_lidar {
        config.lidar = None;
    }
    config.images = !a.lidar_only;
    if a.voxel_gt {
        if let Some(s) = config.surface.as_mut() {
            s.spacing_m = a.gt_spacing_m;
        }
    } else {
        config.surface = None;
    }
    let summary = denser::synth::write_drive(&config, &a.out, true)
        .with_context(|| format!("writing the drive to {}", a.out.display()))?;
    println!(
        "wrote {} frames over {:.0} m ({} primitives, {} LiDAR points, {} ground-truth surface points) to {} in {:.1} s",
        summary.frames,
        summary.route_length_m,
        summary.primitives,
        summary.lidar_points,
        summary.surface_points,
        summary.sequence_dir.display(),
        summary.build_s + summary.frames_s + summary.surface_s
    );
    Ok(())
}

fn demo(a: DemoArgs) -> Result<()> {
    let mut config = pipeline::DemoConfig::new(a.out.clone());
    config.length_m = a.length_m;
    config.frame_spacing_m = a.frame_spacing_m;
    config.seed = a.seed;
    config.config.tv.iterations = a.iterations;
    config.device = a.device.into();
    config.stereo_method = a.stereo_method.parse()?;
    let outcome = pipeline::demo(&config).context("running the demo")?;
    println!(
        "demo: {} frames over {:.0} m, reconstructed from stereo in {:.0} s in all",
        outcome.drive.frames, outcome.drive.route_length_m, outcome.total_s
    );
    print_summary(&outcome.report);
    for p in &outcome.written {
        println!("wrote {}", p.display());
    }
    println!(
        "synthetic drive (KITTI layout): {}",
        outcome.drive.sequence_dir.display()
    );
    Ok(())
}

fn stereo(a: StereoArgs) -> Result<()> {
    let job = pipeline::StereoJob {
        left: a.left.clone(),
        right: a.right.clone(),
        out: a.out.clone(),
        calib: a.calib,
        depth_out: a.depth_out.clone(),
        method: a.method.parse()?,
        num_disparities: a.num_disparities,
        dense: a.dense,
        device: a.device.into(),
    };
    let outcome = pipeline::stereo(&job).with_context(|| {
        format!(
            "stereo matching {} / {}",
            a.left.display(),
            a.right.display()
        )
    })?;
    println!(
        "{}: {}×{} px, {} valid disparities ({:.1} %), matched in {:.2} s",
        job.method,
        outcome.width,
        outcome.height,
        outcome.valid_px,
        100.0 * outcome.valid_px as f64 / (outcome.width as f64 * outcome.height as f64),
        outcome.matching_s
    );
    println!("wrote {}", a.out.display());
    if let Some(d) = a.depth_out {
        println!("wrote {}", d.display());
    }
    Ok(())
}

fn stereo_eval(a: StereoEvalArgs) -> Result<()> {
    let m = pipeline::stereo_eval(&a.gt, &a.pred, a.mask.as_deref())
        .with_context(|| format!("scoring {} against {}", a.pred.display(), a.gt.display()))?;
    println!("| metric | value |");
    println!("|---|---|");
    println!("| scored pixels | {} |", m.gt_pixels);
    println!("| bad-1.0 % | {:.2} |", m.bad1_pct);
    println!("| bad-2.0 % | {:.2} |", m.bad2_pct);
    println!("| bad-3.0 % | {:.2} |", m.bad3_pct);
    println!("| D1 % | {:.2} |", m.d1_pct);
    println!("| EPE px | {:.3} |", m.epe_px);
    println!("| density % | {:.2} |", m.density_pct);
    if let Some(path) = a.json {
        let text = serde_json::to_string_pretty(&m).context("serialising the scores")?;
        std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
