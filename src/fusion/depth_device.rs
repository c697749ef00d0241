//! A depth frame whose depths stay on the GPU: made there from a matcher's disparities
//! (`shaders/disparity_depth.wgsl`, the CPU's f64 quotient in integers) and summarised there as
//! its band slices (`shaders/band_slices.wgsl`), so that the host plans its fusion from 12
//! bytes per slice ([`super::DepthPlan::from_slices`]) instead of 4 bytes per pixel, and the
//! resident fusion reads the depths where they are
//! ([`super::integrate_device_depth_resident`]). Both kernels are exact twins of the CPU, so
//! the fused map is the one the host's depths give.

use super::band_gpu::{band_slice_uniforms, record_band_slices};
use super::{BandSlices, DepthFusionParams, DepthPlan};
use crate::camera::{PinholeIntrinsics, WorldFromCamera};
use crate::depth::{disparity_depth_uniforms, record_disparity_depth, DisparityMap};
use crate::frame::{DepthFrame, Image, RgbImage};
use crate::gpu::GpuContext;
use crate::grid::GridParams;
use crate::Result;

/// A depth frame whose depths are on the device (see the module documentation).
pub struct DeviceDepthFrame {
    /// The camera, pose and colour; `depth_m` has the image's size and no data.
    header: DepthFrame,
    /// The depths (f32, metres, NaN where invalid), row-major.
    depth: wgpu::Buffer,
    slices: BandSlices,
}

impl DeviceDepthFrame {
    /// The frame of the disparities `buf_disparity` (f32 pixels, on the device, as
    /// `intrinsics` sizes them) of a stereo pair `baseline_m` apart, seen from
    /// `world_from_camera`, for fusion into `grid` with `params`: depths and band slices made
    /// in one submit; the slices come back (two waits).
    pub(crate) fn from_disparity_buffer(
        ctx: &GpuContext,
        (grid, params): (&GridParams, &DepthFusionParams),
        (intrinsics, world_from_camera, color): (
            PinholeIntrinsics,
            WorldFromCamera,
            Option<RgbImage>,
        ),
        buf_disparity: &wgpu::Buffer,
        baseline_m: f64,
    ) -> Result<Self> {
        let (w, h) = (intrinsics.width, intrinsics.height);
        let pixels = w as usize * h as usize;
        let to_depth = disparity_depth_uniforms(pixels, intrinsics.fx, baseline_m)?;
        let band = band_slice_uniforms(grid, params, w, h)?;
        let mut encoder = ctx.encoder("device_depth_frame");
        let depth = record_disparity_depth(ctx, &mut encoder, &to_depth, buf_disparity)?;
        let out = record_band_slices(ctx, &mut encoder, &band, &depth)?;
        ctx.submit(encoder);
        let slices = out.read_back(ctx)?;
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
            slices,
        })
    }

    /// [`Self::from_disparity_buffer`] for disparities on the host, uploaded first (the
    /// disparities of `disparity` must be `intrinsics`' size).
    pub fn from_disparity(
        ctx: &GpuContext,
        (grid, params): (&GridParams, &DepthFusionParams),
        view: (PinholeIntrinsics, WorldFromCamera, Option<RgbImage>),
        disparity: &DisparityMap,
        baseline_m: f64,
    ) -> Result<Self> {
        let img = &disparity.disparity_px;
        let (w, h) = (view.0.width, view.0.height);
        if (img.width, img.height) != (w, h) {
            return Err(crate::Error::InvalidArgument(format!(
                "disparities of {}×{} for a camera of {w}×{h}",
                img.width, img.height
            )));
        }
        ctx.check_binding("the disparity map", img.data.len() as u64 * 4)?;
        let buf = ctx.storage("disparity", bytemuck::cast_slice(&img.data));
        Self::from_disparity_buffer(ctx, (grid, params), view, &buf, baseline_m)
    }

    /// The camera, pose, colour and size (its `depth_m` holds no data).
    pub fn header(&self) -> &DepthFrame {
        &self.header
    }

    /// The band slices of the depths.
    pub fn slices(&self) -> &BandSlices {
        &self.slices
    }

    /// The depths' buffer on the device.
    pub(crate) fn depth_buffer(&self) -> &wgpu::Buffer {
        &self.depth
    }

    /// The fusion plan of this frame ([`DepthPlan::from_slices`]).
    pub fn plan(&self, grid: &GridParams, params: &DepthFusionParams) -> DepthPlan {
        DepthPlan::from_slices(grid, &self.header, params, &self.slices)
    }

    /// The frame with its depths read back (counted): what the host would have fused.
    pub fn read_back(&self, ctx: &GpuContext) -> Result<DepthFrame> {
        Self::read_back_from(ctx, &self.header, &self.depth)
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
