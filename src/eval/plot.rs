//! Evaluation pictures as PNG (DENSER Fig. 4 style): overlaid error histograms, and a top view of
//! the reconstructed points coloured by error with a colour bar.
//!
//! Drawn with `plotters`' bitmap backend; text uses DejaVu Sans embedded in the binary
//! (`assets/fonts/`, Bitstream Vera licence), so no system font library is needed. PNGs are
//! encoded with the `image` crate. This module does not compute errors.

use crate::error::{Error, Result};
use crate::eval::stats::ErrorStats;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
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

fn rgb(c: [u8; 3]) -> RGBColor {
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

/// Splat radius (pixels) that closes the gaps between neighbouring points: half the typical point
/// spacing, estimated from the density of filled pixels inside the 8 × 8-pixel cells that hold any
/// point; between 1 and 6.
fn splat_radius_px(
    count: &[u32],
    width: usize,
    px_range: &std::ops::Range<i32>,
    py_range: &std::ops::Range<i32>,
) -> i32 {
    const CELL: i32 = 8;
    let cells_x = ((px_range.end - px_range.start + CELL - 1) / CELL).max(1) as usize;
    let cells_y = ((py_range.end - py_range.start + CELL - 1) / CELL).max(1) as usize;
    let mut cell_used = vec![false; cells_x * cells_y];
    let mut filled = 0usize;
    for py in py_range.clone() {
        for px in px_range.clone() {
            if count[py as usize * width + px as usize] > 0 {
                filled += 1;
                let cx = ((px - px_range.start) / CELL) as usize;
                let cy = ((py - py_range.start) / CELL) as usize;
                cell_used[cy * cells_x + cx] = true;
            }
        }
    }
    let footprint = cell_used.iter().filter(|&&u| u).count() * (CELL * CELL) as usize;
    if filled == 0 || footprint == 0 {
        return 1;
    }
    let spacing_px = (footprint as f64 / filled as f64).sqrt();
    ((spacing_px / 2.0 + 0.5).round() as i32).clamp(1, 6)
}

/// Draws a vertical colour bar for errors `0 ..= max_error_m` (bottom to top) with its left edge
/// at pixel column `x0`, spanning the rows `rows` (with room above for its title), tick labels
/// on its right; the top label reads "≥ max" when the maximum is a tick, since colours clamp.
fn draw_colour_bar<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    x0: u32,
    rows: &std::ops::Range<i32>,
    max_error_m: f64,
) -> std::result::Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let (x0, x1) = (x0 as i32, x0 as i32 + 24);
    let (top, bottom) = (rows.start + 30, rows.end - 1);
    if bottom <= top + 10 {
        return Ok(());
    }
    let span = (bottom - top) as f64;
    let row_of = |e: f64| bottom - ((e / max_error_m) * span).round() as i32;
    for y in top..=bottom {
        let t = (bottom - y) as f32 / span as f32;
        root.draw(&Rectangle::new(
            [(x0, y), (x1, y + 1)],
            rgb(error_colour(t)).filled(),
        ))?;
    }
    root.draw(&Rectangle::new(
        [(x0, top), (x1, bottom + 1)],
        BLACK.stroke_width(1),
    ))?;
    let title = TextStyle::from((FONT, 16)).pos(Pos::new(HPos::Left, VPos::Bottom));
    root.draw(&Text::new("error (m)", (x0 - 10, top - 8), title))?;
    // Ticks at a "nice" step giving at most 6 intervals.
    let raw_step = max_error_m / 6.0;
    let magnitude = 10f64.powf(raw_step.log10().floor());
    let step = [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * magnitude)
        .find(|s| *s >= raw_step)
        .unwrap_or(10.0 * magnitude);
    let decimals = (-(step.log10().floor()) as i32 + i32::from((step / magnitude) == 2.5)).max(0);
    let label_style = TextStyle::from((FONT, 14)).pos(Pos::new(HPos::Left, VPos::Center));
    let ticks = (max_error_m / step + 1e-9).floor() as i64;
    for i in 0..=ticks {
        let e = i as f64 * step;
        let y = row_of(e);
        root.draw(&PathElement::new(
            vec![(x1, y), (x1 + 5, y)],
            BLACK.stroke_width(1),
        ))?;
        let mut text = format!("{e:.prec$}", prec = decimals as usize);
        if (e - max_error_m).abs() < 1e-9 * max_error_m.max(1.0) {
            text = format!("\u{2265} {text}");
        }
        root.draw(&Text::new(text, (x1 + 8, y), label_style.clone()))?;
    }
    Ok(())
}

/// A round offset (multiple of 1 km) near the middle of `values` when they lie 10 km or more
/// from zero, else 0.
fn axis_offset(values: impl Iterator<Item = f64>) -> f64 {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    if lo.abs().max(hi.abs()) < 10_000.0 {
        0.0
    } else {
        (0.5 * (lo + hi) / 1000.0).round() * 1000.0
    }
}

/// Width of the colour-bar panel on the right of a top view, pixels.
const BAR_PANEL_PX: u32 = 140;

/// Top view of `points_m` (world frame, metres) coloured by `errors_m` (metres, one per point):
/// an orthographic view looking down `up_axis`, equal scale on both image axes (metres per pixel),
/// each pixel coloured by the mean error of the points falling into it with [`error_colour`]
/// (clamped at `max_error_m`), empty pixels near filled ones (within half the typical point
/// spacing, 1–6 pixels) coloured like their nearest filled pixel (splatting), axes in metres,
/// and a colour bar.
///
/// `size_px` is the image width (at least 400); the height follows the points' aspect ratio
/// (the map area is kept between 1:4 and 4:1). Errors when the slices differ in length, are
/// empty, hold a non-finite value or negative error, `max_error_m` is not positive, or the file
/// cannot be written.
#[allow(clippy::too_many_arguments)]
pub fn plot_top_view_png(
    path: impl AsRef<Path>,
    surface: &str,
    points_m: &[[f64; 3]],
    errors_m: &[f32],
    scored: Option<&[bool]>,
    trajectory_m: &[[f64; 3]],
    up_axis: UpAxis,
    max_error_m: f64,
    size_px: u32,
) -> Result<()> {
    let path = path.as_ref();
    if let Some(s) = scored {
        if s.len() != points_m.len() {
            return Err(Error::InvalidArgument(format!(
                "top view needs one scored flag per point: {} points, {} flags",
                points_m.len(),
                s.len()
            )));
        }
    }
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
    // Georeferenced coordinates (≥ 10 km) are shown relative to a round offset so that tick
    // labels stay short; the offset is named in the axis title.
    let offset_x = axis_offset(points_m.iter().map(|p| rs * p[ri]));
    let offset_y = axis_offset(points_m.iter().map(|p| us * p[ui]));
    let plane: Vec<(f64, f64)> = points_m
        .iter()
        .map(|p| (rs * p[ri] - offset_x, us * p[ui] - offset_y))
        .collect();
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
    // Points not scored (outside the LiDAR's view) per pixel: drawn grey.
    let mut unscored = vec![0u32; (w as usize) * (h as usize)];
    let mut path_px: Vec<(i32, i32)> = Vec::with_capacity(trajectory_m.len());
    let (px_range, py_range);
    {
        let err = draw_error(path);
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(&err)?;
        let body = root
            .margin(8, 0, 0, 0)
            .titled(
                &format!(
                    "Top view of the {surface} surface: distance to the nearest ground-truth \
                     point ({} points)",
                    points_m.len()
                ),
                (FONT, 22),
            )
            .map_err(&err)?;
        let (map_area, _bar_area) = body.split_horizontally(w - BAR_PANEL_PX);
        let axis_name = |(i, s): (usize, f64), offset: f64| {
            let n = ["x", "y", "z"][i];
            let sign = if s < 0.0 { "\u{2212}" } else { "" };
            if offset == 0.0 {
                format!("{sign}{n} (m)")
            } else if offset > 0.0 {
                format!("{sign}{n} \u{2212} {offset:.0} (m)")
            } else {
                format!("{sign}{n} + {:.0} (m)", -offset)
            }
        };
        let decimals = |extent: f64| {
            if extent >= 50.0 {
                0
            } else if extent >= 5.0 {
                1
            } else {
                2
            }
        };
        let (dx, dy) = (decimals(extent_x), decimals(extent_y));
        let fmt_x = move |v: &f64| format!("{v:.dx$}");
        let fmt_y = move |v: &f64| format!("{v:.dy$}");
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
            .x_desc(axis_name(up_axis.image_axes().0, offset_x))
            .y_desc(axis_name(up_axis.image_axes().1, offset_y))
            .x_label_formatter(&fmt_x)
            .y_label_formatter(&fmt_y)
            .axis_desc_style((FONT, 18))
            .label_style((FONT, 15))
            .draw()
            .map_err(&err)?;
        (px_range, py_range) = chart.plotting_area().get_pixel_range();
        for (i, (&(x, y), &e)) in plane.iter().zip(errors_m).enumerate() {
            let (bx, by) = chart.backend_coord(&(x, y));
            if px_range.contains(&bx) && py_range.contains(&by) {
                let k = by as usize * w as usize + bx as usize;
                if scored.is_none_or(|s| s[i]) {
                    sum[k] += e as f64;
                    count[k] += 1;
                } else {
                    unscored[k] += 1;
                }
            }
        }
        path_px.extend(
            trajectory_m
                .iter()
                .map(|p| chart.backend_coord(&(rs * p[ri] - offset_x, us * p[ui] - offset_y))),
        );

        draw_colour_bar(&root, w - BAR_PANEL_PX + 20, &py_range, max_error_m).map_err(&err)?;
        root.present().map_err(&err)?;
    }

    // Splat: colour each pixel of the plotting area by its own mean error or, when it is empty,
    // by its nearest filled pixel in the (2·radius + 1)² window around it (nearest, not averaged, so that no false
    // intermediate colours appear where the error jumps).
    let radius = splat_radius_px(&count, w as usize, &px_range, &py_range);
    let mut offsets: Vec<(i32, i32)> = (-radius..=radius)
        .flat_map(|dy| (-radius..=radius).map(move |dx| (dx, dy)))
        .filter(|&o| o != (0, 0))
        .collect();
    offsets.sort_by_key(|&(dx, dy)| (dx * dx + dy * dy, dy, dx));
    let max_e = max_error_m as f32;
    // A pixel's colour: its scored points' mean error, else grey when it holds only unscored
    // points; empty pixels take their nearest non-empty neighbour's.
    let colour_at = |k: usize| {
        if count[k] > 0 {
            Some(error_colour((sum[k] / count[k] as f64) as f32 / max_e))
        } else if unscored[k] > 0 {
            Some(UNSCORED_GREY)
        } else {
            None
        }
    };
    for py in py_range.clone() {
        for px in px_range.clone() {
            let k = py as usize * w as usize + px as usize;
            let c = colour_at(k).or_else(|| {
                offsets.iter().find_map(|&(dx, dy)| {
                    let (qx, qy) = (px + dx, py + dy);
                    (px_range.contains(&qx) && py_range.contains(&qy))
                        .then(|| colour_at(qy as usize * w as usize + qx as usize))
                        .flatten()
                })
            });
            if let Some(c) = c {
                buf[3 * k..3 * k + 3].copy_from_slice(&c);
            }
        }
    }
    // The sensor's path: a black line 3 px wide.
    for seg in path_px.windows(2) {
        let ((x0, y0), (x1, y1)) = (seg[0], seg[1]);
        let steps = (x1 - x0).abs().max((y1 - y0).abs()).max(1);
        for s in 0..=steps {
            let x = x0 + (x1 - x0) * s / steps;
            let y = y0 + (y1 - y0) * s / steps;
            for (dx, dy) in [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)] {
                let (qx, qy) = (x + dx, y + dy);
                if px_range.contains(&qx) && py_range.contains(&qy) {
                    let k = qy as usize * w as usize + qx as usize;
                    buf[3 * k..3 * k + 3].copy_from_slice(&[0, 0, 0]);
                }
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
