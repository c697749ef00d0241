// Shared by SGM's post-filters on the device (sgm_median.wgsl, sgm_speckle_*.wgsl) and the
// fill of TGV's initial disparity (tgv_fill_*.wgsl): their uniforms. Disparities are handled as
// bits (shared/float_bits.wgsl): a valid value comes out with the bits it came in with or as
// the CPU's f32 operations make it.
// Keep SgmFilterUniforms in sync with src/gpu/layout.rs.

struct SgmFilterUniforms {
    width: u32,
    height: u32,
    // Speckle regions of at most this many pixels are removed.
    max_size_px: u32,
    // Neighbours differing by at most this much belong to one region, pixels.
    max_diff_px: f32,
    // The fill's value where a whole column has no disparity (the smallest searched), pixels.
    fallback_px: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}
