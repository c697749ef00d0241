//! SGM on the GPU: the path aggregation (`shaders/sgm_paths.wgsl`, one dispatch per direction)
//! runs where the cost volume was made, and the summed costs `S` come back for the selection
//! (winner, uniqueness, sub-pixel fit, left–right check), the median and the speckle filter,
//! which run on the CPU exactly as [`SgmMatcher`]'s do. The sums are integers, equal to the CPU's
//! ([`crate::depth::sgm::aggregate_paths`]), so the disparities are identical to the CPU
//! matcher's bit for bit, on any device.
//!
//! What crosses the bus for one pair: the two images up; the cost volume (1 byte per pixel and
//! disparity, which the selection's sub-pixel window and the variational matcher read) and `S`
//! (2 bytes) down.

use super::{cost_volume_on_device, OnDevice};
use crate::depth::sgm::{CostVolume, SgmMatcher, SgmParams, SgmPaths};
use crate::depth::{DisparityEstimator, DisparityMap};
use crate::frame::GreyImage;
use crate::gpu::layout::SgmPathUniforms;
use crate::gpu::shaders;
use crate::gpu::{ErrorScopes, GpuContext};
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

/// Aggregates the paths of `params` over the cost volume `volume` (u8 costs, 4 per word) of a
/// `width` × `height` image whose grey levels `image` holds (4 per word), on the device; returns
/// the buffer of `S` (u16, 2 per word, the volume's order). One submit.
fn aggregate_on_device(
    ctx: &GpuContext,
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
    let sums = ctx.storage_zeroed("sgm_sums", words * 4);
    let mut encoder = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("sgm_paths"),
        });
    for &(dx, dy) in directions(params.paths) {
        let lines = match (dx, dy) {
            (_, 0) => height,
            (0, _) => width,
            _ => width + height - 1,
        };
        let uniforms = SgmPathUniforms {
            width,
            height,
            num_disparities: nd as u32,
            dx,
            dy,
            p1: params.p1 as u32,
            p2: params.p2 as u32,
            p2_scale: params.p2_intensity_scale.map_or(0, u32::from),
            lines,
            pad: [0; 3],
        };
        let buf_uniforms = ctx.uniform("sgm_path_uniforms", bytemuck::bytes_of(&uniforms));
        let bind = ctx.bind_group(
            "sgm_paths",
            &kernel.layout,
            &[&buf_uniforms, volume, image, &sums],
        );
        // One workgroup (64 invocations) per path line.
        ctx.record_dispatch(&mut encoder, &kernel, &bind, lines as u64 * 64)?;
    }
    ctx.submit(encoder);
    Ok(sums)
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
    if (image.width, image.height) != (volume.width, volume.height)
        || volume.num_disparities != params.num_disparities
    {
        return Err(Error::InvalidArgument(format!(
            "image {}×{} and cost volume {}×{}×{} do not match the parameters' {} disparities",
            image.width,
            image.height,
            volume.width,
            volume.height,
            volume.num_disparities,
            params.num_disparities
        )));
    }
    if volume.width == 0 || volume.height == 0 {
        return Ok(Vec::new());
    }
    let scope = ErrorScopes::push(&ctx.device);
    let buf_volume = ctx.storage("sgm_volume", &volume.cost);
    let buf_image = ctx.storage("sgm_image", &image.data);
    let sums = aggregate_on_device(
        ctx,
        (&buf_volume, &buf_image),
        (volume.width, volume.height),
        params,
    )?;
    scope.pop("running the SGM path kernels")?;
    read_sums(ctx, &sums, volume.cost.len())
}

/// SGM of a pair whose cost volume is on the device (`on_device`, read back as `volume`; `left`
/// its left image): the paths aggregated there, the selection and filters of [`SgmMatcher`] on
/// the CPU. Beyond [`GPU_SGM_MAX_DISPARITIES`] the aggregation runs on the CPU (the same result).
pub(super) fn sgm_from_device(
    ctx: &GpuContext,
    matcher: &SgmMatcher,
    left: &GreyImage,
    volume: &CostVolume,
    on_device: &OnDevice,
) -> Result<DisparityMap> {
    let p = &matcher.params;
    p.validate()?;
    if p.num_disparities > GPU_SGM_MAX_DISPARITIES {
        return matcher.estimate_from_volume(left, volume);
    }
    if volume.width == 0 || volume.height == 0 {
        return Err(Error::InvalidArgument("stereo images are empty".into()));
    }
    let scope = ErrorScopes::push(&ctx.device);
    let sums = aggregate_on_device(
        ctx,
        (&on_device.volume, &on_device.left),
        (volume.width, volume.height),
        p,
    )?;
    scope.pop("running the SGM path kernels")?;
    let sums = read_sums(ctx, &sums, volume.cost.len())?;
    matcher.estimate_from_sums(volume, &sums)
}

/// [`SgmMatcher`] with its cost volume and path aggregation on the GPU; the same disparities.
#[derive(Debug)]
pub struct SgmMatcherGpu {
    ctx: std::sync::Arc<GpuContext>,
    matcher: SgmMatcher,
}

impl SgmMatcherGpu {
    /// `matcher` on the device of `ctx`.
    pub fn new(ctx: std::sync::Arc<GpuContext>, matcher: SgmMatcher) -> Self {
        SgmMatcherGpu { ctx, matcher }
    }
}

impl DisparityEstimator for SgmMatcherGpu {
    fn name(&self) -> &str {
        self.matcher.name()
    }

    fn estimate(&self, left: &GreyImage, right: &GreyImage) -> Result<DisparityMap> {
        let p = &self.matcher.params;
        p.validate()?;
        let census = (&p.census, p.min_disparity_px, p.num_disparities);
        let (volume, on_device) = cost_volume_on_device(&self.ctx, left, right, census)?;
        sgm_from_device(&self.ctx, &self.matcher, left, &volume, &on_device)
    }
}
