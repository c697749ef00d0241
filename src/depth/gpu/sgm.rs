//! SGM on the GPU, where the cost volume was made: the path aggregation
//! (`shaders/sgm_paths.wgsl`, all directions in one dispatch), the winner selection
//! (`shaders/sgm_right.wgsl`, the right image's winners, then `shaders/sgm_select.wgsl`:
//! winner-take-all, the uniqueness test, the sub-pixel fit, the left–right check and the
//! confidence) and the median and speckle filters (`sgm_filters.rs`), in one submit. The sums
//! and the fit's terms are integers, equal to the CPU's ([`crate::depth::sgm::aggregate_paths`]);
//! the fit's and the confidence's divisions are rounded as the CPU's f32 divisions round them
//! (`shaders/shared/exact_div.wgsl`, in integers: WGSL would let a device divide within
//! 2.5 ULP), and the filters repeat the CPU's f32 operations: the disparities and confidences
//! are the CPU matcher's bit for bit on every device.
//!
//! What crosses the bus for one pair of `SgmMatcherGpu`: the two images up, the disparities and
//! confidences down (8 bytes per pixel), in one submit and one wait; the cost volume and `S`
//! stay on the device. TGV-tensor ([`super::estimate_tgv_gpu`]) keeps SGM's result there too.
//! Every buffer and bind group is kept between pairs (`crate::gpu::kept`): after the first pair
//! of a size, a pair creates none.

use super::sgm_filters::{read_sgm, record_filters, MapOnDevice};
use super::{cost_volume_on_device, record_cost_volume, OnDevice};
use crate::depth::sgm::{check_volume, CostVolume, SgmMatcher, SgmParams, SgmPaths, SubpixelFit};
use crate::depth::{DisparityEstimator, DisparityMap, OnDeviceDisparity};
use crate::frame::{GreyImage, Image};
use crate::gpu::kept::Kept;
use crate::gpu::layout::{SgmPathUniforms, SgmSelectUniforms};
use crate::gpu::shaders;
use crate::gpu::{ErrorScopes, GpuContext, StageTally};
use crate::{Error, Result};

/// Most disparities one aggregation workgroup holds (64 invocations, 4 slices each; keep in sync
/// with `MAX_DISPARITIES` in `shaders/sgm_paths.wgsl`).
pub const GPU_SGM_MAX_DISPARITIES: usize = 256;

/// The directions `(dx, dy)` of `paths`, each the step from a pixel's predecessor to it.
fn directions(paths: SgmPaths) -> &'static [(i32, i32)] {
    match paths {
        SgmPaths::Four => &[(1, 0), (-1, 0), (0, 1), (0, -1)],
        SgmPaths::Five => &[(1, 0), (-1, 0), (0, 1), (1, 1), (-1, 1)],
        SgmPaths::Eight => &[
            (1, 0),
            (-1, 0),
            (0, 1),
            (1, 1),
            (-1, 1),
            (0, -1),
            (1, -1),
            (-1, -1),
        ],
    }
}

/// Records the aggregation of the paths of `params` over the cost volume `volume` (u8 costs, 4
/// per word) of a `width` × `height` image whose grey levels `image` holds (4 per word); returns
/// the buffer of `S` (u16, 2 per word, the volume's order).
fn record_aggregation(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    kept: &mut Kept,
    (volume, image): (&wgpu::Buffer, &wgpu::Buffer),
    (width, height): (u32, u32),
    params: &SgmParams,
) -> Result<wgpu::Buffer> {
    let nd = params.num_disparities;
    if nd > GPU_SGM_MAX_DISPARITIES {
        return Err(Error::InvalidArgument(format!(
            "SGM on the GPU searches at most {GPU_SGM_MAX_DISPARITIES} disparities, not {nd}; use --device cpu"
        )));
    }
    let entries = width as u64 * height as u64 * nd as u64;
    ctx.check_binding(
        "SGM's summed costs (2 bytes per pixel and disparity)",
        entries * 2,
    )?;
    let kernel = ctx.kernel(&shaders::SGM_PATHS)?;
    let words = entries.div_ceil(2);
    let sums = kept.scratch(ctx, "sgm_sums", words * 4);
    encoder.clear_buffer(&sums, 0, Some(words * 4));
    let mut uniforms = SgmPathUniforms {
        width,
        height,
        num_disparities: nd as u32,
        p1: params.p1 as u32,
        p2: params.p2 as u32,
        p2_scale: params.p2_intensity_scale.map_or(0, u32::from),
        ..Default::default()
    };
    // The longest lines first (the horizontal ones: `width` steps each), so that they start
    // first; a direction's lines are consecutive workgroups.
    let mut dirs: Vec<(i32, i32)> = directions(params.paths).to_vec();
    dirs.sort_by_key(|&(_, dy)| dy != 0);
    for (k, &(dx, dy)) in dirs.iter().enumerate() {
        let lines = match (dx, dy) {
            (_, 0) => height,
            (0, _) => width,
            _ => width + height - 1,
        };
        uniforms.dirs[k] = [dx, dy, uniforms.lines as i32, lines as i32];
        uniforms.lines += lines;
    }
    uniforms.directions = dirs.len() as u32;
    let bytes = bytemuck::bytes_of(&uniforms);
    let buf_uniforms = kept.uniform_with(ctx, "sgm_path_uniforms", bytes);
    let bind = kept.bind_group(
        ctx,
        "sgm_paths",
        &kernel.layout,
        &[&buf_uniforms, volume, image, &sums],
    );
    // One workgroup (64 invocations) per path line, of every direction.
    ctx.record_dispatch(encoder, &kernel, &bind, uniforms.lines as u64 * 64)?;
    Ok(sums)
}

/// Records the winner selection over `sums` (and the raw costs `volume`, for the windowed fit)
/// of a `width` × `height` image; returns its disparities and confidences.
fn record_selection(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    kept: &mut Kept,
    (sums, volume): (&wgpu::Buffer, &wgpu::Buffer),
    (width, height): (u32, u32),
    params: &SgmParams,
) -> Result<MapOnDevice> {
    let radius = params.subpixel_cost_window / 2;
    // The window's sums of u8 costs stay below 2^24, exact in f32 as the CPU converts them.
    if radius > 127 {
        return Err(Error::InvalidArgument(format!(
            "a sub-pixel cost window of {} pixels on the GPU (at most 255); use --device cpu",
            params.subpixel_cost_window
        )));
    }
    let right = ctx.kernel(&shaders::SGM_RIGHT)?;
    let select = ctx.kernel(&shaders::SGM_SELECT)?;
    let n = width as u64 * height as u64;
    let uniq = params.uniqueness_ratio;
    let uniforms = SgmSelectUniforms {
        width,
        height,
        num_disparities: params.num_disparities as u32,
        min_disparity_px: params.min_disparity_px,
        subpixel: match params.subpixel {
            SubpixelFit::None => 0,
            SubpixelFit::Parabola => 1,
            SubpixelFit::Equiangular => 2,
        },
        radius,
        lr_max_diff: params.lr_max_diff_px.map_or(0xffff, |d| d.min(0xfffe)),
        // 1: the test `S_second · 1 < S_best` never holds (S_second ≥ S_best).
        uniqueness_factor: if uniq > 0.0 { 1.0 - uniq } else { 1.0 },
    };
    let buf_uniforms = kept.uniform_with(ctx, "sgm_select_uniforms", bytemuck::bytes_of(&uniforms));
    // Every entry of these is written by its kernel.
    let right_k = kept.scratch(ctx, "sgm_right_k", n * 4);
    let disparity = kept.scratch(ctx, "sgm_disparity", n * 4);
    let confidence = kept.scratch(ctx, "sgm_confidence", n * 4);
    let bind = kept.bind_group(
        ctx,
        "sgm_right",
        &right.layout,
        &[&buf_uniforms, sums, &right_k],
    );
    ctx.record_dispatch(encoder, &right, &bind, n)?;
    let bind = kept.bind_group(
        ctx,
        "sgm_select",
        &select.layout,
        &[
            &buf_uniforms,
            sums,
            volume,
            &right_k,
            &disparity,
            &confidence,
        ],
    );
    ctx.record_dispatch(encoder, &select, &bind, n)?;
    Ok(MapOnDevice {
        disparity,
        confidence,
        width,
        height,
    })
}

/// Reads `S` back: `entries` u16 values.
fn read_sums(ctx: &GpuContext, sums: &wgpu::Buffer, entries: usize) -> Result<Vec<u16>> {
    let mut out: Vec<u16> = ctx.read_back_as(sums, entries.div_ceil(2) * 2)?;
    out.truncate(entries);
    Ok(out)
}

/// [`crate::depth::sgm::aggregate_paths`] on the GPU: `S` of `volume` with `image` the left
/// image, equal to the CPU's. Uploads the volume and the image.
pub fn aggregate_paths_gpu(
    ctx: &GpuContext,
    volume: &CostVolume,
    image: &GreyImage,
    params: &SgmParams,
) -> Result<Vec<u16>> {
    params.validate()?;
    check_volume(volume, image, params)?;
    if volume.width == 0 || volume.height == 0 {
        return Ok(Vec::new());
    }
    let scope = ErrorScopes::push(&ctx.device);
    let buf_volume = ctx.storage("sgm_volume", &volume.cost);
    let buf_image = ctx.storage("sgm_image", &image.data);
    let mut encoder = ctx.encoder("sgm_paths");
    let sums = record_aggregation(
        ctx,
        &mut encoder,
        &mut Kept::default(),
        (&buf_volume, &buf_image),
        (volume.width, volume.height),
        params,
    )?;
    ctx.submit(encoder);
    scope.pop("running the SGM path kernels")?;
    read_sums(ctx, &sums, volume.cost.len())
}

/// SGM of a pair whose cost volume is on the device (`on_device`), appended to `encoder`
/// (which may hold the work that makes the volume): the paths aggregated, the winners selected
/// and the filters applied there ([`SgmMatcher`]'s, with its `params`); returns the result, on
/// the device. At most [`GPU_SGM_MAX_DISPARITIES`] disparities.
pub(super) fn sgm_on_device(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    params: &SgmParams,
    kept: &mut Kept,
    on_device: &OnDevice,
) -> Result<MapOnDevice> {
    params.validate()?;
    let size = (on_device.shape.width, on_device.shape.height);
    let volume = (&on_device.volume, &on_device.left);
    let sums = record_aggregation(ctx, encoder, kept, volume, size, params)?;
    let selection = record_selection(ctx, encoder, kept, (&sums, volume.0), size, params)?;
    record_filters(ctx, encoder, kept, selection, params)
}

/// [`sgm_on_device`], submitted and read back: one submit and one wait in all.
pub(super) fn sgm_recorded(
    ctx: &GpuContext,
    mut encoder: wgpu::CommandEncoder,
    matcher: &SgmMatcher,
    kept: &mut Kept,
    on_device: &OnDevice,
) -> Result<DisparityMap> {
    let scope = ErrorScopes::push(&ctx.device);
    let sgm = sgm_on_device(ctx, &mut encoder, &matcher.params, kept, on_device)?;
    let map = read_sgm(ctx, encoder, kept, &sgm)?;
    scope.pop("running the SGM kernels")?;
    Ok(map)
}

/// SGM's selection over sums computed elsewhere, on the device: [`crate::depth::sgm::select_disparities`]'s
/// twin, for tests. Uploads `sums` and the raw costs of `volume`.
pub fn select_disparities_gpu(
    ctx: &GpuContext,
    sums: &[u16],
    volume: &CostVolume,
    params: &SgmParams,
) -> Result<(Image<f32>, Image<f32>)> {
    params.validate()?;
    let (w, h) = (volume.width, volume.height);
    if sums.len() != volume.cost.len() || volume.num_disparities != params.num_disparities {
        return Err(Error::InvalidArgument(format!(
            "{} sums for a volume of {} entries and {} disparities ({} in the parameters)",
            sums.len(),
            volume.cost.len(),
            volume.num_disparities,
            params.num_disparities
        )));
    }
    let scope = ErrorScopes::push(&ctx.device);
    let buf_sums = ctx.storage("sgm_sums", bytemuck::cast_slice(sums));
    let buf_volume = ctx.storage("sgm_volume", &volume.cost);
    let mut encoder = ctx.encoder("sgm_select");
    let mut kept = Kept::default();
    let pair = (&buf_sums, &buf_volume);
    let selection = record_selection(ctx, &mut encoder, &mut kept, pair, (w, h), params)?;
    let out = read_sgm(ctx, encoder, &mut kept, &selection)?;
    scope.pop("running the SGM selection kernels")?;
    Ok((
        out.disparity_px,
        out.confidence.expect("read with its confidence"),
    ))
}

/// [`SgmMatcher`] on the GPU: the cost volume, the path aggregation, the selection and the
/// filters there; the same disparities (see the module documentation). Beyond
/// [`GPU_SGM_MAX_DISPARITIES`] the aggregation and selection run on the CPU over the volume
/// read back (the same result).
#[derive(Debug)]
pub struct SgmMatcherGpu {
    ctx: std::sync::Arc<GpuContext>,
    matcher: SgmMatcher,
    /// The buffers and bind groups of the aggregation and selection, kept between pairs.
    kept: std::sync::Mutex<Kept>,
    /// Where each pair's traffic is added.
    tally: StageTally,
}

impl SgmMatcherGpu {
    /// `matcher` on the device of `ctx`.
    pub fn new(ctx: std::sync::Arc<GpuContext>, matcher: SgmMatcher) -> Self {
        SgmMatcherGpu {
            ctx,
            matcher,
            kept: Default::default(),
            tally: StageTally::default(),
        }
    }

    /// Adds each pair's GPU traffic to `tally` (a run's stereo figures).
    pub fn counting_into(mut self, tally: StageTally) -> Self {
        self.tally = tally;
        self
    }
}

impl DisparityEstimator for SgmMatcherGpu {
    fn name(&self) -> &str {
        self.matcher.name()
    }

    fn estimate(&self, left: &GreyImage, right: &GreyImage) -> Result<DisparityMap> {
        self.tally
            .count(&self.ctx, || self.estimate_uncounted(left, right))
    }

    fn estimate_on_device(
        &self,
        left: &GreyImage,
        right: &GreyImage,
        finish: &mut dyn FnMut(OnDeviceDisparity) -> Result<()>,
    ) -> Option<Result<()>> {
        let p = &self.matcher.params;
        if p.num_disparities > GPU_SGM_MAX_DISPARITIES {
            return None;
        }
        Some(self.tally.count(&self.ctx, || {
            p.validate()?;
            let census = (&p.census, p.min_disparity_px, p.num_disparities);
            let mut kept = self.kept.lock().unwrap_or_else(|e| e.into_inner());
            let mut encoder = self.ctx.encoder("sgm");
            let scope = ErrorScopes::push(&self.ctx.device);
            let on_device =
                record_cost_volume(&self.ctx, &mut encoder, &mut kept, (left, right), census)?;
            let sgm = sgm_on_device(&self.ctx, &mut encoder, p, &mut kept, &on_device)?;
            scope.pop("recording the census cost and SGM kernels")?;
            finish(OnDeviceDisparity {
                ctx: &self.ctx,
                encoder,
                disparity: &sgm.disparity,
                width: sgm.width,
                height: sgm.height,
            })
        }))
    }
}

impl SgmMatcherGpu {
    fn estimate_uncounted(&self, left: &GreyImage, right: &GreyImage) -> Result<DisparityMap> {
        let p = &self.matcher.params;
        p.validate()?;
        let census = (&p.census, p.min_disparity_px, p.num_disparities);
        if p.num_disparities > GPU_SGM_MAX_DISPARITIES {
            let (volume, _) = cost_volume_on_device(&self.ctx, left, right, census)?;
            return self.matcher.estimate_from_volume(left, &volume);
        }
        let mut kept = self.kept.lock().unwrap_or_else(|e| e.into_inner());
        let mut encoder = self.ctx.encoder("sgm");
        let scope = ErrorScopes::push(&self.ctx.device);
        let on_device =
            record_cost_volume(&self.ctx, &mut encoder, &mut kept, (left, right), census)?;
        let map = sgm_recorded(&self.ctx, encoder, &self.matcher, &mut kept, &on_device)?;
        scope.pop("recording the census cost kernels")?;
        Ok(map)
    }
}
