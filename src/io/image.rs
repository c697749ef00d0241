//! Image files: 8-bit grey and colour images in every format the `image` crate reads here (PNG,
//! JPEG, TIFF, PNM = PBM/PGM/PPM, BMP, WebP), 16-bit depth images (PNG, TIFF, PGM) and 16-bit (or
//! 8-bit) binary PGM through an own decoder.
//!
//! What it does: decodes into the crate's [`Image`] types and encodes them back, converting
//! integer depth units to metres (and back) with an explicit `units_per_m` factor, e.g. 5000 for
//! TUM RGB-D PNGs and 1000 for millimetre PGMs. The format is guessed from the file's first bytes
//! (then the extension), so a `.png` that holds a JPEG still reads. Every error names the file.
//!
//! What it does not do: colour management (pixels are taken as stored, sRGB assumed), 16-bit
//! colour (decoded and reduced to 8 bits), floating-point depth images, or lossy-format checks
//! (a JPEG depth map is refused only when it is not 16-bit, which JPEG never is).
//!
//! # Byte layouts
//! * PNG and TIFF: whatever the `image` crate reads; 16-bit samples are stored big-endian inside
//!   PNG (either order in TIFF), the crate hands them over as native `u16`.
//! * Binary PGM (`P5`, Netpbm spec): ASCII header `P5 <width> <height> <maxval>` separated by
//!   whitespace (with `#` comments up to end of line), then exactly one whitespace byte, then
//!   `width·height` samples, row-major, top row first. A sample is one byte when
//!   `maxval < 256`, otherwise two bytes **big-endian** (most significant byte first), as
//!   OpenCV's `imwrite` produces.
//! * Depth: an integer sample `s` means `s / units_per_m` metres along the optical axis; `0`
//!   means "no measurement" and becomes NaN in a [`DepthImage`].

use crate::error::{Error, Result};
use crate::frame::{DepthImage, GreyImage, Image, RgbImage};
use image::{DynamicImage, ImageBuffer, ImageReader, Luma, Rgb};
use std::path::Path;

/// File extensions (lower case) of the image formats this build reads, in the order a frame
/// folder is searched when several exist ([`find_image`]).
pub const IMAGE_EXTENSIONS: &[&str] = &[
    "png", "jpg", "jpeg", "tif", "tiff", "pgm", "ppm", "pnm", "pbm", "bmp", "webp",
];

/// Whether `path` has one of [`IMAGE_EXTENSIONS`] (any case).
pub fn has_image_extension(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.iter().any(|x| e.eq_ignore_ascii_case(x)))
}

/// The first existing file `dir/stem.EXT` for `EXT` in [`IMAGE_EXTENSIONS`] order (lower, then
/// upper case), or `None`.
pub fn find_image(dir: &Path, stem: &str) -> Option<std::path::PathBuf> {
    IMAGE_EXTENSIONS.iter().find_map(|ext| {
        [ext.to_string(), ext.to_ascii_uppercase()]
            .into_iter()
            .map(|e| dir.join(format!("{stem}.{e}")))
            .find(|p| p.is_file())
    })
}

/// Decodes any image file the `image` crate understands (see [`IMAGE_EXTENSIONS`]).
fn decode(path: &Path) -> Result<DynamicImage> {
    let reader = ImageReader::open(path)
        .map_err(|e| Error::io(path, e))?
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    if reader.format().is_none() {
        return Err(Error::bad_input(
            path,
            format!(
                "not an image this build reads (formats: {})",
                IMAGE_EXTENSIONS.join(", ")
            ),
        ));
    }
    reader.decode().map_err(|e| match e {
        image::ImageError::IoError(io) => Error::io(path, io),
        image::ImageError::Unsupported(u) => Error::bad_input(
            path,
            format!(
                "cannot decode image: {u} (formats read: {})",
                IMAGE_EXTENSIONS.join(", ")
            ),
        ),
        other => Error::bad_input(path, format!("cannot decode image: {other}")),
    })
}

/// Reads an image as 8-bit grey; colour images are converted to luma (Rec. 709 weights, as the
/// `image` crate does), 16-bit images are scaled to 8 bits.
pub fn read_grey(path: impl AsRef<Path>) -> Result<GreyImage> {
    let img = decode(path.as_ref())?.into_luma8();
    let (width, height) = img.dimensions();
    Ok(Image {
        width,
        height,
        data: img.into_raw(),
    })
}

/// Reads an image as 8-bit RGB; grey images are replicated into the three channels and alpha is
/// dropped.
pub fn read_rgb(path: impl AsRef<Path>) -> Result<RgbImage> {
    let img = decode(path.as_ref())?.into_rgb8();
    let (width, height) = img.dimensions();
    let data = img
        .into_raw()
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    Ok(Image {
        width,
        height,
        data,
    })
}

/// Reads a single-channel 16-bit image (PNG; any format of [`read_u16`]) as raw integer samples.
/// Kept for callers that name PNG; it is [`read_u16`].
pub fn read_png_u16(path: impl AsRef<Path>) -> Result<Image<u16>> {
    read_u16(path)
}

/// Reads a single-channel 16-bit image (PNG, TIFF, PGM, any format the `image` crate decodes) as
/// raw integer samples. An 8-bit grey image is accepted and widened without scaling; a colour
/// image is an error.
pub fn read_u16(path: impl AsRef<Path>) -> Result<Image<u16>> {
    let path = path.as_ref();
    let img = decode(path)?;
    let (width, height) = (img.width(), img.height());
    let data: Vec<u16> = match img {
        DynamicImage::ImageLuma16(b) => b.into_raw(),
        DynamicImage::ImageLuma8(b) => b.into_raw().into_iter().map(u16::from).collect(),
        other => {
            return Err(Error::bad_input(
                path,
                format!(
                    "expected a single-channel 16-bit depth image, found {:?}",
                    other.color()
                ),
            ))
        }
    };
    Ok(Image {
        width,
        height,
        data,
    })
}

/// Converts integer depth samples to metres: `s / units_per_m`, 0 → NaN.
pub fn depth_from_u16(raw: &Image<u16>, units_per_m: f64) -> DepthImage {
    let inv = 1.0 / units_per_m;
    let data = raw
        .data
        .iter()
        .map(|&s| {
            if s == 0 {
                f32::NAN
            } else {
                (s as f64 * inv) as f32
            }
        })
        .collect();
    Image {
        width: raw.width,
        height: raw.height,
        data,
    }
}

fn check_units(units_per_m: f64) -> Result<()> {
    if units_per_m.is_finite() && units_per_m > 0.0 {
        Ok(())
    } else {
        Err(Error::InvalidArgument(format!(
            "depth units per metre must be > 0, got {units_per_m}"
        )))
    }
}

/// Reads a 16-bit depth PNG where a sample `s` means `s / units_per_m` metres (5000 for TUM
/// RGB-D, 1000 for millimetres); 0 becomes NaN (invalid).
pub fn read_depth_png_u16(path: impl AsRef<Path>, units_per_m: f64) -> Result<DepthImage> {
    check_units(units_per_m)?;
    Ok(depth_from_u16(&read_png_u16(path)?, units_per_m))
}

/// Reads a 16-bit depth image in any format of [`read_u16`] (binary PGM through
/// [`read_pgm_u16`]) where a sample `s` means `s / units_per_m` metres; 0 becomes NaN.
pub fn read_depth_u16(path: impl AsRef<Path>, units_per_m: f64) -> Result<DepthImage> {
    let path = path.as_ref();
    check_units(units_per_m)?;
    let is_pgm = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("pgm"));
    let raw = if is_pgm {
        read_pgm_u16(path)?
    } else {
        read_u16(path)?
    };
    Ok(depth_from_u16(&raw, units_per_m))
}

/// Reads a binary PGM (`P5`, 8 or 16 bits, 16-bit samples big-endian) as raw samples.
pub fn read_pgm_u16(path: impl AsRef<Path>) -> Result<Image<u16>> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode_pgm(&bytes).map_err(|msg| Error::bad_input(path, msg))
}

/// Reads a binary 16-bit PGM depth map where a sample `s` means `s / units_per_m` metres (1000
/// for millimetres); 0 becomes NaN (invalid).
pub fn read_depth_pgm_u16(path: impl AsRef<Path>, units_per_m: f64) -> Result<DepthImage> {
    check_units(units_per_m)?;
    Ok(depth_from_u16(&read_pgm_u16(path)?, units_per_m))
}

/// Decodes a binary PGM held in memory (see the module doc for the layout).
pub fn decode_pgm(bytes: &[u8]) -> std::result::Result<Image<u16>, String> {
    if bytes.len() < 2 || &bytes[..2] != b"P5" {
        return Err("not a binary PGM file (magic 'P5' missing)".into());
    }
    let mut pos = 2;
    let mut fields = [0u64; 3];
    for (k, field) in fields.iter_mut().enumerate() {
        // Skip whitespace and comments.
        loop {
            match bytes.get(pos) {
                Some(b'#') => {
                    while bytes.get(pos).is_some_and(|&c| c != b'\n') {
                        pos += 1;
                    }
                }
                Some(c) if c.is_ascii_whitespace() => pos += 1,
                _ => break,
            }
        }
        let start = pos;
        while bytes.get(pos).is_some_and(|c| c.is_ascii_digit()) {
            pos += 1;
        }
        let name = ["width", "height", "maxval"][k];
        let text = std::str::from_utf8(&bytes[start..pos]).unwrap_or("");
        *field = text
            .parse()
            .map_err(|_| format!("PGM header: cannot read the {name}"))?;
    }
    if !bytes.get(pos).is_some_and(|c| c.is_ascii_whitespace()) {
        return Err("PGM header: no whitespace after maxval".into());
    }
    pos += 1;
    let [width, height, maxval] = fields;
    if !(1..=65535).contains(&maxval) {
        return Err(format!("PGM header: maxval {maxval} is outside 1..65535"));
    }
    if width == 0 || height == 0 || width > u32::MAX as u64 || height > u32::MAX as u64 {
        return Err(format!("PGM header: bad size {width}x{height}"));
    }
    let n = (width * height) as usize;
    let bytes_per_sample = if maxval < 256 { 1 } else { 2 };
    let body = &bytes[pos..];
    if body.len() < n * bytes_per_sample {
        return Err(format!(
            "truncated PGM: {width}x{height} needs {} bytes of samples, found {}",
            n * bytes_per_sample,
            body.len()
        ));
    }
    let data = if bytes_per_sample == 1 {
        body[..n].iter().map(|&b| b as u16).collect()
    } else {
        body[..2 * n]
            .chunks_exact(2)
            .map(|c| u16::from_be_bytes([c[0], c[1]]))
            .collect()
    };
    Ok(Image {
        width: width as u32,
        height: height as u32,
        data,
    })
}

/// Encodes a 16-bit binary PGM (`maxval` 65535, big-endian samples).
pub fn encode_pgm_u16(img: &Image<u16>) -> Vec<u8> {
    let mut out = format!("P5\n{} {}\n65535\n", img.width, img.height).into_bytes();
    out.reserve(img.data.len() * 2);
    for &s in &img.data {
        out.extend_from_slice(&s.to_be_bytes());
    }
    out
}

/// Writes a 16-bit binary PGM (`maxval` 65535, big-endian samples).
pub fn write_pgm_u16(path: impl AsRef<Path>, img: &Image<u16>) -> Result<()> {
    let path = path.as_ref();
    check_size(img)?;
    crate::io::atomic::write_file(path, &encode_pgm_u16(img))
}

/// Converts metres to integer samples `round(d · units_per_m)`; NaN / non-positive → 0. Fails
/// (naming how many pixels) when a valid depth does not fit in 1..=65535 units.
pub fn depth_to_u16(depth: &DepthImage, units_per_m: f64) -> Result<Image<u16>> {
    check_units(units_per_m)?;
    let mut out_of_range = 0usize;
    let mut max_m = 0.0f32;
    let data = depth
        .data
        .iter()
        .map(|&d| {
            if !(d.is_finite() && d > 0.0) {
                return 0;
            }
            let s = (d as f64 * units_per_m).round();
            if (1.0..=65535.0).contains(&s) {
                s as u16
            } else {
                out_of_range += 1;
                max_m = max_m.max(d);
                0
            }
        })
        .collect();
    if out_of_range > 0 {
        return Err(Error::InvalidArgument(format!(
            "{out_of_range} depths (up to {max_m} m) do not fit a 16-bit sample at {units_per_m} units per metre \
             (representable: {:.6}..{:.3} m)",
            1.0 / units_per_m,
            65535.0 / units_per_m
        )));
    }
    Ok(Image {
        width: depth.width,
        height: depth.height,
        data,
    })
}

fn check_size<T>(img: &Image<T>) -> Result<()> {
    if img.data.len() != img.width as usize * img.height as usize {
        return Err(Error::InvalidArgument(format!(
            "image is {}x{} but holds {} pixels",
            img.width,
            img.height,
            img.data.len()
        )));
    }
    Ok(())
}

fn save_err(path: &Path, e: image::ImageError) -> Error {
    match e {
        image::ImageError::IoError(io) => Error::io(path, io),
        other => Error::bad_input(path, format!("cannot encode image: {other}")),
    }
}

/// Encodes `buf` as PNG in memory and writes it through `io::atomic` (complete or absent).
fn save_png<P, C>(path: &Path, buf: &ImageBuffer<P, C>) -> Result<()>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    let mut bytes = std::io::Cursor::new(Vec::new());
    buf.write_to(&mut bytes, image::ImageFormat::Png)
        .map_err(|e| save_err(path, e))?;
    crate::io::atomic::write_file(path, bytes.get_ref())
}

/// Writes a 16-bit grey PNG of raw samples.
pub fn write_png_u16(path: impl AsRef<Path>, img: &Image<u16>) -> Result<()> {
    let path = path.as_ref();
    check_size(img)?;
    let buf: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_raw(img.width, img.height, img.data.clone())
            .ok_or_else(|| Error::InvalidArgument("image buffer size mismatch".into()))?;
    save_png(path, &buf)
}

/// Writes a depth map as a 16-bit PNG with `units_per_m` integer units per metre (NaN → 0).
/// Fails when a valid depth does not fit in 16 bits (see [`depth_to_u16`]).
pub fn write_depth_png_u16(
    path: impl AsRef<Path>,
    depth: &DepthImage,
    units_per_m: f64,
) -> Result<()> {
    check_size(depth)?;
    write_png_u16(path, &depth_to_u16(depth, units_per_m)?)
}

/// Writes an 8-bit grey PNG.
pub fn write_grey_png(path: impl AsRef<Path>, img: &GreyImage) -> Result<()> {
    let path = path.as_ref();
    check_size(img)?;
    let buf: ImageBuffer<Luma<u8>, Vec<u8>> =
        ImageBuffer::from_raw(img.width, img.height, img.data.clone())
            .ok_or_else(|| Error::InvalidArgument("image buffer size mismatch".into()))?;
    save_png(path, &buf)
}

/// Writes an 8-bit RGB PNG.
pub fn write_rgb_png(path: impl AsRef<Path>, img: &RgbImage) -> Result<()> {
    let path = path.as_ref();
    check_size(img)?;
    let raw: Vec<u8> = img.data.iter().flatten().copied().collect();
    let buf: ImageBuffer<Rgb<u8>, Vec<u8>> = ImageBuffer::from_raw(img.width, img.height, raw)
        .ok_or_else(|| Error::InvalidArgument("image buffer size mismatch".into()))?;
    save_png(path, &buf)
}

/// Width and height of an image file, read from its header only.
pub fn image_size(path: impl AsRef<Path>) -> Result<(u32, u32)> {
    let path = path.as_ref();
    let reader = ImageReader::open(path)
        .map_err(|e| Error::io(path, e))?
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    reader.into_dimensions().map_err(|e| match e {
        image::ImageError::IoError(io) => Error::io(path, io),
        other => Error::bad_input(path, format!("cannot read image header: {other}")),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pgm_roundtrip_big_endian() {
        let img = Image {
            width: 3,
            height: 2,
            data: vec![0, 1, 256, 1000, 65535, 258],
        };
        let bytes = encode_pgm_u16(&img);
        // 258 = 0x0102 is stored most significant byte first.
        let n = bytes.len();
        assert_eq!(&bytes[n - 2..], &[1, 2]);
        assert_eq!(decode_pgm(&bytes).unwrap(), img);
    }

    #[test]
    fn pgm_with_comment_and_8bit() {
        let mut bytes = b"P5 # comment\n2 # w\n1\n255\n".to_vec();
        bytes.extend_from_slice(&[7, 200]);
        let img = decode_pgm(&bytes).unwrap();
        assert_eq!((img.width, img.height), (2, 1));
        assert_eq!(img.data, vec![7, 200]);
    }

    #[test]
    fn pgm_truncated_and_bad_magic() {
        let img = Image {
            width: 4,
            height: 4,
            data: vec![5u16; 16],
        };
        let bytes = encode_pgm_u16(&img);
        let err = decode_pgm(&bytes[..bytes.len() - 1]).unwrap_err();
        assert!(err.contains("truncated"), "{err}");
        assert!(decode_pgm(b"P6 1 1 255\n\0\0\0")
            .unwrap_err()
            .contains("P5"));
    }

    #[test]
    fn depth_units_conversion() {
        let raw = Image {
            width: 3,
            height: 1,
            data: vec![0, 5000, 65535],
        };
        let d = depth_from_u16(&raw, 5000.0);
        assert!(d.data[0].is_nan());
        assert_eq!(d.data[1], 1.0);
        assert!((d.data[2] - 13.107).abs() < 1e-5);
        assert_eq!(depth_to_u16(&d, 5000.0).unwrap(), raw);
        let too_far = Image {
            width: 1,
            height: 1,
            data: vec![20.0f32],
        };
        assert!(depth_to_u16(&too_far, 5000.0).is_err());
    }
}
