//! The terrain stages of Kim & Shin: noise removal, resampling to a regular grid,
//! hole filling, Röttger quadtree error metrics, CLOD mesh extraction and tiling, plus the
//! Delaunay baseline they are measured against. Each stage is a plain function with a
//! `…Params` struct; none reads files or prints.

pub mod accuracy;
pub mod delaunay;
pub mod denoise;
pub mod extract;
pub mod fill;
pub mod ground;
mod ground_plane;
mod ground_refine;
pub mod heightfield;
pub mod largevoid;
pub mod quadtree;
#[cfg(any(test, feature = "testing"))]
pub mod reference;
pub mod resample;
pub mod tiles;
pub mod voidfill;

pub use denoise::{denoise, DenoiseParams, Denoised};
pub use fill::{fill, Fallback, FillParams, FillReport};
pub use heightfield::{CellState, Heightfield};
pub use resample::{resample, CellMethod, ResampleParams, Resampled};
// The products the encoders in `output` take (types only; the stages stay in their modules).
pub use extract::{TileMeshes, TileTriangulation};
pub use quadtree::Quadtree;
pub use tiles::{Preset, SetLayout, Tile, TileSet};

use crate::points::Bounds;
use rayon::prelude::*;

/// Bounds and number of the points whose `keep` flag is set (all when `None`): a plain loop
/// per fixed chunk (the compiler keeps the running min/max in registers), chunks merged in
/// order.
pub(crate) fn bounds_of(x: &[f64], y: &[f64], z: &[f64], keep: Option<&[bool]>) -> (Bounds, usize) {
    const CHUNK: usize = 1 << 16;
    (0..x.len().div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let r = c * CHUNK..((c + 1) * CHUNK).min(x.len());
            let (mut lo, mut hi, mut n) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3], 0usize);
            let (x, y, z) = (&x[r.clone()], &y[r.clone()], &z[r.clone()]);
            let k = keep.map(|k| &k[r]);
            for i in 0..x.len() {
                if k.is_none_or(|k| k[i]) {
                    n += 1;
                    lo[0] = lo[0].min(x[i]);
                    hi[0] = hi[0].max(x[i]);
                    lo[1] = lo[1].min(y[i]);
                    hi[1] = hi[1].max(y[i]);
                    lo[2] = lo[2].min(z[i]);
                    hi[2] = hi[2].max(z[i]);
                }
            }
            (Bounds { min: lo, max: hi }, n)
        })
        .reduce(|| (Bounds::EMPTY, 0), |a, b| (a.0.union(b.0), a.1 + b.1))
}

/// Small heightfields and tile sets for the unit tests of the terrain and output modules.
/// Deserialises an optional fixed-length array (`size = [w, h]`), refusing a wrong number of
/// elements: serde's own array support stops after N and silently drops the rest.
pub(crate) fn exact_array<'de, D, T, const N: usize>(
    d: D,
) -> std::result::Result<Option<[T; N]>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: serde::Deserialize<'de>,
{
    use serde::de::Error as _;
    use serde::Deserialize as _;
    let Some(v) = Option::<Vec<T>>::deserialize(d)? else {
        return Ok(None);
    };
    let n = v.len();
    v.try_into().map(Some).map_err(|_| {
        D::Error::invalid_length(n, &format!("an array of exactly {N} elements").as_str())
    })
}

#[cfg(test)]
pub(crate) mod testutil {
    use super::tiles::{tile, TileParams, TileSet};
    use super::{CellState, Heightfield};

    /// A `cols` × `rows` grid of unit cells at the origin, every cell measured at `f(i, j)`.
    pub(crate) fn field(cols: usize, rows: usize, f: impl Fn(usize, usize) -> f32) -> Heightfield {
        field_at(cols, rows, [0.0, 0.0], [1.0, 1.0], f)
    }

    /// As [`field`], with the grid's south-west corner at `corner` and cells of `cell_size`.
    pub(crate) fn field_at(
        cols: usize,
        rows: usize,
        corner: [f64; 2],
        cell_size: [f64; 2],
        f: impl Fn(usize, usize) -> f32,
    ) -> Heightfield {
        let mut hf = Heightfield::empty(cols, rows, corner, cell_size, 0.0, None);
        for j in 0..rows {
            for i in 0..cols {
                hf.heights[[j, i]] = f(i, j);
                hf.state[[j, i]] = CellState::Measured;
            }
        }
        hf
    }

    /// `hf` cut into tiles of `size` samples.
    pub(crate) fn tiles_of(hf: &Heightfield, size: usize) -> TileSet {
        let params = TileParams {
            size: Some(size),
            ..Default::default()
        };
        tile(hf, &params).unwrap()
    }
}
