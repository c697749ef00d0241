// A depth frame's listed blocks as the host sends them (`FrameKeys` in src/fusion/depth_keys.rs):
// the uniforms and the offset of each listed block from the frame's origin block. The kernel
// that includes this file declares `params: FrameKeyUniforms` and `keys: array<u32>`. Keep
// `FrameKeyUniforms` in sync with src/gpu/layout.rs; `offset_of` is the twin of `unpack_offset`
// in src/fusion/depth_keys.rs.

struct FrameKeyUniforms {
    // The origin block's key (xyz); w: words per key (1 packed, 3 wide).
    origin: vec4<i32>,
    // Per camera axis c: the origin block's base coordinate, fixed point, three words (xyz).
    base: array<vec4<u32>, 3>,
    // [3k + c]: the step of one block along world axis k, camera axis c, fixed point.
    steps: array<vec4<u32>, 9>,
    block_count: u32,
    // Table capacity − 1 (the capacity is a power of two).
    mask: u32,
    // Blocks from this index on are fused only where a frame created them (base w = 1).
    first_unsettled: u32,
    _pad: u32,
}

// Block b's offset from the origin block (x: bits 0–10, y: 11–20, z: 21–31, two's complement).
fn offset_of(b: u32) -> vec3<i32> {
    if (params.origin.w == 1) {
        let w = keys[b];
        return vec3<i32>(
            bitcast<i32>(w << 21u) >> 21u,
            bitcast<i32>(w << 11u) >> 22u,
            bitcast<i32>(w) >> 21u,
        );
    }
    let k = 3u * b;
    return bitcast<vec3<i32>>(vec3<u32>(keys[k], keys[k + 1u], keys[k + 2u]));
}

