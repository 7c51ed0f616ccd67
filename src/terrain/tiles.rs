//! Cutting the filled heightfield into square tiles of (2^k + 1)² samples that share their
//! border rows and columns (the block shape is the one Röttger et al. 1998 need for
//! their quadtree, Kim & Shin §2.4). The last tiles of a row or column are padded by edge
//! replication and remember how much of them is real data (the *valid extent*).
//!
//! Engine presets: `unity` keeps the quadtree tiles (Unity terrains are 2^n + 1 squares up to
//! 4097 that share their edges with their neighbours, exactly this layout; its default tile
//! size is 513, Unity's own default heightmap resolution). `unreal` first resamples the whole
//! heightfield (bilinear) so that each axis has one of Unreal Engine's recommended landscape
//! sizes (505, 1009, 2017, 4033, 8129 samples: the smallest that holds the data, so no sample
//! is lost; 8129 caps it), then tiles that grid; the outputs add a whole-landscape heightmap.
//!
//! Tile (col, row) starts at global sample (col·(T − 1), row·(T − 1)); row 0 is the southern
//! row of tiles, as row 0 of the heightfield is its southern row.

use crate::error::{Error, Result};
use crate::points::Crs;
use crate::terrain::{CellState, Heightfield};
use ndarray::Array2;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Smallest tile size allowed (2^6 + 1).
pub const MIN_TILE_SIZE: usize = 65;
/// Largest tile size allowed (2^12 + 1, Unity's largest heightmap).
pub const MAX_TILE_SIZE: usize = 4097;
/// Default tile size.
pub const DEFAULT_TILE_SIZE: usize = 257;
/// Default tile size under the `unity` preset (Unity's default heightmap resolution).
pub const UNITY_TILE_SIZE: usize = 513;
/// Unreal Engine's recommended landscape sizes per axis, in samples.
pub const UNREAL_SIZES: [usize; 5] = [505, 1009, 2017, 4033, 8129];

/// Which game engine the tile set is laid out for.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// Plain quadtree tiles.
    #[default]
    None,
    /// Unity terrains: 2^n + 1 tiles up to 4097 sharing edges (default size 513).
    Unity,
    /// Unreal landscapes: the whole grid resampled to a recommended landscape size per axis.
    Unreal,
}

/// `[tiles]`: how the heightfield is cut.
#[derive(Debug, Clone, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TileParams {
    /// Samples per tile side, 2^k + 1 from 65 to 4097 (default 257; 513 with `preset = "unity"`).
    #[serde(default)]
    pub size: Option<usize>,
    /// Engine preset: `none` (default), `unity` or `unreal`.
    #[serde(default)]
    pub preset: Preset,
}

impl TileParams {
    /// The tile size in effect.
    pub fn tile_size(&self) -> usize {
        self.size.unwrap_or(match self.preset {
            Preset::Unity => UNITY_TILE_SIZE,
            _ => DEFAULT_TILE_SIZE,
        })
    }

    /// Checks the parameters; the error names `tiles.size`.
    pub fn validate(&self) -> Result<()> {
        let t = self.tile_size();
        if !(MIN_TILE_SIZE..=MAX_TILE_SIZE).contains(&t) || !(t - 1).is_power_of_two() {
            return Err(Error::param(
                "tiles",
                "size",
                t,
                format!("must be 2^k + 1 between {MIN_TILE_SIZE} and {MAX_TILE_SIZE} (65, 129, 257, 513, 1025, 2049, 4097)"),
            ));
        }
        Ok(())
    }
}

/// One tile: a (2^k + 1)² block of heights and where it sits in the whole grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Tile {
    /// Tile column (east) in the tile grid.
    pub col: usize,
    /// Tile row (north) in the tile grid; row 0 is the southern row.
    pub row: usize,
    /// Global sample index (i, j) of the tile's sample (0, 0).
    pub origin: [usize; 2],
    /// Samples of real data from `origin` (columns, rows); beyond them the tile is padding.
    pub valid: [usize; 2],
    /// Heights relative to the set's `z_offset`, `[row j, col i]`, NaN at holes.
    pub heights: Array2<f32>,
    /// Number of hole samples inside the valid extent (0: no NaN anywhere in `heights`,
    /// padding included, which the quadtree's fast path relies on).
    pub holes: usize,
    /// Lowest and highest height (relative to the set's `z_offset`) of the valid extent, None
    /// if it is all holes.
    pub z_range: Option<[f32; 2]>,
}

impl Tile {
    /// Hole samples the tile owns in a grid of `grid` tiles: its valid extent minus the
    /// border it shares east and north (so that `TileSet::holes` counts each sample once).
    pub fn owned_holes(&self, grid: [usize; 2]) -> usize {
        if self.holes == 0 {
            return 0;
        }
        let w = self.valid[0] - usize::from(self.col + 1 < grid[0]);
        let h = self.valid[1] - usize::from(self.row + 1 < grid[1]);
        (0..h)
            .map(|j| (0..w).filter(|&i| self.heights[[j, i]].is_nan()).count())
            .sum()
    }

    /// The heights as one row-major slice (tiles are built contiguous).
    pub fn height_slice(&self) -> &[f32] {
        self.heights
            .as_slice()
            .expect("tile heights are contiguous")
    }
}

/// The layout and georeference of a tile set: its tile grid and the world placement of its
/// samples. A [`TileSet`] is this plus its tiles; the set-level writers' summary
/// (`output::SetSummary`) is this plus a few figures of the tiles.
#[derive(Debug, Clone, PartialEq)]
pub struct SetLayout {
    /// Samples per tile side (2^k + 1).
    pub tile_size: usize,
    /// Tiles in x and y.
    pub grid: [usize; 2],
    /// Samples of the whole grid (columns, rows) that the tiles hold.
    pub samples: [usize; 2],
    /// Samples of the heightfield before an engine preset resampled it (columns, rows).
    pub source_samples: [usize; 2],
    /// The preset the set was made for.
    pub preset: Preset,
    /// World x, y of the grid's south-west corner (outer corner of cell (0, 0)).
    pub corner: [f64; 2],
    /// Distance between samples in world units (x, y).
    pub cell_size: [f64; 2],
    /// World z of height 0.
    pub z_offset: f64,
    /// Coordinate reference system.
    pub crs: Option<Crs>,
}

impl SetLayout {
    /// Quadtree depth k of the tiles (tile size 2^k + 1).
    pub fn levels(&self) -> u32 {
        (self.tile_size - 1).trailing_zeros()
    }

    /// World x, y of global sample (i, j) (a cell centre; fractional indices allowed).
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

/// A heightfield cut into tiles, with the georeference of the whole set.
#[derive(Debug, Clone, PartialEq)]
pub struct TileSet {
    /// Tile grid and georeference; its fields read through the set (`set.grid`).
    pub layout: SetLayout,
    /// The tiles, row by row from the south, west to east within a row.
    pub tiles: Vec<Tile>,
}

/// A set is read as its layout plus its tiles: `set.grid` is `set.layout.grid`. (The
/// layout is shared with `output::SetSummary`; reading through it keeps every reader of a
/// set's geometry unchanged.)
impl std::ops::Deref for TileSet {
    type Target = SetLayout;

    fn deref(&self) -> &SetLayout {
        &self.layout
    }
}

impl TileSet {
    /// The tile at (col, row), if inside the grid.
    pub fn tile(&self, col: usize, row: usize) -> Option<&Tile> {
        (col < self.grid[0] && row < self.grid[1]).then(|| &self.tiles[row * self.grid[0] + col])
    }

    /// Index in `tiles` of the tile at (col, row).
    pub fn index(&self, col: usize, row: usize) -> usize {
        row * self.grid[0] + col
    }

    /// Hole samples of the whole grid (a sample on a shared border counts once).
    pub fn holes(&self) -> usize {
        if self.tiles.iter().all(|t| t.holes == 0) {
            return 0;
        }
        self.tiles
            .par_iter()
            .map(|t| t.owned_holes(self.grid))
            .sum()
    }

    /// World z range over all non-hole samples.
    pub fn z_range(&self) -> Option<(f64, f64)> {
        // Padding repeats valid samples, so the tiles' valid ranges cover every height.
        let (lo, hi) = self
            .tiles
            .iter()
            .filter_map(|t| t.z_range)
            .fold((f32::INFINITY, f32::NEG_INFINITY), |a, b| {
                (a.0.min(b[0]), a.1.max(b[1]))
            });
        (lo <= hi).then_some((self.z_offset + lo as f64, self.z_offset + hi as f64))
    }

    /// The whole grid put back together from the tiles' valid extents (NaN at holes).
    pub fn assemble(&self) -> Array2<f32> {
        let [cols, rows] = self.samples;
        let mut out = Array2::from_elem((rows, cols), f32::NAN);
        for t in &self.tiles {
            for j in 0..t.valid[1] {
                for i in 0..t.valid[0] {
                    out[[t.origin[1] + j, t.origin[0] + i]] = t.heights[[j, i]];
                }
            }
        }
        out
    }
}

/// Tiles needed to cover `n` samples with tiles of `size` samples sharing one sample.
pub(crate) fn tiles_for(n: usize, size: usize) -> usize {
    ((n.saturating_sub(1)) + (size - 2)) / (size - 1)
}

/// Cuts `hf` into tiles as `params` says (resampling it first under the `unreal` preset).
pub fn tile(hf: &Heightfield, params: &TileParams) -> Result<TileSet> {
    params.validate()?;
    let (cols, rows) = (hf.cols(), hf.rows());
    if cols < 2 || rows < 2 {
        return Err(Error::Data {
            stage: "tiles",
            message: format!("the heightfield has {cols}×{rows} samples; tiles need at least 2×2"),
        });
    }
    let source_samples = [cols, rows];
    let fitted;
    let hf = if params.preset == Preset::Unreal {
        let target = [unreal_size(cols), unreal_size(rows)];
        if target != [cols, rows] {
            fitted = resample_to(hf, target[0], target[1]);
            &fitted
        } else {
            hf
        }
    } else {
        hf
    };
    let t = params.tile_size();
    let (cols, rows) = (hf.cols(), hf.rows());
    let grid = [tiles_for(cols, t), tiles_for(rows, t)];
    let step = t - 1;
    // Row-major views (no copy when the heightfield already is, as the stages build it).
    let (src_heights, src_state) = (
        hf.heights.as_standard_layout(),
        hf.state.as_standard_layout(),
    );
    let (src_heights, src_state) = (
        src_heights.as_slice().unwrap_or_default(),
        src_state.as_slice().unwrap_or_default(),
    );
    let tiles: Vec<Tile> = (0..grid[0] * grid[1])
        .into_par_iter()
        .map(|k| {
            let (col, row) = (k % grid[0], k / grid[0]);
            let origin = [col * step, row * step];
            let valid = [(cols - origin[0]).min(t), (rows - origin[1]).min(t)];
            let mut heights = Array2::<f32>::zeros((t, t));
            let mut holes = 0;
            let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
            // Whole rows at a time (the grid and the tile are row-major): the columns past the
            // grid's edge repeat its last sample.
            let (x0, inside) = (origin[0], (cols - origin[0]).min(t));
            let out_rows = heights
                .as_slice_mut()
                .unwrap_or_default()
                .chunks_exact_mut(t);
            for (j, out) in out_rows.enumerate() {
                let g = (origin[1] + j).min(rows - 1) * cols + x0;
                let (src_h, src_s) = (&src_heights[g..g + inside], &src_state[g..g + inside]);
                let valid_row = j < valid[1];
                for (o, (&h, &s)) in out.iter_mut().zip(src_h.iter().zip(src_s)) {
                    let h = if s.has_height() && h.is_finite() {
                        h
                    } else {
                        f32::NAN
                    };
                    // Inside the grid, i < valid[0] (valid[0] is the same minimum).
                    if valid_row {
                        if h.is_nan() {
                            holes += 1;
                        } else {
                            lo = lo.min(h);
                            hi = hi.max(h);
                        }
                    }
                    *o = h;
                }
                let last = out[inside - 1];
                out[inside..].fill(last);
            }
            Tile {
                col,
                row,
                origin,
                valid,
                heights,
                holes,
                z_range: (lo <= hi).then_some([lo, hi]),
            }
        })
        .collect();
    Ok(TileSet {
        layout: SetLayout {
            tile_size: t,
            grid,
            samples: [cols, rows],
            source_samples,
            preset: params.preset,
            corner: hf.corner,
            cell_size: hf.cell_size,
            z_offset: hf.z_offset,
            crs: hf.crs.clone(),
        },
        tiles,
    })
}

/// The Unreal landscape size for an axis of `n` samples: the smallest recommended size that
/// holds them, or the largest one.
pub fn unreal_size(n: usize) -> usize {
    UNREAL_SIZES
        .iter()
        .copied()
        .find(|&s| s >= n)
        .unwrap_or(UNREAL_SIZES[UNREAL_SIZES.len() - 1])
}

/// `hf` resampled to `cols` × `rows` samples over the same extent: bilinear between the
/// original cell centres (a new sample next to a hole is a hole). Sample states follow the
/// nearest original sample; counts are zero.
pub fn resample_to(hf: &Heightfield, cols: usize, rows: usize) -> Heightfield {
    let cell_size = [
        hf.cell_size[0] * hf.cols() as f64 / cols as f64,
        hf.cell_size[1] * hf.rows() as f64 / rows as f64,
    ];
    let mut out = Heightfield::empty(
        cols,
        rows,
        hf.corner,
        cell_size,
        hf.z_offset,
        hf.crs.clone(),
    );
    let rows_out: Vec<(Vec<f32>, Vec<CellState>)> = (0..rows)
        .into_par_iter()
        .map(|j| {
            let mut hs = Vec::with_capacity(cols);
            let mut st = Vec::with_capacity(cols);
            for i in 0..cols {
                let [x, y] = [
                    hf.corner[0] + (i as f64 + 0.5) * cell_size[0],
                    hf.corner[1] + (j as f64 + 0.5) * cell_size[1],
                ];
                let near = hf.cell_of(x, y).unwrap_or((hf.cols() - 1, hf.rows() - 1));
                match hf.sample_bilinear(x, y) {
                    Some(z) => {
                        hs.push((z - hf.z_offset) as f32);
                        let s = hf.state[[near.1, near.0]];
                        st.push(if s.has_height() {
                            s
                        } else {
                            CellState::Interpolated
                        });
                    }
                    None => {
                        hs.push(f32::NAN);
                        st.push(CellState::Empty);
                    }
                }
            }
            (hs, st)
        })
        .collect();
    for (j, (hs, st)) in rows_out.into_iter().enumerate() {
        for i in 0..cols {
            out.heights[[j, i]] = hs[i];
            out.state[[j, i]] = st[i];
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::testutil::field_at;

    /// `hf` tiled at `size` with no preset.
    fn tile_at(hf: &Heightfield, size: usize) -> TileSet {
        tile(
            hf,
            &TileParams {
                size: Some(size),
                preset: Preset::None,
            },
        )
        .unwrap()
    }

    fn ramp(cols: usize, rows: usize) -> Heightfield {
        field_at(cols, rows, [1000.0, 2000.0], [0.5, 0.5], |i, j| {
            (i * 1000 + j) as f32
        })
    }

    #[test]
    fn sizes_are_checked() {
        for bad in [0, 1, 64, 66, 100, 256, 258, 8193, 4096] {
            let p = TileParams {
                size: Some(bad),
                preset: Preset::None,
            };
            let e = p.validate().unwrap_err().to_string();
            assert!(
                e.starts_with(&format!("tiles: size = {bad}: must be 2^k + 1")),
                "{e}"
            );
        }
        for good in [65, 129, 257, 513, 1025, 2049, 4097] {
            TileParams {
                size: Some(good),
                preset: Preset::None,
            }
            .validate()
            .unwrap();
        }
        assert_eq!(
            TileParams {
                size: None,
                preset: Preset::Unity
            }
            .tile_size(),
            513
        );
        assert_eq!(TileParams::default().tile_size(), 257);
    }

    #[test]
    fn tiles_share_borders_and_pad_by_replication() {
        let hf = ramp(300, 130);
        let set = tile_at(&hf, 129);
        // 300 samples: 128 + 128 + 44 → 3 tiles; 130 rows: 2 tiles.
        assert_eq!(set.grid, [3, 2]);
        let t = set.tile(2, 1).unwrap();
        assert_eq!(t.origin, [256, 128]);
        assert_eq!(t.valid, [44, 2]);
        // Padding replicates the last real column and row.
        assert_eq!(t.heights[[100, 100]], hf.heights[[129, 299]]);
        // Shared border: last column of tile (0,0) = first column of tile (1,0).
        let a = set.tile(0, 0).unwrap();
        let b = set.tile(1, 0).unwrap();
        for j in 0..129 {
            assert_eq!(a.heights[[j, 128]], b.heights[[j, 0]]);
        }
        assert_eq!(set.assemble(), hf.heights);
    }

    #[test]
    fn exact_fit_needs_no_padding() {
        let hf = ramp(129, 65);
        let set = tile_at(&hf, 65);
        assert_eq!(set.grid, [2, 1]);
        assert!(set.tiles.iter().all(|t| t.valid == [65, 65]));
    }

    #[test]
    fn holes_are_counted_in_the_valid_extent() {
        let mut hf = ramp(70, 70);
        hf.heights[[69, 69]] = f32::NAN;
        hf.state[[69, 69]] = CellState::Empty;
        let set = tile_at(&hf, 65);
        // Sample (69, 69) is inside tile (1,1) only; its replicas in the padding do not count.
        assert_eq!(set.holes(), 1);
        // A hole on the shared border is in two tiles' valid extents but counts once.
        hf.heights[[10, 64]] = f32::NAN;
        hf.state[[10, 64]] = CellState::Empty;
        let set = tile_at(&hf, 65);
        assert_eq!(set.tiles.iter().map(|t| t.holes).sum::<usize>(), 3);
        assert_eq!(set.holes(), 2);
        assert!(set.tile(1, 1).unwrap().heights[[10, 10]].is_nan());
    }

    #[test]
    fn unreal_resamples_each_axis_to_a_landscape_size() {
        assert_eq!(unreal_size(300), 505);
        assert_eq!(unreal_size(505), 505);
        assert_eq!(unreal_size(506), 1009);
        assert_eq!(unreal_size(9000), 8129);
        let hf = ramp(300, 600);
        let set = tile(
            &hf,
            &TileParams {
                size: None,
                preset: Preset::Unreal,
            },
        )
        .unwrap();
        assert_eq!(set.samples, [505, 1009]);
        assert_eq!(set.source_samples, [300, 600]);
        // Same extent, finer cells.
        assert!((set.cell_size[0] * 505.0 - 150.0).abs() < 1e-9);
        // A linear ramp stays linear under bilinear resampling (inside the outer half cells).
        let full = set.assemble();
        let x = set.sample_xy(250.0, 500.0);
        let z = hf.sample_bilinear(x[0], x[1]).unwrap();
        assert!((full[[500, 250]] as f64 - z).abs() < 1e-2);
    }
}
