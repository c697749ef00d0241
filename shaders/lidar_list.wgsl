// A LiDAR scan's (block, ray) pairs listed on the device: each ray's band walked through the
// blocks it crosses (shared/lidar_traverse.wgsl) and the ray written among each crossed block's
// pairs (at ray_offsets, lidar_prefix.wgsl) at a place taken by an atomic counter: each
// block's rays in some order, which lidar_rank.wgsl puts in scan order. One invocation per
// ray. Shared files and bindings: src/gpu/shaders.rs.

// Per pair: its ray, each block's in the order written.
@group(0) @binding(7) var<storage, read_write> unsorted_rays: array<u32>;

// Writes ray k among the pairs of listed block b.
fn visit_listed(b: u32, k: u32) {
    let at = atomicAdd(&fill[b], 1u);
    if (at >= ray_offsets[b + 1u] - ray_offsets[b]) {
        atomicAdd(&counters[1], 1u);
        return;
    }
    unsorted_rays[ray_offsets[b] + at] = k;
}
