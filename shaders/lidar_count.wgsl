// A LiDAR scan's (block, ray) pairs counted on the device: each ray's band walked through the
// blocks it crosses (shared/lidar_traverse.wgsl), one count per crossing, so that
// lidar_prefix.wgsl places each listed block's pairs without the host sending where. One
// invocation per ray. Shared files and bindings: src/gpu/shaders.rs.

fn visit_listed(b: u32, k: u32) {
    atomicAdd(&fill[b], 1u);
}
