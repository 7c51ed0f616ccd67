//! How far a tile's lattice triangulation lies from the grid's own bilinear surface.
//!
//! A Cesium tile's vertices sit on a regular longitude/latitude lattice whose heights are the
//! grid's bilinear heights at the lattice points (see `tms`). Between them the tile's finest
//! triangulation L (each lattice square split by the diagonal through its 2 × 2 block's
//! centre, the extractor's finest fans) is linear, while the grid's bilinear surface G bends
//! along the grid's cells: at a wall the lattice, turned against the grid and not passing
//! through its samples, cuts corners. [`square_errors`] gives, per lattice square, the exact
//! largest |L − G| over its closed area (up to the projection's curvature over a tile, a
//! fraction of a millimetre on the tiles it is used for).
//!
//! Why it is exact: in grid coordinates a lattice triangle is a triangle (the projection is
//! affine to well under a millimetre over a tile) and on each grid cell L − G is linear minus
//! bilinear, a + b·x + c·y + d·x·y, whose second derivatives in x and in y vanish: it is
//! harmonic, so its extremes over (triangle ∩ cell) lie on that piece's boundary. The
//! boundary is made of grid-line segments, on which G is linear (so L − G is linear: extremes
//! at their ends, which are grid nodes or crossings with the triangle's edges), and of pieces
//! of the triangle's edges, on which L − G is quadratic (extremes at the piece's ends or at
//! its vertex). So the maximum is taken over the grid nodes inside the square and, along each
//! lattice edge, its crossings with grid lines and each piece's vertex. Hand-written: no
//! crate bounds a piecewise-linear surface against a bilinear grid.

/// The lattice of one tile: `(n + 1)²` points, row-major from the south-west, each a position
/// in fractional grid coordinates and its height (the grid's bilinear height there).
pub struct Lattice<'a> {
    /// Intervals per side.
    pub n: usize,
    /// Grid coordinates (column, row) of lattice point (i, j) at `j * (n + 1) + i`.
    pub at: &'a [[f64; 2]],
    /// Heights of the lattice points, same order.
    pub h: &'a [f64],
}

/// Whether lattice square (i, j) is split by the diagonal (i, j)–(i + 1, j + 1) (else by
/// (i + 1, j)–(i, j + 1)): the diagonal through the centre of its 2 × 2 block, the corner with
/// odd coordinates.
#[inline]
pub fn main_diagonal(i: usize, j: usize) -> bool {
    (i % 2 == 1) == (j % 2 == 1)
}

/// Height of the lattice square (i, j)'s triangulation at fractions (fu, fv) of the square,
/// from its corner heights h00, h10, h01, h11.
#[inline]
pub fn square_height(
    i: usize,
    j: usize,
    [fu, fv]: [f64; 2],
    [h00, h10, h01, h11]: [f64; 4],
) -> f64 {
    if main_diagonal(i, j) {
        if fu >= fv {
            h00 + fu * (h10 - h00) + fv * (h11 - h10)
        } else {
            h00 + fv * (h01 - h00) + fu * (h11 - h01)
        }
    } else if fu + fv <= 1.0 {
        h00 + fu * (h10 - h00) + fv * (h01 - h00)
    } else {
        h11 + (1.0 - fu) * (h01 - h11) + (1.0 - fv) * (h10 - h11)
    }
}

/// Largest |L − G| along the lattice edge from `p0` (height `h0`) to `p1` (height `h1`), G
/// being `grid` (the bilinear surface, continuous, bilinear on each unit cell), and the
/// fraction of the edge where it is taken. `cuts` is scratch space.
pub(crate) fn edge_error(
    p0: [f64; 2],
    p1: [f64; 2],
    h0: f64,
    h1: f64,
    grid: &impl Fn([f64; 2]) -> f64,
    cuts: &mut Vec<f64>,
) -> (f64, f64) {
    cuts.clear();
    cuts.push(0.0);
    for k in 0..2 {
        let (a, b) = (p0[k], p1[k]);
        if a != b {
            // Integer lines strictly between a and b.
            let (lo, hi) = (a.min(b), a.max(b));
            let mut c = lo.floor() + 1.0;
            while c < hi {
                cuts.push((c - a) / (b - a));
                c += 1.0;
            }
        }
    }
    cuts.push(1.0);
    cuts.sort_unstable_by(f64::total_cmp);
    let e = |t: f64| {
        let p = [p0[0] + t * (p1[0] - p0[0]), p0[1] + t * (p1[1] - p0[1])];
        h0 + t * (h1 - h0) - grid(p)
    };
    let mut worst = (0.0f64, 0.0f64);
    let mut take = |err: f64, t: f64| {
        if err.abs() > worst.0 {
            worst = (err.abs(), t);
        }
    };
    let mut ea = e(cuts[0]);
    take(ea, cuts[0]);
    for w in cuts.windows(2) {
        let (ta, tb) = (w[0], w[1]);
        let eb = e(tb);
        take(eb, tb);
        if tb > ta {
            // On (ta, tb) e is a quadratic q(s) = em + beta·s + alpha·s², s ∈ [−1, 1].
            let tm = 0.5 * (ta + tb);
            let em = e(tm);
            let beta = 0.5 * (eb - ea);
            let alpha = 0.5 * (ea + eb) - em;
            take(em, tm);
            if alpha != 0.0 {
                let s = -beta / (2.0 * alpha);
                if s.abs() < 1.0 {
                    take(em - beta * beta / (4.0 * alpha), tm + s * 0.5 * (tb - ta));
                }
            }
        }
        ea = eb;
    }
    worst
}

/// Per lattice square (i, j), at `j * n + i`, the largest |L − G| over its closed area, G
/// given by `grid` (fractional grid coordinates → height, bilinear on unit cells, continuous).
pub fn square_errors(lat: &Lattice<'_>, grid: impl Fn([f64; 2]) -> f64) -> Vec<f32> {
    let n = lat.n;
    let w = n + 1;
    let mut out = vec![0.0f64; n * n];
    let mut cuts = Vec::new();
    let bump = |out: &mut [f64], i: isize, j: isize, e: f64| {
        if (0..n as isize).contains(&i) && (0..n as isize).contains(&j) {
            let s = &mut out[j as usize * n + i as usize];
            *s = s.max(e);
        }
    };
    let edge = |a: (usize, usize), b: (usize, usize), cuts: &mut Vec<f64>| {
        let (ka, kb) = (a.1 * w + a.0, b.1 * w + b.0);
        edge_error(lat.at[ka], lat.at[kb], lat.h[ka], lat.h[kb], &grid, cuts).0
    };
    for j in 0..=n {
        for i in 0..=n {
            let (ii, jj) = (i as isize, j as isize);
            if i < n {
                // East edge: the squares below and above it.
                let e = edge((i, j), (i + 1, j), &mut cuts);
                bump(&mut out, ii, jj - 1, e);
                bump(&mut out, ii, jj, e);
            }
            if j < n {
                // North edge: the squares left and right of it.
                let e = edge((i, j), (i, j + 1), &mut cuts);
                bump(&mut out, ii - 1, jj, e);
                bump(&mut out, ii, jj, e);
            }
            if i < n && j < n {
                let e = if main_diagonal(i, j) {
                    edge((i, j), (i + 1, j + 1), &mut cuts)
                } else {
                    edge((i + 1, j), (i, j + 1), &mut cuts)
                };
                bump(&mut out, ii, jj, e);
            }
        }
    }
    // Grid nodes inside the tile: located through the tile's affine map (lattice → grid,
    // from its corners), their square's triangulation against the node's height.
    let p00 = lat.at[0];
    let ex = [
        (lat.at[n][0] - p00[0]) / n as f64,
        (lat.at[n][1] - p00[1]) / n as f64,
    ];
    let ey = [
        (lat.at[n * w][0] - p00[0]) / n as f64,
        (lat.at[n * w][1] - p00[1]) / n as f64,
    ];
    let det = ex[0] * ey[1] - ex[1] * ey[0];
    if det != 0.0 {
        let corners = [lat.at[0], lat.at[n], lat.at[n * w], lat.at[n * w + n]];
        let lo = |k: usize| corners.iter().map(|c| c[k]).fold(f64::INFINITY, f64::min);
        let hi = |k: usize| {
            corners
                .iter()
                .map(|c| c[k])
                .fold(f64::NEG_INFINITY, f64::max)
        };
        let (x0, x1) = (lo(0).ceil() as i64, hi(0).floor() as i64);
        let (y0, y1) = (lo(1).ceil() as i64, hi(1).floor() as i64);
        for b in y0..=y1 {
            for a in x0..=x1 {
                let (dx, dy) = (a as f64 - p00[0], b as f64 - p00[1]);
                let u = (dx * ey[1] - dy * ey[0]) / det;
                let v = (ex[0] * dy - ex[1] * dx) / det;
                if !(0.0..=n as f64).contains(&u) || !(0.0..=n as f64).contains(&v) {
                    continue;
                }
                let (i, j) = ((u as usize).min(n - 1), (v as usize).min(n - 1));
                let h = |di: usize, dj: usize| lat.h[(j + dj) * w + i + di];
                let l = square_height(
                    i,
                    j,
                    [u - i as f64, v - j as f64],
                    [h(0, 0), h(1, 0), h(0, 1), h(1, 1)],
                );
                let e = (l - grid([a as f64, b as f64])).abs();
                bump(&mut out, i as isize, j as isize, e);
            }
        }
    }
    out.into_iter().map(|e| e as f32).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid of unit cells with one high sample (a pyramid of bilinear cells).
    fn spike(p: [f64; 2]) -> f64 {
        let h = |i: i64, j: i64| if (i, j) == (5, 5) { 4.0 } else { 0.0 };
        let (i0, j0) = (p[0].floor() as i64, p[1].floor() as i64);
        let (di, dj) = (p[0] - i0 as f64, p[1] - j0 as f64);
        (h(i0, j0) * (1.0 - di) + h(i0 + 1, j0) * di) * (1.0 - dj)
            + (h(i0, j0 + 1) * (1.0 - di) + h(i0 + 1, j0 + 1) * di) * dj
    }

    /// The slow, obvious twin: the worst |L − G| over a dense sampling of each square.
    fn sampled(lat: &Lattice<'_>, grid: impl Fn([f64; 2]) -> f64, k: usize) -> Vec<f64> {
        let n = lat.n;
        let w = n + 1;
        let mut out = vec![0.0; n * n];
        for j in 0..n {
            for i in 0..n {
                let h = |di: usize, dj: usize| lat.h[(j + dj) * w + i + di];
                let p = |di: usize, dj: usize| lat.at[(j + dj) * w + i + di];
                for b in 0..=k {
                    for a in 0..=k {
                        let (fu, fv) = (a as f64 / k as f64, b as f64 / k as f64);
                        let l = square_height(i, j, [fu, fv], [h(0, 0), h(1, 0), h(0, 1), h(1, 1)]);
                        let q = |c: usize| {
                            (p(0, 0)[c] * (1.0 - fu) + p(1, 0)[c] * fu) * (1.0 - fv)
                                + (p(0, 1)[c] * (1.0 - fu) + p(1, 1)[c] * fu) * fv
                        };
                        let e = (l - grid([q(0), q(1)])).abs();
                        out[j * n + i] = f64::max(out[j * n + i], e);
                    }
                }
            }
        }
        out
    }

    #[test]
    fn matches_dense_sampling_on_a_turned_lattice() {
        // A lattice of 0.7 cells turned by 0.3 rad over the spike.
        let n = 16;
        let (c, s) = (0.3f64.cos(), 0.3f64.sin());
        let at: Vec<[f64; 2]> = (0..=n)
            .flat_map(|j| {
                (0..=n).map(move |i| {
                    let (u, v) = (0.7 * i as f64, 0.7 * j as f64);
                    [1.3 + c * u - s * v, 0.4 + s * u + c * v]
                })
            })
            .collect();
        let h: Vec<f64> = at.iter().map(|&p| spike(p)).collect();
        let lat = Lattice { n, at: &at, h: &h };
        let exact = square_errors(&lat, spike);
        let dense = sampled(&lat, spike, 200);
        let mut worst = 0.0f64;
        for (e, d) in exact.iter().zip(&dense) {
            // Exact is the supremum: never below the samples, and they come within the
            // sampling's resolution of it.
            assert!(f64::from(*e) >= d - 1e-6, "{e} < {d}");
            assert!(f64::from(*e) <= d + 0.05, "{e} > {d}");
            worst = worst.max(f64::from(*e));
        }
        assert!(worst > 0.5, "the spike is missed by the lattice: {worst}");
    }

    #[test]
    fn a_plane_is_resampled_exactly() {
        let n = 8;
        let at: Vec<[f64; 2]> = (0..=n)
            .flat_map(|j| (0..=n).map(move |i| [0.37 * i as f64 + 0.1, 0.61 * j as f64]))
            .collect();
        let plane = |p: [f64; 2]| 2.0 + 0.5 * p[0] - 0.25 * p[1];
        let h: Vec<f64> = at.iter().map(|&p| plane(p)).collect();
        let e = square_errors(&Lattice { n, at: &at, h: &h }, plane);
        assert!(e.iter().all(|&v| v < 1e-9), "{e:?}");
    }
}
