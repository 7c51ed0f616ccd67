//! Candidate vertex pairs for contraction (Garland & Heckbert 1997, §3): two vertices that
//! share no edge but lie closer than `pair_distance` may be contracted like an edge, which
//! joins separate parts. The candidates are chosen once, at the start, from a uniform grid
//! of cell side `pair_distance` (a vertex's partners are in its own cell or the 26 around
//! it), not from all pairs; contractions then rename their ends as edges' ends are renamed.

use glam::DVec3;
use rustc_hash::FxHashMap;

/// At most this many candidate pairs per vertex on average: a larger `pair_distance` is
/// refused (the pairs would grow as the square of the vertices within reach).
pub(crate) const MAX_PAIRS_PER_VERTEX: usize = 16;

/// The grid cell of `p` for cell side `d` (the float-to-int cast saturates).
#[inline]
fn cell(p: DVec3, d: f64) -> [i64; 3] {
    let c = (p / d).floor();
    [c.x as i64, c.y as i64, c.z as i64]
}

/// Pairs (u, v), u < v, of `eligible` vertices closer than `d` (strictly) that `adjacent`
/// does not join, in (u, v) order; `None` when there would be more than `cap`.
pub(crate) fn close_pairs(
    pos: &[DVec3],
    eligible: impl Fn(u32) -> bool,
    adjacent: impl Fn(u32, u32) -> bool,
    d: f64,
    cap: usize,
) -> Option<Vec<[u32; 2]>> {
    let mut order: Vec<([i64; 3], u32)> = (0..pos.len() as u32)
        .filter(|&v| eligible(v))
        .map(|v| (cell(pos[v as usize], d), v))
        .collect();
    order.sort_unstable();
    let mut cells: FxHashMap<[i64; 3], (usize, usize)> = FxHashMap::default();
    let mut i = 0;
    while i < order.len() {
        let j = i + order[i..].iter().take_while(|x| x.0 == order[i].0).count();
        cells.insert(order[i].0, (i, j));
        i = j;
    }
    let mut out = Vec::new();
    let mut near: Vec<u32> = Vec::new();
    let mut by_vertex: Vec<(u32, [i64; 3])> = order.iter().map(|&(c, v)| (v, c)).collect();
    by_vertex.sort_unstable();
    for &(v, c) in &by_vertex {
        near.clear();
        let p = pos[v as usize];
        for dx in -1..=1i64 {
            for dy in -1..=1i64 {
                for dz in -1..=1i64 {
                    let key = [
                        c[0].saturating_add(dx),
                        c[1].saturating_add(dy),
                        c[2].saturating_add(dz),
                    ];
                    // Saturated neighbours may repeat a cell: visit each once.
                    if (dx != 0 && key[0] == c[0])
                        || (dy != 0 && key[1] == c[1])
                        || (dz != 0 && key[2] == c[2])
                    {
                        continue;
                    }
                    let Some(&(s, e)) = cells.get(&key) else {
                        continue;
                    };
                    for &(_, u) in &order[s..e] {
                        if u > v && (pos[u as usize] - p).length() < d && !adjacent(v, u) {
                            near.push(u);
                        }
                    }
                }
            }
        }
        near.sort_unstable();
        if out.len() + near.len() > cap {
            return None;
        }
        out.extend(near.iter().map(|&u| [v, u]));
    }
    Some(out)
}

/// [`close_pairs`] by brute force over all pairs (the twin in the tests).
#[cfg(test)]
pub(crate) fn close_pairs_slow(
    pos: &[DVec3],
    eligible: impl Fn(u32) -> bool,
    adjacent: impl Fn(u32, u32) -> bool,
    d: f64,
) -> Vec<[u32; 2]> {
    let n = pos.len() as u32;
    let mut out = Vec::new();
    for v in 0..n {
        for u in v + 1..n {
            if eligible(v)
                && eligible(u)
                && (pos[u as usize] - pos[v as usize]).length() < d
                && !adjacent(v, u)
            {
                out.push([v, u]);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// The grid finds exactly the pairs the brute-force search finds.
        #[test]
        fn grid_pairs_equal_all_pairs(
            pts in proptest::collection::vec((-3.0f64..3.0, -3.0f64..3.0, -1.0f64..1.0), 0..80),
            d in 0.05f64..2.0,
        ) {
            let pos: Vec<DVec3> = pts.iter().map(|&(x, y, z)| DVec3::new(x, y, z)).collect();
            let eligible = |v: u32| v % 7 != 3;
            let adjacent = |u: u32, v: u32| (u + v).is_multiple_of(5);
            let fast = close_pairs(&pos, eligible, adjacent, d, usize::MAX).unwrap();
            let slow = close_pairs_slow(&pos, eligible, adjacent, d);
            prop_assert_eq!(&fast, &slow);
            if !slow.is_empty() {
                prop_assert!(close_pairs(&pos, eligible, adjacent, d, slow.len() - 1).is_none());
            }
        }
    }
}
