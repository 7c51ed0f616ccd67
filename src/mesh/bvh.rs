//! A bounding volume hierarchy over a mesh's triangles for closest-point queries (the
//! point-to-surface distance of the Metro error; the local checks of QEM's
//! intersection guard).
//!
//! Written here rather than taken from a crate: the crates of the field are built for ray
//! casting (`bvh`, `obvhs`) or pull in a whole physics stack for point projection (`parry3d`
//! with nalgebra). What the error measurement needs is narrow and hot: an exact f64
//! point-to-triangle distance (positions are f32, but the Hausdorff figures are reported to
//! 1e-4 % of the diagonal, and sample points are computed in f64), a *warm start* from a
//! hint triangle (consecutive samples of one source triangle land on the same or a
//! neighbouring target triangle, so the first candidate bounds the search and most boxes
//! are pruned at once), an optional upper bound for early-out, and flat arrays built from
//! a `TriMesh` without copying it into another mesh type.
//!
//! Build: binned surface-area heuristic (12 bins on the longest centroid axis, leaves of at
//! most 4 triangles), serial and deterministic. Nodes are stored depth-first: the left child
//! follows its parent, the right child's index is stored.

use super::TriMesh;
use glam::{DVec3, Vec3, Vec3A};

const LEAF_MAX: usize = 4;
const BINS: usize = 12;

/// Boxes are f32 (SIMD): mesh positions are f32, so the boxes are exact, and the query
/// side pads them (see [`Bvh::closest`]) so that rounding the query point never prunes a box
/// that holds a closer triangle.
#[derive(Debug, Clone, Copy)]
struct Node {
    min: Vec3A,
    max: Vec3A,
    /// Leaf: first slot; inner: index of the right child.
    index: u32,
    /// Leaf: number of triangles (> 0); inner: 0.
    count: u32,
    /// Normal cone of the triangles below (axis x, y, z and a threshold t): every nonzero
    /// normal of a triangle below is within π/2 of any unit direction n̂ with n̂ · axis > t
    /// (see [`Bvh::never_faces_away`]). A threshold above 1 certifies nothing; below −1
    /// (no triangle below has a nonzero normal) everything.
    cone: [f32; 4],
}

/// One triangle in build order: a corner and two edge vectors, and its index in the mesh.
#[derive(Debug, Clone, Copy)]
struct Tri {
    a: DVec3,
    ab: DVec3,
    ac: DVec3,
    /// Bounding sphere (centre, radius) for a cheap lower bound before the exact test.
    centre: DVec3,
    radius: f64,
    id: u32,
}

/// The nearest surface point found by [`Bvh::closest`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Squared distance to the surface.
    pub dist2: f64,
    /// The nearest point.
    pub point: DVec3,
    /// The triangle it lies on (index into the mesh's triangles).
    pub triangle: u32,
    /// Build slot of that triangle: pass it back as the next query's hint.
    pub slot: u32,
}

/// A BVH over one mesh's triangles.
#[derive(Debug, Clone)]
pub struct Bvh {
    nodes: Vec<Node>,
    tris: Vec<Tri>,
    /// Largest |coordinate| of the mesh (scale of the f32 rounding error).
    magnitude: f32,
}

#[derive(Clone, Copy)]
struct Bounds {
    min: DVec3,
    max: DVec3,
}

impl Bounds {
    const EMPTY: Bounds = Bounds {
        min: DVec3::splat(f64::INFINITY),
        max: DVec3::splat(f64::NEG_INFINITY),
    };
    fn grow(&mut self, p: DVec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    fn join(&mut self, o: &Bounds) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }
    fn half_area(&self) -> f64 {
        let d = (self.max - self.min).max(DVec3::ZERO);
        d.x * d.y + d.y * d.z + d.z * d.x
    }
}

impl Bvh {
    /// Builds the hierarchy over `mesh`'s triangles (degenerate ones included: a sliver is
    /// still part of the surface).
    pub fn new(mesh: &TriMesh) -> Bvh {
        let mut tris: Vec<Tri> = (0..mesh.indices.len())
            .map(|f| {
                let [a, b, c] = mesh.corners(f);
                let centre = (a + b + c) / 3.0;
                let radius = (a - centre)
                    .length()
                    .max((b - centre).length())
                    .max((c - centre).length());
                Tri {
                    a,
                    ab: b - a,
                    ac: c - a,
                    centre,
                    radius,
                    id: f as u32,
                }
            })
            .collect();
        let mut boxes: Vec<(Bounds, DVec3)> = tris
            .iter()
            .map(|t| {
                let mut b = Bounds::EMPTY;
                b.grow(t.a);
                b.grow(t.a + t.ab);
                b.grow(t.a + t.ac);
                (b, (b.min + b.max) * 0.5)
            })
            .collect();
        let mut nodes = Vec::with_capacity(2 * tris.len() / LEAF_MAX + 1);
        if !tris.is_empty() {
            build(&mut nodes, &mut tris, &mut boxes, 0);
            build_cones(&mut nodes, &tris);
        }
        let magnitude = mesh
            .positions
            .iter()
            .fold(0.0f32, |m, p| m.max(p.abs().max_element()));
        Bvh {
            nodes,
            tris,
            magnitude,
        }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// True when built over no triangle.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// [`Bvh::closest`] with no `max_dist2`, found faster from a triangle near `p` (the
    /// build slot `hint` of an earlier [`Hit`]): its distance bounds the search. The result
    /// is the very one of `closest(p, None, f64::INFINITY)`, ties included (same walk, the
    /// first triangle of least distance; the bound only prunes boxes and triangles farther
    /// than it, and the least distance is at most the hint's), so a caller that must agree
    /// with an unhinted query elsewhere (the fold-over check of `compare --check-folds`)
    /// may use it. A `hint` out of range is ignored.
    pub fn closest_bounded_by(&self, p: DVec3, hint: u32) -> Option<Hit> {
        let bound = match self.tris.get(hint as usize) {
            // Above the hint's own distance by far more than its rounding.
            Some(t) => closest_on_tri(t, p).1 * (1.0 + 1e-6) + f64::MIN_POSITIVE,
            None => f64::INFINITY,
        };
        self.closest(p, None, bound)
            .or_else(|| self.closest(p, None, f64::INFINITY))
    }

    /// Whether the triangle [`Bvh::closest_bounded_by`]`(p, hint)` finds is sure not to face
    /// away from `n`: true only when every triangle that could be that hit has
    /// `n.dot(self.normal(slot)) >= 0` (computed as written), found without searching for
    /// the hit. False means "not shown", not "faces away": the caller then searches.
    ///
    /// Why it is exact: the hit lies no farther from `p` than the hint triangle, so it is in
    /// a node whose padded box is within that distance (the search's own pruning, with the
    /// same padding). Such a node is skipped when its normal cone shows that every normal
    /// below it is less than π/2 − 10⁻⁵ from `n` (margins far above the rounding of the
    /// cone, of n̂ and of the dot product: see `build_cones`); in a leaf, a triangle facing
    /// away is ruled out only by a distance (the search's conservative sphere bound, or its
    /// exact distance) above the hint's. The fold-over check of the quadric simplifier asks
    /// this first: on a smooth patch the cones decide a few levels above the leaves, with no
    /// point-to-triangle distance computed.
    pub fn never_faces_away(&self, p: DVec3, n: DVec3, hint: u32) -> bool {
        let (Some(t), Some(nh)) = (self.tris.get(hint as usize), direction(n)) else {
            return false;
        };
        let bound = closest_on_tri(t, p).1 * (1.0 + 1e-6) + f64::MIN_POSITIVE;
        let fbound = loosen(bound);
        let pf = p.as_vec3a();
        let scale = self.magnitude as f64 + p.abs().max_element();
        let pad =
            4.0 * f32::EPSILON * self.magnitude.max(pf.abs().max_element()) + f32::MIN_POSITIVE;
        let mut stack = [0u32; 64];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let ni = stack[sp];
            let node = &self.nodes[ni as usize];
            if box_dist2(node, pf, pad) > fbound {
                continue;
            }
            let [x, y, z, t] = node.cone;
            if nh.dot(DVec3::new(x as f64, y as f64, z as f64)) > t as f64 {
                continue;
            }
            if node.count == 0 {
                if sp + 2 > stack.len() {
                    // Deeper than the fixed stack: not shown (the caller searches).
                    return false;
                }
                stack[sp] = node.index;
                stack[sp + 1] = ni + 1;
                sp += 2;
                continue;
            }
            for s in node.index..node.index + node.count {
                let t = &self.tris[s as usize];
                if n.dot(t.ab.cross(t.ac)) >= 0.0 {
                    continue;
                }
                let len = (p - t.centre).length();
                let gap = len - t.radius - 1e-12 * (len + t.radius + scale);
                if gap > 0.0 && gap * gap > bound * (1.0 + 1e-9) {
                    continue;
                }
                if closest_on_tri(t, p).1 <= bound {
                    return false;
                }
            }
        }
        true
    }

    /// The (unnormalised) normal (b − a) × (c − a) of the triangle in build slot `slot`, from
    /// the hierarchy's own f64 copy of its corners: the very bits of computing it from the
    /// mesh's corners, without loading the mesh.
    pub fn normal(&self, slot: u32) -> DVec3 {
        let t = &self.tris[slot as usize];
        t.ab.cross(t.ac)
    }

    /// The build slot of each of the mesh's triangles (the inverse of [`Hit::triangle`]
    /// to [`Hit::slot`]), for seeding [`Bvh::closest_bounded_by`].
    pub fn slots(&self) -> Vec<u32> {
        let mut out = vec![u32::MAX; self.tris.len()];
        for (s, t) in self.tris.iter().enumerate() {
            out[t.id as usize] = s as u32;
        }
        out
    }

    /// The nearest point of the surface to `p`. `hint` (a previous [`Hit::slot`]) seeds the
    /// search; `max_dist2` stops it early: when nothing is closer than that, the result is
    /// None. Returns None for an empty hierarchy.
    pub fn closest(&self, p: DVec3, hint: Option<u32>, max_dist2: f64) -> Option<Hit> {
        if self.tris.is_empty() {
            return None;
        }
        let mut best: Option<Hit> = None;
        let mut bound = max_dist2;
        if let Some(h) = hint.filter(|&h| (h as usize) < self.tris.len()) {
            let (q, d2) = closest_on_tri(&self.tris[h as usize], p);
            if d2 <= bound {
                bound = d2;
                best = Some(self.hit(h, q, d2));
            }
        }
        // Box tests run in f32: pad every box by a few ulps of the largest coordinate in
        // play, so that the rounded query point never prunes a box it should open.
        let pf = p.as_vec3a();
        let scale = self.magnitude as f64 + p.abs().max_element();
        let pad =
            4.0 * f32::EPSILON * self.magnitude.max(pf.abs().max_element()) + f32::MIN_POSITIVE;
        let boxed = |n: &Node| box_dist2(n, pf, pad);
        let mut fbound = loosen(bound);
        let mut stack = [0u32; 64];
        let mut sp = 0usize;
        let mut node = 0u32;
        if boxed(&self.nodes[0]) > fbound {
            return best;
        }
        loop {
            let n = &self.nodes[node as usize];
            if n.count > 0 {
                for s in n.index..n.index + n.count {
                    let t = &self.tris[s as usize];
                    // Lower bound from the bounding sphere before the exact test, made
                    // conservative against rounding (of the distance, the radius and the
                    // exact test's own point) so that it never skips a triangle the exact
                    // test would take: the result is then the first triangle of least
                    // computed distance in the walk's order, whatever `max_dist2` above
                    // that least distance was given (see `closest_bounded_by`).
                    let len = (p - t.centre).length();
                    let gap = len - t.radius - 1e-12 * (len + t.radius + scale);
                    if gap > 0.0 && gap * gap > bound * (1.0 + 1e-9) {
                        continue;
                    }
                    let (q, d2) = closest_on_tri(t, p);
                    if d2 < bound || (best.is_none() && d2 <= bound) {
                        bound = d2;
                        fbound = loosen(bound);
                        best = Some(self.hit(s, q, d2));
                    }
                }
            } else {
                let (l, r) = (node + 1, n.index);
                let dl = boxed(&self.nodes[l as usize]);
                let dr = boxed(&self.nodes[r as usize]);
                let (near, far, dn, df) = if dl <= dr {
                    (l, r, dl, dr)
                } else {
                    (r, l, dr, dl)
                };
                if dn <= fbound {
                    if df <= fbound && sp < stack.len() {
                        stack[sp] = far;
                        sp += 1;
                    }
                    node = near;
                    continue;
                }
            }
            // Pop the next box still worth opening.
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                node = stack[sp];
                if boxed(&self.nodes[node as usize]) <= fbound {
                    break;
                }
            }
        }
    }

    /// Calls `f` with every triangle (mesh index) in a leaf whose box meets the closed box
    /// [`min`, `max`]: a superset of the triangles whose own boxes meet it (callers test
    /// those exactly). Boxes are padded by a few ulps of the largest coordinate, like
    /// [`Bvh::closest`], so rounding never drops a candidate.
    pub fn for_each_overlap(&self, min: Vec3, max: Vec3, mut f: impl FnMut(u32)) {
        if self.tris.is_empty() {
            return;
        }
        let (lo, hi) = (Vec3A::from(min), Vec3A::from(max));
        let pad = 4.0 * f32::EPSILON * self.magnitude.max(lo.abs().max(hi.abs()).max_element())
            + f32::MIN_POSITIVE;
        let (lo, hi) = (lo - Vec3A::splat(pad), hi + Vec3A::splat(pad));
        let meets = |n: &Node| !(n.min.cmpgt(hi).any() || lo.cmpgt(n.max).any());
        let mut stack = [0u32; 64];
        let mut spill: Vec<u32> = Vec::new();
        let mut sp = 0usize;
        let mut node = 0u32;
        loop {
            let n = &self.nodes[node as usize];
            if meets(n) {
                if n.count > 0 {
                    for s in n.index..n.index + n.count {
                        f(self.tris[s as usize].id);
                    }
                } else {
                    // A deeper tree than the fixed stack spills (Vec::new does not
                    // allocate until then): no subtree is ever dropped.
                    if sp < stack.len() {
                        stack[sp] = n.index;
                        sp += 1;
                    } else {
                        spill.push(n.index);
                    }
                    node += 1;
                    continue;
                }
            }
            if let Some(s) = spill.pop() {
                node = s;
            } else if sp == 0 {
                return;
            } else {
                sp -= 1;
                node = stack[sp];
            }
        }
    }

    fn hit(&self, slot: u32, point: DVec3, dist2: f64) -> Hit {
        Hit {
            dist2,
            point,
            triangle: self.tris[slot as usize].id,
            slot,
        }
    }
}

/// Recursive binned-SAH build of `tris[..]` (with their boxes and centroids); returns the
/// node index.
fn build(
    nodes: &mut Vec<Node>,
    tris: &mut [Tri],
    boxes: &mut [(Bounds, DVec3)],
    first: u32,
) -> u32 {
    let me = nodes.len() as u32;
    let mut bb = Bounds::EMPTY;
    let mut cb = Bounds::EMPTY;
    for (b, c) in boxes.iter() {
        bb.join(b);
        cb.grow(*c);
    }
    nodes.push(Node {
        min: bb.min.as_vec3a(),
        max: bb.max.as_vec3a(),
        index: first,
        count: tris.len() as u32,
        cone: [0.0, 0.0, 0.0, 2.0],
    });
    if tris.len() <= LEAF_MAX {
        return me;
    }
    let ext = cb.max - cb.min;
    let axis = if ext.x >= ext.y && ext.x >= ext.z {
        0
    } else if ext.y >= ext.z {
        1
    } else {
        2
    };
    let (lo, width) = (cb.min[axis], ext[axis]);
    let mid = if width <= 0.0 {
        // All centroids coincide: split the list in half.
        tris.len() / 2
    } else {
        let bin_of = |c: DVec3| (((c[axis] - lo) / width * BINS as f64) as usize).min(BINS - 1);
        let mut bins = [(Bounds::EMPTY, 0usize); BINS];
        for (b, c) in boxes.iter() {
            let k = bin_of(*c);
            bins[k].0.join(b);
            bins[k].1 += 1;
        }
        // Sweep: cost of splitting after bin k.
        let mut right_area = [0.0f64; BINS];
        let mut acc = Bounds::EMPTY;
        let mut cnt = 0;
        let mut right_count = [0usize; BINS];
        for k in (1..BINS).rev() {
            acc.join(&bins[k].0);
            cnt += bins[k].1;
            right_area[k] = acc.half_area();
            right_count[k] = cnt;
        }
        let mut best = (f64::INFINITY, 0usize);
        let mut acc = Bounds::EMPTY;
        let mut cnt = 0;
        for k in 0..BINS - 1 {
            acc.join(&bins[k].0);
            cnt += bins[k].1;
            if cnt == 0 || right_count[k + 1] == 0 {
                continue;
            }
            let cost = acc.half_area() * cnt as f64 + right_area[k + 1] * right_count[k + 1] as f64;
            if cost < best.0 {
                best = (cost, k);
            }
        }
        if best.0.is_infinite() {
            tris.len() / 2
        } else {
            // Stable partition by bin (keeps the order deterministic and simple).
            let split = best.1;
            let mut i = 0;
            for j in 0..tris.len() {
                if bin_of(boxes[j].1) <= split {
                    tris.swap(i, j);
                    boxes.swap(i, j);
                    i += 1;
                }
            }
            i
        }
    };
    let (lt, rt) = tris.split_at_mut(mid);
    let (lb, rb) = boxes.split_at_mut(mid);
    build(nodes, lt, lb, first);
    let right = build(nodes, rt, rb, first + mid as u32);
    let n = &mut nodes[me as usize];
    n.index = right;
    n.count = 0;
    me
}

/// The unit direction of `v`, scaled first so that a tiny nonzero vector has one too; None
/// for zero.
fn direction(v: DVec3) -> Option<DVec3> {
    let m = v.abs().max_element();
    (m > 0.0 && m.is_finite()).then(|| (v / m).normalize())
}

/// The angle between unit vectors (atan2: accurate near 0 and π, where acos is not).
fn angle(u: DVec3, d: DVec3) -> f64 {
    u.cross(d).length().atan2(u.dot(d))
}

/// Fills every node's normal cone (children follow their parents in `nodes`, so a reverse
/// sweep meets them first): a leaf's axis is the normalised sum of its triangles' unit
/// normals and its half-angle the largest angle to one of them; an inner node's axis is the
/// normalised sum of its children's axes and its half-angle covers theirs (the angle
/// between axes plus the child's half-angle). Stored as [`Node::cone`]: the axis in f32 and
/// the threshold sin(θ + 10⁻⁵) + 2·10⁻⁶, so that n̂ · axis above it puts n̂ within
/// π/2 − θ − 10⁻⁵ of the f64 axis (the f32 axis is within 1.1·10⁻⁷ of it, the half-angles
/// within 10⁻¹⁴ of the exact ones), hence within π/2 − 10⁻⁵ of every normal below.
fn build_cones(nodes: &mut [Node], tris: &[Tri]) {
    // Per node: (unit axis, half-angle); None when no triangle below has a normal.
    let mut cones: Vec<Option<(DVec3, f64)>> = vec![None; nodes.len()];
    let wide = (DVec3::Z, std::f64::consts::PI);
    for i in (0..nodes.len()).rev() {
        let node = nodes[i];
        let cone = if node.count > 0 {
            let ts = &tris[node.index as usize..(node.index + node.count) as usize];
            let dirs = || ts.iter().filter_map(|t| direction(t.ab.cross(t.ac)));
            if dirs().next().is_none() {
                None
            } else {
                Some(match dirs().sum::<DVec3>().try_normalize() {
                    Some(u) => (u, dirs().map(|d| angle(u, d)).fold(0.0, f64::max)),
                    None => wide,
                })
            }
        } else {
            match (cones[i + 1], cones[node.index as usize]) {
                (None, c) | (c, None) => c,
                (Some((ua, ta)), Some((ub, tb))) => Some(match (ua + ub).try_normalize() {
                    Some(u) => (u, (angle(u, ua) + ta).max(angle(u, ub) + tb)),
                    None => wide,
                }),
            }
        };
        cones[i] = cone;
        nodes[i].cone = match cone {
            None => [0.0, 0.0, 0.0, -2.0],
            Some((u, t)) if t + 1e-5 < std::f64::consts::FRAC_PI_2 => [
                u.x as f32,
                u.y as f32,
                u.z as f32,
                ((t + 1e-5).sin() + 2e-6) as f32,
            ],
            Some(_) => [0.0, 0.0, 0.0, 2.0],
        };
    }
}

/// Squared distance from `p` to box `n` grown by `pad` on every side.
#[inline]
fn box_dist2(n: &Node, p: Vec3A, pad: f32) -> f32 {
    let d = ((n.min - p).max(p - n.max) - Vec3A::splat(pad)).max(Vec3A::ZERO);
    d.length_squared()
}

/// An f64 squared distance as an f32 bound that is never smaller (rounding up by a margin
/// larger than the f32 error of a squared box distance).
#[inline]
fn loosen(bound: f64) -> f32 {
    if bound >= f32::MAX as f64 {
        f32::INFINITY
    } else {
        (bound * (1.0 + 1e-5)) as f32 + f32::MIN_POSITIVE
    }
}

#[inline]
fn closest_on_tri(t: &Tri, p: DVec3) -> (DVec3, f64) {
    let q = closest_point_on_triangle(p, t.a, t.ab, t.ac);
    (q, (q - p).length_squared())
}

/// The point of triangle (a, a + ab, a + ac) nearest to `p` (Ericson, Real-Time Collision
/// Detection §5.1.5, in f64; degenerate triangles fall back to their edges).
#[inline]
pub fn closest_point_on_triangle(p: DVec3, a: DVec3, ab: DVec3, ac: DVec3) -> DVec3 {
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = ap - ab;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return a + ab;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return a + ab * v;
    }
    let cp = ap - ac;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return a + ac;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return a + ac * w;
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return a + ab + (ac - ab) * w;
    }
    let denom = va + vb + vc;
    if denom > 0.0 && denom.is_finite() {
        let v = vb / denom;
        let w = vc / denom;
        return a + ab * v + ac * w;
    }
    // Degenerate (zero-area) triangle: the nearest of its three edges.
    let seg = |s: DVec3, d: DVec3| {
        let l = d.length_squared();
        let t = if l > 0.0 {
            ((p - s).dot(d) / l).clamp(0.0, 1.0)
        } else {
            0.0
        };
        s + d * t
    };
    let cands = [seg(a, ab), seg(a, ac), seg(a + ab, ac - ab)];
    cands
        .into_iter()
        .min_by(|x, y| {
            (*x - p)
                .length_squared()
                .total_cmp(&(*y - p).length_squared())
        })
        .unwrap_or(a)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use glam::Vec3;

    /// The slow, obvious twin: every triangle.
    fn brute(mesh: &TriMesh, p: DVec3) -> f64 {
        (0..mesh.indices.len())
            .map(|f| {
                let [a, b, c] = mesh.corners(f);
                (closest_point_on_triangle(p, a, b - a, c - a) - p).length_squared()
            })
            .fold(f64::INFINITY, f64::min)
    }

    fn random_mesh(rng: &mut SplitMix64, n: usize) -> TriMesh {
        let mut m = TriMesh::default();
        for _ in 0..n {
            let base = Vec3::new(rng.unit() as f32, rng.unit() as f32, rng.unit() as f32) * 10.0;
            let k = m.positions.len() as u32;
            for _ in 0..3 {
                m.positions.push(
                    base + Vec3::new(rng.unit() as f32, rng.unit() as f32, rng.unit() as f32),
                );
            }
            m.indices.push([k, k + 1, k + 2]);
        }
        // A degenerate sliver and a point-triangle.
        let k = m.positions.len() as u32;
        m.positions
            .extend([Vec3::ZERO, Vec3::X, Vec3::X * 2.0, Vec3::splat(3.0)]);
        m.indices.push([k, k + 1, k + 2]);
        m.indices.push([k + 3, k + 3, k + 3]);
        m
    }

    #[test]
    fn agrees_with_brute_force() {
        let mut rng = SplitMix64::new(7);
        let m = random_mesh(&mut rng, 300);
        let bvh = Bvh::new(&m);
        let mut hint = None;
        for _ in 0..2000 {
            let p = DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 14.0 - 2.0;
            let hit = bvh.closest(p, hint, f64::INFINITY).unwrap();
            let want = brute(&m, p);
            assert!(
                (hit.dist2 - want).abs() <= 1e-12 * want.max(1.0),
                "{} vs {want}",
                hit.dist2
            );
            assert!(((hit.point - p).length_squared() - hit.dist2).abs() < 1e-9);
            hint = Some(hit.slot);
        }
    }

    #[test]
    fn bound_prunes_and_reports_nothing_farther() {
        let mut rng = SplitMix64::new(3);
        let m = random_mesh(&mut rng, 50);
        let bvh = Bvh::new(&m);
        let p = DVec3::splat(100.0);
        let d2 = brute(&m, p);
        assert!(bvh.closest(p, None, d2 * 0.99).is_none());
        assert_eq!(bvh.closest(p, None, d2 * 1.01).unwrap().dist2, d2);
    }

    /// The hinted search gives the unhinted one's very hit (the fold-over check relies on
    /// it), ties included: on a grid of triangles, points above shared vertices and edges
    /// are equally near to several triangles.
    #[test]
    fn bounded_by_a_hint_equals_the_unhinted_search() {
        let mut rng = SplitMix64::new(11);
        let mut m = random_mesh(&mut rng, 200);
        let n = 12u32;
        let k = m.positions.len() as u32;
        for j in 0..=n {
            for i in 0..=n {
                m.positions
                    .push(Vec3::new(i as f32, j as f32, 0.5 * (i % 3) as f32));
            }
        }
        for j in 0..n {
            for i in 0..n {
                let v = k + j * (n + 1) + i;
                m.indices.push([v, v + 1, v + n + 2]);
                m.indices.push([v, v + n + 2, v + n + 1]);
            }
        }
        let bvh = Bvh::new(&m);
        let slots = bvh.slots();
        assert!(slots.iter().all(|&s| (s as usize) < bvh.len()));
        for q in 0..3000 {
            let p = if q % 2 == 0 {
                DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 14.0 - 2.0
            } else {
                // Above a grid vertex or edge midpoint: ties.
                let (i, j) = ((rng.unit() * 24.0).floor(), (rng.unit() * 24.0).floor());
                DVec3::new(i * 0.5, j * 0.5, rng.unit() * 3.0 - 1.0)
            };
            let want = bvh.closest(p, None, f64::INFINITY).unwrap();
            let hint = slots[(rng.unit() * m.indices.len() as f64) as usize % slots.len()];
            assert_eq!(bvh.closest_bounded_by(p, hint), Some(want));
            assert_eq!(bvh.closest_bounded_by(p, want.slot), Some(want));
        }
    }

    /// A UV sphere of radius 3 around (5, 5, 5), outward faces: smooth, so the cones decide.
    fn sphere(rings: u32, segs: u32) -> TriMesh {
        let mut m = TriMesh::default();
        for i in 0..=rings {
            let th = std::f32::consts::PI * i as f32 / rings as f32;
            for j in 0..segs {
                let ph = std::f32::consts::TAU * j as f32 / segs as f32;
                let d = Vec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
                m.positions.push(Vec3::splat(5.0) + d * 3.0);
            }
        }
        for i in 0..rings {
            for j in 0..segs {
                let (a, b) = (i * segs + j, i * segs + (j + 1) % segs);
                let (c, d) = (a + segs, b + segs);
                m.indices.push([a, c, b]);
                m.indices.push([b, c, d]);
            }
        }
        m
    }

    /// `never_faces_away` says true only when the hit of the hinted search (the fold-over
    /// check's) has a normal not facing away from n: on a smooth sphere, where it decides
    /// most queries, and on random triangle soup, where the cones are wide; with directions
    /// near the surface's normal, opposite to it and random, and random hints.
    #[test]
    fn never_faces_away_only_when_the_hit_does_not() {
        let mut rng = SplitMix64::new(5);
        let soup = random_mesh(&mut rng, 300);
        for (m, smooth) in [(sphere(40, 80), true), (soup, false)] {
            let bvh = Bvh::new(&m);
            let (mut shown, mut away) = (0, 0);
            for q in 0..4000 {
                let dir = (DVec3::new(rng.unit(), rng.unit(), rng.unit()) - DVec3::splat(0.5))
                    .normalize_or(DVec3::X);
                let p = DVec3::splat(5.0) + dir * (1.5 + 3.0 * rng.unit());
                let out = dir;
                let r = DVec3::new(rng.unit(), rng.unit(), rng.unit()) - DVec3::splat(0.5);
                let n = match q % 3 {
                    0 => out + r * 0.5,
                    1 => -out + r * 0.5,
                    _ => r,
                };
                // A good hint (the nearest) or any.
                let hint = match q % 2 {
                    0 => bvh.closest(p, None, f64::INFINITY).unwrap().slot,
                    _ => (rng.unit() * bvh.len() as f64) as u32 % bvh.len() as u32,
                };
                let hit = bvh.closest_bounded_by(p, hint).unwrap();
                let faces_away = n.dot(bvh.normal(hit.slot)) < 0.0;
                away += faces_away as usize;
                if bvh.never_faces_away(p, n, hint) {
                    assert!(!faces_away, "query {q}: shown, but the hit faces away");
                    shown += 1;
                }
            }
            assert!(away > 500, "{away}");
            if smooth {
                assert!(shown > 1000, "the cones decide too little: {shown}");
            }
        }
    }

    #[test]
    fn triangle_regions() {
        let (a, ab, ac) = (DVec3::ZERO, DVec3::X, DVec3::Y);
        let c = |p: DVec3| closest_point_on_triangle(p, a, ab, ac);
        assert_eq!(c(DVec3::new(0.25, 0.25, 3.0)), DVec3::new(0.25, 0.25, 0.0));
        assert_eq!(c(DVec3::new(-1.0, -1.0, 0.0)), DVec3::ZERO);
        assert_eq!(c(DVec3::new(2.0, -1.0, 0.0)), DVec3::X);
        assert_eq!(c(DVec3::new(0.5, -1.0, 1.0)), DVec3::new(0.5, 0.0, 0.0));
        assert_eq!(c(DVec3::new(1.0, 1.0, 0.0)), DVec3::new(0.5, 0.5, 0.0));
    }
}
