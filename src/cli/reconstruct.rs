//! `denser reconstruct`: a sequence through fusion, regularization, meshing and evaluation, the
//! map in RAM or, with `--map`, in a directory of chunk files paged within a budget (resumable).
//! Both run the same lines over a different store.

use super::{
    help, BudgetArgs, DeviceArgs, GpuPoolArgs, GridArgs, Outcome, RangeArgs, StereoArg, TvArgs,
};
use anyhow::{Context, Result};
use clap::ValueEnum;
use denser::backend::Backend;
use denser::depth::tgv::HoleFill;
use denser::depth::StereoMethod;
use denser::eval::{evaluate_reconstruction, GroundTruth, RunFacts};
use denser::io::sequence::{
    detect_input, open_input, FrameRange, InputKind, RangeSource, Sequence,
};
use denser::map::job::{relative_hint, JobRecord};
use denser::map::layout::MANIFEST_FILE;
use denser::map::manifest::FRAMES_UNKNOWN;
use denser::map::store::MapStore;
use denser::map::MapLocation;
use denser::memory::peak_rss_bytes;
use denser::outofcore::pager::{OverrunPolicy, PagerConfig};
use denser::outofcore::regional::check_budget_up_front;
use denser::outofcore::PagedStore;
use denser::reconstruct::{ReconstructionConfig, Reconstructor};
use denser::store::{BlockStore, MemoryStore};
use std::path::{Path, PathBuf};

mod report;
pub(crate) use report::{RegularizeLine, Report};

#[derive(clap::Args)]
pub(crate) struct Args {
    /// The input: a KITTI `sequences/NN` folder, TUM RGB-D, numbered RGB-D (`pose.txt`,
    /// `depth/`), a folder of scans (`scans/` and a trajectory) or a ROS 2 bag (a folder with
    /// `metadata.yaml`, or an .mcap / .db3 file).
    input: PathBuf,
    #[arg(long, default_value = "out", help = help::OUT)]
    out: PathBuf,
    /// Range source for KITTI-layout input.
    #[arg(long, value_enum, default_value = "lidar")]
    depth: DepthArg,
    #[command(flatten)]
    how: super::input::InputArgs,
    #[command(flatten)]
    range: RangeArgs,
    #[arg(long, help = help::GT, help_heading = "Evaluation")]
    gt: Option<PathBuf>,
    /// Skip the evaluation.
    #[arg(long, help_heading = "Evaluation")]
    no_eval: bool,
    /// Leave every K-th frame's LiDAR scan out of fusion and score against those scans alone
    /// (with --depth lidar, scoring against the fused scans measures consistency, not
    /// accuracy). KITTI-layout input, in RAM (not with --map or --gt); K ≥ 2.
    #[arg(long, value_name = "K", help_heading = "Evaluation")]
    holdout: Option<usize>,
    #[arg(long, value_enum, default_value = "tgv-tensor", help = help::METHOD, help_heading = "Stereo (--depth stereo)")]
    method: StereoArg,
    #[arg(long, default_value_t = 128, help = help::NUM_DISPARITIES, help_heading = "Stereo (--depth stereo)")]
    num_disparities: usize,
    #[command(flatten)]
    device: DeviceArgs,
    #[command(flatten)]
    gpu_pool: GpuPoolArgs,
    #[arg(long, help = help::KERNEL_TIMES, help_heading = "Device")]
    kernel_times: bool,
    #[command(flatten)]
    grid: GridArgs,
    #[command(flatten)]
    tv: TvArgs,
    #[command(flatten)]
    map: MapArgs,
}

/// Where range data comes from for KITTI-layout input.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum DepthArg {
    /// Velodyne scans.
    Lidar,
    /// Ground-truth depth maps of a synthetic drive.
    Gt,
    /// Stereo matching on the image pairs.
    Stereo,
}

/// `--map` and its out-of-core settings.
#[derive(clap::Args, Clone, Debug)]
pub(crate) struct MapArgs {
    /// Stream the map through this directory (or s3://bucket/prefix) of compressed chunk files
    /// (created, or resumed when it holds a map of the same job) instead of keeping it in RAM.
    #[arg(long, value_name = "MAP", help_heading = "Out of core")]
    map: Option<MapLocation>,
    #[command(flatten)]
    budget: BudgetArgs,
    /// Chunk edge in blocks (a chunk is one file; 16 blocks = 12.8 m at 10 cm voxels). Default:
    /// 16, or 8 or 4 when regularizing one chunk of 16 (or 8) with its halo might not fit the
    /// memory budget.
    #[arg(long, help_heading = "Out of core")]
    chunk_blocks: Option<u32>,
    /// Commit a resumable checkpoint every this many frames (0: only at the end).
    #[arg(long, default_value_t = 50, help_heading = "Out of core")]
    checkpoint_every: u64,
    /// Go on (with a warning) when one frame needs more than the budget, instead of stopping.
    #[arg(long, help_heading = "Out of core")]
    allow_overrun: bool,
    /// Fuse (and mesh the raw field) only; regularize later with `denser regularize`.
    #[arg(long, help_heading = "Out of core")]
    skip_regularize: bool,
}

/// A reconstruction to run: the command's flags, resolved (the demo builds one too).
pub(crate) struct Job {
    pub input: PathBuf,
    /// How to read it (poses, extrinsic, a bag's topics).
    pub how: super::input::InputArgs,
    pub out_dir: PathBuf,
    pub source: RangeSource,
    pub range: FrameRange,
    pub config: ReconstructionConfig,
    pub stereo_method: StereoMethod,
    pub num_disparities: usize,
    /// `None`: in RAM.
    pub map: Option<MapJob>,
    pub regularize: bool,
    /// Ground truth for the report (`None`: no evaluation).
    pub ground_truth: Option<GroundTruth>,
    /// With `Some(k)`, every k-th selected frame is not fused (its scan is the ground truth).
    pub holdout: Option<usize>,
    /// Sentences the report must carry about its ground truth.
    pub evaluation_notes: Vec<String>,
    /// Stages before the reconstruction, for the report (the demo's synthesis).
    pub earlier_timings_s: Vec<(String, f64)>,
}

/// Out-of-core settings of a job.
pub(crate) struct MapJob {
    pub dir: MapLocation,
    pub budget: BudgetArgs,
    pub chunk_blocks: Option<u32>,
    pub checkpoint_every: u64,
    pub overrun: OverrunPolicy,
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    // An input that is not there, or of no known layout, is refused before anything else runs
    // (the GPU probe included).
    let kind =
        detect_input(&a.input).with_context(|| format!("reconstructing {}", a.input.display()))?;
    let config = a.grid.config(&a.tv);
    let range = a.range.range();
    let mut evaluation_notes = Vec::new();
    let ground_truth = if let Some(k) = a.holdout {
        let kitti = kind == InputKind::Kitti
            || (kind.lidar_or_stereo() && matches!(a.depth, DepthArg::Lidar));
        let refused = if k < 2 {
            Some("K must be at least 2 (every K-th frame is left out)")
        } else if a.no_eval || a.gt.is_some() {
            Some("it is the ground truth: not with --no-eval or --gt")
        } else if a.map.map.is_some() {
            Some("held-out runs are evaluations in RAM: not with --map")
        } else if !kitti {
            Some("it needs LiDAR scans to leave out: a KITTI-layout sequence, or a folder of scans or a bag with --depth lidar")
        } else {
            None
        };
        if let Some(why) = refused {
            anyhow::bail!("--holdout {k}: {why}");
        }
        evaluation_notes.push(format!(
            "Ground truth: the LiDAR scans of one selected frame in {k}, left out of fusion (--holdout {k})."
        ));
        Some(scans_of_input(&a, kind, held_out_range(range, k)))
    } else if a.no_eval {
        None
    } else {
        match (&a.gt, kind) {
            // `--poses` is the input's: it poses a KITTI `--gt` only when the input is KITTI too
            // (the same drive), never a folder of scans' or bag's ground truth.
            (Some(p), kind) => Some(GroundTruth::from_path(
                p.clone(),
                a.how.poses.clone().filter(|_| kind == InputKind::Kitti),
                range,
            )),
            // A KITTI layout fused from its images or depth maps, with no scans to score
            // against (a drive made with `synth --no-lidar`): nothing to evaluate, said once,
            // rather than an error after the whole run.
            (None, InputKind::Kitti)
                if !matches!(a.depth, DepthArg::Lidar) && !has_scans(&a.input.join("velodyne")) =>
            {
                tracing::info!(
                    "not evaluating: {} holds no LiDAR scan to score against (--gt FILE gives a \
                     ground truth)",
                    a.input.join("velodyne").display()
                );
                None
            }
            (None, kind)
                if kind == InputKind::Kitti
                    || (kind.lidar_or_stereo() && matches!(a.depth, DepthArg::Lidar)) =>
            {
                if matches!(a.depth, DepthArg::Lidar) {
                    evaluation_notes.push(
                        "The ground truth is the LiDAR that was fused: these scores measure how \
                         well the map agrees with its own input, not its accuracy. `--holdout K` \
                         scores against scans left out of fusion."
                            .to_string(),
                    );
                }
                Some(scans_of_input(&a, kind, range))
            }
            _ => None,
        }
    };
    let job = Job {
        input: a.input.clone(),
        how: a.how.clone(),
        out_dir: a.out.clone(),
        source: match a.depth {
            DepthArg::Lidar => RangeSource::Lidar,
            DepthArg::Gt => RangeSource::GroundTruthDepth,
            DepthArg::Stereo => RangeSource::Stereo,
        },
        range,
        config,
        stereo_method: a.method.into(),
        num_disparities: a.num_disparities,
        map: a.map.map.as_ref().map(|dir| MapJob {
            dir: dir.clone(),
            budget: a.map.budget,
            chunk_blocks: a.map.chunk_blocks,
            checkpoint_every: a.map.checkpoint_every,
            overrun: if a.map.allow_overrun {
                OverrunPolicy::Warn
            } else {
                OverrunPolicy::Error
            },
        }),
        regularize: !a.map.skip_regularize,
        ground_truth,
        holdout: a.holdout,
        evaluation_notes,
        earlier_timings_s: Vec::new(),
    };
    let backend = a.device.backend_with(a.gpu_pool.options())?;
    let timed = match backend.gpu_context() {
        Some(ctx) if a.kernel_times => Some((ctx.clone(), ctx.start_kernel_timing())),
        _ => None,
    };
    let mut report = run_job(&job, backend)?;
    report.kernel_times = timed.map(|(ctx, on)| match on {
        true => super::bench::kernel_table(&ctx),
        false => format!("{}: no timestamp queries, kernels not timed\n", ctx.name()),
    });
    Ok(Box::new(report))
}

/// The frames `--holdout k` leaves out of `range`: every k-th selected frame, the first at
/// position k − 1 (the fusion keeps the others).
/// The input's own LiDAR scans of `frames` as ground truth.
/// Whether `dir` holds a KITTI scan file (`*.bin`).
fn has_scans(dir: &Path) -> bool {
    std::fs::read_dir(dir).is_ok_and(|entries| {
        entries.flatten().any(|e| {
            e.path()
                .extension()
                .is_some_and(|x| x.eq_ignore_ascii_case("bin"))
        })
    })
}

fn scans_of_input(a: &Args, kind: InputKind, frames: FrameRange) -> GroundTruth {
    if kind == InputKind::Kitti {
        GroundTruth::KittiLidar {
            sequence: a.input.clone(),
            poses: a.how.poses.clone(),
            frames,
        }
    } else {
        GroundTruth::Scans {
            input: a.input.clone(),
            options: a.how.options(RangeSource::Lidar),
            frames,
        }
    }
}

fn held_out_range(range: FrameRange, k: usize) -> FrameRange {
    let step = range.step.max(1);
    FrameRange {
        first: range.first + (k - 1) * step,
        last: range.last,
        step: k * step,
    }
}

/// Every file a reconstruction may write into its output folder (besides `top_view_*.png` and
/// `view_*.png`).
const OUTPUT_FILES: &[&str] = &[
    "mesh_raw.ply",
    "mesh_regularized.ply",
    "points_regularized.ply",
    "report.json",
    "report.md",
    "error_histogram.png",
    "map_report.json",
];

/// Removes the outputs of an earlier run that this run did not rewrite (a report beside meshes
/// it no longer describes), so the folder holds one run's results.
fn remove_stale_outputs(out_dir: &std::path::Path, written: &[PathBuf]) -> std::io::Result<()> {
    for entry in std::fs::read_dir(out_dir)? {
        let path = entry?.path();
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let ours = OUTPUT_FILES.contains(&name.as_str())
            || ((name.starts_with("top_view_") || name.starts_with("view_"))
                && name.ends_with(".png"));
        if ours && !written.iter().any(|w| w.file_name() == path.file_name()) {
            tracing::info!("removing {} (an earlier run's output)", path.display());
            std::fs::remove_file(&path)?;
        }
    }
    Ok(())
}

/// Runs `job` with `backend`'s stages: fusion (resuming a map), regularization, surfaces,
/// evaluation.
pub(crate) fn run_job(job: &Job, backend: Backend) -> Result<Report> {
    let context = || match &job.map {
        Some(m) => format!("reconstructing {} into map {}", job.input.display(), m.dir),
        None => format!("reconstructing {}", job.input.display()),
    };
    let stereo = match job.source {
        RangeSource::Stereo => Some(
            backend
                .stereo_matcher(
                    job.stereo_method,
                    denser::depth::SgmParams {
                        num_disparities: job.num_disparities,
                        ..Default::default()
                    },
                    HoleFill::None,
                )
                .with_context(context)?,
        ),
        _ => None,
    };
    let stereo_device = stereo.as_ref().map(|_| backend.stereo_device());
    // Where the results go is checked before any work (a file, a read-only folder, no space).
    denser::io::atomic::check_output_dir(&job.out_dir)
        .with_context(|| format!("checking the output folder {}", job.out_dir.display()))?;
    let mut options = job.how.options(job.source);
    if backend.keeps_depth_on_device() {
        // Stereo and fusion on one GPU: the depths stay there between them.
        options.depth_on_device = Some((job.config.grid, job.config.depth_fusion));
    }
    let seq = open_input(&job.input, &options, stereo).with_context(context)?;
    let frames = job
        .range
        .select(seq.len(), &seq.describe())
        .with_context(context)?;
    let store: Box<dyn BlockStore> = match &job.map {
        None => Box::new(MemoryStore::new(job.config.grid).with_limit(ram_limit_bytes())),
        Some(m) => Box::new(open_map(job, m, seq.as_ref()).with_context(context)?),
    };
    let checkpoint_every = job.map.as_ref().map_or(0, |m| m.checkpoint_every);
    let mut rec = Reconstructor::with_store(job.config, store, backend, checkpoint_every)?;
    let resumed = rec.frames_committed();
    let frames: Vec<usize> = match job.holdout {
        // The k-th selected frame is held out when k ≡ K − 1 (mod K): `held_out_range`'s frames.
        Some(k) => frames
            .iter()
            .enumerate()
            .filter(|(i, _)| i % k != k - 1)
            .map(|(_, f)| *f)
            .collect(),
        None => frames,
    };
    rec.fuse_sequence(seq.as_ref(), &frames)
        .with_context(context)?;
    // The input (with the stereo matcher's cost volumes) is done with: free it before the
    // regularizer allocates its arrays, so their memory does not add up.
    let input = seq.describe();
    drop(seq);
    denser::memory::release_free_memory();
    let bar = denser::progress::bar(0, "regularizing");
    let results = rec
        .write_results(&job.out_dir, job.regularize, &mut |done, total| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
            true
        })
        .with_context(context)?;
    bar.finish_and_clear();
    let mut written = results.files();
    let (surfaces, regularize) = (results.surfaces, results.regularize);
    // The map is done with: free it before the evaluation loads the ground truth, so the two do
    // not add up.
    let (run, gpu_stats, gpu_traffic) = (
        RunFacts::of(&rec).with_memory_budget(job.map.as_ref().map(|m| m.budget.memory_budget)),
        rec.resident_stats(),
        rec.gpu_traffic(),
    );
    let fusion_device = rec.backend().fusion_device_name();
    let gpu_kernels = rec.backend().gpu_context().map(|c| c.kernel_compilation());
    // A paged map's surfaces are meshed chunk by chunk by the exporter, on the CPU.
    let mesh_device = match rec.gpu_traffic() {
        Some(g) if g.meshes > 0 => rec.backend().device_name(),
        _ => "CPU".to_string(),
    };
    drop(rec);
    // The map's blocks (3 KiB each) were freed into glibc's arenas, which keep them resident.
    denser::memory::release_free_memory();
    let evaluation = match &job.ground_truth {
        Some(gt) => {
            let (report, files) = evaluate_reconstruction(
                &run,
                &surfaces,
                regularize.as_ref(),
                gt,
                &input,
                &job.earlier_timings_s,
                &job.out_dir,
            )
            .context("evaluating")?;
            let mut report = report;
            if !job.evaluation_notes.is_empty() {
                // The notes belong in the written report too: rewritten with them.
                report.notes = job.evaluation_notes.clone();
                report.write_json(job.out_dir.join("report.json"))?;
                report.write_markdown(job.out_dir.join("report.md"))?;
            }
            written.extend(files);
            Some(report)
        }
        None => None,
    };
    let report = Report {
        input,
        device: run.device,
        fusion_device,
        mesh_device,
        stereo_device,
        frames: frames.len(),
        resumed_from_frame: resumed,
        timings: run.timings,
        summary: run.summary,
        gpu: gpu_stats,
        gpu_traffic,
        gpu_kernels,
        kernel_times: None,
        regularize,
        surfaces,
        evaluation,
        written,
        peak_rss_bytes: peak_rss_bytes(),
    };
    let mut report = report;
    if job.map.is_some() {
        let path = job.out_dir.join("map_report.json");
        denser::io::atomic::write_file(
            &path,
            serde_json::to_string_pretty(&report.json())?.as_bytes(),
        )?;
        report.written.push(path);
    }
    remove_stale_outputs(&job.out_dir, &report.written)
        .with_context(|| format!("cleaning {}", job.out_dir.display()))?;
    Ok(report)
}

/// RAM an in-memory run may plan to use: `DENSER_RAM_LIMIT` (e.g. `8GiB`) when set, else 90 % of
/// the smaller of the memory available at start and the cgroup's limit (containers).
fn ram_limit_bytes() -> u64 {
    if let Some(v) = std::env::var_os("DENSER_RAM_LIMIT") {
        match super::parse_bytes(&v.to_string_lossy()) {
            Ok(b) => return b,
            Err(e) => tracing::warn!("DENSER_RAM_LIMIT: {e}; ignored"),
        }
    }
    let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap_or_default();
    let available = meminfo
        .lines()
        .find(|l| l.starts_with("MemAvailable:"))
        .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        .map_or(u64::MAX, |kb| kb * 1024);
    let cgroup = std::fs::read_to_string("/sys/fs/cgroup/memory.max")
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok())
        .unwrap_or(u64::MAX);
    let limit = available.min(cgroup);
    if limit == u64::MAX {
        u64::MAX
    } else {
        limit / 10 * 9
    }
}

/// The chunk edge of a new map when `--chunk-blocks` is not given: the default, halved while
/// regularizing one chunk with its halo might not fit the budget (`check`), down to 4 blocks
/// (whose refusal, if even that does not fit, names the budget that would do).
fn planned_chunk_blocks(check: impl Fn(u32) -> denser::Result<()>) -> denser::Result<u32> {
    let mut c = denser::map::DEFAULT_CHUNK_BLOCKS;
    loop {
        match check(c) {
            Ok(()) => {
                if c != denser::map::DEFAULT_CHUNK_BLOCKS {
                    tracing::info!(
                        "chunks of {c}³ blocks, so that regularizing one region fits the memory budget"
                    );
                }
                return Ok(c);
            }
            Err(e) if c <= 4 => return Err(e),
            Err(_) => c /= 2,
        }
    }
}

/// Opens (resuming) or creates the job's map, checking its job record.
fn open_map(job: &Job, m: &MapJob, seq: &dyn Sequence) -> denser::Result<PagedStore> {
    // Fusion within the budget: large buffers go straight back to the kernel.
    denser::memory::map_large_allocations();
    // Regularization's memory is checked before any frame is fused (issue 15): a run never fuses
    // for minutes and then finds its budget too small for one region.
    let regional = m.budget.regional()?;
    let check = |chunk_blocks: u32| -> denser::Result<()> {
        if job.regularize {
            check_budget_up_front(chunk_blocks, &regional, job.config.tv.iterations)?;
        }
        Ok(())
    };
    let source = match detect_input(&job.input)? {
        InputKind::Kitti => job.source.as_str(),
        kind if kind.lidar_or_stereo() => job.source.as_str(),
        _ => "rgbd",
    };
    let stereo = job.source == RangeSource::Stereo && source == "stereo";
    let record = JobRecord {
        source: source.to_string(),
        input_fingerprint: seq.fingerprint(),
        input_frames: seq.len() as u64,
        first_frame: job.range.first as u64,
        last_frame: job.range.last.map(|l| l as u64),
        frame_step: job.range.step.max(1) as u64,
        voxel_size_m: job.config.grid.voxel_size_m,
        truncation_m: job.config.grid.truncation_m,
        max_depth_m: if source == "lidar" {
            job.config.lidar_fusion.max_range_m
        } else {
            job.config.depth_fusion.max_depth_m
        },
        stereo_method: if stereo {
            job.stereo_method.as_str().to_string()
        } else {
            String::new()
        },
        num_disparities: if stereo {
            job.num_disparities as u32
        } else {
            0
        },
        input_hint: String::new(),
        created_by: format!("denser {}", env!("CARGO_PKG_VERSION")),
    };
    let exists = match m.dir.as_dir() {
        Some(d) => d.join(MANIFEST_FILE).exists(),
        None => m.dir.open_files()?.exists(MANIFEST_FILE)?,
    };
    let mut store = if exists {
        // The writer lock first: the job record is checked (and a legacy one upgraded) under it.
        let store = MapStore::open_at(&m.dir)?;
        check(store.chunk_blocks())?;
        if store.manifest().header.frames_committed == FRAMES_UNKNOWN {
            return Err(denser::Error::bad_input(
                m.dir.display_path(),
                "this map's manifest was rebuilt by `denser repair`, which cannot know how many frames were fused: fusion cannot resume it (regularize, export and inspect work); reconstruct into a new --map folder",
            ));
        }
        record.check_or_write_at(
            &**store.files(),
            &job.input,
            store.manifest().header.frames_committed,
        )?;
        store
    } else {
        let chunk_blocks = match m.chunk_blocks {
            Some(c) => {
                check(c)?;
                c
            }
            None => planned_chunk_blocks(check)?,
        };
        let s = MapStore::create_at(&m.dir, job.config.grid, chunk_blocks)?;
        let hint = match m.dir.as_dir() {
            Some(d) => relative_hint(d, &job.input),
            None => job.input.display().to_string(),
        };
        JobRecord {
            input_hint: hint,
            ..record
        }
        .write_at(&**s.files())?;
        s
    };
    store.set_cache_budget(m.budget.memory_budget / 4);
    Ok(PagedStore::new(
        store,
        PagerConfig {
            budget_bytes: denser::memory::data_share_bytes(m.budget.memory_budget),
            overrun: m.overrun,
            writer_threads: 2,
        },
        regional,
        denser::export::write_map_surface,
    ))
}
