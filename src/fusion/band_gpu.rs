//! The GPU twin of [`super::band_slices`]: `shaders/band_slices.wgsl` summarises a depth image
//! on the device as its band slices ([`BandSlices`]), 12 bytes each, from which the host lists
//! the frame's blocks ([`super::blocks_of_band_slices`]) without the image. The kernel makes the
//! CPU's decisions exactly: it compares depths by their bits and their differences in 64-bit
//! fixed point against thresholds derived here ([`band_slice_uniforms`]).

use super::{BandSlice, BandSlices, DepthFusionParams, BAND_SLICE_MAX_SIDE_PX, BAND_TILE_PX};
use crate::frame::Image;
use crate::gpu::kept::Kept;
use crate::gpu::layout::BandSliceUniforms;
use crate::gpu::{shaders, ErrorScopes, GpuContext};
use crate::grid::GridParams;
use crate::{Error, Result};

/// Units of the kernel's fixed point: 2⁻⁴⁰ m.
const FIXED_PER_M: f64 = (1u64 << 40) as f64;

/// Slices one tile can make at most (one per pixel).
const SLICES_PER_TILE: u64 = (BAND_TILE_PX * BAND_TILE_PX) as u64;

/// `x` (≥ 0, an integer below 2⁶⁴) as the kernel's (low, high) words.
fn words(x: f64) -> [u32; 2] {
    let n = x as u64;
    [n as u32, (n >> 32) as u32]
}

/// The uniforms of `band_slices.wgsl` for an image of `width` × `height` of `grid` fused with
/// `params`, or why the kernel cannot make the CPU's decisions for them.
pub fn band_slice_uniforms(
    grid: &GridParams,
    params: &DepthFusionParams,
    width: u32,
    height: u32,
) -> Result<BandSliceUniforms> {
    if width == 0
        || height == 0
        || width > BAND_SLICE_MAX_SIDE_PX
        || height > BAND_SLICE_MAX_SIDE_PX
    {
        return Err(Error::InvalidArgument(format!(
            "band slices on the GPU take images of 1 to {BAND_SLICE_MAX_SIDE_PX} pixels a side, \
             not {width}×{height}"
        )));
    }
    // Usable depths within the fixed point's exact range, [2⁻¹⁷, 2²⁴) m.
    let (lo_m, hi_m) = (params.min_depth_m, params.max_depth_m);
    if !(lo_m >= (-17f32).exp2() && hi_m < 24f32.exp2()) {
        return Err(Error::InvalidArgument(format!(
            "band slices on the GPU need usable depths within [2⁻¹⁷, 2²⁴) m, not [{lo_m}, {hi_m}]"
        )));
    }
    // `(hi - lo) as f64 > 2μ` for an f32 difference: the difference rounds above the largest
    // f32 `t` ≤ 2μ exactly when it is past the midpoint between `t` and the next f32 (or at
    // it, where that next f32 is the even one).
    let two_mu = 2.0 * grid.truncation_m as f64;
    let mut t = two_mu as f32;
    if t as f64 > two_mu {
        t = f32::from_bits(t.to_bits() - 1);
    }
    let next = f32::from_bits(t.to_bits() + 1);
    let mid = 0.5 * (t as f64 + next as f64) * FIXED_PER_M;
    let spread = 0.5 * grid.truncation_m as f64 * FIXED_PER_M;
    if !(t > 0.0 && mid.fract() == 0.0 && mid < 2f64.powi(64)) {
        return Err(Error::InvalidArgument(format!(
            "band slices on the GPU need 2μ within [2⁻¹⁶, 2²⁴) m, not {two_mu} m"
        )));
    }
    let tiles_x = width.div_ceil(BAND_TILE_PX as u32);
    let tiles = tiles_x * height.div_ceil(BAND_TILE_PX as u32);
    Ok(BandSliceUniforms {
        size: [width, height, tiles_x, tiles],
        usable_bits: [lo_m.to_bits(), hi_m.to_bits()],
        capacity: (tiles as u64 * SLICES_PER_TILE) as u32,
        gap_tie_up: (next.to_bits() & 1 == 0) as u32,
        gap_mid: words(mid),
        spread: words(spread.floor()),
    })
}

/// The band slices of the depth image `depth_m` of a frame of `grid` fused with `params`, made
/// on the GPU: equal to [`super::band_slices`]'s (`tests/gpu/band_slices.rs`). Uploads the
/// image and reads back the counters, then the slices.
pub fn band_slices_on_gpu(
    ctx: &GpuContext,
    grid: &GridParams,
    depth_m: &Image<f32>,
    params: &DepthFusionParams,
) -> Result<BandSlices> {
    let uniforms = band_slice_uniforms(grid, params, depth_m.width, depth_m.height)?;
    ctx.check_binding("the depth image", depth_m.data.len() as u64 * 4)?;
    let buf_depth = ctx.storage("band_depth", bytemuck::cast_slice(&depth_m.data));
    let mut encoder = ctx.encoder("band_slices");
    let kept = &mut Kept::default();
    let out = record_band_slices((ctx, kept), &mut encoder, &uniforms, &buf_depth)?;
    out.submit_and_read_back((ctx, kept), encoder, 0)
}

/// The outputs of a recorded `band_slices.wgsl` dispatch, on the device.
pub(crate) struct BandSliceOutputs {
    counters: wgpu::Buffer,
    slices: wgpu::Buffer,
    capacity: u64,
}

/// Records `band_slices.wgsl` over the depths `buf_depth` (f32, as `uniforms` describes the
/// image) into `encoder`, with its buffers and bind group kept in `kept` (the counters cleared
/// through the queue: 8 bytes up).
pub(crate) fn record_band_slices(
    (ctx, kept): (&GpuContext, &mut Kept),
    encoder: &mut wgpu::CommandEncoder,
    uniforms: &BandSliceUniforms,
    buf_depth: &wgpu::Buffer,
) -> Result<BandSliceOutputs> {
    let tiles = uniforms.size[3] as u64;
    let capacity = uniforms.capacity as u64;
    ctx.check_binding("band slices (768 bytes per 8×8 tile)", capacity * 12)?;
    let kernel = ctx.kernel(&shaders::BAND_SLICES)?;
    let scope = ErrorScopes::push(&ctx.device);
    let uniform_bytes = bytemuck::bytes_of(uniforms);
    let buf_uniforms = kept.uniform_with(ctx, "band_slice_uniforms", uniform_bytes);
    let buf_scratch = kept.scratch(ctx, "band_scratch", tiles * SLICES_PER_TILE * 4);
    let counters = kept.storage_with(ctx, "band_counters", &[0; 8]);
    let slices = kept.scratch(ctx, "band_slices", capacity * 12);
    let buffers = [&buf_uniforms, buf_depth, &buf_scratch, &counters, &slices];
    let bind = kept.bind_group(ctx, "band_slices", &kernel.layout, &buffers);
    ctx.record_dispatch(encoder, &kernel, &bind, tiles)?;
    scope.pop("recording a depth frame's band slices on the GPU")?;
    Ok(BandSliceOutputs {
        counters,
        slices,
        capacity,
    })
}

impl BandSliceOutputs {
    /// Slices the output holds.
    pub(crate) fn capacity(&self) -> u64 {
        self.capacity
    }

    /// The slices' words and the counters (`[0]` slices made, `[1]` usable pixels).
    pub(crate) fn buffers(&self) -> (&wgpu::Buffer, &wgpu::Buffer) {
        (&self.slices, &self.counters)
    }

    /// Where the parts of `words` are on the device, with their lengths, bytes: a readback's
    /// sources.
    pub(crate) fn sources(&self, words: &SliceWords) -> [(&wgpu::Buffer, usize); 2] {
        [(&self.counters, 8), (&self.slices, 12 * words.slices.len())]
    }

    /// Submits `encoder` (holding the dispatch) and reads back the slices: the counters and
    /// the first `expected` slices in one wait, then, where the kernel made more, all of them
    /// in a second. A caller that expects about as many as the last frame made reads a frame
    /// in one wait for a few more bytes than its slices.
    pub(crate) fn submit_and_read_back(
        &self,
        (ctx, kept): (&GpuContext, &mut Kept),
        encoder: wgpu::CommandEncoder,
        expected: usize,
    ) -> Result<BandSlices> {
        let mut words = SliceWords::new(expected.min(self.capacity as usize));
        let sources = self.sources(&words).map(|(buffer, _)| buffer);
        let mut parts: Vec<_> = sources.into_iter().zip(words.targets()).collect();
        ctx.submit_and_read_back(encoder, kept, &mut parts)?;
        if let Some(slices) = words.slices(self.capacity)? {
            return Ok(slices);
        }
        words.slices = ctx.read_back_as(&self.slices, words.count())?;
        Ok(words.slices(self.capacity)?.expect("read whole"))
    }
}

/// What a frame's slices read back: the counters (`[0]` slices made, `[1]` usable pixels) and
/// the first slices.
pub(crate) struct SliceWords {
    counters: [u32; 2],
    slices: Vec<[u32; 3]>,
}

impl SliceWords {
    /// Room for the counters and `expected` slices.
    pub(crate) fn new(expected: usize) -> Self {
        SliceWords {
            counters: [0; 2],
            slices: bytemuck::zeroed_vec(expected),
        }
    }

    /// The two parts' bytes, in the order of [`BandSliceOutputs::sources`].
    pub(crate) fn targets(&mut self) -> [&mut [u8]; 2] {
        [
            bytemuck::cast_slice_mut(&mut self.counters),
            bytemuck::cast_slice_mut(&mut self.slices),
        ]
    }

    /// Slices made, as the device counted them.
    pub(crate) fn count(&self) -> usize {
        self.counters[0] as usize
    }

    /// The slices these words hold of an output of `capacity` slices, or `None` where the
    /// kernel made more than they hold (read them again with room for [`SliceWords::count`]).
    pub(crate) fn slices(&self, capacity: u64) -> Result<Option<BandSlices>> {
        let count = self.count();
        if count as u64 > capacity {
            return Err(Error::Gpu(format!(
                "the band kernel made {count} slices, more than the {capacity} a frame can have"
            )));
        }
        if count > self.slices.len() {
            return Ok(None);
        }
        let slices = self.slices[..count].iter().copied().map(BandSlice::unpack);
        Ok(Some(BandSlices::new(
            slices.collect(),
            self.counters[1] as usize,
        )))
    }
}
