// The neighbour table of the resident TV problem: for block k and each direction (+x, −x, +y,
// −y, +z, −z) the neighbouring block's number, or NONE when it is not resident. CPU twin: the
// neighbour table `TvProblem::from_state` builds from its sorted block list. Shared files and
// bindings: src/gpu/shaders.rs.

@group(0) @binding(1) var<storage, read> table: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> listed: array<vec4<u32>>;
@group(0) @binding(3) var<storage, read> block_of_slot: array<u32>;
@group(0) @binding(4) var<storage, read_write> neighbors: array<u32>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let k = flat_index(wg, num_wg, local);
    if (k >= params.block_count) {
        return;
    }
    let key = bitcast<vec3<i32>>(listed[k].xyz);
    for (var j = 0u; j < 6u; j = j + 1u) {
        var offset = vec3<i32>(0, 0, 0);
        offset[j / 2u] = select(-1, 1, j % 2u == 0u);
        let slot = table_find(key + offset, params.table_mask);
        var nb = RESIDENT_NONE;
        if (slot < SLOT_TOMBSTONE) {
            nb = block_of_slot[slot];
        }
        neighbors[k * 6u + j] = nb;
    }
}
