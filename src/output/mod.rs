//! Encoders of the tiled terrain: EXR tiles, the JSON manifest, 16-bit PNG/RAW heightmaps,
//! shaded-relief and wireframe previews, and per-tile meshes. Encoders compute nothing of
//! the terrain: they turn what the stages produced ([`TerrainProducts`]: the tile set, its
//! quadtree d2, the tile meshes) into bytes. [`write_terrain`] writes the whole set into a
//! directory (the pipeline passes its staged directory, which replaces the previous output
//! only when everything succeeded).
//!
//! Two kinds of writer:
//! - a tile encoder ([`TileEncoder`]) turns one tile's products (heights, d2, mask, mesh)
//!   into one file; adding a format is one new file here and one new variant;
//! - a set-level writer (manifest, Unreal landscape, previews) takes a [`SetSummary`] of the
//!   set (and the assembled heights where it draws or encodes the whole grid).
//!
//! Layout of the output directory:
//! ```text
//! manifest.json
//! tiles/tile_CCC_RRR.exr         one per tile (col CCC east, row RRR north, from 0)
//! heightmaps/tile_CCC_RRR.png    16-bit greyscale, north up
//! heightmaps/tile_CCC_RRR.raw    16-bit little-endian, south row first (Unity)
//! heightmaps/landscape.png|.r16  whole landscape (unreal preset)
//! meshes/tile_CCC_RRR.glb        glTF binary, y up, metres (the default format)
//! meshes/tile_CCC_RRR.ply|.obj   binary PLY and OBJ with normals, z up, CRS units
//! preview/relief.png             shaded relief
//! preview/wireframe.png          the CLOD mesh over the relief
//! heightmaps/tile_CCC_RRR.pgw|.prj|.png.aux.xml  the PNG's world file and CRS
//! dem.tif                        the whole grid, Cloud-Optimized GeoTIFF (`geotiff = true`)
//! geotiff/tile_CCC_RRR.tif       one GeoTIFF per tile (`geotiff_tiles = true`)
//! terrain/layer.json, terrain/{z}/{x}/{y}.terrain  Cesium quantized-mesh tileset
//!                                (`quantized_mesh = true`; built by `geo::tms`)
//! ```

pub mod exr;
pub mod georef;
pub mod geotiff;
pub mod heightmap;
pub mod manifest;
pub mod preview;
pub mod qmesh;
mod settings;
mod summary;
mod tile;

pub use settings::OutputConfig;
pub use summary::{MeshSummary, SetSummary, TileSummary};
pub use tile::{TileEncoder, TileProducts};

use crate::error::{Error, Result};
use crate::progress::Progress;
use crate::terrain::{Preset, Quadtree, TileMeshes, TileSet};
use heightmap::HeightEncoding;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::Path;

/// What the stages produced for the encoders: the tile set, its quadtree d2 and, when
/// extracted, the tile meshes.
#[derive(Debug, Clone, Copy)]
pub struct TerrainProducts<'a> {
    /// The tiles (heights, masks through NaN).
    pub set: &'a TileSet,
    /// Röttger's d2 per tile.
    pub quadtree: &'a Quadtree,
    /// The tile meshes (`None` when no output asked for them).
    pub meshes: Option<&'a TileMeshes>,
}

fn put(dir: &Path, rel: &str, bytes: &[u8]) -> Result<()> {
    let p = dir.join(rel);
    std::fs::write(&p, bytes).map_err(|e| Error::io(&p, e))
}

/// Writes every output `out` switches on for `products` into `dir` (which must exist);
/// returns the files written, relative to `dir`, sorted.
pub fn write_terrain(
    dir: &Path,
    products: &TerrainProducts<'_>,
    out: &OutputConfig,
    progress: &dyn Progress,
) -> Result<Vec<String>> {
    out.validate()?;
    let set = products.set;
    let summary = SetSummary::of(set, products.quadtree, products.meshes);
    let mut writer = TileWriter::new(dir, summary, out)?;
    progress.start("writing tiles", set.tiles.len() as u64);
    let all: Vec<usize> = (0..set.tiles.len()).collect();
    writer.write(dir, products, &all, progress)?;
    progress.finish();
    writer.finish(dir, products, out)
}

/// True when every output `out` switches on is a tile encoder or the manifest: then the
/// tiles can be written a few at a time, each with only its own heights in memory (no mesh
/// extraction, previews, `dem.tif` or quantized-mesh tileset, which take the whole set).
pub fn writes_tile_by_tile(out: &OutputConfig) -> bool {
    !out.wants_meshes() && !out.wants_previews() && !out.geotiff && !out.quantized_mesh
}

/// The tile encoders and the manifest of one set, fed its tiles in any groups: the set's
/// summary (and so the 16-bit height encoding, whose range is the whole set's) is fixed
/// first, each tile is encoded when its heights are at hand, and [`TileWriter::finish`]
/// writes the set-level files.
pub struct TileWriter {
    summary: SetSummary,
    enc: HeightEncoding,
    encoders: Vec<TileEncoder>,
    per_tile: Vec<Option<BTreeMap<String, String>>>,
}

impl TileWriter {
    /// The writer of the set `summary` describes; makes the output subdirectories in `dir`.
    pub fn new(dir: &Path, summary: SetSummary, out: &OutputConfig) -> Result<TileWriter> {
        let enc = HeightEncoding::for_set(&summary);
        let mut encoders = TileEncoder::for_settings(out);
        let has_crs = summary.crs.as_ref().and_then(crate::geo::wkt_of).is_some();
        encoders.retain(|e| has_crs || !e.needs_crs());
        let mut subdirs: Vec<&str> = encoders.iter().map(|e| e.dir()).collect();
        if out.wants_previews() {
            subdirs.push("preview");
        }
        subdirs.dedup();
        for sub in subdirs {
            let p = dir.join(sub);
            std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
        }
        let per_tile = vec![None; summary.tiles.len()];
        Ok(TileWriter {
            summary,
            enc,
            encoders,
            per_tile,
        })
    }

    /// Encodes `tiles` (indices in the set) of `products`, whose heights those tiles must
    /// hold (other tiles' are not read).
    pub fn write(
        &mut self,
        dir: &Path,
        products: &TerrainProducts<'_>,
        tiles: &[usize],
        progress: &dyn Progress,
    ) -> Result<()> {
        let mpu = self.summary.metres_per_unit();
        let (enc, encoders) = (&self.enc, &self.encoders);
        let got: Vec<BTreeMap<String, String>> = tiles
            .par_iter()
            .map(|&t| -> Result<BTreeMap<String, String>> {
                let tile = TileProducts::new(products, t, enc, mpu);
                let mut files = BTreeMap::new();
                for e in encoders {
                    let rel = format!("{}/{}.{}", e.dir(), tile.name, e.ext());
                    put(dir, &rel, &e.encode(&tile)?)?;
                    files.insert(e.key().to_string(), rel);
                }
                progress.advance(1);
                Ok(files)
            })
            .collect::<Result<_>>()?;
        for (&t, files) in tiles.iter().zip(got) {
            self.per_tile[t] = Some(files);
        }
        Ok(())
    }

    /// Writes the set-level files (landscape heightmaps, previews, `dem.tif`: these read
    /// the heights of the whole `products`; the manifest) once every tile is written;
    /// returns all files written, sorted.
    pub fn finish(
        self,
        dir: &Path,
        products: &TerrainProducts<'_>,
        out: &OutputConfig,
    ) -> Result<Vec<String>> {
        let TileWriter {
            summary,
            enc,
            per_tile,
            ..
        } = self;
        let per_tile: Vec<BTreeMap<String, String>> = per_tile
            .into_iter()
            .enumerate()
            .map(|(t, f)| f.ok_or_else(|| Error::Internal(format!("tile {t} was not written"))))
            .collect::<Result<_>>()?;
        let (landscape, previews) = write_set_level(dir, products, &summary, &enc, out)?;
        let mut files: Vec<String> = per_tile.iter().flat_map(|m| m.values().cloned()).collect();
        files.extend(landscape.iter().cloned());
        files.extend(previews.iter().cloned());
        if out.geotiff {
            put(dir, georef::DEM_FILE, &georef::dem_geotiff(products.set)?)?;
            files.push(georef::DEM_FILE.to_string());
        }
        if out.manifest {
            let written = manifest::Written {
                tiles: per_tile,
                landscape,
                previews,
            };
            let m = manifest::build(&summary, out, &enc, written);
            let text =
                serde_json::to_string_pretty(&m).map_err(|e| Error::Internal(e.to_string()))?;
            put(dir, "manifest.json", format!("{text}\n").as_bytes())?;
            files.push("manifest.json".to_string());
        }
        files.sort();
        Ok(files)
    }
}

/// The writers of the whole set but the manifest: the Unreal landscape heightmaps and the
/// previews. Returns the landscape files and the preview files written.
fn write_set_level(
    dir: &Path,
    products: &TerrainProducts<'_>,
    summary: &SetSummary,
    enc: &HeightEncoding,
    out: &OutputConfig,
) -> Result<(Vec<String>, Vec<String>)> {
    let mut landscape = Vec::new();
    if summary.preset == Preset::Unreal && out.wants_heightmaps() {
        let heights = products.set.assemble();
        let values = heightmap::landscape_values(&heights, summary.z_offset, enc);
        drop(heights);
        if out.png {
            put(
                dir,
                "heightmaps/landscape.png",
                &heightmap::png_bytes(&values, summary.samples[0])?,
            )?;
            landscape.push("heightmaps/landscape.png".to_string());
        }
        if out.raw {
            put(
                dir,
                "heightmaps/landscape.r16",
                &heightmap::raw_bytes(&values, summary.samples[0], true),
            )?;
            landscape.push("heightmaps/landscape.r16".to_string());
        }
    }

    let mut previews = Vec::new();
    if out.wants_previews() {
        let base = preview::relief(summary, &products.set.assemble(), out.preview_size);
        if out.relief {
            put(dir, "preview/relief.png", &base.png()?)?;
            previews.push("preview/relief.png".to_string());
        }
        if let (true, Some(meshes)) = (out.wireframe, products.meshes) {
            put(
                dir,
                "preview/wireframe.png",
                &preview::wireframe(summary, &base, &meshes.tiles).png()?,
            )?;
            previews.push("preview/wireframe.png".to_string());
        }
    }
    Ok((landscape, previews))
}
