//! A depth frame whose depths stay on the device (`denser::fusion::DeviceDepthFrame`): made
//! there from disparities, planned from its band slices and fused where it is, against the
//! same frame with its depths converted and fused from the host: the same depths, the same plan,
//! the same map, and, once warm, a frame that sends only its colour and offsets up.

use crate::common::{fuse_depth_resident, gpu};
use crate::street::street_frame;
use denser::depth::{disparity_to_depth, DisparityMap};
use denser::frame::{DepthFrame, Image};
use denser::fusion::{
    integrate_device_depth_resident, DepthFusionParams, DepthPlan, DeviceDepthFrame,
    DeviceDepthKept,
};
use denser::gpu::{GpuTraffic, ResidentMap, ResidentOptions};
use denser::grid::{BlockIndex, GridParams, Layer};
use denser::reconstruct::{ReconstructionConfig, Reconstructor};
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// KITTI's stereo baseline, metres.
const BASELINE_M: f64 = 0.537_165_7;

/// The disparities a matcher would find for `frame`'s depths, with holes.
fn disparities_of(frame: &DepthFrame) -> DisparityMap {
    let fb = frame.intrinsics.fx * BASELINE_M;
    let w = frame.depth_m.width as usize;
    let data = (frame.depth_m.data.iter().enumerate())
        .map(|(p, &z)| {
            if (p % w + 3 * (p / w)).is_multiple_of(13) {
                f32::NAN
            } else {
                (fb / z as f64) as f32
            }
        })
        .collect();
    DisparityMap {
        disparity_px: Image {
            width: frame.depth_m.width,
            height: frame.depth_m.height,
            data,
        },
        confidence: None,
    }
}

/// Street frames made on the device from disparities, planned and fused there, against the
/// host's: with the blocks listed on the device (where it has f64) and from the slices.
#[test]
fn a_frame_fused_from_its_depths_on_the_device_is_the_hosts() {
    with_and_without_f64(frames_fused_from_the_device);
}

/// Runs `check` on the GPU without f64 (bands listed from their slices by the host) and, where
/// the device has f64, with it (bands listed on the device); nothing without a GPU.
fn with_and_without_f64(check: impl Fn(Arc<denser::gpu::GpuContext>)) {
    let Some(ctx) = gpu() else { return };
    let f64_too = ctx.has_f64();
    check(Arc::new(ctx.without_f64()));
    if f64_too {
        check(Arc::new(gpu().expect("a GPU")));
    } else {
        crate::common::skip("no f64 on this device: the blocks are listed from the slices");
    }
}

fn frames_fused_from_the_device(ctx: Arc<denser::gpu::GpuContext>) {
    let grid = GridParams::paper(0.1);
    let params = DepthFusionParams::default();
    let new_map = || {
        let mut map =
            ResidentMap::new(ctx.clone(), grid, ResidentOptions::default()).expect("pool");
        map.set_frames_in_flight(true);
        map
    };
    let (mut host_map, mut host_layer) = (new_map(), Layer::new(grid));
    let (mut dev_map, mut dev_layer) = (new_map(), Layer::new(grid));
    let mut steady = 0;
    for k in 0..6u32 {
        let frame = street_frame(0.8 * k as f64, k);
        let disparity = disparities_of(&frame);
        let fx = frame.intrinsics.fx;
        let host_frame = DepthFrame {
            depth_m: disparity_to_depth(&disparity, fx, BASELINE_M),
            ..frame.clone()
        };
        fuse_depth_resident(&mut host_map, &mut host_layer, &host_frame, &params).expect("fuse");
        let view = (
            frame.intrinsics,
            frame.world_from_camera,
            frame.color.clone(),
        );
        let made = ctx.traffic();
        let kept = &mut DeviceDepthKept::default();
        let disparity = (&disparity, BASELINE_M);
        let dev = DeviceDepthFrame::from_disparity(&ctx, (&grid, &params), view, disparity, kept)
            .expect("device frame");
        // The band comes back late: made without a wait, collected when asked for.
        assert_eq!(ctx.traffic().since(made).waits, 0);
        let band = dev.device_band().expect("collected");
        let made = ctx.traffic().since(made);
        if ctx.has_f64() {
            // The blocks listed on the device: what comes back is 4 bytes a block (and the
            // slices it could not decide), not the slices (12 bytes each, ~22 k here).
            let band = band.expect("listed on the device");
            assert!(made.readback_bytes <= 64 << 10, "{made:?}");
            assert!(
                band.deferred.len() * 1000 <= band.blocks.len(),
                "{}",
                band.deferred.len()
            );
        }
        let back = dev.read_back(&ctx).expect("read back");
        let bits = |f: &DepthFrame| {
            f.depth_m
                .data
                .iter()
                .map(|d| d.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&back), bits(&host_frame), "frame {k}: depths");
        let plan = dev.plan(&grid, &params).expect("plan");
        let host_plan = DepthPlan::new(&grid, &host_frame, &params);
        assert_eq!(plan.band, host_plan.band, "frame {k}: band");
        assert_eq!(plan.measurements, host_plan.measurements);
        assert!(
            plan.band.len() > 3000,
            "{} blocks: not a street",
            plan.band.len()
        );
        ctx.wait_idle_uncounted().expect("idle");
        let (grows, before) = (dev_map.stats().grows, ctx.traffic());
        let table_writes = dev_map.stats().table_writes;
        integrate_device_depth_resident(&mut dev_map, &mut dev_layer, &dev, &params, (&plan, None))
            .expect("fuse on the device");
        let t = ctx.traffic().since(before);
        let table_writes = dev_map.stats().table_writes - table_writes;
        eprintln!("frame {k}: made with {made:?}, fusion {t:?}");
        if k >= 3 && dev_map.stats().grows == grows {
            // Warm: the colour (3 bytes a pixel) and the blocks' offsets go up, not the depths.
            steady += 1;
            let colour = 3 * frame.depth_m.data.len() as u64;
            assert!(t.upload_bytes <= colour + (64 << 10), "{t:?}");
            assert!(t.readback_bytes <= 64 << 10, "{t:?}");
            assert_eq!((t.submits, t.waits, t.buffers_created), (1, 0, 0), "{t:?}");
            // Its hundreds of new blocks inserted on the device: the host writes at most the
            // released blocks' entries, in one write put in place there.
            assert!(table_writes <= 1, "frame {k}: {table_writes} table writes");
        }
    }
    assert!(steady >= 2, "{steady} warm frames");
    host_map.sync(&mut host_layer).expect("sync");
    dev_map.sync(&mut dev_layer).expect("sync");
    let blocks = host_layer.indices_sorted();
    assert!(blocks.len() > 3000, "{} blocks", blocks.len());
    assert_eq!(dev_layer.indices_sorted(), blocks);
    assert!(blocks.iter().all(|i| dev_layer.get(i) == host_layer.get(i)));
}

/// Frames made ahead of their plans, more of them than the readback ring holds, whose bands
/// outgrow what the last band collected led them to read back: each listed again from its own
/// depths (the kept buffers hold a later frame's by then) and planned as the host plans it.
#[test]
fn frames_made_ahead_with_larger_bands_plan_as_the_host() {
    with_and_without_f64(frames_made_ahead);
}

fn frames_made_ahead(ctx: Arc<denser::gpu::GpuContext>) {
    let grid = GridParams::paper(0.1);
    let params = DepthFusionParams::default();
    let kept = &mut DeviceDepthKept::default();
    let make = |k: u32, patch: bool, kept: &mut DeviceDepthKept| {
        let frame = street_frame(0.8 * k as f64, k);
        let mut disparity = disparities_of(&frame);
        if patch {
            // A 16×16 patch of depths: a band of a few blocks.
            let w = disparity.disparity_px.width as usize;
            for (p, d) in disparity.disparity_px.data.iter_mut().enumerate() {
                if p % w >= 16 || p / w >= 16 {
                    *d = f32::NAN;
                }
            }
        }
        let fx = frame.intrinsics.fx;
        let host = DepthFrame {
            depth_m: disparity_to_depth(&disparity, fx, BASELINE_M),
            ..frame.clone()
        };
        let view = (frame.intrinsics, frame.world_from_camera, None);
        let disparity = (&disparity, BASELINE_M);
        let dev = DeviceDepthFrame::from_disparity(&ctx, (&grid, &params), view, disparity, kept)
            .expect("device frame");
        (host, dev)
    };
    let (host, small) = make(0, true, kept);
    let small_plan = small.plan(&grid, &params).expect("plan");
    assert_eq!(small_plan.band, DepthPlan::new(&grid, &host, &params).band);
    assert!(
        small_plan.band.len() < 64,
        "{} blocks",
        small_plan.band.len()
    );
    let before = ctx.traffic();
    let ahead: Vec<_> = (1..6).map(|k| make(k, false, kept)).collect();
    // Each frame's work held until the next is made (which submits it first); the last's now.
    kept.submit_held();
    let made = ctx.traffic().since(before);
    assert_eq!(
        (made.submits, made.waits),
        (5, 0),
        "made without waiting: {made:?}"
    );
    let before = ctx.traffic();
    for (k, (host, dev)) in ahead.iter().enumerate() {
        let plan = dev.plan(&grid, &params).expect("plan");
        let host_plan = DepthPlan::new(&grid, host, &params);
        assert_eq!(plan.band, host_plan.band, "frame {k}");
        assert_eq!(plan.measurements, host_plan.measurements, "frame {k}");
        assert!(plan.band.len() > 3000, "{} blocks", plan.band.len());
    }
    // Each band listed again (one submit) and read back whole.
    let t = ctx.traffic().since(before);
    eprintln!("{}: five frames planned: {t:?}", ctx.name());
    assert_eq!(t.submits, 5, "{t:?}");
}

/// Depth frames from the host (a street's depths with NaN, ±∞, zero, negative, subnormal and
/// out-of-range values among them) sent up and listed on the device: held for a later submit,
/// then one submit and no wait each, the depths up once and bit for bit, and the plan the host makes of them; a frame that
/// is not its camera's size is refused, naming both sizes.
#[test]
fn a_host_frame_listed_on_the_device_plans_as_the_host() {
    with_and_without_f64(host_frames_listed);
}

fn host_frames_listed(ctx: Arc<denser::gpu::GpuContext>) {
    let grid = GridParams::paper(0.1);
    let params = DepthFusionParams::default();
    let kept = &mut DeviceDepthKept::default();
    let (lo, hi) = (params.min_depth_m, params.max_depth_m);
    let below = |d: f32| f32::from_bits(d.to_bits() - 1);
    let above = |d: f32| f32::from_bits(d.to_bits() + 1);
    let odd = [
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        0.0,
        -0.0,
        -3.0,
        f32::MIN_POSITIVE / 4.0,
        below(lo),
        lo,
        hi,
        above(hi),
        1e30,
    ];
    for k in 0..3u32 {
        let mut frame = street_frame(0.8 * k as f64, k);
        let pixels = frame.depth_m.data.len() as u64;
        for (p, d) in frame.depth_m.data.iter_mut().enumerate() {
            if p % 7 == k as usize {
                *d = odd[(p / 7) % odd.len()];
            }
        }
        assert!(DeviceDepthFrame::can_list(&frame, &grid, &params));
        let before = ctx.traffic();
        let dev = DeviceDepthFrame::from_depths(&ctx, (&grid, &params), frame.clone(), kept)
            .expect("sent up");
        // Recorded, and held for a submit of the caller's (the fusion before it), or its own.
        assert_eq!(ctx.traffic().since(before).submits, 0);
        dev.submit_now();
        let t = ctx.traffic().since(before);
        assert_eq!((t.submits, t.waits), (1, 0), "{t:?}");
        assert!(t.upload_bytes >= 4 * pixels, "{t:?}");
        assert!(t.upload_bytes <= 4 * pixels + (64 << 10), "{t:?}");
        assert!(!dev.matched());
        let plan = dev.plan(&grid, &params).expect("plan");
        let host_plan = DepthPlan::new(&grid, &frame, &params);
        assert_eq!(plan.band, host_plan.band, "frame {k}: band");
        assert_eq!(plan.measurements, host_plan.measurements, "frame {k}");
        assert!(plan.band.len() > 3000, "{} blocks", plan.band.len());
        let bits = |f: &DepthFrame| {
            f.depth_m
                .data
                .iter()
                .map(|d| d.to_bits())
                .collect::<Vec<_>>()
        };
        let back = dev.read_back(&ctx).expect("read back");
        assert_eq!(bits(&back), bits(&frame), "frame {k}: depths");
        assert_eq!(back.color, frame.color);
    }
    // A wall in whole millimetres (a depth camera's), μ four voxels: 2μ is a whole block, so
    // a slice of one depth has about a whole number of pieces. The device counts them in the
    // host's rounding and leaves no slice to the host (it left them all before).
    let mut grid4 = GridParams::paper(0.05);
    grid4.truncation_m = 0.2;
    let mut wall = street_frame(0.0, 0);
    let w = wall.depth_m.width as usize;
    for (p, d) in wall.depth_m.data.iter_mut().enumerate() {
        *d = (2000 + 7 * (p % w / 40)) as f32 / 1000.0;
    }
    let dev = DeviceDepthFrame::from_depths(&ctx, (&grid4, &params), wall.clone(), kept)
        .expect("sent up");
    let plan = dev.plan(&grid4, &params).expect("plan");
    assert_eq!(
        plan.band,
        DepthPlan::new(&grid4, &wall, &params).band,
        "wall"
    );
    assert!(plan.band.len() > 50, "{} blocks", plan.band.len());
    if let Some(band) = dev.device_band().expect("band") {
        assert_eq!(
            band.deferred.len(),
            0,
            "{} blocks listed",
            band.blocks.len()
        );
    }
    // Two frames made before either is planned: the second's upload into the kept buffer
    // submits the first's held work before it, so each lists its own depths.
    let mut frames = [street_frame(0.0, 1), street_frame(1.6, 2)];
    // A street's depths do not change along it: the second street is narrower.
    frames[1].depth_m.data.iter_mut().for_each(|d| *d *= 0.75);
    let send = |f: &DepthFrame, kept: &mut DeviceDepthKept| {
        DeviceDepthFrame::from_depths(&ctx, (&grid, &params), f.clone(), kept).expect("sent up")
    };
    let made = [send(&frames[0], kept), send(&frames[1], kept)];
    for (dev, frame) in made.iter().zip(&frames) {
        let (plan, host) = (
            dev.plan(&grid, &params),
            DepthPlan::new(&grid, frame, &params),
        );
        assert!(
            plan.expect("plan").band == host.band,
            "made ahead: not the host's band"
        );
        let back = dev.read_back(&ctx).expect("read back");
        assert!(back
            .depth_m
            .data
            .iter()
            .zip(&frame.depth_m.data)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
    }
    // A frame dropped before its work was submitted takes the work with it: the frames made
    // after it, around the readback ring and back to its staging buffer, plan as the host.
    drop(send(&frames[1], kept));
    for k in 0..4 {
        let plan = send(&frames[k % 2], kept)
            .plan(&grid, &params)
            .expect("plan");
        let host = DepthPlan::new(&grid, &frames[k % 2], &params);
        assert!(
            plan.band == host.band,
            "after a dropped frame: not the host's band"
        );
    }
    let mut frame = street_frame(0.0, 0);
    frame.depth_m = Image::filled(100, 50, 1.0);
    assert!(!DeviceDepthFrame::can_list(&frame, &grid, &params));
    let refused = DeviceDepthFrame::from_depths(&ctx, (&grid, &params), frame, kept);
    let message = refused.err().expect("refused").to_string();
    assert!(
        message.contains("100×50") && message.contains("1241×376"),
        "{message}"
    );
}

/// Depth frames from the host fused as `reconstruct --depth gt --device gpu` fuses them
/// (`Reconstructor::fuse_input`, frames in flight): each sent up and listed on the device and
/// fused a call later, the same map as of the frames the host planned; once warm, where the
/// device keeps up, a frame in one submit (its fusion, with the next frame's listing riding in
/// it; 546d416 took two), no wait, nothing created, its depths and colour up once (plus 64
/// KiB), at most 64 KiB down.
#[test]
fn host_depth_frames_are_listed_on_the_device_and_fused_a_call_later() {
    use denser::backend::Backend;
    use denser::io::sequence::RangeInput;
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let config = ReconstructionConfig::paper(0.1);
    let options = ResidentOptions {
        initial_blocks: 16384,
        ..Default::default()
    };
    let new = || Reconstructor::in_memory(config, Backend::gpu(ctx.clone(), options));
    let frames: Vec<DepthFrame> = (0..6).map(|k| street_frame(0.8 * k as f64, k)).collect();
    let mut host = new().expect("reconstructor");
    for f in &frames {
        host.fuse_depth(f).expect("fuse");
    }
    host.sync().expect("sync");
    let mut dev = new().expect("reconstructor");
    let mut after_each = Vec::new();
    for (i, f) in frames.iter().enumerate() {
        ctx.wait_idle_uncounted().expect("idle");
        dev.fuse_input(RangeInput::Depth(f.clone())).expect("fuse");
        // The frame before this one fused, this one listed and waiting.
        assert_eq!(dev.frames_total(), i as u64, "after frame {i}");
        after_each.push(dev.gpu_traffic().expect("on a GPU").depth);
    }
    dev.sync().expect("sync");
    assert_eq!(dev.frames_total(), 6);
    assert_same_map(
        host.layer(),
        dev.layer(),
        3000,
        "host frames listed on the device",
    );
    // Frames 4 and 5 sent up and listed, frames 3 and 4 fused.
    let t = after_each[5].since(after_each[3]);
    eprintln!("the last two frames, listed on the device: {t:?}");
    assert_eq!((t.submits, t.waits), (2, 0), "{t:?}");
    assert_eq!((t.buffers_created, t.bind_groups_created), (0, 0), "{t:?}");
    let pixels = frames[0].depth_m.data.len() as u64;
    assert!(t.upload_bytes <= 2 * (7 * pixels + (64 << 10)), "{t:?}");
    if ctx.has_f64() {
        assert!(t.readback_bytes <= 2 * (64 << 10), "{t:?}");
    }
    // A block a frame listed and left empty, listed again by the next, stays in its slot: a
    // block is made at most once per run of consecutive frames whose bands list it (the pool
    // never spilled), where 546d416 released it when its frame was collected and made it again
    // for the next.
    let stats = dev.resident_stats().expect("GPU tier");
    let bands: Vec<HashSet<BlockIndex>> = (frames.iter())
        .map(|f| DepthPlan::new(&config.grid, f, &config.depth_fusion).band)
        .map(|band| band.into_iter().collect())
        .collect();
    let runs: usize = (0..bands.len())
        .map(|k| match k {
            0 => bands[0].len(),
            _ => bands[k].difference(&bands[k - 1]).count(),
        })
        .sum();
    eprintln!("{stats:?}; {runs} runs of bands listing a block");
    assert_eq!(stats.blocks_spilled, 0);
    assert!(stats.empty_blocks_kept > 0, "{stats:?}");
    assert!(stats.blocks_created <= runs as u64, "{stats:?}");
}

/// Real RGB-D frames (`../shared/data/rgbd_5frames_slambook2`: 640×480, depths in mm with
/// holes) fused on the GPU as `reconstruct` fuses them (`fuse_sequence`: each listed on the
/// device in the submit of the frame before's fusion, and fused a call later) make the map of
/// the same frames planned on the host and fused on the same GPU (one submit each).
#[test]
fn real_rgbd_frames_listed_on_the_device_make_the_hosts_map() {
    use denser::backend::Backend;
    use denser::io::sequence::{open_sequence, FrameRange, RangeInput, RangeSource};
    let Some(ctx) = gpu() else { return };
    let Some(dir) = crate::common::shared_data("rgbd_5frames_slambook2") else {
        return;
    };
    let ctx = Arc::new(ctx);
    let seq = open_sequence(&dir, RangeSource::Lidar, None, None).expect("sequence");
    let mut config = ReconstructionConfig::paper(0.05);
    config.grid.truncation_m = 0.2;
    let backend = || Backend::gpu(ctx.clone(), ResidentOptions::default());
    let new = || Reconstructor::in_memory(config, backend()).expect("reconstructor");
    let mut dev = new();
    let frames = FrameRange::ALL.indices(seq.len());
    dev.fuse_sequence(seq.as_ref(), &frames).expect("fusion");
    let mut host = new();
    for i in frames {
        let RangeInput::Depth(frame) = seq.read(i).expect("frame") else {
            panic!("frame {i}: not a depth frame")
        };
        host.fuse_depth(&frame).expect("fuse");
    }
    host.sync().expect("sync");
    assert_eq!((dev.frames_total(), host.frames_total()), (5, 5));
    assert_same_map(host.layer(), dev.layer(), 100, "RGB-D");
    let submits = |rec: &Reconstructor| rec.gpu_traffic().expect("GPU").depth.submits;
    eprintln!("RGB-D, listed on the device: {:?}", dev.gpu_traffic());
    // One submit a frame where the device kept up (the next frame's listing riding in it), two
    // where it was behind, and the first frame's listing alone: no band outgrew its readback
    // (no slice was left to the host).
    let (dev_submits, host_submits) = (submits(&dev), submits(&host));
    assert_eq!(host_submits, 5);
    assert!((6..=10).contains(&dev_submits), "{dev_submits} submits");
}

/// A 320×96 synthetic stereo drive of `frames` pairs written under `dir`, with LiDAR scans
/// where `lidar` (the bag fixture script needs them).
fn small_drive(dir: &Path, frames: usize, lidar: bool) -> PathBuf {
    use denser::synth::{write_drive, CityConfig, DriveConfig, StereoRig};
    let mut drive = DriveConfig {
        city: CityConfig {
            seed: 3,
            length_m: 60.0,
            frame_spacing_m: 1.0,
            max_frames: Some(frames),
            ..Default::default()
        },
        rig: StereoRig::kitti().scaled(320, 96),
        surface: None,
        ..Default::default()
    };
    if !lidar {
        drive.lidar = None;
    }
    write_drive(&drive, dir, false).expect("drive").sequence_dir
}

/// How `fuse_stereo` hands a pair's depths to the fusion.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Depths {
    /// Read back as disparities and converted on the host.
    Host,
    /// Kept on the device, each pair fused by its own call (`Reconstructor::fuse`).
    Device,
    /// Kept on the device, each pair fused by the next call (`Reconstructor::fuse_input`, as
    /// `reconstruct --depth stereo --device gpu` does), the device idle before each call (a
    /// device that keeps up).
    InFlight,
}

/// The stereo input `input` matched with `method` (32 disparities) on the GPU of `ctx` and
/// fused there, each pair's depths handed on as `depths` says: the map, and the stereo
/// traffic and the depth frames' after each pair.
fn fuse_stereo(
    ctx: &Arc<denser::gpu::GpuContext>,
    input: &Path,
    method: denser::depth::StereoMethod,
    depths: Depths,
) -> (Reconstructor, Vec<(GpuTraffic, GpuTraffic)>) {
    let on_device = depths != Depths::Host;
    use denser::backend::Backend;
    use denser::depth::tgv::HoleFill;
    use denser::depth::SgmParams;
    use denser::io::sequence::{open_input, InputOptions, RangeInput, RangeSource};
    let config = ReconstructionConfig::paper(0.1);
    let backend = Backend::gpu(ctx.clone(), ResidentOptions::default());
    let sgm = SgmParams {
        num_disparities: 32,
        ..Default::default()
    };
    let matcher = backend
        .stereo_matcher(method, sgm, HoleFill::None)
        .expect("matcher");
    assert!(backend.keeps_depth_on_device());
    let mut options = InputOptions::new(RangeSource::Stereo);
    if on_device {
        options.depth_on_device = Some((config.grid, config.depth_fusion));
    }
    let seq = open_input(input, &options, Some(matcher)).expect("sequence");
    let mut rec = Reconstructor::in_memory(config, backend).expect("reconstructor");
    let mut after_each = Vec::new();
    for i in 0..seq.len() {
        let pair = seq.read(i).expect("pair");
        assert_eq!(matches!(pair, RangeInput::DeviceDepth(_)), on_device);
        let frames = rec.frames_total();
        if depths == Depths::InFlight {
            ctx.wait_idle_uncounted().expect("idle");
            rec.fuse_input(pair).expect("fuse");
            // The pair before this one fused, this one waiting.
            assert_eq!(rec.frames_total(), i as u64, "after pair {i}");
        } else {
            rec.fuse(&pair).expect("fuse");
            assert_eq!(rec.frames_total(), frames + 1);
        }
        let traffic = rec.gpu_traffic().expect("on a GPU");
        after_each.push((traffic.stereo, traffic.depth));
    }
    rec.sync().expect("sync");
    (rec, after_each)
}

/// Whether two maps hold the same blocks with the same voxels (and more than `least`).
fn assert_same_map(a: &Layer, b: &Layer, least: usize, what: &str) {
    let blocks = a.indices_sorted();
    assert!(blocks.len() > least, "{what}: {} blocks", blocks.len());
    assert_eq!(b.indices_sorted(), blocks, "{what}");
    assert!(blocks.iter().all(|i| a.get(i) == b.get(i)), "{what}");
}

/// A stereo drive read with GPU SGM and fused on the same GPU, its depths kept on the device
/// or read back as disparities: the same map, and a pair that reads back its band's blocks
/// instead of its disparities and confidences (after warm-up in one submit and one wait,
/// creating nothing), and a frame that sends its colour up but no depths.
#[test]
fn a_stereo_drive_keeps_its_depths_on_the_device_and_makes_the_same_map() {
    use denser::depth::StereoMethod;
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let dir = tempfile::tempdir().expect("tempdir");
    let input = small_drive(dir.path(), 5, false);
    let (w, h) = (320u64, 96u64);
    for method in [StereoMethod::Sgm, StereoMethod::TgvTensor] {
        let (host, _) = fuse_stereo(&ctx, &input, method, Depths::Host);
        let (dev, after_each) = fuse_stereo(&ctx, &input, method, Depths::Device);
        assert_same_map(host.layer(), dev.layer(), 300, &format!("{method:?}"));
        // Once three pairs have sized the kept buffers and made the readback's ring: a pair
        // fused by its own call is one submit and one wait (for its band), and creates nothing.
        let t = after_each[4].0.since(after_each[2].0);
        eprintln!("{method:?}, the last two pairs: {t:?}");
        assert_eq!((t.submits, t.waits), (2, 2), "{method:?}: {t:?}");
        if ctx.has_f64() {
            // The blocks come back (~7 k a pair here, 4 bytes each), not the slices.
            assert!(t.readback_bytes <= 2 * (64 << 10), "{method:?}: {t:?}");
        }
        let created = (t.buffers_created, t.bind_groups_created);
        assert_eq!(created, (0, 0), "{method:?}: {t:?}");
        let (host_traffic, dev_traffic) = (
            host.gpu_traffic().expect("GPU"),
            dev.gpu_traffic().expect("GPU"),
        );
        // Per pair: the two grey images up; the map's 8 bytes per pixel no longer come back.
        let pairs = dev_traffic.stereo_pairs;
        assert_eq!(pairs, 5);
        let (up, down) = (
            dev_traffic.stereo.upload_bytes,
            dev_traffic.stereo.readback_bytes,
        );
        assert!(up / pairs <= 2 * w * h + (64 << 10), "{dev_traffic:?}");
        assert!(host_traffic.stereo.readback_bytes / pairs >= 8 * w * h);
        assert!(down / pairs < 4 * w * h, "{dev_traffic:?}");
        // Per frame: no depths up (4 bytes per pixel), only the colour (3) and the offsets.
        let frames = dev_traffic.depth_frames;
        let (dev_up, host_up) = (
            dev_traffic.depth.upload_bytes,
            host_traffic.depth.upload_bytes,
        );
        assert_eq!(host_up - dev_up, frames * 4 * w * h, "{dev_traffic:?}");
    }
}

/// A stereo drive whose pairs are fused a call later, as `reconstruct` fuses them: the map of
/// the pairs read back, and, where the device keeps up, a warm pair that waits for nothing
/// (its band collected when the next pair comes) and costs one submit, its matching and
/// listing riding in the pair before's fusion (546d416: two, the pair's and the fusion's),
/// creating nothing.
#[test]
fn a_stereo_pair_fused_a_call_later_waits_for_no_band() {
    use denser::depth::StereoMethod;
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let dir = tempfile::tempdir().expect("tempdir");
    let input = small_drive(dir.path(), 6, false);
    let (host, _) = fuse_stereo(&ctx, &input, StereoMethod::Sgm, Depths::Host);
    let (dev, after_each) = fuse_stereo(&ctx, &input, StereoMethod::Sgm, Depths::InFlight);
    assert_same_map(host.layer(), dev.layer(), 300, "in flight");
    // Pairs 4 and 5 read, pairs 3 and 4 collected (the ring's staging buffers made by then).
    let (stereo, depth) = (
        after_each[5].0.since(after_each[3].0),
        after_each[5].1.since(after_each[3].1),
    );
    eprintln!("the last two pairs, fused a call later: {stereo:?}, their fusion {depth:?}");
    let t = stereo.plus(depth);
    assert_eq!((t.submits, t.waits), (2, 0), "{t:?}");
    assert_eq!((t.buffers_created, t.bind_groups_created), (0, 0), "{t:?}");
    if ctx.has_f64() {
        assert!(stereo.readback_bytes <= 2 * (64 << 10), "{stereo:?}");
    }
    assert!(stereo.readback_bytes > 0, "the bands came back: {stereo:?}");
}

/// A ROS 2 bag's stereo pairs (`tools/make_input_fixtures.py` writes a synthetic drive's as a
/// bag) keep their depths on the device as a KITTI layout's do, and make the map their depths
/// read back make.
#[test]
fn a_stereo_bag_keeps_its_depths_on_the_device() {
    use crate::common::skip;
    use denser::depth::StereoMethod;
    let Some(ctx) = gpu() else { return };
    let ctx = Arc::new(ctx);
    let dir = tempfile::tempdir().expect("tempdir");
    let input = small_drive(&dir.path().join("drive"), 2, true);
    let out = dir.path().join("fixtures");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/make_input_fixtures.py");
    let made = std::process::Command::new("python3")
        .arg(&script)
        .arg(&input)
        .arg(&out)
        .args(["--frames", "2"])
        .output();
    match made {
        Ok(o) if o.status.success() => {}
        Ok(o) if o.status.code() == Some(3) => {
            let why = String::from_utf8_lossy(&o.stderr);
            return skip(&format!("no bag: {}", why.trim()));
        }
        Ok(o) => panic!(
            "the fixture script failed: {}",
            String::from_utf8_lossy(&o.stderr)
        ),
        Err(e) => return skip(&format!("python3 cannot run ({e}): no bag")),
    }
    let bag = out.join("bag_stereo");
    let (host, _) = fuse_stereo(&ctx, &bag, StereoMethod::Sgm, Depths::Host);
    let (dev, after_each) = fuse_stereo(&ctx, &bag, StereoMethod::Sgm, Depths::InFlight);
    assert_eq!(after_each.len(), 2);
    assert_same_map(host.layer(), dev.layer(), 100, "bag");
}
