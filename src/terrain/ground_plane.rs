//! The last step of the ground classification ([`super::ground`]), which SMRF does not have:
//! ground points that stand above the plane fitted to the ground points around them are
//! objects after all.
//!
//! SMRF's final test compares each point with the provisional DEM, with a tolerance of
//! `threshold` + `scalar` × the DEM's slope: half a metre on flat ground, more on slopes. The
//! DEM is inpainted from cells' lowest returns, so it runs under the ground, and the test is
//! wide: a shrub, a low branch or a hedge point up to a metre above the ground passes it,
//! most of all on slopes (on the ISPRS samples most objects called ground were such points:
//! 682 of samp51's 3,895 object points). Here every ground point is compared with the
//! least-squares plane of the other ground points within `radius` point spacings (the
//! moving-surface idea of the filters compared by Sithole & Vosselman, "Experimental
//! comparison of filter algorithms for bare-Earth extraction from airborne laser scanning
//! point clouds", 2004): a point more than `threshold` + `rms` × (the plane's own RMS
//! misfit) + `slope` × (the plane's slope) × (the point spacing) above it is an object. The
//! misfit and the slope make the test wider where the ground itself is rough or steep, as on
//! a quarry's faces; a second round judges again against the planes of the points that are
//! left, once the highest have gone.
//!
//! The neighbourhood is the square of cells of the classifier's grid around the point's
//! cell (half-width `ceil(radius × spacing / cell)`), and each cell holds the moments of its
//! ground points (count, sums of x, y, z and of their products), so that a plane costs one
//! sum of a few cells' moments and a 2 × 2 solve, whatever the density (no search per
//! point; a NumPy prototype with the 10–14 nearest ground points scored the same on the
//! ISPRS samples). The point's own moments are taken out of the sum, so a point never
//! supports itself.

use rayon::prelude::*;

/// Default radius of the neighbourhood, point spacings (`[ground] plane_radius`).
pub(crate) const DEFAULT_RADIUS: f64 = 2.5;
/// Default height above the plane beyond which a point is an object, metres
/// (`plane_threshold`).
pub(crate) const DEFAULT_THRESHOLD: f64 = 0.25;
/// Default tolerance added per metre of the plane's RMS misfit (`plane_rms`).
pub(crate) const DEFAULT_RMS: f64 = 2.0;
/// Default tolerance added per unit of the plane's slope, in point spacings (`plane_slope`).
pub(crate) const DEFAULT_SLOPE: f64 = 0.15;
/// Default rounds (`plane_rounds`).
pub(crate) const DEFAULT_ROUNDS: usize = 2;
/// Fewest neighbours a plane is fitted to; a point with fewer is not judged.
const MIN_NEIGHBOURS: f64 = 4.0;

/// The test's parameters (see the module notes), radius in point spacings.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PlaneTest {
    pub radius: f64,
    pub threshold: f64,
    pub rms: f64,
    pub slope: f64,
    pub rounds: usize,
}

/// Where the points fall: the classifier's grid (origin and cell in data units) and the
/// conversion of the data's units to metres.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Cells {
    pub cols: usize,
    pub rows: usize,
    pub origin: [f64; 2],
    pub cell: f64,
    pub zref: f64,
    pub mpu: f64,
}

impl Cells {
    #[inline]
    fn of(&self, x: f64, y: f64) -> (usize, usize) {
        let i = (((x - self.origin[0]) / self.cell) as usize).min(self.cols - 1);
        let j = (((y - self.origin[1]) / self.cell) as usize).min(self.rows - 1);
        (i, j)
    }

    /// The point in metres, relative to the grid's origin and `zref`.
    #[inline]
    fn metres(&self, x: f64, y: f64, z: f64) -> [f64; 3] {
        [
            (x - self.origin[0]) * self.mpu,
            (y - self.origin[1]) * self.mpu,
            (z - self.zref) * self.mpu,
        ]
    }
}

/// Moments of a set of points: n, Σx, Σy, Σz, Σxx, Σxy, Σyy, Σxz, Σyz, Σzz.
type Moments = [f64; 10];

#[inline]
fn moments_of([x, y, z]: [f64; 3]) -> Moments {
    [1.0, x, y, z, x * x, x * y, y * y, x * z, y * z, z * z]
}

#[inline]
fn add(a: &mut Moments, b: &Moments) {
    for (a, b) in a.iter_mut().zip(b) {
        *a += b;
    }
}

/// Height of `p` above the least-squares plane z = a + b x + c y of the points whose moments
/// are `m`, and the test's tolerance there; None when the points are too few or (nearly) on
/// a line.
#[inline]
fn height_above(m: &Moments, p: [f64; 3], t: &PlaneTest, spacing_m: f64) -> Option<(f64, f64)> {
    let n = m[0];
    if n < MIN_NEIGHBOURS {
        return None;
    }
    let r = 1.0 / n;
    let (mx, my, mz) = (m[1] * r, m[2] * r, m[3] * r);
    let cxx = m[4] * r - mx * mx;
    let cxy = m[5] * r - mx * my;
    let cyy = m[6] * r - my * my;
    let cxz = m[7] * r - mx * mz;
    let cyz = m[8] * r - my * mz;
    let czz = m[9] * r - mz * mz;
    let det = cxx * cyy - cxy * cxy;
    let scale = cxx + cyy;
    if det.is_nan() || det <= 1e-6 * scale * scale {
        return None;
    }
    let rd = 1.0 / det;
    let a = (cxz * cyy - cyz * cxy) * rd;
    let b = (cyz * cxx - cxz * cxy) * rd;
    let rms = (czz - a * cxz - b * cyz).max(0.0).sqrt();
    let h = p[2] - (mz + a * (p[0] - mx) + b * (p[1] - my));
    // Not `hypot`: libm's careful version was a twentieth of the whole run on autzen_full.
    let tol = t.threshold + t.rms * rms + t.slope * (a * a + b * b).sqrt() * spacing_m;
    Some((h, tol))
}

/// Turns into objects the ground points that stand above the plane of their ground
/// neighbours (see the module notes); `keep` as in `classify`. Returns the points turned.
/// Per round: the ground points bucketed by grid row (in index order), the moments of each
/// cell summed row by row in parallel (each row's cells by one task, in point order: the
/// same bits for any thread count), then every point judged against the moments of the
/// rounds' start.
#[allow(clippy::too_many_arguments)]
pub(crate) fn drop_above_plane(
    x: &[f64],
    y: &[f64],
    z: &[f64],
    ground: &mut [bool],
    cells: &Cells,
    spacing_m: f64,
    cell_m: f64,
    t: &PlaneTest,
) -> usize {
    let (cols, rows) = (cells.cols, cells.rows);
    let half = ((t.radius * spacing_m / cell_m).ceil() as usize).max(1);
    // Ground points by row of the grid (a counting sort, stable: index order in each row).
    let row_of: Vec<u32> = (0..x.len())
        .into_par_iter()
        .map(|p| {
            if ground[p] {
                cells.of(x[p], y[p]).1 as u32
            } else {
                u32::MAX
            }
        })
        .collect();
    let mut start = vec![0usize; rows + 1];
    for &r in &row_of {
        if r != u32::MAX {
            start[r as usize + 1] += 1;
        }
    }
    for j in 0..rows {
        start[j + 1] += start[j];
    }
    let mut order = vec![0u32; start[rows]];
    let mut next = start.clone();
    for (p, &r) in row_of.iter().enumerate() {
        if r != u32::MAX {
            order[next[r as usize]] = p as u32;
            next[r as usize] += 1;
        }
    }
    drop((row_of, next));
    // The column of each point of `order`.
    let col_of: Vec<u32> = order
        .par_iter()
        .map(|&p| cells.of(x[p as usize], y[p as usize]).0 as u32)
        .collect();
    // The cells that hold a ground point are the only ones with moments: numbered row by
    // row (`slot`: the number within the row, u32::MAX for the others; `base`: the row's
    // first; `cell_col`: the column of each), so that the moments take a few bytes per point,
    // not 80 per cell of the grid.
    let mut slot = vec![u32::MAX; cols * rows];
    let by_row: Vec<Vec<u32>> = slot
        .par_chunks_mut(cols)
        .enumerate()
        .map(|(j, row)| {
            let mut list = Vec::new();
            for &i in &col_of[start[j]..start[j + 1]] {
                if row[i as usize] == u32::MAX {
                    row[i as usize] = list.len() as u32;
                    list.push(i);
                }
            }
            list
        })
        .collect();
    let counts: Vec<usize> = by_row.iter().map(Vec::len).collect();
    let mut base = vec![0usize; rows + 1];
    for j in 0..rows {
        base[j + 1] = base[j] + counts[j];
    }
    let cell_col = by_row.concat();
    drop(by_row);
    let mut moments: Vec<Moments> = vec![[0.0; 10]; base[rows]];
    let mut total = 0;
    for _ in 0..t.rounds {
        // The moments of the ground points left.
        let mut rest = &mut moments[..];
        let mut by_row = Vec::with_capacity(rows);
        for &n in &counts {
            let (head, tail) = rest.split_at_mut(n);
            by_row.push(head);
            rest = tail;
        }
        by_row.into_par_iter().enumerate().for_each(|(j, row)| {
            row.iter_mut().for_each(|m| *m = [0.0; 10]);
            let span = start[j]..start[j + 1];
            for (&p, &i) in order[span.clone()].iter().zip(&col_of[span]) {
                let p = p as usize;
                if ground[p] {
                    let k = slot[j * cols + i as usize] as usize;
                    add(&mut row[k], &moments_of(cells.metres(x[p], y[p], z[p])));
                }
            }
        });
        let window = Window {
            moments: &moments,
            cell_col: &cell_col,
            base: &base,
            rows,
            half,
        };
        let gone: Vec<u32> = (0..rows)
            .into_par_iter()
            .map_init(
                || WindowScratch::new(cols),
                |scratch, j| {
                    let mut out = Vec::new();
                    let span = start[j]..start[j + 1];
                    let (points, at) = (&order[span.clone()], &col_of[span]);
                    if !points.iter().any(|&p| ground[p as usize]) {
                        return out;
                    }
                    let win = window.sums(j, points, at, ground, scratch);
                    for (&p, &i) in points.iter().zip(at) {
                        let p = p as usize;
                        if !ground[p] {
                            continue;
                        }
                        let q = cells.metres(x[p], y[p], z[p]);
                        let mut m = win[i as usize];
                        for (a, b) in m.iter_mut().zip(moments_of(q)) {
                            *a -= b;
                        }
                        if height_above(&m, q, t, spacing_m).is_some_and(|(h, tol)| h > tol) {
                            out.push(p as u32);
                        }
                    }
                    out
                },
            )
            .flatten_iter()
            .collect();
        if gone.is_empty() {
            break;
        }
        total += gone.len();
        for p in gone {
            ground[p as usize] = false;
        }
    }
    total
}

/// The moments of one round and the square neighbourhood of half-width `half` cells.
struct Window<'a> {
    /// The moments of the cells that hold ground points, row by row …
    moments: &'a [Moments],
    /// … their columns …
    cell_col: &'a [u32],
    /// … and where each row's start (one more entry than rows).
    base: &'a [usize],
    rows: usize,
    half: usize,
}

/// Per-worker buffers of [`Window::sums`].
struct WindowScratch {
    /// Column sums over the window's rows (all zero between calls).
    col: Vec<Moments>,
    /// Window sums at the cells that hold a ground point of the row.
    win: Vec<Moments>,
    /// The columns whose window sum is done.
    done: Vec<bool>,
}

impl WindowScratch {
    fn new(cols: usize) -> WindowScratch {
        WindowScratch {
            col: vec![[0.0; 10]; cols],
            win: vec![[0.0; 10]; cols],
            done: vec![false; cols],
        }
    }
}

impl Window<'_> {
    /// The window sums of row `j` (the cells of rows j − half ..= j + half summed by column,
    /// then the columns i − half ..= i + half of those; once per cell, not per point; no
    /// running sum, whose subtractions would drift), at the cells `at` of the row's ground
    /// points only. The column sums visit only the cells that hold ground points, each
    /// row's in turn (so each column's in row order): the others' moments are zero and all
    /// the moments are ≥ 0 (coordinates from the grid's origin and `zref`, the bounds'
    /// minimum), so adding them would change no bit: the sums are the same bits as over
    /// every cell in the same order. Other entries of the returned row are stale.
    fn sums<'s>(
        &self,
        j: usize,
        points: &[u32],
        at: &[u32],
        ground: &[bool],
        s: &'s mut WindowScratch,
    ) -> &'s [Moments] {
        let (cols, half) = (s.col.len(), self.half);
        let (j0, j1) = (j.saturating_sub(half), (j + half).min(self.rows - 1));
        let cells = self.base[j0]..self.base[j1 + 1];
        for (&c, m) in self.cell_col[cells.clone()]
            .iter()
            .zip(&self.moments[cells.clone()])
        {
            add(&mut s.col[c as usize], m);
        }
        for (&p, &i) in points.iter().zip(at) {
            let i = i as usize;
            if !ground[p as usize] || s.done[i] {
                continue;
            }
            s.done[i] = true;
            let mut w = [0.0; 10];
            for c in &s.col[i.saturating_sub(half)..=(i + half).min(cols - 1)] {
                add(&mut w, c);
            }
            s.win[i] = w;
        }
        for &i in at {
            s.done[i as usize] = false;
        }
        for &c in &self.cell_col[cells] {
            s.col[c as usize] = [0.0; 10];
        }
        &s.win
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    const T: PlaneTest = PlaneTest {
        radius: DEFAULT_RADIUS,
        threshold: DEFAULT_THRESHOLD,
        rms: DEFAULT_RMS,
        slope: DEFAULT_SLOPE,
        rounds: DEFAULT_ROUNDS,
    };

    /// The slow twin of the plane: a direct least-squares fit (normal equations of z = a +
    /// b x + c y solved by Cramer's rule) of the listed points.
    fn height_slow(pts: &[[f64; 3]], p: [f64; 3]) -> f64 {
        let mut a = [[0.0f64; 3]; 3];
        let mut r = [0.0f64; 3];
        for q in pts {
            let v = [1.0, q[0], q[1]];
            for i in 0..3 {
                for j in 0..3 {
                    a[i][j] += v[i] * v[j];
                }
                r[i] += v[i] * q[2];
            }
        }
        let det3 = |m: [[f64; 3]; 3]| {
            m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
                - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
                + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
        };
        let d = det3(a);
        let c: Vec<f64> = (0..3)
            .map(|k| {
                let mut m = a;
                for i in 0..3 {
                    m[i][k] = r[i];
                }
                det3(m) / d
            })
            .collect();
        p[2] - (c[0] + c[1] * p[0] + c[2] * p[1])
    }

    #[test]
    fn plane_height_equals_the_direct_fit() {
        let mut rng = SplitMix64::new(3);
        for _ in 0..50 {
            let pts: Vec<[f64; 3]> = (0..12)
                .map(|_| {
                    let (x, y) = (rng.range(100.0, 104.0), rng.range(50.0, 54.0));
                    [x, y, 3.0 + 0.4 * x - 0.2 * y + rng.range(-0.3, 0.3)]
                })
                .collect();
            let mut m = [0.0; 10];
            for q in &pts {
                for (a, b) in m.iter_mut().zip(moments_of(*q)) {
                    *a += b;
                }
            }
            let p = [102.0, 52.0, 40.0];
            let (h, _) = height_above(&m, p, &T, 1.0).unwrap();
            assert!((h - height_slow(&pts, p)).abs() < 1e-6, "{h}");
        }
    }

    /// On a noisy sloping plane, one point 1.5 m up (a shrub) is dropped; the ground stays.
    #[test]
    fn a_shrub_on_a_slope_goes_the_ground_stays() {
        let mut rng = SplitMix64::new(9);
        let (mut x, mut y, mut z) = (vec![], vec![], vec![]);
        for _ in 0..4000 {
            let (px, py) = (rng.range(0.0, 60.0), rng.range(0.0, 60.0));
            x.push(px);
            y.push(py);
            z.push(10.0 + 0.3 * px + 0.1 * py + rng.range(-0.05, 0.05));
        }
        x.push(30.0);
        y.push(30.0);
        z.push(10.0 + 0.3 * 30.0 + 0.1 * 30.0 + 1.5);
        let mut ground = vec![true; x.len()];
        let cells = Cells {
            cols: 60,
            rows: 60,
            origin: [0.0, 0.0],
            cell: 1.0,
            zref: 0.0,
            mpu: 1.0,
        };
        let spacing = (3600.0f64 / 4001.0).sqrt();
        let n = drop_above_plane(&x, &y, &z, &mut ground, &cells, spacing, 1.0, &T);
        assert_eq!(n, 1);
        assert!(!ground[4000]);
    }
}
