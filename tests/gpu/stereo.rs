//! The stereo kernels against their CPU twins (`src/gpu/stereo.rs` vs `src/depth/`): TGV
//! primal–dual iterations, the point-wise decoupling search, census signatures and the cost
//! volume, and the whole variational matcher, on a generated piecewise-planar pair (always) and
//! on Middlebury 2014 Motorcycle (quarter size; skipped when `../shared/data` is absent). Every
//! test skips with a message where no GPU adapter exists (`tools/setup.sh` installs lavapipe).
//!
//! Tolerances (the kernels repeat the CPU's f32 operations in order; lavapipe gives identical
//! results, other GPUs may contract to FMA or divide within 2.5 ULP):
//! - census signatures and cost volumes: equal (integers);
//! - TGV, 50 iterations: |Δu| ≤ 1e-3 px on every pixel, energies within 1e-5 relative; on
//!   llvmpipe the whole state is bit-identical for TV and TGV (identity tensors), while with
//!   the image tensors (TGV-tensor) 1-ulp differences appear (measured: max |Δu| 7.6e-6 px
//!   after 50 iterations on Motorcycle);
//! - point-wise search: |Δa| ≤ 1e-3 px on ≥ 99.9 % of pixels (a near-tie between two slices
//!   may flip on other GPUs); on llvmpipe bit-identical;
//! - whole matcher: ≤ 0.5 % of dense pixels differ by > 0.1 px and bad-2.0 within 0.2 points
//!   on the generated pair, Motorcycle and KITTI 00/0 (its LiDAR scan as ground truth; measured
//!   on llvmpipe: none by > 0.1 px, bad-2.0 equal); with TV bit-identical on llvmpipe.

use crate::common;

use crate::depth_support;
use common::gpu;

use denser::depth::census::{census_transform, CensusKind, CensusParams};
use denser::depth::metrics::mask_from_middlebury;
use denser::depth::sgm::CostVolume;
use denser::depth::tgv::{
    box_filtered_costs, costs_at_disparities, decoupling_search, diffusion_tensors, HoleFill,
    Regularizer, TgvMatcher, TgvParams, TgvProblem,
};
use denser::depth::{
    census_transform_gpu, cost_volume_gpu, costs_at_disparities_gpu, diffusion_tensors_gpu,
    estimate_tgv_gpu, pointwise_search_gpu, window_costs_gpu, DisparityEstimator, DisparityMap,
    TgvMatcherGpu, TgvProblemGpu,
};
use denser::depth::{disparity_from_points, evaluate_disparity, SgmMatcher, SgmParams};
use denser::frame::{GreyImage, Image};
use denser::gpu::GpuContext;
use depth_support::{city_like_planes, piecewise_planar_pair};

/// Whether the adapter is Mesa's llvmpipe, where the kernels are bit-identical to the CPU.
fn is_llvmpipe(ctx: &GpuContext) -> bool {
    ctx.describe().contains("llvmpipe")
}

/// The generated pair: 200×100, city-like planes, noise σ = 4 grey levels.
fn generated_pair() -> (GreyImage, GreyImage, Image<f32>) {
    let (w, h) = (200, 100);
    piecewise_planar_pair(w, h, &city_like_planes(w, h), 4.0)
}

/// Middlebury 2014 Motorcycle (quarter size): left, right, ground truth, non-occlusion mask.
fn motorcycle() -> Option<(GreyImage, GreyImage, Image<f32>, Image<bool>)> {
    let dir = common::shared_data("middlebury2014_motorcycle_Q_sttr/trainingQ/Motorcycle")?;
    let read = |f: &str| denser::io::image::read_grey(dir.join(f)).expect("read image");
    let gt = denser::io::pfm::read_pfm(dir.join("disp0GT.pfm")).expect("read PFM");
    let nocc = mask_from_middlebury(&read("mask0nocc.png"));
    Some((read("im0.png"), read("im1.png"), gt, nocc))
}

fn sgm_params(num_disparities: usize) -> SgmParams {
    SgmParams {
        num_disparities,
        ..SgmParams::default()
    }
}

/// Point-wise winner-take-all over the raw costs: a noisy real coupling target.
fn wta(v: &CostVolume) -> Vec<f32> {
    let n = v.width as usize * v.height as usize;
    (0..n)
        .map(|i| {
            let c = &v.cost[i * v.num_disparities..(i + 1) * v.num_disparities];
            let k = (0..c.len()).min_by_key(|&k| c[k]).unwrap_or(0);
            (k as i32 + v.min_disparity_px) as f32
        })
        .collect()
}

/// Values that differ in their bits, and the largest absolute difference.
fn compare(a: &[f32], b: &[f32]) -> (usize, f32) {
    assert_eq!(a.len(), b.len());
    let differing = a
        .iter()
        .zip(b)
        .filter(|(x, y)| x.to_bits() != y.to_bits())
        .count();
    let max = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max);
    (differing, max)
}

/// Runs `iterations` TGV iterations on the CPU and the GPU from the same problem and compares
/// the whole state and the energy; returns max |Δu|.
fn check_iterate(
    ctx: &GpuContext,
    what: &str,
    initial: &TgvProblem,
    a: &[f32],
    theta: f32,
    iterations: u32,
) -> f32 {
    let mut cpu = initial.clone();
    cpu.iterate(a, theta, iterations).expect("CPU iterate");
    let mut gpu_state = initial.clone();
    let mut g = TgvProblemGpu::upload(ctx, initial).expect("upload");
    g.iterate(a, theta, iterations).expect("GPU iterate");
    g.download(&mut gpu_state).expect("download");
    assert_eq!(g.u().expect("u"), gpu_state.u());
    let (u_cpu, u_gpu) = (cpu.u(), gpu_state.u());
    let (du_bits, du) = compare(&u_cpu, &u_gpu);
    let (pc, bc, dc) = cpu.state();
    let (pg, bg, dg) = gpu_state.state();
    let (p_bits, dp) = compare(pc.as_flattened(), pg.as_flattened());
    let (b_bits, db) = compare(bc.as_flattened(), bg.as_flattened());
    let (d_bits, dd) = compare(dc.as_flattened(), dg.as_flattened());
    let e0 = initial.energy(a, theta).expect("energy");
    let e_cpu = cpu.energy(a, theta).expect("energy");
    let e_gpu = gpu_state.energy(a, theta).expect("energy");
    let moved = compare(&initial.u(), &u_gpu).1;
    eprintln!(
        "{what}: {iterations} iterations on {}×{}: max |Δu| = {du:e} px ({du_bits} values differ), \
         primal {p_bits} differ (max {dp:e}), primal_bar {b_bits} (max {db:e}), dual {d_bits} \
         (max {dd:e}); energy {e0:.6e} -> CPU {e_cpu:.9e}, GPU {e_gpu:.9e} (rel. diff {:e}); \
         u moved up to {moved} px",
        initial.width,
        initial.height,
        ((e_gpu - e_cpu) / e_cpu).abs()
    );
    assert!(du <= 1e-3, "{what}: |Δu| {du}");
    assert!(((e_gpu - e_cpu) / e_cpu).abs() <= 1e-5, "{what}: energies");
    assert!(e_gpu < e0, "{what}: the energy did not decrease");
    assert!(moved > 0.05, "{what}: u barely moved ({moved} px)");
    // With identity tensors (TV, TGV) the kernels are bit-identical on llvmpipe; with the
    // image tensors 1-ulp differences appear in u (Mesa's compiler evaluates some of T p's
    // products differently, e.g. fused), so TGV-tensor is held to the tolerance only.
    if is_llvmpipe(ctx) && initial.regularizer != Regularizer::TgvTensor {
        assert_eq!(
            (p_bits, b_bits, d_bits),
            (0, 0, 0),
            "{what}: not bit-identical on llvmpipe"
        );
    }
    du
}

/// A TGV problem on `left` (tensors from the image for `TgvTensor`) starting at `u0`.
fn problem_on(left: &GreyImage, u0: &[f32], reg: Regularizer) -> TgvProblem {
    let p = TgvParams::default();
    let (w, h) = (left.width as usize, left.height as usize);
    let tensors = match reg {
        Regularizer::TgvTensor => diffusion_tensors(left, p.gamma, p.beta),
        _ => vec![[1.0, 0.0, 1.0]; w * h],
    };
    TgvProblem::new(u0, w, h, reg, p.alpha1, p.alpha2, tensors).expect("problem")
}

#[test]
fn tgv_iterations_match_the_cpu_on_a_generated_pair() {
    let Some(ctx) = gpu() else { return };
    let (left, right, _) = generated_pair();
    let volume = SgmMatcher::new(sgm_params(48))
        .unwrap()
        .cost_volume(&left, &right)
        .unwrap();
    let a = wta(&volume);
    for reg in [Regularizer::TgvTensor, Regularizer::Tgv, Regularizer::Tv] {
        let initial = problem_on(&left, &a, reg);
        check_iterate(&ctx, &format!("generated {reg:?}"), &initial, &a, 0.2, 50);
    }
    // Two calls with different θ continue from the GPU state: 20 + 30 iterations on the GPU
    // equal the same on the CPU.
    let initial = problem_on(&left, &a, Regularizer::TgvTensor);
    let mut cpu = initial.clone();
    cpu.iterate(&a, 0.5, 20).unwrap();
    cpu.iterate(&a, 0.1, 30).unwrap();
    let mut g = TgvProblemGpu::upload(&ctx, &initial).unwrap();
    g.iterate(&a, 0.5, 20).unwrap();
    g.iterate(&a, 0.1, 30).unwrap();
    let (bits, du) = compare(&cpu.u(), &g.u().unwrap());
    eprintln!("θ 0.5 then 0.1: max |Δu| = {du:e} px ({bits} values differ)");
    assert!(du <= 1e-3);
    // And a CPU state continues on the GPU: 25 CPU + 25 GPU = 50 CPU.
    let mut mixed = initial.clone();
    mixed.iterate(&a, 0.2, 25).unwrap();
    let mut g = TgvProblemGpu::upload(&ctx, &mixed).unwrap();
    g.iterate(&a, 0.2, 25).unwrap();
    g.download(&mut mixed).unwrap();
    let mut cpu = initial.clone();
    cpu.iterate(&a, 0.2, 50).unwrap();
    let (bits, du) = compare(&cpu.u(), &mixed.u());
    eprintln!("25 CPU + 25 GPU vs 50 CPU: max |Δu| = {du:e} px ({bits} values differ)");
    assert!(du <= 1e-3);
    // Bad input is an error, not a panic.
    assert!(g.iterate(&a[1..], 0.2, 1).is_err());
    assert!(g.iterate(&a, 0.0, 1).is_err());
}

#[test]
fn tgv_iterations_match_the_cpu_on_middlebury() {
    let Some(ctx) = gpu() else { return };
    let Some((left, right, _, _)) = motorcycle() else {
        return;
    };
    let volume = SgmMatcher::new(sgm_params(70))
        .unwrap()
        .cost_volume(&left, &right)
        .unwrap();
    let a = wta(&volume);
    let initial = problem_on(&left, &a, Regularizer::TgvTensor);
    check_iterate(&ctx, "Motorcycle TgvTensor", &initial, &a, 0.2, 50);
}

/// Compares the point-wise search on both devices; returns (differing pixels, max |Δa|).
fn check_search(ctx: &GpuContext, what: &str, volume: &CostVolume, u: &[f32]) {
    for window in [1, 5] {
        for theta in [0.02, 0.2, 4.0] {
            let cpu = decoupling_search(volume, window, u, 0.5, theta).expect("CPU search");
            let gpu = pointwise_search_gpu(ctx, volume, window, u, 0.5, theta).expect("GPU search");
            let (bits, max) = compare(&cpu, &gpu);
            let far = cpu
                .iter()
                .zip(&gpu)
                .filter(|(c, g)| (*c - *g).abs() > 1e-3)
                .count();
            let moved = compare(u, &gpu).1;
            eprintln!(
                "{what}: window {window}, θ {theta}: {bits} of {} differ (max {max:e} px, \
                 {far} by > 1e-3 px); a moved up to {moved} px from u",
                cpu.len()
            );
            assert!(
                far as f64 <= 1e-3 * cpu.len() as f64,
                "{what}: {far} differ"
            );
            assert!(moved > 0.1, "{what}: the search did nothing");
            if is_llvmpipe(ctx) {
                assert_eq!(bits, 0, "{what}: not bit-identical on llvmpipe");
            }
        }
    }
}

#[test]
fn pointwise_search_matches_the_cpu() {
    let Some(ctx) = gpu() else { return };
    let (left, right, gt) = generated_pair();
    let volume = SgmMatcher::new(sgm_params(48))
        .unwrap()
        .cost_volume(&left, &right)
        .unwrap();
    // u: the ground truth plus a deterministic wobble of up to ±1.5 px.
    let u: Vec<f32> = gt
        .data
        .iter()
        .enumerate()
        .map(|(i, &d)| d + 1.5 * ((i as f32) * 0.37).sin())
        .collect();
    check_search(&ctx, "generated", &volume, &u);
    if let Some((left, right, _, _)) = motorcycle() {
        let volume = SgmMatcher::new(sgm_params(70))
            .unwrap()
            .cost_volume(&left, &right)
            .unwrap();
        let u: Vec<f32> = wta(&volume)
            .iter()
            .enumerate()
            .map(|(i, &d)| d + 0.7 * ((i as f32) * 0.11).cos())
            .collect();
        check_search(&ctx, "Motorcycle", &volume, &u);
    }
    assert!(pointwise_search_gpu(&ctx, &volume, 5, &u[1..], 0.5, 0.2).is_err());
    assert!(pointwise_search_gpu(&ctx, &volume, 4, &u, 0.5, 0.2).is_err());
}

fn check_census(ctx: &GpuContext, what: &str, left: &GreyImage, right: &GreyImage) {
    let kinds = [
        (CensusParams::default(), 0, 64),
        (
            CensusParams {
                window_width: 7,
                window_height: 7,
                kind: CensusKind::Ternary { threshold: 3 },
            },
            -4,
            40,
        ),
        (
            CensusParams {
                window_width: 5,
                window_height: 3,
                kind: CensusKind::Binary,
            },
            3,
            33,
        ),
    ];
    for (census, dmin, nd) in kinds {
        let cpu = census_transform(left, &census).unwrap();
        let gpu = census_transform_gpu(ctx, left, &census).expect("GPU census");
        let differing_sig = cpu
            .data
            .iter()
            .zip(&gpu.data)
            .filter(|(a, b)| a != b)
            .count();
        let sgm = SgmMatcher::new(SgmParams {
            min_disparity_px: dmin,
            num_disparities: nd,
            census,
            ..SgmParams::default()
        })
        .unwrap();
        let v_cpu = sgm.cost_volume(left, right).unwrap();
        let v_gpu = cost_volume_gpu(ctx, left, right, &census, dmin, nd).expect("GPU volume");
        let differing_cost = v_cpu
            .cost
            .iter()
            .zip(&v_gpu.cost)
            .filter(|(a, b)| a != b)
            .count();
        let distinct = v_gpu
            .cost
            .iter()
            .fold([false; 256], |mut seen, &c| {
                seen[c as usize] = true;
                seen
            })
            .iter()
            .filter(|&&s| s)
            .count();
        eprintln!(
            "{what}: {}×{} {:?} d ∈ [{dmin}, {}): {differing_sig} of {} signature words and \
             {differing_cost} of {} costs differ ({distinct} distinct cost values)",
            census.window_width,
            census.window_height,
            census.kind,
            dmin + nd as i32,
            cpu.data.len(),
            v_cpu.cost.len()
        );
        assert_eq!(gpu, cpu, "{what}: census signatures");
        assert_eq!(
            (v_gpu.width, v_gpu.height, v_gpu.min_disparity_px),
            (v_cpu.width, v_cpu.height, v_cpu.min_disparity_px)
        );
        assert_eq!(
            (v_gpu.num_disparities, v_gpu.max_cost),
            (v_cpu.num_disparities, v_cpu.max_cost)
        );
        assert!(v_gpu.cost == v_cpu.cost, "{what}: cost volumes differ");
        assert!(distinct > 10, "{what}: a degenerate volume");
    }
}

#[test]
fn census_and_cost_volume_match_the_cpu() {
    let Some(ctx) = gpu() else { return };
    let (left, right, _) = generated_pair();
    check_census(&ctx, "generated", &left, &right);
    // Odd sizes exercise the packing of bytes into words.
    let crop = |img: &GreyImage| Image {
        width: 37,
        height: 5,
        data: (0..5)
            .flat_map(|y| img.data[y * img.width as usize..][..37].to_vec())
            .collect(),
    };
    check_census(&ctx, "generated 37×5 crop", &crop(&left), &crop(&right));
    if let Some((left, right, _, _)) = motorcycle() {
        check_census(&ctx, "Motorcycle", &left, &right);
    }
    let small = Image::filled(4, 4, 0u8);
    assert!(cost_volume_gpu(&ctx, &left, &small, &CensusParams::default(), 0, 8).is_err());
}

/// The whole matcher on both devices: (pixels differing by > 0.1 px, bad-2.0 CPU, bad-2.0 GPU).
fn check_matcher(
    ctx: &GpuContext,
    what: &str,
    m: &TgvMatcher,
    left: &GreyImage,
    right: &GreyImage,
    gt: &Image<f32>,
) {
    let cpu = m.estimate_with_stages(left, right).expect("CPU");
    let gpu = estimate_tgv_gpu(ctx, m, left, right).expect("GPU");
    assert_eq!(
        cpu.sgm.disparity_px.data.len(),
        gpu.sgm.disparity_px.data.len()
    );
    let sgm_same = cpu
        .sgm
        .disparity_px
        .data
        .iter()
        .zip(&gpu.sgm.disparity_px.data)
        .all(|(a, b)| a.to_bits() == b.to_bits());
    let (bits, max) = compare(&cpu.dense_px, &gpu.dense_px);
    let n = cpu.dense_px.len();
    let far = cpu
        .dense_px
        .iter()
        .zip(&gpu.dense_px)
        .filter(|(c, g)| (*c - *g).abs() > 0.1)
        .count();
    let far_pct = 100.0 * far as f64 / n as f64;
    let dense = |d: &Vec<f32>| Image {
        width: left.width,
        height: left.height,
        data: d.clone(),
    };
    let b_cpu = evaluate_disparity(&cpu.result.disparity_px, gt, None).unwrap();
    let b_gpu = evaluate_disparity(&gpu.result.disparity_px, gt, None).unwrap();
    let d_cpu = evaluate_disparity(&dense(&cpu.dense_px), gt, None).unwrap();
    let d_gpu = evaluate_disparity(&dense(&gpu.dense_px), gt, None).unwrap();
    eprintln!(
        "{what}: SGM init identical: {sgm_same}; dense disparity: {bits} of {n} differ, {far} \
         ({far_pct:.4} %) by > 0.1 px, max {max:e} px; bad-2.0 (all, missing = bad) CPU {:.3} %, \
         GPU {:.3} %; dense bad-2.0 CPU {:.3} %, GPU {:.3} %; density CPU {:.2} %, GPU {:.2} %",
        b_cpu.bad2_pct,
        b_gpu.bad2_pct,
        d_cpu.bad2_pct,
        d_gpu.bad2_pct,
        b_cpu.density_pct,
        b_gpu.density_pct
    );
    assert!(sgm_same, "{what}: the GPU cost volume changed SGM");
    assert!(far_pct <= 0.5, "{what}: {far_pct} % differ by > 0.1 px");
    assert!((b_cpu.bad2_pct - b_gpu.bad2_pct).abs() <= 0.2, "{what}");
    assert!((d_cpu.bad2_pct - d_gpu.bad2_pct).abs() <= 0.2, "{what}");
    // The refinement did real work: it changed SGM's map.
    let changed = cpu
        .dense_px
        .iter()
        .zip(&cpu.sgm.disparity_px.data)
        .filter(|(d, s)| s.is_finite() && (*d - *s).abs() > 0.1)
        .count();
    assert!(
        changed > n / 100,
        "{what}: TGV changed only {changed} pixels"
    );
    if is_llvmpipe(ctx) && m.params.regularizer != Regularizer::TgvTensor {
        assert_eq!(bits, 0, "{what}: not bit-identical on llvmpipe");
    }
}

#[test]
fn the_gpu_matchers_invalidation_equals_the_cpus_for_its_disparities() {
    // The map is made on the device (shaders/tgv_occluded.wgsl, tgv_invalidate.wgsl): given
    // the GPU's own dense disparity and SGM map, the CPU's invalidation gives the same bits, in
    // every hole-filling mode.
    let Some(ctx) = gpu() else { return };
    let (left, right, _) = generated_pair();
    let mut kept_somewhere = [0usize; 3];
    for (k, hole_fill) in [HoleFill::None, HoleFill::Visible, HoleFill::All]
        .into_iter()
        .enumerate()
    {
        let m = TgvMatcher::new(TgvParams {
            sgm: sgm_params(48),
            hole_fill,
            ..TgvParams::default()
        })
        .unwrap();
        let gpu = estimate_tgv_gpu(&ctx, &m, &left, &right).expect("GPU");
        let volume = SgmMatcher::new(m.params.sgm)
            .unwrap()
            .cost_volume(&left, &right)
            .unwrap();
        let costs = costs_at_disparities(&gpu.dense_px, &volume);
        let want = m.invalidate_with(&gpu.dense_px, &gpu.sgm, &costs, volume.shape());
        let bits = |d: &Image<f32>| d.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert!(
            bits(&want.disparity_px) == bits(&gpu.result.disparity_px),
            "{hole_fill:?}: disparities"
        );
        let conf = |d: &DisparityMap| bits(d.confidence.as_ref().expect("confidence"));
        assert!(
            conf(&want) == conf(&gpu.result),
            "{hole_fill:?}: confidences"
        );
        kept_somewhere[k] = want
            .disparity_px
            .data
            .iter()
            .filter(|d| d.is_finite())
            .count();
    }
    eprintln!("valid pixels (none, visible, all): {kept_somewhere:?}");
    // The modes differ here, so each rule was exercised.
    assert!(kept_somewhere[0] < kept_somewhere[1] && kept_somewhere[1] < kept_somewhere[2]);
}

#[test]
fn tgv_matcher_on_the_gpu_matches_the_cpu() {
    let Some(ctx) = gpu() else { return };
    let (left, right, gt) = generated_pair();
    for reg in [Regularizer::TgvTensor, Regularizer::Tv] {
        let m = TgvMatcher::new(TgvParams {
            regularizer: reg,
            sgm: sgm_params(48),
            ..TgvParams::default()
        })
        .unwrap();
        check_matcher(&ctx, &format!("generated {reg:?}"), &m, &left, &right, &gt);
    }
    if let Some((left, right, gt, _)) = motorcycle() {
        let m = TgvMatcher::new(TgvParams {
            sgm: sgm_params(70),
            ..TgvParams::default()
        })
        .unwrap();
        check_matcher(&ctx, "Motorcycle TgvTensor", &m, &left, &right, &gt);
    }
    if let Some((left, right, gt)) = kitti_pair() {
        let m = TgvMatcher::new(TgvParams {
            sgm: sgm_params(128),
            ..TgvParams::default()
        })
        .unwrap();
        check_matcher(&ctx, "KITTI 00/0 TgvTensor", &m, &left, &right, &gt);
    }
}

/// KITTI odometry 00 frame 0 (1241×376) with its LiDAR scan projected into image_0 as ground
/// truth.
fn kitti_pair() -> Option<(GreyImage, GreyImage, Image<f32>)> {
    let root = common::shared_data("kitti_odom00_frames000-005")?;
    let seq = denser::io::kitti::KittiSequence::open(root.join("sequences/00"), None).ok()?;
    let (left, right) = (seq.grey(0, 0).ok()?, seq.grey(1, 0).ok()?);
    let k = seq.intrinsics(0).ok()?;
    let cam0_from_velo = seq.calib().cam_from_velo(0);
    let points: Vec<[f64; 3]> = (seq.velodyne(0).ok()?.points_sensor_m.iter())
        .map(|p| {
            let c = cam0_from_velo * nalgebra::Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            [c.x, c.y, c.z]
        })
        .collect();
    let gt = disparity_from_points(&points, &k, seq.calib().baseline_m(0, 1));
    Some((left, right, gt))
}

#[test]
fn window_sums_on_the_gpu_equal_the_cpu_box_filter() {
    let Some(ctx) = gpu() else { return };
    let (left, right, _) = generated_pair();
    // 48 slices (a pixel's costs fill whole words), 47 (odd: one entry at a time) and, on
    // Motorcycle, 70 (even: pairs whose words start at any byte).
    let mut pairs = vec![
        ("generated", left.clone(), right.clone(), 48),
        ("generated, 47 slices", left, right, 47),
    ];
    if let Some((left, right, _, _)) = motorcycle() {
        pairs.push(("Motorcycle", left, right, 70));
    }
    for (what, left, right, nd) in &pairs {
        let volume = SgmMatcher::new(sgm_params(*nd))
            .unwrap()
            .cost_volume(left, right)
            .unwrap();
        for window in [2, 3, 5, 9] {
            let cpu = box_filtered_costs(&volume, window);
            let gpu = window_costs_gpu(&ctx, &volume, window).expect("GPU");
            assert!(cpu.1 == gpu.1, "{what}, window {window}: counts differ");
            let differ = cpu.0.iter().zip(&gpu.0).filter(|(a, b)| a != b).count();
            assert_eq!(differ, 0, "{what}, window {window}: sums differ");
            assert_eq!(cpu.0.len(), gpu.0.len());
        }
    }
    assert!(window_costs_gpu(&ctx, &pairs_volume(&pairs[0]), 1).is_err());
}

fn pairs_volume((_, left, right, nd): &(&str, GreyImage, GreyImage, usize)) -> CostVolume {
    SgmMatcher::new(sgm_params(*nd))
        .unwrap()
        .cost_volume(left, right)
        .unwrap()
}

#[test]
fn the_gpu_matcher_sends_no_costs_up_and_reads_back_no_volume() {
    // The variational matchers on the GPU: the cost volume is made on the device, aggregated
    // along SGM's paths there, its winners selected and filtered there, the initial disparity
    // filled there, the costs summed over their window there, and the map invalidated there.
    // What goes up is the two images; what comes down is the map; one wait. After the first
    // pair, a pair creates no buffer and no bind group.
    let Some(ctx) = gpu() else { return };
    let ctx = std::sync::Arc::new(ctx);
    let (left, right, _) = generated_pair();
    let nd = 48;
    for regularizer in [Regularizer::TgvTensor, Regularizer::Tgv, Regularizer::Tv] {
        let m = TgvMatcher::new(TgvParams {
            regularizer,
            sgm: sgm_params(nd),
            ..TgvParams::default()
        })
        .unwrap();
        let matcher = TgvMatcherGpu::new(ctx.clone(), m.clone());
        let first = matcher.estimate(&left, &right).expect("GPU");
        let before = ctx.traffic();
        let second = matcher.estimate(&left, &right).expect("GPU");
        let t = ctx.traffic().since(before);
        let pixels = (left.width * left.height) as u64;
        let entries = pixels * nd as u64;
        eprintln!("{regularizer:?}: {pixels} pixels, {entries} cost entries, a later pair: {t:?}");
        // The images (1 byte per pixel each) and uniforms: the tensors are computed from the
        // left image (TGV-tensor) or written as identities (TV, TGV), the initial disparity is
        // filled from SGM's and the primal, its over-relaxation and the dual are made from it,
        // all on the device. Before, the initial disparity went up (4 bytes per pixel), before
        // that the primal (12), the coupling target as zeros (4), the identity tensors (12),
        // and the window sums and counts (2 bytes per entry and 4 per pixel).
        assert!(
            t.upload_bytes <= 2 * pixels + (64 << 10),
            "{regularizer:?}: {t:?}"
        );
        // Down: the map's disparities and confidences (8 bytes per pixel), made on the device
        // (SGM's sums, its map, TGV's state and the costs stay there). Before, SGM's map and
        // each pixel's disparity and cost came down for the CPU's invalidation (13 bytes per
        // pixel), before that SGM's unfiltered selection (16), and before that the cost volume
        // (1 byte per entry, 48 per pixel here) and the whole primal (12).
        assert!(
            t.readback_bytes <= 8 * pixels + (64 << 10),
            "{regularizer:?}: {t:?}"
        );
        // One submit and one wait, for everything that comes back: the rounds' uniforms are
        // copied from a table on the device (before: 12 submits, a search and its iterations
        // each, and two waits, SGM's first; before that three, the volume's first).
        assert_eq!((t.submits, t.waits), (1, 1), "{regularizer:?}: {t:?}");
        assert_eq!((t.buffers_created, t.bind_groups_created), (0, 0), "{t:?}");
        // Kept buffers change nothing: both pairs give the one-shot matcher's map, bit for bit.
        let once = estimate_tgv_gpu(&ctx, &m, &left, &right)
            .expect("GPU")
            .result;
        let bits = |d: &DisparityMap| {
            d.disparity_px
                .data
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>()
        };
        assert!(bits(&first) == bits(&once) && bits(&second) == bits(&once));
    }
}

#[test]
fn the_costs_at_the_disparities_are_gathered_on_the_gpu_as_on_the_cpu() {
    // The invalidation's cost lookup: the slice nearest each disparity (halves away from zero,
    // clamped to the range) on both devices, on the halves and next to them, below and above
    // the range, and on arbitrary disparities; a non-finite disparity (which TGV never makes)
    // only has to leave the kernel in bounds.
    let Some(ctx) = gpu() else { return };
    let (w, h, nd, dmin) = (37u32, 5u32, 13usize, -2i32);
    let n = (w * h) as usize;
    let mut state = 0x2545_f491u32;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        state
    };
    let volume = CostVolume {
        width: w,
        height: h,
        min_disparity_px: dmin,
        num_disparities: nd,
        max_cost: 62,
        cost: (0..n * nd).map(|_| (next() % 63) as u8).collect(),
    };
    // Slice 5.5 and its neighbouring floats, less d_min (exact: the result has finer steps).
    let near_half = |step: i32| f32::from_bits((5.5f32.to_bits() as i32 + step) as u32) - 2.0;
    let mut dense: Vec<f32> = vec![
        -2.5,
        -1.5,
        near_half(0),
        near_half(-1),
        near_half(1),
        -2.0 + 0.49999997,
        -2.0 - 0.49999997,
        -1e9,
        1e9,
        10.5,
        10.499999,
        11.0,
        0.0,
        -0.0,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
    ];
    let finite_listed = dense.len() - 3;
    while dense.len() < n {
        dense.push(-5.0 + (next() % 20_000) as f32 * 1e-3);
    }
    let cpu = costs_at_disparities(&dense, &volume);
    let (u, gpu_costs) = costs_at_disparities_gpu(&ctx, &volume, &dense).expect("GPU");
    assert_eq!((u.len(), gpu_costs.len()), (n, n));
    let mut compared = 0;
    for i in 0..n {
        if !dense[i].is_finite() {
            continue;
        }
        assert_eq!(
            u[i].to_bits(),
            dense[i].to_bits(),
            "pixel {i}: disparity read back"
        );
        assert_eq!(cpu[i], gpu_costs[i], "pixel {i}: disparity {}", dense[i]);
        compared += 1;
    }
    assert_eq!(compared, n - 3);
    // The rule itself, on the listed values: slice 0 below the range, the last above it.
    let slice = |i: usize| volume.cost[i * nd..(i + 1) * nd].to_vec();
    assert_eq!(
        cpu[0],
        slice(0)[0],
        "-2.5 is slice 0 (−0.5 rounds to −1, clamped)"
    );
    assert_eq!(
        cpu[2],
        slice(2)[6],
        "3.5 − (−2) = 5.5 rounds away from zero to 6"
    );
    assert_eq!(cpu[3], slice(3)[5], "just below 5.5 rounds to 5");
    assert_eq!(cpu[4], slice(4)[6], "just above 5.5 rounds to 6");
    assert_eq!(cpu[8], slice(8)[nd - 1], "above the range: the last slice");
    assert!(finite_listed < n);
}

#[test]
fn diffusion_tensors_on_the_gpu_match_the_cpu() {
    // The same f32 operations in order; `exp` and `pow` are the device's (on llvmpipe within
    // a few ULP of the CPU's), so entries agree within 1e-5 (they lie in [-1, 1]).
    let Some(ctx) = gpu() else { return };
    let (left, _, _) = generated_pair();
    let mut images = vec![("generated", left)];
    if let Some((left, _, _, _)) = motorcycle() {
        images.push(("Motorcycle", left));
    }
    let p = TgvParams::default();
    for (what, image) in &images {
        let cpu = diffusion_tensors(image, p.gamma, p.beta);
        let gpu = diffusion_tensors_gpu(&ctx, image, p.gamma, p.beta).expect("GPU");
        assert_eq!(cpu.len(), gpu.len());
        let mut worst = 0f32;
        let mut anisotropic = 0;
        for (c, g) in cpu.iter().zip(&gpu) {
            for k in 0..3 {
                worst = worst.max((c[k] - g[k]).abs());
            }
            anisotropic += (c[1] != 0.0) as usize;
        }
        eprintln!("{what}: max |ΔT| = {worst:e}, {anisotropic} anisotropic pixels");
        assert!(worst <= 1e-5, "{what}: {worst}");
        assert!(anisotropic > cpu.len() / 10, "{what}: the image has edges");
    }
}
