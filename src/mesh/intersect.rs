//! Exact triangle–triangle intersection, and the fold-over and self-intersection checker of
//! `terratile compare --check-folds` (issue 11; also the simplifiers' tests).
//!
//! The predicates are the `robust` crate's adaptive-exact `orient3d` / `orient2d`
//! (Shewchuk). Mesh positions are f32, so every corner is exact in f64 and the signs below
//! are exact: no tolerance decides whether two triangles meet.
//!
//! The triangle–triangle test is written here on top of those predicates rather than taken
//! from a crate (none of the maintained ones is exact: `parry3d` works in floats with
//! tolerances). It is not Devillers–Guigue's case table but the plainer reduction it
//! optimises: two closed triangles intersect iff an edge of one meets the other (the
//! intersection is a convex set whose extreme points each lie on an edge of one triangle).
//! Each edge–triangle test is exact, degenerate cases included: a segment crossing the
//! plane is tested against the three edge lines with `orient3d`; coplanar configurations
//! are projected onto a coordinate plane chosen by an exact test so the projection keeps
//! incidence; zero-area triangles are the union of their edges; fully collinear
//! configurations reduce to interval overlap.

use super::{Bvh, TriMesh};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use robust::{orient2d, orient3d, Coord, Coord3D};
use rustc_hash::FxHashMap;
use serde::Serialize;

#[inline]
fn o3(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> i8 {
    let c3 = |p: DVec3| Coord3D {
        x: p.x,
        y: p.y,
        z: p.z,
    };
    sign(orient3d(c3(a), c3(b), c3(c), c3(d)))
}

#[inline]
fn sign(v: f64) -> i8 {
    if v > 0.0 {
        1
    } else if v < 0.0 {
        -1
    } else {
        0
    }
}

/// Drops coordinate `k`: the projection onto a coordinate plane (exact).
#[inline]
fn proj(p: DVec3, k: usize) -> Coord<f64> {
    match k {
        0 => Coord { x: p.y, y: p.z },
        1 => Coord { x: p.z, y: p.x },
        _ => Coord { x: p.x, y: p.y },
    }
}

#[inline]
fn o2(a: Coord<f64>, b: Coord<f64>, c: Coord<f64>) -> i8 {
    sign(orient2d(a, b, c))
}

/// True when a, b, c are collinear (or coincide), exactly: a non-collinear triple keeps a
/// non-zero orientation in the projection along any axis its normal is not perpendicular to.
fn collinear3(a: DVec3, b: DVec3, c: DVec3) -> bool {
    (0..3).all(|k| o2(proj(a, k), proj(b, k), proj(c, k)) == 0)
}

/// Closed 2D segment intersection (degenerate segments included).
fn seg_seg2(a: Coord<f64>, b: Coord<f64>, c: Coord<f64>, d: Coord<f64>) -> bool {
    let on = |p: Coord<f64>, q: Coord<f64>, x: Coord<f64>| {
        x.x >= p.x.min(q.x) && x.x <= p.x.max(q.x) && x.y >= p.y.min(q.y) && x.y <= p.y.max(q.y)
    };
    let d1 = o2(c, d, a);
    let d2 = o2(c, d, b);
    let d3 = o2(a, b, c);
    let d4 = o2(a, b, d);
    if d1 * d2 < 0 && d3 * d4 < 0 {
        return true;
    }
    (d1 == 0 && on(c, d, a))
        || (d2 == 0 && on(c, d, b))
        || (d3 == 0 && on(a, b, c))
        || (d4 == 0 && on(a, b, d))
}

/// Closed 3D segment intersection.
fn seg_seg3(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> bool {
    if o3(a, b, c, d) != 0 {
        return false;
    }
    // Coplanar: project along an axis that keeps some triple non-collinear (then the
    // projection is injective on the common plane).
    for k in 0..3 {
        let (pa, pb, pc, pd) = (proj(a, k), proj(b, k), proj(c, k), proj(d, k));
        if o2(pa, pb, pc) != 0 || o2(pa, pb, pd) != 0 || o2(pa, pc, pd) != 0 || o2(pb, pc, pd) != 0
        {
            return seg_seg2(pa, pb, pc, pd);
        }
    }
    // All four collinear: overlap of intervals along the axis of largest extent (the line's
    // direction is not perpendicular to it unless all points coincide).
    let lo = a.min(b).min(c).min(d);
    let hi = a.max(b).max(c).max(d);
    let k = (hi - lo).max_position();
    let (s0, s1) = (a[k].min(b[k]), a[k].max(b[k]));
    let (t0, t1) = (c[k].min(d[k]), c[k].max(d[k]));
    s0 <= t1 && t0 <= s1
}

/// Closed segment [a, b] against closed triangle (p, q, r), exactly.
pub fn segment_triangle(a: DVec3, b: DVec3, p: DVec3, q: DVec3, r: DVec3) -> bool {
    if collinear3(p, q, r) {
        // A zero-area triangle is the union of its edges.
        return seg_seg3(a, b, p, q) || seg_seg3(a, b, q, r) || seg_seg3(a, b, r, p);
    }
    segment_proper_triangle(a, b, p, q, r, o3(p, q, r, a), o3(p, q, r, b))
}

/// [`segment_triangle`] for a triangle of non-zero area, given the sides of a and b
/// (`o3(p, q, r, ·)`): exactly-zero orientations are the slow path of the adaptive
/// predicate, so callers that have them pass them on.
fn segment_proper_triangle(
    a: DVec3,
    b: DVec3,
    p: DVec3,
    q: DVec3,
    r: DVec3,
    sa: i8,
    sb: i8,
) -> bool {
    if sa * sb > 0 {
        return false;
    }
    if sa != 0 || sb != 0 {
        // The line crosses the plane once, between a and b: it meets the closed triangle
        // iff it is on the same side of (or on) all three edge lines.
        let s1 = o3(a, b, p, q);
        let s2 = o3(a, b, q, r);
        let s3 = o3(a, b, r, p);
        let pos = s1 > 0 || s2 > 0 || s3 > 0;
        let neg = s1 < 0 || s2 < 0 || s3 < 0;
        return !(pos && neg);
    }
    // Coplanar with a proper triangle: project where the triangle keeps its area.
    let k = (0..3)
        .find(|&k| o2(proj(p, k), proj(q, k), proj(r, k)) != 0)
        .expect("a non-collinear triangle has a non-degenerate projection");
    let (pa, pb, pp, pq, pr) = (proj(a, k), proj(b, k), proj(p, k), proj(q, k), proj(r, k));
    let inside = |x: Coord<f64>| {
        let s = [o2(pp, pq, x), o2(pq, pr, x), o2(pr, pp, x)];
        !(s.iter().any(|&v| v > 0) && s.iter().any(|&v| v < 0))
    };
    inside(pa)
        || inside(pb)
        || seg_seg2(pa, pb, pp, pq)
        || seg_seg2(pa, pb, pq, pr)
        || seg_seg2(pa, pb, pr, pp)
}

/// Whether two closed triangles share at least one point, exactly.
pub fn triangles_intersect(t: [DVec3; 3], u: [DVec3; 3]) -> bool {
    // Cheap exact rejections first: boxes, then one triangle strictly on one side of the
    // other's plane.
    let (tmin, tmax) = (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
    let (umin, umax) = (u[0].min(u[1]).min(u[2]), u[0].max(u[1]).max(u[2]));
    if tmin.cmpgt(umax).any() || umin.cmpgt(tmax).any() {
        return false;
    }
    let sides = |p: [DVec3; 3], q: [DVec3; 3]| q.map(|x| o3(p[0], p[1], p[2], x));
    let apart = |s: [i8; 3]| s.iter().all(|&v| v > 0) || s.iter().all(|&v| v < 0);
    let st = sides(t, u);
    if apart(st) {
        return false;
    }
    let tdeg = collinear3(t[0], t[1], t[2]);
    if !tdeg && st == [0; 3] {
        // u lies in t's proper plane (so t in u's): the other three exact zeros, the
        // predicate's slowest case, need not be computed.
        return coplanar(t, u, false);
    }
    let su = sides(u, t);
    if apart(su) {
        return false;
    }
    let udeg = collinear3(u[0], u[1], u[2]);
    if !udeg && su == [0; 3] {
        return coplanar(t, u, tdeg);
    }
    let edges_meet = |t: [DVec3; 3], u: [DVec3; 3], udeg: bool, su: [i8; 3]| {
        (0..3).any(|i| {
            let j = (i + 1) % 3;
            if udeg {
                segment_triangle(t[i], t[j], u[0], u[1], u[2])
            } else {
                segment_proper_triangle(t[i], t[j], u[0], u[1], u[2], su[i], su[j])
            }
        })
    };
    edges_meet(t, u, udeg, su) || edges_meet(u, t, tdeg, st)
}

/// Two triangles in one plane, at least one (`t` unless `tdeg`) of non-zero area: in 2D,
/// an edge of one crosses an edge of the other, or one holds a vertex of the other.
fn coplanar(t: [DVec3; 3], u: [DVec3; 3], tdeg: bool) -> bool {
    let (t, u) = if tdeg { (u, t) } else { (t, u) };
    let k = (0..3)
        .find(|&k| o2(proj(t[0], k), proj(t[1], k), proj(t[2], k)) != 0)
        .expect("a non-collinear triangle has a non-degenerate projection");
    let (pt, pu) = (t.map(|p| proj(p, k)), u.map(|p| proj(p, k)));
    let inside = |tri: [Coord<f64>; 3], x: Coord<f64>| {
        let s = [
            o2(tri[0], tri[1], x),
            o2(tri[1], tri[2], x),
            o2(tri[2], tri[0], x),
        ];
        !(s.iter().any(|&v| v > 0) && s.iter().any(|&v| v < 0))
    };
    (0..3).any(|i| (0..3).any(|j| seg_seg2(pt[i], pt[(i + 1) % 3], pu[j], pu[(j + 1) % 3])))
        || inside(pt, pu[0])
        || (o2(pu[0], pu[1], pu[2]) != 0 && inside(pu, pt[0]))
}

/// Every vertex's id after welding exact duplicates (same position): faces are adjacent
/// when they share a welded vertex, so faces meeting across a UV seam or a colour split
/// (duplicated vertices) are not counted as intersecting.
pub fn welded_ids(mesh: &TriMesh) -> Vec<u32> {
    let mut first: FxHashMap<[u32; 3], u32> = FxHashMap::default();
    mesh.positions
        .iter()
        .enumerate()
        .map(|(i, p)| {
            // + 0.0 turns -0.0 into 0.0: the same point.
            let key = (*p + Vec3::ZERO).to_array().map(f32::to_bits);
            *first.entry(key).or_insert(i as u32)
        })
        .collect()
}

fn adjacent(w: &[u32], a: [u32; 3], b: [u32; 3]) -> bool {
    a.iter()
        .any(|&i| b.iter().any(|&j| w[i as usize] == w[j as usize]))
}

/// Pairs (i < j) of non-adjacent faces (no welded vertex in common) that intersect, sorted:
/// candidates from the BVH's box query, then the exact test.
pub fn self_intersections(mesh: &TriMesh) -> Vec<(u32, u32)> {
    let bvh = Bvh::new(mesh);
    let w = welded_ids(mesh);
    let mut pairs: Vec<(u32, u32)> = (0..mesh.indices.len())
        .into_par_iter()
        .flat_map_iter(|i| {
            let t = mesh.corners(i);
            let (lo, hi) = tri_box(mesh, i);
            let mut out = Vec::new();
            bvh.for_each_overlap(lo, hi, |j| {
                let j = j as usize;
                if j > i
                    && !adjacent(&w, mesh.indices[i], mesh.indices[j])
                    && triangles_intersect(t, mesh.corners(j))
                {
                    out.push((i as u32, j as u32));
                }
            });
            out
        })
        .collect();
    pairs.sort_unstable();
    pairs
}

/// The O(n²) twin of [`self_intersections`]: every pair, no hierarchy.
pub fn self_intersections_brute(mesh: &TriMesh) -> Vec<(u32, u32)> {
    let w = welded_ids(mesh);
    let n = mesh.indices.len();
    let corners: Vec<[DVec3; 3]> = (0..n).map(|f| mesh.corners(f)).collect();
    (0..n)
        .into_par_iter()
        .flat_map_iter(|i| {
            let corners = &corners;
            let w = &w;
            (i + 1..n).filter_map(move |j| {
                (!adjacent(w, mesh.indices[i], mesh.indices[j])
                    && triangles_intersect(corners[i], corners[j]))
                .then_some((i as u32, j as u32))
            })
        })
        .collect()
}

fn tri_box(mesh: &TriMesh, f: usize) -> (Vec3, Vec3) {
    let [a, b, c] = mesh.indices[f].map(|i| mesh.positions[i as usize]);
    (a.min(b).min(c), a.max(b).max(c))
}

/// Faces of `out` whose normal is more than 90° from the normal of the `original` surface
/// at the point nearest to the face's centroid (zero-area faces on either side are not
/// judged). Sorted.
pub fn fold_overs(original: &TriMesh, original_bvh: &Bvh, out: &TriMesh) -> Vec<u32> {
    (0..out.indices.len())
        .into_par_iter()
        .filter(|&f| {
            let [a, b, c] = out.corners(f);
            let n = (b - a).cross(c - a);
            if n == DVec3::ZERO {
                return false;
            }
            let Some(hit) = original_bvh.closest((a + b + c) / 3.0, None, f64::INFINITY) else {
                return false;
            };
            let [p, q, r] = original.corners(hit.triangle as usize);
            n.dot((q - p).cross(r - p)) < 0.0
        })
        .map(|f| f as u32)
        .collect()
}

/// What `--check-folds` found.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct FoldReport {
    /// Faces of the simplified mesh that fold over against the original.
    pub fold_overs: Vec<u32>,
    /// Faces of the simplified mesh in at least one intersecting non-adjacent pair.
    pub self_intersecting_faces: Vec<u32>,
    /// Intersecting non-adjacent face pairs of the simplified mesh.
    pub self_intersecting_pairs: usize,
    /// The original's own self-intersecting faces (an input's flaws are not the
    /// simplifier's).
    pub original_self_intersecting_faces: Vec<u32>,
    /// The original's own intersecting pairs.
    pub original_self_intersecting_pairs: usize,
}

/// The faces named in `pairs`, sorted, once each.
pub fn faces_of(pairs: &[(u32, u32)]) -> Vec<u32> {
    let mut f: Vec<u32> = pairs.iter().flat_map(|&(a, b)| [a, b]).collect();
    f.sort_unstable();
    f.dedup();
    f
}

/// Fold-overs of `out` against `original`, and both meshes' self-intersections.
pub fn check_folds(original: &TriMesh, out: &TriMesh) -> FoldReport {
    let bvh = Bvh::new(original);
    let pairs = self_intersections(out);
    let orig = self_intersections(original);
    FoldReport {
        fold_overs: fold_overs(original, &bvh, out),
        self_intersecting_faces: faces_of(&pairs),
        self_intersecting_pairs: pairs.len(),
        original_self_intersecting_faces: faces_of(&orig),
        original_self_intersecting_pairs: orig.len(),
    }
}

impl std::fmt::Display for FoldReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let list = |f: &mut std::fmt::Formatter<'_>, v: &[u32]| -> std::fmt::Result {
            const SHOWN: usize = 20;
            for (k, x) in v.iter().take(SHOWN).enumerate() {
                write!(f, "{}{x}", if k == 0 { ": " } else { " " })?;
            }
            if v.len() > SHOWN {
                write!(f, " … ({} more)", v.len() - SHOWN)?;
            }
            writeln!(f)
        };
        write!(f, "fold-overs: {} faces", self.fold_overs.len())?;
        list(f, &self.fold_overs)?;
        write!(
            f,
            "self-intersections: {} faces in {} pairs",
            self.self_intersecting_faces.len(),
            self.self_intersecting_pairs
        )?;
        list(f, &self.self_intersecting_faces)?;
        write!(
            f,
            "original's own self-intersections: {} faces in {} pairs",
            self.original_self_intersecting_faces.len(),
            self.original_self_intersecting_pairs
        )?;
        list(f, &self.original_self_intersecting_faces)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn v(x: f64, y: f64, z: f64) -> DVec3 {
        DVec3::new(x, y, z)
    }

    #[test]
    fn closed_cases() {
        let t = [v(0., 0., 0.), v(1., 0., 0.), v(0., 1., 0.)];
        // Piercing.
        assert!(triangles_intersect(
            t,
            [v(0.2, 0.2, -1.), v(0.2, 0.2, 1.), v(5., 5., 0.5)]
        ));
        // Touching at a vertex only (closed sets meet).
        assert!(triangles_intersect(
            t,
            [v(1., 0., 0.), v(2., 0., 1.), v(2., 1., 1.)]
        ));
        // Just apart.
        assert!(!triangles_intersect(
            t,
            [v(0.6, 0.6, -1.), v(0.6, 0.6, 1.), v(5., 5., 0.)]
        ));
        // Coplanar overlap, coplanar containment, coplanar apart.
        assert!(triangles_intersect(
            t,
            [v(0.5, 0.5, 0.), v(-1., 0.2, 0.), v(0.2, -1., 0.)]
        ));
        assert!(triangles_intersect(
            t,
            [v(0.1, 0.1, 0.), v(0.2, 0.1, 0.), v(0.1, 0.2, 0.)]
        ));
        assert!(!triangles_intersect(
            t,
            [v(0.6, 0.6, 0.), v(2., 0.6, 0.), v(0.6, 2., 0.)]
        ));
        // Zero-area triangles: a segment through the interior; collinear segments.
        assert!(triangles_intersect(
            t,
            [v(0.2, 0.2, -1.), v(0.2, 0.2, 1.), v(0.2, 0.2, 0.)]
        ));
        let s = [v(0., 0., 0.), v(2., 0., 0.), v(1., 0., 0.)];
        assert!(triangles_intersect(
            s,
            [v(1.5, 0., 0.), v(3., 0., 0.), v(3., 0., 0.)]
        ));
        assert!(!triangles_intersect(
            s,
            [v(2.5, 0., 0.), v(3., 0., 0.), v(3., 0., 0.)]
        ));
    }

    /// Exact rational-free reference for random integer triangles: sample-free, via the
    /// separating axis theorem over the 11 candidate axes, in i128 (exact for small ints).
    /// Coplanar pairs need the in-plane edge normals as well: added as n × e.
    fn sat(t: [DVec3; 3], u: [DVec3; 3]) -> bool {
        let ti: Vec<[i128; 3]> = t
            .iter()
            .map(|p| [p.x as i128, p.y as i128, p.z as i128])
            .collect();
        let ui: Vec<[i128; 3]> = u
            .iter()
            .map(|p| [p.x as i128, p.y as i128, p.z as i128])
            .collect();
        let sub = |a: [i128; 3], b: [i128; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let cross = |a: [i128; 3], b: [i128; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let dot = |a: [i128; 3], b: [i128; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let edges = |p: &[[i128; 3]]| [sub(p[1], p[0]), sub(p[2], p[1]), sub(p[0], p[2])];
        let (et, eu) = (edges(&ti), edges(&ui));
        let nt = cross(et[0], et[1]);
        let nu = cross(eu[0], eu[1]);
        let mut axes = vec![nt, nu];
        for a in et {
            for b in eu {
                axes.push(cross(a, b));
            }
            axes.push(cross(nt, a));
            axes.push(cross(nu, a));
        }
        for b in eu {
            axes.push(cross(nt, b));
            axes.push(cross(nu, b));
        }
        // Degenerate triangles: also axes from edges against the coordinate axes.
        for e in et.iter().chain(eu.iter()) {
            for k in 0..3 {
                let mut x = [0i128; 3];
                x[k] = 1;
                axes.push(cross(*e, x));
                axes.push(cross(cross(*e, x), *e));
            }
        }
        for k in 0..3 {
            let mut x = [0i128; 3];
            x[k] = 1;
            axes.push(x);
        }
        for a in axes {
            if a == [0, 0, 0] {
                continue;
            }
            let pt: Vec<i128> = ti.iter().map(|&p| dot(p, a)).collect();
            let pu: Vec<i128> = ui.iter().map(|&p| dot(p, a)).collect();
            let (t0, t1) = (*pt.iter().min().unwrap(), *pt.iter().max().unwrap());
            let (u0, u1) = (*pu.iter().min().unwrap(), *pu.iter().max().unwrap());
            if t1 < u0 || u1 < t0 {
                return false;
            }
        }
        true
    }

    fn tri() -> impl Strategy<Value = [DVec3; 3]> {
        prop::array::uniform3(prop::array::uniform3(-3i32..=3))
            .prop_map(|t| t.map(|p| v(p[0] as f64, p[1] as f64, p[2] as f64)))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(3000))]

        /// On small integer grids (many coplanar, touching and degenerate pairs) the exact
        /// test agrees with the separating-axis test in exact integers, for non-degenerate
        /// triangles (SAT's axis set is complete for those).
        #[test]
        fn agrees_with_separating_axes(t in tri(), u in tri()) {
            prop_assume!(!collinear3(t[0], t[1], t[2]) && !collinear3(u[0], u[1], u[2]));
            prop_assert_eq!(triangles_intersect(t, u), sat(t, u));
            prop_assert_eq!(triangles_intersect(t, u), triangles_intersect(u, t));
        }

        /// The BVH-driven checker finds exactly the brute-force pairs on random meshes
        /// (random triangles over few shared vertices: plenty of intersections, adjacency
        /// and coincident positions).
        #[test]
        fn bvh_checker_equals_brute_force(
            pts in prop::collection::vec(prop::array::uniform3(-4i32..=4), 4..24),
            faces in prop::collection::vec(prop::array::uniform3(0usize..1000), 1..40),
        ) {
            let mesh = TriMesh {
                positions: pts.iter().map(|p| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32 * 0.5)).collect(),
                indices: faces.iter().map(|f| f.map(|i| (i % pts.len()) as u32)).collect(),
                ..TriMesh::default()
            };
            prop_assert_eq!(self_intersections(&mesh), self_intersections_brute(&mesh));
        }
    }

    #[test]
    fn fold_over_found() {
        let orig = TriMesh {
            positions: vec![
                Vec3::new(0., 0., 0.),
                Vec3::new(1., 0., 0.),
                Vec3::new(0., 1., 0.),
            ],
            indices: vec![[0, 1, 2]],
            ..TriMesh::default()
        };
        let mut flipped = orig.clone();
        flipped.indices = vec![[0, 2, 1]];
        let r = check_folds(&orig, &flipped);
        assert_eq!(r.fold_overs, vec![0]);
        assert!(check_folds(&orig, &orig).fold_overs.is_empty());
    }
}
