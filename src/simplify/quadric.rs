//! Error quadrics (Garland & Heckbert 1997): the sum of squared distances to a set of planes
//! as a symmetric 4 × 4 form, in f64. Used for the quadric-optimal representative of vertex
//! clustering (Lindstrom 2000) and, in later stages, for QEM edge collapse (SPEC §9).
//!
//! The minimiser is found as Lindstrom does: starting from a fallback point x₀ (the cluster
//! centroid), move by the pseudo-inverse of A restricted to its well-conditioned
//! eigendirections. A flat cluster then moves only along its normal, a crease only across
//! it, and a point cluster not at all: never the far-away solution of an ill-conditioned
//! system.

use glam::{DMat3, DVec3};
use std::ops::{Add, AddAssign, Mul};

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

    /// The point minimising Q, found from `fallback` along the eigendirections of A whose
    /// eigenvalue is at least `rel_eps` × the largest (Lindstrom's truncated pseudo-inverse);
    /// `fallback` itself when A vanishes.
    pub fn minimizer(&self, fallback: DVec3, rel_eps: f64) -> DVec3 {
        let m = self.matrix();
        let (vals, vecs) = sym3_eigen(m);
        let lmax = vals.iter().fold(0.0f64, |a, &v| a.max(v.abs()));
        if lmax <= 0.0 || !lmax.is_finite() {
            return fallback;
        }
        // Gradient/2 at the fallback: A x0 + b; the step solves A dx = -(A x0 + b).
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
