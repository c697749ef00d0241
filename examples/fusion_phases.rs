#[path = "../tests/common/mod.rs"]
mod common;
use common::*;
use denser::fusion::*;
use denser::grid::*;
use std::time::Instant;
fn main() {
    let scene = SphereScene {
        center: [0.0, 0.0, 0.0],
        radius: 1.0,
        floor_y: 1.0,
    };
    let mut rng = Rng(1);
    let frames: Vec<_> = orbit(8, 3.0, -1.2, scene.center)
        .into_iter()
        .map(|p| scene.render(&vga(), p, 0.005, 8.0, &mut rng))
        .collect();
    let grid = GridParams {
        voxel_size_m: 0.1,
        truncation_m: 0.8,
    };
    let mut layer = Layer::new(grid);
    for f in &frames {
        integrate_depth(&mut layer, f, &DepthFusionParams::default());
    }
    let p = DepthFusionParams::default();
    for _ in 0..1 {
        let t = Instant::now();
        let mut n = 0;
        for _ in 0..2 {
            n = depth_frame_blocks(&grid, &frames[0], &p).len();
        }
        let a = t.elapsed().as_secs_f64() / 2.0 * 1e3;
        let t = Instant::now();
        let mut m = 0;
        for _ in 0..2 {
            m = visible_blocks(&layer, &frames[0], &p).len();
        }
        let b = t.elapsed().as_secs_f64() / 2.0 * 1e3;
        let t = Instant::now();
        let mut st = FusionStats::default();
        for _ in 0..2 {
            st = integrate_depth(&mut layer, &frames[0], &p).1;
        }
        let c = t.elapsed().as_secs_f64() / 2.0 * 1e3;
        println!("band {a:.2} ms ({n} blocks), visible {b:.2} ms ({m}), total {c:.2} ms, {:?}, layer {} blocks", st, layer.block_count());
    }
}
