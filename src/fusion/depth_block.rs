//! The CPU kernel of depth-map fusion: one block's 512 voxels projected, matched against the
//! depth map and averaged in (twin of `fuse_voxel` in `shaders/shared/fuse_common.wgsl`: the same
//! f32 operations in the same order, so the same bits).
//!
//! Three loops the compiler vectorises, with no branch per voxel: the projection, the pixel
//! reads, the update. A frame is read through [`FramePixels`]: per pixel one word holding its
//! depth (NaN where unusable) and its colour, plus one extra NaN pixel that every voxel outside
//! the image reads. A voxel is then updated exactly when `d − z ≥ −μ` holds for the depth `d`
//! it reads, which NaN fails. Before, a scalar loop selected the voxels with three
//! data-dependent branches and the saturating `f32 as i32` conversions of the rounding were
//! done lane by lane: this kernel made depth fusion 1.6–2.2× faster (`docs/bench/speed.md`).

use super::depth::{usable, DepthFusionParams, DepthGeometry};
use crate::frame::DepthFrame;
use crate::gpu::layout::pack_rgb;
use crate::grid::{fused_lane, Block, VOXELS_PER_BLOCK, VOXELS_PER_SIDE};
use rayon::prelude::*;

/// A depth frame's pixels as [`fuse_block`] reads them, with one trailing pixel for voxels
/// that project outside the image.
pub(super) struct FramePixels {
    /// Per pixel, the bits of its depth in metres (NaN where [`usable`] rejects it, and at the
    /// trailing pixel) in the low word, its colour `r | g << 8 | b << 16` in the high word: one
    /// load per voxel.
    packed: Vec<u64>,
    /// Whether colour is fused.
    color: bool,
}

/// Pixels per rayon task when preparing [`FramePixels`].
const PREPARE_CHUNK: usize = 1 << 14;

impl FramePixels {
    const fn empty() -> Self {
        FramePixels {
            packed: Vec::new(),
            color: false,
        }
    }

    /// Runs `f` on the pixels of `frame`, with colour when `params.use_color` and the frame has
    /// it. The buffers are the calling thread's, kept between frames (a frame's are as large as
    /// its image; allocating them afresh cost a page fault per 4 KiB every frame).
    pub(super) fn with<R>(
        frame: &DepthFrame,
        params: &DepthFusionParams,
        f: impl FnOnce(&FramePixels) -> R,
    ) -> R {
        thread_local! {
            static PIXELS: std::cell::RefCell<FramePixels> = const {
                std::cell::RefCell::new(FramePixels::empty())
            };
        }
        PIXELS.with(|cell| match cell.try_borrow_mut() {
            Ok(mut pixels) => {
                pixels.fill(frame, params);
                f(&pixels)
            }
            // Re-entered on this thread (a rayon worker that, waiting inside `f`, took up
            // another frame's fusion): that frame gets buffers of its own.
            Err(_) => {
                let mut pixels = FramePixels::empty();
                pixels.fill(frame, params);
                f(&pixels)
            }
        })
    }

    fn fill(&mut self, frame: &DepthFrame, params: &DepthFusionParams) {
        let src = &frame.depth_m.data;
        let nan = f32::NAN.to_bits() as u64;
        self.packed.resize(src.len() + 1, nan);
        self.packed[src.len()] = nan;
        let color = frame.color.as_ref().filter(|_| params.use_color);
        self.color = color.is_some();
        self.packed[..src.len()]
            .par_chunks_mut(PREPARE_CHUNK)
            .enumerate()
            .for_each(|(chunk, out)| {
                let pixels = chunk * PREPARE_CHUNK..chunk * PREPARE_CHUNK + out.len();
                match color {
                    Some(c) => {
                        pack_words::<true>(out, &src[pixels.clone()], &c.data[pixels], params)
                    }
                    None => pack_words::<false>(out, &src[pixels], &[], params),
                }
            });
    }
}

/// The words of [`FramePixels`] for `depth_m` and (when `COLOR`) `rgb`, into `out`. Compiled
/// for AVX-512, AVX2 and the baseline, picked at run time (the colours' 3-byte stride is
/// unpacked by vector shuffles where the target has them).
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512vl+avx512vbmi+avx2+avx+sse4.1",
    "x86_64+avx2+avx+sse4.1",
    "x86_64+sse4.1"
))]
fn pack_words<const COLOR: bool>(
    out: &mut [u64],
    depth_m: &[f32],
    rgb: &[[u8; 3]],
    params: &DepthFusionParams,
) {
    let depth = |d: f32| if usable(d, params) { d } else { f32::NAN }.to_bits() as u64;
    if COLOR {
        for ((o, &d), &c) in out.iter_mut().zip(depth_m).zip(rgb) {
            *o = depth(d) | (pack_rgb(c) as u64) << 32;
        }
    } else {
        for (o, &d) in out.iter_mut().zip(depth_m) {
            *o = depth(d);
        }
    }
}

/// `⌊x + ½⌋` exactly, as the f64 `round_i64(x as f64)` the loop used before and the kernels'
/// `round_half_up` (`shaders/shared/rounding.wgsl`): `x − ⌊x⌋` is exact in f32, `x + 0.5` is not.
#[inline(always)]
fn round_half_up(x: f32) -> f32 {
    let fl = x.floor();
    fl + if x - fl >= 0.5 { 1.0 } else { 0.0 }
}

/// `x` as an integer for the integral `x ∈ [0, 2²³)` (`u`, `v` inside the image): the
/// mantissa of `x + 2²³`. Unlike `as u32`, whose saturation the compiler does not vectorise;
/// any other `x` gives some number without harm (the lane is not inside).
#[inline(always)]
fn small_int(x: f32) -> u32 {
    (x + 8_388_608.0).to_bits() & 0x7f_ffff
}

/// Fuses `pixels` into `block` (camera-frame centre of its voxel (0, 0, 0) at `base`): every
/// voxel whose centre projects to a usable pixel with `d − z ≥ −μ` gets the running mean of
/// `min(d − z, μ)/μ` and of the pixel's colour ([`crate::grid::Block::fuse`]'s arithmetic).
/// Returns the number of voxels updated.
pub(super) fn fuse_block(
    k: &DepthGeometry,
    base: [f32; 3],
    pixels: &FramePixels,
    block: &mut Block,
) -> usize {
    if pixels.color {
        fuse_lanes::<true>(k, base, pixels, block)
    } else {
        fuse_lanes::<false>(k, base, pixels, block)
    }
}

/// The loop of [`fuse_block`]: lane `i` is voxel `i` (x + 8y + 64z). Compiled for AVX-512,
/// AVX2 and the baseline, picked at run time.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512vl+avx2+avx+sse4.1",
    "x86_64+avx2+avx+sse4.1",
    "x86_64+sse4.1"
))]
fn fuse_lanes<const COLOR: bool>(
    k: &DepthGeometry,
    base: [f32; 3],
    pixels: &FramePixels,
    block: &mut Block,
) -> usize {
    let [ax, ay, az] = k.axis_m;
    let (ax, ay, az) = ([ax.x, ax.y, ax.z], [ay.x, ay.y, ay.z], [az.x, az.y, az.z]);
    let (w, h) = (k.width as f32, k.height as f32);
    let (mu, inv_mu) = (k.truncation_m, 1.0 / k.truncation_m);
    let packed = &pixels.packed[..];
    // The trailing pixel, read by voxels outside the image.
    let outside = (packed.len() - 1) as u32;
    // Projection: the pixel each voxel centre reads, and its depth along the view.
    let mut pixel = [0u32; VOXELS_PER_BLOCK];
    let mut z_m = [0f32; VOXELS_PER_BLOCK];
    for i in 0..VOXELS_PER_BLOCK {
        let x = (i % VOXELS_PER_SIDE) as f32;
        let y = ((i / VOXELS_PER_SIDE) % VOXELS_PER_SIDE) as f32;
        let z = (i / (VOXELS_PER_SIDE * VOXELS_PER_SIDE)) as f32;
        // row = base + a_y·y + a_z·z, p = row + a_x·x (per component, this order).
        // Spelled out: a closure (`[0, 1, 2].map(…)`) is not inlined into this function's
        // target features, and the loop then calls it three times per voxel.
        let p = [
            base[0] + ay[0] * y + az[0] * z + ax[0] * x,
            base[1] + ay[1] * y + az[1] * z + ax[1] * x,
            base[2] + ay[2] * y + az[2] * z + ax[2] * x,
        ];
        let inv_z = 1.0 / p[2];
        let u = round_half_up(k.fx * p[0] * inv_z + k.cx);
        let v = round_half_up(k.fy * p[1] * inv_z + k.cy);
        let inside = (p[2] > 0.0) & (u >= 0.0) & (v >= 0.0) & (u < w) & (v < h);
        // Wrapping: a lane outside the image may hold any number (its index is not used).
        let index = small_int(v)
            .wrapping_mul(k.width)
            .wrapping_add(small_int(u));
        pixel[i] = if inside { index } else { outside };
        z_m[i] = p[2];
    }
    // The pixels' depths and colours (in range by construction; the `min` drops the bounds
    // checks).
    assert!(!packed.is_empty());
    let mut d_m = [0f32; VOXELS_PER_BLOCK];
    let mut c = [0u32; VOXELS_PER_BLOCK];
    for i in 0..VOXELS_PER_BLOCK {
        let p = packed[(pixel[i] as usize).min(packed.len() - 1)];
        d_m[i] = f32::from_bits(p as u32);
        c[i] = (p >> 32) as u32;
    }
    // Most blocks in view have some voxel to update; those that have none are not written.
    let n = (0..VOXELS_PER_BLOCK)
        .filter(|&i| d_m[i] - z_m[i] >= -mu)
        .count();
    if n == 0 {
        return 0;
    }
    // The update.
    let Block {
        tsdf,
        weight_omega,
        color,
        regularized,
    } = block;
    for i in 0..VOXELS_PER_BLOCK {
        let sdf = d_m[i] - z_m[i];
        // NaN (unusable pixel, or outside) fails the comparison.
        let up = sdf >= -mu;
        let t = sdf.min(mu) * inv_mu;
        let ci = c[i];
        let rgb = COLOR.then_some([ci as u8, (ci >> 8) as u8, (ci >> 16) as u8]);
        fused_lane(
            up,
            t,
            rgb,
            &mut tsdf[i],
            &mut weight_omega[i],
            &mut color[i],
        );
    }
    if let Some(u) = regularized {
        // The raw field changed, so the regularized value follows it (`Block::store_fused`).
        for i in 0..VOXELS_PER_BLOCK {
            if d_m[i] - z_m[i] >= -mu {
                u[i] = tsdf[i];
            }
        }
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::PinholeIntrinsics;
    use crate::frame::Image;
    use crate::grid::{encode_tsdf, BlockIndex, GridParams, MAX_WEIGHT, OMEGA_BIT};
    use crate::synth::rng::Rng;
    use nalgebra::{Isometry3, Vector3};

    /// The definition: each voxel projected on its own, with branches, and fused by
    /// [`Block::fuse`] from the frame as given (the usable test per pixel, colour as `[u8; 3]`).
    fn reference(
        k: &DepthGeometry,
        base: [f32; 3],
        frame: &DepthFrame,
        params: &DepthFusionParams,
        block: &mut Block,
    ) -> usize {
        let color = frame.color.as_ref().filter(|_| params.use_color);
        let mut n = 0;
        for i in 0..VOXELS_PER_BLOCK {
            let x = (i % 8) as f32;
            let y = ((i / 8) % 8) as f32;
            let z = (i / 64) as f32;
            let [ax, ay, az] = k.axis_m.map(|a| [a.x, a.y, a.z]);
            let (mu, inv_mu) = (k.truncation_m, 1.0 / k.truncation_m);
            let p: [f32; 3] = std::array::from_fn(|c| base[c] + ay[c] * y + az[c] * z + ax[c] * x);
            if p[2] <= 0.0 {
                continue;
            }
            let inv_z = 1.0 / p[2];
            let u = round_half_up(k.fx * p[0] * inv_z + k.cx);
            let v = round_half_up(k.fy * p[1] * inv_z + k.cy);
            if u < 0.0 || v < 0.0 || u >= k.width as f32 || v >= k.height as f32 {
                continue;
            }
            let pixel = v as usize * k.width as usize + u as usize;
            let d = frame.depth_m.data[pixel];
            if !usable(d, params) || d - p[2] < -mu {
                continue;
            }
            let t = (d - p[2]).min(mu) * inv_mu;
            block.fuse(i, t, color.map(|c| c.data[pixel]));
            n += 1;
        }
        n
    }

    #[test]
    fn frame_pixels_nest() {
        // A thread that fuses a second frame while it holds the first's pixels (a rayon worker
        // can, while it waits) gets that frame's pixels, and the first's stay as they were.
        let frame = |d: f32| DepthFrame {
            intrinsics: PinholeIntrinsics {
                fx: 1.0,
                fy: 1.0,
                cx: 0.0,
                cy: 0.0,
                width: 2,
                height: 1,
            },
            world_from_camera: Isometry3::identity(),
            depth_m: Image {
                width: 2,
                height: 1,
                data: vec![d, f32::NAN],
            },
            color: None,
        };
        let params = DepthFusionParams::default();
        let depth = |p: &FramePixels| {
            p.packed
                .iter()
                .map(|&w| f32::from_bits(w as u32))
                .collect::<Vec<_>>()
        };
        FramePixels::with(&frame(1.5), &params, |outer| {
            FramePixels::with(&frame(2.5), &params, |inner| {
                assert_eq!(depth(inner)[0], 2.5);
                assert!(depth(inner)[1].is_nan() && depth(inner)[2].is_nan());
            });
            assert_eq!(depth(outer)[0], 1.5);
            assert_eq!(outer.packed.len(), 3);
        });
    }

    #[test]
    fn block_kernel_equals_voxel_by_voxel_fusion() {
        // A 640×48 camera, tilted, looking at depths around 3 m with holes (NaN, 0, beyond the
        // range), over a box of blocks in front of, around and behind the camera, whose voxels
        // hold random earlier observations (some blocks with u): every kernel result must be
        // the reference's, bit for bit, with colour, without, and with greys. (A row of 640
        // pixels makes a lane outside the image overflow `u32` in its index, as real frames do.)
        let mut rng = Rng::new(14, 2);
        let (w, h) = (640u32, 48u32);
        let grid = GridParams {
            voxel_size_m: 0.1,
            truncation_m: 0.4,
        };
        let mut counts = (0, 0);
        for round in 0..6 {
            let depth: Vec<f32> = (0..w * h)
                .map(|_| match rng.f64() {
                    r if r < 0.08 => f32::NAN,
                    r if r < 0.1 => 0.0,
                    r if r < 0.13 => 60.0,
                    r if r < 0.15 => f32::INFINITY,
                    _ => (2.0 + 2.0 * rng.f64()) as f32,
                })
                .collect();
            let color: Vec<[u8; 3]> = (0..w * h)
                .map(|_| {
                    let g = (rng.f64() * 255.0) as u8;
                    if rng.chance(0.3) {
                        [g; 3]
                    } else {
                        [g, (rng.f64() * 255.0) as u8, 255 - g]
                    }
                })
                .collect();
            let frame = DepthFrame {
                intrinsics: PinholeIntrinsics {
                    fx: 500.0,
                    fy: 52.0,
                    cx: 319.7,
                    cy: 23.2,
                    width: w,
                    height: h,
                },
                world_from_camera: Isometry3::new(
                    Vector3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), 0.3),
                    Vector3::new(
                        rng.range(-0.2, 0.2),
                        rng.range(-0.2, 0.2),
                        rng.range(-3.0, 3.0),
                    ),
                ),
                depth_m: Image {
                    width: w,
                    height: h,
                    data: depth,
                },
                color: (round % 3 != 2).then_some(Image {
                    width: w,
                    height: h,
                    data: color,
                }),
            };
            let params = DepthFusionParams {
                use_color: round % 2 == 0,
                ..DepthFusionParams::default()
            };
            let g = DepthGeometry::new(&grid, &frame);
            FramePixels::with(&frame, &params, |pixels| {
                for (bi, index) in (-4..4)
                    .flat_map(|x| (-4..4).flat_map(move |y| (-2..7).map(move |z| [x, y, z])))
                    .enumerate()
                {
                    let index = BlockIndex(index);
                    let mut a = Block::default();
                    for i in 0..VOXELS_PER_BLOCK {
                        let w = (rng.f64() * 130.0) as u8;
                        a.weight_omega[i] = w.min(MAX_WEIGHT) | if w > 0 { OMEGA_BIT } else { 0 };
                        a.tsdf[i] = encode_tsdf(rng.f64() as f32 * 2.0 - 1.0);
                        let g = (rng.f64() * 255.0) as u8;
                        a.color[i] = if rng.chance(0.5) {
                            [g; 3]
                        } else {
                            [g, 7, 255 - g]
                        };
                    }
                    if bi % 5 == 0 {
                        a.regularized = Some(Box::new(a.tsdf.map(|t| t / 2)));
                    }
                    let mut b = a.clone();
                    let base = g.block_base(&grid, index);
                    let base = [base.x, base.y, base.z];
                    let n_ref = reference(&g, base, &frame, &params, &mut a);
                    let n = fuse_block(&g, base, pixels, &mut b);
                    assert_eq!(n, n_ref, "round {round}, block {index:?}");
                    assert!(a == b, "round {round}, block {index:?}");
                    counts.0 += n;
                    counts.1 += VOXELS_PER_BLOCK - n;
                }
            });
        }
        // Both outcomes occur often.
        assert!(counts.0 > 50_000 && counts.1 > 50_000, "{counts:?}");
    }
}
