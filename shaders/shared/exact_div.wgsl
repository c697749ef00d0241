// Integer quotients rounded as the CPU's f32 division rounds them (to nearest, ties to even),
// computed in integers: WGSL lets a device divide floats within 2.5 ULP, so a quotient the host
// would compute as `n as f32 / d as f32` (both exact in f32: |n|, d < 2^24) is computed here by
// long division instead. CPU twin: that f32 division (tests/gpu/sgm.rs compares every pixel).

// The f32 nearest to n / d, ties to even; d > 0, |n| < 2^31.
fn div_rounded(n: i32, d: u32) -> f32 {
    if (n == 0) {
        return 0.0;
    }
    let a = u32(abs(n));
    // The quotient is m · 2^-f with m brought to 26 bits: 24 kept, a rounding bit and one
    // more; `sticky` says whether anything below them is non-zero.
    var m = a / d;
    var r = a % d;
    var f = 0;
    var sticky = 0u;
    while (m >= 0x4000000u) {
        sticky = sticky | (m & 1u);
        m = m >> 1u;
        f = f - 1;
    }
    while (m < 0x2000000u) {
        r = r << 1u;
        m = m << 1u;
        if (r >= d) {
            m = m | 1u;
            r = r - d;
        }
        f = f + 1;
    }
    sticky = sticky | (m & 1u) | select(0u, 1u, r != 0u);
    var keep = m >> 2u;
    if (((m >> 1u) & 1u) == 1u && (sticky == 1u || (keep & 1u) == 1u)) {
        keep = keep + 1u;
    }
    // keep ≤ 2^24: exact in f32, and so is the scaling of a normal value.
    let q = ldexp(f32(keep), 2 - f);
    return select(q, -q, n < 0);
}
