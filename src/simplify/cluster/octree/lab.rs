//! Experiments (not shipped): variants of the adaptive tree measured on the shared meshes.
#![allow(dead_code, clippy::all)]

use super::super::{
    build_output, count_distinct, count_surviving, floating, uniform, Clustering, Prepared,
    Representative, Target,
};
use super::{stats, OctreeOptions, VertexData};
use crate::mesh::{hausdorff, io, HausdorffParams, TriMesh};
use crate::simplify::quadric::Quadric;
use glam::DVec3;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

pub fn load(name: &str) -> TriMesh {
    io::read(&std::path::Path::new("/work/shared/data/meshes").join(name)).unwrap()
}

#[derive(Debug, Clone, Copy, Default)]
pub struct E {
    pub tris: usize,
    pub verts: usize,
    pub max: f64,
    pub eavg: f64,
    pub metro: f64,
    pub f: [f64; 3],
    pub b: [f64; 3],
}

pub fn eval(mesh: &TriMesh, prep: &Prepared, cl: &Clustering) -> E {
    let out = build_output(prep, cl, Representative::Quadric);
    let r = hausdorff(mesh, &out, &HausdorffParams::default()).unwrap();
    E {
        tris: out.triangle_count(),
        verts: out.vertex_count(),
        max: r.max_pct,
        eavg: r.mean_pct,
        metro: r.sample_mean_pct,
        f: [
            r.forward.max_pct,
            r.forward.mean_pct,
            r.forward.sample_mean_pct,
        ],
        b: [
            r.backward.max_pct,
            r.backward.mean_pct,
            r.backward.sample_mean_pct,
        ],
    }
}

/// Shifts of the grid origin, as fractions of a cell.
pub const SHIFTS: [[f64; 3]; 8] = [
    [0.0, 0.0, 0.0],
    [0.5, 0.5, 0.5],
    [0.25, 0.75, 0.5],
    [0.75, 0.25, 0.125],
    [0.125, 0.375, 0.875],
    [0.625, 0.875, 0.375],
    [0.375, 0.125, 0.625],
    [0.875, 0.625, 0.25],
];

pub fn shifted<'a>(mesh: &'a TriMesh, shift: [f64; 3], cell: f64) -> Prepared<'a> {
    let mut p = Prepared::new(mesh);
    let d = DVec3::from_array(shift) * cell;
    p.bounds.min -= d.as_vec3();
    p
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SplitAt {
    /// Octants of a cube (the classic octree), root enlarged as in octree.rs.
    Cube,
    /// At the members' centroid.
    Centroid,
    /// At the members' median per axis.
    Median,
    /// At the middle of the members' bounding box.
    BoxMid,
    /// No tree: the uniform grid (reference for the post-passes).
    Grid,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Law {
    Paper(f64, f64),
    /// Dv · (eps + θavg)^p
    Pow(f64, f64),
    /// Quadric: area · (rms + eps·Dv)
    QuadL1(f64),
    /// Quadric: rms + eps·Dv
    QuadRms(f64),
    /// Quadric: area^p (rms + eps·Dv)
    QuadLp(f64, f64),
    /// Quadric: total squared + eps·area·Dv²
    QuadL2(f64),
    /// Dv * area^q * (1 + a θavg + b θmax)
    AreaPaper(f64, f64, f64),
}

#[derive(Debug, Clone, Copy)]
pub struct KOpts {
    pub split: SplitAt,
    pub axis_frac: f64,
    pub law: Law,
    pub lloyd: usize,
    pub lloyd_cost: LloydCost,
    pub cc: bool,
    /// Axis choice: split along the axes whose binary split lowers the quadric L1 error by
    /// at least this fraction of the best axis's (None: axes by extent).
    pub aniso: Option<f64>,
    /// Mixed priority: (A + mu·Ā)·(...) for the quadric laws.
    pub mu: f64,
    /// Axis choice by the law's own score instead of the quadric.
    pub aniso_law: bool,
    /// Tikhonov regularisation (relative to tr A) for the scoring minimiser (0: eigen).
    pub tik: f64,
    pub tik_axis: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LloydCost {
    /// Squared distance to the cluster's (unweighted) centroid.
    Centroid,
    /// Squared distance to the area-weighted centroid.
    AreaCentroid,
    /// Squared distance to the cluster's quadric representative.
    Rep,
    /// Vertex quadric at the cluster rep + lambda · dist² to centroid (relative)
    Quadric(f64),
}

impl Default for KOpts {
    fn default() -> Self {
        KOpts {
            split: SplitAt::Centroid,
            axis_frac: 0.0,
            law: Law::Paper(2.0, 0.5),
            lloyd: 0,
            lloyd_cost: LloydCost::Centroid,
            cc: false,
            aniso: None,
            mu: 0.0,
            aniso_law: false,
            tik: 0.0,
            tik_axis: 0.0,
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Node {
    lo: DVec3,
    hi: DVec3,
    start: usize,
    end: usize,
    depth: u32,
}

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

pub struct Lab<'a> {
    pub prep: &'a Prepared<'a>,
    vd: VertexData,
    /// Vertex quadric by dense index.
    q: Vec<Quadric>,
    /// Vertex area (third of incident triangles) by dense index.
    area: Vec<f64>,
    /// Neighbours by dense index.
    nb: Vec<Vec<u32>>,
    pub abar: std::cell::Cell<f64>,
}

impl<'a> Lab<'a> {
    pub fn new(prep: &'a Prepared<'a>) -> Lab<'a> {
        let vd = VertexData::new(prep);
        let qs = prep.quadrics();
        let q = prep.active.iter().map(|&v| qs[v as usize]).collect();
        let n = prep.dense_pos.len();
        let mut area = vec![0.0; n];
        let mut nb = vec![Vec::new(); n];
        for (f, t) in prep.dense_faces.iter().enumerate() {
            let a = vd.face[f][3] as f64 / 3.0;
            for k in 0..3 {
                area[t[k] as usize] += a;
                let (x, y) = (t[k], t[(k + 1) % 3]);
                if x != y {
                    nb[x as usize].push(y);
                    nb[y as usize].push(x);
                }
            }
        }
        for l in &mut nb {
            l.sort_unstable();
            l.dedup();
        }
        Lab {
            prep,
            vd,
            q,
            area,
            nb,
            abar: std::cell::Cell::new(0.0),
        }
    }

    fn pos(&self, d: u32) -> DVec3 {
        self.prep.dense_pos[d as usize].as_dvec3()
    }

    fn quad_score(&self, o: &KOpts, m: &[u32]) -> (DVec3, f64, f64) {
        if o.tik <= 0.0 {
            return self.quad_rep(m);
        }
        let mut q = Quadric::ZERO;
        let mut c = DVec3::ZERO;
        for &d in m {
            q += self.q[d as usize];
            c += self.pos(d);
        }
        c /= m.len() as f64;
        let tr = q.a[0] + q.a[3] + q.a[5];
        let delta = o.tik * tr;
        // minimise Q(x) + delta |x - c|^2: (A + delta I) x = -b + delta c
        let a = q.matrix() + glam::DMat3::from_diagonal(DVec3::splat(delta));
        let rhs = -q.linear() + c * delta;
        let x = a.inverse() * rhs;
        let x = if x.is_finite() { x } else { c };
        (x, q.eval(x), tr)
    }

    fn quad_rep(&self, m: &[u32]) -> (DVec3, f64, f64) {
        let mut q = Quadric::ZERO;
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        let mut c = DVec3::ZERO;
        for &d in m {
            q += self.q[d as usize];
            let p = self.pos(d);
            lo = lo.min(p);
            hi = hi.max(p);
            c += p;
        }
        c /= m.len() as f64;
        let pad = hi - lo;
        let x = q.minimizer(c, 1e-2).clamp(lo - pad, hi + pad);
        let tr = q.a[0] + q.a[3] + q.a[5];
        (x, q.eval(x), tr)
    }

    fn score(&self, o: &KOpts, m: &[u32], depth: u32) -> f64 {
        if m.len() < 2 || depth > 40 {
            return 0.0;
        }
        match o.law {
            Law::Paper(a, b) => {
                let s = stats(self.prep, &self.vd, m);
                s.dv * (1.0 + a * s.theta_avg + b * s.theta_max)
            }
            Law::AreaPaper(qa, a, b) => {
                let s = stats(self.prep, &self.vd, m);
                let ar: f64 = m.iter().map(|&d| self.area[d as usize]).sum();
                s.dv * ar.powf(qa) * (1.0 + a * s.theta_avg + b * s.theta_max)
            }
            Law::Pow(p, eps) => {
                let s = stats(self.prep, &self.vd, m);
                s.dv * (eps + s.theta_avg).powf(p)
            }
            Law::QuadL1(eps) | Law::QuadRms(eps) | Law::QuadL2(eps) | Law::QuadLp(_, eps) => {
                let (_, e2, tr) = self.quad_score(o, m);
                let s = stats(self.prep, &self.vd, m);
                let rms = (e2 / tr.max(1e-300)).sqrt();
                let a = tr + o.mu * self.abar.get();
                match o.law {
                    Law::QuadL1(_) => a * (rms + eps * s.dv),
                    Law::QuadRms(_) => rms + eps * s.dv,
                    Law::QuadLp(p, _) => a.powf(p) * (rms + eps * s.dv),
                    _ => e2 + eps * tr * s.dv * s.dv,
                }
            }
        }
    }

    /// Builds the tree greedily until the fast count reaches `goal`.
    fn tree(&self, o: &KOpts, goal: u64, root_cell: Option<f64>) -> Vec<u32> {
        let prep = self.prep;
        let n = prep.dense_pos.len();
        let mut perm: Vec<u32> = (0..n as u32).collect();
        let b = prep.bounds;
        let mut lo = b.min.as_dvec3();
        let mut hi = b.max.as_dvec3();
        if o.split == SplitAt::Cube {
            let size = (hi - lo).max_element() * (1.0 + 1e-9) + f64::MIN_POSITIVE;
            let size = match root_cell {
                Some(s0) if s0 < size => s0 * 2f64.powf((size / s0).log2().ceil()),
                _ => size,
            };
            hi = lo + DVec3::splat(size);
        }
        let _ = &mut lo;
        let mut nodes = vec![Node {
            lo,
            hi,
            start: 0,
            end: n,
            depth: 0,
        }];
        let mut leaf_of = vec![0u32; n];
        let mut heap = BinaryHeap::new();
        heap.push(Entry {
            score: self.score(o, &perm, 0),
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
        let mut count = 0u64;
        let mut touched = Vec::new();
        let mut scratch = Vec::new();
        while let Some(top) = heap.pop() {
            if count >= goal || top.score <= 0.0 {
                break;
            }
            let node = nodes[top.node as usize];
            touched.clear();
            for &d in &perm[node.start..node.end] {
                for &f in self.vd.faces.of(d) {
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
            // Split.
            let m = &perm[node.start..node.end];
            let (ext_lo, ext_hi, cen) = {
                let mut l = DVec3::splat(f64::INFINITY);
                let mut h = DVec3::splat(f64::NEG_INFINITY);
                let mut c = DVec3::ZERO;
                for &d in m {
                    let p = self.pos(d);
                    l = l.min(p);
                    h = h.max(p);
                    c += p;
                }
                (l, h, c / m.len() as f64)
            };
            let ext = ext_hi - ext_lo;
            let (mid, axes): (DVec3, [bool; 3]) = match o.split {
                SplitAt::Cube => ((node.lo + node.hi) * 0.5, [true; 3]),
                _ => {
                    let mx = ext.max_element();
                    let mut axes = [0, 1, 2].map(|k| ext[k] > 0.0 && ext[k] >= o.axis_frac * mx);
                    if let Some(beta) = o.aniso {
                        let at = match o.split {
                            SplitAt::Centroid => cen,
                            _ => (ext_lo + ext_hi) * 0.5,
                        };
                        let l1 = |ms: &[u32]| -> f64 {
                            if ms.len() < 2 {
                                return 0.0;
                            }
                            if o.aniso_law {
                                return self.score(o, ms, 0);
                            }
                            let mut oo = *o;
                            if o.tik_axis > 0.0 {
                                oo.tik = o.tik_axis;
                            }
                            let (_, e2, tr) = self.quad_score(&oo, ms);
                            (e2 * tr).max(0.0).sqrt()
                        };
                        let parent = l1(m);
                        let mut red = [f64::NEG_INFINITY; 3];
                        let (mut a, mut b) = (Vec::new(), Vec::new());
                        for k in 0..3 {
                            if !axes[k] {
                                continue;
                            }
                            a.clear();
                            b.clear();
                            for &d in m {
                                if self.pos(d)[k] >= at[k] {
                                    a.push(d)
                                } else {
                                    b.push(d)
                                }
                            }
                            if a.is_empty() || b.is_empty() {
                                axes[k] = false;
                                continue;
                            }
                            red[k] = parent - l1(&a) - l1(&b);
                        }
                        let best = red.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                        if best > 0.0 {
                            for k in 0..3 {
                                axes[k] = axes[k] && red[k] >= beta * best;
                            }
                        }
                    }
                    let mid = match o.split {
                        SplitAt::Centroid => cen,
                        SplitAt::BoxMid => (ext_lo + ext_hi) * 0.5,
                        _ => {
                            let mut med = DVec3::ZERO;
                            let mut v: Vec<f64> = Vec::with_capacity(m.len());
                            for k in 0..3 {
                                v.clear();
                                v.extend(m.iter().map(|&d| self.pos(d)[k]));
                                v.sort_by(|a, b| a.total_cmp(b));
                                let mut x = v[v.len() / 2];
                                if x <= v[0] {
                                    // all equal below: pick next greater
                                    x = v.iter().copied().find(|&y| y > v[0]).unwrap_or(x);
                                }
                                med[k] = x;
                            }
                            med
                        }
                    };
                    (mid, axes)
                }
            };
            let octant = |p: DVec3| {
                let mut k = 0usize;
                for a in 0..3 {
                    if axes[a] && p[a] >= mid[a] {
                        k |= 1 << a;
                    }
                }
                k
            };
            let mut counts = [0usize; 8];
            for &d in m {
                counts[octant(self.pos(d))] += 1;
            }
            if o.split != SplitAt::Cube && counts.iter().filter(|&&c| c > 0).count() < 2 {
                // Cannot split further: leave it (score 0).
                continue;
            }
            let mut offs = [0usize; 8];
            for k in 1..8 {
                offs[k] = offs[k - 1] + counts[k - 1];
            }
            scratch.clear();
            scratch.resize(m.len(), 0u32);
            let mut fill = offs;
            for &d in m {
                let k = octant(self.pos(d));
                scratch[fill[k]] = d;
                fill[k] += 1;
            }
            perm[node.start..node.end].copy_from_slice(&scratch);
            let mut kids = Vec::new();
            for k in 0..8 {
                if counts[k] == 0 {
                    continue;
                }
                let mut clo = node.lo;
                let mut chi = node.hi;
                for a in 0..3 {
                    if axes[a] {
                        if k & (1 << a) != 0 {
                            clo[a] = mid[a];
                        } else {
                            chi[a] = mid[a];
                        }
                    }
                }
                let id = nodes.len() as u32;
                nodes.push(Node {
                    lo: clo,
                    hi: chi,
                    start: node.start + offs[k],
                    end: node.start + offs[k] + counts[k],
                    depth: node.depth + 1,
                });
                kids.push(id);
                for &d in &perm[node.start + offs[k]..node.start + offs[k] + counts[k]] {
                    leaf_of[d as usize] = id;
                }
            }
            for &f in &touched {
                count += survives(&leaf_of, f) as u64;
            }
            for &k in &kids {
                let kn = nodes[k as usize];
                heap.push(Entry {
                    score: self.score(o, &perm[kn.start..kn.end], kn.depth),
                    node: k,
                });
            }
        }
        leaf_of
    }

    fn split_components(&self, keys: &[u32]) -> Vec<u32> {
        let n = keys.len();
        let mut root: Vec<u32> = (0..n as u32).collect();
        fn find(r: &mut [u32], mut x: u32) -> u32 {
            while r[x as usize] != x {
                r[x as usize] = r[r[x as usize] as usize];
                x = r[x as usize];
            }
            x
        }
        for t in &self.prep.dense_faces {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                if keys[a as usize] == keys[b as usize] {
                    let (ra, rb) = (find(&mut root, a), find(&mut root, b));
                    if ra != rb {
                        root[ra.max(rb) as usize] = ra.min(rb);
                    }
                }
            }
        }
        (0..n as u32).map(|v| find(&mut root, v)).collect()
    }

    fn lloyd(&self, o: &KOpts, keys: &[u32]) -> Vec<u32> {
        let cl = Clustering::from_keys(keys);
        let mut of = cl.of.clone();
        let nc = cl.count;
        for _ in 0..o.lloyd {
            // Centres.
            let mut sum = vec![DVec3::ZERO; nc];
            let mut w = vec![0.0; nc];
            let mut members: Vec<Vec<u32>> = vec![Vec::new(); nc];
            for d in 0..of.len() {
                let c = of[d] as usize;
                let wt = match o.lloyd_cost {
                    LloydCost::AreaCentroid => self.area[d],
                    _ => 1.0,
                };
                sum[c] += self.pos(d as u32) * wt;
                w[c] += wt;
                members[c].push(d as u32);
            }
            let cen: Vec<DVec3> = (0..nc)
                .map(|c| {
                    if w[c] > 0.0 {
                        sum[c] / w[c]
                    } else {
                        DVec3::splat(f64::NAN)
                    }
                })
                .collect();
            let reps: Vec<(DVec3, f64)> = match o.lloyd_cost {
                LloydCost::Rep | LloydCost::Quadric(_) => (0..nc)
                    .map(|c| {
                        if members[c].is_empty() {
                            (DVec3::splat(f64::NAN), 0.0)
                        } else {
                            let (x, e2, tr) = self.quad_rep(&members[c]);
                            (x, e2 / tr.max(1e-300))
                        }
                    })
                    .collect(),
                _ => Vec::new(),
            };
            // Typical squared size per cluster (for the quadric cost's distance term).
            let size2: Vec<f64> = (0..nc)
                .map(|c| {
                    let m = &members[c];
                    if m.is_empty() {
                        return 1.0;
                    }
                    m.iter()
                        .map(|&d| (self.pos(d) - cen[c]).length_squared())
                        .sum::<f64>()
                        / m.len() as f64
                })
                .collect();
            let cost = |d: u32, c: usize| -> f64 {
                let p = self.pos(d);
                match o.lloyd_cost {
                    LloydCost::Centroid | LloydCost::AreaCentroid => (p - cen[c]).length_squared(),
                    LloydCost::Rep => (p - reps[c].0).length_squared(),
                    LloydCost::Quadric(lambda) => {
                        let q = self.q[d as usize];
                        let tr = q.a[0] + q.a[3] + q.a[5];
                        q.eval(reps[c].0) / tr.max(1e-300) + lambda * (p - cen[c]).length_squared()
                    }
                }
            };
            let next: Vec<u32> = (0..of.len() as u32)
                .map(|d| {
                    let mut best = (cost(d, of[d as usize] as usize), of[d as usize]);
                    for &u in &self.nb[d as usize] {
                        let c = of[u as usize];
                        if c == best.1 {
                            continue;
                        }
                        let x = cost(d, c as usize);
                        if x < best.0 {
                            best = (x, c);
                        }
                    }
                    best.1
                })
                .collect();
            of = next;
        }
        of
    }

    /// Full clustering for a triangle target.
    pub fn cluster(&self, o: &KOpts, target: u64) -> Clustering {
        // Mean cluster weight (quadric trace ~ 3 × area) at the target.
        let tot: f64 = self.q.iter().map(|q| q.a[0] + q.a[3] + q.a[5]).sum();
        self.abar.set(tot / (target as f64 / 2.0));
        let root_cell = Some(uniform::initial_cell(self.prep, target));
        let mut goal = target;
        let mut best: Option<(u64, Clustering)> = None;
        for _ in 0..4 {
            let mut keys = if o.split == SplitAt::Grid {
                uniform::cluster(self.prep, Target::Triangles(goal)).0.of
            } else {
                self.tree(o, goal, root_cell)
            };
            if o.cc {
                keys = self.split_components(&keys);
            }
            if o.lloyd > 0 {
                if std::env::var("LAB_DRIFT").is_ok() {
                    let before = count_distinct(&self.prep.dense_faces, &keys);
                    let k2 = self.lloyd(o, &keys);
                    let after = count_distinct(&self.prep.dense_faces, &k2);
                    println!("   drift goal {goal} before {before} after {after}");
                }
                keys = self.lloyd(o, &keys);
                if o.cc {
                    keys = self.split_components(&keys);
                }
            }
            let exact = count_distinct(&self.prep.dense_faces, &keys) as u64;
            let miss = (exact as i64 - target as i64).unsigned_abs();
            let cl = Clustering::from_keys(&keys);
            if best.as_ref().map_or(true, |b| miss < b.0) {
                best = Some((miss, cl));
            }
            if miss as f64 <= 0.005 * target as f64 {
                break;
            }
            goal = ((goal as f64 * target as f64 / exact.max(1) as f64).round() as u64).max(1);
        }
        best.unwrap().1
    }
}

pub fn run_uniform(mesh: &TriMesh, target: u64, shift: [f64; 3]) -> E {
    let p0 = Prepared::new(mesh);
    let cell = uniform::initial_cell(&p0, target);
    let prep = shifted(mesh, shift, cell);
    let (cl, _, _) = uniform::cluster(&prep, Target::Triangles(target));
    eval(mesh, &prep, &cl)
}

pub fn run_floating(mesh: &TriMesh, target: u64) -> E {
    let prep = Prepared::new(mesh);
    let (cl, _, _) = floating::cluster(&prep, Target::Triangles(target));
    eval(mesh, &prep, &cl)
}

pub fn run_octree(mesh: &TriMesh, target: u64, shift: [f64; 3]) -> E {
    let p0 = Prepared::new(mesh);
    let cell = uniform::initial_cell(&p0, target);
    let prep = shifted(mesh, shift, cell);
    let opts = OctreeOptions {
        theta_avg_weight: 2.0,
        theta_max_weight: 0.5,
        refine: vec![],
        max_depth: 20,
    };
    let (cl, _, _) = super::cluster(&prep, Target::Triangles(target), &opts);
    eval(mesh, &prep, &cl)
}

pub fn run_lab(mesh: &TriMesh, target: u64, o: &KOpts, shift: [f64; 3]) -> E {
    let p0 = Prepared::new(mesh);
    let cell = uniform::initial_cell(&p0, target);
    let prep = shifted(mesh, shift, cell);
    let lab = Lab::new(&prep);
    let cl = lab.cluster(o, target);
    eval(mesh, &prep, &cl)
}

pub fn avg(es: &[E]) -> E {
    let n = es.len() as f64;
    let mut a = E::default();
    for e in es {
        a.tris += e.tris;
        a.verts += e.verts;
        a.max += e.max / n;
        a.eavg += e.eavg / n;
        a.metro += e.metro / n;
        for k in 0..3 {
            a.f[k] += e.f[k] / n;
            a.b[k] += e.b[k] / n;
        }
    }
    a.tris /= es.len();
    a.verts /= es.len();
    a
}

pub fn row(name: &str, e: &E) -> String {
    format!(
        "{name:<44} {:>5}/{:>5} max {:.3} eavg {:.4} metro {:.4} | fwd {:.3}/{:.4}/{:.4} bwd {:.3}/{:.4}/{:.4}",
        e.tris, e.verts, e.max, e.eavg, e.metro, e.f[0], e.f[1], e.f[2], e.b[0], e.b[1], e.b[2]
    )
}

pub const CASES: [(&str, f64); 8] = [
    ("triceratops.obj", 0.33),
    ("triceratops.obj", 0.10),
    ("bunny.obj", 0.33),
    ("bunny.obj", 0.10),
    ("cow.obj", 0.33),
    ("cow.obj", 0.10),
    ("fandisk.obj", 0.33),
    ("fandisk.obj", 0.10),
];

pub fn target_of(name: &str, ratio: f64, m: &TriMesh) -> u64 {
    if name == "triceratops.obj" && ratio == 0.33 {
        1850
    } else {
        (m.triangle_count() as f64 * ratio).round() as u64
    }
}

fn env_list(name: &str, default: &str) -> Vec<String> {
    std::env::var(name)
        .unwrap_or_else(|_| default.into())
        .split(',')
        .map(|s| s.to_string())
        .collect()
}

/// `LAB_CASES=tri33,cow10` style selection.
fn cases() -> Vec<(&'static str, f64)> {
    let sel = env_list("LAB_CASES", "tri33");
    CASES
        .iter()
        .copied()
        .filter(|(n, r)| {
            let tag = format!("{}{}", &n[..3], (r * 100.0).round() as u32);
            sel.iter().any(|s| s == "all" || *s == tag)
        })
        .collect()
}

fn nshifts() -> usize {
    std::env::var("LAB_SHIFTS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1)
}

pub fn variants() -> Vec<(String, KOpts)> {
    let d = KOpts::default();
    let mut v = vec![];
    let spec = std::env::var("LAB_VARIANTS").unwrap_or_else(|_| "base".into());
    for s in spec.split(';') {
        let s = s.trim();
        if s.is_empty() {
            continue;
        }
        // name = key=value,key=value
        let mut o = d;
        for kv in s.split(',') {
            let mut it = kv.splitn(2, '=');
            let k = it.next().unwrap().trim();
            let val = it.next().unwrap_or("").trim();
            let f = |x: &str| x.parse::<f64>().unwrap();
            match k {
                "base" => {}
                "split" => {
                    o.split = match val {
                        "cube" => SplitAt::Cube,
                        "centroid" => SplitAt::Centroid,
                        "median" => SplitAt::Median,
                        "boxmid" => SplitAt::BoxMid,
                        "grid" => SplitAt::Grid,
                        _ => panic!("{val}"),
                    }
                }
                "frac" => o.axis_frac = f(val),
                "lloyd" => o.lloyd = val.parse().unwrap(),
                "cc" => o.cc = val == "1",
                "aniso" => o.aniso = Some(f(val)),
                "mu" => o.mu = f(val),
                "al" => o.aniso_law = val == "1",
                "tik" => o.tik = f(val),
                "tika" => o.tik_axis = f(val),
                "cost" => {
                    o.lloyd_cost = match val {
                        "centroid" => LloydCost::Centroid,
                        "area" => LloydCost::AreaCentroid,
                        "rep" => LloydCost::Rep,
                        x if x.starts_with('q') => LloydCost::Quadric(f(&x[1..])),
                        _ => panic!("{val}"),
                    }
                }
                "law" => {
                    let p: Vec<&str> = val.split(':').collect();
                    o.law = match p[0] {
                        "paper" => Law::Paper(f(p[1]), f(p[2])),
                        "pow" => Law::Pow(f(p[1]), f(p[2])),
                        "l1" => Law::QuadL1(f(p[1])),
                        "rms" => Law::QuadRms(f(p[1])),
                        "lp" => Law::QuadLp(f(p[1]), f(p[2])),
                        "l2" => Law::QuadL2(f(p[1])),
                        "area" => Law::AreaPaper(f(p[1]), f(p[2]), f(p[3])),
                        _ => panic!("{val}"),
                    }
                }
                _ => panic!("unknown key {k}"),
            }
        }
        v.push((s.to_string(), o));
    }
    v
}

#[test]
#[ignore]
fn lab() {
    let ns = nshifts();
    let base = std::env::var("LAB_BASE").map_or(true, |v| v == "1");
    for (name, ratio) in cases() {
        let m = load(name);
        let t = target_of(name, ratio, &m);
        println!("== {name} {ratio} target {t} ({ns} shifts)");
        if base {
            let u: Vec<E> = SHIFTS[..ns]
                .iter()
                .map(|&s| run_uniform(&m, t, s))
                .collect();
            println!("{}", row("uniform", &avg(&u)));
            println!("{}", row("floating", &run_floating(&m, t)));
            let o: Vec<E> = SHIFTS[..ns].iter().map(|&s| run_octree(&m, t, s)).collect();
            println!("{}", row("octree(current)", &avg(&o)));
        }
        for (vn, o) in variants() {
            let es: Vec<E> = SHIFTS[..ns]
                .iter()
                .map(|&s| run_lab(&m, t, &o, s))
                .collect();
            println!("{}", row(&vn, &avg(&es)));
        }
    }
}

#[test]
#[ignore]
fn lab_baselines() {
    let m = load("triceratops.obj");
    for t in [1750u64, 1800, 1825, 1850, 1875, 1900, 1950] {
        println!("{}", row(&format!("floating {t}"), &run_floating(&m, t)));
    }
    for (i, s) in SHIFTS.iter().enumerate() {
        println!(
            "{}",
            row(&format!("uniform shift {i}"), &run_uniform(&m, 1850, *s))
        );
    }
    for (i, s) in SHIFTS.iter().enumerate() {
        println!(
            "{}",
            row(&format!("octree shift {i}"), &run_octree(&m, 1850, *s))
        );
    }
}

#[test]
#[ignore]
fn lab_floating_max() {
    let m = load("triceratops.obj");
    let prep = Prepared::new(&m);
    let (cl, s, _) = floating::cluster(&prep, Target::Triangles(1850));
    for rep in [
        Representative::Quadric,
        Representative::Centroid,
        Representative::Important,
    ] {
        let out = build_output(&prep, &cl, rep);
        let r = hausdorff(&m, &out, &HausdorffParams::default()).unwrap();
        println!(
            "{rep}: cell {s:.4} diag {:.3} fwd max {:.3}% at {:?}; bwd max {:.3}% at {:?}",
            r.diagonal, r.forward.max_pct, r.forward.max_at, r.backward.max_pct, r.backward.max_at
        );
    }
    let out = build_output(&prep, &cl, Representative::Quadric);
    let r = hausdorff(&m, &out, &HausdorffParams::default()).unwrap();
    let at = DVec3::from_array(r.forward.max_at);
    // Nearest original vertices and their clusters.
    let mut near: Vec<(f64, usize)> = (0..prep.dense_pos.len())
        .map(|d| ((prep.dense_pos[d].as_dvec3() - at).length(), d))
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0));
    let w = prep.weights();
    for &(dist, d) in near.iter().take(12) {
        let c = cl.of[d];
        let members: Vec<usize> = (0..cl.of.len()).filter(|&x| cl.of[x] == c).collect();
        let cen: DVec3 = members
            .iter()
            .map(|&x| prep.dense_pos[x].as_dvec3())
            .sum::<DVec3>()
            / members.len() as f64;
        println!(
            "v{d} at {:.3} dist {dist:.3} cluster {c} ({} members, centroid {:.3}, w {:.3})",
            prep.dense_pos[d],
            members.len(),
            cen,
            w[prep.active[d] as usize]
        );
    }
    println!("bounds {:?}", prep.bounds);
}

/// Summary: each variant against the better baseline per case (uniform at shift 0, floating).
#[test]
#[ignore]
fn lab_summary() {
    let cs = cases();
    let meshes: Vec<(String, TriMesh, u64, E, E)> = cs
        .iter()
        .map(|&(n, r)| {
            let m = load(n);
            let t = target_of(n, r, &m);
            let u = run_uniform(&m, t, [0.0; 3]);
            let f = run_floating(&m, t);
            (format!("{}{}", &n[..3], (r * 100.0).round()), m, t, u, f)
        })
        .collect();
    let vs = variants();
    let verbose = std::env::var("LAB_VERBOSE").is_ok();
    for (vn, o) in &vs {
        let mut lr = [0.0f64; 3];
        let mut wins = [0usize; 3];
        let mut cells = String::new();
        for (tag, m, t, u, f) in &meshes {
            let e = run_lab(m, *t, o, [0.0; 3]);
            let r = [
                e.max / u.max.min(f.max),
                e.eavg / u.eavg.min(f.eavg),
                e.metro / u.metro.min(f.metro),
            ];
            for k in 0..3 {
                lr[k] += r[k].ln();
                wins[k] += (r[k] < 1.0) as usize;
            }
            cells += &format!(" {tag}:{:.2}/{:.2}/{:.2}", r[0], r[1], r[2]);
            if verbose {
                println!("   {tag} {}", row(vn, &e));
            }
        }
        let n = meshes.len() as f64;
        println!(
            "{vn:<60} gm {:.3}/{:.3}/{:.3} wins {}/{}/{} |{cells}",
            (lr[0] / n).exp(),
            (lr[1] / n).exp(),
            (lr[2] / n).exp(),
            wins[0],
            wins[1],
            wins[2]
        );
    }
}

/// Per output triangle: area and max distance to the original (backward E_avg terms).
pub fn bwd_terms(orig: &TriMesh, out: &TriMesh) -> Vec<(f64, f64, usize)> {
    let bvh = crate::mesh::Bvh::new(orig);
    (0..out.triangle_count())
        .map(|f| {
            let [a, b, c] = out.corners(f);
            let area = out.face_area(f);
            let mut worst = 0.0f64;
            let k = 8;
            for i in 0..=k {
                for j in 0..=(k - i) {
                    let p = a + (b - a) * (i as f64 / k as f64) + (c - a) * (j as f64 / k as f64);
                    let h = orig_closest(&bvh, p);
                    worst = worst.max(h);
                }
            }
            (area, worst, f)
        })
        .collect()
}

fn orig_closest(bvh: &crate::mesh::Bvh, p: DVec3) -> f64 {
    bvh.closest(p, None, f64::INFINITY)
        .map_or(0.0, |h| h.dist2.sqrt())
}

#[test]
#[ignore]
fn lab_tail() {
    let m = load("triceratops.obj");
    let diag = m.diagonal();
    let total: f64 = m.area();
    let mut show = |name: &str, out: &TriMesh| {
        let mut t = bwd_terms(&m, out);
        let tot_out: f64 = t.iter().map(|x| x.0).sum();
        let eavg: f64 = t.iter().map(|x| x.0 * x.1).sum::<f64>() / tot_out;
        t.sort_by(|a, b| (b.0 * b.1).total_cmp(&(a.0 * a.1)));
        let mut acc = 0.0;
        let mut s = String::new();
        let n = t.len();
        for (i, x) in t.iter().enumerate() {
            acc += x.0 * x.1;
            for q in [0.01, 0.05, 0.1, 0.25, 0.5] {
                if i + 1 == (q * n as f64) as usize {
                    s += &format!(" top{:.0}%:{:.2}", q * 100.0, acc / (eavg * tot_out));
                }
            }
        }
        // Area and folds.
        let on = out.face_areas();
        let _ = on;
        println!(
            "{name:<30} n {n} area ratio {:.4} eavg {:.4}%{s}",
            tot_out / total,
            100.0 * eavg / diag
        );
    };
    let prep = Prepared::new(&m);
    let (cl, _, _) = uniform::cluster(&prep, Target::Triangles(1850));
    show(
        "uniform",
        &build_output(&prep, &cl, Representative::Quadric),
    );
    let (cl, _, _) = floating::cluster(&prep, Target::Triangles(1850));
    show(
        "floating",
        &build_output(&prep, &cl, Representative::Quadric),
    );
    let lab = Lab::new(&prep);
    for (vn, o) in variants() {
        let cl = lab.cluster(&o, 1850);
        show(&vn, &build_output(&prep, &cl, Representative::Quadric));
    }
}

#[test]
#[ignore]
fn lab_where() {
    let name = std::env::var("LAB_MESH").unwrap_or("triceratops.obj".into());
    let m = load(&name);
    let t: u64 = std::env::var("LAB_T")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1850);
    let prep = Prepared::new(&m);
    let lab = Lab::new(&prep);
    for (vn, o) in variants() {
        let cl = lab.cluster(&o, t);
        let out = build_output(&prep, &cl, Representative::Quadric);
        let r = hausdorff(&m, &out, &HausdorffParams::default()).unwrap();
        println!(
            "{vn}: fwd max {:.3}% at {:?}; bwd max {:.3}% at {:?}",
            r.forward.max_pct, r.forward.max_at, r.backward.max_pct, r.backward.max_at
        );
        let at = DVec3::from_array(r.forward.max_at);
        let mut near: Vec<(f64, usize)> = (0..prep.dense_pos.len())
            .map(|d| ((prep.dense_pos[d].as_dvec3() - at).length(), d))
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut seen = vec![];
        for &(dist, d) in near.iter().take(40) {
            let c = cl.of[d];
            if seen.contains(&c) {
                continue;
            }
            seen.push(c);
            let members: Vec<usize> = (0..cl.of.len()).filter(|&x| cl.of[x] == c).collect();
            let cen: DVec3 = members
                .iter()
                .map(|&x| prep.dense_pos[x].as_dvec3())
                .sum::<DVec3>()
                / members.len() as f64;
            // surviving triangles touching this cluster
            let tris = prep
                .dense_faces
                .iter()
                .filter(|t| {
                    let k = t.map(|v| cl.of[v as usize]);
                    k.contains(&c) && k[0] != k[1] && k[1] != k[2] && k[0] != k[2]
                })
                .count();
            println!(
                "  v{d} dist {dist:.3} cluster {c}: {} members, centroid {:.3}, {tris} tris",
                members.len(),
                cen
            );
        }
    }
}

#[test]
#[ignore]
fn lab_eigen_cost() {
    let m = load("bunny.obj");
    let prep = Prepared::new(&m);
    let qs = prep.quadrics();
    let n = 200_000;
    let mut acc = DVec3::ZERO;
    let t = std::time::Instant::now();
    for i in 0..n {
        let a = qs[prep.active[i % prep.active.len()] as usize]
            + qs[prep.active[(i * 7 + 3) % prep.active.len()] as usize]
            + qs[prep.active[(i * 13 + 5) % prep.active.len()] as usize];
        acc += a.minimizer(DVec3::ZERO, 1e-2);
    }
    println!(
        "eigen minimizer: {:.3} us each {acc}",
        t.elapsed().as_secs_f64() * 1e6 / n as f64
    );
    let t = std::time::Instant::now();
    for i in 0..n {
        let a = qs[prep.active[i % prep.active.len()] as usize]
            + qs[prep.active[(i * 7 + 3) % prep.active.len()] as usize]
            + qs[prep.active[(i * 13 + 5) % prep.active.len()] as usize];
        let tr = a.a[0] + a.a[3] + a.a[5];
        let mm = a.matrix() + glam::DMat3::from_diagonal(DVec3::splat(1e-3 * tr));
        acc += mm.inverse() * (-a.linear());
    }
    println!(
        "tikhonov: {:.3} us each {acc}",
        t.elapsed().as_secs_f64() * 1e6 / n as f64
    );
}
