//! Writers of the tiled terrain: EXR tiles, the JSON manifest, 16-bit PNG/RAW
//! heightmaps, shaded-relief and wireframe previews, and per-tile meshes. [`write_terrain`]
//! writes the whole set into a directory (the pipeline passes its staged directory, which
//! replaces the previous output only when everything succeeded).
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
//! ```

pub mod exr;
pub mod geotiff;
pub mod glb;
pub mod heightmap;
pub mod manifest;
pub mod preview;

use crate::config::OutputConfig;
use crate::error::{Error, Result};
use crate::progress::Progress;
use crate::terrain::extract::{self, Criterion, ExtractParams, Refiner, TileTriangulation};
use crate::terrain::quadtree::Quadtree;
use crate::terrain::tiles::{Preset, TileSet};
use heightmap::HeightEncoding;
use manifest::*;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

/// Centimetres per metre: Unreal's landscape figures are in centimetres.
const CM_PER_M: f64 = 100.0;

/// Unreal's landscape height: height(cm) = location_z + (value − UNREAL_MID_VALUE) · scale_z
/// / UNREAL_Z_DIVISOR, for a 16-bit value.
const UNREAL_MID_VALUE: f64 = 32768.0;

/// See [`UNREAL_MID_VALUE`].
const UNREAL_Z_DIVISOR: f64 = 128.0;

/// Mesh file formats for tile meshes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshFormat {
    /// Stanford PLY, binary little endian (the mesh module's writer).
    Ply,
    /// Wavefront OBJ (the mesh module's writer).
    Obj,
    /// glTF 2.0 binary.
    Glb,
}

impl MeshFormat {
    /// The formats written by default: glb alone. Game engines and 3-D tools import it
    /// directly (Unity through glTFast, Unreal, Godot, Blender), it is the smallest of the
    /// three (about a third of OBJ's bytes) and the fastest to write; writing all three made
    /// autzen_full's 56 MB of LAZ into 1.1 GB of output.
    pub const DEFAULT: [MeshFormat; 1] = [MeshFormat::Glb];

    /// File extension.
    pub fn ext(self) -> &'static str {
        match self {
            MeshFormat::Ply => "ply",
            MeshFormat::Obj => "obj",
            MeshFormat::Glb => "glb",
        }
    }

    /// `mesh` encoded in this format (`name` labels it where the format has names). Its
    /// positions are in units of `metres_per_unit` metres: PLY and OBJ keep them (CRS units,
    /// like the EXR tiles), glb writes metres (glTF's unit).
    pub fn encode(
        self,
        mesh: &crate::mesh::TriMesh,
        name: &str,
        metres_per_unit: f64,
    ) -> Result<Vec<u8>> {
        use crate::mesh::io::{obj, ply};
        let mut out = Vec::new();
        let io = |e: std::io::Error| Error::Internal(format!("{name}: {e}"));
        match self {
            MeshFormat::Ply => {
                ply::write_ply(mesh, &mut out, ply::Encoding::BinaryLittleEndian).map_err(io)?
            }
            MeshFormat::Obj => {
                // About 40 bytes a `v`/`vn` line and 48 an `f` line: reserving saves the
                // copies of a doubling buffer (a tenth of the writing time).
                let lines = mesh.vertex_count()
                    * (1 + usize::from(mesh.normals.is_some()) + usize::from(mesh.uvs.is_some()));
                out.reserve(40 * lines + 48 * mesh.triangle_count());
                obj::write_obj(mesh, &mut out).map_err(io)?
            }
            MeshFormat::Glb => out = glb::glb_bytes(mesh, name, metres_per_unit)?,
        }
        Ok(out)
    }
}

/// What [`write_terrain`] did.
#[derive(Debug, Clone, Default)]
pub struct TerrainWrite {
    /// Files written, relative to the directory, sorted.
    pub files: Vec<String>,
    /// Surface triangles over all tile meshes (0 when none were extracted).
    pub triangles: usize,
    /// Seconds spent extracting meshes (vertical error tree included).
    pub extract_s: f64,
    /// Seconds spent encoding and writing files.
    pub write_s: f64,
}

/// Checks the `[output]` switches that have a range; errors name the key.
pub fn validate(out: &OutputConfig) -> Result<()> {
    if !(16..=16384).contains(&out.preview_size) {
        return Err(Error::param(
            "output",
            "preview_size",
            out.preview_size,
            "must be 16 to 16384 pixels",
        ));
    }
    Ok(())
}

/// True when the switches ask for a mesh (files or the wireframe picture).
pub fn wants_meshes(out: &OutputConfig) -> bool {
    !out.meshes.is_empty() || out.wireframe
}

/// Metres per CRS unit of the set (1 without a CRS or when the CRS says nothing about
/// units). The one conversion behind every engine-facing number: glb positions, the
/// manifest's `unity` and `unreal` blocks.
pub fn metres_per_unit(set: &TileSet) -> f64 {
    set.crs.as_ref().map_or(1.0, |c| c.metres_per_unit())
}

fn tile_name(set: &TileSet, t: usize) -> String {
    let tl = &set.tiles[t];
    let w = set.grid[0].max(set.grid[1]).to_string().len().max(3);
    format!("tile_{:0w$}_{:0w$}", tl.col, tl.row, w = w)
}

fn put(dir: &Path, rel: &str, bytes: &[u8]) -> Result<()> {
    let p = dir.join(rel);
    std::fs::write(&p, bytes).map_err(|e| Error::io(&p, e))
}

/// Triangulates every tile as `params` say (with skirts when asked).
pub fn extract_meshes(
    set: &TileSet,
    qt: &Quadtree,
    params: &ExtractParams,
) -> Result<Vec<TileTriangulation>> {
    let criterion = params.criterion(set, qt)?;
    // Refuse holes before spending time on the error tree.
    extract::check_no_holes(set)?;
    let err = extract::error_tree(set, &criterion);
    let refiner = Refiner::new(set, qt, err.as_deref(), criterion)?;
    let mut tris = extract::extract(set, &refiner)?;
    let depth = params.skirt_depth_units(set) as f32;
    if depth > 0.0 {
        tris.par_iter_mut()
            .for_each(|t| extract::add_skirts(t, depth));
    }
    Ok(tris)
}

fn criterion_text(params: &ExtractParams, set: &TileSet, qt: &Quadtree) -> Result<String> {
    Ok(match params.criterion(set, qt)? {
        Criterion::Tolerance { max_error } => format!(
            "view-independent: every sample within {} m ({max_error} height units) of the mesh",
            params.tolerance
        ),
        Criterion::View {
            eye,
            min_resolution_c,
            desired_resolution_c,
            ..
        } => format!(
            "view-dependent (Röttger): viewpoint {eye:?}, C = {min_resolution_c}, c = {desired_resolution_c}"
        ),
    })
}

/// Writes every output `out` switches on for `set` into `dir` (which must exist).
pub fn write_terrain(
    dir: &Path,
    set: &TileSet,
    qt: &Quadtree,
    params: &ExtractParams,
    out: &OutputConfig,
    progress: &dyn Progress,
) -> Result<TerrainWrite> {
    validate(out)?;
    let mut report = TerrainWrite::default();
    let t0 = Instant::now();
    let tris = if wants_meshes(out) {
        Some(extract_meshes(set, qt, params)?)
    } else {
        None
    };
    report.extract_s = t0.elapsed().as_secs_f64();
    report.triangles = tris
        .as_ref()
        .map_or(0, |v| v.iter().map(|t| t.surface_triangles).sum());

    let t1 = Instant::now();
    let enc = HeightEncoding::for_set(set);
    let unit_m = metres_per_unit(set);
    for (on, sub) in [
        (out.exr, "tiles"),
        (out.png || out.raw, "heightmaps"),
        (!out.meshes.is_empty(), "meshes"),
        (out.relief || out.wireframe, "preview"),
    ] {
        if on {
            let p = dir.join(sub);
            std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
        }
    }
    progress.start("writing tiles", set.tiles.len() as u64);
    let per_tile: Vec<BTreeMap<String, String>> = (0..set.tiles.len())
        .into_par_iter()
        .map(|t| -> Result<BTreeMap<String, String>> {
            let name = tile_name(set, t);
            let mut files = BTreeMap::new();
            if out.exr {
                let rel = format!("tiles/{name}.exr");
                put(
                    dir,
                    &rel,
                    &exr::encode_tile(set, qt, t, out.exr_compression)?,
                )?;
                files.insert("exr".to_string(), rel);
            }
            if out.png || out.raw {
                let values = heightmap::tile_values(set, &enc, t);
                if out.png {
                    let rel = format!("heightmaps/{name}.png");
                    put(dir, &rel, &heightmap::png_bytes(&values, set.tile_size)?)?;
                    files.insert("png".to_string(), rel);
                    for (kind, text) in georeference_files(set, t) {
                        let rel = format!("heightmaps/{name}.{kind}");
                        put(dir, &rel, text.as_bytes())?;
                        files.insert(kind.to_string(), rel);
                    }
                }
                if out.raw {
                    let rel = format!("heightmaps/{name}.raw");
                    put(
                        dir,
                        &rel,
                        &heightmap::raw_bytes(&values, set.tile_size, false),
                    )?;
                    files.insert("raw".to_string(), rel);
                }
            }
            if let Some(tris) = &tris {
                if !out.meshes.is_empty() {
                    let mesh = extract::to_trimesh(set, &tris[t]);
                    for f in &out.meshes {
                        let rel = format!("meshes/{name}.{}", f.ext());
                        put(dir, &rel, &f.encode(&mesh, &name, unit_m)?)?;
                        files.insert(f.ext().to_string(), rel);
                    }
                }
            }
            progress.advance(1);
            Ok(files)
        })
        .collect::<Result<_>>()?;
    progress.finish();

    let mut landscape = Vec::new();
    if set.preset == Preset::Unreal && (out.png || out.raw) {
        let values = heightmap::landscape_values(set, &enc);
        if out.png {
            put(
                dir,
                "heightmaps/landscape.png",
                &heightmap::png_bytes(&values, set.samples[0])?,
            )?;
            landscape.push("heightmaps/landscape.png".to_string());
        }
        if out.raw {
            put(
                dir,
                "heightmaps/landscape.r16",
                &heightmap::raw_bytes(&values, set.samples[0], true),
            )?;
            landscape.push("heightmaps/landscape.r16".to_string());
        }
    }

    let dem = if out.geotiff {
        put(dir, DEM_FILE, &dem_geotiff(set)?)?;
        Some(DEM_FILE.to_string())
    } else {
        None
    };

    let mut previews = Vec::new();
    if out.relief || out.wireframe {
        let base = preview::relief(set, out.preview_size);
        if out.relief {
            put(dir, "preview/relief.png", &base.png()?)?;
            previews.push("preview/relief.png".to_string());
        }
        if let (true, Some(tris)) = (out.wireframe, &tris) {
            put(
                dir,
                "preview/wireframe.png",
                &preview::wireframe(set, &base, tris).png()?,
            )?;
            previews.push("preview/wireframe.png".to_string());
        }
    }

    let mut files: Vec<String> = per_tile.iter().flat_map(|m| m.values().cloned()).collect();
    files.extend(landscape.iter().cloned());
    files.extend(previews.iter().cloned());
    files.extend(dem.iter().cloned());
    if out.manifest {
        let m = build_manifest(
            set,
            qt,
            params,
            out,
            &enc,
            per_tile,
            tris.as_deref(),
            landscape,
            previews,
        )?;
        let text = serde_json::to_string_pretty(&m).map_err(|e| Error::Internal(e.to_string()))?;
        put(dir, "manifest.json", format!("{text}\n").as_bytes())?;
        files.push("manifest.json".to_string());
    }
    files.sort();
    report.files = files;
    report.write_s = t1.elapsed().as_secs_f64();
    Ok(report)
}

/// The Cloud-Optimized GeoTIFF of the whole grid.
pub const DEM_FILE: &str = "dem.tif";

/// Where the whole grid lies, for the GeoTIFF: the outer north-west corner and the spacing.
pub fn grid_georef(set: &TileSet) -> geotiff::Georef {
    geotiff::Georef {
        west: set.corner[0],
        north: set.corner[1] + set.samples[1] as f64 * set.cell_size[1],
        pixel: set.cell_size,
    }
}

/// `dem.tif`: the grid's heights (the EXR tiles' f32 values, north row first), NaN at holes.
pub fn dem_geotiff(set: &TileSet) -> Result<Vec<u8>> {
    let grid = set.assemble();
    let values: Vec<f32> = grid.rows().into_iter().rev().flatten().copied().collect();
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

/// The world file (`pgw`) of tile `t`'s PNG heightmap (every pixel, padding included) and,
/// when the CRS is known, its `.prj` (the CRS as WKT, for ESRI's tools) and `.png.aux.xml`
/// (the same WKT where GDAL looks for it).
fn georeference_files(set: &TileSet, t: usize) -> Vec<(&'static str, String)> {
    let tile = &set.tiles[t];
    let n = set.tile_size as f64;
    let west = set.corner[0] + tile.origin[0] as f64 * set.cell_size[0];
    let north = set.corner[1] + (tile.origin[1] as f64 + n) * set.cell_size[1];
    let georef = geotiff::Georef {
        west,
        north,
        pixel: set.cell_size,
    };
    let mut out = vec![("pgw", geotiff::world_file(&georef))];
    if let Some(wkt) = set.crs.as_ref().and_then(crate::geo::wkt_of) {
        // GDAL (and so QGIS) takes a PNG's CRS from its PAM file, not from a .prj.
        out.push(("png.aux.xml", geotiff::pam_xml(&wkt)));
        out.push(("prj", wkt));
    }
    out
}

#[allow(clippy::too_many_arguments)]
fn build_manifest(
    set: &TileSet,
    qt: &Quadtree,
    params: &ExtractParams,
    out: &OutputConfig,
    enc: &HeightEncoding,
    per_tile: Vec<BTreeMap<String, String>>,
    tris: Option<&[TileTriangulation]>,
    landscape: Vec<String>,
    previews: Vec<String>,
) -> Result<Manifest> {
    let first = set.sample_xy(0.0, 0.0);
    let z_range = set.z_range();
    let unit_m = metres_per_unit(set);
    let tiles = set
        .tiles
        .par_iter()
        .zip(per_tile)
        .enumerate()
        .map(|(t, (tile, files))| TileEntry {
            col: tile.col,
            row: tile.row,
            grid_offset: tile.origin,
            valid: tile.valid,
            origin: set.sample_xy(tile.origin[0] as f64, tile.origin[1] as f64),
            z_range: tile
                .z_range
                .map(|[lo, hi]| [set.z_offset + lo as f64, set.z_offset + hi as f64]),
            holes: tile.holes,
            triangles: tris.map(|v| v[t].surface_triangles),
            files,
        })
        .collect();
    Ok(Manifest {
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
            holes: set.holes(),
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
            exr_row_order: "north-first".into(),
        },
        quadtree: QuadtreeInfo {
            c: qt.c,
            k: qt.k,
            levels: set.levels(),
            d2: "height units per sample spacing: (1/d)·max|Δh| over the 4 edge midpoints and both diagonals, d in samples; \
                 stored at the node's centre sample; divide by the spacing for Röttger's dimensionless d2"
                .into(),
            borders: "propagated with K across tiles; nodes touching a shared border hold the maximum of their mirror group, \
                      so a tile's own d2 decides its neighbours' subdivision along the border"
                .into(),
        },
        heightmaps: HeightmapInfo::of(enc, landscape),
        meshes: (!out.meshes.is_empty() && tris.is_some())
            .then(|| -> Result<MeshInfo> {
                Ok(MeshInfo {
                    formats: out.meshes.iter().map(|f| f.ext().to_string()).collect(),
                    origin: [first[0], first[1], set.z_offset],
                    axes: "glb: x east, y up, z south (glTF); others: x east, y north, z up".into(),
                    units: format!(
                        "glb: metres (glTF); ply, obj: CRS units ({unit_m} m each), like the EXR tiles; \
                         origin: CRS units"
                    ),
                    criterion: criterion_text(params, set, qt)?,
                    skirt_depth: params.skirt_depth_units(set),
                })
            })
            .transpose()?,
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
        tiles,
    })
}
