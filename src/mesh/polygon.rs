//! Polygon triangulation by ear clipping in the polygon's Newell plane (Newell's normal is
//! robust for non-planar and concave polygons, where the first corner's cross product is
//! not). Triangles keep the polygon's orientation. Degenerate polygons (collinear corners,
//! self-intersections) still produce n − 2 triangles: when no ear exists, the most convex
//! corner is clipped, so no face is ever silently dropped.

use glam::{DVec2, DVec3, Vec3};

/// Reusable scratch space for [`Triangulator::triangulate`] (no allocation per polygon once
/// warmed up).
#[derive(Debug, Default)]
pub struct Triangulator {
    flat: Vec<DVec2>,
    ring: Vec<usize>,
}

/// Newell's normal of a polygon (not normalised; zero for a degenerate polygon).
pub fn newell_normal(positions: &[Vec3], poly: &[u32]) -> DVec3 {
    let mut n = DVec3::ZERO;
    for (k, &a) in poly.iter().enumerate() {
        let p = positions[a as usize].as_dvec3();
        let q = positions[poly[(k + 1) % poly.len()] as usize].as_dvec3();
        n.x += (p.y - q.y) * (p.z + q.z);
        n.y += (p.z - q.z) * (p.x + q.x);
        n.z += (p.x - q.x) * (p.y + q.y);
    }
    n
}

#[inline]
fn cross2(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

impl Triangulator {
    /// Appends the triangles of polygon `poly` (indices into `positions`, at least 3) to
    /// `out`: `poly.len() - 2` of them.
    pub fn triangulate(&mut self, positions: &[Vec3], poly: &[u32], out: &mut Vec<[u32; 3]>) {
        let n = poly.len();
        if n < 3 {
            return;
        }
        if n == 3 {
            out.push([poly[0], poly[1], poly[2]]);
            return;
        }
        let normal = newell_normal(positions, poly);
        if normal.length_squared() == 0.0 || !normal.is_finite() {
            // No plane: a fan keeps the face count and the corner order.
            for k in 1..n - 1 {
                out.push([poly[0], poly[k], poly[k + 1]]);
            }
            return;
        }
        let w = normal.normalize();
        let u = w.any_orthonormal_vector();
        let v = w.cross(u);
        self.flat.clear();
        self.flat.extend(poly.iter().map(|&i| {
            let p = positions[i as usize].as_dvec3();
            DVec2::new(p.dot(u), p.dot(v))
        }));
        self.ring.clear();
        self.ring.extend(0..n);
        // Scale for the convexity tolerance: relative to the polygon's size.
        let extent = self
            .flat
            .iter()
            .fold(0.0f64, |m, p| m.max(p.x.abs()).max(p.y.abs()));
        let eps = 1e-12 * extent * extent;
        while self.ring.len() > 3 {
            let m = self.ring.len();
            let mut best: Option<(usize, f64)> = None;
            let mut ear = None;
            for k in 0..m {
                let (ia, ib, ic) = (
                    self.ring[(k + m - 1) % m],
                    self.ring[k],
                    self.ring[(k + 1) % m],
                );
                let (a, b, c) = (self.flat[ia], self.flat[ib], self.flat[ic]);
                let turn = cross2(b - a, c - b);
                if best.is_none_or(|(_, t)| turn > t) {
                    best = Some((k, turn));
                }
                if turn <= eps {
                    continue;
                }
                let blocked = self.ring.iter().any(|&j| {
                    if j == ia || j == ib || j == ic {
                        return false;
                    }
                    let p = self.flat[j];
                    if p == a || p == b || p == c {
                        return false;
                    }
                    cross2(b - a, p - a) >= 0.0
                        && cross2(c - b, p - b) >= 0.0
                        && cross2(a - c, p - c) >= 0.0
                });
                if !blocked {
                    ear = Some(k);
                    break;
                }
            }
            let k = ear.unwrap_or_else(|| best.map_or(0, |(k, _)| k));
            let m = self.ring.len();
            let (ia, ib, ic) = (
                self.ring[(k + m - 1) % m],
                self.ring[k],
                self.ring[(k + 1) % m],
            );
            out.push([poly[ia], poly[ib], poly[ic]]);
            self.ring.remove(k);
        }
        out.push([poly[self.ring[0]], poly[self.ring[1]], poly[self.ring[2]]]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(p: &[Vec3], tris: &[[u32; 3]]) -> f64 {
        tris.iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| p[i as usize].as_dvec3());
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }

    #[test]
    fn concave_polygon_is_covered_exactly() {
        // An L shape of area 3, tilted out of the xy plane.
        let flat = [(0., 0.), (2., 0.), (2., 1.), (1., 1.), (1., 2.), (0., 2.)];
        let p: Vec<Vec3> = flat
            .iter()
            .map(|&(x, y)| Vec3::new(x, y * 0.6, y * 0.8))
            .collect();
        let poly: Vec<u32> = (0..6).collect();
        let mut out = Vec::new();
        Triangulator::default().triangulate(&p, &poly, &mut out);
        assert_eq!(out.len(), 4);
        assert!((area(&p, &out) - 3.0).abs() < 1e-6);
        // Orientation kept: every triangle's normal agrees with the polygon's.
        let n = newell_normal(&p, &poly);
        for t in &out {
            let [a, b, c] = t.map(|i| p[i as usize].as_dvec3());
            assert!((b - a).cross(c - a).dot(n) > 0.0);
        }
    }

    #[test]
    fn collinear_polygon_still_gives_n_minus_2() {
        let p: Vec<Vec3> = (0..5).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
        let mut out = Vec::new();
        Triangulator::default().triangulate(&p, &[0, 1, 2, 3, 4], &mut out);
        assert_eq!(out.len(), 3);
    }

    #[test]
    fn quad_gives_two_triangles_with_all_corners() {
        let p = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let mut out = Vec::new();
        Triangulator::default().triangulate(&p, &[0, 1, 2, 3], &mut out);
        assert_eq!(out.len(), 2);
        assert!((area(&p, &out) - 1.0).abs() < 1e-9);
    }
}
