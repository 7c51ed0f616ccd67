//! Uniform grid clustering (Rossignac & Borrel 1993): a cubic grid anchored at the
//! bounding box's minimum corner; all vertices of one cell form one cluster.
//!
//! The target search needs no hash table: a pass computes one packed cell key per vertex
//! and counts the triangles whose corners have three different keys, both in parallel, so a
//! pass costs two streaming loops over the vertices and triangles.

use super::{search_target, Clustering, Prepared, Target};
use rayon::prelude::*;

/// Cells per axis at most (keys pack three 21-bit coordinates).
const MAX_CELLS: f64 = (1u64 << 20) as f64;

/// Cell key of every active vertex for cell size `s`.
fn keys(prep: &Prepared, s: f64, out: &mut Vec<u64>) {
    let min = prep.bounds.min.as_dvec3();
    let inv = 1.0 / s;
    prep.dense_pos
        .par_iter()
        .with_min_len(8192)
        .map(|p| {
            // Points are >= min, so truncation is floor (and a cast saturates at 0).
            let c = (p.as_dvec3() - min) * inv;
            let q = |x: f64| (x as u64).min((1 << 21) - 1);
            q(c.x) | (q(c.y) << 21) | (q(c.z) << 42)
        })
        .collect_into_vec(out);
}

/// Smallest cell size allowed for this mesh (keys must fit), and never zero.
pub fn min_cell(prep: &Prepared) -> f64 {
    let ext = prep.bounds.size().max_element() as f64;
    (ext / MAX_CELLS).max(f64::MIN_POSITIVE)
}

/// A first guess of the cell size giving `target` triangles: a closed surface of area A cut
/// into cells of size s has about 1.5·A/s² occupied cells and twice as many triangles.
pub fn initial_cell(prep: &Prepared, target: u64) -> f64 {
    (3.0 * prep.area / target.max(1) as f64).sqrt()
}

/// Clusters `prep` on a uniform grid: returns the clustering, the cell size and the number of
/// passes made.
pub fn cluster(prep: &Prepared, target: Target) -> (Clustering, f64, usize) {
    let mut buf = Vec::with_capacity(prep.dense_pos.len());
    let min_s = min_cell(prep);
    let (s, evals) = match target {
        Target::Scale(s) => (s.max(min_s), 1),
        Target::Triangles(t) => search_target(
            &prep.dense_faces,
            |s| {
                let mut k = Vec::with_capacity(prep.dense_pos.len());
                keys(prep, s, &mut k);
                k
            },
            t,
            initial_cell(prep, t),
            min_s,
        ),
    };
    keys(prep, s, &mut buf);
    (Clustering::from_keys(&buf), s, evals)
}

#[cfg(test)]
mod tests {
    use super::super::tests::grid;
    use super::super::{simplify, Method, SimplifyParams};
    use super::*;

    #[test]
    fn cells_group_exactly_the_vertices_of_a_cell() {
        let m = grid(10);
        let prep = Prepared::new(&m);
        let (cl, s, _) = cluster(&prep, Target::Scale(0.25));
        assert_eq!(s, 0.25);
        // The slow twin: compare every pair of vertices.
        let cell = |d: usize| (prep.dense_pos[d] - prep.bounds.min).as_dvec3() / 0.25;
        for a in 0..prep.active.len() {
            for b in 0..prep.active.len() {
                let same = cell(a).floor() == cell(b).floor();
                assert_eq!(same, cl.of[a] == cl.of[b], "{a} {b}");
            }
        }
    }

    #[test]
    fn reaches_the_target_and_leaves_no_degenerate_or_duplicate() {
        let m = grid(40);
        let out = simplify(&m, &SimplifyParams::triangles(Method::Uniform, 300)).unwrap();
        let n = out.mesh.triangle_count();
        assert!((250..=350).contains(&n), "{n}");
        let mut clean = out.mesh.clone();
        let r = clean.clean();
        assert_eq!(
            (r.degenerate, r.duplicate, r.unreferenced),
            (0, 0, 0),
            "{r:?}"
        );
    }
}
