// A depth frame's listed blocks on the device, one invocation per block: the block's key from
// its offset to the frame's origin block (one packed word, or three), its pool slot through the
// GPU hash table, and its base (the camera-frame centre of its voxel (0, 0, 0), metres):
// base(origin) + Σₖ stepₖ·dₖ summed exactly in 96-bit fixed point (units of 2⁻⁶⁴ m; integer
// arithmetic, which no compiler rewrites), then rounded once to the nearest f32. CPU twin:
// `FrameKeys::base` and `unpack_offset` in src/fusion/depth_keys.rs, equal bit for bit (its
// module documentation says why the result is the CPU's f64-then-f32 base but for rare
// rounding ties). Shared files and bindings: src/gpu/shaders.rs.

@group(0) @binding(0) var<uniform> params: FrameKeyUniforms;
@group(0) @binding(1) var<storage, read> table: array<vec4<u32>>;
// Per listed block: its packed offset, or three words (x, y, z) when origin.w is 3.
@group(0) @binding(2) var<storage, read> keys: array<u32>;
// Per listed block: its slot, SLOT_EMPTY when absent.
@group(0) @binding(3) var<storage, read_write> slots: array<u32>;
// Per listed block: its base (xyz) and w = 1 where fused only if a frame created it.
@group(0) @binding(4) var<storage, read_write> block_base: array<vec4<f32>>;

// A 96-bit two's complement integer as six 16-bit limbs, least significant first (lo: limbs
// 0–2, hi: 3–5), so that a limb times a 16-bit factor plus a carry fits 32 bits.
struct Wide {
    lo: vec3<u32>,
    hi: vec3<u32>,
}

fn wide_of(v: vec4<u32>) -> Wide {
    return Wide(
        vec3<u32>(v.x & 0xffffu, v.x >> 16u, v.y & 0xffffu),
        vec3<u32>(v.y >> 16u, v.z & 0xffffu, v.z >> 16u),
    );
}

// The three 32-bit words of x, least significant first.
fn wide_words(x: Wide) -> vec3<u32> {
    return vec3<u32>(x.lo.x | (x.lo.y << 16u), x.lo.z | (x.hi.x << 16u), x.hi.y | (x.hi.z << 16u));
}

// x + y (mod 2⁹⁶).
fn wide_add(x: Wide, y: Wide) -> Wide {
    var t = x.lo.x + y.lo.x;
    let l0 = t & 0xffffu;
    t = x.lo.y + y.lo.y + (t >> 16u);
    let l1 = t & 0xffffu;
    t = x.lo.z + y.lo.z + (t >> 16u);
    let l2 = t & 0xffffu;
    t = x.hi.x + y.hi.x + (t >> 16u);
    let l3 = t & 0xffffu;
    t = x.hi.y + y.hi.y + (t >> 16u);
    let l4 = t & 0xffffu;
    t = x.hi.z + y.hi.z + (t >> 16u);
    return Wide(vec3<u32>(l0, l1, l2), vec3<u32>(l3, l4, t & 0xffffu));
}

// x · k (mod 2⁹⁶) for k < 2¹⁶.
fn wide_mul(x: Wide, k: u32) -> Wide {
    var t = x.lo.x * k;
    let l0 = t & 0xffffu;
    t = x.lo.y * k + (t >> 16u);
    let l1 = t & 0xffffu;
    t = x.lo.z * k + (t >> 16u);
    let l2 = t & 0xffffu;
    t = x.hi.x * k + (t >> 16u);
    let l3 = t & 0xffffu;
    t = x.hi.y * k + (t >> 16u);
    let l4 = t & 0xffffu;
    t = x.hi.z * k + (t >> 16u);
    return Wide(vec3<u32>(l0, l1, l2), vec3<u32>(l3, l4, t & 0xffffu));
}

// −x (mod 2⁹⁶).
fn wide_neg(x: Wide) -> Wide {
    let m = vec3<u32>(0xffffu);
    return wide_add(Wide(x.lo ^ m, x.hi ^ m), Wide(vec3<u32>(1u, 0u, 0u), vec3<u32>(0u)));
}

// x · d for |d| < 2²³: |d| as two 16-bit digits, the high one a limb up.
fn wide_mul_signed(x: Wide, d: i32) -> Wide {
    let m = u32(abs(d));
    let high = wide_mul(x, m >> 16u);
    let shifted = Wide(
        vec3<u32>(0u, high.lo.x, high.lo.y),
        vec3<u32>(high.lo.z, high.hi.x, high.hi.y),
    );
    let p = wide_add(shifted, wide_mul(x, m & 0xffffu));
    if (d < 0) {
        return wide_neg(p);
    }
    return p;
}

// Word i of v (0 outside 0–2).
fn word(v: vec3<u32>, i: i32) -> u32 {
    if (i == 0) {
        return v.x;
    }
    if (i == 1) {
        return v.y;
    }
    if (i == 2) {
        return v.z;
    }
    return 0u;
}

// The 32 bits of v from bit `pos` on (bits below 0 and above 95 read as 0).
fn bits_from(v: vec3<u32>, pos: i32) -> u32 {
    let i = pos >> 5u;
    let s = u32(pos & 31);
    let lo = word(v, i);
    if (s == 0u) {
        return lo;
    }
    return (lo >> s) | (word(v, i + 1) << (32u - s));
}

// Whether a bit of v below `pos` is set.
fn any_below(v: vec3<u32>, pos: i32) -> bool {
    if (pos <= 0) {
        return false;
    }
    if (pos >= 96) {
        return any(v != vec3<u32>(0u));
    }
    let i = pos >> 5u;
    let s = u32(pos & 31);
    var below = (i >= 1 && v.x != 0u) || (i >= 2 && v.y != 0u);
    if (s != 0u) {
        below = below || (word(v, i) & ((1u << s) - 1u)) != 0u;
    }
    return below;
}

// The f32 nearest to x · 2⁻⁶⁴ (ties to even).
fn wide_to_f32(x: Wide) -> f32 {
    let negative = (x.hi.z & 0x8000u) != 0u;
    var v = wide_words(x);
    if (negative) {
        v = wide_words(wide_neg(x));
    }
    var top = -1;
    if (v.z != 0u) {
        top = 64 + i32(firstLeadingBit(v.z));
    } else if (v.y != 0u) {
        top = 32 + i32(firstLeadingBit(v.y));
    } else if (v.x != 0u) {
        top = i32(firstLeadingBit(v.x));
    }
    if (top < 0) {
        return 0.0;
    }
    // The mantissa's 24 bits end at bit `last`; the bit below decides, ties to even.
    let last = top - 23;
    var m = bits_from(v, last) & 0xffffffu;
    let half = (bits_from(v, last - 1) & 1u) != 0u;
    if (half && (any_below(v, last - 1) || (m & 1u) != 0u)) {
        m = m + 1u;
    }
    let r = ldexp(f32(m), last - 64);
    return select(r, -r, negative);
}

// Camera axis c of the base at offset d.
fn base_coordinate(d: vec3<i32>, c: u32) -> f32 {
    var v = wide_of(params.base[c]);
    v = wide_add(v, wide_mul_signed(wide_of(params.steps[c]), d.x));
    v = wide_add(v, wide_mul_signed(wide_of(params.steps[3u + c]), d.y));
    v = wide_add(v, wide_mul_signed(wide_of(params.steps[6u + c]), d.z));
    return wide_to_f32(v);
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let b = flat_index(wg, num_wg, local);
    if (b >= params.block_count) {
        return;
    }
    let d = offset_of(b);
    slots[b] = table_find(params.origin.xyz + d, params.mask);
    let base = vec3<f32>(base_coordinate(d, 0u), base_coordinate(d, 1u), base_coordinate(d, 2u));
    block_base[b] = vec4<f32>(base, select(0.0, 1.0, b >= params.first_unsettled));
}
