//! Tile encoders: one file per tile from that tile's products. A new per-tile format is one
//! new variant here (its directory, extension, manifest key and `encode` arm) and one new
//! file with its encoder.

use super::heightmap::{self, HeightEncoding};
use super::{exr, OutputConfig, TerrainProducts};
use crate::error::{Error, Result};
use crate::mesh::io::MeshFormat;
use crate::mesh::TriMesh;
use std::sync::OnceLock;

/// One per-tile output format and its settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TileEncoder {
    /// OpenEXR: height, d2 and (with holes) mask channels.
    Exr(exr::ExrCompression),
    /// 16-bit greyscale PNG, north up.
    Png,
    /// 16-bit little-endian RAW, south row first (Unity).
    Raw,
    /// The tile's mesh in a mesh file format.
    Mesh(MeshFormat),
    /// The PNG's world file (`.pgw`): where its pixels lie in the CRS.
    WorldFile,
    /// The PNG's `.prj`: the CRS as WKT (ESRI's tools read it).
    Prj,
    /// The PNG's GDAL PAM file (`.png.aux.xml`): the same WKT, where GDAL and QGIS look.
    PngAux,
    /// The tile's valid extent as a Cloud-Optimized GeoTIFF (f32, like `dem.tif`).
    GeoTiff,
}

impl TileEncoder {
    /// The tile encoders `out` switches on, in the order they write.
    pub fn for_settings(out: &OutputConfig) -> Vec<TileEncoder> {
        let mut v = Vec::new();
        if out.exr {
            v.push(TileEncoder::Exr(out.exr_compression));
        }
        if out.png {
            v.extend([
                TileEncoder::Png,
                TileEncoder::WorldFile,
                TileEncoder::Prj,
                TileEncoder::PngAux,
            ]);
        }
        if out.raw {
            v.push(TileEncoder::Raw);
        }
        v.extend(out.meshes.iter().map(|&f| TileEncoder::Mesh(f)));
        if out.geotiff_tiles {
            v.push(TileEncoder::GeoTiff);
        }
        v
    }

    /// The subdirectory its files go to.
    pub fn dir(self) -> &'static str {
        match self {
            TileEncoder::Exr(_) => "tiles",
            TileEncoder::Png
            | TileEncoder::Raw
            | TileEncoder::WorldFile
            | TileEncoder::Prj
            | TileEncoder::PngAux => "heightmaps",
            TileEncoder::Mesh(_) => "meshes",
            TileEncoder::GeoTiff => "geotiff",
        }
    }

    /// The file extension.
    pub fn ext(self) -> &'static str {
        match self {
            TileEncoder::Exr(_) => "exr",
            TileEncoder::Png => "png",
            TileEncoder::Raw => "raw",
            TileEncoder::Mesh(f) => f.ext(),
            TileEncoder::WorldFile => "pgw",
            TileEncoder::Prj => "prj",
            TileEncoder::PngAux => "png.aux.xml",
            TileEncoder::GeoTiff => "tif",
        }
    }

    /// True for the files that say the CRS (left out when the set has none).
    pub fn needs_crs(self) -> bool {
        matches!(self, TileEncoder::Prj | TileEncoder::PngAux)
    }

    /// The kind a tile's file is listed under in the manifest (`files`).
    pub fn key(self) -> &'static str {
        self.ext()
    }

    /// The file's bytes for `tile`.
    pub fn encode(self, tile: &TileProducts<'_>) -> Result<Vec<u8>> {
        let p = tile.products;
        match self {
            TileEncoder::Exr(c) => exr::encode_tile(p.set, p.quadtree, tile.index, c),
            TileEncoder::Png => heightmap::png_bytes(tile.values(), p.set.tile_size),
            TileEncoder::Raw => Ok(heightmap::raw_bytes(tile.values(), p.set.tile_size, false)),
            TileEncoder::Mesh(f) => f.encode(tile.mesh()?, &tile.name, tile.metres_per_unit),
            TileEncoder::WorldFile => Ok(super::georef::world_file(p.set, tile.index).into_bytes()),
            TileEncoder::GeoTiff => super::georef::tile_geotiff(p.set, tile.index),
            TileEncoder::Prj | TileEncoder::PngAux => {
                let wkt = p
                    .set
                    .crs
                    .as_ref()
                    .and_then(crate::geo::wkt_of)
                    .ok_or_else(|| {
                        Error::Internal(format!("{}: a CRS file without a CRS", tile.name))
                    })?;
                Ok(if self == TileEncoder::Prj {
                    wkt.into_bytes()
                } else {
                    super::geotiff::pam_xml(&wkt).into_bytes()
                })
            }
        }
    }
}

/// One tile's products as its encoders see them; what several encoders share (the 16-bit
/// values, the mesh) is computed once, on first use.
pub struct TileProducts<'a> {
    /// The whole run's products.
    pub products: &'a TerrainProducts<'a>,
    /// The tile's index in the set.
    pub index: usize,
    /// The tile's file name without extension (`tile_CCC_RRR`).
    pub name: String,
    /// The set's 16-bit height encoding.
    pub encoding: &'a HeightEncoding,
    /// Metres per CRS unit.
    pub metres_per_unit: f64,
    values: OnceLock<Vec<u16>>,
    mesh: OnceLock<TriMesh>,
}

impl<'a> TileProducts<'a> {
    /// Tile `index` of `products`.
    pub fn new(
        products: &'a TerrainProducts<'a>,
        index: usize,
        encoding: &'a HeightEncoding,
        metres_per_unit: f64,
    ) -> TileProducts<'a> {
        let set = products.set;
        let tl = &set.tiles[index];
        let w = set.grid[0].max(set.grid[1]).to_string().len().max(3);
        TileProducts {
            products,
            index,
            name: format!("tile_{:0w$}_{:0w$}", tl.col, tl.row, w = w),
            encoding,
            metres_per_unit,
            values: OnceLock::new(),
            mesh: OnceLock::new(),
        }
    }

    /// The tile's 16-bit height values, south row first.
    pub fn values(&self) -> &[u16] {
        self.values
            .get_or_init(|| heightmap::tile_values(self.products.set, self.encoding, self.index))
    }

    /// The tile's mesh (an error when no meshes were extracted).
    pub fn mesh(&self) -> Result<&TriMesh> {
        let meshes = self.products.meshes.ok_or_else(|| {
            Error::Internal(format!(
                "{}: a mesh output without extracted meshes",
                self.name
            ))
        })?;
        Ok(self
            .mesh
            .get_or_init(|| meshes.trimesh(self.products.set, self.index)))
    }
}
