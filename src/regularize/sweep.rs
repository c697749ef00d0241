//! The per-block kernels of [`super::TvProblem::iterate`]: the dual step and the primal step
//! (with relaxation) over one block's 512 voxels, written as straight loops over contiguous
//! arrays so that they vectorise.
//!
//! Each kernel first copies the neighbours it reads into block-sized arrays (the voxel at
//! `x + e_d` for the dual step, `x − e_d` for the primal step; across a block face from the
//! neighbouring block, or 0 when it is not in the problem), then runs one loop over the block
//! with the Ω and link bits as selects instead of branches. A link bit is set only where the
//! neighbour exists and is in Ω, so the placeholder 0 is never used. The arithmetic per voxel is
//! the reference's ([`super::TvProblem::gradient_at`], [`super::TvProblem::divergence_at`]) in
//! the same order, and a skipped term there is an added `+0.0` here, which changes no bit (the
//! sums never hold `−0.0`): `tests.rs` checks the result bit for bit against the scalar
//! reference, and the GPU kernels (`shaders/tv_*.wgsl`) stay its twins.
//!
//! `multiversion` compiles each kernel for AVX-512 and AVX2 besides the baseline and picks one at
//! run time; no target enables FMA contraction (Rust never contracts), so every version gives the
//! same bits.

use super::{bwd, fwd, NONE, OMEGA, STRIDE};
use crate::grid::{VOXELS_PER_BLOCK, VOXELS_PER_SIDE};
use multiversion::multiversion;
use rayon::prelude::*;

const N: usize = VOXELS_PER_BLOCK;
const S: usize = VOXELS_PER_SIDE;
const SLAB: usize = S * S;

/// Copies into `out` the value of `v` at `x + e_d` for every voxel of block `b` (d = 0, 1, 2 for
/// `out[0..3]`); 0 across a face with no neighbour.
#[inline(always)]
fn forward_values(v: &[f32], b: usize, nb: &[u32; 6], out: &mut [[f32; N]; 3]) {
    let own = &v[b * N..(b + 1) * N];
    let other = |k: usize| (nb[k] != NONE).then(|| &v[nb[k] as usize * N..][..N]);
    // +x: in-block shift by one, the x = 7 column from the neighbour's x = 0 column.
    let [ox, oy, oz] = out;
    ox[..N - 1].copy_from_slice(&own[1..]);
    let nx = other(0);
    for r in 0..SLAB {
        ox[r * S + S - 1] = nx.map_or(0.0, |n| n[r * S]);
    }
    // +y: per z slab, rows shifted by one, the y = 7 row from the neighbour's y = 0 row.
    let ny = other(2);
    for z in 0..S {
        let s = z * SLAB;
        oy[s..s + SLAB - S].copy_from_slice(&own[s + S..s + SLAB]);
        match ny {
            Some(n) => oy[s + SLAB - S..s + SLAB].copy_from_slice(&n[s..s + S]),
            None => oy[s + SLAB - S..s + SLAB].fill(0.0),
        }
    }
    // +z: slabs shifted by one, the z = 7 slab from the neighbour's z = 0 slab.
    oz[..N - SLAB].copy_from_slice(&own[SLAB..]);
    match other(4) {
        Some(n) => oz[N - SLAB..].copy_from_slice(&n[..SLAB]),
        None => oz[N - SLAB..].fill(0.0),
    }
}

/// Copies into `out` the value of `v` at `x − e_d` for every voxel of block `b`; 0 across a face
/// with no neighbour.
#[inline(always)]
fn backward_values(v: &[f32], b: usize, nb: &[u32; 6], out: &mut [f32; N], d: usize) {
    let own = &v[b * N..(b + 1) * N];
    let other = (nb[2 * d + 1] != NONE).then(|| &v[nb[2 * d + 1] as usize * N..][..N]);
    match d {
        0 => {
            out[1..].copy_from_slice(&own[..N - 1]);
            for r in 0..SLAB {
                out[r * S] = other.map_or(0.0, |n| n[r * S + S - 1]);
            }
        }
        1 => {
            for z in 0..S {
                let s = z * SLAB;
                out[s + S..s + SLAB].copy_from_slice(&own[s..s + SLAB - S]);
                match other {
                    Some(n) => out[s..s + S].copy_from_slice(&n[s + SLAB - S..s + SLAB]),
                    None => out[s..s + S].fill(0.0),
                }
            }
        }
        _ => {
            out[SLAB..].copy_from_slice(&own[..N - SLAB]);
            match other {
                Some(n) => out[..SLAB].copy_from_slice(&n[N - SLAB..]),
                None => out[..SLAB].fill(0.0),
            }
        }
    }
}

/// The dual step on block `b`: `p ← (p + σ∇ū) / max(1, |p + σ∇ū|)` on Ω, `p` unchanged
/// elsewhere. `p` holds the block's three components.
pub(super) fn dual_block(
    ubar: &[f32],
    b: usize,
    nb: &[u32; 6],
    mask: &[u8],
    p: [&mut [f32]; 3],
    sigma: f32,
) {
    let mut ahead = [[0.0f32; N]; 3];
    forward_values(ubar, b, nb, &mut ahead);
    let centre = &ubar[b * N..(b + 1) * N];
    let [px, py, pz] = p;
    dual_kernel(centre, &ahead, mask, px, py, pz, sigma);
}

#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512vl+avx2+avx",
    "x86_64+avx2+avx",
    "x86_64+sse4.1"
))]
fn dual_kernel(
    centre: &[f32],
    ahead: &[[f32; N]; 3],
    mask: &[u8],
    px: &mut [f32],
    py: &mut [f32],
    pz: &mut [f32],
    sigma: f32,
) {
    let (centre, mask) = (&centre[..N], &mask[..N]);
    let (px, py, pz) = (&mut px[..N], &mut py[..N], &mut pz[..N]);
    let [ax, ay, az] = ahead;
    for i in 0..N {
        let m = mask[i];
        let c = centre[i];
        let gx = if m & fwd(0) != 0 { ax[i] - c } else { 0.0 };
        let gy = if m & fwd(1) != 0 { ay[i] - c } else { 0.0 };
        let gz = if m & fwd(2) != 0 { az[i] - c } else { 0.0 };
        let qx = px[i] + sigma * gx;
        let qy = py[i] + sigma * gy;
        let qz = pz[i] + sigma * gz;
        let scale = 1.0 / (qx * qx + qy * qy + qz * qz).sqrt().max(1.0);
        let inside = m & OMEGA != 0;
        px[i] = if inside { qx * scale } else { px[i] };
        py[i] = if inside { qy * scale } else { py[i] };
        pz[i] = if inside { qz * scale } else { pz[i] };
    }
}

/// Constants of the primal step.
#[derive(Clone, Copy)]
pub(super) struct PrimalConstants {
    pub tau: f32,
    pub lambda: f32,
    pub theta: f32,
}

/// The primal step and relaxation on block `b`: `u ← (u + τ div p + τλwf)/(1 + τλw)`,
/// `ū ← u + θ(u − u_old)` on Ω, both unchanged elsewhere. `p` holds all three components of the
/// whole problem; `u`, `ubar`, `f`, `w`, `mask` the block's.
#[allow(clippy::too_many_arguments)]
pub(super) fn primal_block(
    p: [&[f32]; 3],
    b: usize,
    nb: &[u32; 6],
    mask: &[u8],
    f: &[f32],
    w: &[f32],
    u: &mut [f32],
    ubar: &mut [f32],
    k: PrimalConstants,
) {
    let mut behind = [[0.0f32; N]; 3];
    for d in 0..3 {
        backward_values(p[d], b, nb, &mut behind[d], d);
    }
    let own = p.map(|v| &v[b * N..(b + 1) * N]);
    primal_kernel(own, &behind, mask, f, w, u, ubar, k.tau, k.lambda, k.theta);
}

#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512vl+avx2+avx",
    "x86_64+avx2+avx",
    "x86_64+sse4.1"
))]
#[allow(clippy::too_many_arguments)]
fn primal_kernel(
    own: [&[f32]; 3],
    behind: &[[f32; N]; 3],
    mask: &[u8],
    f: &[f32],
    w: &[f32],
    u: &mut [f32],
    ubar: &mut [f32],
    tau: f32,
    lambda: f32,
    theta: f32,
) {
    let [ox, oy, oz] = own;
    let (ox, oy, oz) = (&ox[..N], &oy[..N], &oz[..N]);
    let [bx, by, bz] = behind;
    let (mask, f, w) = (&mask[..N], &f[..N], &w[..N]);
    let (u, ubar) = (&mut u[..N], &mut ubar[..N]);
    for i in 0..N {
        let m = mask[i];
        // The reference's order: +p_x, −p_x(x − e_x), +p_y, −p_y(x − e_y), +p_z, −p_z(x − e_z).
        let mut div = 0.0f32;
        div += if m & fwd(0) != 0 { ox[i] } else { 0.0 };
        div -= if m & bwd(0) != 0 { bx[i] } else { 0.0 };
        div += if m & fwd(1) != 0 { oy[i] } else { 0.0 };
        div -= if m & bwd(1) != 0 { by[i] } else { 0.0 };
        div += if m & fwd(2) != 0 { oz[i] } else { 0.0 };
        div -= if m & bwd(2) != 0 { bz[i] } else { 0.0 };
        let tlw = tau * lambda * w[i];
        let old = u[i];
        let new = (old + tau * div + tlw * f[i]) / (1.0 + tlw);
        let inside = m & OMEGA != 0;
        u[i] = if inside { new } else { old };
        ubar[i] = if inside {
            new + theta * (new - old)
        } else {
            ubar[i]
        };
    }
}

/// The Ω and link bits of every voxel (see [`super::TvProblem::masks`]) from each voxel's Ω flag
/// and the blocks' neighbour table: per block, with the neighbour across a face read from the
/// neighbouring block (no link where that block is not in the problem).
pub(super) fn link_masks(neighbors: &[[u32; 6]], omega: &[bool]) -> Vec<u8> {
    let mut mask = vec![0u8; omega.len()];
    mask.par_chunks_mut(N)
        .zip(neighbors.par_iter())
        .enumerate()
        .for_each(|(b, (m, nb))| {
            let own = &omega[b * N..(b + 1) * N];
            let other = |k: usize| (nb[k] != NONE).then(|| &omega[nb[k] as usize * N..][..N]);
            let faces: [Option<&[bool]>; 6] = std::array::from_fn(other);
            for z in 0..S {
                for y in 0..S {
                    for x in 0..S {
                        let i = x + S * y + SLAB * z;
                        if !own[i] {
                            continue;
                        }
                        let c = [x, y, z];
                        let mut bits = OMEGA;
                        for d in 0..3 {
                            let ahead = if c[d] + 1 < S {
                                own[i + STRIDE[d]]
                            } else {
                                faces[2 * d].is_some_and(|o| o[i - (S - 1) * STRIDE[d]])
                            };
                            let behind = if c[d] > 0 {
                                own[i - STRIDE[d]]
                            } else {
                                faces[2 * d + 1].is_some_and(|o| o[i + (S - 1) * STRIDE[d]])
                            };
                            bits |=
                                if ahead { fwd(d) } else { 0 } | if behind { bwd(d) } else { 0 };
                        }
                        m[i] = bits;
                    }
                }
            }
        });
    mask
}
