//! What the set-level writers (manifest, Unreal landscape, previews) know of a tile set: a
//! small summary of its geometry and of each tile, taken once from the stages' products, so
//! that those writers never need the whole `TileSet` (and a sharded run can build the same
//! summary from its shards).

use crate::points::Crs;
use crate::terrain::{Preset, Quadtree, TileMeshes, TileSet};

/// One tile, as the set-level writers see it.
#[derive(Debug, Clone, PartialEq)]
pub struct TileSummary {
    /// Column in the tile grid (east).
    pub col: usize,
    /// Row in the tile grid (north).
    pub row: usize,
    /// Sample offset of the tile's first sample in the whole grid.
    pub origin: [usize; 2],
    /// Samples of the tile that lie inside the grid (the rest is padding).
    pub valid: [usize; 2],
    /// Hole samples inside the valid extent.
    pub holes: usize,
    /// Lowest and highest height of the valid samples, relative to the set's `z_offset`.
    pub z_range: Option<[f32; 2]>,
    /// Surface triangles of the tile's mesh, when meshes were extracted.
    pub triangles: Option<usize>,
}

/// A tile set, as the set-level writers see it.
#[derive(Debug, Clone, PartialEq)]
pub struct SetSummary {
    /// Samples per tile side (2^k + 1).
    pub tile_size: usize,
    /// Tiles in x and y.
    pub grid: [usize; 2],
    /// Samples of the whole (possibly resampled) grid.
    pub samples: [usize; 2],
    /// Samples of the grid the tiles were cut from, before any engine resampling.
    pub source_samples: [usize; 2],
    /// The engine preset.
    pub preset: Preset,
    /// World x, y of the grid's south-west corner.
    pub corner: [f64; 2],
    /// Sample spacing in x and y, CRS units.
    pub cell_size: [f64; 2],
    /// World z that stored heights are relative to.
    pub z_offset: f64,
    /// The set's coordinate reference system, when known.
    pub crs: Option<Crs>,
    /// World z range of the valid samples.
    pub z_range: Option<(f64, f64)>,
    /// Hole samples over all tiles.
    pub holes: usize,
    /// Quadtree levels of a tile.
    pub levels: u32,
    /// Röttger's C and K the d2 values were computed with.
    pub quadtree_ck: [f64; 2],
    /// The tiles, in the set's order.
    pub tiles: Vec<TileSummary>,
    /// How the tile meshes were made, when they were extracted.
    pub meshes: Option<MeshSummary>,
}

/// How the tile meshes were made.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshSummary {
    /// The refinement criterion in words.
    pub criterion: String,
    /// Skirt depth in the set's height units (0: no skirts).
    pub skirt_depth: f64,
}

impl SetSummary {
    /// The summary of `set`, with its quadtree's constants and, when meshes were extracted,
    /// each tile's triangle count.
    pub fn of(set: &TileSet, qt: &Quadtree, meshes: Option<&TileMeshes>) -> SetSummary {
        SetSummary::with_holes(set, qt, meshes, set.holes())
    }

    /// As [`SetSummary::of`], with the set's hole samples counted already (`holes`, as
    /// `TileSet::holes` counts them): the heights are not read, so a streamed run's set
    /// whose tiles have left memory can be summarised.
    pub fn with_holes(
        set: &TileSet,
        qt: &Quadtree,
        meshes: Option<&TileMeshes>,
        holes: usize,
    ) -> SetSummary {
        SetSummary {
            tile_size: set.tile_size,
            grid: set.grid,
            samples: set.samples,
            source_samples: set.source_samples,
            preset: set.preset,
            corner: set.corner,
            cell_size: set.cell_size,
            z_offset: set.z_offset,
            crs: set.crs.clone(),
            z_range: set.z_range(),
            holes,
            levels: set.levels(),
            quadtree_ck: [qt.c, qt.k],
            tiles: set
                .tiles
                .iter()
                .enumerate()
                .map(|(t, tile)| TileSummary {
                    col: tile.col,
                    row: tile.row,
                    origin: tile.origin,
                    valid: tile.valid,
                    holes: tile.holes,
                    z_range: tile.z_range,
                    triangles: meshes.map(|m| m.tiles[t].surface_triangles),
                })
                .collect(),
            meshes: meshes.map(|m| MeshSummary {
                criterion: m.criterion.clone(),
                skirt_depth: m.skirt_depth,
            }),
        }
    }

    /// World x, y of grid sample (i, j) (fractional indices allowed), as
    /// `TileSet::sample_xy`.
    pub fn sample_xy(&self, i: f64, j: f64) -> [f64; 2] {
        [
            self.corner[0] + (i + 0.5) * self.cell_size[0],
            self.corner[1] + (j + 0.5) * self.cell_size[1],
        ]
    }

    /// Metres per CRS unit (1 without a CRS or when the CRS says nothing about units). The
    /// one conversion behind every engine-facing number: glb positions, the manifest's
    /// `unity` and `unreal` blocks.
    pub fn metres_per_unit(&self) -> f64 {
        self.crs.as_ref().map_or(1.0, |c| c.metres_per_unit())
    }
}
