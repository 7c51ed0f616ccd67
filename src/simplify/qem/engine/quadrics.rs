//! The engine's per-vertex quadrics, computed from its own vertex → corner lists: the very
//! sums of [`Prepared::quadrics`] (the same planes, added in the same order, so the same
//! bits), without that method's vertex → face table, its quadric per input vertex (welded
//! copies and stray vertices included) and the copy of the active ones: together about a
//! tenth of the engine's memory, allocated (and faulted in page by page) on every run.

use crate::simplify::prep::Prepared;
use crate::simplify::quadric::Quadric;
use glam::DVec3;
use rayon::prelude::*;

/// Per dense vertex, the quadric [`Prepared::quadrics`] gives its input vertex:
/// the area-weighted planes of its faces (in increasing face order) and, at its border
/// edges, the plane through the edge perpendicular to the edge's one face, weighted by the
/// squared edge length (in increasing order of the other end). `faces` are the engine's
/// (dense, every one with three distinct corners), `span`/`pool` its corner lists
/// (each in decreasing corner order), `pos` the dense positions.
///
/// Only for a mesh whose welded faces all have three distinct corners (`None` otherwise,
/// then the caller takes [`Prepared::quadrics`]): a face with a repeated corner has no
/// plane but counts in that method's border search, and the engine drops such faces.
pub(super) fn vertex_quadrics(
    prep: &Prepared<'_>,
    faces: &[[u32; 3]],
    span: &[(u32, u32)],
    pool: &[u32],
    pos: &[DVec3],
) -> Option<Vec<Quadric>> {
    if faces.len() != prep.dense_faces.len() {
        return None;
    }
    // Per face its unit normal, offset and area, as `Prepared::planes` computes them (the
    // engine's faces are the welded ones, renumbered densely in the same vertex order).
    let planes: Vec<(DVec3, f64, f64)> = faces
        .par_iter()
        .with_min_len(4096)
        .map(|t| {
            let p0 = pos[t[0] as usize];
            let c = (pos[t[1] as usize] - p0).cross(pos[t[2] as usize] - p0);
            let len = c.length();
            let n = if len > 0.0 { c / len } else { DVec3::ZERO };
            (n, -n.dot(p0), 0.5 * len)
        })
        .collect();
    let active = &prep.active;
    Some(
        (0..span.len() as u32)
            .into_par_iter()
            .with_min_len(1024)
            .map_init(Vec::new, |edges: &mut Vec<u64>, v| {
                let (start, len) = span[v as usize];
                // Increasing face order, as the vertex → face table lists them.
                let corners = pool[start as usize..(start + len) as usize].iter().rev();
                let mut s = Quadric::ZERO;
                // The parity test of `Prepared::quadrics` on the input's vertex numbers
                // (its outcome, collisions included, decides whether borders are searched).
                let mut parity = 0u64;
                for &c in corners.clone() {
                    let f = c as usize / 3;
                    let (n, d, area) = planes[f];
                    if area > 0.0 {
                        s += Quadric::plane(n, d, area);
                    }
                    for &u in &faces[f] {
                        if u != v {
                            let w = active[u as usize] as u64;
                            parity ^= (w + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
                        }
                    }
                }
                if parity == 0 {
                    return s;
                }
                // The two edges of each face at v as (other end << 32 | face): dense ends
                // order as the input's (the dense numbering keeps the input's order).
                edges.clear();
                for &c in corners {
                    let (f, k) = (c as usize / 3, c as usize % 3);
                    let t = faces[f];
                    edges.push((t[(k + 1) % 3] as u64) << 32 | f as u64);
                    edges.push((t[(k + 2) % 3] as u64) << 32 | f as u64);
                }
                edges.sort_unstable();
                let mut i = 0;
                while i < edges.len() {
                    let u = (edges[i] >> 32) as u32;
                    let mut j = i + 1;
                    while j < edges.len() && (edges[j] >> 32) as u32 == u {
                        j += 1;
                    }
                    let n = planes[edges[i] as u32 as usize].0;
                    if j - i == 1 && n != DVec3::ZERO {
                        let (pa, pb) = (pos[v as usize], pos[u as usize]);
                        let e = pb - pa;
                        let m = e.cross(n).normalize_or_zero();
                        if m != DVec3::ZERO {
                            s += Quadric::plane(m, -m.dot(pa), e.length_squared());
                        }
                    }
                    i = j;
                }
                s
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::super::{corner_lists, live_faces};
    use crate::mesh::TriMesh;
    use crate::simplify::prep::Prepared;
    use glam::{DVec3, Vec3};
    use proptest::prelude::*;

    /// The engine's quadrics against [`Prepared::quadrics`], bit for bit; `None` when the
    /// engine falls back to that method (a welded face with a repeated corner).
    fn agree(m: &TriMesh) -> Option<()> {
        let prep = Prepared::new(m);
        let pos: Vec<DVec3> = prep.dense_pos.iter().map(|p| p.as_dvec3()).collect();
        let (faces, _) = live_faces(&prep);
        let (span, pool) = corner_lists(prep.active.len(), &faces);
        let ours = super::vertex_quadrics(&prep, &faces, &span, &pool, &pos)?;
        let theirs = prep.quadrics();
        assert_eq!(ours.len(), prep.active.len());
        for (d, q) in ours.iter().enumerate() {
            assert_eq!(*q, theirs[prep.active[d] as usize], "vertex {d}");
        }
        Some(())
    }

    /// Closed, open (a hole, a border) and welded (seam copies) meshes.
    #[test]
    fn equal_the_prepared_quadrics() {
        let mut open = crate::simplify::test_meshes::grid(9);
        open.indices.remove(40);
        let mut seam = crate::simplify::test_meshes::icosphere(2, 1.0);
        let copy = seam.positions.len() as u32;
        seam.positions
            .push(seam.positions[seam.indices[0][0] as usize]);
        seam.indices[0][0] = copy;
        for m in [crate::simplify::test_meshes::icosphere(2, 1.0), open, seam] {
            assert!(agree(&m).is_some());
        }
    }

    proptest! {
        /// Random triangle soups over few vertices (non-manifold edges, flipped faces,
        /// stray vertices, repeated positions): equal, or the fallback when a welded face
        /// repeats a corner.
        #[test]
        fn equal_the_prepared_quadrics_on_soups(
            pts in proptest::collection::vec((0u8..4, 0u8..4, 0u8..4), 4..16),
            raw in proptest::collection::vec((0usize..16, 0usize..16, 0usize..16), 1..40),
        ) {
            let positions: Vec<Vec3> = pts
                .iter()
                .map(|&(x, y, z)| Vec3::new(x as f32, y as f32, (z as f32) * 0.5 + x as f32 * 0.1))
                .collect();
            let n = positions.len();
            let indices: Vec<[u32; 3]> = raw
                .into_iter()
                .map(|(a, b, c)| [a % n, b % n, c % n].map(|v| v as u32))
                .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
                .collect();
            prop_assume!(!indices.is_empty());
            let m = TriMesh { positions, indices, ..TriMesh::default() };
            let _ = agree(&m);
        }
    }
}
