//! Adaptive octree clustering, the paper's method (Kim et al. 1999 §III).
//!
//! The bounding cube is subdivided as an octree: a node splits into its eight octants
//! (empty octants are not created) while its vertices spread (Dv, eq. 5–6) and its
//! triangles' normals vary (θmax, θavg, eq. 1–4); each leaf is one cluster, represented by
//! its quadric-optimal point.
//!
//! 1. **The split score: the paper's quantities.** Dv = the mean distance of a node's
//!    vertices to their centroid (eq. 5–6); θavg = the normal variation of the triangles in
//!    the node (a triangle is in it once per corner there, with a third of its area) about
//!    their mean normal N = Σ A·n / ‖Σ A·n‖, taken as acos of the area-weighted mean cosine,
//!    acos(‖Σ A·n‖ / Σ A) (eq. 2–4 average the angle itself; the mean cosine makes θavg a sum
//!    over members, so an octant's is summed in the same pass that sorts it); θmax = the
//!    largest angle between the normals of two adjacent triangles in the node (eq. 1). The
//!    paper splits while `Dv · (1 + a·θavg + b·θmax) > T` and leaves the weights open; we
//!    multiply by the node's area A (Σ A/3 over its triangles' corners) — `A · Dv · (1 +
//!    a·θavg + b·θmax)` is then about the node's share of the mean error (area × sagitta ∝
//!    A · Dv · θ on a curved surface) — and split in order of decreasing score from a
//!    priority queue until the target is reached, so one pass sweeps T from +∞ down.
//!    Defaults a = 3, b = 0.5, by measurement (docs/notes/octree.md).
//! 2. **The split.** A node splits at the centre of its cell into (up to) eight octants, as
//!    in the paper. A cell whose vertices all lie in one octant shrinks to it and splits
//!    again (the chain of one-child nodes collapsed). [`SplitPoint::Centroid`] splits at
//!    the vertices' centroid instead (a point-region octree); it measured worse (notes).
//! 3. **Relaxation.** Two passes after the tree: in each, every vertex on a cluster's
//!    border moves to the cluster, among its own and those of its triangles' other
//!    corners, whose quadric representative lies closest to the planes of its own
//!    triangles (its quadric divided by its weight, evaluated at that representative),
//!    plus 10⁻⁴ × its squared distance to that cluster's centroid (which keeps clusters
//!    compact where the planes do not decide); then the representatives are recomputed.
//!    All moves of a pass are decided from the clusters before it. The octants' straight
//!    walls cut across features; the passes move the borders onto them (without them the
//!    errors are 20–50 % higher, docs/notes/octree.md).
//!
//! Selective refinement (the paper's Fig. 8): a node whose cell meets a refine box has its
//! score multiplied by factor⁴; on a curved surface the score grows as the cell size to the
//! fourth power (A ∝ s², Dv ∝ s, θavg ∝ s), so cells there come out about `factor` times smaller.
//!
//! Reaching a target: the greedy pass keeps the number of surviving triangles up to date
//! incrementally (only triangles around the split node's vertices change) and stops at the
//! prefix of its split sequence closest to the goal; relaxation and duplicate triangles then
//! shift the exact count by a few per cent, so the goal is corrected from the exact count
//! (splits are undone or made from where the pass stands) at most three times.

use super::{quadric_point, Clustering, NormalStats, Prepared, RefineBox, SimplifyParams, Target};
use crate::mesh::adjacency::VertexFaces;
use crate::simplify::quadric::Quadric;
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// Default weight of θavg (radians) in the normal-variation factor.
pub const THETA_AVG_WEIGHT: f64 = 3.0;
/// Default weight of θmax (radians) in the normal-variation factor.
pub const THETA_MAX_WEIGHT: f64 = 0.5;
/// Relaxation passes after the tree is built.
pub const RELAX_PASSES: usize = 2;
/// Weight of the squared distance to a cluster's centroid in the relaxation's cost.
pub const COMPACTNESS: f64 = 1e-4;
/// Where a node's eight octants meet, by default.
pub const SPLIT_POINT: SplitPoint = SplitPoint::CellCentre;
/// With a target, nodes of more vertices than this (or than 16 × an average cluster) are
/// split before the greedy pass.
const FORCE_MIN: usize = 2048;
/// Deepest node (the root is depth 0).
const MAX_DEPTH: u32 = 96;
/// Member lists longer than this are summed in fixed chunks in parallel (the chunks, not
/// the threads, fix the order of the sums: figures are identical for any thread count).
const CHUNK: usize = 8192;

/// Octree settings beyond the target.
#[derive(Debug, Clone, PartialEq)]
pub struct OctreeOptions {
    /// Weight of θavg in the normal-variation factor.
    pub theta_avg_weight: f64,
    /// Weight of θmax in the normal-variation factor.
    pub theta_max_weight: f64,
    /// Boxes refined more finely.
    pub refine: Vec<RefineBox>,
    /// Relaxation passes after the tree.
    pub relax_passes: usize,
    /// Where a node's octants meet.
    pub split_point: SplitPoint,
}

/// Where a node's eight octants meet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SplitPoint {
    /// The node's vertex centroid (a point-region octree: octants of unequal size).
    Centroid,
    /// The centre of the node's cell (the classic octree: eight equal octants).
    CellCentre,
}

impl OctreeOptions {
    /// The options `params` give (defaults where absent).
    pub fn from_params(p: &SimplifyParams) -> OctreeOptions {
        OctreeOptions {
            theta_avg_weight: p.theta_avg_weight.unwrap_or(THETA_AVG_WEIGHT),
            theta_max_weight: p.theta_max_weight.unwrap_or(THETA_MAX_WEIGHT),
            refine: p.refine.clone(),
            relax_passes: RELAX_PASSES,
            split_point: SPLIT_POINT,
        }
    }
}

/// What one pass over a node's members gathers.
#[derive(Debug, Clone, Copy)]
struct Summary {
    q: Quadric,
    sum: DVec3,
    lo: DVec3,
    hi: DVec3,
    n: usize,
    /// Σ (A/3)·n over the members' triangles (each triangle once per corner here).
    an: DVec3,
    /// Σ A/3 over the same.
    area: f64,
    /// The largest θmax of a member.
    tmax: f64,
}

impl Summary {
    const EMPTY: Summary = Summary {
        q: Quadric::ZERO,
        sum: DVec3::ZERO,
        lo: DVec3::splat(f64::INFINITY),
        hi: DVec3::splat(f64::NEG_INFINITY),
        n: 0,
        an: DVec3::ZERO,
        area: 0.0,
        tmax: 0.0,
    };

    fn add(&mut self, r: &Rec) {
        self.q += r.q;
        self.sum += r.p;
        self.lo = self.lo.min(r.p);
        self.hi = self.hi.max(r.p);
        self.n += 1;
        self.an += r.an.as_dvec3();
        self.area += r.area as f64;
        self.tmax = self.tmax.max(r.tmax as f64);
    }

    fn merge(mut self, o: Summary) -> Summary {
        self.q += o.q;
        self.sum += o.sum;
        self.lo = self.lo.min(o.lo);
        self.hi = self.hi.max(o.hi);
        self.n += o.n;
        self.an += o.an;
        self.area += o.area;
        self.tmax = self.tmax.max(o.tmax);
        self
    }

    /// θavg of the members' triangles: the angle whose cosine is the area-weighted mean
    /// cosine between their normals and the mean normal N = Σ A·n / ‖Σ A·n‖, i.e.
    /// acos(‖Σ A·n‖ / Σ A).
    fn theta_avg(&self) -> f64 {
        if self.area > 0.0 {
            (self.an.length() / self.area).clamp(-1.0, 1.0).acos()
        } else {
            0.0
        }
    }

    fn centroid(&self) -> DVec3 {
        self.sum / self.n.max(1) as f64
    }
}

/// A vertex's quadric and position, stored in the tree's member order so that the passes
/// over a node stream through memory instead of gathering by vertex id.
#[derive(Debug, Clone, Copy)]
struct Rec {
    q: Quadric,
    p: DVec3,
    /// Σ (A/3)·n over the vertex's triangles (f32: a split heuristic needs no more, and
    /// the passes over a node are bound by the bytes they stream).
    an: Vec3,
    /// Σ A/3 over them.
    area: f32,
    /// The largest angle between the normals of two of its triangles sharing an edge.
    tmax: f32,
}

/// `f` over `m` in fixed chunks (in parallel when there are several), combined in order.
fn chunked<S: Sync, T: Send>(
    m: &[S],
    f: impl Fn(&[S]) -> T + Sync,
    combine: impl Fn(T, T) -> T,
) -> T {
    if m.len() <= CHUNK {
        return f(m);
    }
    let parts: Vec<T> = m.par_chunks(CHUNK).map(&f).collect();
    let mut it = parts.into_iter();
    let first = it.next().expect("at least one chunk");
    it.fold(first, combine)
}

/// Per-vertex inputs, by dense index (views of what [`Prepared`] computes anyway: the
/// quadric representative needs the quadrics, and they need the vertex → triangles rows;
/// the normal statistics come from the same pass as the quadrics).
struct Data<'a> {
    prep: &'a Prepared<'a>,
    quadrics: &'a [Quadric],
    faces: &'a VertexFaces,
    /// Per vertex (not dense index): Σ (A/3)·n, Σ A/3 and θmax (see [`NormalStats`]).
    normals: &'a [NormalStats],
}

impl<'a> Data<'a> {
    fn new(prep: &'a Prepared<'a>) -> Data<'a> {
        let (quadrics, normals) = prep.quadrics_and_normals();
        Data {
            prep,
            quadrics,
            faces: prep.vertex_faces(),
            normals,
        }
    }

    /// The record of dense vertex `d`.
    #[inline]
    fn rec(&self, d: u32) -> Rec {
        let v = self.prep.active[d as usize] as usize;
        let ns = self.normals[v];
        Rec {
            q: self.quadrics[v],
            p: self.pos(d),
            an: ns.area_normal,
            area: ns.area,
            tmax: ns.theta_max,
        }
    }

    /// The quadric of dense vertex `d`.
    #[inline]
    fn q(&self, d: u32) -> &'a Quadric {
        &self.quadrics[self.prep.active[d as usize] as usize]
    }

    /// The triangles of dense vertex `d` (indices into `dense_faces`, which has the welded
    /// triangles' order).
    #[inline]
    fn faces_of(&self, d: u32) -> &'a [u32] {
        self.faces.of(self.prep.active[d as usize])
    }

    #[inline]
    fn pos(&self, d: u32) -> DVec3 {
        self.prep.dense_pos[d as usize].as_dvec3()
    }

    fn summary(&self, m: &[u32]) -> Summary {
        chunked(
            m,
            |part| {
                let mut s = Summary::EMPTY;
                for &d in part {
                    s.add(&self.rec(d));
                }
                s
            },
            Summary::merge,
        )
    }
}

/// A node of the subdivision.
#[derive(Debug, Clone, Copy)]
struct Node {
    /// The node's cell (for the refine boxes).
    lo: DVec3,
    hi: DVec3,
    /// Members are `perm[start..end]`.
    start: usize,
    end: usize,
    depth: u32,
    /// Position sum of the members.
    sum: DVec3,
    score: f64,
    state: State,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// A current leaf: a cluster.
    Leaf,
    /// Split into `count` children, nodes `first..first + count` (the non-empty octants,
    /// `perm`-adjacent in octant order).
    Split { first: u32, count: u32 },
    /// A child of an undone split (its queue entry, if any, is stale).
    Dead,
}

/// A queue entry: larger score first, then the older node.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Entry {
    score: f64,
    node: u32,
}

impl Eq for Entry {}

impl Ord for Entry {
    fn cmp(&self, o: &Self) -> Ordering {
        self.score.total_cmp(&o.score).then(o.node.cmp(&self.node))
    }
}

impl PartialOrd for Entry {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

/// A split made, to undo it.
#[derive(Debug, Clone, Copy)]
struct Logged {
    node: u32,
    /// The fast count before it, when it was being kept.
    count_before: Option<usize>,
}

struct Tree<'a> {
    data: Data<'a>,
    opts: &'a OctreeOptions,
    nodes: Vec<Node>,
    /// Vertices in node order: a node's members are `perm[start..end]`.
    perm: Vec<u32>,
    /// Their records, in the same order.
    recs: Vec<Rec>,
    scratch: Vec<u32>,
    scratch_recs: Vec<Rec>,
    /// Octant of every member of the node being split.
    codes: Vec<u8>,
    heap: BinaryHeap<Entry>,
    /// Leaf (node id) of every vertex.
    leaf_of: Vec<u32>,
    leaves: usize,
    /// Surviving triangles (three different leaves, duplicates included), once kept.
    count: Option<usize>,
    log: Vec<Logged>,
    touched: Vec<u32>,
}

impl<'a> Tree<'a> {
    /// The tree's first leaves. With `force`, every node of more than that many vertices is
    /// split first, in parallel (see [`force_split`]); otherwise the root is the one leaf.
    fn new(prep: &'a Prepared<'a>, opts: &'a OctreeOptions, force: Option<usize>) -> Tree<'a> {
        let data = Data::new(prep);
        let n = prep.dense_pos.len();
        let mut perm: Vec<u32> = (0..n as u32).collect();
        // The root cell: the bounding cube (the paper's octree), centred on the bounding box.
        let (lo, hi) = (prep.bounds.min.as_dvec3(), prep.bounds.max.as_dvec3());
        let (c, h) = ((lo + hi) * 0.5, (hi - lo).max_element() * 0.5);
        let (lo, hi) = (c - DVec3::splat(h), c + DVec3::splat(h));
        let mut pieces = Vec::new();
        match force {
            Some(limit) if n > limit => {
                let sum = data.summary(&perm).sum;
                let sp = opts.split_point;
                force_split(
                    &data,
                    sp,
                    &mut perm,
                    0,
                    (lo, hi),
                    sum,
                    0,
                    limit,
                    &mut pieces,
                );
            }
            _ => pieces.push(Piece {
                lo,
                hi,
                start: 0,
                end: n,
                depth: 0,
            }),
        }
        let recs: Vec<Rec> = perm
            .par_iter()
            .with_min_len(4096)
            .map(|&v| data.rec(v))
            .collect();
        let mut leaf_of = vec![0; n];
        for (id, pc) in pieces.iter().enumerate() {
            for &v in &perm[pc.start..pc.end] {
                leaf_of[v as usize] = id as u32;
            }
        }
        let mut tree = Tree {
            data,
            opts,
            nodes: Vec::new(),
            perm,
            recs,
            scratch: Vec::new(),
            scratch_recs: Vec::new(),
            codes: Vec::new(),
            heap: BinaryHeap::new(),
            leaf_of,
            leaves: pieces.len(),
            count: None,
            log: Vec::new(),
            touched: Vec::new(),
        };
        let t = &tree;
        let nodes: Vec<Node> = pieces
            .par_iter()
            .map(|pc| {
                let m = &t.recs[pc.start..pc.end];
                let mut s = Summary::EMPTY;
                for r in m {
                    s.add(r);
                }
                let c = s.centroid();
                let dv = m.iter().map(|r| (r.p - c).length()).sum::<f64>() / m.len().max(1) as f64;
                t.make_node(pc.lo, pc.hi, pc.start, pc.end, pc.depth, &s, dv)
            })
            .collect();
        for (id, node) in nodes.iter().enumerate() {
            tree.heap.push(Entry {
                score: node.score,
                node: id as u32,
            });
        }
        tree.nodes = nodes;
        tree
    }

    /// The score of a node with members summarised by `s` (see the module header).
    fn score(&self, s: &Summary, dv: f64, depth: u32, lo: DVec3, hi: DVec3) -> f64 {
        if s.n < 2 || depth >= MAX_DEPTH || !(s.area > 0.0 && s.area.is_finite()) {
            return 0.0;
        }
        let factor = self
            .opts
            .refine
            .iter()
            .filter(|b| {
                lo.cmple(DVec3::from_array(b.max)).all() && hi.cmpge(DVec3::from_array(b.min)).all()
            })
            .map(|b| b.factor.powi(4))
            .reduce(f64::max)
            .unwrap_or(1.0);
        let o = self.opts;
        s.area
            * dv
            * (1.0 + o.theta_avg_weight * s.theta_avg() + o.theta_max_weight * s.tmax)
            * factor
    }

    #[allow(clippy::too_many_arguments)]
    fn make_node(
        &self,
        lo: DVec3,
        hi: DVec3,
        start: usize,
        end: usize,
        depth: u32,
        s: &Summary,
        dv: f64,
    ) -> Node {
        Node {
            lo,
            hi,
            start,
            end,
            depth,
            sum: s.sum,
            score: self.score(s, dv, depth, lo, hi),
            state: State::Leaf,
        }
    }

    /// Splits leaf `id` into its non-empty octants around the split point; returns the
    /// children's ids (None when all its members coincide).
    ///
    /// With the cell centre as split point, a cell whose members all fall in one octant
    /// is shrunk to that octant and tried again (the chain of one-child nodes a plain
    /// octree would build there, collapsed).
    fn split(&mut self, id: u32) -> Option<std::ops::Range<u32>> {
        let node = self.nodes[id as usize];
        let n = node.end - node.start;
        let (mut lo, mut hi) = (node.lo, node.hi);
        let mut codes = std::mem::take(&mut self.codes);
        // Pass 1: every member's octant, and each octant's summary.
        let mut bins;
        let mut c;
        let mut depth = node.depth;
        loop {
            c = match self.opts.split_point {
                SplitPoint::Centroid => node.sum / n as f64,
                SplitPoint::CellCentre => (lo + hi) * 0.5,
            };
            codes.clear();
            bins = [Summary::EMPTY; 8];
            for r in &self.recs[node.start..node.end] {
                let o = octant(r.p, c);
                codes.push(o as u8);
                bins[o].add(r);
            }
            let full = bins.iter().filter(|b| b.n > 0).count();
            if full >= 2 {
                break;
            }
            if self.opts.split_point == SplitPoint::Centroid || depth >= MAX_DEPTH {
                self.codes = codes;
                return None;
            }
            let o = bins.iter().position(|b| b.n > 0).expect("members");
            (lo, hi) = octant_cell(lo, hi, c, o);
            depth += 1;
        }
        // Pass 2: scatter the members into octant order (stable), measuring each
        // octant's Dv on the way (its centroid is known from pass 1).
        let mut at = [0usize; 8];
        let mut next = 0;
        for (o, b) in bins.iter().enumerate() {
            at[o] = next;
            next += b.n;
        }
        let starts = at;
        let centre = bins.map(|b| b.centroid());
        let mut dist = [0.0f64; 8];
        self.scratch.resize(n, 0);
        self.scratch_recs.resize(n, self.recs[node.start]);
        for (i, &o) in codes.iter().enumerate() {
            let o = o as usize;
            let r = self.recs[node.start + i];
            dist[o] += (r.p - centre[o]).length();
            self.scratch[at[o]] = self.perm[node.start + i];
            self.scratch_recs[at[o]] = r;
            at[o] += 1;
        }
        self.perm[node.start..node.end].copy_from_slice(&self.scratch[..n]);
        self.recs[node.start..node.end].copy_from_slice(&self.scratch_recs[..n]);
        self.codes = codes;
        let first = self.nodes.len() as u32;
        for o in 0..8 {
            let b = &bins[o];
            if b.n == 0 {
                continue;
            }
            let (clo, chi) = octant_cell(lo, hi, c, o);
            let start = node.start + starts[o];
            let kid = self.make_node(
                clo,
                chi,
                start,
                start + b.n,
                depth + 1,
                b,
                dist[o] / b.n as f64,
            );
            self.nodes.push(kid);
        }
        let last = self.nodes.len() as u32;
        self.nodes[id as usize].state = State::Split {
            first,
            count: last - first,
        };
        Some(first..last)
    }

    /// Triangles with two or more corners among `perm[start..end]` (which are all in leaf
    /// `leaf`): the only ones whose survival a change of those vertices' leaves can alter.
    /// Each is listed once, from its first corner there.
    fn collect_touched(&mut self, start: usize, end: usize, leaf: u32) {
        self.touched.clear();
        let faces = &self.data.prep.dense_faces;
        for &d in &self.perm[start..end] {
            for &f in self.data.faces_of(d) {
                let t = faces[f as usize];
                let mut inside = 0;
                let mut first = u32::MAX;
                for &x in &t {
                    if self.leaf_of[x as usize] == leaf {
                        inside += 1;
                        if first == u32::MAX {
                            first = x;
                        }
                    }
                }
                if inside >= 2 && first == d {
                    self.touched.push(f);
                }
            }
        }
    }

    fn survivors(&self, faces: &[u32]) -> usize {
        let tri = &self.data.prep.dense_faces;
        faces
            .iter()
            .filter(|&&f| {
                let t = tri[f as usize];
                let l = t.map(|v| self.leaf_of[v as usize]);
                l[0] != l[1] && l[1] != l[2] && l[0] != l[2]
            })
            .count()
    }

    /// Pops the best leaf and splits it; false when no leaf with a score above `floor` can
    /// be split. With `keep_count` the count (which must be known) is kept up to date;
    /// otherwise it becomes unknown.
    fn step(&mut self, keep_count: bool, floor: f64) -> bool {
        loop {
            let Some(top) = self.heap.pop() else {
                return false;
            };
            let node = self.nodes[top.node as usize];
            if node.state != State::Leaf {
                continue;
            }
            if top.score <= floor {
                self.heap.push(top);
                return false;
            }
            let keep = keep_count && self.count.is_some();
            // Before the split these triangles are degenerate (two corners in one leaf).
            if keep {
                self.collect_touched(node.start, node.end, top.node);
            }
            let Some(kids) = self.split(top.node) else {
                // Cannot be cut (coincident vertices): a leaf for good.
                self.nodes[top.node as usize].score = 0.0;
                continue;
            };
            for k in kids.clone() {
                let kn = self.nodes[k as usize];
                for i in kn.start..kn.end {
                    self.leaf_of[self.perm[i] as usize] = k;
                }
                self.heap.push(Entry {
                    score: kn.score,
                    node: k,
                });
            }
            self.leaves += kids.len() - 1;
            let before = self.count;
            self.count = match self.count {
                Some(c) if keep => Some(c + self.survivors(&self.touched)),
                _ => None,
            };
            self.log.push(Logged {
                node: top.node,
                count_before: before,
            });
            return true;
        }
    }

    /// The fast count from scratch.
    fn recount(&mut self) -> usize {
        let c = super::count_surviving(&self.data.prep.dense_faces, &self.leaf_of);
        self.count = Some(c);
        c
    }

    /// Splits without keeping the count until about `fraction` of the leaves `goal` needs
    /// (predicted from the triangles per leaf so far, two to start with), then counts.
    fn bulk(&mut self, goal: u64, fraction: f64) {
        let per_leaf = match self.count {
            Some(c) if self.leaves > 0 && c > 0 => c as f64 / self.leaves as f64,
            _ => 2.0,
        };
        let leaves = (fraction * goal as f64 / per_leaf) as usize;
        if self.count.is_some() && leaves <= self.leaves + 16 {
            return;
        }
        while self.leaves < leaves {
            if !self.step(false, 0.0) {
                break;
            }
        }
        self.recount();
    }

    /// Undoes the last split.
    fn undo(&mut self) {
        let Some(l) = self.log.pop() else { return };
        let node = self.nodes[l.node as usize];
        let State::Split { first, count } = node.state else {
            unreachable!("a logged node is split")
        };
        for k in first..first + count {
            self.nodes[k as usize].state = State::Dead;
        }
        for i in node.start..node.end {
            self.leaf_of[self.perm[i] as usize] = l.node;
        }
        self.nodes[l.node as usize].state = State::Leaf;
        self.heap.push(Entry {
            score: node.score,
            node: l.node,
        });
        self.leaves -= count as usize - 1;
        self.count =
            Some(l.count_before.unwrap_or_else(|| {
                super::count_surviving(&self.data.prep.dense_faces, &self.leaf_of)
            }));
    }

    /// Moves along the split sequence to the state whose fast count is closest to `goal`.
    fn seek(&mut self, goal: u64) {
        let miss = |c: usize| (c as i64 - goal as i64).unsigned_abs();
        let now = |t: &Tree| t.count.unwrap_or(0);
        if self.count.is_none_or(|c| (c as u64) < goal) {
            // Most splits happen far from the goal, where the count is not needed: split
            // in bulk to half the goal, then to 97 % of it as predicted by the triangles
            // per leaf there, and keep the count exactly only for the last splits.
            if self.count.is_none() {
                self.bulk(goal, 0.5);
            }
            if now(self) < goal as usize {
                self.bulk(goal, 0.97);
            }
            while now(self) < goal as usize {
                if !self.step(true, 0.0) {
                    return;
                }
            }
            // Past the goal: the state before the last split may be closer.
            if let Some(b) = self.log.last().and_then(|l| l.count_before) {
                if miss(b) < miss(now(self)) {
                    self.undo();
                }
            }
        } else {
            while now(self) as u64 > goal && !self.log.is_empty() {
                self.undo();
            }
            // Below the goal: one more split may be closer.
            let below = now(self);
            if self.step(true, 0.0) && miss(now(self)) >= miss(below) {
                self.undo();
            }
        }
    }

    /// The largest score of a leaf (the threshold the current state stands for).
    fn threshold(&self) -> f64 {
        self.nodes
            .iter()
            .filter(|n| n.state == State::Leaf)
            .map(|n| n.score)
            .fold(0.0, f64::max)
    }

    /// The clusters after `passes` relaxation passes, as a key per vertex.
    fn relaxed(&self, passes: usize) -> Vec<u32> {
        // Dense cluster ids from the leaf ids.
        let mut id = vec![u32::MAX; self.nodes.len()];
        let mut nc = 0u32;
        let mut keys: Vec<u32> = self
            .leaf_of
            .iter()
            .map(|&l| {
                if id[l as usize] == u32::MAX {
                    id[l as usize] = nc;
                    nc += 1;
                }
                id[l as usize]
            })
            .collect();
        for _ in 0..passes {
            keys = relax_pass(&self.data, &keys, nc as usize);
        }
        keys
    }
}

/// A first leaf of the tree: a cell and a range of `perm`.
#[derive(Debug, Clone, Copy)]
struct Piece {
    lo: DVec3,
    hi: DVec3,
    start: usize,
    end: usize,
    depth: u32,
}

/// The octant of `p` around `c`: bit k set when `p[k] >= c[k]`.
#[inline]
fn octant(p: DVec3, c: DVec3) -> usize {
    (p.x >= c.x) as usize | ((p.y >= c.y) as usize) << 1 | ((p.z >= c.z) as usize) << 2
}

/// The cell of octant `o` of the cell `lo..hi` split at `c`.
fn octant_cell(lo: DVec3, hi: DVec3, c: DVec3, o: usize) -> (DVec3, DVec3) {
    let (mut a, mut b) = (lo, hi);
    for k in 0..3 {
        if (o >> k) & 1 == 1 {
            a[k] = c[k];
        } else {
            b[k] = c[k];
        }
    }
    (a, b)
}

/// Splits every node of more than `limit` vertices into its octants, recursively and in
/// parallel, and lists the resulting leaves in depth-first order. Such nodes are split by
/// the greedy pass in any case (at the targets this is used for, a leaf averages a
/// sixteenth of `limit` vertices), so only the order of the work changes: their scores,
/// and the exact sums they would need, are skipped, and the octants go to several threads.
#[allow(clippy::too_many_arguments)]
fn force_split(
    d: &Data,
    split_point: SplitPoint,
    perm: &mut [u32],
    start: usize,
    cell: (DVec3, DVec3),
    sum: DVec3,
    depth: u32,
    limit: usize,
    out: &mut Vec<Piece>,
) {
    let n = perm.len();
    let leaf = Piece {
        lo: cell.0,
        hi: cell.1,
        start,
        end: start + n,
        depth,
    };
    if n <= limit || depth >= MAX_DEPTH {
        out.push(leaf);
        return;
    }
    let c = match split_point {
        SplitPoint::Centroid => sum / n as f64,
        SplitPoint::CellCentre => (cell.0 + cell.1) * 0.5,
    };
    // Stable counting sort into octant order, summing each octant's positions.
    let mut count = [0usize; 8];
    let mut sums = [DVec3::ZERO; 8];
    for &v in perm.iter() {
        let p = d.pos(v);
        let o = octant(p, c);
        count[o] += 1;
        sums[o] += p;
    }
    if count.iter().filter(|&&k| k > 0).count() < 2 && split_point == SplitPoint::Centroid {
        out.push(leaf); // all members coincide
        return;
    }
    let mut at = [0usize; 8];
    let mut next = 0;
    for o in 0..8 {
        at[o] = next;
        next += count[o];
    }
    let mut sorted = vec![0u32; n];
    for &v in perm.iter() {
        let o = octant(d.pos(v), c);
        sorted[at[o]] = v;
        at[o] += 1;
    }
    perm.copy_from_slice(&sorted);
    drop(sorted);
    // The octants' slices, in order (empty ones dropped).
    let mut parts = Vec::with_capacity(8);
    let mut rest = perm;
    let mut offset = start;
    for (o, &k) in count.iter().enumerate() {
        let (mine, tail) = rest.split_at_mut(k);
        rest = tail;
        if k > 0 {
            parts.push((o, mine, offset));
        }
        offset += k;
    }
    let recurse = |(o, part, s): (usize, &mut [u32], usize)| {
        let mut pieces = Vec::new();
        let cell = octant_cell(cell.0, cell.1, c, o);
        let sum = sums[o];
        force_split(
            d,
            split_point,
            part,
            s,
            cell,
            sum,
            depth + 1,
            limit,
            &mut pieces,
        );
        pieces
    };
    if n > CHUNK {
        let lists: Vec<Vec<Piece>> = parts.into_par_iter().map(recurse).collect();
        out.extend(lists.into_iter().flatten());
    } else {
        for part in parts {
            out.extend(recurse(part));
        }
    }
}

/// One relaxation pass (see the module header): returns every vertex's new cluster.
fn relax_pass(d: &Data, keys: &[u32], nc: usize) -> Vec<u32> {
    let n = keys.len();
    // Quadric, position sum, box and size per cluster, summed in vertex order: the
    // quadrics are then read in sequence and the sums (a few hundred KB) stay in cache;
    // gathering each cluster's members instead cost twice as much.
    let mut acc = vec![
        (
            Quadric::ZERO,
            DVec3::ZERO,
            DVec3::INFINITY,
            DVec3::NEG_INFINITY,
            0u32
        );
        nc
    ];
    for (v, &c) in keys.iter().enumerate() {
        let p = d.pos(v as u32);
        let a = &mut acc[c as usize];
        a.0 += *d.q(v as u32);
        a.1 += p;
        a.2 = a.2.min(p);
        a.3 = a.3.max(p);
        a.4 += 1;
    }
    // (representative, centroid) per cluster.
    let reps: Vec<(DVec3, DVec3)> = acc
        .par_iter()
        .with_min_len(256)
        .map(|&(q, sum, lo, hi, k)| {
            if k == 0 {
                return (DVec3::NAN, DVec3::NAN);
            }
            let centroid = sum / k as f64;
            (quadric_point(&q, centroid, lo, hi), centroid)
        })
        .collect();
    let tri = &d.prep.dense_faces;
    (0..n as u32)
        .into_par_iter()
        .with_min_len(1024)
        .map(|v| {
            let q = d.q(v);
            let w = q.weight();
            let p = d.pos(v);
            let cost = |c: u32| {
                let (x, centroid) = reps[c as usize];
                let planes = if w > 0.0 { q.eval(x) / w } else { 0.0 };
                planes + COMPACTNESS * (p - centroid).length_squared()
            };
            let own = keys[v as usize];
            // Inside a cluster (most vertices) nothing is evaluated.
            let mut best = (f64::NAN, own);
            let mut last = own;
            for &f in d.faces_of(v) {
                for &u in &tri[f as usize] {
                    let c = keys[u as usize];
                    if c == last || c == own {
                        continue;
                    }
                    last = c;
                    if best.0.is_nan() {
                        best.0 = cost(own);
                    }
                    let e = cost(c);
                    if e < best.0 || (e == best.0 && c < best.1 && best.1 != own) {
                        best = (e, c);
                    }
                }
            }
            best.1
        })
        .collect()
}

/// Clusters `prep` with the adaptive octree: returns the clustering, the threshold reached
/// and the number of splits made.
pub fn cluster(prep: &Prepared, target: Target, opts: &OctreeOptions) -> (Clustering, f64, usize) {
    // With a target, nodes of more than 16 × the vertices of an average cluster (and more
    // than FORCE_MIN) are split up front.
    let force = match target {
        Target::Triangles(t) => {
            let n = prep.dense_pos.len() as u64;
            Some((16 * n / t.max(1)).max(FORCE_MIN as u64) as usize)
        }
        Target::Scale(_) => None,
    };
    let mut tree = Tree::new(prep, opts, force);
    let faces = &prep.dense_faces;
    match target {
        Target::Scale(t) => {
            while tree.step(false, t) {}
            let keys = tree.relaxed(opts.relax_passes);
            (Clustering::from_keys(&keys), t, tree.log.len())
        }
        Target::Triangles(t) => {
            let mut goal = t.max(1);
            let mut best: Option<(u64, Vec<u32>, f64, usize)> = None;
            for _round in 0..4 {
                tree.seek(goal);
                let keys = tree.relaxed(opts.relax_passes);
                let exact = super::count_distinct(faces, &keys) as u64;
                let miss = exact.abs_diff(t);
                if best.as_ref().is_none_or(|b| miss < b.0) {
                    best = Some((miss, keys, tree.threshold(), tree.log.len()));
                }
                // Within 1 % is as close as the grid methods get (their search stops there).
                if miss as f64 <= (0.01 * t as f64).max(1.0) || exact == 0 {
                    break;
                }
                let next = ((goal as f64 * t as f64 / exact as f64).round() as u64).max(1);
                if next == goal {
                    break;
                }
                goal = next;
            }
            let (_, keys, threshold, splits) = best.expect("at least one round");
            (Clustering::from_keys(&keys), threshold, splits)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::grid;
    use super::super::{simplify, Method, SimplifyParams};
    use super::*;
    use crate::mesh::TriMesh;
    use glam::Vec3;

    fn opts(relax: usize) -> OctreeOptions {
        OctreeOptions {
            theta_avg_weight: THETA_AVG_WEIGHT,
            theta_max_weight: THETA_MAX_WEIGHT,
            refine: Vec::new(),
            relax_passes: relax,
            split_point: SPLIT_POINT,
        }
    }

    /// A closed cylinder of radius 1 along x, `len` long, `nu` × `nv` quads.
    fn cylinder(len: f32, nu: usize, nv: usize) -> TriMesh {
        let mut m = TriMesh::default();
        for i in 0..=nu {
            for j in 0..nv {
                let a = std::f32::consts::TAU * j as f32 / nv as f32;
                m.positions
                    .push(Vec3::new(len * i as f32 / nu as f32, a.cos(), a.sin()));
            }
        }
        let id = |i: usize, j: usize| (i * nv + j % nv) as u32;
        for i in 0..nu {
            for j in 0..nv {
                m.indices.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                m.indices.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        // Caps: a centre vertex each.
        for (i, x) in [(0, 0.0), (nu, len)] {
            let c = m.positions.len() as u32;
            m.positions.push(Vec3::new(x, 0.0, 0.0));
            for j in 0..nv {
                if i == 0 {
                    m.indices.push([c, id(i, j + 1), id(i, j)]);
                } else {
                    m.indices.push([c, id(i, j), id(i, j + 1)]);
                }
            }
        }
        m
    }

    #[test]
    fn normal_variation_of_a_flat_patch_and_a_fold() {
        let mut m = grid(6);
        for p in &mut m.positions {
            p.z = 0.0;
        }
        let all: Vec<u32> = (0..49).collect();
        let prep = Prepared::new(&m);
        let s = Data::new(&prep).summary(&all);
        // θavg's inputs are f32: acos near 1 turns their rounding into ~1e-3 rad.
        assert!(s.theta_avg() < 2e-3 && s.tmax < 1e-6, "{s:?}");
        assert!((s.area - 1.0).abs() < 1e-6, "{s:?}");
        // Fold the right half up by 90°: θmax = π/2 along the fold; equal areas on both
        // sides, each 45° from the mean normal.
        for p in &mut m.positions {
            if p.x > 0.5 {
                let d = p.x - 0.5;
                p.x = 0.5;
                p.z = d;
            }
        }
        let prep = Prepared::new(&m);
        let s = Data::new(&prep).summary(&all);
        let (half, quarter) = (std::f64::consts::FRAC_PI_2, std::f64::consts::FRAC_PI_4);
        assert!((s.tmax - half).abs() < 1e-6, "{s:?}");
        assert!((s.theta_avg() - quarter).abs() < 1e-5, "{s:?}");
    }

    #[test]
    fn node_statistics_match_a_pass_over_its_triangles() {
        // The slow twin: θavg and θmax of a vertex subset straight from its triangles.
        let m = cylinder(3.0, 12, 10);
        let prep = Prepared::new(&m);
        let d = Data::new(&prep);
        let tri = &prep.dense_faces;
        let normal = |f: usize| {
            let p = tri[f].map(|v| prep.dense_pos[v as usize].as_dvec3());
            let c = (p[1] - p[0]).cross(p[2] - p[0]);
            (c.normalize(), 0.5 * c.length())
        };
        let members: Vec<u32> = (0..prep.dense_pos.len() as u32)
            .filter(|v| v % 3 != 1)
            .collect();
        let s = d.summary(&members);
        let (mut an, mut area, mut tmax) = (DVec3::ZERO, 0.0, 0.0f64);
        for (f, t) in tri.iter().enumerate() {
            let (n, a) = normal(f);
            for v in t {
                if members.contains(v) {
                    an += n * a / 3.0;
                    area += a / 3.0;
                }
            }
            for (g, u) in tri.iter().enumerate() {
                // Adjacent (an edge in common) and sharing a corner among the members.
                let common: Vec<u32> = t.iter().copied().filter(|x| u.contains(x)).collect();
                if g != f && common.len() == 2 && common.iter().any(|x| members.contains(x)) {
                    tmax = tmax.max(n.dot(normal(g).0).clamp(-1.0, 1.0).acos());
                }
            }
        }
        let slow = (an.length() / area).min(1.0).acos();
        assert!(
            (s.theta_avg() - slow).abs() < 1e-5,
            "{} vs {slow}",
            s.theta_avg()
        );
        assert!((s.area - area).abs() < 1e-6 * area);
        assert!((s.tmax - tmax).abs() < 1e-6, "{} vs {tmax}", s.tmax);
        assert!(s.theta_avg() > 0.3 && tmax > 0.3, "{s:?}");
    }

    #[test]
    fn greedy_pass_equals_the_threshold_tree() {
        // The slow twin: the tree of threshold T built recursively, every node with a
        // score above T split, compared leaf by leaf.
        let m = grid(30);
        let prep = Prepared::new(&m);
        let o = opts(0);
        let (_, t, _) = cluster(&prep, Target::Triangles(300), &o);
        let (fast, _, _) = cluster(&prep, Target::Scale(t), &o);
        let mut tree = Tree::new(&prep, &o, None);
        let mut stack = vec![0u32];
        let mut leaf_of = vec![0u32; prep.dense_pos.len()];
        while let Some(id) = stack.pop() {
            let node = tree.nodes[id as usize];
            let kids = if node.score > t { tree.split(id) } else { None };
            match kids {
                Some(k) => stack.extend(k),
                None => {
                    let node = tree.nodes[id as usize];
                    for i in node.start..node.end {
                        leaf_of[tree.perm[i] as usize] = id;
                    }
                }
            }
        }
        let slow = Clustering::from_keys(&leaf_of);
        assert!(slow.count > 20, "{}", slow.count);
        assert_eq!(fast.count, slow.count);
        assert_eq!(fast.of, slow.of);
    }

    #[test]
    fn a_split_makes_the_non_empty_octants() {
        // The slow twin: the parent's members grouped by hand by their octant around the
        // split point (the cell shrunk first while they all fall in one octant).
        let m = cylinder(6.0, 24, 16);
        let prep = Prepared::new(&m);
        for sp in [SplitPoint::CellCentre, SplitPoint::Centroid] {
            let mut o = opts(0);
            o.split_point = sp;
            let mut tree = Tree::new(&prep, &o, None);
            for _ in 0..60 {
                tree.step(false, 0.0);
            }
            let mut checked = 0;
            for node in &tree.nodes {
                let State::Split { first, count } = node.state else {
                    continue;
                };
                let pts: Vec<(u32, DVec3)> = tree.perm[node.start..node.end]
                    .iter()
                    .map(|&v| (v, tree.data.pos(v)))
                    .collect();
                let which = |p: DVec3, c: DVec3| {
                    let mut o = 0;
                    for k in 0..3 {
                        if p[k] >= c[k] {
                            o += 1 << k;
                        }
                    }
                    o
                };
                let (mut lo, mut hi) = (node.lo, node.hi);
                let c = loop {
                    let c = match sp {
                        SplitPoint::Centroid => {
                            // The node's own sum (summed in member order; the hand sum
                            // agrees up to rounding, which may move a corner by an ulp).
                            let hand = pts.iter().map(|p| p.1).sum::<DVec3>();
                            assert!((hand - node.sum).length() < 1e-9 * pts.len() as f64);
                            node.sum / pts.len() as f64
                        }
                        SplitPoint::CellCentre => (lo + hi) / 2.0,
                    };
                    let o0 = which(pts[0].1, c);
                    if sp == SplitPoint::Centroid || pts.iter().any(|p| which(p.1, c) != o0) {
                        break c;
                    }
                    for k in 0..3 {
                        if o0 & (1 << k) != 0 {
                            lo[k] = c[k];
                        } else {
                            hi[k] = c[k];
                        }
                    }
                };
                let mut kids = (first..first + count).map(|k| tree.nodes[k as usize]);
                for o in 0..8 {
                    let mut want: Vec<u32> = pts
                        .iter()
                        .filter(|p| which(p.1, c) == o)
                        .map(|p| p.0)
                        .collect();
                    if want.is_empty() {
                        continue;
                    }
                    let kid = kids.next().expect("a child per non-empty octant");
                    let mut got = tree.perm[kid.start..kid.end].to_vec();
                    want.sort_unstable();
                    got.sort_unstable();
                    assert_eq!(got, want, "{sp:?} octant {o}");
                    for k in 0..3 {
                        let (a, b) = if o & (1 << k) != 0 {
                            (c[k], hi[k])
                        } else {
                            (lo[k], c[k])
                        };
                        assert_eq!((kid.lo[k], kid.hi[k]), (a, b), "{sp:?} octant {o}");
                    }
                    if sp == SplitPoint::CellCentre {
                        // The root is the bounding cube: every cell is a cube.
                        let e = kid.hi - kid.lo;
                        assert!((e.max_element() - e.min_element()).abs() < 1e-9 * e.x);
                    }
                }
                assert!(kids.next().is_none() && count >= 2);
                checked += 1;
            }
            assert!(checked >= 20, "{sp:?}: {checked}");
        }
    }

    #[test]
    fn relaxation_matches_a_naive_pass() {
        let m = cylinder(4.0, 20, 12);
        let prep = Prepared::new(&m);
        let o = opts(0);
        let (cl, _, _) = cluster(&prep, Target::Triangles(120), &o);
        let d = Data::new(&prep);
        let fast = relax_pass(&d, &cl.of, cl.count);
        // The slow twin: per vertex, every cluster of its triangles' corners, with the
        // representative recomputed from scratch from the cluster's member list.
        let n = cl.of.len();
        for v in 0..n as u32 {
            let cost = |c: u32| {
                let m: Vec<u32> = (0..n as u32).filter(|&u| cl.of[u as usize] == c).collect();
                let mut q = Quadric::ZERO;
                let (mut lo, mut hi, mut s) = (DVec3::INFINITY, DVec3::NEG_INFINITY, DVec3::ZERO);
                for &u in &m {
                    q += *d.q(u);
                    lo = lo.min(d.pos(u));
                    hi = hi.max(d.pos(u));
                    s += d.pos(u);
                }
                let cen = s / m.len() as f64;
                let x = quadric_point(&q, cen, lo, hi);
                let qv = *d.q(v);
                qv.eval(x) / qv.weight() + COMPACTNESS * (d.pos(v) - cen).length_squared()
            };
            let own = cl.of[v as usize];
            let mut cands: Vec<u32> = d
                .faces_of(v)
                .iter()
                .flat_map(|&f| prep.dense_faces[f as usize])
                .map(|u| cl.of[u as usize])
                .filter(|&c| c != own)
                .collect();
            cands.sort_unstable();
            cands.dedup();
            let mut best = (cost(own), own);
            for c in cands {
                let e = cost(c);
                if e < best.0 {
                    best = (e, c);
                }
            }
            assert_eq!(fast[v as usize], best.1, "vertex {v}");
        }
    }

    #[test]
    fn same_clusters_for_any_thread_count() {
        // Big enough for the chunked parallel sums (> 8192 members at the top).
        let m = grid(110);
        crate::testing::assert_same_for_any_thread_count(|| {
            let prep = Prepared::new(&m);
            let o = opts(RELAX_PASSES);
            cluster(&prep, Target::Triangles(2000), &o).0.of
        });
    }

    #[test]
    fn undo_restores_the_count() {
        let m = grid(40);
        let prep = Prepared::new(&m);
        let o = opts(0);
        let mut tree = Tree::new(&prep, &o, None);
        tree.seek(1500);
        let (count, leaves) = (tree.count, tree.leaves);
        let fast = super::super::count_surviving(&prep.dense_faces, &tree.leaf_of);
        assert_eq!(count, Some(fast));
        tree.seek(600);
        let fast = super::super::count_surviving(&prep.dense_faces, &tree.leaf_of);
        assert_eq!(tree.count, Some(fast));
        assert!((fast as i64 - 600).abs() < 30, "{fast}");
        // Undoing splits restores the state exactly.
        let before = (tree.count, tree.leaves, tree.leaf_of.clone());
        for _ in 0..50 {
            assert!(tree.step(true, 0.0));
        }
        assert_ne!(tree.count, before.0);
        for _ in 0..50 {
            tree.undo();
        }
        assert_eq!((tree.count, tree.leaves, tree.leaf_of.clone()), before);
        // Back up to the first goal. The split sequence need not repeat the first one
        // exactly (a re-split node sums its members in their partitioned order, so nearly
        // tied scores may swap), but the count is kept exactly and lands within a split
        // (up to eight children: a few dozen triangles here) of the goal.
        tree.seek(1500);
        let fast = super::super::count_surviving(&prep.dense_faces, &tree.leaf_of);
        assert_eq!(tree.count, Some(fast));
        let miss = |c: usize| (c as i64 - 1500).abs();
        assert!(
            miss(fast) <= 30 && miss(count.unwrap()) <= 30,
            "{fast} vs {count:?}"
        );
        assert!(tree.leaves.abs_diff(leaves) <= 16);
    }

    #[test]
    fn refined_box_gets_more_vertices() {
        let m = grid(40);
        let mut p = SimplifyParams::triangles(Method::Octree, 400);
        let plain = simplify(&m, &p).unwrap().mesh;
        p.refine.push(RefineBox {
            min: [0.0, 0.0, -1.0],
            max: [0.3, 0.3, 1.0],
            factor: 2.0,
        });
        let refined = simplify(&m, &p).unwrap().mesh;
        let inside = |m: &TriMesh| {
            m.positions
                .iter()
                .filter(|p| p.x < 0.3 && p.y < 0.3)
                .count()
        };
        assert!(
            inside(&refined) > 2 * inside(&plain),
            "{} vs {}",
            inside(&refined),
            inside(&plain)
        );
    }
}
