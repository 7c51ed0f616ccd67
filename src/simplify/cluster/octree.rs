//! Adaptive octree clustering, the paper's method (Kim et al., seed 000 §III.2; SPEC §7).
//!
//! The bounding cube is split into octants, and a node keeps splitting while its vertex
//! spread exceeds a threshold that shrinks as its normals vary:
//!
//! - Dv = mean ‖v − v̄‖ over the node's vertices (eq. 5–6);
//! - θmax = the largest angle between the normals of two adjacent triangles in the node
//!   (eq. 1), a triangle being in the node when one of its corners is;
//! - θavg = the area-weighted mean angle between those triangles' normals and the node's
//!   mean-plane normal N = Σ A·n / ‖Σ A·n‖ (eq. 2–4); each triangle counts once per corner
//!   in the node, with a third of its area.
//!
//! Threshold law (the paper leaves it open; ours, chosen by measurement, notes/mesh.md):
//! split when `Dv · (1 + w_avg·θavg + w_max·θmax) > T` (angles in radians), i.e. the
//! threshold on Dv is T / (1 + w_avg·θavg + w_max·θmax). Call the left side the node's
//! score. Nodes inside a user's refine box have their score multiplied by its factor
//! (selective refinement, the paper's Fig. 8).
//!
//! Reaching a target without searching T: nodes are split greedily in order of decreasing
//! score from a priority queue. Stopping when the best remaining score is ≤ T gives exactly
//! the tree of threshold T (a node with score > T whose ancestors all split is always
//! popped before any node with score ≤ T), so one pass sweeps T from +∞ downwards while the
//! number of surviving triangles is kept up to date incrementally (only triangles around
//! the split node's vertices change). The pass stops at the state closest to the target.

use super::{Clustering, Prepared, RefineBox, SimplifyParams, Target};
use crate::mesh::adjacency::VertexFaces;
use glam::DVec3;
use rayon::prelude::*;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// Octree settings beyond the target.
#[derive(Debug, Clone, PartialEq)]
pub struct OctreeOptions {
    /// Weight of θavg in the normal-variation factor.
    pub theta_avg_weight: f64,
    /// Weight of θmax in the normal-variation factor.
    pub theta_max_weight: f64,
    /// Boxes refined more finely.
    pub refine: Vec<RefineBox>,
    /// Deepest level (the root is level 0).
    pub max_depth: u32,
}

/// Default weight of θavg (radians) in the normal-variation factor.
pub const THETA_AVG_WEIGHT: f64 = 2.0;
/// Default weight of θmax (radians) in the normal-variation factor.
pub const THETA_MAX_WEIGHT: f64 = 0.5;

impl OctreeOptions {
    /// The options `params` give (defaults where absent).
    pub fn from_params(p: &SimplifyParams) -> OctreeOptions {
        OctreeOptions {
            theta_avg_weight: p.theta_avg_weight.unwrap_or(THETA_AVG_WEIGHT),
            theta_max_weight: p.theta_max_weight.unwrap_or(THETA_MAX_WEIGHT),
            refine: p.refine.clone(),
            max_depth: 20,
        }
    }
}

/// Per-vertex inputs of the node statistics (by dense index).
struct VertexData {
    faces: VertexFaces,
    /// Unit normal (x, y, z) and area of each triangle, packed in f32 for the innermost
    /// loop (a split heuristic needs no more precision; the layout halves the memory read).
    face: Vec<[f32; 4]>,
    /// Largest dihedral angle over the vertex's edges.
    theta_max: Vec<f32>,
    /// Σ (A/3)·n over the vertex's triangles.
    area_normal: Vec<DVec3>,
}

impl VertexData {
    fn new(prep: &Prepared) -> VertexData {
        let n = prep.dense_pos.len();
        let faces = VertexFaces::new(&prep.dense_faces, n);
        let pos = |d: u32| prep.dense_pos[d as usize].as_dvec3();
        let face: Vec<[f32; 4]> = prep
            .dense_faces
            .par_iter()
            .with_min_len(4096)
            .map(|t| {
                let c = (pos(t[1]) - pos(t[0])).cross(pos(t[2]) - pos(t[0]));
                let nrm = c.normalize_or_zero().as_vec3();
                [nrm.x, nrm.y, nrm.z, (0.5 * c.length()) as f32]
            })
            .collect();
        let normal = |f: u32| {
            let x = face[f as usize];
            glam::Vec3::new(x[0], x[1], x[2])
        };
        // θmax per vertex: the largest angle between the normals of two triangles sharing
        // an edge at the vertex (they share the vertex and one more corner).
        let theta_max: Vec<f32> = (0..n as u32)
            .into_par_iter()
            .with_min_len(1024)
            .map_init(Vec::new, |fan: &mut Vec<(u32, u32, glam::Vec3)>, d| {
                // The vertex's triangles as (the two other corners, normal).
                fan.clear();
                for &f in faces.of(d) {
                    let t = prep.dense_faces[f as usize];
                    let k = t.iter().position(|&x| x == d).unwrap_or(0);
                    fan.push((t[(k + 1) % 3], t[(k + 2) % 3], normal(f)));
                }
                let mut worst = 0.0f32;
                for (i, &(a, b, nf)) in fan.iter().enumerate() {
                    if nf == glam::Vec3::ZERO {
                        continue;
                    }
                    for &(c, e, ng) in &fan[i + 1..] {
                        if (a == c || a == e || b == c || b == e) && ng != glam::Vec3::ZERO {
                            worst = worst.max(fast_acos_f32(nf.dot(ng)));
                        }
                    }
                }
                worst
            })
            .collect();
        let area_normal: Vec<DVec3> = (0..n as u32)
            .into_par_iter()
            .with_min_len(4096)
            .map(|d| {
                faces
                    .of(d)
                    .iter()
                    .map(|&f| normal(f).as_dvec3() * (face[f as usize][3] as f64 / 3.0))
                    .sum()
            })
            .collect();
        VertexData {
            faces,
            face,
            theta_max,
            area_normal,
        }
    }
}

/// [`fast_acos`] in f32.
#[inline]
pub fn fast_acos_f32(x: f32) -> f32 {
    let x = x.clamp(-1.0, 1.0);
    let a = x.abs();
    let r =
        (1.0 - a).sqrt() * (1.570_728_8 + a * (-0.212_114_4 + a * (0.074_261_0 - a * 0.018_729_3)));
    if x >= 0.0 {
        r
    } else {
        std::f32::consts::PI - r
    }
}

/// acos with |error| < 7e-5 rad (Abramowitz & Stegun 4.4.45): plenty for a split heuristic,
/// and several times cheaper than the libm call in the innermost loop.
#[inline]
pub fn fast_acos(x: f64) -> f64 {
    let x = x.clamp(-1.0, 1.0);
    let a = x.abs();
    let r =
        (1.0 - a).sqrt() * (1.570_728_8 + a * (-0.212_114_4 + a * (0.074_261_0 - a * 0.018_729_3)));
    if x >= 0.0 {
        r
    } else {
        std::f64::consts::PI - r
    }
}

/// Above this many vertices, a node's θavg is estimated from a regular subsample.
const SAMPLE_LIMIT: usize = 4096;

/// Statistics of one node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeStats {
    /// Mean distance of the vertices to their centroid.
    pub dv: f64,
    /// Largest angle between adjacent triangle normals.
    pub theta_max: f64,
    /// Area-weighted mean angle to the mean-plane normal.
    pub theta_avg: f64,
}

fn stats(prep: &Prepared, vd: &VertexData, members: &[u32]) -> NodeStats {
    let pos = |d: u32| prep.dense_pos[d as usize].as_dvec3();
    let n = members.len() as f64;
    let mut c = DVec3::ZERO;
    let mut s = DVec3::ZERO;
    let mut theta_max = 0.0f32;
    for &d in members {
        c += pos(d);
        s += vd.area_normal[d as usize];
        theta_max = theta_max.max(vd.theta_max[d as usize]);
    }
    c /= n;
    let dv = members.iter().map(|&d| (pos(d) - c).length()).sum::<f64>() / n;
    let theta_avg = match s.try_normalize() {
        // No mean plane (a closed surface's normals cancel): as varied as can be.
        None => std::f64::consts::FRAC_PI_2,
        Some(nrm) => {
            let nrm = nrm.as_vec3();
            let (mut num, mut den) = (0.0f64, 0.0f64);
            // Large nodes (the top levels, always split in practice) estimate θavg from a
            // regular subsample of their vertices: the full sum would cost a pass over the
            // whole mesh per level.
            let step = members.len().div_ceil(SAMPLE_LIMIT);
            for &d in members.iter().step_by(step) {
                let (mut pn, mut pd) = (0.0f32, 0.0f32);
                for &f in vd.faces.of(d) {
                    let x = vd.face[f as usize];
                    let dot = x[0] * nrm.x + x[1] * nrm.y + x[2] * nrm.z;
                    pn += x[3] * fast_acos_f32(dot);
                    pd += x[3];
                }
                num += pn as f64;
                den += pd as f64;
            }
            if den > 0.0 {
                num / den
            } else {
                0.0
            }
        }
    };
    NodeStats {
        dv,
        theta_max: theta_max as f64,
        theta_avg,
    }
}

#[derive(Debug, Clone, Copy)]
struct Node {
    min: DVec3,
    size: f64,
    depth: u32,
    /// Members are `perm[start..end]`.
    start: usize,
    end: usize,
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

struct Octree<'a> {
    prep: &'a Prepared<'a>,
    vd: VertexData,
    opts: &'a OctreeOptions,
    nodes: Vec<Node>,
    perm: Vec<u32>,
    scratch: Vec<u32>,
}

impl Octree<'_> {
    fn score(&self, node: &Node) -> f64 {
        let m = &self.perm[node.start..node.end];
        if m.len() < 2 || node.depth >= self.opts.max_depth {
            return 0.0;
        }
        let st = stats(self.prep, &self.vd, m);
        let variation = 1.0
            + self.opts.theta_avg_weight * st.theta_avg
            + self.opts.theta_max_weight * st.theta_max;
        let max = node.min + DVec3::splat(node.size);
        let factor = self
            .opts
            .refine
            .iter()
            .filter(|r| {
                node.min.cmple(DVec3::from_array(r.max)).all()
                    && max.cmpge(DVec3::from_array(r.min)).all()
            })
            .map(|r| r.factor)
            .reduce(f64::max)
            .unwrap_or(1.0);
        st.dv * variation * factor
    }

    /// Splits `node` into its non-empty octants; returns the new node ids.
    fn split(&mut self, id: u32) -> Vec<u32> {
        let node = self.nodes[id as usize];
        let half = node.size * 0.5;
        let mid = node.min + DVec3::splat(half);
        let octant = |d: u32| {
            let p = self.prep.dense_pos[d as usize].as_dvec3();
            (p.x >= mid.x) as usize
                | ((p.y >= mid.y) as usize) << 1
                | ((p.z >= mid.z) as usize) << 2
        };
        let m = &self.perm[node.start..node.end];
        let mut counts = [0usize; 8];
        for &d in m {
            counts[octant(d)] += 1;
        }
        let mut offs = [0usize; 8];
        for k in 1..8 {
            offs[k] = offs[k - 1] + counts[k - 1];
        }
        self.scratch.clear();
        self.scratch.resize(m.len(), 0);
        let mut fill = offs;
        for &d in m {
            let o = octant(d);
            self.scratch[fill[o]] = d;
            fill[o] += 1;
        }
        self.perm[node.start..node.end].copy_from_slice(&self.scratch);
        let mut kids = Vec::with_capacity(8);
        for k in 0..8 {
            if counts[k] == 0 {
                continue;
            }
            let off =
                DVec3::new((k & 1) as f64, ((k >> 1) & 1) as f64, ((k >> 2) & 1) as f64) * half;
            kids.push(self.nodes.len() as u32);
            self.nodes.push(Node {
                min: node.min + off,
                size: half,
                depth: node.depth + 1,
                start: node.start + offs[k],
                end: node.start + offs[k] + counts[k],
            });
        }
        kids
    }
}

/// Clusters `prep` with the adaptive octree: returns the clustering, the threshold reached
/// and the number of splits made.
pub fn cluster(prep: &Prepared, target: Target, opts: &OctreeOptions) -> (Clustering, f64, usize) {
    let n = prep.dense_pos.len();
    let size = (prep.bounds.size().max_element() as f64).max(f64::MIN_POSITIVE);
    // A hair larger than the box, so that the far faces fall inside the last octants.
    let size = size * (1.0 + 1e-9) + f64::MIN_POSITIVE;
    // With a triangle target, enlarge the root so that one level has the cell size a
    // uniform grid would need for that target: the octree's power-of-two sizes then bracket
    // the right scale instead of falling anywhere (measured: ~10 % lower error on average
    // over grid placements, notes/mesh.md).
    let size = match target {
        Target::Triangles(t) => {
            let s0 = super::uniform::initial_cell(prep, t);
            if s0 > 0.0 && s0.is_finite() && s0 < size {
                s0 * 2f64.powf((size / s0).log2().ceil())
            } else {
                size
            }
        }
        Target::Scale(_) => size,
    };
    let mut tree = Octree {
        prep,
        vd: VertexData::new(prep),
        opts,
        nodes: vec![Node {
            min: prep.bounds.min.as_dvec3(),
            size,
            depth: 0,
            start: 0,
            end: n,
        }],
        perm: (0..n as u32).collect(),
        scratch: Vec::new(),
    };
    let mut leaf_of = vec![0u32; n];
    let mut heap = BinaryHeap::new();
    heap.push(Entry {
        score: tree.score(&tree.nodes[0]),
        node: 0,
    });
    let faces = &prep.dense_faces;
    let survives = |leaf_of: &[u32], f: u32| {
        let t = faces[f as usize];
        let (a, b, c) = (
            leaf_of[t[0] as usize],
            leaf_of[t[1] as usize],
            leaf_of[t[2] as usize],
        );
        a != b && b != c && a != c
    };
    let mut count = 0usize;
    let mut leaves = 1usize;
    let mut exact = !matches!(target, Target::Triangles(_));
    let mut touched: Vec<u32> = Vec::new();
    let mut splits = 0usize;
    // The last split, to undo it when the state before was closer to the target.
    let mut last: Option<(u32, f64)> = None;
    let mut reached = f64::INFINITY;
    // The fast count includes duplicate triangles (two sheets collapsing onto the same
    // leaves); after each pass the exact count corrects the goal, at most three times.
    let mut goal = match target {
        Target::Triangles(t) => t,
        Target::Scale(_) => 0,
    };
    let mut rounds = 0;
    loop {
        while let Some(&top) = heap.peek() {
            match target {
                Target::Scale(t) if top.score <= t => break,
                Target::Triangles(_) if count as u64 >= goal => break,
                _ => {}
            }
            if top.score <= 0.0 {
                break;
            }
            heap.pop();
            reached = top.score;
            let node = tree.nodes[top.node as usize];
            // Only triangles with two or more corners in the node can change: before the
            // split they are degenerate (two corners in one leaf); a triangle with one corner
            // here keeps its three distinct leaves. List each once, from its first corner here.
            // Far from the target, the count is not needed yet (estimated as two triangles per
            // leaf) and this pass, a sweep over the mesh per level at the top, is skipped.
            touched.clear();
            if exact {
                for &d in &tree.perm[node.start..node.end] {
                    for &f in tree.vd.faces.of(d) {
                        let t = faces[f as usize];
                        let mut inside = 0;
                        let mut first = u32::MAX;
                        for &x in &t {
                            if leaf_of[x as usize] == top.node {
                                inside += 1;
                                if first == u32::MAX {
                                    first = x;
                                }
                            }
                        }
                        if inside >= 2 && first == d {
                            touched.push(f);
                        }
                    }
                }
            }
            let was_exact = exact;
            let kids = tree.split(top.node);
            let kid_nodes: Vec<Node> = kids.iter().map(|&k| tree.nodes[k as usize]).collect();
            for (&k, kn) in kids.iter().zip(&kid_nodes) {
                for &d in &tree.perm[kn.start..kn.end] {
                    leaf_of[d as usize] = k;
                }
            }
            leaves += kids.len() - 1;
            if exact {
                for &f in &touched {
                    count += survives(&leaf_of, f) as usize;
                }
            } else if let Target::Triangles(_) = target {
                if 4 * leaves as u64 >= goal {
                    exact = true;
                    count = super::count_surviving(faces, &leaf_of);
                }
            }
            // Undoing is only sound when the count before is known.
            last = was_exact.then_some((top.node, top.score));
            splits += 1;
            let scores: Vec<f64> = if node.end - node.start > 20_000 {
                kid_nodes.par_iter().map(|kn| tree.score(kn)).collect()
            } else {
                kid_nodes.iter().map(|kn| tree.score(kn)).collect()
            };
            for (&k, s) in kids.iter().zip(scores) {
                heap.push(Entry { score: s, node: k });
            }
        }
        let Target::Triangles(t) = target else { break };
        rounds += 1;
        let exact_now = super::count_distinct(faces, &leaf_of);
        if rounds >= 3 || heap.is_empty() || exact_now as f64 >= 0.99 * t as f64 {
            break;
        }
        goal = (goal as f64 * t as f64 / exact_now.max(1) as f64).round() as u64 + 1;
    }
    // The threshold this state stands for: the best score left unsplit.
    let mut threshold = heap.peek().map_or(reached, |e| e.score);
    // Undo the last split when the state before it is closer to the target.
    if let (Target::Triangles(t), Some((node_id, score))) = (target, last) {
        let t = t as i64;
        let now = super::count_distinct(faces, &leaf_of) as i64;
        let node = tree.nodes[node_id as usize];
        let kids: Vec<u32> = tree.perm[node.start..node.end]
            .iter()
            .map(|&d| leaf_of[d as usize])
            .collect();
        for &d in &tree.perm[node.start..node.end] {
            leaf_of[d as usize] = node_id;
        }
        let before = super::count_distinct(faces, &leaf_of) as i64;
        if (before - t).abs() < (now - t).abs() {
            threshold = score;
            splits -= 1;
        } else {
            for (&d, &k) in tree.perm[node.start..node.end].iter().zip(&kids) {
                leaf_of[d as usize] = k;
            }
        }
    }
    (Clustering::from_keys(&leaf_of), threshold, splits)
}

#[cfg(test)]
mod tests {
    use super::super::tests::grid;
    use super::super::{simplify, Method, SimplifyParams};
    use super::*;

    #[test]
    fn fast_acos_is_close() {
        for i in 0..=2000 {
            let x = -1.0 + i as f64 / 1000.0;
            assert!((fast_acos(x) - x.acos()).abs() < 7e-5, "{x}");
        }
    }

    #[test]
    fn stats_of_a_flat_patch_and_a_fold() {
        let mut m = grid(6);
        for p in &mut m.positions {
            p.z = 0.0;
        }
        let prep = Prepared::new(&m);
        let vd = VertexData::new(&prep);
        let all: Vec<u32> = (0..prep.active.len() as u32).collect();
        let st = stats(&prep, &vd, &all);
        assert!(st.theta_max < 1e-3 && st.theta_avg < 1e-3, "{st:?}");
        // Fold the right half up by 90°: θmax = π/2 along the fold.
        for p in &mut m.positions {
            if p.x > 0.5 {
                let d = p.x - 0.5;
                p.x = 0.5;
                p.z = d;
            }
        }
        let prep = Prepared::new(&m);
        let vd = VertexData::new(&prep);
        let st = stats(&prep, &vd, &all);
        assert!(
            (st.theta_max - std::f64::consts::FRAC_PI_2).abs() < 1e-3,
            "{st:?}"
        );
        // Equal areas on both sides: each half is 45° from the mean plane.
        assert!(
            (st.theta_avg - std::f64::consts::FRAC_PI_4).abs() < 1e-3,
            "{st:?}"
        );
    }

    #[test]
    fn greedy_pass_equals_the_threshold_tree() {
        // The slow twin: build the tree of threshold T recursively and compare clusters.
        let m = grid(24);
        let prep = Prepared::new(&m);
        let opts = OctreeOptions::from_params(&SimplifyParams::ratio(Method::Octree, 0.5));
        let (_, t, _) = cluster(&prep, Target::Triangles(300), &opts);
        let (fast, _, _) = cluster(&prep, Target::Scale(t), &opts);
        let mut tree = Octree {
            prep: &prep,
            vd: VertexData::new(&prep),
            opts: &opts,
            nodes: vec![],
            perm: (0..prep.active.len() as u32).collect(),
            scratch: vec![],
        };
        let size = prep.bounds.size().max_element() as f64 * (1.0 + 1e-9) + f64::MIN_POSITIVE;
        tree.nodes.push(Node {
            min: prep.bounds.min.as_dvec3(),
            size,
            depth: 0,
            start: 0,
            end: prep.active.len(),
        });
        let mut leaf_of = vec![0u32; prep.active.len()];
        let mut stack = vec![0u32];
        while let Some(id) = stack.pop() {
            let node = tree.nodes[id as usize];
            if tree.score(&node) > t {
                stack.extend(tree.split(id));
            } else {
                for &d in &tree.perm[node.start..node.end] {
                    leaf_of[d as usize] = id;
                }
            }
        }
        let slow = Clustering::from_keys(&leaf_of);
        assert_eq!(fast.count, slow.count);
        assert_eq!(fast.of, slow.of);
    }

    #[test]
    fn refined_box_gets_more_vertices() {
        let m = grid(40);
        let mut p = SimplifyParams::triangles(Method::Octree, 400);
        let plain = simplify(&m, &p).unwrap().mesh;
        p.refine.push(RefineBox {
            min: [0.0, 0.0, -1.0],
            max: [0.3, 0.3, 1.0],
            factor: 8.0,
        });
        let refined = simplify(&m, &p).unwrap().mesh;
        let inside = |m: &crate::mesh::TriMesh| {
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

#[cfg(test)]
mod lab;
