//! Census transform (Zabih & Woodfill 1994) and its ternary variant, with the Hamming distance as
//! matching cost.
//!
//! The census signature of a pixel encodes, for every other pixel of a `window_width ×
//! window_height` window centred on it, how that neighbour's intensity compares with the centre.
//! - [`CensusKind::Binary`]: one bit per neighbour, set when the neighbour is darker than the
//!   centre. A 9×7 window gives 62 bits (one `u64`).
//! - [`CensusKind::Ternary`]: two bits per neighbour (Stein 2004; the DENSER paper's data term):
//!   the first set when the neighbour is brighter than the centre by more than `threshold`, the
//!   second when darker by more than `threshold`, neither when similar. The Hamming distance then costs 1 for similar-vs-different and
//!   2 for brighter-vs-darker. A 7×7 window gives 96 bits (two `u64`s).
//!
//! Pixels outside the image are replaced by the nearest border pixel (clamp). Signatures are at
//! most 128 bits, so the Hamming cost fits a `u8`.
//!
//! This module computes signatures and costs only; the cost volume and its aggregation live in
//! [`crate::depth::sgm`].

use crate::error::{Error, Result};
use crate::frame::GreyImage;
use rayon::prelude::*;

/// How neighbours are compared with the centre pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CensusKind {
    /// One bit per neighbour: neighbour < centre.
    Binary,
    /// Two bits per neighbour: brighter / darker by more than `threshold` grey levels, or similar.
    Ternary {
        /// Grey levels (0–255) within which a neighbour counts as similar to the centre.
        threshold: u8,
    },
}

/// Census window and comparison.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CensusParams {
    /// Window width, pixels (odd, ≥ 3).
    pub window_width: u32,
    /// Window height, pixels (odd, ≥ 1).
    pub window_height: u32,
    /// Binary or ternary comparison.
    pub kind: CensusKind,
}

impl Default for CensusParams {
    /// A 9×7 binary census: 62 bits in one `u64`.
    fn default() -> Self {
        CensusParams {
            window_width: 9,
            window_height: 7,
            kind: CensusKind::Binary,
        }
    }
}

impl CensusParams {
    /// Bits per signature: (window area − 1) × (1 for binary, 2 for ternary).
    pub fn bits(&self) -> u32 {
        let n = self.window_width * self.window_height - 1;
        match self.kind {
            CensusKind::Binary => n,
            CensusKind::Ternary { .. } => 2 * n,
        }
    }

    /// Checks that the window is odd-sized and that the signature fits 128 bits.
    pub fn validate(&self) -> Result<()> {
        if self.window_width.is_multiple_of(2) || self.window_height.is_multiple_of(2) {
            return Err(Error::InvalidArgument(format!(
                "census window must have odd sides, got {}×{}",
                self.window_width, self.window_height
            )));
        }
        if self.window_width * self.window_height < 3 {
            return Err(Error::InvalidArgument(
                "census window must hold at least 3 pixels".into(),
            ));
        }
        if self.bits() > 128 {
            return Err(Error::InvalidArgument(format!(
                "census signature of a {}×{} window needs {} bits; at most 128 are supported",
                self.window_width,
                self.window_height,
                self.bits()
            )));
        }
        Ok(())
    }
}

/// Census signatures of every pixel, row-major, `words_per_pixel` `u64`s each.
#[derive(Clone, Debug, PartialEq)]
pub struct CensusImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `u64` words per signature (1 or 2).
    pub words_per_pixel: usize,
    /// Number of meaningful bits per signature (the largest possible Hamming cost).
    pub bits: u32,
    /// Signatures; pixel (u, v) occupies `data[(v·width + u)·words_per_pixel ..][..words_per_pixel]`.
    pub data: Vec<u64>,
}

impl CensusImage {
    /// The signature of pixel (u, v).
    #[inline]
    pub fn signature(&self, u: u32, v: u32) -> &[u64] {
        let i = (v as usize * self.width as usize + u as usize) * self.words_per_pixel;
        &self.data[i..i + self.words_per_pixel]
    }
}

/// Hamming distance between two signatures of equal length (number of differing bits).
#[inline]
pub fn hamming(a: &[u64], b: &[u64]) -> u32 {
    a.iter().zip(b).map(|(x, y)| (x ^ y).count_ones()).sum()
}

/// Computes the census signature of every pixel of `image` (rayon-parallel over rows).
pub fn census_transform(image: &GreyImage, params: &CensusParams) -> Result<CensusImage> {
    params.validate()?;
    let w = image.width as usize;
    let h = image.height as usize;
    if image.data.len() != w * h {
        return Err(Error::InvalidArgument(format!(
            "image data holds {} pixels, expected {}×{}",
            image.data.len(),
            w,
            h
        )));
    }
    let bits = params.bits();
    let words = if bits > 64 { 2 } else { 1 };
    let mut data = vec![0u64; w * h * words];
    if w == 0 || h == 0 {
        return Ok(CensusImage {
            width: image.width,
            height: image.height,
            words_per_pixel: words,
            bits,
            data,
        });
    }
    let rx = (params.window_width / 2) as isize;
    let ry = (params.window_height / 2) as isize;
    // Neighbour offsets in a fixed order, centre excluded.
    let offsets: Vec<(isize, isize)> = (-ry..=ry)
        .flat_map(|dy| (-rx..=rx).map(move |dx| (dx, dy)))
        .filter(|&(dx, dy)| dx != 0 || dy != 0)
        .collect();
    let kind = params.kind;
    data.par_chunks_mut(w * words)
        .enumerate()
        .for_each(|(v, out_row)| {
            // Clamped source rows for this output row, and a column map padded by `rx` on each side.
            let rows: Vec<&[u8]> = (-ry..=ry)
                .map(|dy| {
                    let y = (v as isize + dy).clamp(0, h as isize - 1) as usize;
                    &image.data[y * w..(y + 1) * w]
                })
                .collect();
            let padded: Vec<Vec<u8>> = rows
                .iter()
                .map(|row| {
                    let mut p = Vec::with_capacity(w + 2 * rx as usize);
                    p.extend(std::iter::repeat_n(row[0], rx as usize));
                    p.extend_from_slice(row);
                    p.extend(std::iter::repeat_n(row[w - 1], rx as usize));
                    p
                })
                .collect();
            let rxu = rx as usize;
            let centre = &padded[ry as usize][rxu..rxu + w];
            let neighbours: Vec<&[u8]> = offsets
                .iter()
                .map(|&(dx, dy)| {
                    let start = (dx + rx) as usize;
                    &padded[(dy + ry) as usize][start..start + w]
                })
                .collect();
            census_row(&neighbours, centre, kind, words, out_row);
        });
    Ok(CensusImage {
        width: image.width,
        height: image.height,
        words_per_pixel: words,
        bits,
        data,
    })
}

/// Signatures of one row from its neighbour rows (one per offset, in signature order, each
/// aligned with `centre`), into `out` (`words` per pixel). Dispatched to a copy compiled for
/// AVX-512BW or AVX2 where the CPU has it.
fn census_row(
    neighbours: &[&[u8]],
    centre: &[u8],
    kind: CensusKind,
    words: usize,
    out: &mut [u64],
) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2")]
        fn avx512(nb: &[&[u8]], c: &[u8], kind: CensusKind, words: usize, out: &mut [u64]) {
            census_row_impl(nb, c, kind, words, out)
        }
        #[target_feature(enable = "avx2")]
        fn avx2(nb: &[&[u8]], c: &[u8], kind: CensusKind, words: usize, out: &mut [u64]) {
            census_row_impl(nb, c, kind, words, out)
        }
        if std::is_x86_feature_detected!("avx512bw") && std::is_x86_feature_detected!("avx512vl") {
            // SAFETY: the CPU supports the features the copy was compiled for (checked above).
            unsafe { avx512(neighbours, centre, kind, words, out) };
            return;
        }
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: as above.
            unsafe { avx2(neighbours, centre, kind, words, out) };
            return;
        }
    }
    census_row_impl(neighbours, centre, kind, words, out)
}

/// [`census_row`]: the comparisons of up to 8 bits of every pixel are gathered in one byte per
/// pixel (`u8` lanes, so they vectorise 64 wide), and each byte is then placed in its word.
/// Bit `i` of a binary signature (bits `2i`, `2i + 1` of a ternary one) is neighbour `i`.
#[inline(always)]
fn census_row_impl(
    neighbours: &[&[u8]],
    centre: &[u8],
    kind: CensusKind,
    words: usize,
    out: &mut [u64],
) {
    let w = centre.len();
    let per_byte = match kind {
        CensusKind::Binary => 8,
        CensusKind::Ternary { .. } => 4,
    };
    let mut sig = [vec![0u64; w], vec![0u64; if words > 1 { w } else { 0 }]];
    let mut byte = vec![0u8; w];
    for (g, group) in neighbours.chunks(per_byte).enumerate() {
        byte.fill(0);
        for (j, nb) in group.iter().enumerate() {
            match kind {
                CensusKind::Binary => {
                    for ((b, &n), &c) in byte.iter_mut().zip(nb.iter()).zip(centre) {
                        *b |= ((n < c) as u8) << j;
                    }
                }
                CensusKind::Ternary { threshold } => {
                    let t = threshold as i16;
                    for ((b, &n), &c) in byte.iter_mut().zip(nb.iter()).zip(centre) {
                        let diff = n as i16 - c as i16;
                        *b |= (((diff > t) as u8) | (((diff < -t) as u8) << 1)) << (2 * j);
                    }
                }
            }
        }
        let (word, shift) = (g / 8, 8 * (g % 8));
        for (s, &b) in sig[word].iter_mut().zip(&byte) {
            *s |= (b as u64) << shift;
        }
    }
    if words == 1 {
        out.copy_from_slice(&sig[0]);
    } else {
        for (u, o) in out.chunks_exact_mut(2).enumerate() {
            o[0] = sig[0][u];
            o[1] = sig[1][u];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Image;

    #[test]
    fn binary_signature_of_a_3x3_patch() {
        // Centre 50; neighbours in row-major order (centre skipped): 10 60 50 / 40 · 90 / 0 50 70.
        let img = Image {
            width: 3,
            height: 3,
            data: vec![10, 60, 50, 40, 50, 90, 0, 50, 70],
        };
        let p = CensusParams {
            window_width: 3,
            window_height: 3,
            kind: CensusKind::Binary,
        };
        let c = census_transform(&img, &p).unwrap();
        // Neighbours in order [10, 60, 50, 40, 90, 0, 50, 70]: darker at indices 0, 3, 5.
        assert_eq!(c.signature(1, 1), &[0b101001]);
        assert_eq!(c.bits, 8);
    }

    #[test]
    fn ternary_signature_and_hamming_weights() {
        let img = Image {
            width: 3,
            height: 1,
            data: vec![10, 50, 53],
        };
        let p = CensusParams {
            window_width: 3,
            window_height: 1,
            kind: CensusKind::Ternary { threshold: 4 },
        };
        let c = census_transform(&img, &p).unwrap();
        // Neighbours of the centre: 10 (darker by 40 → bits 01 → bit 1), 53 (similar → 00).
        assert_eq!(c.signature(1, 0), &[0b0010]);
        // Brighter (10) vs darker (01) differ by 2, similar vs darker by 1.
        assert_eq!(hamming(&[0b10], &[0b01]), 2);
        assert_eq!(hamming(&[0b00], &[0b01]), 1);
    }

    #[test]
    fn window_sizes_are_checked() {
        let even = CensusParams {
            window_width: 8,
            window_height: 7,
            kind: CensusKind::Binary,
        };
        assert!(even.validate().is_err());
        let big = CensusParams {
            window_width: 11,
            window_height: 9,
            kind: CensusKind::Ternary { threshold: 2 },
        };
        assert!(big.validate().is_err());
        let two_words = CensusParams {
            window_width: 9,
            window_height: 7,
            kind: CensusKind::Ternary { threshold: 2 },
        };
        assert_eq!(two_words.bits(), 124);
        let img = Image::filled(5, 4, 7u8);
        let c = census_transform(&img, &two_words).unwrap();
        assert_eq!(c.words_per_pixel, 2);
        assert!(
            c.data.iter().all(|&w| w == 0),
            "a flat image has all-similar signatures"
        );
    }

    /// Direct per-pixel definition, for comparison with the row-vectorised transform.
    fn reference(img: &GreyImage, p: &CensusParams, u: i64, v: i64) -> [u64; 2] {
        let (rx, ry) = ((p.window_width / 2) as i64, (p.window_height / 2) as i64);
        let px = |x: i64, y: i64| {
            let x = x.clamp(0, img.width as i64 - 1) as u32;
            let y = y.clamp(0, img.height as i64 - 1) as u32;
            img.at(x, y) as i16
        };
        let c = px(u, v);
        let mut sig = [0u64; 2];
        let mut bit = 0;
        for dy in -ry..=ry {
            for dx in -rx..=rx {
                if dx == 0 && dy == 0 {
                    continue;
                }
                let n = px(u + dx, v + dy);
                match p.kind {
                    CensusKind::Binary => {
                        sig[bit / 64] |= ((n < c) as u64) << (bit % 64);
                        bit += 1;
                    }
                    CensusKind::Ternary { threshold } => {
                        let t = threshold as i16;
                        sig[bit / 64] |= ((n - c > t) as u64) << (bit % 64);
                        sig[(bit + 1) / 64] |= ((n - c < -t) as u64) << ((bit + 1) % 64);
                        bit += 2;
                    }
                }
            }
        }
        sig
    }

    #[test]
    fn matches_the_per_pixel_definition_on_random_images() {
        let mut state = 0x1234_5678_9abc_def0u64;
        let data: Vec<u8> = (0..23 * 17)
            .map(|_| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (state >> 56) as u8
            })
            .collect();
        let img = Image {
            width: 23,
            height: 17,
            data,
        };
        for p in [
            CensusParams::default(),
            CensusParams {
                window_width: 7,
                window_height: 7,
                kind: CensusKind::Ternary { threshold: 3 },
            },
            CensusParams {
                window_width: 9,
                window_height: 7,
                kind: CensusKind::Ternary { threshold: 0 },
            },
        ] {
            let c = census_transform(&img, &p).unwrap();
            for v in 0..17 {
                for u in 0..23 {
                    let r = reference(&img, &p, u as i64, v as i64);
                    assert_eq!(
                        c.signature(u, v),
                        &r[..c.words_per_pixel],
                        "{p:?} at ({u}, {v})"
                    );
                }
            }
        }
    }
}
