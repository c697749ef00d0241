// Exact twins of the CPU's rounding (WGSL's round() rounds halves to even).

// ⌊x + ½⌋ as the CPU's `round_i64(x as f64)` (src/grid/index.rs), exact in f32: x − ⌊x⌋ is
// representable, whereas x + 0.5 may round up (x = 0.49999997).
fn round_half_up(x: f32) -> f32 {
    let fl = floor(x);
    return fl + select(0.0, 1.0, x - fl >= 0.5);
}

// Rust's `f32::round`: halves away from zero, exact.
fn round_half_away(x: f32) -> f32 {
    let a = abs(x);
    let fl = floor(a);
    let r = fl + select(0.0, 1.0, a - fl >= 0.5);
    return select(r, -r, x < 0.0);
}
