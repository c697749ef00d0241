//! A depth frame's listed blocks as the GPU tier sends them to `shaders/frame_keys.wgsl`: each
//! block as its offset from the frame's origin block (the block holding the camera centre),
//! packed into one 32-bit word, from which the device resolves the block's pool slot and
//! computes its base. So a listed block costs 4 bytes up instead of its key and base (32).
//!
//! **Packed offsets** ([`pack_offset`]): x in bits 0–10, y in 11–20, z in 21–31, each two's
//! complement (±1024, ±512, ±1024 blocks: ±820 m, ±410 m, ±820 m at 10 cm voxels). A frame with
//! a block beyond that sends three words per block instead (wide keys; still no base).
//!
//! **Bases.** The CPU computes a block's base (the camera-frame centre of its voxel (0, 0, 0))
//! in f64 and rounds it to f32 ([`DepthGeometry::block_base`]). The device has no f64, and a
//! shader compiler may rewrite float arithmetic (error-free float sums do not survive it), so
//! it evaluates the same affine map, base(origin) + Σₖ stepₖ·dₖ, in integers: the origin's base
//! and each block step in 96-bit fixed point (units of 2⁻⁶⁴ m, rounded from their f64 values),
//! the sum exact, then rounded once to the nearest f32. That equals the CPU's base except where
//! a coordinate lies within about 1e-13 m of an f32 rounding midpoint (then one ULP apart;
//! `tests` below counts them over a city frame's blocks). [`FrameKeys::base`] is the kernel's
//! CPU twin (the same integers, the same rounding), equal to it bit for bit on any adapter.

use super::depth::DepthGeometry;
use crate::gpu::layout::FrameKeyUniforms;
use crate::grid::{BlockIndex, GridParams};
use crate::{Error, Result};
use nalgebra::Vector3;

/// Bits of a packed offset along x, y and z.
pub const OFFSET_BITS: [u32; 3] = [11, 10, 11];

/// Wide keys hold offsets below this in magnitude (their 12-bit halves stay exact in f32).
const WIDE_LIMIT: i32 = 1 << 23;

/// `d` packed into one word ([`OFFSET_BITS`], two's complement), or `None` when a component
/// does not fit.
#[inline]
pub fn pack_offset(d: [i32; 3]) -> Option<u32> {
    let mut word = 0u32;
    let mut shift = 0;
    for (c, bits) in d.into_iter().zip(OFFSET_BITS) {
        let half = 1i32 << (bits - 1);
        if c < -half || c >= half {
            return None;
        }
        word |= ((c as u32) & ((1u32 << bits) - 1)) << shift;
        shift += bits;
    }
    Some(word)
}

/// The offset packed in `word` (twin of `offset_of` in `shaders/frame_keys.wgsl`).
pub fn unpack_offset(word: u32) -> [i32; 3] {
    [
        ((word << 21) as i32) >> 21,
        ((word << 11) as i32) >> 22,
        (word as i32) >> 21,
    ]
}

/// Fractional bits of the kernel's fixed point.
const FRACTION_BITS: i32 = 64;
/// The fixed point's values stay below this in magnitude (metres): 96 bits hold ±2³¹ m.
const FIXED_LIMIT_M: f64 = (1u64 << 30) as f64;

/// `x` metres in units of 2⁻⁶⁴ m, rounded.
fn fixed(x: f64) -> i128 {
    (x * 2f64.powi(FRACTION_BITS)).round() as i128
}

/// `v` as the three 32-bit words of its 96-bit two's complement, least significant first.
fn words96(v: i128) -> [u32; 4] {
    [v as u32, (v >> 32) as u32, (v >> 64) as u32, 0]
}

/// The value of three words (`words96`'s inverse).
fn of_words96(w: [u32; 4]) -> i128 {
    let v = w[0] as i128 | (w[1] as i128) << 32 | (w[2] as i128) << 64;
    (v << 32) >> 32
}

/// A depth frame's listed blocks as the GPU tier uploads them (see the module documentation).
#[derive(Clone, Debug)]
pub struct FrameKeys {
    origin: BlockIndex,
    words: Vec<u32>,
    wide: bool,
    uniforms: FrameKeyUniforms,
}

impl FrameKeys {
    /// The keys of `blocks` on `grid` for a frame of `geometry`; the blocks from
    /// `first_unsettled` on are fused only where a frame created them
    /// (`src/gpu/resident/late.rs`).
    pub fn new(
        grid: &GridParams,
        geometry: &DepthGeometry,
        blocks: &[BlockIndex],
        first_unsettled: usize,
    ) -> Result<Self> {
        let camera = geometry.camera_from_world.inverse().translation.vector;
        let origin = grid.block_of_point(camera.into());
        let offsets = blocks.iter().map(|b| offset(*b, origin));
        let packed: Option<Vec<u32>> = offsets.clone().map(pack_offset).collect();
        let (words, wide) = match packed {
            Some(words) => (words, false),
            None => {
                let mut words = Vec::with_capacity(3 * blocks.len());
                for d in offsets {
                    if d.iter().any(|c| c.abs() >= WIDE_LIMIT) {
                        return Err(Error::InvalidArgument(format!(
                            "block offset {d:?} from the camera's block is too large for the GPU \
                             tier's keys (at most {WIDE_LIMIT} blocks per axis)"
                        )));
                    }
                    words.extend(d.map(|c| c as u32));
                }
                (words, true)
            }
        };
        let base = geometry.block_base_f64(grid, origin);
        let rot = geometry.camera_from_world.rotation;
        let size_m = grid.block_size_m();
        let mut steps = [[0u32; 4]; 9];
        for (k, axis) in [Vector3::x(), Vector3::y(), Vector3::z()]
            .iter()
            .enumerate()
        {
            let step: Vector3<f64> = rot * (axis * size_m);
            for c in 0..3 {
                steps[3 * k + c] = words96(fixed(step[c]));
            }
        }
        let reach_m = size_m * (if wide { WIDE_LIMIT } else { 1024 }) as f64;
        if base.amax() >= FIXED_LIMIT_M || 3.0 * reach_m >= FIXED_LIMIT_M {
            return Err(Error::InvalidArgument(format!(
                "a frame {:.0} m from its blocks is beyond the GPU tier's fixed point ({} m)",
                base.amax().max(reach_m),
                FIXED_LIMIT_M
            )));
        }
        let uniforms = FrameKeyUniforms {
            origin: [
                origin.0[0],
                origin.0[1],
                origin.0[2],
                if wide { 3 } else { 1 },
            ],
            base: [0, 1, 2].map(|c| words96(fixed(base[c]))),
            steps,
            block_count: blocks.len() as u32,
            mask: 0,
            first_unsettled: first_unsettled.min(blocks.len()) as u32,
            pad: 0,
        };
        Ok(FrameKeys {
            origin,
            words,
            wide,
            uniforms,
        })
    }

    /// The frame's origin block (the camera centre's).
    pub fn origin(&self) -> BlockIndex {
        self.origin
    }

    /// The words that go up: one per block, or three when [`FrameKeys::is_wide`].
    pub fn words(&self) -> &[u32] {
        &self.words
    }

    /// Whether some block lies beyond the packed range (three words per block).
    pub fn is_wide(&self) -> bool {
        self.wide
    }

    /// The kernel's uniforms, for a hash table of `mask + 1` entries.
    pub fn uniforms(&self, mask: u32) -> FrameKeyUniforms {
        FrameKeyUniforms {
            mask,
            ..self.uniforms
        }
    }

    /// The base of block `b` as `shaders/frame_keys.wgsl` computes it (its CPU twin): the
    /// exact fixed-point sum, rounded to the nearest f32 (ties to even) by the integer's own
    /// conversion, then scaled by 2⁻⁶⁴ (exact).
    pub fn base(&self, b: BlockIndex) -> [f32; 3] {
        let d = offset(b, self.origin);
        let u = &self.uniforms;
        [0, 1, 2].map(|c| {
            let mut v = of_words96(u.base[c]);
            for (k, &dk) in d.iter().enumerate() {
                v += of_words96(u.steps[3 * k + c]) * dk as i128;
            }
            (v as f32) * 2f32.powi(-FRACTION_BITS)
        })
    }
}

/// `b − origin`, per axis (written out: a frame computes thousands, and an array `map` left
/// out of line by the compiler made `FrameKeys::new` 2.5× slower).
#[inline]
fn offset(b: BlockIndex, origin: BlockIndex) -> [i32; 3] {
    let ([x, y, z], [ox, oy, oz]) = (b.0, origin.0);
    [x.wrapping_sub(ox), y.wrapping_sub(oy), z.wrapping_sub(oz)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::PinholeIntrinsics;
    use crate::frame::{DepthFrame, Image};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    #[test]
    fn offsets_pack_and_unpack() {
        for d in [
            [0, 0, 0],
            [-1, -1, -1],
            [1023, 511, 1023],
            [-1024, -512, -1024],
            [17, -300, -999],
        ] {
            let w = pack_offset(d).expect("fits");
            assert_eq!(unpack_offset(w), d);
        }
        for d in [[1024, 0, 0], [0, 512, 0], [0, 0, -1025], [0, -513, 0]] {
            assert_eq!(pack_offset(d), None, "{d:?}");
        }
    }

    /// A KITTI-sized frame far from the world origin, rotated about every axis.
    fn far_frame() -> DepthFrame {
        let rot = UnitQuaternion::from_euler_angles(0.1, -0.7, 0.05);
        DepthFrame {
            depth_m: Image::filled(1241, 376, 10.0),
            color: None,
            intrinsics: PinholeIntrinsics {
                fx: 718.856,
                fy: 718.856,
                cx: 607.19,
                cy: 185.22,
                width: 1241,
                height: 376,
            },
            world_from_camera: Isometry3::from_parts(
                Translation3::new(1234.567, -3.21, -2345.678),
                rot,
            ),
        }
    }

    #[test]
    fn the_kernels_bases_are_the_cpus_but_for_rare_rounding_ties() {
        // Every block within ±80 blocks of the camera's (±64 m at 10 cm voxels), packed and
        // wide, against the CPU's f64-then-f32 bases.
        let grid = GridParams::paper(0.1);
        let frame = far_frame();
        let g = DepthGeometry::new(&grid, &frame);
        let camera = frame.world_from_camera.translation.vector;
        let o = grid.block_of_point(camera.into());
        let mut blocks = Vec::new();
        for z in -80..=80 {
            for y in -40..=40 {
                for x in -80..=80 {
                    blocks.push(o.offset([x, y, z]));
                }
            }
        }
        let keys = FrameKeys::new(&grid, &g, &blocks, blocks.len()).expect("keys");
        assert!(!keys.is_wide() && keys.words().len() == blocks.len());
        // One ULP apart where a coordinate lies near an f32 rounding midpoint; near zero (a
        // ULP below 1e-10 m) the CPU's own f64 rounding of kilometre-sized world coordinates
        // (~1e-13 m) exceeds a ULP too, so there the bound is absolute.
        let (mut differ, mut worst_ulps, mut worst_m) = (0usize, 0i64, 0f64);
        for b in &blocks {
            let cpu = g.block_base(&grid, *b);
            let twin = keys.base(*b);
            for c in 0..3 {
                let ulps = (cpu[c].to_bits() as i64 - twin[c].to_bits() as i64).abs();
                differ += (ulps != 0) as usize;
                if cpu[c].abs() > 1e-3 {
                    worst_ulps = worst_ulps.max(ulps);
                } else {
                    worst_m = worst_m.max((cpu[c] as f64 - twin[c] as f64).abs());
                }
            }
        }
        eprintln!(
            "{differ} of {} coordinates differ (worst {worst_ulps} ULP beyond 1 mm of zero, \
             {worst_m:e} m within it)",
            3 * blocks.len()
        );
        assert!(
            worst_ulps <= 1 && worst_m <= 1e-10,
            "{worst_ulps} ULP, {worst_m:e} m"
        );
        assert!(differ * 100_000 <= 3 * blocks.len(), "{differ}");
        // A block beyond the packed range makes the keys wide; the bases do not change.
        let mut far = blocks[..1000].to_vec();
        far.push(o.offset([5000, 0, 0]));
        let wide = FrameKeys::new(&grid, &g, &far, 0).expect("wide keys");
        assert!(wide.is_wide() && wide.words().len() == 3 * far.len());
        assert_eq!(wide.base(far[7]), keys.base(far[7]));
        assert_eq!(wide.uniforms(7).first_unsettled, 0);
        assert_eq!(wide.uniforms(7).mask, 7);
    }
}
