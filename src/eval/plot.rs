//! Evaluation pictures as PNG (DENSER Fig. 4 style): overlaid error histograms, and a top view of
//! the reconstructed points coloured by error with a colour bar.
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
const FONT: &str = "sans-serif";

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
fn ensure_font() -> Result<()> {
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
fn draw_error<E: std::fmt::Display>(path: &Path) -> impl Fn(E) -> Error + '_ {
    move |e| {
        Error::io(
            path,
            std::io::Error::other(format!("drawing the chart failed: {e}")),
        )
    }
}

/// Encodes an RGB buffer as PNG at `path`.
fn save_png(path: &Path, rgb: &[u8], (w, h): (u32, u32)) -> Result<()> {
    image::save_buffer_with_format(
        path,
        rgb,
        w,
        h,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(|e| match e {
        image::ImageError::IoError(io) => Error::io(path, io),
        other => Error::io(path, std::io::Error::other(other.to_string())),
    })
}

fn rgb(c: [u8; 3]) -> RGBColor {
    RGBColor(c[0], c[1], c[2])
}

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
            let legend = format!(
                "{label}: median {:.3} m, p75 {:.3} m ({} points)",
                stats.median_m, stats.p75_m, stats.count
            );
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

/// Width of the colour-bar panel on the right of a top view, pixels.
const BAR_PANEL_PX: u32 = 140;

/// Top view of `points_m` (world frame, metres) coloured by `errors_m` (metres, one per point):
/// an orthographic view looking down `up_axis`, equal scale on both image axes (metres per pixel),
/// each pixel coloured by the mean error of the points falling into it with [`error_colour`]
/// (clamped at `max_error_m`), empty pixels within `max(1, size_px / 800)` pixels of filled ones
/// filled from their neighbours (splatting), axes in metres, and a colour bar.
///
/// `size_px` is the image width (at least 400); the height follows the points' aspect ratio
/// (the map area is kept between 1:4 and 4:1). Errors when the slices differ in length, are
/// empty, hold a non-finite value or negative error, `max_error_m` is not positive, or the file
/// cannot be written.
pub fn plot_top_view_png(
    path: impl AsRef<Path>,
    points_m: &[[f64; 3]],
    errors_m: &[f32],
    up_axis: UpAxis,
    max_error_m: f64,
    size_px: u32,
) -> Result<()> {
    let path = path.as_ref();
    if points_m.len() != errors_m.len() {
        return Err(Error::InvalidArgument(format!(
            "top view needs one error per point: {} points, {} errors",
            points_m.len(),
            errors_m.len()
        )));
    }
    if points_m.is_empty() {
        return Err(Error::InvalidArgument("top view of zero points".into()));
    }
    if !(max_error_m.is_finite() && max_error_m > 0.0) {
        return Err(Error::InvalidArgument(format!(
            "top-view colour range must be a positive number of metres, got {max_error_m}"
        )));
    }
    if !(400..=20_000).contains(&size_px) {
        return Err(Error::InvalidArgument(format!(
            "top-view width must be 400..=20000 pixels, got {size_px}"
        )));
    }
    if let Some(i) = points_m
        .iter()
        .position(|p| p.iter().any(|v| !v.is_finite()))
    {
        return Err(Error::InvalidArgument(format!(
            "top-view point {i} is not finite"
        )));
    }
    if let Some(i) = errors_m.iter().position(|e| !(e.is_finite() && *e >= 0.0)) {
        return Err(Error::InvalidArgument(format!(
            "top-view error {i} is {}; errors must be finite and non-negative",
            errors_m[i]
        )));
    }
    ensure_font()?;

    // Image-plane coordinates (right, up) of every point, and their extent.
    let ((ri, rs), (ui, us)) = up_axis.image_axes();
    let plane: Vec<(f64, f64)> = points_m.iter().map(|p| (rs * p[ri], us * p[ui])).collect();
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y) in &plane {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    let extent_x = (x1 - x0).max(1e-3);
    let extent_y = (y1 - y0).max(1e-3);

    // Layout: the map panel's plotting area gets ~ (width − decorations) pixels across; its height
    // follows the data's aspect ratio.
    let (caption_px, margin_px, x_label_px, y_label_px) = (50u32, 15u32, 55u32, 80u32);
    let plot_w_est = size_px - BAR_PANEL_PX - 2 * margin_px - y_label_px;
    let plot_h_est = ((plot_w_est as f64) * extent_y / extent_x)
        .clamp(plot_w_est as f64 / 4.0, 4.0 * plot_w_est as f64);
    let height = (plot_h_est.round() as u32 + caption_px + 2 * margin_px + x_label_px).max(300);
    let (w, h) = (size_px, height);

    let mut buf = vec![255u8; (w as usize) * (h as usize) * 3];
    // Per-pixel sum of errors and count, over the whole image (backend coordinates).
    let mut sum = vec![0.0f64; (w as usize) * (h as usize)];
    let mut count = vec![0u32; (w as usize) * (h as usize)];
    let (px_range, py_range);
    {
        let err = draw_error(path);
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(&err)?;
        let body = root
            .titled(
                &format!(
                    "Top view: distance to the nearest ground-truth point ({} points)",
                    points_m.len()
                ),
                (FONT, 22),
            )
            .map_err(&err)?;
        let (map_area, bar_area) = body.split_horizontally(w - BAR_PANEL_PX);
        let axis_name = |(i, s): (usize, f64)| {
            let n = ["x", "y", "z"][i];
            if s < 0.0 {
                format!("\u{2212}{n} (m)")
            } else {
                format!("{n} (m)")
            }
        };
        // Measure the plotting area, then choose ranges with equal metres per pixel.
        let (pw, ph) = ChartBuilder::on(&map_area)
            .margin(margin_px)
            .x_label_area_size(x_label_px)
            .y_label_area_size(y_label_px)
            .build_cartesian_2d(0f64..1f64, 0f64..1f64)
            .map_err(&err)?
            .plotting_area()
            .dim_in_pixel();
        let m_per_px = (extent_x / pw.max(1) as f64).max(extent_y / ph.max(1) as f64) * 1.02;
        let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
        let half_x = 0.5 * m_per_px * pw as f64;
        let half_y = 0.5 * m_per_px * ph as f64;
        let mut chart = ChartBuilder::on(&map_area)
            .margin(margin_px)
            .x_label_area_size(x_label_px)
            .y_label_area_size(y_label_px)
            .build_cartesian_2d((cx - half_x)..(cx + half_x), (cy - half_y)..(cy + half_y))
            .map_err(&err)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(axis_name(up_axis.image_axes().0))
            .y_desc(axis_name(up_axis.image_axes().1))
            .axis_desc_style((FONT, 18))
            .label_style((FONT, 15))
            .draw()
            .map_err(&err)?;
        (px_range, py_range) = chart.plotting_area().get_pixel_range();
        for (&(x, y), &e) in plane.iter().zip(errors_m) {
            let (bx, by) = chart.backend_coord(&(x, y));
            if px_range.contains(&bx) && py_range.contains(&by) {
                let k = by as usize * w as usize + bx as usize;
                sum[k] += e as f64;
                count[k] += 1;
            }
        }

        // Colour bar: 0 .. max_error_m, bottom to top.
        let mut bar = ChartBuilder::on(&bar_area)
            .margin_top(margin_px + 10)
            .margin_bottom(margin_px + x_label_px)
            .margin_right(55)
            .y_label_area_size(65)
            .build_cartesian_2d(0f64..1f64, 0f64..max_error_m)
            .map_err(&err)?;
        bar.configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_desc("error (m)")
            .axis_desc_style((FONT, 18))
            .label_style((FONT, 15))
            .draw()
            .map_err(&err)?;
        let steps = 256;
        bar.draw_series((0..steps).map(|i| {
            let lo = max_error_m * i as f64 / steps as f64;
            let hi = max_error_m * (i + 1) as f64 / steps as f64;
            let c = error_colour((i as f32 + 0.5) / steps as f32);
            Rectangle::new([(0.0, lo), (1.0, hi)], rgb(c).filled())
        }))
        .map_err(&err)?;
        root.present().map_err(&err)?;
    }

    // Splat: colour each pixel of the plotting area by its own mean error, or by the mean of its
    // filled neighbours within `radius` pixels when it is empty.
    let radius = (size_px / 800).max(1) as i32;
    let max_e = max_error_m as f32;
    for py in py_range.clone() {
        for px in px_range.clone() {
            let k = py as usize * w as usize + px as usize;
            let mean = if count[k] > 0 {
                Some(sum[k] / count[k] as f64)
            } else {
                let (mut s, mut n) = (0.0f64, 0u32);
                for dy in -radius..=radius {
                    for dx in -radius..=radius {
                        let (qx, qy) = (px + dx, py + dy);
                        if px_range.contains(&qx) && py_range.contains(&qy) {
                            let q = qy as usize * w as usize + qx as usize;
                            if count[q] > 0 {
                                s += sum[q] / count[q] as f64;
                                n += 1;
                            }
                        }
                    }
                }
                (n > 0).then(|| s / n as f64)
            };
            if let Some(mean) = mean {
                let c = error_colour(mean as f32 / max_e);
                buf[3 * k..3 * k + 3].copy_from_slice(&c);
            }
        }
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
