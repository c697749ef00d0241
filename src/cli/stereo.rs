//! `denser stereo` (disparity, and depth, of one rectified pair) and `denser stereo-eval`
//! (scores against ground truth).

use super::{help, DeviceArgs, Outcome, StereoArg};
use anyhow::{bail, Context, Result};
use denser::depth::sgm::SgmPaths;
use denser::depth::tgv::HoleFill;
use denser::depth::SgmParams;
use denser::depth::{DisparityMap, StereoMethod, StereoMetrics};
use denser::frame::Image;
use denser::io::calib::read_stereo_calibration;
use denser::Error;
use std::fmt;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub(crate) struct Args {
    /// Left (reference) image (any format the `image` crate reads; colour is converted to grey).
    left: PathBuf,
    /// Right image.
    right: PathBuf,
    #[arg(long, help = help::OUT)]
    out: PathBuf,
    /// Calibration for depth: KITTI odometry or Middlebury 2014 `calib.txt`.
    #[arg(long)]
    calib: Option<PathBuf>,
    /// Depth output: 16-bit PNG, depth_m = value / 256, 0 = invalid (needs --calib).
    #[arg(long)]
    depth_out: Option<PathBuf>,
    #[arg(long, value_enum, default_value = "tgv-tensor", help = help::METHOD)]
    method: StereoArg,
    #[arg(long, default_value_t = 128, help = help::NUM_DISPARITIES)]
    num_disparities: usize,
    /// SGM aggregation directions (of sgm, and of the variational methods' SGM initialisation):
    /// 4 (→ ← ↓ ↑), 5 (→ ← ↓ ↘ ↙, OpenCV StereoSGBM's 3-way mode: faster, see
    /// docs/bench/stereo.md) or 8 (all directions). Default: 8.
    #[arg(long, value_parser = parse_sgm_paths)]
    sgm_paths: Option<SgmPaths>,
    /// SGM left–right check: largest difference between the left and the right image's integer
    /// disparities, pixels; `off` disables the check. Default: 1.
    #[arg(long, value_parser = parse_lr_check)]
    sgm_lr_max_diff: Option<LrCheck>,
    /// SGM uniqueness margin in [0, 1): a pixel is invalid when some disparity more than one
    /// pixel from the winner costs less than `S_best / (1 − margin)`; 0 disables. Default:
    /// 0.05. With 5 paths, `--sgm-lr-max-diff 2 --sgm-uniqueness 0` scored better than OpenCV
    /// on KITTI and Middlebury (docs/bench/stereo.md), but made fused maps worse: the strict
    /// defaults are for `reconstruct`.
    #[arg(long)]
    sgm_uniqueness: Option<f32>,
    /// tv/tgv/tgv-tensor: keep occluded and poorly matching pixels (dense output for benchmarks
    /// that count missing pixels as errors).
    #[arg(long)]
    dense: bool,
    #[command(flatten)]
    device: DeviceArgs,
    #[arg(long, help = super::help::KERNEL_TIMES, help_heading = "Device")]
    kernel_times: bool,
}

#[derive(clap::Args)]
pub(crate) struct EvalArgs {
    /// Ground-truth disparity: Middlebury PFM (inf = unknown) or KITTI 16-bit PNG (value/256, 0 = unknown).
    gt: PathBuf,
    /// Predicted disparity, same formats (missing = NaN/inf/0 counts as an error).
    pred: PathBuf,
    /// Optional Middlebury-style mask PNG: only pixels of value 255 are scored.
    #[arg(long)]
    mask: Option<PathBuf>,
    /// Also write the scores as JSON to this file.
    #[arg(long = "json-out", alias = "json")]
    json: Option<PathBuf>,
}

struct Matched {
    method: StereoMethod,
    device: String,
    width: u32,
    height: u32,
    valid_px: usize,
    matching_s: f64,
    written: Vec<PathBuf>,
    /// What each file holds.
    notes: Vec<String>,
    /// `--kernel-times`: the kernels' device times (a Markdown table) or why there are none.
    kernel_times: Option<String>,
    /// What matching cost the GPU, when it ran there.
    traffic: Option<denser::gpu::GpuTraffic>,
}

impl fmt::Display for Matched {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{} on {}: {}×{} px, {} valid disparities ({:.1} %), matched in {:.3} s",
            self.method,
            self.device,
            self.width,
            self.height,
            self.valid_px,
            100.0 * self.valid_px as f64 / (self.width as f64 * self.height as f64),
            self.matching_s
        )?;
        if let Some(t) = &self.traffic {
            writeln!(f, "GPU traffic of the pair: {}", t.describe_per(1))?;
        }
        for n in &self.notes {
            writeln!(f, "  {n}")?;
        }
        if let Some(table) = &self.kernel_times {
            write!(f, "\n{table}\n")?;
        }
        write!(f, "{}", super::Written(&self.written))
    }
}

/// `--sgm-lr-max-diff`: the tolerance of the left–right check, or none.
#[derive(Clone, Copy, Debug)]
struct LrCheck(Option<u32>);

/// `--sgm-lr-max-diff`: a number of pixels, or `off`.
fn parse_lr_check(s: &str) -> std::result::Result<LrCheck, String> {
    if s == "off" {
        return Ok(LrCheck(None));
    }
    s.parse()
        .map(|px| LrCheck(Some(px)))
        .map_err(|_| format!("expected a number of pixels or `off`, got {s}"))
}

/// `--sgm-paths`: 4, 5 or 8.
fn parse_sgm_paths(s: &str) -> std::result::Result<SgmPaths, String> {
    match s {
        "4" => Ok(SgmPaths::Four),
        "5" => Ok(SgmPaths::Five),
        "8" => Ok(SgmPaths::Eight),
        _ => Err(format!("expected 4, 5 or 8 paths, got {s}")),
    }
}

pub(crate) fn run(a: Args) -> Result<Outcome> {
    let method: StereoMethod = a.method.into();
    let context = || {
        format!(
            "stereo matching {} / {}",
            a.left.display(),
            a.right.display()
        )
    };
    let calib = a
        .calib
        .as_deref()
        .map(read_stereo_calibration)
        .transpose()
        .with_context(context)?;
    if a.depth_out.is_some() && calib.is_none() {
        bail!("--depth-out needs --calib (KITTI or Middlebury calib.txt)");
    }
    if a.dense && !method.is_variational() {
        bail!("--dense applies to the variational methods (tv, tgv, tgv-tensor), not sgm");
    }
    let backend = a.device.backend()?;
    // A picture beside the PFM, which no ordinary viewer shows.
    let colour_path = match a.out.with_extension("png") {
        p if p == a.out => a.out.with_extension("color.png"),
        p => p,
    };
    for out in [&a.out, &colour_path].into_iter().chain(&a.depth_out) {
        denser::io::atomic::check_output_file(out)?;
    }
    let left = denser::io::image::read_grey(&a.left).with_context(context)?;
    let right = denser::io::image::read_grey(&a.right).with_context(context)?;
    if left.width != right.width || left.height != right.height {
        return Err(Error::bad_input(
            &a.right,
            format!(
                "right image is {}×{} but the left image {} is {}×{}",
                right.width,
                right.height,
                a.left.display(),
                left.width,
                left.height
            ),
        ))
        .with_context(context);
    }
    let fill = if a.dense {
        HoleFill::All
    } else {
        HoleFill::Visible
    };
    let defaults = SgmParams::default();
    let sgm = SgmParams {
        num_disparities: a.num_disparities,
        paths: a.sgm_paths.unwrap_or(defaults.paths),
        lr_max_diff_px: a.sgm_lr_max_diff.map_or(defaults.lr_max_diff_px, |l| l.0),
        uniqueness_ratio: a.sgm_uniqueness.unwrap_or(defaults.uniqueness_ratio),
        ..defaults
    };
    let estimator = backend.stereo_matcher(method, sgm, fill)?;
    let timed = match backend.gpu_context() {
        Some(ctx) if a.kernel_times => Some((ctx.clone(), ctx.start_kernel_timing())),
        _ => None,
    };
    let traffic_before = backend.gpu_context().map(|c| c.traffic());
    let started = std::time::Instant::now();
    let map = estimator.estimate(&left, &right).with_context(context)?;
    let matching_s = started.elapsed().as_secs_f64();
    let traffic = backend
        .gpu_context()
        .zip(traffic_before)
        .map(|(c, before)| c.traffic().since(before))
        .filter(|t| t.submits > 0);
    let kernel_times = timed.map(|(ctx, on)| match on {
        true => super::bench::kernel_table(&ctx),
        false => format!("{}: no timestamp queries, kernels not timed\n", ctx.name()),
    });
    denser::io::pfm::write_pfm(&a.out, &map.disparity_px)?;
    let (colour, scale_px) = denser::depth::disparity_false_colour(&map.disparity_px, None);
    denser::io::image::write_rgb_png(&colour_path, &colour)?;
    let mut written = vec![a.out.clone(), colour_path];
    if let (Some(path), Some(c)) = (&a.depth_out, calib) {
        let shifted = DisparityMap {
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
        let mut depth = denser::depth::disparity_to_depth(&shifted, c.fx_px, c.baseline_m);
        for z in depth.data.iter_mut() {
            if *z * 256.0 > u16::MAX as f32 {
                *z = f32::NAN;
            }
        }
        denser::io::image::write_depth_png_u16(path, &depth, 256.0)?;
        written.push(path.clone());
    }
    let notes = vec![
        format!(
            "{}: the disparity in false colour, blue 0 px → red {scale_px:.1} px (the 99th percentile), black where none",
            written[1].display()
        ),
        format!("{}: the disparity (Middlebury PFM, float32, inf where none)", a.out.display()),
    ]
    .into_iter()
    .chain(a.depth_out.iter().map(|p| {
        format!(
            "{}: depth as a 16-bit PNG, depth_m = value / 256, 0 where none (it looks black in an ordinary viewer)",
            p.display()
        )
    }))
    .collect();
    Ok(Box::new(Matched {
        method,
        kernel_times,
        traffic,
        device: backend.stereo_device(),
        width: left.width,
        height: left.height,
        valid_px: map.valid_count(),
        matching_s,
        written,
        notes,
    }))
}

struct Scores {
    metrics: StereoMetrics,
    json: Option<PathBuf>,
}

impl fmt::Display for Scores {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let m = &self.metrics;
        writeln!(f, "| metric | value |")?;
        writeln!(f, "|---|---|")?;
        writeln!(f, "| scored pixels | {} |", m.gt_pixels)?;
        writeln!(f, "| bad-1.0 % | {:.2} |", m.bad1_pct)?;
        writeln!(f, "| bad-2.0 % | {:.2} |", m.bad2_pct)?;
        writeln!(f, "| bad-3.0 % | {:.2} |", m.bad3_pct)?;
        writeln!(f, "| D1 % | {:.2} |", m.d1_pct)?;
        writeln!(f, "| EPE px | {:.3} |", m.epe_px)?;
        writeln!(f, "| density % | {:.2} |", m.density_pct)?;
        if let Some(p) = &self.json {
            writeln!(f, "wrote {}", p.display())?;
        }
        Ok(())
    }
}

pub(crate) fn run_eval(a: EvalArgs) -> Result<Outcome> {
    let metrics = stereo_eval(&a.gt, &a.pred, a.mask.as_deref())
        .with_context(|| format!("scoring {} against {}", a.pred.display(), a.gt.display()))?;
    if let Some(path) = &a.json {
        let text = serde_json::to_string_pretty(&metrics).context("serialising the scores")?;
        denser::io::atomic::write_file(path, text.as_bytes())?;
    }
    Ok(Box::new(Scores {
        metrics,
        json: a.json,
    }))
}

/// `denser stereo-eval`: scores a predicted disparity map (PFM or KITTI 16-bit PNG) against a
/// ground truth in either format, over all ground-truth pixels (missing predictions count as
/// errors), optionally inside a Middlebury-style mask PNG (255 = scored).
fn stereo_eval(gt: &Path, pred: &Path, mask: Option<&Path>) -> denser::Result<StereoMetrics> {
    let gt_img = denser::depth::disparity_io::read_disparity(gt)?;
    let pred_img = denser::depth::disparity_io::read_disparity(pred)?;
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
            let grey = denser::io::image::read_grey(m)?;
            if grey.width != gt_img.width || grey.height != gt_img.height {
                return Err(Error::bad_input(
                    m,
                    format!(
                        "mask is {}×{} but the ground truth is {}×{}",
                        grey.width, grey.height, gt_img.width, gt_img.height
                    ),
                ));
            }
            Some(denser::depth::metrics::mask_from_middlebury(&grey))
        }
        None => None,
    };
    denser::depth::evaluate_disparity(&pred_img, &gt_img, mask_img.as_ref())
}
