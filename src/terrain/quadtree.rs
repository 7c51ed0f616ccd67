//! Röttger quadtree error metrics (Kim & Shin §2.4, after Röttger, Heidrich, Slusallek
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
//! Storage: the interchange form is one (2^k + 1)² matrix per tile with each value at
//! its node's centre (that is what the EXR `d2` channel holds, see [`NodeValues::to_matrix`]).
//! In memory the values are kept level by level ([`NodeValues`]), which is the same data in a
//! third of the space: two thirds of the matrix are samples that are no node's centre, and
//! writing a 4097² matrix costs more in fresh pages than computing d2 does.
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
    /// d2 of every node, one [`NodeValues`] per tile (same order as `TileSet::tiles`).
    /// Units: height units per sample spacing.
    pub d2: Vec<NodeValues>,
}

/// One value per quadtree node of a (2^k + 1)² tile, stored level by level: level m (node
/// edge 2^m samples, m = 1 … k) holds ((2^k) / 2^m)² values, row-major from the south-west
/// node. The node of level m at (a, b) has its centre at sample (r + 2ra, r + 2rb), r = 2^(m−1).
#[derive(Debug, Clone, PartialEq)]
pub struct NodeValues {
    size: usize,
    levels: Vec<Vec<f32>>,
}

impl NodeValues {
    /// All zero, for a tile of `size` = 2^k + 1 samples.
    pub fn zeros(size: usize) -> NodeValues {
        let k = (size - 1).trailing_zeros();
        let levels = (1..=k)
            .map(|m| vec![0.0; ((size - 1) >> m).pow(2)])
            .collect();
        NodeValues { size, levels }
    }

    /// The values of a tile of `size` = 2^k + 1 samples from its levels 1…k (as
    /// [`level`](Self::level) gives them); None when their number or lengths do not fit.
    pub fn from_levels(size: usize, levels: Vec<Vec<f32>>) -> Option<NodeValues> {
        let z = Self::zeros(size);
        let fits = z.levels.len() == levels.len()
            && z.levels
                .iter()
                .zip(&levels)
                .all(|(a, b)| a.len() == b.len());
        fits.then_some(NodeValues { size, levels })
    }

    /// Samples per tile side.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Nodes per side at level m (1-based).
    pub fn nodes(&self, level: u32) -> usize {
        (self.size - 1) >> level
    }

    /// The values of level m (1-based), row-major from the south-west.
    pub fn level(&self, level: u32) -> &[f32] {
        &self.levels[level as usize - 1]
    }

    /// The value of the node centred at sample (ci, cj); 0 if no node is centred there.
    #[inline]
    pub fn get(&self, ci: usize, cj: usize) -> f32 {
        let tz = ci.trailing_zeros();
        if ci == 0
            || cj == 0
            || tz != cj.trailing_zeros()
            || ci >= self.size - 1
            || cj >= self.size - 1
        {
            return 0.0;
        }
        let nodes = (self.size - 1) >> (tz + 1);
        self.levels[tz as usize][(cj >> (tz + 1)) * nodes + (ci >> (tz + 1))]
    }

    fn set(&mut self, ci: usize, cj: usize, v: f32) {
        let tz = ci.trailing_zeros();
        let nodes = (self.size - 1) >> (tz + 1);
        self.levels[tz as usize][(cj >> (tz + 1)) * nodes + (ci >> (tz + 1))] = v;
    }

    /// The interchange matrix: `[row j, col i]`, each value at its node's centre, 0 elsewhere.
    pub fn to_matrix(&self) -> Array2<f32> {
        let mut m = Array2::zeros((self.size, self.size));
        self.for_each(|ci, cj, v| m[[cj, ci]] = v);
        m
    }

    /// Calls `f(ci, cj, value)` for every node.
    pub fn for_each(&self, mut f: impl FnMut(usize, usize, f32)) {
        for (idx, vals) in self.levels.iter().enumerate() {
            let r = 1usize << idx;
            let nodes = (self.size - 1) / (2 * r);
            for (k, v) in vals.iter().enumerate() {
                f(r + 2 * r * (k % nodes), r + 2 * r * (k / nodes), *v);
            }
        }
    }
}

/// d2 for every node of every tile, propagated and reconciled across tile borders.
pub fn build(set: &TileSet, params: &QuadtreeParams) -> Result<Quadtree> {
    params.validate()?;
    let k = params.k();
    let d2 = propagate(set, k as f32, raw_d2_row);
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
pub fn vertical_error(set: &TileSet) -> Vec<NodeValues> {
    propagate(set, 1.0, |h, n, r, cj, _, out| {
        for (a, slot) in out.iter_mut().enumerate() {
            *slot = round_up(raw_vertical_error(h, n, r + 2 * r * a, cj, r));
        }
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

/// [`raw_d2`] of every node of half edge r in the node row centred on sample row `cj`
/// (one function for the whole row, so that the loop is compiled as one).
/// `nan_free` promises that `h` holds no NaN (a tile without holes).
pub fn raw_d2_row(h: &[f32], n: usize, r: usize, cj: usize, nan_free: bool, out: &mut [f32]) {
    let (s, m, t) = (
        &h[(cj - r) * n..][..n],
        &h[cj * n..][..n],
        &h[(cj + r) * n..][..n],
    );
    // Without NaN a plain comparison is the same maximum, and one instruction instead of
    // f32::max's NaN handling. The two finest levels (four fifths of all nodes) get their
    // stride as a constant, which lets the compiler drop the bounds checks.
    let plain = |a: f32, b: f32| if a >= b { a } else { b };
    match (r, nan_free) {
        (1, true) => d2_row_kernel::<1>(s, m, t, 1, out, plain),
        (2, true) => d2_row_kernel::<2>(s, m, t, 2, out, plain),
        (_, true) => d2_row_kernel::<0>(s, m, t, r, out, plain),
        (_, false) => d2_row_kernel::<0>(s, m, t, r, out, f32::max),
    }
}

/// The d2 row loop; `R` > 0 is the half edge as a constant, 0 means "use `r`".
#[inline(always)]
fn d2_row_kernel<const R: usize>(
    s: &[f32],
    m: &[f32],
    t: &[f32],
    r: usize,
    out: &mut [f32],
    max: impl Fn(f32, f32) -> f32,
) {
    let r = if R > 0 { R } else { r };
    let d = 2 * r;
    let len = out.len() * d + 1;
    let (s, m, t) = (&s[..len], &m[..len], &t[..len]);
    // d is a power of two: multiplying by 1/d is exact, as dividing is.
    let inv = 1.0 / d as f32;
    for (a, slot) in out.iter_mut().enumerate() {
        let (i0, i1, i2) = (a * d, a * d + r, a * d + d);
        let (sw, so, se) = (s[i0], s[i1], s[i2]);
        let (w, c, e) = (m[i0], m[i1], m[i2]);
        let (nw, no, ne) = (t[i0], t[i1], t[i2]);
        let dh = (so - 0.5 * (sw + se)).abs();
        let dh = max(dh, (no - 0.5 * (nw + ne)).abs());
        let dh = max(dh, (w - 0.5 * (sw + nw)).abs());
        let dh = max(dh, (e - 0.5 * (se + ne)).abs());
        let dh = max(dh, (c - 0.5 * (sw + ne)).abs());
        let dh = max(dh, (c - 0.5 * (se + nw)).abs());
        *slot = if dh.is_nan() { 0.0 } else { dh * inv };
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
fn propagate<F>(set: &TileSet, k: f32, raw: F) -> Vec<NodeValues>
where
    F: Fn(&[f32], usize, usize, usize, bool, &mut [f32]) + Sync,
{
    let n = set.tile_size;
    let mut out: Vec<NodeValues> = set.tiles.iter().map(|_| NodeValues::zeros(n)).collect();
    // Levels 1 and 2 in one pass over the heights (they are nearly all the work, and memory
    // bound): level 1 has no children, and level 2 reads level-1 rows still in cache.
    // Reconciling level 1 after level 2 gives the same values as before it: a level-1 node
    // on a border is a child or bordering child of level-2 nodes on the same border, whose
    // mirror groups then take the maximum over the level-1 node's mirrors too.
    out.par_iter_mut()
        .zip(set.tiles.par_iter())
        .for_each(|(m, tile)| {
            let h = tile.height_slice();
            let (l1, rest) = m.levels.split_at_mut(1);
            fused_levels_1_2(&raw, h, n, k, tile.holes == 0, &mut l1[0], &mut rest[0]);
        });
    reconcile(set.grid, n, &mut out, 1);
    reconcile(set.grid, n, &mut out, 2);
    let heights = |t: usize| (set.tiles[t].height_slice(), set.tiles[t].holes == 0);
    close_levels(set.grid, n, k, 3, &mut out, heights, &raw);
    out
}

/// Levels `from`… of the propagation: each node takes max(own, `k` × the nodes one level
/// lower that it contains or borders), its own value written first by `raw` from the tile's
/// heights (`heights(t)`: the tile's samples and whether they are NaN-free); then mirror
/// groups take their maximum.
fn close_levels<'h, F, H>(
    grid: [usize; 2],
    n: usize,
    k: f32,
    from: u32,
    out: &mut [NodeValues],
    heights: H,
    raw: &F,
) where
    F: Fn(&[f32], usize, usize, usize, bool, &mut [f32]) + Sync,
    H: Fn(usize) -> (&'h [f32], bool) + Sync,
{
    let levels = (n - 1).trailing_zeros();
    for level in from..=levels {
        let r = 1usize << (level - 1);
        let nodes = (n - 1) / (2 * r);
        out.par_iter_mut().enumerate().for_each(|(t, m)| {
            let (h, nan_free) = heights(t);
            let (lower, rest) = m.levels.split_at_mut(level as usize - 1);
            // Level m − 1 has 2 × nodes per side: children of (a, b) are (2a.., 2b..).
            let low: &[f32] = &lower[level as usize - 2];
            let ln = 2 * nodes;
            rest[0]
                .par_chunks_mut(nodes)
                .enumerate()
                .for_each(|(b, row)| {
                    let y = |k: usize| &low[k * ln..(k + 1) * ln];
                    let below = (b > 0).then(|| y(2 * b - 1));
                    let above = (b + 1 < nodes).then(|| y(2 * b + 2));
                    parent_row(
                        raw,
                        h,
                        n,
                        r,
                        b,
                        k,
                        nan_free,
                        below,
                        y(2 * b),
                        y(2 * b + 1),
                        above,
                        row,
                    );
                });
        });
        reconcile(grid, n, out, r);
    }
}

/// Finishes the propagation of node values computed on parts of a tile grid (shards of
/// whole tiles, each propagated and reconciled on its own by [`build`] or
/// [`vertical_error`]): `values` holds every tile of the `grid`, row by row from the south,
/// and `k` is the propagation factor they were computed with (K for d2, 1 for the vertical
/// error). Propagation is a max-plus closure, monotone and idempotent, and the shards'
/// values lie between the raw values and the global result, so propagating them once more,
/// each node's own value taken from `values` instead of from the heights, gives exactly the
/// values [`build`] computes on the whole grid: the same maxima of the same f32 products.
pub fn merge(grid: [usize; 2], k: f32, values: &mut [NodeValues]) {
    let Some(n) = values.first().map(|v| v.size) else {
        return;
    };
    debug_assert_eq!(values.len(), grid[0] * grid[1]);
    reconcile(grid, n, values, 1);
    // The own value is the shard's, already in place: nothing to compute from heights.
    close_levels(
        grid,
        n,
        k,
        2,
        values,
        |_| (&[][..], true),
        &|_, _, _, _, _, _| {},
    );
}

/// Level-2 rows computed per block, each block a sequential band over the heights.
const FUSED_BLOCK: usize = 16;

/// Levels 1 and 2 of one tile; `l1`, `l2` are the level arrays (row-major, south first).
fn fused_levels_1_2<F>(
    raw: &F,
    h: &[f32],
    n: usize,
    k: f32,
    nan_free: bool,
    l1: &mut [f32],
    l2: &mut [f32],
) where
    F: Fn(&[f32], usize, usize, usize, bool, &mut [f32]) + Sync,
{
    let n1 = (n - 1) / 2;
    let n2 = n1 / 2;
    let level1_row = |b1: usize, out: &mut [f32]| raw(h, n, 1, 1 + 2 * b1, nan_free, out);
    l2.par_chunks_mut(n2 * FUSED_BLOCK)
        .zip(l1.par_chunks_mut(2 * n1 * FUSED_BLOCK))
        .enumerate()
        .for_each(|(blk, (l2b, l1b))| {
            let b0 = blk * FUSED_BLOCK;
            // Level-1 rows 2b − 1 (below) and 2b + 2 (above) of level-2 row b; at the block's
            // edges they belong to the neighbouring block and are computed again here.
            let mut below = vec![0.0f32; n1];
            let mut above = vec![0.0f32; n1];
            if b0 > 0 {
                level1_row(2 * b0 - 1, &mut below);
            }
            for (bb, row2) in l2b.chunks_mut(n2).enumerate() {
                let b = b0 + bb;
                let (r0, r1) = l1b[2 * bb * n1..(2 * bb + 2) * n1].split_at_mut(n1);
                if bb > 0 {
                    r0.copy_from_slice(&above);
                } else {
                    level1_row(2 * b, r0);
                }
                level1_row(2 * b + 1, r1);
                let has_above = b + 1 < n2;
                if has_above {
                    level1_row(2 * b + 2, &mut above);
                }
                let lo = (b > 0).then_some(&below[..]);
                let hi = has_above.then_some(&above[..]);
                parent_row(raw, h, n, 2, b, k, nan_free, lo, r0, r1, hi, row2);
                below.copy_from_slice(r1);
            }
        });
}

/// One row b of nodes of half edge r: own value, max with k × the children (level-1 rows
/// `y0`, `y1` of the level below) and the children of the edge neighbours (same rows left and
/// right; rows `below` and `above` down and up, when inside the tile).
#[allow(clippy::too_many_arguments)]
#[inline]
fn parent_row<F>(
    raw: &F,
    h: &[f32],
    n: usize,
    r: usize,
    b: usize,
    k: f32,
    nan_free: bool,
    below: Option<&[f32]>,
    y0: &[f32],
    y1: &[f32],
    above: Option<&[f32]>,
    out: &mut [f32],
) where
    F: Fn(&[f32], usize, usize, usize, bool, &mut [f32]),
{
    let nodes = out.len();
    let d = 2 * r;
    raw(h, n, r, r + b * d, nan_free, out);
    // Node values are never NaN and never negative (a node without data is 0): a plain
    // comparison is max, and 0 is its neutral element.
    let mx = |a: f32, b: f32| if a >= b { a } else { b };
    let w = 2 * nodes;
    let (y0, y1) = (&y0[..w], &y1[..w]);
    // Per column of the level below: the max of the two child rows, and of the rows below
    // and above (the bordering children of the neighbours down and up).
    let col: Vec<f32> = y0.iter().zip(y1).map(|(a, b)| mx(*a, *b)).collect();
    let mut vert = vec![0.0f32; w];
    for rows in [below, above].into_iter().flatten() {
        for (v, x) in vert.iter_mut().zip(&rows[..w]) {
            *v = mx(*v, *x);
        }
    }
    for (a, slot) in out.iter_mut().enumerate() {
        let x = 2 * a;
        let left = if a > 0 { col[x - 1] } else { 0.0 };
        let right = if x + 2 < w { col[x + 2] } else { 0.0 };
        let m = mx(
            mx(mx(col[x], col[x + 1]), mx(left, right)),
            mx(vert[x], vert[x + 1]),
        );
        *slot = mx(*slot, k * m);
    }
}

/// Gives every group of mirror nodes of half edge `r` across tile borders their maximum.
fn reconcile(grid: [usize; 2], n: usize, m: &mut [NodeValues], r: usize) {
    let [gx, gy] = grid;
    let index = |col: usize, row: usize| row * gx + col;
    if gx * gy == 1 {
        return;
    }
    if 2 * r == n - 1 {
        // Roots touch all four borders: all of them form one group.
        let c = n / 2;
        let top = m
            .iter()
            .map(|a| a.get(c, c))
            .fold(f32::NEG_INFINITY, f32::max);
        for a in m.iter_mut() {
            a.set(c, c, top);
        }
        return;
    }
    let (lo, hi) = (r, n - 1 - r);
    // Shared vertical borders, then shared horizontal ones: the second pass completes the
    // four-node groups around tile corners.
    for row in 0..gy {
        for col in 0..gx - 1 {
            let (ia, ib) = (index(col, row), index(col + 1, row));
            for cj in (r..n).step_by(2 * r) {
                let v = m[ia].get(hi, cj).max(m[ib].get(lo, cj));
                m[ia].set(hi, cj, v);
                m[ib].set(lo, cj, v);
            }
        }
    }
    for row in 0..gy - 1 {
        for col in 0..gx {
            let (ia, ib) = (index(col, row), index(col, row + 1));
            for ci in (r..n).step_by(2 * r) {
                let v = m[ia].get(ci, hi).max(m[ib].get(ci, lo));
                m[ia].set(ci, hi, v);
                m[ib].set(ci, lo, v);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::testutil::{field, tiles_of};

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
        let set = tiles_of(&hf, 65);
        let q = build(&set, &QuadtreeParams::default()).unwrap();
        assert!(q.d2[0].to_matrix().iter().all(|v| *v == 0.0));
        assert!(vertical_error(&set)[0]
            .to_matrix()
            .iter()
            .all(|v| *v == 0.0));
    }

    #[test]
    fn a_single_bump_is_seen_at_every_level() {
        // A spike at the centre sample of the root: d2 of the root = spike / 64.
        let hf = field(65, 65, |i, j| if (i, j) == (32, 32) { 64.0 } else { 0.0 });
        let set = tiles_of(&hf, 65);
        let q = build(&set, &QuadtreeParams::default()).unwrap();
        assert_eq!(q.d2[0].get(32, 32), 1.0);
        // For the four d = 2 nodes around it the spike is a corner: their edge midpoints
        // next to it are 32 off the corner mean.
        assert_eq!(q.d2[0].get(31, 31), 16.0);
        let e = vertical_error(&set);
        // The root's fan runs from the spike down to the corners: the samples next to the
        // centre are 64 · 31/32 below it.
        assert_eq!(e[0].get(32, 32), 62.0);
        assert_eq!(e[0].get(31, 31), 32.0);
        // d = 4 below the spike: its east edge, unsplit, runs 0 → 64 over 4 samples, so the
        // sample one below the spike is 48 off.
        assert_eq!(e[0].get(30, 30), 48.0);
    }

    #[test]
    fn node_values_index_like_the_matrix() {
        let mut v = NodeValues::zeros(65);
        let mut k = 0.0;
        let mut centres = Vec::new();
        for m in 1..=6u32 {
            let r = 1usize << (m - 1);
            for cj in (r..64).step_by(2 * r) {
                for ci in (r..64).step_by(2 * r) {
                    k += 1.0;
                    v.set(ci, cj, k);
                    centres.push((ci, cj, k));
                }
            }
        }
        let m = v.to_matrix();
        for (ci, cj, k) in centres {
            assert_eq!(v.get(ci, cj), k);
            assert_eq!(m[[cj, ci]], k);
        }
        assert_eq!(
            m.iter().filter(|x| **x != 0.0).count(),
            v.levels.iter().map(Vec::len).sum::<usize>()
        );
        assert_eq!(v.get(0, 5), 0.0);
        assert_eq!(v.get(2, 4), 0.0);
        assert_eq!(v.get(64, 64), 0.0);
    }

    #[test]
    fn round_up_never_understates() {
        for v in [0.1f64, 1.0 / 3.0, 1e-9, 12345.678901, 0.0] {
            assert!(round_up(v) as f64 >= v);
        }
    }
}
