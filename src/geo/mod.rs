//! Reprojection to WGS 84 geographic coordinates, in pure Rust.
//!
//! Choice: `proj4rs` (a Rust transcription of PROJ's projections, held to PROJ's results)
//! applies PROJ strings; `crs-definitions` maps EPSG codes to PROJ strings (the EPSG
//! database as PROJ exports it, TOWGS84 included); `proj4wkt` turns a WKT (WKT1, ESRI's
//! flavour, WKT2) into a PROJ string when a file has no EPSG code (Autzen's Oregon Lambert in
//! international feet). Together they need no system PROJ, no database file and no network,
//! so the default job still builds on a machine with only Rust. The price is PROJ.4's datum
//! model: one 3- or 7-parameter shift to WGS 84 per CRS (no grids, no time-dependent
//! frames), which differs from PROJ's own choice of transformation by up to about a metre
//! for NAD83(CSRS) (see the reference data's notes). `geodesy` (Rust Geodesy) was the
//! alternative; it has no EPSG table and no WKT reader, so every CRS would be ours to spell.

pub mod cells;
pub mod tin;
pub mod tms;

use crate::points::Crs;
use proj4rs::proj::Proj;

/// PROJ string of WGS 84 geographic coordinates.
const WGS84: &str = "+proj=longlat +datum=WGS84 +no_defs";

/// A CRS that cannot be turned into a transformation, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Unsupported {
    /// The CRS as the input names it (`EPSG:n` or the start of its WKT).
    pub crs: String,
    /// Why.
    pub reason: String,
}

impl std::fmt::Display for Unsupported {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "CRS {} cannot be reprojected to WGS 84: {}",
            self.crs, self.reason
        )
    }
}

/// The PROJ string of EPSG code `code`, if the table has it.
pub fn epsg_proj_string(code: u32) -> Option<&'static str> {
    u16::try_from(code)
        .ok()
        .and_then(crs_definitions::from_code)
        .map(|d| d.proj4)
}

/// True when EPSG `code` is a geographic (longitude/latitude) CRS.
pub fn epsg_is_geographic(code: u32) -> bool {
    epsg_proj_string(code).is_some_and(|p| p.contains("+proj=longlat"))
}

/// The CRS that `[input] crs` names: `EPSG:n` (any case) of a code the EPSG table has.
pub fn crs_from_key(text: &str) -> Result<Crs, String> {
    let t = text.trim();
    let code = t
        .get(..5)
        .filter(|p| p.eq_ignore_ascii_case("EPSG:"))
        .and_then(|_| t[5..].trim().parse::<u32>().ok())
        .ok_or_else(|| "must be \"EPSG:n\" with n an EPSG code".to_string())?;
    let def = u16::try_from(code)
        .ok()
        .and_then(crs_definitions::from_code)
        .ok_or_else(|| format!("EPSG:{code} is not a code of the EPSG table terratile knows"))?;
    let unit = proj_unit_metres(def.proj4).map(|(name, metres)| crate::points::LinearUnit {
        name: name.to_string(),
        metres,
    });
    Ok(Crs {
        wkt: Some(without_towgs84(def.wkt)),
        epsg: Some(code),
        geotiff: None,
        unit,
        vertical: None,
    })
}

/// The linear unit of a PROJ string (`+units=`, `+to_meter=`); None for geographic CRSs.
fn proj_unit_metres(p: &str) -> Option<(&'static str, f64)> {
    if p.contains("+proj=longlat") {
        return None;
    }
    for tok in p.split_whitespace() {
        match tok {
            "+units=m" => return Some(("metre", 1.0)),
            "+units=ft" => return Some(("foot", 0.3048)),
            "+units=us-ft" => return Some(("US survey foot", 1200.0 / 3937.0)),
            _ => {
                if let Some(v) = tok.strip_prefix("+to_meter=") {
                    return v.parse().ok().map(|m| ("unit", m));
                }
            }
        }
    }
    Some(("metre", 1.0))
}

/// The CRS as WKT for a `.prj` file: the input's own WKT, else the EPSG table's without its
/// `TOWGS84` node (GDAL would read that as a bound CRS, a different CRS from the EPSG one;
/// the datum shift is the transformation's business, not the CRS's).
pub fn wkt_of(crs: &Crs) -> Option<String> {
    crs.wkt.clone().or_else(|| {
        crs.epsg
            .and_then(|c| u16::try_from(c).ok())
            .and_then(crs_definitions::from_code)
            .map(|d| without_towgs84(d.wkt))
    })
}

/// `wkt` without its `,TOWGS84[…]` node (which holds numbers only, so no nested brackets).
fn without_towgs84(wkt: &str) -> String {
    match wkt.find(",TOWGS84[") {
        Some(at) => match wkt[at..].find(']') {
            Some(end) => format!("{}{}", &wkt[..at], &wkt[at + end + 1..]),
            None => wkt.to_string(),
        },
        None => wkt.to_string(),
    }
}

/// A transformation between a CRS and WGS 84 longitude/latitude (degrees).
pub struct ToWgs84 {
    src: Proj,
    dst: Proj,
    /// The PROJ string of the source CRS.
    pub proj_string: String,
}

impl std::fmt::Debug for ToWgs84 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ToWgs84")
            .field("proj_string", &self.proj_string)
            .finish()
    }
}

impl ToWgs84 {
    /// The transformation from `crs`: its EPSG code when it has one, else its WKT.
    pub fn new(crs: &Crs) -> Result<ToWgs84, Unsupported> {
        let name = crs_name(crs);
        let fail = |reason: String| Unsupported {
            crs: name.clone(),
            reason,
        };
        let proj_string = match (crs.epsg, &crs.wkt) {
            (Some(code), wkt) => match epsg_proj_string(code) {
                Some(p) => p.to_string(),
                None => match wkt {
                    Some(w) => proj4wkt::wkt_to_projstring(w)
                        .map_err(|e| fail(format!("not in the EPSG table, and its WKT: {e}")))?,
                    None => return Err(fail("not in the EPSG table terratile knows".into())),
                },
            },
            (None, Some(w)) => {
                proj4wkt::wkt_to_projstring(w).map_err(|e| fail(format!("its WKT: {e}")))?
            }
            (None, None) => {
                return Err(fail(
                    "the input states neither an EPSG code nor a WKT (GeoTIFF keys alone)".into(),
                ))
            }
        };
        let src = Proj::from_proj_string(&proj_string)
            .map_err(|e| fail(format!("{proj_string}: {e}")))?;
        let dst = Proj::from_proj_string(WGS84).map_err(|e| fail(e.to_string()))?;
        let t = ToWgs84 {
            src,
            dst,
            proj_string,
        };
        // A definition proj4rs parses but cannot invert shows here, not at the first corner.
        if !t.src.has_inverse() {
            return Err(fail(format!(
                "{}: proj4rs has no inverse of this projection",
                t.proj_string
            )));
        }
        Ok(t)
    }

    /// WGS 84 longitude and latitude (degrees) of `(x, y)` in the CRS; None where the
    /// projection is undefined.
    pub fn forward(&self, x: f64, y: f64) -> Option<[f64; 2]> {
        let mut p = (x, y, 0.0);
        if self.src.is_latlong() {
            p = (x.to_radians(), y.to_radians(), 0.0);
        }
        proj4rs::transform::transform(&self.src, &self.dst, &mut p).ok()?;
        let out = [p.0.to_degrees(), p.1.to_degrees()];
        out.iter().all(|v| v.is_finite()).then_some(out)
    }

    /// `(x, y)` in the CRS of WGS 84 longitude and latitude (degrees).
    pub fn inverse(&self, lon: f64, lat: f64) -> Option<[f64; 2]> {
        let mut p = (lon.to_radians(), lat.to_radians(), 0.0);
        proj4rs::transform::transform(&self.dst, &self.src, &mut p).ok()?;
        let mut out = [p.0, p.1];
        if self.src.is_latlong() {
            out = [p.0.to_degrees(), p.1.to_degrees()];
        }
        out.iter().all(|v| v.is_finite()).then_some(out)
    }
}

/// `EPSG:n`, else the first 60 characters of the WKT, else the GeoTIFF keys.
pub fn crs_name(crs: &Crs) -> String {
    let t = crs.text();
    match t.char_indices().nth(60) {
        Some((i, _)) => format!("{}…", &t[..i]),
        None => t,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn key_parses_epsg_and_refuses_the_rest() {
        let c = crs_from_key("EPSG:28992").unwrap();
        assert_eq!(c.epsg, Some(28992));
        assert_eq!(c.metres_per_unit(), 1.0);
        assert_eq!(crs_from_key("epsg:2992").unwrap().metres_per_unit(), 0.3048);
        assert!(crs_from_key("EPSG:99999")
            .unwrap_err()
            .contains("EPSG:99999"));
        assert!(crs_from_key("EPSG:1").is_err());
        assert!(crs_from_key("28992").is_err());
        assert!(crs_from_key("EPSG:").is_err());
    }

    #[test]
    fn prj_drops_towgs84() {
        let w = wkt_of(&crs_from_key("EPSG:28992").unwrap()).unwrap();
        assert!(!w.contains("TOWGS84"), "{w}");
        assert!(
            w.contains("DATUM[\"Amersfoort\",SPHEROID[")
                && w.ends_with("AUTHORITY[\"EPSG\",\"28992\"]]")
        );
    }

    #[test]
    fn utm_round_trip() {
        let t = ToWgs84::new(&crs_from_key("EPSG:32632").unwrap()).unwrap();
        let [lon, lat] = t.forward(500000.0, 0.0).unwrap();
        assert!(
            (lon - 9.0).abs() < 1e-12 && lat.abs() < 1e-12,
            "{lon} {lat}"
        );
        let [x, y] = t.inverse(lon, lat).unwrap();
        assert!((x - 500000.0).abs() < 1e-6 && y.abs() < 1e-6);
    }
}
