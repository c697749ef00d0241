// Semi-global path aggregation along one direction r = (dx, dy), on the device where the cost
// volume was made (CPU twin: `aggregate_paths` in src/depth/sgm.rs, eq. 13 of Hirschmüller 2008):
//   L_r(p, d) = C(p, d) + min(L_r(q, d), min(L_r(q, d − 1), L_r(q, d + 1)) + P1, min_k L_r(q, k) + P2')
//               − min_k L_r(q, k),   q = p − r,
// with L_r(p, ·) = C(p, ·) where q lies outside the image, and P2' = max(P1 + 1, P2·s / (s + |I(p) − I(q)|))
// when the intensity scale s is not 0 (else P2). Integers throughout: the sums equal the CPU's.
//
// One workgroup walks one path line: it starts at a pixel whose predecessor is outside the image
// and steps by r while inside. Every direction's lines are in one dispatch (the directions are
// independent, and S's additions commute), the longest lines first, so the device works on all
// of them at once instead of one direction after the other. Its 64 invocations own the
// disparities d ≡ local (mod 64), at most 4 each (256 disparities). Each step reads the previous
// pixel's L_r and its minimum from workgroup memory and writes the new ones into the other half
// (one barrier per step); the next pixel's costs and grey level are loaded before the barrier,
// so their latency overlaps it. L_r is added into S, u16 entries packed two per word, by
// atomicAdd of the value shifted to its half: 8 paths of census costs with P2 ≤ 2000 stay below
// 2¹⁶, so no half carries into the other, and the order of the additions does not matter.
// Keep SgmPathUniforms in sync with src/gpu/layout.rs. Shared files and bindings:
// src/gpu/shaders.rs.

struct SgmPathUniforms {
    width: u32,
    height: u32,
    num_disparities: u32,
    p1: u32,
    p2: u32,
    // Intensity scale s of the adaptive P2; 0: P2 throughout.
    p2_scale: u32,
    // Directions in `dirs`.
    directions: u32,
    // Path lines of all directions (workgroups that work).
    lines: u32,
    // Per direction: its step (dx, dy), pixels (each −1, 0 or 1, not both 0), its first line
    // (workgroup) and its number of lines; the first lines of the directions increase.
    dirs: array<vec4<i32>, 8>,
}

@group(0) @binding(0) var<uniform> params: SgmPathUniforms;
// u8 costs, 4 per word: entry (y·width + x)·num_disparities + d.
@group(0) @binding(1) var<storage, read> volume: array<u32>;
// The left image, u8 grey levels, 4 per word.
@group(0) @binding(2) var<storage, read> image: array<u32>;
// S: u16 entries (the volume's order), 2 per word.
@group(0) @binding(3) var<storage, read_write> sums: array<atomic<u32>>;

const LANES: u32 = 64u;
const PER_LANE: u32 = 4u;
const MAX_DISPARITIES: u32 = 256u;
// Larger than any path cost plus P2 (the CPU's padding, `BIG`): never the best predecessor.
const PAD: u32 = 16384u;

// Two rows of L_r (previous and current step), each padded with PAD at d = −1 and d = D.
var<workgroup> rows: array<u32, 516>;
// min_k L_r of the last three steps (read, being made, being reset).
var<workgroup> mins: array<atomic<u32>, 3>;

fn cost_at(e: u32) -> u32 {
    return packed_byte(volume[e >> 2u], e);
}

fn grey_at(i: u32) -> u32 {
    return packed_byte(image[i >> 2u], i);
}

fn p2_for(a: u32, b: u32) -> u32 {
    if (params.p2_scale == 0u) {
        return params.p2;
    }
    let delta = max(a, b) - min(a, b);
    let s = params.p2_scale;
    return max(params.p1 + 1u, params.p2 * s / (s + delta));
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
) {
    let global_line = wg.y * num_wg.x + wg.x;
    if (global_line >= params.lines) {
        return;
    }
    var r = 0u;
    for (var k = 1u; k < params.directions; k = k + 1u) {
        if (global_line >= u32(params.dirs[k].z)) {
            r = k;
        }
    }
    let dir = params.dirs[r];
    let line = global_line - u32(dir.z);
    let w = i32(params.width);
    let h = i32(params.height);
    let nd = params.num_disparities;
    let dx = dir.x;
    let dy = dir.y;
    // The line's first pixel: on the entry row (dy ≠ 0), then down the entry column; a row or
    // a column per line when r is axis-aligned.
    let x_entry = select(w - 1, 0, dx >= 0);
    let y_entry = select(h - 1, 0, dy >= 0);
    var x = x_entry;
    var y = y_entry;
    if (dy == 0) {
        y = i32(line);
    } else if (dx == 0) {
        x = i32(line);
    } else if (line < params.width) {
        x = i32(line);
    } else {
        y = y_entry + dy * (i32(line - params.width) + 1);
    }
    var steps = 0;
    if (dy == 0) {
        steps = w;
    } else if (dx == 0) {
        steps = h;
    } else {
        let sx = select(x + 1, w - x, dx > 0);
        let sy = select(y + 1, h - y, dy > 0);
        steps = min(sx, sy);
    }
    let stride = MAX_DISPARITIES + 2u;
    // Padding of both rows, and the first minimum's slot.
    if (lane < 2u) {
        rows[lane * stride] = PAD;
        rows[lane * stride + nd + 1u] = PAD;
    }
    if (lane == 0u) {
        atomicStore(&mins[0], PAD);
        atomicStore(&mins[1], PAD);
        atomicStore(&mins[2], PAD);
    }
    // The first pixel's costs and grey level; each step loads the next pixel's.
    var pix = u32(y * w + x);
    var costs: array<u32, 4>;
    for (var j = 0u; j < PER_LANE; j = j + 1u) {
        let d = lane + j * LANES;
        if (d < nd) {
            costs[j] = cost_at(pix * nd + d);
        }
    }
    var grey = grey_at(pix);
    workgroupBarrier();
    var grey_prev = 0u;
    for (var k = 0; k < steps; k = k + 1) {
        let cur = u32(k & 1);
        let prev = 1u - cur;
        let slot = u32(k % 3);
        let prev_min = atomicLoad(&mins[(slot + 2u) % 3u]);
        let p2 = p2_for(grey, grey_prev);
        var local_min = PAD;
        for (var j = 0u; j < PER_LANE; j = j + 1u) {
            let d = lane + j * LANES;
            if (d < nd) {
                let e = pix * nd + d;
                let c = costs[j];
                var v = c;
                if (k > 0) {
                    let base = prev * stride + d;
                    let lo = rows[base];
                    let mid = rows[base + 1u];
                    let hi = rows[base + 2u];
                    let best = min(min(mid, min(lo, hi) + params.p1), prev_min + p2);
                    v = c + best - prev_min;
                }
                rows[cur * stride + d + 1u] = v;
                local_min = min(local_min, v);
                atomicAdd(&sums[e >> 1u], v << ((e & 1u) * 16u));
            }
        }
        atomicMin(&mins[slot], local_min);
        if (lane == 0u) {
            atomicStore(&mins[(slot + 1u) % 3u], PAD);
        }
        grey_prev = grey;
        x = x + dx;
        y = y + dy;
        if (k + 1 < steps) {
            pix = u32(y * w + x);
            for (var j = 0u; j < PER_LANE; j = j + 1u) {
                let d = lane + j * LANES;
                if (d < nd) {
                    costs[j] = cost_at(pix * nd + d);
                }
            }
            grey = grey_at(pix);
        }
        workgroupBarrier();
    }
}
