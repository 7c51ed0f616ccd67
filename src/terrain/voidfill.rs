//! Void filling by a membrane (Laplace) surface: every unknown cell becomes the mean of its
//! four neighbours, the known cells held fixed. The result is the discrete harmonic
//! interpolant of the known cells: smooth in every direction, inside the range of the
//! heights around the void (maximum principle: no spikes, no plateaus), and a plane is
//! reproduced exactly. At the grid's border a missing neighbour is left out of the mean
//! (zero slope across the border), so a void that reaches the border continues flat there
//! instead of being extrapolated to heights the data never had.
//!
//! The solver is a cascadic multigrid (Bornemann & Deuflhard, "The cascadic multigrid method
//! for elliptic problems", 1996): the grid is coarsened by injection (coarse cell (I, J) is
//! fine cell (2I, 2J)) down to a few thousand cells, the coarsest level is solved by red-black
//! Gauss-Seidel to convergence, and each finer level starts from the bilinear prolongation of
//! the level below and is smoothed by red-black Gauss-Seidel until no cell moves more than
//! the tolerance (or a sweep cap is reached). Red-black order makes a sweep independent of the
//! thread count: a red cell reads only black cells and the reverse, so the result is the same
//! bits for any number of threads. Hand-written because no crate of the field solves a
//! Laplace problem on a masked grid in place (the sparse solvers need an assembled matrix,
//! 20 bytes a cell and more).

use rayon::prelude::*;

/// Below this many cells a level is solved directly by iteration, not coarsened further.
const COARSEST: usize = 4096;
/// Sweep cap of the coarsest level (it is at most a few thousand cells).
const COARSE_SWEEPS: usize = 20_000;
/// Sweep cap of every finer level: the prolonged coarse solution is already smooth, the
/// sweeps only take out what the coarse grid could not represent.
const FINE_SWEEPS: usize = 400;
/// Unknown cells per parallel work item of a sweep.
const CHUNK: usize = 1 << 14;
/// Over-relaxation factor of the sweeps (successive over-relaxation, Young 1950): the smooth
/// error the coarse level leaves decays in O(width) sweeps instead of O(width²).
const OMEGA: f32 = 1.85;

/// Fills every NaN cell of the row-major `rows` × `cols` grid `z` with the membrane surface
/// of its finite cells; finite cells are never changed. `tol` is the largest change of a
/// cell in the last sweep at which a level counts as converged (same unit as `z`). A grid
/// without any finite cell is left as it is. Returns the number of cells filled.
pub fn membrane_fill(z: &mut [f32], cols: usize, rows: usize, tol: f32) -> usize {
    assert_eq!(z.len(), cols * rows, "grid size");
    let known: Vec<bool> = z.par_iter().map(|v| v.is_finite()).collect();
    let unknown = known.iter().filter(|k| !**k).count();
    if unknown == 0 || unknown == z.len() {
        return 0;
    }
    solve(z, &known, cols, rows, tol.max(0.0));
    unknown
}

/// A tolerance for [`membrane_fill`] fit for heights `z`: 10⁻⁵ of their range, at least
/// 10⁻⁶ (so a flat grid still converges in one sweep).
pub fn default_tolerance(z: &[f32]) -> f32 {
    let (lo, hi) = z
        .par_iter()
        .filter(|v| v.is_finite())
        .fold(
            || (f32::INFINITY, f32::NEG_INFINITY),
            |(a, b), &v| (a.min(v), b.max(v)),
        )
        .reduce(
            || (f32::INFINITY, f32::NEG_INFINITY),
            |x, y| (x.0.min(y.0), x.1.max(y.1)),
        );
    if lo > hi {
        return 1e-6;
    }
    ((hi - lo) * 1e-5).max(1e-6)
}

/// Solves one level: coarsen, solve the coarse level, prolong, smooth.
fn solve(z: &mut [f32], known: &[bool], cols: usize, rows: usize, tol: f32) {
    let (cc, cr) = (cols.div_ceil(2), rows.div_ceil(2));
    let coarse_ok = cols * rows > COARSEST && cc >= 2 && cr >= 2;
    let mut sweeps = FINE_SWEEPS;
    if coarse_ok {
        let mut zc = vec![f32::NAN; cc * cr];
        let mut kc = vec![false; cc * cr];
        zc.par_chunks_mut(cc)
            .zip(kc.par_chunks_mut(cc))
            .enumerate()
            .for_each(|(jc, (zr, kr))| {
                for ic in 0..cc {
                    let k = 2 * jc * cols + 2 * ic;
                    if known[k] {
                        zr[ic] = z[k];
                        kr[ic] = true;
                    }
                }
            });
        let nk = kc.iter().filter(|k| **k).count();
        if nk > 0 {
            if nk < kc.len() {
                solve(&mut zc, &kc, cc, cr, tol);
            }
            prolong(z, known, cols, &zc, cc, cr);
        } else {
            seed_with_mean(z, known);
            sweeps = COARSE_SWEEPS;
        }
    } else {
        seed_with_mean(z, known);
        sweeps = COARSE_SWEEPS;
    }
    smooth(z, known, cols, rows, tol, sweeps);
}

/// Starts every unknown cell at the mean of the known ones.
fn seed_with_mean(z: &mut [f32], known: &[bool]) {
    let (s, n) = z
        .iter()
        .zip(known)
        .filter(|(_, k)| **k)
        .fold((0.0f64, 0usize), |(s, n), (v, _)| (s + *v as f64, n + 1));
    let mean = (s / n.max(1) as f64) as f32;
    for (v, k) in z.iter_mut().zip(known) {
        if !k {
            *v = mean;
        }
    }
}

/// Unknown fine cells take the bilinear interpolation of the solved coarse level (a fine cell
/// at an odd index lies half-way between two coarse cells; beyond the last coarse cell the
/// last one is used).
fn prolong(z: &mut [f32], known: &[bool], cols: usize, zc: &[f32], cc: usize, cr: usize) {
    z.par_chunks_mut(cols).enumerate().for_each(|(j, row)| {
        let (j0, j1) = (j / 2, j.div_ceil(2).min(cr - 1));
        for (i, v) in row.iter_mut().enumerate() {
            if known[j * cols + i] {
                continue;
            }
            let (i0, i1) = (i / 2, i.div_ceil(2).min(cc - 1));
            let a = zc[j0 * cc + i0] + zc[j0 * cc + i1];
            let b = zc[j1 * cc + i0] + zc[j1 * cc + i1];
            *v = (a + b) * 0.25;
        }
    });
}

/// Rows per band of the parallel write-back of a half-sweep.
const BAND_ROWS: usize = 32;

/// Red-black Gauss-Seidel over the unknown cells until the largest change of a sweep is at
/// most `tol`, at most `max_sweeps` sweeps.
fn smooth(z: &mut [f32], known: &[bool], cols: usize, rows: usize, tol: f32, max_sweeps: usize) {
    // Unknown cells by colour, as indices with a border flag in the top bits: bit 63 left
    // neighbour exists, 62 right, 61 below, 60 above. Sorted by index, so the cells of a band
    // of rows are one run (`starts`).
    let mut colours: [Vec<u64>; 2] = [Vec::new(), Vec::new()];
    for j in 0..rows {
        for i in 0..cols {
            let k = j * cols + i;
            if known[k] {
                continue;
            }
            let flags = ((i > 0) as u64) << 63
                | ((i + 1 < cols) as u64) << 62
                | ((j > 0) as u64) << 61
                | ((j + 1 < rows) as u64) << 60;
            colours[(i + j) & 1].push(k as u64 | flags);
        }
    }
    let band = BAND_ROWS * cols;
    let starts: [Vec<usize>; 2] = std::array::from_fn(|c| {
        (0..=rows.div_ceil(BAND_ROWS))
            .map(|b| colours[c].partition_point(|&x| ((x & MASK) as usize) < b * band))
            .collect()
    });
    let mut buf = vec![0.0f32; colours[0].len().max(colours[1].len())];
    for _ in 0..max_sweeps {
        let mut change = 0.0f32;
        for (cells, starts) in colours.iter().zip(&starts) {
            change = change.max(sweep(z, cols, cells, starts, &mut buf, OMEGA));
        }
        if change <= tol {
            break;
        }
    }
}

/// Index bits of a cell entry of [`smooth`] (the top four are its border flags).
const MASK: u64 = (1 << 60) - 1;

/// One half-sweep over the cells of one colour; returns the largest change. A cell of one
/// colour reads only cells of the other, so the new values are computed first from the grid
/// as it is (in parallel, into `buf`), then written back band by band (in parallel, each band
/// its own rows): the same values whatever the order or the thread count.
fn sweep(
    z: &mut [f32],
    cols: usize,
    cells: &[u64],
    starts: &[usize],
    buf: &mut [f32],
    omega: f32,
) -> f32 {
    let zr: &[f32] = z;
    let change = buf[..cells.len()]
        .par_chunks_mut(CHUNK)
        .zip(cells.par_chunks(CHUNK))
        .map(|(out, chunk)| {
            let mut change = 0.0f32;
            for (o, &c) in out.iter_mut().zip(chunk) {
                let k = (c & MASK) as usize;
                let (mut s, mut n) = (0.0f32, 0.0f32);
                if c & (1 << 63) != 0 {
                    s += zr[k - 1];
                    n += 1.0;
                }
                if c & (1 << 62) != 0 {
                    s += zr[k + 1];
                    n += 1.0;
                }
                if c & (1 << 61) != 0 {
                    s += zr[k - cols];
                    n += 1.0;
                }
                if c & (1 << 60) != 0 {
                    s += zr[k + cols];
                    n += 1.0;
                }
                let v = if n > 0.0 {
                    zr[k] + omega * (s / n - zr[k])
                } else {
                    zr[k]
                };
                change = change.max((v - zr[k]).abs());
                *o = v;
            }
            change
        })
        .reduce(|| 0.0, f32::max);
    let band = BAND_ROWS * cols;
    let buf: &[f32] = buf;
    z.par_chunks_mut(band).enumerate().for_each(|(b, zb)| {
        let (s, e) = (starts[b], starts[b + 1]);
        for (&c, &v) in cells[s..e].iter().zip(&buf[s..e]) {
            zb[(c & MASK) as usize - b * band] = v;
        }
    });
    change
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// The slow, obvious twin: assemble the membrane equations of the unknown cells as a
    /// dense matrix and solve them by Gaussian elimination with partial pivoting.
    pub(crate) fn dense_membrane(z: &[f32], cols: usize, rows: usize) -> Vec<f64> {
        let unknown: Vec<usize> = (0..z.len()).filter(|&k| !z[k].is_finite()).collect();
        let mut index = vec![usize::MAX; z.len()];
        for (u, &k) in unknown.iter().enumerate() {
            index[k] = u;
        }
        let n = unknown.len();
        let mut a = vec![0.0f64; n * n];
        let mut b = vec![0.0f64; n];
        for (u, &k) in unknown.iter().enumerate() {
            let (i, j) = (k % cols, k / cols);
            let mut nb = Vec::new();
            if i > 0 {
                nb.push(k - 1);
            }
            if i + 1 < cols {
                nb.push(k + 1);
            }
            if j > 0 {
                nb.push(k - cols);
            }
            if j + 1 < rows {
                nb.push(k + cols);
            }
            a[u * n + u] = nb.len() as f64;
            for m in nb {
                if index[m] == usize::MAX {
                    b[u] += z[m] as f64;
                } else {
                    a[u * n + index[m]] -= 1.0;
                }
            }
        }
        for c in 0..n {
            let p = (c..n)
                .max_by(|&x, &y| a[x * n + c].abs().total_cmp(&a[y * n + c].abs()))
                .unwrap();
            for k in 0..n {
                a.swap(c * n + k, p * n + k);
            }
            b.swap(c, p);
            for r in c + 1..n {
                let f = a[r * n + c] / a[c * n + c];
                if f != 0.0 {
                    for k in c..n {
                        a[r * n + k] -= f * a[c * n + k];
                    }
                    b[r] -= f * b[c];
                }
            }
        }
        let mut x = vec![0.0; n];
        for r in (0..n).rev() {
            let s: f64 = (r + 1..n).map(|k| a[r * n + k] * x[k]).sum();
            x[r] = (b[r] - s) / a[r * n + r];
        }
        let mut out: Vec<f64> = z.iter().map(|v| *v as f64).collect();
        for (u, &k) in unknown.iter().enumerate() {
            out[k] = x[u];
        }
        out
    }

    /// A grid of `f(i, j)` with random discs removed (kept off the border when `inner`).
    fn holey(
        seed: u64,
        cols: usize,
        rows: usize,
        inner: bool,
        f: impl Fn(f64, f64) -> f64,
    ) -> Vec<f32> {
        let mut rng = SplitMix64::new(seed);
        let mut z: Vec<f32> = (0..cols * rows)
            .map(|k| f((k % cols) as f64, (k / cols) as f64) as f32)
            .collect();
        for _ in 0..1 + rng.below(6) {
            let r = 1 + rng.below((cols.min(rows) / 4) as u64) as i64;
            let cx = rng.below(cols as u64) as i64;
            let cy = rng.below(rows as u64) as i64;
            for j in 0..rows as i64 {
                for i in 0..cols as i64 {
                    let border = i == 0 || j == 0 || i + 1 == cols as i64 || j + 1 == rows as i64;
                    if (i - cx).pow(2) + (j - cy).pow(2) <= r * r && !(inner && border) {
                        z[j as usize * cols + i as usize] = f32::NAN;
                    }
                }
            }
        }
        z
    }

    #[test]
    fn equals_the_dense_solve() {
        for seed in 0..12 {
            let (cols, rows) = (9 + seed as usize % 5, 7 + seed as usize % 4);
            let z = holey(seed, cols, rows, false, |x, y| {
                (x * 0.7).sin() * 3.0 + y * 0.2
            });
            let want = dense_membrane(&z, cols, rows);
            let mut got = z.clone();
            membrane_fill(&mut got, cols, rows, 1e-7);
            for k in 0..z.len() {
                assert!(
                    (got[k] as f64 - want[k]).abs() < 1e-4,
                    "seed {seed} cell {k}: {} vs {}",
                    got[k],
                    want[k]
                );
            }
        }
    }

    #[test]
    fn multigrid_equals_the_dense_solve() {
        // Large enough to be coarsened twice, small enough for the dense twin.
        let (cols, rows) = (97, 65);
        let mut z: Vec<f32> = (0..cols * rows)
            .map(|k| ((k % cols) as f32 * 0.1).cos() * 5.0 + (k / cols) as f32 * 0.05)
            .collect();
        for j in 20..45 {
            for i in 30..70 {
                z[j * cols + i] = f32::NAN;
            }
        }
        let want = dense_membrane(&z, cols, rows);
        let mut got = z.clone();
        membrane_fill(&mut got, cols, rows, 1e-7);
        let worst = (0..z.len())
            .map(|k| (got[k] as f64 - want[k]).abs())
            .fold(0.0, f64::max);
        assert!(worst < 2e-3, "largest difference {worst}");
    }

    #[test]
    fn nothing_known_is_left_alone() {
        let mut z = vec![f32::NAN; 12];
        assert_eq!(membrane_fill(&mut z, 4, 3, 1e-6), 0);
        assert!(z.iter().all(|v| v.is_nan()));
    }
}
