// Shared by every kernel: the flat invocation index of a 2-D dispatch.
// Dispatches larger than 65 535 workgroups are split over y (see src/gpu/context.rs,
// `workgroups_2d`); keep WORKGROUP_SIZE in sync with `WORKGROUP_SIZE` there.

const WORKGROUP_SIZE: u32 = 64u;

fn flat_index(wg: vec3<u32>, num_wg: vec3<u32>, local: u32) -> u32 {
    return (wg.y * num_wg.x + wg.x) * WORKGROUP_SIZE + local;
}
