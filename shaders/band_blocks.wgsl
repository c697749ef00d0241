// A depth frame's band blocks listed from its band slices on the device, one invocation per
// slice: the decisions of `SliceGeometry::blocks_of_slice` in src/fusion/band.rs (the slice's
// frustum cut into pieces along the view, each piece's box of blocks, each block tested against
// the piece's depth range and the slice's four side planes), made in f64 relative to the
// camera's block. The device's f64 arithmetic may round, fuse or divide otherwise than the
// host's, so every comparison is decided only where its value clears zero by more than `eps`
// (far more than the two could differ); a block decided in, for some piece, goes into the
// frame's block set (`table`), and a slice with a block it cannot decide is handed to the host
// whole (`deferred`), which lists it exactly (host side: src/fusion/band_blocks_gpu.rs). So the
// blocks listed are exactly the host's, whatever the device's rounding. Needs SHADER_F64.
// Shared files and bindings: src/gpu/shaders.rs.

// [0..9) the camera's x, y and z axes (world frame), [9..12) the camera centre less the
// camera block's corner (metres), [12] block side (m), [13] its inverse, [14] μ (m), [15] fx,
// [16] fy, [17] cx, [18] cy (pixels), [19] eps (m), [20] table slots (a power of two),
// [21] its log2, [22] slices the input holds at most, [23] blocks a slice's box may hold,
// [24..26) μ's f64 bits and [26..28) B's (low word, high word, each a whole number).
@group(0) @binding(0) var<storage, read> params: array<f64>;
// Three words per slice (`BandSlice::pack`), from band_slices.wgsl.
@group(0) @binding(1) var<storage, read> slices: array<u32>;
// band_slices.wgsl's counters: [0] slices made.
@group(0) @binding(2) var<storage, read> slice_counters: array<u32>;
// The frame's block set: 0 or 1 + a block's packed offset from the camera block.
@group(0) @binding(3) var<storage, read_write> table: array<atomic<u32>>;
// [0] keys listed (band_blocks_keys.wgsl), [1] slices deferred.
@group(0) @binding(4) var<storage, read_write> counts: array<atomic<u32>>;
// Three words per deferred slice.
@group(0) @binding(5) var<storage, read_write> deferred: array<u32>;

const MARGIN_M: f64 = 1e-6lf;
// Offsets from the camera block are packed in 10 bits per axis.
const MAX_OFFSET: i32 = 511;

// Three-valued decisions: false, true, undecided.
const NO: u32 = 0u;
const YES: u32 = 1u;
const UNSURE: u32 = 2u;

fn sign_of(v: f64) -> u32 {
    let eps = params[19];
    if (v > eps) {
        return YES;
    }
    if (v < -eps) {
        return NO;
    }
    return UNSURE;
}

fn and3(a: u32, b: u32) -> u32 {
    if (a == NO || b == NO) {
        return NO;
    }
    if (a == UNSURE || b == UNSURE) {
        return UNSURE;
    }
    return YES;
}

fn or3(a: u32, b: u32) -> u32 {
    if (a == YES || b == YES) {
        return YES;
    }
    if (a == UNSURE || b == UNSURE) {
        return UNSURE;
    }
    return NO;
}

fn param3(at: u32) -> vec3<f64> {
    return vec3<f64>(params[at], params[at + 1u], params[at + 2u]);
}

fn reach(n: vec3<f64>) -> f64 {
    return 0.5lf * params[12] * (abs(n.x) + abs(n.y) + abs(n.z));
}

// Whether block offset `o` lies in [⌊lo/B⌋, ⌊hi/B⌋] (lo, hi relative to the camera block).
fn in_span(o: i32, lo: f64, hi: f64) -> u32 {
    let inv = params[13];
    let e = params[19] * inv;
    let q_lo = lo * inv;
    let q_hi = hi * inv;
    if (f64(o) >= floor(q_lo + e) && f64(o) <= floor(q_hi - e)) {
        return YES;
    }
    if (f64(o) < floor(q_lo - e) || f64(o) > floor(q_hi + e)) {
        return NO;
    }
    return UNSURE;
}

fn defer_slice(i: u32) {
    let k = atomicAdd(&counts[1], 1u);
    deferred[3u * k] = slices[3u * i];
    deferred[3u * k + 1u] = slices[3u * i + 1u];
    deferred[3u * k + 2u] = slices[3u * i + 2u];
}

// Adds 1 + the packed offset `key` to the set; false where the set is full.
fn insert(key: u32) -> bool {
    let slots = u32(params[20]);
    let shift = 32u - u32(params[21]);
    var s = (key * 0x9e3779b1u) >> shift;
    for (var probe = 0u; probe < slots; probe = probe + 1u) {
        let r = atomicCompareExchangeWeak(&table[s], 0u, key + 1u);
        if (r.exchanged || r.old_value == key + 1u) {
            return true;
        }
        if (r.old_value == 0u) {
            // A spurious failure of the weak exchange: try the slot again.
            continue;
        }
        s = (s + 1u) & (slots - 1u);
    }
    return false;
}

// The host's ⌈(z1 − z0)/B⌉ (at least 1) for a slice of depths `lo` to `hi` (f32 bits):
// `SliceGeometry::blocks_of_slice` in src/fusion/band.rs, in its f64 rounding
// (shared/exact_f64.wgsl); 0 where that arithmetic left the finite values it handles.
fn host_pieces(lo: u32, hi: u32) -> i32 {
    let mu = vec2<u32>(u32(params[24]), u32(params[25]));
    let block = vec2<u32>(u32(params[26]), u32(params[27]));
    let z0 = f64_max(f64_sub(f64_from_f32(lo), mu), vec2<u32>(0u));
    let z1 = f64_add(f64_from_f32(hi), mu);
    let q = f64_div(f64_sub(z1, z0), block);
    let whole = f64_floor_i32(q);
    let above = any(f64_from_i32(whole) != q);
    if (f64_status != 0u) {
        return 0;
    }
    return max(whole + select(0, 1, above), 1);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) num_wg: vec3<u32>,
        @builtin(local_invocation_index) local: u32) {
    let i = flat_index(wg, num_wg, local);
    if (i >= min(slice_counters[0], u32(params[22]))) {
        return;
    }
    let w = slices[3u * i];
    let lo = f64(bitcast<f32>(slices[3u * i + 1u]));
    let hi = f64(bitcast<f32>(slices[3u * i + 2u]));
    let u0 = w & 0x1fffu;
    let v0 = (w >> 13u) & 0x1fffu;
    let u1 = u0 + ((w >> 26u) & 7u);
    let v1 = v0 + ((w >> 29u) & 7u);
    let a = vec2<f64>((f64(u0) - params[17]) / params[15], (f64(u1) - params[17]) / params[15]);
    let b = vec2<f64>((f64(v0) - params[18]) / params[16], (f64(v1) - params[18]) / params[16]);
    let mu = params[14];
    let z0 = max(lo - mu, 0.0lf);
    let z1 = hi + mu;
    let cx = param3(0u);
    let cy = param3(3u);
    let cz = param3(6u);
    let origin = param3(9u);
    let block = params[12];
    let eps = params[19];
    // Side planes through the camera centre, inward normals (four names: llvmpipe cannot
    // index a local array dynamically).
    let s0 = cx + cz * -a.x;
    let s1 = -cx + cz * a.y;
    let s2 = cy + cz * -b.x;
    let s3 = -cy + cz * b.y;
    let m0 = reach(s0) + MARGIN_M;
    let m1 = reach(s1) + MARGIN_M;
    let m2 = reach(s2) + MARGIN_M;
    let m3 = reach(s3) + MARGIN_M;
    let view_reach = reach(cz);
    // The edge rays' least and greatest components per axis.
    let r00 = (cx * a.x + cy * b.x) + cz;
    let r01 = (cx * a.x + cy * b.y) + cz;
    let r10 = (cx * a.y + cy * b.x) + cz;
    let r11 = (cx * a.y + cy * b.y) + cz;
    let r_lo = min(min(r00, r01), min(r10, r11));
    let r_hi = max(max(r00, r01), max(r10, r11));
    // Pieces: ⌈(z1 − z0)/B⌉, at least one. Where the quotient is about an integer n ≥ 1
    // (a slice of one depth where 2μ is a whole number of blocks, as μ = 4 voxels makes it),
    // the host's quotient is taken in its own rounding; about 0, both sides make one piece.
    let q = (z1 - z0) * params[13];
    var pieces = max(ceil(q), 1.0lf);
    if (floor(q - eps) != floor(q + eps) && floor(q + eps) >= 1.0lf) {
        let n = host_pieces(slices[3u * i + 1u], slices[3u * i + 2u]);
        if (n == 0) {
            defer_slice(i);
            return;
        }
        pieces = f64(n);
    }
    let dz = (z1 - z0) / pieces;
    let n_pieces = i32(pieces);
    // Candidates: the box of the slice's eight corners, widened.
    let wide = 2.0lf * MARGIN_M + 4.0lf * eps;
    let c_lo = min(origin + r_lo * z0, origin + r_lo * z1) - vec3<f64>(wide);
    let c_hi = max(origin + r_hi * z0, origin + r_hi * z1) + vec3<f64>(wide);
    let first = vec3<i32>(floor(c_lo * params[13]));
    let last = vec3<i32>(floor(c_hi * params[13]));
    let span = vec3<f64>(last - first + vec3<i32>(1));
    if (any(first < vec3<i32>(-MAX_OFFSET)) || any(last > vec3<i32>(MAX_OFFSET))
        || span.x * span.y * span.z > params[23]) {
        defer_slice(i);
        return;
    }
    for (var bx = first.x; bx <= last.x; bx = bx + 1) {
        for (var by = first.y; by <= last.y; by = by + 1) {
            for (var bz = first.z; bz <= last.z; bz = bz + 1) {
                let o = vec3<i32>(bx, by, bz);
                let centre = (vec3<f64>(o) + vec3<f64>(0.5lf)) * block - origin;
                var inside = and3(sign_of(dot(s0, centre) + m0), sign_of(dot(s1, centre) + m1));
                inside = and3(inside, sign_of(dot(s2, centre) + m2));
                inside = and3(inside, sign_of(dot(s3, centre) + m3));
                if (inside == NO) {
                    continue;
                }
                let depth = dot(cz, centre);
                // The pieces whose depths could reach the block's: a piece is dz ≥ B/2 deep
                // (a single piece may be as thin as zero: it is the only one tested).
                var p_lo = 0;
                var p_hi = 0;
                if (n_pieces > 1) {
                    p_lo = max(i32(floor((depth - view_reach - MARGIN_M - z0) / dz)) - 2, 0);
                    p_hi = min(i32(floor((depth + view_reach + MARGIN_M - z0) / dz)) + 2,
                        n_pieces - 1);
                }
                var any_piece = NO;
                for (var p = p_lo; p <= p_hi; p = p + 1) {
                    let za = z0 + dz * f64(p);
                    var zb = za + dz;
                    if (p + 1 == n_pieces) {
                        zb = z1;
                    }
                    var piece = and3(sign_of(depth + view_reach - (za - MARGIN_M)),
                        sign_of(zb + MARGIN_M - (depth - view_reach)));
                    // The piece's box, relative to the camera block.
                    let x_lo = min(origin + r_lo * za, origin + r_lo * zb) - vec3<f64>(MARGIN_M);
                    let x_hi = max(origin + r_hi * za, origin + r_hi * zb) + vec3<f64>(MARGIN_M);
                    piece = and3(piece, in_span(bx, x_lo.x, x_hi.x));
                    piece = and3(piece, in_span(by, x_lo.y, x_hi.y));
                    piece = and3(piece, in_span(bz, x_lo.z, x_hi.z));
                    any_piece = or3(any_piece, piece);
                }
                let listed = and3(inside, any_piece);
                if (listed == UNSURE) {
                    defer_slice(i);
                    return;
                }
                if (listed == YES) {
                    let key = u32(bx + 512) | (u32(by + 512) << 10u) | (u32(bz + 512) << 20u);
                    if (!insert(key)) {
                        defer_slice(i);
                        return;
                    }
                }
            }
        }
    }
}
