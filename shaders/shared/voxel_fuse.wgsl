// `Block::fuse` (src/grid/block.rs) on one packed voxel: the paper's running average of the
// normalised TSDF and of the colour, weight + 1 (capped), Ω set. Words as `GpuVoxel` in
// src/gpu/layout.rs: `tsdf_weight` bits 0–15 quantised TSDF (i16), 16–23 weight (0–6) and Ω (7),
// bit 24 set here (updated); `color` r | g << 8 | b << 16. Keep in sync with both.
// Used by fuse_lidar.wgsl and, through shared/fuse_common.wgsl, by the depth kernels.

// Bits 0–15: quantised TSDF (i16, two's complement); bits 16–23: weight (0–6) and Ω (7);
// bit 24: set when the voxel was updated (cleared by the host when it takes the voxel back).
// `color`: r | g << 8 | b << 16.
struct GpuVoxel {
    tsdf_weight: u32,
    color: u32,
}

// Channel at bit `shift` of the running mean of colours `rgb` (new) and `color` (old, weight
// `w_old`), in place.
fn mix_channel(rgb: u32, color: u32, shift: u32, w_old: f32, w_new: f32) -> u32 {
    let c = f32((rgb >> shift) & 0xffu);
    let o = f32((color >> shift) & 0xffu);
    let m = clamp(round_half_away((c + w_old * o) / w_new), 0.0, 255.0);
    return u32(m) << shift;
}

// The voxel (`tsdf_weight`, `color`) after fusing the normalised TSDF `t` ∈ [−1, 1] and, when
// `use_color`, the colour `rgb` (else the colour is kept).
fn fuse_packed(tsdf_weight: u32, color: u32, t: f32, rgb: u32, use_color: bool) -> vec2<u32> {
    let tsdf_scale = 32767.0;
    let q_old = (bitcast<i32>(tsdf_weight << 16u)) >> 16u;
    let weight_old = (tsdf_weight >> 16u) & 0x7fu;
    let w_old = f32(weight_old);
    let w_new = w_old + 1.0;
    let f_old = f32(q_old) / tsdf_scale;
    let f_new = (t + w_old * f_old) / w_new;
    let q_new = i32(round_half_away(clamp(f_new, -1.0, 1.0) * tsdf_scale));
    var out_color = color;
    if (use_color) {
        // No loop over the channels: llvmpipe caps the loop iterations of an invocation.
        out_color = mix_channel(rgb, color, 0u, w_old, w_new)
            | mix_channel(rgb, color, 8u, w_old, w_new)
            | mix_channel(rgb, color, 16u, w_old, w_new);
    }
    // Weight capped at 127, Ω (bit 7) set, updated (bit 24) set.
    let weight = min(weight_old + 1u, 127u) | 128u;
    return vec2<u32>((bitcast<u32>(q_new) & 0xffffu) | (weight << 16u) | 0x1000000u, out_color);
}
