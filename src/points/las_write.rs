//! Writing point clouds as LAS 1.2 through `las::Writer` (for `generate` and the removed-noise
//! output), and record pass-through for `convert`. Every write goes to a temporary file that
//! is renamed into place, so a failed write leaves nothing behind.

use super::{Crs, LasHeader, PointCloud};
use crate::error::{Error, Result};
use crate::fsutil::write_atomic;
use std::path::Path;

/// How to write a cloud as LAS.
#[derive(Debug, Clone)]
pub struct LasWriteOptions {
    /// Scale factors (0.01 = centimetres for metric data).
    pub scale: [f64; 3],
    /// Offsets; `None` picks the bounds' minimum rounded down to a multiple of 1000 units.
    pub offset: Option<[f64; 3]>,
    /// CRS to record (as a WKT VLR, or GeoTIFF keys for a bare EPSG code).
    pub crs: Option<Crs>,
    /// Overrides every point's class (e.g. 7 for points removed as noise).
    pub classification: Option<u8>,
}

impl Default for LasWriteOptions {
    fn default() -> Self {
        LasWriteOptions {
            scale: [0.01; 3],
            offset: None,
            crs: None,
            classification: None,
        }
    }
}

impl LasWriteOptions {
    /// The offsets used for a cloud with these bounds.
    pub fn offset_for(&self, b: &super::Bounds) -> [f64; 3] {
        self.offset.unwrap_or_else(|| {
            if b.is_empty() {
                [0.0; 3]
            } else {
                b.min.map(|m| (m / 1000.0).floor() * 1000.0)
            }
        })
    }
}

fn projection_vlr(record_id: u16, data: Vec<u8>, description: &str) -> las::Vlr {
    las::Vlr {
        user_id: "LASF_Projection".into(),
        record_id,
        description: description.into(),
        data,
    }
}

/// The VLRs that record `crs` in a LAS 1.2 file.
fn crs_vlrs(crs: &Crs) -> Vec<las::Vlr> {
    if let Some(wkt) = &crs.wkt {
        let mut data = wkt.as_bytes().to_vec();
        data.push(0);
        return vec![projection_vlr(2112, data, "OGC WKT")];
    }
    let Some(code) = crs.epsg.filter(|&c| c <= u16::MAX as u32) else {
        return Vec::new();
    };
    // GeoKey directory 1.1.0: model type projected (1), ProjectedCSType = code, and the
    // linear unit when it is one GeoTIFF names.
    let mut keys: Vec<[u16; 4]> = vec![[1024, 0, 1, 1], [3072, 0, 1, code as u16]];
    if let Some(u) = &crs.unit {
        let unit = if u.metres == 1.0 {
            Some(9001)
        } else if u.metres == 0.3048 {
            Some(9002)
        } else if (u.metres - 1200.0 / 3937.0).abs() < 1e-12 {
            Some(9003)
        } else {
            None
        };
        if let Some(unit) = unit {
            keys.push([3076, 0, 1, unit]);
        }
    }
    let mut shorts = vec![1u16, 1, 0, keys.len() as u16];
    shorts.extend(keys.iter().flatten());
    let data = shorts.iter().flat_map(|s| s.to_le_bytes()).collect();
    vec![projection_vlr(34735, data, "GeoTIFF GeoKeyDirectoryTag")]
}

/// Writes `cloud` to `path` as LAS 1.2, point format 0 (x, y, z, intensity, returns, class).
pub fn write_las(path: &Path, cloud: &PointCloud, opts: &LasWriteOptions) -> Result<()> {
    let bounds = cloud.bounds();
    let offset = opts.offset_for(&bounds);
    let mut b = las::Builder::from((1, 2));
    b.point_format = las::point::Format::new(0).map_err(|e| Error::Internal(e.to_string()))?;
    b.generating_software = format!("terratile {}", env!("CARGO_PKG_VERSION"));
    b.system_identifier = "terratile".into();
    b.transforms = las::Vector {
        x: las::Transform {
            scale: opts.scale[0],
            offset: offset[0],
        },
        y: las::Transform {
            scale: opts.scale[1],
            offset: offset[1],
        },
        z: las::Transform {
            scale: opts.scale[2],
            offset: offset[2],
        },
    };
    if let Some(crs) = &opts.crs {
        b.vlrs = crs_vlrs(crs);
    }
    let header = b
        .into_header()
        .map_err(|e| Error::Internal(format!("LAS header: {e}")))?;
    // las::Writer wants to own a 'static writer, so the file is built in memory and then
    // written atomically.
    let buf = std::io::Cursor::new(Vec::with_capacity(cloud.len() * 20 + 4096));
    let mut writer = las::Writer::new(buf, header).map_err(|e| las_err(path, e))?;
    // The stored integers' range per axis, as las-rs rounds them (see the header patch).
    let mut stored = [[i64::MAX, i64::MIN]; 3];
    {
        for i in 0..cloud.len() {
            for (k, v) in [cloud.x[i], cloud.y[i], cloud.z[i]].into_iter().enumerate() {
                let n = ((v - offset[k]) / opts.scale[k]).round() as i64;
                stored[k] = [stored[k][0].min(n), stored[k][1].max(n)];
            }
            let class = opts
                .classification
                .or_else(|| cloud.classification.get(i).copied())
                .unwrap_or(1);
            let p = las::Point {
                x: cloud.x[i],
                y: cloud.y[i],
                z: cloud.z[i],
                intensity: cloud.intensity.get(i).copied().unwrap_or(0),
                return_number: cloud.return_number.get(i).copied().unwrap_or(1),
                number_of_returns: cloud.number_of_returns.get(i).copied().unwrap_or(1),
                classification: las::point::Classification::new(class)
                    .map_err(|e| las_err(path, e))?,
                ..Default::default()
            };
            writer.write_point(p).map_err(|e| las_err(path, e))?;
        }
    }
    let mut buf = writer
        .into_inner()
        .map_err(|e| las_err(path, e))?
        .into_inner();
    // las-rs writes the header's box rounded outward (floor and ceiling of each bound on the
    // lattice, in floating point), which can put a bound one step beyond the stored points
    // (156.76 / 0.01 is 15675.999…, floored to 15675). The LAS specification asks for the
    // points' actual extent, and a reader that trusts the box (the streamed run, which
    // checks it against the decoded points) would have to count again: so the box is
    // rewritten with the stored points' own, decoded as every reader decodes them. It lies
    // at a fixed place in every LAS version's header (bytes 179..227: max x, min x, max y,
    // min y, max z, min z); las-rs has no way to set it.
    if !cloud.is_empty() {
        let decoded = |k: usize, n: i64| opts.scale[k] * f64::from(n as i32) + offset[k];
        let mut at = 179;
        for (k, [lo, hi]) in stored.into_iter().enumerate() {
            for n in [hi, lo] {
                buf[at..at + 8].copy_from_slice(&decoded(k, n).to_le_bytes());
                at += 8;
            }
        }
    }
    crate::fsutil::write_bytes_atomic(path, &buf)
}

fn las_err(path: &Path, e: las::Error) -> Error {
    match e {
        las::Error::Io(io) => Error::io(path, io),
        other => Error::Usage(format!("{}: cannot write LAS: {other}", path.display())),
    }
}

/// Writes an uncompressed LAS holding `records` (whole records in `h`'s point format) with
/// `h`'s header fields, VLRs and CRS; counts and bounds are recomputed from the records.
pub fn write_raw_las(
    path: &Path,
    h: &LasHeader,
    records: &[u8],
    bounds: &super::Bounds,
) -> Result<()> {
    let len = h.record_length as usize;
    let n = (records.len() / len) as u64;
    let mut raw = h.raw.clone();
    raw.point_data_record_format = h.point_format;
    let vlrs: Vec<las::raw::Vlr> = h
        .vlrs
        .iter()
        .filter(|v| !v.is_laszip() && !v.extended && v.data.len() <= u16::MAX as usize)
        .map(|v| v.to_raw())
        .collect();
    raw.number_of_variable_length_records = vlrs.len() as u32;
    raw.evlr = None;
    let vlr_bytes: u64 = vlrs
        .iter()
        .map(|v| super::las_header::VLR_HEADER_SIZE + v.data.len() as u64)
        .sum();
    raw.offset_to_point_data = (raw.header_size as u64 + vlr_bytes) as u32;
    raw.number_of_point_records = if n <= u32::MAX as u64 && h.point_format < 6 {
        n as u32
    } else {
        0
    };
    if let Some(lf) = raw.large_file.as_mut() {
        lf.number_of_point_records = n;
        lf.number_of_points_by_return = [0; 15];
    }
    raw.number_of_points_by_return = [0; 5];
    let extended = h.point_format >= 6;
    for r in records.chunks_exact(len) {
        let ret = if extended { r[14] & 0x0F } else { r[14] & 0x07 };
        if (1..=5).contains(&ret) {
            raw.number_of_points_by_return[ret as usize - 1] += 1;
        }
        if let Some(lf) = raw.large_file.as_mut() {
            if (1..=15).contains(&ret) {
                lf.number_of_points_by_return[ret as usize - 1] += 1;
            }
        }
    }
    raw.min_x = bounds.min[0];
    raw.min_y = bounds.min[1];
    raw.min_z = bounds.min[2];
    raw.max_x = bounds.max[0];
    raw.max_y = bounds.max[1];
    raw.max_z = bounds.max[2];
    write_atomic(path, |w| {
        raw.write_to(&mut *w).map_err(|e| las_err(path, e))?;
        for v in &vlrs {
            v.write_to(&mut *w).map_err(|e| las_err(path, e))?;
        }
        std::io::Write::write_all(w, records).map_err(|e| Error::io(path, e))
    })
}

/// Writes the records of the cloud points flagged in `select` (one flag per point of the
/// cloud read from `sources` with `opts`) to an uncompressed LAS at `path`, byte for byte in
/// the inputs' point format (colour, GPS time and extra bytes kept), each with its class set
/// to `class`. Returns false, writing nothing, when the sources are not all LAS/LAZ of one
/// point format, record length, scale and offset (the caller then writes plain points).
pub fn write_selected_records(
    path: &Path,
    sources: &[super::SourceInfo],
    opts: &super::ReadOptions,
    select: &[bool],
    class: u8,
) -> Result<bool> {
    let n = select.len();
    write_records_with(path, sources, opts, n, |i| {
        select.get(i).copied().unwrap_or(false).then_some(class)
    })
}

/// Writes every record of the cloud read from `sources` with `opts` to an uncompressed LAS
/// at `path`, in order and byte for byte in the inputs' point format, with point `i`'s class
/// set to `classes[i]` (nothing else changes). Returns false, writing nothing, as
/// [`write_selected_records`] does.
pub fn write_reclassified_records(
    path: &Path,
    sources: &[super::SourceInfo],
    opts: &super::ReadOptions,
    classes: &[u8],
) -> Result<bool> {
    write_records_with(path, sources, opts, classes.len(), |i| {
        classes.get(i).copied()
    })
}

/// The world coordinates of a LAS record.
fn record_xyz(h: &LasHeader, r: &[u8]) -> [f64; 3] {
    std::array::from_fn(|k| {
        let v = i32::from_le_bytes([r[4 * k], r[4 * k + 1], r[4 * k + 2], r[4 * k + 3]]);
        h.scale[k] * f64::from(v) + h.offset[k]
    })
}

/// [`write_reclassified_records`] from records kept by [`super::read_keeping_records`]
/// instead of decoding the input again: sets record `i`'s class to `classes[i]` in place and
/// writes the records as an uncompressed LAS with the file's header (the same bytes).
pub fn write_reclassified_raw(
    path: &Path,
    raw: &mut super::RawRecords,
    classes: &[u8],
) -> Result<()> {
    use rayon::prelude::*;
    let h = &raw.header;
    let len = h.record_length as usize;
    if len == 0 || raw.records.len() != classes.len() * len {
        return Err(Error::Internal(format!(
            "{}: {} bytes of records for {} classes",
            path.display(),
            raw.records.len(),
            classes.len()
        )));
    }
    let extended = h.point_format >= 6;
    const CHUNK: usize = 1 << 16;
    let bounds = raw
        .records
        .par_chunks_mut(CHUNK * len)
        .zip(classes.par_chunks(CHUNK))
        .map(|(recs, cls)| {
            let mut b = super::Bounds::EMPTY;
            for (r, &class) in recs.chunks_exact_mut(len).zip(cls) {
                if extended {
                    r[16] = class;
                } else {
                    r[15] = (r[15] & 0xE0) | (class & 0x1F);
                }
                b.add(record_xyz(h, r));
            }
            b
        })
        .reduce(|| super::Bounds::EMPTY, super::Bounds::union);
    write_raw_las(path, h, &raw.records, &bounds)
}

/// The records of the `n` cloud points read from `sources` with `opts` for which `class_of`
/// (by point index) gives a class, written with that class.
fn write_records_with(
    path: &Path,
    sources: &[super::SourceInfo],
    opts: &super::ReadOptions,
    n: usize,
    mut class_of: impl FnMut(usize) -> Option<u8>,
) -> Result<bool> {
    use super::Format;
    let Some(first) = sources.first() else {
        return Ok(false);
    };
    let same = sources.iter().all(|s| {
        matches!(s.format, Format::Las | Format::Laz)
            && s.point_format == first.point_format
            && s.record_length == first.record_length
            && s.scale == first.scale
            && s.offset == first.offset
    });
    if !same {
        return Ok(false);
    }
    let mut header = None;
    let mut out: Vec<u8> = Vec::new();
    let mut bounds = super::Bounds::EMPTY;
    let mut index = 0usize;
    for s in sources {
        let map = super::map_file(&s.path)?;
        let h = LasHeader::parse(&s.path, &map)?;
        let len = h.record_length as usize;
        let extended = h.point_format >= 6;
        let mut left = s.points_read;
        super::las_read::for_each_batch(&s.path, &map, &h, |recs| {
            for r in recs.chunks_exact(len) {
                if left == 0 {
                    return Ok(false);
                }
                let c = if extended { r[16] } else { r[15] & 0x1F };
                if !opts.classes.keeps(c) {
                    continue;
                }
                left -= 1;
                let keep = class_of(index);
                index += 1;
                let Some(class) = keep else {
                    continue;
                };
                let at = out.len();
                out.extend_from_slice(r);
                let rec = &mut out[at..];
                if extended {
                    rec[16] = class;
                } else {
                    rec[15] = (rec[15] & 0xE0) | (class & 0x1F);
                }
                bounds.add(record_xyz(&h, r));
            }
            Ok(left > 0)
        })?;
        header.get_or_insert(h);
    }
    if index != n {
        return Err(Error::Internal(format!(
            "{}: re-reading the inputs found {index} points, the run read {n}",
            path.display(),
        )));
    }
    let Some(h) = header else {
        return Ok(false);
    };
    write_raw_las(path, &h, &out, &bounds)?;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The header's box is the stored points' own, to the bit, where las-rs would round a
    /// bound outward (156.76 / 0.01 is 15675.999… in floating point).
    #[test]
    fn the_header_box_is_the_stored_points_extent() {
        let mut cloud = PointCloud::default();
        for (x, y, z) in [
            (10.07, 5.03, 156.76),
            (12.29, 7.71, 474.13),
            (11.0, 6.0, 200.0),
        ] {
            cloud.x.push(x);
            cloud.y.push(y);
            cloud.z.push(z);
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("box.las");
        write_las(&path, &cloud, &LasWriteOptions::default()).unwrap();
        let b = std::fs::read(&path).unwrap();
        let f64_at = |at: usize| f64::from_le_bytes(b[at..at + 8].try_into().unwrap());
        let i32_at = |at: usize| i32::from_le_bytes(b[at..at + 4].try_into().unwrap());
        let (scale, offset) = (
            [f64_at(131), f64_at(139), f64_at(147)],
            [f64_at(155), f64_at(163), f64_at(171)],
        );
        let data = u32::from_le_bytes(b[96..100].try_into().unwrap()) as usize;
        let len = u16::from_le_bytes(b[105..107].try_into().unwrap()) as usize;
        for k in 0..3 {
            let decoded: Vec<f64> = (0..cloud.len())
                .map(|p| scale[k] * f64::from(i32_at(data + p * len + 4 * k)) + offset[k])
                .collect();
            let max = decoded.iter().copied().fold(f64::MIN, f64::max);
            let min = decoded.iter().copied().fold(f64::MAX, f64::min);
            assert_eq!(
                f64_at(179 + 16 * k).to_bits(),
                max.to_bits(),
                "max, axis {k}"
            );
            assert_eq!(
                f64_at(187 + 16 * k).to_bits(),
                min.to_bits(),
                "min, axis {k}"
            );
        }
    }
}
