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
//! The axis fill decides it as it finds a cell's neighbours (`fill::fill_band`), so no
//! second pass looks along the rows and columns again.
//!
//! The membrane then fills the large-void cells with the measured and the small-hole cells
//! held fixed: smooth in every direction, inside the range of the heights around the void (no
//! spikes, no plateaus), a plane reproduced exactly.

use super::fill::FillReport;
use super::heightfield::{CellState, Heightfield};
use super::voidfill;
use rayon::prelude::*;

/// After the axis fill in its membrane mode (`fill::fill_band`: the cells without a measured
/// cell within the radius on all four sides left NaN, their state already
/// [`CellState::Fallback`], counted in `report.empty`): the membrane surface of the rest
/// fills them. `range` is the range of the finite heights left (the solve's tolerance).
/// `report` is the axis fill's; it is updated to what this did.
pub(crate) fn membrane_large_voids(
    hf: &mut Heightfield,
    [lo, hi]: [f32; 2],
    report: &mut FillReport,
) {
    let (cols, rows) = (hf.cols(), hf.rows());
    if cols == 0 || rows == 0 {
        return;
    }
    let Some(h) = hf.heights.as_slice_mut() else {
        return;
    };
    let unknown = report.empty;
    // The membrane fills every cell it solves for unless no cell is known: then it leaves
    // them all NaN, and they are `Empty` again.
    let solved = unknown > 0 && unknown < h.len();
    if !solved && unknown > 0 {
        if let Some(s) = hf.state.as_slice_mut() {
            s.par_iter_mut().for_each(|s| {
                if *s == CellState::Fallback {
                    *s = CellState::Empty;
                }
            });
        }
    }
    let tol = voidfill::tolerance_of_range(lo, hi);
    let filled = voidfill::membrane_fill(h, cols, rows, tol);
    debug_assert_eq!(filled, if solved { unknown } else { 0 });
    if solved {
        report.fallback += unknown;
        report.empty = 0;
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
