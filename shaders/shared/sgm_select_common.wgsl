// Shared by sgm_right.wgsl and sgm_select.wgsl: the selection's uniforms and the summed path
// costs S (u16 entries, 2 per word, entry (y·width + x)·num_disparities + k).
// Keep SgmSelectUniforms in sync with src/gpu/layout.rs.

struct SgmSelectUniforms {
    width: u32,
    height: u32,
    num_disparities: u32,
    // Disparity of slice 0, pixels.
    min_disparity_px: i32,
    // 0: none, 1: parabola, 2: equiangular (SubpixelFit).
    subpixel: u32,
    // Radius of the raw costs' window of the sub-pixel fit; 0: the fit reads S.
    radius: u32,
    // Largest left–right difference, slices; NO_SLICE: no check.
    lr_max_diff: u32,
    // 1 − the uniqueness ratio (1: no uniqueness test), the host's f32.
    uniqueness_factor: f32,
}

// "No slice" (the CPU's u16::MAX).
const NO_SLICE: u32 = 0xffffu;

fn sum_at(e: u32) -> u32 {
    return (sums[e >> 1u] >> ((e & 1u) * 16u)) & 0xffffu;
}
