//! Floating-cell clustering (Low & Tan 1997; Kim et al. 1999 §II.2). Vertices are weighted
//! by their visual importance w = (longest incident edge) · cos(θ/2), θ the largest angle
//! between two incident edges (the chance to lie on a silhouette). In order of decreasing
//! weight, a vertex no cell holds yet becomes the centre of a new cell — a cube of edge
//! `cell_size` centred on it; finally every vertex joins the nearest centre (Euclidean)
//! among the cells that contain it.
//!
//! Centres are more than half a cell apart (in the max norm), so a grid of half-cell buckets
//! holds at most one centre per bucket and a vertex finds every candidate among its 27
//! neighbouring buckets. The grid is a dense array when it is small next to the mesh (the
//! common case: 3–4× faster than hashing the 27 lookups per vertex), a hash map otherwise.

use super::{search_target, uniform, Clustering, Prepared, Target};
use glam::DVec3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;

struct Pass {
    /// Centre index (0.. in creation order) of each active vertex.
    of: Vec<u32>,
    centres: usize,
}

/// Half-cell bucket of `p` (p ≥ min, so truncation is floor; `floor` itself is a libm call
/// here and showed in profiles).
#[inline]
fn bucket(p: DVec3, min: DVec3, inv_h: f64) -> (i64, i64, i64) {
    let c = (p - min) * inv_h;
    (c.x as i64, c.y as i64, c.z as i64)
}

/// Half-cell buckets → centre index.
enum Buckets {
    /// Row-major over `dims` buckets, `u32::MAX` = empty.
    Dense { dims: [i64; 3], cells: Vec<u32> },
    /// Occupied buckets only, keyed by their full coordinates.
    Sparse(FxHashMap<(i64, i64, i64), u32>),
}

impl Buckets {
    /// Buckets for the points in `bounds` (bucketed by [`bucket`] from `min` = the bounds'
    /// minimum at `inv_h`), dense when `dense` allows it and there are at most
    /// `max(8 · vertices, 2²⁰)` of them.
    fn new(bounds: &crate::mesh::Aabb, inv_h: f64, vertices: usize, dense: bool) -> Buckets {
        // The grid's extent comes from the same f64 arithmetic as every lookup, so the point
        // on the bounds' maximum face falls in the last bucket, never past it (a difference
        // taken in f32 can round down a bucket).
        let min = bounds.min.as_dvec3();
        let last = bucket(bounds.max.as_dvec3(), min, inv_h);
        let dims = [last.0, last.1, last.2].map(|l| l.saturating_add(1));
        let cells = dims.iter().map(|&d| d as f64).product::<f64>();
        if dense && cells <= (8 * vertices).max(1 << 20) as f64 {
            Buckets::Dense {
                dims,
                cells: vec![u32::MAX; cells as usize],
            }
        } else {
            Buckets::Sparse(FxHashMap::default())
        }
    }

    #[inline]
    fn get(&self, b: (i64, i64, i64)) -> Option<u32> {
        match self {
            Buckets::Dense { dims, cells } => {
                if b.0 < 0
                    || b.1 < 0
                    || b.2 < 0
                    || b.0 >= dims[0]
                    || b.1 >= dims[1]
                    || b.2 >= dims[2]
                {
                    return None;
                }
                let c = cells[((b.2 * dims[1] + b.1) * dims[0] + b.0) as usize];
                (c != u32::MAX).then_some(c)
            }
            Buckets::Sparse(map) => map.get(&b).copied(),
        }
    }

    #[inline]
    fn insert(&mut self, b: (i64, i64, i64), c: u32) {
        match self {
            Buckets::Dense { dims, cells } => {
                // A point of the bounds is always inside the grid (see `new`).
                debug_assert!(
                    (0..3).all(|k| [b.0, b.1, b.2][k] < dims[k]),
                    "{b:?} {dims:?}"
                );
                cells[((b.2 * dims[1] + b.1) * dims[0] + b.0) as usize] = c;
            }
            Buckets::Sparse(map) => {
                map.insert(b, c);
            }
        }
    }
}

/// Centres so far, bucketed by half-cell.
struct Centres<'a> {
    prep: &'a Prepared<'a>,
    grid: Buckets,
    /// Positions of the centres, by centre index (kept here, not looked up through the
    /// vertex: the 27-bucket scans are the method's hot loop).
    list: Vec<DVec3>,
    min: DVec3,
    h: f64,
    inv_h: f64,
}

impl Centres<'_> {
    #[inline]
    fn pos(&self, d: u32) -> DVec3 {
        self.prep.dense_pos[d as usize].as_dvec3()
    }

    /// Whether some centre's cell holds `p` (its own bucket first: where a covering centre
    /// most often is).
    #[inline]
    fn covered(&self, p: DVec3) -> bool {
        let b = bucket(p, self.min, self.inv_h);
        let holds = |d: (i64, i64, i64)| {
            self.grid
                .get((b.0 + d.0, b.1 + d.1, b.2 + d.2))
                .is_some_and(|c| (self.list[c as usize] - p).abs().max_element() <= self.h)
        };
        if holds((0, 0, 0)) {
            return true;
        }
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    if (dx, dy, dz) != (0, 0, 0) && holds((dx, dy, dz)) {
                        return true;
                    }
                }
            }
        }
        false
    }

    /// Calls `visit(centre index, centre position)` for every centre whose cell holds `p`.
    #[inline]
    fn covering(&self, p: DVec3, mut visit: impl FnMut(u32, DVec3)) {
        let b = bucket(p, self.min, self.inv_h);
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    if let Some(c) = self.grid.get((b.0 + dx, b.1 + dy, b.2 + dz)) {
                        let q = self.list[c as usize];
                        if (q - p).abs().max_element() <= self.h {
                            visit(c, q);
                        }
                    }
                }
            }
        }
    }
}

fn pass(prep: &Prepared, order: &[u32], s: f64) -> Pass {
    pass_in(prep, order, s, true)
}

/// [`pass`], with the dense bucket grid allowed or not (tests compare the two).
fn pass_in(prep: &Prepared, order: &[u32], s: f64, dense: bool) -> Pass {
    let h = 0.5 * s;
    let mut cs = Centres {
        prep,
        grid: Buckets::new(&prep.bounds, 1.0 / h, prep.dense_pos.len(), dense),
        list: Vec::new(),
        min: prep.bounds.min.as_dvec3(),
        h,
        inv_h: 1.0 / h,
    };
    for &v in order {
        let p = cs.pos(v);
        if !cs.covered(p) {
            let next = cs.list.len() as u32;
            cs.grid.insert(bucket(p, cs.min, cs.inv_h), next);
            cs.list.push(p);
        }
    }
    let cs = &cs;
    let of: Vec<u32> = (0..prep.dense_pos.len() as u32)
        .into_par_iter()
        .with_min_len(1024)
        .map(|v| {
            let p = cs.pos(v);
            let mut best = (f64::INFINITY, u32::MAX);
            cs.covering(p, |c, q| {
                let d = (q - p).length_squared();
                if d < best.0 || (d == best.0 && c < best.1) {
                    best = (d, c);
                }
            });
            best.1
        })
        .collect();
    Pass {
        of,
        centres: cs.list.len(),
    }
}

/// Active vertices (dense indices) in order of decreasing weight, ties by index: the order
/// in which they may become centres.
fn weight_order(prep: &Prepared) -> Vec<u32> {
    let w = prep.weights();
    let mut order: Vec<u32> = (0..prep.active.len() as u32).collect();
    order.par_sort_unstable_by(|&a, &b| {
        w[prep.active[b as usize] as usize]
            .total_cmp(&w[prep.active[a as usize] as usize])
            .then(a.cmp(&b))
    });
    order
}

/// Clusters `prep` with floating cells: returns the clustering, the cell size and the number
/// of passes made.
pub fn cluster(prep: &Prepared, target: Target) -> (Clustering, f64, usize) {
    let order = weight_order(prep);
    let min_s = 2.0 * uniform::min_cell(prep);
    let (s, evals) = match target {
        Target::Scale(s) => (s.max(min_s), 1),
        Target::Triangles(t) => {
            search_target(
                &prep.dense_faces,
                |s| pass(prep, &order, s).of,
                t,
                // Centres pack closer than grid cells: start from a larger cell.
                1.5 * uniform::initial_cell(prep, t),
                min_s,
            )
        }
    };
    let p = pass(prep, &order, s);
    debug_assert!(p.of.iter().all(|&c| (c as usize) < p.centres));
    (Clustering::from_keys(&p.of), s, evals)
}

#[cfg(test)]
mod tests {
    use super::super::tests::grid;
    use super::*;
    use crate::mesh::TriMesh;
    use glam::Vec3;

    #[test]
    fn every_vertex_joins_the_nearest_covering_centre() {
        let m = grid(12);
        let prep = Prepared::new(&m);
        let order = weight_order(&prep);
        let s = 0.2;
        let p = pass(&prep, &order, s);
        assert!(matches!(
            Buckets::new(&prep.bounds, 2.0 / s, prep.dense_pos.len(), true),
            Buckets::Dense { .. }
        ));
        // The hash-map grid (huge or far-flung meshes) gives the same clusters.
        let sparse = pass_in(&prep, &order, s, false);
        assert_eq!(
            (sparse.of.clone(), sparse.centres),
            (p.of.clone(), p.centres)
        );
        // The slow twin: greedy centres by scanning all earlier centres.
        let pos = |d: u32| prep.dense_pos[d as usize].as_dvec3();
        let mut centres: Vec<u32> = Vec::new();
        for &v in &order {
            if !centres
                .iter()
                .any(|&c| (pos(c) - pos(v)).abs().max_element() <= s / 2.0)
            {
                centres.push(v);
            }
        }
        assert_eq!(centres.len(), p.centres);
        for v in 0..prep.active.len() as u32 {
            let want = (0..centres.len() as u32)
                .filter(|&c| (pos(centres[c as usize]) - pos(v)).abs().max_element() <= s / 2.0)
                .min_by(|&a, &b| {
                    (pos(centres[a as usize]) - pos(v))
                        .length_squared()
                        .total_cmp(&(pos(centres[b as usize]) - pos(v)).length_squared())
                        .then(a.cmp(&b))
                })
                .unwrap();
            assert_eq!(p.of[v as usize], want, "vertex {v}");
        }
    }

    #[test]
    fn far_and_large_coordinates_bucket_the_same_dense_or_sparse() {
        // Mixed signs and large magnitudes, where a grid sized by an f32 difference came out
        // one bucket short (found in review): every cell size must give the dense and the
        // sparse grid the same clusters, and neither may index past its end.
        let triangle = TriMesh {
            positions: vec![
                Vec3::new(-64.0, 0.0, 0.0),
                Vec3::new((1u64 << 30) as f32, 0.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
            ],
            indices: vec![[0, 1, 2]],
            ..TriMesh::default()
        };
        let mut scattered = TriMesh::default();
        let mut rng = crate::rng::SplitMix64::new(11);
        for _ in 0..300 {
            scattered.positions.push(Vec3::new(
                rng.range(-7e5, 9e7) as f32,
                rng.range(-3.3e6, 4e5) as f32,
                rng.range(-1.0, 1.0) as f32,
            ));
        }
        scattered.indices = (0..298).map(|i| [i, i + 1, i + 2]).collect();
        for m in [triangle, scattered] {
            let prep = Prepared::new(&m);
            let order = weight_order(&prep);
            let mut cells = vec![715_827_925.333_325_4];
            cells.extend((0..60).map(|k| 1e3 * 1.37f64.powi(k)));
            for s in cells {
                let (d, sp) = (
                    pass_in(&prep, &order, s, true),
                    pass_in(&prep, &order, s, false),
                );
                assert!(d.of.iter().all(|&c| (c as usize) < d.centres), "{s}");
                assert_eq!((d.of, d.centres), (sp.of, sp.centres), "{s}");
            }
        }
    }
}
