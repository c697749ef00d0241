//! Stereo rendering of the synthetic city by ray casting: a rectified KITTI-like rig, Lambertian
//! shading under a sun (with shadow rays) and a sky-dome ambient term, distance haze, optional
//! supersampling, a small gain difference between the two cameras and Gaussian sensor noise
//! seeded per frame and camera. Produces colour and grey images for both cameras and the exact
//! depth (z) of the left camera. Does not simulate motion blur, lens distortion or auto exposure.

use super::city::City;
use super::geometry::Ray;
use super::rng::{gaussian, hash3};
use super::texture::Rgb;
use crate::camera::{PinholeIntrinsics, WorldFromCamera};
use crate::frame::{DepthImage, GreyImage, Image, RgbImage};
use nalgebra::{Isometry3, Point3, Translation3, Vector3};
use rayon::prelude::*;
use std::sync::OnceLock;

/// A rectified stereo rig: both cameras share the intrinsics; the right camera sits
/// `baseline_m` along the left camera's +x axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StereoRig {
    /// Intrinsics of both cameras.
    pub intrinsics: PinholeIntrinsics,
    /// Distance between the optical centres along x, metres.
    pub baseline_m: f64,
}

impl StereoRig {
    /// KITTI odometry's grey pair (sequence 00): 1241×376, f = 718.856 px, baseline 0.54 m
    /// (P1[0,3] = −fx·b = −386.1448).
    pub fn kitti() -> Self {
        StereoRig {
            intrinsics: PinholeIntrinsics {
                fx: 718.856,
                fy: 718.856,
                cx: 607.1928,
                cy: 185.2157,
                width: 1241,
                height: 376,
            },
            baseline_m: 386.1448 / 718.856,
        }
    }

    /// The same rig imaging the same field of view at `width × height` pixels.
    pub fn scaled(&self, width: u32, height: u32) -> Self {
        let k = &self.intrinsics;
        let (sx, sy) = (
            width as f64 / k.width as f64,
            height as f64 / k.height as f64,
        );
        StereoRig {
            intrinsics: PinholeIntrinsics {
                fx: k.fx * sx,
                fy: k.fy * sy,
                cx: (k.cx + 0.5) * sx - 0.5,
                cy: (k.cy + 0.5) * sy - 0.5,
                width,
                height,
            },
            baseline_m: self.baseline_m,
        }
    }

    /// Pose of the right camera given the left one.
    pub fn right_from(&self, world_from_left: &WorldFromCamera) -> WorldFromCamera {
        world_from_left
            * Isometry3::from_parts(
                Translation3::new(self.baseline_m, 0.0, 0.0),
                Default::default(),
            )
    }
}

/// Rendering settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    /// Rays per pixel side (1: one ray per pixel; 2: 2×2 supersampling).
    pub supersampling: u32,
    /// Cast shadow rays towards the sun.
    pub shadows: bool,
    /// Standard deviation of the Gaussian noise added to each colour channel, 8-bit levels.
    pub noise_sigma: f64,
    /// Gain of the right camera relative to the left (e.g. 0.96: 4 % darker).
    pub right_gain: f64,
    /// Overall exposure multiplier.
    pub exposure: f64,
    /// Unit vector towards the sun (world frame, y down: the sun has negative y).
    pub sun_direction: Vector3<f64>,
    /// Distance at which haze has taken 63 % of the colour, metres.
    pub haze_m: f64,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            supersampling: 1,
            shadows: true,
            noise_sigma: 2.0,
            right_gain: 0.96,
            exposure: 1.0,
            sun_direction: Vector3::new(-0.45, -0.75, 0.5).normalize(),
            haze_m: 600.0,
        }
    }
}

/// One rendered stereo pair with the left camera's exact depth.
#[derive(Clone, Debug, PartialEq)]
pub struct StereoFrame {
    /// Left colour image.
    pub left_rgb: RgbImage,
    /// Right colour image.
    pub right_rgb: RgbImage,
    /// Left grey image (luma of the left colour image).
    pub left_grey: GreyImage,
    /// Right grey image.
    pub right_grey: GreyImage,
    /// Left-camera depth (z), metres, NaN where the ray sees sky.
    pub depth_gt_m: DepthImage,
}

const SUN: [f32; 3] = [1.0, 0.96, 0.88];
const AMBIENT: [f32; 3] = [0.3, 0.34, 0.42];
const HORIZON: [f32; 3] = [0.72, 0.78, 0.86];
const ZENITH: [f32; 3] = [0.3, 0.48, 0.78];

fn gamma_lut() -> &'static [u8] {
    static LUT: OnceLock<Vec<u8>> = OnceLock::new();
    LUT.get_or_init(|| {
        (0..=4096)
            .map(|i| ((i as f64 / 4096.0).powf(1.0 / 2.2) * 255.0).round() as u8)
            .collect()
    })
}

fn gamma_f_lut() -> &'static [f32] {
    static LUT: OnceLock<Vec<f32>> = OnceLock::new();
    LUT.get_or_init(|| {
        (0..=4096)
            .map(|i| ((i as f64 / 4096.0).powf(1.0 / 2.2) * 255.0) as f32)
            .collect()
    })
}

/// Encodes a linear value in [0, 1] to 8-bit levels (gamma 2.2), as a float.
#[inline]
fn encode(v: f32) -> f32 {
    gamma_f_lut()[((v.clamp(0.0, 1.0) * 4096.0) as usize).min(4096)]
}

/// Linear albedo to 8-bit sRGB-like colour (gamma 2.2), for coloured point samples.
pub fn albedo_to_srgb(c: Rgb) -> [u8; 3] {
    let lut = gamma_lut();
    c.map(|v| lut[((v.clamp(0.0, 1.0) * 4096.0) as usize).min(4096)])
}

/// Luma (BT.601) of an 8-bit colour.
#[inline]
pub fn luma(c: [u8; 3]) -> u8 {
    (0.299 * c[0] as f32 + 0.587 * c[1] as f32 + 0.114 * c[2] as f32)
        .round()
        .clamp(0.0, 255.0) as u8
}

fn sky(d: &Vector3<f64>) -> Rgb {
    let up = (-d.y / d.norm()).max(0.0);
    let t = up.powf(0.6);
    let mut c = [0f32; 3];
    for k in 0..3 {
        c[k] = HORIZON[k] + (ZENITH[k] - HORIZON[k]) * t as f32;
    }
    c
}

impl City {
    /// Radiance (linear) seen along `ray`, and the hit parameter (None for sky).
    fn shade(&self, ray: &Ray, opts: &RenderOptions) -> (Rgb, Option<f64>) {
        let Some(h) = self.cast(ray) else {
            return (sky(&ray.direction), None);
        };
        let mut n = h.normal;
        if n.dot(&ray.direction) > 0.0 {
            n = -n;
        }
        let l = opts.sun_direction;
        let ndl = n.dot(&l);
        // Facing away, or in a shadow (tested only for faces towards the sun).
        let shadowed =
            || opts.shadows && self.occluded(&Ray::new(h.point + n * 1e-4, l), f64::INFINITY);
        let lit = if ndl <= 0.0 || shadowed() {
            0.0
        } else {
            ndl as f32
        };
        let sky_amb = (0.55 + 0.45 * (-n.y)) as f32;
        let dist = h.t * ray.direction.norm();
        let fog = (-dist / opts.haze_m).exp() as f32;
        let mut c = [0f32; 3];
        for k in 0..3 {
            let v = h.albedo[k] * (SUN[k] * lit + AMBIENT[k] * sky_amb * 1.2);
            c[k] = v * fog + HORIZON[k] * (1.0 - fog);
        }
        (c, Some(h.t))
    }

    /// Renders one camera: colour (with `gain` and noise seeded by `seed`) and, if asked, depth.
    pub fn render_view(
        &self,
        world_from_camera: &WorldFromCamera,
        intrinsics: &PinholeIntrinsics,
        gain: f64,
        seed: u64,
        opts: &RenderOptions,
        with_depth: bool,
    ) -> (RgbImage, Option<DepthImage>) {
        let (w, h) = (intrinsics.width as usize, intrinsics.height as usize);
        let mut rgb = Image::filled(intrinsics.width, intrinsics.height, [0u8; 3]);
        let mut depth = Image::filled(intrinsics.width, intrinsics.height, f32::NAN);
        let origin = Point3::from(world_from_camera.translation.vector);
        let rot = world_from_camera.rotation.to_rotation_matrix();
        let k = opts.supersampling.max(1) as usize;
        let offsets: Vec<f64> = (0..k).map(|i| (i as f64 + 0.5) / k as f64 - 0.5).collect();
        let scale = (opts.exposure * gain) as f32 / (k * k) as f32;
        let sigma = opts.noise_sigma as f32;
        let centre_is_sample = k % 2 == 1;
        rgb.data
            .par_chunks_mut(w)
            .zip(depth.data.par_chunks_mut(w))
            .enumerate()
            .for_each(|(v, (row, drow))| {
                for u in 0..w {
                    let mut acc = [0f32; 3];
                    let mut depth_t = None;
                    for (a, oy) in offsets.iter().enumerate() {
                        for (b, ox) in offsets.iter().enumerate() {
                            let dc = intrinsics.ray(u as f64 + ox, v as f64 + oy);
                            let ray = Ray::new(origin, rot * dc);
                            let (c, t) = self.shade(&ray, opts);
                            if centre_is_sample && a == k / 2 && b == k / 2 {
                                depth_t = Some(t);
                            }
                            for q in 0..3 {
                                acc[q] += c[q];
                            }
                        }
                    }
                    if with_depth {
                        let t = match depth_t {
                            Some(t) => t,
                            None => self
                                .cast(&Ray::new(origin, rot * intrinsics.ray(u as f64, v as f64)))
                                .map(|h| h.t),
                        };
                        // The camera ray's direction has z = 1 in the camera frame, so t is the depth.
                        drow[u] = t.map_or(f32::NAN, |t| t as f32);
                    }
                    let pix = v * w + u;
                    let mut out = [0u8; 3];
                    for q in 0..3 {
                        let noise = sigma * gaussian(hash3(seed, pix as u64, q as u64)) as f32;
                        out[q] = (encode(acc[q] * scale) + noise).round().clamp(0.0, 255.0) as u8;
                    }
                    row[u] = out;
                }
            });
        let _ = h;
        (rgb, with_depth.then_some(depth))
    }

    /// Renders the stereo pair at `world_from_cam0` (the left camera) and the left depth;
    /// `frame_seed` seeds the sensor noise (see [`City::frame_seed`]).
    pub fn render_stereo(
        &self,
        world_from_cam0: &WorldFromCamera,
        rig: &StereoRig,
        opts: &RenderOptions,
        frame_seed: u64,
    ) -> StereoFrame {
        let (left_rgb, depth) = self.render_view(
            world_from_cam0,
            &rig.intrinsics,
            1.0,
            hash3(frame_seed, 0, 0x1EF7),
            opts,
            true,
        );
        let (right_rgb, _) = self.render_view(
            &rig.right_from(world_from_cam0),
            &rig.intrinsics,
            opts.right_gain,
            hash3(frame_seed, 1, 0x816E7),
            opts,
            false,
        );
        let grey = |img: &RgbImage| GreyImage {
            width: img.width,
            height: img.height,
            data: img.data.iter().map(|&c| luma(c)).collect(),
        };
        StereoFrame {
            left_grey: grey(&left_rgb),
            right_grey: grey(&right_rgb),
            left_rgb,
            right_rgb,
            depth_gt_m: depth.unwrap_or_else(|| {
                Image::filled(rig.intrinsics.width, rig.intrinsics.height, f32::NAN)
            }),
        }
    }
}
