//! A block of 8×8×8 voxels stored as a structure of arrays.
//!
//! Bytes per voxel: TSDF `i16` (2) + weight and Ω packed in one `u8` (1) + RGB (3) = 6, plus 2 for
//! the regularized field `u` once a block has been regularized (8 in all), plus the hash entry
//! shared by 512 voxels.

use super::index::VOXELS_PER_BLOCK;

/// Largest stored weight (observation count). Bit 7 of the packed byte is the Ω flag.
pub const MAX_WEIGHT: u8 = 127;
/// The Ω bit in [`Block::weight_omega`]: set when a range sensor directly observed the voxel.
pub const OMEGA_BIT: u8 = 0x80;

const TSDF_SCALE: f32 = 32767.0;

/// Quantises a normalised TSDF value (clamped to [−1, 1]).
#[inline]
pub fn encode_tsdf(f: f32) -> i16 {
    round_half_away(f.clamp(-1.0, 1.0) * TSDF_SCALE) as i16
}

/// `x.round() as i32` (halves away from zero) for |x| < 2³¹, inline: baseline x86-64 has no
/// SSE4.1 `roundss`, so `f32::round` is a library call, which was 5 % of depth fusion. Exact:
/// `x − trunc(x)` is representable for every f32, so the comparison with ½ decides as `round`
/// does (WGSL's twin is `round_half_away` in `shaders/shared/rounding.wgsl`). NaN gives 0, as
/// `f32::round(NaN) as i32` does.
#[inline(always)]
pub fn round_half_away(x: f32) -> i32 {
    let t = x as i32;
    let frac = x - t as f32;
    t + (frac >= 0.5) as i32 - (frac <= -0.5) as i32
}

/// [`round_half_away`] for `|x| ≤ 2²²` and NaN (0), in operations the compiler vectorises: the
/// saturating `f32 as i32` of `round_half_away` becomes one scalar conversion per lane in a
/// vectorised loop. `x + 1.5·2²³` rounds `x` to the nearest integer, ties to even, and its low
/// mantissa bits are that integer; a tie then moves away from zero. Every value the running
/// means round (TSDF codes within ±32767, colour channels within 0..=255) is in range.
#[inline(always)]
fn round_half_away_small(x: f32) -> i32 {
    const MAGIC: f32 = 12_582_912.0; // 1.5·2²³
    let even = (x + MAGIC).to_bits() as i32 - MAGIC.to_bits() as i32;
    let d = x - even as f32;
    let away = even + ((d == 0.5) & (x > 0.0)) as i32 - ((d == -0.5) & (x < 0.0)) as i32;
    if x.is_nan() {
        0
    } else {
        away
    }
}

/// The normalised TSDF value of a quantised one.
#[inline]
pub fn decode_tsdf(q: i16) -> f32 {
    q as f32 / TSDF_SCALE
}

/// One block: every array is indexed by `linear_index(x, y, z)`.
#[derive(Clone, PartialEq)]
pub struct Block {
    /// Raw fused TSDF `f` = truncated SDF / μ, quantised with [`encode_tsdf`].
    pub tsdf: [i16; VOXELS_PER_BLOCK],
    /// Bits 0–6: weight (observations, ≤ [`MAX_WEIGHT`]); bit 7: Ω ([`OMEGA_BIT`]).
    pub weight_omega: [u8; VOXELS_PER_BLOCK],
    /// Running mean colour (sRGB).
    pub color: [[u8; 3]; VOXELS_PER_BLOCK],
    /// Regularized TSDF `u` (same quantisation as `tsdf`), present once the block was regularized.
    pub regularized: Option<Box<[i16; VOXELS_PER_BLOCK]>>,
}

/// A decoded view of one voxel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Voxel {
    /// Normalised TSDF f ∈ [−1, 1].
    pub tsdf: f32,
    /// Observation count.
    pub weight: u8,
    /// Directly observed by a range sensor.
    pub omega: bool,
    /// Colour.
    pub color: [u8; 3],
}

impl Default for Block {
    fn default() -> Self {
        Block {
            tsdf: [encode_tsdf(1.0); VOXELS_PER_BLOCK],
            weight_omega: [0; VOXELS_PER_BLOCK],
            color: [[0; 3]; VOXELS_PER_BLOCK],
            regularized: None,
        }
    }
}

impl std::fmt::Debug for Block {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Block")
            .field("observed_voxels", &self.observed_count())
            .field("regularized", &self.regularized.is_some())
            .finish()
    }
}

impl Block {
    /// A fresh block: f = +1 (free), weight 0, outside Ω.
    pub fn new_boxed() -> Box<Block> {
        Box::default()
    }

    /// Weight of voxel `i`.
    #[inline]
    pub fn weight(&self, i: usize) -> u8 {
        self.weight_omega[i] & !OMEGA_BIT
    }

    /// Whether voxel `i` is in Ω.
    #[inline]
    pub fn omega(&self, i: usize) -> bool {
        self.weight_omega[i] & OMEGA_BIT != 0
    }

    /// Decoded voxel `i`.
    #[inline]
    pub fn voxel(&self, i: usize) -> Voxel {
        Voxel {
            tsdf: decode_tsdf(self.tsdf[i]),
            weight: self.weight(i),
            omega: self.omega(i),
            color: self.color[i],
        }
    }

    /// The regularized value of voxel `i` if present, else the raw one.
    #[inline]
    pub fn regularized_or_raw(&self, i: usize) -> f32 {
        match &self.regularized {
            Some(u) => decode_tsdf(u[i]),
            None => decode_tsdf(self.tsdf[i]),
        }
    }

    /// Whether some voxel is in Ω.
    pub fn observed(&self) -> bool {
        // An OR over all 512 bytes (vectorised) rather than `any`, which stops early but tests
        // byte by byte.
        self.weight_omega.iter().fold(0, |acc, &w| acc | w) & OMEGA_BIT != 0
    }

    /// Number of voxels in Ω.
    pub fn observed_count(&self) -> usize {
        self.weight_omega
            .iter()
            .filter(|&&w| w & OMEGA_BIT != 0)
            .count()
    }

    /// Fuses one observation into voxel `i`: the paper's running average
    /// `f_k = (u + w_{k−1} f_{k−1}) / (w_{k−1} + 1)` with `u` the normalised truncated SDF, the
    /// same for colour, and sets Ω. At [`MAX_WEIGHT`] the weight stays and the average keeps
    /// moving (an exponential average with factor 1/128).
    #[inline]
    pub fn fuse(&mut self, i: usize, tsdf_normalized: f32, color: Option<[u8; 3]>) {
        let w_old = self.weight(i) as f32;
        let tsdf = mean_tsdf(tsdf_normalized, w_old, self.tsdf[i]);
        let color = match color {
            Some(c) => {
                let old = self.color[i];
                if c[0] == c[1] && c[1] == c[2] && old[0] == old[1] && old[1] == old[2] {
                    // Grey into grey (every LiDAR update): one channel, the same bits.
                    let m = mean_channel(c[0], w_old, old[0]);
                    let w = (self.weight(i) + 1).min(MAX_WEIGHT);
                    self.store_fused(i, tsdf, w | OMEGA_BIT, [m; 3]);
                    return;
                }
                [0, 1, 2].map(|k| mean_channel(c[k], w_old, old[k]))
            }
            None => self.color[i],
        };
        let w = (self.weight(i) + 1).min(MAX_WEIGHT);
        self.store_fused(i, tsdf, w | OMEGA_BIT, color);
    }

    /// Stores the result of fusing voxel `i` (by [`Block::fuse`], or read back from a GPU kernel
    /// that runs its twin): quantised TSDF, weight with the Ω bit, colour. The raw field changed,
    /// so a stored regularized value follows it (it no longer matches the data; the next
    /// regularization recomputes it).
    #[inline]
    pub fn store_fused(&mut self, i: usize, tsdf: i16, weight_omega: u8, color: [u8; 3]) {
        self.tsdf[i] = tsdf;
        self.weight_omega[i] = weight_omega;
        self.color[i] = color;
        if let Some(u) = self.regularized.as_mut() {
            u[i] = tsdf;
        }
    }

    /// Bytes this block occupies in memory (heap included), not counting its hash entry.
    pub fn heap_bytes(&self) -> usize {
        std::mem::size_of::<Block>()
            + self
                .regularized
                .as_ref()
                .map_or(0, |_| std::mem::size_of::<[i16; VOXELS_PER_BLOCK]>())
    }
}

/// The running mean of a voxel's TSDF after one more observation `t` (normalised), from
/// `w_old` observations averaging to quantised `q`: the one formula of [`Block::fuse`] and
/// [`fused_lane`] (the WGSL twin is `fuse_packed` in `shaders/shared/voxel_fuse.wgsl`).
#[inline(always)]
fn mean_tsdf(t: f32, w_old: f32, q: i16) -> i16 {
    // `encode_tsdf`, with the rounding the compiler vectorises.
    let f = (t + w_old * decode_tsdf(q)) / (w_old + 1.0);
    round_half_away_small(f.clamp(-1.0, 1.0) * TSDF_SCALE) as i16
}

/// The running mean of one colour channel after one more observation `c`, from `w_old`
/// observations averaging to `old`.
#[inline(always)]
fn mean_channel(c: u8, w_old: f32, old: u8) -> u8 {
    round_half_away_small((c as f32 + w_old * old as f32) / (w_old + 1.0)) as u8
}

/// One lane of a vectorised update: a voxel's fields after one more observation (normalised
/// TSDF `t`, colour `c`; `None` keeps the colour) when `up`, unchanged otherwise. The arithmetic
/// of [`Block::fuse`], written branch-free for a loop that runs it lane by lane: the depth
/// kernel (`src/fusion/depth_block.rs`, whose test checks it against `fuse`).
#[inline(always)]
pub(crate) fn fused_lane(
    up: bool,
    t: f32,
    c: Option<[u8; 3]>,
    tsdf: &mut i16,
    weight_omega: &mut u8,
    color: &mut [u8; 3],
) {
    let w_raw = *weight_omega & !OMEGA_BIT;
    let w_old = w_raw as f32;
    let f = mean_tsdf(t, w_old, *tsdf);
    let w = (w_raw + 1).min(MAX_WEIGHT) | OMEGA_BIT;
    *tsdf = if up { f } else { *tsdf };
    *weight_omega = if up { w } else { *weight_omega };
    if let Some(c) = c {
        let old = *color;
        // Spelled out: `[0, 1, 2].map(…)` here kept the loop from vectorising (street, 5 cm:
        // 66–68 → 81–84 ms per frame).
        let mixed = [
            mean_channel(c[0], w_old, old[0]),
            mean_channel(c[1], w_old, old[1]),
            mean_channel(c[2], w_old, old[2]),
        ];
        *color = if up { mixed } else { old };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fuse_is_the_running_mean() {
        let mut b = Block::default();
        for (k, u) in [0.5f32, -0.25, 0.1].iter().enumerate() {
            b.fuse(3, *u, Some([30 * (k as u8 + 1), 0, 255]));
        }
        assert!((b.voxel(3).tsdf - (0.5 - 0.25 + 0.1) / 3.0).abs() < 1e-4);
        assert_eq!(b.weight(3), 3);
        assert!(b.omega(3));
        assert_eq!(b.color[3], [60, 0, 255]);
        assert!(!b.omega(4));
    }

    #[test]
    fn weight_saturates() {
        let mut b = Block::default();
        for _ in 0..300 {
            b.fuse(0, -1.0, None);
        }
        assert_eq!(b.weight(0), MAX_WEIGHT);
        assert!(b.omega(0));
        assert_eq!(b.tsdf[0], encode_tsdf(-1.0));
    }

    #[test]
    fn inline_rounding_equals_f32_round() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut values: Vec<f32> =
            vec![0.5, -0.5, 1.5, -1.5, 2.5, 0.49999997, -0.49999997, 32766.5];
        values.extend([0.0f32, -0.0, 254.5, 255.0, f32::NAN]);
        for _ in 0..200_000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let x = f32::from_bits(state as u32);
            if x.is_finite() && x.abs() < 1e9 {
                values.push(x);
            }
            values.push((state >> 40) as f32 / 256.0 - 32768.0);
        }
        // Every tie and its neighbours in the running means' range, exhaustively at ½ steps.
        values.extend((-2 * 32768..=2 * 32768).map(|i| i as f32 * 0.5));
        values.extend([4_194_304.0, -4_194_304.0, 4_194_303.5, -4_194_303.5]);
        for x in values {
            assert_eq!(round_half_away(x), x.round() as i32, "{x}");
            if !(x.abs() > 4_194_304.0) {
                assert_eq!(round_half_away_small(x), round_half_away(x), "{x}");
                let (below, above) = (x.next_down(), x.next_up());
                assert_eq!(
                    round_half_away_small(below),
                    below.round() as i32,
                    "{below}"
                );
                assert_eq!(
                    round_half_away_small(above),
                    above.round() as i32,
                    "{above}"
                );
            }
        }
    }

    #[test]
    fn six_bytes_per_voxel_raw() {
        // 3072 bytes of voxel data + the Option<Box> pointer.
        assert_eq!(std::mem::size_of::<Block>(), VOXELS_PER_BLOCK * 6 + 8);
    }
}
