//! Resampling the denoised points to a regular grid, Kim & Shin §2.2.
//!
//! The paper's rule: with Pt points left after noise removal, an N × N grid with
//! N = round(sqrt(Pt)) over the points' x/y range, so that there is about one point per cell;
//! cells need not be square (Ix = Rx / N, Iy = Ry / N). A point falls in cell
//! i = min(floor((x − min x) / Ix), N − 1), likewise j. A cell's height is the mean z of its
//! points (the paper), or their minimum (bare earth from the lowest returns) or maximum (the
//! surface). `cell_size` (square cells) or `size = [width, height]` replace the rule.
//!
//! **Speed and determinism.** Each kept point's cell index is computed once, in parallel
//! (4 bytes per point). The grid is then cut into one band of rows per worker; each worker
//! streams over the cell indices and accumulates the points of its own rows, in file order,
//! straight into its rows of the grid: no scratch beyond one f64 per cell, no atomics, and
//! since every cell is summed by one worker in file order, the means are bit-identical for
//! any number of workers. In the pipeline those f64 sums live in the buffer noise removal
//! sorted its keys in (8 bytes per point, already mapped), and one worker computes the cells
//! on the fly: at 10 M points the fresh pages (and the kernel zeroing them) were most of
//! this stage's cost.

use super::heightfield::{choose_z_offset, CellState, Heightfield};
use crate::error::{Error, Result};
use crate::points::{Bounds, Crs, PointCloud};
use ndarray::{Array2, Axis};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How a cell's height is made from its points.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum CellMethod {
    /// Mean z of the cell's points (the paper).
    #[default]
    Mean,
    /// Lowest z (bare earth from the lowest returns).
    Min,
    /// Highest z (the top surface).
    Max,
}

/// `[resample]`: the regular grid.
#[derive(Debug, Clone, PartialEq, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ResampleParams {
    /// `mean` (default), `min` or `max` of the points in a cell.
    pub method: CellMethod,
    /// Square cells of this edge, in the data's units, instead of the √N × √N rule.
    pub cell_size: Option<f64>,
    /// The grid as `[width, height]` cells instead of the √N × √N rule.
    #[serde(default, deserialize_with = "crate::terrain::exact_array")]
    pub size: Option<[u64; 2]>,
}

/// Cells along one axis at most (the grid is also capped at 2^31 cells in all).
pub const MAX_CELLS_PER_AXIS: u64 = 1 << 20;

impl ResampleParams {
    /// Checks the values a user can get wrong, before any data is read.
    pub fn validate(&self) -> Result<()> {
        if let Some(c) = self.cell_size {
            if !(c > 0.0 && c.is_finite()) {
                return Err(Error::param(
                    "resample",
                    "cell_size",
                    c,
                    "must be a positive, finite length in the data's units",
                ));
            }
            if self.size.is_some() {
                return Err(Error::param(
                    "resample",
                    "size",
                    format!("{:?}", self.size.unwrap_or_default()),
                    "give either cell_size or size, not both",
                ));
            }
        }
        if let Some([w, h]) = self.size {
            if w == 0 || h == 0 {
                return Err(Error::param(
                    "resample",
                    "size",
                    format!("[{w}, {h}]"),
                    "a grid needs at least one cell along each axis",
                ));
            }
            if w > MAX_CELLS_PER_AXIS || h > MAX_CELLS_PER_AXIS || w * h > (1 << 31) {
                return Err(Error::param(
                    "resample",
                    "size",
                    format!("[{w}, {h}]"),
                    format!("at most {MAX_CELLS_PER_AXIS} cells per axis and 2^31 in all"),
                ));
            }
        }
        Ok(())
    }
}

/// The grid a resampling run chose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GridSpec {
    /// Columns (x).
    pub cols: usize,
    /// Rows (y).
    pub rows: usize,
    /// South-west corner.
    pub corner: [f64; 2],
    /// Cell width and height.
    pub cell_size: [f64; 2],
    /// World z of height 0.
    pub z_offset: f64,
}

impl GridSpec {
    /// The grid for `points` points (after noise removal) within `b`.
    pub fn new(params: &ResampleParams, b: &Bounds, points: usize) -> Result<GridSpec> {
        params.validate()?;
        let [rx, ry, _] = b.size();
        for (axis, r, lo) in [("x range", rx, b.min[0]), ("y range", ry, b.min[1])] {
            if r.is_nan() || r <= 0.0 {
                return Err(Error::param(
                    "resample",
                    axis,
                    r,
                    format!(
                        "all {points} points share {} = {lo}: they lie on one line or one spot, \
                         which spans no grid",
                        &axis[..1]
                    ),
                ));
            }
        }
        let (cols, rows, cell_size) = if let Some(c) = params.cell_size {
            let n = |r: f64| (r / c).ceil().max(1.0);
            let (w, h) = (n(rx), n(ry));
            if w > MAX_CELLS_PER_AXIS as f64
                || h > MAX_CELLS_PER_AXIS as f64
                || w * h > (1u64 << 31) as f64
            {
                return Err(Error::param(
                    "resample",
                    "cell_size",
                    c,
                    format!("makes a {w} × {h} grid over {rx} × {ry}: at most {MAX_CELLS_PER_AXIS} cells per axis and 2^31 in all"),
                ));
            }
            (w as usize, h as usize, [c, c])
        } else if let Some([w, h]) = params.size {
            (w as usize, h as usize, [rx / w as f64, ry / h as f64])
        } else {
            let n = ((points as f64).sqrt().round() as usize).max(1);
            (n, n, [rx / n as f64, ry / n as f64])
        };
        let z_offset = choose_z_offset(b.min[2], b.max[2]);
        Ok(GridSpec {
            cols,
            rows,
            corner: [b.min[0], b.min[1]],
            cell_size,
            z_offset,
        })
    }

    /// The cell (i, j) of a point, clamped into the grid (the paper's `min(…, N − 1)`).
    #[inline(always)]
    pub fn cell(&self, x: f64, y: f64) -> (usize, usize) {
        (self.col(x), self.row(y))
    }

    /// The column of a point's x.
    #[inline(always)]
    pub fn col(&self, x: f64) -> usize {
        clamped_index((x - self.corner[0]) / self.cell_size[0], self.cols)
    }

    /// The row of a point's y.
    #[inline(always)]
    pub fn row(&self, y: f64) -> usize {
        clamped_index((y - self.corner[1]) / self.cell_size[1], self.rows)
    }
}

/// `(v as usize).min(n − 1)` for every f64 `v` (NaN and negatives to 0, beyond to n − 1),
/// through a signed conversion: x86-64 has no unsigned one before AVX-512, so `as usize`
/// costs a dozen instructions where `as i64` costs a few, and this runs for every point.
#[inline(always)]
fn clamped_index(v: f64, n: usize) -> usize {
    (v as i64).clamp(0, n as i64 - 1) as usize
}

/// What resampling produced.
#[derive(Debug, Clone)]
pub struct Resampled {
    /// The grid: measured cells have a height and a count, the rest are empty.
    pub grid: Heightfield,
    /// The grid's parameters.
    pub spec: GridSpec,
    /// Points binned.
    pub points: usize,
}

/// Bins the points of `cloud` whose `keep` flag is set (all when `None`) into a grid.
pub fn resample(
    cloud: &PointCloud,
    keep: Option<&[bool]>,
    params: &ResampleParams,
) -> Result<Resampled> {
    resample_reusing(cloud, keep, params, &mut Vec::new(), None)
}

/// [`resample`] reusing `scratch` (left there by [`super::denoise::denoise_reusing`]) for
/// the per-cell sums: a buffer the size of the point count that is already mapped costs no
/// page faults, while a fresh one of 40–85 MB at 5–10 M points is faulted in page by page.
/// `known`, when given, must be the tight bounds of the kept points and their number (as
/// noise removal found them: [`super::denoise::Denoised::kept_bounds`]); otherwise they are
/// measured here.
pub(crate) fn resample_reusing(
    cloud: &PointCloud,
    keep: Option<&[bool]>,
    params: &ResampleParams,
    scratch: &mut Vec<u64>,
    known: Option<(Bounds, usize)>,
) -> Result<Resampled> {
    resample_into(
        [&cloud.x, &cloud.y, &cloud.z],
        keep,
        params,
        cloud.crs().cloned(),
        scratch,
        known,
    )
}

/// [`resample`] on bare coordinate columns.
pub fn resample_xyz(
    x: &[f64],
    y: &[f64],
    z: &[f64],
    keep: Option<&[bool]>,
    params: &ResampleParams,
    crs: Option<Crs>,
) -> Result<Resampled> {
    resample_into([x, y, z], keep, params, crs, &mut Vec::new(), None)
}

fn resample_into(
    [x, y, z]: [&[f64]; 3],
    keep: Option<&[bool]>,
    params: &ResampleParams,
    crs: Option<Crs>,
    scratch: &mut Vec<u64>,
    known: Option<(Bounds, usize)>,
) -> Result<Resampled> {
    params.validate()?;
    let (bounds, points) = known.unwrap_or_else(|| super::bounds_of(x, y, z, keep));
    if points == 0 {
        return Err(Error::Data {
            stage: "resample",
            message: "no points to resample".into(),
        });
    }
    let spec = GridSpec::new(params, &bounds, points)?;
    let window = [0..spec.cols, 0..spec.rows];
    let grid = bin(x, y, z, keep, &spec, window, params.method, crs, scratch);
    Ok(Resampled { grid, spec, points })
}

/// The cells `window` (columns, rows) of the grid `spec`, from the points of `x`, `y`, `z`
/// whose `keep` flag is set (all when `None`): a shard's part of the whole run's grid,
/// holding exactly the heights the whole grid holds there when the points are those of
/// the window, in input order. Its corner is that of the window's first cell.
pub fn resample_window(
    [x, y, z]: [&[f64]; 3],
    keep: Option<&[bool]>,
    spec: &GridSpec,
    window: [std::ops::Range<usize>; 2],
    method: CellMethod,
    crs: Option<Crs>,
) -> Heightfield {
    bin(x, y, z, keep, spec, window, method, crs, &mut Vec::new())
}

/// Makes `scratch` `cells` zeroed sums; true when it was allocated afresh (its pages are then
/// already zero and the workers need not fill them).
fn reset_scratch(scratch: &mut Vec<u64>, cells: usize) -> bool {
    let fresh = scratch.capacity() < cells;
    if fresh {
        *scratch = Vec::new();
        *scratch = vec![0u64; cells];
    } else {
        scratch.truncate(cells);
        scratch.resize(cells, 0);
    }
    fresh
}

/// The corner of the window starting at cell (`i0`, `j0`): the whole grid's corner itself for
/// a window at its start (no `+ 0.0`, which would turn a −0 corner into +0).
fn window_corner(spec: &GridSpec, i0: usize, j0: usize) -> [f64; 2] {
    [
        if i0 == 0 {
            spec.corner[0]
        } else {
            spec.corner[0] + i0 as f64 * spec.cell_size[0]
        },
        if j0 == 0 {
            spec.corner[1]
        } else {
            spec.corner[1] + j0 as f64 * spec.cell_size[1]
        },
    ]
}

/// Bins the kept points into the cells `window` of `spec` (points outside it are skipped).
#[allow(clippy::too_many_arguments)]
fn bin(
    x: &[f64],
    y: &[f64],
    z: &[f64],
    keep: Option<&[bool]>,
    spec: &GridSpec,
    window: [std::ops::Range<usize>; 2],
    method: CellMethod,
    crs: Option<Crs>,
    scratch: &mut Vec<u64>,
) -> Heightfield {
    let kept = |i: usize| keep.is_none_or(|k| k[i]);
    let spec = *spec;
    let [i0, j0] = [window[0].start, window[1].start];
    let (cols, rows) = (window[0].len(), window[1].len());
    let n = x.len();
    // Bands of rows, one task each: a task scans all points and takes those in its rows, in
    // file order, into its own rows of the grid. No scratch but one f64 per cell, no atomics,
    // and each cell is summed in file order whatever the number of bands.
    let bands = rayon::current_num_threads().clamp(1, 16).min(rows);
    let band_rows = rows.div_ceil(bands);
    // With several bands, each kept point's cell is computed once (u32::MAX for removed
    // points), so that the bands scan 4 bytes per point instead of recomputing it. One band
    // computes it on the fly and saves the array (4 bytes per point, faulted in afresh).
    let cell_of = |i: usize| {
        if kept(i) {
            let (ci, cj) = spec.cell(x[i], y[i]);
            // Outside the window (wrapping below its start), like a removed point.
            let (ci, cj) = (ci.wrapping_sub(i0), cj.wrapping_sub(j0));
            if ci < cols && cj < rows {
                (cj * cols + ci) as u32
            } else {
                u32::MAX
            }
        } else {
            u32::MAX
        }
    };
    let cell: Vec<u32> = if bands > 1 {
        (0..n)
            .into_par_iter()
            .with_min_len(1 << 14)
            .map(cell_of)
            .collect()
    } else {
        Vec::new()
    };
    // The sums (f64 bits), one per cell, in the reused scratch.
    let cells = rows * cols;
    let fresh = reset_scratch(scratch, cells);
    let init = match method {
        CellMethod::Mean => 0.0f64,
        CellMethod::Min => f64::INFINITY,
        CellMethod::Max => f64::NEG_INFINITY,
    };
    let mut heights = Array2::<f32>::zeros((rows, cols));
    let mut counts = Array2::<u32>::zeros((rows, cols));
    // Filled by the workers: a serial fill faulted its fresh pages in on the calling thread
    // while the workers waited.
    let mut state = Array2::from_shape_vec(
        (rows, cols),
        (0..cells)
            .into_par_iter()
            .with_min_len(1 << 16)
            .map(|_| CellState::Empty)
            .collect(),
    )
    .expect("rows × cols states");
    heights
        .axis_chunks_iter_mut(Axis(0), band_rows)
        .into_par_iter()
        .zip(counts.axis_chunks_iter_mut(Axis(0), band_rows))
        .zip(state.axis_chunks_iter_mut(Axis(0), band_rows))
        .zip(scratch.par_chunks_mut(band_rows * cols))
        .enumerate()
        .for_each(|(band, (((mut h, mut c), mut s), acc))| {
            let (Some(h), Some(c), Some(s)) =
                (h.as_slice_mut(), c.as_slice_mut(), s.as_slice_mut())
            else {
                return;
            };
            if !(fresh && init.to_bits() == 0) {
                acc.fill(init.to_bits());
            }
            let first = (band * band_rows * cols) as u32;
            let span = h.len() as u32;
            let mut add = |i: usize, cell: u32| {
                // Removed points (u32::MAX) and other bands' cells fall outside the span.
                let k = cell.wrapping_sub(first);
                if k >= span {
                    return;
                }
                let k = k as usize;
                c[k] += 1;
                let a = f64::from_bits(acc[k]);
                acc[k] = match method {
                    CellMethod::Mean => a + z[i],
                    CellMethod::Min => a.min(z[i]),
                    CellMethod::Max => a.max(z[i]),
                }
                .to_bits();
            };
            if cell.is_empty() {
                (0..n).for_each(|i| add(i, cell_of(i)));
            } else {
                cell.iter().enumerate().for_each(|(i, &k)| add(i, k));
            }
            for k in 0..h.len() {
                if c[k] == 0 {
                    h[k] = f32::NAN;
                    continue;
                }
                let a = f64::from_bits(acc[k]);
                let v = match method {
                    CellMethod::Mean => a / c[k] as f64,
                    _ => a,
                };
                h[k] = (v - spec.z_offset) as f32;
                s[k] = CellState::Measured;
            }
        });
    Heightfield {
        heights,
        counts,
        state,
        corner: window_corner(&spec, i0, j0),
        cell_size: spec.cell_size,
        z_offset: spec.z_offset,
        crs,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::terrain::reference::{self, same_grid as same};

    fn scene() -> PointCloud {
        crate::generate::generate(&crate::generate::GenerateParams {
            seed: 5,
            points: 30_000,
            ..Default::default()
        })
        .unwrap()
        .cloud
    }

    #[test]
    fn fast_equals_slow_for_every_method_and_override() {
        let c = scene();
        let keep: Vec<bool> = (0..c.len()).map(|i| i % 7 != 3).collect();
        for method in [CellMethod::Mean, CellMethod::Min, CellMethod::Max] {
            for (cell_size, size) in [(None, None), (Some(2.5), None), (None, Some([100, 37]))] {
                let p = ResampleParams {
                    method,
                    cell_size,
                    size,
                };
                let fast = resample(&c, Some(&keep), &p).unwrap().grid;
                let slow = reference::resample(&c, Some(&keep), &p).unwrap();
                assert!(same(&fast, &slow), "{p:?}");
            }
        }
    }

    #[test]
    fn reused_scratch_gives_the_same_grid() {
        let c = scene();
        let keep: Vec<bool> = (0..c.len()).map(|i| i % 5 != 1).collect();
        for method in [CellMethod::Mean, CellMethod::Min, CellMethod::Max] {
            let p = ResampleParams {
                method,
                ..Default::default()
            };
            let want = resample(&c, Some(&keep), &p).unwrap().grid;
            // Leftovers of another stage (too short, and long enough), on 1, 2 and 8 bands.
            for len in [10, c.len() + 7] {
                for threads in [1, 2, 8] {
                    let mut scratch: Vec<u64> = (0..len as u64)
                        .map(|i| i.wrapping_mul(0x9E37_79B9_7F4A_7C15))
                        .collect();
                    let got = rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .unwrap()
                        .install(|| resample_reusing(&c, Some(&keep), &p, &mut scratch, None))
                        .unwrap()
                        .grid;
                    assert!(same(&got, &want), "{method:?} {len} {threads}");
                }
            }
        }
    }

    #[test]
    fn clamped_index_is_the_unsigned_cast() {
        let mut rng = crate::rng::SplitMix64::new(3);
        let special = [
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            -0.0,
            0.0,
            -0.5,
            -1.0,
            0.999_999_999,
            1.0,
            4.0,
            4.5,
            5.0,
            1e19,
            -1e19,
            9.3e18,
            f64::MAX,
            f64::MIN_POSITIVE,
        ];
        for n in [1usize, 2, 5, 1842, 1 << 20] {
            let random = (0..10_000).map(|_| (rng.unit() * 3.0 - 1.0) * n as f64);
            for v in special.into_iter().chain(random) {
                assert_eq!(clamped_index(v, n), (v as usize).min(n - 1), "{v} {n}");
            }
        }
    }

    #[test]
    fn sqrt_rule_and_paper_clamp() {
        let c = scene();
        let r = resample(&c, None, &ResampleParams::default()).unwrap();
        let n = (c.len() as f64).sqrt().round() as usize;
        assert_eq!((r.spec.cols, r.spec.rows), (n, n));
        let b = c.bounds();
        assert_eq!(r.spec.cell(b.max[0], b.max[1]), (n - 1, n - 1));
        assert_eq!(
            r.grid.counts.iter().map(|&v| v as usize).sum::<usize>(),
            c.len()
        );
        // Every measured cell's height lies within its points' z range.
        assert!(r.grid.heights.iter().all(|h| h.is_nan() || (h.abs() < 1e4)));
    }

    #[test]
    fn same_bits_for_any_thread_count() {
        let c = scene();
        let run = |t: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(t)
                .build()
                .unwrap()
                .install(|| resample(&c, None, &ResampleParams::default()).unwrap().grid)
        };
        let one = run(1);
        assert!(same(&one, &run(2)));
        assert!(same(&one, &run(8)));
    }

    #[test]
    fn bad_overrides() {
        let c = scene();
        for (p, start) in [
            (
                ResampleParams {
                    cell_size: Some(0.0),
                    ..Default::default()
                },
                "resample: cell_size = 0:",
            ),
            (
                ResampleParams {
                    cell_size: Some(f64::NAN),
                    ..Default::default()
                },
                "resample: cell_size = NaN:",
            ),
            (
                ResampleParams {
                    size: Some([0, 10]),
                    ..Default::default()
                },
                "resample: size = [0, 10]:",
            ),
            (
                ResampleParams {
                    size: Some([10, 0]),
                    ..Default::default()
                },
                "resample: size = [10, 0]:",
            ),
        ] {
            let e = resample(&c, None, &p).unwrap_err().to_string();
            assert!(e.starts_with(start), "{e}");
        }
    }

    #[test]
    fn a_line_of_points_is_refused() {
        let x: Vec<f64> = (0..50).map(|i| 10.0 + i as f64).collect();
        let y = vec![3.0; 50];
        let z = vec![1.0; 50];
        let e = resample_xyz(&x, &y, &z, None, &ResampleParams::default(), None)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("resample: y range = 0: all 50 points share y = 3"),
            "{e}"
        );
        let one = resample_xyz(
            &[1.0; 5],
            &[2.0; 5],
            &[3.0; 5],
            None,
            &ResampleParams::default(),
            None,
        )
        .unwrap_err()
        .to_string();
        assert!(one.starts_with("resample: x range = 0"), "{one}");
    }
}
