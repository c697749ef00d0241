// SGM's winner selection (CPU twin: `RowSelect::finish` and `winner` in
// src/depth/aggregate/select.rs): winner-take-all over S (the first slice of the smallest sum),
// the uniqueness test against the smallest sum more than one slice away, the sub-pixel fit (on
// S, or on the raw costs summed over a window), the left–right check against the right image's
// winners (sgm_right.wgsl) and the confidence. Integer until the fit; the fit's and the
// confidence's divisions are the device's (IEEE on llvmpipe, within 2.5 ULP elsewhere). One
// invocation per pixel; NaN where invalid. Shared files and bindings: src/gpu/shaders.rs.

@group(0) @binding(0) var<uniform> params: SgmSelectUniforms;
@group(0) @binding(1) var<storage, read> sums: array<u32>;
// u8 costs, 4 per word (the raw costs of the windowed fit).
@group(0) @binding(2) var<storage, read> volume: array<u32>;
@group(0) @binding(3) var<storage, read> right_k: array<u32>;
@group(0) @binding(4) var<storage, read_write> disparity: array<f32>;
@group(0) @binding(5) var<storage, read_write> confidence: array<f32>;

fn nan() -> f32 {
    return bitcast<f32>(0x7fc00000u);
}

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
    disparity[i] = nan();
    confidence[i] = 0.0;
    let xr = i32(x) - params.min_disparity_px - i32(bk);
    if (xr < 0 || xr >= i32(w)) {
        return;
    }
    let uniq = params.uniqueness;
    if (uniq > 0.0 && f32(second) * (1.0 - uniq) < f32(best)) {
        return;
    }
    var d = f32(params.min_disparity_px + i32(bk));
    if (bk > 0u && bk + 1u < nd) {
        var a = f32(sum_at(base + bk - 1u));
        var b = f32(best);
        var c = f32(sum_at(base + bk + 1u));
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
            a = f32(abc.x);
            b = f32(abc.y);
            c = f32(abc.z);
        }
        var offset = 0.0;
        if (params.subpixel == 1u) {
            let den = a - 2.0 * b + c;
            if (den > 0.0) {
                offset = (a - c) / (2.0 * den);
            }
        } else if (params.subpixel == 2u) {
            let den = max(a, c) - b;
            if (den > 0.0) {
                offset = (a - c) / (2.0 * den);
            }
        }
        d = d + clamp(offset, -0.5, 0.5);
    }
    var conf = 0.0;
    if (second != NO_SLICE && second != 0u) {
        conf = f32(second - min(second, best)) / f32(second);
    }
    if (params.lr_max_diff != NO_SLICE) {
        let rk = right_k[y * w + (w - 1u - u32(xr))];
        let diff = max(rk, bk) - min(rk, bk);
        if (rk == NO_SLICE || diff > params.lr_max_diff) {
            return;
        }
    }
    disparity[i] = d;
    confidence[i] = conf;
}
