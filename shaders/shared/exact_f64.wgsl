// Binary64 (the CPU's f64) arithmetic in 32-bit integers, rounded as IEEE 754 rounds (to
// nearest, ties to even), so that a kernel reproduces the CPU's f64 values bit for bit on any
// device: a device's own f64, where it has one, may fuse a multiply with an add, or divide
// within some ULPs. CPU twin: Rust's f64 (`tests/gpu/exact_f64.rs` compares every operation).
// A value is its f64's bits, `vec2<u32>(low word, high word)`. Zeros (with their signs),
// subnormal and normal values are exact; an infinite or NaN operand, an overflow, a division
// by zero or a floor beyond i32 sets `f64_status`, which the kernel reports (the CPU's values
// are finite where this is used).

var<private> f64_status: u32 = 0u;

// An unsigned 64-bit integer as (low word, high word).
fn u64_add(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.x + b.x;
    return vec2<u32>(lo, a.y + b.y + select(0u, 1u, lo < a.x));
}

fn u64_sub(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    return vec2<u32>(a.x - b.x, a.y - b.y - select(0u, 1u, a.x < b.x));
}

fn u64_less(a: vec2<u32>, b: vec2<u32>) -> bool {
    return a.y < b.y || (a.y == b.y && a.x < b.x);
}

fn u64_is_zero(a: vec2<u32>) -> bool {
    return a.x == 0u && a.y == 0u;
}

// a << n, n < 64 (WGSL shifts by n mod 32, so the word boundary is handled apart).
fn u64_shl(a: vec2<u32>, n: u32) -> vec2<u32> {
    if (n == 0u) {
        return a;
    }
    if (n >= 32u) {
        return vec2<u32>(0u, a.x << (n - 32u));
    }
    return vec2<u32>(a.x << n, (a.y << n) | (a.x >> (32u - n)));
}

// a >> n (any n), with bit 0 set where a non-zero bit was shifted out ("sticky"): below a
// rounding point two bits up or more, it decides as the exact value does.
fn u64_shr_sticky(a: vec2<u32>, n: u32) -> vec2<u32> {
    if (n == 0u) {
        return a;
    }
    if (n >= 64u) {
        return vec2<u32>(select(0u, 1u, !u64_is_zero(a)), 0u);
    }
    var r: vec2<u32>;
    var lost: u32;
    if (n >= 32u) {
        let m = n - 32u;
        if (m == 0u) {
            r = vec2<u32>(a.y, 0u);
            lost = a.x;
        } else {
            r = vec2<u32>(a.y >> m, 0u);
            lost = a.x | (a.y << (32u - m));
        }
    } else {
        r = vec2<u32>((a.x >> n) | (a.y << (32u - n)), a.y >> n);
        lost = a.x << (32u - n);
    }
    return vec2<u32>(r.x | select(0u, 1u, lost != 0u), r.y);
}

fn u64_clz(a: vec2<u32>) -> u32 {
    if (a.y != 0u) {
        return countLeadingZeros(a.y);
    }
    return 32u + countLeadingZeros(a.x);
}

// A finite value as sign, exponent and significand: (−1)^neg · m · 2^(exp − 63), m's bit 63
// set, or m = 0 for a zero.
struct F64Parts {
    neg: bool,
    exp: i32,
    m: vec2<u32>,
}

fn f64_unpack(v: vec2<u32>) -> F64Parts {
    let neg = (v.y >> 31u) == 1u;
    let e = i32((v.y >> 20u) & 0x7ffu);
    let frac = vec2<u32>(v.x, v.y & 0xfffffu);
    if (e == 0x7ff) {
        f64_status = 1u;
        return F64Parts(neg, 0, vec2<u32>(0u, 0u));
    }
    if (e == 0) {
        if (u64_is_zero(frac)) {
            return F64Parts(neg, 0, frac);
        }
        // Subnormal: frac · 2^−1074.
        let z = u64_clz(frac);
        return F64Parts(neg, -1011 - i32(z), u64_shl(frac, z));
    }
    return F64Parts(neg, e - 1023, u64_shl(vec2<u32>(frac.x, frac.y | 0x100000u), 11u));
}

fn f64_sign_bit(neg: bool) -> u32 {
    return select(0u, 0x80000000u, neg);
}

// The f64 nearest to (−1)^neg · m · 2^(exp − 63) (ties to even), m's bit 63 set; `sticky`:
// whether the exact value has non-zero bits below m's bit 0.
fn f64_round(neg: bool, exp: i32, m_in: vec2<u32>, sticky: bool) -> vec2<u32> {
    var field = exp + 1023;
    if (field >= 0x7ff) {
        f64_status = 1u;
        return vec2<u32>(0u, 0x7ff00000u | f64_sign_bit(neg));
    }
    var m = m_in;
    if (field < 1) {
        // Subnormal: the significand shifted to the fixed exponent.
        m = u64_shr_sticky(m, u32(1 - field));
        field = 0;
    }
    // 53 bits kept (the leading one included), 11 below.
    var keep = vec2<u32>((m.x >> 11u) | (m.y << 21u), m.y >> 11u);
    let rest = m.x & 0x7ffu;
    if (rest > 0x400u || (rest == 0x400u && (sticky || (keep.x & 1u) == 1u))) {
        keep = u64_add(keep, vec2<u32>(1u, 0u));
    }
    // The leading one adds 1 to the exponent field (a carry to 2^53 adds 1 more).
    var hi = keep.y;
    if (field >= 1) {
        hi = (u32(field - 1) << 20u) + keep.y;
    }
    if ((hi >> 20u) >= 0x7ffu) {
        f64_status = 1u;
        return vec2<u32>(0u, 0x7ff00000u | f64_sign_bit(neg));
    }
    return vec2<u32>(keep.x, hi | f64_sign_bit(neg));
}

// The f32 nearest to the same value (its bits): the CPU's `x as f32`.
fn f32_round(neg: bool, exp: i32, m_in: vec2<u32>, sticky: bool) -> u32 {
    var field = exp + 127;
    if (field >= 0xff) {
        f64_status = 1u;
        return 0x7f800000u | f64_sign_bit(neg);
    }
    var m = m_in;
    if (field < 1) {
        m = u64_shr_sticky(m, u32(1 - field));
        field = 0;
    }
    // 24 bits kept, 40 below: bits 39..32 in the high word, the low word whole.
    let keep = m.y >> 8u;
    let low = m.y & 0xffu;
    let above = low > 0x80u || (low == 0x80u && (m.x != 0u || sticky));
    let tie = low == 0x80u && m.x == 0u && !sticky;
    var k = keep;
    if (above || (tie && (keep & 1u) == 1u)) {
        k = k + 1u;
    }
    var bits = k;
    if (field >= 1) {
        bits = (u32(field - 1) << 23u) + k;
    }
    if ((bits >> 23u) >= 0xffu) {
        f64_status = 1u;
        bits = 0x7f800000u;
    }
    return bits | f64_sign_bit(neg);
}

fn f64_is_zero(v: vec2<u32>) -> bool {
    return v.x == 0u && (v.y & 0x7fffffffu) == 0u;
}

fn f64_neg(v: vec2<u32>) -> vec2<u32> {
    return vec2<u32>(v.x, v.y ^ 0x80000000u);
}

// The CPU's `x as f32` (bits).
fn f64_to_f32(v: vec2<u32>) -> u32 {
    let p = f64_unpack(v);
    if (u64_is_zero(p.m)) {
        return f64_sign_bit(p.neg);
    }
    return f32_round(p.neg, p.exp, p.m, false);
}

// The CPU's `x as f64` of an f32 (bits): exact.
fn f64_from_f32(b: u32) -> vec2<u32> {
    let neg = (b >> 31u) == 1u;
    let e = i32((b >> 23u) & 0xffu);
    let frac = b & 0x7fffffu;
    if (e == 0xff) {
        f64_status = 1u;
        return vec2<u32>(0u, 0u);
    }
    if (e == 0) {
        if (frac == 0u) {
            return vec2<u32>(0u, f64_sign_bit(neg));
        }
        let z = 32u + countLeadingZeros(frac);
        return f64_round(neg, -86 - i32(z), u64_shl(vec2<u32>(frac, 0u), z), false);
    }
    return f64_round(neg, e - 127, vec2<u32>(0u, (frac | 0x800000u) << 8u), false);
}

// The CPU's `n as f64`: exact.
fn f64_from_i32(n: i32) -> vec2<u32> {
    if (n == 0) {
        return vec2<u32>(0u, 0u);
    }
    let a = u32(abs(n));
    let z = 32u + countLeadingZeros(a);
    return f64_round(n < 0, 63 - i32(z), u64_shl(vec2<u32>(a, 0u), z), false);
}

fn f64_add(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let x = f64_unpack(a);
    let y = f64_unpack(b);
    if (u64_is_zero(y.m)) {
        if (u64_is_zero(x.m)) {
            // (−0) + (−0) = −0; any other sum of zeros is +0.
            return vec2<u32>(0u, f64_sign_bit(x.neg && y.neg));
        }
        return a;
    }
    if (u64_is_zero(x.m)) {
        return b;
    }
    var big = x;
    var small = y;
    if (y.exp > x.exp || (y.exp == x.exp && u64_less(x.m, y.m))) {
        big = y;
        small = x;
    }
    // Bit 62 of `mb` stands for 2^big.exp (bit 63 is room for a carry); the smaller is aligned
    // with a sticky bit, exact where it matters (a cancellation of more than a bit needs
    // exponents at most one apart, and then nothing is shifted out).
    let mb = u64_shr_sticky(big.m, 1u);
    let ms = u64_shr_sticky(small.m, 1u + u32(big.exp - small.exp));
    var m: vec2<u32>;
    if (big.neg == small.neg) {
        m = u64_add(mb, ms);
    } else {
        m = u64_sub(mb, ms);
    }
    if (u64_is_zero(m)) {
        return vec2<u32>(0u, 0u);
    }
    let z = u64_clz(m);
    return f64_round(big.neg, big.exp + 1 - i32(z), u64_shl(m, z), false);
}

fn f64_sub(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    return f64_add(a, f64_neg(b));
}

// The 64-bit product of two words.
fn u32_mul_wide(a: u32, b: u32) -> vec2<u32> {
    let al = a & 0xffffu;
    let ah = a >> 16u;
    let bl = b & 0xffffu;
    let bh = b >> 16u;
    let ll = al * bl;
    let lh = al * bh;
    let mid = lh + ah * bl;
    let mid_carry = select(0u, 0x10000u, mid < lh);
    let lo = ll + (mid << 16u);
    let lo_carry = select(0u, 1u, lo < ll);
    return vec2<u32>(lo, ah * bh + (mid >> 16u) + mid_carry + lo_carry);
}

// w + v · 2^32 (128-bit w, no carry out of the top word).
fn u128_add_at1(w: vec4<u32>, v: vec2<u32>) -> vec4<u32> {
    let s1 = w.y + v.x;
    let c1 = select(0u, 1u, s1 < v.x);
    let t2 = w.z + v.y;
    let c2 = select(0u, 1u, t2 < v.y);
    let s2 = t2 + c1;
    let c3 = select(0u, 1u, s2 < c1);
    return vec4<u32>(w.x, s1, s2, w.w + c2 + c3);
}

fn f64_mul(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let x = f64_unpack(a);
    let y = f64_unpack(b);
    let neg = x.neg != y.neg;
    if (u64_is_zero(x.m) || u64_is_zero(y.m)) {
        return vec2<u32>(0u, f64_sign_bit(neg));
    }
    // The 53-bit significands' product, 2^104 ≤ P < 2^106, in four words.
    let p = u64_shr_sticky(x.m, 11u);
    let q = u64_shr_sticky(y.m, 11u);
    let ll = u32_mul_wide(p.x, q.x);
    let hh = u32_mul_wide(p.y, q.y);
    var w = vec4<u32>(ll.x, ll.y, hh.x, hh.y);
    w = u128_add_at1(w, u32_mul_wide(p.x, q.y));
    w = u128_add_at1(w, u32_mul_wide(p.y, q.x));
    // Its leading bit (105 or 104) brought to bit 63 of m: P >> (41 or 42).
    var lead = 104;
    var r = 9u;
    if ((w.w >> 9u) != 0u) {
        lead = 105;
        r = 10u;
    }
    let m = vec2<u32>((w.y >> r) | (w.z << (32u - r)), (w.z >> r) | (w.w << (32u - r)));
    let sticky = w.x != 0u || (w.y & ((1u << r) - 1u)) != 0u;
    return f64_round(neg, x.exp + y.exp + lead - 104, m, sticky);
}

fn f64_div(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let x = f64_unpack(a);
    let y = f64_unpack(b);
    let neg = x.neg != y.neg;
    if (u64_is_zero(y.m)) {
        f64_status = 1u;
        return vec2<u32>(0u, 0x7ff00000u | f64_sign_bit(neg));
    }
    if (u64_is_zero(x.m)) {
        return vec2<u32>(0u, f64_sign_bit(neg));
    }
    // Long division of the 53-bit significands: 64 quotient bits, bit 63 for 2^0.
    var rem = u64_shr_sticky(x.m, 11u);
    let d = u64_shr_sticky(y.m, 11u);
    var q = vec2<u32>(0u, 0u);
    for (var i = 0u; i < 64u; i = i + 1u) {
        q = u64_shl(q, 1u);
        if (!u64_less(rem, d)) {
            rem = u64_sub(rem, d);
            q.x = q.x | 1u;
        }
        rem = u64_shl(rem, 1u);
    }
    var exp = x.exp - y.exp;
    if ((q.y >> 31u) == 0u) {
        q = u64_shl(q, 1u);
        exp = exp - 1;
    }
    return f64_round(neg, exp, q, !u64_is_zero(rem));
}

// a >> n, 0 < n < 64, the bits shifted out dropped.
fn u64_shr(a: vec2<u32>, n: u32) -> vec2<u32> {
    if (n >= 32u) {
        return vec2<u32>(a.y >> (n - 32u), 0u);
    }
    return vec2<u32>((a.x >> n) | (a.y << (32u - n)), a.y >> n);
}

fn f64_sqrt(a: vec2<u32>) -> vec2<u32> {
    let x = f64_unpack(a);
    if (u64_is_zero(x.m)) {
        return a;
    }
    if (x.neg) {
        f64_status = 1u;
        return vec2<u32>(0u, 0x7ff80000u);
    }
    // a = sig · 2^e2, sig of 53 bits (54 where e2 is made even); the root of N = sig · 2^56,
    // 2^108 ≤ N < 2^110, digit by digit: 55 bits, 2^54 ≤ root < 2^55, and whether any
    // remainder is left.
    var sig = u64_shr(x.m, 11u);
    var e2 = x.exp - 52;
    if ((e2 & 1) != 0) {
        sig = u64_shl(sig, 1u);
        e2 = e2 - 1;
    }
    var rem = vec2<u32>(0u, 0u);
    var root = vec2<u32>(0u, 0u);
    for (var i = 54; i >= 0; i = i - 1) {
        // Bits 2i + 1 and 2i of N: sig's bits 2i − 55 and 2i − 56, zero below bit 56.
        var pair = 0u;
        if (i >= 28) {
            let at = u32(2 * i - 56);
            if (at == 0u) {
                pair = sig.x & 3u;
            } else {
                pair = u64_shr(sig, at).x & 3u;
            }
        }
        rem = u64_shl(rem, 2u);
        rem.x = rem.x | pair;
        let trial = u64_shl(root, 2u) | vec2<u32>(1u, 0u);
        root = u64_shl(root, 1u);
        if (!u64_less(rem, trial)) {
            rem = u64_sub(rem, trial);
            root.x = root.x | 1u;
        }
    }
    // √a = root · 2^((e2 − 56) / 2); root's bit 54 brought to bit 63.
    return f64_round(false, (e2 - 56) / 2 + 54, u64_shl(root, 9u), !u64_is_zero(rem));
}

// a < b, for finite values (−0 = +0).
fn f64_less(a: vec2<u32>, b: vec2<u32>) -> bool {
    if (f64_is_zero(a) && f64_is_zero(b)) {
        return false;
    }
    // Bits mapped to integers in the values' order.
    var ka = vec2<u32>(a.x, a.y | 0x80000000u);
    if ((a.y >> 31u) == 1u) {
        ka = ~a;
    }
    var kb = vec2<u32>(b.x, b.y | 0x80000000u);
    if ((b.y >> 31u) == 1u) {
        kb = ~b;
    }
    return u64_less(ka, kb);
}

// The CPU's `a.max(b)` and `a.min(b)` for finite values (which zero of two is unspecified).
fn f64_max(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    return select(a, b, f64_less(a, b));
}

fn f64_min(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    return select(a, b, f64_less(b, a));
}

// ⌊v⌋ as an i32 (the CPU's `floor_i64`, src/grid/index.rs, where it fits).
fn f64_floor_i32(v: vec2<u32>) -> i32 {
    let p = f64_unpack(v);
    if (u64_is_zero(p.m)) {
        return 0;
    }
    if (p.exp < 0) {
        return select(0, -1, p.neg);
    }
    if (p.exp >= 31) {
        f64_status = 1u;
        return 0;
    }
    // The integer part is m >> (63 − exp), 33 to 63 bits down: in the high word.
    let r = u32(31 - p.exp);
    let whole = p.m.y >> r;
    let frac = p.m.x != 0u || (p.m.y & ((1u << r) - 1u)) != 0u;
    if (p.neg) {
        return -i32(whole) - select(0, 1, frac);
    }
    return i32(whole);
}

// The cell of edge 1 / `inv_cell` holding the ray's point o + t·d along one axis:
// ⌊(o + t·d) · inv_cell⌋, the CPU's `floor_i64((o + t * d) * inv_cell)`.
fn f64_cell_at(o: vec2<u32>, t: vec2<u32>, d: vec2<u32>, inv_cell: vec2<u32>) -> i32 {
    return f64_floor_i32(f64_mul(f64_add(o, f64_mul(t, d)), inv_cell));
}
