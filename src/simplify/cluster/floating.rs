//! Floating-cell clustering (Low & Tan 1997; SPEC §7; seed 000 §II.2). Vertices are weighted
//! by their visual importance w = (longest incident edge) · cos(θ/2), θ the largest angle
//! between two incident edges (the chance to lie on a silhouette). In order of decreasing
//! weight, a vertex no cell holds yet becomes the centre of a new cell — a cube of edge
//! `cell_size` centred on it; finally every vertex joins the nearest centre (Euclidean)
//! among the cells that contain it.
//!
//! Centres are more than half a cell apart (in the max norm), so a hash grid of half-cell
//! buckets holds at most one centre per bucket and a vertex finds every candidate among its
//! 27 neighbouring buckets.

use super::{search_target, uniform, Clustering, Prepared, Target};
use glam::DVec3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;

struct Pass {
    /// Centre index (0.. in creation order) of each active vertex.
    of: Vec<u32>,
    centres: usize,
}

/// Packed half-cell bucket of `p`.
#[inline]
fn bucket(p: DVec3, min: DVec3, inv_h: f64) -> (i64, i64, i64) {
    let c = ((p - min) * inv_h).floor();
    (c.x as i64, c.y as i64, c.z as i64)
}

#[inline]
fn pack(b: (i64, i64, i64)) -> u64 {
    let m = (1u64 << 21) - 1;
    ((b.0 as u64) & m) | (((b.1 as u64) & m) << 21) | (((b.2 as u64) & m) << 42)
}

/// Centres so far, bucketed by half-cell.
struct Centres<'a> {
    prep: &'a Prepared<'a>,
    grid: FxHashMap<u64, u32>,
    list: Vec<u32>,
    min: DVec3,
    h: f64,
    inv_h: f64,
}

impl Centres<'_> {
    #[inline]
    fn pos(&self, d: u32) -> DVec3 {
        self.prep.dense_pos[d as usize].as_dvec3()
    }

    /// Calls `visit(centre index, centre position)` for every centre whose cell holds `p`.
    #[inline]
    fn covering(&self, p: DVec3, mut visit: impl FnMut(u32, DVec3)) {
        let b = bucket(p, self.min, self.inv_h);
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    if let Some(&c) = self.grid.get(&pack((b.0 + dx, b.1 + dy, b.2 + dz))) {
                        let q = self.pos(self.list[c as usize]);
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
    let h = 0.5 * s;
    let mut cs = Centres {
        prep,
        grid: FxHashMap::default(),
        list: Vec::new(),
        min: prep.bounds.min.as_dvec3(),
        h,
        inv_h: 1.0 / h,
    };
    for &v in order {
        let p = cs.pos(v);
        let mut covered = false;
        cs.covering(p, |_, _| covered = true);
        if !covered {
            let key = pack(bucket(p, cs.min, cs.inv_h));
            let next = cs.list.len() as u32;
            cs.grid.insert(key, next);
            cs.list.push(v);
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

/// Clusters `prep` with floating cells: returns the clustering, the cell size and the number
/// of passes made.
pub fn cluster(prep: &Prepared, target: Target) -> (Clustering, f64, usize) {
    let w = prep.weights();
    let mut order: Vec<u32> = (0..prep.active.len() as u32).collect();
    order.par_sort_unstable_by(|&a, &b| {
        w[prep.active[b as usize] as usize]
            .total_cmp(&w[prep.active[a as usize] as usize])
            .then(a.cmp(&b))
    });
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

    #[test]
    fn every_vertex_joins_the_nearest_covering_centre() {
        let m = grid(12);
        let prep = Prepared::new(&m);
        let w = prep.weights();
        let mut order: Vec<u32> = (0..prep.active.len() as u32).collect();
        order.sort_by(|&a, &b| {
            w[prep.active[b as usize] as usize]
                .total_cmp(&w[prep.active[a as usize] as usize])
                .then(a.cmp(&b))
        });
        let s = 0.2;
        let p = pass(&prep, &order, s);
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
}
