//! The `[output]` table: which encoders run, and their settings. It lives with the encoders
//! it switches (the pipeline file's schema in `config` only names it).

use crate::error::{check, Error, Result};
use crate::mesh::io::MeshFormat;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// `[output]`
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct OutputConfig {
    /// Output directory, relative to the pipeline file's directory (default `out`).
    #[serde(default = "default_out")]
    pub dir: PathBuf,
    /// Write one OpenEXR file per tile: height, d2 (and mask) channels (default true).
    #[serde(default = "yes")]
    pub exr: bool,
    /// EXR compression: `none` (default), `rle`, `zips`, `zip` or `piz`; all lossless.
    #[serde(default)]
    pub exr_compression: super::exr::ExrCompression,
    /// Write `manifest.json` (default true).
    #[serde(default = "yes")]
    pub manifest: bool,
    /// Write a 16-bit PNG heightmap per tile (default true).
    #[serde(default = "yes")]
    pub png: bool,
    /// Write a 16-bit RAW heightmap per tile, Unity's layout (default true).
    #[serde(default = "yes")]
    pub raw: bool,
    /// Write the shaded-relief preview `preview/relief.png` (default true).
    #[serde(default = "yes")]
    pub relief: bool,
    /// Write `preview/wireframe.png`, the CLOD mesh over the relief (default true).
    #[serde(default = "yes")]
    pub wireframe: bool,
    /// Tile mesh formats to write (default `["glb"]`; `[]` for none).
    #[serde(default = "default_meshes")]
    pub meshes: Vec<MeshFormat>,
    /// Write `dem.tif`, the whole heightfield as one Cloud-Optimized GeoTIFF (default false).
    #[serde(default)]
    pub geotiff: bool,
    /// Write `geotiff/tile_CCC_RRR.tif`, each tile's valid extent as a GeoTIFF (default false).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub geotiff_tiles: bool,
    /// Write `terrain/`, a Cesium quantized-mesh tileset (default false; needs the CRS).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub quantized_mesh: bool,
    /// Largest vertical distance, metres, between the tileset's meshes and each level's
    /// resampled heights (default 0.5).
    #[serde(
        default = "default_qmesh_tolerance",
        skip_serializing_if = "is_default_qmesh_tolerance"
    )]
    pub quantized_mesh_tolerance: f64,
    /// Keep the lattice meshes on the tileset's most detailed level too (default false: an
    /// adaptive triangulation within the tolerance of the grid's surface everywhere).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub quantized_mesh_lattice: bool,
    /// Longer side of the preview pictures in pixels (default 2048; small grids are
    /// enlarged at most 4×).
    #[serde(default = "default_preview_size")]
    pub preview_size: usize,
}

fn default_out() -> PathBuf {
    PathBuf::from("out")
}

fn yes() -> bool {
    true
}

fn default_meshes() -> Vec<MeshFormat> {
    MeshFormat::DEFAULT_TILE.to_vec()
}

fn default_qmesh_tolerance() -> f64 {
    crate::terrain::extract::DEFAULT_TOLERANCE_M
}

fn is_default_qmesh_tolerance(t: &f64) -> bool {
    *t == default_qmesh_tolerance()
}

fn default_preview_size() -> usize {
    2048
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            dir: default_out(),
            exr: true,
            exr_compression: Default::default(),
            manifest: true,
            png: true,
            raw: true,
            relief: true,
            wireframe: true,
            meshes: default_meshes(),
            geotiff: false,
            geotiff_tiles: false,
            quantized_mesh: false,
            quantized_mesh_tolerance: default_qmesh_tolerance(),
            quantized_mesh_lattice: false,
            preview_size: default_preview_size(),
        }
    }
}

impl OutputConfig {
    /// Checks the switches that have a range; errors name the key.
    pub fn validate(&self) -> Result<()> {
        if !(16..=16384).contains(&self.preview_size) {
            return Err(Error::param(
                "output",
                "preview_size",
                self.preview_size,
                "must be 16 to 16384 pixels",
            ));
        }
        check::positive(
            "output",
            "quantized_mesh_tolerance",
            self.quantized_mesh_tolerance,
            "must be > 0 metres",
        )
    }

    /// True when the switches ask for a mesh (files or the wireframe picture).
    pub fn wants_meshes(&self) -> bool {
        !self.meshes.is_empty() || self.wireframe
    }

    /// True when the switches ask for a 16-bit heightmap (PNG or RAW).
    pub fn wants_heightmaps(&self) -> bool {
        self.png || self.raw
    }

    /// True when the switches ask for a preview picture.
    pub fn wants_previews(&self) -> bool {
        self.relief || self.wireframe
    }
}
