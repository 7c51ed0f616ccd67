//! The collapse engine: flat per-vertex and per-face arrays, vertex → corner lists as
//! intrusive linked lists (a collapse splices one list into another: no allocation), a
//! binary heap of candidates with per-vertex stamps for lazy invalidation, and scratch
//! vectors reused across collapses. See the module above for the order and the checks.

use super::{QemParams, QemReport, QemResult, QuadricMerge};
use crate::mesh::adjacency::EdgeFaces;
use crate::mesh::TriMesh;
use crate::simplify::prep::Prepared;
use crate::simplify::quadric::Quadric;
use glam::{DVec3, Vec2, Vec3};
use std::cmp::Reverse;
use std::collections::BinaryHeap;

const NONE: u32 = u32::MAX;

/// A triangle is "of zero area" after a collapse when twice its area is below this fraction
/// of the squared bbox diagonal.
const ZERO_AREA: f64 = 1e-12;

/// Weight of a border edge's perpendicular plane, in units of its squared length: 10
/// measured best on bunny (its holes) at 50 % and 10 % (symmetric max 0.113 → 0.038 % and
/// 0.232 → 0.202 % of the diagonal against 1; 100 and 1000 gave the same max and a
/// slightly larger mean).
const BORDER_WEIGHT: f64 = 10.0;

/// The optimal placement's 3 × 3 system counts as ill-conditioned when |det A| is below
/// this fraction of (trace A / 3)³ (the determinant of a well-conditioned A of that size).
const ILL_CONDITIONED: f64 = 1e-6;

/// Which validity checks run before a collapse (all by default; the tests switch single
/// ones off to see them matter).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Checks {
    /// The link condition, the pinch rule and the duplicate-triangle rule.
    pub topology: bool,
    /// No triangle normal turns by 90° or more.
    pub flips: bool,
    /// No triangle of zero area.
    pub zero_area: bool,
}

impl Default for Checks {
    fn default() -> Checks {
        Checks {
            topology: true,
            flips: true,
            zero_area: true,
        }
    }
}

/// One collapse, as input vertices: enough to replay the sequence on another
/// representation of the mesh (progressive strips).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CollapseStep {
    /// The input vertex standing for the survivor (its welded representative).
    pub kept: u32,
    /// The input vertex standing for the vertex removed.
    pub removed: u32,
    /// Where the survivor is placed.
    pub position: DVec3,
}

/// A candidate in the heap: ordered by cost (non-negative f64 bits order as the numbers),
/// then by its vertices; the stamps say which state it was computed from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct Entry {
    cost: u64,
    a: u32,
    b: u32,
    sa: u32,
    sb: u32,
}

/// A candidate collapse: the merged quadric, the placed point and its cost.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    q: Quadric,
    p: DVec3,
    cost: f64,
}

/// The state of an edge-collapse simplification.
pub struct Collapse<'m> {
    mesh: &'m TriMesh,
    params: QemParams,
    /// Public so that tests and later stages can switch checks.
    pub checks: Checks,
    // Per dense vertex.
    pos: Vec<DVec3>,
    quad: Vec<Quadric>,
    alive: Vec<bool>,
    border: Vec<bool>,
    locked: Vec<bool>,
    stamp: Vec<u32>,
    /// Refused edges at each vertex (so that only vertices with some are searched).
    refused_at: Vec<u32>,
    head: Vec<u32>,
    /// The input vertex whose attributes a dense vertex carries.
    source: Vec<u32>,
    normals: Option<Vec<Vec3>>,
    colors: Option<Vec<[f32; 4]>>,
    uvs: Option<Vec<Vec2>>,
    // Per face and corner.
    faces: Vec<[u32; 3]>,
    face_alive: Vec<bool>,
    orig_face: Vec<u32>,
    next: Vec<u32>,
    // Candidates and scratch.
    heap: BinaryHeap<Reverse<Entry>>,
    /// Edges refused when they came up and not pushed again since.
    refused: rustc_hash::FxHashSet<u64>,
    ring: Vec<u32>,
    nb: Vec<u32>,
    nb2: Vec<u32>,
    pairs: Vec<[u32; 2]>,
    // Figures.
    tris: usize,
    collapses: usize,
    rejected: usize,
    max_error: f64,
    non_manifold: usize,
    area_eps: f64,
    /// The sequence of collapses (survivor, removed), kept for the twin test.
    pub log: Vec<(u32, u32)>,
    /// Whether `steps` is filled (off by default: most runs need no replay).
    pub record: bool,
    /// With `record`: every collapse in order, as input vertices.
    pub steps: Vec<CollapseStep>,
    /// The exact intersection check's boxes, when `params.check_intersections`.
    guard: Option<super::guard::Guard>,
    /// The input's closest-point hierarchy, for the fold-over half of that check.
    orig_bvh: Option<crate::mesh::Bvh>,
}

impl<'m> Collapse<'m> {
    /// Sets up the state for `prep`'s mesh.
    pub fn new(prep: &Prepared<'m>, params: &QemParams) -> Collapse<'m> {
        let mesh = prep.mesh;
        let n = prep.active.len();
        let qs = prep.quadrics();
        let pos: Vec<DVec3> = prep.dense_pos.iter().map(|p| p.as_dvec3()).collect();
        let quad: Vec<Quadric> = prep.active.iter().map(|&v| qs[v as usize]).collect();
        // Triangles with a repeated (welded) corner have no area and no edges to collapse.
        let mut faces = Vec::with_capacity(prep.dense_faces.len());
        let mut orig_face = Vec::with_capacity(prep.dense_faces.len());
        for (f, t) in prep.dense_faces.iter().enumerate() {
            if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
                faces.push(*t);
                orig_face.push(f as u32);
            }
        }
        let mut head = vec![NONE; n];
        let mut next = vec![NONE; faces.len() * 3];
        for (f, t) in faces.iter().enumerate() {
            for k in 0..3 {
                let c = 3 * f + k;
                next[c] = head[t[k] as usize];
                head[t[k] as usize] = c as u32;
            }
        }
        // Manifold analysis: border edges, non-manifold edges, and fans that are neither a
        // disk nor a half-disk (a vertex with f triangles has f neighbours inside a surface,
        // f + 1 on a border with two border edges).
        let ef = EdgeFaces::new(&faces);
        let mut border = vec![false; n];
        let mut locked = vec![false; n];
        let mut border_edges = vec![0u32; n];
        let mut degree = vec![0u32; n];
        let mut fcount = vec![0u32; n];
        for (e, &[a, b]) in ef.edges().iter().enumerate() {
            degree[a as usize] += 1;
            degree[b as usize] += 1;
            match ef.faces(e as u32).len() {
                1 => {
                    border[a as usize] = true;
                    border[b as usize] = true;
                    border_edges[a as usize] += 1;
                    border_edges[b as usize] += 1;
                }
                2 => {}
                _ => {
                    locked[a as usize] = true;
                    locked[b as usize] = true;
                }
            }
        }
        for t in &faces {
            for &v in t {
                fcount[v as usize] += 1;
            }
        }
        for v in 0..n {
            let disk = border_edges[v] == 0 && degree[v] == fcount[v];
            let half = border_edges[v] == 2 && degree[v] == fcount[v] + 1;
            if !(disk || half) {
                locked[v] = true;
            }
        }
        let non_manifold = locked.iter().filter(|&&l| l).count();
        // Border planes: the preparation adds, at a border edge, the plane through the edge
        // perpendicular to its triangle with weight |e|²; the engine adds it again
        // BORDER_WEIGHT − 1 times (see BORDER_WEIGHT).
        let mut quad = quad;
        let extra = BORDER_WEIGHT - 1.0;
        if extra > 0.0 {
            for (e, &[a, b]) in ef.edges().iter().enumerate() {
                let fs = ef.faces(e as u32);
                if fs.len() != 1 {
                    continue;
                }
                let t = faces[fs[0] as usize];
                let [p0, p1, p2] = t.map(|v| pos[v as usize]);
                let n = (p1 - p0).cross(p2 - p0).normalize_or_zero();
                let (pa, pb) = (pos[a as usize], pos[b as usize]);
                let m = (pb - pa).cross(n).normalize_or_zero();
                if n == DVec3::ZERO || m == DVec3::ZERO {
                    continue;
                }
                let q = Quadric::plane(m, -m.dot(pa), extra * (pb - pa).length_squared());
                quad[a as usize] += q;
                quad[b as usize] += q;
            }
        }
        // Attribute seams: a welded vertex whose input copies differ in an attribute keeps
        // all its copies and is never moved (seams are not collapsed across).
        let source: Vec<u32> = prep.active.clone();
        for v in 0..mesh.vertex_count() {
            let w = prep.weld[v] as usize;
            if w == v {
                continue;
            }
            let differ = mesh.normals.as_ref().is_some_and(|a| a[v] != a[w])
                || mesh.colors.as_ref().is_some_and(|a| a[v] != a[w])
                || mesh.uvs.as_ref().is_some_and(|a| a[v] != a[w]);
            let d = prep.dense_of[w];
            if differ && d != NONE {
                locked[d as usize] = true;
            }
        }
        fn pick<T: Copy>(a: &[T], source: &[u32]) -> Vec<T> {
            source.iter().map(|&v| a[v as usize]).collect()
        }
        let diag = prep.bounds.diagonal();
        let tris = faces.len();
        let mut c = Collapse {
            mesh,
            params: params.clone(),
            checks: Checks::default(),
            pos,
            quad,
            alive: vec![true; n],
            border,
            locked,
            stamp: vec![0; n],
            refused_at: vec![0; n],
            head,
            normals: mesh.normals.as_deref().map(|a| pick(a, &source)),
            colors: mesh.colors.as_deref().map(|a| pick(a, &source)),
            uvs: mesh.uvs.as_deref().map(|a| pick(a, &source)),
            source,
            face_alive: vec![true; faces.len()],
            faces,
            orig_face,
            next,
            heap: BinaryHeap::new(),
            refused: Default::default(),
            ring: Vec::new(),
            nb: Vec::new(),
            nb2: Vec::new(),
            pairs: Vec::new(),
            tris,
            collapses: 0,
            rejected: 0,
            max_error: 0.0,
            non_manifold,
            area_eps: ZERO_AREA * diag * diag,
            log: Vec::new(),
            record: false,
            steps: Vec::new(),
            guard: None,
            orig_bvh: None,
        };
        if params.check_intersections {
            let mut g = super::guard::Guard::default();
            g.build(c.faces.len(), |_| true, |f| c.face_box(f));
            c.guard = Some(g);
            c.orig_bvh = Some(crate::mesh::Bvh::new(mesh));
        }
        c.heap.reserve(ef.len());
        for &[a, b] in ef.edges() {
            c.push(a.min(b), a.max(b));
        }
        c
    }

    /// The box of face `f` now.
    fn face_box(&self, f: usize) -> (DVec3, DVec3) {
        let [a, b, c] = self.faces[f].map(|u| self.pos[u as usize]);
        (a.min(b).min(c), a.max(b).max(c))
    }

    /// With the intersection check: whether collapsing (a, b) to `c.p` makes a moved face
    /// meet a live face that shares no vertex with it (exact predicates, on the f32 point
    /// the output will hold: `candidate` rounds it). Faces that share a vertex are left to
    /// the flip and zero-area checks, as `compare --check-folds` leaves them. Since faces
    /// only ever gain common vertices by collapses, every pair of non-adjacent output faces
    /// that meets was either tested here when the later of the two last moved, or already
    /// met in the input.
    ///
    /// It also refuses a moved face that folds over against the input: a normal more than
    /// 90° from the input's at the input point nearest to the face's centroid (the very
    /// computation of `compare --check-folds`, on the same f32 corners in the same order, so
    /// an output face that was ever moved passes that checker). The flip check compares
    /// with the current mesh only, which drifts from the input over many collapses.
    fn intersects(&mut self, a: u32, b: u32, c: &Candidate) -> bool {
        let Some(mut guard) = self.guard.take() else {
            return false;
        };
        let mut hit = false;
        for v in [a, b] {
            self.each_face(v, |f| {
                let t = self.faces[f];
                if hit || t.contains(&a) && t.contains(&b) {
                    return;
                }
                let ids = t.map(|u| if u == b { a } else { u });
                let tri = t.map(|u| {
                    if u == a || u == b {
                        c.p
                    } else {
                        self.pos[u as usize]
                    }
                });
                if let Some(bvh) = &self.orig_bvh {
                    let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
                    if n != DVec3::ZERO {
                        let centre = (tri[0] + tri[1] + tri[2]) / 3.0;
                        if let Some(h) = bvh.closest(centre, None, f64::INFINITY) {
                            let [p, q, r] = self.mesh.corners(h.triangle as usize);
                            if n.dot((q - p).cross(r - p)) < 0.0 {
                                hit = true;
                                return;
                            }
                        }
                    }
                }
                let lo = tri[0].min(tri[1]).min(tri[2]);
                let hi = tri[0].max(tri[1]).max(tri[2]);
                hit = guard.any(lo, hi, |g| {
                    let g = g as usize;
                    if !self.face_alive[g] {
                        return false;
                    }
                    let gt = self.faces[g];
                    if gt
                        .iter()
                        .any(|&u| ids.contains(&if u == b { a } else { u }))
                    {
                        return false;
                    }
                    crate::mesh::intersect::triangles_intersect(
                        tri,
                        gt.map(|u| self.pos[u as usize]),
                    )
                });
            });
        }
        self.guard = Some(guard);
        hit
    }

    /// After a collapse into `s`: the moved faces' boxes grow into the guard (rebuilt when
    /// half of its faces have died).
    fn refit(&mut self, s: u32) {
        let Some(mut guard) = self.guard.take() else {
            return;
        };
        if guard.stale(self.tris) {
            guard.build(
                self.faces.len(),
                |f| self.face_alive[f],
                |f| self.face_box(f),
            );
        } else {
            self.each_face(s, |f| {
                let (lo, hi) = self.face_box(f);
                guard.grow(f, lo, hi);
            });
        }
        self.guard = Some(guard);
    }

    /// Triangles now.
    pub fn triangles(&self) -> usize {
        self.tris
    }

    /// The merged quadric of `a` and `b`.
    #[inline]
    fn merged(&self, a: u32, b: u32) -> Quadric {
        let q = self.quad[a as usize] + self.quad[b as usize];
        match self.params.merge {
            QuadricMerge::Sum => q,
            QuadricMerge::Mean => q * 0.5,
        }
    }

    /// The collapse of edge (a, b): merged quadric, placement and cost; `None` when the
    /// edge may not be collapsed whatever the neighbourhood (a locked vertex, two pinned
    /// border vertices).
    fn candidate(&self, a: u32, b: u32) -> Option<Candidate> {
        let (ua, ub) = (a as usize, b as usize);
        if self.locked[ua] || self.locked[ub] {
            return None;
        }
        let q = self.merged(a, b);
        let (pa, pb) = (self.pos[ua], self.pos[ub]);
        let pinned = self.params.lock_border;
        let p = match (pinned && self.border[ua], pinned && self.border[ub]) {
            (true, true) => return None,
            (true, false) => pa,
            (false, true) => pb,
            (false, false) => match self.params.placement {
                super::Placement::Optimal => optimal(&q, pa, pb),
                super::Placement::Endpoint => {
                    if q.eval(pb) < q.eval(pa) {
                        pb
                    } else {
                        pa
                    }
                }
            },
        };
        // With the intersection check, the point is tested where the output will hold it.
        let p = if self.params.check_intersections {
            p.as_vec3().as_dvec3()
        } else {
            p
        };
        Some(Candidate {
            q,
            p,
            cost: match self.params.cost {
                super::Cost::Quadric => q.eval(p),
                super::Cost::Distance => {
                    let e = error(&q, p);
                    e * e
                }
            },
        })
    }

    /// Pushes edge (a, b), a < b, with its current cost.
    fn push(&mut self, a: u32, b: u32) {
        if let Some(c) = self.candidate(a, b) {
            self.heap.push(Reverse(Entry {
                cost: c.cost.to_bits(),
                a,
                b,
                sa: self.stamp[a as usize],
                sb: self.stamp[b as usize],
            }));
        }
    }

    /// Calls `f` on every live face of `v` (as a face index).
    #[inline]
    fn each_face(&self, v: u32, mut f: impl FnMut(usize)) {
        let mut c = self.head[v as usize];
        while c != NONE {
            let face = c as usize / 3;
            if self.face_alive[face] {
                f(face);
            }
            c = self.next[c as usize];
        }
    }

    /// The neighbours of `v`, sorted, into `out`.
    fn neighbours(&self, v: u32, out: &mut Vec<u32>) {
        out.clear();
        self.each_face(v, |f| {
            out.extend(self.faces[f].iter().filter(|&&u| u != v));
        });
        out.sort_unstable();
        out.dedup();
    }

    /// Whether collapsing (a, b) to `c` passes the checks.
    fn valid(&mut self, a: u32, b: u32, c: &Candidate) -> bool {
        if let Some(e) = self.params.max_error {
            if error(&c.q, c.p) > e {
                return false;
            }
        }
        let mut shared = 0;
        self.each_face(a, |f| {
            if self.faces[f].contains(&b) {
                shared += 1;
            }
        });
        if shared == 0 || shared > 2 {
            return false;
        }
        if self.checks.topology {
            if shared == 2 && self.border[a as usize] && self.border[b as usize] {
                return false;
            }
            // Link condition: the common neighbours are the far corners of the edge's
            // triangles, no more.
            let (mut na, mut nb) = (std::mem::take(&mut self.nb), std::mem::take(&mut self.nb2));
            self.neighbours(a, &mut na);
            self.neighbours(b, &mut nb);
            let common = count_common(&na, &nb); // a, b are not in their own lists
            self.nb = na;
            self.nb2 = nb;
            if common != shared {
                return false;
            }
            // No duplicate triangle: a face (a, x, y) and a face (b, x, y) would both become
            // (s, x, y).
            let mut pairs = std::mem::take(&mut self.pairs);
            pairs.clear();
            for (v, other) in [(a, b), (b, a)] {
                self.each_face(v, |f| {
                    let t = self.faces[f];
                    if !t.contains(&other) {
                        let mut r: [u32; 2] = [0; 2];
                        let mut k = 0;
                        for &u in &t {
                            if u != v {
                                r[k] = u;
                                k += 1;
                            }
                        }
                        pairs.push([r[0].min(r[1]), r[0].max(r[1])]);
                    }
                });
            }
            pairs.sort_unstable();
            let dup = pairs.windows(2).any(|w| w[0] == w[1]);
            self.pairs = pairs;
            if dup {
                return false;
            }
        }
        if self.checks.flips || self.checks.zero_area {
            for v in [a, b] {
                let mut ok = true;
                self.each_face(v, |f| {
                    let t = self.faces[f];
                    if !ok || t.contains(&a) && t.contains(&b) {
                        return;
                    }
                    let old = t.map(|u| self.pos[u as usize]);
                    let new = t.map(|u| if u == v { c.p } else { self.pos[u as usize] });
                    let n0 = (old[1] - old[0]).cross(old[2] - old[0]);
                    let n1 = (new[1] - new[0]).cross(new[2] - new[0]);
                    if self.checks.zero_area && n1.length() <= self.area_eps {
                        ok = false;
                    }
                    if self.checks.flips && n0.dot(n1) <= 0.0 {
                        ok = false;
                    }
                });
                if !ok {
                    return false;
                }
            }
        }
        !self.intersects(a, b, c)
    }

    /// Collapses (a, b), a < b, to `c`: `a` survives.
    fn collapse(&mut self, a: u32, b: u32, c: &Candidate) {
        let (s, g) = (a, b);
        // Attributes, interpolated at the placed point's parameter on the edge.
        let (ps, pg) = (self.pos[s as usize], self.pos[g as usize]);
        let e = pg - ps;
        let t = if e.length_squared() > 0.0 {
            ((c.p - ps).dot(e) / e.length_squared()).clamp(0.0, 1.0) as f32
        } else {
            0.0
        };
        let (us, ug) = (s as usize, g as usize);
        if let Some(n) = &mut self.normals {
            n[us] = n[us].lerp(n[ug], t).normalize_or_zero();
        }
        if let Some(col) = &mut self.colors {
            let (x, y) = (col[us], col[ug]);
            col[us] = std::array::from_fn(|k| x[k] + (y[k] - x[k]) * t);
        }
        if let Some(uv) = &mut self.uvs {
            uv[us] = uv[us].lerp(uv[ug], t);
        }
        // Faces of g: those on the edge die, the others move to s.
        let mut cnr = self.head[ug];
        let mut moved = NONE;
        while cnr != NONE {
            let nxt = self.next[cnr as usize];
            let f = cnr as usize / 3;
            if self.face_alive[f] {
                if self.faces[f].contains(&s) {
                    self.face_alive[f] = false;
                    self.tris -= 1;
                } else {
                    self.faces[f][cnr as usize % 3] = s;
                    self.next[cnr as usize] = moved;
                    moved = cnr;
                }
            }
            cnr = nxt;
        }
        self.head[ug] = NONE;
        // s's own list without the dead faces, then the moved corners.
        let mut cnr = self.head[us];
        while cnr != NONE {
            let nxt = self.next[cnr as usize];
            if self.face_alive[cnr as usize / 3] {
                self.next[cnr as usize] = moved;
                moved = cnr;
            }
            cnr = nxt;
        }
        self.head[us] = moved;
        self.pos[us] = c.p;
        self.quad[us] = c.q;
        self.border[us] |= self.border[ug];
        self.alive[ug] = false;
        self.collapses += 1;
        self.max_error = self.max_error.max(error(&c.q, c.p));
        self.log.push((s, g));
        if self.record {
            self.steps.push(CollapseStep {
                kept: self.source[us],
                removed: self.source[ug],
                position: c.p,
            });
        }
        self.refit(s);
    }

    /// After a collapse into `s`: the edges of `s` get a new cost (its stamp changes, so
    /// their old entries are skipped), and the edges of its neighbours that were refused
    /// before are pushed again (their validity may have changed; their cost has not, so
    /// the entries still in the heap stay as they are).
    fn update(&mut self, s: u32) {
        let mut ring = std::mem::take(&mut self.ring);
        self.neighbours(s, &mut ring);
        let us = s as usize;
        self.stamp[us] = self.stamp[us].wrapping_add(1);
        for &x in &ring {
            let key = edge_key(s, x);
            if self.refused_at[us] > 0 && self.refused.remove(&key) {
                self.refused_at[us] -= 1;
                self.refused_at[x as usize] -= 1;
            }
            self.push(s.min(x), s.max(x));
        }
        let mut nb = std::mem::take(&mut self.nb);
        for &w in &ring {
            if self.refused_at[w as usize] == 0 {
                continue;
            }
            self.neighbours(w, &mut nb);
            for &x in &nb {
                if x != s && self.refused.remove(&edge_key(w, x)) {
                    self.refused_at[w as usize] -= 1;
                    self.refused_at[x as usize] -= 1;
                    self.push(w.min(x), w.max(x));
                }
            }
        }
        self.nb = nb;
        self.ring = ring;
    }

    /// The heap-driven loop: collapse the least-cost valid edge until `target` triangles
    /// or no valid collapse is left.
    pub fn run_fast(&mut self, target: usize) {
        while self.tris > target {
            let Some(Reverse(e)) = self.heap.pop() else {
                break;
            };
            let (ua, ub) = (e.a as usize, e.b as usize);
            if !self.alive[ua]
                || !self.alive[ub]
                || self.stamp[ua] != e.sa
                || self.stamp[ub] != e.sb
            {
                continue;
            }
            let Some(c) = self.candidate(e.a, e.b) else {
                continue;
            };
            if self.valid(e.a, e.b, &c) {
                self.collapse(e.a, e.b, &c);
                self.update(e.a);
            } else {
                self.rejected += 1;
                if self.refused.insert(edge_key(e.a, e.b)) {
                    self.refused_at[ua] += 1;
                    self.refused_at[ub] += 1;
                }
            }
        }
    }

    /// The slow, obvious loop: every step, every edge's cost and validity, take the least.
    pub fn run_slow(&mut self, target: usize) {
        let mut edges: Vec<[u32; 2]> = Vec::new();
        while self.tris > target {
            edges.clear();
            for (f, t) in self.faces.iter().enumerate() {
                if self.face_alive[f] {
                    for k in 0..3 {
                        let (u, v) = (t[k], t[(k + 1) % 3]);
                        edges.push([u.min(v), u.max(v)]);
                    }
                }
            }
            edges.sort_unstable();
            edges.dedup();
            let mut best: Option<(u64, u32, u32, Candidate)> = None;
            for &[a, b] in &edges {
                let Some(c) = self.candidate(a, b) else {
                    continue;
                };
                let key = (c.cost.to_bits(), a, b);
                if best.as_ref().is_some_and(|x| (x.0, x.1, x.2) <= key) {
                    continue;
                }
                if self.valid(a, b, &c) {
                    best = Some((key.0, a, b, c));
                }
            }
            let Some((_, a, b, c)) = best else {
                break;
            };
            self.collapse(a, b, &c);
        }
    }

    /// The simplified mesh and the report.
    pub fn finish(self) -> QemResult {
        let mesh = self.mesh;
        // Output vertices: one per live dense vertex, in order; a locked seam vertex keeps
        // one output vertex per input copy (attributes of that copy).
        let mut out_of = vec![NONE; self.pos.len()];
        let mut copy_of: rustc_hash::FxHashMap<u32, u32> = Default::default();
        let mut out = TriMesh::default();
        let want_n = self.normals.is_some();
        let want_c = self.colors.is_some();
        let want_uv = self.uvs.is_some();
        let (mut on, mut oc, mut ouv) = (Vec::new(), Vec::new(), Vec::new());
        for (f, t) in self.faces.iter().enumerate() {
            if !self.face_alive[f] {
                continue;
            }
            let orig = mesh.indices[self.orig_face[f] as usize];
            let mut tri = [0u32; 3];
            for k in 0..3 {
                let d = t[k] as usize;
                // A locked vertex never moves, so its corners still name their input copy.
                let seam = self.locked[d] && self.source[d] != orig[k];
                let id = if seam {
                    let o = orig[k];
                    let next = out.positions.len() as u32;
                    let id = *copy_of.entry(o).or_insert(next);
                    if id == next {
                        out.positions.push(self.pos[d].as_vec3());
                        if want_n {
                            on.push(mesh.normals.as_ref().map_or(Vec3::ZERO, |a| a[o as usize]));
                        }
                        if want_c {
                            oc.push(mesh.colors.as_ref().map_or([0.0; 4], |a| a[o as usize]));
                        }
                        if want_uv {
                            ouv.push(mesh.uvs.as_ref().map_or(Vec2::ZERO, |a| a[o as usize]));
                        }
                    }
                    id
                } else {
                    if out_of[d] == NONE {
                        out_of[d] = out.positions.len() as u32;
                        out.positions.push(self.pos[d].as_vec3());
                        if let Some(a) = &self.normals {
                            on.push(a[d]);
                        }
                        if let Some(a) = &self.colors {
                            oc.push(a[d]);
                        }
                        if let Some(a) = &self.uvs {
                            ouv.push(a[d]);
                        }
                    }
                    out_of[d]
                };
                tri[k] = id;
            }
            out.indices.push(tri);
        }
        out.normals = want_n.then_some(on);
        out.colors = want_c.then_some(oc);
        out.uvs = want_uv.then_some(ouv);
        let report = QemReport {
            placement: self.params.placement,
            quadric_merge: self.params.merge,
            target: self.params.triangles,
            target_reached: self.tris as u64 <= self.params.triangles,
            collapses: self.collapses,
            rejected: self.rejected,
            max_error: self.max_error,
            non_manifold_vertices: self.non_manifold,
        };
        QemResult { mesh: out, report }
    }
}

/// The error of placing a vertex with quadric `q` at `p`: the root mean square distance to
/// its planes (Q(p) over the summed plane weights), in model units.
#[inline]
pub(crate) fn error(q: &Quadric, p: DVec3) -> f64 {
    let w = q.weight();
    if w > 0.0 {
        (q.eval(p) / w).sqrt()
    } else {
        0.0
    }
}

/// The optimal placement: the minimiser of `q` by a 3 × 3 solve; when the system is
/// ill-conditioned (flat or crease-like neighbourhoods), the best of `a`, `b` and their
/// midpoint (ties in that order).
pub(crate) fn optimal(q: &Quadric, a: DVec3, b: DVec3) -> DVec3 {
    let m = q.matrix();
    let det = m.determinant();
    let s = q.weight() / 3.0;
    if s > 0.0 && det.abs() > ILL_CONDITIONED * s * s * s {
        let x = m.inverse() * -q.linear();
        if x.is_finite() {
            return x;
        }
    }
    let mid = 0.5 * (a + b);
    let mut best = (q.eval(a), a);
    for p in [b, mid] {
        let e = q.eval(p);
        if e < best.0 {
            best = (e, p);
        }
    }
    best.1
}

/// An undirected edge as one number.
#[inline]
fn edge_key(a: u32, b: u32) -> u64 {
    (a.min(b) as u64) << 32 | a.max(b) as u64
}

/// Number of values in both sorted lists.
fn count_common(x: &[u32], y: &[u32]) -> usize {
    let (mut i, mut j, mut n) = (0, 0, 0);
    while i < x.len() && j < y.len() {
        match x[i].cmp(&y[j]) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                n += 1;
                i += 1;
                j += 1;
            }
        }
    }
    n
}

/// [`super::simplify`] through the slow twin (every candidate recomputed every step).
pub fn simplify_slow(mesh: &TriMesh, params: &QemParams) -> crate::error::Result<QemResult> {
    super::check(mesh, params)?;
    let prep = Prepared::new(mesh);
    let mut c = Collapse::new(&prep, params);
    c.run_slow(params.triangles as usize);
    Ok(c.finish())
}
