//! The end of the GPU variational matcher, on the device: the occlusion test
//! (`shaders/tgv_occluded.wgsl`) and the invalidation with its confidences
//! (`shaders/tgv_invalidate.wgsl`), twins of [`TgvMatcher::invalidate_with`] over the
//! problem's disparity, its costs read where the volume was made and SGM's map where SGM left
//! it. So a pair's map is made on the device and only the result comes back (8 bytes per
//! pixel).

use super::problem::TgvProblemGpu;
use super::sgm_filters::MapOnDevice;
use crate::depth::sgm::VolumeShape;
use crate::depth::tgv::{HoleFill, TgvMatcher};
use crate::gpu::layout::InvalidateUniforms;
use crate::gpu::shaders;
use crate::Result;

impl TgvProblemGpu<'_> {
    /// Records `matcher`'s invalidation of the problem's disparity against SGM's map `sgm`,
    /// with the raw costs `raw` of a volume of shape `volume`; returns the result, on the device.
    pub(super) fn record_invalidation(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        matcher: &TgvMatcher,
        (volume, raw): (VolumeShape, &wgpu::Buffer),
        sgm: &MapOnDevice,
    ) -> Result<MapOnDevice> {
        self.check_shape(volume)?;
        let p = &matcher.params;
        let ctx = self.context();
        let n = volume.width as u64 * volume.height as u64;
        let uniforms = InvalidateUniforms {
            width: volume.width,
            height: volume.height,
            num_disparities: volume.num_disparities as u32,
            min_disparity_px: volume.min_disparity_px as f32,
            hole_fill: match p.hole_fill {
                HoleFill::None => 0,
                HoleFill::Visible => 1,
                HoleFill::All => 2,
            },
            occlusion_tolerance_px: p.occlusion_tolerance_px,
            max_bits: p.max_cost_fraction * volume.max_cost as f32,
            max_cost: volume.max_cost as u32,
        };
        let bytes = bytemuck::bytes_of(&uniforms);
        let buf_uniforms = self.kept.uniform_with(ctx, "invalidate_uniforms", bytes);
        // Every pixel of both is written by the kernels.
        let out = MapOnDevice {
            disparity: self.kept.scratch(ctx, "tgv_result_disparity", n * 4),
            confidence: self.kept.scratch(ctx, "tgv_result_confidence", n * 4),
            width: volume.width,
            height: volume.height,
        };
        let buffers = [
            &buf_uniforms,
            raw,
            &self.primal,
            &sgm.disparity,
            &sgm.confidence,
            &out.disparity,
            &out.confidence,
        ];
        let passes = [
            (&shaders::TGV_OCCLUDED, volume.height as u64),
            (&shaders::TGV_INVALIDATE, n),
        ];
        for (source, invocations) in passes {
            let kernel = ctx.kernel(source)?;
            let bind = self
                .kept
                .bind_group(ctx, source.file, &kernel.layout, &buffers);
            ctx.record_dispatch(encoder, &kernel, &bind, invocations)?;
        }
        Ok(out)
    }
}
