//! One OpenEXR file per tile, written with the `exr` crate: f32 channels `height`
//! (world z − z_offset) and `d2` (Röttger's metric at node centres, 0 elsewhere), plus `mask`
//! (1 data, 0 hole) when the tile has holes. Scan lines run north to south (row 0 of the image
//! is the tile's northern row, as in any image viewer). The georeference is in header
//! attributes: `tileIndex`, `gridOffset`, `validSize` (int vectors), `originX`, `originY`
//! (world x, y of the tile's south-west sample, a cell centre), `cellSizeX`, `cellSizeY`,
//! `zOffset`, `roettgerC`, `roettgerK` (doubles), `crs` and `rowOrder` (text).
//!
//! Determinism: the `exr` crate keeps custom attributes in a `HashMap`, whose iteration order
//! changes from run to run, so the header's attributes are put back in name order after
//! encoding (the order OpenEXR's own library writes; the header keeps its length, so the
//! chunk offsets stay valid). Blocks are compressed on the calling thread, in line order: the
//! caller parallelises over tiles, and the bytes do not depend on the thread count.

use crate::error::{Error, Result};
use crate::terrain::{Quadtree, TileSet};
use exr::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::io::Cursor;
use std::path::Path;

/// Lossless EXR compressions offered for tiles.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ExrCompression {
    /// No compression (default: the whole pipeline's time matters most; RLE saves only
    /// 13–25 % of the bytes for about six times the encoding time, see the README's
    /// measurements).
    #[default]
    None,
    /// Run-length encoding.
    Rle,
    /// Deflate per scan line.
    Zips,
    /// Deflate per 16 scan lines: the smallest files, about 8× the encoding time of RLE.
    Zip,
    /// Wavelet + Huffman.
    Piz,
}

impl ExrCompression {
    /// Every choice, for measurements.
    pub const ALL: [ExrCompression; 5] = [
        ExrCompression::None,
        ExrCompression::Rle,
        ExrCompression::Zips,
        ExrCompression::Zip,
        ExrCompression::Piz,
    ];

    fn exr(self) -> Compression {
        match self {
            ExrCompression::None => Compression::Uncompressed,
            ExrCompression::Rle => Compression::RLE,
            ExrCompression::Zips => Compression::ZIP1,
            ExrCompression::Zip => Compression::ZIP16,
            ExrCompression::Piz => Compression::PIZ,
        }
    }

    /// The name used in pipeline.toml.
    pub fn name(self) -> &'static str {
        match self {
            ExrCompression::None => "none",
            ExrCompression::Rle => "rle",
            ExrCompression::Zips => "zips",
            ExrCompression::Zip => "zip",
            ExrCompression::Piz => "piz",
        }
    }
}

/// EXR text from a string (EXR text is Latin-1: other characters become `?`).
fn text(s: &str) -> Text {
    let latin: String = s
        .chars()
        .map(|c| if (c as u32) < 256 { c } else { '?' })
        .collect();
    Text::new_or_none(&latin).unwrap_or_else(|| Text::new_or_none("?").expect("ascii"))
}

/// Encodes tile `t` of `set` as an EXR file in memory.
pub fn encode_tile(
    set: &TileSet,
    qt: &Quadtree,
    t: usize,
    compression: ExrCompression,
) -> Result<Vec<u8>> {
    let tile = &set.tiles[t];
    let n = set.tile_size;
    // North row first.
    let flip = |a: &ndarray::Array2<f32>| -> Vec<f32> {
        let mut v = Vec::with_capacity(n * n);
        match a.as_slice() {
            // Tiles are built in standard layout: whole rows at a time.
            Some(s) => s.chunks_exact(n).rev().for_each(|r| v.extend_from_slice(r)),
            None => (0..n)
                .rev()
                .for_each(|j| v.extend(a.row(j).iter().copied())),
        }
        v
    };
    let mut channels: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
    channels.push(AnyChannel::new(
        "height",
        FlatSamples::F32(flip(&tile.heights)),
    ));
    let mut d2 = vec![0.0f32; n * n];
    qt.d2[t].for_each(|ci, cj, v| d2[(n - 1 - cj) * n + ci] = v);
    channels.push(AnyChannel::new("d2", FlatSamples::F32(d2)));
    if tile.holes > 0 {
        let mask = tile.heights.mapv(|h| if h.is_nan() { 0.0 } else { 1.0 });
        channels.push(AnyChannel::new("mask", FlatSamples::F32(flip(&mask))));
    }
    let mut attrs = LayerAttributes {
        software_name: Some(text(concat!("terratile ", env!("CARGO_PKG_VERSION")))),
        ..Default::default()
    };
    let other = &mut attrs.other;
    let iv = |a: usize, b: usize| AttributeValue::IntVec2(Vec2(a as i32, b as i32));
    other.insert(text("tileIndex"), iv(tile.col, tile.row));
    other.insert(text("gridOffset"), iv(tile.origin[0], tile.origin[1]));
    other.insert(text("validSize"), iv(tile.valid[0], tile.valid[1]));
    let [ox, oy] = set.sample_xy(tile.origin[0] as f64, tile.origin[1] as f64);
    other.insert(text("originX"), AttributeValue::F64(ox));
    other.insert(text("originY"), AttributeValue::F64(oy));
    other.insert(text("cellSizeX"), AttributeValue::F64(set.cell_size[0]));
    other.insert(text("cellSizeY"), AttributeValue::F64(set.cell_size[1]));
    other.insert(text("zOffset"), AttributeValue::F64(set.z_offset));
    other.insert(text("roettgerC"), AttributeValue::F64(qt.c));
    other.insert(text("roettgerK"), AttributeValue::F64(qt.k));
    other.insert(text("rowOrder"), AttributeValue::Text(text("north-first")));
    if let Some(crs) = &set.crs {
        other.insert(text("crs"), AttributeValue::Text(text(&crs.text())));
    }
    let encoding = Encoding {
        compression: compression.exr(),
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    // Room for the uncompressed samples, the line offsets and chunk headers and the header,
    // so that the buffer is not regrown (and copied) on the way.
    let capacity = n * n * 4 * channels.len() + 16 * n + 4096;
    let layer = Layer::new((n, n), attrs, encoding, AnyChannels::sort(channels));
    let image = Image::from_layer(layer);
    let mut buf = Cursor::new(Vec::with_capacity(capacity));
    image
        .write()
        .non_parallel()
        .to_buffered(&mut buf)
        .map_err(|e| Error::Internal(format!("exr encoding of tile {t}: {e}")))?;
    let mut bytes = buf.into_inner();
    sort_header_attributes(&mut bytes)?;
    Ok(bytes)
}

/// Rewrites the single-part header's attribute list of an EXR file in name order.
fn sort_header_attributes(bytes: &mut [u8]) -> Result<()> {
    let bad = || Error::Internal("exr header layout not understood".into());
    let flags = u32::from_le_bytes(
        bytes
            .get(4..8)
            .ok_or_else(bad)?
            .try_into()
            .map_err(|_| bad())?,
    );
    if flags & 0x1000 != 0 {
        // Multi-part files are not written here.
        return Err(bad());
    }
    let start = 8;
    let mut pos = start;
    let mut records: Vec<(Vec<u8>, std::ops::Range<usize>)> = Vec::new();
    let cstr = |p: usize| -> Result<usize> {
        let len = bytes
            .get(p..)
            .ok_or_else(bad)?
            .iter()
            .position(|&b| b == 0)
            .ok_or_else(bad)?;
        Ok(p + len)
    };
    loop {
        if *bytes.get(pos).ok_or_else(bad)? == 0 {
            break;
        }
        let name_end = cstr(pos)?;
        let type_end = cstr(name_end + 1)?;
        let size_at = type_end + 1;
        let size = i32::from_le_bytes(
            bytes
                .get(size_at..size_at + 4)
                .ok_or_else(bad)?
                .try_into()
                .map_err(|_| bad())?,
        );
        let end = size_at + 4 + usize::try_from(size).map_err(|_| bad())?;
        if end > bytes.len() {
            return Err(bad());
        }
        records.push((bytes[pos..name_end].to_vec(), pos..end));
        pos = end;
    }
    let mut sorted = records.clone();
    sorted.sort_by(|a, b| a.0.cmp(&b.0));
    let mut out = Vec::with_capacity(pos - start);
    for (_, r) in &sorted {
        out.extend_from_slice(&bytes[r.clone()]);
    }
    bytes[start..pos].copy_from_slice(&out);
    Ok(())
}

/// A tile read back from an EXR file.
#[derive(Debug, Clone, PartialEq)]
pub struct ExrTile {
    /// Samples per side.
    pub size: usize,
    /// Heights, `[row j, col i]` with row 0 south (flipped back from the file's order).
    pub height: ndarray::Array2<f32>,
    /// d2 at node centres, same layout.
    pub d2: ndarray::Array2<f32>,
    /// 1 data, 0 hole, when the file has a mask.
    pub mask: Option<ndarray::Array2<f32>>,
    /// The header's custom attributes, formatted as text.
    pub attributes: BTreeMap<String, String>,
}

/// Reads a tile written by [`encode_tile`].
pub fn read_tile(path: &Path) -> Result<ExrTile> {
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| Error::format(path, 0, format!("not a readable OpenEXR tile: {e}")))?;
    let layer = image.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    if w != h {
        return Err(Error::format(
            path,
            0,
            format!("tile is {w}×{h}, not square"),
        ));
    }
    let get = |name: &str| -> Option<ndarray::Array2<f32>> {
        let ch = layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name == text(name))?;
        let v: Vec<f32> = ch.sample_data.values_as_f32().collect();
        let mut a = ndarray::Array2::zeros((h, w));
        for (k, x) in v.into_iter().enumerate() {
            a[[h - 1 - k / w, k % w]] = x;
        }
        Some(a)
    };
    let missing = |c: &str| Error::format(path, 0, format!("no `{c}` channel"));
    let mut attributes = BTreeMap::new();
    for (k, v) in &layer.attributes.other {
        let s = match v {
            AttributeValue::Text(t) => t.to_string(),
            AttributeValue::F64(x) => format!("{x:?}"),
            AttributeValue::IntVec2(Vec2(a, b)) => format!("{a} {b}"),
            other => format!("{other:?}"),
        };
        attributes.insert(k.to_string(), s);
    }
    Ok(ExrTile {
        size: w,
        height: get("height").ok_or_else(|| missing("height"))?,
        d2: get("d2").ok_or_else(|| missing("d2"))?,
        mask: get("mask"),
        attributes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::quadtree::{build, QuadtreeParams};
    use crate::terrain::testutil::tiles_of;
    use crate::terrain::{CellState, Heightfield};

    #[test]
    fn round_trip_every_compression_and_fixed_attribute_order() {
        let mut hf = Heightfield::empty(100, 70, [5000.0, 7000.0], [0.5, 0.5], 100.0, None);
        for j in 0..70 {
            for i in 0..100 {
                hf.heights[[j, i]] = ((i * 31 + j * 17) % 97) as f32 * 0.37 - 5.0;
                hf.state[[j, i]] = CellState::Measured;
            }
        }
        hf.heights[[3, 4]] = f32::NAN;
        hf.state[[3, 4]] = CellState::Empty;
        let set = tiles_of(&hf, 65);
        let qt = build(&set, &QuadtreeParams::default()).unwrap();
        let dir = tempfile::tempdir().unwrap();
        for c in ExrCompression::ALL {
            for t in 0..set.tiles.len() {
                let a = encode_tile(&set, &qt, t, c).unwrap();
                // The attribute order no longer depends on the HashMap's seed.
                for _ in 0..3 {
                    assert_eq!(a, encode_tile(&set, &qt, t, c).unwrap());
                }
                let p = dir.path().join(format!("{}-{t}.exr", c.name()));
                std::fs::write(&p, &a).unwrap();
                let back = read_tile(&p).unwrap();
                let tl = &set.tiles[t];
                for (x, y) in back.height.iter().zip(tl.heights.iter()) {
                    assert_eq!(x.to_bits(), y.to_bits());
                }
                assert_eq!(back.d2, qt.d2[t].to_matrix());
                assert_eq!(back.mask.is_some(), t == 0);
                assert_eq!(
                    back.attributes["tileIndex"],
                    format!("{} {}", tl.col, tl.row)
                );
                assert_eq!(
                    back.attributes["validSize"],
                    format!("{} {}", tl.valid[0], tl.valid[1])
                );
                assert_eq!(back.attributes["zOffset"], "100.0");
                assert_eq!(
                    back.attributes["originX"],
                    format!("{:?}", 5000.25 + 0.5 * tl.origin[0] as f64)
                );
            }
        }
    }
}
