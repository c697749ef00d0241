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
//!
//! A frame's work (a matcher's, its depths' copy, its listing and the band's readback) is
//! recorded and held in the frame: `Reconstructor::fuse_input` has it ride in the submit of the
//! frame before's fusion where the device keeps up (one submit a frame), or submits it alone;
//! planning or reading the frame submits what is still held.

use super::band_blocks_gpu::{band_block_params, record_band_blocks, BandDecoder, BandWords};
use super::band_gpu::{band_slice_uniforms, record_band_slices, BandSliceOutputs, SliceWords};
use super::{BandSlices, DepthFusionParams, DepthPlan, DeviceBand};
use crate::camera::{PinholeIntrinsics, WorldFromCamera};
use crate::depth::{
    disparity_depth_uniforms, record_disparity_depth, DisparityMap, OnDeviceDisparity,
};
use crate::frame::{DepthFrame, Image, RgbImage};
use crate::gpu::kept::{BufferPool, Kept, Pooled};
use crate::gpu::layout::BandSliceUniforms;
use crate::gpu::readback::{LateReadback, ReadbackArm, ReadbackRing};
use crate::gpu::GpuContext;
use crate::grid::GridParams;
use crate::Result;
use std::sync::{Arc, Mutex};

/// A depth frame whose depths are on the device (see the module documentation).
pub struct DeviceDepthFrame {
    /// The camera, pose and colour; `depth_m` has the image's size and no data.
    header: DepthFrame,
    /// The depths (f32, metres, NaN where invalid), row-major, in a buffer handed back to the
    /// pool of its [`DeviceDepthKept`] when the frame is dropped.
    depth: Pooled,
    /// The device they are on.
    ctx: Arc<GpuContext>,
    /// The band, collected when first asked for.
    band: Mutex<FrameBand>,
    /// The voxel size, truncation and usable depths (bits) the band was listed for.
    made_for: [u32; 4],
    /// Whether a matcher made the depths on the device (else they came from the host).
    matched: bool,
    /// The frame's own work (a matcher's, its depths' copy, its band's listing and readback)
    /// until it is submitted: with the fusion before it ([`Self::take_unsubmitted`]), alone
    /// ([`Self::submit_now`]), or by its [`DeviceDepthKept`] before that makes another frame.
    unsubmitted: Held,
}

/// A frame's work recorded and not yet submitted, owned by the frame and seen by the
/// [`DeviceDepthKept`] it was made with, which submits it before its buffers are written for
/// another frame.
type Held = Arc<Mutex<Option<HeldWork>>>;

/// Work recorded for a device and held for a later submit, and what asks for its readback.
pub(crate) struct HeldWork {
    ctx: Arc<GpuContext>,
    encoder: wgpu::CommandEncoder,
    readback: ReadbackArm,
}

impl HeldWork {
    /// The commands, to submit with the caller's, and what to call once they are submitted.
    pub(crate) fn into_parts(self) -> (wgpu::CommandEncoder, ReadbackArm) {
        (self.encoder, self.readback)
    }
}

/// Submits the work `held` still holds, alone.
fn submit_held(held: &Held) {
    let work = held.lock().unwrap_or_else(|e| e.into_inner()).take();
    if let Some(work) = work {
        work.ctx.submit(work.encoder);
        work.readback.submitted();
    }
}

/// What came back of a frame's band, or is on its way.
enum FrameBand {
    /// Its slices (a device without f64): the host lists the blocks from them.
    Slices(BandSlices),
    /// Its blocks, listed on the device, and the slices the device left to the host.
    Listed(DeviceBand),
    /// Submitted with the frame and not collected yet.
    Late(Box<LateBand>),
    /// Collecting it failed (the error was returned then).
    Failed,
}

/// A frame's band on its way back through the ring of staging buffers of its
/// [`DeviceDepthKept`] (`src/gpu/readback.rs`), collected when the frame is first planned: a
/// frame planned a pair later, as `Reconstructor::fuse_input` does with frames in flight,
/// finds it there and waits for nothing. Where the frame made more blocks (or slices) than
/// the readback held, the band is listed again from the frame's own depths, in buffers of its
/// own (the kept ones serve the frames made since), and read back whole in one wait.
struct LateBand {
    readback: LateReadback,
    words: LateWords,
    /// The band's uniforms, to list it again.
    uniforms: BandSliceUniforms,
    shared: Arc<BandsShared>,
}

/// What the frames of one [`DeviceDepthKept`] share with it once made: the buffers a second
/// listing uses ([`LateBand`]), and what the last band collected had (slices, or blocks and
/// deferred slices), which sizes the next frames' readbacks.
#[derive(Debug, Default)]
struct BandsShared {
    relist: Mutex<Kept>,
    last: Mutex<[usize; 2]>,
}

/// What a late band's readback fills in.
enum LateWords {
    /// Blocks listed on the device, listed with `params` of [`band_block_params`].
    Listed(BandWords, BandDecoder, (Vec<f64>, [i64; 3])),
    /// Slices, of an output of that many.
    Slices(SliceWords, u64),
}

impl LateBand {
    /// The band, waiting (one counted wait) only where the device has not got there, and a
    /// second time where the frame's band did not fit the readback.
    fn collect(self, ctx: &GpuContext, depth: &wgpu::Buffer) -> Result<FrameBand> {
        let LateBand {
            readback,
            words,
            uniforms,
            shared,
        } = self;
        ctx.poll_finished()?;
        let relist = || shared.relist.lock().unwrap_or_else(|e| e.into_inner());
        let (band, counts) = match words {
            LateWords::Listed(mut words, decoder, (params, base)) => {
                readback.collect(ctx, &mut words.targets())?;
                let band = match decoder.band(&words)? {
                    Some(band) => band,
                    None => {
                        let kept = &mut *relist();
                        let (mut encoder, out) = relist_slices((ctx, kept), &uniforms, depth)?;
                        let listed =
                            record_band_blocks((ctx, kept), &mut encoder, (&params, base), &out)?;
                        let counts = words.counts();
                        listed.submit_and_read_back((ctx, kept), encoder, &out, counts)?
                    }
                };
                let counts = [band.blocks.len(), band.deferred.len()];
                (FrameBand::Listed(band), counts)
            }
            LateWords::Slices(mut words, capacity) => {
                readback.collect(ctx, &mut words.targets())?;
                let slices = match words.slices(capacity)? {
                    Some(slices) => slices,
                    None => {
                        let kept = &mut *relist();
                        let (encoder, out) = relist_slices((ctx, kept), &uniforms, depth)?;
                        out.submit_and_read_back((ctx, kept), encoder, words.count())?
                    }
                };
                let counts = [slices.slices.len(), 0];
                (FrameBand::Slices(slices), counts)
            }
        };
        *shared.last.lock().unwrap_or_else(|e| e.into_inner()) = counts;
        Ok(band)
    }
}

/// The slices of the depths `depth` with `uniforms` recorded again, in buffers of `kept`: the
/// first step of listing a band again ([`LateBand`]).
fn relist_slices(
    (ctx, kept): (&GpuContext, &mut Kept),
    uniforms: &BandSliceUniforms,
    depth: &wgpu::Buffer,
) -> Result<(wgpu::CommandEncoder, BandSliceOutputs)> {
    let mut encoder = ctx.encoder("band_relisted");
    let out = record_band_slices((ctx, kept), &mut encoder, uniforms, depth)?;
    Ok((encoder, out))
}

/// What making depth frames on a device keeps between frames, so that a frame creates no
/// buffer or bind group once the first have sized them and waits for nothing where it is
/// planned after the device got through it: the kernels' buffers and bind groups, the depth
/// buffers of frames dropped already (the reader runs ahead of the fusion, so as many are lent
/// as frames are alive at once), the ring of staging buffers the bands come back through, and
/// how many blocks (or slices) the last band collected had, which sizes the next readbacks.
#[derive(Default)]
pub struct DeviceDepthKept {
    kept: Kept,
    depths: BufferPool,
    ring: ReadbackRing,
    shared: Arc<BandsShared>,
    /// The work of the last frame made, where it is still held (not kept alive here: a frame
    /// dropped drops its work with it, and nothing of it is submitted later).
    held: Option<std::sync::Weak<Mutex<Option<HeldWork>>>>,
}

impl std::fmt::Debug for DeviceDepthKept {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeviceDepthKept")
            .field("shared", &self.shared)
            .finish_non_exhaustive()
    }
}

impl DeviceDepthKept {
    /// Submits the work of the last frame made where it is still held: before anything writes
    /// the buffers it reads for another frame (the frames made here do it first; a matcher
    /// writing its own must call it before).
    pub fn submit_held(&mut self) {
        if let Some(held) = self.held.take().and_then(|h| h.upgrade()) {
            submit_held(&held);
        }
    }

    /// What the next frame's readback holds of each of the two kinds `last` counts: the last
    /// band's and an eighth more, plus `spare`, as neighbouring frames of a drive make about
    /// as many; before any, `first`. Fewer cost the frame a second listing and wait.
    fn expected(&self, spare: [usize; 2], first: [usize; 2]) -> (usize, usize) {
        let [a, b] = *self.shared.last.lock().unwrap_or_else(|e| e.into_inner());
        if a == 0 {
            return (first[0], first[1]);
        }
        (a + a / 8 + spare[0], b + b / 8 + spare[1])
    }
}

/// A camera of the frame's size, its pose and its colour.
pub type CameraView = (PinholeIntrinsics, WorldFromCamera, Option<RgbImage>);

/// The band slices' uniforms of depths of `size` seen by `camera`, for fusion with `fusion`;
/// an error where the size is not the camera's or the device cannot list the band.
fn band_uniforms(
    (grid, params): (&GridParams, &DepthFusionParams),
    camera: &PinholeIntrinsics,
    (w, h): (u32, u32),
) -> Result<BandSliceUniforms> {
    if (camera.width, camera.height) != (w, h) {
        return Err(crate::Error::InvalidArgument(format!(
            "depths of {w}×{h} for a camera of {}×{}",
            camera.width, camera.height
        )));
    }
    band_slice_uniforms(grid, params, w, h)
}

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
    /// recorded after the matcher's work, in buffers of `kept`, and held with it for a later
    /// submit, as [`Self::from_depths`] holds its own; the blocks (or slices) come back later,
    /// collected when the frame is planned ([`LateBand`]).
    pub fn from_on_device(
        d: OnDeviceDisparity,
        fusion: (&GridParams, &DepthFusionParams),
        view: CameraView,
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
        kept.submit_held();
        let band = band_uniforms(fusion, &view.0, (w, h))?;
        let pixels = w as usize * h as usize;
        let to_depth = disparity_depth_uniforms(pixels, view.0.fx, baseline_m)?;
        let made =
            record_disparity_depth((ctx, &mut kept.kept), &mut encoder, &to_depth, disparity)?;
        let frame = Self::listed(ctx, encoder, (fusion, band), view, &made, kept)?;
        Ok(DeviceDepthFrame {
            matched: true,
            ..frame
        })
    }

    /// The frame of depths the host holds (a depth camera's, ground truth, a CPU matcher's),
    /// for fusion into `grid` with `params` on `ctx`: its depths uploaded once (4 bytes per
    /// pixel; the frame keeps a copy on the device for the fusion), its band slices and (with
    /// f64) blocks listed on the device; the band comes back later, as a matched pair's does,
    /// so that the host walks none of its pixels. The work is recorded, not submitted: the
    /// fusion of the frame before takes it into its own submit ([`Self::take_unsubmitted`]),
    /// or the frame submits it alone when first planned or read ([`Self::submit_now`]). Any
    /// depth values go up (NaN, ±∞, zero and negative ones are not usable, as on the host). An
    /// error where the image is not the camera's size or the device cannot list its band (see
    /// [`Self::can_list`]).
    pub fn from_depths(
        ctx: &Arc<GpuContext>,
        fusion: (&GridParams, &DepthFusionParams),
        frame: DepthFrame,
        kept: &mut DeviceDepthKept,
    ) -> Result<Self> {
        let DepthFrame {
            intrinsics,
            world_from_camera,
            depth_m,
            color,
        } = frame;
        let band = band_uniforms(fusion, &intrinsics, (depth_m.width, depth_m.height))?;
        ctx.check_binding("the depth map", depth_m.data.len() as u64 * 4)?;
        kept.submit_held();
        let data = bytemuck::cast_slice(&depth_m.data);
        let sent = kept.kept.storage_with(ctx, "host_depth", data);
        let encoder = ctx.encoder("host_depth_frame");
        let view = (intrinsics, world_from_camera, color);
        Self::listed(ctx, encoder, (fusion, band), view, &sent, kept)
    }

    /// Whether [`Self::from_depths`] takes a frame of `frame`'s size into `grid` with `params`
    /// (its band can be listed on a device): images of 1 to 8 192 pixels a side, the camera's
    /// size, usable depths within [2⁻¹⁷, 2²⁴) m, μ within [2⁻¹⁷, 2²³) m.
    pub fn can_list(frame: &DepthFrame, grid: &GridParams, params: &DepthFusionParams) -> bool {
        let size = (frame.depth_m.width, frame.depth_m.height);
        band_uniforms((grid, params), &frame.intrinsics, size).is_ok()
    }

    /// The frame of the depths `made` (a buffer of `kept`, so that the kernels bind the same
    /// buffers every frame) seen as `view`: its own copy of them (the kernels' buffers serve
    /// the next frame), its band slices and (with f64) band blocks recorded into `encoder` in
    /// buffers of `kept`, and the band's readback through `kept`'s ring: all held in the frame
    /// for a later submit ([`Self::take_unsubmitted`], [`Self::submit_now`]).
    fn listed(
        ctx: &Arc<GpuContext>,
        mut encoder: wgpu::CommandEncoder,
        ((grid, params), band): ((&GridParams, &DepthFusionParams), BandSliceUniforms),
        (intrinsics, world_from_camera, color): CameraView,
        made: &wgpu::Buffer,
        kept: &mut DeviceDepthKept,
    ) -> Result<Self> {
        let bytes = intrinsics.width as u64 * intrinsics.height as u64 * 4;
        let depth = (kept.depths).copy_of(ctx, &mut encoder, "depth", (made, bytes));
        // Slices (12 bytes), or blocks (4) and deferred slices (12): at most 48 KiB before
        // the first band says how many.
        let expected = if ctx.has_f64() {
            kept.expected([256, 64], [8192, 1024])
        } else {
            kept.expected([1024, 0], [4096, 0])
        };
        let DeviceDepthKept {
            kept: buffers,
            ring,
            shared,
            ..
        } = kept;
        let out = record_band_slices((ctx, buffers), &mut encoder, &band, made)?;
        let (readback, words) = if ctx.has_f64() {
            // The blocks listed where the slices are: a few KiB come back.
            let p = band_block_params(grid, &intrinsics, &world_from_camera, out.capacity());
            let listed = record_band_blocks((ctx, buffers), &mut encoder, (&p.0, p.1), &out)?;
            let words = BandWords::new(listed.clamp(expected));
            let readback = ring.record(ctx, &mut encoder, &listed.sources(&out, &words));
            (readback, LateWords::Listed(words, listed.decoder(), p))
        } else {
            let words = SliceWords::new(expected.0.min(out.capacity() as usize));
            let readback = ring.record(ctx, &mut encoder, &out.sources(&words));
            (readback, LateWords::Slices(words, out.capacity()))
        };
        let unsubmitted = Arc::new(Mutex::new(Some(HeldWork {
            ctx: ctx.clone(),
            encoder,
            readback: readback.arm(),
        })));
        kept.held = Some(Arc::downgrade(&unsubmitted));
        let band = FrameBand::Late(Box::new(LateBand {
            readback,
            words,
            uniforms: band,
            shared: shared.clone(),
        }));
        let header = DepthFrame {
            intrinsics,
            world_from_camera,
            depth_m: Image {
                width: intrinsics.width,
                height: intrinsics.height,
                data: Vec::new(),
            },
            color,
        };
        Ok(DeviceDepthFrame {
            header,
            depth,
            ctx: ctx.clone(),
            band: Mutex::new(band),
            made_for: made_for(grid, params),
            matched: false,
            unsubmitted,
        })
    }

    /// [`Self::from_on_device`] for disparities on the host, uploaded first (in a buffer made
    /// for it), the rest in buffers of `kept`.
    pub fn from_disparity(
        ctx: &Arc<GpuContext>,
        fusion: (&GridParams, &DepthFusionParams),
        view: CameraView,
        (disparity, baseline_m): (&DisparityMap, f64),
        kept: &mut DeviceDepthKept,
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
        Self::from_on_device(d, fusion, view, baseline_m, kept)
    }

    /// The camera, pose, colour and size (its `depth_m` holds no data).
    pub fn header(&self) -> &DepthFrame {
        &self.header
    }

    /// Whether a matcher made the depths on the device ([`Self::from_on_device`]), rather than
    /// the host sending them up ([`Self::from_depths`]).
    pub fn matched(&self) -> bool {
        self.matched
    }

    /// The context of the device the depths are on.
    pub fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }

    /// The frame's own work where it is still held, for the caller to submit with its own,
    /// then to call the readback's [`ReadbackArm::submitted`].
    pub(crate) fn take_unsubmitted(&self) -> Option<HeldWork> {
        (self.unsubmitted.lock().unwrap_or_else(|e| e.into_inner())).take()
    }

    /// Whether the band is here or its readback has arrived (as of a poll of the device now):
    /// planning the frame waits for nothing.
    pub fn band_arrived(&self) -> Result<bool> {
        self.ctx.poll_finished()?;
        Ok(
            match &*self.band.lock().unwrap_or_else(|e| e.into_inner()) {
                FrameBand::Late(late) => late.readback.is_ready(),
                _ => true,
            },
        )
    }

    /// Submits the frame's own work where it is still held (no other submit took it).
    pub fn submit_now(&self) {
        submit_held(&self.unsubmitted);
    }

    /// The band, collected first where it is still on its way ([`LateBand`]).
    fn band(&self) -> Result<std::sync::MutexGuard<'_, FrameBand>> {
        self.submit_now();
        let mut band = self.band.lock().unwrap_or_else(|e| e.into_inner());
        if let FrameBand::Late(_) = &*band {
            let FrameBand::Late(late) = std::mem::replace(&mut *band, FrameBand::Failed) else {
                unreachable!("matched above")
            };
            *band = late.collect(&self.ctx, self.depth.buffer())?;
        }
        if let FrameBand::Failed = &*band {
            return Err(crate::Error::Gpu(
                "a depth frame's band could not be read back from the device".into(),
            ));
        }
        Ok(band)
    }

    /// Collects the band where it is on its way: waits (one counted wait) only where the
    /// device has not finished the frame; [`Self::plan`] then waits for nothing.
    pub fn collect_band(&self) -> Result<()> {
        self.band().map(|_| ())
    }

    /// The band slices of the depths, where they came back (a device without f64); collects
    /// the band first where it is on its way.
    pub fn slices(&self) -> Result<Option<BandSlices>> {
        Ok(match &*self.band()? {
            FrameBand::Slices(s) => Some(s.clone()),
            _ => None,
        })
    }

    /// The band as the device listed it, where it did (a device with f64); collects it first
    /// where it is on its way.
    pub fn device_band(&self) -> Result<Option<DeviceBand>> {
        Ok(match &*self.band()? {
            FrameBand::Listed(b) => Some(b.clone()),
            _ => None,
        })
    }

    /// The depths' buffer on the device.
    pub(crate) fn depth_buffer(&self) -> &wgpu::Buffer {
        self.depth.buffer()
    }

    /// The fusion plan of this frame ([`DepthPlan::from_slices`]) into `grid` with `params`,
    /// which must be those its slices were made for; collects the band first where it is on
    /// its way (a counted wait where the device has not finished it).
    pub fn plan(&self, grid: &GridParams, params: &DepthFusionParams) -> Result<DepthPlan> {
        if made_for(grid, params) != self.made_for {
            return Err(crate::Error::InvalidArgument(
                "a depth frame on the device planned with other fusion parameters than its band \
                 slices were made for"
                    .into(),
            ));
        }
        Ok(match &*self.band()? {
            FrameBand::Slices(s) => DepthPlan::from_slices(grid, &self.header, params, s),
            FrameBand::Listed(b) => DepthPlan::from_device_band(grid, &self.header, params, b),
            FrameBand::Late(_) | FrameBand::Failed => unreachable!("collected by band()"),
        })
    }

    /// The frame with its depths read back (counted): what the host would have fused.
    pub fn read_back(&self, ctx: &GpuContext) -> Result<DepthFrame> {
        self.submit_now();
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
