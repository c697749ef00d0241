//! Summary statistics of a set of point distances: mean, RMSE, exact percentiles, a fixed-width
//! histogram with an overflow bin, and its mode (DENSER Sec. VI, Fig. 4 and Table I).
//!
//! Everything here is computed exactly from the distances (percentiles from a sorted copy), except
//! [`ErrorStats::fraction_below`], which reads the histogram (exact at bin edges). This module does
//! not compute distances; see [`crate::eval::GroundTruthIndex`].

use crate::error::{Error, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Layout of an error histogram: regular bins `[i·w, (i+1)·w)` for `i < n` with
/// `n = ceil(max_m / bin_width_m)`, then one overflow bin `[n·w, ∞)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HistogramSpec {
    /// Width of one regular bin, metres.
    pub bin_width_m: f64,
    /// Errors at or beyond this distance (rounded up to a whole bin) land in the overflow bin,
    /// metres.
    pub max_m: f64,
}

impl Default for HistogramSpec {
    /// 1 cm bins up to 1 m (101 bins with the overflow bin).
    fn default() -> Self {
        HistogramSpec {
            bin_width_m: 0.01,
            max_m: 1.0,
        }
    }
}

impl HistogramSpec {
    /// Largest number of regular bins accepted, to keep a typo from allocating gigabytes.
    pub const MAX_BINS: usize = 1_000_000;

    /// Checks that the bin width is positive and finite, `max_m ≥ bin_width_m`, and that there are
    /// at most [`Self::MAX_BINS`] bins.
    pub fn validate(&self) -> Result<()> {
        if !(self.bin_width_m.is_finite() && self.bin_width_m > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "histogram bin width must be a positive number of metres, got {}",
                self.bin_width_m
            )));
        }
        if !(self.max_m.is_finite() && self.max_m >= self.bin_width_m) {
            return Err(Error::InvalidArgument(format!(
                "histogram range must be at least one bin ({} m), got {} m",
                self.bin_width_m, self.max_m
            )));
        }
        let bins = (self.max_m / self.bin_width_m).ceil();
        if bins > Self::MAX_BINS as f64 {
            return Err(Error::InvalidArgument(format!(
                "histogram would have {bins} bins (max {}); use wider bins",
                Self::MAX_BINS
            )));
        }
        Ok(())
    }

    /// Number of regular bins `n = ceil(max_m / bin_width_m)` (the overflow bin not counted).
    pub fn regular_bins(&self) -> usize {
        // Guard against ceil(5.000000000001) = 6 from a rounding error in max/width.
        let ratio = self.max_m / self.bin_width_m;
        let rounded = ratio.round();
        if (ratio - rounded).abs() < 1e-9 * rounded.max(1.0) {
            rounded.max(1.0) as usize
        } else {
            ratio.ceil().max(1.0) as usize
        }
    }
}

/// A histogram of distances with fixed-width bins; the last entry of `counts` is the overflow bin.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Histogram {
    /// Width of each regular bin, metres. Bin `i` covers `[i·w, (i+1)·w)`.
    pub bin_width_m: f64,
    /// Number of distances per bin; `counts.len() − 1` regular bins, then the overflow bin
    /// holding every distance `≥ (counts.len() − 1)·w`.
    pub counts: Vec<u64>,
}

impl Histogram {
    /// Bins `distances_m` (assumed finite and non-negative) by `spec` (assumed valid).
    fn from_distances(distances_m: &[f32], spec: &HistogramSpec) -> Histogram {
        let regular = spec.regular_bins();
        let mut counts = vec![0u64; regular + 1];
        for &d in distances_m {
            let bin = ((d as f64) / spec.bin_width_m).floor();
            let i = if bin >= regular as f64 {
                regular
            } else {
                bin.max(0.0) as usize
            };
            counts[i] += 1;
        }
        Histogram {
            bin_width_m: spec.bin_width_m,
            counts,
        }
    }

    /// Number of regular bins (excluding the overflow bin).
    pub fn regular_bins(&self) -> usize {
        self.counts.len().saturating_sub(1)
    }

    /// Number of distances in the overflow bin.
    pub fn overflow_count(&self) -> u64 {
        self.counts.last().copied().unwrap_or(0)
    }

    /// Total number of distances binned.
    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// Edges `[lo, hi)` of bin `i`, metres; the overflow bin's `hi` is `f64::INFINITY`.
    pub fn bin_range_m(&self, i: usize) -> (f64, f64) {
        let lo = i as f64 * self.bin_width_m;
        if i >= self.regular_bins() {
            (lo, f64::INFINITY)
        } else {
            (lo, lo + self.bin_width_m)
        }
    }

    /// Fraction of all distances in each bin (sums to 1 over all bins, overflow included).
    pub fn fractions(&self) -> Vec<f64> {
        let total = self.total().max(1) as f64;
        self.counts.iter().map(|&c| c as f64 / total).collect()
    }
}

/// Statistics of a set of point-to-point distances, metres (one reconstruction vs. ground truth).
///
/// Percentiles use linear interpolation between the two closest ranks of the sorted distances
/// (rank `p·(count − 1)`, NumPy's default), so `median_m` is the mean of the two middle values
/// when `count` is even.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorStats {
    /// Number of distances.
    pub count: u64,
    /// Arithmetic mean, metres.
    pub mean_m: f64,
    /// Root mean square, metres.
    pub rmse_m: f64,
    /// 50th percentile, metres.
    pub median_m: f64,
    /// 75th percentile, metres.
    pub p75_m: f64,
    /// 90th percentile, metres.
    pub p90_m: f64,
    /// Centre of the fullest regular histogram bin (the lowest such bin on a tie), metres;
    /// `None` when every distance lies in the overflow bin.
    pub mode_m: Option<f64>,
    /// Largest distance, metres.
    pub max_m: f64,
    /// Histogram of the distances.
    pub histogram: Histogram,
}

impl ErrorStats {
    /// Statistics of `distances_m` (metres), binned by `spec`.
    ///
    /// Errors when `distances_m` is empty, holds a negative or non-finite value, or `spec` is
    /// invalid.
    pub fn from_distances(distances_m: &[f32], spec: &HistogramSpec) -> Result<ErrorStats> {
        ErrorStats::from_owned_distances(distances_m.to_vec(), spec)
    }

    /// [`ErrorStats::from_distances`], sorting `distances_m` in place (no copy: the 27.9 M
    /// completeness distances of a 200 m drive are 107 MiB).
    pub fn from_owned_distances(
        mut distances_m: Vec<f32>,
        spec: &HistogramSpec,
    ) -> Result<ErrorStats> {
        spec.validate()?;
        if distances_m.is_empty() {
            return Err(Error::InvalidArgument(
                "cannot compute error statistics of zero distances".into(),
            ));
        }
        if let Some((i, d)) = distances_m
            .iter()
            .enumerate()
            .find(|(_, d)| !(d.is_finite() && **d >= 0.0))
        {
            return Err(Error::InvalidArgument(format!(
                "distance {i} is {d}; distances must be finite and non-negative"
            )));
        }
        // Values equal under total_cmp are the same bits: any sort gives the same array.
        distances_m.par_sort_unstable_by(f32::total_cmp);
        let sorted = distances_m;
        let n = sorted.len() as f64;
        let (sum, sum_sq) = sorted.iter().fold((0.0f64, 0.0f64), |(s, q), &d| {
            let d = d as f64;
            (s + d, q + d * d)
        });
        let histogram = Histogram::from_distances(&sorted, spec);
        let regular = histogram.regular_bins();
        let mut mode_bin: Option<(usize, u64)> = None;
        for (i, &c) in histogram.counts[..regular].iter().enumerate() {
            if c > 0 && mode_bin.is_none_or(|(_, best)| c > best) {
                mode_bin = Some((i, c));
            }
        }
        Ok(ErrorStats {
            count: sorted.len() as u64,
            mean_m: sum / n,
            rmse_m: (sum_sq / n).sqrt(),
            median_m: percentile_of_sorted(&sorted, 0.5),
            p75_m: percentile_of_sorted(&sorted, 0.75),
            p90_m: percentile_of_sorted(&sorted, 0.9),
            mode_m: mode_bin.map(|(i, _)| (i as f64 + 0.5) * spec.bin_width_m),
            max_m: sorted[sorted.len() - 1] as f64,
            histogram,
        })
    }

    /// Fraction of distances below `threshold_m`, read from the histogram: exact when the threshold
    /// is a bin edge, linearly interpolated inside a bin, and counting every overflow distance as
    /// above the threshold (so it is a lower bound beyond the histogram's range).
    pub fn fraction_below(&self, threshold_m: f64) -> f64 {
        let h = &self.histogram;
        if self.count == 0 || threshold_m.is_nan() || threshold_m <= 0.0 {
            return 0.0;
        }
        let mut below = 0.0f64;
        for i in 0..h.regular_bins() {
            let (lo, hi) = h.bin_range_m(i);
            if threshold_m >= hi {
                below += h.counts[i] as f64;
            } else {
                if threshold_m > lo {
                    below += h.counts[i] as f64 * (threshold_m - lo) / h.bin_width_m;
                }
                break;
            }
        }
        below / self.count as f64
    }
}

/// The `p`-quantile (`0 ≤ p ≤ 1`) of ascending `sorted` values by linear interpolation between
/// ranks `floor(p·(n−1))` and `ceil(p·(n−1))` (NumPy's default method). Returns NaN when empty.
pub fn percentile_of_sorted(sorted: &[f32], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = p.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let lo = rank.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    let t = rank - lo as f64;
    let (a, b) = (sorted[lo] as f64, sorted[hi] as f64);
    a + (b - a) * t
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(w: f64, max: f64) -> HistogramSpec {
        HistogramSpec {
            bin_width_m: w,
            max_m: max,
        }
    }

    #[test]
    fn hand_computed_small_set() {
        // Distances 1..=10 (odd count would be 9; use 10 to test the even median).
        let d: Vec<f32> = (1..=10).map(|i| i as f32).collect();
        let s = ErrorStats::from_distances(&d, &spec(2.0, 8.0)).unwrap();
        assert_eq!(s.count, 10);
        assert!((s.mean_m - 5.5).abs() < 1e-12);
        // sum of squares 1..10 = 385 → rmse = sqrt(38.5)
        assert!((s.rmse_m - 38.5f64.sqrt()).abs() < 1e-12);
        // median of 1..10 = 5.5; p75: rank 0.75·9 = 6.75 → 7 + 0.75 = 7.75; p90: rank 8.1 → 9.1
        assert!((s.median_m - 5.5).abs() < 1e-12);
        assert!((s.p75_m - 7.75).abs() < 1e-12);
        assert!((s.p90_m - 9.1).abs() < 1e-6);
        assert_eq!(s.max_m, 10.0);
        // bins [0,2):1 [2,4):2,3 [4,6):4,5 [6,8):6,7 overflow: 8,9,10
        assert_eq!(s.histogram.counts, vec![1, 2, 2, 2, 3]);
        assert_eq!(s.histogram.overflow_count(), 3);
        // fullest regular bin: tie between bins 1..3 at 2 → lowest, centre 3.0
        assert_eq!(s.mode_m, Some(3.0));
    }

    #[test]
    fn odd_count_median_is_middle_value() {
        let d = [0.3f32, 0.1, 0.2, 0.5, 0.4];
        let s = ErrorStats::from_distances(&d, &HistogramSpec::default()).unwrap();
        assert!((s.median_m - 0.3).abs() < 1e-7);
        // p75: rank 3 exactly → 0.4
        assert!((s.p75_m - 0.4).abs() < 1e-7);
    }

    #[test]
    fn mode_picks_fullest_bin_centre() {
        let mut d = vec![0.012f32; 3];
        d.extend([0.055f32; 7]);
        d.extend([0.3f32; 5]);
        let s = ErrorStats::from_distances(&d, &spec(0.01, 1.0)).unwrap();
        assert!((s.mode_m.unwrap() - 0.055).abs() < 1e-12);
        assert_eq!(s.histogram.counts[1], 3);
        assert_eq!(s.histogram.counts[5], 7);
        assert_eq!(s.histogram.counts[30], 5);
        assert_eq!(s.histogram.counts.len(), 101);
    }

    #[test]
    fn all_overflow_has_no_mode() {
        let s = ErrorStats::from_distances(&[5.0, 6.0], &spec(0.1, 1.0)).unwrap();
        assert_eq!(s.mode_m, None);
        assert_eq!(s.histogram.overflow_count(), 2);
    }

    #[test]
    fn fraction_below_reads_histogram() {
        // 4 distances in [0,1), 4 in [1,2), 2 overflow.
        let d = [0.1f32, 0.2, 0.6, 0.9, 1.1, 1.2, 1.5, 1.9, 5.0, 7.0];
        let s = ErrorStats::from_distances(&d, &spec(1.0, 2.0)).unwrap();
        assert!((s.fraction_below(1.0) - 0.4).abs() < 1e-12);
        assert!((s.fraction_below(2.0) - 0.8).abs() < 1e-12);
        assert!((s.fraction_below(1.5) - 0.6).abs() < 1e-12);
        assert!((s.fraction_below(100.0) - 0.8).abs() < 1e-12);
        assert_eq!(s.fraction_below(0.0), 0.0);
    }

    #[test]
    fn regular_bins_tolerates_rounding() {
        assert_eq!(spec(0.01, 1.0).regular_bins(), 100);
        assert_eq!(spec(0.1, 0.3).regular_bins(), 3);
        assert_eq!(spec(0.3, 1.0).regular_bins(), 4);
    }

    #[test]
    fn rejects_bad_input() {
        assert!(ErrorStats::from_distances(&[], &HistogramSpec::default()).is_err());
        let e = ErrorStats::from_distances(&[0.1, f32::NAN], &HistogramSpec::default());
        assert!(e.unwrap_err().to_string().contains("distance 1"));
        assert!(ErrorStats::from_distances(&[-0.1], &HistogramSpec::default()).is_err());
        assert!(ErrorStats::from_distances(&[0.1], &spec(0.0, 1.0)).is_err());
        assert!(ErrorStats::from_distances(&[0.1], &spec(0.1, 0.05)).is_err());
        assert!(ErrorStats::from_distances(&[0.1], &spec(1e-9, 1.0)).is_err());
    }

    #[test]
    fn percentile_interpolates_like_numpy() {
        // numpy.percentile([1, 2, 4], 25) = 1.5
        assert!((percentile_of_sorted(&[1.0, 2.0, 4.0], 0.25) - 1.5).abs() < 1e-12);
        assert_eq!(percentile_of_sorted(&[7.0], 0.9), 7.0);
        assert!(percentile_of_sorted(&[], 0.5).is_nan());
    }
}
