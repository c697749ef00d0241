//! Census signatures and the cost volume on the GPU (`shaders/census.wgsl`,
//! `shaders/census_cost.wgsl`), twins of `src/depth/census.rs` and `CostVolume::from_census`:
//! integers, bit-identical. The volume stays on the device for the stages that read it there
//! ([`OnDevice`]); it is read back only where the CPU needs it.

use crate::depth::census::{CensusImage, CensusKind, CensusParams};
use crate::depth::sgm::{CostVolume, VolumeShape};
use crate::frame::GreyImage;
use crate::gpu::kept::Kept;
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

/// The names of one image's kept census buffers and bind group.
struct CensusNames {
    uniforms: &'static str,
    image: &'static str,
    signatures: &'static str,
    bind: &'static str,
}

/// The left and the right image's.
const CENSUS_NAMES: [CensusNames; 2] = [
    CensusNames {
        uniforms: "census_uniforms_left",
        image: "census_image_left",
        signatures: "census_signatures_left",
        bind: "census_left",
    },
    CensusNames {
        uniforms: "census_uniforms_right",
        image: "census_image_right",
        signatures: "census_signatures_right",
        bind: "census_right",
    },
];

/// Records the census transform of `image` into a kept signature buffer (`words` u32 per
/// pixel, every one written); returns it and the image's buffer on the device (grey levels, 4
/// per word).
fn record_census(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    (kept, names): (&mut Kept, &CensusNames),
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
    let buf_uniforms = kept.uniform_with(ctx, names.uniforms, bytemuck::bytes_of(&uniforms));
    let buf_image = kept.storage_with(ctx, names.image, &image.data);
    let buf_sig = kept.scratch(ctx, names.signatures, n * words as u64 * 4);
    let bind = kept.bind_group(
        ctx,
        names.bind,
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
    let mut encoder = ctx.encoder("census");
    let mut kept = Kept::default();
    let names = (&mut kept, &CENSUS_NAMES[0]);
    let (sig, _) = record_census(ctx, &mut encoder, names, image, params, words)?;
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
/// num_disparities)`, bit-identical to [`crate::depth::SgmMatcher::cost_volume`] (CPU:
/// `census_transform` and `CostVolume::from_census`). Fails with [`Error::GpuCapacity`] when the
/// volume (1 byte per pixel and disparity) does not fit one binding.
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
    /// The volume's size, disparity range and largest cost (the signature's bits).
    pub(super) shape: VolumeShape,
}

/// [`cost_volume_gpu`], also returning the volume and the left image on the device.
pub(super) fn cost_volume_on_device(
    ctx: &GpuContext,
    left: &GreyImage,
    right: &GreyImage,
    args: (&CensusParams, i32, usize),
) -> Result<(CostVolume, OnDevice)> {
    let scope = ErrorScopes::push(&ctx.device);
    let mut encoder = ctx.encoder("census_cost");
    let on_device =
        record_cost_volume(ctx, &mut encoder, &mut Kept::default(), (left, right), args)?;
    ctx.submit(encoder);
    scope.pop("running the census cost kernels")?;
    let shape = on_device.shape;
    let entries = shape.width as usize * shape.height as usize * shape.num_disparities;
    let mut cost: Vec<u8> = ctx.read_back_as(&on_device.volume, entries.div_ceil(4) * 4)?;
    cost.truncate(entries);
    let volume = CostVolume {
        width: shape.width,
        height: shape.height,
        min_disparity_px: shape.min_disparity_px,
        num_disparities: shape.num_disparities,
        max_cost: shape.max_cost,
        cost,
    };
    Ok((volume, on_device))
}

/// Records the making of the cost volume of [`cost_volume_gpu`] on the device, where it stays
/// (nothing read back), in `kept`'s buffers; returns it with the left image.
pub(super) fn record_cost_volume(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    kept: &mut Kept,
    (left, right): (&GreyImage, &GreyImage),
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
    let [l, r] = &CENSUS_NAMES;
    let (sig_left, left_image) = record_census(ctx, encoder, (kept, l), left, census, words)?;
    let (sig_right, _) = record_census(ctx, encoder, (kept, r), right, census, words)?;
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
    let buf_uniforms = kept.uniform_with(ctx, "cost_uniforms", bytemuck::bytes_of(&uniforms));
    let packed_words = entries.div_ceil(4);
    // Every word is written by the kernel.
    let buf_volume = kept.scratch(ctx, "cost_volume", packed_words * 4);
    let bind = kept.bind_group(
        ctx,
        "census_cost",
        &kernel.layout,
        &[&buf_uniforms, &sig_left, &sig_right, &buf_volume],
    );
    ctx.record_dispatch(encoder, &kernel, &bind, packed_words)?;
    Ok(OnDevice {
        volume: buf_volume,
        left: left_image,
        shape: VolumeShape {
            width: left.width,
            height: left.height,
            min_disparity_px,
            num_disparities,
            max_cost,
        },
    })
}
