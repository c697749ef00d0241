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
//! CPU's on llvmpipe). SGM's path aggregation and winner selection run there too (`sgm.rs`),
//! and at the end each pixel's disparity and its cost at that disparity are gathered there
//! (`shaders/tgv_cost_at.wgsl`, 5 bytes per pixel), so neither the volume nor the TGV state
//! comes back. What stays on the CPU: SGM's median and speckle filters, the initial problem
//! (without TGV-tensor's tensors, made on the device) and the invalidation over the gathered
//! costs. Every array must fit one storage binding (the largest is the window sums, 2 bytes
//! per pixel and disparity: 119 MB for 1241×376×128, under llvmpipe's 128 MiB); a larger input
//! is an [`crate::Error::GpuCapacity`], never truncated.

use crate::depth::sgm::{CostVolume, SgmMatcher, VolumeShape};
use crate::depth::tgv::{
    check_search, diffusion_tensors, steps_for, Regularizer, Tensor, TgvMatcher, TgvProblem,
    TgvStages,
};
use crate::depth::{DisparityEstimator, DisparityMap};
use crate::frame::GreyImage;
use crate::gpu::kept::Kept;
use crate::gpu::layout::{CostAtUniforms, TensorUniforms, TgvUniforms};
use crate::gpu::shaders;
use crate::gpu::{ErrorScopes, GpuContext, Kernel, StageTally};
use crate::{Error, Result};

/// Primal–dual iterations recorded per command buffer (bounds the size of one submission).
const ITERATIONS_PER_SUBMIT: u32 = 64;

mod data_cost;
use data_cost::DataCostGpu;
mod census;
pub use census::{census_transform_gpu, cost_volume_gpu};
use census::{cost_volume_on_device, record_cost_volume, OnDevice};
mod sgm;
pub use sgm::{
    aggregate_paths_gpu, select_disparities_gpu, SgmMatcherGpu, GPU_SGM_MAX_DISPARITIES,
};

/// A [`TgvProblem`] resident on the GPU: tensors, coupling target, primal, over-relaxed primal
/// and dual, in the CPU's layout (`[u, v1, v2]`, `[p1, p2, q11, q22, q12]` per pixel). Its
/// buffers, uniforms and bind groups are kept ([`Kept`]): a matcher hands them from one pair
/// to the next, so a pair of the same size creates none.
#[derive(Debug)]
pub struct TgvProblemGpu<'c> {
    ctx: &'c GpuContext,
    width: usize,
    height: usize,
    regularizer: Regularizer,
    alpha1: f32,
    alpha2: f32,
    tau: f32,
    sigma: f32,
    tensors: wgpu::Buffer,
    target: wgpu::Buffer,
    primal: wgpu::Buffer,
    primal_bar: wgpu::Buffer,
    dual: wgpu::Buffer,
    kept: Kept,
}

/// Where a GPU problem's diffusion tensors come from.
enum Tensors<'a> {
    /// Identities (TV and TGV), written on the device by `shaders/tgv_init.wgsl`.
    Identity,
    /// Uploaded, `[t11, t12, t22]` per pixel.
    Host(&'a [Tensor]),
    /// Made on the device from the left image's grey levels in this buffer (4 per word), with
    /// γ and β (`shaders/tgv_tensors.wgsl`).
    Device(&'a wgpu::Buffer, f32, f32),
}

impl<'c> TgvProblemGpu<'c> {
    /// Uploads `problem` (its parameters and whole state; a fresh problem's state, from
    /// [`TgvProblem::new`], is made on the device from its disparity). Fails with
    /// [`Error::GpuCapacity`] when the dual (20 bytes per pixel) does not fit one binding.
    pub fn upload(ctx: &'c GpuContext, problem: &TgvProblem) -> Result<Self> {
        let (w, h) = (problem.width, problem.height);
        let tensors = Tensors::Host(problem.tensors());
        let setup = (problem.regularizer, problem.alpha1, problem.alpha2);
        if problem.is_fresh() {
            return Self::fresh_in(
                ctx,
                Kept::default(),
                (problem.u_slice(), w, h),
                setup,
                tensors,
            );
        }
        let mut gpu = Self::allocate(ctx, Kept::default(), (w, h), setup)?;
        let scope = ErrorScopes::push(&ctx.device);
        let (primal, primal_bar, dual) = problem.state();
        let kept = &mut gpu.kept;
        let bytes = |a: &[[f32; 3]]| bytemuck::cast_slice::<[f32; 3], u8>(a).to_vec();
        kept.storage_with(ctx, "tgv_tensors", bytemuck::cast_slice(problem.tensors()));
        kept.storage_with(ctx, "tgv_primal", &bytes(&primal));
        kept.storage_with(ctx, "tgv_primal_bar", &bytes(&primal_bar));
        kept.storage_with(ctx, "tgv_dual", bytemuck::cast_slice(&dual));
        scope.pop("uploading the TGV problem")?;
        Ok(gpu)
    }

    /// The buffers of a `width` × `height` problem in `kept` (contents unspecified), with its
    /// regularizer and weights. Fails with [`Error::GpuCapacity`] when the dual (20 bytes per
    /// pixel) does not fit one binding.
    fn allocate(
        ctx: &'c GpuContext,
        mut kept: Kept,
        (width, height): (usize, usize),
        (regularizer, alpha1, alpha2): (Regularizer, f32, f32),
    ) -> Result<Self> {
        let n = (width * height) as u64;
        ctx.check_binding("TGV dual (20 bytes per pixel)", n * 20)?;
        if n > u32::MAX as u64 / 5 {
            return Err(Error::GpuCapacity {
                what: "TGV pixels (u32 indices)".into(),
                needed_bytes: n,
                limit_bytes: u32::MAX as u64 / 5,
            });
        }
        let (tau, sigma) = steps_for(regularizer);
        let scope = ErrorScopes::push(&ctx.device);
        let gpu = TgvProblemGpu {
            ctx,
            width,
            height,
            regularizer,
            alpha1,
            alpha2,
            tau,
            sigma,
            tensors: kept.scratch(ctx, "tgv_tensors", n * 12),
            target: kept.scratch(ctx, "tgv_target", n * 4),
            primal: kept.scratch(ctx, "tgv_primal", n * 12),
            primal_bar: kept.scratch(ctx, "tgv_primal_bar", n * 12),
            dual: kept.scratch(ctx, "tgv_dual", n * 20),
            kept,
        };
        scope.pop("allocating the TGV problem")?;
        Ok(gpu)
    }

    /// A fresh problem ([`TgvProblem::new`]'s: primal `[u0, 0, 0]`, the over-relaxed primal
    /// equal to it, the dual zero) made on the device from `u0` (`shaders/tgv_init.wgsl`: 4 bytes
    /// per pixel go up, not the 40-byte state), in `kept`'s buffers, with `tensors`.
    fn fresh_in(
        ctx: &'c GpuContext,
        kept: Kept,
        (u0, width, height): (&[f32], usize, usize),
        setup: (Regularizer, f32, f32),
        tensors: Tensors,
    ) -> Result<Self> {
        if u0.len() != width * height {
            return Err(Error::InvalidArgument(format!(
                "a {width}×{height} TGV problem from {} disparities",
                u0.len()
            )));
        }
        let mut gpu = Self::allocate(ctx, kept, (width, height), setup)?;
        let n = u0.len() as u64;
        let scope = ErrorScopes::push(&ctx.device);
        // The disparity goes up where `tgv_init` reads it; the first point-wise search then
        // overwrites it with the coupling target.
        gpu.kept
            .storage_with(ctx, "tgv_target", bytemuck::cast_slice(u0));
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("tgv_state"),
            });
        let identity = matches!(tensors, Tensors::Identity);
        let (kernel, bind) = gpu.prepare_init(&shaders::TGV_INIT, 1.0, identity)?;
        if n > 0 {
            ctx.record_dispatch(&mut encoder, &kernel, &bind, n)?;
        }
        match tensors {
            Tensors::Identity => {}
            Tensors::Host(t) => {
                gpu.kept
                    .storage_with(ctx, "tgv_tensors", bytemuck::cast_slice(t));
            }
            Tensors::Device(image, gamma, beta) => {
                gpu.record_tensors(&mut encoder, image, (gamma, beta))?;
            }
        }
        ctx.submit(encoder);
        scope.pop("making the TGV problem")?;
        Ok(gpu)
    }

    /// Its kept buffers, uniforms and bind groups, for the next problem.
    fn into_kept(self) -> Kept {
        self.kept
    }

    /// Width, pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height, pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    fn pixels(&self) -> usize {
        self.width * self.height
    }

    /// [`TgvProblem::iterate`] on the GPU: `iterations` primal–dual iterations toward the
    /// coupling target `a` (one disparity per pixel, pixels) with weight `1/(2θ)`. The state
    /// stays on the GPU ([`TgvProblemGpu::download`] fetches it).
    pub fn iterate(&mut self, a: &[f32], theta: f32, iterations: u32) -> Result<()> {
        if a.len() != self.pixels() {
            return Err(Error::InvalidArgument(format!(
                "coupling target has {} values, the problem {}×{}",
                a.len(),
                self.width,
                self.height
            )));
        }
        self.check_theta(theta)?;
        if self.pixels() == 0 {
            return Ok(());
        }
        self.ctx
            .write_buffer(&self.target, 0, bytemuck::cast_slice(a));
        self.run(theta, iterations)
    }

    fn check_theta(&self, theta: f32) -> Result<()> {
        if !(theta.is_finite() && theta > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "θ must be positive and finite, got {theta}"
            )));
        }
        Ok(())
    }

    /// `kernel` (of the iterations' layout, `shared/tgv_common.wgsl`) and its kept bind group,
    /// the kept uniforms written for the coupling weight `1/(2θ)`.
    fn prepare(
        &mut self,
        kernel: &'static shaders::ShaderSource,
        theta: f32,
    ) -> Result<(std::sync::Arc<Kernel>, wgpu::BindGroup)> {
        self.prepare_init(kernel, theta, false)
    }

    /// [`TgvProblemGpu::prepare`], with `tgv_init.wgsl` writing identity tensors when
    /// `identity_tensors`.
    fn prepare_init(
        &mut self,
        kernel: &'static shaders::ShaderSource,
        theta: f32,
        identity_tensors: bool,
    ) -> Result<(std::sync::Arc<Kernel>, wgpu::BindGroup)> {
        let ctx = self.ctx;
        let compiled = ctx.kernel(kernel)?;
        let uniforms = TgvUniforms {
            width: self.width as u32,
            height: self.height as u32,
            tv: (self.regularizer == Regularizer::Tv) as u32,
            identity_tensors: identity_tensors as u32,
            sigma: self.sigma,
            tau: self.tau,
            alpha1: self.alpha1,
            alpha2: self.alpha2,
            // The CPU's `coupling = tau / theta`, in f32.
            coupling: self.tau / theta,
            pad1: [0; 3],
        };
        let bytes = bytemuck::bytes_of(&uniforms);
        let buf_uniforms = self.kept.uniform_with(ctx, "tgv_uniforms", bytes);
        let buffers = [
            &buf_uniforms,
            &self.tensors,
            &self.target,
            &self.primal,
            &self.primal_bar,
            &self.dual,
        ];
        // The kernels share one layout (shared/tgv_common.wgsl), but each pipeline has its own
        // layout object: one bind group per kernel.
        let bind = self
            .kept
            .bind_group(ctx, kernel.file, &compiled.layout, &buffers);
        Ok((compiled, bind))
    }

    /// `iterations` iterations toward the target already in `self.target`.
    fn run(&mut self, theta: f32, iterations: u32) -> Result<()> {
        let ctx = self.ctx;
        let n = self.pixels() as u64;
        let scope = ErrorScopes::push(&ctx.device);
        let (dual_kernel, bind_dual) = self.prepare(&shaders::TGV_DUAL, theta)?;
        let (primal_kernel, bind_primal) = self.prepare(&shaders::TGV_PRIMAL, theta)?;
        let mut left = iterations;
        while left > 0 {
            let batch = left.min(ITERATIONS_PER_SUBMIT);
            left -= batch;
            let mut encoder = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("tgv") });
            for _ in 0..batch {
                // One pass per step: a pass boundary orders the dual writes before the primal
                // reads (and the primal writes before the next dual step).
                ctx.record_dispatch(&mut encoder, &dual_kernel, &bind_dual, n)?;
                ctx.record_dispatch(&mut encoder, &primal_kernel, &bind_primal, n)?;
            }
            ctx.submit(encoder);
        }
        scope.pop("running the TGV kernels")
    }

    /// Records `shaders/tgv_tensors.wgsl`: the tensors from the grey levels in `image`.
    fn record_tensors(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        image: &wgpu::Buffer,
        (gamma, beta): (f32, f32),
    ) -> Result<()> {
        let ctx = self.ctx;
        let kernel = ctx.kernel(&shaders::TGV_TENSORS)?;
        let uniforms = TensorUniforms {
            width: self.width as u32,
            height: self.height as u32,
            gamma,
            beta,
            pad: [0; 4],
        };
        let bytes = bytemuck::bytes_of(&uniforms);
        let buf_uniforms = self.kept.uniform_with(ctx, "tensor_uniforms", bytes);
        let buffers = [&buf_uniforms, image, &self.tensors];
        let bind = self
            .kept
            .bind_group(ctx, "tgv_tensors", &kernel.layout, &buffers);
        ctx.record_dispatch(encoder, &kernel, &bind, self.pixels() as u64)
    }

    /// The disparity `u`, pixels (read back).
    pub fn u(&self) -> Result<Vec<f32>> {
        let primal: Vec<[f32; 3]> = self.ctx.read_back_as(&self.primal, self.pixels())?;
        Ok(primal.iter().map(|p| p[0]).collect())
    }

    /// Writes the GPU state (primal, over-relaxed primal, dual) into `problem`, which must be the
    /// one uploaded (same size), so that it can continue on either device.
    pub fn download(&self, problem: &mut TgvProblem) -> Result<()> {
        if (problem.width, problem.height) != (self.width, self.height) {
            return Err(Error::InvalidArgument(format!(
                "downloading a {}×{} GPU problem into a {}×{} one",
                self.width, self.height, problem.width, problem.height
            )));
        }
        let n = self.pixels();
        let mut primal: Vec<[f32; 3]> = bytemuck::zeroed_vec(n);
        let mut primal_bar: Vec<[f32; 3]> = bytemuck::zeroed_vec(n);
        let mut dual: Vec<[f32; 5]> = bytemuck::zeroed_vec(n);
        self.ctx.read_back_into(&mut [
            (&self.primal, bytemuck::cast_slice_mut(&mut primal)),
            (&self.primal_bar, bytemuck::cast_slice_mut(&mut primal_bar)),
            (&self.dual, bytemuck::cast_slice_mut(&mut dual)),
        ])?;
        problem.set_state(&primal, &primal_bar, &dual)
    }
}

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
    let mut encoder = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("pointwise"),
        });
    let kept = &mut Kept::default();
    data.record_search(
        (ctx, kept),
        &mut encoder,
        (&buf_u, 1),
        &buf_a,
        lambda,
        theta,
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
    let gpu = TgvProblemGpu::fresh_in(ctx, Kept::default(), (&u0, w, h), setup, tensors)?;
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
    refine_on_device(ctx, Kept::default(), matcher, (left, None), on_device, init)?.u()
}

/// [`refine_gpu`] over the raw costs `raw` already on the device (of a volume of shape
/// `volume`), with TGV-tensor's tensors made there from `left_on_device` (the left image's
/// buffer) when given, in the buffers of `kept`; returns the problem, still on the device.
fn refine_on_device<'c>(
    ctx: &'c GpuContext,
    kept: Kept,
    matcher: &TgvMatcher,
    (left, left_on_device): (&GreyImage, Option<&wgpu::Buffer>),
    (volume, raw): (VolumeShape, &wgpu::Buffer),
    init: &DisparityMap,
) -> Result<TgvProblemGpu<'c>> {
    let p = &matcher.params;
    p.validate()?;
    let (w, h) = (volume.width as usize, volume.height as usize);
    let u0 = matcher.initial_disparity(left, volume, init)?;
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
    let mut gpu = TgvProblemGpu::fresh_in(ctx, kept, (&u0, w, h), setup, tensors)?;
    let data = DataCostGpu::on_device(ctx, &mut gpu.kept, volume, raw, p.cost_window)?;
    for k in 0..p.outer_iterations {
        let theta = p.theta(k);
        let scope = ErrorScopes::push(&ctx.device);
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("pointwise"),
            });
        // u is the first of the primal's three floats per pixel; a is the problem's target.
        data.record_search(
            (ctx, &mut gpu.kept),
            &mut encoder,
            (&gpu.primal, 3),
            &gpu.target,
            p.lambda,
            theta,
        )?;
        ctx.submit(encoder);
        scope.pop("running the point-wise search")?;
        gpu.run(theta, p.inner_iterations)?;
    }
    Ok(gpu)
}

impl TgvProblemGpu<'_> {
    /// Records `shaders/tgv_cost_at.wgsl` over the disparity and the raw costs `raw` (of a
    /// volume of shape `volume`), and reads back in the same submit each pixel's disparity and
    /// its cost ([`crate::depth::tgv::costs_at_disparities`]): 5 bytes per pixel, in kept
    /// buffers.
    fn disparities_and_costs(
        &mut self,
        (volume, raw): (VolumeShape, &wgpu::Buffer),
    ) -> Result<(Vec<f32>, Vec<u8>)> {
        let (ctx, n) = (self.ctx, self.pixels());
        if (volume.width as usize, volume.height as usize) != (self.width, self.height) {
            return Err(Error::InvalidArgument(format!(
                "a {}×{} cost volume for a {}×{} problem",
                volume.width, volume.height, self.width, self.height
            )));
        }
        if n == 0 {
            return Ok((Vec::new(), Vec::new()));
        }
        let kernel = ctx.kernel(&shaders::TGV_COST_AT)?;
        let uniforms = CostAtUniforms {
            width: volume.width,
            height: volume.height,
            num_disparities: volume.num_disparities as u32,
            min_disparity_px: volume.min_disparity_px as f32,
        };
        let scope = ErrorScopes::push(&ctx.device);
        let bytes = bytemuck::bytes_of(&uniforms);
        let buf_uniforms = self.kept.uniform_with(ctx, "cost_at_uniforms", bytes);
        let words = n + n.div_ceil(4);
        let out = self.kept.scratch(ctx, "cost_at_out", words as u64 * 4);
        let buffers = [&buf_uniforms, raw, &self.primal, &out];
        let bind = self
            .kept
            .bind_group(ctx, "tgv_cost_at", &kernel.layout, &buffers);
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("tgv_cost_at"),
            });
        ctx.record_dispatch(&mut encoder, &kernel, &bind, n.div_ceil(4) as u64)?;
        let mut back = vec![0u32; words];
        ctx.submit_and_read_back(
            encoder,
            &mut self.kept,
            &mut [(&out, bytemuck::cast_slice_mut(&mut back))],
        )?;
        scope.pop("gathering the disparities' costs")?;
        let dense = back[..n].iter().map(|&b| f32::from_bits(b)).collect();
        let mut costs = bytemuck::cast_slice::<u32, u8>(&back[n..]).to_vec();
        costs.truncate(n);
        Ok((dense, costs))
    }
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
    gpu.disparities_and_costs((volume.shape(), &raw))
}

/// [`TgvMatcher::estimate_with_stages`] on the GPU: the census, the cost volume and SGM's
/// aggregation and selection in one submit and one wait ([`SgmMatcherGpu`]'s), then the
/// refinement ([`refine_gpu`]) over the volume where it was made, then each pixel's disparity
/// and its cost gathered there for the invalidation. SGM's filters, the initial problem and the
/// invalidation run on the CPU; neither the volume nor the TGV state comes back.
pub fn estimate_tgv_gpu(
    ctx: &GpuContext,
    matcher: &TgvMatcher,
    left: &GreyImage,
    right: &GreyImage,
) -> Result<TgvStages> {
    estimate_kept(ctx, matcher, &mut Kept::default(), left, right)
}

/// [`estimate_tgv_gpu`] with the census, cost, SGM and gathering buffers and bind groups kept
/// in `kept` between pairs.
fn estimate_kept(
    ctx: &GpuContext,
    matcher: &TgvMatcher,
    kept: &mut Kept,
    left: &GreyImage,
    right: &GreyImage,
) -> Result<TgvStages> {
    let p = &matcher.params;
    p.validate()?;
    let sgm = SgmMatcher::new(p.sgm)?;
    let census = (&p.sgm.census, p.sgm.min_disparity_px, p.sgm.num_disparities);
    let (init, on_device) = if p.sgm.num_disparities <= GPU_SGM_MAX_DISPARITIES {
        let scope = ErrorScopes::push(&ctx.device);
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("sgm") });
        let on_device = record_cost_volume(ctx, &mut encoder, kept, (left, right), census)?;
        let init = sgm::sgm_recorded(ctx, encoder, &sgm, kept, &on_device)?;
        scope.pop("recording the census cost kernels")?;
        (init, on_device)
    } else {
        // More disparities than the device's aggregation holds: SGM on the CPU over the volume
        // read back.
        let (volume, on_device) = cost_volume_on_device(ctx, left, right, census)?;
        (sgm.estimate_from_volume(left, &volume)?, on_device)
    };
    let volume = (on_device.shape, &on_device.volume);
    let left_on_device = (left, Some(&on_device.left));
    let taken = std::mem::take(kept);
    let mut gpu = refine_on_device(ctx, taken, matcher, left_on_device, volume, &init)?;
    let gathered = gpu.disparities_and_costs(volume);
    *kept = gpu.into_kept();
    let (dense, costs) = gathered?;
    let shape = on_device.shape;
    let result = matcher.invalidate_with(&dense, &init, &costs, shape);
    Ok(TgvStages {
        sgm: init,
        dense_px: dense,
        result,
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
        let stages = self.tally.count(&self.ctx, || {
            estimate_kept(&self.ctx, &self.matcher, &mut kept, left, right)
        })?;
        Ok(stages.result)
    }
}
