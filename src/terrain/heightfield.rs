//! The regular grid every terrain stage after resampling works on: f32 heights in an ndarray
//! `Array2` indexed `[row j, col i]` (row 0 at min y), per-cell sample
//! counts, per-cell state (measured, interpolated, fallback, empty), and the georeference
//! that places it in the world.
//!
//! Geometry: the grid covers `[corner.x, corner.x + cols·cell_size.x]` × likewise in y; cell
//! (i, j) spans `[corner.x + i·dx, corner.x + (i+1)·dx)`, and its height is the sample at
//! the cell *centre*, `corner + (i + ½, j + ½)·cell_size`. Heights are stored relative to
//! `z_offset` (world z = z_offset + height), which is 0 unless the data's z is so large that
//! f32 would lose centimetres.

use crate::points::Crs;
use ndarray::Array2;
use serde::Serialize;

/// What a cell's height is based on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[repr(u8)]
pub enum CellState {
    /// No sample and not filled: a hole (masked, with `fallback = "nodata"`).
    Empty = 0,
    /// At least one point fell in the cell.
    Measured = 1,
    /// Filled by interpolation from measured neighbours within the radius.
    Interpolated = 2,
    /// Filled by the fallback (global mean or smooth fill): no neighbour within the radius.
    Fallback = 3,
}

impl CellState {
    /// True for every state but `Empty`.
    #[inline]
    pub fn has_height(self) -> bool {
        self != CellState::Empty
    }
}

/// A georeferenced regular heightfield.
#[derive(Debug, Clone, PartialEq)]
pub struct Heightfield {
    /// Heights relative to `z_offset`, `[row j, col i]`; NaN where `state` is `Empty`.
    pub heights: Array2<f32>,
    /// Points that fell in each cell (0 for holes and filled cells).
    pub counts: Array2<u32>,
    /// How each cell got its height.
    pub state: Array2<CellState>,
    /// World x, y of the grid's south-west corner (the outer corner of cell (0, 0)).
    pub corner: [f64; 2],
    /// Cell width (x) and height (y) in world units.
    pub cell_size: [f64; 2],
    /// World z of height 0.
    pub z_offset: f64,
    /// Coordinate reference system of the source points.
    pub crs: Option<Crs>,
}

/// Above this |z|, heights are stored relative to an offset: f32 keeps 24 bits, so at
/// |z| < 10 000 units the step is under a millimetre.
pub const Z_OFFSET_THRESHOLD: f64 = 10_000.0;

/// The offset to store heights of data with z range `[zmin, zmax]` (0 for ordinary terrain).
pub fn choose_z_offset(zmin: f64, zmax: f64) -> f64 {
    if zmin.abs().max(zmax.abs()) < Z_OFFSET_THRESHOLD {
        0.0
    } else {
        (zmin / 100.0).floor() * 100.0
    }
}

impl Heightfield {
    /// An all-empty grid of `cols` × `rows` cells.
    pub fn empty(
        cols: usize,
        rows: usize,
        corner: [f64; 2],
        cell_size: [f64; 2],
        z_offset: f64,
        crs: Option<Crs>,
    ) -> Heightfield {
        Heightfield {
            heights: Array2::from_elem((rows, cols), f32::NAN),
            counts: Array2::zeros((rows, cols)),
            state: Array2::from_elem((rows, cols), CellState::Empty),
            corner,
            cell_size,
            z_offset,
            crs,
        }
    }

    /// Number of columns (x).
    pub fn cols(&self) -> usize {
        self.heights.ncols()
    }

    /// Number of rows (y).
    pub fn rows(&self) -> usize {
        self.heights.nrows()
    }

    /// World x, y of the centre of cell (i, j), where its height sample sits.
    #[inline]
    pub fn centre(&self, i: usize, j: usize) -> [f64; 2] {
        [
            self.corner[0] + (i as f64 + 0.5) * self.cell_size[0],
            self.corner[1] + (j as f64 + 0.5) * self.cell_size[1],
        ]
    }

    /// The cell holding world point (x, y), if inside the grid.
    #[inline]
    pub fn cell_of(&self, x: f64, y: f64) -> Option<(usize, usize)> {
        let fi = (x - self.corner[0]) / self.cell_size[0];
        let fj = (y - self.corner[1]) / self.cell_size[1];
        if !(fi >= 0.0 && fj >= 0.0) {
            return None;
        }
        let (i, j) = (fi as usize, fj as usize);
        (i < self.cols() && j < self.rows()).then_some((i, j))
    }

    /// World z at cell (i, j), or None for a hole.
    #[inline]
    pub fn z(&self, i: usize, j: usize) -> Option<f64> {
        let h = self.heights[[j, i]];
        (self.state[[j, i]].has_height() && h.is_finite()).then_some(self.z_offset + h as f64)
    }

    /// World z at (x, y) by bilinear interpolation between the four surrounding cell centres
    /// (clamped to the outermost centres at the grid's edge). None outside the grid or when
    /// a contributing cell is a hole.
    pub fn sample_bilinear(&self, x: f64, y: f64) -> Option<f64> {
        let (cols, rows) = (self.cols(), self.rows());
        if cols == 0 || rows == 0 {
            return None;
        }
        let fx = (x - self.corner[0]) / self.cell_size[0] - 0.5;
        let fy = (y - self.corner[1]) / self.cell_size[1] - 0.5;
        let (w, h) = (cols as f64, rows as f64);
        if !(fx >= -0.5 && fy >= -0.5 && fx <= w - 0.5 && fy <= h - 0.5) {
            return None;
        }
        let fx = fx.clamp(0.0, w - 1.0);
        let fy = fy.clamp(0.0, h - 1.0);
        let i0 = (fx.floor() as usize).min(cols.saturating_sub(2));
        let j0 = (fy.floor() as usize).min(rows.saturating_sub(2));
        let i1 = (i0 + 1).min(cols - 1);
        let j1 = (j0 + 1).min(rows - 1);
        let (tx, ty) = (fx - i0 as f64, fy - j0 as f64);
        let z00 = self.z(i0, j0)?;
        let z10 = self.z(i1, j0)?;
        let z01 = self.z(i0, j1)?;
        let z11 = self.z(i1, j1)?;
        Some((z00 * (1.0 - tx) + z10 * tx) * (1.0 - ty) + (z01 * (1.0 - tx) + z11 * tx) * ty)
    }

    /// Number of cells in each state: (empty, measured, interpolated, fallback).
    pub fn census(&self) -> [usize; 4] {
        let mut c = [0usize; 4];
        for s in self.state.iter() {
            c[*s as usize] += 1;
        }
        c
    }

    /// World z range over cells that have a height.
    pub fn z_range(&self) -> Option<(f64, f64)> {
        let mut lo = f32::INFINITY;
        let mut hi = f32::NEG_INFINITY;
        for (h, s) in self.heights.iter().zip(self.state.iter()) {
            if s.has_height() && h.is_finite() {
                lo = lo.min(*h);
                hi = hi.max(*h);
            }
        }
        (lo <= hi).then_some((self.z_offset + lo as f64, self.z_offset + hi as f64))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::testutil::field_at;

    #[test]
    fn bilinear_reproduces_a_plane() {
        // Cell centres at 101 + 2i, 200.5 + j.
        let hf = field_at(4, 3, [100.0, 200.0], [2.0, 1.0], |i, j| {
            let (x, y) = (101.0 + 2.0 * i as f64, 200.5 + j as f64);
            (0.5 * x - 0.25 * y) as f32
        });
        assert_eq!(hf.centre(1, 2), [103.0, 202.5]);
        let z = hf.sample_bilinear(103.3, 201.2).unwrap();
        assert!((z - (0.5 * 103.3 - 0.25 * 201.2)).abs() < 1e-4);
        assert_eq!(hf.cell_of(103.3, 201.2), Some((1, 1)));
        assert_eq!(hf.cell_of(99.0, 201.0), None);
        assert!(hf.sample_bilinear(99.0, 201.0).is_none());
    }

    #[test]
    fn holes_are_not_sampled() {
        let hf = Heightfield::empty(2, 2, [0.0, 0.0], [1.0, 1.0], 0.0, None);
        assert_eq!(hf.census(), [4, 0, 0, 0]);
        assert!(hf.sample_bilinear(1.0, 1.0).is_none());
        assert!(hf.z_range().is_none());
    }

    #[test]
    fn z_offset_only_for_large_heights() {
        assert_eq!(choose_z_offset(100.0, 900.0), 0.0);
        assert_eq!(choose_z_offset(12_345.0, 12_400.0), 12_300.0);
    }
}
