// Shared by the kernels that pass disparities through as bits (SGM's selection and filters,
// the fill and the invalidation of the variational matcher): NaN never becomes a float there,
// and invalid pixels come out with the CPU's NaN.

// Rust's f32::NAN.
const NAN_BITS: u32 = 0x7fc00000u;

fn is_nan_bits(b: u32) -> bool {
    return (b & 0x7fffffffu) > 0x7f800000u;
}

fn is_finite_bits(b: u32) -> bool {
    return (b & 0x7f800000u) != 0x7f800000u;
}
