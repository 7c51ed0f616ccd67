//! Hole filling, Kim & Shin §2.3: radius-bounded bilinear interpolation
//! from the nearest measured cells to the left, right, below and above.
//!
//! For an empty cell, the nearest *measured* cell along its row to the left (distance dl,
//! height L) and to the right (dr, R), and along its column below (dd, D) and above (du, U),
//! each within `radius` cells, are combined as Kim & Shin §2.3 says:
//! hx = (L·dr + R·dl)/(dl + dr), hy = (D·du + U·dd)/(dd + du) and, with both pairs,
//! h = (hx/(dl+dr) + hy/(dd+du)) / (1/(dl+dr) + 1/(dd+du)); with an incomplete pair, the
//! neighbours found are averaged with inverse-distance weights (which is the pair formula
//! when only one pair is found). Distances are in world units (cells × cell size along
//! that axis), so non-square cells weigh their axes fairly.
//!
//! Only measured cells are sources, so the result does not depend on the visiting order.
//! The nearest measured cells come from prefix scans: the grid is cut into one band of rows
//! per worker; a worker sweeps its band top-down once to note the nearest measured row above
//! each cell, then bottom-up keeping the last measured row of every column, scanning each row
//! both ways for the nearest measured cell left and right. The `radius` rows beyond a band's
//! edges are copied beforehand, so bands never read what another band writes. O(cells),
//! 2 bytes of scratch per cell.
//!
//! Cells with no measured cell within the radius take the fallback: the mean height of all
//! samples (the paper), `nodata` (the hole stays, masked), or `smooth` — a push-pull fill
//! (Gortler et al. 1996): the known cells are averaged up a pyramid of 2×2 blocks until
//! every coarse cell is known, then each unknown cell takes the bilinear interpolation of
//! the level above. It continues the surrounding terrain into lakes and data gaps instead of
//! putting a plateau at the survey's mean height there.

use super::heightfield::{CellState, Heightfield};
use crate::error::{Error, Result};
use ndarray::{Axis, Zip};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// What a cell without a measured neighbour within the radius becomes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Fallback {
    /// The mean height of all samples (the paper).
    Mean,
    /// Nothing: the cell stays a hole (NaN, state `Empty`), masked in the outputs.
    Nodata,
    /// A smooth continuation of the surrounding terrain (push-pull over a pyramid): no
    /// holes and no plateaus; the default, because game tiles need both.
    #[default]
    Smooth,
    /// The membrane (Laplace) surface of the cells around every large void (see
    /// `largevoid`): also takes the cells the axis fill could only reach from one side.
    Membrane,
}

/// Default `radius` in cells.
pub const DEFAULT_RADIUS: f64 = 8.0;

/// `[fill]`: hole filling.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct FillParams {
    /// Run the stage (default true).
    pub enabled: bool,
    /// How far to look for a measured cell along the row and the column, in cells
    /// (default 8).
    pub radius: f64,
    /// `smooth` (default), `mean` (the paper) or `nodata` for cells with no measured cell
    /// within the radius; `membrane` for those and the cells reached from one side only.
    pub fallback: Fallback,
}

impl Default for FillParams {
    fn default() -> Self {
        FillParams {
            enabled: true,
            radius: DEFAULT_RADIUS,
            fallback: Fallback::default(),
        }
    }
}

impl FillParams {
    /// Checks the values a user can get wrong, before any data is read.
    pub fn validate(&self) -> Result<()> {
        if !(self.radius > 0.0 && self.radius.is_finite()) {
            return Err(Error::param(
                "fill",
                "radius",
                self.radius,
                "must be a positive number of cells",
            ));
        }
        if self.radius > MAX_RADIUS as f64 {
            return Err(Error::param(
                "fill",
                "radius",
                self.radius,
                format!("at most {MAX_RADIUS} cells"),
            ));
        }
        Ok(())
    }

    /// The radius in whole cells (0 below one cell: no neighbour is that close).
    fn cells(&self) -> u16 {
        self.radius.floor().clamp(0.0, MAX_RADIUS as f64) as u16
    }
}

/// Largest `radius`: distances are kept as 16-bit cell counts.
pub const MAX_RADIUS: u16 = u16::MAX;

/// What filling did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct FillReport {
    /// Cells with samples.
    pub measured: usize,
    /// Cells filled by interpolation.
    pub interpolated: usize,
    /// Cells filled by the fallback.
    pub fallback: usize,
    /// Cells left empty (`nodata`).
    pub empty: usize,
}

/// Fills the empty cells of `hf` in place. Measured cells are never changed.
pub fn fill(hf: &mut Heightfield, params: &FillParams) -> Result<FillReport> {
    params.validate()?;
    let r = params.cells() as usize;
    let (rows, cols) = hf.heights.dim();
    if rows == 0 || cols == 0 {
        return Ok(FillReport::default());
    }
    if !hf.heights.is_standard_layout() || !hf.state.is_standard_layout() {
        hf.heights = hf.heights.as_standard_layout().into_owned();
        hf.state = hf.state.as_standard_layout().into_owned();
    }
    // Bands of rows, a few per worker so that rayon can balance them (with one band per
    // worker, a band holding most of the holes keeps one core busy while the other idles). A band
    // reads measured cells up to `r` rows beyond its edges: those rows are copied first
    // (measured cells never change, so the copies stay true while the bands are filled in
    // parallel): 2r rows per band, so bands are kept to about 2r rows or more.
    let bands = (rayon::current_num_threads() * 4)
        .min(rows.div_ceil((2 * r).max(16)))
        .clamp(1, 64);
    let band_rows = rows.div_ceil(bands);
    let halo = |j0: usize, j1: usize| -> Halo {
        let (a, b) = (j0.min(rows), j1.min(rows));
        (a, rows_of(&hf.heights, a..b), rows_of(&hf.state, a..b))
    };
    let halos: Vec<[Halo; 2]> = (0..rows.div_ceil(band_rows))
        .map(|b| {
            let (j0, j1) = (b * band_rows, ((b + 1) * band_rows).min(rows));
            [halo(j0.saturating_sub(r), j0), halo(j1, j1 + r)]
        })
        .collect();
    let [dx, dy] = hf.cell_size;
    let membrane = params.fallback == Fallback::Membrane;
    let none = BandFill {
        measured: 0,
        interpolated: 0,
        missing: 0,
        lo: f32::INFINITY,
        hi: f32::NEG_INFINITY,
    };
    let done = hf
        .heights
        .axis_chunks_iter_mut(Axis(0), band_rows)
        .into_par_iter()
        .zip(hf.state.axis_chunks_iter_mut(Axis(0), band_rows))
        .zip(&halos)
        .enumerate()
        .map(|(band, ((mut h, mut s), halo))| {
            let (Some(h), Some(s)) = (h.as_slice_mut(), s.as_slice_mut()) else {
                return none;
            };
            let at = Band {
                j0: band * band_rows,
                cols,
                r,
                cell: [dx, dy],
                membrane,
            };
            fill_band(h, s, &at, halo)
        })
        .reduce(
            || none,
            |a, b| BandFill {
                measured: a.measured + b.measured,
                interpolated: a.interpolated + b.interpolated,
                missing: a.missing + b.missing,
                lo: a.lo.min(b.lo),
                hi: a.hi.max(b.hi),
            },
        );
    drop(halos);
    let mut report = FillReport {
        measured: done.measured,
        interpolated: done.interpolated,
        fallback: 0,
        empty: done.missing,
    };
    let missing = done.missing;
    if membrane {
        super::largevoid::membrane_large_voids(hf, [done.lo, done.hi], &mut report);
    } else if missing > 0 {
        match params.fallback {
            Fallback::Membrane => {}
            Fallback::Nodata => {}
            Fallback::Mean => {
                let mean = sample_mean(hf) as f32;
                Zip::from(&mut hf.heights)
                    .and(&mut hf.state)
                    .par_for_each(|h, s| {
                        if *s == CellState::Empty {
                            *h = mean;
                            *s = CellState::Fallback;
                        }
                    });
                (report.fallback, report.empty) = (missing, 0);
            }
            Fallback::Smooth => {
                push_pull(hf);
                (report.fallback, report.empty) = (missing, 0);
            }
        }
    }
    Ok(report)
}

/// Rows copied from beyond a band's edge: (first row, heights, states), whole rows.
type Halo = (usize, Vec<f32>, Vec<CellState>);

/// A copy of the rows `rows` of `a` (whole rows, in memory order).
fn rows_of<T: Copy>(a: &ndarray::Array2<T>, rows: std::ops::Range<usize>) -> Vec<T> {
    let part = a.slice(ndarray::s![rows, ..]);
    match part.as_slice() {
        Some(s) => s.to_vec(),
        None => part.iter().copied().collect(),
    }
}

/// Where a band lies and how it is filled.
struct Band {
    /// First row.
    j0: usize,
    cols: usize,
    /// Radius in cells.
    r: usize,
    /// Cell size (x, y).
    cell: [f64; 2],
    /// `fallback = "membrane"`: only the cells with a measured cell on all four sides are
    /// interpolated; every other empty cell is left to the membrane (see `largevoid`).
    membrane: bool,
}

/// What [`fill_band`] did.
#[derive(Debug, Clone, Copy)]
struct BandFill {
    measured: usize,
    interpolated: usize,
    /// Empty cells left (with `membrane`: every one the membrane solves for).
    missing: usize,
    /// With `membrane`, the range of the finite heights left (the tolerance of its solve).
    lo: f32,
    hi: f32,
}

/// The rows a band may read: its own (`j0..j1`, in the band's slices) and its halos' (the
/// rows below from `below.0`, the rows above from `above.0`), by grid row.
struct BandRows<'a> {
    j0: usize,
    j1: usize,
    cols: usize,
    below: &'a Halo,
    above: &'a Halo,
}

impl BandRows<'_> {
    /// Where row `j` (own or halo) lies in its slice.
    #[inline]
    fn row(&self, j: usize) -> std::ops::Range<usize> {
        let k = if j >= self.j1 {
            (j - self.above.0) * self.cols
        } else if j >= self.j0 {
            (j - self.j0) * self.cols
        } else {
            (j - self.below.0) * self.cols
        };
        k..k + self.cols
    }

    /// The height at (j, i): the band's own `h` or a halo's.
    #[inline]
    fn height(&self, h: &[f32], j: usize, i: usize) -> f32 {
        let k = self.row(j).start + i;
        if j >= self.j1 {
            self.above.1[k]
        } else if j >= self.j0 {
            h[k]
        } else {
            self.below.1[k]
        }
    }

    /// One past the last row readable above.
    #[inline]
    fn hi(&self) -> usize {
        self.above.0 + self.above.1.len() / self.cols
    }

    /// Whether (j, i), at or above the band's first row, is measured (false past the halo).
    #[inline]
    fn measured_at(&self, s: &[CellState], j: usize, i: usize) -> bool {
        j < self.hi()
            && (if j >= self.j1 {
                self.above.2[(j - self.above.0) * self.cols + i]
            } else {
                s[(j - self.j0) * self.cols + i]
            }) == CellState::Measured
    }

    /// Distance to the nearest measured cell above (j, i) within `r` rows (0: none), looked
    /// up when a hole needs it (the scan stops at the first measured cell), instead of a
    /// top-down sweep that wrote a distance for every cell of the band. Rows above j are
    /// visited later, so their states are still the measured ones.
    #[inline]
    fn up_gap(&self, s: &[CellState], j: usize, i: usize, r: usize) -> usize {
        (1..=r)
            .take_while(|d| j + d < self.hi())
            .find(|&d| self.measured_at(s, j + d, i))
            .unwrap_or(0)
    }
}

/// Interpolates the empty cells of one band (rows from `at.j0`; `h`, `s` its cells) from the
/// measured cells within `at.r` cells, reading beyond the band from `halo` (below, above).
/// With `at.membrane` a cell is interpolated only with both of Kim & Shin's pairs complete;
/// the others become NaN, their state [`CellState::Fallback`] (what the membrane makes of
/// them), counted as missing: flagging them here spares a second pass that looked along every
/// interpolated cell's row and column again.
fn fill_band(h: &mut [f32], s: &mut [CellState], at: &Band, halo: &[Halo; 2]) -> BandFill {
    let Band {
        j0,
        cols,
        r,
        cell: [dx, dy],
        membrane,
    } = *at;
    let (mut zlo, mut zhi) = (f32::INFINITY, f32::NEG_INFINITY);
    let rows = BandRows {
        j0,
        j1: j0 + h.len() / cols,
        cols,
        below: &halo[0],
        above: &halo[1],
    };
    let j1 = rows.j1;
    let lo = rows.below.0;
    // The up distance each column's hole of the previous row found (`up_row[i]` = that row
    // + 1, `up_d[i]` the distance, 0 for none): the hole below it has the same nearest
    // measured cell above, one row closer (rows above are still unchanged), or when there
    // was none within r rows, can only find one r rows up. A run of holes down a column thus
    // costs one look per hole instead of a scan of up to r rows each (a strided scan: most of
    // this stage's cache misses).
    let mut up_row = vec![u32::MAX; cols];
    let mut up_d = vec![0u16; cols];
    // Bottom-up: the nearest measured row below from a running record (`last`), the nearest
    // measured cell to the right from a backward scan of the row, to the left from a running
    // record along the row; then Kim & Shin's combination.
    let mut last = vec![u32::MAX; cols];
    for j in lo..j0 {
        for (l, st) in last.iter_mut().zip(&rows.below.2[rows.row(j)]) {
            if *st == CellState::Measured {
                *l = j as u32;
            }
        }
    }
    let mut right = vec![0u16; cols];
    let weights = Weights::new(r, [dx, dy]);
    let (mut measured, mut done, mut missing) = (0, 0, 0);
    for j in j0..j1 {
        let row = (j - j0) * cols;
        let mut prev = usize::MAX;
        for i in (0..cols).rev() {
            right[i] = if prev != usize::MAX && prev - i <= r {
                (prev - i) as u16
            } else {
                0
            };
            if s[row + i] == CellState::Measured {
                prev = i;
            }
        }
        let mut left_at = usize::MAX;
        for i in 0..cols {
            match s[row + i] {
                CellState::Measured => {
                    measured += 1;
                    last[i] = j as u32;
                    left_at = i;
                    if membrane && h[row + i].is_finite() {
                        (zlo, zhi) = (zlo.min(h[row + i]), zhi.max(h[row + i]));
                    }
                    continue;
                }
                CellState::Empty => {}
                _ => {
                    if membrane && h[row + i].is_finite() {
                        (zlo, zhi) = (zlo.min(h[row + i]), zhi.max(h[row + i]));
                    }
                    continue;
                }
            }
            let l = if left_at != usize::MAX && i - left_at <= r {
                i - left_at
            } else {
                0
            };
            let rt = right[i] as usize;
            let d = (j as u32).wrapping_sub(last[i]) as usize;
            let d = if last[i] != u32::MAX && d <= r { d } else { 0 };
            let u = match up_d[i] {
                _ if up_row[i] != j as u32 => rows.up_gap(s, j, i, r),
                0 if r > 0 && rows.measured_at(s, j + r, i) => r,
                0 => 0,
                d if d >= 2 => d as usize - 1,
                // (The hole's cell was measured: cannot be; scan as without a record.)
                _ => rows.up_gap(s, j, i, r),
            };
            up_row[i] = j as u32 + 1;
            up_d[i] = u as u16;
            if membrane && (l == 0 || rt == 0 || d == 0 || u == 0) {
                h[row + i] = f32::NAN;
                s[row + i] = CellState::Fallback;
                missing += 1;
                continue;
            }
            let n = Neighbours {
                left: (l > 0).then(|| (l as f64 * dx, h[row + i - l] as f64)),
                right: (rt > 0).then(|| (rt as f64 * dx, h[row + i + rt] as f64)),
                down: (d > 0).then(|| (d as f64 * dy, rows.height(h, j - d, i) as f64)),
                up: (u > 0).then(|| (u as f64 * dy, rows.height(h, j + u, i) as f64)),
            };
            match weights.interpolate(&n, [l, rt, d, u]) {
                Some(v) => {
                    h[row + i] = v as f32;
                    s[row + i] = CellState::Interpolated;
                    done += 1;
                    if membrane && h[row + i].is_finite() {
                        (zlo, zhi) = (zlo.min(h[row + i]), zhi.max(h[row + i]));
                    }
                }
                None => missing += 1,
            }
        }
    }
    BandFill {
        measured,
        interpolated: done,
        missing,
        lo: zlo,
        hi: zhi,
    }
}

/// The measured neighbours of an empty cell: (distance in world units, height).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Neighbours {
    pub left: Option<(f64, f64)>,
    pub right: Option<(f64, f64)>,
    pub down: Option<(f64, f64)>,
    pub up: Option<(f64, f64)>,
}

impl Neighbours {
    /// Kim & Shin's combination (§2.3); None without any neighbour.
    pub fn interpolate(&self) -> Option<f64> {
        if let (Some((dl, l)), Some((dr, r)), Some((dd, d)), Some((du, u))) =
            (self.left, self.right, self.down, self.up)
        {
            let hx = (l * dr + r * dl) / (dl + dr);
            let hy = (d * du + u * dd) / (dd + du);
            let (wx, wy) = (1.0 / (dl + dr), 1.0 / (dd + du));
            return Some((hx * wx + hy * wy) / (wx + wy));
        }
        let (mut num, mut den) = (0.0, 0.0);
        for (d, v) in [self.left, self.right, self.down, self.up]
            .into_iter()
            .flatten()
        {
            num += v / d;
            den += 1.0 / d;
        }
        (den > 0.0).then(|| num / den)
    }
}

/// The distance sums and reciprocals of Kim & Shin's combination for every pair of whole
/// cell distances within the radius, each computed once by the very operations
/// [`Neighbours::interpolate`] performs, so that looking them up gives the same bits: two of
/// the five divisions an interpolated cell costs (the pair weights) become loads. Built for
/// radii up to [`Weights::MAX_TABULATED`] cells (a few KiB); beyond, cells are interpolated
/// by [`Neighbours::interpolate`] itself.
struct Weights {
    /// Radius in cells; 0 when not tabulated.
    r: usize,
    /// Per axis (x, y), for distances a, b in 1..=r at `(a − 1)·r + b − 1`: a·cell + b·cell
    /// and 1 / (a·cell + b·cell).
    sum: [Vec<f64>; 2],
    inv_sum: [Vec<f64>; 2],
    /// Per axis, for a distance a in 1..=r at `a − 1`: 1 / (a·cell).
    inv: [Vec<f64>; 2],
}

impl Weights {
    /// Largest radius tabulated (r² entries per table).
    const MAX_TABULATED: usize = 64;

    fn new(r: usize, cell: [f64; 2]) -> Weights {
        if r == 0 || r > Weights::MAX_TABULATED {
            return Weights {
                r: 0,
                sum: [Vec::new(), Vec::new()],
                inv_sum: [Vec::new(), Vec::new()],
                inv: [Vec::new(), Vec::new()],
            };
        }
        let pairs = |c: f64| -> Vec<f64> {
            (0..r * r)
                .map(|k| (k / r + 1) as f64 * c + (k % r + 1) as f64 * c)
                .collect()
        };
        let sum = [pairs(cell[0]), pairs(cell[1])];
        let inv_sum = [
            sum[0].iter().map(|s| 1.0 / s).collect(),
            sum[1].iter().map(|s| 1.0 / s).collect(),
        ];
        let inv = cell.map(|c| (1..=r).map(|a| 1.0 / (a as f64 * c)).collect());
        Weights {
            r,
            sum,
            inv_sum,
            inv,
        }
    }

    /// [`Neighbours::interpolate`] of `n`, whose distances are `cells` = (left, right, down,
    /// up) whole cells (0: that neighbour is absent) times the cell size of their axis.
    #[inline]
    fn interpolate(&self, n: &Neighbours, cells: [usize; 4]) -> Option<f64> {
        let r = self.r;
        if r == 0 {
            return n.interpolate();
        }
        let [l, rt, d, u] = cells;
        if let (Some((dl, lv)), Some((dr, rv)), Some((dd, dv)), Some((du, uv))) =
            (n.left, n.right, n.down, n.up)
        {
            let (px, py) = ((l - 1) * r + rt - 1, (d - 1) * r + u - 1);
            let hx = (lv * dr + rv * dl) / self.sum[0][px];
            let hy = (dv * du + uv * dd) / self.sum[1][py];
            let (wx, wy) = (self.inv_sum[0][px], self.inv_sum[1][py]);
            return Some((hx * wx + hy * wy) / (wx + wy));
        }
        let (mut num, mut den) = (0.0, 0.0);
        for (k, side) in [n.left, n.right, n.down, n.up].into_iter().enumerate() {
            if let Some((dist, v)) = side {
                num += v / dist;
                den += self.inv[k / 2][cells[k] - 1];
            }
        }
        (den > 0.0).then(|| num / den)
    }
}

/// Mean height of all samples: measured cells weighted by their counts (for `mean` cells,
/// exactly the mean of the points' z up to f32 rounding). Summed in fixed chunks, so the
/// result does not depend on the thread count.
pub(crate) fn sample_mean(hf: &Heightfield) -> f64 {
    let h = hf.heights.as_slice_memory_order();
    let c = hf.counts.as_slice_memory_order();
    let s = hf.state.as_slice_memory_order();
    let (Some(h), Some(c), Some(s)) = (h, c, s) else {
        return f64::NAN;
    };
    let parts: Vec<(f64, f64)> = h
        .par_chunks(1 << 14)
        .zip(c.par_chunks(1 << 14))
        .zip(s.par_chunks(1 << 14))
        .map(|((h, c), s)| {
            let mut acc = (0.0, 0.0);
            for k in 0..h.len() {
                if s[k] == CellState::Measured {
                    acc.0 += h[k] as f64 * c[k] as f64;
                    acc.1 += c[k] as f64;
                }
            }
            acc
        })
        .collect();
    let (num, den) = parts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
    num / den
}

/// Push-pull fill of every `Empty` cell from the cells that have a height. Unknown values
/// are NaN at every level (a cell with a height is finite), so a level is one f32 array.
pub(crate) fn push_pull(hf: &mut Heightfield) {
    let (rows, cols) = hf.heights.dim();
    let Some(level0) = hf.heights.as_slice() else {
        return;
    };
    // Push: average the known children of each 2×2 block until a level is all known.
    let mut pyramid: Vec<(Vec<f32>, usize, usize)> = Vec::new();
    loop {
        let (v, h, w) = match pyramid.last() {
            Some((v, h, w)) => (v.as_slice(), *h, *w),
            None => (level0, rows, cols),
        };
        if !v.par_iter().any(|x| x.is_nan()) {
            break;
        }
        if h == 1 && w == 1 {
            return; // nothing known at all: the holes stay
        }
        let next = push_level(v, h, w);
        pyramid.push(next);
    }
    if let Some(h0) = hf.heights.as_slice_mut() {
        pull_down(h0, cols, pyramid);
    }
    mark_fallback(hf);
}

/// Empty cells that now have a height were filled by the fallback.
pub(crate) fn mark_fallback(hf: &mut Heightfield) {
    Zip::from(&mut hf.state)
        .and(&hf.heights)
        .par_for_each(|s, h| {
            if *s == CellState::Empty && !h.is_nan() {
                *s = CellState::Fallback;
            }
        });
}

/// The pull half of [`push_pull`]: fills each level's unknown cells from the completed level
/// above, top down (`pyramid` from level 1 up, its last level complete), then those of
/// `level0` (`w` wide).
pub(crate) fn pull_down(level0: &mut [f32], w: usize, mut pyramid: Vec<(Vec<f32>, usize, usize)>) {
    let mut above = match pyramid.pop() {
        Some(top) => top,
        None => return,
    };
    while let Some(mut level) = pyramid.pop() {
        pull_level(&mut level.0, level.2, &above.0, above.1, above.2);
        above = level;
    }
    pull_level(level0, w, &above.0, above.1, above.2);
}

/// One level up: each cell the mean of the known (non-NaN) cells of its 2×2 block.
pub(crate) fn push_level(v: &[f32], h: usize, w: usize) -> (Vec<f32>, usize, usize) {
    let (nh, nw) = (h.div_ceil(2), w.div_ceil(2));
    let mut up = vec![f32::NAN; nh * nw];
    up.par_chunks_mut(nw).enumerate().for_each(|(j, out)| {
        // The block's two rows (the second absent past the last row) as slices, so that the
        // children are read without an index or bounds test each: (2j, 2i), (2j, 2i + 1),
        // (2j + 1, 2i), (2j + 1, 2i + 1) in that order, as the sum's rounding needs.
        let lower = &v[2 * j * w..(2 * j + 1) * w];
        let upper = v.get((2 * j + 1) * w..(2 * j + 2) * w).unwrap_or(&[]);
        let mut above = upper.chunks(2);
        for (o, below) in out.iter_mut().zip(lower.chunks(2)) {
            let (mut sum, mut n) = (0.0f64, 0u32);
            for &x in below.iter().chain(above.next().unwrap_or(&[])) {
                if !x.is_nan() {
                    sum += x as f64;
                    n += 1;
                }
            }
            if n > 0 {
                *o = (sum / n as f64) as f32;
            }
        }
    });
    (up, nh, nw)
}

/// Fills the NaN cells of a level `w` wide bilinearly from the level above (ah × aw).
fn pull_level(v: &mut [f32], w: usize, above: &[f32], ah: usize, aw: usize) {
    v.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
        for (i, x) in row.iter_mut().enumerate() {
            if x.is_nan() {
                *x = bilinear_half(above, ah, aw, i, j) as f32;
            }
        }
    });
}

/// The value of the coarser level `a` (ah × aw, half resolution) at the centre of fine
/// cell (i, j).
fn bilinear_half(a: &[f32], ah: usize, aw: usize, i: usize, j: usize) -> f64 {
    let fx = ((i as f64 + 0.5) / 2.0 - 0.5).clamp(0.0, (aw - 1) as f64);
    let fy = ((j as f64 + 0.5) / 2.0 - 0.5).clamp(0.0, (ah - 1) as f64);
    // fx, fy ≥ 0: truncation is the floor (and no libm call on baseline x86-64).
    let (i0, j0) = (fx as usize, fy as usize);
    let (i1, j1) = ((i0 + 1).min(aw - 1), (j0 + 1).min(ah - 1));
    let (tx, ty) = (fx - i0 as f64, fy - j0 as f64);
    let g = |j: usize, i: usize| a[j * aw + i] as f64;
    (g(j0, i0) * (1.0 - tx) + g(j0, i1) * tx) * (1.0 - ty)
        + (g(j1, i0) * (1.0 - tx) + g(j1, i1) * tx) * ty
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    use crate::terrain::reference;

    fn same(a: &Heightfield, b: &Heightfield) -> bool {
        a.heights
            .iter()
            .zip(b.heights.iter())
            .all(|(p, q)| p.to_bits() == q.to_bits())
            && a.state == b.state
    }

    /// A grid with random holes and one big void.
    pub(crate) fn holey(seed: u64, cols: usize, rows: usize) -> Heightfield {
        let mut rng = crate::rng::SplitMix64::new(seed);
        let mut hf = Heightfield::empty(cols, rows, [0.0, 0.0], [1.5, 1.0], 0.0, None);
        for j in 0..rows {
            for i in 0..cols {
                let void = (i as f64 - cols as f64 * 0.6).hypot(j as f64 - rows as f64 * 0.4)
                    < rows as f64 * 0.2;
                if !void && rng.unit() < 0.6 {
                    hf.heights[[j, i]] =
                        (0.3 * i as f64 + 5.0 * (j as f64 * 0.1).sin() + rng.unit()) as f32;
                    hf.counts[[j, i]] = 1 + rng.below(3) as u32;
                    hf.state[[j, i]] = CellState::Measured;
                }
            }
        }
        hf
    }

    #[test]
    fn fast_equals_slow() {
        for fallback in [Fallback::Mean, Fallback::Nodata, Fallback::Smooth] {
            for (seed, radius) in [(1, 1.0), (2, 3.0), (3, 8.0), (4, 40.0)] {
                let hf = holey(seed, 71, 53);
                let p = FillParams {
                    radius,
                    fallback,
                    ..Default::default()
                };
                let mut fast = hf.clone();
                fill(&mut fast, &p).unwrap();
                assert!(same(&fast, &reference::fill(&hf, &p).unwrap()), "{p:?}");
            }
        }
    }

    /// [`push_level`] as first written: each child by its index, bounds tested.
    fn push_level_by_index(v: &[f32], h: usize, w: usize) -> Vec<f32> {
        let (nh, nw) = (h.div_ceil(2), w.div_ceil(2));
        let mut up = vec![f32::NAN; nh * nw];
        for j in 0..nh {
            for i in 0..nw {
                let (mut sum, mut n) = (0.0f64, 0u32);
                for (cj, ci) in [
                    (2 * j, 2 * i),
                    (2 * j, 2 * i + 1),
                    (2 * j + 1, 2 * i),
                    (2 * j + 1, 2 * i + 1),
                ] {
                    if cj < h && ci < w && !v[cj * w + ci].is_nan() {
                        sum += v[cj * w + ci] as f64;
                        n += 1;
                    }
                }
                if n > 0 {
                    up[j * nw + i] = (sum / n as f64) as f32;
                }
            }
        }
        up
    }

    #[test]
    fn push_level_equals_the_indexed_one() {
        let mut rng = crate::rng::SplitMix64::new(11);
        for (h, w) in [(1, 1), (1, 2), (2, 1), (3, 3), (7, 4), (4, 9), (33, 17)] {
            let v: Vec<f32> = (0..h * w)
                .map(|_| {
                    if rng.unit() < 0.4 {
                        f32::NAN
                    } else {
                        (rng.unit() * 1000.0) as f32
                    }
                })
                .collect();
            let (up, nh, nw) = push_level(&v, h, w);
            assert_eq!((nh, nw), (h.div_ceil(2), w.div_ceil(2)));
            let want = push_level_by_index(&v, h, w);
            assert!(
                up.iter()
                    .zip(&want)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{h}×{w}"
            );
        }
    }

    #[test]
    fn tabulated_weights_give_the_same_bits() {
        let mut rng = crate::rng::SplitMix64::new(7);
        for (r, cell) in [(1, [1.0, 1.0]), (8, [1.86, 2.527]), (13, [0.3, 7.1])] {
            let w = Weights::new(r, cell);
            for _ in 0..20_000 {
                // Each side absent (0) or at 1..=r cells.
                let cells: [usize; 4] = std::array::from_fn(|_| rng.below(r as u64 + 1) as usize);
                let mut side = |k: usize, c: f64| {
                    (cells[k] > 0).then(|| (cells[k] as f64 * c, 100.0 * rng.unit() - 50.0))
                };
                let n = Neighbours {
                    left: side(0, cell[0]),
                    right: side(1, cell[0]),
                    down: side(2, cell[1]),
                    up: side(3, cell[1]),
                };
                let (fast, slow) = (w.interpolate(&n, cells), n.interpolate());
                assert_eq!(fast.map(f64::to_bits), slow.map(f64::to_bits), "{cells:?}");
            }
        }
    }

    #[test]
    fn spec_formula_on_a_cross() {
        // L = 1 at distance 1, R = 4 at distance 2, D = 10 at 1, U = 20 at 3 (unit cells).
        let n = Neighbours {
            left: Some((1.0, 1.0)),
            right: Some((2.0, 4.0)),
            down: Some((1.0, 10.0)),
            up: Some((3.0, 20.0)),
        };
        let hx = (1.0 * 2.0 + 4.0 * 1.0) / 3.0;
        let hy = (10.0 * 3.0 + 20.0 * 1.0) / 4.0;
        let want = (hx / 3.0 + hy / 4.0) / (1.0 / 3.0 + 1.0 / 4.0);
        assert!((n.interpolate().unwrap() - want).abs() < 1e-12);
        let pair = Neighbours {
            left: Some((1.0, 1.0)),
            right: Some((2.0, 4.0)),
            ..Default::default()
        };
        assert!((pair.interpolate().unwrap() - hx).abs() < 1e-12);
        assert!(Neighbours::default().interpolate().is_none());
    }

    #[test]
    fn planes_are_filled_exactly() {
        // 2 × 2 holes surrounded by measured cells: every hole has both pairs, and along a row
        // or a column the pair formula is linear interpolation, so a plane comes back exactly.
        let mut hf = Heightfield::empty(21, 17, [0.0, 0.0], [1.0, 2.0], 0.0, None);
        let hole = |k: usize| k % 4 == 1 || k % 4 == 2;
        for j in 0..17 {
            for i in 0..21 {
                if !(hole(i) && hole(j)) {
                    hf.heights[[j, i]] = (2.0 * i as f64 + 0.5 * j as f64) as f32;
                    hf.state[[j, i]] = CellState::Measured;
                }
            }
        }
        let report = fill(&mut hf, &FillParams::default()).unwrap();
        assert_eq!(report.interpolated, 5 * 4 * 4);
        for j in 0..17 {
            for i in 0..21 {
                let want = 2.0 * i as f32 + 0.5 * j as f32;
                assert!(
                    (hf.heights[[j, i]] - want).abs() < 1e-4,
                    "{i} {j}: {}",
                    hf.heights[[j, i]]
                );
            }
        }
    }

    #[test]
    fn radius_below_one_cell_interpolates_nothing() {
        // Regression (found by proptest): a radius of 0.5 cells reaches no neighbour; every
        // hole goes to the fallback, as in the reference.
        let hf = holey(5, 30, 20);
        let p = FillParams {
            radius: 0.5,
            fallback: Fallback::Mean,
            ..Default::default()
        };
        let mut fast = hf.clone();
        let r = fill(&mut fast, &p).unwrap();
        assert_eq!(r.interpolated, 0);
        assert!(same(&fast, &reference::fill(&hf, &p).unwrap()));
    }

    #[test]
    fn bad_radius() {
        let mut hf = holey(1, 10, 10);
        for r in [0.0, -1.0, f64::NAN, 1e9] {
            let e = fill(
                &mut hf,
                &FillParams {
                    radius: r,
                    ..Default::default()
                },
            )
            .unwrap_err()
            .to_string();
            assert!(e.starts_with(&format!("fill: radius = {r}:")), "{e}");
        }
    }
}
