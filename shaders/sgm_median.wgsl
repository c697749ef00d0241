// SGM's 3×3 median over valid neighbours (CPU twin: `median_filter_3x3` in
// src/depth/sgm/filters.rs): every valid pixel becomes the median of the valid values of its
// 3×3 neighbourhood (an even count averages the two middle ones, 0.5 · (lo + hi) as the CPU
// computes it); invalid (NaN) pixels stay as they are. Values are ordered as `f32::total_cmp`
// orders them, through the same integer keys. One invocation per pixel. Shared files and
// bindings: src/gpu/shaders.rs.

@group(0) @binding(0) var<uniform> params: SgmFilterUniforms;
@group(0) @binding(1) var<storage, read> disparity_in: array<u32>;
@group(0) @binding(2) var<storage, read_write> disparity_out: array<u32>;

// `total_order_key`: an i32 whose order is total_cmp's (its own inverse on the bits).
fn total_order_key(b: u32) -> i32 {
    let k = bitcast<i32>(b);
    return k ^ bitcast<i32>(bitcast<u32>(k >> 31u) >> 1u);
}

// Above the key of every value (+∞'s is 0x7f800000); NaN has no key here.
const INVALID_KEY: i32 = 0x7fffffff;

fn value_bits(key: i32) -> u32 {
    return bitcast<u32>(total_order_key(bitcast<u32>(key)));
}

// The key of pixel (x, y), or INVALID_KEY outside the image or where the value is NaN.
fn key_at(x: i32, y: i32) -> i32 {
    if (x < 0 || y < 0 || x >= i32(params.width) || y >= i32(params.height)) {
        return INVALID_KEY;
    }
    let v = disparity_in[u32(y) * params.width + u32(x)];
    if (is_nan_bits(v)) {
        return INVALID_KEY;
    }
    return total_order_key(v);
}

fn count_valid(a: i32, b: i32, c: i32) -> u32 {
    return select(0u, 1u, a != INVALID_KEY) + select(0u, 1u, b != INVALID_KEY)
        + select(0u, 1u, c != INVALID_KEY);
}

// Orders two keys.
fn ce(a: ptr<function, i32>, b: ptr<function, i32>) {
    let lo = min(*a, *b);
    let hi = max(*a, *b);
    *a = lo;
    *b = hi;
}

// k[m], by selects (no dynamic index).
fn pick(k: array<i32, 9>, m: u32) -> i32 {
    var out = k[0];
    out = select(out, k[1], m == 1u);
    out = select(out, k[2], m == 2u);
    out = select(out, k[3], m == 3u);
    out = select(out, k[4], m == 4u);
    out = select(out, k[5], m == 5u);
    out = select(out, k[6], m == 6u);
    out = select(out, k[7], m == 7u);
    out = select(out, k[8], m == 8u);
    return out;
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
    let centre = disparity_in[i];
    if (is_nan_bits(centre)) {
        disparity_out[i] = centre;
        return;
    }
    let x = i32(i % w);
    let y = i32(i / w);
    // The 3×3 neighbourhood's keys, an invalid or missing neighbour as INVALID_KEY (above every
    // value's key), sorted by a fixed network of 25 compare-exchanges: the first n are then
    // the n valid values in order (the order of a set of integers is unique: the CPU's sorting
    // network gives the same). No dynamic index into a local array: llvmpipe (LLVM 15) on an
    // AVX-512 host miscompiled the insertion sort into one that this replaced.
    var k0 = key_at(x - 1, y - 1);
    var k1 = key_at(x, y - 1);
    var k2 = key_at(x + 1, y - 1);
    var k3 = key_at(x - 1, y);
    var k4 = key_at(x, y);
    var k5 = key_at(x + 1, y);
    var k6 = key_at(x - 1, y + 1);
    var k7 = key_at(x, y + 1);
    var k8 = key_at(x + 1, y + 1);
    let n = count_valid(k0, k1, k2) + count_valid(k3, k4, k5) + count_valid(k6, k7, k8);
    ce(&k0, &k1);
    ce(&k3, &k4);
    ce(&k6, &k7);
    ce(&k1, &k2);
    ce(&k4, &k5);
    ce(&k7, &k8);
    ce(&k0, &k1);
    ce(&k3, &k4);
    ce(&k6, &k7);
    ce(&k0, &k3);
    ce(&k3, &k6);
    ce(&k0, &k3);
    ce(&k1, &k4);
    ce(&k4, &k7);
    ce(&k1, &k4);
    ce(&k2, &k5);
    ce(&k5, &k8);
    ce(&k2, &k5);
    ce(&k1, &k3);
    ce(&k5, &k7);
    ce(&k2, &k6);
    ce(&k4, &k6);
    ce(&k2, &k4);
    ce(&k2, &k3);
    ce(&k5, &k6);
    let hi = value_bits(pick(array<i32, 9>(k0, k1, k2, k3, k4, k5, k6, k7, k8), n / 2u));
    if (n % 2u == 1u) {
        disparity_out[i] = hi;
        return;
    }
    let lo = value_bits(pick(array<i32, 9>(k0, k1, k2, k3, k4, k5, k6, k7, k8), n / 2u - 1u));
    disparity_out[i] = bitcast<u32>(0.5 * (bitcast<f32>(lo) + bitcast<f32>(hi)));
}
