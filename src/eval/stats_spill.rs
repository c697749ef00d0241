//! Exact error statistics of more distances than fit in memory: the distances are appended to a
//! scratch file ([`DistanceSpill`]) and summarised in two sequential passes over it, in memory
//! bounded independently of their number (a few MiB plus the histogram).
//!
//! The result equals [`ErrorStats::from_distances`] on the same values: count, histogram, mode,
//! maximum and the percentiles bit for bit, mean and RMSE to rounding (the sums are taken in file
//! order, compensated, instead of in ascending order). Percentiles are found without sorting by a
//! radix selection on the bit patterns, whose order is the order of non-negative `f32`s: pass 1
//! counts the top 16 bits of every value, which locates the bucket of each needed rank; pass 2
//! counts the low 16 bits of the values in those buckets only, which gives the ranks' exact values.

use crate::error::{Error, Result};
use crate::eval::stats::{ErrorStats, Histogram, HistogramSpec};
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// Sign bit of a stored distance: set for a distance pushed with `scored == false`.
const UNSCORED_BIT: u32 = 0x8000_0000;

/// Bytes read from the scratch file at a time (a multiple of 4).
const BLOCK_BYTES: usize = 1 << 20;

/// Which of the spilled distances [`DistanceSpill::stats`] summarises.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Which {
    /// Every distance pushed.
    All,
    /// Only the distances pushed with `scored == true`.
    Scored,
}

/// Distances (metres, `f32`) appended to a scratch file, each flagged scored or not, for exact
/// statistics in bounded memory ([`DistanceSpill::stats`]).
///
/// The file holds one little-endian `f32` per distance, a distance pushed with `scored == false`
/// with its sign bit set. It is created (an existing file at the path is replaced) by
/// [`DistanceSpill::create`] and removed when the spill is dropped.
pub struct DistanceSpill {
    path: PathBuf,
    writer: Option<BufWriter<File>>,
    len: u64,
    scored_len: u64,
}

impl DistanceSpill {
    /// Creates the scratch file at `path` (replacing any file there).
    pub fn create(path: &Path) -> Result<Self> {
        let file = File::create(path).map_err(|e| Error::io(path, e))?;
        Ok(DistanceSpill {
            path: path.to_path_buf(),
            writer: Some(BufWriter::with_capacity(1 << 16, file)),
            len: 0,
            scored_len: 0,
        })
    }

    /// The scratch file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends one distance, metres; `scored == false` marks a point that was not scored (e.g.
    /// outside the sensor's view), which [`Which::Scored`] leaves out. `−0.0` is stored as `+0.0`.
    ///
    /// Errors when the distance is negative or not finite, or on a write error.
    pub fn push(&mut self, distance_m: f32, scored: bool) -> Result<()> {
        if !(distance_m.is_finite() && distance_m >= 0.0) {
            return Err(Error::InvalidArgument(format!(
                "distance {} is {distance_m}; distances must be finite and non-negative",
                self.len
            )));
        }
        // Clears the sign of −0.0, which would otherwise read back as an unscored +0.0.
        let bits = distance_m.to_bits() & !UNSCORED_BIT;
        let bits = if scored { bits } else { bits | UNSCORED_BIT };
        let writer = self.writer.as_mut().expect("writer present until drop");
        writer
            .write_all(&bits.to_le_bytes())
            .map_err(|e| Error::io(&self.path, e))?;
        self.len += 1;
        self.scored_len += u64::from(scored);
        Ok(())
    }

    /// Number of distances pushed.
    pub fn len(&self) -> u64 {
        self.len
    }

    /// Whether no distance was pushed.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Number of distances pushed with `scored == true`.
    pub fn scored_len(&self) -> u64 {
        self.scored_len
    }

    /// Statistics of the selected distances, binned by `spec`: equal to
    /// [`ErrorStats::from_distances`] on them (see the module documentation), computed in two
    /// sequential passes over the scratch file. `None` when the selection is empty. More distances
    /// may be pushed afterwards.
    ///
    /// Errors when `spec` is invalid, on an I/O error, or when the file does not hold the
    /// distances pushed (changed by someone else).
    pub fn stats(&mut self, spec: &HistogramSpec, which: Which) -> Result<Option<ErrorStats>> {
        spec.validate()?;
        let n = match which {
            Which::All => self.len,
            Which::Scored => self.scored_len,
        };
        if n == 0 {
            return Ok(None);
        }
        self.writer
            .as_mut()
            .expect("writer present until drop")
            .flush()
            .map_err(|e| Error::io(&self.path, e))?;
        let selected = |b: u32| which == Which::All || b & UNSCORED_BIT == 0;

        // Pass 1: top-16-bit buckets, sums, maximum, histogram.
        let regular = spec.regular_bins();
        let mut counts = vec![0u64; regular + 1];
        let mut buckets = vec![0u64; 1 << 16];
        let (mut sum, mut sum_sq) = (Neumaier::default(), Neumaier::default());
        let mut max_bits = 0u32;
        let mut seen = 0u64;
        self.for_each_value(|b| {
            if !selected(b) {
                return;
            }
            let v = b & !UNSCORED_BIT;
            seen += 1;
            buckets[(v >> 16) as usize] += 1;
            max_bits = max_bits.max(v);
            let d = f32::from_bits(v) as f64;
            sum.add(d);
            sum_sq.add(d * d);
            // Binning exactly as `Histogram::from_distances`.
            let bin = (d / spec.bin_width_m).floor();
            let i = if bin >= regular as f64 {
                regular
            } else {
                bin.max(0.0) as usize
            };
            counts[i] += 1;
        })?;
        if seen != n {
            return Err(Error::bad_input(
                &self.path,
                format!("the scratch file holds {seen} selected distances, {n} were pushed"),
            ));
        }

        // The ranks each percentile interpolates between, as `percentile_of_sorted`.
        let ps = [0.5f64, 0.75, 0.9];
        let ranks: Vec<(u64, u64, f64)> = ps
            .iter()
            .map(|&p| {
                let rank = p.clamp(0.0, 1.0) * (n - 1) as f64;
                let lo = rank.floor() as u64;
                (lo, (lo + 1).min(n - 1), rank - lo as f64)
            })
            .collect();
        // Bucket of each needed rank and the number of values in the buckets below it.
        let locate = |r: u64| {
            let mut below = 0u64;
            for (k, &c) in buckets.iter().enumerate() {
                if r < below + c {
                    return (k, below);
                }
                below += c;
            }
            unreachable!("rank {r} < count {n}")
        };
        let mut slot_of = vec![u8::MAX; 1 << 16];
        let mut needed: Vec<usize> = Vec::with_capacity(6);
        for &(lo, hi, _) in &ranks {
            for r in [lo, hi] {
                let (k, _) = locate(r);
                if slot_of[k] == u8::MAX {
                    slot_of[k] = needed.len() as u8;
                    needed.push(k);
                }
            }
        }

        // Pass 2: low-16-bit counts within the needed buckets.
        let mut low = vec![vec![0u64; 1 << 16]; needed.len()];
        self.for_each_value(|b| {
            if !selected(b) {
                return;
            }
            let v = b & !UNSCORED_BIT;
            let slot = slot_of[(v >> 16) as usize];
            if slot != u8::MAX {
                low[slot as usize][(v & 0xFFFF) as usize] += 1;
            }
        })?;
        let value_at = |r: u64| -> f32 {
            let (k, below) = locate(r);
            let counts = &low[slot_of[k] as usize];
            let mut at = below;
            for (j, &c) in counts.iter().enumerate() {
                if r < at + c {
                    return f32::from_bits(((k as u32) << 16) | j as u32);
                }
                at += c;
            }
            unreachable!("rank {r} lies in bucket {k}")
        };
        let pct: Vec<f64> = ranks
            .iter()
            .map(|&(lo, hi, t)| {
                let (a, b) = (value_at(lo) as f64, value_at(hi) as f64);
                a + (b - a) * t
            })
            .collect();

        let mut mode_bin: Option<(usize, u64)> = None;
        for (i, &c) in counts[..regular].iter().enumerate() {
            if c > 0 && mode_bin.is_none_or(|(_, best)| c > best) {
                mode_bin = Some((i, c));
            }
        }
        let nf = n as f64;
        Ok(Some(ErrorStats {
            count: n,
            mean_m: sum.total() / nf,
            rmse_m: (sum_sq.total() / nf).sqrt(),
            median_m: pct[0],
            p75_m: pct[1],
            p90_m: pct[2],
            mode_m: mode_bin.map(|(i, _)| (i as f64 + 0.5) * spec.bin_width_m),
            max_m: f32::from_bits(max_bits) as f64,
            histogram: Histogram {
                bin_width_m: spec.bin_width_m,
                counts,
            },
        }))
    }

    /// Calls `f` with the stored bits of every distance, in order, reading the (flushed) file in
    /// blocks of [`BLOCK_BYTES`]. Errors on an I/O error or when the file does not hold exactly
    /// the distances pushed.
    fn for_each_value(&self, mut f: impl FnMut(u32)) -> Result<()> {
        let io = |e| Error::io(&self.path, e);
        let mut file = File::open(&self.path).map_err(io)?;
        let mut block = vec![0u8; BLOCK_BYTES];
        let mut values = 0u64;
        loop {
            // Fill the block (short reads are allowed), so that values never straddle blocks.
            let mut filled = 0;
            while filled < block.len() {
                match file.read(&mut block[filled..]) {
                    Ok(0) => break,
                    Ok(k) => filled += k,
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                    Err(e) => return Err(io(e)),
                }
            }
            if filled % 4 != 0 || values + (filled / 4) as u64 > self.len {
                break;
            }
            for c in block[..filled].chunks_exact(4) {
                f(u32::from_le_bytes([c[0], c[1], c[2], c[3]]));
            }
            values += (filled / 4) as u64;
            if filled < block.len() {
                break;
            }
        }
        let bytes = file.metadata().map_err(io)?.len();
        if values != self.len || bytes != 4 * self.len {
            return Err(Error::bad_input(
                &self.path,
                format!(
                    "the scratch file holds {bytes} bytes, expected {} ({} distances): it was \
                     changed by someone else",
                    4 * self.len,
                    self.len
                ),
            ));
        }
        Ok(())
    }
}

impl Drop for DistanceSpill {
    fn drop(&mut self) {
        // Close before removing (required on Windows); a scratch file left behind is harmless.
        drop(self.writer.take());
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Neumaier's compensated sum: the sum of many non-negative `f64`s without the error growing with
/// their number.
#[derive(Default)]
struct Neumaier {
    sum: f64,
    compensation: f64,
}

impl Neumaier {
    fn add(&mut self, v: f64) {
        let t = self.sum + v;
        if self.sum.abs() >= v.abs() {
            self.compensation += (self.sum - t) + v;
        } else {
            self.compensation += (v - t) + self.sum;
        }
        self.sum = t;
    }

    fn total(&self) -> f64 {
        self.sum + self.compensation
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SplitMix64: a small deterministic generator.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        /// Uniform in [0, 1).
        fn unit(&mut self) -> f32 {
            (self.next() >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    fn spec(w: f64, max: f64) -> HistogramSpec {
        HistogramSpec {
            bin_width_m: w,
            max_m: max,
        }
    }

    fn assert_same(got: &ErrorStats, want: &ErrorStats) {
        assert_eq!(got.count, want.count);
        assert_eq!(got.histogram, want.histogram);
        assert_eq!(got.mode_m.map(f64::to_bits), want.mode_m.map(f64::to_bits));
        for (name, a, b) in [
            ("max", got.max_m, want.max_m),
            ("median", got.median_m, want.median_m),
            ("p75", got.p75_m, want.p75_m),
            ("p90", got.p90_m, want.p90_m),
        ] {
            assert_eq!(a.to_bits(), b.to_bits(), "{name}: {a} vs {b}");
        }
        for (name, a, b) in [
            ("mean", got.mean_m, want.mean_m),
            ("rmse", got.rmse_m, want.rmse_m),
        ] {
            assert!((a - b).abs() <= 1e-12 * b.abs(), "{name}: {a} vs {b}");
        }
    }

    /// Spills `values` (with their scored flags) and checks both selections against
    /// `ErrorStats::from_distances`.
    fn check(values: &[(f32, bool)], spec: &HistogramSpec) {
        let dir = tempfile::tempdir().unwrap();
        let mut spill = DistanceSpill::create(&dir.path().join("d.bin")).unwrap();
        for &(d, s) in values {
            spill.push(d, s).unwrap();
        }
        assert_eq!(spill.len(), values.len() as u64);
        for which in [Which::All, Which::Scored] {
            let chosen: Vec<f32> = values
                .iter()
                .filter(|(_, s)| which == Which::All || *s)
                .map(|(d, _)| *d)
                .collect();
            let got = spill.stats(spec, which).unwrap();
            if chosen.is_empty() {
                assert!(got.is_none(), "{which:?}");
            } else {
                let want = ErrorStats::from_distances(&chosen, spec).unwrap();
                assert_same(&got.expect("non-empty selection"), &want);
            }
        }
        assert_eq!(
            spill.scored_len(),
            values.iter().filter(|(_, s)| *s).count() as u64
        );
    }

    #[test]
    fn random_distances_match_in_memory_stats() {
        let mut rng = Rng(1);
        for n in [1usize, 2, 3, 4, 5, 10, 17, 100, 1001, 65_537] {
            let values: Vec<(f32, bool)> = (0..n)
                .map(|_| (rng.unit() * rng.unit() * 1.5, !rng.next().is_multiple_of(4)))
                .collect();
            check(&values, &HistogramSpec::default());
            check(&values, &spec(0.05, 0.5));
        }
    }

    #[test]
    fn ties_zeros_and_overflow() {
        let mut rng = Rng(2);
        let set = [0.0f32, 0.01, 0.25, 0.2500001, 3.0];
        for n in [1usize, 2, 3, 6, 7, 50, 999] {
            let values: Vec<(f32, bool)> = (0..n)
                .map(|_| (set[(rng.next() % 5) as usize], rng.next().is_multiple_of(2)))
                .collect();
            check(&values, &spec(0.01, 1.0));
        }
        check(&[(0.0, true)], &HistogramSpec::default());
        check(&[(0.0, true), (0.0, true)], &HistogramSpec::default());
        check(&[(0.0, false), (7.0, true), (0.0, true)], &spec(0.1, 1.0));
        // Everything in the overflow bin: no mode.
        check(&[(5.0, true), (6.0, true), (1e30, true)], &spec(0.1, 1.0));
        // Values whose bit patterns share the top 16 bits, and huge and tiny ones.
        let close: Vec<(f32, bool)> = (0..300)
            .map(|i| (f32::from_bits(0x3F80_0000 + (i * 7919) % 1000), i % 3 != 0))
            .chain([(f32::MAX, true), (f32::from_bits(1), true)])
            .collect();
        check(&close, &spec(0.5, 2.0));
    }

    #[test]
    fn empty_selection_is_none() {
        let dir = tempfile::tempdir().unwrap();
        let mut spill = DistanceSpill::create(&dir.path().join("d.bin")).unwrap();
        assert!(spill.is_empty());
        assert!(spill.stats(&spec(0.1, 1.0), Which::All).unwrap().is_none());
        spill.push(0.3, false).unwrap();
        assert!(spill
            .stats(&spec(0.1, 1.0), Which::Scored)
            .unwrap()
            .is_none());
        assert_eq!(
            spill
                .stats(&spec(0.1, 1.0), Which::All)
                .unwrap()
                .unwrap()
                .count,
            1
        );
        // Pushing after `stats` continues the same file.
        spill.push(0.1, true).unwrap();
        let s = spill
            .stats(&spec(0.1, 1.0), Which::Scored)
            .unwrap()
            .unwrap();
        assert_eq!((s.count, s.max_m), (1, 0.1f32 as f64));
    }

    #[test]
    fn rejects_bad_distances_and_spec() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.bin");
        let mut spill = DistanceSpill::create(&path).unwrap();
        spill.push(0.5, true).unwrap();
        for bad in [f32::NAN, -0.1, f32::INFINITY, f32::NEG_INFINITY] {
            let e = spill.push(bad, true).unwrap_err().to_string();
            assert!(
                e.contains("distance 1") && e.contains("non-negative"),
                "{e}"
            );
        }
        assert_eq!(spill.len(), 1);
        // −0.0 is a zero distance, scored.
        spill.push(-0.0, true).unwrap();
        let s = spill
            .stats(&spec(0.1, 1.0), Which::Scored)
            .unwrap()
            .unwrap();
        assert_eq!((s.count, s.median_m.to_bits()), (2, 0.25f64.to_bits()));
        assert!(spill.stats(&spec(0.0, 1.0), Which::All).is_err());
        // A file changed behind the spill's back is reported, not misread.
        std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .unwrap()
            .write_all(&[0, 0])
            .unwrap();
        let e = spill.stats(&spec(0.1, 1.0), Which::All).unwrap_err();
        assert!(e.to_string().contains("changed by someone else"), "{e}");
        drop(spill);
        assert!(!path.exists(), "the scratch file is removed on drop");
    }

    #[test]
    fn millions_cross_block_boundaries() {
        let mut rng = Rng(3);
        // 2.1 M distances = 8.4 MB: several 1 MiB blocks and a partial last one.
        let values: Vec<(f32, bool)> = (0..2_100_003)
            .map(|_| {
                let u = rng.unit();
                (u * u * u * 2.0, !rng.next().is_multiple_of(10))
            })
            .collect();
        check(&values, &HistogramSpec::default());
    }
}
