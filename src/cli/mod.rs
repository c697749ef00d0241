//! The `denser` command line, in ripgrep's shape: [`Cli`] parses, one module per command runs
//! it over the library and returns an outcome that implements `Display` (printed once, on
//! stdout), errors are printed once with their chain on stderr, and a closed stdout (`denser …
//! | head`) ends the program quietly. Flags that several commands share are groups defined here
//! once ([`GridArgs`], [`TvArgs`], [`RangeArgs`], [`DeviceArgs`], [`GpuPoolArgs`],
//! [`BudgetArgs`]), and the help text of every flag several commands share once ([`help`]).
//!
//! Exit codes: 0 success; 1 the command ran and found a problem it reports (`inspect --verify`
//! with damaged chunks); 2 an error (bad input, I/O, GPU) or a usage error.

mod bench;
mod demo;
mod evaluate;
mod export;
mod input;
mod inspect;
mod merge;
mod reconstruct;
mod regularize;
mod repair;
mod stereo;
mod synth;

use clap::{Args, Parser, Subcommand, ValueEnum};
use denser::backend::{AdapterClass, GpuStages, RECORDED_FASTER};
use denser::gpu::{DeviceChoice, ResidentOptions};
use denser::io::sequence::FrameRange;
use denser::reconstruct::ReconstructionConfig;
use std::fmt;
use std::io::Write;
use std::process::ExitCode;

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
    /// Fuse a sequence (KITTI odometry, TUM or simple RGB-D, a folder of scans, a ROS 2 bag),
    /// regularize, mesh and report.
    #[command(
        after_help = "Example:\n  denser reconstruct data/sequences/00 --depth lidar --out out/run\n  denser reconstruct data/sequences/00 --depth stereo --last 200 --out out/stereo\n  denser reconstruct data/sequences/00 --depth lidar --map maps/city --memory-budget 1GiB --out out/city\n  denser reconstruct drive_bag --lidar-topic /velodyne_points --out out/bag\n  denser reconstruct slam_out --poses slam_out/poses.tum --extrinsic lidar_to_imu.txt --out out/scans"
    )]
    Reconstruct(Box<reconstruct::Args>),
    /// Print fusion, regularization and meshing throughput on real RGB-D frames.
    #[command(
        after_help = "Example:\n  denser bench --rgbd drive/sequences/00 --passes 3 --max-depth-m 40"
    )]
    Bench(bench::Args),
    /// Synthesise a short city drive, reconstruct it from stereo, regularize, mesh and evaluate.
    #[command(after_help = "Example:\n  denser demo --out out/demo --method sgm")]
    Demo(demo::Args),
    /// Score meshes against ground truth (distance to the nearest ground-truth point, as the paper).
    #[command(
        after_help = "Example:\n  denser evaluate --mesh raw=out/run/mesh_raw.ply --mesh out/run/mesh_regularized.ply --gt data/sequences/00 --out out/eval"
    )]
    Evaluate(evaluate::Args),
    /// Generate a synthetic city drive with exact ground truth, in the KITTI odometry layout.
    #[command(
        after_help = "Example:\n  denser synth --out drives/d60 --length-m 60 --lidar-only\n  denser synth --out drives/kitti00 --trajectory poses/00.txt --length-m 5000 --lidar-only"
    )]
    Synth(synth::Args),
    /// Re-regularize a stored map region by region within a memory budget (resumable).
    #[command(
        after_help = "Example:\n  denser regularize maps/city --lambda 0.6 --iterations 200 --memory-budget 512MiB\n  denser regularize s3://city/maps/city --shard auto/16     # one task of an array job"
    )]
    Regularize(regularize::Args),
    /// Convert a stored map, tile by tile, to one mesh (PLY) or point cloud (PLY, LAS, LAZ).
    #[command(
        after_help = "Example:\n  denser export maps/city --mesh city.ply --regularized\n  denser export maps/city --points city.copc.laz --georef EPSG:32632@691000,5335000,500\n  denser export maps/city --tiles city_tiles"
    )]
    Export(export::Args),
    /// List what an input holds (a bag's topics, types, transforms) and what reconstruct would use.
    #[command(
        name = "inspect-input",
        after_help = "Example:\n  denser inspect-input drive.mcap\n  denser inspect-input recordings/bag_0 --lidar-topic /ouster/points --fixed-frame odom"
    )]
    InspectInput(input::Args),
    /// Summarise a stored map (chunks, blocks, voxels, bytes) and verify its checksums.
    #[command(after_help = "Example:\n  denser inspect maps/city --verify")]
    Inspect(inspect::Args),
    /// Combine maps of one grid and world frame (drives fused apart) into a new map, chunk by chunk.
    #[command(after_help = "Example:\n  denser merge maps/drive1 maps/drive2 --out maps/both")]
    Merge(merge::Args),
    /// Rebuild a lost or unreadable map manifest from the chunk files (newest intact versions).
    #[command(after_help = "Example:\n  denser repair maps/city")]
    Repair(repair::Args),
    /// Disparity (and depth) of one rectified stereo pair, written as Middlebury PFM.
    #[command(
        after_help = "Example:\n  denser stereo left.png right.png --out disp.pfm --calib calib.txt --depth-out depth.png"
    )]
    Stereo(stereo::Args),
    /// Score a disparity map against ground truth (bad-1/2/3, D1, EPE, density).
    #[command(
        after_help = "Example:\n  denser stereo-eval gt.pfm disp.pfm --mask nonocc.png --json-out scores.json"
    )]
    StereoEval(stereo::EvalArgs),
    /// Print the first GPU adapter as JSON and exit (what `--device auto` asks in a child
    /// process, so that probing costs the main process no memory).
    #[command(hide = true)]
    ProbeGpu,
}

/// What a command reports when it succeeds: printed once, on stdout.
pub(crate) type Outcome = Box<dyn fmt::Display>;

/// An outcome that also fails the run (exit 1): the command ran and found a problem.
#[derive(Debug)]
pub(crate) struct Problems(pub String);

impl fmt::Display for Problems {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Problems {}

/// Whether the log may be coloured: only on a terminal, and not when `NO_COLOR` is set to
/// anything (<https://no-color.org>). A log redirected to a file (Slurm, Kubernetes, `2>log`)
/// holds no escape codes.
fn colour_on_stderr() -> bool {
    use std::io::IsTerminal;
    std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty())
}

/// Parses the command line, runs the command, prints its outcome or its error once.
pub fn main() -> ExitCode {
    ensure_runtime_dir();
    install_signal_handlers();
    let cli = Cli::parse();
    // wgpu probes its GL backend too; EGL failing where only Vulkan exists is noise.
    let filter = tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| {
        tracing_subscriber::EnvFilter::new(format!("{},wgpu_hal::gles=off", cli.log))
    });
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(colour_on_stderr())
        .with_target(false)
        .init();
    let result = match cli.command {
        Command::Reconstruct(a) => reconstruct::run(*a),
        Command::Bench(a) => bench::run(a),
        Command::Synth(a) => synth::run(a),
        Command::Evaluate(a) => evaluate::run(a),
        Command::Demo(a) => demo::run(a),
        Command::Regularize(a) => regularize::run(a),
        Command::Export(a) => export::run(a),
        Command::Inspect(a) => inspect::run(a),
        Command::InspectInput(a) => input::run(a),
        Command::Merge(a) => merge::run(a),
        Command::Repair(a) => repair::run(a),
        Command::Stereo(a) => stereo::run(a),
        Command::StereoEval(a) => stereo::run_eval(a),
        Command::ProbeGpu => Ok(Box::new(
            serde_json::json!(denser::gpu::GpuContext::probe()).to_string() + "\n",
        ) as Outcome),
    };
    if std::env::var_os(denser::map::fault::FAULT_INJECTION_VARIABLE).is_some() {
        // For the crash suite (tests/cli/faults.rs): how many map operations this run made.
        eprintln!(
            "{}: {} map operations",
            denser::map::fault::FAULT_INJECTION_VARIABLE,
            denser::map::fault::operations()
        );
    }
    let printed = result.and_then(|outcome| {
        let mut out = std::io::stdout().lock();
        write!(out, "{outcome}")?;
        out.flush()?;
        Ok(())
    });
    match printed {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if is_broken_pipe(&e) => ExitCode::SUCCESS,
        Err(e) => {
            if let Some(p) = e.downcast_ref::<Problems>() {
                // The report itself, then the verdict.
                let _ = writeln!(std::io::stdout().lock(), "{p}");
                return ExitCode::from(1);
            }
            for line in error_lines(&e) {
                eprintln!("{line}");
            }
            ExitCode::from(2)
        }
    }
}

/// SIGINT and SIGTERM remove the unfinished outputs (`io::atomic`) and exit with 130; the map,
/// committed only by atomic renames, keeps its last commit. A file-size limit (SIGXFSZ) makes
/// writes fail with an error (and the same cleanup) instead of killing the process mid-file.
fn install_signal_handlers() {
    let _ = ctrlc::set_handler(|| {
        let removed = denser::io::atomic::remove_pending();
        let _ = writeln!(
            std::io::stderr(),
            "interrupted: {removed} unfinished output file(s) removed; a map keeps its last commit"
        );
        std::process::exit(130);
    });
    #[cfg(unix)]
    // SAFETY: setting a signal's disposition to SIG_IGN before any thread starts.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

/// The lines an error is printed as: `error: …`, then one `  caused by: …` per cause, except a
/// cause whose text the line above already holds (an error that prints its source in its own
/// message), which is not repeated.
fn error_lines(e: &anyhow::Error) -> Vec<String> {
    let mut lines = vec![format!("error: {e}")];
    let mut above = e.to_string();
    for cause in e.chain().skip(1) {
        let text = cause.to_string();
        if !above.contains(&text) {
            lines.push(format!("  caused by: {text}"));
        }
        above = text;
    }
    lines
}

/// Whether `e` is (caused by) a write to a closed pipe: the reader went away, which is not an
/// error of ours (`denser inspect MAP | head`).
fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
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

/// Parses a byte size: `1GiB`, `512MiB`, `64M` (binary), `2GB` (decimal), or plain bytes.
pub(crate) fn parse_bytes(s: &str) -> Result<u64, String> {
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

/// Mebibytes, for summaries.
pub(crate) fn mib(bytes: u64) -> f64 {
    bytes as f64 / (1u64 << 20) as f64
}

/// Where the computing stages run.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub(crate) enum DeviceArg {
    /// On a hardware GPU, the stages measured faster there than on the CPU (today TV
    /// regularization, stereo and meshing; fusion stays on the CPU); without one, the
    /// CPU.
    Auto,
    /// The CPU.
    Cpu,
    /// Every stage that has a kernel on the GPU, software adapters (lavapipe) included; an
    /// error when no adapter exists.
    Gpu,
}

/// `--device`.
#[derive(Args, Clone, Copy, Debug)]
pub(crate) struct DeviceArgs {
    #[arg(long, value_enum, default_value = "auto", help = help::DEVICE, help_heading = "Device")]
    pub device: DeviceArg,
}

/// The GPU block pool of the commands that fuse (`reconstruct`, `demo`).
#[derive(Args, Clone, Copy, Debug)]
pub(crate) struct GpuPoolArgs {
    /// Largest GPU block pool (4 KiB per block; bounded by the device's largest buffer). Fused
    /// blocks (depth frames' and LiDAR scans') stay on the GPU between frames; beyond this they
    /// spill to RAM.
    #[arg(long, default_value = "2GiB", value_parser = parse_bytes, help_heading = "Device")]
    pub gpu_memory_budget: u64,
}

impl GpuPoolArgs {
    /// The pool these flags ask for.
    pub fn options(&self) -> ResidentOptions {
        ResidentOptions {
            max_bytes: self.gpu_memory_budget,
            ..Default::default()
        }
    }
}

impl DeviceArgs {
    /// The backend these flags ask for, with the default GPU pool (the commands that do not
    /// fuse): [`DeviceArgs::backend_with`].
    pub fn backend(&self) -> denser::Result<denser::backend::Backend> {
        self.backend_with(ResidentOptions::default())
    }

    /// The backend these flags ask for, its GPU block pool within `options`. `auto` asks a
    /// child process (`denser probe-gpu`) which adapter exists, and opens it here only when it
    /// is a hardware GPU: loading a software driver to find out would cost this process its
    /// memory (~80 MiB of llvmpipe) for nothing.
    pub fn backend_with(
        &self,
        options: ResidentOptions,
    ) -> denser::Result<denser::backend::Backend> {
        let choice = match self.device {
            DeviceArg::Cpu => DeviceChoice::Cpu,
            DeviceArg::Gpu => DeviceChoice::Gpu,
            DeviceArg::Auto => match probe_in_child() {
                Some(Some((name, software))) => {
                    let class = AdapterClass::of(software);
                    if GpuStages::auto_rule(class, RECORDED_FASTER).any() {
                        tracing::debug!("probe: {class:?} adapter {name}");
                        DeviceChoice::Auto
                    } else {
                        // The summary names each stage's device: the probe's answer is a detail.
                        tracing::debug!(
                            "device: {name} ({class:?} adapter): no stage is recorded faster on \
                             one than on the CPU, running on the CPU (--device gpu uses it anyway)"
                        );
                        DeviceChoice::Cpu
                    }
                }
                Some(None) => {
                    tracing::debug!("device: no GPU adapter found, running on the CPU");
                    DeviceChoice::Cpu
                }
                // The probe itself failed (no executable path, a crash in a driver): decide
                // in this process, as without a probe.
                None => DeviceChoice::Auto,
            },
        };
        denser::backend::Backend::open(choice, options)
    }
}

/// Runs `denser probe-gpu` and reads its answer: `Some(None)` no adapter, `Some(Some((name,
/// software)))` one, `None` when the probe could not run.
fn probe_in_child() -> Option<Option<(String, bool)>> {
    let exe = std::env::current_exe().ok()?;
    let out = std::process::Command::new(exe)
        .args(["--log", "error", "probe-gpu"])
        .stderr(std::process::Stdio::null())
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    serde_json::from_slice(&out.stdout).ok()
}

/// The TV regularizer's parameters.
#[derive(Args, Clone, Copy, Debug)]
pub(crate) struct TvArgs {
    /// TV data weight λ (default: the paper's, 0.8 at 10 cm, 0.4 at 20 cm).
    #[arg(long, help_heading = "Regularization")]
    pub lambda: Option<f32>,
    /// Primal–dual iterations.
    #[arg(long, default_value_t = 100, help_heading = "Regularization")]
    pub iterations: u32,
}

impl TvArgs {
    /// The paper's parameters for `voxel_size_m` with these overrides.
    pub fn params(&self, voxel_size_m: f32) -> denser::regularize::TvParams {
        let mut tv = denser::regularize::TvParams::paper(voxel_size_m);
        if let Some(l) = self.lambda {
            tv.lambda = l;
        }
        tv.iterations = self.iterations;
        tv
    }
}

/// The map's grid and the fusion limits.
#[derive(Args, Clone, Copy, Debug)]
pub(crate) struct GridArgs {
    /// Voxel edge, metres (paper: 0.10 or 0.20).
    #[arg(
        long = "voxel-size-m",
        alias = "voxel-size",
        default_value_t = 0.1,
        help_heading = "Map"
    )]
    pub voxel_size_m: f32,
    /// Truncation μ, metres (default: the paper's, 1.0 at 10 cm and 1.6 at 20 cm, else 10 voxels).
    #[arg(long = "truncation-m", alias = "truncation", help_heading = "Map")]
    pub truncation_m: Option<f32>,
    #[arg(long = "max-depth-m", alias = "max-depth", help = help::MAX_DEPTH_M, help_heading = "Map")]
    pub max_depth_m: Option<f32>,
}

impl GridArgs {
    /// The reconstruction settings for these flags and the regularizer's.
    pub fn config(&self, tv: &TvArgs) -> ReconstructionConfig {
        let mut c = ReconstructionConfig::paper(self.voxel_size_m);
        if let Some(t) = self.truncation_m {
            c.grid.truncation_m = t;
        }
        c.tv = tv.params(self.voxel_size_m);
        if let Some(d) = self.max_depth_m {
            c.depth_fusion.max_depth_m = d;
            c.lidar_fusion.max_range_m = d;
        }
        c
    }
}

pub(crate) mod help;

/// Which frames of a sequence.
#[derive(Args, Clone, Copy, Debug)]
pub(crate) struct RangeArgs {
    /// First frame.
    #[arg(long, default_value_t = 0, help_heading = "Frames")]
    pub first: usize,
    /// One past the last frame (default: all).
    #[arg(long, help_heading = "Frames")]
    pub last: Option<usize>,
    /// Use every n-th frame.
    #[arg(long, default_value_t = 1, help_heading = "Frames")]
    pub step: usize,
}

impl RangeArgs {
    /// The range.
    pub fn range(&self) -> FrameRange {
        FrameRange {
            first: self.first,
            last: self.last,
            step: self.step,
        }
    }
}

/// The memory budget of out-of-core work.
#[derive(Args, Clone, Copy, Debug)]
pub(crate) struct BudgetArgs {
    #[arg(long, default_value = "1GiB", value_parser = parse_bytes, help = help::MEMORY_BUDGET, help_heading = "Out of core")]
    pub memory_budget: u64,
    /// Regularization region edge, chunks (bigger regions spend less on halos, need more
    /// memory); by default the largest whose working memory fits --memory-budget.
    #[arg(long, help_heading = "Out of core")]
    pub region_chunks: Option<u32>,
    /// Regularization iterations per sweep: every region this many iterations at a time, the
    /// solver state kept in the map between sweeps, a halo of (this + 1) voxels (15: two blocks, 7: one);
    /// 0 solves each region with all iterations at once and the exact halo.
    #[arg(long, default_value_t = denser::outofcore::sweeps::DEFAULT_SWEEP_ITERATIONS, help_heading = "Out of core")]
    pub sweep_iterations: u32,
}

impl BudgetArgs {
    /// Regional regularization within this budget.
    pub fn regional(&self) -> denser::Result<denser::outofcore::regional::RegionalOptions> {
        if self.region_chunks == Some(0) {
            return Err(denser::Error::InvalidArgument(
                "--region-chunks must be at least 1 (leave it out to fit the budget)".into(),
            ));
        }
        Ok(denser::outofcore::regional::RegionalOptions {
            region_chunks: self.region_chunks.unwrap_or(0),
            budget_bytes: denser::memory::data_share_bytes(self.memory_budget),
            halo_blocks: None,
            sweep_iterations: (self.sweep_iterations > 0).then_some(self.sweep_iterations),
        })
    }
}

/// The stereo matchers, as the CLI names them.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub(crate) enum StereoArg {
    /// Census + semi-global matching (the baseline).
    Sgm,
    /// Census + first-order TV (variational).
    Tv,
    /// Census + isotropic TGV.
    Tgv,
    /// Census + TGV with the anisotropic tensor (the paper's).
    TgvTensor,
}

impl From<StereoArg> for denser::depth::StereoMethod {
    fn from(s: StereoArg) -> Self {
        use denser::depth::StereoMethod as M;
        match s {
            StereoArg::Sgm => M::Sgm,
            StereoArg::Tv => M::Tv,
            StereoArg::Tgv => M::Tgv,
            StereoArg::TgvTensor => M::TgvTensor,
        }
    }
}

/// The paper's table (median, 75th percentile, mode, area) for each surface, and the changes of
/// the second against the first.
pub(crate) struct EvaluationTable<'a>(pub &'a denser::eval::EvaluationReport);

impl fmt::Display for EvaluationTable<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let report = self.0;
        for n in &report.notes {
            writeln!(f, "note: {n}")?;
        }
        // With a coverage mask the accuracy columns are the scored points' (where the LiDAR
        // could have measured); every point's figures are in report.md's "all points" rows.
        let scored = report.coverage.is_some();
        if scored {
            writeln!(
                f,
                "accuracy scored where the LiDAR could have measured (all points: report.md)"
            )?;
        }
        writeln!(
            f,
            "{:<12} {:>10} {:>10} {:>10} {:>12} {:>12}",
            "surface",
            if scored { "median m*" } else { "median m" },
            if scored { "p75 m*" } else { "p75 m" },
            "mode m",
            "area m²",
            "complete m"
        )?;
        for s in &report.surfaces {
            writeln!(
                f,
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
            )?;
        }
        if let (Some(a), Some(b)) = (report.surfaces.first(), report.surfaces.get(1)) {
            let rel = |x: f64, y: f64| 100.0 * (y - x) / x.max(1e-12);
            writeln!(
                f,
                "{} vs {}: median {:+.0} %, p75 {:+.0} %, area {:+.0} %",
                b.label,
                a.label,
                rel(a.accuracy.median_m, b.accuracy.median_m),
                rel(a.accuracy.p75_m, b.accuracy.p75_m),
                rel(a.surface_area_m2, b.surface_area_m2)
            )?;
        }
        Ok(())
    }
}

/// One `wrote PATH` line per file.
pub(crate) struct Written<'a>(pub &'a [std::path::PathBuf]);

impl fmt::Display for Written<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for p in self.0 {
            writeln!(f, "wrote {}", p.display())?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
