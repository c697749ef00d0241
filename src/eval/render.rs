//! Pictures of a mesh for the report: the surface in its own colours (or by height, when it has
//! none), shaded by a light from
//! above the viewer, seen straight down and from an oblique viewpoint (35° above the horizon,
//! from the south-west of the image), by a small z-buffer rasterizer (no GPU, no window).
//! Orthographic: equal metres per pixel across the picture, so lengths compare.

use super::plot::{draw_error, ensure_font, save_png, UpAxis, FONT};
use crate::error::{Error, Result};
use crate::mesh::Mesh;
use nalgebra::Vector3;
use plotters::prelude::*;
use std::path::Path;

/// Where a picture looks from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshView {
    /// Straight down the up axis (north up the image, as the top views of the errors).
    Top,
    /// From 35° above the horizon, looking diagonally across the map.
    Oblique,
}

/// How the surface is coloured.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshColour {
    /// The mesh's own vertex colours.
    Own,
    /// Height above the lowest part, blue (low) → red (high), for meshes without colour.
    Height,
}

impl MeshColour {
    /// [`MeshColour::Height`] for a mesh whose colours are all grey (LiDAR reflectance, grey
    /// cameras), else its own.
    pub fn for_mesh(mesh: &Mesh) -> MeshColour {
        let grey = mesh
            .colors
            .iter()
            .filter(|c| MeshColour::is_grey(c))
            .count();
        MeshColour::for_counts(grey as u64, mesh.colors.len() as u64)
    }

    /// Whether a colour is grey (its three channels equal).
    pub fn is_grey(c: &[u8; 3]) -> bool {
        c[0] == c[1] && c[1] == c[2]
    }

    /// [`MeshColour::for_mesh`] from counts: `grey` of `total` vertices grey.
    pub fn for_counts(grey: u64, total: u64) -> MeshColour {
        if grey as f64 >= 0.99 * total as f64 {
            MeshColour::Height
        } else {
            MeshColour::Own
        }
    }
}

/// Background of the pictures.
const BACKGROUND: [u8; 3] = [255, 255, 255];

/// Renders `mesh` seen from `view` (with `up` the world's up axis) into a PNG at `path`,
/// `width_px` wide (the height follows the extent of the middle 99 % of the vertices on each
/// axis, between a quarter and the width; what lies beyond is cut off), with
/// `title` written in its top-left corner. Errors on an empty mesh or a file that cannot be
/// written.
pub fn render_mesh_png(
    path: impl AsRef<Path>,
    mesh: &Mesh,
    up: UpAxis,
    view: MeshView,
    colour_by: MeshColour,
    width_px: u32,
    title: &str,
) -> Result<()> {
    let path = path.as_ref();
    if mesh.triangles.is_empty() {
        return Err(Error::InvalidArgument(format!(
            "{}: a picture of a mesh without triangles",
            path.display()
        )));
    }
    let vertices: Vec<[f64; 3]> = mesh
        .positions_m
        .iter()
        .map(|q| q.map(|v| v as f64))
        .collect();
    let mut picture = MeshPicture::new(&vertices, up, view, colour_by, width_px);
    drop(vertices);
    let p = |k: u32| mesh.positions_m[k as usize].map(|v| v as f64);
    for t in &mesh.triangles {
        let c = t.map(|k| mesh.colors.get(k as usize).copied().unwrap_or([180; 3]));
        picture.add_triangle([p(t[0]), p(t[1]), p(t[2])], c);
    }
    picture.finish(path, title)
}

/// A picture of a mesh being drawn triangle by triangle ([`render_mesh_png`] for a mesh in
/// memory; a mesh streamed from a file gives its triangles one at a time): the framing is
/// fixed up front from the vertices (all, or an even sample of them), then each triangle is
/// rasterized into the z-buffer.
pub struct MeshPicture {
    colour_by: MeshColour,
    right: Vector3<f64>,
    up_img: Vector3<f64>,
    look: Vector3<f64>,
    up_v: Vector3<f64>,
    light: Vector3<f64>,
    h_lo: f64,
    h_hi: f64,
    w: u32,
    h: u32,
    band: f64,
    content: f64,
    scale: f64,
    cx: f64,
    cy: f64,
    rgb: Vec<u8>,
    depth: Vec<f64>,
}

impl MeshPicture {
    /// A blank picture framed on `vertices` (all of the mesh's, or an even sample; not empty).
    pub fn new(
        vertices: &[[f64; 3]],
        up: UpAxis,
        view: MeshView,
        colour_by: MeshColour,
        width_px: u32,
    ) -> MeshPicture {
        // Image axes: the up axis's right/forward pair (as the top views of the errors).
        let ((ri, rs), (fi, fs)) = up.image_axes();
        let axis = |i: usize, s: f64| {
            let mut v = Vector3::zeros();
            v[i] = s;
            v
        };
        let (right0, forward0) = (axis(ri, rs), axis(fi, fs));
        let up_v = right0.cross(&forward0);
        let (right, up_img, look) = match view {
            MeshView::Top => (right0, forward0, -up_v),
            MeshView::Oblique => {
                let horizontal = (forward0 + right0).normalize();
                let el = 35f64.to_radians();
                let look = (horizontal * el.cos() - up_v * el.sin()).normalize();
                let right = look.cross(&up_v).normalize();
                (right, right.cross(&look), look)
            }
        };
        // Light from above and behind the viewer.
        let light = (-look + up_v).normalize();
        let v3 = |q: &[f64; 3]| Vector3::new(q[0], q[1], q[2]);
        // Height range for colouring by height: 1st to 99th percentile of the vertices.
        let (h_lo, h_hi) = {
            let mut hs: Vec<f64> = vertices.iter().map(|q| v3(q).dot(&up_v)).collect();
            let n = hs.len().saturating_sub(1);
            let lo = *hs.select_nth_unstable_by(n / 100, f64::total_cmp).1;
            let hi = *hs.select_nth_unstable_by(n - n / 100, f64::total_cmp).1;
            (lo, hi.max(lo + 1e-6))
        };
        // Framing: the middle 99 % of the vertices on each image axis (a few stray triangles far
        // away do not shrink the city to a dot).
        let (mut lo, mut hi) = ([0.0; 2], [0.0; 2]);
        for (a, dir) in [right, up_img].iter().enumerate() {
            let mut c: Vec<f64> = vertices.iter().map(|q| v3(q).dot(dir)).collect();
            let n = c.len() - 1;
            let (k0, k1) = (
                (n as f64 * 0.005) as usize,
                (n as f64 * 0.995).ceil() as usize,
            );
            lo[a] = *c.select_nth_unstable_by(k0, f64::total_cmp).1;
            hi[a] = *c.select_nth_unstable_by(k1.min(n), f64::total_cmp).1;
        }
        let margin = 10.0;
        let w = width_px.max(200);
        let span = [(hi[0] - lo[0]).max(1e-6), (hi[1] - lo[1]).max(1e-6)];
        // A band at the top for the title.
        let band = 40.0;
        let content = ((w as f64 - 2.0 * margin) * span[1] / span[0] + 2.0 * margin)
            .clamp(w as f64 / 4.0, w as f64);
        let h = (content + band) as u32;
        let scale = ((w as f64 - 2.0 * margin) / span[0]).min((content - 2.0 * margin) / span[1]);
        let (cx, cy) = ((lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0);
        let mut rgb = vec![0u8; (w * h * 3) as usize];
        for px in rgb.chunks_exact_mut(3) {
            px.copy_from_slice(&BACKGROUND);
        }
        MeshPicture {
            colour_by,
            right,
            up_img,
            look,
            up_v,
            light,
            h_lo,
            h_hi,
            w,
            h,
            band,
            content,
            scale,
            cx,
            cy,
            rgb,
            depth: vec![f64::INFINITY; (w * h) as usize],
        }
    }

    fn to_px(&self, v: &Vector3<f64>) -> (f64, f64, f64) {
        (
            self.w as f64 / 2.0 + (v.dot(&self.right) - self.cx) * self.scale,
            self.band + self.content / 2.0 - (v.dot(&self.up_img) - self.cy) * self.scale,
            v.dot(&self.look),
        )
    }

    /// Draws one triangle (corners in the world frame, metres, and their colours).
    pub fn add_triangle(&mut self, corners: [[f64; 3]; 3], colours: [[u8; 3]; 3]) {
        let v = corners.map(|q| Vector3::new(q[0], q[1], q[2]));
        let n = (v[1] - v[0]).cross(&(v[2] - v[0]));
        let Some(n) = n.try_normalize(1e-12) else {
            return;
        };
        // Two-sided Lambert shading with some ambient light.
        let shade = 0.3 + 0.7 * n.dot(&self.light).abs();
        let colour = {
            let c = match self.colour_by {
                MeshColour::Own => colours,
                MeshColour::Height => {
                    let h = (v[0] + v[1] + v[2]).dot(&self.up_v) / 3.0;
                    let t = ((h - self.h_lo) / (self.h_hi - self.h_lo)) as f32;
                    [super::error_colour(t); 3]
                }
            };
            let mean = |i: usize| (c[0][i] as f64 + c[1][i] as f64 + c[2][i] as f64) / 3.0;
            [0, 1, 2].map(|i| (mean(i) * shade).round().clamp(0.0, 255.0) as u8)
        };
        let s = v.map(|q| self.to_px(&q));
        let area = (s[1].0 - s[0].0) * (s[2].1 - s[0].1) - (s[2].0 - s[0].0) * (s[1].1 - s[0].1);
        if area.abs() < 1e-12 {
            return;
        }
        let (w, h) = (self.w, self.h);
        let (xs, ys) = (s.map(|q| q.0), s.map(|q| q.1));
        let lo = |v: [f64; 3]| v.iter().copied().fold(f64::INFINITY, f64::min).floor();
        let hi = |v: [f64; 3]| v.iter().copied().fold(f64::NEG_INFINITY, f64::max).ceil();
        let (x0, x1) = (lo(xs).max(0.0) as i64, (hi(xs) as i64).min(w as i64 - 1));
        let (y0, y1) = (
            lo(ys).max(self.band) as i64,
            (hi(ys) as i64).min(h as i64 - 1),
        );
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (fx, fy) = (x as f64 + 0.5, y as f64 + 0.5);
                // Barycentric coordinates from the signed edge functions.
                let edge = |a: (f64, f64, f64), b: (f64, f64, f64)| {
                    ((b.0 - a.0) * (fy - a.1) - (b.1 - a.1) * (fx - a.0)) / area
                };
                let (b0, b1, b2) = (edge(s[1], s[2]), edge(s[2], s[0]), edge(s[0], s[1]));
                if b0 < 0.0 || b1 < 0.0 || b2 < 0.0 {
                    continue;
                }
                let z = b0 * s[0].2 + b1 * s[1].2 + b2 * s[2].2;
                let k = (y as u32 * w + x as u32) as usize;
                if z < self.depth[k] {
                    self.depth[k] = z;
                    self.rgb[3 * k..3 * k + 3].copy_from_slice(&colour);
                }
            }
        }
    }

    /// Writes the title and the PNG at `path`.
    pub fn finish(mut self, path: &Path, title: &str) -> Result<()> {
        ensure_font()?;
        let (w, h) = (self.w, self.h);
        {
            let root = BitMapBackend::with_buffer(&mut self.rgb, (w, h)).into_drawing_area();
            root.draw(&Text::new(
                title.to_string(),
                (12, 8),
                TextStyle::from((FONT, 22)).color(&BLACK),
            ))
            .map_err(draw_error(path))?;
            root.present().map_err(draw_error(path))?;
        }
        save_png(path, &self.rgb, (w, h))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A red unit square in the plane y = 0 and a green one 1 m above it (y = −1, KITTI's up
    /// being −y), offset in x: seen from the top, both show; the upper one hides what is under it.
    #[test]
    fn the_top_view_shows_the_upper_surface_where_two_overlap() {
        let mut mesh = Mesh::default();
        let square = |mesh: &mut Mesh, x0: f32, y: f32, c: [u8; 3]| {
            let base = mesh.positions_m.len() as u32;
            for (x, z) in [(x0, 0.0), (x0 + 1.0, 0.0), (x0, 1.0), (x0 + 1.0, 1.0)] {
                mesh.positions_m.push([x, y, z]);
                mesh.colors.push(c);
            }
            mesh.triangles.push([base, base + 1, base + 2]);
            mesh.triangles.push([base + 1, base + 3, base + 2]);
        };
        square(&mut mesh, 0.0, 0.0, [200, 0, 0]);
        square(&mut mesh, 0.5, -1.0, [0, 200, 0]);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("top.png");
        render_mesh_png(
            &path,
            &mesh,
            UpAxis::NegY,
            MeshView::Top,
            MeshColour::Own,
            300,
            "",
        )
        .unwrap();
        let img = crate::io::image::read_rgb(&path).unwrap();
        let at = |x: u32, y: u32| img.data[(y * img.width + x) as usize];
        let row = img.height / 2;
        // x spans 0..1.5 m across the picture: the left quarter is the red square alone, the
        // right part the green one, above the red where they overlap (shaded, so by hue).
        let left = at(img.width / 8, row);
        let middle = at(img.width / 2, row);
        assert!(left[0] > 100 && left[1] == 0, "{left:?}");
        assert!(middle[1] > 100 && middle[0] == 0, "{middle:?}");
        assert_eq!(MeshColour::for_mesh(&mesh), MeshColour::Own);
        // By height: the lower (red) square turns blue, the upper (green) one red.
        let top = MeshView::Top;
        render_mesh_png(&path, &mesh, UpAxis::NegY, top, MeshColour::Height, 300, "").unwrap();
        let img = crate::io::image::read_rgb(&path).unwrap();
        let at = |x: u32, y: u32| img.data[(y * img.width + x) as usize];
        let (low, high) = (at(img.width / 8, row), at(img.width / 2, row));
        assert!(low[2] > low[0] && high[0] > high[2], "{low:?} {high:?}");
        let oblique = MeshView::Oblique;
        render_mesh_png(
            &path,
            &mesh,
            UpAxis::NegY,
            oblique,
            MeshColour::Own,
            300,
            "o",
        )
        .unwrap();
        let empty = Mesh::default();
        assert!(
            render_mesh_png(&path, &empty, UpAxis::NegY, top, MeshColour::Own, 300, "").is_err()
        );
    }
}
