// Projective depth-map TSDF fusion of one voxel (DENSER Sec. III-A), shared by fuse_depth.wgsl
// (blocks uploaded per call) and fuse_depth_resident.wgsl (blocks resident in the GPU pool).
// CPU twin: `integrate_depth` in src/fusion/depth.rs with `Block::fuse` in src/grid/block.rs.
// Buffer layouts: keep in sync with `FuseUniforms` and `GpuVoxel` in src/gpu/layout.rs.
// Bindings 0–5 are common to both kernels. Needs shared/float_bits.wgsl and
// shared/packed_bytes.wgsl.

struct FuseUniforms {
    // Camera-frame step of one voxel along world x, y, z (xyz; w unused), metres.
    axis_x: vec4<f32>,
    axis_y: vec4<f32>,
    axis_z: vec4<f32>,
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    width: u32,
    height: u32,
    // Truncation μ, metres, and 1/μ.
    mu: f32,
    inv_mu: f32,
    // Voxels of the listed blocks (blocks × 512).
    voxel_count: u32,
    use_color: u32,
    // The usable depth range, metres (`usable` in src/fusion/depth.rs).
    min_depth_m: f32,
    max_depth_m: f32,
}

@group(0) @binding(0) var<uniform> params: FuseUniforms;
// Camera-frame centre of voxel (0, 0, 0) of each listed block (xyz; w unused), metres.
@group(0) @binding(1) var<storage, read> block_base: array<vec4<f32>>;
// Depth (z) per pixel, metres, row-major.
@group(0) @binding(2) var<storage, read> depth: array<f32>;
// The colour image as uploaded: 3 bytes (r, g, b) per pixel, row-major, packed four bytes to
// a word (one unused word when the frame fuses no colour).
@group(0) @binding(3) var<storage, read> color_bytes: array<u32>;
// The voxels the kernel updates in place.
@group(0) @binding(4) var<storage, read_write> voxels: array<GpuVoxel>;
// [0]: voxel updates applied; [1]: listed blocks missing from the GPU hash table (resident
// kernel only; must stay 0).
@group(0) @binding(5) var<storage, read_write> counters: array<atomic<u32>>;

// Fuses the frame into voxel `i` (x + 8y + 64z) of listed block `b`, stored at `voxels[gv]`.
// Returns whether the voxel was updated.
fn fuse_voxel(b: u32, i: u32, gv: u32) -> bool {
    let x = f32(i % 8u);
    let y = f32((i / 8u) % 8u);
    let z = f32(i / 64u);
    // Same order of operations as the CPU: row = base + ay·y + az·z, p = row + ax·x.
    let row = block_base[b].xyz + params.axis_y.xyz * y + params.axis_z.xyz * z;
    let pc = row + params.axis_x.xyz * x;
    if (pc.z <= 0.0) {
        return false;
    }
    let inv_z = 1.0 / pc.z;
    let uf = params.fx * pc.x * inv_z + params.cx;
    let vf = params.fy * pc.y * inv_z + params.cy;
    let ur = round_half_up(uf);
    let vr = round_half_up(vf);
    if (ur < 0.0 || vr < 0.0 || ur >= f32(params.width) || vr >= f32(params.height)) {
        return false;
    }
    let pix = u32(vr) * params.width + u32(ur);
    let d = depth[pix];
    // `usable`: finite (tested on the bits) and within the depth range.
    if (!is_finite_bits(bitcast<u32>(d)) || !(d >= params.min_depth_m && d <= params.max_depth_m)) {
        return false;
    }
    let sdf = d - pc.z;
    if (sdf < -params.mu) {
        return false;
    }
    let t = min(sdf, params.mu) * params.inv_mu;

    // Block::fuse: the paper's running average, weight capped, Ω set (shared/voxel_fuse.wgsl).
    var rgb = 0u;
    if (params.use_color != 0u) {
        let j = pix * 3u;
        rgb = packed_byte(color_bytes[j / 4u], j)
            | (packed_byte(color_bytes[(j + 1u) / 4u], j + 1u) << 8u)
            | (packed_byte(color_bytes[(j + 2u) / 4u], j + 2u) << 16u);
    }
    let v = voxels[gv];
    let out = fuse_packed(v.tsdf_weight, v.color, t, rgb, params.use_color != 0u);
    voxels[gv] = GpuVoxel(out.x, out.y);
    atomicAdd(&counters[0], 1u);
    return true;
}
