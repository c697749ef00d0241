// The resident blocks in view, found on the device: one invocation per entry of the GPU hash
// table. A live entry's block is tested as `ViewFrustum::meets_block` tests it (its bounding
// sphere against the near and far planes and the four sides of the widened image), in f32
// relative to the camera's block, with a margin larger than the f32 arithmetic's error: a
// block that clears every plane by the margin is in view, one that misses a plane by it is not,
// and the few in between are listed apart for the host to decide in f64. So the blocks in view
// and the host's decisions together are exactly the host's set. Host side:
// src/fusion/visible_gpu.rs (the words of `params`). Shared files and bindings:
// src/gpu/shaders.rs.

// [0..3] the camera's block (i32); [3] table entries; [4..7] the camera block's first corner
// minus the camera's position plus half a block (world, metres, f32); [7..16] camera-from-world
// rotation, row-major; [16] block edge, [17] a block's bounding radius, [18] far plane (metres);
// [19] margin per metre of the magnitudes involved; [20..32] the four sides' inward unit
// normals (camera frame).
@group(0) @binding(0) var<storage, read> params: array<u32>;
@group(0) @binding(1) var<storage, read> table: array<vec4<u32>>;
// [0] entries in view, [1] entries undecided.
@group(0) @binding(2) var<storage, read_write> counts: array<atomic<u32>>;
// Table entries (positions) of blocks in view, in no defined order.
@group(0) @binding(3) var<storage, read_write> in_view: array<u32>;
// Table entries of blocks the host decides.
@group(0) @binding(4) var<storage, read_write> undecided: array<u32>;

fn word_f32(i: u32) -> f32 {
    return bitcast<f32>(params[i]);
}

fn vec_at(i: u32) -> vec3<f32> {
    return vec3<f32>(word_f32(i), word_f32(i + 1u), word_f32(i + 2u));
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let e = flat_index(wg, num_wg, local);
    if (e >= params[3]) {
        return;
    }
    let entry = table[e];
    if (entry.w >= SLOT_TOMBSTONE) {
        return;
    }
    let camera_block = bitcast<vec3<i32>>(vec3<u32>(params[0], params[1], params[2]));
    let d = bitcast<vec3<i32>>(entry.xyz) - camera_block;
    let w = vec3<f32>(d) * word_f32(16u) + vec_at(4u);
    let c = vec3<f32>(dot(vec_at(7u), w), dot(vec_at(10u), w), dot(vec_at(13u), w));
    let r = word_f32(17u);
    let far = word_f32(18u);
    let margin = word_f32(19u) * (abs(w.x) + abs(w.y) + abs(w.z) + far + r);
    // The least clearance of the sphere past a plane (in view where every one is ≥ 0; the
    // sides strictly).
    var least = min(c.z + r, far + r - c.z);
    for (var k = 0u; k < 4u; k = k + 1u) {
        least = min(least, dot(vec_at(20u + 3u * k), c) + r);
    }
    if (least < -margin) {
        return;
    }
    if (least > margin) {
        in_view[atomicAdd(&counts[0], 1u)] = e;
    } else {
        undecided[atomicAdd(&counts[1], 1u)] = e;
    }
}
