// The frame's block set of band_blocks.wgsl as a list, one invocation per slot: each key found
// is appended (in no defined order: the host sorts) and its slot emptied for the next frame.
// Shared files and bindings: src/gpu/shaders.rs.

// As band_blocks.wgsl's: [20] table slots.
@group(0) @binding(0) var<storage, read> params: array<f64>;
@group(0) @binding(1) var<storage, read_write> table: array<atomic<u32>>;
// [0] keys listed.
@group(0) @binding(2) var<storage, read_write> counts: array<atomic<u32>>;
// Packed offsets from the camera block (10 bits per axis, +512).
@group(0) @binding(3) var<storage, read_write> keys: array<u32>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) num_wg: vec3<u32>,
        @builtin(local_invocation_index) local: u32) {
    let s = flat_index(wg, num_wg, local);
    if (s >= u32(params[20])) {
        return;
    }
    let entry = atomicLoad(&table[s]);
    if (entry != 0u) {
        keys[atomicAdd(&counts[0], 1u)] = entry - 1u;
        atomicStore(&table[s], 0u);
    }
}
