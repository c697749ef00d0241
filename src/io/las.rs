//! LAS / LAZ point clouds through the `las` crate.
//!
//! What it does: reads every point's coordinates (and RGB when the point format has it) into a
//! [`PointCloud`], reads the declared linear units from the GeoTIFF keys, and writes a
//! [`PointCloud`] as LAS 1.4 (compressed LAZ when the path ends in `.laz`), with an optional
//! OGC WKT coordinate reference system.
//!
//! What it does not do: reproject between coordinate reference systems, keep classification,
//! intensity, GPS time or other per-point attributes, or stream files larger than memory.
//!
//! # Conventions
//! * Coordinates: LAS stores `i32` integers `X` with a per-axis `scale` and `offset`; the value is
//!   `X·scale + offset` in the CRS's units. [`read_point_cloud`] returns those values unchanged
//!   (international feet for `autzen_trim.las`); [`read_point_cloud_metres`] multiplies them by
//!   the units declared in the GeoTIFF keys (`ProjLinearUnitsGeoKey` 3076 for x/y,
//!   `VerticalUnitsGeoKey` 4099 for z, falling back to the horizontal unit), metres when none
//!   is declared.
//! * Colour: LAS stores 16-bit RGB. Files whose channels never exceed 255 hold 8-bit values in
//!   the 16-bit fields (a common writer bug) and are taken as is; otherwise the high byte is
//!   kept (`v >> 8`). The writer stores `v·257` so that 255 maps to 65535 and reading returns
//!   the original 8-bit values exactly.
//! * Writing: LAS 1.4, point format 7 (with RGB) when the cloud has colours, else 6;
//!   `scale` = 0.001 (1 mm steps, so at most 0.5 mm rounding) and `offset` = the bounding-box
//!   centre rounded to whole metres, so coordinates within ±2 147 km of the centre fit. Headers are
//!   complete: creation date (UTC day of writing), system identifier `EXTRACTION` (the points are
//!   extracted from a fused map), generating software `denser <version>`, every point return 1
//!   of 1 (so the by-return counts add up), the WKT bit set with an OGC WKT CRS VLR
//!   (`LASF_Projection`, record 2112) when a CRS is given, legacy point counts 0 (as LAS 1.4
//!   asks for formats 6–10), and zero bounds for an empty file (the `las` crate would write ±inf
//!   and fill in the legacy counts; the header is patched after closing).

use crate::error::{Error, Result};
use crate::frame::PointCloud;
use las::{Builder, Color, Point, Reader, Transform, Vector, Version, Writer};
use std::path::Path;

/// Quantisation step used by [`write_point_cloud`], metres.
pub const WRITE_SCALE_M: f64 = 0.001;

fn las_err(path: &Path, e: las::Error) -> Error {
    match e {
        las::Error::Io(io) => Error::io(path, io),
        other => Error::bad_input(path, format!("LAS: {other}")),
    }
}

/// True when `e` (or an error it wraps, e.g. inside the LAZ decoder) is an unexpected EOF.
fn is_eof(e: &las::Error) -> bool {
    if let las::Error::Io(io) = e {
        return io.kind() == std::io::ErrorKind::UnexpectedEof;
    }
    let mut source: Option<&(dyn std::error::Error + 'static)> = std::error::Error::source(e);
    while let Some(s) = source {
        if s.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::UnexpectedEof)
        {
            return true;
        }
        source = s.source();
    }
    false
}

fn open(path: &Path) -> Result<Reader> {
    // Open the file ourselves so that "not found" is an I/O error naming the path.
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    Reader::new(std::io::BufReader::new(file)).map_err(|e| {
        if is_eof(&e) {
            Error::bad_input(
                path,
                "truncated LAS: the file ends inside its header or VLRs",
            )
        } else if matches!(e, las::Error::LasZipError(_)) {
            Error::bad_input(
                path,
                format!("cannot open the LAZ data (truncated or corrupt file?): {e}"),
            )
        } else {
            las_err(path, e)
        }
    })
}

/// Reads all points of a LAS/LAZ file, coordinates in the file's own units (see the module
/// doc), colours scaled to 8 bits when the point format has RGB. Fails with the file's name
/// when it is truncated (fewer point records than the header announces) or malformed.
pub fn read_point_cloud(path: impl AsRef<Path>) -> Result<PointCloud> {
    let path = path.as_ref();
    let mut reader = open(path)?;
    let expected = reader.header().number_of_points();
    let compressed = reader.header().point_format().is_compressed;
    let data = reader.read_all().map_err(|e| {
        if is_eof(&e) {
            let size = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
            Error::bad_input(
                path,
                format!(
                    "truncated {}: the header announces {expected} points but the file ends early ({size} bytes)",
                    if compressed { "LAZ" } else { "LAS" }
                ),
            )
        } else if compressed {
            // The LAZ decoder wraps its I/O errors without exposing them as a source.
            Error::bad_input(
                path,
                format!("cannot decompress the LAZ points (truncated or corrupt file?): {e}"),
            )
        } else {
            las_err(path, e)
        }
    })?;
    if (data.len() as u64) < expected {
        return Err(Error::bad_input(
            path,
            format!(
                "truncated LAS: the header announces {expected} points, only {} could be read",
                data.len()
            ),
        ));
    }
    let points_m: Vec<[f64; 3]> = data
        .x()
        .zip(data.y())
        .zip(data.z())
        .map(|((x, y), z)| [x, y, z])
        .collect();
    let colors = data.rgb().map(|rgb| {
        let raw: Vec<(u16, u16, u16)> = rgb.collect();
        let max = raw
            .iter()
            .map(|&(r, g, b)| r.max(g).max(b))
            .max()
            .unwrap_or(0);
        let shift = if max <= 255 { 0 } else { 8 };
        raw.into_iter()
            .map(|(r, g, b)| [(r >> shift) as u8, (g >> shift) as u8, (b >> shift) as u8])
            .collect()
    });
    Ok(PointCloud { points_m, colors })
}

/// The linear units declared by a LAS file's GeoTIFF keys, metres per unit, as
/// `(horizontal, vertical)`; `None` when the file declares no horizontal unit. The vertical unit
/// falls back to the horizontal one. Known codes: 9001 metre, 9002 foot (0.3048), 9003 US
/// survey foot (1200/3937); other codes are an error.
pub fn linear_units_m(path: impl AsRef<Path>) -> Result<Option<(f64, f64)>> {
    let path = path.as_ref();
    let reader = open(path)?;
    let Some(vlr) = reader
        .header()
        .all_vlrs()
        .find(|v| v.user_id.trim_end_matches('\0') == "LASF_Projection" && v.record_id == 34735)
    else {
        return Ok(None);
    };
    let words: Vec<u16> = vlr
        .data
        .chunks_exact(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect();
    let key = |id: u16| -> Option<u16> {
        let n = *words.get(3)? as usize;
        (0..n).find_map(|k| {
            let e = words.get(4 + 4 * k..8 + 4 * k)?;
            // Location 0 means the value is stored inline in the 4th word.
            (e[0] == id && e[1] == 0).then_some(e[3])
        })
    };
    let unit = |code: u16| -> Result<f64> {
        match code {
            9001 => Ok(1.0),
            9002 => Ok(0.3048),
            9003 => Ok(1200.0 / 3937.0),
            other => Err(Error::bad_input(
                path,
                format!("unsupported GeoTIFF linear unit code {other}"),
            )),
        }
    };
    let Some(h) = key(3076) else { return Ok(None) };
    let h = unit(h)?;
    let v = match key(4099) {
        Some(code) => unit(code)?,
        None => h,
    };
    Ok(Some((h, v)))
}

/// Reads a LAS/LAZ file with coordinates converted to metres using [`linear_units_m`]
/// (unchanged when the file declares no unit).
pub fn read_point_cloud_metres(path: impl AsRef<Path>) -> Result<PointCloud> {
    let path = path.as_ref();
    let mut cloud = read_point_cloud(path)?;
    if let Some((h, v)) = linear_units_m(path)? {
        for p in &mut cloud.points_m {
            *p = [p[0] * h, p[1] * h, p[2] * v];
        }
    }
    Ok(cloud)
}

/// Writes `cloud` as LAS 1.4 (LAZ when `path` ends in `.laz`, any case) with no CRS; see the
/// module doc for scale, offset, point format and header fields. Fails on non-finite coordinates,
/// colour count mismatch, or a cloud wider than the 32-bit integer range at 1 mm (±2 147 km
/// around its centre).
pub fn write_point_cloud(path: impl AsRef<Path>, cloud: &PointCloud) -> Result<()> {
    let path = path.as_ref();
    if let Some(c) = &cloud.colors {
        if c.len() != cloud.points_m.len() {
            return Err(Error::InvalidArgument(format!(
                "{}: {} points but {} colours",
                path.display(),
                cloud.points_m.len(),
                c.len()
            )));
        }
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in &cloud.points_m {
        for k in 0..3 {
            if !p[k].is_finite() {
                return Err(Error::InvalidArgument(format!(
                    "{}: non-finite coordinate {p:?}",
                    path.display()
                )));
            }
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let mut offset = [0.0; 3];
    if !cloud.points_m.is_empty() {
        for k in 0..3 {
            offset[k] = (0.5 * (lo[k] + hi[k])).round();
            let reach = (hi[k] - offset[k]).max(offset[k] - lo[k]) / WRITE_SCALE_M;
            if reach >= i32::MAX as f64 {
                return Err(Error::InvalidArgument(format!(
                    "{}: extent {:.0} m along axis {k} does not fit LAS 32-bit integers at {} m",
                    path.display(),
                    hi[k] - lo[k],
                    WRITE_SCALE_M
                )));
            }
        }
    }
    let mut writer = LasPointWriter::create(path, offset, cloud.colors.is_some(), None)?;
    for (i, p) in cloud.points_m.iter().enumerate() {
        writer.write(*p, cloud.colors.as_ref().map(|c| c[i]))?;
    }
    writer.close()
}

/// The system identifier written into every LAS header (the LAS 1.4 value for data extracted
/// from other data).
pub const SYSTEM_IDENTIFIER: &str = "EXTRACTION";

/// The generating software written into every LAS header.
pub fn generating_software() -> String {
    format!("denser {}", env!("CARGO_PKG_VERSION"))
}

/// Today's date (UTC) for the header's creation day and year.
fn today() -> Option<chrono::NaiveDate> {
    Some(chrono::Utc::now().date_naive())
}

/// A LAS/LAZ file written point by point (for exports larger than memory): LAS 1.4, point format
/// 7 with colour or 6 without, scale [`WRITE_SCALE_M`] around a fixed offset; LAZ when the path
/// ends in `.laz`. Header bounds and counts are filled in by [`LasPointWriter::close`].
pub struct LasPointWriter {
    path: std::path::PathBuf,
    /// Where the file is written until [`LasPointWriter::close`] renames it into place.
    temp: Option<crate::io::atomic::TempPath>,
    writer: Option<Writer<std::io::BufWriter<std::fs::File>>>,
    offset_m: [f64; 3],
    points: u64,
}

impl LasPointWriter {
    /// Creates the file; points must lie within ±2 147 km of `offset_m`. `crs_wkt`: OGC WKT of
    /// the coordinates' CRS, written as a WKT VLR.
    pub fn create(
        path: &Path,
        offset_m: [f64; 3],
        colors: bool,
        crs_wkt: Option<&str>,
    ) -> Result<Self> {
        let mut builder = Builder::from(Version::new(1, 4));
        let format = if colors { 7 } else { 6 };
        builder.point_format = las::point::Format::new(format).map_err(|e| las_err(path, e))?;
        builder.generating_software = generating_software();
        builder.system_identifier = SYSTEM_IDENTIFIER.into();
        builder.date = today();
        let t = |k: usize| Transform {
            scale: WRITE_SCALE_M,
            offset: offset_m[k],
        };
        builder.transforms = Vector {
            x: t(0),
            y: t(1),
            z: t(2),
        };
        builder.point_format.is_compressed = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("laz"));
        let mut header = builder.into_header().map_err(|e| las_err(path, e))?;
        if let Some(wkt) = crs_wkt {
            // WKT strings in LAS are null-terminated.
            let mut bytes = wkt.as_bytes().to_vec();
            bytes.push(0);
            header.set_wkt_crs(bytes).map_err(|e| las_err(path, e))?;
        }
        let temp = crate::io::atomic::TempPath::for_target(path);
        let file = std::fs::File::create(temp.path()).map_err(|e| Error::io(path, e))?;
        let writer =
            Writer::new(std::io::BufWriter::new(file), header).map_err(|e| las_err(path, e))?;
        Ok(LasPointWriter {
            path: path.to_path_buf(),
            temp: Some(temp),
            writer: Some(writer),
            offset_m,
            points: 0,
        })
    }

    /// Appends one point (metres) with an optional sRGB colour.
    pub fn write(&mut self, p: [f64; 3], color: Option<[u8; 3]>) -> Result<()> {
        for k in 0..3 {
            if !p[k].is_finite()
                || ((p[k] - self.offset_m[k]) / WRITE_SCALE_M).abs() >= i32::MAX as f64
            {
                return Err(Error::InvalidArgument(format!(
                    "{}: coordinate {p:?} is not finite or too far from the offset {:?} for LAS 32-bit integers",
                    self.path.display(),
                    self.offset_m
                )));
            }
        }
        let color =
            color.map(|[r, g, b]| Color::new(r as u16 * 257, g as u16 * 257, b as u16 * 257));
        let point = Point {
            x: p[0],
            y: p[1],
            z: p[2],
            color,
            return_number: 1,
            number_of_returns: 1,
            gps_time: Some(0.0),
            ..Default::default()
        };
        let w = self.writer.as_mut().expect("open until closed");
        w.write_point(point).map_err(|e| las_err(&self.path, e))?;
        self.points += 1;
        Ok(())
    }

    /// Finishes the file (header bounds and counts).
    pub fn close(mut self) -> Result<()> {
        let mut w = self.writer.take().expect("open until closed");
        if let Err(e) = w.close() {
            // `las::Writer` panics when dropped unclosed; after a failed close, leak it instead.
            std::mem::forget(w);
            return Err(las_err(&self.path, e));
        }
        drop(w);
        let temp = self.temp.take().expect("open until closed");
        patch_header(temp.path(), self.points == 0)?;
        temp.persist(&self.path)
    }
}

/// Offset of the legacy point count in a LAS header; the five legacy by-return counts follow.
const HEADER_LEGACY_COUNT_OFFSET: u64 = 107;
/// Offset of `max_x` in a LAS header; the six bounds (`f64`: max x, min x, max y, min y, max z,
/// min z) follow it.
const HEADER_BOUNDS_OFFSET: u64 = 179;

/// Fixes what the `las` crate writes differently from LAS 1.4: the legacy point counts must be 0
/// for point formats 6–10 (it fills them in), and a file with no points gets zero bounds (it
/// leaves ±inf).
fn patch_header(path: &Path, empty: bool) -> Result<()> {
    use std::io::{Seek, SeekFrom, Write};
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .open(path)
        .map_err(|e| Error::io(path, e))?;
    f.seek(SeekFrom::Start(HEADER_LEGACY_COUNT_OFFSET))
        .and_then(|_| f.write_all(&[0u8; 24]))
        .map_err(|e| Error::io(path, e))?;
    if empty {
        f.seek(SeekFrom::Start(HEADER_BOUNDS_OFFSET))
            .and_then(|_| f.write_all(&[0u8; 48]))
            .map_err(|e| Error::io(path, e))?;
    }
    f.sync_all().map_err(|e| Error::io(path, e))
}

impl Drop for LasPointWriter {
    fn drop(&mut self) {
        if let Some(mut w) = self.writer.take() {
            if w.close().is_err() {
                std::mem::forget(w);
            }
        }
    }
}
