//! Error quadrics (Garland & Heckbert 1997): the sum of squared distances to a set of planes
//! as a symmetric 4 × 4 form, in f64. Used for the quadric-optimal representative of vertex
//! clustering (Lindstrom 2000) and, in later stages, for QEM edge collapse (Garland & Heckbert 1997).
//!
//! The minimiser is found as Lindstrom does: starting from a fallback point x₀ (the cluster
//! centroid), move by the pseudo-inverse of A restricted to its well-conditioned
//! eigendirections. A flat cluster then moves only along its normal, a crease only across
//! it, and a point cluster not at all: never the far-away solution of an ill-conditioned
//! system.

use glam::{DMat3, DVec3};
use std::ops::{Add, AddAssign, Mul, Sub};

/// A quadric error form Q(x) = xᵀAx + 2bᵀx + c.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Quadric {
    /// Upper triangle of A: a11 a12 a13 a22 a23 a33.
    pub a: [f64; 6],
    /// The linear term b.
    pub b: [f64; 3],
    /// The constant c.
    pub c: f64,
}

impl Quadric {
    /// The zero form.
    pub const ZERO: Quadric = Quadric {
        a: [0.0; 6],
        b: [0.0; 3],
        c: 0.0,
    };

    /// `weight` × squared distance to the plane n·x + d = 0 (`n` unit length).
    pub fn plane(n: DVec3, d: f64, weight: f64) -> Quadric {
        let w = weight;
        Quadric {
            a: [
                w * n.x * n.x,
                w * n.x * n.y,
                w * n.x * n.z,
                w * n.y * n.y,
                w * n.y * n.z,
                w * n.z * n.z,
            ],
            b: [w * n.x * d, w * n.y * d, w * n.z * d],
            c: w * d * d,
        }
    }

    /// The plane through triangle (p, q, r), weighted by its area; zero for a degenerate
    /// triangle.
    pub fn triangle(p: DVec3, q: DVec3, r: DVec3) -> Quadric {
        let cross = (q - p).cross(r - p);
        let len = cross.length();
        if len <= 0.0 || !len.is_finite() {
            return Quadric::ZERO;
        }
        let n = cross / len;
        Quadric::plane(n, -n.dot(p), 0.5 * len)
    }

    /// The matrix A.
    pub fn matrix(&self) -> DMat3 {
        let a = &self.a;
        DMat3::from_cols(
            DVec3::new(a[0], a[1], a[2]),
            DVec3::new(a[1], a[3], a[4]),
            DVec3::new(a[2], a[4], a[5]),
        )
    }

    /// The vector b.
    pub fn linear(&self) -> DVec3 {
        DVec3::from_array(self.b)
    }

    /// Q(x): the weighted sum of squared plane distances at `x` (clamped at 0 against
    /// rounding).
    pub fn eval(&self, x: DVec3) -> f64 {
        (x.dot(self.matrix() * x) + 2.0 * self.linear().dot(x) + self.c).max(0.0)
    }

    /// The summed plane weights: the trace of A (for area-weighted triangle planes, the
    /// area they stand for).
    #[inline]
    pub fn weight(&self) -> f64 {
        self.a[0] + self.a[3] + self.a[5]
    }

    /// The point minimising Q(x) + δ‖x − `toward`‖² with δ = `rel` × [`Quadric::weight`]: a
    /// cheap, always well-posed stand-in for [`Quadric::minimizer`] (one 3 × 3 solve, no
    /// eigenvectors) where only the size of the residual matters.
    pub fn regularized_minimizer(&self, toward: DVec3, rel: f64) -> DVec3 {
        let delta = rel * self.weight();
        if delta <= 0.0 || !delta.is_finite() {
            return toward;
        }
        let m = self.matrix() + DMat3::from_diagonal(DVec3::splat(delta));
        let x = m.inverse() * (toward * delta - self.linear());
        if x.is_finite() {
            x
        } else {
            toward
        }
    }

    /// The point minimising Q, found from `fallback` along the eigendirections of A whose
    /// eigenvalue is at least `rel_eps` × the largest (Lindstrom's truncated pseudo-inverse);
    /// `fallback` itself when A vanishes.
    ///
    /// Closed form (a hot spot of clustering: one call per cluster and more): eigenvalues
    /// from the characteristic cubic; then, by how many are kept, a plain 3 × 3 solve (all
    /// three), a step along the top eigenvector (one), or a solve with the dropped direction
    /// removed (two). The eigenvectors needed are those of eigenvalues at least the cut
    /// apart from the others, found as cross products of rows of A − λI; when that is not
    /// reliable (eigenvalues nearly equal at the cut) the Jacobi solution is used.
    pub fn minimizer(&self, fallback: DVec3, rel_eps: f64) -> DVec3 {
        let m = self.matrix();
        let l = sym3_eigenvalues(&m);
        let lmax = l[0].abs().max(l[2].abs());
        if lmax <= 0.0 || !lmax.is_finite() {
            return fallback;
        }
        let cut = rel_eps * lmax;
        // Gradient/2 at the fallback: A x0 + b; the step solves A dx = -(A x0 + b).
        let g = m * fallback + self.linear();
        let kept = l.iter().filter(|&&v| v > cut).count();
        let step = match kept {
            0 => Some(DVec3::ZERO),
            1 => null_vector(&m, l[0]).map(|u| u * (u.dot(g) / l[0])),
            2 => null_vector(&m, l[2]).map(|u| {
                // Replace the dropped eigenvalue by the largest: a well-conditioned matrix
                // whose inverse acts on g's part across u as the pseudo-inverse does.
                let full = m + outer(u, u) * (l[0] - l[2]);
                full.inverse() * (g - u * u.dot(g))
            }),
            _ => Some(m.inverse() * g),
        };
        let Some(step) = step else {
            return self.minimizer_jacobi(fallback, rel_eps);
        };
        let x = fallback - step;
        if x.is_finite() {
            x
        } else {
            fallback
        }
    }

    /// [`Quadric::minimizer`] through a full Jacobi eigendecomposition: the slow, obvious
    /// twin, and the fallback where the closed form is not reliable.
    pub fn minimizer_jacobi(&self, fallback: DVec3, rel_eps: f64) -> DVec3 {
        let m = self.matrix();
        let (vals, vecs) = sym3_eigen(m);
        let lmax = vals.iter().fold(0.0f64, |a, &v| a.max(v.abs()));
        if lmax <= 0.0 || !lmax.is_finite() {
            return fallback;
        }
        let g = m * fallback + self.linear();
        let mut x = fallback;
        for k in 0..3 {
            if vals[k] > rel_eps * lmax {
                let u = vecs[k];
                x -= u * (u.dot(g) / vals[k]);
            }
        }
        if x.is_finite() {
            x
        } else {
            fallback
        }
    }
}

/// u uᵀ.
fn outer(u: DVec3, v: DVec3) -> DMat3 {
    DMat3::from_cols(v * u.x, v * u.y, v * u.z)
}

/// Eigenvalues of a symmetric 3 × 3 matrix, largest first, in closed form (the
/// trigonometric solution of the characteristic cubic; absolute error ~1e-15 × the
/// largest).
pub fn sym3_eigenvalues(m: &DMat3) -> [f64; 3] {
    let (a00, a11, a22) = (m.x_axis.x, m.y_axis.y, m.z_axis.z);
    let (a01, a02, a12) = (m.y_axis.x, m.z_axis.x, m.z_axis.y);
    let p1 = a01 * a01 + a02 * a02 + a12 * a12;
    if p1 == 0.0 {
        let mut d = [a00, a11, a22];
        d.sort_by(|a, b| b.total_cmp(a));
        return d;
    }
    let q = (a00 + a11 + a22) / 3.0;
    let (b00, b11, b22) = (a00 - q, a11 - q, a22 - q);
    let p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1;
    let p = (p2 / 6.0).sqrt();
    // det(B) / 2 with B = (A − qI) / p.
    let det = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
        + a02 * (a01 * a12 - b11 * a02);
    let r = (det / (2.0 * p * p * p)).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let l0 = q + 2.0 * p * phi.cos();
    let l2 = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    [l0, 3.0 * q - l0 - l2, l2]
}

/// A unit vector of the null space of A − λI for an eigenvalue λ of symmetric `m` that is
/// well apart from the others: the largest cross product of two rows. None when every cross
/// product is tiny (λ is (nearly) repeated).
fn null_vector(m: &DMat3, lambda: f64) -> Option<DVec3> {
    let r0 = DVec3::new(m.x_axis.x - lambda, m.y_axis.x, m.z_axis.x);
    let r1 = DVec3::new(m.x_axis.y, m.y_axis.y - lambda, m.z_axis.y);
    let r2 = DVec3::new(m.x_axis.z, m.y_axis.z, m.z_axis.z - lambda);
    let c = [r0.cross(r1), r0.cross(r2), r1.cross(r2)];
    let (best, n2) = c
        .iter()
        .map(|v| (*v, v.length_squared()))
        .fold((DVec3::ZERO, 0.0), |a, b| if b.1 > a.1 { b } else { a });
    let scale = r0
        .length_squared()
        .max(r1.length_squared())
        .max(r2.length_squared());
    // Rows of rank ≤ 1 (a repeated eigenvalue) give cross products at rounding level.
    if n2.is_nan() || n2 <= 1e-16 * scale * scale {
        return None;
    }
    Some(best / n2.sqrt())
}

impl Sub for Quadric {
    type Output = Quadric;
    fn sub(self, o: Quadric) -> Quadric {
        Quadric {
            a: std::array::from_fn(|k| self.a[k] - o.a[k]),
            b: std::array::from_fn(|k| self.b[k] - o.b[k]),
            c: self.c - o.c,
        }
    }
}

impl Add for Quadric {
    type Output = Quadric;
    fn add(mut self, o: Quadric) -> Quadric {
        self += o;
        self
    }
}

impl AddAssign for Quadric {
    fn add_assign(&mut self, o: Quadric) {
        for k in 0..6 {
            self.a[k] += o.a[k];
        }
        for k in 0..3 {
            self.b[k] += o.b[k];
        }
        self.c += o.c;
    }
}

impl Mul<f64> for Quadric {
    type Output = Quadric;
    fn mul(self, s: f64) -> Quadric {
        Quadric {
            a: self.a.map(|v| v * s),
            b: self.b.map(|v| v * s),
            c: self.c * s,
        }
    }
}

/// Eigenvalues and unit eigenvectors of a symmetric 3 × 3 matrix (cyclic Jacobi; exact to
/// rounding for the small, often singular matrices of quadrics).
pub fn sym3_eigen(m: DMat3) -> ([f64; 3], [DVec3; 3]) {
    let mut a = m.to_cols_array_2d();
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _sweep in 0..24 {
        let off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        let diag = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2];
        // Off-diagonal mass below 1e-22 of the diagonal: eigenvalues good to ~1e-11.
        if off <= 1e-22 * diag || off == 0.0 {
            break;
        }
        for (p, q) in [(0usize, 1usize), (0, 2), (1, 2)] {
            let apq = a[p][q];
            if apq == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // Rotate rows/columns p and q.
            for row in a.iter_mut() {
                let (akp, akq) = (row[p], row[q]);
                row[p] = c * akp - s * akq;
                row[q] = s * akp + c * akq;
            }
            let (rp, rq) = (a[p], a[q]);
            for k in 0..3 {
                a[p][k] = c * rp[k] - s * rq[k];
                a[q][k] = s * rp[k] + c * rq[k];
            }
            for row in v.iter_mut() {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let vals = [a[0][0], a[1][1], a[2][2]];
    let vecs = [0, 1, 2].map(|k| DVec3::new(v[0][k], v[1][k], v[2][k]));
    (vals, vecs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eigen_reconstructs_the_matrix() {
        let m = DMat3::from_cols(
            DVec3::new(4.0, 1.0, -2.0),
            DVec3::new(1.0, 3.0, 0.5),
            DVec3::new(-2.0, 0.5, 1.0),
        );
        let (vals, vecs) = sym3_eigen(m);
        for k in 0..3 {
            let r = m * vecs[k] - vecs[k] * vals[k];
            assert!(r.length() < 1e-12, "{r}");
            assert!((vecs[k].length() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn three_planes_meet_at_a_corner() {
        let q = Quadric::plane(DVec3::X, -1.0, 1.0)
            + Quadric::plane(DVec3::Y, -2.0, 1.0)
            + Quadric::plane(DVec3::Z, -3.0, 2.0);
        let x = q.minimizer(DVec3::ZERO, 1e-9);
        assert!((x - DVec3::new(1.0, 2.0, 3.0)).length() < 1e-12);
        assert!(q.eval(x) < 1e-20);
        assert!((q.eval(DVec3::ZERO) - (1.0 + 4.0 + 18.0)).abs() < 1e-12);
    }

    #[test]
    fn closed_form_minimizer_matches_jacobi() {
        // Random quadrics of 1–6 planes: flat, creases, corners, spread normals, with
        // tilts small and large; borderline cases (an eigenvalue near the cut) skipped.
        let mut rng = crate::rng::SplitMix64::new(7);
        let mut u = || rng.unit();
        let mut compared = [0usize; 4];
        for case in 0..20_000 {
            let planes = 1 + case % 6;
            let base = DVec3::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize_or(DVec3::Z);
            let tilt = [1e-4, 1e-2, 0.1, 1.0][case % 4];
            let mut q = Quadric::ZERO;
            for _ in 0..planes {
                let n = (base + DVec3::new(u() - 0.5, u() - 0.5, u() - 0.5) * tilt)
                    .normalize_or(DVec3::X);
                let n = if u() < 0.2 {
                    n.cross(DVec3::Y).normalize_or(n)
                } else {
                    n
                };
                q += Quadric::plane(n, (u() - 0.5) * 10.0, 0.1 + u() * 5.0);
            }
            let x0 = DVec3::new(u(), u(), u()) * 3.0;
            let (vals, _) = sym3_eigen(q.matrix());
            let lmax = vals.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            let cut = 1e-2 * lmax;
            if vals.iter().any(|&v| v > 0.5 * cut && v < 2.0 * cut) {
                continue;
            }
            let fast = q.minimizer(x0, 1e-2);
            let slow = q.minimizer_jacobi(x0, 1e-2);
            let tol = 1e-7 * (1.0 + slow.length());
            assert!(
                (fast - slow).length() < tol,
                "case {case}: {fast} vs {slow} ({vals:?})"
            );
            compared[vals.iter().filter(|&&v| v > cut).count()] += 1;
        }
        // Every rank was exercised.
        assert!(compared[1..].iter().all(|&c| c > 500), "{compared:?}");
    }

    #[test]
    fn closed_form_eigenvalues_match_jacobi() {
        let mut rng = crate::rng::SplitMix64::new(11);
        for _ in 0..5000 {
            let mut a = [0.0f64; 6];
            for v in &mut a {
                *v = rng.unit() - 0.5;
            }
            let m = DMat3::from_cols(
                DVec3::new(a[0], a[1], a[2]),
                DVec3::new(a[1], a[3], a[4]),
                DVec3::new(a[2], a[4], a[5]),
            );
            let mut slow = sym3_eigen(m).0;
            slow.sort_by(|a, b| b.total_cmp(a));
            let fast = sym3_eigenvalues(&m);
            for k in 0..3 {
                assert!((fast[k] - slow[k]).abs() < 1e-12, "{fast:?} {slow:?}");
            }
        }
        assert_eq!(
            sym3_eigenvalues(&DMat3::from_diagonal(DVec3::new(1.0, 3.0, 2.0))),
            [3.0, 2.0, 1.0]
        );
    }

    #[test]
    fn regularized_minimizer_approaches_the_minimiser() {
        let q = Quadric::plane(DVec3::X, -1.0, 1.0)
            + Quadric::plane(DVec3::Y, -2.0, 1.0)
            + Quadric::plane(DVec3::Z, -3.0, 2.0);
        assert_eq!(q.weight(), 4.0);
        let x = q.regularized_minimizer(DVec3::ZERO, 1e-9);
        assert!((x - DVec3::new(1.0, 2.0, 3.0)).length() < 1e-6, "{x}");
        // A flat quadric: the free directions stay at `toward`.
        let flat = Quadric::plane(DVec3::Z, -1.0, 3.0);
        let x = flat.regularized_minimizer(DVec3::new(0.5, 0.25, 0.0), 1e-6);
        assert!((x - DVec3::new(0.5, 0.25, 1.0)).length() < 1e-5, "{x}");
        assert_eq!(
            Quadric::ZERO.regularized_minimizer(DVec3::ONE, 1e-3),
            DVec3::ONE
        );
        let d = (q - Quadric::plane(DVec3::Z, -3.0, 2.0)).weight();
        assert_eq!(d, 2.0);
    }

    #[test]
    fn flat_cluster_moves_only_along_its_normal() {
        let q = Quadric::triangle(
            DVec3::new(0.0, 0.0, 1.0),
            DVec3::new(1.0, 0.0, 1.0),
            DVec3::new(0.0, 1.0, 1.0),
        );
        let x = q.minimizer(DVec3::new(0.3, 0.4, 0.0), 1e-6);
        assert!((x - DVec3::new(0.3, 0.4, 1.0)).length() < 1e-12, "{x}");
        assert_eq!(Quadric::ZERO.minimizer(DVec3::ONE, 1e-6), DVec3::ONE);
    }
}
