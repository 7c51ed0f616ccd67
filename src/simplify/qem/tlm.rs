//! Fold-free placement by two local mappings (Liu, Geng & Zhou 2004): the new vertex of an
//! edge collapse is found in a plane onto which the edge's neighbourhood projects one to
//! one, and mapped back along the projection direction.
//!
//! 1. Cone: every surviving face t (a face of a or b that does not hold both) must face the
//!    projection direction d, d · n_t > 0. That set is a convex cone; its extreme rays are
//!    the directions ±(n_i × n_j) on the boundary of two constraints that meet all others.
//!    d is their normalised mean (the paper averages the vertices of the cone's cut base);
//!    when the cone has no extreme rays (all normals parallel: a half-space; or a wedge
//!    whose rays cancel) the normalised mean normal is tried. No strictly admissible d:
//!    no placement.
//! 2. Kernel: in the plane ⟂ d, each surviving face (v, x, y) (v the moving vertex) keeps
//!    its orientation iff the new vertex lies strictly left of its projected far edge
//!    x → y. The intersection of those half-planes (clipped to the box of the projected
//!    neighbourhood, which bounds it on a border) is the kernel of the link polygon. The
//!    paper takes the mean of the kernel polygon's vertices and names a better choice as
//!    future work; we take the projection of the quadric's optimal point when it lies in
//!    the kernel, else the point 0.9 of the way from the mean towards it where the segment
//!    leaves the kernel (the mean alone measured 1.9 × optimal's Metro mean on bunny at
//!    10 %). Empty kernel: no placement.
//! 3. Map back: on the line through that point along d, the point of least quadric error;
//!    accepted when the summed and the largest distance between each surviving face before
//!    and after (d_sum and E2 of the paper) are within [`MAX_E2`] and [`MAX_DSUM`] of the
//!    bbox diagonal. The distance between a face before and after (the two share their far
//!    edge) is the larger of the old apex's distance to the new face's plane and the new
//!    apex's to the old one's: the move out of the surface (a move within a flat patch
//!    costs nothing; the paper does not say how it measures).
//!
//! What the construction guarantees: every surviving face projects to a positively
//! oriented triangle in the plane ⟂ d, before and after (d · n > 0 before; the kernel point
//! after, and moving along d does not change a projection), and the projections tile the
//! projected link polygon without overlap. So no face of the patch folds over (its normal
//! keeps a positive component along d, as the old one had) and the patch cannot intersect
//! itself: two of its faces that met in space would overlap in the projection. It says
//! nothing about faces outside the patch: the global box-hierarchy check
//! (`--check-intersections`) is what excludes the patch meeting the rest of the mesh.

use crate::simplify::quadric::Quadric;
use glam::{DVec2, DVec3};

/// Largest distance between a surviving face before and after (E2), as a fraction of the
/// bbox diagonal: 5 %, a guard against a far-away point on a long line, not a simplification
/// target (the collapse order and `max_error` are those).
pub const MAX_E2: f64 = 0.05;
/// Summed distances between the surviving faces before and after (d_sum), as a fraction of
/// the bbox diagonal.
pub const MAX_DSUM: f64 = 0.25;

/// Most surviving faces handled (the fixed buffers' size): a collapse with more is refused.
pub const MAX_FAN: usize = 64;
const MAX_POLY: usize = MAX_FAN + 8;

/// Cosine margin for "strictly" facing d.
const STRICT: f64 = 1e-9;

/// The projection direction for faces with unit normals `normals`: the normalised mean of
/// the admissible cone's extreme rays (or the mean normal when it has none), `None` when no
/// direction has d · n > 0 for every n.
pub fn cone_direction(normals: &[DVec3]) -> Option<DVec3> {
    let admissible = |d: DVec3, tol: f64| normals.iter().all(|n| n.dot(d) >= tol);
    let mut sum = DVec3::ZERO;
    let mut rays = 0;
    // The normals that last ruled out a ray and its opposite: tested first for the next
    // pair, they usually rule out its rays too (two dot products instead of a scan). The
    // outcome is the same: a ray is admissible when every normal admits it, whichever is
    // tested first.
    let (mut wpos, mut wneg) = (0usize, 0usize);
    for (i, ni) in normals.iter().enumerate() {
        for nj in &normals[i + 1..] {
            let r = ni.cross(*nj);
            let len = r.length();
            if len < 1e-9 {
                continue;
            }
            let r = r / len;
            // Whether r and whether −r is admissible, from one dot product per normal
            // (n · (−r) is −(n · r) to the bit) and stopping once both fail: the very
            // outcome of testing each in turn, at half the dot products or less.
            let (sp, sn) = (normals[wpos].dot(r), normals[wneg].dot(r));
            let (mut pos, mut neg) = (sp >= -1e-12, -sn >= -1e-12);
            if pos || neg {
                for (k, n) in normals.iter().enumerate() {
                    let s = n.dot(r);
                    if pos && s < -1e-12 || s.is_nan() {
                        pos = false;
                        wpos = k;
                    }
                    if neg && -s < -1e-12 || s.is_nan() {
                        neg = false;
                        wneg = k;
                    }
                    if !(pos || neg) {
                        break;
                    }
                }
            }
            for (r, ok) in [(r, pos), (-r, neg)] {
                if ok {
                    sum += r;
                    rays += 1;
                }
            }
        }
    }
    let strict = |d: DVec3| admissible(d, STRICT);
    if rays > 0 {
        let d = sum.normalize_or_zero();
        if d != DVec3::ZERO && strict(d) {
            return Some(d);
        }
        // A wedge (every normal ⟂ one axis u, the rays ±u cancel): its section ⟂ u is a
        // plane cone whose extreme rays are among ±(u × n).
        if let Some(u) = first_axis(normals) {
            let mut sum = DVec3::ZERO;
            for n in normals {
                let r = u.cross(*n).normalize_or_zero();
                for r in [r, -r] {
                    if r != DVec3::ZERO && admissible(r, -1e-12) {
                        sum += r;
                    }
                }
            }
            let d = sum.normalize_or_zero();
            if d != DVec3::ZERO && strict(d) {
                return Some(d);
            }
        }
    }
    let mean = normals.iter().copied().sum::<DVec3>().normalize_or_zero();
    (mean != DVec3::ZERO && strict(mean)).then_some(mean)
}

/// The unit cross product of the first two normals that are not parallel.
fn first_axis(normals: &[DVec3]) -> Option<DVec3> {
    normals.iter().enumerate().find_map(|(i, ni)| {
        normals[i + 1..]
            .iter()
            .map(|nj| ni.cross(*nj))
            .find(|r| r.length() >= 1e-9)
            .map(|r| r.normalize())
    })
}

/// The kernel of the half-planes "strictly left of the directed edge (x, y)" clipped to the
/// box [lo, hi], as a convex polygon (counter-clockwise) in `out`; empty when it has no
/// area. Sutherland–Hodgman clipping on fixed buffers (`edges.len()` ≤ [`MAX_FAN`]).
pub fn kernel(edges: &[(DVec2, DVec2)], lo: DVec2, hi: DVec2, out: &mut Poly) {
    out.clear();
    for p in [lo, DVec2::new(hi.x, lo.y), hi, DVec2::new(lo.x, hi.y)] {
        out.push(p);
    }
    // Two buffers clipped into in turn (swapping them moved 1 kB per edge).
    let mut tmp = Poly::default();
    let mut in_tmp = false;
    for &(x, y) in edges {
        let (src, dst) = match in_tmp {
            true => (&tmp, &mut *out),
            false => (&*out, &mut tmp),
        };
        let e = y - x;
        let side = |p: DVec2| e.perp_dot(p - x);
        dst.clear();
        let n = src.len;
        for i in 0..n {
            let (p, q) = (src.pts[i], src.pts[(i + 1) % n]);
            let (sp, sq) = (side(p), side(q));
            if sp > 0.0 {
                dst.push(p);
            }
            if (sp > 0.0) != (sq > 0.0) && sp != sq {
                let t = sp / (sp - sq);
                dst.push(p + (q - p) * t);
            }
        }
        in_tmp = !in_tmp;
        if dst.len < 3 {
            out.clear();
            return;
        }
    }
    if in_tmp {
        out.pts[..tmp.len].copy_from_slice(&tmp.pts[..tmp.len]);
        out.len = tmp.len;
    }
    if out.area() <= 1e-18 * (hi - lo).length_squared() {
        out.clear();
    }
}

/// A convex polygon on a fixed buffer.
#[derive(Debug, Clone, Copy)]
pub struct Poly {
    pts: [DVec2; MAX_POLY],
    len: usize,
}

impl Default for Poly {
    fn default() -> Poly {
        Poly {
            pts: [DVec2::ZERO; MAX_POLY],
            len: 0,
        }
    }
}

impl Poly {
    fn clear(&mut self) {
        self.len = 0;
    }
    fn push(&mut self, p: DVec2) {
        if self.len < MAX_POLY {
            self.pts[self.len] = p;
            self.len += 1;
        }
    }
    /// The vertices.
    pub fn points(&self) -> &[DVec2] {
        &self.pts[..self.len]
    }
    /// Twice the signed area.
    fn area(&self) -> f64 {
        let p = self.points();
        (0..p.len())
            .map(|i| p[i].perp_dot(p[(i + 1) % p.len()]))
            .sum()
    }
    /// Whether `q` is inside (on or left of every edge).
    pub fn contains(&self, q: DVec2) -> bool {
        let p = self.points();
        !p.is_empty()
            && (0..p.len()).all(|i| (p[(i + 1) % p.len()] - p[i]).perp_dot(q - p[i]) >= 0.0)
    }
}

/// The point of the segment from `centre` (inside the convex polygon `k`) to `target`
/// that is nearest `target` while staying inside: `target` itself when it is inside,
/// else 0.9 of the way to the polygon's boundary (strictly inside).
fn toward(k: &Poly, centre: DVec2, target: DVec2) -> DVec2 {
    let p = k.points();
    let mut t = 1.0f64;
    for i in 0..p.len() {
        let e = p[(i + 1) % p.len()] - p[i];
        let (sc, st) = (e.perp_dot(centre - p[i]), e.perp_dot(target - p[i]));
        if st <= 0.0 && sc > 0.0 {
            t = t.min(0.9 * sc / (sc - st));
        } else if st <= 0.0 {
            t = 0.0;
        }
    }
    centre + (target - centre) * t
}

/// The two-local-mappings point for the surviving faces `fan` (each `[v, x, y]` with v the
/// moving vertex's current position, counter-clockwise), the merged quadric `q`, the
/// edge's endpoints (for the box and the fallback along the line) and the quadric's own
/// best point `best`; `diag` is the bbox diagonal. `None`: no fold-free point (empty cone or kernel, too many faces, or the
/// distances over their thresholds).
pub fn place(
    q: &Quadric,
    fan: &[[DVec3; 3]],
    a: DVec3,
    b: DVec3,
    best: DVec3,
    diag: f64,
) -> Option<DVec3> {
    if fan.is_empty() || fan.len() > MAX_FAN {
        return None;
    }
    let mut normals = [DVec3::ZERO; MAX_FAN];
    for (n, t) in normals.iter_mut().zip(fan) {
        *n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
        if *n == DVec3::ZERO {
            return None;
        }
    }
    let d = cone_direction(&normals[..fan.len()])?;
    // Mapping 1: the plane ⟂ d through the edge's midpoint, axes e1 × e2 = d.
    let o = 0.5 * (a + b);
    let e1 = d.any_orthonormal_vector();
    let e2 = d.cross(e1);
    let to2 = |p: DVec3| DVec2::new((p - o).dot(e1), (p - o).dot(e2));
    let mut edges = [(DVec2::ZERO, DVec2::ZERO); MAX_FAN];
    let (mut lo, mut hi) = (to2(a).min(to2(b)), to2(a).max(to2(b)));
    for (e, t) in edges.iter_mut().zip(fan) {
        *e = (to2(t[1]), to2(t[2]));
        lo = lo.min(e.0).min(e.1);
        hi = hi.max(e.0).max(e.1);
    }
    let mut k = Poly::default();
    kernel(&edges[..fan.len()], lo, hi, &mut k);
    if k.len == 0 {
        return None;
    }
    let centre = k.points().iter().copied().sum::<DVec2>() / k.len as f64;
    let c2 = toward(&k, centre, to2(best));
    // Mapping 2: back along d, the least quadric error on the line c + t d.
    let c = o + e1 * c2.x + e2 * c2.y;
    let m = q.matrix();
    let dad = d.dot(m * d);
    let t = if dad > 1e-12 * q.weight().max(f64::MIN_POSITIVE) {
        -(d.dot(m * c) + q.linear().dot(d)) / dad
    } else {
        (o - c).dot(d)
    };
    let p = c + d * t;
    if !p.is_finite() {
        return None;
    }
    let (mut sum, mut max) = (0.0f64, 0.0f64);
    for (t, n) in fan.iter().zip(&normals) {
        let m = (t[1] - p).cross(t[2] - p).normalize_or_zero();
        let dist = n.dot(p - t[0]).abs().max(m.dot(t[0] - p).abs());
        sum += dist;
        max = max.max(dist);
    }
    (max <= MAX_E2 * diag && sum <= MAX_DSUM * diag).then_some(p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Directions spread over the sphere (Fibonacci lattice).
    fn sphere_dirs(n: usize) -> Vec<DVec3> {
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let phi = golden * i as f64;
                DVec3::new(r * phi.cos(), r * phi.sin(), z)
            })
            .collect()
    }

    fn unit(v: (f64, f64, f64)) -> Option<DVec3> {
        let n = DVec3::new(v.0, v.1, v.2);
        (n.length() > 0.1).then(|| n.normalize())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]
        /// Against sampled directions: a direction found is strictly admissible; none found
        /// means no sampled direction clears every face by a visible margin.
        #[test]
        fn the_cone_agrees_with_sampled_directions(
            raw in proptest::collection::vec((-1.0f64..1.0, -1.0f64..1.0, 0.0f64..1.0), 1..10),
            tilt in -1.0f64..1.0,
        ) {
            let normals: Vec<DVec3> = raw
                .into_iter()
                .filter_map(|(x, y, z)| unit((x, y, z + tilt)))
                .collect();
            prop_assume!(!normals.is_empty());
            let got = cone_direction(&normals);
            let sampled = sphere_dirs(20_000)
                .into_iter()
                .map(|d| normals.iter().map(|n| n.dot(d)).fold(f64::INFINITY, f64::min))
                .fold(f64::NEG_INFINITY, f64::max);
            match got {
                Some(d) => {
                    prop_assert!((d.length() - 1.0).abs() < 1e-9);
                    prop_assert!(normals.iter().all(|n| n.dot(d) > 0.0));
                }
                None => prop_assert!(sampled < 0.03, "sampled margin {sampled}"),
            }
            if sampled > 0.03 {
                prop_assert!(got.is_some());
            }
        }

        /// Against point-in-kernel tests: a random point is in the kernel polygon iff it is
        /// strictly left of every edge (and in the box), up to a hair; star-shaped links
        /// (random angles and radii around the origin) always have a kernel holding the
        /// origin.
        #[test]
        fn the_kernel_agrees_with_point_tests(
            mut angles in proptest::collection::vec(0.0f64..std::f64::consts::TAU, 3..12),
            radii in proptest::collection::vec(0.3f64..2.0, 12),
            star in any::<bool>(),
            jitter in proptest::collection::vec((-2.0f64..2.0, -2.0f64..2.0), 12),
            probes in proptest::collection::vec((-2.5f64..2.5, -2.5f64..2.5), 64),
        ) {
            angles.sort_by(f64::total_cmp);
            let pts: Vec<DVec2> = angles
                .iter()
                .enumerate()
                .map(|(i, &t)| {
                    let p = DVec2::new(t.cos(), t.sin()) * radii[i];
                    if star { p } else { DVec2::new(jitter[i].0, jitter[i].1) }
                })
                .collect();
            let edges: Vec<(DVec2, DVec2)> =
                (0..pts.len()).map(|i| (pts[i], pts[(i + 1) % pts.len()])).collect();
            let (lo, hi) = (DVec2::splat(-2.5), DVec2::splat(2.5));
            let mut k = Poly::default();
            kernel(&edges, lo, hi, &mut k);
            let inside = |q: DVec2, tol: f64| edges.iter().all(|&(x, y)| (y - x).perp_dot(q - x) > tol);
            if star && angles.windows(2).all(|w| w[1] - w[0] < std::f64::consts::PI - 1e-3)
                && angles[0] + std::f64::consts::TAU - angles[angles.len() - 1] < std::f64::consts::PI - 1e-3
            {
                prop_assert!(k.contains(DVec2::ZERO), "the origin sees a star-shaped link");
            }
            for (x, y) in probes {
                let q = DVec2::new(x, y);
                if inside(q, 1e-6) {
                    prop_assert!(k.contains(q), "{q} is in every half-plane");
                }
                if !inside(q, -1e-6) {
                    prop_assert!(!k.contains(q) || k.points().is_empty(), "{q} is outside one");
                }
            }
            for &v in k.points() {
                prop_assert!(inside(v, -1e-9));
            }
        }
    }

    #[test]
    fn a_non_star_link_is_rejected() {
        // A "C": the inner side of the lower arm wants y < 1, of the upper one y > 9.
        let c = [
            (0.0, 0.0),
            (10.0, 0.0),
            (10.0, 1.0),
            (1.0, 1.0),
            (1.0, 9.0),
            (10.0, 9.0),
            (10.0, 10.0),
            (0.0, 10.0),
        ]
        .map(|(x, y)| DVec3::new(x, y, 0.0));
        let fan: Vec<[DVec3; 3]> = (0..c.len())
            .map(|i| [DVec3::new(0.5, 5.0, 0.0), c[i], c[(i + 1) % c.len()]])
            .collect();
        let q = Quadric::plane(DVec3::Z, 0.0, 1.0);
        assert_eq!(place(&q, &fan, fan[0][0], fan[0][0], fan[0][0], 20.0), None);
        // The same fan with a star-shaped link (a square) is placed, on the plane.
        let s = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)]
            .map(|(x, y)| DVec3::new(x, y, 0.0));
        let fan: Vec<[DVec3; 3]> = (0..4)
            .map(|i| [DVec3::new(3.0, 4.0, 0.0), s[i], s[(i + 1) % 4]])
            .collect();
        let b = DVec3::new(4.0, 4.0, 0.0);
        let p = place(&q, &fan, fan[0][0], b, b, 20.0).expect("a kernel");
        assert!(
            (p - b).length() < 1e-9,
            "the best point is in the kernel: {p}"
        );
        // A best point outside the kernel is pulled inside.
        let far = DVec3::new(15.0, 5.0, 3.0);
        let p = place(&q, &fan, fan[0][0], b, far, 20.0).expect("a kernel");
        assert!(p.z.abs() < 1e-9 && p.x > 5.0 && p.x < 10.0 && p.y > 0.0 && p.y < 10.0);
    }

    #[test]
    fn an_empty_cone_is_rejected() {
        // Two faces facing opposite ways.
        assert_eq!(cone_direction(&[DVec3::Z, -DVec3::Z]), None);
        assert_eq!(cone_direction(&[DVec3::X, DVec3::Y, -DVec3::X]), None);
        let d = cone_direction(&[DVec3::Z, DVec3::new(0.0, 0.6, 0.8)]).unwrap();
        assert!(d.z > 0.0 && d.y > 0.0);
        // A sharp crease, many faces on one side: the mean normal fails, the wedge's
        // bisector does not.
        let n2 = DVec3::new(0.0, 0.9, -0.436).normalize();
        let mut ns = vec![DVec3::Z; 20];
        ns.push(n2);
        let d = cone_direction(&ns).expect("a wedge");
        assert!(d.z > 0.0 && d.dot(n2) > 0.0);
    }
}
