//! Continuous-LOD triangulation of a tile from its quadtree (Kim & Shin §2.4 steps
//! (3)–(4), after Röttger et al. 1998): walk the tree top-down, subdivide a node while the
//! criterion asks for it, and at each leaf emit a triangle fan around its centre through its
//! corners and those edge midpoints whose same-size neighbour exists. Where the neighbour is
//! coarser (it does not exist in the tree), the midpoint is skipped, so the fan's edge runs
//! straight along the coarser leaf's edge: no T-junction, no crack.
//!
//! Criteria:
//! - view-independent: subdivide while the node's *vertical error* (the bound of
//!   [`quadtree::vertical_error`], in height units) exceeds the tolerance. Every sample of the
//!   heightfield then lies within the tolerance of the mesh, vertically: a leaf's bound covers
//!   every sample in it for either choice at each edge midpoint, and a finest leaf (d = 2)
//!   reproduces its samples except a skipped midpoint, which lies on the edge of a coarser
//!   leaf whose own bound covers it.
//! - view-dependent (Röttger): subdivide while l / (d · C · max(c · d2, 1)) < 1, with l the
//!   distance from the viewpoint to the node centre (taken at the set's mid height, so that
//!   |l(a) − l(b)| never exceeds the horizontal distance of the centres, which is what the
//!   K-propagation of d2 assumes), d the node's edge length in world units and d2 made
//!   dimensionless by the sample spacing.
//!
//! Existence of a neighbour: the same-size neighbour exists iff its parent is subdivided.
//! Across a tile border, that parent is the mirror of this node's parent, whose value the
//! quadtree reconciliation made equal: extraction of a tile needs no other tile's data.
//!
//! The padding of the last tiles is clipped away: triangles are cut at the last valid sample
//! row and column (planar, so the surface inside is unchanged), and the mesh covers exactly
//! the heightfield. Optional skirts hang from the tile mesh's outer edges.

use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use crate::terrain::quadtree::{self, NodeValues, Quadtree};
use crate::terrain::tiles::TileSet;
use glam::Vec3;
use ndarray::Array2;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::{HashMap, HashSet};

/// Default vertical tolerance of view-independent meshes, metres.
pub const DEFAULT_TOLERANCE_M: f64 = 0.5;
/// Default desired global resolution c of the view-dependent criterion.
pub const DEFAULT_DESIRED_RESOLUTION_C: f64 = 25.0;

/// `[extract]`: how tile meshes (and the wireframe preview) are triangulated.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ExtractParams {
    /// View-independent mode: largest vertical distance, in metres, between any heightfield
    /// sample and the mesh (default 0.5; must be > 0).
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
    /// View-dependent mode: the viewpoint in world coordinates `[x, y, z]`; when given, the
    /// Röttger criterion is used instead of the tolerance.
    #[serde(default, deserialize_with = "crate::terrain::exact_array")]
    pub viewpoint: Option<[f64; 3]>,
    /// Röttger's desired global resolution c of the view-dependent criterion (default 25).
    #[serde(default = "default_c")]
    pub desired_resolution_c: f64,
    /// Depth in metres of skirts hung from every tile mesh's outer edges (default 0: none).
    #[serde(default)]
    pub skirt_depth: f64,
}

fn default_tolerance() -> f64 {
    DEFAULT_TOLERANCE_M
}

fn default_c() -> f64 {
    DEFAULT_DESIRED_RESOLUTION_C
}

impl Default for ExtractParams {
    fn default() -> Self {
        ExtractParams {
            tolerance: DEFAULT_TOLERANCE_M,
            viewpoint: None,
            desired_resolution_c: DEFAULT_DESIRED_RESOLUTION_C,
            skirt_depth: 0.0,
        }
    }
}

impl ExtractParams {
    /// Checks the parameters; errors name the parameter.
    pub fn validate(&self) -> Result<()> {
        let (tol, c, skirt) = (self.tolerance, self.desired_resolution_c, self.skirt_depth);
        for (key, v, in_range, why) in [
            ("tolerance", tol, tol > 0.0, "must be > 0 metres"),
            (
                "desired_resolution_c",
                c,
                c > 0.0,
                "Röttger's c must be > 0",
            ),
            ("skirt_depth", skirt, skirt >= 0.0, "must be ≥ 0 metres"),
        ] {
            if !(v.is_finite() && in_range) {
                return Err(Error::param("extract", key, v, why));
            }
        }
        if let Some(v) = self.viewpoint {
            if !v.iter().all(|c| c.is_finite()) {
                return Err(Error::param(
                    "extract",
                    "viewpoint",
                    format!("{v:?}"),
                    "must be three finite numbers",
                ));
            }
        }
        Ok(())
    }

    /// The criterion these parameters describe for `set` (metres converted to the set's
    /// height units through its CRS; heights are taken in the horizontal unit).
    pub fn criterion(&self, set: &TileSet, qt: &Quadtree) -> Result<Criterion> {
        self.validate()?;
        let unit = set.crs.as_ref().map_or(1.0, |c| c.metres_per_unit());
        Ok(match self.viewpoint {
            None => Criterion::Tolerance {
                max_error: self.tolerance / unit,
            },
            Some(eye) => {
                let z_ref = set
                    .z_range()
                    .map_or(set.z_offset, |(lo, hi)| 0.5 * (lo + hi));
                Criterion::View {
                    eye,
                    min_resolution_c: qt.c,
                    desired_resolution_c: self.desired_resolution_c,
                    z_ref,
                }
            }
        })
    }

    /// Skirt depth in the set's height units.
    pub fn skirt_depth_units(&self, set: &TileSet) -> f64 {
        self.skirt_depth / set.crs.as_ref().map_or(1.0, |c| c.metres_per_unit())
    }
}

/// When a node is subdivided.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Criterion {
    /// While its vertical error bound exceeds `max_error` (height units).
    Tolerance {
        /// The tolerance in height units.
        max_error: f64,
    },
    /// While l / (d · C · max(c · d2, 1)) < 1 for the viewpoint `eye`.
    View {
        /// Viewpoint, world coordinates.
        eye: [f64; 3],
        /// Röttger's C (must be the one d2 was propagated with).
        min_resolution_c: f64,
        /// Röttger's c.
        desired_resolution_c: f64,
        /// Height at which node centres are placed for the distance.
        z_ref: f64,
    },
}

impl Criterion {
    /// True when the criterion reads the vertical error tree.
    pub fn needs_vertical_error(&self) -> bool {
        matches!(self, Criterion::Tolerance { .. })
    }
}

/// The metric arrays and the criterion: decides whether a node is subdivided.
#[derive(Debug, Clone, Copy)]
pub struct Refiner<'a> {
    set: &'a TileSet,
    d2: &'a [NodeValues],
    err: Option<&'a [NodeValues]>,
    criterion: Criterion,
    spacing: f64,
}

impl<'a> Refiner<'a> {
    /// A refiner over `set` with its d2 matrices and, for the tolerance criterion, the
    /// vertical error matrices of [`quadtree::vertical_error`].
    pub fn new(
        set: &'a TileSet,
        qt: &'a Quadtree,
        err: Option<&'a [NodeValues]>,
        criterion: Criterion,
    ) -> Result<Refiner<'a>> {
        if criterion.needs_vertical_error() && err.is_none() {
            return Err(Error::Internal(
                "tolerance extraction without the vertical error tree".into(),
            ));
        }
        Ok(Refiner {
            set,
            d2: &qt.d2,
            err,
            criterion,
            spacing: set.cell_size[0].max(set.cell_size[1]),
        })
    }

    /// Is the node of half edge `r` whose metric sits at (vi, vj) of tile `t`, and whose
    /// centre is at local sample coordinates `pos`, subdivided?
    #[inline]
    pub fn split(&self, t: usize, vi: usize, vj: usize, pos: [f64; 2], r: usize) -> bool {
        match self.criterion {
            Criterion::Tolerance { max_error } => {
                let err = self.err.expect("checked in new");
                err[t].get(vi, vj) as f64 > max_error
            }
            Criterion::View {
                eye,
                min_resolution_c,
                desired_resolution_c,
                z_ref,
            } => {
                let tile = &self.set.tiles[t];
                let [x, y] = self.set.sample_xy(
                    tile.origin[0] as f64 + pos[0],
                    tile.origin[1] as f64 + pos[1],
                );
                let l =
                    ((eye[0] - x).powi(2) + (eye[1] - y).powi(2) + (eye[2] - z_ref).powi(2)).sqrt();
                let d = (2 * r) as f64 * self.spacing;
                let d2 = self.d2[t].get(vi, vj) as f64 / self.spacing;
                l < d * min_resolution_c * (desired_resolution_c * d2).max(1.0)
            }
        }
    }
}

/// The triangulation of one tile, in the tile's sample coordinates.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TileTriangulation {
    /// Index of the tile in `TileSet::tiles`.
    pub tile: usize,
    /// Vertex positions as local sample coordinates (i, j); fractional only where clipped.
    pub uv: Vec<[f64; 2]>,
    /// Vertex heights relative to the set's `z_offset`.
    pub z: Vec<f32>,
    /// Triangles, counter-clockwise seen from above.
    pub triangles: Vec<[u32; 3]>,
    /// The first `surface_triangles` triangles are the terrain; the rest are skirts.
    pub surface_triangles: usize,
}

/// What the extraction stage leaves: every tile's triangulation, and how they were made
/// (the encoders write both, the manifest the latter).
#[derive(Debug, Clone, PartialEq)]
pub struct TileMeshes {
    /// One triangulation per tile, in `TileSet::tiles` order (skirts included when asked).
    pub tiles: Vec<TileTriangulation>,
    /// Surface triangles over all tiles (skirts not counted).
    pub triangles: usize,
    /// The refinement criterion in words (tolerance or viewpoint, with its constants).
    pub criterion: String,
    /// Skirt depth in the set's height units (0: no skirts).
    pub skirt_depth: f64,
}

impl TileMeshes {
    /// Tile `t`'s mesh as a [`TriMesh`] (see [`to_trimesh`]).
    pub fn trimesh(&self, set: &TileSet, t: usize) -> TriMesh {
        to_trimesh(set, &self.tiles[t])
    }
}

/// The extraction stage: triangulates every tile of `set` as `params` say (with skirts when
/// asked). Fails if the set has holes (a mesh needs a filled heightfield).
pub fn extract_meshes(set: &TileSet, qt: &Quadtree, params: &ExtractParams) -> Result<TileMeshes> {
    let criterion = params.criterion(set, qt)?;
    // Refuse holes before spending time on the error tree.
    check_no_holes(set)?;
    let err = error_tree(set, &criterion);
    let refiner = Refiner::new(set, qt, err.as_deref(), criterion)?;
    let mut tiles = extract(set, &refiner)?;
    let skirt_depth = params.skirt_depth_units(set);
    let depth = skirt_depth as f32;
    if depth > 0.0 {
        tiles.par_iter_mut().for_each(|t| add_skirts(t, depth));
    }
    Ok(TileMeshes {
        triangles: tiles.iter().map(|t| t.surface_triangles).sum(),
        tiles,
        criterion: criterion_text(params, &criterion),
        skirt_depth,
    })
}

/// `criterion` in words, for the manifest.
fn criterion_text(params: &ExtractParams, criterion: &Criterion) -> String {
    match *criterion {
        Criterion::Tolerance { max_error } => format!(
            "view-independent: every sample within {} m ({max_error} height units) of the mesh",
            params.tolerance
        ),
        Criterion::View {
            eye,
            min_resolution_c,
            desired_resolution_c,
            ..
        } => format!(
            "view-dependent (Röttger): viewpoint {eye:?}, C = {min_resolution_c}, c = {desired_resolution_c}"
        ),
    }
}

/// The error for a set with masked holes: a mesh needs a filled heightfield.
pub fn check_no_holes(set: &TileSet) -> Result<()> {
    let holes = set.holes();
    if holes > 0 {
        return Err(Error::Data {
            stage: "extract",
            message: format!(
                "the heightfield has {holes} masked hole samples; meshes need a filled heightfield \
                 (choose a fill fallback other than \"nodata\", or set output.meshes = [] and output.wireframe = false)"
            ),
        });
    }
    Ok(())
}

/// Triangulates every tile; fails if the set has holes (a mesh needs a filled heightfield).
pub fn extract(set: &TileSet, refiner: &Refiner<'_>) -> Result<Vec<TileTriangulation>> {
    check_no_holes(set)?;
    Ok((0..set.tiles.len())
        .into_par_iter()
        .map(|t| extract_tile(set, t, refiner))
        .collect())
}

/// Ring around a node centre, counter-clockwise from the south-west corner; odd entries are
/// edge midpoints (S, E, N, W).
const RING: [(isize, isize); 8] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (1, 0),
    (1, 1),
    (0, 1),
    (-1, 1),
    (-1, 0),
];

struct Walker<'r, 'a> {
    refiner: &'r Refiner<'a>,
    t: usize,
    n: usize,
    col: usize,
    row: usize,
    grid: [usize; 2],
    heights: &'r Array2<f32>,
    index: Vec<u32>,
    out: TileTriangulation,
}

impl Walker<'_, '_> {
    fn vertex(&mut self, i: usize, j: usize) -> u32 {
        let slot = &mut self.index[j * self.n + i];
        if *slot == u32::MAX {
            *slot = self.out.uv.len() as u32;
            self.out.uv.push([i as f64, j as f64]);
            self.out.z.push(self.heights[[j, i]]);
        }
        *slot
    }

    fn visit(&mut self, ci: usize, cj: usize, r: usize) {
        if r > 1
            && self
                .refiner
                .split(self.t, ci, cj, [ci as f64, cj as f64], r)
        {
            let q = r / 2;
            self.visit(ci - q, cj - q, q);
            self.visit(ci + q, cj - q, q);
            self.visit(ci - q, cj + q, q);
            self.visit(ci + q, cj + q, q);
        } else {
            self.fan(ci, cj, r);
        }
    }

    /// Does the same-size neighbour of node (ci, cj, r) in direction (dx, dy) exist?
    fn neighbour_exists(&self, ci: usize, cj: usize, r: usize, dx: isize, dy: isize) -> bool {
        let d = 2 * r;
        if d == self.n - 1 {
            // Roots always exist (or there is nothing across the border).
            return true;
        }
        let big = 2 * d as isize;
        let parent = |c: isize| (c - r as isize).div_euclid(big) * big + d as isize;
        let (nci, ncj) = (ci as isize + dx * d as isize, cj as isize + dy * d as isize);
        let (pci, pcj) = (parent(nci), parent(ncj));
        let (own_i, own_j) = (parent(ci as isize), parent(cj as isize));
        if (pci, pcj) == (own_i, own_j) {
            return true;
        }
        let last = self.n as isize - 1;
        let inside = (0..=last).contains(&nci) && (0..=last).contains(&ncj);
        if inside {
            return self.refiner.split(
                self.t,
                pci as usize,
                pcj as usize,
                [pci as f64, pcj as f64],
                d,
            );
        }
        let (tc, tr) = (self.col as isize + dx, self.row as isize + dy);
        if tc < 0 || tr < 0 || tc >= self.grid[0] as isize || tr >= self.grid[1] as isize {
            // Outer edge of the terrain: nothing to match.
            return true;
        }
        // Across the border: the neighbour's parent is our parent's mirror (same value).
        self.refiner.split(
            self.t,
            own_i as usize,
            own_j as usize,
            [pci as f64, pcj as f64],
            d,
        )
    }

    fn fan(&mut self, ci: usize, cj: usize, r: usize) {
        let c = self.vertex(ci, cj);
        let mut ring = [0u32; 8];
        let mut len = 0;
        for (k, &(dx, dy)) in RING.iter().enumerate() {
            if k % 2 == 1 && !self.neighbour_exists(ci, cj, r, dx, dy) {
                continue;
            }
            let i = (ci as isize + dx * r as isize) as usize;
            let j = (cj as isize + dy * r as isize) as usize;
            ring[len] = self.vertex(i, j);
            len += 1;
        }
        for k in 0..len {
            self.out.triangles.push([c, ring[k], ring[(k + 1) % len]]);
        }
    }
}

/// Triangulates tile `t` (surface only, clipped to the valid extent).
pub fn extract_tile(set: &TileSet, t: usize, refiner: &Refiner<'_>) -> TileTriangulation {
    let n = set.tile_size;
    let tile = &set.tiles[t];
    let mut w = Walker {
        refiner,
        t,
        n,
        col: tile.col,
        row: tile.row,
        grid: set.grid,
        heights: &tile.heights,
        index: vec![u32::MAX; n * n],
        out: TileTriangulation {
            tile: t,
            ..Default::default()
        },
    };
    let root = (n - 1) / 2;
    w.visit(root, root, root);
    let mut out = w.out;
    if tile.valid[0] < n {
        clip(&mut out, 0, (tile.valid[0] - 1) as f64);
    }
    if tile.valid[1] < n {
        clip(&mut out, 1, (tile.valid[1] - 1) as f64);
    }
    out.surface_triangles = out.triangles.len();
    out
}

/// Cuts the triangulation at coordinate `axis` = `limit`, keeping the side below. The
/// surface is planar per triangle, so new vertices are linear interpolations; an edge shared
/// by two triangles is cut from its inside end in both, giving the same vertex.
fn clip(tri: &mut TileTriangulation, axis: usize, limit: f64) {
    let old = std::mem::take(&mut tri.triangles);
    let mut made: HashMap<(u64, u64), u32> = HashMap::new();
    for t in old {
        let inside = t.map(|v| tri.uv[v as usize][axis] <= limit);
        if inside.iter().all(|&b| b) {
            tri.triangles.push(t);
            continue;
        }
        if !inside.iter().any(|&b| b) {
            continue;
        }
        let mut poly: Vec<u32> = Vec::with_capacity(4);
        for k in 0..3 {
            let (p, q) = (t[k], t[(k + 1) % 3]);
            let (pin, qin) = (inside[k], inside[(k + 1) % 3]);
            if pin {
                poly.push(p);
            }
            if pin != qin {
                let (a, b) = if pin { (p, q) } else { (q, p) };
                let v = cut(tri, &mut made, a, b, axis, limit);
                if poly.last() != Some(&v) {
                    poly.push(v);
                }
            }
        }
        poly.dedup();
        while poly.len() > 1 && poly.first() == poly.last() {
            poly.pop();
        }
        for k in 1..poly.len().saturating_sub(1) {
            let f = [poly[0], poly[k], poly[k + 1]];
            if area2(tri, f) > 0.0 {
                tri.triangles.push(f);
            }
        }
    }
}

/// The point where edge a (inside) → b (outside) crosses `axis` = `limit`.
fn cut(
    tri: &mut TileTriangulation,
    made: &mut HashMap<(u64, u64), u32>,
    a: u32,
    b: u32,
    axis: usize,
    limit: f64,
) -> u32 {
    let (pa, pb) = (tri.uv[a as usize], tri.uv[b as usize]);
    if pa[axis] == limit {
        return a;
    }
    let s = (limit - pa[axis]) / (pb[axis] - pa[axis]);
    let mut p = [pa[0] + s * (pb[0] - pa[0]), pa[1] + s * (pb[1] - pa[1])];
    p[axis] = limit;
    let key = (p[0].to_bits(), p[1].to_bits());
    if let Some(&v) = made.get(&key) {
        return v;
    }
    let (za, zb) = (tri.z[a as usize] as f64, tri.z[b as usize] as f64);
    let v = tri.uv.len() as u32;
    tri.uv.push(p);
    tri.z.push((za + s * (zb - za)) as f32);
    made.insert(key, v);
    v
}

/// Twice the signed area of triangle `f` in sample coordinates.
fn area2(tri: &TileTriangulation, f: [u32; 3]) -> f64 {
    let [a, b, c] = f.map(|v| tri.uv[v as usize]);
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// Hangs skirts of `depth` height units from the outer edges of the surface.
pub fn add_skirts(tri: &mut TileTriangulation, depth: f32) {
    if depth <= 0.0 {
        return;
    }
    let surface = &tri.triangles[..tri.surface_triangles];
    let directed: HashSet<(u32, u32)> = surface
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .collect();
    let boundary: Vec<(u32, u32)> = surface
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .filter(|&(a, b)| !directed.contains(&(b, a)))
        .collect();
    let mut lowered: HashMap<u32, u32> = HashMap::new();
    let mut low = |tri: &mut TileTriangulation, v: u32| -> u32 {
        *lowered.entry(v).or_insert_with(|| {
            let k = tri.uv.len() as u32;
            tri.uv.push(tri.uv[v as usize]);
            tri.z.push(tri.z[v as usize] - depth);
            k
        })
    };
    for (a, b) in boundary {
        let (la, lb) = (low(tri, a), low(tri, b));
        // The outside is to the right of a → b: these face outwards.
        tri.triangles.push([a, lb, b]);
        tri.triangles.push([a, la, lb]);
    }
}

/// A tile triangulation as a mesh: positions relative to the set's first sample centre
/// (x east, y north, z up, z relative to `z_offset`), normals from the whole heightfield's
/// gradient (so they agree across tile borders whatever the level of detail).
///
/// Only the vertices the triangles use are kept (the triangulation also holds vertices of
/// the clipped padding and of left-out midpoints): they keep their relative order and the
/// indices are remapped, so the same triangulation always gives the same mesh.
pub fn to_trimesh(set: &TileSet, tri: &TileTriangulation) -> TriMesh {
    let tile = &set.tiles[tri.tile];
    let [cx, cy] = set.cell_size;
    // New index of every used vertex, in the old order; u32::MAX for unused ones.
    let mut remap = vec![u32::MAX; tri.uv.len()];
    for f in &tri.triangles {
        for &v in f {
            remap[v as usize] = 0;
        }
    }
    let mut used = Vec::new();
    for (old, slot) in remap.iter_mut().enumerate() {
        if *slot == 0 {
            *slot = used.len() as u32;
            used.push(old);
        }
    }
    let positions: Vec<Vec3> = used
        .iter()
        .map(|&v| {
            let p = tri.uv[v];
            let gi = tile.origin[0] as f64 + p[0];
            let gj = tile.origin[1] as f64 + p[1];
            Vec3::new((gi * cx) as f32, (gj * cy) as f32, tri.z[v])
        })
        .collect();
    let normals: Vec<Vec3> = used
        .iter()
        .map(|&v| {
            let p = tri.uv[v];
            normal_at(
                set,
                tile.origin[0] as f64 + p[0],
                tile.origin[1] as f64 + p[1],
            )
        })
        .collect();
    let indices = tri
        .triangles
        .iter()
        .map(|f| f.map(|v| remap[v as usize]))
        .collect();
    TriMesh {
        positions,
        indices,
        normals: Some(normals),
        colors: None,
        uvs: None,
    }
}

/// Height at global sample (i, j), clamped to the grid.
pub fn height_at(set: &TileSet, i: usize, j: usize) -> f32 {
    let step = set.tile_size - 1;
    let i = i.min(set.samples[0] - 1);
    let j = j.min(set.samples[1] - 1);
    let col = (i / step).min(set.grid[0] - 1);
    let row = (j / step).min(set.grid[1] - 1);
    let t = &set.tiles[set.index(col, row)];
    t.heights[[j - t.origin[1], i - t.origin[0]]]
}

/// Unit normal of the heightfield at global sample (i, j) by central differences (one-sided
/// at the grid's edge).
fn grid_normal(set: &TileSet, i: usize, j: usize) -> [f64; 3] {
    let [cols, rows] = set.samples;
    let (i0, i1) = (i.saturating_sub(1), (i + 1).min(cols - 1));
    let (j0, j1) = (j.saturating_sub(1), (j + 1).min(rows - 1));
    let dx = (height_at(set, i1, j) - height_at(set, i0, j)) as f64
        / ((i1 - i0).max(1) as f64 * set.cell_size[0]);
    let dy = (height_at(set, i, j1) - height_at(set, i, j0)) as f64
        / ((j1 - j0).max(1) as f64 * set.cell_size[1]);
    let len = (dx * dx + dy * dy + 1.0).sqrt();
    [-dx / len, -dy / len, 1.0 / len]
}

/// Normal at global sample coordinates (possibly fractional: linear between samples).
fn normal_at(set: &TileSet, gi: f64, gj: f64) -> Vec3 {
    let (i0, j0) = (gi.floor(), gj.floor());
    let (fi, fj) = (gi - i0, gj - j0);
    let (i0, j0) = (i0 as usize, j0 as usize);
    let mut n = [0.0f64; 3];
    for (i, j, w) in [
        (i0, j0, (1.0 - fi) * (1.0 - fj)),
        (i0 + 1, j0, fi * (1.0 - fj)),
        (i0, j0 + 1, (1.0 - fi) * fj),
        (i0 + 1, j0 + 1, fi * fj),
    ] {
        if w > 0.0 {
            let g = grid_normal(set, i, j);
            for k in 0..3 {
                n[k] += w * g[k];
            }
        }
    }
    Vec3::new(n[0] as f32, n[1] as f32, n[2] as f32).normalize()
}

/// Builds the vertical error tree when `criterion` needs it.
pub fn error_tree(set: &TileSet, criterion: &Criterion) -> Option<Vec<NodeValues>> {
    criterion
        .needs_vertical_error()
        .then(|| quadtree::vertical_error(set))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::quadtree::{build, QuadtreeParams};
    use crate::terrain::testutil::{field, tiles_of};
    use crate::terrain::CellState;

    /// Runs `f` with a view-independent refiner of `set` at `max_error`.
    fn with_tolerance(set: &TileSet, max_error: f64, f: impl FnOnce(&Refiner)) {
        let qt = build(set, &QuadtreeParams::default()).unwrap();
        let err = quadtree::vertical_error(set);
        let r = Refiner::new(set, &qt, Some(&err), Criterion::Tolerance { max_error }).unwrap();
        f(&r)
    }

    #[test]
    fn a_plane_is_two_fans_worth_of_triangles() {
        let hf = field(65, 65, |i, j| i as f32 * 0.5 + j as f32);
        let set = tiles_of(&hf, 65);
        with_tolerance(&set, 0.01, |r| {
            let tris = extract(&set, r).unwrap();
            // Root leaf with all four midpoints (outer edges include them): 8 triangles, 9 vertices.
            assert_eq!(tris[0].triangles.len(), 8);
            assert_eq!(tris[0].uv.len(), 9);
        });
    }

    #[test]
    fn holes_refuse_meshes() {
        let mut hf = field(65, 65, |_, _| 1.0);
        hf.heights[[3, 3]] = f32::NAN;
        hf.state[[3, 3]] = CellState::Empty;
        let set = tiles_of(&hf, 65);
        with_tolerance(&set, 0.01, |r| {
            let e = extract(&set, r).unwrap_err().to_string();
            assert!(
                e.starts_with("extract: the heightfield has 1 masked hole samples"),
                "{e}"
            );
        });
    }

    #[test]
    fn params_are_checked() {
        for t in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let p = ExtractParams {
                tolerance: t,
                ..Default::default()
            };
            let e = p.validate().unwrap_err().to_string();
            assert!(e.starts_with("extract: tolerance = "), "{e}");
            assert!(e.ends_with("must be > 0 metres"), "{e}");
        }
        assert!(ExtractParams {
            skirt_depth: -1.0,
            ..Default::default()
        }
        .validate()
        .is_err());
        assert!(ExtractParams {
            desired_resolution_c: 0.0,
            ..Default::default()
        }
        .validate()
        .is_err());
    }

    #[test]
    fn clipping_keeps_the_valid_extent_only() {
        let hf = field(100, 70, |i, j| ((i * 7 + j * 13) % 5) as f32);
        let set = tiles_of(&hf, 65);
        with_tolerance(&set, 0.5, |r| {
            let tris = extract(&set, r).unwrap();
            let t = &tris[set.index(1, 1)];
            let tile = &set.tiles[t.tile];
            assert_eq!(tile.valid, [36, 6]);
            let mut area = 0.0;
            for f in &t.triangles {
                for v in f {
                    let p = t.uv[*v as usize];
                    assert!(p[0] <= 35.0 && p[1] <= 5.0);
                }
                area += area2(t, *f) / 2.0;
            }
            assert!((area - 35.0 * 5.0).abs() < 1e-9, "{area}");
        });
    }

    #[test]
    fn skirts_face_outwards_and_close_the_border() {
        let hf = field(65, 65, |i, j| (i as f32 * 0.3).sin() + j as f32 * 0.1);
        let set = tiles_of(&hf, 65);
        with_tolerance(&set, 0.05, |r| {
            let mut t = extract_tile(&set, 0, r);
            let surface = t.triangles.len();
            add_skirts(&mut t, 2.0);
            assert_eq!(t.surface_triangles, surface);
            assert!(t.triangles.len() > surface);
            let m = to_trimesh(&set, &t);
            for f in &m.indices[surface..] {
                let [a, b, c] = f.map(|v| m.positions[v as usize]);
                let n = (b - a).cross(c - a);
                assert!(n.z.abs() < 1e-6, "skirts are vertical");
                // Outward: away from the tile centre.
                let mid = (a + b + c) / 3.0 - Vec3::new(32.0, 32.0, 0.0);
                assert!(n.x * mid.x + n.y * mid.y > 0.0);
            }
        });
    }
}
