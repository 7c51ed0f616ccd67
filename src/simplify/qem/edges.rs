//! The engine's edge table: every edge of the welded mesh with the face corners that hold
//! it, built from the engine's own vertex → corner lists.
//!
//! The same table as [`crate::mesh::adjacency::EdgeFaces`] (edges sorted by (low, high)
//! vertex, each edge's corners in increasing order, so its faces in the same order), but by
//! one bucket per low vertex rather than by a sort of every half-edge of the mesh: a
//! vertex's half-edges are a few, sorted in place, where the global sort was the larger part
//! of the engine's setup (6–7 % of a one-thread run on bunny → 10 %). The corners come with
//! it, so the canonical corner of an edge (its least) needs no search of its faces.

/// The edges of a triangle mesh and their corners (corner `3f + k` holds the edge from face
/// f's k-th vertex to its next one).
pub(super) struct Edges {
    edges: Vec<[u32; 2]>,
    /// Edge e's corners: `corners[offsets[e]..offsets[e + 1]]`.
    offsets: Vec<u32>,
    corners: Vec<u32>,
}

impl Edges {
    /// The edges of `faces` (each with three distinct corners), from the corner lists of
    /// the `span.len()` vertices (`pool[start..start + len]`: the corners at the vertex).
    pub(super) fn new(faces: &[[u32; 3]], span: &[(u32, u32)], pool: &[u32]) -> Edges {
        let mut edges = Vec::with_capacity(3 * faces.len() / 2 + 1);
        let mut offsets = Vec::with_capacity(3 * faces.len() / 2 + 2);
        let mut corners = Vec::with_capacity(3 * faces.len());
        // Per vertex a: its half-edges to higher vertices, as (other end, corner).
        let mut half: Vec<(u32, u32)> = Vec::new();
        for (a, &(start, len)) in span.iter().enumerate() {
            let a = a as u32;
            half.clear();
            for &c in &pool[start as usize..(start + len) as usize] {
                let (f, k) = (c / 3, c % 3);
                let t = faces[f as usize];
                // Corner k holds the edge to the next vertex; the corner before it holds
                // the edge from the previous vertex to this one.
                let (next, prev) = (t[(k as usize + 1) % 3], t[(k as usize + 2) % 3]);
                if next > a {
                    half.push((next, c));
                }
                if prev > a {
                    half.push((prev, 3 * f + (k + 2) % 3));
                }
            }
            half.sort_unstable();
            for (i, &(b, c)) in half.iter().enumerate() {
                if i == 0 || half[i - 1].0 != b {
                    offsets.push(corners.len() as u32);
                    edges.push([a, b]);
                }
                corners.push(c);
            }
        }
        offsets.push(corners.len() as u32);
        Edges {
            edges,
            offsets,
            corners,
        }
    }

    /// Number of edges.
    pub(super) fn len(&self) -> usize {
        self.edges.len()
    }

    /// All edges (low, high), sorted.
    pub(super) fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }

    /// The corners of edge `e`, in increasing order (one on a border, two inside a
    /// manifold, more where it is not one).
    #[inline]
    pub(super) fn corners(&self, e: usize) -> &[u32] {
        &self.corners[self.offsets[e] as usize..self.offsets[e + 1] as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::Edges;
    use crate::mesh::adjacency::EdgeFaces;
    use proptest::prelude::*;

    proptest! {
        /// Against the sorted table of the mesh module: the same edges in the same order,
        /// the same faces per edge in the same order, and each corner holds its edge.
        #[test]
        fn equals_the_sorted_edge_table(
            raw in proptest::collection::vec([0u32..24, 0u32..24, 0u32..24], 1..60),
        ) {
            let faces: Vec<[u32; 3]> = raw
                .into_iter()
                .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
                .collect();
            let (span, pool) = super::super::engine::corner_lists(24, &faces);
            let ours = Edges::new(&faces, &span, &pool);
            let theirs = EdgeFaces::new(&faces);
            prop_assert_eq!(ours.edges(), theirs.edges());
            for e in 0..ours.len() {
                let fs: Vec<u32> = ours.corners(e).iter().map(|c| c / 3).collect();
                prop_assert_eq!(&fs[..], theirs.faces(e as u32));
                for &c in ours.corners(e) {
                    let t = faces[c as usize / 3];
                    let (u, v) = (t[c as usize % 3], t[(c as usize + 1) % 3]);
                    prop_assert_eq!([u.min(v), u.max(v)], ours.edges()[e]);
                }
            }
        }
    }
}
