//! Coordinate reference system text from LAS VLRs: OGC WKT (LASF_Projection 2112) or
//! GeoTIFF keys (LASF_Projection 34735/34736/34737).
//!
//! The GeoKey directory is decoded here rather than through `las::Header::get_geotiff_crs`,
//! because that needs a full `las::Header`, which `las` cannot build for every file we accept
//! (LAZ point formats, odd padding), and because we also need the linear-unit keys, which it
//! does not interpret.

use serde::Serialize;

const PROJECTION_USER: &[u8] = b"LASF_Projection";

/// A coordinate reference system as far as the file states it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Crs {
    /// OGC WKT text, if the file carries it.
    pub wkt: Option<String>,
    /// EPSG code of the projected (or geographic) CRS, when one is stated.
    pub epsg: Option<u32>,
    /// GeoTIFF keys in readable form (`key=value` list), if the file carries them.
    pub geotiff: Option<String>,
    /// Horizontal linear unit, when stated.
    pub unit: Option<LinearUnit>,
    /// Vertical CRS (datum of the heights), when stated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vertical: Option<VerticalCrs>,
}

/// The vertical CRS of the heights as GeoTIFF keys (VerticalCSType, VerticalCitation,
/// VerticalUnits) or a WKT `VERT_CS` state it.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct VerticalCrs {
    /// EPSG code of the vertical CRS (5713: CGVD28 height).
    pub epsg: Option<u32>,
    /// Its name (`CGVD28`).
    pub name: Option<String>,
    /// EPSG code of its unit (9001: metre).
    pub unit_epsg: Option<u32>,
}

/// A linear unit with its length in metres.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LinearUnit {
    /// Its name as the file gives it (`metre`, `foot`, `US survey foot`).
    pub name: String,
    /// Its length in metres.
    pub metres: f64,
}

impl Crs {
    /// Short text for reports and manifests: `EPSG:n`, else the WKT, else the GeoTIFF keys.
    pub fn text(&self) -> String {
        if let Some(code) = self.epsg {
            format!("EPSG:{code}")
        } else if let Some(w) = &self.wkt {
            w.clone()
        } else {
            self.geotiff.clone().unwrap_or_default()
        }
    }

    /// Length of one horizontal unit in metres (1.0 when the file does not say).
    pub fn metres_per_unit(&self) -> f64 {
        self.unit.as_ref().map_or(1.0, |u| u.metres)
    }

    /// Reads the CRS from a file's VLRs and EVLRs.
    pub fn from_vlrs(vlrs: &[super::las_header::Vlr]) -> Option<Crs> {
        let find = |id: u16| {
            vlrs.iter()
                .find(|v| v.record_id == id && v.user_id.starts_with(PROJECTION_USER))
                .map(|v| v.data.as_slice())
        };
        let wkt = find(2112).map(|d| {
            String::from_utf8_lossy(d)
                .trim_end_matches('\0')
                .trim()
                .to_string()
        });
        let keys = find(34735).and_then(|d| parse_geokeys(d, find(34736), find(34737)));
        if wkt.is_none() && keys.is_none() {
            return None;
        }
        let mut crs = Crs {
            wkt: wkt.filter(|w| !w.is_empty()),
            epsg: None,
            geotiff: None,
            unit: None,
            vertical: None,
        };
        if let Some(keys) = &keys {
            crs.geotiff = Some(
                keys.iter()
                    .map(|(k, v)| format!("{}={}", key_name(*k), v))
                    .collect::<Vec<_>>()
                    .join("; "),
            );
            let code = |id| {
                keys.iter().find_map(|(k, v)| match v {
                    KeyValue::Short(c) if *k == id && *c != 0 && *c != 32767 => Some(*c as u32),
                    _ => None,
                })
            };
            crs.epsg = code(3072).or_else(|| code(2048));
            crs.unit = code(3076).and_then(unit_from_epsg);
            let text = |id| {
                keys.iter().find_map(|(k, v)| match v {
                    KeyValue::Ascii(s) if *k == id => {
                        Some(s.trim_end_matches(['|', '\0']).trim().to_string())
                    }
                    _ => None,
                })
            };
            let vertical = VerticalCrs {
                epsg: code(4096),
                name: text(4097).filter(|s| !s.is_empty()),
                unit_epsg: code(4099),
            };
            if vertical.epsg.is_some() || vertical.name.is_some() {
                crs.vertical = Some(vertical);
            }
            if crs.unit.is_none() && crs.epsg.is_some_and(is_utm) {
                crs.unit = unit_from_epsg(9001);
            }
        }
        if let Some(w) = &crs.wkt {
            if crs.unit.is_none() {
                crs.unit = wkt_linear_unit(w);
            }
            if crs.epsg.is_none() {
                crs.epsg = wkt_top_epsg(w);
            }
        }
        Some(crs)
    }
}

/// A GeoKey value: inline short, doubles, or ASCII.
#[derive(Debug, Clone, PartialEq)]
enum KeyValue {
    Short(u16),
    Doubles(Vec<f64>),
    Ascii(String),
}

impl std::fmt::Display for KeyValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            KeyValue::Short(v) => write!(f, "{v}"),
            KeyValue::Doubles(v) => write!(f, "{v:?}"),
            KeyValue::Ascii(s) => write!(f, "\"{}\"", s.trim_end_matches(['|', '\0'])),
        }
    }
}

fn parse_geokeys(
    dir: &[u8],
    doubles: Option<&[u8]>,
    ascii: Option<&[u8]>,
) -> Option<Vec<(u16, KeyValue)>> {
    let shorts: Vec<u16> = dir
        .chunks_exact(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect();
    let n = *shorts.get(3)? as usize;
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let e = shorts.get(4 + 4 * k..8 + 4 * k)?;
        let (id, loc, count, val) = (e[0], e[1], e[2] as usize, e[3] as usize);
        let value = match loc {
            0 => KeyValue::Short(val as u16),
            34736 => {
                let d = doubles?;
                let v = (0..count)
                    .map(|i| {
                        let at = (val + i) * 8;
                        d.get(at..at + 8)
                            .map(|b| f64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
                    })
                    .collect::<Option<Vec<f64>>>()?;
                KeyValue::Doubles(v)
            }
            34737 => {
                let a = ascii?;
                let s = a.get(val..(val + count).min(a.len()))?;
                KeyValue::Ascii(String::from_utf8_lossy(s).into_owned())
            }
            _ => continue,
        };
        out.push((id, value));
    }
    Some(out)
}

fn key_name(id: u16) -> String {
    match id {
        1024 => "GTModelType".into(),
        1025 => "GTRasterType".into(),
        1026 => "GTCitation".into(),
        2048 => "GeographicType".into(),
        2049 => "GeogCitation".into(),
        2054 => "GeogAngularUnits".into(),
        3072 => "ProjectedCSType".into(),
        3073 => "PCSCitation".into(),
        3076 => "ProjLinearUnits".into(),
        4096 => "VerticalCSType".into(),
        4097 => "VerticalCitation".into(),
        4099 => "VerticalUnits".into(),
        other => format!("key{other}"),
    }
}

fn unit_from_epsg(code: u32) -> Option<LinearUnit> {
    let (name, metres) = match code {
        9001 => ("metre", 1.0),
        9002 => ("foot", 0.3048),
        9003 => ("US survey foot", 1200.0 / 3937.0),
        _ => return None,
    };
    Some(LinearUnit {
        name: name.into(),
        metres,
    })
}

fn is_utm(code: u32) -> bool {
    (32601..=32660).contains(&code)
        || (32701..=32760).contains(&code)
        || (25828..=25838).contains(&code)
}

/// The first linear (non-angular) unit in a WKT string: `UNIT["foot",0.3048]` or
/// WKT2's `LENGTHUNIT["metre",1]`. In WKT1 PROJCS the geographic part's unit is angular,
/// so the first linear one is the projection's.
fn wkt_linear_unit(wkt: &str) -> Option<LinearUnit> {
    let mut rest = wkt;
    while let Some(pos) = rest.find("UNIT[") {
        let after = &rest[pos + 5..];
        let close = after.find(']')?;
        let body = &after[..close];
        let mut parts = body.splitn(3, ',');
        let name = parts.next()?.trim().trim_matches('"').to_string();
        let factor: f64 = parts.next()?.trim().parse().ok()?;
        let lname = name.to_ascii_lowercase();
        let angular =
            lname.contains("degree") || lname.contains("radian") || lname.contains("grad");
        if !angular && factor > 0.0 {
            return Some(LinearUnit {
                name,
                metres: factor,
            });
        }
        rest = &after[close..];
    }
    None
}

/// The EPSG code of the outermost CRS: the last `AUTHORITY["EPSG","n"]` (WKT1) or
/// `ID["EPSG",n]` (WKT2) when it closes the string.
fn wkt_top_epsg(wkt: &str) -> Option<u32> {
    let t = wkt.trim_end();
    let t = t.strip_suffix(']')?.trim_end();
    let t = t.strip_suffix(']')?;
    let start = t.rfind('[')?;
    let head = t[..start].trim_end();
    if !(head.ends_with("AUTHORITY") || head.ends_with("ID")) {
        return None;
    }
    let inner = &t[start + 1..];
    let mut parts = inner.split(',');
    if !parts
        .next()?
        .trim()
        .trim_matches('"')
        .eq_ignore_ascii_case("EPSG")
    {
        return None;
    }
    parts.next()?.trim().trim_matches('"').parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wkt_unit_skips_the_angular_one() {
        let w = r#"PROJCS["x",GEOGCS["NAD83",DATUM["d",SPHEROID["s",6378137,298.2]],UNIT["degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic_2SP"],UNIT["foot",0.3048],AUTHORITY["EPSG","2992"]]"#;
        let u = wkt_linear_unit(w).unwrap();
        assert_eq!(u.name, "foot");
        assert_eq!(u.metres, 0.3048);
        assert_eq!(wkt_top_epsg(w), Some(2992));
    }

    #[test]
    fn geokeys_give_epsg_and_units() {
        // version 1.1.0, 2 keys: ProjectedCSType=32632, ProjLinearUnits=9001
        let shorts: [u16; 12] = [1, 1, 0, 2, 3072, 0, 1, 32632, 3076, 0, 1, 9001];
        let dir: Vec<u8> = shorts.iter().flat_map(|s| s.to_le_bytes()).collect();
        let vlr = super::super::las_header::Vlr {
            user_id: {
                let mut u = [0u8; 16];
                u[..15].copy_from_slice(PROJECTION_USER);
                u
            },
            record_id: 34735,
            description: [0; 32],
            data: dir,
            extended: false,
        };
        let crs = Crs::from_vlrs(&[vlr]).unwrap();
        assert_eq!(crs.epsg, Some(32632));
        assert_eq!(crs.metres_per_unit(), 1.0);
        assert_eq!(crs.text(), "EPSG:32632");
    }
}
