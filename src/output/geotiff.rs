//! Cloud-Optimized GeoTIFF of a heightfield: f32, 512 × 512 internal tiles, DEFLATE with the
//! floating-point predictor, overviews halving down to one tile, and the GeoKeys of the CRS.
//!
//! Layout (what GDAL's COG driver writes and `rio cogeo validate` checks): the header, then
//! every IFD (full resolution first, then the overviews from the largest), then the IFDs'
//! out-of-line values, then the tile data of the smallest overview first and of the full
//! resolution last. A reader fetching the first few kilobytes knows where every tile is.
//!
//! The `tiff` crate writes the container (header, IFD entries and their chain). Its image
//! encoder writes strips only, places each IFD after its own values (so the main IFD would
//! not open the file) and has no floating-point predictor, so three things are ours: the
//! layout (each IFD's entries point into a value area whose place we compute before writing
//! them), the predictor (Adobe's TIFF Technote 3: bytes of a row split into planes, most
//! significant first, then byte differences) and the GeoKey directory (no Rust crate writes
//! GeoKeys; `tiff` only knows their tag numbers).

use crate::error::{Error, Result};
use rayon::prelude::*;
use std::io::{Cursor, Write};
use tiff::decoder::ifd::Entry;
use tiff::encoder::{TiffEncoder, TiffKind, TiffKindBig, TiffKindStandard};
use tiff::tags::{Tag, Type};

/// Tile edge in pixels (GDAL's COG default).
pub const TILE: usize = 512;

/// DEFLATE level: 6 (zlib's default) costs twice the time for 2 % smaller DEMs.
const DEFLATE_LEVEL: u32 = 3;

/// A north-up raster of f32 values, row 0 the northern one.
#[derive(Debug, Clone, Copy)]
pub struct Raster<'a> {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width × height` values, row by row from the north, west to east.
    pub values: &'a [f32],
}

/// Where the raster lies: the outer north-west corner of pixel (0, 0) and the pixel size, in
/// CRS units (GDAL's geotransform `[west, pixel[0], 0, north, 0, −pixel[1]]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Georef {
    /// X of the western edge.
    pub west: f64,
    /// Y of the northern edge.
    pub north: f64,
    /// Pixel width and height (both positive).
    pub pixel: [f64; 2],
}

/// The CRS as GeoKeys say it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GeoCrs {
    /// EPSG code of the CRS, when known.
    pub epsg: Option<u32>,
    /// True for a geographic (longitude, latitude) CRS.
    pub geographic: bool,
    /// The CRS as WKT, used when there is no EPSG code (written as GDAL's `ESRI PE String`
    /// citation, which GDAL parses back).
    pub wkt: Option<String>,
    /// EPSG code of the horizontal linear unit (9001 metre, 9002 foot, 9003 US survey foot).
    pub linear_unit: Option<u16>,
    /// EPSG code of the vertical CRS (5713: CGVD28 height), when stated.
    pub vertical_epsg: Option<u16>,
    /// Name of the vertical datum, when stated.
    pub vertical_citation: Option<String>,
    /// EPSG code of the vertical unit, when stated.
    pub vertical_unit: Option<u16>,
}

/// What else the file says about its values.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Values {
    /// Write `GDAL_NODATA = nan` (holes are NaN).
    pub nan_nodata: bool,
    /// World z = `offset` + value (GDAL's band offset; omitted when 0).
    pub offset: f64,
}

/// One resolution level: its size and its tiles, compressed, row by row.
struct Level {
    width: usize,
    height: usize,
    tiles: Vec<Vec<u8>>,
}

/// The whole file.
pub fn encode_cog(
    raster: Raster,
    georef: &Georef,
    crs: &GeoCrs,
    values: Values,
) -> Result<Vec<u8>> {
    if raster.width == 0
        || raster.height == 0
        || raster.values.len() != raster.width * raster.height
    {
        return Err(Error::Internal(format!(
            "geotiff: {} values for a {} × {} raster",
            raster.values.len(),
            raster.width,
            raster.height
        )));
    }
    let levels = levels(raster);
    let data: usize = levels.iter().flat_map(|l| &l.tiles).map(Vec::len).sum();
    // Classic TIFF addresses 4 GiB; leave room for the directories.
    if data as u64 + (1 << 20) < u32::MAX as u64 {
        write_file::<TiffKindStandard>(&levels, georef, crs, values)
    } else {
        write_file::<TiffKindBig>(&levels, georef, crs, values)
    }
}

/// Full resolution and the overviews (each half the previous one, rounded up, averaging the
/// non-NaN values of each 2 × 2 block), until one fits in a tile.
fn levels(raster: Raster) -> Vec<Level> {
    let mut out = vec![Level {
        width: raster.width,
        height: raster.height,
        tiles: compress_tiles(raster),
    }];
    let mut cur: Vec<f32>;
    let (mut w, mut h) = (raster.width, raster.height);
    let mut src = raster.values;
    let mut owned;
    while w > TILE || h > TILE {
        let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
        cur = vec![0.0; nw * nh];
        cur.par_chunks_mut(nw).enumerate().for_each(|(j, row)| {
            for (i, v) in row.iter_mut().enumerate() {
                let (mut sum, mut n) = (0.0f64, 0u32);
                for (dj, di) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                    let (y, x) = (2 * j + dj, 2 * i + di);
                    if y < h && x < w && !src[y * w + x].is_nan() {
                        sum += src[y * w + x] as f64;
                        n += 1;
                    }
                }
                *v = if n == 0 {
                    f32::NAN
                } else {
                    (sum / n as f64) as f32
                };
            }
        });
        owned = cur;
        out.push(Level {
            width: nw,
            height: nh,
            tiles: compress_tiles(Raster {
                width: nw,
                height: nh,
                values: &owned,
            }),
        });
        src = &owned;
        (w, h) = (nw, nh);
    }
    out
}

/// The raster's tiles, row by row, each padded to TILE × TILE with zeros, predicted and
/// deflated.
fn compress_tiles(r: Raster) -> Vec<Vec<u8>> {
    let (tx, ty) = (r.width.div_ceil(TILE), r.height.div_ceil(TILE));
    (0..tx * ty)
        .into_par_iter()
        .map(|t| {
            let (x0, y0) = ((t % tx) * TILE, (t / tx) * TILE);
            let mut bytes = vec![0u8; TILE * TILE * 4];
            let mut row = [0f32; TILE];
            for (j, out) in bytes.chunks_exact_mut(TILE * 4).enumerate() {
                row.fill(0.0);
                if y0 + j < r.height {
                    let n = TILE.min(r.width - x0);
                    let at = (y0 + j) * r.width + x0;
                    row[..n].copy_from_slice(&r.values[at..at + n]);
                }
                predict_row(&row, out);
            }
            let mut z = flate2::write::ZlibEncoder::new(
                Vec::with_capacity(bytes.len() / 3),
                flate2::Compression::new(DEFLATE_LEVEL),
            );
            // Writing into a Vec cannot fail.
            let _ = z.write_all(&bytes);
            z.finish().unwrap_or_default()
        })
        .collect()
}

/// TIFF's floating-point predictor (Predictor = 3) on one row: byte plane k holds byte k of
/// every value's big-endian form, then every byte becomes its difference to the one before.
pub fn predict_row(row: &[f32], out: &mut [u8]) {
    let n = row.len();
    for (i, v) in row.iter().enumerate() {
        for (k, b) in v.to_be_bytes().into_iter().enumerate() {
            out[k * n + i] = b;
        }
    }
    for i in (1..out.len()).rev() {
        out[i] = out[i].wrapping_sub(out[i - 1]);
    }
}

/// An IFD entry's value before the layout is known: its type, count and bytes (in the
/// file's byte order, the machine's: the `tiff` crate writes native-endian files).
struct Value {
    ty: Type,
    count: usize,
    bytes: Vec<u8>,
}

fn shorts(v: &[u16]) -> Value {
    Value {
        ty: Type::SHORT,
        count: v.len(),
        bytes: v.iter().flat_map(|x| x.to_ne_bytes()).collect(),
    }
}

fn doubles(v: &[f64]) -> Value {
    Value {
        ty: Type::DOUBLE,
        count: v.len(),
        bytes: v.iter().flat_map(|x| x.to_ne_bytes()).collect(),
    }
}

fn ascii(s: &str) -> Value {
    let mut bytes = s.as_bytes().to_vec();
    bytes.push(0);
    Value {
        ty: Type::ASCII,
        count: bytes.len(),
        bytes,
    }
}

fn long(v: u32) -> Value {
    Value {
        ty: Type::LONG,
        count: 1,
        bytes: v.to_ne_bytes().to_vec(),
    }
}

/// Offsets in the file's offset type (LONG, or LONG8 in a BigTIFF).
fn offsets<K: TiffKind>(v: impl Iterator<Item = u64>) -> Value {
    let big = std::mem::size_of::<K::OffsetType>() == 8;
    let bytes: Vec<u8> = if big {
        v.flat_map(|x| x.to_ne_bytes()).collect()
    } else {
        v.flat_map(|x| (x as u32).to_ne_bytes()).collect()
    };
    Value {
        ty: if big { Type::LONG8 } else { Type::LONG },
        count: bytes.len() / if big { 8 } else { 4 },
        bytes,
    }
}

/// GeoKeyDirectory, GeoDoubleParams and GeoAsciiParams for `crs` (GeoTIFF 1.1, raster type
/// PixelIsArea).
fn geokeys(crs: &GeoCrs) -> (Vec<u16>, Vec<u8>) {
    const USER_DEFINED: u16 = 32767;
    let mut keys: Vec<[u16; 4]> = Vec::new();
    let mut text = String::new();
    let mut cite = |keys: &mut Vec<[u16; 4]>, id: u16, s: &str| {
        let s = s.replace('|', "/");
        keys.push([id, 34737, (s.len() + 1) as u16, text.len() as u16]);
        text.push_str(&s);
        text.push('|');
    };
    let code = crs.epsg.and_then(|c| u16::try_from(c).ok());
    match (code, &crs.wkt) {
        (Some(c), _) => {
            keys.push([1024, 0, 1, if crs.geographic { 2 } else { 1 }]);
            keys.push([if crs.geographic { 2048 } else { 3072 }, 0, 1, c]);
        }
        (None, Some(w)) => {
            // GDAL reads a CRS of user-defined model type whose PCSCitation is an "ESRI PE
            // String" as that WKT (ESRI's and OGC's WKT1 both).
            keys.push([1024, 0, 1, USER_DEFINED]);
            cite(&mut keys, 3073, &format!("ESRI PE String = {w}"));
        }
        (None, None) => {}
    }
    keys.push([1025, 0, 1, 1]);
    if let (false, Some(u)) = (crs.geographic, crs.linear_unit) {
        keys.push([3076, 0, 1, u]);
    }
    if let Some(v) = crs.vertical_epsg {
        keys.push([4096, 0, 1, v]);
    }
    if let Some(c) = &crs.vertical_citation {
        cite(&mut keys, 4097, c);
    }
    if let Some(u) = crs.vertical_unit {
        keys.push([4099, 0, 1, u]);
    }
    keys.sort_by_key(|k| k[0]);
    let mut dir = vec![1, 1, 1, keys.len() as u16];
    dir.extend(keys.iter().flatten());
    (dir, text.into_bytes())
}

/// Every IFD's tags, with `data_offsets[level]` the file offset of each tile of that level.
fn directories<K: TiffKind>(
    levels: &[Level],
    data_offsets: &[Vec<u64>],
    georef: &Georef,
    crs: &GeoCrs,
    values: Values,
) -> Vec<Vec<(u16, Value)>> {
    let (keydir, keytext) = geokeys(crs);
    let mut metadata = String::new();
    if values.offset != 0.0 {
        metadata = format!(
            "<GDALMetadata><Item name=\"OFFSET\" sample=\"0\" role=\"offset\">{:?}</Item>\
             <Item name=\"SCALE\" sample=\"0\" role=\"scale\">1</Item></GDALMetadata>",
            values.offset
        );
    }
    levels
        .iter()
        .zip(data_offsets)
        .enumerate()
        .map(|(l, (level, offs))| {
            let mut tags = vec![];
            if l > 0 {
                tags.push((254, long(1))); // NewSubfileType: reduced resolution
            }
            tags.extend([
                (256, long(level.width as u32)),
                (257, long(level.height as u32)),
                (258, shorts(&[32])),
                (259, shorts(&[8])), // Adobe DEFLATE
                (262, shorts(&[1])), // BlackIsZero
                (277, shorts(&[1])),
                (284, shorts(&[1])),
                (317, shorts(&[3])), // floating-point predictor
                (322, shorts(&[TILE as u16])),
                (323, shorts(&[TILE as u16])),
                (324, offsets::<K>(offs.iter().copied())),
                (
                    325,
                    offsets::<K>(level.tiles.iter().map(|t| t.len() as u64)),
                ),
                (339, shorts(&[3])), // IEEE float
            ]);
            if l == 0 {
                tags.push((33550, doubles(&[georef.pixel[0], georef.pixel[1], 0.0])));
                tags.push((
                    33922,
                    doubles(&[0.0, 0.0, 0.0, georef.west, georef.north, 0.0]),
                ));
                tags.push((34735, shorts(&keydir)));
                if !keytext.is_empty() {
                    let mut t = keytext.clone();
                    t.push(0);
                    tags.push((
                        34737,
                        Value {
                            ty: Type::ASCII,
                            count: t.len(),
                            bytes: t,
                        },
                    ));
                }
                if !metadata.is_empty() {
                    tags.push((42112, ascii(&metadata)));
                }
            }
            if values.nan_nodata {
                tags.push((42113, ascii("nan")));
            }
            tags
        })
        .collect()
}

fn write_file<K: TiffKind>(
    levels: &[Level],
    georef: &Georef,
    crs: &GeoCrs,
    values: Values,
) -> Result<Vec<u8>> {
    let big = std::mem::size_of::<K::OffsetType>() == 8;
    let (header, entry, fixed): (usize, usize, usize) = if big { (16, 20, 16) } else { (8, 12, 6) };
    let inline = if big { 8 } else { 4 };
    let err = |e: tiff::TiffError| Error::Internal(format!("geotiff: {e}"));
    // The layout depends only on the number of entries and the sizes of their values, which
    // placeholder offsets already have.
    let zeros: Vec<Vec<u64>> = levels.iter().map(|l| vec![0; l.tiles.len()]).collect();
    let dirs = directories::<K>(levels, &zeros, georef, crs, values);
    // The crate starts every IFD at a multiple of 4 bytes.
    let ifds_end = dirs.iter().fold(header, |at, d| {
        at.next_multiple_of(4) + fixed + entry * d.len()
    });
    let value_bytes: usize = dirs
        .iter()
        .flatten()
        .filter(|(_, v)| v.bytes.len() > inline)
        .map(|(_, v)| v.bytes.len().next_multiple_of(8))
        .sum();
    let data_start = (ifds_end + value_bytes) as u64;
    // Tile data: smallest overview first, full resolution last.
    let mut at = data_start;
    let mut data_offsets = zeros;
    for (l, level) in levels.iter().enumerate().rev() {
        for (t, tile) in level.tiles.iter().enumerate() {
            data_offsets[l][t] = at;
            at += tile.len() as u64;
        }
    }
    let dirs = directories::<K>(levels, &data_offsets, georef, crs, values);

    let mut file = Cursor::new(Vec::with_capacity(at as usize));
    let mut value_area = Vec::with_capacity(value_bytes);
    {
        let mut enc = TiffEncoder::<_, K>::new_generic(&mut file).map_err(err)?;
        for tags in &dirs {
            let mut entries = tiff::Directory::empty();
            for (tag, v) in tags {
                let mut off = [0u8; 8];
                if v.bytes.len() > inline {
                    let pos = ifds_end as u64 + value_area.len() as u64;
                    if big {
                        off = pos.to_ne_bytes();
                    } else {
                        off[..4].copy_from_slice(&(pos as u32).to_ne_bytes());
                    }
                    value_area.extend_from_slice(&v.bytes);
                    value_area.resize(value_area.len().next_multiple_of(8), 0);
                } else {
                    off[..v.bytes.len()].copy_from_slice(&v.bytes);
                }
                let e = if big {
                    Entry::new_u64(v.ty, v.count as u64, off)
                } else {
                    Entry::new(v.ty, v.count as u32, [off[0], off[1], off[2], off[3]])
                };
                entries.extend([(Tag::from_u16_exhaustive(*tag), e)]);
            }
            let mut d = enc.image_directory().map_err(err)?;
            d.extend_from(&entries);
            d.finish().map_err(err)?;
        }
    }
    let mut bytes = file.into_inner();
    if bytes.len() != ifds_end || value_area.len() != value_bytes {
        return Err(Error::Internal(format!(
            "geotiff: directories took {} bytes, {ifds_end} planned",
            bytes.len()
        )));
    }
    bytes.extend_from_slice(&value_area);
    for level in levels.iter().rev() {
        for tile in &level.tiles {
            bytes.extend_from_slice(tile);
        }
    }
    debug_assert_eq!(bytes.len() as u64, at);
    Ok(bytes)
}

impl GeoCrs {
    /// The GeoKeys' view of a CRS read from the input.
    pub fn of(c: &crate::points::Crs) -> GeoCrs {
        let geographic = match c.epsg.and_then(crate::geo::epsg_proj_string) {
            Some(p) => p.contains("+proj=longlat"),
            None => c
                .wkt
                .as_deref()
                .is_some_and(|w| w.trim_start().starts_with("GEOG")),
        };
        let linear_unit = c.unit.as_ref().and_then(|u| {
            [(1.0, 9001), (0.3048, 9002), (1200.0 / 3937.0, 9003)]
                .iter()
                .find(|(m, _)| (u.metres - m).abs() < 1e-12)
                .map(|&(_, code)| code)
        });
        let vertical = c.vertical.as_ref();
        GeoCrs {
            epsg: c.epsg,
            geographic,
            wkt: c.wkt.clone(),
            linear_unit,
            vertical_epsg: vertical
                .and_then(|v| v.epsg)
                .and_then(|e| u16::try_from(e).ok()),
            vertical_citation: vertical.and_then(|v| v.name.clone()),
            vertical_unit: vertical
                .and_then(|v| v.unit_epsg)
                .and_then(|e| u16::try_from(e).ok()),
        }
    }
}

/// An ESRI world file (`.pgw`, `.tfw`): pixel size, rotation terms, and the centre of the
/// north-west pixel, one number a line.
pub fn world_file(georef: &Georef) -> String {
    format!(
        "{:?}\n0\n0\n{:?}\n{:?}\n{:?}\n",
        georef.pixel[0],
        -georef.pixel[1],
        georef.west + 0.5 * georef.pixel[0],
        georef.north - 0.5 * georef.pixel[1]
    )
}

/// A GDAL PAM file (`.aux.xml`) giving a raster's CRS.
pub fn pam_xml(wkt: &str) -> String {
    let esc = wkt
        .replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;");
    format!("<PAMDataset>\n  <SRS dataAxisToSRSAxisMapping=\"1,2\">{esc}</SRS>\n</PAMDataset>\n")
}

#[cfg(test)]
mod tests {
    use super::*;
    use tiff::decoder::{Decoder, DecodingResult};

    fn grid(w: usize, h: usize) -> Vec<f32> {
        (0..w * h)
            .map(|k| {
                let (i, j) = ((k % w) as f32, (k / w) as f32);
                if k % 97 == 5 {
                    f32::NAN
                } else {
                    100.0 + (i * 0.013).sin() * 20.0 + j * 0.25
                }
            })
            .collect()
    }

    fn decode_all(bytes: &[u8]) -> Vec<(u32, u32, Vec<f32>)> {
        let mut dec = Decoder::new(Cursor::new(bytes)).unwrap();
        let mut out = vec![];
        loop {
            let (w, h) = dec.dimensions().unwrap();
            let DecodingResult::F32(v) = dec.read_image().unwrap() else {
                panic!("not f32")
            };
            out.push((w, h, v));
            if !dec.more_images() {
                break;
            }
            dec.next_image().unwrap();
        }
        out
    }

    /// The tiff crate's decoder (an independent implementation of the predictor and the
    /// container) reads every level back; the full resolution bit for bit.
    #[test]
    fn decodes_bit_for_bit() {
        let (w, h) = (1300, 700);
        let v = grid(w, h);
        let crs = GeoCrs {
            epsg: Some(32632),
            linear_unit: Some(9001),
            ..Default::default()
        };
        let georef = Georef {
            west: 500000.0,
            north: 5400000.0,
            pixel: [1.0, 1.0],
        };
        let bytes = encode_cog(
            Raster {
                width: w,
                height: h,
                values: &v,
            },
            &georef,
            &crs,
            Values {
                nan_nodata: true,
                offset: 0.0,
            },
        )
        .unwrap();
        let levels = decode_all(&bytes);
        assert_eq!(
            levels.iter().map(|l| (l.0, l.1)).collect::<Vec<_>>(),
            vec![(1300, 700), (650, 350), (325, 175)]
        );
        let back = &levels[0].2;
        assert_eq!(back.len(), v.len());
        for (a, b) in back.iter().zip(&v) {
            assert_eq!(a.to_bits(), b.to_bits());
        }
        // The overview is the mean of each 2 × 2 block's values.
        let o = &levels[1].2;
        let want = (v[0] as f64 + v[1] as f64 + v[w] as f64 + v[w + 1] as f64) / 4.0;
        assert_eq!(o[0], want as f32);
        // The main IFD opens the file, right after the header.
        assert_eq!(u32::from_le_bytes(bytes[4..8].try_into().unwrap()), 8);
    }

    #[test]
    fn predictor_matches_definition() {
        let row = [1.5f32, -2.25, 3.0];
        let mut out = [0u8; 12];
        predict_row(&row, &mut out);
        // Undo: prefix sums, then gather the planes.
        let mut acc = out;
        for i in 1..acc.len() {
            acc[i] = acc[i].wrapping_add(acc[i - 1]);
        }
        for (i, v) in row.iter().enumerate() {
            let b = [acc[i], acc[3 + i], acc[6 + i], acc[9 + i]];
            assert_eq!(f32::from_be_bytes(b), *v);
        }
    }

    #[test]
    fn geokeys_epsg_and_wkt() {
        let (dir, text) = geokeys(&GeoCrs {
            epsg: Some(3005),
            linear_unit: Some(9001),
            vertical_epsg: Some(5713),
            vertical_citation: Some("CGVD28".into()),
            vertical_unit: Some(9001),
            ..Default::default()
        });
        assert_eq!(&dir[..4], &[1, 1, 1, 7]);
        assert!(dir.chunks(4).any(|k| k == [3072, 0, 1, 3005]));
        assert!(dir.chunks(4).any(|k| k == [4096, 0, 1, 5713]));
        assert_eq!(text, b"CGVD28|");
        let (dir, text) = geokeys(&GeoCrs {
            wkt: Some("PROJCS[\"x\"]".into()),
            ..Default::default()
        });
        assert!(dir.chunks(4).any(|k| k == [1024, 0, 1, 32767]));
        assert_eq!(text, b"ESRI PE String = PROJCS[\"x\"]|");
    }
}
