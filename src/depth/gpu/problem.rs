//! [`TgvProblemGpu`]: the convex subproblem of the variational matcher resident on the GPU,
//! twin of [`TgvProblem`] (`src/depth/tgv/problem.rs`): its buffers, a fresh problem made on the
//! device (`shaders/tgv_init.wgsl`), the primal–dual iterations (`shaders/tgv_dual.wgsl`,
//! `shaders/tgv_primal.wgsl`), the tensors made from the left image
//! (`shaders/tgv_tensors.wgsl`) and the disparities with their costs gathered at the end
//! (`shaders/tgv_cost_at.wgsl`).

use super::data_cost::{DataCostGpu, SEARCH_UNIFORMS};
use crate::depth::sgm::VolumeShape;
use crate::depth::tgv::{steps_for, Regularizer, Tensor, TgvProblem};
use crate::gpu::kept::Kept;
use crate::gpu::layout::{CostAtUniforms, PointwiseUniforms, TensorUniforms, TgvUniforms};
use crate::gpu::shaders;
use crate::gpu::{ErrorScopes, GpuContext, Kernel};
use crate::{Error, Result};

/// The kept uniform buffer of the primal–dual iterations.
const STEP_UNIFORMS: &str = "tgv_uniforms";

/// Primal–dual iterations recorded per command buffer (bounds the size of one submission).
const ITERATIONS_PER_SUBMIT: u32 = 64;

/// A [`TgvProblem`] resident on the GPU: tensors, coupling target, primal, over-relaxed primal
/// and dual, in the CPU's layout (`[u, v1, v2]`, `[p1, p2, q11, q22, q12]` per pixel). Its
/// buffers, uniforms and bind groups are kept (`crate::gpu::kept`): a matcher hands them from
/// one pair to the next, so a pair of the same size creates none.
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
    pub(super) tensors: wgpu::Buffer,
    pub(super) target: wgpu::Buffer,
    pub(super) primal: wgpu::Buffer,
    primal_bar: wgpu::Buffer,
    dual: wgpu::Buffer,
    pub(super) kept: Kept,
}

/// Where a GPU problem's diffusion tensors come from.
pub(super) enum Tensors<'a> {
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
            let mut encoder = ctx.encoder("tgv_state");
            let u0 = (Some(problem.u_slice()), w, h);
            let gpu = Self::fresh_in((ctx, &mut encoder), Kept::default(), u0, setup, tensors)?;
            ctx.submit(encoder);
            return Ok(gpu);
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
            target: Self::target_in(ctx, &mut kept, n as usize),
            primal: kept.scratch(ctx, "tgv_primal", n * 12),
            primal_bar: kept.scratch(ctx, "tgv_primal_bar", n * 12),
            dual: kept.scratch(ctx, "tgv_dual", n * 20),
            kept,
        };
        scope.pop("allocating the TGV problem")?;
        Ok(gpu)
    }

    /// The buffer in `kept` where a fresh problem of `pixels` finds its initial disparity
    /// ([`TgvProblemGpu::fresh_in`] with `None`), and which then holds the coupling target.
    pub(super) fn target_in(ctx: &GpuContext, kept: &mut Kept, pixels: usize) -> wgpu::Buffer {
        kept.scratch(ctx, "tgv_target", pixels as u64 * 4)
    }

    /// A fresh problem ([`TgvProblem::new`]'s: primal `[u0, 0, 0]`, the over-relaxed primal
    /// equal to it, the dual zero) made on the device from `u0` (`shaders/tgv_init.wgsl`), in
    /// `kept`'s buffers, with `tensors`. `u0`: uploaded (4 bytes per pixel, not the 40-byte
    /// state), or `None` when work submitted before wrote it into
    /// [`TgvProblemGpu::target_in`]'s buffer (SGM's, filled on the device). Recorded into
    /// `encoder` (its uniforms have a buffer of their own, so the rounds may share the submit).
    pub(super) fn fresh_in(
        (ctx, encoder): (&'c GpuContext, &mut wgpu::CommandEncoder),
        kept: Kept,
        (u0, width, height): (Option<&[f32]>, usize, usize),
        setup: (Regularizer, f32, f32),
        tensors: Tensors,
    ) -> Result<Self> {
        if let Some(u0) = u0.filter(|u0| u0.len() != width * height) {
            return Err(Error::InvalidArgument(format!(
                "a {width}×{height} TGV problem from {} disparities",
                u0.len()
            )));
        }
        let mut gpu = Self::allocate(ctx, kept, (width, height), setup)?;
        let n = (width * height) as u64;
        let scope = ErrorScopes::push(&ctx.device);
        // The disparity goes up where `tgv_init` reads it; the first point-wise search then
        // overwrites it with the coupling target.
        if let Some(u0) = u0 {
            gpu.kept
                .storage_with(ctx, "tgv_target", bytemuck::cast_slice(u0));
        }
        let identity = matches!(tensors, Tensors::Identity);
        let init = (&shaders::TGV_INIT, "tgv_init_uniforms");
        let (kernel, bind) = gpu.prepare_init(init, 1.0, identity)?;
        if n > 0 {
            ctx.record_dispatch(encoder, &kernel, &bind, n)?;
        }
        match tensors {
            Tensors::Identity => {}
            Tensors::Host(t) => {
                gpu.kept
                    .storage_with(ctx, "tgv_tensors", bytemuck::cast_slice(t));
            }
            Tensors::Device(image, gamma, beta) => {
                gpu.record_tensors(encoder, image, (gamma, beta))?;
            }
        }
        scope.pop("making the TGV problem")?;
        Ok(gpu)
    }

    /// Its GPU.
    pub(super) fn context(&self) -> &'c GpuContext {
        self.ctx
    }

    /// Its kept buffers, uniforms and bind groups, for the next problem.
    pub(super) fn into_kept(self) -> Kept {
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
    /// the kept uniforms ([`STEP_UNIFORMS`]) written for the coupling weight `1/(2θ)`.
    fn prepare(
        &mut self,
        kernel: &'static shaders::ShaderSource,
        theta: f32,
    ) -> Result<(std::sync::Arc<Kernel>, wgpu::BindGroup)> {
        self.prepare_init((kernel, STEP_UNIFORMS), theta, false)
    }

    /// The iterations' uniforms for θ (`identity_tensors`: `tgv_init.wgsl` writes identities).
    fn uniforms(&self, theta: f32, identity_tensors: bool) -> TgvUniforms {
        TgvUniforms {
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
        }
    }

    /// [`TgvProblemGpu::prepare`] with the uniforms in the kept buffer `uniforms_name`, and
    /// `tgv_init.wgsl` writing identity tensors when `identity_tensors`.
    fn prepare_init(
        &mut self,
        (kernel, uniforms_name): (&'static shaders::ShaderSource, &'static str),
        theta: f32,
        identity_tensors: bool,
    ) -> Result<(std::sync::Arc<Kernel>, wgpu::BindGroup)> {
        let ctx = self.ctx;
        let compiled = ctx.kernel(kernel)?;
        let uniforms = self.uniforms(theta, identity_tensors);
        let bytes = bytemuck::bytes_of(&uniforms);
        let buf_uniforms = self.kept.uniform_with(ctx, uniforms_name, bytes);
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

    /// Records the rounds of [`crate::depth::tgv::TgvMatcher::refine`] after what `encoder`
    /// holds: for each θ of `thetas`, the point-wise search over `data` (the coupling target
    /// from u, with λ `lambda`), then `iterations` primal–dual iterations. The rounds' uniforms
    /// are written once, as a table, and each round's are copied from it into the bound uniform
    /// buffers before its dispatches, so that the rounds share a submit with each other and
    /// with what comes before and after. Past [`ITERATIONS_PER_SUBMIT`] iterations, what is
    /// recorded is submitted at a round's end. Returns the encoder, not submitted.
    pub(super) fn record_rounds(
        &mut self,
        mut encoder: wgpu::CommandEncoder,
        data: &DataCostGpu,
        lambda: f32,
        thetas: &[f32],
        iterations: u32,
    ) -> Result<wgpu::CommandEncoder> {
        let ctx = self.ctx;
        for &theta in thetas {
            self.check_theta(theta)?;
        }
        let n = self.pixels() as u64;
        if thetas.is_empty() || n == 0 {
            return Ok(encoder);
        }
        // Per round: the search's uniforms (u is the first of the primal's three floats per
        // pixel) and the iterations'.
        let searches: Vec<PointwiseUniforms> = (thetas.iter())
            .map(|&theta| data.search_uniforms(3, lambda, theta))
            .collect();
        let steps: Vec<TgvUniforms> = thetas.iter().map(|&t| self.uniforms(t, false)).collect();
        let names = ("tgv_search_table", SEARCH_UNIFORMS);
        let search_table = self.kept.uniform_table(ctx, names, &searches);
        let step_table = self
            .kept
            .uniform_table(ctx, ("tgv_step_table", STEP_UNIFORMS), &steps);
        let (dual_kernel, bind_dual) = self.prepare(&shaders::TGV_DUAL, thetas[0])?;
        let (primal_kernel, bind_primal) = self.prepare(&shaders::TGV_PRIMAL, thetas[0])?;
        let mut recorded = 0;
        for (k, &theta) in thetas.iter().enumerate() {
            data.record_search(
                (ctx, &mut self.kept),
                &mut encoder,
                (&self.primal, 3),
                &self.target,
                (lambda, theta),
                Some((&search_table, k)),
            )?;
            step_table.select(&mut encoder, k);
            for _ in 0..iterations {
                // One pass per step: a pass boundary orders the dual writes before the primal
                // reads (and the primal writes before the next dual step).
                ctx.record_dispatch(&mut encoder, &dual_kernel, &bind_dual, n)?;
                ctx.record_dispatch(&mut encoder, &primal_kernel, &bind_primal, n)?;
            }
            recorded += iterations;
            if recorded >= ITERATIONS_PER_SUBMIT && k + 1 < thetas.len() {
                ctx.submit(encoder);
                encoder = ctx.encoder("tgv_rounds");
                recorded = 0;
            }
        }
        Ok(encoder)
    }

    /// `iterations` iterations toward the target already in `self.target`.
    pub(super) fn run(&mut self, theta: f32, iterations: u32) -> Result<()> {
        let ctx = self.ctx;
        let n = self.pixels() as u64;
        let scope = ErrorScopes::push(&ctx.device);
        let (dual_kernel, bind_dual) = self.prepare(&shaders::TGV_DUAL, theta)?;
        let (primal_kernel, bind_primal) = self.prepare(&shaders::TGV_PRIMAL, theta)?;
        let mut left = iterations;
        while left > 0 {
            let batch = left.min(ITERATIONS_PER_SUBMIT);
            left -= batch;
            let mut encoder = ctx.encoder("tgv");
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

impl TgvProblemGpu<'_> {
    /// An error unless `volume` has the problem's size.
    pub(super) fn check_shape(&self, volume: VolumeShape) -> Result<()> {
        if (volume.width as usize, volume.height as usize) != (self.width, self.height) {
            return Err(Error::InvalidArgument(format!(
                "a {}×{} cost volume for a {}×{} problem",
                volume.width, volume.height, self.width, self.height
            )));
        }
        Ok(())
    }

    /// Records `shaders/tgv_cost_at.wgsl` over the disparity and the raw costs `raw` (of a
    /// volume of shape `volume`): each pixel's disparity and its cost
    /// ([`crate::depth::tgv::costs_at_disparities`]), 5 bytes per pixel in a kept buffer,
    /// returned ([`Gathered::decode`] reads it).
    pub(super) fn record_disparities_and_costs(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        (volume, raw): (VolumeShape, &wgpu::Buffer),
    ) -> Result<Gathered> {
        self.check_shape(volume)?;
        let (ctx, n) = (self.ctx, self.pixels());
        let kernel = ctx.kernel(&shaders::TGV_COST_AT)?;
        let uniforms = CostAtUniforms {
            width: volume.width,
            height: volume.height,
            num_disparities: volume.num_disparities as u32,
            min_disparity_px: volume.min_disparity_px as f32,
        };
        let bytes = bytemuck::bytes_of(&uniforms);
        let buf_uniforms = self.kept.uniform_with(ctx, "cost_at_uniforms", bytes);
        let gathered = Gathered {
            out: self
                .kept
                .scratch(ctx, "cost_at_out", (n + n.div_ceil(4)).max(1) as u64 * 4),
            pixels: n,
        };
        let buffers = [&buf_uniforms, raw, &self.primal, &gathered.out];
        let bind = self
            .kept
            .bind_group(ctx, "tgv_cost_at", &kernel.layout, &buffers);
        if n > 0 {
            ctx.record_dispatch(encoder, &kernel, &bind, n.div_ceil(4) as u64)?;
        }
        Ok(gathered)
    }

    /// [`TgvProblemGpu::record_disparities_and_costs`], submitted and read back (one wait);
    /// `more` (buffers and where they go) are read back in the same wait.
    pub(super) fn disparities_and_costs(
        &mut self,
        volume: (VolumeShape, &wgpu::Buffer),
        more: &mut [(&wgpu::Buffer, &mut [u8])],
    ) -> Result<(Vec<f32>, Vec<u8>)> {
        let ctx = self.ctx;
        let scope = ErrorScopes::push(&ctx.device);
        let mut encoder = ctx.encoder("tgv_cost_at");
        let gathered = self.record_disparities_and_costs(&mut encoder, volume)?;
        let mut back = gathered.target();
        let mut buffers = vec![(&gathered.out, bytemuck::cast_slice_mut(&mut back))];
        buffers.extend(more.iter_mut().map(|(b, t)| (*b, &mut **t)));
        ctx.submit_and_read_back(encoder, &mut self.kept, &mut buffers)?;
        scope.pop("gathering the disparities' costs")?;
        Ok(gathered.decode(&back))
    }
}

/// Each pixel's disparity and its cost there, on the device
/// ([`TgvProblemGpu::record_disparities_and_costs`]): the disparities' bits, then the costs, 4
/// per word.
pub(super) struct Gathered {
    pub out: wgpu::Buffer,
    pixels: usize,
}

impl Gathered {
    /// Where to read it back.
    pub fn target(&self) -> Vec<u32> {
        vec![0u32; self.pixels + self.pixels.div_ceil(4)]
    }

    /// The disparities and the costs, from what was read back into [`Gathered::target`].
    pub fn decode(&self, back: &[u32]) -> (Vec<f32>, Vec<u8>) {
        let n = self.pixels;
        let dense = back[..n].iter().map(|&b| f32::from_bits(b)).collect();
        let mut costs = bytemuck::cast_slice::<u32, u8>(&back[n..]).to_vec();
        costs.truncate(n);
        (dense, costs)
    }
}
