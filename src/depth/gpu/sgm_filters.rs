//! SGM's post-filters on the GPU, where the selection left its disparities, and TGV's initial
//! disparity made there from SGM's:
//!
//! - the 3×3 median over valid neighbours (`shaders/sgm_median.wgsl`, twin of
//!   [`crate::depth::sgm::median_filter_3x3`]);
//! - the speckle filter (`shaders/sgm_speckle_{runs,join,count,clear}.wgsl`, twin of
//!   [`crate::depth::sgm::remove_speckles`]): runs per row, joined across rows in a union–find
//!   forest linked by `atomicMin`, sizes counted at the roots, small regions removed;
//! - the fill of TGV's initial disparity (`shaders/tgv_fill_{rows,columns}.wgsl`, twin of
//!   [`crate::depth::tgv::fill_from_background`]).
//!
//! They handle disparities as bits and compute only what the CPU computes in f32 with correctly
//! rounded operations (the median's `0.5 · (lo + hi)`, the speckle test `|a − b| ≤ max`), so the
//! results are the CPU's bit for bit on every device (`tests/gpu/sgm.rs`).

use crate::depth::sgm::SgmParams;
use crate::depth::DisparityMap;
use crate::frame::Image;
use crate::gpu::kept::Kept;
use crate::gpu::layout::SgmFilterUniforms;
use crate::gpu::{shaders, ErrorScopes, GpuContext};
use crate::{Error, Result};

/// A disparity map on the device (SGM's, or the variational matcher's result): per pixel, the
/// disparity's bits (the CPU's NaN where invalid) and the confidence (f32, 0 where invalid), in
/// two buffers of one word per pixel.
#[derive(Debug, Clone)]
pub(super) struct MapOnDevice {
    pub disparity: wgpu::Buffer,
    pub confidence: wgpu::Buffer,
    pub width: u32,
    pub height: u32,
}

impl MapOnDevice {
    fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }

    fn uniforms(&self, params: &SgmParams, fallback_px: f32) -> SgmFilterUniforms {
        SgmFilterUniforms {
            width: self.width,
            height: self.height,
            max_size_px: params.speckle_max_size_px.min(u32::MAX as usize) as u32,
            max_diff_px: params.speckle_max_diff_px,
            fallback_px,
            pad: [0; 3],
        }
    }
}

/// Records [`crate::depth::sgm::SgmMatcher`]'s filters over `sgm` as its CPU matcher applies
/// them: the median (when `params.median_filter`; it writes a second buffer) and then the
/// speckle filter (when `params.speckle_max_size_px > 0`), which also zeroes the confidence of
/// the pixels it removes. Returns the filtered result.
pub(super) fn record_filters(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    kept: &mut Kept,
    sgm: MapOnDevice,
    params: &SgmParams,
) -> Result<MapOnDevice> {
    let n = sgm.pixels();
    if n == 0 || (!params.median_filter && params.speckle_max_size_px == 0) {
        return Ok(sgm);
    }
    ctx.check_binding("SGM's disparities (4 bytes per pixel)", n * 4)?;
    if n >= u32::MAX as u64 {
        return Err(Error::InvalidArgument(format!(
            "{n} pixels: the GPU's speckle filter numbers pixels in 32 bits; use --device cpu"
        )));
    }
    let uniforms = sgm.uniforms(params, 0.0);
    let bytes = bytemuck::bytes_of(&uniforms);
    let buf_uniforms = kept.uniform_with(ctx, "sgm_filter_uniforms", bytes);
    let mut out = sgm;
    if params.median_filter {
        let kernel = ctx.kernel(&shaders::SGM_MEDIAN)?;
        // Every pixel is written by the median.
        let median = kept.scratch(ctx, "sgm_median", n * 4);
        let buffers = [&buf_uniforms, &out.disparity, &median];
        let bind = kept.bind_group(ctx, "sgm_median", &kernel.layout, &buffers);
        ctx.record_dispatch(encoder, &kernel, &bind, n)?;
        out.disparity = median;
    }
    if params.speckle_max_size_px > 0 {
        // Both are written by the first pass.
        let parent = kept.scratch(ctx, "sgm_speckle_parent", n * 4);
        let sizes = kept.scratch(ctx, "sgm_speckle_sizes", n * 4);
        let buffers = [
            &buf_uniforms,
            &out.disparity,
            &parent,
            &sizes,
            &out.confidence,
        ];
        let passes = [
            (&shaders::SGM_SPECKLE_RUNS, out.height as u64),
            (&shaders::SGM_SPECKLE_JOIN, n),
            (&shaders::SGM_SPECKLE_COUNT, n),
            (&shaders::SGM_SPECKLE_CLEAR, n),
        ];
        for (source, invocations) in passes {
            let kernel = ctx.kernel(source)?;
            let bind = kept.bind_group(ctx, source.file, &kernel.layout, &buffers);
            ctx.record_dispatch(encoder, &kernel, &bind, invocations)?;
        }
    }
    Ok(out)
}

/// Records the fill of TGV's initial disparity from `sgm`'s into `target` (4 bytes per pixel):
/// [`crate::depth::tgv::fill_from_background`] with `fallback_px` on the device.
pub(super) fn record_fill(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    kept: &mut Kept,
    sgm: &MapOnDevice,
    fallback_px: f32,
    target: &wgpu::Buffer,
) -> Result<()> {
    let uniforms = sgm.uniforms(&SgmParams::default(), fallback_px);
    let bytes = bytemuck::bytes_of(&uniforms);
    let buf_uniforms = kept.uniform_with(ctx, "tgv_fill_uniforms", bytes);
    let buffers = [&buf_uniforms, &sgm.disparity, target];
    let passes = [
        (&shaders::TGV_FILL_ROWS, sgm.height as u64),
        (&shaders::TGV_FILL_COLUMNS, sgm.width as u64),
    ];
    for (source, invocations) in passes {
        let kernel = ctx.kernel(source)?;
        let bind = kept.bind_group(ctx, source.file, &kernel.layout, &buffers);
        ctx.record_dispatch(encoder, &kernel, &bind, invocations)?;
    }
    Ok(())
}

/// A map of `sgm`'s size for its result to be read into ([`targets`]).
pub(super) fn empty_map(sgm: &MapOnDevice) -> DisparityMap {
    DisparityMap {
        disparity_px: Image::filled(sgm.width, sgm.height, 0.0f32),
        confidence: Some(Image::filled(sgm.width, sgm.height, 0.0f32)),
    }
}

/// `sgm`'s buffers paired with `map`'s images (from [`empty_map`]), for
/// [`GpuContext::submit_and_read_back`].
pub(super) fn targets<'a>(
    sgm: &'a MapOnDevice,
    map: &'a mut DisparityMap,
) -> Vec<(&'a wgpu::Buffer, &'a mut [u8])> {
    let confidence = map.confidence.as_mut().expect("made with a confidence");
    vec![
        (
            &sgm.disparity,
            bytemuck::cast_slice_mut(&mut map.disparity_px.data),
        ),
        (
            &sgm.confidence,
            bytemuck::cast_slice_mut(&mut confidence.data),
        ),
    ]
}

/// Submits `encoder` with `sgm` read back in the same submit (one wait), as a disparity map.
pub(super) fn read_sgm(
    ctx: &GpuContext,
    encoder: wgpu::CommandEncoder,
    kept: &mut Kept,
    sgm: &MapOnDevice,
) -> Result<DisparityMap> {
    let mut map = empty_map(sgm);
    ctx.submit_and_read_back(encoder, kept, &mut targets(sgm, &mut map))?;
    Ok(map)
}

/// Uploads a disparity map (`disparity`, `confidence`; of equal sizes) as [`MapOnDevice`].
fn upload(ctx: &GpuContext, disparity: &Image<f32>, confidence: &Image<f32>) -> MapOnDevice {
    MapOnDevice {
        disparity: ctx.storage("sgm_disparity", bytemuck::cast_slice(&disparity.data)),
        confidence: ctx.storage("sgm_confidence", bytemuck::cast_slice(&confidence.data)),
        width: disparity.width,
        height: disparity.height,
    }
}

fn check_sizes(disparity: &Image<f32>, confidence: &Image<f32>) -> Result<()> {
    let (d, c) = (
        (disparity.width, disparity.height),
        (confidence.width, confidence.height),
    );
    if d != c {
        return Err(Error::InvalidArgument(format!(
            "disparity {}×{} and confidence {}×{} differ in size",
            d.0, d.1, c.0, c.1
        )));
    }
    Ok(())
}

/// SGM's filters (`shaders/sgm_median.wgsl`, `sgm_speckle_*.wgsl`) over an uploaded map, read
/// back: the twin of the CPU matcher's median, speckle filter and confidence rule, for tests.
/// The confidence must be 0 where the disparity is NaN (as the selection leaves it).
pub fn filter_disparities_gpu(
    ctx: &GpuContext,
    disparity: &Image<f32>,
    confidence: &Image<f32>,
    params: &SgmParams,
) -> Result<DisparityMap> {
    check_sizes(disparity, confidence)?;
    let scope = ErrorScopes::push(&ctx.device);
    let sgm = upload(ctx, disparity, confidence);
    let mut encoder = ctx.encoder("sgm_filters");
    let mut kept = Kept::default();
    let out = record_filters(ctx, &mut encoder, &mut kept, sgm, params)?;
    let map = read_sgm(ctx, encoder, &mut kept, &out)?;
    scope.pop("running SGM's filters")?;
    Ok(map)
}

/// [`crate::depth::tgv::fill_from_background`] on the GPU (`shaders/tgv_fill_*.wgsl`) over an
/// uploaded disparity, read back; for tests.
pub fn fill_from_background_gpu(
    ctx: &GpuContext,
    disparity: &Image<f32>,
    fallback_px: f32,
) -> Result<Vec<f32>> {
    let n = disparity.data.len();
    if n == 0 {
        return Ok(Vec::new());
    }
    let scope = ErrorScopes::push(&ctx.device);
    let zeros = Image::filled(disparity.width, disparity.height, 0.0f32);
    let sgm = upload(ctx, disparity, &zeros);
    let mut kept = Kept::default();
    let target = kept.scratch(ctx, "tgv_target", n as u64 * 4);
    let mut encoder = ctx.encoder("tgv_fill");
    record_fill(ctx, &mut encoder, &mut kept, &sgm, fallback_px, &target)?;
    let mut out = vec![0.0f32; n];
    let mut buffers = [(&target, bytemuck::cast_slice_mut(&mut out))];
    ctx.submit_and_read_back(encoder, &mut kept, &mut buffers)?;
    scope.pop("filling the initial disparity")?;
    Ok(out)
}
