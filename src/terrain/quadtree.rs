//! Röttger quadtree error metrics (SPEC §5; seed 003 §2.4, after Röttger, Heidrich, Slusallek
//! and Seidel 1998, "Real-time generation of continuous levels of detail for height fields").
//!
//! A tile of (2^k + 1)² samples is a quadtree: a node has a centre sample (ci, cj) and an edge
//! length d = 2r samples (d = 2 … 2^k). Its d2 is (1/d) · the largest |Δh| over its four edge
//! midpoints and its centre taken against both diagonals, Δh being the true height minus the
//! mean of the two corners the point lies between. The values are stored at the node centres
//! in one (2^k + 1)² matrix per tile (centres of different levels never coincide).
//!
//! Propagation, bottom-up: d2(node) = max(own d2, K · d2 of every node one level lower that it
//! contains or borders along an edge), K = C / (2 (C − 1)). With it, Röttger's refinement
//! criterion never makes two edge-adjacent leaves differ by more than one level: a node of
//! size d that subdivides forces every size-2d node within distance 2d of its centre to
//! subdivide too (the K above is the value at which the two cases of max(c·d2, 1) meet).
//!
//! Tile borders: nodes that touch a shared border have a *mirror* on the other side (the
//! node of the same size and the same border segment). After each level, every group of
//! mirrors takes the maximum of its values (pairs along an edge, four around a tile corner,
//! and all roots together). This covers the propagation across the border (a node's
//! neighbours' children across the border are its mirror's children) and makes a tile
//! self-sufficient: the d2 of the neighbour node that mesh extraction needs at a border is
//! the d2 of its mirror in this very tile. So an engine can extract crack-free meshes tile by
//! tile from the EXR d2 channels alone.
//!
//! The same machinery, with K = 1 and an exact per-node measure, gives the *vertical error*
//! tree of the view-independent extraction (see [`vertical_error`]).
//!
//! Work is level by level over all tiles (the reconciliation of a level must be done before
//! the next level reads it), parallel over tiles and over node rows; allocation is per level
//! and tile, never per node.

use crate::error::{Error, Result};
use crate::terrain::tiles::TileSet;
use ndarray::Array2;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Röttger's (and libMini's) minimum global resolution C.
pub const DEFAULT_MIN_RESOLUTION_C: f64 = 9.0;

/// `[quadtree]`: the error metric's constants.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct QuadtreeParams {
    /// Röttger's minimum global resolution C (> 2, default 9); K = C / (2 (C − 1)).
    #[serde(default = "default_c")]
    pub min_resolution_c: f64,
}

fn default_c() -> f64 {
    DEFAULT_MIN_RESOLUTION_C
}

impl Default for QuadtreeParams {
    fn default() -> Self {
        QuadtreeParams {
            min_resolution_c: DEFAULT_MIN_RESOLUTION_C,
        }
    }
}

impl QuadtreeParams {
    /// K = C / (2 (C − 1)).
    pub fn k(&self) -> f64 {
        propagation_k(self.min_resolution_c)
    }

    /// Checks C; the error names `quadtree.min_resolution_c`.
    pub fn validate(&self) -> Result<()> {
        let c = self.min_resolution_c;
        if !(c.is_finite() && c > 2.0) {
            return Err(Error::param(
                "quadtree",
                "min_resolution_c",
                c,
                "Röttger's C must be a number > 2 (the paper and libMini use 9)",
            ));
        }
        Ok(())
    }
}

/// K = C / (2 (C − 1)).
pub fn propagation_k(c: f64) -> f64 {
    c / (2.0 * (c - 1.0))
}

/// The d2 matrices of a tile set.
#[derive(Debug, Clone, PartialEq)]
pub struct Quadtree {
    /// Röttger's C the values were propagated with.
    pub c: f64,
    /// K = C / (2 (C − 1)).
    pub k: f64,
    /// One (2^k + 1)² matrix per tile (same order as `TileSet::tiles`), d2 at node centres,
    /// 0 at samples that are no node's centre. Units: height units per sample spacing.
    pub d2: Vec<Array2<f32>>,
}

/// d2 for every node of every tile, propagated and reconciled across tile borders.
pub fn build(set: &TileSet, params: &QuadtreeParams) -> Result<Quadtree> {
    params.validate()?;
    let k = params.k();
    let d2 = propagate(set, k as f32, raw_d2);
    Ok(Quadtree {
        c: params.min_resolution_c,
        k,
        d2,
    })
}

/// The vertical error tree: for each node, an upper bound (in height units) of the vertical
/// distance between any sample inside the node and the node's triangle fan, whichever of its
/// edge midpoints the fan skips; propagated with K = 1 and reconciled like d2. A mesh whose
/// leaves all have a value ≤ t is within t of every sample (see `extract`).
pub fn vertical_error(set: &TileSet) -> Vec<Array2<f32>> {
    propagate(set, 1.0, |h, n, ci, cj, r| {
        round_up(raw_vertical_error(h, n, ci, cj, r))
    })
}

/// The smallest f32 ≥ `v` (so a stored bound never understates).
fn round_up(v: f64) -> f32 {
    let f = v as f32;
    if (f as f64) < v && f.is_finite() {
        if f >= 0.0 {
            f32::from_bits(f.to_bits() + 1)
        } else {
            f32::from_bits(f.to_bits() - 1)
        }
    } else {
        f
    }
}

/// (1/d) · max |Δh| over the 4 edge midpoints and the centre against both diagonals, for the
/// node centred at (ci, cj) with half edge r in an n-wide row-major block. Holes (NaN) drop
/// out of the maximum; a node with nothing to measure gets 0.
#[inline(always)]
pub fn raw_d2(h: &[f32], n: usize, ci: usize, cj: usize, r: usize) -> f32 {
    let s = (cj - r) * n;
    let m = cj * n;
    let t = (cj + r) * n;
    let (sw, so, se) = (h[s + ci - r], h[s + ci], h[s + ci + r]);
    let (w, c, e) = (h[m + ci - r], h[m + ci], h[m + ci + r]);
    let (nw, no, ne) = (h[t + ci - r], h[t + ci], h[t + ci + r]);
    let dh = (so - 0.5 * (sw + se)).abs();
    let dh = dh.max((no - 0.5 * (nw + ne)).abs());
    let dh = dh.max((w - 0.5 * (sw + nw)).abs());
    let dh = dh.max((e - 0.5 * (se + ne)).abs());
    let dh = dh.max((c - 0.5 * (sw + ne)).abs());
    let dh = dh.max((c - 0.5 * (se + nw)).abs());
    if dh.is_nan() {
        0.0
    } else {
        dh / (2 * r) as f32
    }
}

/// Largest vertical distance between a sample of the node (centre (ci, cj), half edge r) and
/// its triangle fan, over both choices (midpoint used or skipped) for each of the 4 edges.
/// The fan's four sections are the triangles centre–corner–corner; a sample belongs to the
/// section it faces (samples on a diagonal lie on a fan edge, where both sections agree).
pub fn raw_vertical_error(h: &[f32], n: usize, ci: usize, cj: usize, r: usize) -> f64 {
    let at = |i: usize, j: usize| h[j * n + i] as f64;
    let hc = at(ci, cj);
    let (sw, se, nw, ne) = (
        at(ci - r, cj - r),
        at(ci + r, cj - r),
        at(ci - r, cj + r),
        at(ci + r, cj + r),
    );
    let (so, no, we, ea) = (
        at(ci, cj - r),
        at(ci, cj + r),
        at(ci - r, cj),
        at(ci + r, cj),
    );
    // (corner at s = −1, corner at s = +1, midpoint) per section: south, north, west, east.
    let sections = [(sw, se, so), (nw, ne, no), (sw, nw, we), (se, ne, ea)];
    let rf = r as f64;
    let ri = r as isize;
    let mut worst = 0.0f64;
    for v in -ri..=ri {
        let row = (cj as isize + v) as usize * n;
        for u in -ri..=ri {
            let z = h[row + (ci as isize + u) as usize] as f64;
            // Which section, and the fan's coordinates in it: t towards the edge, s along it.
            let (sec, t, s) = if v.abs() >= u.abs() {
                if v <= 0 {
                    (0, -v, u)
                } else {
                    (1, v, u)
                }
            } else if u < 0 {
                (2, -u, v)
            } else {
                (3, u, v)
            };
            let (a, b, m) = sections[sec];
            let (t, s) = (t as f64 / rf, s as f64 / rf);
            let whole = hc + t * (0.5 * (a + b) - hc) + s * 0.5 * (b - a);
            let split = hc + t * (m - hc) + s * if s < 0.0 { m - a } else { b - m };
            worst = worst.max((z - whole).abs()).max((z - split).abs());
        }
    }
    worst
}

/// Level-by-level computation shared by d2 and the vertical error: `raw` gives a node's own
/// value; each level then takes the max with `k` × the values one level lower that the node
/// contains or borders (inside the tile), and mirror groups across tile borders take their
/// maximum.
fn propagate<F>(set: &TileSet, k: f32, raw: F) -> Vec<Array2<f32>>
where
    F: Fn(&[f32], usize, usize, usize, usize) -> f32 + Sync,
{
    let n = set.tile_size;
    let levels = set.levels();
    let mut out: Vec<Array2<f32>> = set.tiles.iter().map(|_| Array2::zeros((n, n))).collect();
    for level in 1..=levels {
        let r = 1usize << (level - 1);
        let d = 2 * r;
        let nodes = (n - 1) / d;
        out.par_iter_mut()
            .zip(set.tiles.par_iter())
            .for_each(|(m, tile)| {
                let h = tile
                    .heights
                    .as_slice()
                    .expect("tile heights are contiguous");
                let dst = m.as_slice_mut().expect("matrices are contiguous");
                if level == 1 {
                    // The finest level has no children: write straight into the node rows.
                    dst.par_chunks_mut(n)
                        .enumerate()
                        .skip(1)
                        .step_by(2)
                        .for_each(|(cj, row)| {
                            for ci in (1..n - 1).step_by(2) {
                                row[ci] = raw(h, n, ci, cj, 1);
                            }
                        });
                    return;
                }
                let q = r / 2;
                let src: &[f32] = dst;
                let mut vals = vec![0.0f32; nodes * nodes];
                vals.par_chunks_mut(nodes).enumerate().for_each(|(b, row)| {
                    let cj = r + b * d;
                    for (a, slot) in row.iter_mut().enumerate() {
                        let ci = r + a * d;
                        let at = |i: usize, j: usize| src[j * n + i];
                        // Children.
                        let mut lower = at(ci - q, cj - q)
                            .max(at(ci + q, cj - q))
                            .max(at(ci - q, cj + q))
                            .max(at(ci + q, cj + q));
                        // Children of the edge neighbours that touch this node, inside the tile.
                        if a > 0 {
                            lower = lower
                                .max(at(ci - 3 * q, cj - q))
                                .max(at(ci - 3 * q, cj + q));
                        }
                        if a + 1 < nodes {
                            lower = lower
                                .max(at(ci + 3 * q, cj - q))
                                .max(at(ci + 3 * q, cj + q));
                        }
                        if b > 0 {
                            lower = lower
                                .max(at(ci - q, cj - 3 * q))
                                .max(at(ci + q, cj - 3 * q));
                        }
                        if b + 1 < nodes {
                            lower = lower
                                .max(at(ci - q, cj + 3 * q))
                                .max(at(ci + q, cj + 3 * q));
                        }
                        *slot = raw(h, n, ci, cj, r).max(k * lower);
                    }
                });
                for (b, row) in vals.chunks(nodes).enumerate() {
                    let base = (r + b * d) * n + r;
                    for (a, v) in row.iter().enumerate() {
                        dst[base + a * d] = *v;
                    }
                }
            });
        reconcile(set, &mut out, r);
    }
    out
}

/// Gives every group of mirror nodes of half edge `r` across tile borders their maximum.
fn reconcile(set: &TileSet, m: &mut [Array2<f32>], r: usize) {
    let n = set.tile_size;
    let [gx, gy] = set.grid;
    if gx * gy == 1 {
        return;
    }
    if 2 * r == n - 1 {
        // Roots touch all four borders: all of them form one group.
        let c = n / 2;
        let top = m
            .iter()
            .map(|a| a[[c, c]])
            .fold(f32::NEG_INFINITY, f32::max);
        for a in m.iter_mut() {
            a[[c, c]] = top;
        }
        return;
    }
    let (lo, hi) = (r, n - 1 - r);
    // Shared vertical borders, then shared horizontal ones: the second pass completes the
    // four-node groups around tile corners.
    for row in 0..gy {
        for col in 0..gx - 1 {
            let (ia, ib) = (set.index(col, row), set.index(col + 1, row));
            for cj in (r..n).step_by(2 * r) {
                let v = m[ia][[cj, hi]].max(m[ib][[cj, lo]]);
                m[ia][[cj, hi]] = v;
                m[ib][[cj, lo]] = v;
            }
        }
    }
    for row in 0..gy - 1 {
        for col in 0..gx {
            let (ia, ib) = (set.index(col, row), set.index(col, row + 1));
            for ci in (r..n).step_by(2 * r) {
                let v = m[ia][[hi, ci]].max(m[ib][[lo, ci]]);
                m[ia][[hi, ci]] = v;
                m[ib][[lo, ci]] = v;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::tiles::{tile, TileParams};
    use crate::terrain::{CellState, Heightfield};

    fn field(cols: usize, rows: usize, f: impl Fn(usize, usize) -> f32) -> Heightfield {
        let mut hf = Heightfield::empty(cols, rows, [0.0, 0.0], [1.0, 1.0], 0.0, None);
        for j in 0..rows {
            for i in 0..cols {
                hf.heights[[j, i]] = f(i, j);
                hf.state[[j, i]] = CellState::Measured;
            }
        }
        hf
    }

    #[test]
    fn k_is_roettgers() {
        assert_eq!(QuadtreeParams::default().k(), 0.5625);
        assert!(QuadtreeParams {
            min_resolution_c: 2.0
        }
        .validate()
        .is_err());
        assert!(QuadtreeParams {
            min_resolution_c: f64::NAN
        }
        .validate()
        .is_err());
    }

    #[test]
    fn a_plane_has_no_error() {
        let hf = field(65, 65, |i, j| 3.0 * i as f32 - 2.0 * j as f32);
        let set = tile(
            &hf,
            &TileParams {
                size: Some(65),
                ..Default::default()
            },
        )
        .unwrap();
        let q = build(&set, &QuadtreeParams::default()).unwrap();
        assert!(q.d2[0].iter().all(|v| *v == 0.0));
        assert!(vertical_error(&set)[0].iter().all(|v| *v == 0.0));
    }

    #[test]
    fn a_single_bump_is_seen_at_every_level() {
        // A spike at the centre sample of the root: d2 of the root = spike / 64.
        let hf = field(65, 65, |i, j| if (i, j) == (32, 32) { 64.0 } else { 0.0 });
        let set = tile(
            &hf,
            &TileParams {
                size: Some(65),
                ..Default::default()
            },
        )
        .unwrap();
        let q = build(&set, &QuadtreeParams::default()).unwrap();
        assert_eq!(q.d2[0][[32, 32]], 1.0);
        // For the four d = 2 nodes around it the spike is a corner: their edge midpoints
        // next to it are 32 off the corner mean.
        assert_eq!(q.d2[0][[31, 31]], 16.0);
        let e = vertical_error(&set);
        // The root's fan runs from the spike down to the corners: the samples next to the
        // centre are 64 · 31/32 below it.
        assert_eq!(e[0][[32, 32]], 62.0);
        assert_eq!(e[0][[31, 31]], 32.0);
        // d = 4 below the spike: its east edge, unsplit, runs 0 → 64 over 4 samples, so the
        // sample one below the spike is 48 off.
        assert_eq!(e[0][[30, 30]], 48.0);
    }

    #[test]
    fn round_up_never_understates() {
        for v in [0.1f64, 1.0 / 3.0, 1e-9, 12345.678901, 0.0] {
            assert!(round_up(v) as f64 >= v);
        }
    }
}
