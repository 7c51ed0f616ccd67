//! What the set-level writers (manifest, Unreal landscape, previews) know of a tile set: a
//! small summary of its geometry and of each tile, taken once from the stages' products, so
//! that those writers never need the whole `TileSet` (and a sharded run can build the same
//! summary from its shards).

use crate::terrain::{Quadtree, SetLayout, TileMeshes, TileSet};

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

/// A tile set, as the set-level writers see it: its layout (read through the summary:
/// `summary.grid`) and a few figures of its tiles.
#[derive(Debug, Clone, PartialEq)]
pub struct SetSummary {
    /// Tile grid and georeference, the set's own.
    pub layout: SetLayout,
    /// World z range of the valid samples.
    pub z_range: Option<(f64, f64)>,
    /// Hole samples over all tiles.
    pub holes: usize,
    /// Röttger's C and K the d2 values were computed with.
    pub quadtree_ck: [f64; 2],
    /// The tiles, in the set's order.
    pub tiles: Vec<TileSummary>,
    /// How the tile meshes were made, when they were extracted.
    pub meshes: Option<MeshSummary>,
}

/// The summary reads as its layout, as a [`TileSet`] does.
impl std::ops::Deref for SetSummary {
    type Target = SetLayout;

    fn deref(&self) -> &SetLayout {
        &self.layout
    }
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
            layout: set.layout.clone(),
            z_range: set.z_range(),
            holes,
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
}
