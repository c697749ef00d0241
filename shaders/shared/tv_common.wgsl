// Ω-aware TV primal–dual (DENSER Sec. III-C), shared by tv_dual.wgsl and tv_primal.wgsl.
// Data layout: the flat arrays of `TvProblem` (src/regularize/mod.rs); keep in sync with
// src/gpu/layout.rs (`TvUniforms`) and src/regularize/mod.rs (mask bits, neighbour order).
// Voxel g of block slot b is g = b·512 + i, i = x + 8y + 64z.

// Keep in sync with `TvUniforms` in src/gpu/layout.rs.
struct TvUniforms {
    sigma: f32,
    tau: f32,
    lambda: f32,
    theta: f32,
    voxel_count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

const VOXELS_PER_SIDE: u32 = 8u;
const VOXELS_PER_BLOCK: u32 = 512u;
const NONE: u32 = 0xffffffffu;
// Mask bits (src/regularize/mod.rs): bit d = forward link along axis d, bit 3 + d = backward
// link, bit 6 = Ω.
const OMEGA: u32 = 64u;

@group(0) @binding(0) var<uniform> params: TvUniforms;
// Six neighbour slots per block: +x, −x, +y, −y, +z, −z (NONE when absent).
@group(0) @binding(1) var<storage, read> neighbors: array<u32>;
// One mask per voxel (the CPU's u8, widened).
@group(0) @binding(2) var<storage, read> mask: array<u32>;
@group(0) @binding(3) var<storage, read> f: array<f32>;
@group(0) @binding(4) var<storage, read> w: array<f32>;
@group(0) @binding(5) var<storage, read_write> u: array<f32>;
@group(0) @binding(6) var<storage, read_write> ubar: array<f32>;
// Dual variable as three planes (TvProblem::state): p_x of every voxel, then p_y, then p_z;
// component d of voxel g at d·voxel_count + g.
@group(0) @binding(7) var<storage, read_write> p: array<f32>;

fn stride(d: u32) -> u32 {
    return select(select(64u, 8u, d == 1u), 1u, d == 0u);
}

// Flat index of x + e_d, or NONE when its block is not in the problem (TvProblem::forward).
fn forward(g: u32, d: u32) -> u32 {
    let b = g / VOXELS_PER_BLOCK;
    let i = g % VOXELS_PER_BLOCK;
    let s = stride(d);
    let c = (i / s) % VOXELS_PER_SIDE;
    if (c + 1u < VOXELS_PER_SIDE) {
        return g + s;
    }
    let nb = neighbors[b * 6u + 2u * d];
    if (nb == NONE) {
        return NONE;
    }
    return nb * VOXELS_PER_BLOCK + i - (VOXELS_PER_SIDE - 1u) * s;
}

// Flat index of x − e_d, or NONE (TvProblem::backward).
fn backward(g: u32, d: u32) -> u32 {
    let b = g / VOXELS_PER_BLOCK;
    let i = g % VOXELS_PER_BLOCK;
    let s = stride(d);
    let c = (i / s) % VOXELS_PER_SIDE;
    if (c > 0u) {
        return g - s;
    }
    let nb = neighbors[b * 6u + 2u * d + 1u];
    if (nb == NONE) {
        return NONE;
    }
    return nb * VOXELS_PER_BLOCK + i + (VOXELS_PER_SIDE - 1u) * s;
}
