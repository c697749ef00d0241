// SGM's winner selection (CPU twin: `RowSelect::finish` and `winner` in
// src/depth/aggregate/select.rs): winner-take-all over S (the first slice of the smallest sum)
// and the smallest sum more than one slice away, the sub-pixel fit's terms (on S, or on the raw
// costs summed over a window), the left–right check against the right image's winners
// (sgm_right.wgsl). Integers only: the uniqueness test and the fit's and the confidence's
// divisions (f32) are left to the host (`decode_selection` in src/depth/gpu/sgm.rs), which divides as
// the CPU matcher does, so the disparities are the CPU's bit for bit on every device (WGSL lets a
// device divide within 2.5 ULP). One invocation per pixel, four words out:
//   0: the winning slice, or INVALID (matched outside the right image, or inconsistent);
//   1: the fit's numerator a − c (i32);  2: its denominator 2·den (0: no fit);
//   3: the runner-up's sum << 16 | the winner's sum (the confidence's terms).
// Shared files and bindings: src/gpu/shaders.rs.

@group(0) @binding(0) var<uniform> params: SgmSelectUniforms;
@group(0) @binding(1) var<storage, read> sums: array<u32>;
// u8 costs, 4 per word (the raw costs of the windowed fit).
@group(0) @binding(2) var<storage, read> volume: array<u32>;
@group(0) @binding(3) var<storage, read> right_k: array<u32>;
@group(0) @binding(4) var<storage, read_write> selection: array<u32>;

const INVALID: u32 = 0xffffffffu;

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
    let out = i * 4u;
    selection[out] = INVALID;
    selection[out + 1u] = 0u;
    selection[out + 2u] = 0u;
    selection[out + 3u] = (second << 16u) | best;
    let xr = i32(x) - params.min_disparity_px - i32(bk);
    if (xr < 0 || xr >= i32(w)) {
        return;
    }
    if (params.lr_max_diff != NO_SLICE) {
        let rk = right_k[y * w + (w - 1u - u32(xr))];
        let diff = max(rk, bk) - min(rk, bk);
        if (rk == NO_SLICE || diff > params.lr_max_diff) {
            return;
        }
    }
    selection[out] = bk;
    if (params.subpixel == 0u || bk == 0u || bk + 1u >= nd) {
        return;
    }
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
    // Parabola: a − 2b + c; equiangular: max(a, c) − b (the CPU's, exact in f32 for these sums).
    var den = max(a, c) - b;
    if (params.subpixel == 1u) {
        den = a - 2 * b + c;
    }
    if (den > 0) {
        selection[out + 1u] = bitcast<u32>(a - c);
        selection[out + 2u] = u32(2 * den);
    }
}
