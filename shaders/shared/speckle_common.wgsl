// Shared by SGM's speckle filter on the device (sgm_speckle_runs, _join, _count, _clear; CPU
// twin: `remove_speckles` in src/depth/sgm/filters.rs): the bindings and a union–find forest
// over the pixels. The CPU finds the same regions (4-connected valid pixels whose neighbours
// differ by at most max_diff_px) with runs joined serially; here every pixel points at a pixel
// of its region with a smaller index (`parent`, its run's first pixel to start with), runs of
// consecutive rows are joined concurrently by linking the larger root under the smaller
// (atomicMin; a link that lost a race is retried from the new parent), and a region's size is
// counted at its root. The regions are sets, so the result does not depend on the order.
// `parent[i] <= i` always holds, so the forest has no cycle.

@group(0) @binding(0) var<uniform> params: SgmFilterUniforms;
@group(0) @binding(1) var<storage, read_write> disparity: array<u32>;
@group(0) @binding(2) var<storage, read_write> parent: array<atomic<u32>>;
@group(0) @binding(3) var<storage, read_write> region_size: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read_write> confidence: array<f32>;

// Whether valid neighbours with bits a and b are in one region (the CPU's |a − b| ≤ max_diff).
fn connected(a: u32, b: u32) -> bool {
    return abs(bitcast<f32>(a) - bitcast<f32>(b)) <= params.max_diff_px;
}

// Whether the pixels with bits a and b are both valid and connected.
fn joined(a: u32, b: u32) -> bool {
    return !is_nan_bits(a) && !is_nan_bits(b) && connected(a, b);
}

// The root of pixel x's tree, halving the path on the way (each pixel then points at an
// ancestor, still smaller).
fn find_root(x0: u32) -> u32 {
    var x = x0;
    loop {
        let p = atomicLoad(&parent[x]);
        if (p == x) {
            break;
        }
        let g = atomicLoad(&parent[p]);
        if (g != p) {
            atomicStore(&parent[x], g);
        }
        x = g;
    }
    return x;
}

// Joins the trees of pixels a and b.
fn unite(a0: u32, b0: u32) {
    var a = a0;
    var b = b0;
    loop {
        a = find_root(a);
        b = find_root(b);
        if (a == b) {
            break;
        }
        if (a < b) {
            let old = atomicMin(&parent[b], a);
            if (old == b) {
                break;
            }
            b = old;
        } else {
            let old = atomicMin(&parent[a], b);
            if (old == a) {
                break;
            }
            a = old;
        }
    }
}
