//! 16-bit heightmaps: one PNG and one RAW per tile, and under the `unreal` preset
//! one of each for the whole landscape. One encoding for the whole set, so that neighbouring
//! tiles agree on their shared border: world z = `z_offset` + value · `z_scale`. When the set
//! has holes, value 0 is reserved for them (`nodata`) and data runs from 1 to 65535.
//!
//! Layouts: PNG rows run north to south (any image viewer, and Unreal's importer, which maps
//! image rows to +Y, i.e. south, in its left-handed frame). Per-tile RAW is Unity's layout:
//! little-endian u16, the first row the southern one (Unity's `heights[y, x]` has y = 0 at the
//! terrain's origin; import without "Flip Vertically"). The landscape `.r16` follows Unreal,
//! north first, little-endian.

use crate::error::{Error, Result};
use crate::output::SetSummary;
use crate::terrain::TileSet;
use ndarray::Array2;
use serde::Serialize;

/// How 16-bit values map to world heights.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct HeightEncoding {
    /// World z units per step.
    pub z_scale: f64,
    /// World z of value 0.
    pub z_offset: f64,
    /// The value of hole samples, when the set has holes.
    pub nodata: Option<u16>,
}

/// The largest 16-bit height value, as the encodings compute with it.
pub const MAX_VALUE: f64 = u16::MAX as f64;

impl HeightEncoding {
    /// The encoding spanning the set's z range with all 16 bits.
    pub fn for_set(set: &SetSummary) -> HeightEncoding {
        // Padding repeats valid samples, so a tile has a NaN anywhere only if its valid
        // extent counts a hole.
        let holes = set.tiles.iter().any(|t| t.holes > 0);
        let (lo, hi) = set.z_range.unwrap_or((set.z_offset, set.z_offset));
        let first = if holes { 1.0 } else { 0.0 };
        let steps = MAX_VALUE - first;
        let z_scale = if hi > lo { (hi - lo) / steps } else { 1.0 };
        HeightEncoding {
            z_scale,
            z_offset: lo - first * z_scale,
            nodata: holes.then_some(0),
        }
    }

    /// The 16-bit value of a world height (NaN: the hole value).
    #[inline]
    pub fn encode(&self, z: f64) -> u16 {
        if z.is_nan() {
            return self.nodata.unwrap_or(0);
        }
        let lowest = if self.nodata.is_some() { 1.0 } else { 0.0 };
        ((z - self.z_offset) / self.z_scale)
            .round()
            .clamp(lowest, MAX_VALUE) as u16
    }

    /// World height of a value (None for the hole value).
    pub fn decode(&self, v: u16) -> Option<f64> {
        (self.nodata != Some(v)).then_some(self.z_offset + v as f64 * self.z_scale)
    }
}

/// Values of tile `t`, south row first, `tile_size`² of them (padding included).
pub fn tile_values(set: &TileSet, enc: &HeightEncoding, t: usize) -> Vec<u16> {
    let h = &set.tiles[t].heights;
    match h.as_slice() {
        // Tiles are built in standard layout: a plain slice iterator, which the collect
        // below sizes exactly (ndarray's own iterator does not tell its length).
        Some(s) => encode_heights(set.z_offset, enc, s.iter().copied()),
        None => encode_heights(set.z_offset, enc, h.iter().copied()),
    }
}

/// Values of the whole grid (`heights`, assembled from the tiles, heights relative to
/// `z_offset`), south row first.
pub fn landscape_values(heights: &Array2<f32>, z_offset: f64, enc: &HeightEncoding) -> Vec<u16> {
    encode_heights(z_offset, enc, heights.iter().copied())
}

/// `enc.encode(z_offset + h)` for every stored height h, with the constants hoisted (one
/// formula for tiles and landscape, so they agree to the bit).
fn encode_heights(
    z_offset: f64,
    enc: &HeightEncoding,
    heights: impl Iterator<Item = f32>,
) -> Vec<u16> {
    let (base, inv) = (z_offset - enc.z_offset, 1.0 / enc.z_scale);
    let lowest = if enc.nodata.is_some() { 1.0 } else { 0.0 };
    let hole = enc.nodata.unwrap_or(0);
    heights
        .map(|h| {
            if h.is_nan() {
                hole
            } else {
                ((base + h as f64) * inv + 0.5).clamp(lowest, MAX_VALUE) as u16
            }
        })
        .collect()
}

/// A 16-bit greyscale PNG of `values` (`width` wide, south row first), north row on top.
///
/// Through the `png` crate itself rather than `image`'s encoder, which takes native-endian
/// samples and makes a big-endian copy of them before encoding: the big-endian bytes are
/// written here in the one pass that flips the rows (same encoder settings, so the same
/// file to the byte).
pub fn png_bytes(values: &[u16], width: usize) -> Result<Vec<u8>> {
    let w = width.max(1);
    let height = values.len() / w;
    let mut raw = vec![0u8; w * height * 2];
    for (out, row) in raw
        .chunks_exact_mut(w * 2)
        .zip(values.chunks_exact(w).rev())
    {
        for (o, v) in out.chunks_exact_mut(2).zip(row) {
            o.copy_from_slice(&v.to_be_bytes());
        }
    }
    let bad = |e: png::EncodingError| Error::Internal(format!("png encoding: {e}"));
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    // Paeth: as small as the adaptive choice on real tiles, and faster (measured).
    enc.set_compression(png::Compression::Fast);
    enc.set_filter(png::Filter::Paeth);
    enc.write_header()
        .map_err(bad)?
        .write_image_data(&raw)
        .map_err(bad)?;
    Ok(out)
}

/// Little-endian u16 RAW; `north_first` flips the rows (Unreal) or keeps them south first
/// (Unity).
pub fn raw_bytes(values: &[u16], width: usize, north_first_rows: bool) -> Vec<u8> {
    let w = width.max(1);
    let mut out = vec![0u8; values.len() * 2];
    let put = |(o, row): (&mut [u8], &[u16])| {
        for (b, v) in o.chunks_exact_mut(2).zip(row) {
            b.copy_from_slice(&v.to_le_bytes());
        }
    };
    let dst = out.chunks_mut(w * 2);
    if north_first_rows {
        dst.zip(values.chunks(w).rev()).for_each(put);
    } else {
        dst.zip(values.chunks(w)).for_each(put);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::testutil::tiles_of;
    use crate::terrain::{CellState, Heightfield};

    fn set(hole: bool) -> TileSet {
        let mut hf = Heightfield::empty(80, 70, [0.0, 0.0], [1.0, 1.0], 0.0, None);
        for j in 0..70 {
            for i in 0..80 {
                hf.heights[[j, i]] = 100.0 + i as f32 * 0.25 - j as f32 * 0.125;
                hf.state[[j, i]] = CellState::Measured;
            }
        }
        if hole {
            hf.heights[[5, 5]] = f32::NAN;
            hf.state[[5, 5]] = CellState::Empty;
        }
        tiles_of(&hf, 65)
    }

    fn summary(s: &TileSet) -> SetSummary {
        let qt = crate::terrain::quadtree::build(s, &Default::default()).unwrap();
        SetSummary::of(s, &qt, None)
    }

    #[test]
    fn encoding_spans_the_range_within_half_a_step() {
        for hole in [false, true] {
            let s = set(hole);
            let e = HeightEncoding::for_set(&summary(&s));
            let (lo, hi) = s.z_range().unwrap();
            assert_eq!(e.nodata.is_some(), hole);
            assert_eq!(e.encode(lo), if hole { 1 } else { 0 });
            assert_eq!(e.encode(hi), 65535);
            for t in 0..s.tiles.len() {
                let v = tile_values(&s, &e, t);
                for (h, v) in s.tiles[t].heights.iter().zip(&v) {
                    match e.decode(*v) {
                        Some(z) => assert!((z - *h as f64).abs() <= e.z_scale / 2.0 + 1e-9),
                        None => assert!(h.is_nan()),
                    }
                }
            }
        }
    }

    #[test]
    fn png_reads_back_north_up_and_raw_is_little_endian() {
        let s = set(false);
        let e = HeightEncoding::for_set(&summary(&s));
        let v = tile_values(&s, &e, 0);
        let png = png_bytes(&v, 65).unwrap();
        let img = image::load_from_memory(&png).unwrap().into_luma16();
        assert_eq!(img.dimensions(), (65, 65));
        // Image row 0 is the tile's northern row (j = 64).
        assert_eq!(img.get_pixel(3, 0).0[0], v[64 * 65 + 3]);
        assert_eq!(img.get_pixel(3, 64).0[0], v[3]);
        let raw = raw_bytes(&v, 65, false);
        assert_eq!(u16::from_le_bytes([raw[6], raw[7]]), v[3]);
        let raw_n = raw_bytes(&v, 65, true);
        assert_eq!(u16::from_le_bytes([raw_n[6], raw_n[7]]), v[64 * 65 + 3]);
    }

    /// The slow twins: `image`'s PNG encoder on native-endian samples (what `png_bytes` did
    /// before calling `png` itself) and the RAW bytes value by value.
    #[test]
    fn png_and_raw_bytes_equal_their_slow_twins() {
        use image::codecs::png::{CompressionType, FilterType, PngEncoder};
        use image::{ExtendedColorType, ImageEncoder};
        let mut rng = crate::rng::SplitMix64::new(11);
        for (w, h) in [(65usize, 65usize), (1, 7), (9, 1), (257, 3)] {
            let v: Vec<u16> = (0..w * h)
                .map(|k| match k % 5 {
                    0 => (rng.unit() * 65535.0) as u16,
                    _ => (1000 + k % 97) as u16,
                })
                .collect();
            let mut ne = Vec::new();
            for row in v.chunks(w).rev() {
                ne.extend(row.iter().flat_map(|x| x.to_ne_bytes()));
            }
            let mut want = Vec::new();
            PngEncoder::new_with_quality(&mut want, CompressionType::Fast, FilterType::Paeth)
                .write_image(&ne, w as u32, h as u32, ExtendedColorType::L16)
                .unwrap();
            assert_eq!(png_bytes(&v, w).unwrap(), want, "{w} × {h}");
            for north in [false, true] {
                let rows: Vec<&[u16]> = if north {
                    v.chunks(w).rev().collect()
                } else {
                    v.chunks(w).collect()
                };
                let want: Vec<u8> = rows
                    .iter()
                    .flat_map(|r| r.iter().flat_map(|x| x.to_le_bytes()))
                    .collect();
                assert_eq!(raw_bytes(&v, w, north), want, "{w} × {h} {north}");
            }
        }
    }
}
