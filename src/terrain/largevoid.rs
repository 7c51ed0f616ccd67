//! The `membrane` fill of large voids: what the axis fill of Kim & Shin does well (small
//! holes between measured cells) is kept, and everything else becomes the membrane (Laplace)
//! surface of the cells around it ([`super::voidfill`]).
//!
//! Which holes are "large": a cell is a small-hole cell when the axis fill finds a measured
//! cell within `radius` on all four sides (left, right, below and above), so Kim & Shin's
//! formula combines two complete pairs. Every other empty cell is part of a large void: it
//! has a measured cell on one side only along an axis, or none within the radius. Those are
//! the cells that make the axis fill's artefacts: a lone measured cell in a void is copied
//! along its row and column up to `radius` cells (the plus-shaped spikes around removed
//! buildings and trees), and the rim of a wide gap copies the edge height inwards
//! (streaks across flight-line gaps). The criterion is per cell and local (it reads `radius`
//! cells along the row and the column), where a size threshold on connected holes would
//! need the whole hole: a hole is "large" exactly where the axis fill could only extrapolate.
//!
//! The membrane then fills the large-void cells with the measured and the small-hole cells
//! held fixed: smooth in every direction, inside the range of the heights around the void (no
//! spikes, no plateaus), a plane reproduced exactly.

use super::fill::FillReport;
use super::heightfield::{CellState, Heightfield};
use super::voidfill;
use rayon::prelude::*;

/// Rows per parallel band of [`enclosed`].
const BAND: usize = 64;

/// Per cell, whether a measured cell lies within `r` cells to its left, right, below and
/// above (a measured cell counts as enclosed). `state` is row-major, `cols` wide.
pub(crate) fn enclosed(state: &[CellState], cols: usize, r: usize) -> Vec<bool> {
    let rows = state.len() / cols.max(1);
    let measured = |j: usize, i: usize| state[j * cols + i] == CellState::Measured;
    let mut out = vec![false; state.len()];
    if cols == 0 || r == 0 {
        for (o, s) in out.iter_mut().zip(state) {
            *o = *s == CellState::Measured;
        }
        return out;
    }
    out.par_chunks_mut(BAND * cols)
        .enumerate()
        .for_each(|(b, ob)| {
            let j0 = b * BAND;
            let j1 = j0 + ob.len() / cols;
            // Vertical: the nearest measured row below each cell (running record up from
            // r rows under the band), then above (running record down from r rows over it).
            let mut below = vec![usize::MAX; cols];
            let mut vert = vec![false; ob.len()];
            for j in j0.saturating_sub(r)..j1 {
                for (i, last) in below.iter_mut().enumerate() {
                    if measured(j, i) {
                        *last = j;
                    }
                    if j >= j0 {
                        vert[(j - j0) * cols + i] = *last != usize::MAX && j - *last <= r;
                    }
                }
            }
            let mut above = vec![usize::MAX; cols];
            for j in (j0..(j1 + r).min(rows)).rev() {
                for (i, next) in above.iter_mut().enumerate() {
                    if measured(j, i) {
                        *next = j;
                    }
                    if j < j1 {
                        let v = &mut vert[(j - j0) * cols + i];
                        *v = *v && *next != usize::MAX && *next - j <= r;
                    }
                }
            }
            // Horizontal, row by row: the nearest measured cell to the left (forward scan)
            // and to the right (backward scan).
            for j in j0..j1 {
                let row = &mut ob[(j - j0) * cols..(j - j0 + 1) * cols];
                let v = &vert[(j - j0) * cols..(j - j0 + 1) * cols];
                let mut left = usize::MAX;
                for i in 0..cols {
                    if measured(j, i) {
                        left = i;
                    }
                    row[i] = v[i] && left != usize::MAX && i - left <= r;
                }
                let mut right = usize::MAX;
                for i in (0..cols).rev() {
                    if measured(j, i) {
                        right = i;
                    }
                    row[i] = row[i] && right != usize::MAX && right - i <= r;
                }
            }
        });
    out
}

/// Largest `radius` (in cells) for which [`membrane_large_voids`] tests each cell by
/// [`enclosed_at`]; above it the whole-grid passes of [`enclosed`] (linear in the cells for
/// any radius) are cheaper than scans of up to 4 × `radius` cells.
const SCAN_MAX: usize = 32;

/// [`enclosed`] at the one cell (`j`, `i`): the cells along each side, nearest first, the
/// scan stopped at the first measured one and the test at the first side without one. Most
/// empty cells between measured ones find a measured neighbour at once, and a cell deep in a
/// void fails on its first side, so this reads far fewer cells than the whole-grid passes of
/// [`enclosed`] (and writes none) for the radii it is used for ([`SCAN_MAX`]).
fn enclosed_at(
    state: &[CellState],
    cols: usize,
    rows: usize,
    j: usize,
    i: usize,
    r: usize,
) -> bool {
    let k = j * cols + i;
    let m = |k: usize| state[k] == CellState::Measured;
    m(k) || ((1..=r.min(i)).any(|d| m(k - d))
        && (1..=r.min(cols - 1 - i)).any(|d| m(k + d))
        && (1..=r.min(j)).any(|d| m(k - d * cols))
        && (1..=r.min(rows - 1 - j)).any(|d| m(k + d * cols)))
}

/// After the axis fill (holes it could not reach left `Empty`): every empty cell and every
/// interpolated cell that is not [`enclosed`] becomes the membrane surface of the rest.
/// `report` is the axis fill's; it is updated to what this did.
pub(crate) fn membrane_large_voids(hf: &mut Heightfield, r: usize, report: &mut FillReport) {
    let (cols, rows) = (hf.cols(), hf.rows());
    if cols == 0 || rows == 0 {
        return;
    }
    let (Some(h), Some(s)) = (hf.heights.as_slice_mut(), hf.state.as_slice()) else {
        return;
    };
    let whole = (r > SCAN_MAX).then(|| enclosed(s, cols, r));
    // One pass: the cells to solve for become NaN (the states stay until the second pass, as
    // the tests read them), and the range of the cells that stay, for the tolerance.
    let (demoted, lo, hi) = h
        .par_chunks_mut(BAND * cols)
        .enumerate()
        .map(|(b, hb)| {
            let (mut n, mut lo, mut hi) = (0usize, f32::INFINITY, f32::NEG_INFINITY);
            // Row by row: the cell's row and column without a division per cell.
            for (j, hr) in (b * BAND..).zip(hb.chunks_mut(cols)) {
                let k0 = j * cols;
                for ((i, v), st) in hr.iter_mut().enumerate().zip(&s[k0..k0 + cols]) {
                    match st {
                        CellState::Interpolated
                            if !match &whole {
                                Some(w) => w[k0 + i],
                                None => enclosed_at(s, cols, rows, j, i, r),
                            } =>
                        {
                            *v = f32::NAN;
                            n += 1;
                        }
                        CellState::Empty => *v = f32::NAN,
                        _ if v.is_finite() => (lo, hi) = (lo.min(*v), hi.max(*v)),
                        _ => {}
                    }
                }
            }
            (n, lo, hi)
        })
        .reduce(
            || (0, f32::INFINITY, f32::NEG_INFINITY),
            |a, b| (a.0 + b.0, a.1.min(b.1), a.2.max(b.2)),
        );
    drop(whole);
    let unknown = report.empty + demoted;
    // The membrane fills every cell it solves for unless no cell is known (then it leaves
    // them all NaN, `Empty`): the states are set before it runs, in one pass.
    let solved = unknown > 0 && unknown < h.len();
    let to = if solved {
        CellState::Fallback
    } else {
        CellState::Empty
    };
    if let Some(s) = hf.state.as_slice_mut() {
        s.par_chunks_mut(1 << 14)
            .zip(h.par_chunks(1 << 14))
            .for_each(|(s, h)| {
                for (s, h) in s.iter_mut().zip(h) {
                    if *s != CellState::Measured && h.is_nan() {
                        *s = to;
                    }
                }
            });
    }
    let tol = voidfill::tolerance_of_range(lo, hi);
    let filled = voidfill::membrane_fill(h, cols, rows, tol);
    debug_assert_eq!(filled, if solved { unknown } else { 0 });
    report.interpolated -= demoted;
    if solved {
        report.fallback += unknown;
        report.empty = 0;
    } else {
        report.empty = unknown;
    }
}

/// A `n` × `n` grid of rolling terrain (unit cells, heights in tens of metres) with about
/// `empty` of its cells empty: half of them in discs of 3 to 40 cells radius (removed
/// buildings, water), half scattered single cells (gaps between points). For the benchmark
/// and the property tests of the void fill.
#[cfg(any(test, feature = "testing"))]
pub fn voids_grid(seed: u64, n: usize, empty: f64) -> Heightfield {
    let mut rng = crate::rng::SplitMix64::new(seed);
    let mut hf = Heightfield::empty(n, n, [0.0, 0.0], [1.0, 1.0], 0.0, None);
    let (h, s, c) = (
        hf.heights.as_slice_mut().expect("standard layout"),
        hf.state.as_slice_mut().expect("standard layout"),
        hf.counts.as_slice_mut().expect("standard layout"),
    );
    for (k, ((h, s), c)) in h.iter_mut().zip(s.iter_mut()).zip(c.iter_mut()).enumerate() {
        let (x, y) = ((k % n) as f64, (k / n) as f64);
        *h = (20.0 * (x * 0.004).sin() * (y * 0.003).cos() + 0.01 * x + 3.0 * (y * 0.05).sin())
            as f32;
        *s = CellState::Measured;
        *c = 1;
    }
    let target = (empty * (n * n) as f64) as usize;
    let mut removed = 0;
    while removed < target / 2 {
        let r = 3 + rng.below(38) as i64;
        let (cx, cy) = (rng.below(n as u64) as i64, rng.below(n as u64) as i64);
        for j in (cy - r).max(0)..(cy + r + 1).min(n as i64) {
            for i in (cx - r).max(0)..(cx + r + 1).min(n as i64) {
                let k = j as usize * n + i as usize;
                if (i - cx).pow(2) + (j - cy).pow(2) <= r * r && s[k] == CellState::Measured {
                    (s[k], h[k], c[k]) = (CellState::Empty, f32::NAN, 0);
                    removed += 1;
                }
            }
        }
    }
    while removed < target {
        let k = rng.below((n * n) as u64) as usize;
        if s[k] == CellState::Measured {
            (s[k], h[k], c[k]) = (CellState::Empty, f32::NAN, 0);
            removed += 1;
        }
    }
    hf
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The slow twin of [`enclosed`]: look along the four directions cell by cell.
    fn enclosed_slow(state: &[CellState], cols: usize, r: usize) -> Vec<bool> {
        let rows = state.len() / cols;
        let m = |j: i64, i: i64| {
            (0..rows as i64).contains(&j)
                && (0..cols as i64).contains(&i)
                && state[j as usize * cols + i as usize] == CellState::Measured
        };
        let mut out = vec![false; state.len()];
        for j in 0..rows as i64 {
            for i in 0..cols as i64 {
                let r = r as i64;
                let side = |di: i64, dj: i64| (0..=r).any(|d| m(j + d * dj, i + d * di));
                out[j as usize * cols + i as usize] =
                    side(-1, 0) && side(1, 0) && side(0, -1) && side(0, 1);
            }
        }
        out
    }

    #[test]
    fn enclosed_equals_the_slow_scan() {
        let mut rng = crate::rng::SplitMix64::new(7);
        for (cols, rows, p, r) in [(13, 150, 0.2, 3), (70, 9, 0.05, 8), (31, 130, 0.5, 1)] {
            let state: Vec<CellState> = (0..cols * rows)
                .map(|_| {
                    if rng.unit() < p {
                        CellState::Measured
                    } else {
                        CellState::Empty
                    }
                })
                .collect();
            assert_eq!(
                enclosed(&state, cols, r),
                enclosed_slow(&state, cols, r),
                "{cols}×{rows} r {r}"
            );
        }
    }

    #[test]
    fn enclosed_at_equals_the_slow_scan() {
        let mut rng = crate::rng::SplitMix64::new(9);
        for (cols, rows, p, r) in [(13, 40, 0.2, 3), (40, 9, 0.05, 8), (31, 30, 0.5, 1)] {
            let state: Vec<CellState> = (0..cols * rows)
                .map(|_| match rng.below(3) {
                    0 if rng.unit() < 3.0 * p => CellState::Measured,
                    0 | 1 => CellState::Empty,
                    _ => CellState::Interpolated,
                })
                .collect();
            let slow = enclosed_slow(&state, cols, r);
            for (k, want) in slow.iter().enumerate() {
                assert_eq!(
                    enclosed_at(&state, cols, rows, k / cols, k % cols, r),
                    *want,
                    "{cols}×{rows} r {r} cell {k}"
                );
            }
        }
    }

    #[test]
    fn fill_equals_the_reference() {
        use crate::terrain::fill::{fill, tests::holey, Fallback, FillParams};
        use crate::terrain::reference;
        for (seed, radius) in [(1, 1.0), (2, 3.0), (3, 8.0), (4, 40.0)] {
            let hf = holey(seed, 71, 53);
            let p = FillParams {
                radius,
                fallback: Fallback::Membrane,
                ..Default::default()
            };
            let mut fast = hf.clone();
            let report = fill(&mut fast, &p).unwrap();
            let slow = reference::fill(&hf, &p).unwrap();
            assert!(reference::same_grid(&fast, &slow), "{p:?}");
            let count = |s: CellState| fast.state.iter().filter(|x| **x == s).count();
            assert_eq!(report.interpolated, count(CellState::Interpolated));
            assert_eq!(report.fallback, count(CellState::Fallback));
            assert_eq!(report.empty, 0);
            assert!(report.fallback > 0);
        }
    }
}
