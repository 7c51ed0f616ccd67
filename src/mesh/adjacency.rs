//! Adjacency on demand: vertex → triangles, undirected edge → triangles, triangle → its
//! three edges, boundary edges and vertex neighbours, all as compressed rows (flat arrays,
//! no per-vertex heap objects) so that the clustering, QEM and local-mapping stages share one
//! cheap structure. Non-manifold input is represented faithfully: an edge may have any
//! number of triangles, a vertex any number of fans.

use super::TriMesh;
use rayon::prelude::*;

/// Compressed rows: row `i` is `items[offsets[i]..offsets[i + 1]]`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Csr {
    offsets: Vec<u32>,
    items: Vec<u32>,
}

impl Csr {
    /// Rows built from `(row, item)` pairs by a counting sort; within a row, items keep the
    /// order of `pairs`, so the result is deterministic.
    pub fn from_pairs(rows: usize, pairs: impl Iterator<Item = (u32, u32)> + Clone) -> Csr {
        let mut offsets = vec![0u32; rows + 1];
        for (r, _) in pairs.clone() {
            offsets[r as usize + 1] += 1;
        }
        for i in 0..rows {
            offsets[i + 1] += offsets[i];
        }
        let mut fill = offsets.clone();
        let mut items = vec![0u32; offsets[rows] as usize];
        for (r, it) in pairs {
            let slot = &mut fill[r as usize];
            items[*slot as usize] = it;
            *slot += 1;
        }
        Csr { offsets, items }
    }

    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Row `i`.
    #[inline]
    pub fn row(&self, i: usize) -> &[u32] {
        &self.items[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// Total number of items.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// True when there are no items.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }
}

/// Vertex → incident triangles (in increasing triangle order).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct VertexFaces(Csr);

impl VertexFaces {
    /// Builds the rows for `vertex_count` vertices.
    pub fn new(indices: &[[u32; 3]], vertex_count: usize) -> VertexFaces {
        VertexFaces(Csr::from_pairs(
            vertex_count,
            indices
                .iter()
                .enumerate()
                .flat_map(|(f, t)| t.iter().map(move |&v| (v, f as u32))),
        ))
    }

    /// Triangles around vertex `v` (a triangle that uses `v` twice appears twice).
    #[inline]
    pub fn of(&self, v: u32) -> &[u32] {
        self.0.row(v as usize)
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.0.rows()
    }
}

/// Undirected edges (`[low, high]`, sorted), the triangles on each, and each triangle's three
/// edges.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct EdgeFaces {
    edges: Vec<[u32; 2]>,
    faces: Csr,
    face_edges: Vec<[u32; 3]>,
}

impl EdgeFaces {
    /// Builds the edge table. Edge `k` of a triangle joins corners `k` and `(k + 1) % 3`.
    pub fn new(indices: &[[u32; 3]]) -> EdgeFaces {
        // (edge key, triangle·3 + corner): unique, so the parallel sort is deterministic.
        let mut half: Vec<(u64, u32)> = indices
            .par_iter()
            .enumerate()
            .flat_map_iter(|(f, t)| {
                (0..3).map(move |k| {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    let key = ((a.min(b) as u64) << 32) | a.max(b) as u64;
                    (key, f as u32 * 3 + k as u32)
                })
            })
            .collect();
        half.par_sort_unstable();
        let mut edges: Vec<[u32; 2]> = Vec::with_capacity(half.len() / 2 + 1);
        let mut offsets: Vec<u32> = Vec::with_capacity(half.len() / 2 + 2);
        let mut items = Vec::with_capacity(half.len());
        let mut face_edges = vec![[0u32; 3]; indices.len()];
        let mut last = u64::MAX;
        for &(key, fc) in &half {
            if key != last {
                offsets.push(items.len() as u32);
                edges.push([(key >> 32) as u32, key as u32]);
                last = key;
            }
            items.push(fc / 3);
            face_edges[(fc / 3) as usize][(fc % 3) as usize] = edges.len() as u32 - 1;
        }
        offsets.push(items.len() as u32);
        EdgeFaces {
            edges,
            faces: Csr { offsets, items },
            face_edges,
        }
    }

    /// Number of edges.
    pub fn len(&self) -> usize {
        self.edges.len()
    }

    /// True when there are no edges.
    pub fn is_empty(&self) -> bool {
        self.edges.is_empty()
    }

    /// All edges, sorted.
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }

    /// Endpoints of edge `e` (low, high).
    #[inline]
    pub fn edge(&self, e: u32) -> [u32; 2] {
        self.edges[e as usize]
    }

    /// Triangles on edge `e` (1 on a boundary, 2 inside a manifold, more where non-manifold).
    #[inline]
    pub fn faces(&self, e: u32) -> &[u32] {
        self.faces.row(e as usize)
    }

    /// The three edges of triangle `f` (edge `k` joins corners `k` and `k + 1`).
    #[inline]
    pub fn face_edges(&self, f: u32) -> [u32; 3] {
        self.face_edges[f as usize]
    }

    /// The edge joining `a` and `b`, if any.
    pub fn find(&self, a: u32, b: u32) -> Option<u32> {
        let key = [a.min(b), a.max(b)];
        self.edges.binary_search(&key).ok().map(|e| e as u32)
    }

    /// True when edge `e` has exactly one triangle.
    #[inline]
    pub fn is_boundary(&self, e: u32) -> bool {
        self.faces(e).len() == 1
    }

    /// Edges with exactly one triangle (holes and open borders).
    pub fn boundary_edges(&self) -> impl Iterator<Item = u32> + '_ {
        (0..self.edges.len() as u32).filter(|&e| self.is_boundary(e))
    }

    /// Edges with more than two triangles.
    pub fn non_manifold_edges(&self) -> impl Iterator<Item = u32> + '_ {
        (0..self.edges.len() as u32).filter(|&e| self.faces(e).len() > 2)
    }

    /// Vertex → neighbouring vertices through an edge (ascending), for `vertex_count`
    /// vertices.
    pub fn neighbours(&self, vertex_count: usize) -> Csr {
        Csr::from_pairs(
            vertex_count,
            self.edges
                .iter()
                .flat_map(|&[a, b]| [(a, b), (b, a)])
                .filter(|(a, b)| a != b),
        )
    }
}

/// Vertex and edge adjacency of one mesh.
#[derive(Debug, Clone, Default)]
pub struct Adjacency {
    /// Vertex → triangles.
    pub vertex_faces: VertexFaces,
    /// Edges → triangles and triangle → edges.
    pub edge_faces: EdgeFaces,
}

impl Adjacency {
    /// Adjacency of `mesh`.
    pub fn new(mesh: &TriMesh) -> Adjacency {
        Adjacency::of(&mesh.indices, mesh.vertex_count())
    }

    /// Adjacency of `indices` over `vertex_count` vertices (e.g. welded indices).
    pub fn of(indices: &[[u32; 3]], vertex_count: usize) -> Adjacency {
        let (vertex_faces, edge_faces) = rayon::join(
            || VertexFaces::new(indices, vertex_count),
            || EdgeFaces::new(indices),
        );
        Adjacency {
            vertex_faces,
            edge_faces,
        }
    }

    /// Number of boundary edges.
    pub fn boundary_edge_count(&self) -> usize {
        self.edge_faces.boundary_edges().count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two triangles sharing edge 1–2, plus a third hanging on edge 1–2 (non-manifold).
    fn tris() -> Vec<[u32; 3]> {
        vec![[0, 1, 2], [2, 1, 3], [1, 2, 4]]
    }

    #[test]
    fn vertex_faces_lists_every_incident_triangle() {
        let vf = VertexFaces::new(&tris(), 6);
        assert_eq!(vf.of(1), &[0, 1, 2]);
        assert_eq!(vf.of(3), &[1]);
        assert!(vf.of(5).is_empty());
    }

    #[test]
    fn edges_faces_and_boundary_against_brute_force() {
        let t = tris();
        let ef = EdgeFaces::new(&t);
        // Brute force: every unordered pair of corners.
        let mut all: Vec<[u32; 2]> = t
            .iter()
            .flat_map(|t| (0..3).map(move |k| [t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3])]))
            .collect();
        all.sort();
        all.dedup();
        assert_eq!(ef.edges(), &all[..]);
        let e12 = ef.find(2, 1).unwrap();
        assert_eq!(ef.faces(e12), &[0, 1, 2]);
        assert_eq!(ef.non_manifold_edges().collect::<Vec<_>>(), vec![e12]);
        assert_eq!(ef.boundary_edges().count(), all.len() - 1);
        for (f, tri) in t.iter().enumerate() {
            for k in 0..3 {
                let e = ef.face_edges(f as u32)[k];
                assert_eq!(ef.find(tri[k], tri[(k + 1) % 3]), Some(e));
                assert!(ef.faces(e).contains(&(f as u32)));
            }
        }
        let nb = ef.neighbours(6);
        assert_eq!(nb.row(1), &[0, 2, 3, 4]);
    }

    #[test]
    fn closed_tetrahedron_has_no_boundary() {
        let t = vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]];
        let a = Adjacency::of(&t, 4);
        assert_eq!(a.edge_faces.len(), 6);
        assert_eq!(a.boundary_edge_count(), 0);
    }
}
