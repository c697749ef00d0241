// Depth from disparity, one invocation per pixel, as the CPU's `disparity_to_depth` in
// src/depth/mod.rs computes it: z = f·B / d in f64, rounded to f32 (NaN where d is not a
// positive finite number). The device has no f64 and may divide floats within 2.5 ULP, so the
// quotient is taken in integers: ⌊M·2²⁷ / m⌋ by restoring division (f·B = M·2^E, M 53 bits;
// d = m·2^e, m 24 bits), rounded to 53 bits (to nearest, ties to even: the f64 quotient), then
// to 24 (the cast to f32: the same double rounding). CPU twin: `disparity_to_depth`, equal bit
// for bit (tests/gpu/disparity_depth.rs). Keep `DisparityDepthUniforms` in sync with
// src/gpu/layout.rs. Shared files and bindings: src/gpu/shaders.rs.

struct DisparityDepthUniforms {
    pixels: u32,
    // f·B = M · 2^fb_exp, M = fb_high · 2³² + fb_low (53 bits, the top one set).
    fb_exp: i32,
    fb_low: u32,
    fb_high: u32,
}

@group(0) @binding(0) var<uniform> params: DisparityDepthUniforms;
// Disparity bits, pixels.
@group(0) @binding(1) var<storage, read> disparity: array<u32>;
// Depth bits, metres.
@group(0) @binding(2) var<storage, read_write> depth: array<u32>;

// (low, high) >> k, 0 < k < 32.
fn shift_right(x: vec2<u32>, k: u32) -> vec2<u32> {
    return vec2<u32>((x.x >> k) | (x.y << (32u - k)), x.y >> k);
}

fn depth_bits(db: u32) -> u32 {
    // Not a positive finite number (negative ones have the sign bit): NaN.
    if (db == 0u || db >= 0x7f800000u) {
        return NAN_BITS;
    }
    // d = m · 2^(e − 150), m brought to 24 bits.
    var e = i32((db >> 23u) & 0xffu);
    var m = db & 0x7fffffu;
    if (e == 0) {
        e = 1;
        while ((m & 0x800000u) == 0u) {
            m = m << 1u;
            e = e - 1;
        }
    } else {
        m = m | 0x800000u;
    }
    // Q = ⌊N / m⌋ for N = M · 2²⁷ (80 bits), most significant bit first; Q in (2⁵⁵, 2⁵⁷).
    var rem = 0u;
    var q = vec2<u32>(0u, 0u);
    for (var pos = 79; pos >= 0; pos = pos - 1) {
        var bit = 0u;
        if (pos >= 59) {
            bit = (params.fb_high >> u32(pos - 59)) & 1u;
        } else if (pos >= 27) {
            bit = (params.fb_low >> u32(pos - 27)) & 1u;
        }
        rem = (rem << 1u) | bit;
        q = vec2<u32>(q.x << 1u, (q.y << 1u) | (q.x >> 31u));
        if (rem >= m) {
            rem = rem - m;
            q.x = q.x | 1u;
        }
    }
    // The f64 quotient: Q's top 53 bits, to nearest, ties to even. Q's top bit is 55 or 56.
    let k = select(3u, 4u, (q.y >> 24u) != 0u);
    let half = 1u << (k - 1u);
    let dropped = q.x & ((1u << k) - 1u);
    var m64 = shift_right(q, k);
    let above_half = (dropped & (half - 1u)) != 0u || rem != 0u;
    if ((dropped & half) != 0u && (above_half || (m64.x & 1u) == 1u)) {
        m64.x = m64.x + 1u;
        if (m64.x == 0u) {
            m64.y = m64.y + 1u;
        }
    }
    // z = m64 · 2^x.
    var x = i32(k) + params.fb_exp - 27 - (e - 150);
    if (m64.y == 0x200000u) {
        // Rounded up to 2⁵³.
        m64 = vec2<u32>(0u, 0x100000u);
        x = x + 1;
    }
    // The cast to f32: the top 24 of the 53 bits, to nearest, ties to even.
    var mant = (m64.y << 3u) | (m64.x >> 29u);
    var x32 = x + 29;
    let round_bit = (m64.x >> 28u) & 1u;
    let rest = (m64.x & 0x0fffffffu) != 0u;
    if (round_bit == 1u && (rest || (mant & 1u) == 1u)) {
        mant = mant + 1u;
        if (mant == 0x1000000u) {
            mant = 0x800000u;
            x32 = x32 + 1;
        }
    }
    // z = mant · 2^x32, mant in [2²³, 2²⁴): biased exponent x32 + 150. Beyond f32: infinity,
    // as the cast gives; below the normal range cannot happen (the host keeps f·B ≥ 8).
    let biased = x32 + 150;
    if (biased >= 255) {
        return 0x7f800000u;
    }
    return (u32(biased) << 23u) | (mant & 0x7fffffu);
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    if (i >= params.pixels) {
        return;
    }
    depth[i] = depth_bits(disparity[i]);
}
