//! The variational stereo matcher on the GPU, twin of `src/depth/tgv.rs` and the census cost of
//! `src/depth/census.rs` / `src/depth/sgm.rs`:
//!
//! - [`TgvProblemGpu`]: [`TgvProblem::iterate`] (Chambolle–Pock with the tensor, quadratic
//!   coupling toward `a`) as two kernels per iteration, `shaders/tgv_dual.wgsl` (`p`, `q`) and
//!   `shaders/tgv_primal.wgsl` (`u`, `v`, over-relaxation), over `TgvProblem`'s arrays.
//! - [`pointwise_search_gpu`]: the decoupling search over the census costs
//!   (`shaders/tgv_pointwise.wgsl`), twin of [`crate::depth::tgv::decoupling_search`].
//! - [`census_transform_gpu`] and [`cost_volume_gpu`]: census signatures and Hamming costs
//!   (`shaders/census.wgsl`, `shaders/census_cost.wgsl`).
//! - [`refine_gpu`] / [`estimate_tgv_gpu`]: [`TgvMatcher::refine`] /
//!   [`TgvMatcher::estimate_with_stages`] with the cost volume, the point-wise searches and the
//!   primal–dual iterations on the GPU; the state stays on the GPU between rounds.
//!
//! Each kernel repeats its CPU twin's f32 operations in the same order (no `hypot`: the CPU's
//! dual projection uses `sqrt(p1² + p2²)` for this reason), and the costs are integers. On
//! lavapipe census, costs and point-wise search are bit-identical, and so are TV/TGV
//! iterations; with the image tensors (TGV-tensor) u differs by 1 ulp on ~1 % of pixels
//! (cause not found: Mesa's compiler evaluates part of `div(T p)` differently; 7.6e-6 px after
//! 50 iterations on Motorcycle, none of the final disparities by > 0.1 px). Other GPUs may
//! contract to FMA or divide within 2.5 ULP; `tests/gpu_stereo.rs` states the tolerances
//! (|Δu| ≤ 1e-3 px after 50 iterations). The costs' window sums are taken on the device from the
//! cost volume where it was made (`data_cost.rs`, `shaders/cost_window.wgsl`; integer sums, equal
//! to the CPU's), and in [`estimate_tgv_gpu`] TGV-tensor's diffusion tensors from the left image
//! the census read (`shaders/tgv_tensors.wgsl`; the device's `exp` and `pow`: 1.8e-7 from the
//! CPU's on llvmpipe). SGM runs there too, filters included (`sgm.rs`, `sgm_filters.rs`), the
//! initial disparity is filled there from SGM's (`shaders/tgv_fill_*.wgsl`), and at the end the
//! map is invalidated there (`invalidate.rs`: occlusions, the census cost at each pixel's
//! disparity, SGM's agreement and confidence), so a pair sends its two images up and reads its
//! map back (8 bytes per pixel), in one submit and one wait (the rounds' uniforms copied on
//! the device from a table written once); neither the volume nor any stage's state comes
//! back. What stays on the CPU: the initial problem's setup. Every array must fit one storage
//! binding (the largest is the window sums, 2 bytes per pixel and disparity: 119 MB for
//! 1241×376×128, under llvmpipe's 128 MiB); a larger input is an
//! [`crate::Error::GpuCapacity`], never truncated.

use crate::depth::sgm::{CostVolume, SgmMatcher, VolumeShape};
use crate::depth::tgv::{
    check_search, diffusion_tensors, Regularizer, TgvMatcher, TgvProblem, TgvStages,
};
use crate::depth::{DisparityEstimator, DisparityMap, OnDeviceDisparity};
use crate::frame::{GreyImage, Image};
use crate::gpu::kept::Kept;
use crate::gpu::{ErrorScopes, GpuContext, StageTally};
use crate::{Error, Result};

mod data_cost;
use data_cost::DataCostGpu;
mod census;
pub use census::{census_transform_gpu, cost_volume_gpu};
use census::{cost_volume_on_device, record_cost_volume, OnDevice};
mod problem;
use problem::Tensors;
pub use problem::TgvProblemGpu;
mod sgm;
pub use sgm::{
    aggregate_paths_gpu, select_disparities_gpu, SgmMatcherGpu, GPU_SGM_MAX_DISPARITIES,
};
mod sgm_filters;
use sgm_filters::MapOnDevice;
pub use sgm_filters::{fill_from_background_gpu, filter_disparities_gpu};
mod invalidate;
mod to_depth;
pub(crate) use to_depth::record_disparity_depth;
pub use to_depth::{disparity_depth_uniforms, disparity_to_depth_gpu};

/// [`crate::depth::tgv::box_filtered_costs`] on the GPU (`shaders/cost_window.wgsl`): the
/// costs of `volume` summed over `window` × `window` and each pixel's count, read back (the GPU
/// matchers keep them on the device; this is for comparing with the CPU).
pub fn window_costs_gpu(
    ctx: &GpuContext,
    volume: &CostVolume,
    window: u32,
) -> Result<(Vec<u16>, Vec<u16>)> {
    if window < 2 {
        return Err(Error::InvalidArgument(format!(
            "window sums need a window of 2 or more pixels, got {window}"
        )));
    }
    DataCostGpu::new(ctx, volume, window)?.read_back(ctx)
}

/// [`crate::depth::tgv::decoupling_search`] on the GPU: for each pixel the disparity `a`
/// (pixels) minimising `λ·C(x, a) + (u(x) − a)²/(2θ)` over the census costs of `volume`
/// averaged over `cost_window` × `cost_window` (averaged and searched on the GPU), with
/// the parabola fit. Uploads the raw costs on every call and sums them over the window on the
/// GPU ([`refine_gpu`] keeps them resident).
pub fn pointwise_search_gpu(
    ctx: &GpuContext,
    volume: &CostVolume,
    cost_window: u32,
    u: &[f32],
    lambda: f32,
    theta: f32,
) -> Result<Vec<f32>> {
    check_search(volume, cost_window, u, lambda, theta)?;
    let n = u.len() as u64;
    let data = DataCostGpu::new(ctx, volume, cost_window)?;
    let scope = ErrorScopes::push(&ctx.device);
    let buf_u = ctx.storage("pointwise_u", bytemuck::cast_slice(u));
    let buf_a = ctx.storage("pointwise_a", &vec![0u8; u.len() * 4]);
    let mut encoder = ctx.encoder("pointwise");
    let kept = &mut Kept::default();
    data.record_search(
        (ctx, kept),
        &mut encoder,
        (&buf_u, 1),
        &buf_a,
        (lambda, theta),
        None,
    )?;
    ctx.submit(encoder);
    scope.pop("running the point-wise search")?;
    ctx.read_back_as(&buf_a, n as usize)
}

/// [`crate::depth::tgv::diffusion_tensors`] on the GPU (`shaders/tgv_tensors.wgsl`), read back
/// (the GPU matcher keeps them on the device; this is for comparing with the CPU).
pub fn diffusion_tensors_gpu(
    ctx: &GpuContext,
    image: &GreyImage,
    gamma: f32,
    beta: f32,
) -> Result<Vec<[f32; 3]>> {
    let (w, h) = (image.width as usize, image.height as usize);
    let u0 = vec![0.0f32; w * h];
    let buf_image = ctx.storage("tensor_image", &image.data);
    let tensors = Tensors::Device(&buf_image, gamma, beta);
    let setup = (Regularizer::TgvTensor, 1.0, 1.0);
    let size = (Some(&u0[..]), w, h);
    let mut encoder = ctx.encoder("tgv_tensors");
    let gpu = TgvProblemGpu::fresh_in((ctx, &mut encoder), Kept::default(), size, setup, tensors)?;
    ctx.submit(encoder);
    ctx.read_back_as(&gpu.tensors, w * h)
}

/// [`TgvMatcher::refine`] on the GPU: the same rounds (point-wise search, then
/// `inner_iterations` primal–dual iterations, θ annealed) with the costs, `a` and the TGV state
/// resident on the GPU (the costs uploaded once, their window sums taken there); returns the
/// dense regularized disparity, pixels. The tensors and the initialisation are computed on the
/// CPU.
pub fn refine_gpu(
    ctx: &GpuContext,
    matcher: &TgvMatcher,
    left: &GreyImage,
    volume: &CostVolume,
    init: &DisparityMap,
) -> Result<Vec<f32>> {
    matcher.params.validate()?;
    let raw = data_cost::upload_costs(ctx, volume, matcher.params.cost_window)?;
    let on_device = (volume.shape(), &raw);
    let init = Init::Map(init);
    let encoder = ctx.encoder("tgv_refine");
    let kept = (Kept::default(), encoder);
    let (gpu, encoder) = refine_on_device(ctx, kept, matcher, (left, None), on_device, init)?;
    ctx.submit(encoder);
    gpu.u()
}

/// Where [`refine_on_device`] finds SGM's disparity.
enum Init<'a> {
    /// On the host: filled there ([`TgvMatcher::initial_disparity`]) and uploaded.
    Map(&'a DisparityMap),
    /// Already filled on the device, in the problem's target buffer
    /// ([`TgvProblemGpu::target_in`]) of the `kept` handed over.
    OnDevice,
}

/// [`refine_gpu`] over the raw costs `raw` already on the device (of a volume of shape
/// `volume`), from SGM's disparity `init`, with TGV-tensor's tensors made there from
/// `left_on_device` (the left image's buffer) when given, in the buffers of `kept`, recorded
/// after what `encoder` holds; returns the problem, still on the device, and the encoder, not
/// submitted (long runs submit part of it, [`TgvProblemGpu::record_rounds`]).
fn refine_on_device<'c>(
    ctx: &'c GpuContext,
    (kept, mut encoder): (Kept, wgpu::CommandEncoder),
    matcher: &TgvMatcher,
    (left, left_on_device): (&GreyImage, Option<&wgpu::Buffer>),
    (volume, raw): (VolumeShape, &wgpu::Buffer),
    init: Init,
) -> Result<(TgvProblemGpu<'c>, wgpu::CommandEncoder)> {
    let p = &matcher.params;
    p.validate()?;
    let (w, h) = (volume.width as usize, volume.height as usize);
    let u0 = match init {
        Init::Map(init) => Some(matcher.initial_disparity(left, volume, init)?),
        Init::OnDevice => None,
    };
    // TGV-tensor's tensors are made on the device when the image is there: not on the CPU too.
    let host_tensors;
    let tensors = match (left_on_device, p.regularizer) {
        (Some(image), Regularizer::TgvTensor) => Tensors::Device(image, p.gamma, p.beta),
        (None, Regularizer::TgvTensor) => {
            host_tensors = diffusion_tensors(left, p.gamma, p.beta);
            Tensors::Host(&host_tensors)
        }
        _ => Tensors::Identity,
    };
    let setup = (p.regularizer, p.alpha1, p.alpha2);
    let size = (u0.as_deref(), w, h);
    let mut gpu = TgvProblemGpu::fresh_in((ctx, &mut encoder), kept, size, setup, tensors)?;
    let scope = ErrorScopes::push(&ctx.device);
    let window = p.cost_window;
    let data = DataCostGpu::on_device(ctx, &mut gpu.kept, &mut encoder, volume, raw, window)?;
    let thetas: Vec<f32> = (0..p.outer_iterations).map(|k| p.theta(k)).collect();
    let encoder = gpu.record_rounds(encoder, &data, p.lambda, &thetas, p.inner_iterations)?;
    scope.pop("recording the variational matcher's rounds")?;
    Ok((gpu, encoder))
}

/// [`crate::depth::tgv::costs_at_disparities`] on the GPU (`shaders/tgv_cost_at.wgsl`): the
/// disparities `dense` as the TGV primal, `volume` uploaded; returns the disparities as the
/// kernel read them and their costs (for comparing with the CPU).
pub fn costs_at_disparities_gpu(
    ctx: &GpuContext,
    volume: &CostVolume,
    dense: &[f32],
) -> Result<(Vec<f32>, Vec<u8>)> {
    let (w, h) = (volume.width as usize, volume.height as usize);
    let identity = vec![[1.0, 0.0, 1.0]; w * h];
    let problem = TgvProblem::new(dense, w, h, Regularizer::Tv, 1.0, 1.0, identity)?;
    let mut gpu = TgvProblemGpu::upload(ctx, &problem)?;
    let raw = data_cost::upload_costs(ctx, volume, 1)?;
    gpu.disparities_and_costs((volume.shape(), &raw), &mut [])
}

/// [`TgvMatcher::estimate_with_stages`] on the GPU: the census, the cost volume, SGM (its
/// aggregation, selection and filters) and the fill of the initial disparity in one submit
/// ([`SgmMatcherGpu`]'s kernels), the refinement ([`refine_gpu`]) over the volume where it was
/// made, then the invalidation there; only the two images go up, and the stages come back in
/// the pair's one wait. The initial problem (without TGV-tensor's tensors, made on the device)
/// is set up on the CPU. Beyond [`GPU_SGM_MAX_DISPARITIES`], SGM runs on the CPU over the volume
/// read back, and so does the invalidation.
pub fn estimate_tgv_gpu(
    ctx: &GpuContext,
    matcher: &TgvMatcher,
    left: &GreyImage,
    right: &GreyImage,
) -> Result<TgvStages> {
    let finish = Finish::ReadBack { stages: true };
    let stages = estimate_kept(ctx, matcher, &mut Kept::default(), (left, right), finish)?;
    Ok(stages.expect("read back"))
}

/// [`estimate_tgv_gpu`] with the buffers and bind groups kept in `kept` between pairs. With
/// `stages` false only the result comes back (8 bytes per pixel): the stages' `sgm` and
/// `dense_px` are then empty.
fn estimate_kept(
    ctx: &GpuContext,
    matcher: &TgvMatcher,
    kept: &mut Kept,
    (left, right): (&GreyImage, &GreyImage),
    finish: Finish,
) -> Result<Option<TgvStages>> {
    let p = &matcher.params;
    p.validate()?;
    let census = (&p.sgm.census, p.sgm.min_disparity_px, p.sgm.num_disparities);
    if p.sgm.num_disparities > GPU_SGM_MAX_DISPARITIES {
        // More disparities than the device's aggregation holds: SGM on the CPU over the volume
        // read back, and the invalidation after it.
        let sgm = SgmMatcher::new(p.sgm)?;
        let (volume, on_device) = cost_volume_on_device(ctx, left, right, census)?;
        let init = sgm.estimate_from_volume(left, &volume)?;
        let volume = (on_device.shape, &on_device.volume);
        let left_on_device = (left, Some(&on_device.left));
        let taken = (std::mem::take(kept), ctx.encoder("tgv_refine"));
        let (mut gpu, encoder) = refine_on_device(
            ctx,
            taken,
            matcher,
            left_on_device,
            volume,
            Init::Map(&init),
        )?;
        ctx.submit(encoder);
        let gathered = gpu.disparities_and_costs(volume, &mut []);
        *kept = gpu.into_kept();
        let (dense, costs) = gathered?;
        let result = matcher.invalidate_with(&dense, &init, &costs, on_device.shape);
        return Ok(Some(TgvStages {
            sgm: init,
            dense_px: dense,
            result,
        }));
    }
    let scope = ErrorScopes::push(&ctx.device);
    let mut encoder = ctx.encoder("sgm");
    let on_device = record_cost_volume(ctx, &mut encoder, kept, (left, right), census)?;
    let sgm = sgm::sgm_on_device(ctx, &mut encoder, &p.sgm, kept, &on_device)?;
    let shape = on_device.shape;
    let target = TgvProblemGpu::target_in(ctx, kept, shape.width as usize * shape.height as usize);
    let fallback = shape.min_disparity_px as f32;
    sgm_filters::record_fill(ctx, &mut encoder, kept, &sgm, fallback, &target)?;
    scope.pop("recording the census, cost and SGM kernels")?;
    // The whole pair in one submit: census, costs, SGM, the fill, the fresh problem, the
    // window sums, the rounds and the invalidation, with the read-back copy.
    let volume = (shape, &on_device.volume);
    let left_on_device = (left, Some(&on_device.left));
    let taken = (std::mem::take(kept), encoder);
    let (mut gpu, mut encoder) =
        refine_on_device(ctx, taken, matcher, left_on_device, volume, Init::OnDevice)?;
    let finished = match finish {
        Finish::ReadBack { stages } => {
            finish_on_device((&mut gpu, encoder), matcher, volume, &sgm, stages).map(Some)
        }
        Finish::HandOn(arc, hand_on) => {
            let scope = ErrorScopes::push(&ctx.device);
            let result = gpu.record_invalidation(&mut encoder, matcher, volume, &sgm);
            let handed = result.and_then(|result| {
                hand_on(OnDeviceDisparity {
                    ctx: arc,
                    encoder,
                    disparity: &result.disparity,
                    width: result.width,
                    height: result.height,
                })
            });
            handed
                .and_then(|()| scope.pop("invalidating the variational matcher's disparities"))
                .map(|()| None)
        }
    };
    *kept = gpu.into_kept();
    finished
}

/// What becomes of a pair's result on the device: read back (with SGM's map and the dense
/// disparity where `stages`), or handed on where it is.
enum Finish<'f> {
    ReadBack {
        stages: bool,
    },
    /// The matcher's context (the device the map is on) and where the map goes.
    HandOn(
        &'f std::sync::Arc<GpuContext>,
        &'f mut dyn FnMut(OnDeviceDisparity) -> Result<()>,
    ),
}

/// The invalidation of `gpu`'s disparity against SGM's map `sgm`, on the device, recorded after
/// what `encoder` holds and submitted with it, and what comes back in one wait: the result, and
/// with `stages` SGM's map and the dense disparity too (else those stages are empty).
fn finish_on_device(
    (gpu, mut encoder): (&mut TgvProblemGpu, wgpu::CommandEncoder),
    matcher: &TgvMatcher,
    volume: (VolumeShape, &wgpu::Buffer),
    sgm: &MapOnDevice,
    stages: bool,
) -> Result<TgvStages> {
    let ctx = gpu.context();
    let scope = ErrorScopes::push(&ctx.device);
    let result = gpu.record_invalidation(&mut encoder, matcher, volume, sgm)?;
    let mut map = sgm_filters::empty_map(&result);
    let mut init = DisparityMap {
        disparity_px: Image::filled(0, 0, 0.0),
        confidence: None,
    };
    let mut dense_px = Vec::new();
    if stages {
        let gathered = gpu.record_disparities_and_costs(&mut encoder, volume)?;
        let mut back = gathered.target();
        init = sgm_filters::empty_map(sgm);
        let mut buffers = sgm_filters::targets(&result, &mut map);
        buffers.extend(sgm_filters::targets(sgm, &mut init));
        buffers.push((&gathered.out, bytemuck::cast_slice_mut(&mut back)));
        ctx.submit_and_read_back(encoder, &mut gpu.kept, &mut buffers)?;
        dense_px = gathered.decode(&back).0;
    } else {
        let mut buffers = sgm_filters::targets(&result, &mut map);
        ctx.submit_and_read_back(encoder, &mut gpu.kept, &mut buffers)?;
    }
    scope.pop("invalidating the variational matcher's disparities")?;
    Ok(TgvStages {
        sgm: init,
        dense_px,
        result: map,
    })
}

/// A [`TgvMatcher`] that runs on the GPU ([`estimate_tgv_gpu`]), as a [`DisparityEstimator`]
/// (every stereo stage of a GPU `crate::backend::Backend`).
#[derive(Debug)]
pub struct TgvMatcherGpu {
    ctx: std::sync::Arc<GpuContext>,
    matcher: TgvMatcher,
    /// The census, cost, SGM and gathering buffers and bind groups, kept between pairs.
    kept: std::sync::Mutex<Kept>,
    /// Where each pair's traffic is added.
    tally: StageTally,
}

impl TgvMatcherGpu {
    /// `matcher` on the device of `ctx`.
    pub fn new(ctx: std::sync::Arc<GpuContext>, matcher: TgvMatcher) -> Self {
        TgvMatcherGpu {
            ctx,
            matcher,
            kept: Default::default(),
            tally: StageTally::default(),
        }
    }

    /// Adds each pair's GPU traffic to `tally` (a run's stereo figures).
    pub fn counting_into(mut self, tally: StageTally) -> Self {
        self.tally = tally;
        self
    }
}

impl DisparityEstimator for TgvMatcherGpu {
    fn name(&self) -> &str {
        self.matcher.name()
    }

    fn estimate(&self, left: &GreyImage, right: &GreyImage) -> Result<DisparityMap> {
        let mut kept = self.kept.lock().unwrap_or_else(|e| e.into_inner());
        let finish = Finish::ReadBack { stages: false };
        let stages = self.tally.count(&self.ctx, || {
            estimate_kept(&self.ctx, &self.matcher, &mut kept, (left, right), finish)
        })?;
        Ok(stages.expect("read back").result)
    }

    fn estimate_on_device(
        &self,
        left: &GreyImage,
        right: &GreyImage,
        finish: &mut dyn FnMut(OnDeviceDisparity) -> Result<()>,
    ) -> Option<Result<()>> {
        if self.matcher.params.sgm.num_disparities > GPU_SGM_MAX_DISPARITIES {
            return None;
        }
        let mut kept = self.kept.lock().unwrap_or_else(|e| e.into_inner());
        let pair = (left, right);
        Some(self.tally.count(&self.ctx, || {
            let finish = Finish::HandOn(&self.ctx, finish);
            estimate_kept(&self.ctx, &self.matcher, &mut kept, pair, finish).map(|_| ())
        }))
    }
}
