// A fresh TGV problem on the device (CPU twin: `TgvProblem::new`): primal [u0, 0, 0] with u0
// the values in `coupling_target` (where the host wrote them; the first point-wise search
// overwrites them), the over-relaxed primal equal to it, the dual zero, and with
// `identity_tensors` the identity tensors of TV and TGV. So a fresh problem sends 4 bytes per
// pixel up, not its 40-byte state and 12-byte tensors. One invocation per pixel; the bindings are
// the iterations' (shared/tgv_common.wgsl). Shared files and bindings: src/gpu/shaders.rs.

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    if (i >= params.width * params.height) {
        return;
    }
    let u0 = coupling_target[i];
    for (var c = 0u; c < 3u; c++) {
        let value = select(0.0, u0, c == 0u);
        primal[3u * i + c] = value;
        primal_bar[3u * i + c] = value;
    }
    for (var c = 0u; c < 5u; c++) {
        dual[5u * i + c] = 0.0;
    }
    if (params.identity_tensors == 1u) {
        tensors[3u * i] = 1.0;
        tensors[3u * i + 1u] = 0.0;
        tensors[3u * i + 2u] = 1.0;
    }
}
