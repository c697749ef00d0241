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

/// A plane of disparity `d(x, y) = a + b·x + c·y` (left-image pixels) with its own texture,
/// covering the left-image rectangle `[x0, x1) × [y0, y1)` (the background covers everything).
#[derive(Clone, Copy, Debug)]
pub struct DisparityPlane {
    pub a: f64,
    pub b: f64,
    pub c: f64,
    pub rect: [f64; 4],
    pub seed: u64,
}

impl DisparityPlane {
    pub fn at(&self, x: f64, y: f64) -> f64 {
        self.a + self.b * x + self.c * y
    }
    fn contains(&self, x: f64, y: f64) -> bool {
        let [x0, y0, x1, y1] = self.rect;
        x >= x0 && x < x1 && y >= y0 && y < y1
    }
}

/// A piecewise-planar pair: `planes[0]` is the background (covers the image); later planes are
/// in front where they have a larger disparity. Each pixel of either image shows the visible
/// plane with the largest disparity (exact occlusion), textured in left-image coordinates; the
/// right image has gain 0.9 and offset +8. Gaussian noise of `noise_sigma` grey levels (fixed
/// seed) is added to both images. Returns (left, right, ground-truth left disparity).
pub fn piecewise_planar_pair(
    width: u32,
    height: u32,
    planes: &[DisparityPlane],
    noise_sigma: f64,
) -> (GreyImage, GreyImage, Image<f32>) {
    let textures: Vec<Texture> = planes.iter().map(|p| Texture::new(p.seed)).collect();
    let mut rng = 0x1234_5678_9abc_def0u64 ^ width as u64;
    let mut noise = move || {
        // Box–Muller from splitmix64.
        let mut next = || {
            rng = rng.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = rng;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        let (u1, u2) = (next().max(1e-12), next());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    };
    let mut left = Image::filled(width, height, 0u8);
    let mut right = Image::filled(width, height, 0u8);
    let mut gt = Image::filled(width, height, 0.0f32);
    for y in 0..height {
        let yf = y as f64;
        for x in 0..width {
            let xf = x as f64;
            // Left: the plane containing (x, y) with the largest disparity.
            let mut best: Option<(f64, usize)> = None;
            for (i, p) in planes.iter().enumerate() {
                if i == 0 || p.contains(xf, yf) {
                    let d = p.at(xf, yf);
                    if best.is_none_or(|(bd, _)| d > bd) {
                        best = Some((d, i));
                    }
                }
            }
            let (d, i) = best.expect("a background plane");
            *gt.at_mut(x, y) = d as f32;
            let v = textures[i].at(xf, yf) + noise_sigma * noise();
            *left.at_mut(x, y) = v.round().clamp(0.0, 255.0) as u8;
            // Right pixel xr shows left point x = (xr + a + c·y)/(1 − b) of each plane.
            let mut best_r: Option<(f64, usize, f64)> = None;
            for (i, p) in planes.iter().enumerate() {
                let xs = (xf + p.a + p.c * yf) / (1.0 - p.b);
                if i == 0 || p.contains(xs, yf) {
                    let d = p.at(xs, yf);
                    if best_r.is_none_or(|(bd, _, _)| d > bd) {
                        best_r = Some((d, i, xs));
                    }
                }
            }
            let (_, i, xs) = best_r.expect("a background plane");
            let v = 0.9 * textures[i].at(xs, yf) + 8.0 + noise_sigma * noise();
            *right.at_mut(x, y) = v.round().clamp(0.0, 255.0) as u8;
        }
    }
    (left, right, gt)
}

/// The fixed piecewise-planar scene of the TGV tests and bench, scaled to `width × height`: a
/// slanted background (ground-like, disparity growing downwards), a fronto-slanted box and a
/// tilted panel in front.
pub fn city_like_planes(width: u32, height: u32) -> Vec<DisparityPlane> {
    let (w, h) = (width as f64, height as f64);
    vec![
        DisparityPlane {
            a: 6.0,
            b: 0.004,
            c: 18.0 / h,
            rect: [0.0, 0.0, w, h],
            seed: 21,
        },
        DisparityPlane {
            a: 30.0,
            b: -6.0 / w,
            c: 0.0,
            rect: [0.15 * w, 0.2 * h, 0.45 * w, 0.75 * h],
            seed: 22,
        },
        DisparityPlane {
            a: 18.0,
            b: 8.0 / w,
            c: 4.0 / h,
            rect: [0.55 * w, 0.1 * h, 0.85 * w, 0.6 * h],
            seed: 23,
        },
    ]
}
