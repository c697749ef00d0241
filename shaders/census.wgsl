// Census transform (CPU twin: census_transform in src/depth/census.rs): per pixel, one bit per
// neighbour of the window in row-major order, centre skipped (binary: neighbour < centre;
// ternary: bit 2i brighter by more than the threshold, bit 2i + 1 darker by more), pixels
// outside the image clamped to the border. Signature bit b lands in u32 word b / 32, which is
// the CPU's u64 layout read as little-endian u32 pairs. Keep CensusUniforms in sync with
// src/gpu/layout.rs. Shared files and bindings: src/gpu/shaders.rs.

struct CensusUniforms {
    width: u32,
    height: u32,
    window_width: u32,
    window_height: u32,
    ternary: u32,
    threshold: u32,
    // u32 words per signature (2 or 4).
    words: u32,
    pad: u32,
}

@group(0) @binding(0) var<uniform> params: CensusUniforms;
// Grey levels, 4 per word, row-major.
@group(0) @binding(1) var<storage, read> image: array<u32>;
// Signatures, `words` per pixel.
@group(0) @binding(2) var<storage, read_write> signatures: array<u32>;

fn grey(x: i32, y: i32) -> i32 {
    let cx = u32(clamp(x, 0, i32(params.width) - 1));
    let cy = u32(clamp(y, 0, i32(params.height) - 1));
    let j = cy * params.width + cx;
    return i32(packed_byte(image[j >> 2u], j));
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    if (i >= params.width * params.height) {
        return;
    }
    let x = i32(i % params.width);
    let y = i32(i / params.width);
    let rx = i32(params.window_width / 2u);
    let ry = i32(params.window_height / 2u);
    let t = i32(params.threshold);
    let c = grey(x, y);
    var sig = array<u32, 4>(0u, 0u, 0u, 0u);
    var bit = 0u;
    for (var dy = -ry; dy <= ry; dy = dy + 1) {
        for (var dx = -rx; dx <= rx; dx = dx + 1) {
            if (dx == 0 && dy == 0) {
                continue;
            }
            let n = grey(x + dx, y + dy);
            if (params.ternary == 0u) {
                if (n < c) {
                    sig[bit >> 5u] = sig[bit >> 5u] | (1u << (bit & 31u));
                }
                bit = bit + 1u;
            } else {
                let diff = n - c;
                // Bits 2i and 2i + 1 always share a word.
                let pair = select(0u, 1u, diff > t) | select(0u, 2u, diff < -t);
                sig[bit >> 5u] = sig[bit >> 5u] | (pair << (bit & 31u));
                bit = bit + 2u;
            }
        }
    }
    for (var k = 0u; k < params.words; k = k + 1u) {
        signatures[i * params.words + k] = sig[k];
    }
}
