//! Shared preparation for the simplifiers: the welded topology (seams are not holes), the
//! dense active-vertex numbering, and the per-vertex quantities computed once on first use —
//! Low's importance weights, area-weighted plane quadrics with border planes, and the normal
//! statistics of the octree. Vertex clustering (`cluster`) and quadric edge collapse (`qem`)
//! both start from a [`Prepared`] mesh; neither imports the other.

use crate::mesh::adjacency::VertexFaces;
use crate::mesh::{Aabb, TriMesh};
use crate::simplify::quadric::Quadric;
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// A mesh made ready for simplification: welded topology and the active vertex set, with the
/// per-vertex quantities some methods need computed on first use.
pub struct Prepared<'a> {
    /// The input.
    pub mesh: &'a TriMesh,
    /// Vertex → its welded (canonical) vertex.
    pub weld: Vec<u32>,
    /// True when some vertex was welded to another (seams).
    pub has_seams: bool,
    /// Triangles over welded vertices.
    pub faces: Vec<[u32; 3]>,
    /// Canonical vertices that triangles use, ascending: the vertices being clustered,
    /// numbered densely (dense index → vertex).
    pub active: Vec<u32>,
    /// Vertex → dense index (`u32::MAX` when not active).
    pub dense_of: Vec<u32>,
    /// Positions of the active vertices, by dense index.
    pub dense_pos: Vec<Vec3>,
    /// Triangles over dense indices.
    pub dense_faces: Vec<[u32; 3]>,
    /// Bounds of the active vertices.
    pub bounds: Aabb,
    /// Surface area.
    pub area: f64,
    vertex_faces: std::sync::OnceLock<VertexFaces>,
    weights: std::sync::OnceLock<Vec<f64>>,
    quadrics: std::sync::OnceLock<Vec<Quadric>>,
    normals: std::sync::OnceLock<Vec<NormalStats>>,
}

impl<'a> Prepared<'a> {
    /// Welds `mesh` and finds the active vertices.
    pub fn new(mesh: &'a TriMesh) -> Prepared<'a> {
        let weld = mesh.weld_map();
        let has_seams = weld.iter().enumerate().any(|(i, &w)| i as u32 != w);
        let faces = mesh.welded_indices(&weld);
        let mut used = vec![false; mesh.vertex_count()];
        for t in &faces {
            for &v in t {
                used[v as usize] = true;
            }
        }
        let active: Vec<u32> = (0..mesh.vertex_count() as u32)
            .filter(|&v| used[v as usize])
            .collect();
        let mut dense_of = vec![u32::MAX; mesh.vertex_count()];
        for (d, &v) in active.iter().enumerate() {
            dense_of[v as usize] = d as u32;
        }
        let dense_pos: Vec<Vec3> = active.iter().map(|&v| mesh.positions[v as usize]).collect();
        let dense_faces: Vec<[u32; 3]> = faces
            .iter()
            .map(|t| t.map(|v| dense_of[v as usize]))
            .collect();
        let bounds = Aabb::of(dense_pos.iter().copied()).unwrap_or(Aabb {
            min: Vec3::ZERO,
            max: Vec3::ZERO,
        });
        let area = mesh.area();
        Prepared {
            mesh,
            weld,
            has_seams,
            faces,
            active,
            dense_of,
            dense_pos,
            dense_faces,
            bounds,
            area,
            vertex_faces: Default::default(),
            weights: Default::default(),
            quadrics: Default::default(),
            normals: Default::default(),
        }
    }

    /// Position of vertex `v` in f64.
    #[inline]
    pub fn pos(&self, v: u32) -> DVec3 {
        self.mesh.positions[v as usize].as_dvec3()
    }

    /// Vertex → triangles of the welded mesh.
    pub fn vertex_faces(&self) -> &VertexFaces {
        self.vertex_faces
            .get_or_init(|| VertexFaces::new(&self.faces, self.mesh.vertex_count()))
    }

    /// Calls `visit(g)` for every other triangle on edge `k` of triangle `f` (corners `k`
    /// and `k + 1`) of the welded mesh. A local search around one corner: cheaper than
    /// building an edge table by sorting, which dominated the uniform method's time.
    #[inline]
    pub fn across(&self, f: u32, k: usize, mut visit: impl FnMut(u32)) {
        let t = self.faces[f as usize];
        let (a, b) = (t[k], t[(k + 1) % 3]);
        for &g in self.vertex_faces().of(a) {
            if g != f && self.faces[g as usize].contains(&b) {
                visit(g);
            }
        }
    }

    /// Low's visual importance per vertex: (longest incident edge) · cos(θ/2), θ the
    /// largest angle between two incident edges (0 for inactive vertices).
    pub fn weights(&self) -> &[f64] {
        self.weights.get_or_init(|| {
            let vf = self.vertex_faces();
            self.per_vertex(256, Vec::new, |nb: &mut Vec<u32>, v| {
                nb.clear();
                for &f in vf.of(v) {
                    nb.extend(self.faces[f as usize].iter().filter(|&&u| u != v));
                }
                nb.sort_unstable();
                nb.dedup();
                if nb.is_empty() {
                    return 0.0;
                }
                let p = self.pos(v);
                let mut longest = 0.0f64;
                let mut min_cos = 1.0f64;
                for (i, &a) in nb.iter().enumerate() {
                    let ea = self.pos(a) - p;
                    let la = ea.length();
                    longest = longest.max(la);
                    for &b in &nb[i + 1..] {
                        let eb = self.pos(b) - p;
                        let lb = eb.length();
                        if la > 0.0 && lb > 0.0 {
                            min_cos = min_cos.min(ea.dot(eb) / (la * lb));
                        }
                    }
                }
                let theta = min_cos.clamp(-1.0, 1.0).acos();
                longest * (theta * 0.5).cos()
            })
        })
    }

    /// Per-vertex quadric: the area-weighted planes of the incident triangles, plus, on
    /// border edges, a plane through the edge perpendicular to its triangle (weighted by
    /// the squared edge length) so that holes and open borders keep their shape.
    pub fn quadrics(&self) -> &[Quadric] {
        self.quadrics.get_or_init(|| {
            let planes = self.planes();
            self.per_vertex(1024, Vec::new, |edges: &mut Vec<u64>, v| {
                self.vertex_quadric(v, &planes, edges)
            })
        })
    }

    /// The quadrics of [`Prepared::quadrics`] and, from the same pass over every vertex's
    /// triangles (they are loaded for the quadric anyway), the normal statistics the
    /// octree's split rule needs (see [`NormalStats`]).
    pub fn quadrics_and_normals(&self) -> (&[Quadric], &[NormalStats]) {
        if let (Some(q), Some(n)) = (self.quadrics.get(), self.normals.get()) {
            return (q, n);
        }
        let planes = self.planes();
        let both: Vec<(Quadric, NormalStats)> = self.per_vertex(
            1024,
            || (Vec::new(), Vec::new()),
            |(edges, fan): &mut (Vec<u64>, Vec<(u32, u32, Vec3)>), v| {
                let q = self.vertex_quadric(v, &planes, edges);
                // The vertex's triangles as (its two other corners, unit normal).
                fan.clear();
                let (mut an, mut area) = (DVec3::ZERO, 0.0);
                for &f in self.vertex_faces().of(v) {
                    let (n, _, a) = planes[f as usize];
                    an += n * (a / 3.0);
                    area += a / 3.0;
                    if n != DVec3::ZERO {
                        let t = self.faces[f as usize];
                        let k = t.iter().position(|&x| x == v).unwrap_or(0);
                        fan.push((t[(k + 1) % 3], t[(k + 2) % 3], n.as_vec3()));
                    }
                }
                // θmax: the smallest cosine between two triangles sharing an edge at v
                // (they share v and one more corner).
                let mut min_cos = 1.0f32;
                for (i, &(a, b, nf)) in fan.iter().enumerate() {
                    for &(c, e, ng) in &fan[i + 1..] {
                        if a == c || a == e || b == c || b == e {
                            min_cos = min_cos.min(nf.dot(ng));
                        }
                    }
                }
                let stats = NormalStats {
                    area_normal: an.as_vec3(),
                    area: area as f32,
                    theta_max: min_cos.clamp(-1.0, 1.0).acos(),
                };
                (q, stats)
            },
        );
        let (q, n): (Vec<Quadric>, Vec<NormalStats>) = both.into_iter().unzip();
        // Another thread may have filled either meanwhile; the values are the same.
        let _ = self.quadrics.set(q);
        let _ = self.normals.set(n);
        (
            self.quadrics.get().expect("set above"),
            self.normals.get().expect("set above"),
        )
    }

    /// `f(scratch, v)` for every vertex `v`, in parallel in runs of at least `min_len`
    /// vertices, each worker with its own scratch from `init` (no allocation per vertex).
    fn per_vertex<S, T: Send>(
        &self,
        min_len: usize,
        init: impl Fn() -> S + Sync + Send,
        f: impl Fn(&mut S, u32) -> T + Sync + Send,
    ) -> Vec<T> {
        (0..self.mesh.vertex_count() as u32)
            .into_par_iter()
            .with_min_len(min_len)
            .map_init(init, f)
            .collect()
    }

    /// Per welded triangle: its plane (unit normal, offset) and area, computed once.
    fn planes(&self) -> Vec<(DVec3, f64, f64)> {
        self.faces
            .par_iter()
            .with_min_len(4096)
            .map(|t| {
                let p0 = self.pos(t[0]);
                let c = (self.pos(t[1]) - p0).cross(self.pos(t[2]) - p0);
                let len = c.length();
                let n = if len > 0.0 { c / len } else { DVec3::ZERO };
                (n, -n.dot(p0), 0.5 * len)
            })
            .collect()
    }

    /// The quadric of vertex `v` (see [`Prepared::quadrics`]); `edges` is scratch.
    fn vertex_quadric(
        &self,
        v: u32,
        planes: &[(DVec3, f64, f64)],
        edges: &mut Vec<u64>,
    ) -> Quadric {
        let vf = self.vertex_faces();
        let mut s = Quadric::ZERO;
        // Inside a surface every neighbour of v is the far end of exactly two of its
        // triangles' edges. The XOR of a hash of the far ends is then 0, and the exact
        // (sorting) border search below is skipped: it would otherwise cost a third of the
        // uniform method's time.
        let mut parity = 0u64;
        for &f in vf.of(v) {
            let (n, d, area) = planes[f as usize];
            if area > 0.0 {
                s += Quadric::plane(n, d, area);
            }
            let t = self.faces[f as usize];
            for &u in &t {
                if u != v {
                    parity ^= (u as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
                }
            }
        }
        if parity == 0 {
            return s;
        }
        edges.clear();
        for &f in vf.of(v) {
            // The two edges of f at v, as (other end << 32 | triangle).
            let t = self.faces[f as usize];
            for k in 0..3 {
                if t[k] == v {
                    edges.push((t[(k + 1) % 3] as u64) << 32 | f as u64);
                    edges.push((t[(k + 2) % 3] as u64) << 32 | f as u64);
                }
            }
        }
        // An edge at v that only one triangle has is a border: add the plane through it,
        // perpendicular to that triangle.
        edges.sort_unstable();
        let mut i = 0;
        while i < edges.len() {
            let u = (edges[i] >> 32) as u32;
            let mut j = i + 1;
            while j < edges.len() && (edges[j] >> 32) as u32 == u {
                j += 1;
            }
            let n = planes[edges[i] as u32 as usize].0;
            if j - i == 1 && u != v && n != DVec3::ZERO {
                let (pa, pb) = (self.pos(v), self.pos(u));
                let e = pb - pa;
                let m = e.cross(n).normalize_or_zero();
                if m != DVec3::ZERO {
                    s += Quadric::plane(m, -m.dot(pa), e.length_squared());
                }
            }
            i = j;
        }
        s
    }
}

/// A vertex's normal statistics for the octree's split rule (Kim et al. 1999, eq. 1–4), in f32: a
/// split heuristic needs no more, and the octree streams them through every split.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalStats {
    /// Σ (A/3)·n over the vertex's triangles (A area, n unit normal).
    pub area_normal: Vec3,
    /// Σ A/3 over them.
    pub area: f32,
    /// The largest angle (radians) between the normals of two of its triangles sharing an
    /// edge.
    pub theta_max: f32,
}
