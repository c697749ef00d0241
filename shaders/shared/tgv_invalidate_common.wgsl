// Shared by tgv_occluded.wgsl and tgv_invalidate.wgsl, the GPU variational matcher's
// invalidation (CPU twin: `TgvMatcher::invalidate_with` and `occluded` in src/depth/tgv.rs):
// the uniforms and bindings. Keep InvalidateUniforms in sync with src/gpu/layout.rs.

struct InvalidateUniforms {
    width: u32,
    height: u32,
    num_disparities: u32,
    min_disparity_px: f32,
    // 0: none, 1: visible, 2: all (HoleFill).
    hole_fill: u32,
    occlusion_tolerance_px: f32,
    // max_cost_fraction · max_cost, the host's f32.
    max_bits: f32,
    // The census's bits: the largest cost.
    max_cost: u32,
}

@group(0) @binding(0) var<uniform> params: InvalidateUniforms;
// Costs of pixel i, slice k at byte i·num_disparities + k, 4 per word.
@group(0) @binding(1) var<storage, read> volume: array<u32>;
// The TGV primal [u, v1, v2] per pixel.
@group(0) @binding(2) var<storage, read> primal: array<f32>;
// SGM's disparities (bits, NaN where invalid) and confidences.
@group(0) @binding(3) var<storage, read> sgm_disparity: array<u32>;
@group(0) @binding(4) var<storage, read> sgm_confidence: array<f32>;
// The result: disparity bits (tgv_occluded.wgsl leaves each pixel's occlusion flag there for
// tgv_invalidate.wgsl, which reads it and overwrites it) and confidences.
@group(0) @binding(5) var<storage, read_write> disparity: array<u32>;
@group(0) @binding(6) var<storage, read_write> confidence: array<f32>;
