//! Where the set lies, for the georeferenced encoders: the whole grid's GeoTIFF (`dem.tif`)
//! and each PNG heightmap's world file.

use super::geotiff;
use crate::error::Result;
use crate::terrain::TileSet;

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
    let grid = set.assemble();
    let values: Vec<f32> = grid.rows().into_iter().rev().flatten().copied().collect();
    drop(grid);
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
