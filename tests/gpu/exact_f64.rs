//! The device's exact f64 arithmetic (`shaders/shared/exact_f64.wgsl`) against the CPU's f64,
//! bit for bit: every operation on values drawn across the exponent range and on the cases
//! where rounding decides (ties, carries into the exponent, cancellations, subnormals, signed
//! zeros, f32 midpoints, floors of integers and of the values next to them).

use crate::common;

use common::{gpu, Rng};
use denser::gpu::exact_f64::{exact_f64_on_gpu, F64Op};

const OPS: [F64Op; 4] = [F64Op::Add, F64Op::Sub, F64Op::Mul, F64Op::Div];

/// A value with a random sign, significand and an exponent within ±`spread` of 0.
fn value(rng: &mut Rng, spread: i32) -> f64 {
    let e = (rng.next_u64() % (2 * spread as u64 + 1)) as i32 - spread;
    let bits = (rng.next_u64() & ((1 << 52) - 1)) | (((e + 1023) as u64) << 52);
    let v = f64::from_bits(bits);
    if rng.next_u64() & 1 == 1 {
        -v
    } else {
        v
    }
}

/// `v` and the f64s either side of it.
fn around(v: f64) -> [f64; 3] {
    [-1i64, 0, 1].map(|k| f64::from_bits((v.to_bits() as i64 + k) as u64))
}

/// Values where rounding decides: near powers of two, halfway cases, next-door neighbours.
fn edges() -> Vec<f64> {
    let mut v = vec![
        0.0, -0.0, 1.0, -1.0, 0.5, 3.0, 0.1, 1e-300, 2.2e-308, 5e-324, 1e300,
    ];
    for base in [1.0f64, 3.0, 1e3, 8.0, 0.1, 1.0 / 3.0, 1e-310] {
        v.extend(around(base));
    }
    // 1 + 2^-53 is not an f64, but 1 + 2^-52 and the f32 midpoints are.
    v.push(1.0 + f64::EPSILON);
    v.push(1.0 + (f32::EPSILON as f64) / 2.0);
    v.push(1.0 + (f32::EPSILON as f64) * 1.5);
    v.push(-(1.0 + (f32::EPSILON as f64) / 2.0));
    v.push(f32::MAX as f64);
    v.push(f32::MIN_POSITIVE as f64 / 3.0);
    v
}

fn check(ctx: &denser::gpu::GpuContext, cases: &[(F64Op, f64, f64)]) -> usize {
    let got = exact_f64_on_gpu(ctx, cases).expect("device");
    let mut wrong = 0;
    for (&(op, a, b), &(bits, flagged)) in cases.iter().zip(&got) {
        let want = op.cpu(a, b);
        // The CPU's finite results only: the device flags what leaves them.
        let finite = match op {
            F64Op::Add | F64Op::Sub | F64Op::Mul | F64Op::Div => f64::from_bits(want).is_finite(),
            F64Op::ToF32 => f32::from_bits(want as u32).is_finite(),
            F64Op::FloorI32 => a.floor().abs() < 2f64.powi(31),
            F64Op::Sqrt => a >= 0.0 || a == 0.0,
            _ => true,
        };
        if !finite {
            assert!(
                flagged,
                "{op:?}({a:e}, {b:e}) leaves the finite values but was not flagged"
            );
            continue;
        }
        if bits != want || flagged {
            wrong += 1;
            if wrong <= 10 {
                eprintln!("{op:?}({a:e}, {b:e}): device {bits:#018x} (flagged {flagged}), CPU {want:#018x}");
            }
        }
    }
    wrong
}

#[test]
fn exact_f64_operations_equal_the_cpus_bit_for_bit() {
    let Some(ctx) = gpu() else { return };
    let mut rng = Rng(0x5eed);
    let mut cases = Vec::new();
    // Random values: close exponents (cancellations, carries) and wide ones (alignment).
    for spread in [2, 60, 1000] {
        for _ in 0..6000 {
            let op = OPS[(rng.next_u64() % 4) as usize];
            cases.push((op, value(&mut rng, spread), value(&mut rng, spread)));
        }
    }
    // Neighbours: a ± a(1 ± ulp), products and quotients at halfway points.
    for _ in 0..4000 {
        let a = value(&mut rng, 30);
        let b = -around(a)[(rng.next_u64() % 3) as usize];
        cases.push((F64Op::Add, a, b));
        cases.push((F64Op::Sub, a, -b));
        let h = f64::from_bits((rng.next_u64() & 0xfff) | 0x3ff0_0000_0000_0000);
        cases.push((F64Op::Mul, h, 1.0 + 2f64.powi(-26)));
        cases.push((F64Op::Div, a, b));
    }
    let e = edges();
    for &a in &e {
        for &b in &e {
            for op in OPS {
                cases.push((op, a, b));
            }
            cases.push((F64Op::Less, a, b));
        }
    }
    // Conversions and floors: random values, f32 midpoints and their neighbours, integers.
    for _ in 0..6000 {
        let a = value(&mut rng, 140);
        cases.push((F64Op::ToF32, a, 0.0));
        let f = a as f32;
        let mid = (f as f64 + f32::from_bits(f.to_bits() + 1) as f64) / 2.0;
        for m in around(mid) {
            cases.push((F64Op::ToF32, m, 0.0));
        }
        cases.push((
            F64Op::FromF32,
            f64::from_bits(rng.next_u64() & 0x7f7f_ffff),
            0.0,
        ));
        let x = value(&mut rng, 33);
        cases.push((F64Op::FloorI32, x, 0.0));
        let n = (x as i64).clamp(-(1 << 30), 1 << 30) as f64;
        for m in around(n) {
            cases.push((F64Op::FloorI32, m, 0.0));
        }
        cases.push((
            F64Op::FromI32,
            f64::from_bits(rng.next_u64() & 0xffff_ffff),
            0.0,
        ));
        let (p, q) = (value(&mut rng, 3), value(&mut rng, 3));
        cases.push((F64Op::Less, p, q));
    }
    for bits in [0u32, 1, 0x7f_ffff, 0x80_0000, 0x8000_0001, 0x7f7f_ffff] {
        cases.push((F64Op::FromF32, f64::from_bits(bits as u64), 0.0));
    }
    for n in [0i32, 1, -1, i32::MAX, i32::MIN, 1 << 24, -(1 << 24) - 1] {
        cases.push((F64Op::FromI32, f64::from_bits(n as u32 as u64), 0.0));
    }
    for a in [
        1e300,
        2.5,
        -2.5,
        -0.5,
        -0.0,
        1e-320,
        -1e-320,
        2147483647.5,
        -2147483648.0,
    ] {
        cases.push((F64Op::FloorI32, a, 0.0));
    }
    // Square roots: random values (odd and even exponents), squares, the values next to them,
    // subnormals, zeros, negatives (flagged).
    for _ in 0..6000 {
        let a = value(&mut rng, 1000).abs();
        cases.push((F64Op::Sqrt, a, 0.0));
        let s = (value(&mut rng, 20).abs() * 1e3).round();
        for m in around(s * s) {
            cases.push((F64Op::Sqrt, m, 0.0));
        }
    }
    for a in [0.0, -0.0, 5e-324, 1e-310, 2.0, 4.0, 0.25, -1.0, 1e300] {
        cases.push((F64Op::Sqrt, a, 0.0));
    }
    let wrong = check(&ctx, &cases);
    eprintln!(
        "exact f64: {} cases, {wrong} differ from the CPU",
        cases.len()
    );
    assert_eq!(wrong, 0);
}
