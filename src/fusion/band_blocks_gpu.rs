//! The GPU twin of [`super::blocks_of_band_slices`]: `shaders/band_blocks.wgsl` lists a depth
//! frame's band blocks from its band slices where the slices were made, so that a frame read
//! back as its blocks (4 bytes each) instead of its slices (12 bytes each, and many more).
//!
//! The host's listing decides in f64 in world coordinates; the device's f64 may round, fuse
//! and divide otherwise. So the kernel decides a comparison only where its value clears zero
//! by more than [`certainty_margin_m`], far more than the two computations can differ, and
//! hands a slice with any block it cannot decide back whole, for the host to list exactly
//! ([`DeviceBand::blocks`]). Every block the device lists is one the host lists, and every
//! block the host lists comes from the device or from a deferred slice: the same set, whatever
//! the device's rounding. Needs `SHADER_F64` ([`GpuContext::has_f64`]).

use super::band_gpu::BandSliceOutputs;
use super::{blocks_of_band_slices, BandSlice, DepthFusionParams};
use crate::camera::PinholeIntrinsics;
use crate::gpu::kept::Kept;
use crate::gpu::{shaders, ErrorScopes, GpuContext};
use crate::grid::{floor_i64, BlockIndex, GridParams, TouchedBlocks};
use crate::{Error, Result};
use nalgebra::Isometry3;

/// Slots of the device's block set, log2: 65 536, four bytes each (a frame lists a few
/// thousand blocks; a slice whose block finds the set full is deferred).
const TABLE_SLOTS_LOG2: u32 = 16;
const TABLE_SLOTS: u64 = 1 << TABLE_SLOTS_LOG2;

/// Blocks a slice's box may hold for the device to test them; a larger one is deferred.
const MAX_BOX_BLOCKS: f64 = 4096.0;

/// Offsets from the camera's block the kernel packs (10 bits per axis).
const OFFSET_BIAS: i64 = 512;

/// How far the device's value of a compared quantity may be from the host's, metres, where
/// the camera is at `origin_m`: the host computes in world coordinates (rounding within
/// 2⁻⁵² of their magnitude per operation), the device relative to the camera's block (within
/// 2⁻⁵² of tens of metres, a few operations, maybe fused or divided within a few ULP). 10⁻⁸ m
/// and 10⁻¹³ of the distance from the world origin bound both by orders of magnitude, and
/// leave a comparison undecided about once in 10⁷ where its value falls evenly over a block.
pub fn certainty_margin_m(origin_m: &nalgebra::Vector3<f64>) -> f64 {
    1e-8 + 1e-13 * origin_m.amax()
}

/// The kernels' parameters for a frame of `grid` seen by `k` from `world_from_camera`, with
/// room for `slice_capacity` slices, and the camera's block (offsets are from it).
pub(crate) fn band_block_params(
    grid: &GridParams,
    k: &PinholeIntrinsics,
    world_from_camera: &Isometry3<f64>,
    slice_capacity: u64,
) -> (Vec<f64>, [i64; 3]) {
    let rot = world_from_camera.rotation.to_rotation_matrix().into_inner();
    let origin = world_from_camera.translation.vector;
    let block_m = grid.block_size_m();
    let base = [0, 1, 2].map(|a| floor_i64(origin[a] / block_m));
    let mut p = Vec::with_capacity(28);
    for c in 0..3 {
        p.extend(rot.column(c).iter().copied());
    }
    p.extend((0..3).map(|a| origin[a] - base[a] as f64 * block_m));
    p.extend([block_m, 1.0 / block_m, grid.truncation_m as f64]);
    p.extend([k.fx, k.fy, k.cx, k.cy, certainty_margin_m(&origin)]);
    p.extend([TABLE_SLOTS as f64, TABLE_SLOTS_LOG2 as f64]);
    p.extend([slice_capacity as f64, MAX_BOX_BLOCKS]);
    // μ and B as the host's f64 bits, for the exact piece count.
    for v in [grid.truncation_m as f64, block_m] {
        let bits = v.to_bits();
        p.extend([(bits & 0xffff_ffff) as f64, (bits >> 32) as f64]);
    }
    (p, base)
}

/// The outputs of recorded `band_blocks.wgsl` and `band_blocks_keys.wgsl` dispatches.
pub(crate) struct BandBlockOutputs {
    counts: wgpu::Buffer,
    keys: wgpu::Buffer,
    deferred: wgpu::Buffer,
    base: [i64; 3],
    slice_capacity: u64,
}

/// A frame's band as the device listed it: the blocks it decided, and the slices it left to
/// the host.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DeviceBand {
    /// Blocks the device listed, in no particular order.
    pub blocks: Vec<BlockIndex>,
    /// Slices with a block the device could not decide.
    pub deferred: Vec<BandSlice>,
    /// Usable depths in the frame.
    pub usable_pixels: usize,
}

impl DeviceBand {
    /// The frame's band blocks, sorted: the device's and those of the deferred slices (listed
    /// here, exactly), equal to [`super::depth_frame_blocks`] of the frame's depths.
    pub fn blocks(
        &self,
        grid: &GridParams,
        k: &PinholeIntrinsics,
        world_from_camera: &Isometry3<f64>,
        params: &DepthFusionParams,
    ) -> TouchedBlocks {
        let slices = super::BandSlices::new(self.deferred.clone(), 0);
        let host = blocks_of_band_slices(grid, k, world_from_camera, params, &slices);
        let keys = self.blocks.iter().chain(&host).map(BlockIndex::sort_key);
        super::band::sorted_blocks(keys.collect())
    }
}

/// Records the listing of the band blocks of the slices `slices` (recorded before, in the same
/// encoder) with the parameters `(params, base)` of [`band_block_params`], in buffers of `kept`.
pub(crate) fn record_band_blocks(
    (ctx, kept): (&GpuContext, &mut Kept),
    encoder: &mut wgpu::CommandEncoder,
    (params, base): (&[f64], [i64; 3]),
    slices: &BandSliceOutputs,
) -> Result<BandBlockOutputs> {
    if !ctx.has_f64() {
        return Err(Error::Gpu(format!(
            "{} has no f64 arithmetic: the band blocks are listed on the host",
            ctx.name()
        )));
    }
    let slice_capacity = slices.capacity();
    let block = ctx.kernel(&shaders::BAND_BLOCKS)?;
    let listing = ctx.kernel(&shaders::BAND_BLOCKS_KEYS)?;
    let scope = ErrorScopes::push(&ctx.device);
    let buf_params = kept.storage_with(ctx, "band_block_params", bytemuck::cast_slice(params));
    let table = kept.scratch(ctx, "band_block_table", TABLE_SLOTS * 4);
    let counts = kept.storage_with(ctx, "band_block_counts", &[0; 8]);
    let deferred = kept.scratch(ctx, "band_block_deferred", slice_capacity * 12);
    let keys = kept.scratch(ctx, "band_block_keys", TABLE_SLOTS * 4);
    let (slice_words, slice_counters) = slices.buffers();
    let buffers = [
        &buf_params,
        slice_words,
        slice_counters,
        &table,
        &counts,
        &deferred,
    ];
    let bind = kept.bind_group(ctx, "band_blocks", &block.layout, &buffers);
    ctx.record_dispatch(encoder, &block, &bind, slice_capacity)?;
    let buffers = [&buf_params, &table, &counts, &keys];
    let bind = kept.bind_group(ctx, "band_blocks_keys", &listing.layout, &buffers);
    ctx.record_dispatch(encoder, &listing, &bind, TABLE_SLOTS)?;
    scope.pop("recording the listing of a depth frame's band blocks on the GPU")?;
    Ok(BandBlockOutputs {
        counts,
        keys,
        deferred,
        base,
        slice_capacity,
    })
}

/// What a frame's band reads back: the slices' counters (`[0]` made, `[1]` usable pixels),
/// the blocks' counters (`[0]` listed, `[1]` slices deferred), and the first blocks and deferred
/// slices of the device's lists.
pub(crate) struct BandWords {
    slice_counters: [u32; 2],
    counts: [u32; 2],
    keys: Vec<u32>,
    deferred: Vec<[u32; 3]>,
}

impl BandWords {
    /// Room for the counters, `expected.0` blocks and `expected.1` deferred slices.
    pub(crate) fn new(expected: (usize, usize)) -> Self {
        BandWords {
            slice_counters: [0; 2],
            counts: [0; 2],
            keys: bytemuck::zeroed_vec(expected.0),
            deferred: bytemuck::zeroed_vec(expected.1),
        }
    }

    /// The four parts' bytes, in the order of [`BandBlockOutputs::sources`].
    pub(crate) fn targets(&mut self) -> [&mut [u8]; 4] {
        [
            bytemuck::cast_slice_mut(&mut self.slice_counters),
            bytemuck::cast_slice_mut(&mut self.counts),
            bytemuck::cast_slice_mut(&mut self.keys),
            bytemuck::cast_slice_mut(&mut self.deferred),
        ]
    }

    /// Blocks listed and slices deferred, as the device counted them.
    pub(crate) fn counts(&self) -> (usize, usize) {
        (self.counts[0] as usize, self.counts[1] as usize)
    }
}

/// What turns a frame's [`BandWords`] into its band: the camera's block and the room for
/// slices it was listed with.
#[derive(Clone, Copy, Debug)]
pub(crate) struct BandDecoder {
    base: [i64; 3],
    slice_capacity: u64,
}

impl BandDecoder {
    /// The band `words` hold, or `None` where the device listed more blocks or deferred more
    /// slices than they hold (read them again with room for [`BandWords::counts`]).
    pub(crate) fn band(&self, words: &BandWords) -> Result<Option<DeviceBand>> {
        let slices = words.slice_counters[0] as u64;
        if slices > self.slice_capacity {
            return Err(Error::Gpu(format!(
                "the band kernel made {slices} slices, more than the {} a frame can have",
                self.slice_capacity
            )));
        }
        let (n_keys, n_deferred) = words.counts();
        if n_keys > TABLE_SLOTS as usize || n_deferred as u64 > self.slice_capacity {
            return Err(Error::Gpu(format!(
                "the band block kernel listed {n_keys} blocks and deferred {n_deferred} slices, \
                 more than it holds"
            )));
        }
        if n_keys > words.keys.len() || n_deferred > words.deferred.len() {
            return Ok(None);
        }
        let [bx, by, bz] = self.base;
        let field = |key: u32, shift: u32| ((key >> shift) & 1023) as i64 - OFFSET_BIAS;
        let blocks = words.keys[..n_keys]
            .iter()
            .map(|&k| {
                let o = [bx + field(k, 0), by + field(k, 10), bz + field(k, 20)];
                BlockIndex(o.map(|c| c as i32))
            })
            .collect();
        let deferred = &words.deferred[..n_deferred];
        Ok(Some(DeviceBand {
            blocks,
            deferred: deferred.iter().copied().map(BandSlice::unpack).collect(),
            usable_pixels: words.slice_counters[1] as usize,
        }))
    }
}

impl BandBlockOutputs {
    /// The decoder of these outputs' words.
    pub(crate) fn decoder(&self) -> BandDecoder {
        BandDecoder {
            base: self.base,
            slice_capacity: self.slice_capacity,
        }
    }

    /// Where the parts of `words` are on the device (the slices' counters in `slices`), with
    /// their lengths, bytes: a readback's sources.
    pub(crate) fn sources<'a>(
        &'a self,
        slices: &'a BandSliceOutputs,
        words: &BandWords,
    ) -> [(&'a wgpu::Buffer, usize); 4] {
        let (_, slice_counters) = slices.buffers();
        [
            (slice_counters, 8),
            (&self.counts, 8),
            (&self.keys, 4 * words.keys.len()),
            (&self.deferred, 12 * words.deferred.len()),
        ]
    }

    /// `expected` clamped to what the outputs hold.
    pub(crate) fn clamp(&self, expected: (usize, usize)) -> (usize, usize) {
        let keys = expected.0.min(TABLE_SLOTS as usize);
        (keys, expected.1.min(self.slice_capacity as usize))
    }

    /// Submits `encoder` (holding the dispatches) and reads back the band: the counters, the
    /// first `expected.0` blocks and the first `expected.1` deferred slices in one wait, then,
    /// where there were more, all of them in a second.
    pub(crate) fn submit_and_read_back(
        &self,
        (ctx, kept): (&GpuContext, &mut Kept),
        encoder: wgpu::CommandEncoder,
        slices: &BandSliceOutputs,
        expected: (usize, usize),
    ) -> Result<DeviceBand> {
        let mut words = BandWords::new(self.clamp(expected));
        let sources = self.sources(slices, &words).map(|(buffer, _)| buffer);
        let mut parts: Vec<_> = sources.into_iter().zip(words.targets()).collect();
        ctx.submit_and_read_back(encoder, kept, &mut parts)?;
        if let Some(band) = self.decoder().band(&words)? {
            return Ok(band);
        }
        let (n_keys, n_deferred) = words.counts();
        if n_keys > words.keys.len() {
            words.keys = ctx.read_back_as(&self.keys, n_keys)?;
        }
        if n_deferred > words.deferred.len() {
            words.deferred = ctx.read_back_as(&self.deferred, n_deferred)?;
        }
        Ok(self.decoder().band(&words)?.expect("read whole"))
    }
}

/// The band of the depth frame `frame` of `grid` fused with `params`, its slices made and its
/// blocks listed on the GPU (the depths uploaded): for comparing with the host's listing.
/// `Ok(None)` where the device has no f64.
pub fn band_blocks_on_gpu(
    ctx: &GpuContext,
    grid: &GridParams,
    frame: &crate::frame::DepthFrame,
    params: &DepthFusionParams,
) -> Result<Option<DeviceBand>> {
    if !ctx.has_f64() {
        return Ok(None);
    }
    let depth = &frame.depth_m;
    let uniforms = super::band_slice_uniforms(grid, params, depth.width, depth.height)?;
    ctx.check_binding("the depth image", depth.data.len() as u64 * 4)?;
    let buf_depth = ctx.storage("band_depth", bytemuck::cast_slice(&depth.data));
    let mut encoder = ctx.encoder("band_blocks");
    let kept = &mut Kept::default();
    let slices =
        super::band_gpu::record_band_slices((ctx, kept), &mut encoder, &uniforms, &buf_depth)?;
    let (k, pose) = (&frame.intrinsics, &frame.world_from_camera);
    let (p, base) = band_block_params(grid, k, pose, uniforms.capacity as u64);
    let out = record_band_blocks((ctx, kept), &mut encoder, (&p, base), &slices)?;
    out.submit_and_read_back((ctx, kept), encoder, &slices, (0, 0))
        .map(Some)
}
