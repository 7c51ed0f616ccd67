//! Where the set lies, for the georeferenced encoders: the whole grid's GeoTIFF (`dem.tif`)
//! and each PNG heightmap's world file.

use super::geotiff;
use crate::error::Result;
use crate::terrain::TileSet;
use rayon::prelude::*;

/// The Cloud-Optimized GeoTIFF of the whole grid.
pub const DEM_FILE: &str = "dem.tif";

/// The whole grid's outer north-west corner and spacing.
pub fn grid_georef(set: &TileSet) -> geotiff::Georef {
    geotiff::Georef {
        west: set.corner[0],
        north: set.corner[1] + set.samples[1] as f64 * set.cell_size[1],
        pixel: set.cell_size,
    }
}

/// `dem.tif`: the grid's heights (the EXR tiles' f32 values, north row first), NaN at holes;
/// world z = `z_offset` + value (GDAL's band offset).
pub fn dem_geotiff(set: &TileSet) -> Result<Vec<u8>> {
    let values = north_up(set);
    let [width, height] = set.samples;
    cog_of(
        set,
        width,
        height,
        &values,
        grid_georef(set),
        set.holes() > 0,
    )
}

/// The whole grid, north row first, straight from the tiles' valid extents in parallel (NaN
/// where no tile has data): `TileSet::assemble` with its rows reversed, without the second
/// copy of the grid.
pub fn north_up(set: &TileSet) -> Vec<f32> {
    let [cols, rows] = set.samples;
    let mut values = vec![f32::NAN; cols * rows];
    values
        .par_chunks_mut(cols.max(1))
        .enumerate()
        .for_each(|(r, out)| {
            let y = rows - 1 - r;
            for t in &set.tiles {
                if (t.origin[1]..t.origin[1] + t.valid[1]).contains(&y) {
                    let src = t.heights.row(y - t.origin[1]);
                    let dst = &mut out[t.origin[0]..t.origin[0] + t.valid[0]];
                    for (d, s) in dst.iter_mut().zip(src) {
                        *d = *s;
                    }
                }
            }
        });
    values
}

/// `geotiff/tile_CCC_RRR.tif` (`geotiff_tiles = true`): tile `t`'s valid extent (no padding)
/// as a GeoTIFF like `dem.tif`, north row first.
pub fn tile_geotiff(set: &TileSet, t: usize) -> Result<Vec<u8>> {
    let tile = &set.tiles[t];
    let [w, h] = tile.valid;
    let values: Vec<f32> = (0..h)
        .rev()
        .flat_map(|j| (0..w).map(move |i| tile.heights[[j, i]]))
        .collect();
    let georef = geotiff::Georef {
        west: set.corner[0] + tile.origin[0] as f64 * set.cell_size[0],
        north: set.corner[1] + (tile.origin[1] + h) as f64 * set.cell_size[1],
        pixel: set.cell_size,
    };
    cog_of(set, w, h, &values, georef, tile.holes > 0)
}

/// A `width × height` raster of `set` (north row first) as a COG in the set's CRS.
fn cog_of(
    set: &TileSet,
    width: usize,
    height: usize,
    values: &[f32],
    georef: geotiff::Georef,
    nan_nodata: bool,
) -> Result<Vec<u8>> {
    let crs = set
        .crs
        .as_ref()
        .map(geotiff::GeoCrs::of)
        .unwrap_or_default();
    geotiff::encode_cog(
        geotiff::Raster {
            width,
            height,
            values,
        },
        &georef,
        &crs,
        geotiff::Values {
            nan_nodata,
            offset: set.z_offset,
        },
    )
}

/// The world file of tile `t`'s PNG heightmap: every pixel, padding included, at its sample.
pub fn world_file(set: &TileSet, t: usize) -> String {
    let tile = &set.tiles[t];
    let n = set.tile_size as f64;
    geotiff::world_file(&geotiff::Georef {
        west: set.corner[0] + tile.origin[0] as f64 * set.cell_size[0],
        north: set.corner[1] + (tile.origin[1] as f64 + n) * set.cell_size[1],
        pixel: set.cell_size,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::tiles::{tile, TileParams};
    use crate::terrain::{CellState, Heightfield};

    /// `north_up` is `assemble` with its rows reversed, holes included.
    #[test]
    fn north_up_is_assemble_reversed() {
        let (w, h) = (150, 100);
        let mut hf = Heightfield::empty(w, h, [0.0, 0.0], [1.0, 1.0], 0.0, None);
        for j in 0..h {
            for i in 0..w {
                if (i * 7 + j * 3) % 11 != 0 {
                    hf.heights[[j, i]] = (i * 100 + j) as f32;
                    hf.state[[j, i]] = CellState::Measured;
                }
            }
        }
        let set = tile(
            &hf,
            &TileParams {
                size: Some(65),
                ..Default::default()
            },
        )
        .unwrap();
        let want: Vec<u32> = set
            .assemble()
            .rows()
            .into_iter()
            .rev()
            .flatten()
            .map(|v| v.to_bits())
            .collect();
        let got: Vec<u32> = north_up(&set).iter().map(|v| v.to_bits()).collect();
        assert_eq!(got, want);
    }
}
