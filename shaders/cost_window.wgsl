// The census costs summed over a (2r+1)² window, on the device where the cost volume was made
// (CPU twin: `box_filter_into` in src/depth/tgv/search.rs, whose u16 running sums equal the
// direct sums taken here, modulo 2¹⁶ as both wrap): border pixels sum the part of the window
// inside the image, and `counts` holds how many pixels that is. Entry i·num_disparities + k of
// the volume (u8 costs, 4 per word) gives entry i·num_disparities + k of the sums (u16, 2 per
// word); one invocation per output word. Keep WindowUniforms in sync with src/gpu/layout.rs.
// Shared files and bindings: src/gpu/shaders.rs.

struct WindowUniforms {
    width: u32,
    height: u32,
    num_disparities: u32,
    // Window radius r, pixels.
    radius: u32,
    // width · height · num_disparities.
    entries: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> params: WindowUniforms;
@group(0) @binding(1) var<storage, read> volume: array<u32>;
@group(0) @binding(2) var<storage, read_write> sums: array<u32>;
@group(0) @binding(3) var<storage, read_write> counts: array<u32>;

fn cost_at(j: u32) -> u32 {
    return packed_byte(volume[j >> 2u], j);
}

// The window of pixel i inside the image, (x0, y0, x1, y1) inclusive; writes its pixel count
// when `first` (the pixel's slice 0).
fn window_of(i: u32, first: bool) -> vec4<u32> {
    let x = i % params.width;
    let y = i / params.width;
    let r = params.radius;
    let b = vec4<u32>(
        select(0u, x - r, x >= r),
        select(0u, y - r, y >= r),
        min(x + r, params.width - 1u),
        min(y + r, params.height - 1u),
    );
    if (first) {
        counts[i] = (b.z - b.x + 1u) * (b.w - b.y + 1u);
    }
    return b;
}

// The window sum of entry j (pixel j / num_disparities, slice j % num_disparities), and its
// pixel's count when j is the pixel's slice 0.
fn window_sum(j: u32) -> u32 {
    let nd = params.num_disparities;
    let k = j % nd;
    let b = window_of(j / nd, k == 0u);
    var s = 0u;
    for (var yy = b.y; yy <= b.w; yy = yy + 1u) {
        for (var xx = b.x; xx <= b.z; xx = xx + 1u) {
            s = s + cost_at((yy * params.width + xx) * nd + k);
        }
    }
    return s & 0xffffu;
}

// With an even number of slices, entries j and j + 1 (j even) are slices k, k + 1 of one pixel,
// and so are their neighbours' entries: one word read gives both costs. Returns the packed pair.
fn window_sum_pair(j: u32) -> u32 {
    let nd = params.num_disparities;
    let k = j % nd;
    let b = window_of(j / nd, k == 0u);
    var s0 = 0u;
    var s1 = 0u;
    for (var yy = b.y; yy <= b.w; yy = yy + 1u) {
        for (var xx = b.x; xx <= b.z; xx = xx + 1u) {
            // Even, so e and e + 1 share a word.
            let e = (yy * params.width + xx) * nd + k;
            let c = volume[e >> 2u] >> ((e & 3u) * 8u);
            s0 = s0 + (c & 0xffu);
            s1 = s1 + ((c >> 8u) & 0xffu);
        }
    }
    return (s0 & 0xffffu) | ((s1 & 0xffffu) << 16u);
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let w = flat_index(wg, num_wg, local);
    let j = 2u * w;
    if (j >= params.entries) {
        return;
    }
    if (params.num_disparities % 2u == 0u) {
        sums[w] = window_sum_pair(j);
        return;
    }
    var word = window_sum(j);
    if (j + 1u < params.entries) {
        word = word | (window_sum(j + 1u) << 16u);
    }
    sums[w] = word;
}
