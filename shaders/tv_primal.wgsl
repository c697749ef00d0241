// TV primal step and relaxation (CPU twin: TvProblem::iterate, second half):
// u ← (u + τ div p + τλ w f) / (1 + τλ w), ū ← u_new + θ (u_new − u_old), with div = −∇ᵀ.
// Shared files and bindings: src/gpu/shaders.rs.

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
    let n = params.voxel_count;
    var div = 0.0;
    for (var d = 0u; d < 3u; d = d + 1u) {
        if ((m & (1u << d)) != 0u) {
            div = div + p[d * n + g];
        }
        if ((m & (1u << (3u + d))) != 0u) {
            let h = backward(g, d);
            if (h != NONE) {
                div = div - p[d * n + h];
            }
        }
    }
    let tlw = params.tau * params.lambda * w[g];
    let old = u[g];
    let new_u = (old + params.tau * div + tlw * f[g]) / (1.0 + tlw);
    u[g] = new_u;
    ubar[g] = new_u + params.theta * (new_u - old);
}
