// TV dual step: p ← (p + σ∇ū) / max(1, |p + σ∇ū|) on Ω (CPU twin: TvProblem::iterate, first
// half). Shared files and bindings: src/gpu/shaders.rs.

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let g = flat_index(wg, num_wg, local);
    if (g >= params.voxel_count) {
        return;
    }
    let m = mask[g];
    if ((m & OMEGA) == 0u) {
        return;
    }
    var grad = vec3<f32>(0.0, 0.0, 0.0);
    for (var d = 0u; d < 3u; d = d + 1u) {
        if ((m & (1u << d)) != 0u) {
            let h = forward(g, d);
            if (h != NONE) {
                grad[d] = ubar[h] - ubar[g];
            }
        }
    }
    let n = params.voxel_count;
    let q = vec3<f32>(
        p[g] + params.sigma * grad.x,
        p[n + g] + params.sigma * grad.y,
        p[2u * n + g] + params.sigma * grad.z,
    );
    let scale = 1.0 / max(sqrt(q.x * q.x + q.y * q.y + q.z * q.z), 1.0);
    p[g] = q.x * scale;
    p[n + g] = q.y * scale;
    p[2u * n + g] = q.z * scale;
}
