//! The voxel predictor of chunk format 3 (`formats/chunk.md`, "Prediction"): a voxel's value is
//! guessed from the coded voxels before it (lower x, y or z) in its block or in the blocks of the
//! chunk next to it, so that only the residual is stored. TSDF fields are smooth near a surface (a plane is exactly a 2D Lorenzo
//! prediction), so the residuals are mostly sensor noise.

/// Block edge, voxels.
const E: usize = 8;
/// Edge of a block's prediction window: voxels −2..8 along each axis (the block at 0..8, the
/// rest from the neighbouring blocks at lower coordinates).
pub const W: usize = 10;
/// Cells of a prediction window.
pub const WN: usize = W * W * W;

/// Window cell of voxel `(x, y, z)` of the block (each in −2..8).
#[inline]
pub fn cell(x: i32, y: i32, z: i32) -> usize {
    ((x + 2) + W as i32 * (y + 2) + (W * W) as i32 * (z + 2)) as usize
}

/// The prediction of voxel `i` of a block from `v` (values of the window, read only where
/// `coded`: the block's coded voxels `j < i` and its neighbours' coded voxels) and `prev` (the
/// value of the previous coded voxel of the block, 0 for its first). Not clamped: callers clamp
/// to their field's range.
///
/// Rules, first that applies: the mean (rounded toward zero) of the 2D Lorenzo predictions
/// `a + b − ab` of the xy, xz and yz planes whose three voxels are coded; the linear extrapolation
/// `2·v(−1) − v(−2)` along x, then y, then z; the neighbour at −1 along x, then y, then z; `prev`.
pub fn predict(v: &[i32; WN], coded: &[bool; WN], i: usize, prev: i32) -> i32 {
    let at = cell((i % E) as i32, ((i / E) % E) as i32, (i / (E * E)) as i32);
    // Value at (x − dx, y − dy, z − dz) when it is coded.
    let g = |dx: usize, dy: usize, dz: usize| -> Option<i32> {
        let j = at - dx - W * dy - W * W * dz;
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
    use crate::grid::VOXELS_PER_BLOCK;

    /// A window holding `f` at the block's voxels (and nothing outside), coded where `c`.
    fn win(f: impl Fn(usize) -> i32, c: impl Fn(usize) -> bool) -> ([i32; WN], [bool; WN]) {
        let (mut v, mut m) = ([0; WN], [false; WN]);
        for i in 0..VOXELS_PER_BLOCK {
            let k = cell((i % 8) as i32, ((i / 8) % 8) as i32, (i / 64) as i32);
            v[k] = f(i);
            m[k] = c(i);
        }
        (v, m)
    }

    #[test]
    fn planes_are_predicted_exactly_and_fallbacks_apply_in_order() {
        // A plane: every interior voxel is predicted without error.
        let plane =
            |i: usize| 100 * (i % 8) as i32 - 37 * ((i / 8) % 8) as i32 + 11 * (i / 64) as i32;
        let (v, all) = win(plane, |_| true);
        for i in 0..VOXELS_PER_BLOCK {
            let (x, y, z) = (i % 8, (i / 8) % 8, i / 64);
            let faces = (x > 0) as u8 + (y > 0) as u8 + (z > 0) as u8;
            if faces >= 2 || x >= 2 || y >= 2 || z >= 2 {
                assert_eq!(predict(&v, &all, i, -5), plane(i), "voxel {i}");
            }
        }
        // The first voxel: only `prev`.
        assert_eq!(predict(&v, &all, 0, -5), -5);
        // x = 1 on the first row: the neighbour (no second one for a linear extrapolation).
        assert_eq!(predict(&v, &all, 1, -5), plane(0));
        // A neighbour block's voxels count: voxel 0 predicted from x = −1 and −2.
        let (mut nv, mut nc) = (v, all);
        nv[cell(-1, 0, 0)] = 7;
        nv[cell(-2, 0, 0)] = 10;
        nc[cell(-1, 0, 0)] = true;
        nc[cell(-2, 0, 0)] = true;
        assert_eq!(predict(&nv, &nc, 0, -5), 4, "2 · 7 − 10");
        // Mean of three Lorenzo planes, rounded toward zero.
        let (x1, y1, z1) = (8 + 64, 1 + 64, 1 + 8);
        let value = |j: usize| match j {
            j if j == x1 => 1,
            j if j == y1 => 2,
            j if j == z1 => -8,
            _ => 0,
        };
        let (w, c) = win(value, |j| [x1, y1, z1, 64, 8, 1].contains(&j));
        // xy: 1 + 2 − w[64] = 3; xz: 1 − 8 − w[8] = −7; yz: 2 − 8 − w[1] = −6; mean −10/3 → −3.
        assert_eq!(predict(&w, &c, 1 + 8 + 64, 99), -3);
        // Not coded voxels are never read: with none coded, `prev`.
        assert_eq!(predict(&w, &[false; WN], 1 + 8 + 64, 99), 99);
        assert_eq!(predict_u(100, 7), 105, "100 + floor(21 / 4)");
        assert_eq!(predict_u(100, -7), 94, "100 + floor(−21 / 4)");
        assert_eq!(predict_u(i16::MAX, 1000), i16::MAX);
        assert_eq!(clamp_u8(-3), 0);
        assert_eq!(clamp_u8(300), 255);
    }
}
