//! Portable Float Map (PFM) for single-channel float images, in the Middlebury convention used for
//! disparity maps.
//!
//! Layout: the ASCII header `Pf\n<width> <height>\n<scale>\n` followed by `width·height` IEEE-754
//! float32 values, rows stored **bottom-up** (the first row in the file is the image's last row).
//! A negative scale means little-endian floats, a positive one big-endian; its magnitude is
//! ignored. Middlebury marks unknown disparities with `+inf`.
//!
//! In memory (`Image<f32>`, rows top-down) invalid pixels are NaN: [`decode_pfm`] maps every
//! non-finite value (±inf, NaN) to NaN, and [`encode_pfm`] writes NaN and ±inf as `+inf`.
//! The writer always emits little-endian with scale `-1`.
//!
//! Does not handle colour PFM (`PF`, three channels); reading one is an error that says so.

use crate::error::{Error, Result};
use crate::frame::Image;
use std::path::Path;

/// Encodes `image` as a little-endian grey PFM (scale −1, rows bottom-up, NaN/inf → `+inf`),
/// appending the bytes to `out`.
pub fn encode_pfm(image: &Image<f32>, out: &mut Vec<u8>) {
    let header = format!("Pf\n{} {}\n-1\n", image.width, image.height);
    out.reserve(header.len() + image.data.len() * 4);
    out.extend_from_slice(header.as_bytes());
    let width = image.width as usize;
    if width == 0 {
        return;
    }
    for row in image.data.chunks_exact(width).rev() {
        for &value in row {
            let v = if value.is_finite() {
                value
            } else {
                f32::INFINITY
            };
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
}

/// Decodes a grey PFM held in `bytes`; `source` names the file in error messages.
///
/// Errors when the magic is not `Pf` (colour `PF` included), the header is malformed, the scale
/// is zero or not a number, or the data is shorter than `width·height` floats (truncated).
/// Non-finite values become NaN (invalid).
pub fn decode_pfm(bytes: &[u8], source: &Path) -> Result<Image<f32>> {
    let bad = |message: String| Error::bad_input(source, message);
    if bytes.len() < 2 {
        return Err(bad("not a PFM file: too short for the `Pf` magic".into()));
    }
    match &bytes[0..2] {
        b"Pf" => {}
        b"PF" => {
            return Err(bad(
                "colour PFM (`PF`) is not supported; expected grey `Pf`".into(),
            ))
        }
        _ => return Err(bad("not a PFM file: the magic is not `Pf`".into())),
    }
    // Three whitespace-separated header tokens follow the magic, then exactly one whitespace byte.
    let mut pos = 2;
    let mut tokens: Vec<&str> = Vec::with_capacity(3);
    for _ in 0..3 {
        if pos >= bytes.len() {
            return Err(bad(
                "truncated PFM header: expected width, height and scale".into(),
            ));
        }
        if !bytes[pos].is_ascii_whitespace() {
            return Err(bad(
                "malformed PFM header: expected whitespace between fields".into(),
            ));
        }
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() && pos - start < 64 {
            pos += 1;
        }
        let token = std::str::from_utf8(&bytes[start..pos])
            .map_err(|_| bad("malformed PFM header: a field is not ASCII".into()))?;
        if token.is_empty() {
            return Err(bad(
                "truncated PFM header: expected width, height and scale".into(),
            ));
        }
        tokens.push(token);
    }
    if pos >= bytes.len() || !bytes[pos].is_ascii_whitespace() {
        return Err(bad(
            "truncated PFM header: missing the newline after the scale".into(),
        ));
    }
    pos += 1;
    let width: u32 = tokens[0].parse().map_err(|_| {
        bad(format!(
            "malformed PFM header: width `{}` is not a number",
            tokens[0]
        ))
    })?;
    let height: u32 = tokens[1].parse().map_err(|_| {
        bad(format!(
            "malformed PFM header: height `{}` is not a number",
            tokens[1]
        ))
    })?;
    let scale: f64 = tokens[2].parse().map_err(|_| {
        bad(format!(
            "malformed PFM header: scale `{}` is not a number",
            tokens[2]
        ))
    })?;
    if scale == 0.0 || !scale.is_finite() {
        return Err(bad(format!(
            "malformed PFM header: scale must be non-zero, got {scale}"
        )));
    }
    let little_endian = scale < 0.0;
    let count = width as usize * height as usize;
    let data_bytes = &bytes[pos..];
    let needed = count
        .checked_mul(4)
        .ok_or_else(|| bad("PFM image is too large".into()))?;
    if data_bytes.len() < needed {
        return Err(bad(format!(
            "truncated PFM data: {width}×{height} needs {needed} bytes, found {}",
            data_bytes.len()
        )));
    }
    let mut data = vec![0.0f32; count];
    let w = width as usize;
    for (row_in_file, chunk) in data_bytes[..needed].chunks_exact(4 * w.max(1)).enumerate() {
        if w == 0 {
            break;
        }
        let v = height as usize - 1 - row_in_file;
        for (u, b) in chunk.chunks_exact(4).enumerate() {
            let raw = [b[0], b[1], b[2], b[3]];
            let value = if little_endian {
                f32::from_le_bytes(raw)
            } else {
                f32::from_be_bytes(raw)
            };
            data[v * w + u] = if value.is_finite() { value } else { f32::NAN };
        }
    }
    Ok(Image {
        width,
        height,
        data,
    })
}

/// Reads a grey PFM file (see [`decode_pfm`]); errors name `path`.
pub fn read_pfm(path: impl AsRef<Path>) -> Result<Image<f32>> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode_pfm(&bytes, path)
}

/// Writes `image` as a little-endian grey PFM (see [`encode_pfm`]); errors name `path`.
pub fn write_pfm(path: impl AsRef<Path>, image: &Image<f32>) -> Result<()> {
    let path = path.as_ref();
    let mut bytes = Vec::new();
    encode_pfm(image, &mut bytes);
    crate::io::atomic::write_file(path, &bytes)
}
