//! Synthetic rectified stereo pairs with exactly known disparity, shared by the depth tests and
//! the `depth_sgm` bench (included there with `#[path]`).
#![allow(dead_code)]

use denser::frame::{GreyImage, Image};

/// Deterministic value noise: random lattice values (splitmix64 of the cell index) interpolated
/// bilinearly, two octaves (2 px and 7 px cells). Returns grey levels in [0, 255].
pub struct Texture {
    seed: u64,
}

fn hash01(seed: u64, i: i64, j: i64, octave: u64) -> f64 {
    let mut z = seed
        ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ octave.wrapping_mul(0x1656_67B1_9E37_79F9);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

impl Texture {
    pub fn new(seed: u64) -> Self {
        Texture { seed }
    }

    fn octave(&self, x: f64, y: f64, cell: f64, octave: u64) -> f64 {
        let (gx, gy) = (x / cell, y / cell);
        let (i, j) = (gx.floor() as i64, gy.floor() as i64);
        let (fx, fy) = (gx - i as f64, gy - j as f64);
        let v = |di: i64, dj: i64| hash01(self.seed, i + di, j + dj, octave);
        let top = v(0, 0) * (1.0 - fx) + v(1, 0) * fx;
        let bottom = v(0, 1) * (1.0 - fx) + v(1, 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// Grey level at continuous (x, y).
    pub fn at(&self, x: f64, y: f64) -> f64 {
        255.0 * (0.7 * self.octave(x, y, 2.0, 0) + 0.3 * self.octave(x, y, 7.0, 1))
    }
}

/// A pair whose left-image disparity is the plane `d(x, y) = a + b·x + c·y` (pixels): the left
/// image is the texture, the right image samples it at `x = (x_r + a + c·y) / (1 − b)`, so that
/// left pixel x matches right x − d(x, y) exactly. The right image has gain 0.9 and offset +8
/// (a census matcher must not care). Returns (left, right, ground-truth disparity).
pub fn planar_pair(
    width: u32,
    height: u32,
    a: f64,
    b: f64,
    c: f64,
    seed: u64,
) -> (GreyImage, GreyImage, Image<f32>) {
    let t = Texture::new(seed);
    let mut left = Image::filled(width, height, 0u8);
    let mut right = Image::filled(width, height, 0u8);
    let mut gt = Image::filled(width, height, 0.0f32);
    for y in 0..height {
        for x in 0..width {
            let (xf, yf) = (x as f64, y as f64);
            *left.at_mut(x, y) = t.at(xf, yf).round().clamp(0.0, 255.0) as u8;
            let xs = (xf + a + c * yf) / (1.0 - b);
            *right.at_mut(x, y) = (0.9 * t.at(xs, yf) + 8.0).round().clamp(0.0, 255.0) as u8;
            *gt.at_mut(x, y) = (a + b * xf + c * yf) as f32;
        }
    }
    (left, right, gt)
}
