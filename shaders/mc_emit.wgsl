// Marching cubes, pass 2 of 5: every triangle corner of the meshed blocks, in the CPU mesher's
// order (block, cube, triangle, corner): its vertex (position, colour) and its edge's entry in
// the hash table, where the smallest corner number that names the edge is kept. The first
// corner of an edge is the one whose vertex the CPU mesher creates, so the later passes number
// the vertices in its order whatever order the invocations ran in.
// One workgroup per block, one invocation per row of 8 cubes; the rows' triangles are placed by
// a prefix sum over the workgroup.
// Shared files and bindings: src/gpu/shaders.rs; the passes: src/mesh/gpu.rs.

// Per uploaded block, 24 floats: the voxel centres' world coordinates along x, y and z for
// local coordinates 0..7, each the f32 rounding of the f64 centre (`GridParams::voxel_center`).
@group(0) @binding(4) var<storage, read> centres: array<f32>;
// Per meshed block of this dispatch, its first triangle (blocks + 1 entries).
@group(0) @binding(5) var<storage, read> tri_base: array<u32>;
// Three words per entry (zeroed by the host): edge key + 1 (0: empty), the complement of the
// smallest corner number naming it (0: none), and (pass 4) its vertex number.
@group(0) @binding(6) var<storage, read_write> hash: array<atomic<u32>>;
// Five words per corner: x, y, z (f32 bits), colour r | g << 8 | b << 16, hash entry.
@group(0) @binding(7) var<storage, read_write> corners: array<u32>;

// The entry of `key`, inserted if new (linear probing, `mix32` of shared/block_hash.wgsl; the table has more entries than corners,
// so it never fills).
fn entry_of(key: u32) -> u32 {
    var h = mix32(key) & params.table_mask;
    loop {
        let r = atomicCompareExchangeWeak(&hash[3u * h], 0u, key + 1u);
        if (r.exchanged || r.old_value == key + 1u) {
            break;
        }
        if (r.old_value != 0u) {
            h = (h + 1u) & params.table_mask;
        }
        // else: a weak exchange may fail spuriously; try the same entry again.
    }
    return h;
}

// Rounds a non-negative x half away from zero (Rust's `f32::round`; WGSL's `round` ties to even).
fn round_half_away(x: f32) -> f32 {
    let r = floor(x);
    return select(r, r + 1.0, x - r >= 0.5);
}

fn unpack_rgb(c: u32) -> vec3<f32> {
    return vec3<f32>(f32(c & 0xffu), f32((c >> 8u) & 0xffu), f32((c >> 16u) & 0xffu));
}

// Writes corner number `q`: the vertex on edge `e` of cube (x, y, z) of meshed block `b`.
fn emit_corner(b: u32, x: u32, y: u32, z: u32, e: u32, q: u32) {
    let axis = e / 4u;
    let a = EDGE_LOWER[e];
    let ax = x + (a & 1u);
    let ay = y + ((a >> 1u) & 1u);
    let az = z + ((a >> 2u) & 1u);
    var bx = ax;
    var by = ay;
    var bz = az;
    if (axis == 0u) { bx = bx + 1u; }
    if (axis == 1u) { by = by + 1u; }
    if (axis == 2u) { bz = bz + 1u; }
    let at_a = locate(b, ax, ay, az);
    let sa = sample_at(at_a);
    let sb = sample_at(locate(b, bx, by, bz));
    let fa = bitcast<f32>(sa.x);
    let fb = bitcast<f32>(sb.x);
    let t = clamp(fa / (fa - fb), 0.0, 1.0);
    let local = vec3<u32>(ax & 7u, ay & 7u, az & 7u);
    var p = vec3<f32>(
        centres[24u * at_a.x + local.x],
        centres[24u * at_a.x + 8u + local.y],
        centres[24u * at_a.x + 16u + local.z],
    );
    p[axis] = p[axis] + t * params.voxel_size_m;
    let ka = unpack_rgb(sa.y);
    let kb = unpack_rgb(sb.y);
    var rgb = 0u;
    for (var i = 0u; i < 3u; i = i + 1u) {
        let v = min(round_half_away(ka[i] + t * (kb[i] - ka[i])), 255.0);
        rgb = rgb | (u32(v) << (8u * i));
    }
    let key = (at_a.x * 512u + at_a.y) * 3u + axis;
    let h = entry_of(key);
    atomicMax(&hash[3u * h + 1u], ~q);
    corners[5u * q] = bitcast<u32>(p.x);
    corners[5u * q + 1u] = bitcast<u32>(p.y);
    corners[5u * q + 2u] = bitcast<u32>(p.z);
    corners[5u * q + 3u] = rgb;
    corners[5u * q + 4u] = h;
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let b = wg.y * num_wg.x + wg.x;
    let in_range = b < params.blocks;
    let place = params.first_block + b;
    let y = t % 8u;
    let z = t / 8u;
    var cases: array<u32, 8>;
    var total = 0u;
    if (in_range) {
        for (var x = 0u; x < 8u; x = x + 1u) {
            cases[x] = cube_case(place, x, y, z);
            total = total + triangle_count(cases[x]);
        }
    }
    let through_row = inclusive_scan_64(t, total);
    if (!in_range) {
        return;
    }
    var tri = tri_base[b] + through_row - total;
    for (var x = 0u; x < 8u; x = x + 1u) {
        let c = cases[x];
        let n = triangle_count(c);
        for (var j = 0u; j < n; j = j + 1u) {
            for (var k = 0u; k < 3u; k = k + 1u) {
                let e = table[c * params.table_stride + 1u + 3u * j + k];
                emit_corner(place, x, y, z, e, 3u * tri + k);
            }
            tri = tri + 1u;
        }
    }
}
