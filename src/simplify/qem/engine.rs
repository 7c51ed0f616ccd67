//! The collapse engine: flat per-face arrays, one record per vertex with what a candidate's
//! cost reads, vertex → corner lists as runs of one flat pool (reserved at twice the
//! corners; a list that outgrows its run moves to the pool's end), an indexed heap of
//! candidates over face corners, and scratch vectors reused across collapses. See the
//! module above for the order and the checks.
//!
//! Edges as corners: corner `3f + k` stands for the edge from face f's k-th vertex to its
//! next one. Corner slots never move (a collapse renames vertices in place), so an edge
//! keeps its slot through collapses; of the (one or two) corners of an edge the one of
//! least slot is its *canonical* corner, the only one that may be in the heap or marked
//! refused. A collapse into `s` changes which corner is canonical only for edges at `s`
//! (faces die only on the collapsed edge), and those are all re-examined after it.

use super::edges::Edges;
use super::heap::IndexedHeap;
use super::{QemParams, QemReport, QemResult, QuadricMerge};
use crate::mesh::TriMesh;
use crate::simplify::prep::Prepared;
use crate::simplify::quadric::Quadric;
use glam::{DVec3, Vec2, Vec3};
use rayon::prelude::*;

mod hold;
mod passes;

pub use hold::Held;

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

/// A candidate's heap key: ordered by cost (non-negative f64 bits order as the numbers),
/// then by its vertices a < b.
#[inline]
fn key(cost: f64, a: u32, b: u32) -> u128 {
    (cost.to_bits() as u128) << 64 | (a as u128) << 32 | b as u128
}

/// What a candidate's cost and a collapse's bookkeeping read of a vertex, in one record (two
/// cache lines) rather than in seven arrays: the candidates of a collapse's new edges are
/// computed for vertices all over the mesh, and each array touched was a cache miss of its
/// own (the visit mark, the refusal count and the border flag fill the record's padding).
#[derive(Debug, Clone, Copy)]
#[repr(align(64))]
struct Vertex {
    q: Quadric,
    p: DVec3,
    /// Never moved: locked (not a manifold, a seam) or joined by a vertex pair.
    frozen: bool,
    /// The vertex's corners (of live faces): `pool[start..start + len]`, with room for
    /// `cap` in place before the list must move to the pool's end.
    start: u32,
    len: u32,
    cap: u32,
    /// A visit mark (see [`Collapse::epoch`]).
    mark: u32,
    /// Heap engine: more than zero when some refused edge may touch the vertex (an
    /// over-count: it is exact again, zero, after the vertex's edges are searched). Pass
    /// engine: the last pass whose collapse moved the vertex (in the record the pass
    /// reads anyway, rather than in an array of its own).
    refused_at: u32,
    /// On a border (of the input, or merged with a vertex that was).
    border: bool,
}

// The record stays two cache lines.
const _: () = assert!(std::mem::size_of::<Vertex>() == 128);

/// A face a collapse would move (intersection check): its index, its corners with the
/// removed vertex renamed, its corners' new positions and their box.
type Moved = (u32, [u32; 3], [DVec3; 3], DVec3, DVec3);

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
    vx: Vec<Vertex>,
    alive: Vec<bool>,
    locked: Vec<bool>,
    /// Saliency weight H per dense vertex (`params.weights`; empty without).
    weight: Vec<f64>,
    /// The current visit mark of [`Vertex::mark`] (two values: `epoch` and `epoch + 1`).
    epoch: u32,
    /// The vertices' corner lists (see [`Vertex::start`]).
    pool: Vec<u32>,
    /// Scratch of a collapse: the removed vertex's corners that move to the survivor.
    moved_corners: Vec<u32>,
    /// The input vertex whose attributes a dense vertex carries.
    source: Vec<u32>,
    normals: Option<Vec<Vec3>>,
    colors: Option<Vec<[f32; 4]>>,
    uvs: Option<Vec<Vec2>>,
    // Per face and corner.
    faces: Vec<[u32; 3]>,
    face_alive: Vec<bool>,
    orig_face: Vec<u32>,
    // Candidates and scratch.
    /// Canonical corners of the edges not known to be invalid, keyed by [`key`].
    heap: IndexedHeap,
    /// Per corner: a canonical corner whose edge was refused when it came up and not
    /// examined again since.
    refused: Vec<bool>,
    ring: Vec<u32>,
    fan: Vec<(u32, [u32; 3])>,
    tlm_fan: Vec<[DVec3; 3]>,
    diag: f64,
    half: Vec<(u32, u32)>,
    /// Scratch of an update: the new keys of `half`'s slots.
    keys: Vec<Option<u128>>,
    dead: Vec<u32>,
    /// Scratch of an update: the dead faces' corners that were in the heap (their places go
    /// to the edges of the survivor).
    freed: Vec<u32>,
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
    /// Per face, with that check: the build slot of the input triangle last found nearest
    /// to its centroid (a hint that only speeds the next search up).
    fold_hint: Vec<u32>,
    /// Scratch of that check: the moved faces (face, corners, new corner positions) and
    /// the faces near them.
    moved: Vec<Moved>,
    near: Vec<(u32, super::guard::Item)>,
    // Vertex pairs (`params.pair_distance`): heap slot `3 × faces + i` is pair i.
    /// Per pair: its two ends, renamed as their vertices are collapsed.
    pub(crate) pair_ends: Vec<[u32; 2]>,
    /// Per vertex: its first pair end (`2i + k`: end k of pair i), or NONE.
    pair_head: Vec<u32>,
    /// Per pair end: the next pair end of the same vertex.
    pair_next: Vec<u32>,
    /// Per vertex: a contraction of a vertex pair made it (two fans joined at one vertex:
    /// not a manifold there, so it is never moved again).
    joined: Vec<bool>,
    /// Whether `pair_distance` gave more candidate pairs than [`super::pairs`] allows.
    pub(crate) pair_overflow: bool,
    /// With an error bound and free borders: the input's border edges (as zero-area
    /// triangles), so that no border vertex is placed further than the bound from them.
    border_bvh: Option<crate::mesh::Bvh>,
    /// Pass engine: per heap slot (corner or pair), 1 + the collapse count when its edge
    /// was last refused (0: never).
    refused_when: Vec<u32>,
    /// Pass engine: per vertex, the collapse count when a collapse last changed one of its
    /// faces.
    changed: Vec<u32>,
}

/// The dense faces with three distinct corners, and the index of each in
/// `prep.dense_faces`: triangles with a repeated (welded) corner have no area and no edges
/// to collapse.
fn live_faces(prep: &Prepared<'_>) -> (Vec<[u32; 3]>, Vec<u32>) {
    let mut faces = Vec::with_capacity(prep.dense_faces.len());
    let mut orig_face = Vec::with_capacity(prep.dense_faces.len());
    for (f, t) in prep.dense_faces.iter().enumerate() {
        if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
            faces.push(*t);
            orig_face.push(f as u32);
        }
    }
    (faces, orig_face)
}

/// The corners around each of `n` vertices, each vertex's in one run of a flat pool (one
/// or two cache lines per walk, where linked lists cost a dependent load per corner), in
/// decreasing order: per vertex (start, len), and the pool (with room to grow:
/// [`Collapse::collapse`] moves a list that outgrows its run to the pool's end).
pub(super) fn corner_lists(n: usize, faces: &[[u32; 3]]) -> (Vec<(u32, u32)>, Vec<u32>) {
    let mut span = vec![(0u32, 0u32); n];
    for t in faces {
        for &v in t {
            span[v as usize].1 += 1;
        }
    }
    let mut at = 0u32;
    for s in span.iter_mut() {
        s.0 = at;
        at += s.1;
        s.1 = 0;
    }
    let mut pool = Vec::with_capacity(2 * at as usize);
    pool.resize(at as usize, NONE);
    for c in (0..3 * faces.len()).rev() {
        let s = &mut span[faces[c / 3][c % 3] as usize];
        pool[(s.0 + s.1) as usize] = c as u32;
        s.1 += 1;
    }
    (span, pool)
}

/// Manifold analysis: border edges, non-manifold edges, and fans that are neither a disk
/// nor a half-disk (a vertex with f triangles has f neighbours inside a surface, f + 1 on a
/// border with two border edges). Returns per vertex whether it is on a border and whether
/// it is locked (not manifold).
fn manifold(n: usize, faces: &[[u32; 3]], ef: &Edges) -> (Vec<bool>, Vec<bool>) {
    let mut border = vec![false; n];
    let mut locked = vec![false; n];
    let mut border_edges = vec![0u32; n];
    let mut degree = vec![0u32; n];
    let mut fcount = vec![0u32; n];
    for (e, &[a, b]) in ef.edges().iter().enumerate() {
        degree[a as usize] += 1;
        degree[b as usize] += 1;
        match ef.corners(e).len() {
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
    for t in faces {
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
    (border, locked)
}

/// Border planes: the preparation adds, at a border edge, the plane through the edge
/// perpendicular to its triangle with weight |e|²; the engine adds it again
/// BORDER_WEIGHT − 1 times (see BORDER_WEIGHT).
fn add_border_planes(quad: &mut [Quadric], pos: &[DVec3], faces: &[[u32; 3]], ef: &Edges) {
    let extra = BORDER_WEIGHT - 1.0;
    if extra > 0.0 {
        for (e, &[a, b]) in ef.edges().iter().enumerate() {
            let cs = ef.corners(e);
            if cs.len() != 1 {
                continue;
            }
            let t = faces[cs[0] as usize / 3];
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
}

/// The border edges of `prep`'s welded mesh as zero-area triangles (a, b, b) for a
/// closest-point hierarchy; `None` without border.
fn border_edges(prep: &Prepared<'_>, ef: &Edges) -> Option<crate::mesh::Bvh> {
    let indices: Vec<[u32; 3]> = ef
        .edges()
        .iter()
        .enumerate()
        .filter(|&(e, _)| ef.corners(e).len() == 1)
        .map(|(_, &[a, b])| [a, b, b])
        .collect();
    if indices.is_empty() {
        return None;
    }
    let m = TriMesh {
        positions: prep.dense_pos.clone(),
        indices,
        ..TriMesh::default()
    };
    Some(crate::mesh::Bvh::new(&m))
}

/// Attribute seams: a welded vertex whose input copies differ in an attribute keeps all its
/// copies and is never moved (seams are not collapsed across).
fn lock_seams(prep: &Prepared<'_>, locked: &mut [bool]) {
    let mesh = prep.mesh;
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
}

/// Saliency weights per dense vertex (`params.weights`; empty without): the largest of the
/// welded copies' weights.
fn saliency_weights(prep: &Prepared<'_>, params: &QemParams, n: usize) -> Vec<f64> {
    let mut weight = Vec::new();
    if let Some(w) = &params.weights {
        weight = vec![0.0f64; n];
        for (v, &x) in w.iter().enumerate() {
            let d = prep.dense_of[prep.weld[v] as usize];
            if d != NONE {
                weight[d as usize] = weight[d as usize].max(x);
            }
        }
    }
    weight
}

impl<'m> Collapse<'m> {
    /// Sets up the state for `prep`'s mesh.
    pub fn new(prep: &Prepared<'m>, params: &QemParams) -> Collapse<'m> {
        let mesh = prep.mesh;
        let n = prep.active.len();
        let qs = prep.quadrics();
        let pos: Vec<DVec3> = prep.dense_pos.iter().map(|p| p.as_dvec3()).collect();
        let mut quad: Vec<Quadric> = prep.active.iter().map(|&v| qs[v as usize]).collect();
        let (faces, orig_face) = live_faces(prep);
        let (span, pool) = corner_lists(n, &faces);
        let ef = Edges::new(&faces, &span, &pool);
        let (border, mut locked) = manifold(n, &faces, &ef);
        let non_manifold = locked.iter().filter(|&&l| l).count();
        add_border_planes(&mut quad, &pos, &faces, &ef);
        if !params.collapse_seams {
            lock_seams(prep, &mut locked);
        }
        let source: Vec<u32> = prep.active.clone();
        fn pick<T: Copy>(a: &[T], source: &[u32]) -> Vec<T> {
            source.iter().map(|&v| a[v as usize]).collect()
        }
        let mut weight = saliency_weights(prep, params, n);
        if params.weight_rule == super::WeightRule::Quadric {
            // The weights live in the quadrics from here on; the cost is Q(e) alone.
            for (q, &w) in quad.iter_mut().zip(&weight) {
                *q = *q * w;
            }
            weight = Vec::new();
        }
        let vx: Vec<Vertex> = (pos.iter().zip(&quad).zip(&locked).zip(&span).zip(&border))
            .map(|((((&p, &q), &frozen), &(start, len)), &border)| Vertex {
                q,
                p,
                frozen,
                start,
                len,
                cap: len,
                mark: 0,
                refused_at: 0,
                border,
            })
            .collect();
        let diag = prep.bounds.diagonal();
        let tris = faces.len();
        let mut c = Collapse {
            mesh,
            params: params.clone(),
            checks: Checks::default(),
            vx,
            alive: vec![true; n],
            locked,
            weight,
            epoch: 0,
            pool,
            moved_corners: Vec::new(),
            normals: mesh.normals.as_deref().map(|a| pick(a, &source)),
            colors: mesh.colors.as_deref().map(|a| pick(a, &source)),
            uvs: mesh.uvs.as_deref().map(|a| pick(a, &source)),
            source,
            face_alive: vec![true; faces.len()],
            faces,
            orig_face,
            heap: IndexedHeap::default(),
            refused: Vec::new(),
            ring: Vec::new(),
            fan: Vec::new(),
            tlm_fan: Vec::new(),
            diag,
            half: Vec::new(),
            keys: Vec::new(),
            dead: Vec::new(),
            freed: Vec::new(),
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
            fold_hint: Vec::new(),
            moved: Vec::new(),
            near: Vec::new(),
            pair_ends: Vec::new(),
            pair_head: vec![NONE; n],
            pair_next: Vec::new(),
            joined: vec![false; n],
            pair_overflow: false,
            border_bvh: None,
            refused_when: Vec::new(),
            changed: Vec::new(),
        };
        if params.max_error.is_some() && !params.lock_border {
            c.border_bvh = border_edges(prep, &ef);
        }
        if params.pair_distance > 0.0 {
            c.find_pairs(params.pair_distance);
        }
        if params.check_intersections {
            let mut g = super::guard::Guard::default();
            g.build(c.faces.len(), |_| true, |f| c.face_box(f), |f| c.faces[f]);
            c.guard = Some(g);
            let bvh = crate::mesh::Bvh::new(mesh);
            let slots = bvh.slots();
            c.fold_hint = c.orig_face.iter().map(|&o| slots[o as usize]).collect();
            c.orig_bvh = Some(bvh);
        }
        if params.engine == super::Engine::Heap {
            c.seed_heap(&ef);
        }
        c
    }

    /// Every edge of at most two faces at its canonical corner, its cost computed in
    /// parallel (the one parallel part: the collapses themselves are a sequence); fills the
    /// heap and clears the refusal marks.
    fn seed_heap(&mut self, ef: &Edges) {
        let mut canon: Vec<(u32, u32, u32)> = Vec::with_capacity(ef.len());
        for (e, &[a, b]) in ef.edges().iter().enumerate() {
            let cs = ef.corners(e);
            if cs.len() > 2 {
                continue;
            }
            // The least of the edge's corners (they come in increasing order).
            canon.push((cs[0], a, b));
        }
        let base = self.pair_base();
        canon.extend(
            self.pair_ends
                .iter()
                .enumerate()
                .map(|(i, &[a, b])| (base + i as u32, a, b)),
        );
        let c = &*self;
        let entries: Vec<(u128, u32)> = canon
            .par_iter()
            .with_min_len(4096)
            .filter_map(|&(slot, a, b)| c.candidate(a, b).map(|x| (key(x.cost, a, b), slot)))
            .collect();
        let slots = base as usize + self.pair_ends.len();
        self.refused = vec![false; slots];
        self.heap = IndexedHeap::from_entries(slots, entries);
    }

    /// The vertices of corner `c`'s edge.
    #[inline]
    fn corner_edge(&self, c: u32) -> (u32, u32) {
        let (f, k) = (c as usize / 3, c as usize % 3);
        let t = self.faces[f];
        (t[k], t[(k + 1) % 3])
    }

    /// The first heap slot of the vertex pairs (the slots below are face corners).
    #[inline]
    fn pair_base(&self) -> u32 {
        3 * self.faces.len() as u32
    }

    /// The vertices of heap slot `slot`: a corner's edge or a vertex pair.
    #[inline]
    fn slot_edge(&self, slot: u32) -> (u32, u32) {
        match slot.checked_sub(self.pair_base()) {
            Some(i) => {
                let [u, v] = self.pair_ends[i as usize];
                (u, v)
            }
            None => self.corner_edge(slot),
        }
    }

    /// The candidate vertex pairs closer than `d` (see [`super::pairs`]) and their
    /// per-vertex lists; sets `pair_overflow` instead when there are too many.
    fn find_pairs(&mut self, d: f64) {
        let cap = super::pairs::MAX_PAIRS_PER_VERTEX * self.vx.len();
        let adjacent = |u: u32, v: u32| {
            self.corners(u)
                .iter()
                .any(|&c| self.faces[c as usize / 3].contains(&v))
        };
        let eligible = |v: u32| !self.locked[v as usize];
        let pos: Vec<DVec3> = self.vx.iter().map(|v| v.p).collect();
        let Some(pairs) = super::pairs::close_pairs(&pos, eligible, adjacent, d, cap) else {
            self.pair_overflow = true;
            return;
        };
        self.pair_next = vec![NONE; 2 * pairs.len()];
        for (i, ends) in pairs.iter().enumerate() {
            for (k, &v) in ends.iter().enumerate() {
                self.pair_next[2 * i + k] = self.pair_head[v as usize];
                self.pair_head[v as usize] = (2 * i + k) as u32;
            }
        }
        self.pair_ends = pairs;
    }

    /// Moves `g`'s pair ends to `s` (renamed), after a collapse of g into s.
    fn splice_pairs(&mut self, s: u32, g: u32) {
        let mut e = self.pair_head[g as usize];
        while e != NONE {
            let nxt = self.pair_next[e as usize];
            self.pair_ends[e as usize / 2][e as usize % 2] = s;
            self.pair_next[e as usize] = self.pair_head[s as usize];
            self.pair_head[s as usize] = e;
            e = nxt;
        }
        self.pair_head[g as usize] = NONE;
    }

    /// A fresh visit mark (two values: `e` and `e + 1`).
    fn next_epoch(&mut self) -> u32 {
        if self.epoch >= u32::MAX - 2 {
            for v in &mut self.vx {
                v.mark = 0;
            }
            self.epoch = 0;
        }
        self.epoch += 2;
        self.epoch
    }

    /// The box of face `f` now.
    fn face_box(&self, f: usize) -> (DVec3, DVec3) {
        let [a, b, c] = self.faces[f].map(|u| self.vx[u as usize].p);
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
    ///
    /// Speed, not semantics: the guard is walked once for the box of the whole moved fan
    /// (not once per face), each face found is tested against the moved faces whose boxes
    /// meet its box (disjoint boxes cannot meet), a face is cleared of folding by the input
    /// hierarchy's normal cones when they show that no triangle as near as its hint can
    /// face away from it ([`crate::mesh::Bvh::never_faces_away`]: most faces, with no
    /// search), and otherwise the nearest input point is searched from the face's last
    /// nearest triangle ([`crate::mesh::Bvh::closest_bounded_by`]: the very hit of the
    /// unhinted search).
    fn intersects(&mut self, a: u32, b: u32, c: &Candidate) -> bool {
        let Some(mut guard) = self.guard.take() else {
            return false;
        };
        // The faces that move: a face of a or of b not on the edge, its corners with b
        // renamed a, and its corners at the placed point.
        let mut moved = std::mem::take(&mut self.moved);
        moved.clear();
        for v in [a, b] {
            self.each_face(v, |f| {
                let t = self.faces[f];
                if t.contains(&a) && t.contains(&b) {
                    return;
                }
                let ids = t.map(|u| if u == b { a } else { u });
                let tri = t.map(|u| {
                    if u == a || u == b {
                        c.p
                    } else {
                        self.vx[u as usize].p
                    }
                });
                let (lo, hi) = (
                    tri[0].min(tri[1]).min(tri[2]),
                    tri[0].max(tri[1]).max(tri[2]),
                );
                moved.push((f as u32, ids, tri, lo, hi));
            });
        }
        let mut hit = self.folds(&moved);
        if !hit && !moved.is_empty() {
            let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
            for &(_, _, _, tlo, thi) in &moved {
                lo = lo.min(tlo);
                hi = hi.max(thi);
            }
            let mut near = std::mem::take(&mut self.near);
            guard.collect(lo, hi, &mut near);
            // The guard returns live faces only, with their corners' vertices: no face is
            // loaded here until a triangle test needs its corners' positions.
            hit = near.iter().any(|(_, it)| {
                let gt = it.ids.map(|u| if u == b { a } else { u });
                // Every moved face holds a (the new vertex): such a face shares it (the fan
                // itself, a good part of the faces found, is passed here at once).
                if gt.contains(&a) {
                    return false;
                }
                let (glo, ghi) = (it.lo.as_dvec3(), it.hi.as_dvec3());
                // Disjoint boxes cannot meet: a face whose box meets no moved face's box is
                // passed without a test.
                let meets =
                    |tlo: DVec3, thi: DVec3| !(tlo.cmpgt(ghi).any() || glo.cmpgt(thi).any());
                if !moved.iter().any(|&(_, _, _, tlo, thi)| meets(tlo, thi)) {
                    return false;
                }
                // Its corners only once a moved face shares no vertex with it and meets
                // its box (most faces found are next to the fan and share a vertex).
                let mut gp = None;
                moved.iter().any(|(_, ids, tri, tlo, thi)| {
                    if gt.iter().any(|u| ids.contains(u)) || !meets(*tlo, *thi) {
                        return false;
                    }
                    let gp = *gp.get_or_insert_with(|| it.ids.map(|u| self.vx[u as usize].p));
                    crate::mesh::intersect::triangles_intersect(*tri, gp)
                })
            });
            self.near = near;
        }
        self.moved = moved;
        self.guard = Some(guard);
        hit
    }

    /// The fold-over half of [`Collapse::intersects`]: whether a moved face (with its new
    /// corners) has a normal opposite to the input's at the input point nearest its
    /// centroid.
    fn folds(&mut self, moved: &[Moved]) -> bool {
        let Some(bvh) = &self.orig_bvh else {
            return false;
        };
        for &(f, _, tri, _, _) in moved {
            let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
            if n == DVec3::ZERO {
                continue;
            }
            let centre = (tri[0] + tri[1] + tri[2]) / 3.0;
            let hint = self.fold_hint[f as usize];
            // Most faces are shown not to fold by the input's normal cones alone, with no
            // search for the nearest triangle (the same answer: see `never_faces_away`).
            if bvh.never_faces_away(centre, n, hint) {
                continue;
            }
            if let Some(h) = bvh.closest_bounded_by(centre, hint) {
                self.fold_hint[f as usize] = h.slot;
                // The input triangle's normal from the hierarchy's own record of it (just
                // loaded by the search; the same f64 corners, so the same bits as from the
                // mesh, without two more cache misses).
                if n.dot(bvh.normal(h.slot)) < 0.0 {
                    return true;
                }
            }
        }
        false
    }

    /// After a collapse into `s`: the faces that died from `dead[first..]` leave the
    /// guard, the moved faces' boxes grow into it and their corners are renamed (rebuilt
    /// when half of its faces have died).
    fn refit(&mut self, s: u32, first: usize) {
        let Some(mut guard) = self.guard.take() else {
            return;
        };
        if guard.stale(self.tris) {
            guard.build(
                self.faces.len(),
                |f| self.face_alive[f],
                |f| self.face_box(f),
                |f| self.faces[f],
            );
        } else {
            for &f in &self.dead[first..] {
                guard.kill(f as usize);
            }
            self.each_face(s, |f| {
                let (lo, hi) = self.face_box(f);
                guard.grow(f, lo, hi, self.faces[f]);
            });
        }
        self.guard = Some(guard);
    }

    /// An error when `pair_distance` gave more candidate pairs than allowed.
    pub fn pairs_ok(&self) -> crate::error::Result<()> {
        if self.pair_overflow {
            return Err(crate::error::Error::param(
                "simplify",
                "pair_distance",
                self.params.pair_distance,
                format!(
                    "gives more than {} candidate vertex pairs per vertex; choose a smaller distance",
                    super::pairs::MAX_PAIRS_PER_VERTEX
                ),
            ));
        }
        Ok(())
    }

    /// Triangles now.
    pub fn triangles(&self) -> usize {
        self.tris
    }

    /// The merged quadric of `a` and `b`.
    #[inline]
    fn merged(&self, a: u32, b: u32) -> Quadric {
        let q = self.vx[a as usize].q + self.vx[b as usize].q;
        match self.params.merge {
            QuadricMerge::Sum => q,
            QuadricMerge::Mean => q * 0.5,
        }
    }

    /// The saliency weight of the vertex that collapsing (a, b) leaves: (H_a + H_b) / 2.
    #[inline]
    fn merged_weight(&self, a: u32, b: u32) -> f64 {
        0.5 * (self.weight[a as usize] + self.weight[b as usize])
    }

    /// The collapse of edge (a, b): merged quadric, placement and cost; `None` when the
    /// edge may not be collapsed whatever the neighbourhood (a locked vertex, two pinned
    /// border vertices).
    fn candidate(&self, a: u32, b: u32) -> Option<Candidate> {
        let (ua, ub) = (a as usize, b as usize);
        let (va, vb) = (&self.vx[ua], &self.vx[ub]);
        if va.frozen || vb.frozen {
            return None;
        }
        let q = self.merged(a, b);
        let (pa, pb) = (va.p, vb.p);
        let pinned = self.params.lock_border;
        let p = match (pinned && self.vx[ua].border, pinned && self.vx[ub].border) {
            (true, true) => return None,
            (true, false) => pa,
            (false, true) => pb,
            (false, false) => match self.params.placement {
                // Two local mappings: ordered by the optimal point's error; the point itself
                // is found in `valid`.
                super::Placement::Optimal | super::Placement::TwoLocalMappings => {
                    optimal(&q, pa, pb)
                }
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
        let cost = match self.params.cost {
            super::Cost::Quadric => q.eval(p),
            super::Cost::Distance => {
                let e = error(&q, p);
                e * e
            }
        };
        // C(e) = Q(e) · H(e), H(e) the weight the collapsed vertex will carry.
        let cost = match self.weight.is_empty() {
            true => cost,
            false => cost * self.merged_weight(a, b),
        };
        Some(Candidate { q, p, cost })
    }

    /// Puts the edge of canonical corner `corner` in the heap with its current cost (or
    /// takes it out when it may not be collapsed).
    fn push(&mut self, corner: u32) {
        match self.slot_key(corner) {
            Some(k) => self.heap.set(corner, k),
            None => self.heap.remove(corner),
        }
    }

    /// The heap key of heap slot `slot`'s edge now, or `None` when it may not be collapsed.
    #[inline]
    fn slot_key(&self, slot: u32) -> Option<u128> {
        let (u, v) = self.slot_edge(slot);
        let (a, b) = (u.min(v), u.max(v));
        self.candidate(a, b).map(|c| key(c.cost, a, b))
    }

    /// The corners in `v`'s list.
    #[inline]
    fn corners(&self, v: u32) -> &[u32] {
        let x = &self.vx[v as usize];
        &self.pool[x.start as usize..(x.start + x.len) as usize]
    }

    /// Calls `f` on every live face of `v` (as a face index). Outside [`Collapse::collapse`]
    /// a corner list holds only live faces' corners (a collapse rebuilds the survivor's
    /// list, empties the removed vertex's and prunes the dead faces' third corners), so no
    /// face's flag is read here: one cache miss less per face walked.
    #[inline]
    fn each_face(&self, v: u32, mut f: impl FnMut(usize)) {
        for &c in self.corners(v) {
            let face = c as usize / 3;
            debug_assert!(self.face_alive[face], "a dead face in a corner list");
            f(face);
        }
    }

    /// The neighbours of `v` (each once, in fan order) into `out`.
    fn neighbours(&mut self, v: u32, out: &mut Vec<u32>) {
        out.clear();
        let e = self.next_epoch();
        let (start, len) = (self.vx[v as usize].start, self.vx[v as usize].len);
        for i in start..start + len {
            // Live faces only (see `each_face`).
            let face = self.pool[i as usize] as usize / 3;
            for u in self.faces[face] {
                if u != v && self.vx[u as usize].mark != e {
                    self.vx[u as usize].mark = e;
                    out.push(u);
                }
            }
        }
    }

    /// The live faces of a, then those of b, each with its corners, in the scratch vector
    /// taken from `self.fan` (the caller puts it back), and how many are a's.
    #[inline]
    fn take_fans(&mut self, a: u32, b: u32) -> (Vec<(u32, [u32; 3])>, usize) {
        let mut fan = std::mem::take(&mut self.fan);
        fan.clear();
        self.each_face(a, |f| fan.push((f as u32, self.faces[f])));
        let na = fan.len();
        self.each_face(b, |f| fan.push((f as u32, self.faces[f])));
        (fan, na)
    }

    /// Whether collapsing (a, b) to `c` passes the checks. The live faces of a and of b
    /// are gathered once (the corner lists are the pointer chase of the run). With the
    /// two-local-mappings placement, this is where the point is found (it depends on the
    /// faces around the edge, so it is part of the validity, not of the cost: the order
    /// stays that of the optimal point's quadric error, a lower bound of the placed
    /// point's), and `c.p` becomes it.
    fn valid(&mut self, a: u32, b: u32, c: &mut Candidate) -> bool {
        let (fan, na) = self.take_fans(a, b);
        let placed = self.place_two_mappings(a, b, c, &fan[..na], &fan[na..]);
        let ok = placed && self.valid_fans(a, b, c, &fan[..na], &fan[na..]);
        self.fan = fan;
        ok && self.border_within_bound(a, b, c.p) && !self.intersects(a, b, c)
    }

    /// With an error bound E and free borders: whether the vertex left by collapsing (a, b)
    /// to `p` is off the border or within E of the input's border (at the f32 point the
    /// output will hold). The quadric error alone bounds the root mean square distance to
    /// the merged planes, not a border vertex's distance to the border: on bunny's holes
    /// border vertices went up to 3.2 E away without this check.
    fn border_within_bound(&self, a: u32, b: u32, p: DVec3) -> bool {
        let (Some(bvh), Some(e)) = (&self.border_bvh, self.params.max_error) else {
            return true;
        };
        if !(self.vx[a as usize].border || self.vx[b as usize].border) {
            return true;
        }
        let p = p.as_vec3().as_dvec3();
        bvh.closest(p, None, e * e)
            .is_some_and(|h| h.dist2 <= e * e)
    }

    /// Whether contracting the vertex pair (a, b) to `c` passes the checks: the pair shares
    /// no edge and no neighbour (so no edge gains a third face and no triangle is repeated:
    /// the two fans only meet at the new vertex), the error bound, no flip, no zero area,
    /// and the intersection check. The placement is the optimal one whatever
    /// `params.placement` says: the two local mappings need one link polygon around an
    /// edge, and a pair has two.
    fn valid_pair(&mut self, a: u32, b: u32, c: &Candidate) -> bool {
        if a == b || self.params.max_error.is_some_and(|e| error(&c.q, c.p) > e) {
            return false;
        }
        let (fan, na) = self.take_fans(a, b);
        let e = self.next_epoch();
        self.vx[a as usize].mark = e;
        for (_, t) in &fan[..na] {
            for &u in t {
                self.vx[u as usize].mark = e;
            }
        }
        let apart = self.vx[b as usize].mark != e
            && fan[na..]
                .iter()
                .all(|(_, t)| t.iter().all(|&u| self.vx[u as usize].mark != e));
        let ok = apart && self.no_flip(a, b, c, &fan[..na], &fan[na..]);
        self.fan = fan;
        ok && self.border_within_bound(a, b, c.p) && !self.intersects(a, b, c)
    }

    /// With the two-local-mappings placement (and neither endpoint pinned): moves `c.p` to
    /// its point; false when there is none. True otherwise; then the error bound.
    fn place_two_mappings(
        &mut self,
        a: u32,
        b: u32,
        c: &mut Candidate,
        fa: &[(u32, [u32; 3])],
        fb: &[(u32, [u32; 3])],
    ) -> bool {
        let pinned =
            self.params.lock_border && (self.vx[a as usize].border || self.vx[b as usize].border);
        if self.params.placement == super::Placement::TwoLocalMappings && !pinned {
            let mut faces = std::mem::take(&mut self.tlm_fan);
            faces.clear();
            for (v, other, fan) in [(a, b, fa), (b, a, fb)] {
                for (_, t) in fan {
                    if !t.contains(&other) {
                        let k = t.iter().position(|&u| u == v).expect("a face of v");
                        faces.push([0, 1, 2].map(|i| self.vx[t[(k + i) % 3] as usize].p));
                    }
                }
            }
            let (pa, pb) = (self.vx[a as usize].p, self.vx[b as usize].p);
            let p = super::tlm::place(&c.q, &faces, pa, pb, c.p, self.diag);
            self.tlm_fan = faces;
            let Some(p) = p else {
                return false;
            };
            c.p = if self.params.check_intersections {
                p.as_vec3().as_dvec3()
            } else {
                p
            };
        }
        self.params.max_error.is_none_or(|e| error(&c.q, c.p) <= e)
    }

    /// [`Collapse::valid`] on the gathered fans of a and b, without the intersection check.
    fn valid_fans(
        &mut self,
        a: u32,
        b: u32,
        c: &Candidate,
        fa: &[(u32, [u32; 3])],
        fb: &[(u32, [u32; 3])],
    ) -> bool {
        let shared = fa.iter().filter(|(_, t)| t.contains(&b)).count();
        if shared == 0 || shared > 2 {
            return false;
        }
        if self.checks.topology {
            if shared == 2 && self.vx[a as usize].border && self.vx[b as usize].border {
                return false;
            }
            // Link condition: the common neighbours are the far corners of the edge's
            // triangles, no more (marks: e on a's neighbours, e + 1 once counted).
            let e = self.next_epoch();
            for (_, t) in fa {
                for &u in t {
                    if u != a {
                        self.vx[u as usize].mark = e;
                    }
                }
            }
            let mut common = 0;
            for (_, t) in fb {
                for &u in t {
                    if u != b && self.vx[u as usize].mark == e {
                        self.vx[u as usize].mark = e + 1;
                        common += 1;
                    }
                }
            }
            if common != shared {
                return false;
            }
            // No duplicate triangle: a face (a, x, y) and a face (b, x, y) would both become
            // (s, x, y).
            let pairs = &mut self.pairs;
            pairs.clear();
            for (v, other, fan) in [(a, b, fa), (b, a, fb)] {
                for (_, t) in fan {
                    if !t.contains(&other) {
                        let mut r: [u32; 2] = [0; 2];
                        let mut k = 0;
                        for &u in t {
                            if u != v {
                                r[k] = u;
                                k += 1;
                            }
                        }
                        pairs.push([r[0].min(r[1]), r[0].max(r[1])]);
                    }
                }
            }
            pairs.sort_unstable();
            if pairs.windows(2).any(|w| w[0] == w[1]) {
                return false;
            }
        }
        self.no_flip(a, b, c, fa, fb)
    }

    /// The flip and zero-area checks on the faces of a and b that survive, with a and b
    /// moved to `c.p`.
    fn no_flip(
        &self,
        a: u32,
        b: u32,
        c: &Candidate,
        fa: &[(u32, [u32; 3])],
        fb: &[(u32, [u32; 3])],
    ) -> bool {
        if self.checks.flips || self.checks.zero_area {
            for (v, fan) in [(a, fa), (b, fb)] {
                for (_, t) in fan {
                    if t.contains(&a) && t.contains(&b) {
                        continue;
                    }
                    let old = t.map(|u| self.vx[u as usize].p);
                    let new = t.map(|u| if u == v { c.p } else { self.vx[u as usize].p });
                    let n0 = (old[1] - old[0]).cross(old[2] - old[0]);
                    let n1 = (new[1] - new[0]).cross(new[2] - new[0]);
                    if self.checks.zero_area && n1.length() <= self.area_eps {
                        return false;
                    }
                    if self.checks.flips && n0.dot(n1) <= 0.0 {
                        return false;
                    }
                }
            }
        }
        true
    }

    /// Collapses (a, b), a < b, to `c`: `a` survives.
    fn collapse(&mut self, a: u32, b: u32, c: &Candidate) {
        let (s, g) = (a, b);
        // Attributes, interpolated at the placed point's parameter on the edge.
        let (ps, pg) = (self.vx[s as usize].p, self.vx[g as usize].p);
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
        let dead_before = self.dead.len();
        let mut moved = std::mem::take(&mut self.moved_corners);
        moved.clear();
        let (gs, gl) = (self.vx[ug].start as usize, self.vx[ug].len as usize);
        for i in gs..gs + gl {
            // Live faces only (see `each_face`).
            let cnr = self.pool[i];
            let f = cnr as usize / 3;
            if self.faces[f].contains(&s) {
                self.face_alive[f] = false;
                self.tris -= 1;
                self.dead.push(f as u32);
            } else {
                self.faces[f][cnr as usize % 3] = s;
                moved.push(cnr);
            }
        }
        // The faces that died here: the only dead ones in any corner list now. The lists
        // below drop them by name (an edge's one or two faces) rather than by reading every
        // face's flag (a cache miss per corner); by the flag when more died (the topology
        // check switched off).
        let died = &self.dead[dead_before..];
        let gone = (died.len() <= 2).then(|| [0, 1].map(|k| died.get(k).map_or(NONE, |&f| f)));
        self.vx[ug].len = 0;
        // s's new list: its own corners without the dead faces, reversed, then the moved
        // corners, reversed (the order the linked lists this replaced gave: the two-local-
        // mappings point sums over the fan in this order).
        let (ss, sl, cap) = (
            self.vx[us].start as usize,
            self.vx[us].len as usize,
            self.vx[us].cap as usize,
        );
        let mut w = ss;
        for i in ss..ss + sl {
            let cnr = self.pool[i];
            if !self.died(gone, cnr) {
                self.pool[w] = cnr;
                w += 1;
            }
        }
        self.pool[ss..w].reverse();
        let live = w - ss;
        let len = live + moved.len();
        let start = if len <= cap {
            ss
        } else {
            // Outgrown: to the pool's end, with room for half as many again.
            let at = self.pool.len();
            let cap = len + len / 2 + 2;
            self.pool.extend_from_within(ss..w);
            self.pool.resize(at + cap, NONE);
            self.vx[us].cap = cap as u32;
            at
        };
        for (k, &cnr) in moved.iter().rev().enumerate() {
            self.pool[start + live + k] = cnr;
        }
        self.vx[us].start = start as u32;
        self.vx[us].len = len as u32;
        self.moved_corners = moved;
        if !self.weight.is_empty() {
            self.weight[us] = self.merged_weight(s, g);
        }
        // The dead faces' third corners leave their vertices' lists (else every list
        // grows by the faces that died around it, and the walks over them dominate).
        for i in dead_before..self.dead.len() {
            let f = self.dead[i] as usize;
            for x in self.faces[f] {
                if x != s && x != g {
                    self.prune(x, gone);
                }
            }
        }
        // No face died: a vertex pair was contracted.
        self.joined[us] |= self.dead.len() == dead_before;
        self.vx[us].frozen |= self.joined[us];
        self.splice_pairs(s, g);
        self.vx[us].p = c.p;
        self.vx[us].q = c.q;
        self.vx[us].border |= self.vx[ug].border;
        self.vx[us].refused_at += self.vx[ug].refused_at;
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
        self.refit(s, dead_before);
    }

    /// Whether corner `cnr`'s face died in the collapse under way (`gone`: the faces it
    /// killed, when at most two).
    #[inline]
    fn died(&self, gone: Option<[u32; 2]>, cnr: u32) -> bool {
        match gone {
            Some(g) => g.contains(&(cnr / 3)),
            None => !self.face_alive[cnr as usize / 3],
        }
    }

    /// Drops the corners of the faces the collapse under way killed (see
    /// [`Collapse::died`]) from `v`'s list (in order).
    fn prune(&mut self, v: u32, gone: Option<[u32; 2]>) {
        let (start, len) = (self.vx[v as usize].start, self.vx[v as usize].len);
        let mut w = start as usize;
        for i in start as usize..(start + len) as usize {
            let cnr = self.pool[i];
            if !self.died(gone, cnr) {
                self.pool[w] = cnr;
                w += 1;
            }
        }
        self.vx[v as usize].len = (w - start as usize) as u32;
    }

    /// After a collapse into `s`: the corners of the dead faces leave the heap; the edges of
    /// `s` get their canonical corner anew and a new cost; and the edges of its neighbours
    /// that were refused before are examined again (their validity may have changed; their
    /// cost has not, so the entries still in the heap stay as they are).
    ///
    /// A dead face's corner in the heap stood for an edge of the collapsed edge's triangles,
    /// and such an edge goes on as an edge of `s`: its heap place goes to a corner of s that
    /// enters the heap ([`IndexedHeap::replace`]: one sift instead of two). The heap then
    /// holds the same entries as after removing and inserting them one by one, and as the
    /// entries are totally ordered, the collapses come out in the same order.
    fn update(&mut self, s: u32) {
        let mut dead = std::mem::take(&mut self.dead);
        let mut freed = std::mem::take(&mut self.freed);
        freed.clear();
        for &f in &dead {
            for c in 3 * f..3 * f + 3 {
                if self.heap.contains(c) {
                    freed.push(c);
                }
                self.refused[c as usize] = false;
            }
        }
        dead.clear();
        self.dead = dead;
        // The corners of s's edges as (other end, corner), grouped by the other end.
        let mut half = std::mem::take(&mut self.half);
        half.clear();
        self.each_face(s, |f| {
            let t = self.faces[f];
            let k = t.iter().position(|&u| u == s).expect("a face of s");
            half.push((t[(k + 1) % 3], (3 * f + k) as u32));
            half.push((t[(k + 2) % 3], (3 * f + (k + 2) % 3) as u32));
        });
        half.sort_unstable();
        // The new keys first, then the heap: the candidates' vertex records are loaded
        // side by side (independent loads the processor overlaps) instead of each behind
        // the previous heap update. The same heap operations in the same order.
        let mut keys = std::mem::take(&mut self.keys);
        keys.clear();
        for (i, &(x, corner)) in half.iter().enumerate() {
            let dup = i > 0 && half[i - 1].0 == x;
            keys.push(if dup { None } else { self.slot_key(corner) });
        }
        for (&(_, corner), &k) in half.iter().zip(&keys) {
            self.refused[corner as usize] = false;
            match k {
                Some(k) => match freed.last() {
                    Some(&old) if !self.heap.contains(corner) => {
                        freed.pop();
                        self.heap.replace(old, corner, k);
                    }
                    _ => self.heap.set(corner, k),
                },
                None => self.heap.remove(corner),
            }
        }
        for &c in &freed {
            self.heap.remove(c);
        }
        self.freed = freed;
        self.keys = keys;
        self.half = half;
        self.update_pairs(s);
        self.vx[s as usize].refused_at = 0;
        let mut ring = std::mem::take(&mut self.ring);
        self.neighbours(s, &mut ring);
        for &w in &ring {
            if self.vx[w as usize].refused_at == 0 {
                continue;
            }
            let (start, len) = (self.vx[w as usize].start, self.vx[w as usize].len);
            for i in start..start + len {
                // Live faces only (see `each_face`).
                let f = self.pool[i as usize] as usize / 3;
                for corner in 3 * f as u32..3 * f as u32 + 3 {
                    if self.refused[corner as usize] {
                        let (u, v) = self.corner_edge(corner);
                        if u == w || v == w {
                            self.refused[corner as usize] = false;
                            self.push(corner);
                        }
                    }
                }
            }
            let mut e = self.pair_head[w as usize];
            while e != NONE {
                let slot = self.pair_base() + e / 2;
                if self.refused[slot as usize] {
                    self.refused[slot as usize] = false;
                    self.push(slot);
                }
                e = self.pair_next[e as usize];
            }
            self.vx[w as usize].refused_at = 0;
        }
        self.ring = ring;
    }

    /// After a collapse into `s`: its vertex pairs get a new cost; a pair now of s with
    /// itself leaves the heap and s's list, and of two pairs with the same ends the one of
    /// least slot stays in the heap.
    fn update_pairs(&mut self, s: u32) {
        let base = self.pair_base();
        let mut half = std::mem::take(&mut self.half);
        half.clear();
        let (mut prev, mut e) = (NONE, self.pair_head[s as usize]);
        while e != NONE {
            let nxt = self.pair_next[e as usize];
            let [u, v] = self.pair_ends[e as usize / 2];
            let slot = base + e / 2;
            self.refused[slot as usize] = false;
            if u == v {
                self.heap.remove(slot);
                match prev {
                    NONE => self.pair_head[s as usize] = nxt,
                    p => self.pair_next[p as usize] = nxt,
                }
            } else {
                half.push((u ^ v ^ s, slot));
                prev = e;
            }
            e = nxt;
        }
        half.sort_unstable();
        for (i, &(x, slot)) in half.iter().enumerate() {
            if i > 0 && half[i - 1].0 == x {
                self.heap.remove(slot);
            } else {
                self.push(slot);
            }
        }
        self.half = half;
    }

    /// Collapses until `target` triangles or no valid collapse is left, by the engine
    /// `params.engine` names.
    pub fn run(&mut self, target: usize) {
        match self.params.engine {
            super::Engine::Heap => self.run_fast(target),
            super::Engine::Passes => self.run_passes(target),
        }
    }

    /// The heap-driven loop (the heap engine's; the heap is filled when the engine is
    /// set up with `Engine::Heap`): collapse the least-cost valid edge until `target` triangles
    /// or no valid collapse is left.
    pub fn run_fast(&mut self, target: usize) {
        while self.tris > target {
            let Some((k, corner)) = self.heap.pop() else {
                break;
            };
            let (a, b) = ((k >> 32) as u32, k as u32);
            let Some(mut c) = self.candidate(a, b) else {
                continue;
            };
            let ok = match corner >= self.pair_base() {
                true => self.valid_pair(a, b, &c),
                false => self.valid(a, b, &mut c),
            };
            if ok {
                self.collapse(a, b, &c);
                self.update(a);
            } else {
                self.rejected += 1;
                self.refused[corner as usize] = true;
                self.vx[a as usize].refused_at += 1;
                self.vx[b as usize].refused_at += 1;
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
            let n_edges = edges.len();
            let mut pairs: Vec<[u32; 2]> = self
                .pair_ends
                .iter()
                .filter(|[u, v]| u != v)
                .map(|&[u, v]| [u.min(v), u.max(v)])
                .collect();
            pairs.sort_unstable();
            pairs.dedup();
            edges.extend(pairs);
            let mut best: Option<(u64, u32, u32, Candidate)> = None;
            for (i, &[a, b]) in edges.iter().enumerate() {
                let Some(mut c) = self.candidate(a, b) else {
                    continue;
                };
                let key = (c.cost.to_bits(), a, b);
                if best.as_ref().is_some_and(|x| (x.0, x.1, x.2) <= key) {
                    continue;
                }
                let ok = match i >= n_edges {
                    true => self.valid_pair(a, b, &c),
                    false => self.valid(a, b, &mut c),
                };
                if ok {
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
        let mut out_of = vec![NONE; self.vx.len()];
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
                        out.positions.push(self.vx[d].p.as_vec3());
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
                        out.positions.push(self.vx[d].p.as_vec3());
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
    // Cramer's rule through the cofactor columns: the determinant is computed once
    // (`DMat3::inverse` would compute it again).
    let m = q.matrix();
    let (c0, c1, c2) = (m.x_axis, m.y_axis, m.z_axis);
    let (k0, k1, k2) = (c1.cross(c2), c2.cross(c0), c0.cross(c1));
    let det = c0.dot(k0);
    let s = q.weight() / 3.0;
    if s > 0.0 && det.abs() > ILL_CONDITIONED * s * s * s {
        let r = -q.linear();
        let x = DVec3::new(k0.dot(r), k1.dot(r), k2.dot(r)) / det;
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

/// [`super::simplify`] through the slow twin (every candidate recomputed every step).
pub fn simplify_slow(mesh: &TriMesh, params: &QemParams) -> crate::error::Result<QemResult> {
    super::check(mesh, params)?;
    let prep = Prepared::new(mesh);
    let mut c = Collapse::new(&prep, params);
    c.pairs_ok()?;
    c.run_slow(params.triangles as usize);
    Ok(c.finish())
}
