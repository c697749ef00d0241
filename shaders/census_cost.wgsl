// Census cost volume (CPU twin: CostVolume::from_census in src/depth/sgm.rs): the Hamming
// distance of left pixel (x, y) against right pixel (x − d, y) for d = min + k, or max_cost
// where the right pixel is outside the image; pixel i, slice k at entry i·num_disparities + k,
// u8 entries packed 4 per word (one invocation per word). Keep CostUniforms in sync with
// src/gpu/layout.rs. Shared files and bindings: src/gpu/shaders.rs.

struct CostUniforms {
    width: u32,
    height: u32,
    num_disparities: u32,
    min_disparity_px: i32,
    max_cost: u32,
    // u32 words per signature.
    words: u32,
    // width · height · num_disparities.
    entries: u32,
    pad: u32,
}

@group(0) @binding(0) var<uniform> params: CostUniforms;
@group(0) @binding(1) var<storage, read> left_signatures: array<u32>;
@group(0) @binding(2) var<storage, read> right_signatures: array<u32>;
@group(0) @binding(3) var<storage, read_write> volume: array<u32>;

// The cost of left pixel p = (x, y) at slice k.
fn entry_cost(p: u32, x: u32, y: u32, k: u32) -> u32 {
    let xr = i32(x) - params.min_disparity_px - i32(k);
    if (xr < 0 || xr >= i32(params.width)) {
        return params.max_cost;
    }
    let r = y * params.width + u32(xr);
    var c = 0u;
    for (var t = 0u; t < params.words; t = t + 1u) {
        c = c + countOneBits(left_signatures[p * params.words + t]
            ^ right_signatures[r * params.words + t]);
    }
    return c;
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let g = flat_index(wg, num_wg, local);
    let first = 4u * g;
    if (first >= params.entries) {
        return;
    }
    // Entry j is pixel j / nd, slice j % nd: divide once, then step (a word may straddle two
    // pixels when nd is not a multiple of 4).
    let nd = params.num_disparities;
    var p = first / nd;
    var k = first % nd;
    var x = p % params.width;
    var y = p / params.width;
    var word = 0u;
    for (var b = 0u; b < 4u; b = b + 1u) {
        if (first + b >= params.entries) {
            break;
        }
        word = word | (entry_cost(p, x, y, k) << (8u * b));
        k = k + 1u;
        if (k == nd) {
            k = 0u;
            p = p + 1u;
            x = x + 1u;
            if (x == params.width) {
                x = 0u;
                y = y + 1u;
            }
        }
    }
    volume[g] = word;
}
