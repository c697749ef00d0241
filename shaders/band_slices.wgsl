// A depth frame's band as the slices of its 8×8-pixel tiles, one invocation per tile: the
// decisions of `tile_blocks` in src/fusion/band.rs (CPU twin: `band_slices` in
// src/fusion/band/slices.rs, equal slice for slice), made with comparisons of the depths' bits
// and exact differences in 64-bit fixed point (units of 2⁻⁴⁰ m): a tile's usable depths, split
// into ranges at gaps of more than 2μ (as the CPU's f32 difference rounds), and into quadrants,
// down to 2×2 pixels, where a range spreads over more than μ/2 (exactly). Each slice is
// appended as three words (packed rectangle, lo bits, hi bits; `BandSlice::pack`); the order
// of the appends is not defined (the host sorts). Keep `BandSliceUniforms` in sync with
// src/gpu/layout.rs. Shared files and bindings: src/gpu/shaders.rs.

struct BandSliceUniforms {
    width: u32,
    height: u32,
    tiles_x: u32,
    tiles: u32,
    // Usable depths have bits in [min_bits, max_bits] (positive, finite).
    min_bits: u32,
    max_bits: u32,
    // Slices the output holds.
    capacity: u32,
    // 1 where an exact difference equal to gap_mid rounds up (to an even f32 above 2μ).
    gap_tie_up: u32,
    // The midpoint between the largest f32 ≤ 2μ and the next f32, fixed point (low, high).
    gap_mid: vec2<u32>,
    // ⌊μ/2 · 2⁴⁰⌋ (low, high).
    spread: vec2<u32>,
}

@group(0) @binding(0) var<uniform> params: BandSliceUniforms;
// The depth image's bits, rows of `width`.
@group(0) @binding(1) var<storage, read> depth: array<u32>;
// 64 words per tile: a node's sorted depths.
@group(0) @binding(2) var<storage, read_write> scratch: array<u32>;
// [0]: slices appended (may exceed capacity: the host checks); [1]: usable pixels.
@group(0) @binding(3) var<storage, read_write> counters: array<atomic<u32>>;
// Three words per slice.
@group(0) @binding(4) var<storage, read_write> slices: array<u32>;

fn is_usable(b: u32) -> bool {
    return b < 0x7f800000u && b >= params.min_bits && b <= params.max_bits;
}

// A usable depth in units of 2⁻⁴⁰ m, (low, high) words: exact for depths in [2⁻¹⁷, 2²⁴) m,
// which the host checks the usable range lies in.
fn fixed_of(b: u32) -> vec2<u32> {
    let e = (b >> 23u) & 0xffu;
    let m = (b & 0x7fffffu) | 0x800000u;
    let sh = e - 110u;
    if (sh >= 32u) {
        return vec2<u32>(0u, m << (sh - 32u));
    }
    if (sh == 0u) {
        return vec2<u32>(m, 0u);
    }
    return vec2<u32>(m << sh, m >> (32u - sh));
}

// The exact hi − lo (hi ≥ lo), fixed point.
fn difference(lo: u32, hi: u32) -> vec2<u32> {
    let a = fixed_of(hi);
    let b = fixed_of(lo);
    let borrow = select(0u, 1u, a.x < b.x);
    return vec2<u32>(a.x - b.x, a.y - b.y - borrow);
}

// −1, 0 or 1 as a <, = or > b (unsigned 64-bit).
fn compare(a: vec2<u32>, b: vec2<u32>) -> i32 {
    if (a.y != b.y) {
        return select(-1, 1, a.y > b.y);
    }
    if (a.x != b.x) {
        return select(-1, 1, a.x > b.x);
    }
    return 0;
}

// The CPU's `(hi - lo) as f64 > 2.0 * μ` (an f32 difference, rounded to nearest even).
fn gap_exceeds(lo: u32, hi: u32) -> bool {
    let c = compare(difference(lo, hi), params.gap_mid);
    return c > 0 || (c == 0 && params.gap_tie_up == 1u);
}

// The CPU's `hi as f64 - lo as f64 > 0.5 * μ` (exact).
fn spread_exceeds(lo: u32, hi: u32) -> bool {
    return compare(difference(lo, hi), params.spread) > 0;
}

struct Rect {
    u0: u32,
    u1: u32,
    v0: u32,
    v1: u32,
}

struct Range {
    count: u32,
    lo: u32,
    hi: u32,
}

fn range_of(r: Rect) -> Range {
    var out = Range(0u, 0xffffffffu, 0u);
    for (var v = r.v0; v <= r.v1; v = v + 1u) {
        for (var u = r.u0; u <= r.u1; u = u + 1u) {
            let b = depth[v * params.width + u];
            if (is_usable(b)) {
                out.count = out.count + 1u;
                out.lo = min(out.lo, b);
                out.hi = max(out.hi, b);
            }
        }
    }
    return out;
}

fn emit(r: Rect, lo: u32, hi: u32) {
    let k = atomicAdd(&counters[0], 1u);
    if (k < params.capacity) {
        slices[3u * k] = r.u0 | (r.v0 << 13u) | ((r.u1 - r.u0) << 26u) | ((r.v1 - r.v0) << 29u);
        slices[3u * k + 1u] = lo;
        slices[3u * k + 2u] = hi;
    }
}

fn is_smallest(r: Rect) -> bool {
    return r.u1 - r.u0 < 2u && r.v1 - r.v0 < 2u;
}

// Emits the slices of node `r` and returns false, or returns true where it must be split.
// `base`: the tile's scratch words.
fn decide(r: Rect, base: u32) -> bool {
    let range = range_of(r);
    if (range.count == 0u) {
        return false;
    }
    let smallest = is_smallest(r);
    if (!gap_exceeds(range.lo, range.hi)) {
        if (!smallest && spread_exceeds(range.lo, range.hi)) {
            return true;
        }
        emit(r, range.lo, range.hi);
        return false;
    }
    // The usable depths, sorted (insertion; positive floats sort as their bits).
    var n = 0u;
    for (var v = r.v0; v <= r.v1; v = v + 1u) {
        for (var u = r.u0; u <= r.u1; u = u + 1u) {
            let b = depth[v * params.width + u];
            if (is_usable(b)) {
                var j = n;
                loop {
                    if (j == 0u || scratch[base + j - 1u] <= b) {
                        break;
                    }
                    scratch[base + j] = scratch[base + j - 1u];
                    j = j - 1u;
                }
                scratch[base + j] = b;
                n = n + 1u;
            }
        }
    }
    // Ranges at gaps of more than 2μ: split if one spreads too far, else one slice each.
    if (!smallest) {
        var start = scratch[base];
        for (var i = 1u; i < n; i = i + 1u) {
            let p = scratch[base + i - 1u];
            let q = scratch[base + i];
            if (gap_exceeds(p, q)) {
                if (spread_exceeds(start, p)) {
                    return true;
                }
                start = q;
            }
        }
        if (spread_exceeds(start, scratch[base + n - 1u])) {
            return true;
        }
    }
    var start = scratch[base];
    for (var i = 1u; i < n; i = i + 1u) {
        let p = scratch[base + i - 1u];
        let q = scratch[base + i];
        if (gap_exceeds(p, q)) {
            emit(r, start, p);
            start = q;
        }
    }
    emit(r, start, scratch[base + n - 1u]);
    return false;
}

// Quadrant q (0–3) of `r`, as the CPU's split makes them; empty where u0 > u1 or v0 > v1.
fn quadrant(r: Rect, q: u32) -> Rect {
    let um = (r.u0 + r.u1) / 2u;
    let vm = (r.v0 + r.v1) / 2u;
    var out = Rect(r.u0, um, r.v0, vm);
    if ((q & 2u) != 0u) {
        out.u0 = um + 1u;
        out.u1 = r.u1;
    }
    if ((q & 1u) != 0u) {
        out.v0 = vm + 1u;
        out.v1 = r.v1;
    }
    return out;
}

fn is_empty(r: Rect) -> bool {
    return r.u0 > r.u1 || r.v0 > r.v1;
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let t = flat_index(wg, num_wg, local);
    if (t >= params.tiles) {
        return;
    }
    let u0 = (t % params.tiles_x) * 8u;
    let v0 = (t / params.tiles_x) * 8u;
    let tile = Rect(u0, min(u0 + 8u, params.width) - 1u, v0, min(v0 + 8u, params.height) - 1u);
    let base = t * 64u;
    let usable = range_of(tile).count;
    if (usable == 0u) {
        return;
    }
    atomicAdd(&counters[1], usable);
    if (!decide(tile, base)) {
        return;
    }
    // Tiles are at most 8 pixels a side: quadrants at most 4, theirs at most 2 (the smallest,
    // never split). Nested loops instead of recursion, which WGSL has not.
    for (var q = 0u; q < 4u; q = q + 1u) {
        let a = quadrant(tile, q);
        if (is_empty(a) || !decide(a, base)) {
            continue;
        }
        for (var s = 0u; s < 4u; s = s + 1u) {
            let b = quadrant(a, s);
            if (!is_empty(b)) {
                _ = decide(b, base);
            }
        }
    }
}
