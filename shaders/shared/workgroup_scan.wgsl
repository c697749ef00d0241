// Shared by kernels of 64-invocation workgroups that place their invocations' outputs one after
// the other: the inclusive prefix sum of one value per invocation (Hillis–Steele, 6 steps).
// Call in uniform control flow (it has barriers), from every invocation of the workgroup.

var<workgroup> scan_lanes: array<u32, 64>;

// The sum of `v` over invocations 0..=t of the workgroup; `total_64` then reads the sum of all.
fn inclusive_scan_64(t: u32, v: u32) -> u32 {
    scan_lanes[t] = v;
    workgroupBarrier();
    for (var step = 1u; step < 64u; step = step * 2u) {
        var s = scan_lanes[t];
        if (t >= step) {
            s = s + scan_lanes[t - step];
        }
        workgroupBarrier();
        scan_lanes[t] = s;
        workgroupBarrier();
    }
    return scan_lanes[t];
}

// The sum of every invocation's value in the last `inclusive_scan_64`; call before the next.
fn total_64() -> u32 {
    return scan_lanes[63];
}
