//! The most detailed level's tiles as adaptive triangulations of the grid's own surface.
//!
//! A tile of the geographic tiling is not aligned with the projected grid, so a regular
//! longitude/latitude lattice resamples the grid and cuts corners at walls. Here a tile's
//! vertices are instead points of the grid's own bilinear surface G (each vertex's height is
//! G at the vertex's quantized position, so every vertex lies on G), chosen by greedy
//! insertion (Garland and Heckbert, "Fast polygonal approximation of terrains and height
//! fields", 1995): starting from the tile's border, the point where the triangulation lies
//! farthest from G is inserted into a Delaunay triangulation (`spade`) until every triangle is
//! within the tolerance of G everywhere.
//!
//! "Everywhere" is exact: on each grid cell a triangle's
//! plane minus G is linear minus bilinear, harmonic, so its extremes over (triangle ∩ cell) lie
//! on that piece's boundary: at grid nodes inside the triangle, or on the triangle's edges at
//! their crossings with grid lines or at the vertex of the quadratic between two crossings.
//! Each triangle is measured at all of those (up to the tile's map from longitude/latitude to
//! the grid being affine, which over a tile of a few tens of metres it is to well under a
//! millimetre), and the worst of them is the point inserted.
//!
//! Crack-free edges: the vertices on a tile's side depend on that side alone. Each side of
//! every tile of the level is computed once, from its `M + 1` points (projected once per
//! level), as a 1-D simplification of G along it: the side's vertices are taken among its quantized
//! positions (1/32767 of the side), split recursively at the point of the exact largest
//! deviation until each piece is within the tolerance. Both neighbours take that one list, so
//! their shared edge vertices are the same positions and the same heights, and the side's
//! pieces are already within the tolerance (the interior never splits them).
//!
//! Hand-written: spade builds the Delaunay triangulation, but no crate approximates a
//! bilinear grid by a TIN within an exact bound on a region that is not grid-aligned.

use rustc_hash::FxHashMap;
use spade::handles::{FixedFaceHandle, FixedVertexHandle, InnerTag};
use spade::{DelaunayTriangulation, Point2, Triangulation};
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// Largest quantized coordinate of a tile (quantized-mesh's u, v range).
pub const Q: u16 = 32767;

/// The grid's surface in fractional grid coordinates (column, row): bilinear on unit cells,
/// continued past the grid's border by its border values.
pub trait Surface {
    /// Height (metres) at a fractional position.
    fn at(&self, p: [f64; 2]) -> f64;
    /// Height (metres) of grid node (i, j) (clamped to the grid).
    fn node(&self, i: i64, j: i64) -> f64;
    /// Columns and rows of the grid.
    fn size(&self) -> [usize; 2];
    /// Whether `p` is over the grid (the closed rectangle of its nodes). The triangulations
    /// are held to the tolerance there only: past the border the continued surface is an
    /// extrusion of the border's profile, which a Delaunay triangulation would follow only
    /// with a vertex at nearly every node, for heights no one measured.
    fn inside(&self, p: [f64; 2]) -> bool {
        let [c, r] = self.size();
        (0.0..=(c - 1) as f64).contains(&p[0]) && (0.0..=(r - 1) as f64).contains(&p[1])
    }
}

/// Largest |L − G| over the grid along the segment from `p0` (height `h0`) to `p1` (height
/// `h1`), L linear between the ends' heights and G the surface `s` (continuous, bilinear on
/// each unit cell), and the fraction of the segment where it is taken. `cuts` is scratch
/// space.
fn edge_error<S: Surface>(
    s: &S,
    p0: [f64; 2],
    p1: [f64; 2],
    h0: f64,
    h1: f64,
    cuts: &mut Vec<f64>,
) -> (f64, f64) {
    // The crossings with each axis's integer lines strictly between the ends come in
    // increasing t when those lines are walked towards p1: the two runs are merged, not sorted.
    let run = |k: usize| {
        let (a, b) = (p0[k], p1[k]);
        if a == b {
            return (a, 1.0, 0.0, 0, 1.0);
        }
        let (lo, hi) = (a.min(b), a.max(b));
        let (first, last) = (lo.floor() + 1.0, hi.ceil() - 1.0);
        let n = if last >= first {
            (last - first) as usize + 1
        } else {
            0
        };
        if b > a {
            (a, b - a, first, n, 1.0)
        } else {
            (a, b - a, last, n, -1.0)
        }
    };
    let at =
        |(a, d, c0, _, dir): (f64, f64, f64, usize, f64), m: usize| (c0 + dir * m as f64 - a) / d;
    let (rx, ry) = (run(0), run(1));
    cuts.clear();
    cuts.push(0.0);
    let (mut mx, mut my) = (0, 0);
    while mx < rx.3 || my < ry.3 {
        let tx = if mx < rx.3 { at(rx, mx) } else { f64::INFINITY };
        let ty = if my < ry.3 { at(ry, my) } else { f64::INFINITY };
        if tx <= ty {
            cuts.push(tx);
            mx += 1;
        } else {
            cuts.push(ty);
            my += 1;
        }
    }
    cuts.push(1.0);
    let point = |t: f64| [p0[0] + t * (p1[0] - p0[0]), p0[1] + t * (p1[1] - p0[1])];
    let e = |t: f64| h0 + t * (h1 - h0) - s.at(point(t));
    let mut worst = (0.0f64, 0.0f64);
    let mut take = |err: f64, t: f64| {
        if err.abs() > worst.0 {
            worst = (err.abs(), t);
        }
    };
    let mut ea = e(cuts[0]);
    for w in cuts.windows(2) {
        let (ta, tb) = (w[0], w[1]);
        let eb = e(tb);
        // The grid's border lines are among the cuts: a piece is over the grid or not.
        let tm = 0.5 * (ta + tb);
        if s.inside(point(tm)) {
            take(ea, ta);
            take(eb, tb);
            // On (ta, tb) e is a quadratic q(s) = em + beta·s + alpha·s², s ∈ [−1, 1].
            let em = e(tm);
            let beta = 0.5 * (eb - ea);
            let alpha = 0.5 * (ea + eb) - em;
            take(em, tm);
            if alpha != 0.0 {
                let x = -beta / (2.0 * alpha);
                if x.abs() < 1.0 {
                    take(em - beta * beta / (4.0 * alpha), tm + x * 0.5 * (tb - ta));
                }
            }
        }
        ea = eb;
    }
    worst
}

/// A vertex of a tile's side: its quantized position along the side (0..=Q from the side's
/// first corner), its grid position and its height.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SideVertex {
    /// Position along the side, 0..=Q.
    pub k: u16,
    /// Fractional grid coordinates.
    pub p: [f64; 2],
    /// Height, metres.
    pub h: f64,
}

/// The vertices of a tile's side through the grid positions `line` (its `M + 1` exactly
/// projected points from its south or west end, the side linear between them): both ends and
/// as few quantized points between them as keep the piecewise-linear side within `tolerance`
/// of the surface along it, sorted along the side.
pub fn side_vertices<S: Surface>(s: &S, line: &[[f64; 2]], tolerance: f64) -> Vec<SideVertex> {
    side_vertices_through(s, line, &[], tolerance)
}

/// [`side_vertices`] through the quantized positions `through` as well (the dense tiles'
/// crossings of the side with the grid's lines, see `cells`): each piece between two of
/// them is simplified alike.
pub fn side_vertices_through<S: Surface>(
    s: &S,
    line: &[[f64; 2]],
    through: &[u16],
    tolerance: f64,
) -> Vec<SideVertex> {
    let at = |k: u16| {
        let f = f64::from(k) / f64::from(Q) * M as f64;
        let a = (f as usize).min(M - 1);
        let t = f - a as f64;
        // The far end exactly: it is the first corner of the next side.
        let p = if k == Q {
            line[M]
        } else {
            [0, 1].map(|c| line[a][c] + t * (line[a + 1][c] - line[a][c]))
        };
        SideVertex { k, p, h: s.at(p) }
    };
    let mut marks: Vec<u16> = through
        .iter()
        .copied()
        .filter(|&k| k > 0 && k < Q)
        .collect();
    marks.sort_unstable();
    marks.dedup();
    let mut out = vec![at(0)];
    let mut cuts = Vec::new();
    let mut prev = at(0);
    for k in marks.into_iter().chain([Q]) {
        let next = at(k);
        // Pieces still to measure, the next one along the side on top.
        let mut todo = vec![(prev, next)];
        while let Some((v0, v1)) = todo.pop() {
            let (err, t) = edge_error(s, v0.p, v1.p, v0.h, v1.h, &mut cuts);
            if err > tolerance && v1.k - v0.k >= 2 {
                let k = (f64::from(v0.k) + t * f64::from(v1.k - v0.k)).round() as u16;
                let k = k.clamp(v0.k + 1, v1.k - 1);
                let m = at(k);
                todo.push((m, v1));
                todo.push((v0, m));
            } else {
                out.push(v1);
            }
        }
        prev = next;
    }
    out
}

/// A tile's triangulation: vertices (quantized u, v; grid positions; heights) and
/// counter-clockwise triangles.
#[derive(Debug, Clone, Default)]
pub struct TileTin {
    /// Quantized (u, v), 0..=Q east and north.
    pub uv: Vec<[u16; 2]>,
    /// Fractional grid coordinates.
    pub p: Vec<[f64; 2]>,
    /// Heights, metres.
    pub h: Vec<f64>,
    /// Triangles, counter-clockwise in (u, v).
    pub triangles: Vec<[u32; 3]>,
}

/// Pieces per side of a tile's map: the tile's points projected exactly on an `M` × `M`
/// grid of pieces, bilinear within each. Over a piece of a tile of tens of metres the
/// projection's curvature (L²/8R) leaves a few micrometres.
pub const M: usize = 4;

/// A tile's map from (u, v) ∈ [0, 1]² to grid coordinates: bilinear on each of `M` × `M`
/// pieces between exactly projected points.
#[derive(Debug, Clone, Copy)]
pub struct TileMap {
    /// Grid positions of the points (a, b), a, b ∈ 0..=M, at `b * (M + 1) + a` (row-major
    /// from the south-west).
    pts: [[f64; 2]; (M + 1) * (M + 1)],
}

impl TileMap {
    /// The map through the grid positions `pts` (see the field).
    pub fn new(pts: [[f64; 2]; (M + 1) * (M + 1)]) -> TileMap {
        TileMap { pts }
    }

    /// The piece holding (u, v) (the border pieces continue past the tile), the fractions
    /// within it and its corners.
    fn piece(&self, u: f64, v: f64) -> ([f64; 2], [[f64; 2]; 4]) {
        let m = M as f64;
        let a = ((u * m).floor().max(0.0) as usize).min(M - 1);
        let b = ((v * m).floor().max(0.0) as usize).min(M - 1);
        let p = |a: usize, b: usize| self.pts[b * (M + 1) + a];
        (
            [u * m - a as f64, v * m - b as f64],
            [p(a, b), p(a + 1, b), p(a, b + 1), p(a + 1, b + 1)],
        )
    }

    /// Grid position of (u, v).
    pub fn grid(&self, u: f64, v: f64) -> [f64; 2] {
        let ([fu, fv], [c00, c10, c01, c11]) = self.piece(u, v);
        [0, 1].map(|k| {
            (c00[k] * (1.0 - fu) + c10[k] * fu) * (1.0 - fv)
                + (c01[k] * (1.0 - fu) + c11[k] * fu) * fv
        })
    }

    /// Derivatives of the grid position by u and by v at (u, v).
    pub fn jacobian(&self, u: f64, v: f64) -> [[f64; 2]; 2] {
        let ([fu, fv], [c00, c10, c01, c11]) = self.piece(u, v);
        let m = M as f64;
        [
            [0, 1].map(|k| m * ((c10[k] - c00[k]) * (1.0 - fv) + (c11[k] - c01[k]) * fv)),
            [0, 1].map(|k| m * ((c01[k] - c00[k]) * (1.0 - fu) + (c11[k] - c10[k]) * fu)),
        ]
    }

    /// (u, v) of grid position `p` (Newton's method; the map is within a hair of affine over
    /// a tile).
    pub fn inverse(&self, p: [f64; 2]) -> [f64; 2] {
        let mut uv = [0.5, 0.5];
        for _ in 0..6 {
            let q = self.grid(uv[0], uv[1]);
            let [ju, jv] = self.jacobian(uv[0], uv[1]);
            let det = ju[0] * jv[1] - ju[1] * jv[0];
            if det == 0.0 {
                break;
            }
            let r = [p[0] - q[0], p[1] - q[1]];
            uv[0] += (r[0] * jv[1] - r[1] * jv[0]) / det;
            uv[1] += (ju[0] * r[1] - ju[1] * r[0]) / det;
        }
        uv
    }
}

/// A face's worst deviation and where it is, keyed for the heap (largest first; ties by
/// face index, then vertices, so the order never depends on anything but the input).
struct Candidate {
    err: f64,
    face: FixedFaceHandle<InnerTag>,
    vertices: [FixedVertexHandle; 3],
    at: [f64; 2],
}

impl PartialEq for Candidate {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Candidate {
    fn cmp(&self, o: &Self) -> Ordering {
        self.err
            .total_cmp(&o.err)
            .then(o.face.index().cmp(&self.face.index()))
            .then_with(|| {
                let key = |c: &Candidate| c.vertices.map(|v| v.index());
                key(o).cmp(&key(self))
            })
    }
}

/// The worst |plane − G| over the triangle (grid positions `p`, heights `h`): at the grid
/// nodes inside it and along its edges (skipping edges on the tile's border, whose pieces
/// the side simplification already holds within the tolerance), and where.
pub(crate) fn worst_in_triangle<S: Surface>(
    s: &S,
    p: [[f64; 2]; 3],
    h: [f64; 3],
    border: [bool; 3],
    cuts: &mut Vec<f64>,
) -> (f64, [f64; 2]) {
    worst_in_triangle_with(s, p, h, |k| {
        (!border[k]).then(|| {
            let (a, b) = (k, (k + 1) % 3);
            edge_worst(s, p[a], p[b], h[a], h[b], cuts)
        })
    })
}

/// [`edge_error`]'s largest deviation and the grid position where it is taken.
fn edge_worst<S: Surface>(
    s: &S,
    p0: [f64; 2],
    p1: [f64; 2],
    h0: f64,
    h1: f64,
    cuts: &mut Vec<f64>,
) -> (f64, [f64; 2]) {
    let (e, t) = edge_error(s, p0, p1, h0, h1, cuts);
    (
        e,
        [p0[0] + t * (p1[0] - p0[0]), p0[1] + t * (p1[1] - p0[1])],
    )
}

/// [`worst_in_triangle`] with each edge's worst deviation from `edge(k)` (the edge from
/// corner k to corner k + 1; None for an edge not to measure), so that the greedy insertion
/// measures an edge once for both faces that share it.
fn worst_in_triangle_with<S: Surface>(
    s: &S,
    p: [[f64; 2]; 3],
    h: [f64; 3],
    mut edge: impl FnMut(usize) -> Option<(f64, [f64; 2])>,
) -> (f64, [f64; 2]) {
    let mut worst = (0.0f64, p[0]);
    for k in 0..3 {
        if let Some((e, at)) = edge(k) {
            if e > worst.0 {
                worst = (e, at);
            }
        }
    }
    // The plane h = c0 + cx·x + cy·y through the three vertices.
    let (d1, d2) = (
        [p[1][0] - p[0][0], p[1][1] - p[0][1]],
        [p[2][0] - p[0][0], p[2][1] - p[0][1]],
    );
    let det = d1[0] * d2[1] - d1[1] * d2[0];
    if det.abs() < 1e-12 {
        return worst;
    }
    let (g1, g2) = (h[1] - h[0], h[2] - h[0]);
    let cx = (g1 * d2[1] - g2 * d1[1]) / det;
    let cy = (d1[0] * g2 - d2[0] * g1) / det;
    let plane = |x: f64, y: f64| h[0] + cx * (x - p[0][0]) + cy * (y - p[0][1]);
    // Only the nodes over the grid.
    let [cols, rows] = s.size().map(|n| n as i64 - 1);
    let y0 = (p.iter().map(|q| q[1]).fold(f64::INFINITY, f64::min).ceil() as i64).max(0);
    let y1 = (p
        .iter()
        .map(|q| q[1])
        .fold(f64::NEG_INFINITY, f64::max)
        .floor() as i64)
        .min(rows);
    for j in y0..=y1 {
        let y = j as f64;
        // The triangle's extent along the row: where its edges cross it.
        let (mut xl, mut xr) = (f64::INFINITY, f64::NEG_INFINITY);
        for k in 0..3 {
            let (a, b) = (p[k], p[(k + 1) % 3]);
            if (a[1] <= y && y <= b[1]) || (b[1] <= y && y <= a[1]) {
                let x = if a[1] == b[1] {
                    xl = xl.min(a[0].min(b[0]));
                    a[0].max(b[0])
                } else {
                    a[0] + (y - a[1]) / (b[1] - a[1]) * (b[0] - a[0])
                };
                xl = xl.min(x);
                xr = xr.max(x);
            }
        }
        if xl > xr {
            continue;
        }
        for i in (xl.ceil() as i64).max(0)..=(xr.floor() as i64).min(cols) {
            let x = i as f64;
            let e = (plane(x, y) - s.node(i, j)).abs();
            if e > worst.0 {
                worst = (e, [x, y]);
            }
        }
    }
    worst
}

/// The quantized position to insert for face `k` (vertex indices into `out`) whose worst
/// point is at `at` (in quantized units): `at` rounded when that lies in the closed face and
/// is none of its corners nor on the tile's border, else `at` moved towards the face's centroid until it does (a worst
/// point on or near an edge may round to the other side, where inserting it would leave the
/// face as it is); None for a face too small to hold any other quantized position.
fn inside_face(out: &TileTin, k: [usize; 3], at: [f64; 2]) -> Option<[u16; 2]> {
    let c = k.map(|k| out.uv[k].map(i64::from));
    let centroid = [0, 1].map(|d| c.iter().map(|p| p[d] as f64).sum::<f64>() / 3.0);
    let holds = |p: [i64; 2]| {
        (0..3).all(|e| {
            let (a, b) = (c[e], c[(e + 1) % 3]);
            (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) >= 0
        }) && !c.contains(&p)
            // Never on the tile's border, which carries its sides' vertices only.
            && p.iter().all(|&v| (1..i64::from(Q)).contains(&v))
    };
    let mut t = 1.0;
    for _ in 0..24 {
        let p = [0, 1].map(|d| (centroid[d] + t * (at[d] - centroid[d])).round() as i64);
        if holds(p) {
            return Some(p.map(|v| v as u16));
        }
        t *= 0.5;
    }
    None
}

/// The tile with grid map `map`, sides `[south, east, west, north]` (each from
/// [`side_vertices`], south and north running west → east, west and east south → north),
/// triangulated within `tolerance` of the surface. `aspect`: the tile's east–west extent over
/// its north–south extent (metres), so that the Delaunay criterion sees the tile's true shape.
/// At most `max_vertices` vertices (beyond it the tile keeps what it has: a guard against
/// pathological input, far above what the grid's samples need).
pub fn triangulate<S: Surface>(
    s: &S,
    map: &TileMap,
    sides: [&[SideVertex]; 4],
    aspect: f64,
    tolerance: f64,
    max_vertices: usize,
) -> TileTin {
    let [south, east, west, north] = sides;
    let place: [fn(u16) -> [u16; 2]; 4] = [
        |k: u16| [k, 0],
        |k: u16| [Q, k],
        |k: u16| [0, k],
        |k: u16| [k, Q],
    ];
    let mut start = Vec::new();
    for (side, place) in [south, east, west, north].iter().zip(place) {
        for v in side.iter() {
            // Corners come twice (two sides): the second insertion changes nothing.
            start.push((place(v.k), v.p, v.h));
        }
    }
    refine(s, map, &start, aspect, tolerance, max_vertices)
}

/// The greedy insertion of [`triangulate`] into the Delaunay triangulation of the points
/// `start` (quantized u, v; grid position; height), which must hold every point it adds
/// (their convex hull): points already there are skipped, so the result's first vertices
/// are `start`'s distinct ones in order. Used for whole tiles and, by `cells`, for the few
/// grid cells whose twist the closed-form cell triangulations cannot hold.
pub fn refine<S: Surface>(
    s: &S,
    map: &TileMap,
    start: &[([u16; 2], [f64; 2], f64)],
    aspect: f64,
    tolerance: f64,
    max_vertices: usize,
) -> TileTin {
    let q = f64::from(Q);
    let mut out = TileTin::default();
    let mut tri: DelaunayTriangulation<Point2<f64>> = DelaunayTriangulation::new();
    let add = |tri: &mut DelaunayTriangulation<Point2<f64>>,
               out: &mut TileTin,
               uv: [u16; 2],
               p: [f64; 2],
               h: f64,
               hint: Option<FixedVertexHandle>|
     -> Option<FixedVertexHandle> {
        let before = tri.num_vertices();
        let pos = Point2::new(f64::from(uv[0]) * aspect, f64::from(uv[1]));
        let v = match hint {
            Some(hint) => tri.insert_with_hint(pos, hint),
            None => tri.insert(pos),
        }
        .ok()?;
        (tri.num_vertices() > before).then(|| {
            out.uv.push(uv);
            out.p.push(p);
            out.h.push(h);
            v
        })
    };
    for &(uv, p, h) in start {
        add(&mut tri, &mut out, uv, p, h, None);
    }
    let on_border = |uv: [u16; 2], w: [u16; 2]| {
        (uv[0] == w[0] && (uv[0] == 0 || uv[0] == Q))
            || (uv[1] == w[1] && (uv[1] == 0 || uv[1] == Q))
    };
    let mut cuts = Vec::new();
    // Each edge's worst deviation and where, by its vertices (lower first): an edge depends on
    // its ends alone, and the faces around a new vertex keep the old faces' outer edges.
    let mut edges: FxHashMap<(u32, u32), (f64, [f64; 2])> = FxHashMap::default();
    let measure = |tri: &DelaunayTriangulation<Point2<f64>>,
                   out: &TileTin,
                   face: FixedFaceHandle<InnerTag>,
                   cuts: &mut Vec<f64>,
                   edges: &mut FxHashMap<(u32, u32), (f64, [f64; 2])>| {
        let vertices = tri.face(face).vertices().map(|v| v.fix());
        let k = vertices.map(|v| v.index());
        let p = k.map(|k| out.p[k]);
        let h = k.map(|k| out.h[k]);
        let (err, at) = worst_in_triangle_with(s, p, h, |e| {
            let (a, b) = (k[e], k[(e + 1) % 3]);
            if on_border(out.uv[a], out.uv[b]) {
                return None;
            }
            // Measured from its lower-numbered end, once for both faces.
            let (a, b) = (a.min(b), a.max(b));
            Some(
                *edges
                    .entry((a as u32, b as u32))
                    .or_insert_with(|| edge_worst(s, out.p[a], out.p[b], out.h[a], out.h[b], cuts)),
            )
        });
        Candidate {
            err,
            face,
            vertices,
            at,
        }
    };
    let mut heap: BinaryHeap<Candidate> = tri
        .fixed_inner_faces()
        .map(|f| measure(&tri, &out, f, &mut cuts, &mut edges))
        .collect();
    while let Some(c) = heap.pop() {
        if c.err <= tolerance || out.uv.len() >= max_vertices {
            break;
        }
        // A face changed since it was measured is measured again where it changed.
        let current = c.face.index() < tri.num_all_faces()
            && tri.face(c.face).vertices().map(|v| v.fix()) == c.vertices;
        if !current {
            continue;
        }
        let [u, v] = map.inverse(c.at);
        let Some(uv) = inside_face(&out, c.vertices.map(|v| v.index()), [u * q, v * q]) else {
            // No quantized position inside the face but its corners: nothing finer to add.
            continue;
        };
        let p = map.grid(f64::from(uv[0]) / q, f64::from(uv[1]) / q);
        let Some(new) = add(&mut tri, &mut out, uv, p, s.at(p), Some(c.vertices[0])) else {
            continue;
        };
        let faces: Vec<FixedFaceHandle<InnerTag>> = tri
            .vertex(new)
            .out_edges()
            .filter_map(|e| e.face().as_inner().map(|f| f.fix()))
            .collect();
        for f in faces {
            heap.push(measure(&tri, &out, f, &mut cuts, &mut edges));
        }
    }
    out.triangles = tri
        .inner_faces()
        .map(|f| f.vertices().map(|v| v.fix().index() as u32))
        .collect();
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The bilinear surface of a test grid's nodes at `p` (unit cells).
    pub(crate) fn bilinear<S: Surface>(s: &S, p: [f64; 2]) -> f64 {
        let (i0, j0) = (p[0].floor() as i64, p[1].floor() as i64);
        let (di, dj) = (p[0] - i0 as f64, p[1] - j0 as f64);
        (s.node(i0, j0) * (1.0 - di) + s.node(i0 + 1, j0) * di) * (1.0 - dj)
            + (s.node(i0, j0 + 1) * (1.0 - di) + s.node(i0 + 1, j0 + 1) * di) * dj
    }

    /// A grid of unit cells: 0 everywhere but a block of 3 m (a building) and a slope.
    struct Block;
    impl Surface for Block {
        fn at(&self, p: [f64; 2]) -> f64 {
            bilinear(self, p)
        }
        fn node(&self, i: i64, j: i64) -> f64 {
            let (i, j) = (i.clamp(0, 40), j.clamp(0, 40));
            let wall = if (12..20).contains(&i) && (9..25).contains(&j) {
                3.0
            } else {
                0.0
            };
            wall + 0.05 * i as f64 + 0.01 * ((i * 7 + j * 13) % 5) as f64
        }
        fn size(&self) -> [usize; 2] {
            [41, 41]
        }
    }

    /// The slow twin of the exact bound: the TIN against the surface at a dense sampling of
    /// every triangle (`n` steps along each of its sides).
    pub(crate) fn dense_worst<S: Surface>(s: &S, tin: &TileTin, map: &TileMap, n: usize) -> f64 {
        let mut worst = 0.0f64;
        for t in &tin.triangles {
            let k = t.map(|k| k as usize);
            for a in 0..=n {
                for b in 0..=(n - a) {
                    let l = [a as f64 / n as f64, b as f64 / n as f64];
                    let w = [1.0 - l[0] - l[1], l[0], l[1]];
                    let uv = [0, 1].map(|c| {
                        (0..3)
                            .map(|m| w[m] * f64::from(tin.uv[k[m]][c]) / f64::from(Q))
                            .sum::<f64>()
                    });
                    let h: f64 = (0..3).map(|m| w[m] * tin.h[k[m]]).sum();
                    worst = worst.max((h - s.at(map.grid(uv[0], uv[1]))).abs());
                }
            }
        }
        worst
    }

    /// A tile's map points bilinear between `[sw, se, nw, ne]`, and its sides' lines
    /// (south, east, west, north).
    fn map_of(corners: [[f64; 2]; 4]) -> (TileMap, [Vec<[f64; 2]>; 4]) {
        let [c00, c10, c01, c11] = corners;
        let m = M as f64;
        let pt = |a: usize, b: usize| {
            let (u, v) = (a as f64 / m, b as f64 / m);
            [0, 1].map(|k| {
                (c00[k] * (1.0 - u) + c10[k] * u) * (1.0 - v)
                    + (c01[k] * (1.0 - u) + c11[k] * u) * v
            })
        };
        let mut pts = [[0.0; 2]; (M + 1) * (M + 1)];
        for b in 0..=M {
            for a in 0..=M {
                pts[b * (M + 1) + a] = pt(a, b);
            }
        }
        let lines = [
            (0..=M).map(|a| pt(a, 0)).collect(),
            (0..=M).map(|b| pt(M, b)).collect(),
            (0..=M).map(|b| pt(0, b)).collect(),
            (0..=M).map(|a| pt(a, M)).collect(),
        ];
        (TileMap::new(pts), lines)
    }

    fn tile(corners: [[f64; 2]; 4], tol: f64) -> (TileMap, TileTin, [Vec<SideVertex>; 4]) {
        let (map, lines) = map_of(corners);
        let sides = lines.map(|l| side_vertices(&Block, &l, tol));
        let tin = triangulate(
            &Block,
            &map,
            [&sides[0], &sides[1], &sides[2], &sides[3]],
            1.0,
            tol,
            1 << 20,
        );
        (map, tin, sides)
    }

    #[test]
    fn a_turned_tile_holds_the_surface_within_the_tolerance() {
        // A square of 30 cells turned by 0.2 rad over the block.
        let (c, s) = (0.2f64.cos(), 0.2f64.sin());
        let at = |u: f64, v: f64| [3.3 + 30.0 * (c * u - s * v), 2.1 + 30.0 * (s * u + c * v)];
        let corners = [at(0.0, 0.0), at(1.0, 0.0), at(0.0, 1.0), at(1.0, 1.0)];
        let tol = 0.1;
        let (map, tin, sides) = tile(corners, tol);
        let worst = dense_worst(&Block, &tin, &map, 60);
        // Dense sampling never finds more than the exact bound allowed (up to the map's
        // quantisation: a vertex is up to 1/65534 of the tile from where it was chosen).
        assert!(worst <= tol + 1e-6, "{worst}");
        // It needs the block's walls: many vertices, far fewer than the grid's 900 nodes.
        assert!(tin.uv.len() > 30 && tin.uv.len() < 900, "{}", tin.uv.len());
        // The border carries exactly the sides' vertices.
        let on_border = tin
            .uv
            .iter()
            .filter(|p| p[0] == 0 || p[1] == 0 || p[0] == Q || p[1] == Q)
            .count();
        assert_eq!(on_border, sides.iter().map(Vec::len).sum::<usize>() - 4);
        // Every vertex is on the surface; triangles are counter-clockwise and cover the tile.
        for (p, h) in tin.p.iter().zip(&tin.h) {
            assert_eq!(Block.at(*p), *h);
        }
        let mut area = 0.0;
        for t in &tin.triangles {
            let p = t.map(|k| tin.uv[k as usize].map(f64::from));
            let a = (p[1][0] - p[0][0]) * (p[2][1] - p[0][1])
                - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
            assert!(a > 0.0);
            area += a / 2.0;
        }
        assert!((area - f64::from(Q).powi(2)).abs() < 1e-3 * area);
    }

    #[test]
    fn neighbours_share_their_side() {
        // Two tiles side by side: the west one's east side is the east one's west side.
        let tol = 0.05;
        let a = [[0.5, 0.5], [15.5, 0.7], [0.4, 30.2], [15.4, 30.3]];
        let b = [a[1], [30.6, 0.9], a[3], [30.5, 30.4]];
        let (_, west, _) = tile(a, tol);
        let (_, east, _) = tile(b, tol);
        let side = |t: &TileTin, u: u16| {
            let mut v: Vec<(u16, u64)> =
                t.uv.iter()
                    .zip(&t.h)
                    .filter(|(p, _)| p[0] == u)
                    .map(|(p, h)| (p[1], h.to_bits()))
                    .collect();
            v.sort_unstable();
            v
        };
        assert_eq!(side(&west, Q), side(&east, 0));
        assert!(side(&west, Q).len() > 2);
    }

    #[test]
    fn a_plane_needs_only_its_corners() {
        struct Plane;
        impl Surface for Plane {
            fn at(&self, p: [f64; 2]) -> f64 {
                1.0 + 0.3 * p[0] - 0.2 * p[1]
            }
            fn node(&self, i: i64, j: i64) -> f64 {
                self.at([i as f64, j as f64])
            }
            fn size(&self) -> [usize; 2] {
                [100, 100]
            }
        }
        let (map, lines) = map_of([[0.0, 0.0], [20.0, 1.0], [-1.0, 20.0], [19.0, 21.0]]);
        let sides = lines.map(|l| side_vertices(&Plane, &l, 0.01));
        let tin = triangulate(
            &Plane,
            &map,
            [&sides[0], &sides[1], &sides[2], &sides[3]],
            1.0,
            0.01,
            1000,
        );
        assert_eq!(tin.uv.len(), 4);
        assert_eq!(tin.triangles.len(), 2);
    }
}
