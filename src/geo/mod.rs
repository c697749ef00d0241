//! World frames for exports: where the map's coordinates go when they leave `denser`.
//!
//! The map frame is the KITTI cam0 frame of the first pose (x right, y **down**, z forward), so a
//! city exported as is lies on its side in GIS tools. Exports instead use a **world frame**:
//!
//! * the **local z-up frame** (always): `x = z_map` (forward), `y = −x_map` (left),
//!   `z = −y_map` (up), metres; right-handed, a pure rotation ([`LOCAL_FROM_MAP`]);
//! * optionally a **georeference** (`--georef`): a rigid `world_from_map` transform into a
//!   coordinate reference system, given as a 4×4 matrix or as the map origin's coordinates in an
//!   EPSG CRS plus the compass heading of the map's forward axis ([`WorldFrame::parse`]).
//!
//! `formats/georef.md` specifies the `--georef` syntax and the frames. What it does not do:
//! reproject between CRSs, model the UTM scale factor (map metres are taken as grid metres), or
//! know CRSs beyond those [`wkt`] can describe (WGS 84 / UTM, ETRS89 / UTM, WGS 84 geocentric).

pub mod utm;
pub mod wkt;

use crate::error::{Error, Result};
use nalgebra::{Matrix3, Matrix4, Vector3};
use std::path::Path;

/// Rotation from the map frame (x right, y down, z forward) to the local z-up frame (x forward,
/// y left, z up), row-major.
pub const LOCAL_FROM_MAP: [[f64; 3]; 3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]];

/// A coordinate reference system known by EPSG code, with its OGC WKT (version 1) text.
#[derive(Clone, Debug, PartialEq)]
pub struct Crs {
    /// EPSG code.
    pub epsg: u32,
    /// OGC WKT 1 (as LAS 1.4 requires), from [`wkt::wkt_for_epsg`].
    pub wkt: String,
}

/// Where exported coordinates go: `world = world_from_map · map` (rigid), and the CRS of the
/// world coordinates when known.
#[derive(Clone, Debug, PartialEq)]
pub struct WorldFrame {
    /// Map frame → world, a rigid 4×4 transform (last row 0 0 0 1), metres.
    pub world_from_map: Matrix4<f64>,
    /// CRS of the world coordinates (`None`: a local frame).
    pub crs: Option<Crs>,
}

fn local_from_map3() -> Matrix3<f64> {
    let r = LOCAL_FROM_MAP;
    Matrix3::new(
        r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2],
    )
}

fn homogeneous(r: Matrix3<f64>, t: Vector3<f64>) -> Matrix4<f64> {
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    m.fixed_view_mut::<3, 1>(0, 3).copy_from(&t);
    m
}

impl WorldFrame {
    /// The map frame itself (identity; what PLY exports keep by default).
    pub fn map() -> Self {
        WorldFrame {
            world_from_map: Matrix4::identity(),
            crs: None,
        }
    }

    /// The local z-up frame with no georeference ([`LOCAL_FROM_MAP`]).
    pub fn local_z_up() -> Self {
        WorldFrame {
            world_from_map: homogeneous(local_from_map3(), Vector3::zeros()),
            crs: None,
        }
    }

    /// The map origin at `origin` (CRS coordinates: easting, northing, height for a projected
    /// CRS; ECEF x, y, z for EPSG:4978) with the map's forward axis at compass `heading_deg`
    /// (clockwise from grid north; 90 = east, which is the local z-up frame's x axis).
    pub fn from_origin(crs: Option<Crs>, origin: [f64; 3], heading_deg: f64) -> Self {
        let theta = (90.0 - heading_deg).to_radians();
        let rz = Matrix3::new(
            theta.cos(),
            -theta.sin(),
            0.0,
            theta.sin(),
            theta.cos(),
            0.0,
            0.0,
            0.0,
            1.0,
        );
        WorldFrame {
            world_from_map: homogeneous(rz * local_from_map3(), Vector3::from(origin)),
            crs,
        }
    }

    /// Parses a `--georef` value (see `formats/georef.md`):
    /// * `EPSG:<code>@<x>,<y>,<z>[,<heading_deg>]`: the map origin's coordinates in that CRS and
    ///   the compass heading of the map's forward axis (default 90, east);
    /// * a path to a text file with 16 (or 12) numbers, the row-major 4×4 (or 3×4)
    ///   `world_from_map` matrix, optionally with an `EPSG:<code>` token; `#` starts a comment.
    pub fn parse(spec: &str) -> Result<Self> {
        let bad = |m: String| Error::InvalidArgument(format!("--georef {spec:?}: {m}"));
        if let Some(rest) = spec
            .strip_prefix("EPSG:")
            .or_else(|| spec.strip_prefix("epsg:"))
        {
            let (code, origin) = rest
                .split_once('@')
                .ok_or_else(|| bad("expected EPSG:<code>@<x>,<y>,<z>[,<heading_deg>]".into()))?;
            let crs = crs_for(code).map_err(bad)?;
            let v: Vec<f64> = origin
                .split(',')
                .map(|t| t.trim().parse::<f64>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|e| bad(format!("origin {origin:?}: {e}")))?;
            if !(3..=4).contains(&v.len()) || v.iter().any(|x| !x.is_finite()) {
                return Err(bad(format!(
                    "origin {origin:?}: expected 3 coordinates and an optional heading"
                )));
            }
            let heading_deg = v.get(3).copied().unwrap_or(90.0);
            if !(-360.0..=360.0).contains(&heading_deg) {
                return Err(bad(format!(
                    "heading {heading_deg}°: expected a compass heading in [-360, 360] degrees"
                )));
            }
            let origin = [v[0], v[1], v[2]];
            check_area(&crs, origin).map_err(bad)?;
            return Ok(Self::from_origin(Some(crs), origin, heading_deg));
        }
        let path = Path::new(spec);
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::parse_matrix_text(&text).map_err(|m| Error::bad_input(path, m))
    }

    /// Parses the matrix-file form of `--georef` held in memory (errors without a file name).
    pub fn parse_matrix_text(text: &str) -> std::result::Result<Self, String> {
        let mut nums = Vec::new();
        let mut crs = None;
        for line in text.lines() {
            let line = line.split('#').next().unwrap_or("");
            for tok in line.split(|c: char| c.is_whitespace() || c == ',') {
                if tok.is_empty() {
                    continue;
                }
                if let Some(code) = tok
                    .strip_prefix("EPSG:")
                    .or_else(|| tok.strip_prefix("epsg:"))
                {
                    crs = Some(crs_for(code)?);
                } else {
                    nums.push(
                        tok.parse::<f64>()
                            .map_err(|_| format!("{tok:?} is neither a number nor EPSG:<code>"))?,
                    );
                }
            }
        }
        if nums.len() != 16 && nums.len() != 12 {
            return Err(format!(
                "expected the 16 (or 12) numbers of a row-major world_from_map matrix, found {}",
                nums.len()
            ));
        }
        if nums.len() == 16 && nums[12..] != [0.0, 0.0, 0.0, 1.0] {
            return Err(format!(
                "the last matrix row must be 0 0 0 1, found {:?}",
                &nums[12..]
            ));
        }
        let mut m = Matrix4::identity();
        for r in 0..3 {
            for c in 0..4 {
                m[(r, c)] = nums[4 * r + c];
            }
        }
        if nums.iter().any(|x| !x.is_finite()) {
            return Err("non-finite matrix entry".into());
        }
        let rot = m.fixed_view::<3, 3>(0, 0).into_owned();
        let err = (rot.transpose() * rot - Matrix3::identity()).abs().max();
        if err > 1e-6 || rot.determinant() < 0.0 {
            return Err(format!(
                "the 3×3 part is not a rotation (|RᵀR − I| = {err:.2e}, det = {:.6}); \
                 world_from_map must be rigid and keep handedness",
                rot.determinant()
            ));
        }
        if let Some(crs) = &crs {
            check_area(crs, [m[(0, 3)], m[(1, 3)], m[(2, 3)]])
                .map_err(|e| format!("the matrix's translation (the map origin): {e}"))?;
        }
        Ok(WorldFrame {
            world_from_map: m,
            crs,
        })
    }

    /// World coordinates of a map-frame point.
    pub fn to_world(&self, p_map: [f64; 3]) -> [f64; 3] {
        let m = &self.world_from_map;
        [0, 1, 2]
            .map(|r| m[(r, 0)] * p_map[0] + m[(r, 1)] * p_map[1] + m[(r, 2)] * p_map[2] + m[(r, 3)])
    }

    /// Local z-up frame → world ( = `world_from_map · LOCAL_FROM_MAPᵀ`).
    pub fn world_from_local(&self) -> Matrix4<f64> {
        self.world_from_map * homogeneous(local_from_map3().transpose(), Vector3::zeros())
    }

    /// Whether this is the identity (the map frame).
    pub fn is_map_frame(&self) -> bool {
        self.world_from_map == Matrix4::identity() && self.crs.is_none()
    }

    /// Local z-up frame → ECEF (EPSG:4978), for viewers on a globe: direct for a geocentric
    /// CRS; for UTM, the east-north-up frame at the origin's latitude/longitude turned by the
    /// meridian convergence (local metres are true metres; heights ellipsoidal). `None` with no
    /// CRS.
    pub fn ecef_from_local(&self) -> Option<Matrix4<f64>> {
        let crs = self.crs.as_ref()?;
        let wl = self.world_from_local();
        if crs.epsg == 4978 {
            return Some(wl);
        }
        let zone = wkt::utm_zone(crs.epsg)?;
        let t = wl.fixed_view::<3, 1>(0, 3).into_owned();
        let (lat, lon) = zone.inverse(t[0], t[1]);
        let origin = utm::ecef_from_geodetic(zone.ellipsoid, lat, lon, t[2]);
        let [e, n, u] = utm::enu_axes(lat, lon);
        let gamma = zone.convergence_deg(lat, lon).to_radians();
        // Grid east / grid north in true east-north components.
        let ge = [gamma.cos(), -gamma.sin()];
        let gn = [gamma.sin(), gamma.cos()];
        let col = |g: [f64; 2]| Vector3::from([0, 1, 2].map(|k| g[0] * e[k] + g[1] * n[k]));
        let ecef_from_grid = Matrix3::from_columns(&[col(ge), col(gn), Vector3::from(u)]);
        let rot = ecef_from_grid * wl.fixed_view::<3, 3>(0, 0);
        Some(homogeneous(rot, Vector3::from(origin)))
    }
}

/// Heights accepted for a map origin, metres above the ellipsoid: the Dead Sea shore to well
/// above any aircraft survey.
const HEIGHT_RANGE_M: std::ops::RangeInclusive<f64> = -12_000.0..=100_000.0;

/// Checks that `origin` (CRS coordinates) lies where the CRS is defined (issue 36: an easting of
/// 10¹² wrote `null` into a tileset's transform, and a negative northing in a northern zone was
/// accepted). UTM: easting 0–1 000 km (a zone is ~670 km wide at the equator), northing 0 to
/// 9 350 km (84° N) in a northern zone and 1 000 to 10 000 km (80° S to the equator) in a southern
/// one; geocentric: within 100 km of the WGS 84 ellipsoid's surface.
fn check_area(crs: &Crs, origin: [f64; 3]) -> std::result::Result<(), String> {
    let [x, y, z] = origin;
    if let Some(zone) = wkt::utm_zone(crs.epsg) {
        let northing = if zone.north {
            0.0..=9_350_000.0
        } else {
            1_000_000.0..=10_000_000.0
        };
        let hemisphere = if zone.north { "northern" } else { "southern" };
        if !(0.0..=1_000_000.0).contains(&x) {
            return Err(format!(
                "easting {x} m is outside UTM zone {} (0 to 1 000 000 m) of EPSG:{}",
                zone.zone, crs.epsg
            ));
        }
        if !northing.contains(&y) {
            return Err(format!(
                "northing {y} m is outside the {hemisphere} UTM zone {} of EPSG:{} ({} to {} m)",
                zone.zone,
                crs.epsg,
                northing.start(),
                northing.end()
            ));
        }
        if !HEIGHT_RANGE_M.contains(&z) {
            return Err(format!(
                "height {z} m is outside {} to {} m",
                HEIGHT_RANGE_M.start(),
                HEIGHT_RANGE_M.end()
            ));
        }
        return Ok(());
    }
    // Geocentric (EPSG:4978): near the ellipsoid's surface (semi-axes 6 378 137 and 6 356 752 m).
    let r = (x * x + y * y + z * z).sqrt();
    if !(6_256_752.0..=6_478_137.0).contains(&r) {
        return Err(format!(
            "geocentric point ({x}, {y}, {z}) is {:.0} km from the Earth's centre, not within 100 km of its surface (EPSG:{})",
            r / 1000.0,
            crs.epsg
        ));
    }
    Ok(())
}

fn crs_for(code: &str) -> std::result::Result<Crs, String> {
    let epsg: u32 = code
        .trim()
        .parse()
        .map_err(|_| format!("EPSG code {code:?} is not a number"))?;
    let wkt = wkt::wkt_for_epsg(epsg).ok_or_else(|| {
        format!(
            "EPSG:{epsg} is not one this build can describe ({})",
            wkt::KNOWN_CRS
        )
    })?;
    Ok(Crs { epsg, wkt })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn local_frame_is_a_right_handed_z_up_rotation() {
        let w = WorldFrame::local_z_up();
        // Forward (z_map) → x, right (x_map) → −y, down (y_map) → −z.
        assert_eq!(w.to_world([0.0, 0.0, 1.0]), [1.0, 0.0, 0.0]);
        assert_eq!(w.to_world([1.0, 0.0, 0.0]), [0.0, -1.0, 0.0]);
        assert_eq!(w.to_world([0.0, 1.0, 0.0]), [0.0, 0.0, -1.0]);
        assert_eq!(w.world_from_map.determinant(), 1.0);
        assert_eq!(WorldFrame::from_origin(None, [0.0; 3], 90.0), w);
    }

    #[test]
    fn origin_and_heading() {
        let w = WorldFrame::parse("EPSG:32632@691000,5335000,500,0").unwrap();
        // Heading 0: forward points north (+y); up stays up.
        let p = w.to_world([0.0, -2.0, 10.0]);
        assert!((p[0] - 691000.0).abs() < 1e-9 && (p[1] - 5335010.0).abs() < 1e-9);
        assert!((p[2] - 502.0).abs() < 1e-9);
        assert_eq!(w.crs.as_ref().unwrap().epsg, 32632);
    }

    #[test]
    fn matrix_file_form_and_errors() {
        let w = WorldFrame::parse_matrix_text(
            "# world_from_map\nEPSG:25832\n0 0 1 100\n-1 0 0 200\n0 -1 0 300\n0 0 0 1\n",
        )
        .unwrap();
        assert_eq!(w.to_world([0.0, 0.0, 1.0]), [101.0, 200.0, 300.0]);
        assert_eq!(w.crs.unwrap().epsg, 25832);
        let e = WorldFrame::parse_matrix_text("2 0 0 0 0 1 0 0 0 0 1 0").unwrap_err();
        assert!(e.contains("not a rotation"), "{e}");
        let e = WorldFrame::parse_matrix_text("1 0 0").unwrap_err();
        assert!(e.contains("found 3"), "{e}");
        let e = WorldFrame::parse("EPSG:2056@1,2,3")
            .unwrap_err()
            .to_string();
        assert!(e.contains("EPSG:2056") && e.contains("UTM"), "{e}");
    }

    /// Issue 36: origins outside the CRS's area and absurd headings were accepted (an easting of
    /// 10¹² wrote `null` into tileset.json).
    #[test]
    fn origins_outside_the_crs_and_bad_headings_are_refused() {
        for (spec, word) in [
            ("EPSG:32632@1e12,5335000,500", "easting"),
            ("EPSG:32632@691000,5e8,500", "northing"),
            ("EPSG:32632@691000,-5335000,500", "northing"),
            ("EPSG:32732@691000,500000,500", "southern"),
            ("EPSG:25832@691000,5335000,1e7", "height"),
            ("EPSG:32632@691000,5335000,500,1e9", "heading"),
            ("EPSG:4978@1,2,3", "centre"),
        ] {
            let e = WorldFrame::parse(spec).unwrap_err().to_string();
            assert!(e.contains(word), "{spec}: {e}");
        }
        for ok in [
            "EPSG:32632@691000,5335000,500,-90",
            "EPSG:32732@300000,7000000,20",
            "EPSG:4978@4177891.13,855128.58,4727618.05",
        ] {
            assert!(WorldFrame::parse(ok).is_ok(), "{ok}");
        }
        let e =
            WorldFrame::parse_matrix_text("EPSG:32632\n1 0 0 1e12\n0 1 0 0\n0 0 1 0").unwrap_err();
        assert!(e.contains("translation") && e.contains("easting"), "{e}");
    }

    #[test]
    fn ecef_from_utm_matches_proj() {
        // pyproj 3.8: EPSG:32632 (691000, 5335000, 500) → EPSG:4978.
        let w = WorldFrame::parse("EPSG:32632@691000,5335000,500").unwrap();
        let m = w.ecef_from_local().unwrap();
        let expect = [4177891.130820783, 855128.5779302452, 4727618.047799967];
        for k in 0..3 {
            assert!((m[(k, 3)] - expect[k]).abs() < 1e-3, "{k}: {}", m[(k, 3)]);
        }
        // pyproj: (11.5 E, 48.1 N) → (686121.7558017899, 5330438.130176074) in zone 32N.
        let z = wkt::utm_zone(32632).unwrap();
        let (e, n) = z.forward(48.1, 11.5);
        assert!((e - 686121.7558017899).abs() < 1e-4 && (n - 5330438.130176074).abs() < 1e-4);
        // Southern zone 33S: (14.5 E, 22.9 S) → (448721.1114559491, 7467463.071198233).
        let z = wkt::utm_zone(32733).unwrap();
        let (e, n) = z.forward(-22.9, 14.5);
        assert!((e - 448721.1114559491).abs() < 1e-4 && (n - 7467463.071198233).abs() < 1e-4);
        // Up in the local frame is the ellipsoid normal: 100 m up changes the ECEF norm by ~100 m.
        let up = m * nalgebra::Vector4::new(0.0, 0.0, 100.0, 1.0);
        let base = m.fixed_view::<3, 1>(0, 3).norm();
        assert!((up.xyz().norm() - base - 100.0).abs() < 0.01);
    }
}
