// TGV primal descent, proximal coupling step and over-relaxation (CPU twin: TgvProblem::iterate
// in src/depth/tgv.rs, second half):
// u ← (u + τ div(T p) + (τ/θ) a) / (1 + τ/θ), v ← v + τ (T p + div_sym q) (v ≡ 0 for TV),
// ū ← 2·new − old, with the CPU's f32 operations in the same order. Buffers and uniforms:
// shared/tgv_common.wgsl (TgvUniforms in src/gpu/layout.rs). Shared files and bindings: src/gpu/shaders.rs.

// T p at pixel j.
fn tp(j: u32) -> vec2<f32> {
    return apply_tensor(j, vec2<f32>(dual[5u * j], dual[5u * j + 1u]));
}

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
    let o0 = primal[3u * i];
    let o1 = primal[3u * i + 1u];
    let o2 = primal[3u * i + 2u];
    // div = −∇ᵀ of T p (the CPU's div_at).
    var div = 0.0;
    if (x + 1u < w) {
        div = div + tp(i).x;
    }
    if (x > 0u) {
        div = div - tp(i - 1u).x;
    }
    if (y + 1u < h) {
        div = div + tp(i).y;
    }
    if (y > 0u) {
        div = div - tp(i - w).y;
    }
    let u = (o0 + params.tau * div + params.coupling * coupling_target[i]) / (1.0 + params.coupling);
    var v1 = 0.0;
    var v2 = 0.0;
    if (params.tv == 0u) {
        let t = tp(i);
        // div_sym = −εᵀ of q = [q11, q22, q12] (the CPU's sym_div_at).
        let c11 = dual[5u * i + 2u];
        let c22 = dual[5u * i + 3u];
        let c12 = dual[5u * i + 4u];
        var d1 = 0.0;
        var d2 = 0.0;
        if (x > 0u) {
            d1 = d1 + c11;
            d2 = d2 + c12;
        }
        if (x + 1u < w) {
            d1 = d1 - dual[5u * (i + 1u) + 2u];
            d2 = d2 - dual[5u * (i + 1u) + 4u];
        }
        if (y > 0u) {
            d1 = d1 + c12;
            d2 = d2 + c22;
        }
        if (y + 1u < h) {
            d1 = d1 - dual[5u * (i + w) + 4u];
            d2 = d2 - dual[5u * (i + w) + 3u];
        }
        v1 = o1 + params.tau * (t.x + -d1);
        v2 = o2 + params.tau * (t.y + -d2);
    }
    primal[3u * i] = u;
    primal[3u * i + 1u] = v1;
    primal[3u * i + 2u] = v2;
    primal_bar[3u * i] = 2.0 * u - o0;
    primal_bar[3u * i + 1u] = 2.0 * v1 - o1;
    primal_bar[3u * i + 2u] = 2.0 * v2 - o2;
}
