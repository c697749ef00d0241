// SGM's winner selection (CPU twin: `RowSelect::finish` and `winner` in
// src/depth/aggregate/select.rs): winner-take-all over S (the first slice of the smallest sum)
// and the smallest sum more than one slice away, the uniqueness test, the sub-pixel fit (on S,
// or on the raw costs summed over a window), the left–right check against the right image's
// winners (sgm_right.wgsl), and the confidence. The sums and the fit's terms are integers; the
// fit's offset (a − c) / (2·den) and the confidence (S_second − S_best) / S_second are rounded
// as the CPU's f32 divisions round them (shared/exact_div.wgsl), so the disparities and
// confidences are the CPU's bit for bit on every device. One invocation per pixel; out: the
// disparity's bits (the CPU's NaN, 0x7fc00000, where invalid) and the confidence (0 there).
// Shared files and bindings: src/gpu/shaders.rs.

@group(0) @binding(0) var<uniform> params: SgmSelectUniforms;
@group(0) @binding(1) var<storage, read> sums: array<u32>;
// u8 costs, 4 per word (the raw costs of the windowed fit).
@group(0) @binding(2) var<storage, read> volume: array<u32>;
@group(0) @binding(3) var<storage, read> right_k: array<u32>;
@group(0) @binding(4) var<storage, read_write> disparity: array<u32>;
@group(0) @binding(5) var<storage, read_write> confidence: array<f32>;

fn raw_at(e: u32) -> u32 {
    return packed_byte(volume[e >> 2u], e);
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
    let nd = params.num_disparities;
    let base = i * nd;
    var best = NO_SLICE + 1u;
    var bk = 0u;
    for (var k = 0u; k < nd; k = k + 1u) {
        let v = sum_at(base + k);
        if (v < best) {
            best = v;
            bk = k;
        }
    }
    var second = NO_SLICE;
    for (var k = 0u; k < nd; k = k + 1u) {
        if (k + 1u < bk || k > bk + 1u) {
            second = min(second, sum_at(base + k));
        }
    }
    disparity[i] = NAN_BITS;
    confidence[i] = 0.0;
    let xr = i32(x) - params.min_disparity_px - i32(bk);
    if (xr < 0 || xr >= i32(w)) {
        return;
    }
    if (f32(second) * params.uniqueness_factor < f32(best)) {
        return;
    }
    if (params.lr_max_diff != NO_SLICE) {
        let rk = right_k[y * w + (w - 1u - u32(xr))];
        let diff = max(rk, bk) - min(rk, bk);
        if (rk == NO_SLICE || diff > params.lr_max_diff) {
            return;
        }
    }
    var d = f32(params.min_disparity_px + i32(bk));
    if (params.subpixel != 0u && bk > 0u && bk + 1u < nd) {
        var a = i32(sum_at(base + bk - 1u));
        var b = i32(best);
        var c = i32(sum_at(base + bk + 1u));
        let r = params.radius;
        if (r > 0u) {
            var abc = vec3<u32>(0u, 0u, 0u);
            let y0 = select(0u, y - r, y >= r);
            let y1 = min(y + r + 1u, h);
            let x0 = select(0u, x - r, x >= r);
            let x1 = min(x + r + 1u, w);
            for (var yy = y0; yy < y1; yy = yy + 1u) {
                for (var xx = x0; xx < x1; xx = xx + 1u) {
                    let e = (yy * w + xx) * nd + bk - 1u;
                    abc = abc + vec3<u32>(raw_at(e), raw_at(e + 1u), raw_at(e + 2u));
                }
            }
            a = i32(abc.x);
            b = i32(abc.y);
            c = i32(abc.z);
        }
        // Parabola: a − 2b + c; equiangular: max(a, c) − b (the CPU's, exact in f32 for these
        // sums).
        var den = max(a, c) - b;
        if (params.subpixel == 1u) {
            den = a - 2 * b + c;
        }
        if (den > 0) {
            d = d + clamp(div_rounded(a - c, u32(2 * den)), -0.5, 0.5);
        }
    }
    disparity[i] = bitcast<u32>(d);
    if (second != NO_SLICE && second != 0u) {
        confidence[i] = div_rounded(i32(second - min(best, second)), second);
    }
}
