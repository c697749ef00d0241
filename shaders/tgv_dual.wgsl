// TGV dual ascent and projection (CPU twin: TgvProblem::iterate in src/depth/tgv.rs, first half):
// p ← P_{|p|≤α₁}(p + σ T(∇ū − v̄)), q ← P_{|q|≤α₂}(q + σ ε(v̄)) (q skipped for TV), with the
// CPU's f32 operations in the same order. Buffers and uniforms: shared/tgv_common.wgsl
// (TgvUniforms in src/gpu/layout.rs). Shared files and bindings: src/gpu/shaders.rs.

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    let w = params.width;
    let h = params.height;
    if (i >= w * h) {
        return;
    }
    let x = i % w;
    let y = i / w;
    let c0 = primal_bar[3u * i];
    let c1 = primal_bar[3u * i + 1u];
    let c2 = primal_bar[3u * i + 2u];
    // Forward differences, 0 across the last column/row.
    var gx = 0.0;
    if (x + 1u < w) {
        gx = primal_bar[3u * (i + 1u)] - c0;
    }
    var gy = 0.0;
    if (y + 1u < h) {
        gy = primal_bar[3u * (i + w)] - c0;
    }
    let t = apply_tensor(i, vec2<f32>(gx - c1, gy - c2));
    let p1 = dual[5u * i] + params.sigma * t.x;
    let p2 = dual[5u * i + 1u] + params.sigma * t.y;
    let s = max(sqrt(p1 * p1 + p2 * p2) / params.alpha1, 1.0);
    dual[5u * i] = p1 / s;
    dual[5u * i + 1u] = p2 / s;
    if (params.tv != 0u) {
        return;
    }
    // Symmetrised gradient of v̄, backward differences (the centre stands in across the first
    // column/row): [ε11, ε22, ε12].
    var l1 = c1;
    var l2 = c2;
    if (x > 0u) {
        l1 = primal_bar[3u * (i - 1u) + 1u];
        l2 = primal_bar[3u * (i - 1u) + 2u];
    }
    var u1 = c1;
    var u2 = c2;
    if (y > 0u) {
        u1 = primal_bar[3u * (i - w) + 1u];
        u2 = primal_bar[3u * (i - w) + 2u];
    }
    let e11 = c1 - l1;
    let e22 = c2 - u2;
    let e12 = 0.5 * ((c1 - u1) + (c2 - l2));
    let q11 = dual[5u * i + 2u] + params.sigma * e11;
    let q22 = dual[5u * i + 3u] + params.sigma * e22;
    let q12 = dual[5u * i + 4u] + params.sigma * e12;
    let sq = max(sqrt(q11 * q11 + q22 * q22 + 2.0 * q12 * q12) / params.alpha2, 1.0);
    dual[5u * i + 2u] = q11 / sq;
    dual[5u * i + 3u] = q22 / sq;
    dual[5u * i + 4u] = q12 / sq;
}
