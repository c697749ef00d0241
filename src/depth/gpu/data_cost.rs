//! The data term on the GPU: the census costs where the cost volume was made, summed over the
//! window there (`shaders/cost_window.wgsl`), and the point-wise search over them.

use crate::depth::sgm::{CostVolume, VolumeShape};
use crate::gpu::kept::{Kept, UniformTable};
use crate::gpu::layout::{PointwiseUniforms, WindowUniforms};
use crate::gpu::shaders;
use crate::gpu::{ErrorScopes, GpuContext};
use crate::{Error, Result};

/// The kept uniform buffer of the point-wise search.
pub(super) const SEARCH_UNIFORMS: &str = "pointwise_uniforms";

/// The data term on the GPU: packed costs (raw `u8` or window sums `u16`) and per-pixel divisors.
pub(super) struct DataCostGpu {
    costs: wgpu::Buffer,
    counts: wgpu::Buffer,
    cost_bytes: u32,
    width: u32,
    height: u32,
    num_disparities: u32,
    min_disparity_px: f32,
    max_cost: u8,
}

impl DataCostGpu {
    /// The data term of `volume` averaged over `window` × `window` (raw when 1), its costs
    /// uploaded once ([`DataCostGpu::on_device`]).
    pub(super) fn new(ctx: &GpuContext, volume: &CostVolume, window: u32) -> Result<Self> {
        let raw = upload_costs(ctx, volume, window)?;
        let mut encoder = ctx.encoder("cost_window");
        let kept = &mut Kept::default();
        let data = Self::on_device(ctx, kept, &mut encoder, volume.shape(), &raw, window)?;
        ctx.submit(encoder);
        Ok(data)
    }

    /// Fails with [`Error::GpuCapacity`] when the costs of `volume` over `window` do not fit
    /// one binding or u32 indices.
    fn check(ctx: &GpuContext, volume: VolumeShape, window: u32) -> Result<()> {
        let n = volume.width as u64 * volume.height as u64;
        let entries = n * volume.num_disparities as u64;
        if entries > u32::MAX as u64 || volume.num_disparities > u32::MAX as usize {
            return Err(Error::GpuCapacity {
                what: "cost volume entries (u32 indices)".into(),
                needed_bytes: entries,
                limit_bytes: u32::MAX as u64,
            });
        }
        let cost_bytes = if window > 1 { 2 } else { 1 };
        ctx.check_binding("census costs (1 byte per pixel and disparity)", entries)?;
        ctx.check_binding(
            &format!("census costs ({cost_bytes} bytes per pixel and disparity)"),
            entries * cost_bytes,
        )
    }

    /// The data term of the cost volume of shape `volume` on the device (`raw`:
    /// [`super::record_cost_volume`]'s buffer, u8 costs 4 per word) averaged over `window` ×
    /// `window` (raw when 1). The window sums are taken on the device
    /// (`shaders/cost_window.wgsl`, equal to the CPU's `box_filter_into`, recorded into
    /// `encoder`), so no cost goes up.
    pub(super) fn on_device(
        ctx: &GpuContext,
        kept: &mut Kept,
        encoder: &mut wgpu::CommandEncoder,
        volume: VolumeShape,
        raw: &wgpu::Buffer,
        window: u32,
    ) -> Result<Self> {
        Self::check(ctx, volume, window)?;
        let n = volume.width as u64 * volume.height as u64;
        let entries = n * volume.num_disparities as u64;
        let cost_bytes = if window > 1 { 2 } else { 1 };
        let scope = ErrorScopes::push(&ctx.device);
        let (costs, counts) = if window > 1 {
            let kernel = ctx.kernel(&shaders::COST_WINDOW)?;
            let uniforms = WindowUniforms {
                width: volume.width,
                height: volume.height,
                num_disparities: volume.num_disparities as u32,
                radius: window / 2,
                entries: entries as u32,
                pad: [0; 3],
            };
            let bytes = bytemuck::bytes_of(&uniforms);
            let buf_uniforms = kept.uniform_with(ctx, "window_uniforms", bytes);
            let words = entries.div_ceil(2);
            // The kernel writes every word of both.
            let sums = kept.scratch(ctx, "tgv_costs", words * 4);
            let counts = kept.scratch(ctx, "tgv_counts", n * 4);
            let bind = kept.bind_group(
                ctx,
                "cost_window",
                &kernel.layout,
                &[&buf_uniforms, raw, &sums, &counts],
            );
            ctx.record_dispatch(encoder, &kernel, &bind, words)?;
            (sums, counts)
        } else {
            let ones = vec![1u32; n as usize];
            let counts = kept.storage_with(ctx, "tgv_counts", bytemuck::cast_slice(&ones));
            (raw.clone(), counts)
        };
        scope.pop("summing the census costs over their window")?;
        Ok(DataCostGpu {
            costs,
            counts,
            cost_bytes: cost_bytes as u32,
            width: volume.width,
            height: volume.height,
            num_disparities: volume.num_disparities as u32,
            min_disparity_px: volume.min_disparity_px as f32,
            max_cost: volume.max_cost,
        })
    }

    /// The window sums and per-pixel counts, read back (for tests against the CPU).
    pub(super) fn read_back(&self, ctx: &GpuContext) -> Result<(Vec<u16>, Vec<u16>)> {
        let n = (self.width * self.height) as usize;
        let entries = n * self.num_disparities as usize;
        let mut sums: Vec<u16> = ctx.read_back_as(&self.costs, entries.div_ceil(2) * 2)?;
        sums.truncate(entries);
        let counts: Vec<u32> = ctx.read_back_as(&self.counts, n)?;
        Ok((sums, counts.iter().map(|&c| c as u16).collect()))
    }

    /// The point-wise search's uniforms for `u` of stride `u_stride` floats, λ and θ.
    pub(super) fn search_uniforms(
        &self,
        u_stride: u32,
        lambda: f32,
        theta: f32,
    ) -> PointwiseUniforms {
        PointwiseUniforms {
            width: self.width,
            height: self.height,
            num_disparities: self.num_disparities,
            cost_bytes: self.cost_bytes,
            u_stride,
            lambda,
            theta,
            // The CPU's `reach`, in f32.
            reach: (2.0 * theta * lambda * self.max_cost as f32).sqrt(),
            min_disparity_px: self.min_disparity_px,
            pad: [0; 3],
        }
    }

    /// Records one point-wise search reading `u` (stride `u_stride` floats) and writing `a`,
    /// with uniforms and a bind group kept in `kept`. The uniforms are written through the
    /// queue (one search per submit), or, with `table` (a table of
    /// [`DataCostGpu::search_uniforms`] made in `kept` with the uniform buffer
    /// `"pointwise_uniforms"`, and the variant to use), copied from it on the device before the
    /// dispatch, so that searches with different θ share a submit.
    pub(super) fn record_search(
        &self,
        (ctx, kept): (&GpuContext, &mut Kept),
        encoder: &mut wgpu::CommandEncoder,
        (u, u_stride): (&wgpu::Buffer, u32),
        a: &wgpu::Buffer,
        (lambda, theta): (f32, f32),
        table: Option<(&UniformTable, usize)>,
    ) -> Result<()> {
        let kernel = ctx.kernel(&shaders::TGV_POINTWISE)?;
        let buf_uniforms = match table {
            Some((table, k)) => {
                table.select(encoder, k);
                table.uniforms().clone()
            }
            None => {
                let uniforms = self.search_uniforms(u_stride, lambda, theta);
                kept.uniform_with(ctx, SEARCH_UNIFORMS, bytemuck::bytes_of(&uniforms))
            }
        };
        let bind = kept.bind_group(
            ctx,
            "tgv_pointwise",
            &kernel.layout,
            &[&buf_uniforms, &self.costs, &self.counts, u, a],
        );
        let n = self.width as u64 * self.height as u64;
        ctx.record_dispatch(encoder, &kernel, &bind, n)
    }
}

/// The raw costs of `volume` in a new device buffer (u8, 4 per word), after checking that its
/// data term over `window` fits.
pub(super) fn upload_costs(
    ctx: &GpuContext,
    volume: &CostVolume,
    window: u32,
) -> Result<wgpu::Buffer> {
    DataCostGpu::check(ctx, volume.shape(), window)?;
    Ok(ctx.storage("tgv_raw_costs", &volume.cost))
}
