//! Where fusion time goes, per phase (a profiling aid, not a benchmark: `denser bench` and
//! `cargo bench --bench core` hold the figures).
//!
//! `cargo run --release --example fusion_phases [RGBD_DIR] [SYNTH_SEQ]`: depth frames of a
//! numbered RGB-D folder (default `../shared/data/rgbd_5frames_slambook2`) at 10 and 5 cm with
//! μ = 8 voxels (as `denser bench`), then, when a synthetic KITTI sequence is given
//! (`denser synth --lidar-only`), the LiDAR scan of its frame 20 at 10 cm after frames 17–19.

use denser::fusion::*;
use denser::grid::*;
use denser::io::sequence::{open_sequence, RangeInput, RangeSource};
use std::path::PathBuf;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let dir = args.get(1).map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/rgbd_5frames_slambook2")
    });
    let seq = open_sequence(&dir, RangeSource::GroundTruthDepth, None, None)?;
    let frames: Vec<_> = (0..seq.len())
        .filter_map(|i| match seq.read(i) {
            Ok(RangeInput::Depth(f)) => Some(f),
            _ => None,
        })
        .collect();
    let params = DepthFusionParams {
        max_depth_m: 10.0,
        ..Default::default()
    };
    for voxel in [0.10f32, 0.05] {
        let grid = GridParams {
            voxel_size_m: voxel,
            truncation_m: 8.0 * voxel,
        };
        let mut layer = Layer::new(grid);
        let (mut band, mut vis, mut total) = (Vec::new(), Vec::new(), Vec::new());
        let mut last = FusionStats::default();
        for _ in 0..10 {
            for f in &frames {
                let t = Instant::now();
                let plan = DepthPlan::new(&grid, f, &params);
                band.push(t.elapsed().as_secs_f64());
                let t2 = Instant::now();
                let _ = plan.blocks(&layer);
                vis.push(t2.elapsed().as_secs_f64());
                last = integrate_depth_plan(&mut layer, f, &params, &plan).1;
                total.push(t.elapsed().as_secs_f64());
            }
        }
        println!(
            "depth {:.0} cm: plan {:.2} ms, blocks of the plan {:.2} ms, plan + fusion {:.2} ms \
             (medians); last frame {last:?}; {} blocks",
            voxel * 100.0,
            1e3 * median(band),
            1e3 * median(vis),
            1e3 * median(total),
            layer.block_count()
        );
    }
    if let Some(synth) = args.get(2) {
        let seq = open_sequence(std::path::Path::new(synth), RangeSource::Lidar, None, None)?;
        let grid = GridParams::paper(0.1);
        let params = LidarFusionParams::default();
        let mut layer = Layer::new(grid);
        let scan = |k: usize| -> anyhow::Result<denser::frame::LidarScan> {
            match seq.read(k)? {
                RangeInput::Lidar(s) => Ok(s),
                RangeInput::Depth(_) | RangeInput::DeviceDepth(_) => {
                    anyhow::bail!("expected LiDAR")
                }
            }
        };
        for k in 17..20 {
            integrate_lidar(&mut layer, &scan(k)?, &params);
        }
        let s = scan(20)?;
        let (mut plan_s, mut fuse_s, mut ref_s) = (Vec::new(), Vec::new(), Vec::new());
        let mut stats = FusionStats::default();
        let mut pairs = 0;
        for _ in 0..5 {
            let t = Instant::now();
            let plan = LidarPlan::new(&grid, &s, &params);
            plan_s.push(t.elapsed().as_secs_f64());
            pairs = plan.pair_count();
            let mut copy = layer.clone();
            let t = Instant::now();
            stats = integrate_lidar_plan(&mut copy, &plan).1;
            fuse_s.push(t.elapsed().as_secs_f64());
            let t = Instant::now();
            integrate_lidar_reference(&mut copy, &plan);
            ref_s.push(t.elapsed().as_secs_f64());
        }
        println!(
            "lidar 10 cm: plan {:.1} ms, fusion (f32 walk) {:.1} ms, f64 reference walk {:.1} ms \
             (medians); {} rays, {pairs} pairs, {} updates",
            1e3 * median(plan_s),
            1e3 * median(fuse_s),
            1e3 * median(ref_s),
            stats.measurements,
            stats.voxel_updates
        );
    }
    Ok(())
}
