//! Times every stage of the stereo matchers on one rectified pair (median of N runs, wall and
//! process CPU time), for profiling between benchmark runs.
//!
//! Run: `cargo run --release --example stereo_stages -- LEFT RIGHT [RUNS] [NUM_DISPARITIES]`
//! (default: KITTI 00 frame 0 from ../shared/data, 9 runs, 128 disparities). `PATHS=4|5|8`
//! picks the SGM aggregation directions; `ONLY=sgm|tgv` times one matcher only;
//! `LR_MAX_DIFF=2 UNIQUENESS=0` times the looser selection of `denser stereo --sgm-lr-max-diff 2
//! --sgm-uniqueness 0`.
use denser::depth::census::census_transform;
use denser::depth::sgm::{
    aggregate_paths, median_filter_3x3, remove_speckles, select_disparities, CostVolume,
    SgmMatcher, SgmParams, SgmPaths,
};
use denser::depth::tgv::{
    box_filtered_costs, decoupling_search, diffusion_tensors, fill_from_background, Regularizer,
    TgvMatcher, TgvParams, TgvProblem,
};
use denser::depth::DisparityEstimator;
use std::time::Instant;

fn cpu_s() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

fn time<T>(name: &str, runs: usize, mut f: impl FnMut() -> T) -> T {
    let mut wall = Vec::new();
    let mut cpu = Vec::new();
    let mut out = None;
    for _ in 0..runs {
        let (t, c) = (Instant::now(), cpu_s());
        out = Some(f());
        wall.push(t.elapsed().as_secs_f64() * 1e3);
        cpu.push((cpu_s() - c) * 1e3);
    }
    wall.sort_by(f64::total_cmp);
    cpu.sort_by(f64::total_cmp);
    println!(
        "{name:<34} wall median {:7.1} ms (min {:7.1})  cpu median {:7.1} ms",
        wall[runs / 2],
        wall[0],
        cpu[runs / 2]
    );
    out.expect("at least one run")
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let d = "../shared/data/kitti_odom00_frames000-005/sequences/00";
    let left = args
        .get(1)
        .cloned()
        .unwrap_or(format!("{d}/image_0/000000.png"));
    let right = args
        .get(2)
        .cloned()
        .unwrap_or(format!("{d}/image_1/000000.png"));
    let runs: usize = args.get(3).and_then(|v| v.parse().ok()).unwrap_or(9);
    let nd: usize = args.get(4).and_then(|v| v.parse().ok()).unwrap_or(128);
    let l = denser::io::image::read_grey(&left).expect("left image");
    let r = denser::io::image::read_grey(&right).expect("right image");
    println!("{}×{}, {nd} disparities, {runs} runs", l.width, l.height);
    // PATHS=4|5|8: the aggregation directions (default: the library's).
    let paths = match std::env::var("PATHS").as_deref() {
        Ok("4") => SgmPaths::Four,
        Ok("5") => SgmPaths::Five,
        Ok("8") => SgmPaths::Eight,
        _ => SgmParams::default().paths,
    };
    println!("{paths:?} paths");
    // LR_MAX_DIFF=N|off and UNIQUENESS=r: the looser selection that `denser stereo` offers
    // for benchmarks counting missing pixels (default: the library's).
    let defaults = SgmParams::default();
    let lr_max_diff_px = match std::env::var("LR_MAX_DIFF").as_deref() {
        Ok("off") => None,
        Ok(v) => Some(v.parse().expect("LR_MAX_DIFF: pixels or off")),
        Err(_) => defaults.lr_max_diff_px,
    };
    let uniqueness_ratio = std::env::var("UNIQUENESS")
        .map(|v| v.parse().expect("UNIQUENESS: a ratio"))
        .unwrap_or(defaults.uniqueness_ratio);
    let sp = SgmParams {
        num_disparities: nd,
        paths,
        lr_max_diff_px,
        uniqueness_ratio,
        ..defaults
    };
    println!("LR check {lr_max_diff_px:?} px, uniqueness {uniqueness_ratio}");
    let sgm = SgmMatcher::new(sp).expect("parameters");
    // ONLY=sgm|tgv: one estimate and nothing else (for instruction counts under callgrind).
    match std::env::var("ONLY").as_deref() {
        Ok("sgm") => {
            time("sgm estimate (pooled buffers)", runs, || {
                sgm.estimate(&l, &r).expect("sgm")
            });
            return;
        }
        Ok("tgv") => {
            let tgv = TgvMatcher::new(TgvParams {
                sgm: sp,
                ..TgvParams::default()
            })
            .expect("parameters");
            time("tgv-tensor estimate (pooled buffers)", runs, || {
                tgv.estimate(&l, &r).expect("tgv")
            });
            return;
        }
        _ => {}
    }
    let cl = time("census (one image)", runs, || {
        census_transform(&l, &sp.census).expect("census")
    });
    let cr = census_transform(&r, &sp.census).expect("census");
    time("cost volume from census", runs, || {
        CostVolume::from_census(&cl, &cr, 0, nd).expect("volume")
    });
    let volume = time("census + cost volume", runs, || {
        sgm.cost_volume(&l, &r).expect("volume")
    });
    let sum = time("aggregate paths", runs, || {
        aggregate_paths(&volume, &l, &sp).expect("aggregate")
    });
    time("select (WTA, LR, sub-pixel)", runs, || {
        select_disparities(&sum, Some(&volume), l.width, l.height, &sp).expect("select")
    });
    drop(sum);
    let init = time("sgm from volume", runs, || {
        sgm.estimate_from_volume(&l, &volume).expect("sgm")
    });
    let mut filtered = init.disparity_px.clone();
    time("median 3x3", runs, || median_filter_3x3(&init.disparity_px));
    time("speckles", runs, || {
        remove_speckles(
            &mut filtered,
            sp.speckle_max_size_px,
            sp.speckle_max_diff_px,
        )
    });
    time("sgm whole", runs, || sgm.estimate(&l, &r).expect("sgm"));
    time("box filter 5x5", runs, || box_filtered_costs(&volume, 5));
    let u0 = fill_from_background(&init.disparity_px, 0.0);
    time("point-wise search (θ 0.2)", runs, || {
        decoupling_search(&volume, 5, &u0, 0.5, 0.2).expect("search")
    });
    let tensors = time("tensors", runs, || diffusion_tensors(&l, 4.0, 1.0));
    let (w, h) = (l.width as usize, l.height as usize);
    let mut pb =
        TgvProblem::new(&u0, w, h, Regularizer::TgvTensor, 1.0, 5.0, tensors).expect("problem");
    time("10 TGV-tensor iterations", runs, || {
        pb.iterate(&u0, 0.1, 10).expect("iterate")
    });
    let tgv = TgvMatcher::new(TgvParams {
        sgm: sp,
        ..TgvParams::default()
    })
    .expect("parameters");
    time("tgv-tensor refine", runs, || {
        tgv.refine(&l, &volume, &init).expect("refine")
    });
    time("tgv-tensor whole", runs, || {
        tgv.estimate(&l, &r).expect("tgv")
    });
}
