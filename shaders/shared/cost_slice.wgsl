// Shared by tgv_cost_at.wgsl and tgv_invalidate.wgsl: the cost volume's slice nearest to
// disparity u (CPU twin: `costs_at_disparities` in src/depth/tgv.rs), Rust's
// `((u − d_min).round().max(0) as usize).min(n − 1)`: halves away from zero
// (shared/rounding.wgsl), below the range slice 0, above it the last. The subtraction is
// correctly rounded in WGSL and the rest is exact, so the slice is the CPU's for every finite u.

fn slice_of(u: f32, min_disparity_px: f32, num_disparities: u32) -> u32 {
    let last = num_disparities - 1u;
    let x = round_half_away(u - min_disparity_px);
    if (x >= f32(last)) {
        return last;
    }
    if (x > 0.0) {
        return u32(x);
    }
    return 0u;
}
