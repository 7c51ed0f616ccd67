//! Void filling by a membrane (Laplace) surface: every unknown cell becomes the mean of its
//! four neighbours, the known cells held fixed. The result is the discrete harmonic
//! interpolant of the known cells: smooth in every direction, inside the range of the
//! heights around the void (maximum principle: no spikes, no plateaus), and a plane is
//! reproduced exactly. At the grid's border a missing neighbour is left out of the mean
//! (zero slope across the border), so a void that reaches the border continues flat there
//! instead of being extrapolated to heights the data never had.
//!
//! The solver is a cascadic multigrid (Bornemann & Deuflhard, "The cascadic multigrid method
//! for elliptic problems", 1996) whose levels are each solved by multigrid V-cycles
//! (Briggs, Henson & McCormick, "A Multigrid Tutorial", 2000): the grid is coarsened by
//! injection (coarse cell (I, J) is fine cell (2I, 2J)) down to a few thousand cells, the
//! coarsest level is solved by red-black over-relaxed Gauss-Seidel to convergence, and each
//! finer level starts from the bilinear prolongation of the level below and runs V-cycles
//! (2 red-black Gauss-Seidel sweeps, the residual restricted by the transpose of bilinear
//! prolongation, the coarse correction solved recursively where the whole stencil is unknown, prolonged
//! bilinearly, 2 sweeps) until a cycle moves no cell more than the tolerance. Should the
//! cycles stop gaining, the level finishes with plain over-relaxed sweeps. Red-black order
//! makes a sweep independent of the
//! thread count: a red cell reads only black cells and the reverse, so the result is the same
//! bits for any number of threads. Hand-written because no crate of the field solves a
//! Laplace problem on a masked grid in place (the sparse solvers need an assembled matrix,
//! 20 bytes a cell and more).

use rayon::prelude::*;

/// Below this many cells a level is solved directly by iteration, not coarsened further.
const COARSEST: usize = 4096;
/// Sweep cap of the coarsest level (it is at most a few thousand cells).
const COARSE_SWEEPS: usize = 20_000;
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
        }
    } else {
        seed_with_mean(z, known);
    }
    v_cycles(z, known, cols, rows, tol);
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

/// Sweep cap of the plain over-relaxed sweeps a level falls back to when its V-cycles stop
/// gaining.
const FINE_SWEEPS: usize = 400;
/// Sweeps of red-black Gauss-Seidel before and after each coarse-grid correction.
const SMOOTH_SWEEPS: usize = 2;
/// V-cycle cap of a level of the cascade. With the same five-point stencil on every level
/// (no Galerkin coarse operator) a cycle cuts the change only by about 1.6 on the fine levels
/// of scattered voids (about 20 cycles at 4097²); the cap bounds the cases where the
/// tolerance lies below the rounding of `f32` heights.
const MAX_CYCLES: usize = 40;

/// One level of the V-cycle hierarchy. Cells are split by colour: cell (i, j) of colour
/// c = (i + j) mod 2 is `z[c][j * hw + i / 2]`, so a half-sweep writes one array while it
/// reads only the other (the same values for any thread count, and no aliasing).
struct Level {
    cols: usize,
    rows: usize,
    hw: usize,
    /// Heights (finest level) or corrections (coarser levels).
    z: [Vec<f32>; 2],
    /// Right-hand side (restricted residual); all zero on the finest level.
    f: [Vec<f32>; 2],
    /// Cells that are solved for; the others are held fixed (zero correction when coarse).
    free: [Vec<bool>; 2],
}

impl Level {
    fn new(cols: usize, rows: usize, free_full: &[bool]) -> Self {
        let hw = cols.div_ceil(2);
        Level {
            cols,
            rows,
            hw,
            z: [vec![0.0; hw * rows], vec![0.0; hw * rows]],
            f: [vec![0.0; hw * rows], vec![0.0; hw * rows]],
            free: split(free_full, cols, rows, false),
        }
    }

    /// One red-black half-sweep over the free cells of colour `c`, over-relaxed by `omega`;
    /// returns the largest change.
    fn relax(&mut self, c: usize, omega: f32) -> f32 {
        let (cols, rows, hw) = (self.cols, self.rows, self.hw);
        let [z0, z1] = &mut self.z;
        let (zc, zo): (&mut Vec<f32>, &Vec<f32>) = if c == 0 { (z0, z1) } else { (z1, z0) };
        let (free, f) = (&self.free[c], &self.f[c]);
        zc.par_chunks_mut(hw)
            .enumerate()
            .map(|(j, row)| {
                let (s, e) = (j * hw, (j + 1) * hw);
                let (fr, ff, mid) = (&free[s..e], &f[s..e], &zo[s..e]);
                let up = (j > 0).then(|| &zo[s - hw..s]);
                let dn = (j + 1 < rows).then(|| &zo[e..e + hw]);
                let mut change = 0.0f32;
                for i in ((j + c) & 1..cols).step_by(2) {
                    let m = i / 2;
                    if !fr[m] {
                        continue;
                    }
                    let (mut sum, mut n) = (ff[m], 0.0f32);
                    if i > 0 {
                        sum += mid[(i - 1) / 2];
                        n += 1.0;
                    }
                    if i + 1 < cols {
                        sum += mid[i.div_ceil(2)];
                        n += 1.0;
                    }
                    if let Some(u) = up {
                        sum += u[m];
                        n += 1.0;
                    }
                    if let Some(d) = dn {
                        sum += d[m];
                        n += 1.0;
                    }
                    if n > 0.0 {
                        let v = row[m] + omega * (sum / n - row[m]);
                        change = change.max((v - row[m]).abs());
                        row[m] = v;
                    }
                }
                change
            })
            .reduce(|| 0.0, f32::max)
    }

    /// The residual f − L z of every cell as a full row-major grid (zero at fixed cells).
    fn residual(&self) -> Vec<f32> {
        let (cols, rows, hw) = (self.cols, self.rows, self.hw);
        let mut r = vec![0.0f32; cols * rows];
        r.par_chunks_mut(cols).enumerate().for_each(|(j, row)| {
            for (i, out) in row.iter_mut().enumerate() {
                let c = (i + j) & 1;
                let k = j * hw + i / 2;
                if !self.free[c][k] {
                    continue;
                }
                let zo = &self.z[1 - c];
                let (mut sum, mut n) = (self.f[c][k], 0.0f32);
                if i > 0 {
                    sum += zo[j * hw + (i - 1) / 2];
                    n += 1.0;
                }
                if i + 1 < cols {
                    sum += zo[j * hw + i.div_ceil(2)];
                    n += 1.0;
                }
                if j > 0 {
                    sum += zo[k - hw];
                    n += 1.0;
                }
                if j + 1 < rows {
                    sum += zo[k + hw];
                    n += 1.0;
                }
                *out = sum - n * self.z[c][k];
            }
        });
        r
    }

    /// Adds the bilinear prolongation of the coarse correction `ec` (full row-major,
    /// `cc` × `cr`) to the free cells; returns the largest correction.
    fn add_prolonged(&mut self, ec: &[f32], cc: usize, cr: usize) -> f32 {
        let (cols, hw) = (self.cols, self.hw);
        let mut change = 0.0f32;
        for c in 0..2 {
            let free = &self.free[c];
            let m = self.z[c]
                .par_chunks_mut(hw)
                .enumerate()
                .map(|(j, row)| {
                    let (j0, j1) = (j / 2, j.div_ceil(2).min(cr - 1));
                    let mut change = 0.0f32;
                    for i in ((j + c) & 1..cols).step_by(2) {
                        let m = i / 2;
                        if !free[j * hw + m] {
                            continue;
                        }
                        let (i0, i1) = (i / 2, i.div_ceil(2).min(cc - 1));
                        let a = ec[j0 * cc + i0] + ec[j0 * cc + i1];
                        let b = ec[j1 * cc + i0] + ec[j1 * cc + i1];
                        let e = (a + b) * 0.25;
                        change = change.max(e.abs());
                        row[m] += e;
                    }
                    change
                })
                .reduce(|| 0.0, f32::max);
            change = change.max(m);
        }
        change
    }
}

/// Cells of colour c of a full row-major grid, as [`Level`] stores them (`pad` beyond the
/// last column).
fn split<T: Copy + Send + Sync>(full: &[T], cols: usize, rows: usize, pad: T) -> [Vec<T>; 2] {
    let hw = cols.div_ceil(2);
    std::array::from_fn(|c| {
        let mut out = vec![pad; hw * rows];
        out.par_chunks_mut(hw).enumerate().for_each(|(j, row)| {
            for i in ((j + c) & 1..cols).step_by(2) {
                row[i / 2] = full[j * cols + i];
            }
        });
        out
    })
}

/// The inverse of [`split`].
fn join(parts: &[Vec<f32>; 2], cols: usize, rows: usize) -> Vec<f32> {
    let hw = cols.div_ceil(2);
    let mut full = vec![0.0f32; cols * rows];
    full.par_chunks_mut(cols).enumerate().for_each(|(j, row)| {
        for (i, v) in row.iter_mut().enumerate() {
            *v = parts[(i + j) & 1][j * hw + i / 2];
        }
    });
    full
}

/// Weight of fine index `i` in coarse index `ic` under bilinear prolongation (coarse `ic`
/// is fine `2 ic`; an odd fine index lies half-way; past the last coarse index, the last).
fn weight(i: usize, ic: usize, nc: usize) -> f32 {
    0.5 * ((i / 2 == ic) as u8 + (i.div_ceil(2).min(nc - 1) == ic) as u8) as f32
}

/// The transpose of the bilinear prolongation applied to the full grid `r` (`cols` × `rows`):
/// the coarse right-hand side (full weighting times four, the unscaled operator's h²).
fn restrict(r: &[f32], cols: usize, rows: usize, cc: usize, cr: usize) -> Vec<f32> {
    let mut t = vec![0.0f32; cc * rows];
    t.par_chunks_mut(cc).enumerate().for_each(|(j, row)| {
        let src = &r[j * cols..(j + 1) * cols];
        for (ic, out) in row.iter_mut().enumerate() {
            let (lo, hi) = ((2 * ic).saturating_sub(1), (2 * ic + 2).min(cols));
            *out = (lo..hi).map(|i| weight(i, ic, cc) * src[i]).sum();
        }
    });
    let mut fc = vec![0.0f32; cc * cr];
    fc.par_chunks_mut(cc).enumerate().for_each(|(jc, row)| {
        let (lo, hi) = ((2 * jc).saturating_sub(1), (2 * jc + 2).min(rows));
        for j in lo..hi {
            let w = weight(j, jc, cr);
            if w != 0.0 {
                for (out, v) in row.iter_mut().zip(&t[j * cc..(j + 1) * cc]) {
                    *out += w * v;
                }
            }
        }
    });
    fc
}

/// The levels below a level of `cols` × `rows` with the free cells `free` (full layout):
/// a coarse cell is free when every fine cell its prolongation reaches (the 3 × 3 around
/// the fine cell it sits on) is free, so the coarse operator (the same five-point stencil,
/// not the Galerkin product) is used only where it matches the fine one; the injected mask
/// alone (free when the fine cell under it is) diverged on scattered one-cell voids. The
/// last coarse column (row) of a fine grid of even width (height) is held fixed too: it
/// sits one fine cell, not two, from its neighbour beyond. Stops
/// above [`COARSEST`] cells, or where a level would have no free or no fixed cell (a level
/// without fixed cells is singular).
fn hierarchy(free: &[bool], cols: usize, rows: usize) -> Vec<Level> {
    let mut levels = vec![Level::new(cols, rows, free)];
    let (mut cols, mut rows, mut free) = (cols, rows, free.to_vec());
    while cols * rows > COARSEST && cols >= 3 && rows >= 3 {
        let (cc, cr) = (cols.div_ceil(2), rows.div_ceil(2));
        let fc: Vec<bool> = (0..cc * cr)
            .into_par_iter()
            .map(|k| {
                let (ic, jc) = (k % cc, k / cc);
                let edge = (cols % 2 == 0 && ic + 1 == cc) || (rows % 2 == 0 && jc + 1 == cr);
                let (i, j) = (2 * ic, 2 * jc);
                let all = (j.saturating_sub(1)..(j + 2).min(rows))
                    .all(|j| (i.saturating_sub(1)..(i + 2).min(cols)).all(|i| free[j * cols + i]));
                !edge && all
            })
            .collect();
        let nf = fc.iter().filter(|f| **f).count();
        if nf == 0 || nf == fc.len() {
            break;
        }
        levels.push(Level::new(cc, cr, &fc));
        (cols, rows, free) = (cc, cr, fc);
    }
    levels
}

/// Over-relaxed red-black sweeps on `level` until a sweep moves no cell more than `tol`
/// or than `rel` times the first sweep's largest change (a correction needs only relative
/// accuracy), at most `cap` sweeps; returns the sum of the sweeps' largest changes.
fn solve_coarsest(level: &mut Level, tol: f32, rel: f32, cap: usize) -> f32 {
    let (mut total, mut first) = (0.0f32, None);
    for _ in 0..cap {
        let change = level.relax(0, OMEGA).max(level.relax(1, OMEGA));
        total += change;
        let first = *first.get_or_insert(change);
        if change <= tol || change <= rel * first {
            break;
        }
    }
    total
}

/// One V-cycle from level 0 of `levels`; returns the sum of the largest changes of its
/// steps on that level (a bound on the largest change of a cell in the cycle).
fn v_cycle(levels: &mut [Level], tol: f32) -> f32 {
    let (this, below) = levels.split_first_mut().expect("a level");
    let Some(coarse) = below.first_mut() else {
        // The coarsest level: over-relaxed sweeps until it has converged.
        return solve_coarsest(this, tol * 0.1, 1e-4, COARSE_SWEEPS);
    };
    let mut total = 0.0f32;
    for _ in 0..SMOOTH_SWEEPS {
        total += this.relax(0, 1.0).max(this.relax(1, 1.0));
    }
    let r = this.residual();
    let fc = restrict(&r, this.cols, this.rows, coarse.cols, coarse.rows);
    drop(r);
    coarse.f = split(&fc, coarse.cols, coarse.rows, 0.0);
    for z in &mut coarse.z {
        z.par_iter_mut().for_each(|v| *v = 0.0);
    }
    v_cycle(below, tol);
    let (cc, cr) = (below[0].cols, below[0].rows);
    let ec = join(&below[0].z, cc, cr);
    total += this.add_prolonged(&ec, cc, cr);
    for _ in 0..SMOOTH_SWEEPS {
        total += this.relax(0, 1.0).max(this.relax(1, 1.0));
    }
    total
}

/// Multigrid V-cycles on the grid `z` (unknown cells hold the initial guess) until a cycle
/// moves no cell more than `tol`.
fn v_cycles(z: &mut [f32], known: &[bool], cols: usize, rows: usize, tol: f32) {
    let free: Vec<bool> = known.par_iter().map(|k| !k).collect();
    let mut levels = hierarchy(&free, cols, rows);
    drop(free);
    levels[0].z = split(z, cols, rows, 0.0);
    if levels.len() == 1 {
        solve_coarsest(&mut levels[0], tol, 0.0, COARSE_SWEEPS);
    } else {
        let mut last = f32::INFINITY;
        for _ in 0..MAX_CYCLES {
            let before = levels[0].z.clone();
            let change = v_cycle(&mut levels, tol);
            if change <= tol {
                break;
            }
            if change > 0.8 * last {
                // The cycles no longer gain: the changes are down to the rounding of f32
                // heights, or the coarse levels do not match the fine one (a mask the
                // injection coarsens badly, which can diverge). Undo the cycle and finish
                // with plain over-relaxed sweeps, which always converge.
                levels[0].z = before;
                solve_coarsest(&mut levels[0], tol, 0.0, FINE_SWEEPS);
                break;
            }
            last = change;
        }
    }
    let out = join(&levels[0].z, cols, rows);
    z.par_iter_mut()
        .zip(out.par_iter())
        .zip(known.par_iter())
        .for_each(|((v, o), k)| {
            if !k {
                *v = *o;
            }
        });
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
