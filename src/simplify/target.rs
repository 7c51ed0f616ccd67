//! Targets of a simplification and the search for the scale parameter that reaches a target
//! triangle count (used by the clustering methods, whose output count is a monotone-ish
//! function of one scale; the collapse engine stops at its target directly).

use rayon::prelude::*;
use rustc_hash::FxHashSet;

/// What a simplification aims at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Target {
    /// About this many output triangles (the closest the method's scale parameter reaches).
    Triangles(u64),
    /// This cell size (uniform, floating) or split threshold (octree).
    Scale(f64),
}
/// Triangles whose three corners have three different keys (the search's estimate of the
/// output count: duplicates are only removed at the end).
pub fn count_surviving<K: PartialEq + Sync>(faces: &[[u32; 3]], key: &[K]) -> usize {
    faces
        .par_iter()
        .with_min_len(16384)
        .filter(|t| {
            let (a, b, c) = (
                &key[t[0] as usize],
                &key[t[1] as usize],
                &key[t[2] as usize],
            );
            a != b && b != c && a != c
        })
        .count()
}

/// Triangles that survive with three different keys, counting a triple of keys once: the
/// output count (before the rare zero-area check).
pub fn count_distinct<K: Copy + Ord + std::hash::Hash>(faces: &[[u32; 3]], key: &[K]) -> usize {
    let mut seen: FxHashSet<[K; 3]> = FxHashSet::default();
    for t in faces {
        let mut k = t.map(|v| key[v as usize]);
        if k[0] == k[1] || k[1] == k[2] || k[0] == k[2] {
            continue;
        }
        k.sort_unstable();
        seen.insert(k);
    }
    seen.len()
}

/// [`search_scale`] on the fast count, then up to two corrections for the duplicate
/// triangles (two sheets collapsing onto the same clusters) the fast count includes: the
/// search is repeated for a target scaled by fast/exact. Returns (scale, evaluations).
pub fn search_target<K: Copy + Ord + std::hash::Hash + Sync>(
    faces: &[[u32; 3]],
    mut keys_at: impl FnMut(f64) -> Vec<K>,
    target: u64,
    start: f64,
    min_scale: f64,
) -> (f64, usize) {
    let mut goal = target.max(1);
    let mut start = start;
    let mut evals = 0;
    let mut best = (start, f64::INFINITY);
    for _round in 0..3 {
        let (s, fast, e) = search_scale(
            |s| count_surviving(faces, &keys_at(s)),
            goal,
            start,
            min_scale,
        );
        evals += e + 1;
        let exact = count_distinct(faces, &keys_at(s));
        let miss = (exact as f64 - target as f64).abs();
        if miss < best.1 {
            best = (s, miss);
        }
        if miss <= 0.01 * target as f64 || exact == 0 || fast == 0 {
            break;
        }
        goal = ((goal as f64 * target as f64 / exact as f64).round() as u64).max(1);
        start = s;
    }
    (best.0, evals)
}

/// Finds the scale parameter (cell size) whose `count` is closest to `target`, assuming the
/// count falls roughly as scale⁻² (a surface cut into cells). Returns (scale, count,
/// evaluations).
pub fn search_scale(
    mut count: impl FnMut(f64) -> usize,
    target: u64,
    start: f64,
    min_scale: f64,
) -> (f64, usize, usize) {
    let t = target.max(1) as f64;
    let mut evals = 0;
    let mut best = (start, usize::MAX, f64::INFINITY);
    let mut eval = |s: f64, best: &mut (f64, usize, f64)| {
        let c = count(s);
        let miss = (c as f64 - t).abs();
        if miss < best.2 || (miss == best.2 && c < best.1) {
            *best = (s, c, miss);
        }
        c
    };
    // Too many triangles at `lo`, too few at `hi`.
    let (mut lo, mut hi) = (None::<f64>, None::<f64>);
    let mut s = start.max(min_scale);
    while evals < 40 {
        let c = eval(s, &mut best);
        evals += 1;
        // Within 0.5 % of the target is as good as exact for a clustering (each pass
        // costs a sweep over the mesh).
        if (c as f64 - t).abs() <= (0.005 * t).max(0.5) {
            break;
        }
        if c as f64 > t {
            lo = Some(lo.map_or(s, |l: f64| l.max(s)));
        } else {
            hi = Some(hi.map_or(s, |h: f64| h.min(s)));
        }
        let next = match (lo, hi) {
            (Some(l), Some(h)) => {
                if h / l < 1.0 + 1e-4 {
                    break;
                }
                (l * h).sqrt()
            }
            _ => {
                let f = ((c.max(1) as f64) / t).sqrt().clamp(0.25, 4.0);
                let f = if (f - 1.0).abs() < 0.02 {
                    if c as f64 > t {
                        1.02
                    } else {
                        0.98
                    }
                } else {
                    f
                };
                s * f
            }
        };
        if next < min_scale {
            if s <= min_scale {
                break;
            }
            s = min_scale;
        } else {
            s = next;
        }
    }
    (best.0, best.1, evals)
}
