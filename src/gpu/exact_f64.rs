//! Exact binary64 arithmetic on the device (`shaders/shared/exact_f64.wgsl`): the CPU's f64
//! operations in 32-bit integers, rounded as IEEE 754 rounds, so a kernel reproduces the CPU's
//! f64 values bit for bit on any device, with or without `SHADER_F64` (a device's own f64 may
//! fuse a multiply with an add, or divide within some ULPs). Used where a kernel must make
//! what the CPU makes from f64 geometry (a LiDAR scan's rays and (block, ray) pairs,
//! `crate::fusion::lidar_device`). [`F64Op::cpu`] is each operation's CPU twin, and
//! [`exact_f64_on_gpu`] runs them on the device for the tests.

use super::{shaders, GpuContext};
use crate::grid::floor_i64;
use crate::Result;

/// One operation of `exact_f64.wgsl` (its number in `shaders/exact_f64_check.wgsl`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum F64Op {
    /// a + b.
    Add = 0,
    /// a − b.
    Sub = 1,
    /// a × b.
    Mul = 2,
    /// a / b.
    Div = 3,
    /// `a as f32` (its bits).
    ToF32 = 4,
    /// `f as f64` of the f32 whose bits are a's low word.
    FromF32 = 5,
    /// ⌊a⌋ as an i32 (`floor_i64`).
    FloorI32 = 6,
    /// a < b (1 or 0).
    Less = 7,
    /// `n as f64` of the i32 whose bits are a's low word.
    FromI32 = 8,
    /// √a.
    Sqrt = 9,
}

impl F64Op {
    /// The CPU's result, as the device returns it: an f64's bits, or an f32's, an i32's or a
    /// bool's in the low word.
    pub fn cpu(self, a: f64, b: f64) -> u64 {
        let low = a.to_bits() as u32;
        match self {
            F64Op::Add => (a + b).to_bits(),
            F64Op::Sub => (a - b).to_bits(),
            F64Op::Mul => (a * b).to_bits(),
            F64Op::Div => (a / b).to_bits(),
            F64Op::ToF32 => (a as f32).to_bits() as u64,
            F64Op::FromF32 => (f32::from_bits(low) as f64).to_bits(),
            F64Op::FloorI32 => floor_i64(a) as i32 as u32 as u64,
            F64Op::Less => (a < b) as u64,
            F64Op::FromI32 => (low as i32 as f64).to_bits(),
            F64Op::Sqrt => a.sqrt().to_bits(),
        }
    }
}

/// Applies each case's operation on the device; returns each result (as [`F64Op::cpu`]
/// returns it) and whether the device's arithmetic flagged it (an infinite or NaN operand or
/// result, a floor beyond i32).
pub fn exact_f64_on_gpu(ctx: &GpuContext, cases: &[(F64Op, f64, f64)]) -> Result<Vec<(u64, bool)>> {
    if cases.is_empty() {
        return Ok(Vec::new());
    }
    let words: Vec<u32> = cases
        .iter()
        .flat_map(|&(op, a, b)| {
            let (a, b) = (a.to_bits(), b.to_bits());
            [
                op as u32,
                a as u32,
                (a >> 32) as u32,
                b as u32,
                (b >> 32) as u32,
            ]
        })
        .collect();
    let kernel = ctx.kernel(&shaders::EXACT_F64_CHECK)?;
    let buf_cases = ctx.storage("exact_f64_cases", bytemuck::cast_slice(&words));
    let buf_results = ctx.storage_zeroed("exact_f64_results", cases.len() as u64 * 12);
    let bind = ctx.bind_group(
        "exact_f64_check",
        &kernel.layout,
        &[&buf_cases, &buf_results],
    );
    let mut encoder = ctx.encoder("exact_f64_check");
    ctx.record_dispatch(&mut encoder, &kernel, &bind, cases.len() as u64)?;
    ctx.submit(encoder);
    let results: Vec<[u32; 3]> = ctx.read_back_as(&buf_results, cases.len())?;
    Ok(results
        .iter()
        .map(|r| (r[0] as u64 | (r[1] as u64) << 32, r[2] != 0))
        .collect())
}
