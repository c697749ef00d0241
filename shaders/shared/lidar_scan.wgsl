// What the scan kernels (lidar_{rays,listed,list,rank,pairs}.wgsl) share: the scan's constants,
// as the CPU's f64 values' bits (`scan_words` in src/fusion/lidar_device.rs).

// Words: [0, 6) the sensor's position, world frame, metres (x, y, z); [6, 14) its rotation, a
// unit quaternion (i, j, k, w); [14, 16) the voxel size, metres; [16, 18) the truncation μ,
// metres; [18, 20) 1 / voxel size (the CPU's rounding); [20] rays; [21] (block, ray) pairs;
// [22] listed blocks; [23] the listed blocks' table's mask (lidar_listed.wgsl); [24, 26) the
// block size, metres; [26, 28) 1 / block size; [28, 31) the sensor's block (x, y, z), from
// which the listed blocks' packed offsets count; [31] words per listed block sent: 1 (an
// offset packed) or 3 (x, y, z); [32] the entries of lidar_blocks.wgsl's table where it listed
// the scan and is kept for lidar_listed.wgsl to read the counts from, else 0.
@group(0) @binding(0) var<storage, read> scan: array<u32>;

fn scan_f64(w: u32) -> vec2<u32> {
    return vec2<u32>(scan[w], scan[w + 1u]);
}

// Per ray, 4 words: the return as scanned, in the sensor's frame (3 f32), and its grey level.
const RAY_WORDS: u32 = 4u;
// Per ray, 8 words: its unit direction, world frame (3 f64), and its range (f64).
const RAY_F64_WORDS: u32 = 8u;

// Offsets from the sensor's block (scan[28..31)) that lidar_blocks.wgsl's table keys:
// -FOUND_HALF ≤ d < FOUND_HALF on every axis.
const FOUND_HALF: i32 = 512;
// Probes before an insert or a lookup in that table gives up (it is kept at most a quarter
// full).
const FOUND_PROBES: u32 = 4096u;

// The table's key of the block at `key`: its offset packed (10 bits an axis, x low, each biased
// by FOUND_HALF) plus one; 0 where the offset does not pack.
fn found_word(key: vec3<i32>) -> u32 {
    let origin = bitcast<vec3<i32>>(vec3<u32>(scan[28], scan[29], scan[30]));
    let d = key - origin;
    if (any(d < vec3<i32>(-FOUND_HALF)) || any(d >= vec3<i32>(FOUND_HALF))) {
        return 0u;
    }
    let u = bitcast<vec3<u32>>(d + vec3<i32>(FOUND_HALF));
    return (u.x | (u.y << 10u) | (u.z << 20u)) + 1u;
}
