//! Stereo calibration files: KITTI odometry `calib.txt` and Middlebury 2014 `calib.txt`, read
//! into the three numbers depth from disparity needs (`z = fx·B/(d + doffs)`). Errors name the
//! file and the missing or malformed key.

use crate::{Error, Result};
use std::path::Path;

/// Focal length, baseline and disparity offset of a rectified pair, for `z = fx·B/(d + doffs)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StereoCalibration {
    /// Horizontal focal length of the left camera, pixels.
    pub fx_px: f64,
    /// Baseline, metres.
    pub baseline_m: f64,
    /// Middlebury's `doffs` (difference of the principal points, pixels); 0 for KITTI.
    pub doffs_px: f64,
}

/// Reads a stereo calibration: KITTI odometry `calib.txt` (`P0:`/`P1:` lines; fx from P0, the
/// baseline from P1) or Middlebury 2014 `calib.txt` (`cam0=[f 0 cx; …]`, `baseline=` in mm,
/// `doffs=`). Errors name the file.
pub fn read_stereo_calibration(path: &Path) -> Result<StereoCalibration> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    if text.lines().any(|l| l.trim_start().starts_with("cam0=")) {
        let value = |key: &str| -> Result<&str> {
            text.lines()
                .find_map(|l| l.trim().strip_prefix(key))
                .map(str::trim)
                .ok_or_else(|| {
                    Error::bad_input(path, format!("Middlebury calibration lacks `{key}`"))
                })
        };
        let cam0 = value("cam0=")?;
        let fx_px: f64 = cam0
            .trim_start_matches('[')
            .split_whitespace()
            .next()
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| {
                Error::bad_input(
                    path,
                    format!("cannot read the focal length from cam0={cam0}"),
                )
            })?;
        let num = |key: &str| -> Result<f64> {
            let v = value(key)?;
            v.parse()
                .map_err(|_| Error::bad_input(path, format!("`{key}{v}` is not a number")))
        };
        return Ok(StereoCalibration {
            fx_px,
            baseline_m: num("baseline=")? / 1000.0,
            doffs_px: num("doffs=")?,
        });
    }
    let calib = crate::io::kitti::KittiCalib::parse(path, &text)?;
    Ok(StereoCalibration {
        fx_px: calib.p[0][(0, 0)],
        baseline_m: calib.baseline_m(0, 1),
        doffs_px: 0.0,
    })
}

/// `t = K⁻¹·P[:,3]` of a rectified projection matrix `P = K·[I | t]` (K upper triangular with
/// a positive diagonal): the translation of the camera from the reference camera, metres.
pub(crate) fn projection_translation_m(p: &nalgebra::Matrix3x4<f64>) -> nalgebra::Vector3<f64> {
    let k: nalgebra::Matrix3<f64> = p.fixed_view::<3, 3>(0, 0).into_owned();
    let col = p.column(3).into_owned();
    let tz = col.z / k[(2, 2)];
    let ty = (col.y - k[(1, 2)] * tz) / k[(1, 1)];
    let tx = (col.x - k[(0, 1)] * ty - k[(0, 2)] * tz) / k[(0, 0)];
    nalgebra::Vector3::new(tx, ty, tz)
}
