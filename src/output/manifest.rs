//! The tile set's manifest (`manifest.json`): everything an engine importer needs, and enough
//! to put the heightfield back together exactly from the EXR tiles: the whole grid's size,
//! origin and spacing, the tile grid, each tile's place in the grid (`grid_offset`) and valid
//! extent, the row order of every file kind, the 16-bit height encoding, C and K, the CRS.
//!
//! Reassembly: for each tile, read the EXR `height` channel (row 0 north), flip it to south
//! first, and copy its `valid` columns × rows to `grid_offset` in a `samples` grid; world
//! z = `grid.z_offset` + height.

use super::heightmap::{self, HeightEncoding};
use super::{OutputConfig, SetSummary};
use crate::points::Crs;
use crate::terrain::Preset;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Centimetres per metre: Unreal's landscape figures are in centimetres.
const CM_PER_M: f64 = 100.0;

/// Unreal's landscape height: height(cm) = location_z + (value − UNREAL_MID_VALUE) · scale_z
/// / UNREAL_Z_DIVISOR, for a 16-bit value.
const UNREAL_MID_VALUE: f64 = 32768.0;

/// See [`UNREAL_MID_VALUE`].
const UNREAL_Z_DIVISOR: f64 = 128.0;

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
    /// Where the grid lies on the globe (WGS 84), when the CRS is known and reprojectable.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geographic: Option<Geographic>,
    /// Files of the whole grid, by kind, relative paths: `geotiff` (`dem.tif`) and
    /// `cesium_terrain` (the Cesium tileset's `terrain/layer.json`), when written.
    #[serde(default)]
    pub grid_files: std::collections::BTreeMap<String, String>,
    /// The tiles, row by row from the south, west to east.
    pub tiles: Vec<TileEntry>,
}

/// The grid on the globe.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Geographic {
    /// WGS 84 longitude/latitude bounds of the grid's outer extent: [west, south, east, north],
    /// degrees (of its four corners and edge midpoints).
    pub wgs84_bounds: Option<[f64; 4]>,
    /// The grid's outer extent as a GeoJSON Polygon (WGS 84, longitude first, counter-clockwise).
    pub footprint: Option<serde_json::Value>,
    /// The PROJ string the reprojection used.
    pub proj_string: Option<String>,
    /// Why there are no WGS 84 figures, when there are none.
    pub unsupported: Option<String>,
    /// The heights' vertical CRS when the input states it (`CGVD28`, EPSG 5713); null: not stated.
    pub vertical_datum: Option<crate::points::VerticalCrs>,
    /// Tile rows count from the south (row 0 is the southern row), columns from the west.
    pub tile_rows: String,
}

/// The geographic block of a set: the WGS 84 corners through [`crate::geo::ToWgs84`].
pub fn geographic(set: &SetSummary) -> Option<Geographic> {
    let crs = set.crs.as_ref()?;
    let [x0, y0] = set.corner;
    let x1 = x0 + set.samples[0] as f64 * set.cell_size[0];
    let y1 = y0 + set.samples[1] as f64 * set.cell_size[1];
    let (xm, ym) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let mut g = Geographic {
        wgs84_bounds: None,
        footprint: None,
        proj_string: None,
        unsupported: None,
        vertical_datum: crs.vertical.clone(),
        tile_rows: "row 0 is the southern row; rows count north, columns east".into(),
    };
    match crate::geo::ToWgs84::new(crs) {
        Err(e) => g.unsupported = Some(e.to_string()),
        Ok(t) => {
            // Counter-clockwise from the south-west corner, edge midpoints included.
            let ring = [
                (x0, y0),
                (xm, y0),
                (x1, y0),
                (x1, ym),
                (x1, y1),
                (xm, y1),
                (x0, y1),
                (x0, ym),
            ];
            let pts: Option<Vec<[f64; 2]>> = ring.iter().map(|&(x, y)| t.forward(x, y)).collect();
            match pts {
                None => {
                    g.unsupported = Some("the grid's corners fall outside the projection".into())
                }
                Some(p) => {
                    let fold = |f: fn(f64, f64) -> f64, k: usize, init: f64| {
                        p.iter().map(|q| q[k]).fold(init, f)
                    };
                    g.wgs84_bounds = Some([
                        fold(f64::min, 0, f64::INFINITY),
                        fold(f64::min, 1, f64::INFINITY),
                        fold(f64::max, 0, f64::NEG_INFINITY),
                        fold(f64::max, 1, f64::NEG_INFINITY),
                    ]);
                    let mut closed = p.clone();
                    closed.push(p[0]);
                    g.footprint =
                        Some(serde_json::json!({"type": "Polygon", "coordinates": [closed]}));
                    g.proj_string = Some(t.proj_string.clone());
                }
            }
        }
    }
    Some(g)
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
    /// The same channels, structured: name, sample type, units, what a value means, and in
    /// which tiles the channel is present.
    #[serde(default)]
    pub exr_channel_info: Vec<ExrChannel>,
    /// Scan line order of EXR files.
    pub exr_row_order: String,
}

/// One EXR channel, for readers that want more than a sentence.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExrChannel {
    /// Channel name in the EXR file.
    pub name: String,
    /// Sample type (`f32`).
    pub sample_type: String,
    /// Units of a value: `crs_units` (the CRS's horizontal unit, `crs.metres_per_unit` m),
    /// `crs_units_per_sample`, or `none`.
    pub units: String,
    /// World value of a sample: `z_offset + value` (height), `value` (d2, mask).
    pub world: String,
    /// What the value means.
    pub meaning: String,
    /// `every_tile`, or `tiles_with_holes`.
    pub present: String,
    /// The value at holes, when the channel has one (`NaN` for height).
    pub nodata: Option<String>,
}

impl ExrChannel {
    fn new(name: &str, units: &str, world: &str, meaning: &str, present: &str) -> ExrChannel {
        ExrChannel {
            name: name.into(),
            sample_type: "f32".into(),
            units: units.into(),
            world: world.into(),
            meaning: meaning.into(),
            present: present.into(),
            nodata: None,
        }
    }

    /// The channels terratile writes.
    pub fn all() -> Vec<ExrChannel> {
        vec![
            ExrChannel {
                nodata: Some("NaN".into()),
                ..ExrChannel::new(
                    "height",
                    "crs_units",
                    "grid.z_offset + value",
                    "height of the sample",
                    "every_tile",
                )
            },
            ExrChannel::new(
                "d2",
                "crs_units_per_sample",
                "value",
                "Röttger's d2 at quadtree node centres (see quadtree.d2), 0 elsewhere",
                "every_tile",
            ),
            ExrChannel::new(
                "mask",
                "none",
                "value",
                "1 where the sample has data, 0 at a hole",
                "tiles_with_holes",
            ),
        ]
    }
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

/// The files the encoders wrote, by kind: what the manifest lists besides the set.
#[derive(Debug, Clone, Default)]
pub struct Written {
    /// Per tile, in the set's order: its files by kind (`exr`, `png`, …), relative paths.
    pub tiles: Vec<BTreeMap<String, String>>,
    /// The whole-landscape heightmaps (unreal preset).
    pub landscape: Vec<String>,
    /// The preview pictures.
    pub previews: Vec<String>,
}

/// The manifest of `set` as written with `out` (heightmaps in `enc`), listing `written`.
pub fn build(
    set: &SetSummary,
    out: &OutputConfig,
    enc: &HeightEncoding,
    written: Written,
) -> Manifest {
    let first = set.sample_xy(0.0, 0.0);
    let z_range = set.z_range;
    let unit_m = set.metres_per_unit();
    let Written {
        tiles: per_tile,
        landscape,
        previews,
    } = written;
    let tiles = set
        .tiles
        .iter()
        .zip(per_tile)
        .map(|(tile, files)| TileEntry {
            col: tile.col,
            row: tile.row,
            grid_offset: tile.origin,
            valid: tile.valid,
            origin: set.sample_xy(tile.origin[0] as f64, tile.origin[1] as f64),
            z_range: tile
                .z_range
                .map(|[lo, hi]| [set.z_offset + lo as f64, set.z_offset + hi as f64]),
            holes: tile.holes,
            triangles: tile.triangles,
            files,
        })
        .collect();
    Manifest {
        format: "terratile-tiles".into(),
        version: MANIFEST_VERSION,
        generator: concat!("terratile ", env!("CARGO_PKG_VERSION")).into(),
        crs: set.crs.as_ref().map(ManifestCrs::of),
        grid: GridInfo {
            samples: set.samples,
            source_samples: set.source_samples,
            cell_size: set.cell_size,
            corner: set.corner,
            first_sample: first,
            z_offset: set.z_offset,
            z_range: z_range.map(|(a, b)| [a, b]),
            holes: set.holes,
        },
        tiling: TilingInfo {
            tile_size: set.tile_size,
            grid: set.grid,
            step: set.tile_size - 1,
            preset: format!("{:?}", set.preset).to_lowercase(),
            exr_compression: out.exr.then(|| out.exr_compression.name().to_string()),
            exr_channels: vec![
                "height: f32, world z − grid.z_offset, NaN at holes".into(),
                "d2: f32, Röttger's d2 at node centres (0 elsewhere)".into(),
                "mask: f32, 1 data / 0 hole (only in tiles with holes)".into(),
            ],
            exr_channel_info: ExrChannel::all(),
            exr_row_order: "north-first".into(),
        },
        quadtree: QuadtreeInfo {
            c: set.quadtree_ck[0],
            k: set.quadtree_ck[1],
            levels: set.levels(),
            d2: "height units per sample spacing: (1/d)·max|Δh| over the 4 edge midpoints and both diagonals, d in samples; \
                 stored at the node's centre sample; divide by the spacing for Röttger's dimensionless d2"
                .into(),
            borders: "propagated with K across tiles; nodes touching a shared border hold the maximum of their mirror group, \
                      so a tile's own d2 decides its neighbours' subdivision along the border"
                .into(),
        },
        heightmaps: HeightmapInfo::of(enc, landscape),
        meshes: set
            .meshes
            .as_ref()
            .filter(|_| !out.meshes.is_empty())
            .map(|m| MeshInfo {
                formats: out.meshes.iter().map(|f| f.ext().to_string()).collect(),
                origin: [first[0], first[1], set.z_offset],
                axes: "glb: x east, y up, z south (glTF); others: x east, y north, z up".into(),
                units: format!(
                    "glb: metres (glTF); ply, obj: CRS units ({unit_m} m each), like the EXR tiles; \
                     origin: CRS units"
                ),
                criterion: m.criterion.clone(),
                skirt_depth: m.skirt_depth,
            }),
        previews,
        unity: (set.preset == Preset::Unity).then(|| UnityInfo {
            heightmap_resolution: set.tile_size,
            terrain_size: [
                (set.tile_size - 1) as f64 * set.cell_size[0] * unit_m,
                heightmap::MAX_VALUE * enc.z_scale * unit_m,
                (set.tile_size - 1) as f64 * set.cell_size[1] * unit_m,
            ],
            position_y: enc.z_offset * unit_m,
        }),
        unreal: (set.preset == Preset::Unreal).then(|| {
            // Unreal: height(cm) = location_z + (value − 32768) · scale_z / 128.
            let scale_z = CM_PER_M * UNREAL_Z_DIVISOR * enc.z_scale * unit_m;
            UnrealInfo {
                resolution: set.samples,
                scale_cm: [set.cell_size[0] * unit_m * CM_PER_M, set.cell_size[1] * unit_m * CM_PER_M, scale_z],
                location_z_cm: enc.z_offset * unit_m * CM_PER_M + UNREAL_MID_VALUE / UNREAL_Z_DIVISOR * scale_z,
            }
        }),
        geographic: geographic(set),
        grid_files: grid_files(out),
        tiles,
    }
}

/// The whole-grid files `out` writes (the run fails as a whole if one of them cannot be).
fn grid_files(out: &OutputConfig) -> std::collections::BTreeMap<String, String> {
    let mut files = std::collections::BTreeMap::new();
    if out.geotiff {
        files.insert("geotiff".into(), super::georef::DEM_FILE.into());
    }
    if out.quantized_mesh {
        files.insert("cesium_terrain".into(), super::qmesh::layer_path());
    }
    files
}
