//! Renders one frame of the synthetic city at KITTI resolution, times it, and saves the left image.
//!
//! `cargo run --release --example synth_render -- [OUT.png] [FRAME] [SEED] [SUPERSAMPLING]`

use denser::synth::{City, CityConfig, LidarConfig, RenderOptions, StereoRig};
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let out = args
        .get(1)
        .cloned()
        .unwrap_or_else(|| "synth_left.png".into());
    let frame: usize = args.get(2).map_or(Ok(40), |s| s.parse())?;
    let seed: u64 = args.get(3).map_or(Ok(7), |s| s.parse())?;
    let ss: u32 = args.get(4).map_or(Ok(1), |s| s.parse())?;
    let t = Instant::now();
    let city = City::generate(&CityConfig {
        seed,
        length_m: 400.0,
        ..Default::default()
    })?;
    println!(
        "city: {} primitives, {} frames, built in {:.2} s",
        city.primitives().len(),
        city.frame_poses().len(),
        t.elapsed().as_secs_f64()
    );
    let rig = StereoRig::kitti();
    let opts = RenderOptions {
        supersampling: ss,
        ..Default::default()
    };
    let pose = city.frame_poses()[frame.min(city.frame_poses().len() - 1)];
    let lidar = LidarConfig::default();
    let n = 3;
    let mut last = None;
    let t = Instant::now();
    for i in 0..n {
        let f = city.render_stereo(&pose, &rig, &opts, city.frame_seed(i));
        last = Some(f);
    }
    let stereo_s = t.elapsed().as_secs_f64() / n as f64;
    let t = Instant::now();
    let scan = city.scan_lidar(&pose, &lidar, 1);
    let lidar_s = t.elapsed().as_secs_f64();
    println!(
        "stereo pair + depth {:.3} s, lidar {:.3} s ({} points); {:.2} frames/s with lidar",
        stereo_s,
        lidar_s,
        scan.points_sensor_m.len(),
        1.0 / (stereo_s + lidar_s)
    );
    if let Some(f) = last {
        let img = image::RgbImage::from_raw(
            f.left_rgb.width,
            f.left_rgb.height,
            f.left_rgb.data.iter().flatten().copied().collect(),
        )
        .ok_or_else(|| anyhow::anyhow!("bad image size"))?;
        img.save(&out)?;
        let valid = f.depth_gt_m.data.iter().filter(|d| d.is_finite()).count();
        println!(
            "saved {out}; {:.1} % pixels with depth",
            100.0 * valid as f64 / f.depth_gt_m.data.len() as f64
        );
    }
    Ok(())
}
