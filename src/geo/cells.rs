//! Dense tiles of the most detailed level: where the tolerance needs (nearly) every sample of
//! the grid, a tile's mesh is the grid's own cells inside its footprint, triangulated
//! directly, with no Delaunay triangulation and no greedy loop.
//!
//! A grid cell's bilinear surface G = a + bx + cy + d·xy (x, y ∈ [0, 1], d the cell's twist
//! z00 − z10 − z01 + z11) minus the linear interpolant of its values on any triangle inside
//! the cell is d·(xy − L(xy)): harmonic, so largest on the triangle's edges, where it is
//! d·t(1 − t)·Δx·Δy, at most |d|·|ΔxΔy|/4 ≤ |d|/4. So:
//! - the two triangles of a cell (either diagonal) are within |d|/4 of G; the diagonal taken
//!   joins the two corners of nearer heights (it follows a ridge or a valley);
//! - four triangles around the cell's centre (on G: the mean of its corners) are within |d|/16;
//! - a cell twisted more than that takes concentric rings. In general a triangle inside the
//!   cell is within |d|·max|ΔxΔy|/4 of G, the largest over its three edges (on an edge
//!   G − L = d·ΔxΔy·t(1 − t)): edges along the grid's axes cost nothing. So for edges within
//!   s = 4·tolerance/|d|, a ring of width e = 2s/a inside a square of side a (the cell,
//!   a = 1, first) joins the square to the one inside it, whose corners and side midpoints
//!   are the ring's eight new vertices: per side a triangle from the side (or its two halves)
//!   to the inner midpoint (edges a/2 × e) and two to the inner corners (e × e, and an axis
//!   edge); rings follow until the inner square's fan around its centre holds (a²/4 ≤ s).
//!   A square whose inner midpoints alone hold, with triangles from each corner to the two
//!   nearest of them ((a/2 − e)² ≤ s), ends in that diamond (split north–south) instead.
//!   The cell's sides stay whole (no T-junctions) and the pattern is chosen by the closed
//!   form, no search: a twist of up to 40 times the tolerance takes 4 vertices (the
//!   diamond), of 64 times 12 (a ring and a diamond). Such a cell's triangles are then
//!   measured exactly at their quantized vertices (the greedy insertion's measure) instead
//!   of carrying the margin below, which on steep cells (tree edges: 20 m over a cell) is
//!   nearly half of a 0.5 m tolerance; the fan around the centre too, for a cell whose fan
//!   failed only by its margin. Beyond `MAX_RINGS`, or when a triangle fails that measure
//!   or quantisation turns it, the greedy insertion of `tin::refine` takes the cell alone.
//!
//! Vertices sit on the tile's quantized positions (1/32767 of the tile), each at G's height
//! there, so a vertex is up to δ (about a thousandth of a cell) from its grid node. A triangle
//! through such moved vertices is within (bound) + 2·g·δ of G, g the largest slope of G around
//! the cell (the moved triangle is within δ of the unmoved one, and G and the interpolant
//! both change by at most g·δ over δ): that margin is added to every bound.
//!
//! The tile's border: the grid is turned against the tile (1.8° at Autzen), so the cells
//! along a side are cut by it. A dense side carries a vertex at each crossing of a grid line
//! (and where a grid node lies within 1.5 quanta of the side, its projection: the node is
//! then moved onto the side, in both tiles alike), computed from the side alone, so both
//! tiles sharing it take the same list. A cut cell is clipped against the tile's sides
//! (Sutherland–Hodgman), each crossing being looked up in the side's list, and its piece
//! (convex: a cell cut by lines) is fanned when the cell's |d|/4 bound holds (with a wider
//! margin: side vertices may be merged a few quanta away from their crossing), else refined
//! greedily like a twisted cell.
//!
//! Hand-written: no crate clips a grid against a tile whose sides are shared vertex lists,
//! and the closed-form bounds are what make the cells cheap.

use crate::geo::tin::{self, SideVertex, Surface, TileMap, TileTin, Q};

/// Quanta within which a side's crossings merge into one vertex.
const MERGE: u16 = 3;
/// Distance from a side (quanta of that side) within which a grid node counts as on it.
const NEAR: f64 = 1.5;
/// Vertices a twisted cell may take by greedy refinement (a guard: the exact measure needs
/// far fewer).
const CELL_VERTICES: usize = 256;
/// Rings a twisted cell may take (see `Tile::rings`) before the greedy refinement takes it:
/// eight vertices each; a twist of 200 times the tolerance needs 6.
const MAX_RINGS: usize = 12;
/// Share of the closed-form budget a twisted cell's pattern is chosen for: the rest is left
/// for the vertices' quantisation, and the pattern is then measured exactly.
const SLACK: f64 = 0.95;

/// A side of the dense tiles: its vertices and how to find the one a crossing merged into.
#[derive(Debug, Clone)]
pub struct DenseSide {
    /// The side's vertices, sorted along it (first and last its corners).
    pub verts: Vec<SideVertex>,
    /// The side's ends in grid coordinates (the straight line the crossings are taken on).
    p0: [f64; 2],
    p1: [f64; 2],
    /// Grid units within which a node is on the side.
    near: f64,
    /// Every crossing or projected node (quantized position along the side), sorted, with
    /// the index in `verts` of the vertex it merged into. Empty for a side simplified in
    /// one dimension only (`tin::side_vertices`), which no dense tile uses.
    marks: Vec<(u16, u32)>,
}

/// `a + λ(b − a)` where the signed distances `sa` and `sb` of `a` and `b` to a line vanish.
fn crossing(a: [f64; 2], sa: f64, b: [f64; 2], sb: f64) -> [f64; 2] {
    let l = sa / (sa - sb);
    [a[0] + l * (b[0] - a[0]), a[1] + l * (b[1] - a[1])]
}

impl DenseSide {
    /// A side simplified in one dimension (between two tiles that are not dense).
    pub fn simple<S: Surface>(s: &S, line: &[[f64; 2]], tolerance: f64) -> DenseSide {
        DenseSide {
            verts: tin::side_vertices(s, line, tolerance),
            p0: line[0],
            p1: line[tin::M],
            near: 0.0,
            marks: Vec::new(),
        }
    }

    /// The side through `line` (its `M + 1` projected points) with a vertex at every crossing
    /// of a grid line and at the projection of every grid node within `NEAR` quanta of it,
    /// those within `MERGE` quanta of each other merged, and the pieces between them
    /// simplified within `tolerance` as `tin::side_vertices` does.
    pub fn dense<S: Surface>(s: &S, line: &[[f64; 2]], tolerance: f64) -> DenseSide {
        let (p0, p1) = (line[0], line[tin::M]);
        let len = ((p1[0] - p0[0]).powi(2) + (p1[1] - p0[1]).powi(2)).sqrt();
        let mut side = DenseSide {
            verts: Vec::new(),
            p0,
            p1,
            near: NEAR * len / f64::from(Q),
            marks: Vec::new(),
        };
        let [cols, rows] = s.size().map(|n| n as i64 - 1);
        let lo = |a: f64, b: f64| ((a.min(b) - 2.0).floor() as i64).max(0);
        let hi = |a: f64, b: f64, n: i64| ((a.max(b) + 2.0).ceil() as i64).min(n);
        let (i0, i1) = (lo(p0[0], p1[0]), hi(p0[0], p1[0], cols));
        let (j0, j1) = (lo(p0[1], p1[1]), hi(p0[1], p1[1], rows));
        let mut ks: Vec<u16> = vec![0, Q];
        let round = |tq: f64| tq.round().clamp(0.0, f64::from(Q)) as u16;
        for j in j0..=j1 {
            for i in i0..=i1 {
                let a = [i as f64, j as f64];
                let (ca, sa, tq) = side.class(a, 1.0);
                if ca == 0 {
                    ks.push(round(tq));
                    continue;
                }
                for b in [[a[0] + 1.0, a[1]], [a[0], a[1] + 1.0]] {
                    if b[0] > i1 as f64 || b[1] > j1 as f64 {
                        continue;
                    }
                    let (cb, sb, _) = side.class(b, 1.0);
                    if ca * cb == -1 {
                        let (_, t) = side.place(crossing(a, sa, b, sb));
                        if (0.0..=f64::from(Q)).contains(&t) {
                            ks.push(round(t));
                        }
                    }
                }
            }
        }
        ks.sort_unstable();
        ks.dedup();
        // Chains of marks closer than MERGE become one vertex: the chain's end at a corner,
        // else its first mark.
        let mut reps: Vec<u16> = Vec::new();
        let mut chain_of: Vec<usize> = Vec::with_capacity(ks.len());
        for (n, &k) in ks.iter().enumerate() {
            if n == 0 || k - ks[n - 1] >= MERGE {
                reps.push(k);
            } else if k == Q {
                *reps.last_mut().expect("a chain") = Q;
            }
            chain_of.push(reps.len() - 1);
        }
        side.verts = tin::side_vertices_through(s, line, &reps, tolerance);
        side.marks = ks
            .iter()
            .zip(&chain_of)
            .map(|(&k, &c)| {
                let at = side.verts.partition_point(|v| v.k < reps[c]);
                (k, at as u32)
            })
            .collect();
        side
    }

    /// Signed distance of `x` to the side's line (grid units, positive to the left of its
    /// direction) and position along it (quanta from its first end).
    fn place(&self, x: [f64; 2]) -> (f64, f64) {
        let (p0, p1) = (self.p0, self.p1);
        let d = [p1[0] - p0[0], p1[1] - p0[1]];
        let r = [x[0] - p0[0], x[1] - p0[1]];
        let len2 = d[0] * d[0] + d[1] * d[1];
        (
            (d[0] * r[1] - d[1] * r[0]) / len2.sqrt(),
            (d[0] * r[0] + d[1] * r[1]) / len2 * f64::from(Q),
        )
    }

    /// Which side of the line the grid node at `x` is on, for a tile whose inside is on the
    /// side `sign` (+1 left, −1 right): 1 inside, −1 outside, 0 on the side (within `near`
    /// and along its span); with the signed distance (positive inside) and the position
    /// along the side. The one classification both the side's marks and the tiles' clipping
    /// use.
    fn class(&self, x: [f64; 2], sign: f64) -> (i32, f64, f64) {
        let (sd, tq) = self.place(x);
        let span = -f64::from(MERGE)..=f64::from(Q) + f64::from(MERGE);
        let left = if sd.abs() < self.near && span.contains(&tq) {
            0
        } else if sd >= 0.0 {
            1
        } else {
            -1
        };
        (left * sign as i32, sd * sign, tq)
    }

    /// Index in `verts` of the vertex the crossing at `tq` quanta along the side merged
    /// into; None beyond the side's ends (a point the neighbouring side clips away).
    fn lookup(&self, tq: f64) -> Option<usize> {
        let m = f64::from(MERGE);
        if self.marks.is_empty() || !(-m..=f64::from(Q) + m).contains(&tq) {
            return None;
        }
        let at = self.marks.partition_point(|x| f64::from(x.0) < tq);
        let best = match (at.checked_sub(1), self.marks.get(at)) {
            (Some(b), Some(a)) => {
                if tq - f64::from(self.marks[b].0) <= f64::from(a.0) - tq {
                    b
                } else {
                    at
                }
            }
            (Some(b), None) => b,
            (None, _) => at,
        };
        Some(self.marks[best].1 as usize)
    }
}

/// A vertex of a piece being clipped.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Id {
    /// Grid node (column, row).
    Node(i64, i64),
    /// Side `s`'s vertex (not a corner).
    Side(usize, usize),
    /// Tile corner: 0 south-west, 1 south-east, 2 north-west, 3 north-east.
    Corner(usize),
    /// A crossing beyond a side's ends, which another side clips away.
    Free([f64; 2]),
}

/// The corners at the ends of the sides south, east, west, north (each running west → east
/// or south → north).
const ENDS: [[usize; 2]; 4] = [[0, 1], [1, 3], [0, 2], [2, 3]];
/// Which side (left +1, right −1) of each side's direction the tile lies on, for a grid whose
/// axes have the tile's orientation.
const INSIDE: [f64; 4] = [1.0, 1.0, -1.0, -1.0];

/// A tile being built.
struct Tile<'a, S: Surface> {
    s: &'a S,
    map: &'a TileMap,
    sides: [&'a DenseSide; 4],
    inside: [f64; 4],
    out: TileTin,
    /// Tile vertex of each side's vertices.
    side_vertex: [Vec<u32>; 4],
    /// The node block [i0, i1] × [j0, j1].
    i0: i64,
    j0: i64,
    w: i64,
    /// Per node of the block: its vertex (u32::MAX: none yet).
    node_vertex: Vec<u32>,
    /// Per node of the block: the largest height step to a 4-neighbour, metres.
    step: Vec<f64>,
    /// The affine approximation of the map's inverse: centre and inverse Jacobian.
    centre: [f64; 2],
    inv: [[f64; 2]; 2],
    /// Largest move of a vertex from its ideal position (grid units): half a quantum along
    /// u and v, doubled for the map's inverse.
    delta: f64,
    /// The same for the side vertices, which may merge `MERGE` quanta away.
    delta_side: f64,
    aspect: f64,
    tolerance: f64,
    /// Whether the grid's axes turn the other way from the tile's.
    flipped: bool,
}

impl<S: Surface> Tile<'_, S> {
    fn pos(&self, v: Id) -> [f64; 2] {
        match v {
            Id::Node(i, j) => [i as f64, j as f64],
            Id::Side(s, k) => self.sides[s].verts[k].p,
            Id::Corner(c) => {
                let (s, end) = [(0, 0), (0, 1), (3, 0), (3, 1)][c];
                let v = &self.sides[s].verts;
                if end == 0 {
                    v[0].p
                } else {
                    v[v.len() - 1].p
                }
            }
            Id::Free(p) => p,
        }
    }

    /// Position of `v` along side `s` (quanta) when `v` is on it.
    fn on_side(&self, v: Id, s: usize) -> Option<u16> {
        match v {
            Id::Side(t, k) if t == s => Some(self.sides[s].verts[k].k),
            Id::Corner(c) if c == ENDS[s][0] => Some(0),
            Id::Corner(c) if c == ENDS[s][1] => Some(Q),
            _ => None,
        }
    }

    /// The id of side `s`'s vertex `k`.
    fn side_id(&self, s: usize, k: usize) -> Id {
        if k == 0 {
            Id::Corner(ENDS[s][0])
        } else if k + 1 == self.sides[s].verts.len() {
            Id::Corner(ENDS[s][1])
        } else {
            Id::Side(s, k)
        }
    }

    /// `poly` clipped against side `s` into `out`.
    fn clip(&self, poly: &[Id], s: usize, out: &mut Vec<Id>) {
        let side = self.sides[s];
        let sign = self.inside[s];
        out.clear();
        let cls: Vec<(i32, f64, Id)> = poly
            .iter()
            .map(|&v| {
                if self.on_side(v, s).is_some() {
                    return (0, 0.0, v);
                }
                let x = self.pos(v);
                let (c, sd, tq) = side.class(x, sign);
                match v {
                    Id::Node(..) if c == 0 => match side.lookup(tq) {
                        Some(k) => (0, sd, self.side_id(s, k)),
                        None => (if sd >= 0.0 { 1 } else { -1 }, sd, v),
                    },
                    Id::Node(..) => (c, sd, v),
                    _ => (if sd >= 0.0 { 1 } else { -1 }, sd, v),
                }
            })
            .collect();
        let n = poly.len();
        for k in 0..n {
            let (ca, sa, va) = cls[k];
            let (cb, sb, _) = cls[(k + 1) % n];
            if ca >= 0 {
                out.push(va);
            }
            if ca * cb == -1 {
                let x = crossing(self.pos(poly[k]), sa, self.pos(poly[(k + 1) % n]), sb);
                let (_, tq) = side.place(x);
                out.push(match side.lookup(tq) {
                    Some(k) => self.side_id(s, k),
                    None => Id::Free(x),
                });
            }
        }
    }

    /// Height of G at the quantized position `uv` and that position in the grid.
    fn on_surface(&self, uv: [u16; 2]) -> ([f64; 2], f64) {
        let q = f64::from(Q);
        let p = self.map.grid(f64::from(uv[0]) / q, f64::from(uv[1]) / q);
        (p, self.s.at(p))
    }

    fn push(&mut self, uv: [u16; 2]) -> u32 {
        let (p, h) = self.on_surface(uv);
        self.out.uv.push(uv);
        self.out.p.push(p);
        self.out.h.push(h);
        (self.out.uv.len() - 1) as u32
    }

    /// The vertex of grid node (i, j) (inside the tile), made on first use.
    fn node(&mut self, i: i64, j: i64) -> u32 {
        let at = ((j - self.j0) * self.w + (i - self.i0)) as usize;
        if self.node_vertex[at] != u32::MAX {
            return self.node_vertex[at];
        }
        let v = self.point([i as f64, j as f64]);
        self.node_vertex[at] = v;
        v
    }

    /// A new vertex at the quantized position nearest grid position `p` (inside the tile),
    /// at the surface's height there.
    fn point(&mut self, p: [f64; 2]) -> u32 {
        let affine = |p: [f64; 2]| {
            let r = [p[0] - self.centre[0], p[1] - self.centre[1]];
            [
                self.inv[0][0] * r[0] + self.inv[0][1] * r[1],
                self.inv[1][0] * r[0] + self.inv[1][1] * r[1],
            ]
        };
        // The affine guess, then one Newton step with the same Jacobian (the map is affine
        // to a fraction of a quantum over a tile).
        let g = affine(p);
        let uv0 = [0.5 + g[0], 0.5 + g[1]];
        let back = self.map.grid(uv0[0], uv0[1]);
        let c = affine([
            p[0] - back[0] + self.centre[0],
            p[1] - back[1] + self.centre[1],
        ]);
        let q = f64::from(Q);
        let uv = [uv0[0] + c[0], uv0[1] + c[1]].map(|t| (t * q).round().clamp(1.0, q - 1.0) as u16);
        self.push(uv)
    }

    fn z(&self, i: i64, j: i64) -> f64 {
        self.s.node(i, j)
    }

    /// The heights of cell (i, j)'s corners, counter-clockwise from (i, j).
    fn corners(&self, i: i64, j: i64) -> [f64; 4] {
        [
            self.z(i, j),
            self.z(i + 1, j),
            self.z(i + 1, j + 1),
            self.z(i, j + 1),
        ]
    }

    /// Largest slope of G (metres per grid unit) within a cell of cell (i, j).
    fn slope(&self, i: i64, j: i64) -> f64 {
        let mut g = 0.0f64;
        for b in (j - 1)..=(j + 2) {
            let row = (b - self.j0 + 1) * (self.w + 2);
            for a in (i - 1)..=(i + 2) {
                g = g.max(self.step[(row + a - self.i0 + 1) as usize]);
            }
        }
        std::f64::consts::SQRT_2 * g
    }

    fn area(&self, a: u32, b: u32, c: u32) -> i64 {
        let p = [a, b, c].map(|k| self.out.uv[k as usize].map(i64::from));
        (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1])
    }

    /// Triangle (a, b, c), counter-clockwise in the grid, counter-clockwise in (u, v).
    fn tri(&mut self, a: u32, b: u32, c: u32) {
        let t = if self.flipped { [a, c, b] } else { [a, b, c] };
        self.out.triangles.push(t);
    }

    /// Interior cell (i, j): two triangles, four around its centre, or greedy refinement
    /// (false when that failed).
    fn cell(&mut self, i: i64, j: i64) -> bool {
        let z = self.corners(i, j);
        let twist = twist(&z);
        let margin = 2.0 * self.slope(i, j) * self.delta;
        let v = [
            self.node(i, j),
            self.node(i + 1, j),
            self.node(i + 1, j + 1),
            self.node(i, j + 1),
        ];
        if twist / 4.0 + margin <= self.tolerance {
            if (z[0] - z[2]).abs() <= (z[1] - z[3]).abs() {
                self.tri(v[0], v[1], v[2]);
                self.tri(v[0], v[2], v[3]);
            } else {
                self.tri(v[0], v[1], v[3]);
                self.tri(v[1], v[2], v[3]);
            }
            true
        } else if twist / 16.0 + margin <= self.tolerance {
            let uv = [0, 1].map(|c| {
                let sum: u32 = v
                    .iter()
                    .map(|&k| u32::from(self.out.uv[k as usize][c]))
                    .sum();
                ((sum + 2) / 4) as u16
            });
            let m = self.push(uv);
            for e in 0..4 {
                self.tri(v[e], v[(e + 1) % 4], m);
            }
            true
        } else {
            // Each edge of a triangle in the cell must have |ΔxΔy| ≤ s (cell units); with
            // some slack for the vertices' quantisation, and then measured exactly.
            let s = 4.0 * self.tolerance / twist * SLACK;
            if self.rings(i, j, v, s) {
                return true;
            }
            let poly = if self.flipped {
                vec![v[0], v[3], v[2], v[1]]
            } else {
                v.to_vec()
            };
            self.refine(&poly)
        }
    }

    /// Interior cell (i, j) with corner vertices `v` (counter-clockwise in the grid) whose
    /// fan around its centre did not hold with the margin: that fan, or concentric rings and
    /// a diamond (see the module's notes), whose triangle edges all have |ΔxΔy| ≤ `s` in
    /// cell units, so every triangle is within |d|·s/4 of the surface at the ideal
    /// positions. False, with nothing added, when it would take more than `MAX_RINGS` rings
    /// or a triangle at the quantized positions is not counter-clockwise or not within the
    /// tolerance (exact measure).
    fn rings(&mut self, i: i64, j: i64, v: [u32; 4], s: f64) -> bool {
        let (nv, nt) = (self.out.uv.len(), self.out.triangles.len());
        let at = |x: f64, y: f64| [i as f64 + x, j as f64 + y];
        // The current square's boundary counter-clockwise from its south-west corner:
        // corners at even places, the midpoints of its sides (after the first ring) at odd.
        let mut outer = [v[0], 0, v[1], 0, v[2], 0, v[3], 0];
        let (mut lo, mut a, mut mids) = (0.0, 1.0, false);
        let mut rings = 0;
        if a * a <= 4.0 * s {
            // The fan around the centre, measured exactly (its closed form did not hold
            // with the margin).
            let c = self.point(at(0.5, 0.5));
            for k in 0..4 {
                self.tri(v[k], v[(k + 1) % 4], c);
            }
            return self.keep_if_held(i, j, nv, nt);
        }
        while a * a > 4.0 * s {
            rings += 1;
            if rings > MAX_RINGS {
                self.truncate(nv, nt);
                return false;
            }
            let e = 2.0 * s / a;
            let (l, h) = (lo + e, lo + a - e);
            let m = [at(0.5, l), at(h, 0.5), at(0.5, h), at(l, 0.5)].map(|p| self.point(p));
            if 0.5 * a - e <= s.sqrt() {
                // The diamond: the inner midpoints alone, the corners' triangles between
                // two of them (edge (a/2 − e)²), the diamond split north–south.
                for k in 0..4 {
                    self.side_to(&outer, mids, k, m[k]);
                    self.tri(outer[2 * k], m[k], m[(k + 3) % 4]);
                }
                self.tri(m[0], m[1], m[2]);
                self.tri(m[0], m[2], m[3]);
                return self.keep_if_held(i, j, nv, nt);
            }
            let q = [at(l, l), at(h, l), at(h, h), at(l, h)].map(|p| self.point(p));
            for k in 0..4 {
                self.side_to(&outer, mids, k, m[k]);
                self.tri(outer[2 * k], m[k], q[k]);
                self.tri(outer[(2 * k + 2) % 8], q[(k + 1) % 4], m[k]);
            }
            outer = [q[0], m[0], q[1], m[1], q[2], m[2], q[3], m[3]];
            (lo, a, mids) = (l, a - 2.0 * e, true);
        }
        let c = self.point(at(0.5, 0.5));
        for k in 0..8 {
            self.tri(outer[k], outer[(k + 1) % 8], c);
        }
        self.keep_if_held(i, j, nv, nt)
    }

    /// The triangles from side `k` of the square `outer` (corners at even places, side
    /// midpoints at odd ones when `mids`) to the vertex `apex` inside it.
    fn side_to(&mut self, outer: &[u32; 8], mids: bool, k: usize, apex: u32) {
        let (c0, c1) = (outer[2 * k], outer[(2 * k + 2) % 8]);
        if mids {
            self.tri(c0, outer[2 * k + 1], apex);
            self.tri(outer[2 * k + 1], c1, apex);
        } else {
            self.tri(c0, c1, apex);
        }
    }

    /// True when every triangle from `nt` on (inside cell (i, j)) is counter-clockwise after
    /// quantisation and within the tolerance of the surface (the closed forms hold for the
    /// ideal positions, the vertices sit on quantized ones); else drops them and the vertices
    /// from `nv` on, and false. Each triangle is held by [`Tile::cell_bound`] when that
    /// suffices, else by the exact measure (`tin::worst_in_triangle`, the greedy
    /// insertion's own).
    fn keep_if_held(&mut self, i: i64, j: i64, nv: usize, nt: usize) -> bool {
        let mut cuts = Vec::new();
        let twist = twist(&self.corners(i, j));
        let slope = self.slope(i, j);
        let ok = self.out.triangles[nt..].iter().all(|t| {
            let k = t.map(|k| k as usize);
            self.area(t[0], t[1], t[2]) > 0 && {
                let p = k.map(|k| self.out.p[k]);
                cell_bound(p, [i, j], twist, slope) <= self.tolerance || {
                    let h = k.map(|k| self.out.h[k]);
                    tin::worst_in_triangle(self.s, p, h, [false; 3], &mut cuts).0 <= self.tolerance
                }
            }
        });
        if !ok {
            self.truncate(nv, nt);
        }
        ok
    }

    /// Drops the vertices from `nv` on and the triangles from `nt` on.
    fn truncate(&mut self, nv: usize, nt: usize) {
        self.out.uv.truncate(nv);
        self.out.p.truncate(nv);
        self.out.h.truncate(nv);
        self.out.triangles.truncate(nt);
    }

    /// The convex polygon `poly` (counter-clockwise in (u, v)) triangulated by greedy
    /// insertion within the tolerance (exact measure). False when the refinement could not
    /// keep the polygon's vertices (two of them on one quantized position).
    fn refine(&mut self, poly: &[u32]) -> bool {
        let start: Vec<([u16; 2], [f64; 2], f64)> = poly
            .iter()
            .map(|&k| {
                let k = k as usize;
                (self.out.uv[k], self.out.p[k], self.out.h[k])
            })
            .collect();
        let t = tin::refine(
            self.s,
            self.map,
            &start,
            self.aspect,
            self.tolerance,
            poly.len() + CELL_VERTICES,
        );
        if t.uv.len() < poly.len() || t.uv.iter().zip(&start).any(|(a, b)| *a != b.0) {
            return false;
        }
        let base = self.out.uv.len() as u32;
        let index = |k: u32| {
            if (k as usize) < poly.len() {
                poly[k as usize]
            } else {
                base + k - poly.len() as u32
            }
        };
        for k in poly.len()..t.uv.len() {
            self.out.uv.push(t.uv[k]);
            self.out.p.push(t.p[k]);
            self.out.h.push(t.h[k]);
        }
        for f in &t.triangles {
            self.out.triangles.push(f.map(index));
        }
        true
    }

    /// Cell (i, j) cut by the tile's sides: its piece inside the tile. False when the piece
    /// could not be made (the tile then takes the greedy path).
    fn cut_cell(&mut self, i: i64, j: i64) -> bool {
        let mut poly = vec![
            Id::Node(i, j),
            Id::Node(i + 1, j),
            Id::Node(i + 1, j + 1),
            Id::Node(i, j + 1),
        ];
        let mut next = Vec::with_capacity(12);
        for s in [0, 1, 3, 2] {
            self.clip(&poly, s, &mut next);
            std::mem::swap(&mut poly, &mut next);
            if poly.is_empty() {
                return true;
            }
        }
        poly.dedup();
        while poly.len() > 1 && poly.first() == poly.last() {
            poly.pop();
        }
        if poly.len() < 3 {
            return true;
        }
        // The side vertices between two consecutive vertices on one side.
        let mut full = Vec::with_capacity(poly.len() + 4);
        for k in 0..poly.len() {
            let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
            if matches!(a, Id::Free(_)) {
                return false;
            }
            full.push(a);
            for s in 0..4 {
                if let (Some(ka), Some(kb)) = (self.on_side(a, s), self.on_side(b, s)) {
                    let verts = &self.sides[s].verts;
                    let lo = verts.partition_point(|v| v.k <= ka.min(kb));
                    let hi = verts.partition_point(|v| v.k < ka.max(kb));
                    let between: Vec<Id> = (lo..hi).map(|x| self.side_id(s, x)).collect();
                    if ka < kb {
                        full.extend(between);
                    } else {
                        full.extend(between.into_iter().rev());
                    }
                    break;
                }
            }
        }
        let mut vs: Vec<u32> = full
            .iter()
            .map(|&v| match v {
                Id::Node(i, j) => self.node(i, j),
                Id::Side(s, k) => self.side_vertex[s][k],
                Id::Corner(c) => {
                    let (s, end) = [(0, 0), (0, 1), (3, 0), (3, 1)][c];
                    let n = self.side_vertex[s].len();
                    self.side_vertex[s][if end == 0 { 0 } else { n - 1 }]
                }
                Id::Free(_) => u32::MAX,
            })
            .collect();
        vs.dedup();
        while vs.len() > 1 && vs.first() == vs.last() {
            vs.pop();
        }
        if vs.len() < 3 {
            return true;
        }
        let mut twice_area = 0;
        for k in 1..vs.len() - 1 {
            twice_area += self.area(vs[0], vs[k], vs[k + 1]);
        }
        if twice_area == 0 {
            return true;
        }
        if twice_area < 0 {
            vs.reverse();
        }
        let twist = twist(&self.corners(i, j));
        let margin = 2.0 * self.slope(i, j) * self.delta_side;
        if twist / 4.0 + margin <= self.tolerance {
            // A fan from the first vertex whose triangles all turn the right way.
            let n = vs.len();
            for a in 0..n {
                let ok =
                    (1..n - 1).all(|k| self.area(vs[a], vs[(a + k) % n], vs[(a + k + 1) % n]) > 0);
                if ok {
                    for k in 1..n - 1 {
                        let t = [vs[a], vs[(a + k) % n], vs[(a + k + 1) % n]];
                        self.out.triangles.push(t);
                    }
                    return true;
                }
            }
        }
        self.refine(&vs)
    }
}

/// A bilinear cell's twist |z00 − z10 − z01 + z11| from its corners (counter-clockwise): the
/// two-triangle split of the cell is within a quarter of it of the bilinear surface, the fan
/// around its centre within a sixteenth.
fn twist(z: &[f64; 4]) -> f64 {
    (z[0] - z[1] - z[3] + z[2]).abs()
}

/// A bound on |G − L| over the triangle at grid positions `p` whose vertices lie on G (L its
/// linear interpolant of them), for a triangle in or next to cell (i, j) of twist `twist`
/// (metres) inside a neighbourhood where G's slope is at most `slope` (metres per cell).
/// Inside the cell G is one bilinear polynomial, G − L = d·(xy − L(xy)) is harmonic, and on an
/// edge it is d·ΔxΔy·t(1 − t): the bound is exact, |d|·max|ΔxΔy|/4 over the three edges. A
/// vertex quantized up to `out` outside the cell adds, on the sliver past its border, where G
/// and the cell's polynomial G_c agree on the border and part at most with their slopes,
/// |G − G_c| ≤ m = (2·slope + |d|·out)·out, and as much again through the vertices' heights
/// (L against G_c's own interpolant): 2m in all.
fn cell_bound(p: [[f64; 2]; 3], [i, j]: [i64; 2], twist: f64, slope: f64) -> f64 {
    let (x0, y0) = (i as f64, j as f64);
    let out = p
        .iter()
        .map(|q| {
            let ex = (x0 - q[0]).max(q[0] - x0 - 1.0).max(0.0);
            let ey = (y0 - q[1]).max(q[1] - y0 - 1.0).max(0.0);
            ex + ey
        })
        .fold(0.0, f64::max);
    let span = (0..3)
        .map(|k| {
            let (a, b) = (p[k], p[(k + 1) % 3]);
            ((b[0] - a[0]) * (b[1] - a[1])).abs()
        })
        .fold(0.0, f64::max);
    twist * span / 4.0 + 2.0 * (2.0 * slope + twist * out) * out
}

/// Share of a tile's grid nodes where the grid bends by more than `tolerance` over two cells
/// (|z(i−1) − 2z(i) + z(i+1)| along a row or a column): the cheap count that chooses between
/// the dense path and the greedy one. Where most nodes bend, the greedy insertion would take
/// nearly every sample anyway, at ten times the cost per vertex; where few do, it takes far
/// fewer vertices than the cells. Over the nodes of the footprint's bounding box, every
/// second one along each axis.
pub fn roughness<S: Surface>(s: &S, map: &TileMap, tolerance: f64) -> f64 {
    let corners = [
        map.grid(0.0, 0.0),
        map.grid(1.0, 0.0),
        map.grid(0.0, 1.0),
        map.grid(1.0, 1.0),
    ];
    // The nodes of the corners' bounding box along axis `c`.
    let nodes = |c: usize| {
        let (lo, hi) = corners
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |m, p| {
                (m.0.min(p[c]), m.1.max(p[c]))
            });
        (lo.ceil() as i64..=hi.floor() as i64).step_by(2)
    };
    let (mut rough, mut all) = (0usize, 0usize);
    for j in nodes(1) {
        for i in nodes(0) {
            let z = 2.0 * s.node(i, j);
            let bend = (s.node(i - 1, j) + s.node(i + 1, j) - z)
                .abs()
                .max((s.node(i, j - 1) + s.node(i, j + 1) - z).abs());
            rough += usize::from(bend > tolerance);
            all += 1;
        }
    }
    rough as f64 / all.max(1) as f64
}

/// The dense tile with grid map `map` and sides `[south, east, west, north]` (as for
/// `tin::triangulate`, each made by [`DenseSide::dense`]): every grid cell inside the tile
/// triangulated within `tolerance` of the grid's bilinear surface, the cells cut by the
/// sides clipped to it. None when the tile's footprint (with a cell around it) is not inside
/// the grid, or a cut cell could not be made: the caller then takes the greedy path.
pub fn dense_tile<S: Surface>(
    s: &S,
    map: &TileMap,
    sides: [&DenseSide; 4],
    aspect: f64,
    tolerance: f64,
) -> Option<TileTin> {
    if sides.iter().any(|d| d.marks.is_empty()) {
        return None;
    }
    let corners = [
        map.grid(0.0, 0.0),
        map.grid(1.0, 0.0),
        map.grid(0.0, 1.0),
        map.grid(1.0, 1.0),
    ];
    let [cols, rows] = s.size().map(|n| n as i64);
    let xs = corners.map(|c| c[0]);
    let ys = corners.map(|c| c[1]);
    let i0 = xs.iter().copied().fold(f64::INFINITY, f64::min).floor() as i64 - 1;
    let i1 = xs.iter().copied().fold(f64::NEG_INFINITY, f64::max).ceil() as i64 + 1;
    let j0 = ys.iter().copied().fold(f64::INFINITY, f64::min).floor() as i64 - 1;
    let j1 = ys.iter().copied().fold(f64::NEG_INFINITY, f64::max).ceil() as i64 + 1;
    // The block and the slope's reach (two nodes past it) inside the grid.
    if i0 < 2 || j0 < 2 || i1 > cols - 3 || j1 > rows - 3 {
        return None;
    }
    let ju = [
        0.5 * (corners[1][0] - corners[0][0] + corners[3][0] - corners[2][0]),
        0.5 * (corners[1][1] - corners[0][1] + corners[3][1] - corners[2][1]),
    ];
    let jv = [
        0.5 * (corners[2][0] - corners[0][0] + corners[3][0] - corners[1][0]),
        0.5 * (corners[2][1] - corners[0][1] + corners[3][1] - corners[1][1]),
    ];
    let det = ju[0] * jv[1] - ju[1] * jv[0];
    if det == 0.0 {
        return None;
    }
    let flipped = det < 0.0;
    let o = if flipped { -1.0 } else { 1.0 };
    let len = |j: [f64; 2]| (j[0] * j[0] + j[1] * j[1]).sqrt();
    let quantum = (len(ju) + len(jv)) / f64::from(Q);
    let w = i1 - i0 + 1;
    let h = j1 - j0 + 1;
    let mut t = Tile {
        s,
        map,
        sides,
        inside: INSIDE.map(|x| x * o),
        out: TileTin::default(),
        side_vertex: Default::default(),
        i0,
        j0,
        w,
        node_vertex: vec![u32::MAX; (w * h) as usize],
        step: vec![0.0; ((w + 2) * (h + 2)) as usize],
        centre: [0, 1].map(|c| 0.25 * corners.iter().map(|p| p[c]).sum::<f64>()),
        inv: [[jv[1] / det, -jv[0] / det], [-ju[1] / det, ju[0] / det]],
        delta: quantum,
        delta_side: quantum * (1.0 + 2.0 * f64::from(MERGE)),
        aspect,
        tolerance,
        flipped,
    };
    // The side vertices first (corners once), as the greedy path orders them.
    let place: [fn(u16) -> [u16; 2]; 4] = [
        |k: u16| [k, 0],
        |k: u16| [Q, k],
        |k: u16| [0, k],
        |k: u16| [k, Q],
    ];
    let mut corner = [u32::MAX; 4];
    for (s, place) in place.iter().enumerate() {
        let n = sides[s].verts.len();
        let mut ids = Vec::with_capacity(n);
        for (k, v) in sides[s].verts.iter().enumerate() {
            let c = match k {
                0 => Some(ENDS[s][0]),
                _ if k + 1 == n => Some(ENDS[s][1]),
                _ => None,
            };
            if let Some(c) = c.filter(|&c| corner[c] != u32::MAX) {
                ids.push(corner[c]);
                continue;
            }
            t.out.uv.push(place(v.k));
            t.out.p.push(v.p);
            t.out.h.push(v.h);
            let id = (t.out.uv.len() - 1) as u32;
            if let Some(c) = c {
                corner[c] = id;
            }
            ids.push(id);
        }
        t.side_vertex[s] = ids;
    }
    // Height steps around every node of the block and a node past it.
    for b in (j0 - 1)..=(j1 + 1) {
        for a in (i0 - 1)..=(i1 + 1) {
            let z = s.node(a, b);
            let m = [(a + 1, b), (a - 1, b), (a, b + 1), (a, b - 1)]
                .iter()
                .map(|&(x, y)| (s.node(x, y) - z).abs())
                .fold(0.0, f64::max);
            t.step[((b - j0 + 1) * (w + 2) + a - i0 + 1) as usize] = m;
        }
    }
    // Each node's class against each side: bit s set when inside, bit 4 + s when outside.
    let mut class = vec![0u8; (w * h) as usize];
    for b in j0..=j1 {
        for a in i0..=i1 {
            let mut bits = 0u8;
            for (side, d) in sides.iter().enumerate() {
                let (c, _, _) = d.class([a as f64, b as f64], t.inside[side]);
                bits |= match c {
                    1 => 1 << side,
                    -1 => 16 << side,
                    _ => 0,
                };
            }
            class[((b - j0) * w + a - i0) as usize] = bits;
        }
    }
    for b in j0..j1 {
        for a in i0..i1 {
            let at = |x: i64, y: i64| class[((y - j0) * w + x - i0) as usize];
            let c = [at(a, b), at(a + 1, b), at(a + 1, b + 1), at(a, b + 1)];
            if c.iter().all(|&c| c & 15 == 15) {
                if !t.cell(a, b) {
                    return None;
                }
            } else if c.iter().fold(0xF0, |m, &c| m & c) == 0 && !t.cut_cell(a, b) {
                return None;
            }
        }
    }
    Some(t.out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Unit cells with trees: heights from a hash, 0–12 m, on a slope.
    struct Rough;
    impl Surface for Rough {
        fn at(&self, p: [f64; 2]) -> f64 {
            crate::geo::tin::tests::bilinear(self, p)
        }
        fn node(&self, i: i64, j: i64) -> f64 {
            let (i, j) = (i.clamp(0, 79), j.clamp(0, 79));
            let hash = (i * 7919 + j * 104_729) % 97;
            let tree = if (20..50).contains(&i) && (10..60).contains(&j) {
                (hash % 13) as f64
            } else {
                0.01 * (hash % 7) as f64
            };
            0.1 * i as f64 + tree
        }
        fn size(&self) -> [usize; 2] {
            [80, 80]
        }
    }

    /// The tile turned by `angle` over the grid, with corner `origin` and side `size` cells.
    fn map_of(origin: [f64; 2], size: f64, angle: f64) -> (TileMap, [Vec<[f64; 2]>; 4]) {
        let (c, s) = (angle.cos(), angle.sin());
        let at = |u: f64, v: f64| {
            [
                origin[0] + size * (c * u - s * v),
                origin[1] + size * (s * u + c * v),
            ]
        };
        let m = tin::M as f64;
        let mut pts = [[0.0; 2]; (tin::M + 1) * (tin::M + 1)];
        for b in 0..=tin::M {
            for a in 0..=tin::M {
                pts[b * (tin::M + 1) + a] = at(a as f64 / m, b as f64 / m);
            }
        }
        let line = |f: &dyn Fn(f64) -> [f64; 2]| (0..=tin::M).map(|k| f(k as f64 / m)).collect();
        (
            TileMap::new(pts),
            [
                line(&|t| at(t, 0.0)),
                line(&|t| at(1.0, t)),
                line(&|t| at(0.0, t)),
                line(&|t| at(t, 1.0)),
            ],
        )
    }

    #[test]
    fn the_cell_bound_holds_the_sampled_distance() {
        // Triangles in the trees' cells, their vertices on the surface and up to 3 % of a
        // cell past its border: the bound never falls below a dense sampling of |G − L| (the
        // slow twin), and equals it (to rounding) for a triangle inside the cell.
        let mut rng = crate::SplitMix64::new(11);
        let (mut inside, mut outside) = (0, 0);
        for _ in 0..3000 {
            let (i, j) = (21 + rng.below(27) as i64, 11 + rng.below(47) as i64);
            let pad = if rng.below(2) == 0 { 0.0 } else { 0.03 };
            let p = [0, 1, 2].map(|_| {
                [
                    i as f64 + rng.range(-pad, 1.0 + pad),
                    j as f64 + rng.range(-pad, 1.0 + pad),
                ]
            });
            let h = p.map(|q| Rough.at(q));
            let z = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)].map(|(a, b)| Rough.node(a, b));
            let mut step = 0.0f64;
            for b in (j - 1)..=(j + 2) {
                for a in (i - 1)..=(i + 2) {
                    for (x, y) in [(a + 1, b), (a, b + 1)] {
                        step = step.max((Rough.node(x, y) - Rough.node(a, b)).abs());
                    }
                }
            }
            let bound = cell_bound(p, [i, j], twist(&z), std::f64::consts::SQRT_2 * step);
            let n = 40;
            let mut sampled = 0.0f64;
            for a in 0..=n {
                for b in 0..=(n - a) {
                    let w = [a as f64 / n as f64, b as f64 / n as f64];
                    let w = [1.0 - w[0] - w[1], w[0], w[1]];
                    let q = [0, 1].map(|c| (0..3).map(|m| w[m] * p[m][c]).sum::<f64>());
                    let l: f64 = (0..3).map(|m| w[m] * h[m]).sum();
                    sampled = sampled.max((l - Rough.at(q)).abs());
                }
            }
            assert!(bound >= sampled - 1e-9, "{p:?}: bound {bound} < {sampled}");
            let within = p.iter().all(|q| {
                (i as f64..=(i + 1) as f64).contains(&q[0])
                    && (j as f64..=(j + 1) as f64).contains(&q[1])
            });
            if within {
                assert!(bound <= sampled + 1e-9, "{p:?}: bound {bound} > {sampled}");
                inside += 1;
            } else {
                outside += 1;
            }
        }
        assert!(inside > 1000 && outside > 200, "{inside} {outside}");
    }

    #[test]
    fn a_turned_dense_tile_covers_itself_within_the_tolerance() {
        for (angle, tol) in [(0.031, 0.5), (0.4, 0.25), (-0.2, 1.0), (0.0, 0.5)] {
            let (map, lines) = map_of([20.3, 12.7], 40.0, angle);
            let sides = lines.clone().map(|l| DenseSide::dense(&Rough, &l, tol));
            let tin = dense_tile(
                &Rough,
                &map,
                [&sides[0], &sides[1], &sides[2], &sides[3]],
                1.0,
                tol,
            )
            .expect("dense");
            // Counter-clockwise, covering the tile exactly.
            let mut area = 0.0;
            for t in &tin.triangles {
                let p = t.map(|k| tin.uv[k as usize].map(f64::from));
                let a = (p[1][0] - p[0][0]) * (p[2][1] - p[0][1])
                    - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
                assert!(a > 0.0, "angle {angle}: {t:?} {p:?}");
                area += a / 2.0;
            }
            let full = f64::from(Q).powi(2);
            assert!(
                (area - full).abs() < 1e-6 * full,
                "angle {angle}: {area} of {full}"
            );
            // Every vertex on the surface; the border carries the sides' vertices only.
            for (p, h) in tin.p.iter().zip(&tin.h) {
                assert_eq!(Rough.at(*p), *h);
            }
            let on_border = tin
                .uv
                .iter()
                .filter(|p| p[0] == 0 || p[1] == 0 || p[0] == Q || p[1] == Q)
                .count();
            assert_eq!(
                on_border,
                sides.iter().map(|s| s.verts.len()).sum::<usize>() - 4
            );
            let worst = tin::tests::dense_worst(&Rough, &tin, &map, 24);
            assert!(worst <= tol + 1e-9, "angle {angle}: {worst} > {tol}");
            // Nearly every node of the 40² cells, no Delaunay.
            assert!(tin.uv.len() > 1200, "{}", tin.uv.len());
        }
    }

    #[test]
    fn the_neighbour_across_a_dense_side_clips_to_the_same_vertices() {
        // Two tiles side by side: every triangle edge on the shared side joins consecutive
        // side vertices, from both tiles.
        let tol = 0.5;
        let (map_a, lines_a) = map_of([12.3, 9.7], 30.0, 0.05);
        let c = 0.05f64.cos() * 30.0;
        let s = 0.05f64.sin() * 30.0;
        let (map_b, lines_b) = map_of([12.3 + c, 9.7 + s], 30.0, 0.05);
        let shared = DenseSide::dense(&Rough, &lines_a[1], tol);
        let a_sides = lines_a.map(|l| DenseSide::dense(&Rough, &l, tol));
        let b_sides = lines_b.map(|l| DenseSide::dense(&Rough, &l, tol));
        let a = dense_tile(
            &Rough,
            &map_a,
            [&a_sides[0], &shared, &a_sides[2], &a_sides[3]],
            1.0,
            tol,
        )
        .unwrap();
        let b = dense_tile(
            &Rough,
            &map_b,
            [&b_sides[0], &b_sides[1], &shared, &b_sides[3]],
            1.0,
            tol,
        )
        .unwrap();
        let edges = |t: &TileTin, u: u16| {
            let mut e: Vec<[u16; 2]> = Vec::new();
            for f in &t.triangles {
                for k in 0..3 {
                    let (p, q) = (t.uv[f[k] as usize], t.uv[f[(k + 1) % 3] as usize]);
                    if p[0] == u && q[0] == u {
                        let mut x = [p[1], q[1]];
                        x.sort_unstable();
                        e.push(x);
                    }
                }
            }
            e.sort_unstable();
            e
        };
        let want: Vec<[u16; 2]> = shared.verts.windows(2).map(|w| [w[0].k, w[1].k]).collect();
        assert_eq!(edges(&a, Q), want);
        assert_eq!(edges(&b, 0), want);
    }
}
