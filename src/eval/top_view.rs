//! The top view of a reconstructed surface coloured by its error (DENSER Fig. 4 style): an
//! orthographic view down the up axis, each pixel coloured by the mean error of its points, empty
//! pixels near filled ones splatted, the sensor's path, axes in metres and a colour bar.
//! [`TopView`] draws it from points streamed in batches, in memory bounded by the image;
//! [`plot_top_view_png`] from slices. This module does not compute errors.

use super::plot::{
    draw_error, ensure_font, error_colour, rgb, save_png, UpAxis, FONT, UNSCORED_GREY,
};
use crate::error::{Error, Result};
use plotters::coord::cartesian::Cartesian2d;
use plotters::coord::types::RangedCoordf64;
use plotters::coord::CoordTranslate;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::ops::Range;
use std::path::{Path, PathBuf};

/// Splat radius (pixels) that closes the gaps between neighbouring points: half the typical point
/// spacing, estimated from the density of filled pixels inside the 8 × 8-pixel cells that hold any
/// point; between 1 and 6.
fn splat_radius_px(
    count: &[u32],
    width: usize,
    px_range: &Range<i32>,
    py_range: &Range<i32>,
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
    rows: &Range<i32>,
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
/// and a colour bar. Points with a `false` in `scored` are grey where no scored point lies.
///
/// `size_px` is the image width (at least 400); the height follows the points' aspect ratio
/// (the map area is kept between 1:4 and 4:1). Errors when the slices differ in length, are
/// empty, hold a non-finite value or negative error, `max_error_m` is not positive, or the file
/// cannot be written. [`TopView`] draws the same picture from points given in batches.
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
    check_top_view_batch(points_m, errors_m, scored)?;
    if points_m.is_empty() {
        return Err(Error::InvalidArgument("top view of zero points".into()));
    }
    let extreme = |f: fn(f64, f64) -> f64| -> [f64; 3] {
        std::array::from_fn(|i| points_m.iter().map(|p| p[i]).reduce(f).unwrap_or(0.0))
    };
    let bounds = (extreme(f64::min), extreme(f64::max));
    let n = points_m.len() as u64;
    let mut view = TopView::new(path, surface, bounds, n, up_axis, max_error_m, size_px)?;
    view.add(points_m, errors_m, scored)?;
    view.finish(trajectory_m)
}

/// Checks one batch of top-view points: one error (and scored flag, if any) per point, all finite,
/// errors non-negative.
fn check_top_view_batch(
    points_m: &[[f64; 3]],
    errors_m: &[f32],
    scored: Option<&[bool]>,
) -> Result<()> {
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
    Ok(())
}

/// The picture of [`plot_top_view_png`] drawn from points given in batches, in memory bounded by
/// the image (about 19 bytes a pixel) whatever their number: [`TopView::new`] lays the chart out
/// from the bounds of all the points to come, [`TopView::add`] bins each batch into per-pixel
/// error sums, [`TopView::finish`] colours the pixels, draws the sensor's path and writes the PNG.
/// The same points in the same order give the same PNG, byte for byte, in any number of batches.
pub struct TopView {
    path: PathBuf,
    size: (u32, u32),
    /// The RGB image, its caption, axes and colour bar drawn.
    buf: Vec<u8>,
    /// Per pixel of the whole image: sum of the scored points' errors, their number, and the
    /// number of points not scored (outside the LiDAR's view; drawn grey).
    sum: Vec<f64>,
    count: Vec<u32>,
    unscored: Vec<u32>,
    px_range: Range<i32>,
    py_range: Range<i32>,
    /// The chart's map from image-plane metres to pixels (its `backend_coord`).
    coord: Cartesian2d<RangedCoordf64, RangedCoordf64>,
    axes: ((usize, f64), (usize, f64)),
    offset: (f64, f64),
    max_error_m: f64,
}

impl TopView {
    /// Lays out and decorates a top view of `point_count` points (the number in the title) lying
    /// within `bounds_m` (world frame, `(min, max)` corners; the exact bounds of the points give
    /// the picture of [`plot_top_view_png`]). Arguments as [`plot_top_view_png`]'s; errors when
    /// there are no points, the bounds are not finite or inverted, or `max_error_m` or `size_px`
    /// is out of range.
    pub fn new(
        path: impl AsRef<Path>,
        surface: &str,
        bounds_m: ([f64; 3], [f64; 3]),
        point_count: u64,
        up_axis: UpAxis,
        max_error_m: f64,
        size_px: u32,
    ) -> Result<TopView> {
        let path = path.as_ref();
        if point_count == 0 {
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
        let (lo, hi) = bounds_m;
        if lo.iter().chain(&hi).any(|v| !v.is_finite()) || (0..3).any(|i| lo[i] > hi[i]) {
            return Err(Error::InvalidArgument(format!(
                "top-view bounds must be finite with min \u{2264} max, got {lo:?} .. {hi:?}"
            )));
        }
        ensure_font()?;

        // Image-plane coordinates (right, up) of the bounds' extremes.
        let ((ri, rs), (ui, us)) = up_axis.image_axes();
        let (r_ends, u_ends) = ([rs * lo[ri], rs * hi[ri]], [us * lo[ui], us * hi[ui]]);
        // Georeferenced coordinates (≥ 10 km) are shown relative to a round offset so that tick
        // labels stay short; the offset is named in the axis title.
        let offset_x = axis_offset(r_ends.into_iter());
        let offset_y = axis_offset(u_ends.into_iter());
        let (x0, x1) = (r_ends[0].min(r_ends[1]), r_ends[0].max(r_ends[1]));
        let (x0, x1) = (x0 - offset_x, x1 - offset_x);
        let (y0, y1) = (u_ends[0].min(u_ends[1]), u_ends[0].max(u_ends[1]));
        let (y0, y1) = (y0 - offset_y, y1 - offset_y);
        let extent_x = (x1 - x0).max(1e-3);
        let extent_y = (y1 - y0).max(1e-3);

        // Layout: the map panel's plotting area gets ~ (width − decorations) pixels across; its
        // height follows the data's aspect ratio.
        let (caption_px, margin_px, x_label_px, y_label_px) = (50u32, 15u32, 55u32, 80u32);
        let plot_w_est = size_px - BAR_PANEL_PX - 2 * margin_px - y_label_px;
        let plot_h_est = ((plot_w_est as f64) * extent_y / extent_x)
            .clamp(plot_w_est as f64 / 4.0, 4.0 * plot_w_est as f64);
        let height = (plot_h_est.round() as u32 + caption_px + 2 * margin_px + x_label_px).max(300);
        let (w, h) = (size_px, height);

        let mut buf = vec![255u8; (w as usize) * (h as usize) * 3];
        let (px_range, py_range, coord);
        {
            let err = draw_error(path);
            let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
            root.fill(&WHITE).map_err(&err)?;
            let body = root
                .margin(8, 0, 0, 0)
                .titled(
                    &format!(
                        "Top view of the {surface} surface: distance to the nearest ground-truth \
                         point ({point_count} points)"
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
            coord = chart.as_coord_spec().clone();
            draw_colour_bar(&root, w - BAR_PANEL_PX + 20, &py_range, max_error_m).map_err(&err)?;
            root.present().map_err(&err)?;
        }
        let pixels = (w as usize) * (h as usize);
        Ok(TopView {
            path: path.to_path_buf(),
            size: (w, h),
            buf,
            sum: vec![0.0; pixels],
            count: vec![0; pixels],
            unscored: vec![0; pixels],
            px_range,
            py_range,
            coord,
            axes: ((ri, rs), (ui, us)),
            offset: (offset_x, offset_y),
            max_error_m,
        })
    }

    /// Bins a batch of points (world frame, metres) with their errors (metres) and, optionally,
    /// whether each was scored. Points outside the map area are left out. Errors (adding nothing)
    /// when the slices differ in length or hold a non-finite value or negative error.
    pub fn add(
        &mut self,
        points_m: &[[f64; 3]],
        errors_m: &[f32],
        scored: Option<&[bool]>,
    ) -> Result<()> {
        check_top_view_batch(points_m, errors_m, scored)?;
        let ((ri, rs), (ui, us)) = self.axes;
        let w = self.size.0 as usize;
        for (i, (p, &e)) in points_m.iter().zip(errors_m).enumerate() {
            let plane = (rs * p[ri] - self.offset.0, us * p[ui] - self.offset.1);
            let (bx, by) = self.coord.translate(&plane);
            if self.px_range.contains(&bx) && self.py_range.contains(&by) {
                let k = by as usize * w + bx as usize;
                if scored.is_none_or(|s| s[i]) {
                    self.sum[k] += e as f64;
                    self.count[k] += 1;
                } else {
                    self.unscored[k] += 1;
                }
            }
        }
        Ok(())
    }

    /// Colours the map, draws `trajectory_m` (the sensor's path, world frame, metres) as a black
    /// line and writes the PNG (complete or absent).
    pub fn finish(mut self, trajectory_m: &[[f64; 3]]) -> Result<()> {
        let ((ri, rs), (ui, us)) = self.axes;
        let (offset_x, offset_y) = self.offset;
        let path_px: Vec<(i32, i32)> = trajectory_m
            .iter()
            .map(|p| (self.coord).translate(&(rs * p[ri] - offset_x, us * p[ui] - offset_y)))
            .collect();
        let (w, h) = self.size;
        let (px_range, py_range) = (self.px_range.clone(), self.py_range.clone());
        let (sum, count, unscored, buf) = (&self.sum, &self.count, &self.unscored, &mut self.buf);

        // Splat: colour each pixel of the plotting area by its own mean error or, when it is
        // empty, by its nearest filled pixel in the (2·radius + 1)² window around it (nearest,
        // not averaged, so that no false intermediate colours appear where the error jumps).
        let radius = splat_radius_px(count, w as usize, &px_range, &py_range);
        let mut offsets: Vec<(i32, i32)> = (-radius..=radius)
            .flat_map(|dy| (-radius..=radius).map(move |dx| (dx, dy)))
            .filter(|&o| o != (0, 0))
            .collect();
        offsets.sort_by_key(|&(dx, dy)| (dx * dx + dy * dy, dy, dx));
        let max_e = self.max_error_m as f32;
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
        save_png(&self.path, buf, (w, h))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic scene: a 60 m × 25 m street patch (KITTI axes) with errors growing along
    /// x, every seventh point unscored, and a trajectory through it.
    type Scene = (Vec<[f64; 3]>, Vec<f32>, Vec<bool>, Vec<[f64; 3]>);
    fn scene(offset: f64) -> Scene {
        let mut seed = 7u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut p, mut e, mut s) = (vec![], vec![], vec![]);
        for i in 0..20_000 {
            let (x, z) = (60.0 * next(), 25.0 * next());
            p.push([offset + x, 1.5 * next(), offset + z]);
            e.push((x / 60.0 * 0.7) as f32);
            s.push(i % 7 != 0);
        }
        let traj = (0..30)
            .map(|k| [offset + 2.0 * k as f64, 0.0, offset + 12.0])
            .collect();
        (p, e, s, traj)
    }

    fn bounds(points: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
        let lo = std::array::from_fn(|i| points.iter().map(|p| p[i]).fold(f64::MAX, f64::min));
        let hi = std::array::from_fn(|i| points.iter().map(|p| p[i]).fold(f64::MIN, f64::max));
        (lo, hi)
    }

    #[test]
    fn batches_give_the_same_png() {
        let dir = tempfile::tempdir().unwrap();
        // A georeferenced scene: the axes show an offset.
        let (p, e, s, t) = scene(250_000.0);
        let whole = dir.path().join("whole.png");
        plot_top_view_png(&whole, "raw", &p, &e, Some(&s), &t, UpAxis::NegY, 0.5, 900).unwrap();
        let n = p.len() as u64;
        let streamed = dir.path().join("streamed.png");
        let mut view =
            TopView::new(&streamed, "raw", bounds(&p), n, UpAxis::NegY, 0.5, 900).unwrap();
        for r in [0..1, 1..1, 1..9000, 9000..p.len()] {
            view.add(&p[r.clone()], &e[r.clone()], Some(&s[r])).unwrap();
        }
        view.finish(&t).unwrap();
        assert!(std::fs::read(&whole).unwrap() == std::fs::read(&streamed).unwrap());
    }

    #[test]
    fn colours_follow_errors_and_flags() {
        // x right, y up: error 0 left of x = 20 m, 2 m (beyond the 0.5 m range) right of it,
        // unscored above y = 15 m on the left, the sensor's path along y = 5 m.
        let (mut p, mut e, mut s) = (vec![], vec![], vec![]);
        for i in 0..160 {
            for j in 0..80 {
                let (x, y) = (0.25 * i as f64, 0.25 * j as f64);
                p.push([x, y, 0.0]);
                e.push(if x < 20.0 { 0.0 } else { 2.0 });
                s.push(!(x < 20.0 && y > 15.0));
            }
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("colours.png");
        let n = p.len() as u64;
        let mut view = TopView::new(&path, "raw", bounds(&p), n, UpAxis::PosZ, 0.5, 800).unwrap();
        // Bad batches are refused and add nothing.
        assert!(view.add(&p[..2], &e[..1], None).is_err());
        assert!(view.add(&p[..2], &[0.1, -1.0], None).is_err());
        assert!(view.add(&[[f64::NAN, 0.0, 0.0]], &[0.1], None).is_err());
        view.add(&p, &e, Some(&s)).unwrap();
        let at = |x: f64, y: f64| view.coord.translate(&(x, y));
        let probes = [
            (at(10.0, 2.0), error_colour(0.0)),
            (at(30.0, 2.0), error_colour(1.0)),
            (at(10.0, 18.0), UNSCORED_GREY),
            (at(25.0, 5.0), [0, 0, 0]),
            (at(30.0, 18.0), error_colour(1.0)),
        ];
        view.finish(&[[0.0, 5.0, 0.0], [40.0, 5.0, 0.0]]).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        for ((x, y), want) in probes {
            assert_eq!(
                img.get_pixel(x as u32, y as u32).0,
                want,
                "pixel ({x}, {y})"
            );
        }
    }

    #[test]
    fn rejects_bad_layouts() {
        let path = Path::new("unused.png");
        let b = ([0.0; 3], [1.0; 3]);
        assert!(TopView::new(path, "raw", b, 0, UpAxis::NegY, 0.5, 800).is_err());
        assert!(TopView::new(path, "raw", b, 1, UpAxis::NegY, 0.0, 800).is_err());
        assert!(TopView::new(path, "raw", b, 1, UpAxis::NegY, 0.5, 399).is_err());
        assert!(TopView::new(path, "raw", (b.1, b.0), 1, UpAxis::NegY, 0.5, 800).is_err());
        let nan = ([f64::NAN; 3], [1.0; 3]);
        assert!(TopView::new(path, "raw", nan, 1, UpAxis::NegY, 0.5, 800).is_err());
        assert!(
            plot_top_view_png(path, "raw", &[], &[], None, &[], UpAxis::NegY, 0.5, 800).is_err()
        );
    }
}
