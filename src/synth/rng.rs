//! Deterministic hashing and pseudo-random numbers for the synthetic city (SplitMix64). Everything
//! random in `synth` derives from the user's seed through these functions, so a seed fixes every
//! byte of a drive. Not cryptographic.

/// SplitMix64 finaliser: a bijective 64-bit mix with good avalanche.
#[inline]
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Hash of two words.
#[inline]
pub(crate) fn hash2(a: u64, b: u64) -> u64 {
    mix64(a ^ mix64(b ^ 0x51_7CC1_B727_220A))
}

/// Hash of three words.
#[inline]
pub(crate) fn hash3(a: u64, b: u64, c: u64) -> u64 {
    hash2(hash2(a, b), c)
}

/// Maps a hash to a uniform number in [0, 1).
#[inline]
pub(crate) fn unit(h: u64) -> f64 {
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// A standard normal deviate from a hash (Box–Muller on the hash's two halves).
#[inline]
pub(crate) fn gaussian(h: u64) -> f64 {
    let u1 = ((h >> 32) as f64 + 0.5) / 4_294_967_296.0;
    let u2 = ((h & 0xFFFF_FFFF) as f64 + 0.5) / 4_294_967_296.0;
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// A small sequential generator (SplitMix64) used while building the city.
#[derive(Clone, Debug)]
pub(crate) struct Rng {
    state: u64,
}

impl Rng {
    /// A generator for `seed` and a purpose `stream` (so that streams do not interfere).
    pub(crate) fn new(seed: u64, stream: u64) -> Self {
        Rng {
            state: hash2(seed, stream),
        }
    }

    /// Next raw word.
    #[inline]
    pub(crate) fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix64(self.state)
    }

    /// Uniform in [0, 1).
    #[inline]
    pub(crate) fn f64(&mut self) -> f64 {
        unit(self.next_u64())
    }

    /// Uniform in [lo, hi).
    #[inline]
    pub(crate) fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f64()
    }

    /// True with probability `p`.
    #[inline]
    pub(crate) fn chance(&mut self, p: f64) -> bool {
        self.f64() < p
    }

    /// Uniform index in 0..n (n > 0).
    #[inline]
    pub(crate) fn index(&mut self, n: usize) -> usize {
        ((self.f64() * n as f64) as usize).min(n.saturating_sub(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_has_unit_variance_and_zero_mean() {
        let n = 200_000u64;
        let (mut s, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let g = gaussian(hash2(7, i));
            s += g;
            s2 += g * g;
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.02, "var {var}");
    }

    #[test]
    fn rng_is_uniform_and_deterministic() {
        let mut a = Rng::new(3, 1);
        let mut b = Rng::new(3, 1);
        let mut hist = [0usize; 10];
        for _ in 0..100_000 {
            let x = a.f64();
            assert_eq!(x, b.f64());
            hist[(x * 10.0) as usize] += 1;
        }
        for h in hist {
            assert!((h as f64 - 10_000.0).abs() < 500.0, "{hist:?}");
        }
    }
}
