// Gathers the resident TV problem from the pool's voxels: f (the decoded TSDF), w (the
// weight) and the Ω and link bits of every voxel, and counts the Ω voxels. CPU twins:
// `TvProblem::gather` (`decode_tsdf`, `Block::weight`, `Block::omega`) and `link_masks` in
// src/regularize/sweep.rs; f is decoded by exact division (shared/exact_div.wgsl), so every
// array equals the CPU's bit for bit. Shared files and bindings: src/gpu/shaders.rs.

@group(0) @binding(1) var<storage, read> listed: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> neighbors: array<u32>;
// The pool: 512 voxels per slot, two words each (GpuVoxel: TSDF | weight-and-Ω << 16, colour).
@group(0) @binding(3) var<storage, read> pool: array<vec2<u32>>;
@group(0) @binding(4) var<storage, read_write> f: array<f32>;
@group(0) @binding(5) var<storage, read_write> w: array<f32>;
@group(0) @binding(6) var<storage, read_write> mask: array<u32>;
@group(0) @binding(7) var<storage, read_write> counters: array<atomic<u32>>;

var<workgroup> omega_in_group: atomic<u32>;

// Whether voxel i of problem block k is in Ω.
fn omega_at(k: u32, i: u32) -> bool {
    return (pool[listed[k].w * RESIDENT_VOXELS_PER_BLOCK + i].x & POOL_OMEGA_BIT) != 0u;
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let g = flat_index(wg, num_wg, local);
    if (g < params.voxel_count) {
        let k = g / RESIDENT_VOXELS_PER_BLOCK;
        let i = g % RESIDENT_VOXELS_PER_BLOCK;
        let word = pool[listed[k].w * RESIDENT_VOXELS_PER_BLOCK + i].x;
        // The TSDF's 16 bits, sign-extended.
        let tsdf = bitcast<i32>(word << 16u) >> 16u;
        f[g] = div_rounded(tsdf, 32767u);
        w[g] = f32((word >> 16u) & 0x7fu);
        var m = 0u;
        if ((word & POOL_OMEGA_BIT) != 0u) {
            m = RESIDENT_OMEGA;
            atomicAdd(&omega_in_group, 1u);
            for (var d = 0u; d < 3u; d = d + 1u) {
                let s = axis_stride(d);
                let c = (i / s) % 8u;
                var ahead = false;
                if (c + 1u < 8u) {
                    ahead = omega_at(k, i + s);
                } else {
                    let nb = neighbors[k * 6u + 2u * d];
                    ahead = nb != RESIDENT_NONE && omega_at(nb, i - 7u * s);
                }
                var behind = false;
                if (c > 0u) {
                    behind = omega_at(k, i - s);
                } else {
                    let nb = neighbors[k * 6u + 2u * d + 1u];
                    behind = nb != RESIDENT_NONE && omega_at(nb, i + 7u * s);
                }
                m = m | select(0u, 1u << d, ahead) | select(0u, 1u << (3u + d), behind);
            }
        }
        mask[g] = m;
    }
    workgroupBarrier();
    if (local == 0u) {
        atomicAdd(&counters[1], atomicLoad(&omega_in_group));
    }
}
