//! Disparity map files: KITTI's 16-bit PNG (`value / 256` pixels, 0 = invalid) and a reader that
//! picks PFM (Middlebury, [`crate::io::pfm`]) or KITTI PNG by the file extension.
//!
//! In memory disparities are `Image<f32>` in pixels with NaN for invalid. Does not read 8-bit
//! disparity PNGs (their scale is dataset-specific).

use crate::error::{Error, Result};
use crate::frame::Image;
use std::path::Path;

/// Reads a KITTI disparity PNG: 16-bit grey, disparity = value / 256 pixels, 0 → NaN.
/// Errors name the file (unreadable, not a PNG, not 16-bit single channel).
pub fn read_kitti_disparity_png(path: impl AsRef<Path>) -> Result<Image<f32>> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let decoded = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
        .map_err(|e| Error::bad_input(path, format!("not a readable PNG: {e}")))?;
    let image::DynamicImage::ImageLuma16(luma) = decoded else {
        return Err(Error::bad_input(
            path,
            format!(
                "KITTI disparity PNG must be 16-bit single-channel, found {:?}",
                decoded.color()
            ),
        ));
    };
    let (width, height) = luma.dimensions();
    let data = luma
        .into_raw()
        .into_iter()
        .map(|v| if v == 0 { f32::NAN } else { v as f32 / 256.0 })
        .collect();
    Ok(Image {
        width,
        height,
        data,
    })
}

/// Writes a KITTI disparity PNG: `round(d · 256)` clamped to [1, 65535]; NaN, non-finite and
/// non-positive disparities are written as 0 (invalid).
pub fn write_kitti_disparity_png(path: impl AsRef<Path>, disparity: &Image<f32>) -> Result<()> {
    let path = path.as_ref();
    let raw: Vec<u16> = disparity
        .data
        .iter()
        .map(|&d| {
            if d.is_finite() && d > 0.0 {
                (d as f64 * 256.0).round().clamp(1.0, 65535.0) as u16
            } else {
                0
            }
        })
        .collect();
    let buf = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(
        disparity.width,
        disparity.height,
        raw,
    )
    .ok_or_else(|| {
        Error::InvalidArgument("disparity buffer length does not match its size".into())
    })?;
    buf.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| match e {
            image::ImageError::IoError(io) => Error::io(path, io),
            other => Error::bad_input(path, format!("cannot write PNG: {other}")),
        })
}

/// Reads a disparity map by extension: `.pfm` (Middlebury, inf = invalid) or `.png` (KITTI
/// 16-bit). Invalid pixels are NaN.
pub fn read_disparity(path: impl AsRef<Path>) -> Result<Image<f32>> {
    let path = path.as_ref();
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("pfm") => crate::io::pfm::read_pfm(path),
        Some("png") => read_kitti_disparity_png(path),
        _ => Err(Error::bad_input(
            path,
            "unknown disparity format: expected a .pfm or a 16-bit .png file",
        )),
    }
}
