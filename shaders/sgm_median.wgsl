// SGM's 3×3 median over valid neighbours (CPU twin: `median_filter_3x3` in
// src/depth/sgm/filters.rs): every valid pixel becomes the median of the valid values of its
// 3×3 neighbourhood (an even count averages the two middle ones, 0.5 · (lo + hi) as the CPU
// computes it); invalid (NaN) pixels stay as they are. Values are ordered as `f32::total_cmp`
// orders them, through the same integer keys. One invocation per pixel. Shared files and
// bindings: src/gpu/shaders.rs.

@group(0) @binding(0) var<uniform> params: SgmFilterUniforms;
@group(0) @binding(1) var<storage, read> disparity_in: array<u32>;
@group(0) @binding(2) var<storage, read_write> disparity_out: array<u32>;

// `total_order_key`: an i32 whose order is total_cmp's (its own inverse on the bits).
fn total_order_key(b: u32) -> i32 {
    let k = bitcast<i32>(b);
    return k ^ bitcast<i32>(bitcast<u32>(k >> 31u) >> 1u);
}

fn value_bits(key: i32) -> u32 {
    return bitcast<u32>(total_order_key(bitcast<u32>(key)));
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    let w = params.width;
    let h = params.height;
    if (i >= w * h) {
        return;
    }
    let centre = disparity_in[i];
    if (is_nan_bits(centre)) {
        disparity_out[i] = centre;
        return;
    }
    let x = i32(i % w);
    let y = i32(i / w);
    // The valid neighbours' keys, sorted by insertion (the order of a set of integers is
    // unique: the CPU's sorting network gives the same).
    var keys: array<i32, 9>;
    var n = 0u;
    for (var dy = -1; dy <= 1; dy = dy + 1) {
        for (var dx = -1; dx <= 1; dx = dx + 1) {
            let xx = x + dx;
            let yy = y + dy;
            if (xx < 0 || yy < 0 || xx >= i32(w) || yy >= i32(h)) {
                continue;
            }
            let v = disparity_in[u32(yy) * w + u32(xx)];
            if (is_nan_bits(v)) {
                continue;
            }
            let k = total_order_key(v);
            var j = n;
            while (j > 0u && keys[j - 1u] > k) {
                keys[j] = keys[j - 1u];
                j = j - 1u;
            }
            keys[j] = k;
            n = n + 1u;
        }
    }
    let hi = value_bits(keys[n / 2u]);
    if (n % 2u == 1u) {
        disparity_out[i] = hi;
        return;
    }
    let lo = value_bits(keys[n / 2u - 1u]);
    disparity_out[i] = bitcast<u32>(0.5 * (bitcast<f32>(lo) + bitcast<f32>(hi)));
}
