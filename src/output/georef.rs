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
    let crs = set
        .crs
        .as_ref()
        .map(geotiff::GeoCrs::of)
        .unwrap_or_default();
    geotiff::encode_cog(
        geotiff::Raster {
            width: set.samples[0],
            height: set.samples[1],
            values: &values,
        },
        &grid_georef(set),
        &crs,
        geotiff::Values {
            nan_nodata: set.holes() > 0,
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
