//! Census signatures and the cost volume on the GPU (`shaders/census.wgsl`,
//! `shaders/census_cost.wgsl`), twins of `src/depth/census.rs` and `CostVolume::from_census`:
//! integers, bit-identical. The volume stays on the device for the stages that read it there
//! ([`OnDevice`]); it is read back only where the CPU needs it.

use crate::depth::census::{CensusImage, CensusKind, CensusParams};
use crate::depth::sgm::CostVolume;
use crate::frame::GreyImage;
use crate::gpu::layout::{CensusUniforms, CostUniforms};
use crate::gpu::shaders;
use crate::gpu::{ErrorScopes, GpuContext};
use crate::{Error, Result};

/// Checks that a stereo pair is non-empty, equally sized, with consistent buffers.
pub(super) fn check_pair(left: &GreyImage, right: &GreyImage) -> Result<()> {
    for img in [left, right] {
        if img.data.len() != img.width as usize * img.height as usize {
            return Err(Error::InvalidArgument(
                "image buffer length does not match its size".into(),
            ));
        }
    }
    if (left.width, left.height) != (right.width, right.height) {
        return Err(Error::InvalidArgument(format!(
            "stereo images differ in size: {}×{} vs {}×{}",
            left.width, left.height, right.width, right.height
        )));
    }
    if left.width == 0 || left.height == 0 {
        return Err(Error::InvalidArgument("stereo images are empty".into()));
    }
    Ok(())
}

/// Records the census transform of `image` into a new signature buffer (`words` u32 per pixel);
/// returns it and the image's buffer on the device (grey levels, 4 per word).
fn record_census(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    image: &GreyImage,
    params: &CensusParams,
    words: u32,
) -> Result<(wgpu::Buffer, wgpu::Buffer)> {
    let n = image.width as u64 * image.height as u64;
    ctx.check_binding("census signatures", n * words as u64 * 4)?;
    let kernel = ctx.kernel(&shaders::CENSUS)?;
    let (ternary, threshold) = match params.kind {
        CensusKind::Binary => (0, 0),
        CensusKind::Ternary { threshold } => (1, threshold as u32),
    };
    let uniforms = CensusUniforms {
        width: image.width,
        height: image.height,
        window_width: params.window_width,
        window_height: params.window_height,
        ternary,
        threshold,
        words,
        pad: 0,
    };
    let buf_uniforms = ctx.uniform("census_uniforms", bytemuck::bytes_of(&uniforms));
    let buf_image = ctx.storage("census_image", &image.data);
    let buf_sig = ctx.storage_zeroed("census_signatures", n * words as u64 * 4);
    let bind = ctx.bind_group(
        "census",
        &kernel.layout,
        &[&buf_uniforms, &buf_image, &buf_sig],
    );
    ctx.record_dispatch(encoder, &kernel, &bind, n)?;
    Ok((buf_sig, buf_image))
}

/// `u32` words of a signature of `params` (two per `u64` word of [`CensusImage`]).
fn census_words(params: &CensusParams) -> u32 {
    if params.bits() > 64 {
        4
    } else {
        2
    }
}

/// [`crate::depth::census::census_transform`] on the GPU (bit-identical: integer comparisons).
pub fn census_transform_gpu(
    ctx: &GpuContext,
    image: &GreyImage,
    params: &CensusParams,
) -> Result<CensusImage> {
    params.validate()?;
    if image.data.len() != image.width as usize * image.height as usize {
        return Err(Error::InvalidArgument(format!(
            "image data holds {} pixels, expected {}×{}",
            image.data.len(),
            image.width,
            image.height
        )));
    }
    let words = census_words(params);
    let n = image.width as u64 * image.height as u64;
    if n == 0 {
        return Ok(CensusImage {
            width: image.width,
            height: image.height,
            words_per_pixel: words as usize / 2,
            bits: params.bits(),
            data: Vec::new(),
        });
    }
    let scope = ErrorScopes::push(&ctx.device);
    let mut encoder = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("census"),
        });
    let (sig, _) = record_census(ctx, &mut encoder, image, params, words)?;
    ctx.submit(encoder);
    scope.pop("running the census kernel")?;
    // `words` u32 per pixel, read back as u64 words.
    let data = ctx.read_back_as::<u64>(&sig, n as usize * words as usize / 2)?;
    Ok(CensusImage {
        width: image.width,
        height: image.height,
        words_per_pixel: words as usize / 2,
        bits: params.bits(),
        data,
    })
}

/// The census cost volume of a rectified pair on the GPU: census signatures of both images and
/// their Hamming distances for disparities `[min_disparity_px, min_disparity_px +
/// num_disparities)`, bit-identical to [`SgmMatcher::cost_volume`] (CPU: `census_transform` and
/// `CostVolume::from_census`). Fails with [`Error::GpuCapacity`] when the volume (1 byte per
/// pixel and disparity) does not fit one binding.
pub fn cost_volume_gpu(
    ctx: &GpuContext,
    left: &GreyImage,
    right: &GreyImage,
    census: &CensusParams,
    min_disparity_px: i32,
    num_disparities: usize,
) -> Result<CostVolume> {
    let args = (census, min_disparity_px, num_disparities);
    cost_volume_on_device(ctx, left, right, args).map(|(volume, _)| volume)
}

/// The cost volume on the device (u8 costs packed 4 per word) and the left image there (grey
/// levels, 4 per word), for the stages that read them there.
pub(super) struct OnDevice {
    pub(super) volume: wgpu::Buffer,
    pub(super) left: wgpu::Buffer,
    /// The image's size, pixels.
    pub(super) width: u32,
    pub(super) height: u32,
    /// The largest cost (the signature's bits).
    pub(super) max_cost: u8,
}

/// [`cost_volume_gpu`], also returning the volume and the left image on the device.
pub(super) fn cost_volume_on_device(
    ctx: &GpuContext,
    left: &GreyImage,
    right: &GreyImage,
    args: (&CensusParams, i32, usize),
) -> Result<(CostVolume, OnDevice)> {
    let on_device = cost_volume_kept_on_device(ctx, left, right, args)?;
    let entries = on_device.width as usize * on_device.height as usize * args.2;
    let mut cost: Vec<u8> = ctx.read_back_as(&on_device.volume, entries.div_ceil(4) * 4)?;
    cost.truncate(entries);
    let volume = CostVolume {
        width: left.width,
        height: left.height,
        min_disparity_px: args.1,
        num_disparities: args.2,
        max_cost: on_device.max_cost,
        cost,
    };
    Ok((volume, on_device))
}

/// The cost volume of [`cost_volume_gpu`] made on the device and kept there (nothing read
/// back), with the left image.
pub(super) fn cost_volume_kept_on_device(
    ctx: &GpuContext,
    left: &GreyImage,
    right: &GreyImage,
    (census, min_disparity_px, num_disparities): (&CensusParams, i32, usize),
) -> Result<OnDevice> {
    census.validate()?;
    check_pair(left, right)?;
    let max_cost = u8::try_from(census.bits()).map_err(|_| {
        Error::InvalidArgument(format!(
            "census signatures of {} bits do not fit u8 costs",
            census.bits()
        ))
    })?;
    let n = left.width as u64 * left.height as u64;
    let entries = n * num_disparities as u64;
    ctx.check_binding("cost volume (1 byte per pixel and disparity)", entries)?;
    if entries > u32::MAX as u64 || num_disparities == 0 {
        return Err(Error::InvalidArgument(format!(
            "cost volume of {entries} entries: must be between 1 and 2³² − 1"
        )));
    }
    let words = census_words(census);
    let kernel = ctx.kernel(&shaders::CENSUS_COST)?;
    let scope = ErrorScopes::push(&ctx.device);
    let mut encoder = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("census_cost"),
        });
    let (sig_left, left_image) = record_census(ctx, &mut encoder, left, census, words)?;
    let (sig_right, _) = record_census(ctx, &mut encoder, right, census, words)?;
    let uniforms = CostUniforms {
        width: left.width,
        height: left.height,
        num_disparities: num_disparities as u32,
        min_disparity_px,
        max_cost: max_cost as u32,
        words,
        entries: entries as u32,
        pad: 0,
    };
    let buf_uniforms = ctx.uniform("cost_uniforms", bytemuck::bytes_of(&uniforms));
    let packed_words = entries.div_ceil(4);
    let buf_volume = ctx.storage_zeroed("cost_volume", packed_words * 4);
    let bind = ctx.bind_group(
        "census_cost",
        &kernel.layout,
        &[&buf_uniforms, &sig_left, &sig_right, &buf_volume],
    );
    ctx.record_dispatch(&mut encoder, &kernel, &bind, packed_words)?;
    ctx.submit(encoder);
    scope.pop("running the census cost kernels")?;
    Ok(OnDevice {
        volume: buf_volume,
        left: left_image,
        width: left.width,
        height: left.height,
        max_cost,
    })
}
