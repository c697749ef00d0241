//! The voxel predictor of chunk format 3 (`formats/chunk.md`, "Prediction"): a voxel's value is
//! guessed from the coded voxels before it in the same block (lower x, y or z), so that only the
//! residual is stored. TSDF fields are smooth near a surface (a plane is exactly a 2D Lorenzo
//! prediction), so the residuals are mostly sensor noise.

use crate::grid::VOXELS_PER_BLOCK;

/// Block edge, voxels.
const E: usize = 8;

/// The prediction of voxel `i` of a block from `v` (values of the block's voxels, read only at
/// coded voxels `j < i`), `coded` (which voxels are coded) and `prev` (the value of the previous
/// coded voxel of the block, 0 for its first). Not clamped: callers clamp to their field's range.
///
/// Rules, first that applies: the mean (rounded toward zero) of the 2D Lorenzo predictions
/// `a + b − ab` of the xy, xz and yz planes whose three voxels are coded; the linear extrapolation
/// `2·v(−1) − v(−2)` along x, then y, then z; the neighbour at −1 along x, then y, then z; `prev`.
pub fn predict(
    v: &[i32; VOXELS_PER_BLOCK],
    coded: &[bool; VOXELS_PER_BLOCK],
    i: usize,
    prev: i32,
) -> i32 {
    let (x, y, z) = (i % E, (i / E) % E, i / (E * E));
    // Value at (x − dx, y − dy, z − dz) when it lies in the block and is coded.
    let g = |dx: usize, dy: usize, dz: usize| -> Option<i32> {
        if dx > x || dy > y || dz > z {
            return None;
        }
        let j = i - dx - E * dy - E * E * dz;
        coded[j].then(|| v[j])
    };
    let (gx, gy, gz) = (g(1, 0, 0), g(0, 1, 0), g(0, 0, 1));
    let lorenzo = |a: Option<i32>, b: Option<i32>, ab: Option<i32>| Some(a? + b? - ab?);
    let (mut sum, mut n) = (0i32, 0i32);
    for p in [
        lorenzo(gx, gy, g(1, 1, 0)),
        lorenzo(gx, gz, g(1, 0, 1)),
        lorenzo(gy, gz, g(0, 1, 1)),
    ]
    .into_iter()
    .flatten()
    {
        sum += p;
        n += 1;
    }
    if n > 0 {
        return sum / n;
    }
    let linear = |a: Option<i32>, b: Option<i32>| Some(2 * a? - b?);
    linear(gx, g(2, 0, 0))
        .or_else(|| linear(gy, g(0, 2, 0)))
        .or_else(|| linear(gz, g(0, 0, 2)))
        .or(gx)
        .or(gy)
        .or(gz)
        .unwrap_or(prev)
}

/// `p` clamped to the range of an `i16` field.
#[inline]
pub fn clamp_i16(p: i32) -> i16 {
    p.clamp(i16::MIN as i32, i16::MAX as i32) as i16
}

/// `p` clamped to the range of a `u8` field.
#[inline]
pub fn clamp_u8(p: i32) -> u8 {
    p.clamp(0, 255) as u8
}

/// The prediction of `u` at a voxel: `pu` = the clamped prediction of `u` itself, plus three
/// quarters (rounded down) of the TSDF's own residual `ef` = `f − clamped prediction of f`
/// (`u` follows the part of `f` its neighbours do not explain), clamped.
#[inline]
pub fn predict_u(pu: i16, ef: i32) -> i16 {
    clamp_i16(pu as i32 + ((3 * ef) >> 2))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planes_are_predicted_exactly_and_fallbacks_apply_in_order() {
        let all = [true; VOXELS_PER_BLOCK];
        // A plane: every interior voxel is predicted without error.
        let v: [i32; VOXELS_PER_BLOCK] = std::array::from_fn(|i| {
            100 * (i % 8) as i32 - 37 * ((i / 8) % 8) as i32 + 11 * (i / 64) as i32
        });
        for i in 0..VOXELS_PER_BLOCK {
            let (x, y, z) = (i % 8, (i / 8) % 8, i / 64);
            let faces = (x > 0) as u8 + (y > 0) as u8 + (z > 0) as u8;
            if faces >= 2 || x >= 2 || y >= 2 || z >= 2 {
                assert_eq!(predict(&v, &all, i, -5), v[i], "voxel {i}");
            }
        }
        // The first voxel: only `prev`.
        assert_eq!(predict(&v, &all, 0, -5), -5);
        // x = 1 on the first row: the neighbour (no second one for a linear extrapolation).
        assert_eq!(predict(&v, &all, 1, -5), v[0]);
        // Mean of two Lorenzo planes, rounded toward zero: xy gives 1 + 2 − 0 = 3, xz 1 + 4 − 0.
        let mut w = [0i32; VOXELS_PER_BLOCK];
        let (i, x1, y1, z1) = (1 + 8 + 64, 8 + 64, 1 + 64, 1 + 8);
        w[x1] = 1;
        w[y1] = 2;
        w[z1] = -8;
        let mut c = [false; VOXELS_PER_BLOCK];
        for j in [x1, y1, z1, 64, 8, 1] {
            c[j] = true;
        }
        // xy: 1 + 2 − w[64] = 3; xz: 1 − 8 − w[8] = −7; yz: 2 − 8 − w[1] = −6; mean −10/3 → −3.
        assert_eq!(predict(&w, &c, i, 99), -3);
        // Not coded voxels are never read: with none coded, `prev`.
        assert_eq!(predict(&w, &[false; VOXELS_PER_BLOCK], i, 99), 99);
        assert_eq!(predict_u(100, 7), 105, "100 + floor(21 / 4)");
        assert_eq!(predict_u(100, -7), 94, "100 + floor(−21 / 4)");
        assert_eq!(predict_u(i16::MAX, 1000), i16::MAX);
        assert_eq!(clamp_u8(-3), 0);
        assert_eq!(clamp_u8(300), 255);
    }
}
