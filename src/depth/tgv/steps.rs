//! One Chambolle–Pock iteration of [`super::TgvProblem`], row by row: the dual step (ascent and
//! projection of `p`, `q`) and the primal step (descent of `u`, `v` and over-relaxation),
//! rayon-parallel over bands of rows, vectorised along them.

#[allow(unused_imports)]
use super::*;

/// Constants of one iteration.
#[derive(Clone, Copy)]
pub(super) struct StepConsts {
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) tv: bool,
    pub(super) tau: f32,
    pub(super) sigma: f32,
    pub(super) a1: f32,
    pub(super) a2: f32,
    pub(super) coupling: f32,
}

/// `n` mutable arrays split into tasks of [`ROWS_PER_TASK`] rows: one `[&mut [f32]; N]` per task.
pub(super) fn row_tasks<const N: usize>(
    arrays: [&mut Vec<f32>; N],
    w: usize,
) -> Vec<[&mut [f32]; N]> {
    let mut chunks: [std::slice::ChunksMut<'_, f32>; N] =
        arrays.map(|a| a.chunks_mut(ROWS_PER_TASK * w));
    let tasks = chunks[0].len();
    (0..tasks)
        .map(|_| {
            std::array::from_fn(|c| {
                // Every array has the same length, so every iterator yields `tasks` chunks.
                chunks[c].next().unwrap_or_default()
            })
        })
        .collect()
}

/// The dual ascent and projection over every pixel, then `T·p` for the primal step.
pub(super) fn dual_step(
    k: &StepConsts,
    t: &[Vec<f32>; 3],
    x_bar: &[Vec<f32>; 3],
    y: &mut [Vec<f32>; 5],
    tp: &mut [Vec<f32>; 2],
) {
    let w = k.w;
    let [p1, p2, q11, q22, q12] = y;
    let [tp1, tp2] = tp;
    let tasks = row_tasks([p1, p2, q11, q22, q12, tp1, tp2], w);
    tasks.into_par_iter().enumerate().for_each(|(task, out)| {
        let [p1, p2, q11, q22, q12, tp1, tp2] = out;
        let y0 = task * ROWS_PER_TASK;
        for r in 0..p1.len() / w {
            let yy = y0 + r;
            let row = |y: usize| y * w..(y + 1) * w;
            let (cur, next, prev) = (
                row(yy),
                row(if yy + 1 < k.h { yy + 1 } else { yy }),
                row(yy.saturating_sub(1)),
            );
            let rows = DualRows {
                t: [&t[0][cur.clone()], &t[1][cur.clone()], &t[2][cur.clone()]],
                ub: &x_bar[0][cur.clone()],
                ub_next: &x_bar[0][next],
                v1b: &x_bar[1][cur.clone()],
                v2b: &x_bar[2][cur],
                v1b_prev: &x_bar[1][prev.clone()],
                v2b_prev: &x_bar[2][prev],
            };
            let o = r * w..(r + 1) * w;
            let mut outs = DualOut {
                p1: &mut p1[o.clone()],
                p2: &mut p2[o.clone()],
                q11: &mut q11[o.clone()],
                q22: &mut q22[o.clone()],
                q12: &mut q12[o.clone()],
                tp1: &mut tp1[o.clone()],
                tp2: &mut tp2[o],
            };
            dual_row(k, yy > 0, yy + 1 < k.h, &rows, &mut outs);
        }
    });
}

/// Inputs of one row of the dual step: the row's tensors and over-relaxed primal, `ū` of the
/// next row and `v̄` of the previous one (the row itself where there is none).
pub(super) struct DualRows<'a> {
    t: [&'a [f32]; 3],
    ub: &'a [f32],
    ub_next: &'a [f32],
    v1b: &'a [f32],
    v2b: &'a [f32],
    v1b_prev: &'a [f32],
    v2b_prev: &'a [f32],
}

/// Outputs of one row of the dual step.
pub(super) struct DualOut<'a> {
    p1: &'a mut [f32],
    p2: &'a mut [f32],
    q11: &'a mut [f32],
    q22: &'a mut [f32],
    q12: &'a mut [f32],
    tp1: &'a mut [f32],
    tp2: &'a mut [f32],
}

/// One row of the dual step, dispatched to a copy compiled for AVX-512 or AVX2 where the CPU
/// has it (every copy does the same IEEE operations in the same order: Rust never contracts
/// `a * b + c` into a fused multiply–add, so the result is the same bits).
pub(super) fn dual_row(
    k: &StepConsts,
    has_up: bool,
    has_down: bool,
    r: &DualRows,
    o: &mut DualOut,
) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,avx512vl,avx2")]
        fn avx512(k: &StepConsts, u: bool, d: bool, r: &DualRows, o: &mut DualOut) {
            dual_row_impl(k, u, d, r, o)
        }
        #[target_feature(enable = "avx2")]
        fn avx2(k: &StepConsts, u: bool, d: bool, r: &DualRows, o: &mut DualOut) {
            dual_row_impl(k, u, d, r, o)
        }
        if std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx512vl") {
            // SAFETY: the CPU supports the features the copy was compiled for (checked above).
            unsafe { avx512(k, has_up, has_down, r, o) };
            return;
        }
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: as above.
            unsafe { avx2(k, has_up, has_down, r, o) };
            return;
        }
    }
    dual_row_impl(k, has_up, has_down, r, o)
}

#[inline(always)]
pub(super) fn dual_row_impl(k: &StepConsts, up: bool, down: bool, r: &DualRows, o: &mut DualOut) {
    let w = k.w;
    if w == 1 {
        dual_cols::<false, false>(k, up, down, r, 0, 1, o);
        return;
    }
    // The first column, the interior (both horizontal neighbours exist), the last column.
    dual_cols::<false, true>(k, up, down, r, 0, 1, o);
    if w > 2 {
        dual_cols::<true, true>(k, up, down, r, 1, w - 1, o);
    }
    dual_cols::<true, false>(k, up, down, r, w - 1, w, o);
}

/// [`dual_span`] with the row's vertical neighbours chosen at run time.
#[inline(always)]
pub(super) fn dual_cols<const LEFT: bool, const RIGHT: bool>(
    k: &StepConsts,
    up: bool,
    down: bool,
    r: &DualRows,
    x0: usize,
    x1: usize,
    o: &mut DualOut,
) {
    match (up, down) {
        (true, true) => dual_span::<true, true, LEFT, RIGHT>(k, r, x0, x1, o),
        (true, false) => dual_span::<true, false, LEFT, RIGHT>(k, r, x0, x1, o),
        (false, true) => dual_span::<false, true, LEFT, RIGHT>(k, r, x0, x1, o),
        (false, false) => dual_span::<false, false, LEFT, RIGHT>(k, r, x0, x1, o),
    }
}

/// The dual step over pixels `[x0, x1)` of a row whose neighbours above/below (`UP`, `DOWN`)
/// and left/right (`LEFT`, `RIGHT`) exist as given. Per pixel:
/// `p ← proj_α₁(p + σ·T(∇ū − v̄))`, `q ← proj_α₂(q + σ·ε(v̄))`, then `T·p`.
#[inline(always)]
pub(super) fn dual_span<const UP: bool, const DOWN: bool, const LEFT: bool, const RIGHT: bool>(
    k: &StepConsts,
    r: &DualRows,
    x0: usize,
    x1: usize,
    o: &mut DualOut,
) {
    let (sigma, a1, a2, tv) = (k.sigma, k.a1, k.a2, k.tv);
    let n = x1 - x0;
    let span = x0..x1;
    // Neighbour rows, sliced to the span's length (the row itself where the neighbour is
    // absent: never read then).
    let ub = &r.ub[span.clone()];
    let ub_r = if RIGHT { &r.ub[x0 + 1..x1 + 1] } else { ub };
    let ub_d = &r.ub_next[span.clone()];
    let (v1, v2) = (&r.v1b[span.clone()], &r.v2b[span.clone()]);
    let (v1_l, v2_l) = if LEFT {
        (&r.v1b[x0 - 1..x1 - 1], &r.v2b[x0 - 1..x1 - 1])
    } else {
        (v1, v2)
    };
    let (v1_u, v2_u) = (&r.v1b_prev[span.clone()], &r.v2b_prev[span.clone()]);
    let (t11, t12, t22) = (
        &r.t[0][span.clone()],
        &r.t[1][span.clone()],
        &r.t[2][span.clone()],
    );
    let p1 = &mut o.p1[span.clone()];
    let p2 = &mut o.p2[span.clone()];
    let q11 = &mut o.q11[span.clone()];
    let q22 = &mut o.q22[span.clone()];
    let q12 = &mut o.q12[span.clone()];
    let tp1 = &mut o.tp1[span.clone()];
    let tp2 = &mut o.tp2[span];
    for j in 0..n {
        let c0 = ub[j];
        let gx = if RIGHT { ub_r[j] - c0 } else { 0.0 };
        let gy = if DOWN { ub_d[j] - c0 } else { 0.0 };
        let (c1, c2) = (v1[j], v2[j]);
        let (g0, g1) = (gx - c1, gy - c2);
        let tt = [t11[j] * g0 + t12[j] * g1, t12[j] * g0 + t22[j] * g1];
        let (np1, np2) = (p1[j] + sigma * tt[0], p2[j] + sigma * tt[1]);
        // sqrt(p1² + p2²), not `hypot`: the GPU twin (shaders/tgv_dual.wgsl) has no hypot, and
        // |p| ≤ α₁ cannot overflow.
        let s = ((np1 * np1 + np2 * np2).sqrt() / a1).max(1.0);
        let (np1, np2) = (np1 / s, np2 / s);
        p1[j] = np1;
        p2[j] = np2;
        if !tv {
            let (l0, l1) = if LEFT { (v1_l[j], v2_l[j]) } else { (c1, c2) };
            let (u0, u1) = if UP { (v1_u[j], v2_u[j]) } else { (c1, c2) };
            let e = [c1 - l0, c2 - u1, 0.5 * ((c1 - u0) + (c2 - l1))];
            let nq11 = q11[j] + sigma * e[0];
            let nq22 = q22[j] + sigma * e[1];
            let nq12 = q12[j] + sigma * e[2];
            let s = ((nq11 * nq11 + nq22 * nq22 + 2.0 * nq12 * nq12).sqrt() / a2).max(1.0);
            q11[j] = nq11 / s;
            q22[j] = nq22 / s;
            q12[j] = nq12 / s;
        }
        tp1[j] = t11[j] * np1 + t12[j] * np2;
        tp2[j] = t12[j] * np1 + t22[j] * np2;
    }
}

/// The primal descent, the proximal step of the coupling and the over-relaxation over every
/// pixel.
pub(super) fn primal_step(
    k: &StepConsts,
    a: &[f32],
    tp: &[Vec<f32>; 2],
    y: &[Vec<f32>; 5],
    x: &mut [Vec<f32>; 3],
    x_bar: &mut [Vec<f32>; 3],
) {
    let w = k.w;
    let [u, v1, v2] = x;
    let [ub, v1b, v2b] = x_bar;
    let tasks = row_tasks([u, v1, v2, ub, v1b, v2b], w);
    tasks.into_par_iter().enumerate().for_each(|(task, out)| {
        let [u, v1, v2, ub, v1b, v2b] = out;
        let y0 = task * ROWS_PER_TASK;
        for r in 0..u.len() / w {
            let yy = y0 + r;
            let row = |y: usize| y * w..(y + 1) * w;
            let (cur, next, prev) = (
                row(yy),
                row(if yy + 1 < k.h { yy + 1 } else { yy }),
                row(yy.saturating_sub(1)),
            );
            let rows = PrimalRows {
                a: &a[cur.clone()],
                tp1: &tp[0][cur.clone()],
                tp2: &tp[1][cur.clone()],
                tp2_prev: &tp[1][prev],
                q11: &y[2][cur.clone()],
                q22: &y[3][cur.clone()],
                q12: &y[4][cur],
                q22_next: &y[3][next.clone()],
                q12_next: &y[4][next],
            };
            let o = r * w..(r + 1) * w;
            let mut outs = PrimalOut {
                u: &mut u[o.clone()],
                v1: &mut v1[o.clone()],
                v2: &mut v2[o.clone()],
                ub: &mut ub[o.clone()],
                v1b: &mut v1b[o.clone()],
                v2b: &mut v2b[o],
            };
            primal_row(k, yy > 0, yy + 1 < k.h, &rows, &mut outs);
        }
    });
}

/// Inputs of one row of the primal step: `T·p` of the row (and `(T·p)₂` of the row above), `q`
/// of the row (and `q22`, `q12` of the row below), the coupling target.
pub(super) struct PrimalRows<'a> {
    a: &'a [f32],
    tp1: &'a [f32],
    tp2: &'a [f32],
    tp2_prev: &'a [f32],
    q11: &'a [f32],
    q22: &'a [f32],
    q12: &'a [f32],
    q22_next: &'a [f32],
    q12_next: &'a [f32],
}

/// Outputs of one row of the primal step.
pub(super) struct PrimalOut<'a> {
    u: &'a mut [f32],
    v1: &'a mut [f32],
    v2: &'a mut [f32],
    ub: &'a mut [f32],
    v1b: &'a mut [f32],
    v2b: &'a mut [f32],
}

/// One row of the primal step, dispatched like [`dual_row`].
pub(super) fn primal_row(
    k: &StepConsts,
    has_up: bool,
    has_down: bool,
    r: &PrimalRows,
    o: &mut PrimalOut,
) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,avx512vl,avx2")]
        fn avx512(k: &StepConsts, u: bool, d: bool, r: &PrimalRows, o: &mut PrimalOut) {
            primal_row_impl(k, u, d, r, o)
        }
        #[target_feature(enable = "avx2")]
        fn avx2(k: &StepConsts, u: bool, d: bool, r: &PrimalRows, o: &mut PrimalOut) {
            primal_row_impl(k, u, d, r, o)
        }
        if std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx512vl") {
            // SAFETY: the CPU supports the features the copy was compiled for (checked above).
            unsafe { avx512(k, has_up, has_down, r, o) };
            return;
        }
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: as above.
            unsafe { avx2(k, has_up, has_down, r, o) };
            return;
        }
    }
    primal_row_impl(k, has_up, has_down, r, o)
}

#[inline(always)]
pub(super) fn primal_row_impl(
    k: &StepConsts,
    up: bool,
    down: bool,
    r: &PrimalRows,
    o: &mut PrimalOut,
) {
    let w = k.w;
    if w == 1 {
        primal_cols::<false, false>(k, up, down, r, 0, 1, o);
        return;
    }
    primal_cols::<false, true>(k, up, down, r, 0, 1, o);
    if w > 2 {
        primal_cols::<true, true>(k, up, down, r, 1, w - 1, o);
    }
    primal_cols::<true, false>(k, up, down, r, w - 1, w, o);
}

/// [`primal_span`] with the row's vertical neighbours chosen at run time.
#[inline(always)]
pub(super) fn primal_cols<const LEFT: bool, const RIGHT: bool>(
    k: &StepConsts,
    up: bool,
    down: bool,
    r: &PrimalRows,
    x0: usize,
    x1: usize,
    o: &mut PrimalOut,
) {
    match (up, down) {
        (true, true) => primal_span::<true, true, LEFT, RIGHT>(k, r, x0, x1, o),
        (true, false) => primal_span::<true, false, LEFT, RIGHT>(k, r, x0, x1, o),
        (false, true) => primal_span::<false, true, LEFT, RIGHT>(k, r, x0, x1, o),
        (false, false) => primal_span::<false, false, LEFT, RIGHT>(k, r, x0, x1, o),
    }
}

/// The primal step over pixels `[x0, x1)` (neighbour flags as in [`dual_span`]). Per pixel:
/// `u ← (u + τ·div(T·p) + (τ/θ)·a) / (1 + τ/θ)`, `v ← v + τ·(T·p + div_sym q)`, `x̄ = 2x_new − x`.
#[inline(always)]
pub(super) fn primal_span<const UP: bool, const DOWN: bool, const LEFT: bool, const RIGHT: bool>(
    k: &StepConsts,
    r: &PrimalRows,
    x0: usize,
    x1: usize,
    o: &mut PrimalOut,
) {
    let (tau, coupling, tv) = (k.tau, k.coupling, k.tv);
    let n = x1 - x0;
    let span = x0..x1;
    let a = &r.a[span.clone()];
    let tp1 = &r.tp1[span.clone()];
    let tp1_l = if LEFT { &r.tp1[x0 - 1..x1 - 1] } else { tp1 };
    let tp2 = &r.tp2[span.clone()];
    let tp2_u = &r.tp2_prev[span.clone()];
    let (q11, q22, q12) = (
        &r.q11[span.clone()],
        &r.q22[span.clone()],
        &r.q12[span.clone()],
    );
    let (q11_r, q12_r) = if RIGHT {
        (&r.q11[x0 + 1..x1 + 1], &r.q12[x0 + 1..x1 + 1])
    } else {
        (q11, q12)
    };
    let (q22_d, q12_d) = (&r.q22_next[span.clone()], &r.q12_next[span.clone()]);
    let u = &mut o.u[span.clone()];
    let v1 = &mut o.v1[span.clone()];
    let v2 = &mut o.v2[span.clone()];
    let ub = &mut o.ub[span.clone()];
    let v1b = &mut o.v1b[span.clone()];
    let v2b = &mut o.v2b[span];
    for j in 0..n {
        let old = [u[j], v1[j], v2[j]];
        // div(T·p), in the order of `div_at`.
        let mut div_tp = 0.0;
        if RIGHT {
            div_tp += tp1[j];
        }
        if LEFT {
            div_tp -= tp1_l[j];
        }
        if DOWN {
            div_tp += tp2[j];
        }
        if UP {
            div_tp -= tp2_u[j];
        }
        let nu = (old[0] + tau * div_tp + coupling * a[j]) / (1.0 + coupling);
        let (nv1, nv2) = if tv {
            (0.0, 0.0)
        } else {
            // div_sym q, in the order of `sym_div_at`.
            let (mut d1, mut d2) = (0.0f32, 0.0f32);
            if LEFT {
                d1 += q11[j];
                d2 += q12[j];
            }
            if RIGHT {
                d1 -= q11_r[j];
                d2 -= q12_r[j];
            }
            if UP {
                d1 += q12[j];
                d2 += q22[j];
            }
            if DOWN {
                d1 -= q12_d[j];
                d2 -= q22_d[j];
            }
            let ds = [-d1, -d2];
            (
                old[1] + tau * (tp1[j] + ds[0]),
                old[2] + tau * (tp2[j] + ds[1]),
            )
        };
        u[j] = nu;
        v1[j] = nv1;
        v2[j] = nv2;
        ub[j] = 2.0 * nu - old[0];
        v1b[j] = 2.0 * nv1 - old[1];
        v2b[j] = 2.0 * nv2 - old[2];
    }
}
