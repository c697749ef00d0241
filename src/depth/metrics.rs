//! Disparity accuracy against ground truth, as the Middlebury and KITTI benchmarks score it.
//!
//! Scored pixels are those with a finite ground truth (and inside the optional mask, e.g. a
//! Middlebury non-occlusion mask). Over them:
//! - bad-t: percentage with `|d − gt| > t` pixels, a missing (NaN) prediction counting as bad;
//! - D1 (KITTI 2015): percentage with error `> 3` px **and** `> 5 %` of `gt`, missing = bad;
//! - EPE: mean `|d − gt|` over scored pixels that also have a prediction;
//! - density: percentage of scored pixels that have a prediction.
//!
//! Does not read files; see [`crate::depth::disparity_io`] and [`crate::io::pfm`].

use crate::error::{Error, Result};
use crate::frame::{GreyImage, Image};

/// Scores of a disparity map against ground truth. Percentages in [0, 100].
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct StereoMetrics {
    /// Percentage of scored pixels with error > 1 px (missing = bad).
    pub bad1_pct: f64,
    /// Percentage of scored pixels with error > 2 px (missing = bad).
    pub bad2_pct: f64,
    /// Percentage of scored pixels with error > 3 px (missing = bad).
    pub bad3_pct: f64,
    /// KITTI D1: percentage of scored pixels with error > 3 px and > 5 % of the ground truth
    /// (missing = bad).
    pub d1_pct: f64,
    /// Mean absolute error over scored pixels with a prediction, pixels (NaN when there are none).
    pub epe_px: f64,
    /// Percentage of scored pixels with a prediction.
    pub density_pct: f64,
    /// Number of scored pixels (finite ground truth inside the mask).
    pub gt_pixels: usize,
}

/// Scores `pred` against `gt` (disparities in pixels, NaN/inf = invalid) over the pixels where
/// `gt` is finite and, if given, `mask` is true. Errors when sizes differ.
pub fn evaluate_disparity(
    pred: &Image<f32>,
    gt: &Image<f32>,
    mask: Option<&Image<bool>>,
) -> Result<StereoMetrics> {
    if pred.width != gt.width || pred.height != gt.height {
        return Err(Error::InvalidArgument(format!(
            "prediction is {}×{} but ground truth is {}×{}",
            pred.width, pred.height, gt.width, gt.height
        )));
    }
    if let Some(m) = mask {
        if m.width != gt.width || m.height != gt.height {
            return Err(Error::InvalidArgument(format!(
                "mask is {}×{} but ground truth is {}×{}",
                m.width, m.height, gt.width, gt.height
            )));
        }
    }
    let mut n = 0usize;
    let mut with_pred = 0usize;
    let mut bad = [0usize; 3];
    let mut d1 = 0usize;
    let mut abs_sum = 0.0f64;
    for i in 0..gt.data.len() {
        let g = gt.data[i];
        if !g.is_finite() || mask.is_some_and(|m| !m.data[i]) {
            continue;
        }
        n += 1;
        let p = pred.data[i];
        if !p.is_finite() {
            bad.iter_mut().for_each(|b| *b += 1);
            d1 += 1;
            continue;
        }
        with_pred += 1;
        let err = (p as f64 - g as f64).abs();
        abs_sum += err;
        for (t, b) in bad.iter_mut().enumerate() {
            if err > (t + 1) as f64 {
                *b += 1;
            }
        }
        if err > 3.0 && err > 0.05 * (g as f64).abs() {
            d1 += 1;
        }
    }
    let pct = |k: usize| {
        if n == 0 {
            0.0
        } else {
            100.0 * k as f64 / n as f64
        }
    };
    Ok(StereoMetrics {
        bad1_pct: pct(bad[0]),
        bad2_pct: pct(bad[1]),
        bad3_pct: pct(bad[2]),
        d1_pct: pct(d1),
        epe_px: if with_pred == 0 {
            f64::NAN
        } else {
            abs_sum / with_pred as f64
        },
        density_pct: pct(with_pred),
        gt_pixels: n,
    })
}

/// A boolean mask from a Middlebury mask image: true where the value is 255 (non-occluded);
/// 128 (occluded) and 0 (unknown) are false.
pub fn mask_from_middlebury(mask: &GreyImage) -> Image<bool> {
    Image {
        width: mask.width,
        height: mask.height,
        data: mask.data.iter().map(|&v| v == 255).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(data: Vec<f32>) -> Image<f32> {
        Image {
            width: data.len() as u32,
            height: 1,
            data,
        }
    }

    #[test]
    fn hand_made_scores() {
        let nan = f32::NAN;
        // gt:   10   10    10    100   100  nan  20
        // pred: 10.5 11.5  12.5  nan   96   7    nan
        // errs: 0.5  1.5   2.5   miss  4    -    miss
        let gt = img(vec![10.0, 10.0, 10.0, 100.0, 100.0, nan, 20.0]);
        let pred = img(vec![10.5, 11.5, 12.5, nan, 96.0, 7.0, nan]);
        let m = evaluate_disparity(&pred, &gt, None).unwrap();
        assert_eq!(m.gt_pixels, 6);
        assert!((m.bad1_pct - 100.0 * 5.0 / 6.0).abs() < 1e-9); // 1.5, 2.5, miss, 4, miss
        assert!((m.bad2_pct - 100.0 * 4.0 / 6.0).abs() < 1e-9); // 2.5, miss, 4, miss
        assert!((m.bad3_pct - 100.0 * 3.0 / 6.0).abs() < 1e-9); // miss, 4, miss
                                                                // D1: error 4 at gt 100 is 4 % < 5 % → good; only the two misses count.
        assert!((m.d1_pct - 100.0 * 2.0 / 6.0).abs() < 1e-9);
        assert!((m.epe_px - (0.5 + 1.5 + 2.5 + 4.0) / 4.0).abs() < 1e-9);
        assert!((m.density_pct - 100.0 * 4.0 / 6.0).abs() < 1e-9);
    }

    #[test]
    fn mask_restricts_scored_pixels() {
        let gt = img(vec![10.0, 10.0, 10.0]);
        let pred = img(vec![10.0, 20.0, f32::NAN]);
        let mask = Image {
            width: 3,
            height: 1,
            data: vec![true, false, false],
        };
        let m = evaluate_disparity(&pred, &gt, Some(&mask)).unwrap();
        assert_eq!(m.gt_pixels, 1);
        assert_eq!(m.bad1_pct, 0.0);
        assert_eq!(m.density_pct, 100.0);
        assert_eq!(m.epe_px, 0.0);
        let all = evaluate_disparity(&pred, &gt, None).unwrap();
        assert!((all.bad3_pct - 200.0 / 3.0).abs() < 1e-9);
        assert!((all.d1_pct - 200.0 / 3.0).abs() < 1e-9);
    }

    #[test]
    fn size_mismatch_is_an_error() {
        assert!(evaluate_disparity(&img(vec![1.0]), &img(vec![1.0, 2.0]), None).is_err());
        let mm = Image {
            width: 1,
            height: 1,
            data: vec![true],
        };
        assert!(evaluate_disparity(&img(vec![1.0, 2.0]), &img(vec![1.0, 2.0]), Some(&mm)).is_err());
    }

    #[test]
    fn middlebury_mask_values() {
        let m = mask_from_middlebury(&Image {
            width: 3,
            height: 1,
            data: vec![255, 128, 0],
        });
        assert_eq!(m.data, vec![true, false, false]);
    }
}
