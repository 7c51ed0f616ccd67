//! The tile set's manifest (`manifest.json`): everything an engine importer needs, and enough
//! to put the heightfield back together exactly from the EXR tiles: the whole grid's size,
//! origin and spacing, the tile grid, each tile's place in the grid (`grid_offset`) and valid
//! extent, the row order of every file kind, the 16-bit height encoding, C and K, the CRS.
//!
//! Reassembly: for each tile, read the EXR `height` channel (row 0 north), flip it to south
//! first, and copy its `valid` columns × rows to `grid_offset` in a `samples` grid; world
//! z = `grid.z_offset` + height.

use crate::output::heightmap::HeightEncoding;
use crate::points::Crs;
use serde::{Deserialize, Serialize};

/// Manifest format version.
pub const MANIFEST_VERSION: u32 = 1;

/// `manifest.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Always `terratile-tiles`.
    pub format: String,
    /// Manifest format version.
    pub version: u32,
    /// The program that wrote it.
    pub generator: String,
    /// Coordinate reference system, when the input stated one.
    pub crs: Option<ManifestCrs>,
    /// The whole grid.
    pub grid: GridInfo,
    /// The tile layout.
    pub tiling: TilingInfo,
    /// Röttger's constants the d2 channels were computed with.
    pub quadtree: QuadtreeInfo,
    /// The 16-bit heightmaps' encoding and layout.
    pub heightmaps: HeightmapInfo,
    /// The tile meshes, when written.
    pub meshes: Option<MeshInfo>,
    /// Preview pictures (relative paths), when written.
    pub previews: Vec<String>,
    /// Unity terrain settings, under the `unity` preset.
    pub unity: Option<UnityInfo>,
    /// Unreal landscape settings, under the `unreal` preset.
    pub unreal: Option<UnrealInfo>,
    /// The tiles, row by row from the south, west to east.
    pub tiles: Vec<TileEntry>,
}

/// CRS facts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ManifestCrs {
    /// Short text: `EPSG:n`, else WKT, else GeoTIFF keys.
    pub text: String,
    /// EPSG code when stated.
    pub epsg: Option<u32>,
    /// OGC WKT when the file carried it.
    pub wkt: Option<String>,
    /// Metres per horizontal unit (1 for metres, 0.3048 for international feet).
    pub metres_per_unit: f64,
}

impl ManifestCrs {
    /// From the reader's CRS.
    pub fn of(c: &Crs) -> ManifestCrs {
        ManifestCrs {
            text: c.text(),
            epsg: c.epsg,
            wkt: c.wkt.clone(),
            metres_per_unit: c.metres_per_unit(),
        }
    }
}

/// The whole grid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridInfo {
    /// Samples (columns, rows).
    pub samples: [usize; 2],
    /// Samples of the heightfield before a preset resampled it.
    pub source_samples: [usize; 2],
    /// Distance between samples (x, y), CRS units.
    pub cell_size: [f64; 2],
    /// World x, y of the grid's outer south-west corner.
    pub corner: [f64; 2],
    /// World x, y of sample (0, 0), the south-west cell centre.
    pub first_sample: [f64; 2],
    /// World z of stored height 0 (EXR heights are relative to it).
    pub z_offset: f64,
    /// World z range of the data (null when all holes).
    pub z_range: Option<[f64; 2]>,
    /// Hole samples (masked in the EXR files; 0 in the 16-bit heightmaps).
    pub holes: usize,
}

/// The tile layout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TilingInfo {
    /// Samples per tile side (2^k + 1).
    pub tile_size: usize,
    /// Tiles in x and y.
    pub grid: [usize; 2],
    /// Distance in samples between neighbouring tiles' origins (tile_size − 1: they share a
    /// border row/column).
    pub step: usize,
    /// Engine preset.
    pub preset: String,
    /// EXR compression, when EXR tiles were written.
    pub exr_compression: Option<String>,
    /// EXR channels and what they hold.
    pub exr_channels: Vec<String>,
    /// Scan line order of EXR files.
    pub exr_row_order: String,
}

/// Röttger's constants.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct QuadtreeInfo {
    /// Minimum global resolution C.
    pub c: f64,
    /// K = C / (2 (C − 1)).
    pub k: f64,
    /// Quadtree depth of a tile (tile_size = 2^levels + 1).
    pub levels: u32,
    /// Units and placement of d2.
    pub d2: String,
    /// Reconciliation across tile borders.
    pub borders: String,
}

/// The 16-bit heightmaps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeightmapInfo {
    /// World z = z_offset + value · z_scale.
    pub z_scale: f64,
    /// World z of value 0.
    pub z_offset: f64,
    /// Value of holes (null: no holes).
    pub nodata: Option<u16>,
    /// PNG row order.
    pub png_rows: String,
    /// Per-tile RAW layout.
    pub raw_layout: String,
    /// Whole-landscape heightmap files (unreal preset).
    pub landscape: Vec<String>,
}

/// The tile meshes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeshInfo {
    /// Formats written.
    pub formats: Vec<String>,
    /// World x, y, z of the meshes' origin (sample (0, 0) at `grid.z_offset`).
    pub origin: [f64; 3],
    /// Axes of each format.
    pub axes: String,
    /// Units of each format's positions (glb: metres; PLY and OBJ: CRS units).
    #[serde(default)]
    pub units: String,
    /// How the meshes were triangulated.
    pub criterion: String,
    /// Skirt depth, height units (0: none).
    pub skirt_depth: f64,
}

/// Unity terrain settings (one Terrain per tile, neighbours sharing edges).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UnityInfo {
    /// TerrainData.heightmapResolution.
    pub heightmap_resolution: usize,
    /// TerrainData.size: x width, y height range, z length, in metres (Unity's unit).
    pub terrain_size: [f64; 3],
    /// World height of heightmap value 0 (Terrain position y), in metres.
    pub position_y: f64,
}

/// Unreal landscape settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UnrealInfo {
    /// Landscape resolution (x, y) in samples.
    pub resolution: [usize; 2],
    /// Landscape scale in centimetres per unit step (x, y, z), as the import dialog wants it.
    pub scale_cm: [f64; 3],
    /// Landscape location z in centimetres so that the heights land at world z.
    pub location_z_cm: f64,
}

/// One tile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TileEntry {
    /// Tile column (east).
    pub col: usize,
    /// Tile row (north), 0 in the south.
    pub row: usize,
    /// Global sample index of the tile's south-west sample.
    pub grid_offset: [usize; 2],
    /// Samples of real data from the south-west corner (columns, rows).
    pub valid: [usize; 2],
    /// World x, y of the tile's south-west sample.
    pub origin: [f64; 2],
    /// World z range of the tile's valid samples.
    pub z_range: Option<[f64; 2]>,
    /// Hole samples in the valid extent.
    pub holes: usize,
    /// Surface triangles of the tile mesh, when extracted.
    pub triangles: Option<usize>,
    /// Files of this tile, by kind (`exr`, `png`, `raw`, `ply`, `obj`, `glb`), relative paths.
    pub files: std::collections::BTreeMap<String, String>,
}

impl HeightmapInfo {
    /// From the encoding.
    pub fn of(enc: &HeightEncoding, landscape: Vec<String>) -> HeightmapInfo {
        HeightmapInfo {
            z_scale: enc.z_scale,
            z_offset: enc.z_offset,
            nodata: enc.nodata,
            png_rows: "north-first".into(),
            raw_layout: "u16 little-endian, south row first (Unity; per tile); landscape .r16 north row first (Unreal)"
                .into(),
            landscape,
        }
    }
}
