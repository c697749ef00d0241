//! Depth from disparity on the GPU (`shaders/disparity_depth.wgsl`), equal bit for bit to the
//! CPU's [`crate::depth::disparity_to_depth`]: the kernel takes the f64 quotient `f·B / d` in
//! integers and rounds it twice, as the CPU's f64 division and cast to f32 do. A building block
//! for a depth map that stays on the device, where a matcher left its disparities.

use crate::depth::DisparityMap;
use crate::frame::{DepthImage, Image};
use crate::gpu::kept::Kept;
use crate::gpu::layout::DisparityDepthUniforms;
use crate::gpu::{shaders, ErrorScopes, GpuContext};
use crate::{Error, Result};

/// The uniforms of `disparity_depth.wgsl` for `pixels` pixels and `f·B = fx_px · baseline_m`
/// (the product the CPU takes), or why the kernel cannot convert with it: it needs
/// `8 ≤ f·B < 2¹⁰⁰` (every positive f32 disparity then gives a normal f32 depth or infinity).
pub fn disparity_depth_uniforms(
    pixels: usize,
    fx_px: f64,
    baseline_m: f64,
) -> Result<DisparityDepthUniforms> {
    let fb = fx_px * baseline_m;
    if !(8.0..2f64.powi(100)).contains(&fb) {
        return Err(Error::InvalidArgument(format!(
            "depth from disparity on the GPU needs 8 ≤ f·B < 2¹⁰⁰ (pixel·metres), not {fb} \
             (f = {fx_px} px, B = {baseline_m} m)"
        )));
    }
    let pixels = u32::try_from(pixels)
        .map_err(|_| Error::InvalidArgument(format!("{pixels} pixels: too many for one map")))?;
    // fb = M · 2^E with M of 53 bits (a normal f64).
    let bits = fb.to_bits();
    let mantissa = (bits & ((1u64 << 52) - 1)) | (1u64 << 52);
    Ok(DisparityDepthUniforms {
        pixels,
        fb_exp: ((bits >> 52) & 0x7ff) as i32 - 1075,
        fb_words: [mantissa as u32, (mantissa >> 32) as u32],
    })
}

/// [`crate::depth::disparity_to_depth`] on the GPU: the disparities go up, the kernel runs,
/// the depths come back (the comparison with the CPU; the pipeline would keep them there).
pub fn disparity_to_depth_gpu(
    ctx: &GpuContext,
    disparity: &DisparityMap,
    fx_px: f64,
    baseline_m: f64,
) -> Result<DepthImage> {
    let img = &disparity.disparity_px;
    let uniforms = disparity_depth_uniforms(img.data.len(), fx_px, baseline_m)?;
    if img.data.is_empty() {
        return Ok(Image {
            width: img.width,
            height: img.height,
            data: Vec::new(),
        });
    }
    ctx.check_binding("the disparity map", img.data.len() as u64 * 4)?;
    let buf_disparity = ctx.storage("disparity", bytemuck::cast_slice(&img.data));
    let mut encoder = ctx.encoder("disparity_depth");
    let kept = &mut Kept::default();
    let buf_depth = record_disparity_depth((ctx, kept), &mut encoder, &uniforms, &buf_disparity)?;
    ctx.submit(encoder);
    Ok(Image {
        width: img.width,
        height: img.height,
        data: ctx.read_back_as(&buf_depth, img.data.len())?,
    })
}

/// Records `disparity_depth.wgsl` over the disparities `buf_disparity` (f32, `uniforms.pixels`
/// of them) into `encoder`, with its buffers and bind group kept in `kept`; returns the buffer
/// the depths will be in (f32, metres; `kept`'s, overwritten by the next call).
pub(crate) fn record_disparity_depth(
    (ctx, kept): (&GpuContext, &mut Kept),
    encoder: &mut wgpu::CommandEncoder,
    uniforms: &DisparityDepthUniforms,
    buf_disparity: &wgpu::Buffer,
) -> Result<wgpu::Buffer> {
    let pixels = uniforms.pixels as u64;
    ctx.check_binding("the depth map", pixels * 4)?;
    let kernel = ctx.kernel(&shaders::DISPARITY_DEPTH)?;
    let scope = ErrorScopes::push(&ctx.device);
    let uniform_bytes = bytemuck::bytes_of(uniforms);
    let buf_uniforms = kept.uniform_with(ctx, "disparity_depth_uniforms", uniform_bytes);
    let buf_depth = kept.scratch(ctx, "depth", pixels * 4);
    let bind = kept.bind_group(
        ctx,
        "disparity_depth",
        &kernel.layout,
        &[&buf_uniforms, buf_disparity, &buf_depth],
    );
    ctx.record_dispatch(encoder, &kernel, &bind, pixels)?;
    scope.pop("recording depth from disparity on the GPU")?;
    Ok(buf_depth)
}
