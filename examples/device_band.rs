//! The band of real depth frames listed on the GPU (`DeviceDepthFrame::from_depths`): for each
//! frame of an RGB-D sequence, at three voxel sizes with μ = 4 voxels, the blocks the device
//! listed, the slices it left to the host, the bytes read back, submits and waits, and whether
//! the plan equals the host's (`DepthPlan::new`). Skips without a GPU adapter.
//!
//!   cargo run --release --example device_band -- [RGBD_DIR]
//!
//! (default `../shared/data/rgbd_5frames_slambook2`; `docs/bench/gpu.md`).

use denser::fusion::{DepthPlan, DeviceDepthFrame, DeviceDepthKept};
use denser::gpu::GpuContext;
use denser::io::sequence::{open_sequence, RangeInput, RangeSource};
use denser::reconstruct::ReconstructionConfig;
use std::sync::Arc;

fn main() -> anyhow::Result<()> {
    let dir = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "../shared/data/rgbd_5frames_slambook2".into());
    let Some(ctx) = GpuContext::new()? else {
        println!("no GPU adapter: nothing to list");
        return Ok(());
    };
    let ctx = Arc::new(ctx);
    println!("{dir} on {}", ctx.name());
    let seq = open_sequence(std::path::Path::new(&dir), RangeSource::Lidar, None, None)?;
    for voxel_m in [0.02f32, 0.05, 0.1] {
        let mut config = ReconstructionConfig::paper(voxel_m);
        config.grid.truncation_m = 4.0 * voxel_m;
        let fusion = (&config.grid, &config.depth_fusion);
        let mut kept = DeviceDepthKept::default();
        for i in 0..seq.len() {
            let RangeInput::Depth(frame) = seq.read(i)? else {
                anyhow::bail!("frame {i} is not a depth frame");
            };
            let host = DepthPlan::new(fusion.0, &frame, fusion.1);
            let before = ctx.traffic();
            let dev = DeviceDepthFrame::from_depths(&ctx, fusion, frame, &mut kept)?;
            let plan = dev.plan(fusion.0, fusion.1)?;
            let t = ctx.traffic().since(before);
            let (blocks, deferred) = match dev.device_band()? {
                Some(b) => (b.blocks.len(), b.deferred.len()),
                None => (0, 0),
            };
            println!(
                "voxel {voxel_m} m, frame {i}: {} band blocks, {blocks} listed by the device, \
                 {deferred} slices left to the host, {} bytes down, {} submits, {} waits, \
                 the host's plan: {}",
                host.band.len(),
                t.readback_bytes,
                t.submits,
                t.waits,
                plan.band == host.band && plan.measurements == host.measurements
            );
        }
    }
    Ok(())
}
