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

/// DEFLATE level 1: miniz_oxide's fast greedy path. On autzen_full's grid after the predictor
/// (73 MB of tiles) it took 0.18 CPU-seconds for 43.0 % of the bytes, against 0.69 s for
/// 41.9 % at level 3 and 0.98 s for 41.6 % at level 6; zlib-rs took 0.43 s for 42.1 % at its
/// level 2 and 0.22 s for 47.0 % at level 1 (README, "Georeferenced outputs").
const DEFLATE_LEVEL: u32 = 1;

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
/// non-NaN values of each 2 × 2 block), until one fits in a tile. Every tile of every level is
/// compressed in one parallel pass (70 tiles for a 3253² grid: the small levels do not wait
/// for the large one); each tile's bytes depend on its pixels alone, so the file is the same
/// for any thread count.
fn levels(raster: Raster) -> Vec<Level> {
    let mut overviews: Vec<(usize, usize, Vec<f32>)> = Vec::new();
    let (mut w, mut h) = (raster.width, raster.height);
    while w > TILE || h > TILE {
        let src = overviews.last().map_or(raster.values, |o| &o.2[..]);
        let (nw, nh, half) = halve(src, w, h);
        overviews.push((nw, nh, half));
        (w, h) = (nw, nh);
    }
    let rasters: Vec<Raster> = std::iter::once(raster)
        .chain(overviews.iter().map(|(w, h, v)| Raster {
            width: *w,
            height: *h,
            values: v,
        }))
        .collect();
    let jobs: Vec<(usize, usize)> = rasters
        .iter()
        .enumerate()
        .flat_map(|(l, r)| {
            (0..r.width.div_ceil(TILE) * r.height.div_ceil(TILE)).map(move |t| (l, t))
        })
        .collect();
    let mut tiles = jobs
        .into_par_iter()
        .map_init(
            || (vec![0u8; TILE * TILE * 4], [0u8; TILE * 4]),
            |(bytes, planes), (l, t)| compress_tile(rasters[l], t, bytes, planes),
        )
        .collect::<Vec<_>>()
        .into_iter();
    rasters
        .iter()
        .map(|r| Level {
            width: r.width,
            height: r.height,
            tiles: tiles
                .by_ref()
                .take(r.width.div_ceil(TILE) * r.height.div_ceil(TILE))
                .collect(),
        })
        .collect()
}

/// The next overview of a `w × h` raster: `⌈w/2⌉ × ⌈h/2⌉`, each value the mean of the non-NaN
/// values of its 2 × 2 block (NaN when there are none; the last row and column of an odd
/// raster average what they have).
fn halve(src: &[f32], w: usize, h: usize) -> (usize, usize, Vec<f32>) {
    let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = vec![0.0; nw * nh];
    out.par_chunks_mut(nw).enumerate().for_each(|(j, row)| {
        let top = &src[2 * j * w..][..w];
        let bottom = (2 * j + 1 < h).then(|| &src[(2 * j + 1) * w..][..w]);
        for (i, v) in row.iter_mut().enumerate() {
            let x = 2 * i;
            let (mut sum, mut n) = (0.0f64, 0u32);
            let mut add = |z: f32| {
                if !z.is_nan() {
                    sum += z as f64;
                    n += 1;
                }
            };
            add(top[x]);
            if x + 1 < w {
                add(top[x + 1]);
            }
            if let Some(b) = bottom {
                add(b[x]);
                if x + 1 < w {
                    add(b[x + 1]);
                }
            }
            *v = if n == 0 {
                f32::NAN
            } else {
                (sum / n as f64) as f32
            };
        }
    });
    (nw, nh, out)
}

/// Tile `t` (row by row) of `r`, padded to TILE × TILE with zeros, predicted and deflated.
/// `bytes` (TILE² × 4) and `planes` (TILE × 4) are scratch space a thread reuses.
fn compress_tile(r: Raster, t: usize, bytes: &mut [u8], planes: &mut [u8; TILE * 4]) -> Vec<u8> {
    let tx = r.width.div_ceil(TILE);
    let (x0, y0) = ((t % tx) * TILE, (t / tx) * TILE);
    let n = TILE.min(r.width - x0);
    for (j, out) in bytes.chunks_exact_mut(TILE * 4).enumerate() {
        let row = match y0 + j < r.height {
            true => &r.values[(y0 + j) * r.width + x0..][..n],
            false => &[][..],
        };
        predict_row_into(row, planes, out);
    }
    let mut z = flate2::write::ZlibEncoder::new(
        Vec::with_capacity(bytes.len() / 2),
        flate2::Compression::new(DEFLATE_LEVEL),
    );
    // Writing into a Vec cannot fail.
    let _ = z.write_all(bytes);
    z.finish().unwrap_or_default()
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

/// [`predict_row`] for a tile row of TILE values whose first `row.len()` come from the
/// raster and the rest are zero padding, written to `out`; the byte planes go through
/// `planes` first so that both passes are straight loops the compiler vectorises (the
/// in-place backward difference above is not). `predict_row` is its slow, obvious twin.
fn predict_row_into(row: &[f32], planes: &mut [u8; TILE * 4], out: &mut [u8]) {
    let (p0, rest) = planes.split_at_mut(TILE);
    let (p1, rest) = rest.split_at_mut(TILE);
    let (p2, p3) = rest.split_at_mut(TILE);
    let padded = row.iter().copied().chain(std::iter::repeat(0.0));
    for ((((v, a), b), c), d) in padded.zip(p0).zip(p1.iter_mut()).zip(p2.iter_mut()).zip(p3) {
        [*a, *b, *c, *d] = v.to_be_bytes();
    }
    out[0] = planes[0];
    for (o, w) in out[1..].iter_mut().zip(planes.windows(2)) {
        *o = w[1].wrapping_sub(w[0]);
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

    /// The vectorised predictor is its slow twin's output, padding included.
    #[test]
    fn predictor_fast_path_matches_twin() {
        let mut planes = [0u8; TILE * 4];
        for n in [0, 1, 7, 300, TILE] {
            let row: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin() * 1e3).collect();
            let mut padded = row.clone();
            padded.resize(TILE, 0.0);
            let mut want = vec![0u8; TILE * 4];
            predict_row(&padded, &mut want);
            let mut got = vec![0xAAu8; TILE * 4];
            predict_row_into(&row, &mut planes, &mut got);
            assert_eq!(got, want, "{n} values");
        }
    }

    /// Each overview value is the mean of its block's non-NaN values (odd sizes: the last row
    /// and column average what they have).
    #[test]
    fn halve_is_the_block_mean() {
        let (w, h) = (7, 5);
        let v = grid(w, h);
        let (nw, nh, o) = halve(&v, w, h);
        assert_eq!((nw, nh), (4, 3));
        for j in 0..nh {
            for i in 0..nw {
                let block: Vec<f64> = [(0, 0), (0, 1), (1, 0), (1, 1)]
                    .iter()
                    .map(|(dj, di)| (2 * j + dj, 2 * i + di))
                    .filter(|&(y, x)| y < h && x < w && !v[y * w + x].is_nan())
                    .map(|(y, x)| v[y * w + x] as f64)
                    .collect();
                let want = match block.len() {
                    0 => f32::NAN,
                    n => (block.iter().sum::<f64>() / n as f64) as f32,
                };
                assert_eq!(o[j * nw + i].to_bits(), want.to_bits(), "({i}, {j})");
            }
        }
    }

    /// Same bytes with 1 and 3 threads (tiles of several levels compressed at once).
    #[test]
    fn same_bytes_any_thread_count() {
        let (w, h) = (1100, 1030);
        let v = grid(w, h);
        let encode = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                encode_cog(
                    Raster {
                        width: w,
                        height: h,
                        values: &v,
                    },
                    &Georef {
                        west: 0.0,
                        north: 0.0,
                        pixel: [1.0, 1.0],
                    },
                    &GeoCrs::default(),
                    Values::default(),
                )
                .unwrap()
            })
        };
        assert_eq!(encode(1), encode(3));
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
