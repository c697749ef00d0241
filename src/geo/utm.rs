//! Universal Transverse Mercator: grid coordinates ↔ geodetic latitude/longitude, and
//! geodetic ↔ Earth-centred Earth-fixed (ECEF) coordinates.
//!
//! What it does: the Krüger series of the transverse Mercator projection to order n⁴ (C. F. F.
//! Karney, "Transverse Mercator with an accuracy of a few nanometres", J. Geodesy 85, 2011,
//! eqs. 35–36 forward and the matching inverse series), accurate to well under a millimetre within
//! a UTM zone; the meridian convergence and point scale from the same series; ECEF from the
//! ellipsoid's closed form. Used to place a georeferenced 3D Tiles tileset on the globe.
//!
//! What it does not do: datum shifts (WGS 84 and ETRS89/GRS 80 are taken on their own
//! ellipsoids, which differ by 0.1 mm in the semi-minor axis), heights above the geoid (heights
//! are ellipsoidal), or zones outside 1–60.

/// A reference ellipsoid: semi-major axis `a_m` (metres) and inverse flattening.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ellipsoid {
    /// Semi-major axis, metres.
    pub a_m: f64,
    /// Inverse flattening 1/f.
    pub inv_f: f64,
}

/// WGS 84.
pub const WGS84: Ellipsoid = Ellipsoid {
    a_m: 6_378_137.0,
    inv_f: 298.257_223_563,
};

/// GRS 80 (ETRS89).
pub const GRS80: Ellipsoid = Ellipsoid {
    a_m: 6_378_137.0,
    inv_f: 298.257_222_101,
};

/// A UTM zone: number 1–60, hemisphere and ellipsoid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UtmZone {
    /// Zone number, 1..=60 (central meridian −183° + 6°·zone).
    pub zone: u8,
    /// Northern hemisphere (false northing 0) or southern (10 000 km).
    pub north: bool,
    /// The ellipsoid of the datum.
    pub ellipsoid: Ellipsoid,
}

const K0: f64 = 0.9996;
const FALSE_EASTING_M: f64 = 500_000.0;
const FALSE_NORTHING_SOUTH_M: f64 = 10_000_000.0;

struct Series {
    big_a: f64,
    alpha: [f64; 4],
    beta: [f64; 4],
    e: f64,
}

fn series(ell: Ellipsoid) -> Series {
    let f = 1.0 / ell.inv_f;
    let n = f / (2.0 - f);
    let (n2, n3, n4) = (n * n, n * n * n, n * n * n * n);
    let big_a = ell.a_m / (1.0 + n) * (1.0 + n2 / 4.0 + n4 / 64.0);
    let alpha = [
        n / 2.0 - 2.0 / 3.0 * n2 + 5.0 / 16.0 * n3 + 41.0 / 180.0 * n4,
        13.0 / 48.0 * n2 - 3.0 / 5.0 * n3 + 557.0 / 1440.0 * n4,
        61.0 / 240.0 * n3 - 103.0 / 140.0 * n4,
        49561.0 / 161280.0 * n4,
    ];
    let beta = [
        n / 2.0 - 2.0 / 3.0 * n2 + 37.0 / 96.0 * n3 - 1.0 / 360.0 * n4,
        1.0 / 48.0 * n2 + 1.0 / 15.0 * n3 - 437.0 / 1440.0 * n4,
        17.0 / 480.0 * n3 - 37.0 / 840.0 * n4,
        4397.0 / 161280.0 * n4,
    ];
    let e = (f * (2.0 - f)).sqrt();
    Series {
        big_a,
        alpha,
        beta,
        e,
    }
}

impl UtmZone {
    /// Central meridian, degrees.
    pub fn central_meridian_deg(&self) -> f64 {
        -183.0 + 6.0 * self.zone as f64
    }

    /// Grid coordinates (easting, northing; metres) of a geodetic latitude/longitude (degrees).
    pub fn forward(&self, lat_deg: f64, lon_deg: f64) -> (f64, f64) {
        let s = series(self.ellipsoid);
        let phi = lat_deg.to_radians();
        let lam = (lon_deg - self.central_meridian_deg()).to_radians();
        let t = (phi.sin().atanh() - s.e * (s.e * phi.sin()).atanh()).sinh();
        let xi_p = t.atan2(lam.cos());
        let eta_p = (lam.sin() / (t * t + lam.cos() * lam.cos()).sqrt()).asinh();
        let mut xi = xi_p;
        let mut eta = eta_p;
        for (j, a) in s.alpha.iter().enumerate() {
            let k = 2.0 * (j + 1) as f64;
            xi += a * (k * xi_p).sin() * (k * eta_p).cosh();
            eta += a * (k * xi_p).cos() * (k * eta_p).sinh();
        }
        let e = FALSE_EASTING_M + K0 * s.big_a * eta;
        let n = K0 * s.big_a * xi
            + if self.north {
                0.0
            } else {
                FALSE_NORTHING_SOUTH_M
            };
        (e, n)
    }

    /// Geodetic latitude/longitude (degrees) of grid coordinates (metres).
    pub fn inverse(&self, easting_m: f64, northing_m: f64) -> (f64, f64) {
        let s = series(self.ellipsoid);
        let n0 = if self.north {
            0.0
        } else {
            FALSE_NORTHING_SOUTH_M
        };
        let xi = (northing_m - n0) / (K0 * s.big_a);
        let eta = (easting_m - FALSE_EASTING_M) / (K0 * s.big_a);
        let mut xi_p = xi;
        let mut eta_p = eta;
        for (j, b) in s.beta.iter().enumerate() {
            let k = 2.0 * (j + 1) as f64;
            xi_p -= b * (k * xi).sin() * (k * eta).cosh();
            eta_p -= b * (k * xi).cos() * (k * eta).sinh();
        }
        let lam = eta_p.sinh().atan2(xi_p.cos());
        let tau_p = xi_p.sin() / (eta_p.sinh().powi(2) + xi_p.cos().powi(2)).sqrt();
        // Newton iteration for τ = tan φ from τ' (Karney eqs. 19–21).
        let e2 = s.e * s.e;
        let mut tau = tau_p;
        for _ in 0..6 {
            let sigma = (s.e * (s.e * tau / (1.0 + tau * tau).sqrt()).atanh()).sinh();
            let tp = tau * (1.0 + sigma * sigma).sqrt() - sigma * (1.0 + tau * tau).sqrt();
            let d = (tau_p - tp) / (1.0 + tp * tp).sqrt() * (1.0 + (1.0 - e2) * tau * tau)
                / ((1.0 - e2) * (1.0 + tau * tau).sqrt());
            tau += d;
            if d.abs() < 1e-14 {
                break;
            }
        }
        (
            tau.atan().to_degrees(),
            self.central_meridian_deg() + lam.to_degrees(),
        )
    }

    /// Meridian convergence at a geodetic position, degrees: the angle from true north to grid
    /// north, positive when grid north lies east of true north (east of the central meridian in
    /// the northern hemisphere). Computed as the azimuth of a short step along grid north.
    pub fn convergence_deg(&self, lat_deg: f64, lon_deg: f64) -> f64 {
        let (e, n) = self.forward(lat_deg, lon_deg);
        let (lat2, lon2) = self.inverse(e, n + 1.0);
        let ell = self.ellipsoid;
        let phi = lat_deg.to_radians();
        let f = 1.0 / ell.inv_f;
        let e2 = f * (2.0 - f);
        let w = (1.0 - e2 * phi.sin().powi(2)).sqrt();
        let m = ell.a_m * (1.0 - e2) / w.powi(3); // meridian radius of curvature
        let nn = ell.a_m / w; // prime vertical radius
        let d_north = (lat2 - lat_deg).to_radians() * m;
        let d_east = (lon2 - lon_deg).to_radians() * nn * phi.cos();
        d_east.atan2(d_north).to_degrees()
    }
}

/// ECEF coordinates (metres) of a geodetic position (degrees, ellipsoidal height in metres).
pub fn ecef_from_geodetic(ell: Ellipsoid, lat_deg: f64, lon_deg: f64, h_m: f64) -> [f64; 3] {
    let f = 1.0 / ell.inv_f;
    let e2 = f * (2.0 - f);
    let (phi, lam) = (lat_deg.to_radians(), lon_deg.to_radians());
    let nn = ell.a_m / (1.0 - e2 * phi.sin().powi(2)).sqrt();
    [
        (nn + h_m) * phi.cos() * lam.cos(),
        (nn + h_m) * phi.cos() * lam.sin(),
        (nn * (1.0 - e2) + h_m) * phi.sin(),
    ]
}

/// The unit vectors east, north, up of the local tangent frame at a geodetic position, in ECEF.
pub fn enu_axes(lat_deg: f64, lon_deg: f64) -> [[f64; 3]; 3] {
    let (phi, lam) = (lat_deg.to_radians(), lon_deg.to_radians());
    [
        [-lam.sin(), lam.cos(), 0.0],
        [-phi.sin() * lam.cos(), -phi.sin() * lam.sin(), phi.cos()],
        [phi.cos() * lam.cos(), phi.cos() * lam.sin(), phi.sin()],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forward_inverse_round_trip_across_a_zone() {
        let z = UtmZone {
            zone: 32,
            north: true,
            ellipsoid: WGS84,
        };
        for lat in [0.5, 30.0, 48.1, 70.0] {
            for dlon in [-3.0, -1.2, 0.0, 2.9] {
                let lon = 9.0 + dlon;
                let (e, n) = z.forward(lat, lon);
                let (lat2, lon2) = z.inverse(e, n);
                assert!((lat2 - lat).abs() < 1e-10 && (lon2 - lon).abs() < 1e-10);
            }
        }
        // On the central meridian the easting is the false easting and γ = 0.
        let (e, _) = z.forward(45.0, 9.0);
        assert!((e - 500_000.0).abs() < 1e-6);
        assert!(z.convergence_deg(45.0, 9.0).abs() < 1e-6);
        // East of it (north): positive convergence ≈ Δλ·sin φ.
        let g = z.convergence_deg(45.0, 11.0);
        assert!((g - 2.0 * 45f64.to_radians().sin()).abs() < 0.01, "{g}");
    }

    #[test]
    fn ecef_of_known_points() {
        let p = ecef_from_geodetic(WGS84, 0.0, 0.0, 0.0);
        assert_eq!(p, [6_378_137.0, 0.0, 0.0]);
        let q = ecef_from_geodetic(WGS84, 90.0, 0.0, 0.0);
        assert!((q[2] - 6_356_752.314_245).abs() < 1e-3);
    }
}
