//! Stereo ablation on the real pairs under ../shared/data: SGM, the dense variational result and
//! the final map (invalid pixels marked) for one regularizer, on Middlebury 2014 Motorcycle (bad-2
//! over all and non-occluded GT pixels, missing = bad) and KITTI 00 frame 0 vs its projected LiDAR
//! (D1, EPE, density). Parameters from the environment (defaults = `TgvParams::default()`):
//! `REG=tv|tgv|tgv-tensor DATA=mb,kitti LAMBDA A1 A2 GAMMA BETA WIN OUTER INNER T0 T1 MAXC OCC`,
//! and the SGM stage's `PATHS P1 P2 UNIQ LR MEDIAN SPK SPKD` (see `sgm_params`).
//! Run: `REG=tgv-tensor DATA=mb,kitti cargo run --release --example stereo_ablation`.
use denser::depth::metrics::mask_from_middlebury;
use denser::depth::sgm::SgmPaths;
use denser::depth::tgv::{HoleFill, Regularizer, TgvMatcher, TgvParams};
use denser::depth::{disparity_from_points, evaluate_disparity, SgmParams};
use denser::io::kitti::KittiSequence;
fn env<T: std::str::FromStr>(k: &str, d: T) -> T {
    std::env::var(k)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(d)
}
/// The SGM stage: the defaults with `PATHS=4|5|8 P1 P2 UNIQ LR (px, < 0 off) MEDIAN=0|1 SPK
/// SPKD` from the environment.
fn sgm_params(nd: usize) -> SgmParams {
    let d = SgmParams::default();
    let lr: i64 = env("LR", d.lr_max_diff_px.map_or(-1, i64::from));
    SgmParams {
        num_disparities: nd,
        paths: match env("PATHS", 0u32) {
            4 => SgmPaths::Four,
            5 => SgmPaths::Five,
            8 => SgmPaths::Eight,
            _ => d.paths,
        },
        p1: env("P1", d.p1),
        p2: env("P2", d.p2),
        uniqueness_ratio: env("UNIQ", d.uniqueness_ratio),
        lr_max_diff_px: u32::try_from(lr).ok(),
        median_filter: env("MEDIAN", u8::from(d.median_filter)) != 0,
        speckle_max_size_px: env("SPK", d.speckle_max_size_px),
        speckle_max_diff_px: env("SPKD", d.speckle_max_diff_px),
        ..d
    }
}
fn main() {
    let reg = match std::env::var("REG").unwrap_or("tgv-tensor".into()).as_str() {
        "tv" => Regularizer::Tv,
        "tgv" => Regularizer::Tgv,
        _ => Regularizer::TgvTensor,
    };
    let mk = |nd: usize| {
        TgvMatcher::new(TgvParams {
            regularizer: reg,
            lambda: env("LAMBDA", 0.5),
            alpha1: env("A1", 1.0),
            alpha2: env("A2", 5.0),
            gamma: env("GAMMA", 4.0),
            beta: env("BETA", 1.0),
            cost_window: env("WIN", 5),
            outer_iterations: env("OUTER", 4),
            inner_iterations: env("INNER", 10),
            theta_start: env("T0", 0.2),
            theta_end: env("T1", 0.02),
            max_cost_fraction: env("MAXC", 0.35),
            occlusion_tolerance_px: env("OCC", 0.5),
            hole_fill: match std::env::var("FILL").as_deref() {
                Ok("none") => HoleFill::None,
                Ok("all") => HoleFill::All,
                _ => HoleFill::Visible,
            },
            sgm: sgm_params(nd),
        })
        .unwrap()
    };
    let which = std::env::var("DATA").unwrap_or("mb".into());
    let mb_dir = std::path::Path::new(
        "../shared/data/middlebury2014_motorcycle_Q_sttr/trainingQ/Motorcycle",
    );
    let kitti_dir = std::path::Path::new("../shared/data/kitti_odom00_frames000-005/sequences/00");
    if !mb_dir.is_dir() || !kitti_dir.is_dir() {
        eprintln!("../shared/data is missing: nothing to measure");
        return;
    }
    if which.contains("mb") {
        let dir = std::path::Path::new(
            "../shared/data/middlebury2014_motorcycle_Q_sttr/trainingQ/Motorcycle",
        );
        let l = denser::io::image::read_grey(dir.join("im0.png")).unwrap();
        let r = denser::io::image::read_grey(dir.join("im1.png")).unwrap();
        let gt = denser::io::pfm::read_pfm(dir.join("disp0GT.pfm")).unwrap();
        let nocc_png = image::open(dir.join("mask0nocc.png")).unwrap().to_luma8();
        let nocc = mask_from_middlebury(&denser::frame::Image {
            width: nocc_png.width(),
            height: nocc_png.height(),
            data: nocc_png.into_raw(),
        });
        let t = std::time::Instant::now();
        let st = mk(70).estimate_with_stages(&l, &r).unwrap();
        let dt = t.elapsed().as_secs_f64();
        let dense = denser::frame::Image {
            width: l.width,
            height: l.height,
            data: st.dense_px.clone(),
        };
        for (name, d) in [
            ("sgm", &st.sgm.disparity_px),
            ("dense", &dense),
            ("final", &st.result.disparity_px),
        ] {
            let a = evaluate_disparity(d, &gt, None).unwrap();
            let n = evaluate_disparity(d, &gt, Some(&nocc)).unwrap();
            println!("MB {name:6} all bad2 {:.2} bad1 {:.2} epe {:.3} dens {:.1} | nocc bad2 {:.2} epe {:.3}", a.bad2_pct, a.bad1_pct, a.epe_px, a.density_pct, n.bad2_pct, n.epe_px);
        }
        println!("MB time {dt:.2}s");
    }
    if which.contains("kitti") {
        let seq = KittiSequence::open(
            "../shared/data/kitti_odom00_frames000-005/sequences/00",
            None,
        )
        .unwrap();
        let (l, r) = (seq.grey(0, 0).unwrap(), seq.grey(1, 0).unwrap());
        let k = seq.intrinsics(0).unwrap();
        let b = seq.calib().baseline_m(0, 1);
        let scan = seq.velodyne(0).unwrap();
        let c = seq.calib().cam_from_velo(0);
        let pts: Vec<[f64; 3]> = scan
            .points_sensor_m
            .iter()
            .map(|p| {
                let q = c * nalgebra::Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                [q.x, q.y, q.z]
            })
            .collect();
        let gt = disparity_from_points(&pts, &k, b);
        let t = std::time::Instant::now();
        let st = mk(128).estimate_with_stages(&l, &r).unwrap();
        let dt = t.elapsed().as_secs_f64();
        let dense = denser::frame::Image {
            width: l.width,
            height: l.height,
            data: st.dense_px.clone(),
        };
        for (name, d) in [
            ("sgm", &st.sgm.disparity_px),
            ("dense", &dense),
            ("final", &st.result.disparity_px),
        ] {
            let m = evaluate_disparity(d, &gt, None).unwrap();
            println!(
                "KITTI {name:6} bad2 {:.2} D1 {:.2} EPE {:.3} dens {:.1} bad3 {:.2}",
                m.bad2_pct, m.d1_pct, m.epe_px, m.density_pct, m.bad3_pct
            );
        }
        println!("KITTI time {dt:.2}s");
    }
}
