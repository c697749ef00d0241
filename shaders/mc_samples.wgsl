// Marching cubes, pass 0 where the blocks are resident on the GPU: each upload place's samples
// made from its pool slot instead of packed on the host (src/mesh/gpu_samples.rs). Per voxel
// two words: the field's value, decoded by exact division as the host's `decode_tsdf` divides
// (shared/exact_div.wgsl), and the colour with the valid bit (Ω and weight > 0). CPU twin: the
// host's packing in `Batch::upload` (src/mesh/gpu.rs), bit for bit. Keep `McSampleUniforms` in
// sync with src/gpu/layout.rs. Shared files and bindings: src/gpu/shaders.rs.

struct McSampleUniforms {
    // Upload places.
    places: u32,
    // 1: the values are the regularized field's, from `values`; 0: the pool's raw TSDF.
    regularized: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: McSampleUniforms;
// Per place: its pool slot.
@group(0) @binding(1) var<storage, read> place_slot: array<u32>;
// The pool: 512 voxels per slot (GpuVoxel: TSDF | weight-and-Ω << 16, colour).
@group(0) @binding(2) var<storage, read> pool: array<vec2<u32>>;
// The regularized field's i16 per voxel, two per word, 256 words per place (regularized only).
@group(0) @binding(3) var<storage, read> values: array<u32>;
@group(0) @binding(4) var<storage, read_write> samples: array<vec2<u32>>;

// Bit of a sample's second word: the voxel is in Ω with weight > 0 (`VALID_BIT`).
const SAMPLE_VALID: u32 = 0x1000000u;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let g = flat_index(wg, num_wg, local);
    if (g >= params.places * 512u) {
        return;
    }
    let voxel = pool[place_slot[g / 512u] * 512u + g % 512u];
    var bits = voxel.x & 0xffffu;
    if (params.regularized != 0u) {
        bits = (values[g / 2u] >> (16u * (g % 2u))) & 0xffffu;
    }
    // The i16, sign-extended.
    let q = bitcast<i32>(bits << 16u) >> 16u;
    let weight_omega = (voxel.x >> 16u) & 0xffu;
    let valid = (weight_omega & 0x80u) != 0u && (weight_omega & 0x7fu) > 0u;
    samples[g] = vec2<u32>(
        bitcast<u32>(div_rounded(q, 32767u)),
        (voxel.y & 0xffffffu) | select(0u, SAMPLE_VALID, valid),
    );
}
