// Shared by tgv_dual.wgsl and tgv_primal.wgsl (CPU twin: TgvProblem::iterate in
// src/depth/tgv.rs): uniforms, bindings (one layout for both kernels) and the tensor product.
// Keep TgvUniforms in sync with src/gpu/layout.rs; the arrays keep TgvProblem's layout.

struct TgvUniforms {
    width: u32,
    height: u32,
    // 1 for TV (v ≡ 0, no q), 0 for TGV.
    tv: u32,
    // 1: tgv_init.wgsl also writes identity tensors (read by no other kernel).
    identity_tensors: u32,
    sigma: f32,
    tau: f32,
    alpha1: f32,
    alpha2: f32,
    // τ/θ (computed on the CPU, as there).
    coupling: f32,
    pad1: u32,
    pad2: u32,
    pad3: u32,
}

@group(0) @binding(0) var<uniform> params: TgvUniforms;
// Diffusion tensor [t11, t12, t22] per pixel (written only by tgv_init.wgsl, for identities).
@group(0) @binding(1) var<storage, read_write> tensors: array<f32>;
// Coupling target a per pixel, pixels.
@group(0) @binding(2) var<storage, read> coupling_target: array<f32>;
// Primal [u, v1, v2] per pixel.
@group(0) @binding(3) var<storage, read_write> primal: array<f32>;
// Over-relaxed primal, same layout.
@group(0) @binding(4) var<storage, read_write> primal_bar: array<f32>;
// Dual [p1, p2, q11, q22, q12] per pixel.
@group(0) @binding(5) var<storage, read_write> dual: array<f32>;

// T g for the tensor of pixel i (the CPU's `apply`, same operation order).
fn apply_tensor(i: u32, g: vec2<f32>) -> vec2<f32> {
    let t11 = tensors[3u * i];
    let t12 = tensors[3u * i + 1u];
    let t22 = tensors[3u * i + 2u];
    return vec2<f32>(t11 * g.x + t12 * g.y, t12 * g.x + t22 * g.y);
}
