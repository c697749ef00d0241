//! OGC WKT (version 1, as the LAS 1.4 specification asks) for the coordinate reference systems
//! `denser` can georeference into, generated from their EPSG definitions:
//!
//! * EPSG:32601–32660 and 32701–32760: WGS 84 / UTM zone 1N–60N, 1S–60S;
//! * EPSG:25828–25838: ETRS89 / UTM zone 28N–38N;
//! * EPSG:4978: WGS 84 geocentric (ECEF).
//!
//! Other CRSs would need the EPSG database, which this crate does not carry.

use super::utm::{UtmZone, GRS80, WGS84};

/// The CRSs [`wkt_for_epsg`] knows, in words (for error messages).
pub const KNOWN_CRS: &str =
    "known: WGS 84 / UTM EPSG:32601–32660 and 32701–32760, ETRS89 / UTM EPSG:25828–25838, WGS 84 geocentric EPSG:4978";

/// The UTM zone of an EPSG code, if it is one of the UTM CRSs above.
pub fn utm_zone(epsg: u32) -> Option<UtmZone> {
    match epsg {
        32601..=32660 => Some(UtmZone {
            zone: (epsg - 32600) as u8,
            north: true,
            ellipsoid: WGS84,
        }),
        32701..=32760 => Some(UtmZone {
            zone: (epsg - 32700) as u8,
            north: false,
            ellipsoid: WGS84,
        }),
        25828..=25838 => Some(UtmZone {
            zone: (epsg - 25800) as u8,
            north: true,
            ellipsoid: GRS80,
        }),
        _ => None,
    }
}

const WGS84_GEOGCS: &str = r#"GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4326"]]"#;
const ETRS89_GEOGCS: &str = r#"GEOGCS["ETRS89",DATUM["European_Terrestrial_Reference_System_1989",SPHEROID["GRS 1980",6378137,298.257222101,AUTHORITY["EPSG","7019"]],TOWGS84[0,0,0,0,0,0,0],AUTHORITY["EPSG","6258"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4258"]]"#;

/// WKT 1 of an EPSG CRS listed in the module doc, or `None`.
pub fn wkt_for_epsg(epsg: u32) -> Option<String> {
    if epsg == 4978 {
        return Some(
            r#"GEOCCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["Geocentric X",OTHER],AXIS["Geocentric Y",OTHER],AXIS["Geocentric Z",NORTH],AUTHORITY["EPSG","4978"]]"#
                .to_string(),
        );
    }
    let z = utm_zone(epsg)?;
    let (name, geogcs) = if z.ellipsoid == WGS84 {
        ("WGS 84", WGS84_GEOGCS)
    } else {
        ("ETRS89", ETRS89_GEOGCS)
    };
    let hemi = if z.north { 'N' } else { 'S' };
    let false_northing = if z.north { 0 } else { 10_000_000 };
    Some(format!(
        r#"PROJCS["{name} / UTM zone {zone}{hemi}",{geogcs},PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",{cm}],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],PARAMETER["false_northing",{false_northing}],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["Easting",EAST],AXIS["Northing",NORTH],AUTHORITY["EPSG","{epsg}"]]"#,
        zone = z.zone,
        cm = z.central_meridian_deg(),
    ))
}
