//! Two steps of the ground classification ([`super::ground`]) that SMRF does not have, both
//! measured on the ISPRS filter-test samples (see the README's "Ground classification"):
//!
//! - [`nearest_fill`]: before the progressive opening, the empty cells within one point
//!   spacing of a measured cell take the height of the nearest one. Left unknown (the
//!   erosion's identity), a gap between scan lines let a window hold a single isolated point
//!   (a shrub, a low branch), whose opening is then its own height: it was never cut, and
//!   in the sparse rural samples most objects called ground were such points. Filled with
//!   the membrane surface instead (the paper's order), every isolated point became a spike
//!   that the smallest window cut, rims and crests included. The nearest height makes a
//!   point a small plateau of its own height, as a dense survey would sample it; gaps wider
//!   than the spacing (water, shadows) stay unknown.
//! - [`readmit_supported`]: after the hysteresis, an object cell is ground again when the
//!   ground cells around it (within 1.5 point spacings) reach its height, to within a small
//!   tolerance, in two opposite directions. A crest, a quarry's rim or an embankment
//!   continues at its own height along its line, so its cut cells are held up on both sides
//!   along it; a building, a tree or a shrub has lower ground on every side, and an object
//!   on a slope is met by ground at its height only uphill, in less than a half-plane. It
//!   repeats while cells change (a cell re-admitted may hold up its neighbours), each round
//!   judging every candidate against the previous round's mask, so the result does not
//!   depend on the order or the thread count. This is the breakline argument of progressive
//!   TIN densification (Axelsson, "DEM generation from laser scanner data using adaptive TIN
//!   models", 2000), which grows the ground along a surface rather than judging a cell by
//!   the windows around it, reduced to a grid test.

use rayon::prelude::*;

/// Cells of the nearest-height fill beyond which an empty cell stays unknown, from the point
/// spacing: `ceil(spacing / cell)`, at least 1.
pub(crate) fn fill_reach(spacing_m: f64, cell_m: f64) -> usize {
    let r = (spacing_m / cell_m).ceil();
    if r.is_finite() && r >= 1.0 {
        (r as usize).min(64)
    } else {
        1
    }
}

/// Fills the unknown cells (+∞) of `z` within Manhattan distance `reach` of a measured cell
/// with the lowest height among the measured cells at the smallest such distance; the
/// others stay +∞. One pass over the grid per unit of distance (each cell at distance d
/// takes the lowest of its 4-neighbours at distance d − 1, which is the lowest source at
/// distance d): `reach` is a few cells.
pub(crate) fn nearest_fill(z: &mut [f32], cols: usize, rows: usize, reach: usize) {
    // Distance of each cell's value: 0 measured, u8::MAX unknown.
    let mut dist: Vec<u8> = z
        .par_iter()
        .map(|v| if v.is_finite() { 0 } else { u8::MAX })
        .collect();
    for d in 1..=reach.min(u8::MAX as usize - 1) as u8 {
        let (pz, pd) = (z.to_vec(), dist.clone());
        let changed = z
            .par_chunks_mut(cols)
            .zip(dist.par_chunks_mut(cols))
            .enumerate()
            .map(|(j, (zr, dr))| {
                let mut changed = false;
                for i in 0..cols {
                    if dr[i] != u8::MAX {
                        continue;
                    }
                    let k = j * cols + i;
                    let nb = [
                        (i > 0).then(|| k - 1),
                        (i + 1 < cols).then(|| k + 1),
                        (j > 0).then(|| k - cols),
                        (j + 1 < rows).then(|| k + cols),
                    ];
                    let mut v = f32::INFINITY;
                    for m in nb.into_iter().flatten() {
                        if pd[m] == d - 1 {
                            v = v.min(pz[m]);
                        }
                    }
                    if v.is_finite() {
                        zr[i] = v;
                        dr[i] = d;
                        changed = true;
                    }
                }
                changed
            })
            .reduce(|| false, |a, b| a || b);
        if !changed {
            break;
        }
    }
}

/// Sectors of the direction test of [`readmit_supported`].
const SECTORS: usize = 8;
/// Default reach of [`nearest_fill`], in point spacings (`[ground] gap_fill`).
pub(crate) const DEFAULT_GAP_FILL: f64 = 1.0;
/// Default radius of the neighbourhood of [`readmit_supported`], in point spacings (or
/// cells, when a cell is wider than the spacing; `[ground] support_radius`).
pub(crate) const DEFAULT_SUPPORT_RADIUS: f64 = 1.5;
/// Default height tolerance of a supporting ground cell: this many metres …
pub(crate) const DEFAULT_SUPPORT_TOLERANCE: f64 = 0.3;
/// … plus this many metres per metre of distance (the crest may fall along its line).
pub(crate) const DEFAULT_SUPPORT_SLOPE: f64 = 0.2;

/// The crest test's parameters: radius (in point spacings as configured; in metres when
/// given to [`readmit_supported`]), tolerance in metres plus `slope` metres per metre of
/// distance.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Support {
    pub radius: f64,
    pub tolerance: f64,
    pub slope: f64,
}
/// Rounds of [`readmit_supported`] at most (on the ISPRS samples it settles in fewer).
const MAX_ROUNDS: usize = 32;

/// The neighbourhood of [`readmit_supported`]: (di, dj, height tolerance at that distance in
/// metres, sector).
fn support_offsets(radius_m: f64, cell_m: f64, s: Support) -> Vec<(isize, isize, f32, usize)> {
    let (tolerance, slope) = (s.tolerance as f32, s.slope as f32);
    let r = ((radius_m / cell_m).ceil() as isize).max(1);
    let mut offs = Vec::new();
    for dj in -r..=r {
        for di in -r..=r {
            let d = ((di * di + dj * dj) as f64).sqrt() * cell_m;
            if (di, dj) == (0, 0) || d > radius_m {
                continue;
            }
            let a = (dj as f64).atan2(di as f64) + std::f64::consts::PI;
            let s = ((a / std::f64::consts::TAU * SECTORS as f64) as usize) % SECTORS;
            offs.push((di, dj, tolerance + slope * d as f32, s));
        }
    }
    offs
}

/// Whether object cell `k` is held up by ground cells in two opposite directions (sectors
/// s and s + 4 ± 1).
fn supported(
    k: usize,
    object: &[bool],
    live: &[bool],
    z: &[f32],
    cols: usize,
    rows: usize,
    offs: &[(isize, isize, f32, usize)],
) -> bool {
    let (i, j) = ((k % cols) as isize, (k / cols) as isize);
    let mut sup = [false; SECTORS];
    for &(di, dj, tol, s) in offs {
        let (ii, jj) = (i + di, j + dj);
        if ii < 0 || jj < 0 || ii >= cols as isize || jj >= rows as isize {
            continue;
        }
        let m = jj as usize * cols + ii as usize;
        if live[m] && !object[m] && z[m] >= z[k] - tol {
            sup[s] = true;
        }
    }
    (0..SECTORS).any(|s| {
        let o = s + SECTORS / 2;
        sup[s] && (sup[(o - 1) % SECTORS] || sup[o % SECTORS] || sup[(o + 1) % SECTORS])
    })
}

/// Re-admits as ground the object cells held up by ground in two opposite directions (see
/// the module notes). `live`: the cells that hold a point and are not low outliers (only
/// they are judged or support); `z`: the minimum surface in metres; `radius_m` the
/// `s` the neighbourhood's radius in metres and the tolerances. Rounds repeat while cells change; after the first,
/// only the object cells near a changed cell are judged again (the others see the same
/// neighbourhood as before). Returns the cells re-admitted.
pub(crate) fn readmit_supported(
    object: &mut [bool],
    live: &[bool],
    z: &[f32],
    cols: usize,
    rows: usize,
    cell_m: f64,
    s: Support,
) -> usize {
    let radius_m = s.radius;
    let offs = support_offsets(radius_m, cell_m, s);
    let r = ((radius_m / cell_m).ceil() as usize).max(1);
    let mut cand: Vec<usize> = (0..object.len())
        .into_par_iter()
        .filter(|&k| object[k] && live[k])
        .collect();
    let mut mark = vec![false; object.len()];
    let mut total = 0;
    for _ in 0..MAX_ROUNDS {
        let flips: Vec<usize> = cand
            .par_iter()
            .copied()
            .filter(|&k| supported(k, object, live, z, cols, rows, &offs))
            .collect();
        if flips.is_empty() {
            break;
        }
        total += flips.len();
        for &k in &flips {
            object[k] = false;
        }
        // The next round's candidates: object cells within r of a re-admitted cell.
        cand.clear();
        for &k in &flips {
            let (i, j) = (k % cols, k / cols);
            for jj in j.saturating_sub(r)..=(j + r).min(rows - 1) {
                for ii in i.saturating_sub(r)..=(i + r).min(cols - 1) {
                    let m = jj * cols + ii;
                    if object[m] && live[m] && !mark[m] {
                        mark[m] = true;
                        cand.push(m);
                    }
                }
            }
        }
        for &m in &cand {
            mark[m] = false;
        }
        cand.sort_unstable();
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    const DEFAULTS: Support = Support {
        radius: DEFAULT_SUPPORT_RADIUS,
        tolerance: DEFAULT_SUPPORT_TOLERANCE,
        slope: DEFAULT_SUPPORT_SLOPE,
    };
    /// The defaults with a radius of 2 m (2 cells of 1 m).
    const RADIUS_2: Support = Support {
        radius: 2.0,
        ..DEFAULTS
    };

    /// The slow twin of [`nearest_fill`]: for every unknown cell, a scan of all measured
    /// cells for the smallest Manhattan distance and the lowest height at it.
    fn nearest_fill_slow(z: &[f32], cols: usize, reach: usize) -> Vec<f32> {
        let mut out = z.to_vec();
        for k in 0..z.len() {
            if z[k].is_finite() {
                continue;
            }
            let (i, j) = (k % cols, k / cols);
            let mut best = (usize::MAX, f32::INFINITY);
            for (m, &v) in z.iter().enumerate() {
                if !v.is_finite() {
                    continue;
                }
                let d = (m % cols).abs_diff(i) + (m / cols).abs_diff(j);
                if d < best.0 || (d == best.0 && v < best.1) {
                    best = (d, v);
                }
            }
            if best.0 <= reach {
                out[k] = best.1;
            }
        }
        out
    }

    #[test]
    fn nearest_fill_equals_the_scan() {
        let mut rng = SplitMix64::new(5);
        for (cols, rows) in [(1, 1), (4, 1), (1, 6), (17, 11), (40, 23)] {
            for unknown in [0.0, 0.5, 0.9, 1.0] {
                let z: Vec<f32> = (0..cols * rows)
                    .map(|_| {
                        if rng.unit() < unknown {
                            f32::INFINITY
                        } else {
                            // Few distinct heights, so that ties at one distance occur.
                            (rng.range(0.0, 4.0) as i32) as f32
                        }
                    })
                    .collect();
                for reach in [1, 2, 3, 7] {
                    let mut fast = z.clone();
                    nearest_fill(&mut fast, cols, rows, reach);
                    assert_eq!(
                        fast,
                        nearest_fill_slow(&z, cols, reach),
                        "{cols}×{rows} unknown {unknown} reach {reach}"
                    );
                }
            }
        }
    }

    /// The slow twin of [`readmit_supported`]: every object cell judged again in every
    /// round, until a round changes nothing.
    fn readmit_slow(object: &mut [bool], live: &[bool], z: &[f32], cols: usize, rows: usize) {
        let offs = support_offsets(2.0, 1.0, DEFAULTS);
        loop {
            let flips: Vec<usize> = (0..object.len())
                .filter(|&k| {
                    object[k] && live[k] && supported(k, object, live, z, cols, rows, &offs)
                })
                .collect();
            if flips.is_empty() {
                return;
            }
            for k in flips {
                object[k] = false;
            }
        }
    }

    #[test]
    fn readmission_equals_full_rounds() {
        let mut rng = SplitMix64::new(9);
        for (cols, rows) in [(3, 3), (20, 13), (47, 31)] {
            for _ in 0..4 {
                let z: Vec<f32> = (0..cols * rows)
                    .map(|_| rng.range(0.0, 3.0) as f32)
                    .collect();
                let live: Vec<bool> = (0..cols * rows).map(|_| rng.unit() < 0.8).collect();
                let object: Vec<bool> = (0..cols * rows).map(|_| rng.unit() < 0.5).collect();
                let (mut fast, mut slow) = (object.clone(), object);
                readmit_supported(&mut fast, &live, &z, cols, rows, 1.0, RADIUS_2);
                readmit_slow(&mut slow, &live, &z, cols, rows);
                assert_eq!(fast, slow, "{cols}×{rows}");
            }
        }
    }

    /// A ridge whose crest cells were cut here and there (objects; in a sparse survey the
    /// opening cuts some of a crest's points and not others) is ground again; a box of the same height on flat ground stays an object, and so does a box on a
    /// slope that meets the ground at its height uphill only.
    #[test]
    fn crests_come_back_boxes_stay() {
        let (cols, rows) = (60, 40);
        let mut z = vec![0.0f32; cols * rows];
        let mut object = vec![false; cols * rows];
        for j in 0..rows {
            for i in 0..cols {
                let k = j * cols + i;
                // A ridge along x at rows 8..=12, its crest at row 10, 5 m high and level.
                if (8..=12).contains(&j) {
                    z[k] = 5.0 - 2.0 * (j as f32 - 10.0).abs();
                    object[k] = j == 10 && (5..55).contains(&i) && i % 3 != 0;
                }
                // A 5 m box on flat ground.
                if (20..30).contains(&i) && (20..28).contains(&j) {
                    z[k] = 5.0;
                    object[k] = true;
                }
                // A slope rising 1 m per cell along x in rows 32..40, with a 3 m box at
                // columns 40..44.
                if j >= 32 {
                    z[k] = i as f32 * 1.0;
                    if (40..44).contains(&i) {
                        z[k] += 3.0;
                        object[k] = true;
                    }
                }
            }
        }
        let live = vec![true; cols * rows];
        readmit_supported(&mut object, &live, &z, cols, rows, 1.0, RADIUS_2);
        assert!(
            (5..55).all(|i| !object[10 * cols + i]),
            "a crest cell stayed"
        );
        assert!((20..30).all(|i| (20..28).all(|j| object[j * cols + i])));
        assert!((40..44).all(|i| (33..39).all(|j| object[j * cols + i])));
    }
}
