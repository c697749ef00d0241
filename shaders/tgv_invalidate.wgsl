// The GPU variational matcher's invalidation and confidence (CPU twin:
// `TgvMatcher::invalidate_with` in src/depth/tgv.rs), after tgv_occluded.wgsl: a pixel keeps
// its regularized disparity u where SGM found one, or where the hole-filling rule admits it
// (visible: not occluded and its census cost at u, read from the volume at u's nearest slice as
// tgv_cost_at.wgsl reads it, at most max_bits; all: always, even matched outside the right
// image); its confidence is SGM's or the match quality 1 − cost / max_cost where SGM agrees
// within a pixel, half the match quality where it does not. The quotient is rounded as the
// CPU's f32 division rounds it (shared/exact_div.wgsl), so the map is the CPU's bit for bit
// given the same u. One invocation per pixel. Shared files and bindings: src/gpu/shaders.rs.

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    let w = params.width;
    if (i >= w * params.height) {
        return;
    }
    let occluded = disparity[i] == 1u;
    disparity[i] = NAN_BITS;
    confidence[i] = 0.0;
    let d = primal[3u * i];
    if (!is_finite_bits(bitcast<u32>(d)) || (params.hole_fill != 2u && f32(i % w) - d < -0.5)) {
        return;
    }
    let k = slice_of(d, params.min_disparity_px, params.num_disparities);
    let j = i * params.num_disparities + k;
    let c = packed_byte(volume[j >> 2u], j);
    let s = sgm_disparity[i];
    let sgm_valid = is_finite_bits(s);
    let agrees = sgm_valid && abs(bitcast<f32>(s) - d) <= 1.0;
    let visible = params.hole_fill == 1u && !occluded && f32(c) <= params.max_bits;
    if (!(sgm_valid || visible || params.hole_fill == 2u)) {
        return;
    }
    disparity[i] = bitcast<u32>(d);
    let quality = clamp(1.0 - div_rounded(i32(c), params.max_cost), 0.0, 1.0);
    confidence[i] = select(0.5 * quality, max(sgm_confidence[i], quality), agrees);
}
