//! Void filling by a membrane (Laplace) surface: every unknown cell becomes the mean of its
//! four neighbours, the known cells held fixed. The result is the discrete harmonic
//! interpolant of the known cells: smooth in every direction, inside the range of the
//! heights around the void (maximum principle: no spikes, no plateaus), and a plane is
//! reproduced exactly. At the grid's border a missing neighbour is left out of the mean
//! (zero slope across the border), so a void that reaches the border continues flat there
//! instead of being extrapolated to heights the data never had.
//!
//! The unknown cells split into 4-connected components (found from the runs of unknown cells
//! of each row, joined row to row by union-find), and the equations of one component involve
//! no other: each is solved on its own bounding box, in parallel over the components, each on
//! one thread, so the bytes are the same for any thread count. A single cell is the mean of
//! its neighbours; a component of at most [`SMALL`] cells is solved by symmetric Gauss-Seidel
//! sweeps; a larger one by multigrid (Briggs, Henson & McCormick, "A Multigrid Tutorial",
//! 2000): bilinear prolongation P, restriction R = Pᵀ, and the Galerkin coarse operator
//! R A P (a 9-point stencil per coarse cell) computed from the masked fine operator, so the
//! coarse levels see the void's true shape (a coarse cell half inside the void keeps the part
//! that is). The earlier geometric coarsening (the same five-point stencil on an eroded mask)
//! divided the change by only about 1.6 a cycle on these masks; the Galerkin cycles divide it
//! by about 4 to 7. A full-multigrid start (the right-hand side restricted to every level, the
//! coarsest solved, each finer level started from the prolongation of the one below and
//! improved by one V-cycle) is followed by V(1, 1) cycles (forward Gauss-Seidel before the
//! coarse correction, backward after) until the estimated error is within the tolerance.
//! A component of [`PAR_CELLS`] cells or more (a survey sparser than the grid, whose empty
//! cells join into one void around the measured ones) is swept in colours instead, red-black
//! on the fine level and four colours on the coarse ones, with its rows in parallel: the cells
//! of one colour do not depend on each other, so its bytes too are the same for any thread
//! count, and both cores work on it.
//! Hand-written because no crate of the field solves a Laplace problem on a masked grid
//! in place (the sparse solvers need an assembled matrix, 20 bytes a cell and more).

use rayon::prelude::*;

/// Fills every NaN cell of the row-major `rows` × `cols` grid `z` with the membrane surface
/// of its finite cells; finite cells are never changed. `tol` bounds the error left in a
/// cell, estimated from the last two iterations' largest changes (same unit as `z`). A grid
/// without any finite cell is left as it is. Returns the number of cells filled.
pub fn membrane_fill(z: &mut [f32], cols: usize, rows: usize, tol: f32) -> usize {
    assert_eq!(z.len(), cols * rows, "grid size");
    let runs = Runs::new(z, cols);
    let unknown: usize = runs.len.iter().map(|&n| n as usize).sum();
    if unknown == 0 || unknown == z.len() {
        return 0;
    }
    let tol = tol.max(0.0);
    let (order, starts) = runs.components(rows);
    // Each component's cells, run after run, in one buffer.
    let mut out = vec![0.0f32; unknown];
    let mut at = vec![0usize; runs.i0.len()];
    let mut parts: Vec<(&[u32], &mut [f32])> = Vec::with_capacity(starts.len() - 1);
    let mut rest = out.as_mut_slice();
    let mut o = 0;
    for w in starts.windows(2) {
        let rs = &order[w[0]..w[1]];
        let n: usize = rs.iter().map(|&r| runs.len[r as usize] as usize).sum();
        for &r in rs {
            at[r as usize] = o;
            o += runs.len[r as usize] as usize;
        }
        let (a, b) = std::mem::take(&mut rest).split_at_mut(n);
        parts.push((rs, a));
        rest = b;
    }
    {
        let zr: &[f32] = z;
        parts
            .par_iter_mut()
            .with_max_len(1)
            .for_each(|(rs, o)| solve_component(zr, cols, rows, &runs, rs, o, tol));
    }
    z.par_chunks_mut(cols).enumerate().for_each(|(j, row)| {
        let rs = runs.row[j]..runs.row[j + 1];
        for ((i0, n), a) in runs.i0[rs.clone()]
            .iter()
            .zip(&runs.len[rs.clone()])
            .zip(&at[rs])
        {
            let (i0, n) = (*i0 as usize, *n as usize);
            row[i0..i0 + n].copy_from_slice(&out[*a..*a + n]);
        }
    });
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
    tolerance_of_range(lo, hi)
}

/// [`default_tolerance`] of heights whose finite ones span `lo..=hi` (`lo > hi`: none).
pub fn tolerance_of_range(lo: f32, hi: f32) -> f32 {
    if lo > hi {
        return 1e-6;
    }
    ((hi - lo) * 1e-5).max(1e-6)
}

/// The runs of unknown (not finite) cells of each row.
struct Runs {
    /// First run of each row (one more entry than rows).
    row: Vec<usize>,
    /// Row, first column and length of each run.
    j: Vec<u32>,
    i0: Vec<u32>,
    len: Vec<u32>,
}

impl Runs {
    /// Row, first column and length of run `r`.
    fn get(&self, r: u32) -> (usize, usize, usize) {
        let r = r as usize;
        (
            self.j[r] as usize,
            self.i0[r] as usize,
            self.len[r] as usize,
        )
    }

    fn new(z: &[f32], cols: usize) -> Self {
        let per_row: Vec<Vec<(u32, u32)>> = z
            .par_chunks(cols)
            .map(|row| {
                let mut v = Vec::new();
                let mut i = 0;
                while i < cols {
                    if row[i].is_finite() {
                        i += 1;
                        continue;
                    }
                    let s = i;
                    while i < cols && !row[i].is_finite() {
                        i += 1;
                    }
                    v.push((s as u32, (i - s) as u32));
                }
                v
            })
            .collect();
        let n: usize = per_row.iter().map(Vec::len).sum();
        let mut runs = Runs {
            row: Vec::with_capacity(per_row.len() + 1),
            j: Vec::with_capacity(n),
            i0: Vec::with_capacity(n),
            len: Vec::with_capacity(n),
        };
        runs.row.push(0);
        for (j, v) in per_row.iter().enumerate() {
            for &(i0, l) in v {
                runs.j.push(j as u32);
                runs.i0.push(i0);
                runs.len.push(l);
            }
            runs.row.push(runs.i0.len());
        }
        runs
    }

    /// Groups the runs by 4-connected component: the run indices of each component in row
    /// order, and where each component starts (one more entry than components). Components
    /// are numbered by their first run (the same for any thread count).
    fn components(&self, rows: usize) -> (Vec<u32>, Vec<usize>) {
        let n = self.i0.len();
        let mut parent: Vec<u32> = (0..n as u32).collect();
        fn find(p: &mut [u32], mut x: u32) -> u32 {
            while p[x as usize] != x {
                p[x as usize] = p[p[x as usize] as usize];
                x = p[x as usize];
            }
            x
        }
        for j in 1..rows {
            let (mut a, ae) = (self.row[j - 1], self.row[j]);
            let (mut b, be) = (self.row[j], self.row[j + 1]);
            while a < ae && b < be {
                let (a0, a1) = (self.i0[a], self.i0[a] + self.len[a]);
                let (b0, b1) = (self.i0[b], self.i0[b] + self.len[b]);
                if a0 < b1 && b0 < a1 {
                    let (ra, rb) = (find(&mut parent, a as u32), find(&mut parent, b as u32));
                    if ra != rb {
                        let (lo, hi) = (ra.min(rb), ra.max(rb));
                        parent[hi as usize] = lo;
                    }
                }
                if a1 <= b1 {
                    a += 1;
                } else {
                    b += 1;
                }
            }
        }
        let mut id = vec![u32::MAX; n];
        let mut count = Vec::new();
        let comp: Vec<u32> = (0..n as u32)
            .map(|r| {
                let root = find(&mut parent, r) as usize;
                if id[root] == u32::MAX {
                    id[root] = count.len() as u32;
                    count.push(0usize);
                }
                count[id[root] as usize] += 1;
                id[root]
            })
            .collect();
        let mut starts = Vec::with_capacity(count.len() + 1);
        starts.push(0);
        for c in &count {
            starts.push(starts.last().unwrap() + c);
        }
        let mut fill = starts.clone();
        let mut order = vec![0u32; n];
        for (r, c) in comp.iter().enumerate() {
            let c = *c as usize;
            order[fill[c]] = r as u32;
            fill[c] += 1;
        }
        (order, starts)
    }
}

/// The finest level of a component: the five-point operator on a local box (the component's
/// bounding box and a ring of one cell). `nb[k]` is the number of in-grid neighbours of a free
/// cell, 0 at every other cell; `x` holds the heights: the known ones at fixed cells, 0
/// outside the grid and at other components' cells (never a neighbour of a free cell).
struct Fine {
    cols: usize,
    rows: usize,
    nb: Vec<u8>,
    x: Vec<f32>,
    /// Swept in colours, rows in parallel (see [`PAR_CELLS`]).
    par: bool,
}

/// A coarse level: the Galerkin operator R A P as a 9-point stencil per cell (offsets in row
/// order, dy then dx in −1..=1), active where its centre weight is positive. `kind` is
/// [`INACTIVE`], [`INTERIOR`] (the stencil is the level's interior stencil `interior`, which
/// the sweeps read from registers instead of the array) or [`EDGE`].
struct Coarse {
    cols: usize,
    rows: usize,
    st: Vec<[f32; 9]>,
    kind: Vec<u8>,
    interior: [f32; 9],
    x: Vec<f32>,
    b: Vec<f32>,
    /// Swept in colours, rows in parallel (see [`PAR_CELLS`]).
    par: bool,
}

/// [`Coarse::kind`] of a cell outside the level's void.
const INACTIVE: u8 = 0;
/// [`Coarse::kind`] of a cell whose stencil is the level's interior stencil.
const INTERIOR: u8 = 1;
/// [`Coarse::kind`] of any other active cell (its own stencil in [`Coarse::st`]).
const EDGE: u8 = 2;

/// 1 / n for the n in-grid neighbours of a cell.
const INV: [f32; 5] = [0.0, 1.0, 0.5, 1.0 / 3.0, 0.25];
/// Components up to this many cells are solved by Gauss-Seidel sweeps alone (a few cells
/// across: the sweeps converge in a few dozen).
const SMALL: usize = 24;
/// V-cycle cap of a component: reached only when the tolerance lies below the rounding of
/// `f32` heights (the cycles then stop gaining).
const MAX_CYCLES: usize = 40;
/// Gauss-Seidel sweeps before and after each coarse-grid correction.
const SMOOTH: usize = 1;
/// Sweep cap of the coarsest level (at most a few cells across). Its operator can be
/// singular (coarse cells whose prolongation reaches the same single fine cell); sweeps
/// then converge on the part that matters (P e) while the rest drifts by rounding, so the
/// cap, not the relative criterion, ends them.
const COARSEST_SWEEPS: usize = 20;
/// A component of at least this many cells (a level of at least this many cells of such a
/// component) is swept in colours with its rows in parallel, so that a void covering most
/// of the grid does not keep one core busy while the other idles: red-black on the fine
/// level (the five-point stencil couples only cells of different colours), four colours
/// (the parities of the column and the row) on the coarse levels (the nine-point stencils
/// couple only cells of different colours). The cells of one colour are then independent,
/// so the result is the same for any thread count. Smaller components keep the
/// lexicographic sweeps (many of them run side by side already).
const PAR_CELLS: usize = 1 << 16;
/// Rows per parallel band of a swept level.
const BAND_ROWS: usize = 16;
/// Sweep cap of the Gauss-Seidel solve of a small component.
const SMALL_SWEEPS: usize = 100_000;

/// Solves the component whose runs are `rs` (indices into `runs`) and writes its heights to
/// `out`, run after run.
fn solve_component(
    z: &[f32],
    cols: usize,
    rows: usize,
    runs: &Runs,
    rs: &[u32],
    out: &mut [f32],
    tol: f32,
) {
    let (mut i0, mut i1, mut j0, mut j1) = (usize::MAX, 0, usize::MAX, 0);
    for &r in rs {
        let (j, a, n) = runs.get(r);
        (i0, i1, j0, j1) = (i0.min(a), i1.max(a + n - 1), j0.min(j), j1.max(j));
    }
    let count = out.len();
    let nbcount = |i: usize, j: usize| {
        (i > 0) as u8 + (i + 1 < cols) as u8 + (j > 0) as u8 + (j + 1 < rows) as u8
    };
    if count == 1 {
        let (i, j) = (i0, j0);
        let k = j * cols + i;
        let mut s = 0.0f32;
        if i > 0 {
            s += z[k - 1];
        }
        if i + 1 < cols {
            s += z[k + 1];
        }
        if j > 0 {
            s += z[k - cols];
        }
        if j + 1 < rows {
            s += z[k + cols];
        }
        out[0] = s / nbcount(i, j) as f32;
        return;
    }
    // Local box with a ring: local (li, lj) is global (i0 + li − 1, j0 + lj − 1).
    let (lc, lr) = (i1 - i0 + 3, j1 - j0 + 3);
    let mut f = Fine {
        cols: lc,
        rows: lr,
        nb: vec![0; lc * lr],
        x: vec![0.0; lc * lr],
        par: count >= PAR_CELLS,
    };
    // The box's columns inside the grid: global ga..gb, local from la.
    let (ga, gb) = (i0.saturating_sub(1), (i1 + 2).min(cols));
    let la = ga + 1 - i0;
    for lj in 0..lr {
        let Some(j) = (j0 + lj).checked_sub(1).filter(|j| *j < rows) else {
            continue;
        };
        let src = &z[j * cols + ga..j * cols + gb];
        for (x, v) in f.x[lj * lc + la..].iter_mut().zip(src) {
            if v.is_finite() {
                *x = *v;
            }
        }
    }
    for &r in rs {
        let (j, a, n) = runs.get(r);
        for i in a..a + n {
            f.nb[(j + 1 - j0) * lc + (i + 1 - i0)] = nbcount(i, j);
        }
    }
    if count <= SMALL {
        gs_fine_converge(&mut f, tol);
    } else {
        let mut levels: Vec<Coarse> = vec![galerkin_fine(&f, f.par)];
        loop {
            let l = levels.last().unwrap();
            let (cc, cr) = coarse_dims(l.cols, l.rows);
            if (cc >= l.cols && cr >= l.rows)
                || l.kind.iter().filter(|k| **k != INACTIVE).count() <= 9
            {
                break;
            }
            let c = galerkin_coarse(l, levels.len(), f.par);
            levels.push(c);
        }
        let mut r = Vec::with_capacity(f.x.len());
        fmg(&mut f, &mut levels, &mut r);
        let mut last = f32::INFINITY;
        for _ in 0..MAX_CYCLES {
            let change = v_cycle(&mut f, &mut levels, &mut r);
            if converged(change, last, tol) {
                break;
            }
            last = change;
        }
    }
    let mut o = 0;
    for &r in rs {
        let (j, a, n) = runs.get(r);
        let s = (j + 1 - j0) * lc + (a + 1 - i0);
        out[o..o + n].copy_from_slice(&f.x[s..s + n]);
        o += n;
    }
}

/// Whether an iteration whose last step moved no cell more than `change` (the one before:
/// `last`) is within `tol` of the solution: the error left is about change · ρ / (1 − ρ)
/// with ρ = change / last the rate of the iteration.
fn converged(change: f32, last: f32, tol: f32) -> bool {
    // Aim at half the tolerance: the estimate from the largest changes is rough (on random
    // masks of 60 % unknown cells the error left was up to 3 times the estimate's aim).
    let tol = 0.5 * tol;
    if change <= tol * 1e-3 {
        return true;
    }
    let rho = (change / last).min(0.999);
    change <= tol && change * rho <= tol * (1.0 - rho)
}

/// One Gauss-Seidel sweep of the fine level (forward, or `backward`); returns the largest
/// change.
fn gs_fine(f: &mut Fine, backward: bool) -> f32 {
    if f.par {
        let order = if backward { [1, 0] } else { [0, 1] };
        return order
            .iter()
            .fold(0.0, |m, &colour| m.max(gs_fine_colour(f, colour)));
    }
    let c = f.cols;
    let len = f.x.len();
    let (x, nb) = (&mut f.x, &f.nb);
    let mut change = 0.0f32;
    // The neighbour the sweep has just updated (left going forward, right going backward)
    // is carried in a register and added last: the chain from one cell's result to the next
    // is then one addition and one multiplication (the sweep is bound by it), where reading
    // it back from memory first and adding it first made it a store, a load, three
    // additions and a multiplication.
    if backward {
        let mut prev = x[len - c];
        for k in (c..len - c).rev() {
            let n = nb[k];
            if n != 0 {
                let v = (x[k - 1] + x[k - c] + x[k + c] + prev) * INV[n as usize];
                change = change.max((v - x[k]).abs());
                x[k] = v;
                prev = v;
            } else {
                prev = x[k];
            }
        }
    } else {
        let mut prev = x[c - 1];
        for k in c..len - c {
            let n = nb[k];
            if n != 0 {
                let v = (x[k + 1] + x[k - c] + x[k + c] + prev) * INV[n as usize];
                change = change.max((v - x[k]).abs());
                x[k] = v;
                prev = v;
            } else {
                prev = x[k];
            }
        }
    }
    change
}

/// One half of a red-black sweep of the fine level: the free cells whose column + row has the
/// parity `colour`, rows in parallel; returns the largest change.
fn gs_fine_colour(f: &mut Fine, colour: usize) -> f32 {
    let (c, nb) = (f.cols, &f.nb);
    colour_pass(&mut f.x, c, |j, above, row, below| {
        let nb = &nb[j * c..(j + 1) * c];
        let mut change = 0.0f32;
        for i in (1 + (j + 1 + colour) % 2..c - 1).step_by(2) {
            let n = nb[i];
            if n != 0 {
                let v = (row[i - 1] + row[i + 1] + above[i] + below[i]) * INV[n as usize];
                change = change.max((v - row[i]).abs());
                row[i] = v;
            }
        }
        change
    })
}

/// Runs `update(j, above, row, below)` on every row `j` of `x` (`c` wide) but the first and
/// the last (a level's ring), bands of [`BAND_ROWS`] rows in parallel, and returns the largest
/// of what the calls return. `update` may change only cells that no call reads from a
/// neighbouring row (the cells of one colour): the rows next to a band are copied before the
/// pass, so the result does not depend on the order of the bands.
fn colour_pass(
    x: &mut [f32],
    c: usize,
    update: impl Fn(usize, &[f32], &mut [f32], &[f32]) -> f32 + Sync,
) -> f32 {
    let rows = x.len() / c;
    let copies: Vec<[Vec<f32>; 2]> = (0..rows.div_ceil(BAND_ROWS))
        .map(|b| {
            let (j0, j1) = (b * BAND_ROWS, ((b + 1) * BAND_ROWS).min(rows));
            let above = if j0 > 0 {
                x[(j0 - 1) * c..j0 * c].to_vec()
            } else {
                Vec::new()
            };
            let below = if j1 < rows {
                x[j1 * c..(j1 + 1) * c].to_vec()
            } else {
                Vec::new()
            };
            [above, below]
        })
        .collect();
    x.par_chunks_mut(BAND_ROWS * c)
        .zip(&copies)
        .enumerate()
        .map(|(b, (band, [above, below]))| {
            let n = band.len() / c;
            let mut m = 0.0f32;
            for r in 0..n {
                let j = b * BAND_ROWS + r;
                if j == 0 || j + 1 == rows {
                    continue;
                }
                let (head, tail) = band.split_at_mut(r * c);
                let (row, tail) = tail.split_at_mut(c);
                let a: &[f32] = if r > 0 { &head[(r - 1) * c..] } else { above };
                let d: &[f32] = if r + 1 < n { &tail[..c] } else { below };
                m = m.max(update(j, a, row, d));
            }
            m
        })
        .reduce(|| 0.0, f32::max)
}

/// Symmetric Gauss-Seidel sweeps until [`converged`].
fn gs_fine_converge(f: &mut Fine, tol: f32) {
    let mut last = f32::INFINITY;
    for s in 0..SMALL_SWEEPS {
        let change = gs_fine(f, s % 2 == 1);
        if converged(change, last, tol) {
            break;
        }
        last = change;
    }
}

/// The size of the level below a level of `cols` × `rows` cells. Every level keeps a ring of
/// inactive cells around its active ones (a stencil never reads outside the array): fine
/// cell i (even) sits on coarse cell i / 2 + 1, an odd one half-way between two.
fn coarse_dims(cols: usize, rows: usize) -> (usize, usize) {
    ((cols - 1) / 2 + 3, (rows - 1) / 2 + 3)
}

/// R A P at one coarse cell as a dense map (the slow, obvious twin of [`rap`]): weight of entry `o` of the stencil of fine cell
/// `c` (of the 3 × 3 around the coarse cell's fine centre, row order) in coarse offset `out`:
/// `RAP[c * 9 + o][out]`, from the bilinear weights (1, ½, ¼) of R and P.
#[cfg(test)]
const RAP_DENSE: [[f32; 9]; 81] = {
    // Bilinear weight of fine offset u (−2..=2 from the centre) on coarse offset v (−1..=1).
    const fn q(u: i32, v: i32) -> f32 {
        match (u, v) {
            (-2, -1) | (0, 0) | (2, 1) => 1.0,
            (-1, -1) | (-1, 0) | (1, 0) | (1, 1) => 0.5,
            _ => 0.0,
        }
    }
    let mut m = [[0.0f32; 9]; 81];
    let mut c = 0;
    while c < 9 {
        let (ax, ay) = (c as i32 % 3 - 1, c as i32 / 3 - 1);
        let wa = q(2 * ax, 0).max(q(ax, 0)) * q(2 * ay, 0).max(q(ay, 0));
        let mut o = 0;
        while o < 9 {
            let (bx, by) = (ax + o as i32 % 3 - 1, ay + o as i32 / 3 - 1);
            let mut out = 0;
            while out < 9 {
                let (vx, vy) = (out as i32 % 3 - 1, out as i32 / 3 - 1);
                m[c * 9 + o][out] += wa * q(bx, vx) * q(by, vy);
                out += 1;
            }
            o += 1;
        }
        c += 1;
    }
    m
};

/// R A P at one coarse cell from the 9-point stencils of the 3 × 3 fine cells around its
/// centre (zero stencils at inactive cells), in two separable passes: along x, then along y.
#[inline]
fn rap(a: &[[f32; 9]; 9]) -> [f32; 9] {
    // Q[u + 2][v + 1]: bilinear weight of fine offset u (from the centre) on coarse offset v.
    const Q: [[f32; 3]; 5] = [
        [1.0, 0.0, 0.0],
        [0.5, 0.5, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.5, 0.5],
        [0.0, 0.0, 1.0],
    ];
    // Weight of a fine cell of the 3 × 3 in R, per axis.
    const W: [f32; 3] = [0.5, 1.0, 0.5];
    // t[ay][oy][vx]: the x pass (fine column ax, stencil column ox onto coarse column vx).
    let mut t = [[[0.0f32; 3]; 3]; 3];
    for ay in 0..3 {
        for oy in 0..3 {
            for ax in 0..3 {
                for ox in 0..3 {
                    let v = W[ax] * a[ay * 3 + ax][oy * 3 + ox];
                    for vx in 0..3 {
                        t[ay][oy][vx] += v * Q[ax + ox][vx];
                    }
                }
            }
        }
    }
    let mut s = [0.0f32; 9];
    for ay in 0..3 {
        for oy in 0..3 {
            for vy in 0..3 {
                let w = W[ay] * Q[ay + oy][vy];
                for vx in 0..3 {
                    s[vy * 3 + vx] += w * t[ay][oy][vx];
                }
            }
        }
    }
    s
}

/// The interior stencil of level `l` (0: the five-point one).
fn standard(l: usize) -> [f32; 9] {
    let mut s = [0.0, -1.0, 0.0, -1.0, 4.0, -1.0, 0.0, -1.0, 0.0];
    for _ in 0..l {
        s = rap(&[s; 9]);
    }
    s
}

/// The level below a level of `cols` × `rows` cells (its index `level`, 0 the finest) whose
/// stencils are `stencil(k)` and whose cells are of `class[k]` ([`INACTIVE`]: a zero
/// stencil; [`INTERIOR`]: the level's interior stencil; [`EDGE`]: any other): R A P at every
/// coarse cell, the interior stencil of the level below where all nine fine cells under it
/// are interior, which most are, and nothing where all nine are inactive (the box around a
/// round void), both read from the classes alone.
fn galerkin_with(
    cols: usize,
    rows: usize,
    level: usize,
    par: bool,
    class: &[u8],
    stencil: impl Fn(usize) -> [f32; 9],
) -> Coarse {
    let (cc, cr) = coarse_dims(cols, rows);
    let s_std = standard(level + 1);
    let mut st = vec![[0.0f32; 9]; cc * cr];
    let mut kind = vec![INACTIVE; cc * cr];
    for cj in 1..cr - 1 {
        let fj = 2 * (cj - 1);
        for ci in 1..cc - 1 {
            let fi = 2 * (ci - 1);
            let at = |dx: usize, dy: usize| -> Option<usize> {
                let (i, j) = ((fi + dx).checked_sub(1)?, (fj + dy).checked_sub(1)?);
                (i < cols && j < rows).then_some(j * cols + i)
            };
            // The classes of the 3 × 3 fine cells: all interior, all inactive, or mixed.
            let (mut all_std, mut any) = (true, false);
            if fi >= 1 && fj >= 1 && fi + 1 < cols && fj + 1 < rows {
                let a = (fj - 1) * cols + fi - 1;
                for m in [a, a + cols, a + 2 * cols] {
                    for c in &class[m..m + 3] {
                        all_std &= *c == INTERIOR;
                        any |= *c != INACTIVE;
                    }
                }
            } else {
                for dy in 0..3 {
                    for dx in 0..3 {
                        let c = at(dx, dy).map_or(INACTIVE, |m| class[m]);
                        all_std &= c == INTERIOR;
                        any |= c != INACTIVE;
                    }
                }
            }
            let k = cj * cc + ci;
            if all_std {
                st[k] = s_std;
                kind[k] = INTERIOR;
                continue;
            }
            // No active fine cell under it: R A P is zero.
            if !any {
                continue;
            }
            let mut a = [[0.0f32; 9]; 9];
            for dy in 0..3 {
                for dx in 0..3 {
                    if let Some(m) = at(dx, dy) {
                        a[dy * 3 + dx] = stencil(m);
                    }
                }
            }
            let s = rap(&a);
            // An inactive coarse cell keeps a zero stencil, as its class says.
            if s[4] > 0.0 {
                st[k] = s;
                kind[k] = EDGE;
            }
        }
    }
    Coarse {
        cols: cc,
        rows: cr,
        st,
        kind,
        interior: s_std,
        par: par && cc * cr >= PAR_CELLS / 4,
        x: vec![0.0; cc * cr],
        b: vec![0.0; cc * cr],
    }
}

/// The first coarse level, from the fine level's five-point operator (the entries to the
/// fixed cells dropped: their values are in the right-hand side).
fn galerkin_fine(f: &Fine, par: bool) -> Coarse {
    let c = f.cols;
    let nb = &f.nb;
    // A free cell whose four neighbours are free has the five-point stencil itself (its
    // four neighbours lie inside the grid, so it counts four).
    let mut class = vec![INACTIVE; nb.len()];
    for (k, cl) in class.iter_mut().enumerate().take(nb.len() - c).skip(c) {
        if nb[k] != 0 {
            *cl = if nb[k - 1] != 0 && nb[k + 1] != 0 && nb[k - c] != 0 && nb[k + c] != 0 {
                INTERIOR
            } else {
                EDGE
            };
        }
    }
    galerkin_with(f.cols, f.rows, 0, par, &class, |a| {
        if nb[a] == 0 {
            return [0.0; 9];
        }
        let e = |b: usize| -((nb[b] != 0) as u8 as f32);
        [
            0.0,
            e(a - c),
            0.0,
            e(a - 1),
            nb[a] as f32,
            e(a + 1),
            0.0,
            e(a + c),
            0.0,
        ]
    })
}

/// The level below coarse level `l` (its index `level`).
fn galerkin_coarse(l: &Coarse, level: usize, par: bool) -> Coarse {
    galerkin_with(l.cols, l.rows, level, par, &l.kind, |a| l.st[a])
}

/// b − A x at coarse cell `k` of a level `c` wide, its centre term left out unless `centre`
/// (a sweep divides what is left by the centre weight).
#[inline(always)]
fn stencil_residual(s: &[f32; 9], x: &[f32], b: f32, k: usize, c: usize, centre: bool) -> f32 {
    let r = b - s[0] * x[k - c - 1] - s[1] * x[k - c] - s[2] * x[k - c + 1] - s[3] * x[k - 1];
    let r = if centre { r - s[4] * x[k] } else { r };
    r - s[5] * x[k + 1] - s[6] * x[k + c - 1] - s[7] * x[k + c] - s[8] * x[k + c + 1]
}

/// One Gauss-Seidel sweep of a coarse level (forward, or `backward`); returns the largest
/// change.
fn gs_coarse(l: &mut Coarse, backward: bool) -> f32 {
    if l.par {
        let order = if backward { [3, 2, 1, 0] } else { [0, 1, 2, 3] };
        return order
            .iter()
            .fold(0.0, |m, &colour| m.max(gs_coarse_colour(l, colour)));
    }
    let c = l.cols;
    let len = l.x.len();
    let (kind, st, b, x, si) = (&l.kind, &l.st, &l.b, &mut l.x, l.interior);
    let inv_si = 1.0 / si[4];
    let mut change = 0.0f32;
    // As in `gs_fine`, the neighbour just updated (stencil entry `p`) is carried in a
    // register and enters last, and the centre weight's inverse does not depend on the
    // heights: the chain from one cell to the next is one multiply-subtract and one
    // multiplication.
    macro_rules! sweep {
        ($range:expr, $p:expr, $prev:expr) => {{
            let mut prev = x[$prev];
            for k in $range {
                let (s, inv) = match kind[k] {
                    INACTIVE => {
                        prev = x[k];
                        continue;
                    }
                    INTERIOR => (&si, inv_si),
                    _ => (&st[k], 1.0 / st[k][4]),
                };
                let mut r = b[k];
                for (o, w) in s.iter().enumerate() {
                    if o != 4 && o != $p {
                        r -= w * x[k + o % 3 + (o / 3) * c - 1 - c];
                    }
                }
                let v = (r - s[$p] * prev) * inv;
                change = change.max((v - x[k]).abs());
                x[k] = v;
                prev = v;
            }
        }};
    }
    if backward {
        sweep!((c + 1..len - c - 1).rev(), 5, len - c - 1);
    } else {
        sweep!(c + 1..len - c - 1, 3, c);
    }
    change
}

/// A quarter of a four-colour sweep of a coarse level: the active cells whose column has the
/// parity `colour % 2` and whose row has the parity `colour / 2`, rows in parallel; returns
/// the largest change.
fn gs_coarse_colour(l: &mut Coarse, colour: usize) -> f32 {
    let (c, kind, st, b, si) = (l.cols, &l.kind, &l.st, &l.b, l.interior);
    colour_pass(&mut l.x, c, |j, above, row, below| {
        if j % 2 != colour / 2 {
            return 0.0;
        }
        let mut change = 0.0f32;
        for i in (1 + (1 + colour) % 2..c - 1).step_by(2) {
            let k = j * c + i;
            let s = match kind[k] {
                INACTIVE => continue,
                INTERIOR => &si,
                _ => &st[k],
            };
            let r = b[k]
                - s[0] * above[i - 1]
                - s[1] * above[i]
                - s[2] * above[i + 1]
                - s[3] * row[i - 1]
                - s[5] * row[i + 1]
                - s[6] * below[i - 1]
                - s[7] * below[i]
                - s[8] * below[i + 1];
            let v = r / s[4];
            change = change.max((v - row[i]).abs());
            row[i] = v;
        }
        change
    })
}

/// Runs `f(j, row)` on every row `j` of `v` (`c` wide), in parallel when `par`; returns the
/// largest of what the calls return.
fn rows_mut<T: Send>(
    v: &mut [T],
    c: usize,
    par: bool,
    f: impl Fn(usize, &mut [T]) -> f32 + Sync,
) -> f32 {
    if par {
        v.par_chunks_mut(c)
            .enumerate()
            .map(|(j, row)| f(j, row))
            .reduce(|| 0.0, f32::max)
    } else {
        v.chunks_mut(c)
            .enumerate()
            .map(|(j, row)| f(j, row))
            .fold(0.0, f32::max)
    }
}

/// `x` (a level `cols` wide) gets P e, e the coarse level's `x`, added (or set, `add` false)
/// at the active cells;
/// returns the largest correction.
fn prolong(
    x: &mut [f32],
    cols: usize,
    active: impl Fn(usize) -> bool + Sync,
    c: &Coarse,
    add: bool,
    par: bool,
) -> f32 {
    let rows = x.len() / cols;
    let cc = c.cols;
    rows_mut(x, cols, par, |j, row| {
        if j == 0 || j + 1 == rows {
            return 0.0;
        }
        let mut m = 0.0f32;
        let (ja, jb) = (j / 2 + 1, j.div_ceil(2) + 1);
        let (ra, rb) = (&c.x[ja * cc..(ja + 1) * cc], &c.x[jb * cc..(jb + 1) * cc]);
        for (i, xa) in row.iter_mut().enumerate().take(cols - 1).skip(1) {
            if !active(j * cols + i) {
                continue;
            }
            let (ia, ib) = (i / 2 + 1, i.div_ceil(2) + 1);
            let e = 0.25 * (ra[ia] + ra[ib] + rb[ia] + rb[ib]);
            m = m.max(e.abs());
            if add {
                *xa += e;
            } else {
                *xa = e;
            }
        }
        m
    })
}

/// R r: the coarse right-hand side from the fine residual `r` (full fine layout).
fn restrict(r: &[f32], cols: usize, rows: usize, c: &mut Coarse) {
    let (cc, cr) = (c.cols, c.rows);
    c.x.fill(0.0);
    let kind = &c.kind;
    rows_mut(&mut c.b, cc, c.par, |cj, b| {
        if cj == 0 || cj + 1 == cr {
            return 0.0;
        }
        for (ci, out) in b.iter_mut().enumerate().take(cc - 1).skip(1) {
            let k = cj * cc + ci;
            if kind[k] == INACTIVE {
                *out = 0.0;
                continue;
            }
            let (fi, fj) = (2 * (ci - 1), 2 * (cj - 1));
            if fi >= 1 && fj >= 1 && fi + 1 < cols && fj + 1 < rows {
                // The 3 × 3 fine cells around the centre, all inside the level.
                let a = (fj - 1) * cols + fi - 1;
                let row = |m: usize| 0.5 * r[m] + r[m + 1] + 0.5 * r[m + 2];
                *out = 0.5 * row(a) + row(a + cols) + 0.5 * row(a + 2 * cols);
                continue;
            }
            let mut s = 0.0f32;
            for dy in 0..3 {
                let Some(aj) = (fj + dy).checked_sub(1).filter(|j| *j < rows) else {
                    continue;
                };
                for dx in 0..3 {
                    let Some(ai) = (fi + dx).checked_sub(1).filter(|i| *i < cols) else {
                        continue;
                    };
                    let w = [0.5, 1.0, 0.5][dx] * [0.5, 1.0, 0.5][dy];
                    s += w * r[aj * cols + ai];
                }
            }
            *out = s;
        }
        0.0
    });
}

/// The residual of the fine level into `out` (zero at every cell but the free ones); with
/// `rhs_only`, the right-hand side alone: the sum of each free cell's fixed neighbours.
fn residual_fine(f: &Fine, rhs_only: bool, out: &mut Vec<f32>) {
    let w = f.cols;
    let x = &f.x;
    out.resize(x.len(), 0.0);
    let rows = f.rows;
    rows_mut(out, w, f.par, |j, row| {
        row.fill(0.0);
        if j == 0 || j + 1 == rows {
            return 0.0;
        }
        let nb = &f.nb[j * w..(j + 1) * w];
        let (up, mid, down) = (
            &x[(j - 1) * w..j * w],
            &x[j * w..(j + 1) * w],
            &x[(j + 1) * w..(j + 2) * w],
        );
        let (nup, ndown) = (&f.nb[(j - 1) * w..j * w], &f.nb[(j + 1) * w..(j + 2) * w]);
        for i in 1..w - 1 {
            let n = nb[i];
            if n == 0 {
                continue;
            }
            row[i] = if rhs_only {
                let g = |free: u8, v: f32| if free != 0 { 0.0 } else { v };
                g(nb[i - 1], mid[i - 1])
                    + g(nb[i + 1], mid[i + 1])
                    + g(nup[i], up[i])
                    + g(ndown[i], down[i])
            } else {
                mid[i - 1] + mid[i + 1] + up[i] + down[i] - n as f32 * mid[i]
            };
        }
        0.0
    });
}

/// The residual b − A x of a coarse level into `out` (zero at inactive cells).
fn residual_coarse(l: &Coarse, out: &mut Vec<f32>) {
    let w = l.cols;
    let (x, si) = (&l.x, &l.interior);
    out.resize(x.len(), 0.0);
    rows_mut(out, w, l.par, |j, row| {
        for (i, o) in row.iter_mut().enumerate() {
            let k = j * w + i;
            *o = match l.kind[k] {
                INACTIVE => 0.0,
                INTERIOR => stencil_residual(si, x, l.b[k], k, w, true),
                _ => stencil_residual(&l.st[k], x, l.b[k], k, w, true),
            };
        }
        0.0
    });
}

/// One V-cycle from the fine level; returns the sum of the largest changes of its steps on
/// the fine level (a bound on the largest change of a cell in the cycle).
fn v_cycle(f: &mut Fine, levels: &mut [Coarse], r: &mut Vec<f32>) -> f32 {
    let mut total = 0.0;
    for _ in 0..SMOOTH {
        total += gs_fine(f, false);
    }
    residual_fine(f, false, r);
    restrict(r, f.cols, f.rows, &mut levels[0]);
    v_coarse(levels, r);
    let nb = &f.nb;
    total += prolong(&mut f.x, f.cols, |a| nb[a] != 0, &levels[0], true, f.par);
    for _ in 0..SMOOTH {
        total += gs_fine(f, true);
    }
    total
}

/// Gauss-Seidel sweeps on the coarsest level until its change falls to 10⁻⁴ of the first,
/// at most [`COARSEST_SWEEPS`].
fn solve_coarsest(l: &mut Coarse) {
    let mut first = None;
    for s in 0..COARSEST_SWEEPS {
        let ch = gs_coarse(l, s % 2 == 1);
        let f0 = *first.get_or_insert(ch);
        if ch <= 1e-4 * f0 || ch == 0.0 {
            break;
        }
    }
}

/// One V-cycle from the first of `levels` (the coarsest is solved by sweeps).
fn v_coarse(levels: &mut [Coarse], r: &mut Vec<f32>) {
    let (this, below) = levels.split_first_mut().unwrap();
    if below.is_empty() {
        solve_coarsest(this);
        return;
    }
    for _ in 0..SMOOTH {
        gs_coarse(this, false);
    }
    residual_coarse(this, r);
    restrict(r, this.cols, this.rows, &mut below[0]);
    v_coarse(below, r);
    prolong_coarse(this, &below[0], true);
    for _ in 0..SMOOTH {
        gs_coarse(this, true);
    }
}

/// [`prolong`] from coarse level `below` to coarse level `this`.
fn prolong_coarse(this: &mut Coarse, below: &Coarse, add: bool) {
    let kind = &this.kind;
    prolong(
        &mut this.x,
        this.cols,
        |a| kind[a] != INACTIVE,
        below,
        add,
        this.par,
    );
}

/// Full multigrid start: the right-hand side restricted to every level, the coarsest solved,
/// and each finer level started from the prolongation of the one below and improved by one
/// V-cycle.
fn fmg(f: &mut Fine, levels: &mut [Coarse], r: &mut Vec<f32>) {
    residual_fine(f, true, r);
    restrict(r, f.cols, f.rows, &mut levels[0]);
    for l in 1..levels.len() {
        let (a, b) = levels.split_at_mut(l);
        let fine = &a[l - 1];
        restrict(&fine.b, fine.cols, fine.rows, &mut b[0]);
    }
    let n = levels.len();
    solve_coarsest(&mut levels[n - 1]);
    for l in (0..n - 1).rev() {
        let (a, b) = levels.split_at_mut(l + 1);
        let this = &mut a[l];
        prolong_coarse(this, &b[0], false);
        v_coarse(&mut levels[l..], r);
    }
    let nb = &f.nb;
    prolong(&mut f.x, f.cols, |a| nb[a] != 0, &levels[0], false, f.par);
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
    fn rap_equals_the_dense_product() {
        let mut rng = SplitMix64::new(5);
        for _ in 0..50 {
            let mut a = [[0.0f32; 9]; 9];
            for v in a.as_flattened_mut() {
                *v = rng.range(-4.0, 4.0) as f32;
            }
            let mut want = [0.0f64; 9];
            for (i, row) in RAP_DENSE.iter().enumerate() {
                for (out, w) in row.iter().enumerate() {
                    want[out] += *w as f64 * a[i / 9][i % 9] as f64;
                }
            }
            let got = rap(&a);
            for o in 0..9 {
                assert!(
                    (got[o] as f64 - want[o]).abs() < 1e-4,
                    "{got:?} vs {want:?}"
                );
            }
        }
        // The interior stencil of the first coarse level: the Galerkin product of the
        // five-point Laplacian with bilinear transfers (rows sum to zero).
        let s = standard(1);
        assert_eq!(s, [-0.25, -0.5, -0.25, -0.5, 3.0, -0.5, -0.25, -0.5, -0.25]);
    }

    /// A void of more than [`PAR_CELLS`] cells (swept in colours, rows in parallel): a plane
    /// comes back within the tolerance, and 1, 2 and 8 threads give the same bits.
    #[test]
    fn large_void_in_colours_is_a_plane_and_the_same_on_any_thread_count() {
        let (cols, rows) = (420, 330);
        let plane = |i: usize, j: usize| 100.0 + 0.3 * i as f64 - 0.2 * j as f64;
        let mut rng = SplitMix64::new(11);
        let z: Vec<f32> = (0..cols * rows)
            .map(|k| {
                let (i, j) = (k % cols, k / cols);
                let rim = i == 0 || j == 0 || i + 1 == cols || j + 1 == rows;
                // The rim and a sparse scatter of known cells, as in a sparse survey.
                if rim || rng.unit() < 0.03 {
                    plane(i, j) as f32
                } else {
                    f32::NAN
                }
            })
            .collect();
        let unknown = z.iter().filter(|v| v.is_nan()).count();
        assert!(unknown > PAR_CELLS);
        let tol = 1e-3;
        let run = |n: usize| {
            let mut out = z.clone();
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
                .install(|| membrane_fill(&mut out, cols, rows, tol));
            out
        };
        let one = run(1);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for n in [2, 8] {
            assert_eq!(bits(&one), bits(&run(n)), "{n} threads");
        }
        let worst = (0..z.len())
            .map(|k| (one[k] as f64 - plane(k % cols, k / cols)).abs())
            .fold(0.0, f64::max);
        assert!(worst < 4.0 * tol as f64, "largest error {worst}");
    }

    #[test]
    fn nothing_known_is_left_alone() {
        let mut z = vec![f32::NAN; 12];
        assert_eq!(membrane_fill(&mut z, 4, 3, 1e-6), 0);
        assert!(z.iter().all(|v| v.is_nan()));
    }
}
