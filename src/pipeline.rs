//! End-to-end jobs used by the CLI: read a sequence, fuse, regularise, mesh, write, evaluate.
//! Everything here is orchestration; the stages live in their own modules.

use crate::frame::{Image, PointCloud};
use crate::io::kitti::KittiSequence;
use crate::io::rgbd::{SimpleRgbdOptions, SimpleRgbdSequence, TumOptions, TumRgbdSequence};
use crate::io::DepthSequence;
use crate::mesh::{Field, Mesh};
use crate::reconstruct::{ReconstructionConfig, Reconstructor};
use crate::regularize::RegularizeStats;
use crate::{Error, Result};
use std::path::{Path, PathBuf};

/// The layouts `denser reconstruct` understands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputKind {
    /// KITTI odometry: a `sequences/NN` folder with `calib.txt`.
    Kitti,
    /// TUM RGB-D: `depth.txt`, `rgb.txt`, `groundtruth.txt`.
    Tum,
    /// Numbered RGB-D frames: `depth/N.pgm|png`, `color/N.png`, `pose.txt`.
    SimpleRgbd,
}

/// Recognises the layout of `dir`.
pub fn detect_input(dir: &Path) -> Result<InputKind> {
    if !dir.is_dir() {
        return Err(Error::bad_input(
            dir,
            "not a directory (expected a KITTI sequence or an RGB-D folder)",
        ));
    }
    if dir.join("calib.txt").is_file() {
        Ok(InputKind::Kitti)
    } else if dir.join("depth.txt").is_file() {
        Ok(InputKind::Tum)
    } else if dir.join("pose.txt").is_file() && dir.join("depth").is_dir() {
        Ok(InputKind::SimpleRgbd)
    } else {
        Err(Error::bad_input(
            dir,
            "unrecognised layout: expected calib.txt (KITTI odometry), depth.txt (TUM RGB-D) or pose.txt with depth/ (simple RGB-D)",
        ))
    }
}

/// Where range data comes from for a KITTI-layout sequence.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum RangeSource {
    /// Velodyne scans.
    Lidar,
    /// Ground-truth depth maps (`depth_gt/`, written by `denser synth`).
    GroundTruthDepth,
    /// Depth from the stereo pair (image_2/image_3 or image_0/image_1).
    Stereo,
}

/// A `reconstruct` job.
#[derive(Clone, Debug)]
pub struct ReconstructJob {
    /// Sequence folder.
    pub input: PathBuf,
    /// KITTI poses file, when not at `<root>/poses/NN.txt`.
    pub poses: Option<PathBuf>,
    /// Output folder (created).
    pub out_dir: PathBuf,
    /// Range source for KITTI-layout input.
    pub source: RangeSource,
    /// Stages' parameters.
    pub config: ReconstructionConfig,
    /// First frame and one past the last (all frames when `None`).
    pub frames: Option<(usize, usize)>,
    /// Use every n-th frame.
    pub frame_step: usize,
    /// Stereo matcher for [`RangeSource::Stereo`].
    pub stereo_method: crate::depth::StereoMethod,
    /// Disparity search range, pixels.
    pub num_disparities: usize,
    /// Where depth fusion and regularisation run (LiDAR fusion and meshing use the CPU).
    pub device: crate::gpu::DeviceChoice,
    /// Largest GPU block pool, bytes (4 KiB per block), when fusing on a GPU.
    pub gpu_budget_bytes: u64,
}

/// What a reconstruction produced.
#[derive(Debug)]
pub struct ReconstructOutcome {
    /// The map and its timings.
    pub reconstructor: Reconstructor,
    /// Mesh of the raw field.
    pub raw: Mesh,
    /// Mesh of the regularised field.
    pub regularized: Mesh,
    /// Regulariser counters.
    pub regularize_stats: RegularizeStats,
    /// Files written.
    pub written: Vec<PathBuf>,
    /// Voxels in Ω before regularisation.
    pub observed_voxels: usize,
}

fn frame_indices(len: usize, frames: Option<(usize, usize)>, step: usize) -> Vec<usize> {
    let (a, b) = frames.unwrap_or((0, len));
    (a.min(len)..b.min(len)).step_by(step.max(1)).collect()
}

/// Opens an RGB-D folder of either layout as a depth sequence.
pub fn open_depth_sequence(dir: &Path, kind: InputKind) -> Result<Box<dyn DepthSequence>> {
    Ok(match kind {
        InputKind::Tum => Box::new(TumRgbdSequence::open(dir, TumOptions::default())?),
        InputKind::SimpleRgbd => Box::new(SimpleRgbdSequence::open(
            dir,
            SimpleRgbdOptions::slambook2(),
        )?),
        InputKind::Kitti => {
            return Err(Error::bad_input(
                dir,
                "a KITTI sequence is not an RGB-D sequence",
            ))
        }
    })
}

/// All Velodyne scans of the given frames in the world frame: the paper's ground truth.
pub fn merged_lidar(seq: &KittiSequence, frames: &[usize]) -> Result<PointCloud> {
    let mut cloud = PointCloud::default();
    for &i in frames {
        if !seq.has_velodyne(i) {
            continue;
        }
        let scan = seq.velodyne(i)?;
        let t = scan.world_from_sensor;
        cloud.points_m.extend(scan.points_sensor_m.iter().map(|p| {
            let w = t * nalgebra::Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            [w.x, w.y, w.z]
        }));
    }
    Ok(cloud)
}

/// Depth frames from a KITTI-layout sequence's rectified grey pair (image_0, image_1), with
/// `z = fx·B/d`. Colour comes from image_2 where the colour camera coincides with cam0 (synthetic
/// drives); otherwise the grey value is used as colour.
pub struct StereoDepth {
    estimator: Box<dyn crate::depth::DisparityEstimator>,
}

impl StereoDepth {
    /// A stereo depth source using `method` over `num_disparities` disparities. Variational
    /// methods keep SGM's validity ([`crate::depth::tgv::HoleFill::None`]): filled holes raised
    /// the demo's raw median error from 4.6 to 6.5 cm.
    pub fn new(method: crate::depth::StereoMethod, num_disparities: usize) -> Result<Self> {
        Ok(StereoDepth {
            estimator: method
                .estimator_with_fill(num_disparities, crate::depth::tgv::HoleFill::None)?,
        })
    }

    /// The depth frame of frame `i`.
    pub fn frame(&self, seq: &KittiSequence, i: usize) -> Result<crate::frame::DepthFrame> {
        let left = seq.grey(0, i)?;
        let right = seq.grey(1, i)?;
        let disparity = self.estimator.estimate(&left, &right)?;
        let mut intrinsics = seq.intrinsics(0)?;
        intrinsics.width = left.width;
        intrinsics.height = left.height;
        let baseline_m = seq.calib().baseline_m(0, 1);
        if !(baseline_m.is_finite() && baseline_m > 0.0) {
            return Err(Error::bad_input(
                seq.dir().join("calib.txt"),
                format!("stereo baseline P0→P1 must be positive, got {baseline_m} m"),
            ));
        }
        let depth_m = crate::depth::disparity_to_depth(&disparity, intrinsics.fx, baseline_m);
        let world_from_camera = seq
            .pose(i)
            .ok_or_else(|| Error::bad_input(seq.dir(), format!("no pose for frame {i}")))?;
        let color =
            if seq.has_image(2, i) && seq.calib().cam_from_cam0_translation_m(2).norm() < 1e-6 {
                Some(seq.color(2, i)?)
            } else {
                Some(crate::frame::Image {
                    width: left.width,
                    height: left.height,
                    data: left.data.iter().map(|&g| [g; 3]).collect(),
                })
            };
        Ok(crate::frame::DepthFrame {
            intrinsics,
            world_from_camera,
            depth_m,
            color,
        })
    }
}

/// Frame `i` of a KITTI-layout sequence with ground-truth depth (`depth_gt/NNNNNN.png`, 16-bit,
/// depth·256, 0 invalid, in the left grey camera), coloured from `image_2` when present (the
/// synthetic rig's colour camera coincides with cam0).
pub fn kitti_gt_depth_frame(seq: &KittiSequence, i: usize) -> Result<crate::frame::DepthFrame> {
    let path = seq.dir().join("depth_gt").join(format!("{i:06}.png"));
    if !path.is_file() {
        return Err(Error::bad_input(&path, "no ground-truth depth for this frame (only synthetic drives written by `denser synth` have depth_gt/)"));
    }
    let depth_m = crate::io::image::read_depth_png_u16(&path, 256.0)?;
    let mut intrinsics = seq.intrinsics(0)?;
    intrinsics.width = depth_m.width;
    intrinsics.height = depth_m.height;
    let world_from_camera = seq
        .pose(i)
        .ok_or_else(|| Error::bad_input(seq.dir(), format!("no pose for frame {i}")))?;
    let color = if seq.has_image(2, i) && seq.calib().cam_from_cam0_translation_m(2).norm() < 1e-6 {
        Some(seq.color(2, i)?)
    } else {
        None
    };
    Ok(crate::frame::DepthFrame {
        intrinsics,
        world_from_camera,
        depth_m,
        color,
    })
}

/// One range measurement of a job's input, ready to fuse.
pub enum RangeInput {
    /// A depth map with pose (RGB-D, ground-truth depth, or stereo).
    Depth(crate::frame::DepthFrame),
    /// A LiDAR scan with pose.
    Lidar(crate::frame::LidarScan),
}

/// The frames a job fuses, in order (indices into its sequence).
pub fn job_frame_count(job: &ReconstructJob) -> Result<usize> {
    Ok(match detect_input(&job.input)? {
        InputKind::Kitti => {
            let seq = KittiSequence::open(&job.input, job.poses.as_deref())?;
            frame_indices(seq.len(), job.frames, job.frame_step).len()
        }
        kind => {
            let seq = open_depth_sequence(&job.input, kind)?;
            frame_indices(seq.len(), job.frames, job.frame_step).len()
        }
    })
}

/// Reads (and for stereo, computes) the job's inputs one at a time, skipping the first `skip` of
/// its frames (already fused by a resumed run), and hands each to `sink` with the seconds spent
/// producing it. Nothing is held beyond the current frame.
pub fn for_each_input(
    job: &ReconstructJob,
    skip: usize,
    mut sink: impl FnMut(RangeInput, f64) -> Result<()>,
) -> Result<()> {
    match detect_input(&job.input)? {
        InputKind::Kitti => {
            let seq = KittiSequence::open(&job.input, job.poses.as_deref())?;
            let frames = frame_indices(seq.len(), job.frames, job.frame_step);
            let stereo = StereoDepth::new(job.stereo_method, job.num_disparities)?;
            let bar = crate::progress::bar(frames.len() as u64, "fusing");
            bar.inc(skip.min(frames.len()) as u64);
            for &i in frames.iter().skip(skip) {
                let t = std::time::Instant::now();
                let input = match job.source {
                    RangeSource::Lidar => RangeInput::Lidar(seq.velodyne(i)?),
                    RangeSource::GroundTruthDepth => {
                        RangeInput::Depth(kitti_gt_depth_frame(&seq, i)?)
                    }
                    RangeSource::Stereo => RangeInput::Depth(stereo.frame(&seq, i)?),
                };
                sink(input, t.elapsed().as_secs_f64())?;
                bar.inc(1);
            }
            bar.finish_and_clear();
        }
        kind => {
            let seq = open_depth_sequence(&job.input, kind)?;
            let frames = frame_indices(seq.len(), job.frames, job.frame_step);
            let bar = crate::progress::bar(frames.len() as u64, "fusing");
            bar.inc(skip.min(frames.len()) as u64);
            for &i in frames.iter().skip(skip) {
                let t = std::time::Instant::now();
                let frame = seq.frame(i)?;
                sink(RangeInput::Depth(frame), t.elapsed().as_secs_f64())?;
                bar.inc(1);
            }
            bar.finish_and_clear();
        }
    }
    Ok(())
}

/// Fuses the job's input into a fresh reconstructor (no regularisation yet).
pub fn fuse_input(job: &ReconstructJob) -> Result<Reconstructor> {
    let mut rec = Reconstructor::new(job.config)?;
    rec.set_gpu(job.device.open()?.map(std::sync::Arc::new));
    rec.set_gpu_options(crate::gpu::ResidentOptions {
        max_bytes: job.gpu_budget_bytes,
        ..Default::default()
    });
    for_each_input(job, 0, |input, input_s| {
        rec.add_input_time(input_s);
        match input {
            RangeInput::Depth(f) => rec.fuse_depth(&f)?,
            RangeInput::Lidar(s) => rec.fuse_lidar(&s)?,
        };
        Ok(())
    })?;
    rec.sync_gpu()?;
    if let Some(r) = rec.resident_stats() {
        let per = |s: f64| 1e3 * s / r.frames.max(1) as f64;
        tracing::info!(
            "GPU pool: {} of {} blocks resident (peak {}), {} uploaded, {} read back, {} spilled, \
             {} grows, {} oversize frames; per frame: listing blocks (CPU) {:.1} ms, residency \
             {:.1} ms, kernels {:.1} ms, write-back {:.1} ms",
            r.resident_blocks,
            r.capacity_blocks,
            r.peak_resident_blocks,
            r.blocks_uploaded,
            r.blocks_downloaded,
            r.blocks_spilled,
            r.grows,
            r.oversize_frames,
            per(r.list_s),
            per(r.residency_s),
            per(r.kernel_s),
            per(r.download_s)
        );
    }
    tracing::info!(
        blocks = rec.layer().block_count(),
        ms_per_frame = rec.timings().fusion_ms_per_frame(),
        "fused {} frames",
        rec.timings().frames_fused
    );
    Ok(rec)
}

/// Regularises, meshes both fields and writes `mesh_raw.ply`, `mesh_regularized.ply` and the
/// regularised surface points (`points_regularized.ply`) into `out_dir`.
pub fn finish(mut rec: Reconstructor, out_dir: &Path) -> Result<ReconstructOutcome> {
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    let observed_voxels = rec.layer().observed_voxel_count();
    let raw = rec.mesh(Field::Raw);
    let regularize_stats = rec.regularize()?;
    let regularized = rec.mesh(Field::Regularized);
    let mut written = Vec::new();
    for (name, mesh) in [
        ("mesh_raw.ply", &raw),
        ("mesh_regularized.ply", &regularized),
    ] {
        let path = out_dir.join(name);
        crate::io::ply::write_mesh_ply(&path, mesh)?;
        written.push(path);
    }
    let points = out_dir.join("points_regularized.ply");
    crate::io::ply::write_points_ply(&points, &regularized.to_point_cloud())?;
    written.push(points);
    Ok(ReconstructOutcome {
        reconstructor: rec,
        raw,
        regularized,
        regularize_stats,
        written,
        observed_voxels,
    })
}

/// Fusion, regularisation and marching-cubes throughput on an RGB-D folder, at 10 cm and 5 cm
/// voxels with μ = 8 voxels (Open3D's default, so `tools/bench_open3d.py` runs the same settings).
/// Returns a Markdown table. Frames are loaded once; each pass re-fuses all of them.
pub fn bench_rgbd(dir: &Path, passes: usize) -> Result<String> {
    let kind = detect_input(dir)?;
    let seq = open_depth_sequence(dir, kind)?;
    let frames: Vec<_> = (0..seq.len())
        .map(|i| seq.frame(i))
        .collect::<Result<_>>()?;
    let mut out = String::from(
        "| voxel | μ | median ms/frame | M voxel updates/s | blocks | bytes/voxel | TV M voxel-it/s | MC ms |\n|---|---|---|---|---|---|---|---|\n",
    );
    for voxel in [0.10f32, 0.05] {
        let mut config = ReconstructionConfig::paper(voxel);
        config.grid.truncation_m = 8.0 * voxel;
        config.depth_fusion.max_depth_m = 10.0;
        config.tv.iterations = 20;
        let mut rec = Reconstructor::new(config)?;
        let mut times = Vec::new();
        let mut updates = 0usize;
        for _ in 0..passes.max(1) {
            for f in &frames {
                let t = std::time::Instant::now();
                let (_, stats) =
                    crate::fusion::integrate_depth(rec.layer_mut(), f, &config.depth_fusion);
                times.push(t.elapsed().as_secs_f64());
                updates += stats.voxel_updates;
            }
        }
        let total: f64 = times.iter().sum();
        times.sort_by(f64::total_cmp);
        let median_ms = 1e3 * times[times.len() / 2];
        let bytes = rec.layer().bytes_per_voxel();
        rec.regularize()?;
        let t = std::time::Instant::now();
        rec.mesh(Field::Regularized);
        let mc_ms = 1e3 * t.elapsed().as_secs_f64();
        out.push_str(&format!(
            "| {:.0} cm | {:.2} m | {:.2} | {:.1} | {} | {:.2} | {:.1} | {:.1} |\n",
            voxel * 100.0,
            config.grid.truncation_m,
            median_ms,
            updates as f64 / total / 1e6,
            rec.layer().block_count(),
            bytes,
            rec.timings().voxel_iterations_per_s() / 1e6,
            mc_ms
        ));
    }
    Ok(out)
}

/// Ground truth for evaluation.
#[derive(Clone, Debug)]
pub enum GroundTruth {
    /// All Velodyne scans of a KITTI-layout sequence (frames as given) in the world frame — the
    /// paper's ground truth.
    KittiLidar {
        /// Sequence folder.
        sequence: PathBuf,
        /// Poses file, when not at the default place.
        poses: Option<PathBuf>,
        /// First frame and one past the last.
        frames: Option<(usize, usize)>,
        /// Use every n-th scan.
        step: usize,
    },
    /// A point cloud file: `.las`, `.laz` (coordinates converted to metres) or `.ply`.
    File(PathBuf),
}

impl GroundTruth {
    /// Loads the ground-truth points (world frame, metres).
    pub fn load(&self) -> Result<PointCloud> {
        match self {
            GroundTruth::KittiLidar {
                sequence,
                poses,
                frames,
                step,
            } => {
                let seq = KittiSequence::open(sequence, poses.as_deref())?;
                merged_lidar(&seq, &frame_indices(seq.len(), *frames, *step))
            }
            GroundTruth::File(path) => {
                let ext = path
                    .extension()
                    .and_then(|e| e.to_str())
                    .unwrap_or("")
                    .to_ascii_lowercase();
                match ext.as_str() {
                    "las" | "laz" => crate::io::las::read_point_cloud_metres(path),
                    "ply" => Ok(crate::io::ply::read_ply(path)?.0),
                    _ => Err(Error::bad_input(
                        path,
                        "ground truth must be .las, .laz or .ply",
                    )),
                }
            }
        }
    }

    /// A short description for reports.
    pub fn describe(&self) -> String {
        match self {
            GroundTruth::KittiLidar { sequence, .. } => {
                format!("LiDAR scans of {}", sequence.display())
            }
            GroundTruth::File(p) => p.display().to_string(),
        }
    }
}

/// Peak resident memory of this process (Linux `VmHWM`), bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Scores labelled meshes against `ground_truth` and writes `report.json`, `report.md`,
/// `error_histogram.png` and `top_view_<label>.png` into `out_dir`. The first mesh is the
/// baseline of the relative changes. `voxels` gives (voxel count, bytes per voxel) for surfaces
/// made from a map.
pub fn evaluate_meshes(
    meshes: &[(&str, &Mesh)],
    ground_truth: &PointCloud,
    report: &mut crate::eval::EvaluationReport,
    voxels: Option<(u64, f64)>,
    out_dir: &Path,
) -> Result<Vec<PathBuf>> {
    use crate::eval::{
        evaluate_mesh_detailed, plot_error_histograms_png, plot_top_view_png, EvalOptions,
        GroundTruthIndex, UpAxis,
    };
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    let t = std::time::Instant::now();
    let index = GroundTruthIndex::new(ground_truth)?;
    let options = EvalOptions::default();
    let mut written = Vec::new();
    let mut evaluations = Vec::new();
    for (label, mesh) in meshes {
        let mut e = evaluate_mesh_detailed(label, mesh, &index, &options)?;
        if let Some((count, bpv)) = voxels {
            e.report = e.report.with_voxels(count, bpv);
        }
        let top = out_dir.join(format!("top_view_{label}.png"));
        plot_top_view_png(&top, &e.points_m, &e.accuracy_m, UpAxis::NegY, 0.5, 1600)?;
        written.push(top);
        evaluations.push(e);
    }
    let series: Vec<(&str, &crate::eval::ErrorStats)> = evaluations
        .iter()
        .map(|e| (e.report.label.as_str(), &e.report.accuracy))
        .collect();
    let hist = out_dir.join("error_histogram.png");
    plot_error_histograms_png(&hist, &series, 0.5)?;
    written.push(hist);
    report
        .surfaces
        .extend(evaluations.into_iter().map(|e| e.report));
    report
        .timings_s
        .push(("evaluation".into(), t.elapsed().as_secs_f64()));
    if let Some(rss) = peak_rss_bytes() {
        report
            .memory_bytes
            .push(("peak resident (process)".into(), rss));
    }
    let json = out_dir.join("report.json");
    report.write_json(&json)?;
    let md = out_dir.join("report.md");
    report.write_markdown(&md)?;
    written.extend([json, md]);
    Ok(written)
}

/// Evaluates a finished reconstruction (raw and regularised meshes) and writes the report.
pub fn evaluate_outcome(
    outcome: &ReconstructOutcome,
    ground_truth: &GroundTruth,
    source: &str,
    out_dir: &Path,
) -> Result<(crate::eval::EvaluationReport, Vec<PathBuf>)> {
    let t = std::time::Instant::now();
    let gt = ground_truth.load()?;
    let load_s = t.elapsed().as_secs_f64();
    let mut report = crate::eval::EvaluationReport::new(
        format!("{source}; ground truth: {}", ground_truth.describe()),
        gt.len() as u64,
    );
    let timings = outcome.reconstructor.timings();
    report.timings_s.extend([
        (
            "input (reading, stereo matching)".to_string(),
            timings.input_s,
        ),
        ("fusion".to_string(), timings.fusion_s),
        ("regularisation".to_string(), timings.regularize_s),
        ("marching cubes (both fields)".to_string(), timings.mesh_s),
        ("loading ground truth".to_string(), load_s),
    ]);
    let layer = outcome.reconstructor.layer();
    report
        .memory_bytes
        .push(("voxel map (RAM)".into(), layer.memory_bytes() as u64));
    let config = outcome.reconstructor.config();
    report.parameters = serde_json::json!({
        "voxel_size_m": config.grid.voxel_size_m,
        "truncation_m": config.grid.truncation_m,
        "tv": config.tv,
        "frames_fused": timings.frames_fused,
        "fusion_ms_per_frame": timings.fusion_ms_per_frame(),
        "voxel_updates_per_s": timings.voxel_updates_per_s(),
        "regularizer_voxel_iterations_per_s": timings.voxel_iterations_per_s(),
        "allocated_blocks": layer.block_count(),
        "omega_voxels": outcome.observed_voxels,
        "energy_before": outcome.regularize_stats.energy_before,
        "energy_after": outcome.regularize_stats.energy_after,
    });
    // The map's size: allocated voxels (blocks × 512) and RAM bytes per allocated voxel.
    let allocated = (layer.block_count() * crate::grid::VOXELS_PER_BLOCK) as u64;
    let voxels = Some((allocated, layer.bytes_per_voxel()));
    let written = evaluate_meshes(
        &[("raw", &outcome.raw), ("regularized", &outcome.regularized)],
        &gt,
        &mut report,
        voxels,
        out_dir,
    )?;
    Ok((report, written))
}

/// Settings of `denser demo`: a short synthetic drive reconstructed from stereo.
#[derive(Clone, Debug)]
pub struct DemoConfig {
    /// Output folder: `drive/` (the synthetic sequence) and the results.
    pub out_dir: PathBuf,
    /// Length of the drive, metres.
    pub length_m: f64,
    /// Distance between frames, metres.
    pub frame_spacing_m: f64,
    /// Seed of the city.
    pub seed: u64,
    /// Reconstruction settings.
    pub config: ReconstructionConfig,
    /// Where depth fusion and regularisation run.
    pub device: crate::gpu::DeviceChoice,
    /// Stereo matcher (default: TGV with the anisotropic tensor, the paper's).
    pub stereo_method: crate::depth::StereoMethod,
}

impl DemoConfig {
    /// The README's default: 200 m, a frame every 2 m, 10 cm voxels with the paper's μ and λ,
    /// stereo depth used up to 20 m (at 0.54 m baseline a quarter-pixel disparity error is ±0.26 m there).
    pub fn new(out_dir: PathBuf) -> Self {
        let mut config = ReconstructionConfig::paper(0.1);
        config.depth_fusion.max_depth_m = 20.0;
        DemoConfig {
            out_dir,
            length_m: 200.0,
            frame_spacing_m: 2.0,
            seed: 1,
            config,
            device: crate::gpu::DeviceChoice::Auto,
            stereo_method: crate::depth::StereoMethod::TgvTensor,
        }
    }
}

/// What the demo produced.
#[derive(Debug)]
pub struct DemoOutcome {
    /// The synthetic drive.
    pub drive: crate::synth::DriveSummary,
    /// The evaluation (raw, regularised).
    pub report: crate::eval::EvaluationReport,
    /// Files written.
    pub written: Vec<PathBuf>,
    /// Seconds for the whole demo.
    pub total_s: f64,
}

/// `denser demo`: synthesises a city drive (KITTI layout, with LiDAR), reconstructs it from the
/// stereo pairs (census + TGV-tensor or SGM → depth → fusion → regularisation → meshes) and scores both meshes against
/// the merged LiDAR scans, as the paper does.
pub fn demo(demo: &DemoConfig) -> Result<DemoOutcome> {
    let started = std::time::Instant::now();
    let drive_dir = demo.out_dir.join("drive");
    let mut drive = crate::synth::DriveConfig::default();
    drive.city.seed = demo.seed;
    drive.city.length_m = demo.length_m;
    drive.city.frame_spacing_m = demo.frame_spacing_m;
    drive.surface = None;
    tracing::info!(
        "synthesising a {:.0} m drive into {}",
        demo.length_m,
        drive_dir.display()
    );
    let summary = crate::synth::write_drive(&drive, &drive_dir, true)?;
    let job = ReconstructJob {
        input: summary.sequence_dir.clone(),
        poses: None,
        out_dir: demo.out_dir.clone(),
        source: RangeSource::Stereo,
        config: demo.config,
        frames: None,
        frame_step: 1,
        stereo_method: demo.stereo_method,
        num_disparities: 128,
        device: demo.device,
        gpu_budget_bytes: crate::gpu::ResidentOptions::default().max_bytes,
    };
    let rec = fuse_input(&job)?;
    let outcome = finish(rec, &demo.out_dir)?;
    let gt = GroundTruth::KittiLidar {
        sequence: summary.sequence_dir.clone(),
        poses: None,
        frames: None,
        step: 1,
    };
    let (mut report, mut written) = evaluate_outcome(
        &outcome,
        &gt,
        &format!(
            "synthetic drive (seed {}, {:.0} m, {} frames) from stereo ({})",
            demo.seed, summary.route_length_m, summary.frames, demo.stereo_method
        ),
        &demo.out_dir,
    )?;
    report.timings_s.insert(
        0,
        (
            "synthesising the drive".into(),
            summary.build_s + summary.frames_s + summary.surface_s,
        ),
    );
    let total_s = started.elapsed().as_secs_f64();
    report.write_json(demo.out_dir.join("report.json"))?;
    report.write_markdown(demo.out_dir.join("report.md"))?;
    written.splice(0..0, outcome.written);
    Ok(DemoOutcome {
        drive: summary,
        report,
        written,
        total_s,
    })
}

/// Out-of-core settings of `reconstruct --map`.
#[derive(Clone, Debug)]
pub struct MapJob {
    /// The map directory (created, or resumed when it holds a map of the same job).
    pub dir: PathBuf,
    /// Bytes of voxel blocks kept in RAM at most (fusion, regularisation regions).
    pub budget_bytes: u64,
    /// Chunk edge, blocks.
    pub chunk_blocks: u32,
    /// Commit a checkpoint every this many frames (0: only at the end).
    pub checkpoint_every: u64,
    /// Regularisation region edge, chunks.
    pub region_chunks: u32,
    /// What to do when one frame's working set exceeds the budget.
    pub overrun: crate::tiles::pager::OverrunPolicy,
    /// Export meshes (raw and regularised) into the job's output folder at the end.
    pub export_meshes: bool,
    /// Regularise the map at the end (else leave it to `denser regularize`).
    pub regularize: bool,
}

/// What a streamed reconstruction did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MapOutcome {
    /// Frames fused in all (this run and the runs it resumed).
    pub frames_fused: u64,
    /// Frames already committed when this run started (0 for a fresh map).
    pub resumed_from_frame: u64,
    /// Seconds producing inputs (reading, stereo).
    pub input_s: f64,
    /// Seconds in fusion proper.
    pub fusion_s: f64,
    /// Seconds paging (reads, evictions, waits, checkpoints).
    pub paging_s: f64,
    /// Voxel updates in this run.
    pub voxel_updates: usize,
    /// Pager counters.
    pub pager: crate::tiles::pager::PagerStats,
    /// GPU tier counters, when depth frames were fused on a GPU.
    pub gpu: Option<crate::gpu::ResidentStats>,
    /// Offline regularisation counters.
    pub regularize: crate::tiles::regional::MapRegularizeStats,
    /// The map on disk.
    pub summary: crate::tiles::store::MapSummary,
    /// Exported files and their counters.
    pub exports: Vec<(PathBuf, crate::tiles::export::ExportStats)>,
    /// Peak resident set of the process, bytes (Linux).
    pub peak_rss_bytes: Option<u64>,
}

/// Identity of the job that made a map, stored as `job.json` beside the manifest so a resumed run
/// refuses to continue a map made from other data or settings.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
struct MapJobRecord {
    input: String,
    source: String,
    frames: Option<(usize, usize)>,
    frame_step: usize,
    voxel_size_m: f32,
    truncation_m: f32,
    max_depth_m: f32,
    stereo: String,
    num_disparities: usize,
}

impl MapJobRecord {
    fn of(job: &ReconstructJob) -> Self {
        MapJobRecord {
            input: std::fs::canonicalize(&job.input)
                .unwrap_or_else(|_| job.input.clone())
                .display()
                .to_string(),
            source: format!("{:?}", job.source),
            frames: job.frames,
            frame_step: job.frame_step,
            voxel_size_m: job.config.grid.voxel_size_m,
            truncation_m: job.config.grid.truncation_m,
            max_depth_m: job.config.depth_fusion.max_depth_m,
            stereo: job.stereo_method.as_str().to_string(),
            num_disparities: job.num_disparities,
        }
    }
}

/// `reconstruct --map`: fuses the job's input through the pager into a chunked map on disk
/// (resuming a killed run of the same job from its last checkpoint), regularises it region by
/// region, and exports both meshes tile by tile. Memory is bounded by `map.budget_bytes` plus a
/// fixed overhead, whatever the length of the drive.
pub fn reconstruct_map(job: &ReconstructJob, map: &MapJob) -> Result<MapOutcome> {
    use crate::tiles::{export, pager, regional, store::MapStore, stream::StreamingFusion};
    let record = MapJobRecord::of(job);
    let record_path = map.dir.join("job.json");
    let store = if map.dir.join(crate::tiles::store::MANIFEST_FILE).exists() {
        let stored: MapJobRecord = serde_json::from_slice(
            &std::fs::read(&record_path).map_err(|e| Error::io(&record_path, e))?,
        )
        .map_err(|e| Error::bad_input(&record_path, e.to_string()))?;
        if stored != record {
            return Err(Error::bad_input(
                &record_path,
                format!("this map was made by another job ({stored:?}); use a new --map folder to reconstruct {record:?}"),
            ));
        }
        MapStore::open(&map.dir)?
    } else {
        let s = MapStore::create(&map.dir, job.config.grid, map.chunk_blocks)?;
        crate::tiles::store::write_atomically(
            &record_path,
            serde_json::to_string_pretty(&record)
                .expect("job record serialises")
                .as_bytes(),
        )?;
        s
    };
    let resumed_from_frame = store.manifest().header.frames_committed;
    let total = job_frame_count(job)? as u64;
    if resumed_from_frame > total {
        return Err(Error::bad_input(
            &map.dir,
            format!(
                "the map has {resumed_from_frame} frames committed but the job has only {total}"
            ),
        ));
    }
    if resumed_from_frame > 0 {
        tracing::info!(
            "resuming {} after {resumed_from_frame} committed frames",
            map.dir.display()
        );
    }
    let pager = pager::Pager::new(
        store,
        pager::PagerConfig {
            budget_bytes: map.budget_bytes,
            overrun: map.overrun,
            writer_threads: 2,
        },
    );
    let mut fusion = StreamingFusion::new(
        pager,
        job.config.depth_fusion,
        job.config.lidar_fusion,
        map.checkpoint_every,
    );
    if let Some(ctx) = job.device.open()? {
        let options = crate::gpu::ResidentOptions {
            max_bytes: job.gpu_budget_bytes,
            ..Default::default()
        };
        let resident =
            crate::gpu::ResidentMap::new(std::sync::Arc::new(ctx), job.config.grid, options)?;
        fusion = fusion.with_gpu(resident);
    }
    let mut input_s = 0.0;
    for_each_input(job, resumed_from_frame as usize, |input, s| {
        input_s += s;
        match input {
            RangeInput::Depth(f) => fusion.fuse_depth(&f)?,
            RangeInput::Lidar(scan) => fusion.fuse_lidar(&scan)?,
        };
        Ok(())
    })?;
    let (fusion_s, paging_s, voxel_updates, frames_fused, gpu) = (
        fusion.fusion_s,
        fusion.paging_s,
        fusion.voxel_updates,
        fusion.frames_fused(),
        fusion.gpu_stats(),
    );
    let (mut store, pager_stats) = fusion.finish()?;
    let bar = crate::progress::bar(0, "regularising");
    let regularize = if !map.regularize {
        regional::MapRegularizeStats::default()
    } else {
        regional::regularize_map(
            &mut store,
            &job.config.tv,
            &regional::RegionalOptions {
                region_chunks: map.region_chunks,
                budget_bytes: map.budget_bytes,
                halo_blocks: None,
            },
            |done, total| {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
                true
            },
        )?
    };
    bar.finish_and_clear();
    let mut exports = Vec::new();
    if map.export_meshes {
        std::fs::create_dir_all(&job.out_dir).map_err(|e| Error::io(&job.out_dir, e))?;
        let fields: &[(&str, Field)] = if map.regularize {
            &[
                ("mesh_raw.ply", Field::Raw),
                ("mesh_regularized.ply", Field::Regularized),
            ]
        } else {
            &[("mesh_raw.ply", Field::Raw)]
        };
        for &(name, field) in fields {
            let path = job.out_dir.join(name);
            let st = export::export(
                &store,
                field,
                None,
                &export::ExportTarget::Mesh(path.clone()),
            )?;
            exports.push((path, st));
        }
    }
    Ok(MapOutcome {
        frames_fused,
        resumed_from_frame,
        input_s,
        fusion_s,
        paging_s,
        voxel_updates,
        pager: pager_stats,
        gpu,
        regularize,
        summary: store.summary(),
        exports,
        peak_rss_bytes: peak_rss_bytes(),
    })
}

/// Focal length, baseline and disparity offset of a rectified pair, for `z = fx·B/(d + doffs)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StereoCalibration {
    /// Horizontal focal length of the left camera, pixels.
    pub fx_px: f64,
    /// Baseline, metres.
    pub baseline_m: f64,
    /// Middlebury's `doffs` (difference of the principal points, pixels); 0 for KITTI.
    pub doffs_px: f64,
}

/// Reads a stereo calibration: KITTI odometry `calib.txt` (`P0:`/`P1:` lines; fx from P0, the
/// baseline from P1) or Middlebury 2014 `calib.txt` (`cam0=[f 0 cx; …]`, `baseline=` in mm,
/// `doffs=`). Errors name the file.
pub fn read_stereo_calibration(path: &Path) -> Result<StereoCalibration> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    if text.lines().any(|l| l.trim_start().starts_with("cam0=")) {
        let value = |key: &str| -> Result<&str> {
            text.lines()
                .find_map(|l| l.trim().strip_prefix(key))
                .map(str::trim)
                .ok_or_else(|| {
                    Error::bad_input(path, format!("Middlebury calibration lacks `{key}`"))
                })
        };
        let cam0 = value("cam0=")?;
        let fx_px: f64 = cam0
            .trim_start_matches('[')
            .split_whitespace()
            .next()
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| {
                Error::bad_input(
                    path,
                    format!("cannot read the focal length from cam0={cam0}"),
                )
            })?;
        let num = |key: &str| -> Result<f64> {
            let v = value(key)?;
            v.parse()
                .map_err(|_| Error::bad_input(path, format!("`{key}{v}` is not a number")))
        };
        return Ok(StereoCalibration {
            fx_px,
            baseline_m: num("baseline=")? / 1000.0,
            doffs_px: num("doffs=")?,
        });
    }
    let calib = crate::io::kitti::KittiCalib::parse(path, &text)?;
    Ok(StereoCalibration {
        fx_px: calib.p[0][(0, 0)],
        baseline_m: calib.baseline_m(0, 1),
        doffs_px: 0.0,
    })
}

/// Settings of `denser stereo`.
#[derive(Clone, Debug)]
pub struct StereoJob {
    /// Left (reference) image; colour is converted to grey.
    pub left: PathBuf,
    /// Right image.
    pub right: PathBuf,
    /// Disparity output (Middlebury PFM: float32, bottom-up, `inf` = invalid).
    pub out: PathBuf,
    /// Calibration (KITTI or Middlebury `calib.txt`), needed for `depth_out`.
    pub calib: Option<PathBuf>,
    /// Depth output: 16-bit PNG, `depth_m = value / 256`, 0 = invalid or beyond 255.99 m.
    pub depth_out: Option<PathBuf>,
    /// Matcher.
    pub method: crate::depth::StereoMethod,
    /// Disparities searched, pixels.
    pub num_disparities: usize,
    /// Variational methods only: keep occluded and poorly matching pixels (dense output for
    /// benchmarks that count missing pixels as errors).
    pub dense: bool,
    /// Where the variational methods run (census cost, refinement); SGM runs on the CPU.
    pub device: crate::gpu::DeviceChoice,
}

/// What `denser stereo` did.
#[derive(Clone, Debug)]
pub struct StereoOutcome {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Valid disparities.
    pub valid_px: usize,
    /// Seconds spent matching.
    pub matching_s: f64,
}

/// `denser stereo`: disparity of a rectified pair, written as PFM, and optionally depth.
pub fn stereo(job: &StereoJob) -> Result<StereoOutcome> {
    let calib = job
        .calib
        .as_deref()
        .map(read_stereo_calibration)
        .transpose()?;
    if job.depth_out.is_some() && calib.is_none() {
        return Err(Error::InvalidArgument(
            "--depth-out needs --calib (KITTI or Middlebury calib.txt)".into(),
        ));
    }
    let left = crate::io::image::read_grey(&job.left)?;
    let right = crate::io::image::read_grey(&job.right)?;
    if left.width != right.width || left.height != right.height {
        return Err(Error::bad_input(
            &job.right,
            format!(
                "right image is {}×{} but the left image {} is {}×{}",
                right.width,
                right.height,
                job.left.display(),
                left.width,
                left.height
            ),
        ));
    }
    if job.dense && !job.method.is_variational() {
        return Err(Error::InvalidArgument(
            "--dense applies to the variational methods (tv, tgv, tgv-tensor), not sgm".into(),
        ));
    }
    let fill = if job.dense {
        crate::depth::tgv::HoleFill::All
    } else {
        crate::depth::tgv::HoleFill::Visible
    };
    let estimator: Box<dyn crate::depth::DisparityEstimator> =
        match job.method.tgv_matcher(job.num_disparities, fill)? {
            Some(m) => match job.device.open()? {
                Some(ctx) => Box::new(crate::gpu::TgvMatcherGpu::new(ctx, m)),
                None => Box::new(m),
            },
            None => job.method.estimator_with_fill(job.num_disparities, fill)?,
        };
    let started = std::time::Instant::now();
    let map = estimator.estimate(&left, &right)?;
    let matching_s = started.elapsed().as_secs_f64();
    crate::io::pfm::write_pfm(&job.out, &map.disparity_px)?;
    if let (Some(path), Some(c)) = (&job.depth_out, calib) {
        let shifted = crate::depth::DisparityMap {
            disparity_px: Image {
                width: map.disparity_px.width,
                height: map.disparity_px.height,
                data: map
                    .disparity_px
                    .data
                    .iter()
                    .map(|&d| d + c.doffs_px as f32)
                    .collect(),
            },
            confidence: None,
        };
        let mut depth = crate::depth::disparity_to_depth(&shifted, c.fx_px, c.baseline_m);
        for z in depth.data.iter_mut() {
            if *z * 256.0 > u16::MAX as f32 {
                *z = f32::NAN;
            }
        }
        crate::io::image::write_depth_png_u16(path, &depth, 256.0)?;
    }
    Ok(StereoOutcome {
        width: left.width,
        height: left.height,
        valid_px: map.valid_count(),
        matching_s,
    })
}

/// `denser stereo-eval`: scores a predicted disparity map (PFM or KITTI 16-bit PNG) against a
/// ground truth in either format, over all ground-truth pixels (missing predictions count as
/// errors), optionally inside a Middlebury-style mask PNG (255 = scored).
pub fn stereo_eval(
    gt: &Path,
    pred: &Path,
    mask: Option<&Path>,
) -> Result<crate::depth::StereoMetrics> {
    let gt_img = crate::depth::disparity_io::read_disparity(gt)?;
    let pred_img = crate::depth::disparity_io::read_disparity(pred)?;
    if gt_img.width != pred_img.width || gt_img.height != pred_img.height {
        return Err(Error::bad_input(
            pred,
            format!(
                "prediction is {}×{} but the ground truth {} is {}×{}",
                pred_img.width,
                pred_img.height,
                gt.display(),
                gt_img.width,
                gt_img.height
            ),
        ));
    }
    let mask_img = match mask {
        Some(m) => {
            let grey = crate::io::image::read_grey(m)?;
            if grey.width != gt_img.width || grey.height != gt_img.height {
                return Err(Error::bad_input(
                    m,
                    format!(
                        "mask is {}×{} but the ground truth is {}×{}",
                        grey.width, grey.height, gt_img.width, gt_img.height
                    ),
                ));
            }
            Some(crate::depth::metrics::mask_from_middlebury(&grey))
        }
        None => None,
    };
    crate::depth::evaluate_disparity(&pred_img, &gt_img, mask_img.as_ref())
}
