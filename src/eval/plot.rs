//! Evaluation pictures as PNG (DENSER Fig. 4 style): overlaid error histograms, and what the top
//! view of the reconstructed points coloured by error (`top_view`) shares with them: the error
//! colormap, the up axis, the font and the PNG writer.
//!
//! Drawn with `plotters`' bitmap backend; text uses DejaVu Sans embedded in the binary
//! (`assets/fonts/`, Bitstream Vera licence), so no system font library is needed. PNGs are
//! encoded with the `image` crate. This module does not compute errors.

use crate::error::{Error, Result};
use crate::eval::stats::ErrorStats;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::OnceLock;

/// DejaVu Sans 2.37 (Debian `fonts-dejavu-core`); licence in `assets/fonts/DejaVuSans-LICENSE.txt`.
static FONT_TTF: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");

/// Font family name the charts use.
pub(super) const FONT: &str = "sans-serif";

/// Series colours (matplotlib's tab10: red, blue, green, orange, purple): the first surface
/// (usually "raw") is red, the second (usually "regularized") blue.
pub const SERIES_COLOURS: [[u8; 3]; 5] = [
    [214, 39, 40],
    [31, 119, 180],
    [44, 160, 44],
    [255, 127, 14],
    [148, 103, 189],
];

/// Colormap anchors, low error → high error: ColorBrewer RdYlBu (11 classes), reversed, so that
/// small errors are blue, middling ones pale yellow and large ones dark red.
const COLORMAP: [[u8; 3]; 11] = [
    [49, 54, 149],
    [69, 117, 180],
    [116, 173, 209],
    [171, 217, 233],
    [224, 243, 248],
    [255, 255, 191],
    [254, 224, 144],
    [253, 174, 97],
    [244, 109, 67],
    [215, 48, 39],
    [165, 0, 38],
];

/// The error colormap at `t ∈ [0, 1]` (clamped; NaN maps to 0): piecewise-linear between the
/// ColorBrewer RdYlBu anchors, blue (0) → yellow (0.5) → red (1).
pub fn error_colour(t: f32) -> [u8; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    let x = t * (COLORMAP.len() - 1) as f32;
    let i = (x.floor() as usize).min(COLORMAP.len() - 2);
    let f = x - i as f32;
    let (a, b) = (COLORMAP[i], COLORMAP[i + 1]);
    std::array::from_fn(|k| (a[k] as f32 + (b[k] as f32 - a[k] as f32) * f).round() as u8)
}

/// The world axis that points up; a top view looks down it (from +up towards −up).
///
/// The image axes are chosen so the picture is not mirrored: `right × forward = up`, with
/// "forward" pointing up the image. KITTI's camera/world frame is y-down (x right, z forward), so
/// its up axis is [`UpAxis::NegY`], which shows x to the right and z up the image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum UpAxis {
    /// +x is up: image right = +y, image up = +z.
    PosX,
    /// −x is up: image right = +y, image up = −z.
    NegX,
    /// +y is up (OpenGL-style): image right = +x, image up = −z.
    PosY,
    /// −y is up (KITTI, camera frames): image right = +x, image up = +z.
    #[default]
    NegY,
    /// +z is up (LAS, ENU maps): image right = +x, image up = +y.
    PosZ,
    /// −z is up (NED): image right = +x, image up = −y.
    NegZ,
}

impl UpAxis {
    /// `((axis, sign) of image right, (axis, sign) of image up)`; axis 0 = x, 1 = y, 2 = z.
    pub fn image_axes(self) -> ((usize, f64), (usize, f64)) {
        match self {
            UpAxis::PosX => ((1, 1.0), (2, 1.0)),
            UpAxis::NegX => ((1, 1.0), (2, -1.0)),
            UpAxis::PosY => ((0, 1.0), (2, -1.0)),
            UpAxis::NegY => ((0, 1.0), (2, 1.0)),
            UpAxis::PosZ => ((0, 1.0), (1, 1.0)),
            UpAxis::NegZ => ((0, 1.0), (1, -1.0)),
        }
    }
}

/// Registers the embedded font once.
pub(super) fn ensure_font() -> Result<()> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| register_font(FONT, FontStyle::Normal, FONT_TTF).is_ok());
    if ok {
        Ok(())
    } else {
        Err(Error::InvalidArgument(
            "the embedded font could not be parsed".into(),
        ))
    }
}

/// A drawing failure on `path`, reported as an I/O error on that file.
pub(super) fn draw_error<E: std::fmt::Display>(path: &Path) -> impl Fn(E) -> Error + '_ {
    move |e| {
        Error::io(
            path,
            std::io::Error::other(format!("drawing the chart failed: {e}")),
        )
    }
}

/// Encodes an RGB buffer as PNG at `path` (complete or absent: `io::atomic`).
pub(super) fn save_png(path: &Path, rgb: &[u8], (w, h): (u32, u32)) -> Result<()> {
    let buf: image::RgbImage = image::ImageBuffer::from_raw(w, h, rgb.to_vec())
        .ok_or_else(|| Error::InvalidArgument(format!("{}: image buffer size", path.display())))?;
    let mut bytes = std::io::Cursor::new(Vec::new());
    buf.write_to(&mut bytes, image::ImageFormat::Png)
        .map_err(|e| Error::io(path, std::io::Error::other(e)))?;
    crate::io::atomic::write_file(path, bytes.get_ref())
}

pub(super) fn rgb(c: [u8; 3]) -> RGBColor {
    RGBColor(c[0], c[1], c[2])
}

/// Colour of points that were not scored (outside the LiDAR's view) in the top view.
pub const UNSCORED_GREY: [u8; 3] = [190, 190, 190];

/// Overlaid error histograms (paper Fig. 4): x = error in metres from 0 to `max_m`, y = fraction
/// of each surface's scored points per bin; one filled, outlined series per `(label, stats)` in
/// [`SERIES_COLOURS`] order, with a legend giving each median. Writes a 1000×600 PNG to `path`.
///
/// Errors when `series` is empty, `max_m` is not positive and finite, or the file cannot be
/// written.
pub fn plot_error_histograms_png(
    path: impl AsRef<Path>,
    series: &[(&str, &ErrorStats)],
    max_m: f64,
) -> Result<()> {
    let path = path.as_ref();
    if series.is_empty() {
        return Err(Error::InvalidArgument("no histogram to plot".into()));
    }
    if !(max_m.is_finite() && max_m > 0.0) {
        return Err(Error::InvalidArgument(format!(
            "histogram plot range must be a positive number of metres, got {max_m}"
        )));
    }
    ensure_font()?;
    let (w, h) = (1000u32, 600u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let err = draw_error(path);
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(&err)?;
        let y_top = series
            .iter()
            .flat_map(|(_, s)| {
                let hist = &s.histogram;
                let f = hist.fractions();
                (0..hist.regular_bins())
                    .filter(move |&i| hist.bin_range_m(i).0 < max_m)
                    .map(move |i| f[i])
            })
            .fold(0.0f64, f64::max);
        let y_top = if y_top > 0.0 { y_top * 1.12 } else { 1.0 };
        let mut chart = ChartBuilder::on(&root)
            .caption("Distance to the nearest ground-truth point", (FONT, 28))
            .margin(20)
            .x_label_area_size(55)
            .y_label_area_size(80)
            .build_cartesian_2d(0f64..max_m, 0f64..y_top)
            .map_err(&err)?;
        chart
            .configure_mesh()
            .x_desc("error (m)")
            .y_desc("fraction of points")
            .axis_desc_style((FONT, 20))
            .label_style((FONT, 16))
            .light_line_style(RGBColor(235, 235, 235))
            .bold_line_style(RGBColor(215, 215, 215))
            .draw()
            .map_err(&err)?;
        for (k, (label, stats)) in series.iter().enumerate() {
            let colour = rgb(SERIES_COLOURS[k % SERIES_COLOURS.len()]);
            let hist = &stats.histogram;
            let f = hist.fractions();
            let bins: Vec<(f64, f64, f64)> = (0..hist.regular_bins())
                .map(|i| (hist.bin_range_m(i), f[i]))
                .filter(|((lo, _), _)| *lo < max_m)
                .map(|((lo, hi), f)| (lo, hi.min(max_m), f))
                .collect();
            chart
                .draw_series(bins.iter().map(|&(lo, hi, f)| {
                    Rectangle::new([(lo, 0.0), (hi, f)], colour.mix(0.22).filled())
                }))
                .map_err(&err)?;
            let mut outline = vec![(0.0, 0.0)];
            for &(lo, hi, f) in &bins {
                outline.push((lo, f));
                outline.push((hi, f));
            }
            if let Some(&(_, hi, _)) = bins.last() {
                outline.push((hi, 0.0));
            }
            // The share past the plotted range (the overflow bin and the regular bins beyond
            // it), said in the legend since it is not drawn.
            let beyond: f64 = (0..f.len())
                .filter(|&i| i >= hist.regular_bins() || hist.bin_range_m(i).0 >= max_m)
                .map(|i| f[i])
                .sum();
            let mut legend = format!(
                "{label}: median {:.3} m, p75 {:.3} m ({} points",
                stats.median_m, stats.p75_m, stats.count
            );
            if beyond > 0.0 {
                legend.push_str(&format!(
                    "; {:.1} % beyond {max_m} m, not drawn",
                    100.0 * beyond
                ));
            }
            legend.push(')');
            chart
                .draw_series(std::iter::once(PathElement::new(
                    outline,
                    colour.stroke_width(2),
                )))
                .map_err(&err)?
                .label(legend)
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 6), (x + 24, y + 6)], colour.filled())
                });
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.9))
            .border_style(RGBColor(120, 120, 120))
            .label_font((FONT, 18))
            .margin(12)
            .draw()
            .map_err(&err)?;
        root.present().map_err(&err)?;
    }
    save_png(path, &buf, (w, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colormap_ends_and_middle() {
        assert_eq!(error_colour(0.0), COLORMAP[0]);
        assert_eq!(error_colour(1.0), COLORMAP[10]);
        assert_eq!(error_colour(0.5), COLORMAP[5]);
        assert_eq!(error_colour(7.0), COLORMAP[10]);
        assert_eq!(error_colour(f32::NAN), COLORMAP[0]);
        // Halfway between the first two anchors.
        assert_eq!(error_colour(0.05), [59, 86, 165]);
    }

    #[test]
    fn image_axes_are_right_handed() {
        for up in [
            UpAxis::PosX,
            UpAxis::NegX,
            UpAxis::PosY,
            UpAxis::NegY,
            UpAxis::PosZ,
            UpAxis::NegZ,
        ] {
            let ((ri, rs), (ui, us)) = up.image_axes();
            let mut r = nalgebra::Vector3::zeros();
            r[ri] = rs;
            let mut u = nalgebra::Vector3::zeros();
            u[ui] = us;
            let cross = r.cross(&u);
            let expected = match up {
                UpAxis::PosX => nalgebra::Vector3::x(),
                UpAxis::NegX => -nalgebra::Vector3::x(),
                UpAxis::PosY => nalgebra::Vector3::y(),
                UpAxis::NegY => -nalgebra::Vector3::y(),
                UpAxis::PosZ => nalgebra::Vector3::z(),
                UpAxis::NegZ => -nalgebra::Vector3::z(),
            };
            assert_eq!(cross, expected, "{up:?}");
        }
    }
}
