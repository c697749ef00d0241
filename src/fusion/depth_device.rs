//! A depth frame whose depths stay on the GPU: made there from a matcher's disparities
//! (`shaders/disparity_depth.wgsl`, the CPU's f64 quotient in integers), summarised there as
//! its band slices (`shaders/band_slices.wgsl`) and, where the device has f64, its band blocks
//! listed there from the slices (`shaders/band_blocks.wgsl`, [`super::DeviceBand`]), so that
//! the host plans its fusion from 4 bytes per block ([`super::DepthPlan::from_device_band`]),
//! or else 12 bytes per slice ([`super::DepthPlan::from_slices`]), instead of 4 bytes per
//! pixel, and the resident fusion reads the depths where they are
//! ([`super::integrate_device_depth_resident`]). The kernels make the CPU's decisions exactly
//! (the block listing by deciding only what it is certain of and leaving the rest to the
//! host), so the fused map is the one the host's depths give.

use super::band_blocks_gpu::{band_block_params, record_band_blocks};
use super::band_gpu::{band_slice_uniforms, record_band_slices};
use super::{BandSlices, DepthFusionParams, DepthPlan, DeviceBand};
use crate::camera::{PinholeIntrinsics, WorldFromCamera};
use crate::depth::{
    disparity_depth_uniforms, record_disparity_depth, DisparityMap, OnDeviceDisparity,
};
use crate::frame::{DepthFrame, Image, RgbImage};
use crate::gpu::kept::{BufferPool, Kept, Pooled};
use crate::gpu::GpuContext;
use crate::grid::GridParams;
use crate::Result;
use std::sync::Arc;

/// A depth frame whose depths are on the device (see the module documentation).
pub struct DeviceDepthFrame {
    /// The camera, pose and colour; `depth_m` has the image's size and no data.
    header: DepthFrame,
    /// The depths (f32, metres, NaN where invalid), row-major, in a buffer handed back to the
    /// pool of its [`DeviceDepthKept`] when the frame is dropped.
    depth: Pooled,
    /// The device they are on.
    ctx: Arc<GpuContext>,
    band: FrameBand,
    /// The voxel size, truncation and usable depths (bits) the band was listed for.
    made_for: [u32; 4],
}

/// What came back of a frame's band.
enum FrameBand {
    /// Its slices (a device without f64): the host lists the blocks from them.
    Slices(BandSlices),
    /// Its blocks, listed on the device, and the slices the device left to the host.
    Listed(DeviceBand),
}

/// What making depth frames on a device keeps between frames, so that a frame creates no
/// buffer or bind group once the first have sized them and is read back in one wait: the
/// kernels' buffers and bind groups, the depth buffers of frames dropped already (the reader
/// runs ahead of the fusion, so as many are lent as frames are alive at once), and how many
/// slices the last frame made, which sizes the next frame's readback
/// ([`super::band_gpu::BandSliceOutputs::submit_and_read_back`]).
#[derive(Debug, Default)]
pub struct DeviceDepthKept {
    kept: Kept,
    depths: BufferPool,
    /// What the last frame read back: slices, or blocks and deferred slices.
    last: [usize; 2],
}

impl DeviceDepthKept {
    /// What the next frame's one wait reads of each of the two kinds `last` counts: the last
    /// frame's and an eighth more, plus `spare`, as neighbouring frames of a drive make about
    /// as many. Fewer cost a second wait; the first frame, with none to go by, takes it.
    fn expected(&self, spare: [usize; 2]) -> (usize, usize) {
        if self.last[0] == 0 {
            return (0, 0);
        }
        let [a, b] = self.last;
        (a + a / 8 + spare[0], b + b / 8 + spare[1])
    }
}

/// A camera of the frame's size, its pose and its colour.
pub type CameraView = (PinholeIntrinsics, WorldFromCamera, Option<RgbImage>);

/// What a band depends on besides the depths and the camera: the voxel size, μ and the usable
/// depths, as bits.
fn made_for(grid: &GridParams, params: &DepthFusionParams) -> [u32; 4] {
    let values = [grid.voxel_size_m, grid.truncation_m];
    [values[0], values[1], params.min_depth_m, params.max_depth_m].map(f32::to_bits)
}

impl DeviceDepthFrame {
    /// The frame of the disparities `d` (on the device, as a matcher left them) of a stereo
    /// pair `baseline_m` apart, seen as `view` (camera of `d`'s size, pose, colour), for
    /// fusion into `grid` with `params`: depths, band slices and (with f64) band blocks
    /// recorded after the matcher's work, in buffers of `kept`, and submitted with it; the
    /// blocks (or slices) come back in the same wait (a second where the frame makes more than
    /// [`DeviceDepthKept`] expects).
    pub fn from_on_device(
        d: OnDeviceDisparity,
        (grid, params): (&GridParams, &DepthFusionParams),
        (intrinsics, world_from_camera, color): CameraView,
        baseline_m: f64,
        kept: &mut DeviceDepthKept,
    ) -> Result<Self> {
        let OnDeviceDisparity {
            ctx,
            mut encoder,
            disparity,
            width: w,
            height: h,
        } = d;
        if (intrinsics.width, intrinsics.height) != (w, h) {
            return Err(crate::Error::InvalidArgument(format!(
                "disparities of {w}×{h} for a camera of {}×{}",
                intrinsics.width, intrinsics.height
            )));
        }
        let pixels = w as usize * h as usize;
        let to_depth = disparity_depth_uniforms(pixels, intrinsics.fx, baseline_m)?;
        let band = band_slice_uniforms(grid, params, w, h)?;
        // Slices (12 bytes), or blocks (4) and deferred slices (12).
        let expected = kept.expected(if ctx.has_f64() { [256, 64] } else { [1024, 0] });
        let DeviceDepthKept {
            kept: buffers,
            depths,
            last,
        } = kept;
        let made = record_disparity_depth((ctx, buffers), &mut encoder, &to_depth, disparity)?;
        let out = record_band_slices((ctx, buffers), &mut encoder, &band, &made)?;
        // The frame's own copy of its depths: the kernels' buffers serve the next frame.
        let depth = depths.copy_of(ctx, &mut encoder, "depth", (&made, pixels as u64 * 4));
        let band = if ctx.has_f64() {
            // The blocks listed where the slices are: a few KiB come back.
            let p = band_block_params(grid, &intrinsics, &world_from_camera, out.capacity());
            let listed = record_band_blocks((ctx, buffers), &mut encoder, (&p.0, p.1), &out)?;
            let band = listed.submit_and_read_back((ctx, buffers), encoder, &out, expected)?;
            *last = [band.blocks.len(), band.deferred.len()];
            FrameBand::Listed(band)
        } else {
            let slices = out.submit_and_read_back((ctx, buffers), encoder, expected.0)?;
            *last = [slices.slices.len(), 0];
            FrameBand::Slices(slices)
        };
        let header = DepthFrame {
            intrinsics,
            world_from_camera,
            depth_m: Image {
                width: w,
                height: h,
                data: Vec::new(),
            },
            color,
        };
        Ok(DeviceDepthFrame {
            header,
            depth,
            ctx: ctx.clone(),
            band,
            made_for: made_for(grid, params),
        })
    }

    /// [`Self::from_on_device`] for disparities on the host, uploaded first (nothing kept).
    pub fn from_disparity(
        ctx: &Arc<GpuContext>,
        fusion: (&GridParams, &DepthFusionParams),
        view: CameraView,
        disparity: &DisparityMap,
        baseline_m: f64,
    ) -> Result<Self> {
        let img = &disparity.disparity_px;
        ctx.check_binding("the disparity map", img.data.len() as u64 * 4)?;
        let buf = ctx.storage("disparity", bytemuck::cast_slice(&img.data));
        let d = OnDeviceDisparity {
            ctx,
            encoder: ctx.encoder("device_depth_frame"),
            disparity: &buf,
            width: img.width,
            height: img.height,
        };
        let kept = &mut DeviceDepthKept::default();
        Self::from_on_device(d, fusion, view, baseline_m, kept)
    }

    /// The camera, pose, colour and size (its `depth_m` holds no data).
    pub fn header(&self) -> &DepthFrame {
        &self.header
    }

    /// The context of the device the depths are on.
    pub fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }

    /// The band slices of the depths, where they came back (a device without f64).
    pub fn slices(&self) -> Option<&BandSlices> {
        match &self.band {
            FrameBand::Slices(s) => Some(s),
            FrameBand::Listed(_) => None,
        }
    }

    /// The band as the device listed it, where it did (a device with f64).
    pub fn device_band(&self) -> Option<&DeviceBand> {
        match &self.band {
            FrameBand::Listed(b) => Some(b),
            FrameBand::Slices(_) => None,
        }
    }

    /// The depths' buffer on the device.
    pub(crate) fn depth_buffer(&self) -> &wgpu::Buffer {
        self.depth.buffer()
    }

    /// The fusion plan of this frame ([`DepthPlan::from_slices`]) into `grid` with `params`,
    /// which must be those its slices were made for.
    pub fn plan(&self, grid: &GridParams, params: &DepthFusionParams) -> Result<DepthPlan> {
        if made_for(grid, params) != self.made_for {
            return Err(crate::Error::InvalidArgument(
                "a depth frame on the device planned with other fusion parameters than its band \
                 slices were made for"
                    .into(),
            ));
        }
        Ok(match &self.band {
            FrameBand::Slices(s) => DepthPlan::from_slices(grid, &self.header, params, s),
            FrameBand::Listed(b) => DepthPlan::from_device_band(grid, &self.header, params, b),
        })
    }

    /// The frame with its depths read back (counted): what the host would have fused.
    pub fn read_back(&self, ctx: &GpuContext) -> Result<DepthFrame> {
        Self::read_back_from(ctx, &self.header, self.depth.buffer())
    }

    /// `header` with the depths of `depth` read back.
    pub(crate) fn read_back_from(
        ctx: &GpuContext,
        header: &DepthFrame,
        depth: &wgpu::Buffer,
    ) -> Result<DepthFrame> {
        let (w, h) = (header.depth_m.width, header.depth_m.height);
        Ok(DepthFrame {
            depth_m: Image {
                width: w,
                height: h,
                data: ctx.read_back_as(depth, w as usize * h as usize)?,
            },
            ..header.clone()
        })
    }
}
