// The diffusion tensors of TGV-tensor from the left image, on the device where the census read
// it (CPU twin: `diffusion_tensors` in src/depth/tgv/operators.rs, whose f32 operations this
// repeats in order; `exp` and `pow` are the device's, within a few ULP of the CPU's): central
// differences of the grey levels / 255 (one-sided at the borders), n = ∇I/|∇I|,
// k = 1 − exp(−γ|∇I|^β), T = I − k n nᵀ as [t11, t12, t22]; the identity where |∇I| < 1e-6.
// One invocation per pixel. Keep TensorUniforms in sync with src/gpu/layout.rs.
// Shared files and bindings: src/gpu/shaders.rs.

struct TensorUniforms {
    width: u32,
    height: u32,
    gamma: f32,
    beta: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
    _pad3: u32,
}

@group(0) @binding(0) var<uniform> params: TensorUniforms;
// Grey levels, 4 per word, row-major.
@group(0) @binding(1) var<storage, read> image: array<u32>;
// Three floats per pixel.
@group(0) @binding(2) var<storage, read_write> tensors: array<f32>;

fn level(x: u32, y: u32) -> f32 {
    let j = y * params.width + x;
    return f32(packed_byte(image[j >> 2u], j)) / 255.0;
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
    let xl = select(0u, x - 1u, x > 0u);
    let xr = min(x + 1u, w - 1u);
    let yu = select(0u, y - 1u, y > 0u);
    let yd = min(y + 1u, h - 1u);
    var gx = 0.0;
    if (xr > xl) {
        gx = (level(xr, y) - level(xl, y)) / f32(xr - xl);
    }
    var gy = 0.0;
    if (yd > yu) {
        gy = (level(x, yd) - level(x, yu)) / f32(yd - yu);
    }
    let norm = sqrt(gx * gx + gy * gy);
    var t = vec3<f32>(1.0, 0.0, 1.0);
    if (norm >= 1e-6) {
        let n1 = gx / norm;
        let n2 = gy / norm;
        let k = 1.0 - exp(-params.gamma * pow(norm, params.beta));
        t = vec3<f32>(1.0 - k * n1 * n1, -k * n1 * n2, 1.0 - k * n2 * n2);
    }
    tensors[3u * i] = t.x;
    tensors[3u * i + 1u] = t.y;
    tensors[3u * i + 2u] = t.z;
}
