//! The terrain of a Cesium tileset: the set's heights resampled onto the tiles of the
//! geographic TMS tiling scheme (EPSG:4326; level z has 2^(z+1) × 2^z tiles of 180/2^z
//! degrees, two root tiles, rows counted from the south) and triangulated per level by the
//! same Röttger quadtree / vertical-tolerance extractor as the tile meshes.
//!
//! Each level is made into a [`TileSet`] of its own whose samples are a regular
//! longitude/latitude lattice, 64 intervals per tileset tile (tile size 65), and whose tiles
//! are exactly the TMS tiles covering the survey. The quadtree's reconciliation across tile
//! borders then makes neighbouring tiles of a level split their shared edges alike: shared
//! edge vertices are identical, no cracks, no T-junctions (see `terrain::extract`).
//!
//! The level matching the grid's spacing is different: a lattice turned against the grid and
//! not passing through its samples cuts corners at walls, so there each tile is an adaptive
//! triangulation of the grid's own bilinear surface (`tin`: vertices on that surface, every
//! triangle within the tolerance of it everywhere, each tile side simplified once for both
//! tiles that share it, so their edge vertices are identical).
//!
//! Heights: each lattice sample is projected into the input's CRS (proj4rs) and sampled
//! bilinearly from the filled grid; outside the survey the grid's edge is continued
//! (coordinates clamped), so tiles that reach past the survey have no cliffs. Heights are the
//! input's, in metres: orthometric for the surveys here (terratile has no geoid model), which
//! Cesium draws as if they were ellipsoidal (an offset of the geoid undulation, tens of metres).
//!
//! Speed: on small tiles (≤ [`LATTICE_MAX_DEGREES`]) only every [`LATTICE`]-th sample (and
//! the tile's corners and edges at that spacing) is projected exactly; the others are
//! bilinear between them. Over ≤ 0.01° a map projection's second derivative (≈ 1/R) makes
//! that error ≤ L²/(8R) ≈ 0.3 mm for L = 1/8 of the tile, far below a height sample's
//! influence. Shared border samples are computed from the same border lattice points, so
//! they are bit-identical in both tiles.

use crate::error::{Error, Result};
use crate::geo::{cells, tin, ToWgs84};
use crate::terrain::extract::{self, Criterion, ExtractParams, Refiner, TileTriangulation};
use crate::terrain::quadtree::{self, NodeValues, Quadtree};
use crate::terrain::{Tile, TileSet};
use ndarray::Array2;
use rayon::prelude::*;

/// Share of a tile's grid nodes bending beyond the tolerance (`cells::roughness`) from which
/// its most detailed mesh is the grid's cells rather than a greedy insertion.
pub const DENSE_SHARE: f64 = 0.2;
/// Intervals per tileset tile side (65 samples, Cesium's own heightmap tiles' size).
pub const TILE_INTERVALS: usize = 64;
/// Projection lattice step (samples) on small tiles.
pub const LATTICE: usize = 8;
/// Largest tile span (degrees) projected through the lattice; larger tiles project every
/// sample.
pub const LATTICE_MAX_DEGREES: f64 = 0.01;
/// The finest level terratile writes in full (tiles of 180/2^22 degrees, ≈ 4.8 m).
pub const MAX_LEVEL: u32 = 22;
/// WGS 84 semi-major axis and flattening.
const WGS84_A: f64 = 6_378_137.0;
const WGS84_F: f64 = 1.0 / 298.257_223_563;

/// Tiles of a level covering the survey: inclusive column and row ranges.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TileRange {
    /// Level.
    pub z: u32,
    /// First and last column (east from −180°).
    pub x: [u32; 2],
    /// First and last row (north from −90°).
    pub y: [u32; 2],
}

/// One tile of the tileset, ready for the encoder.
#[derive(Debug, Clone, PartialEq)]
pub struct TerrainTile {
    /// Level, column, row (TMS: row 0 at the south pole).
    pub zxy: [u32; 3],
    /// [west, south, east, north], degrees.
    pub bounds: [f64; 4],
    /// Vertex positions quantized east and north within the tile (0..=32767, quantized-mesh's
    /// u and v), in the order of their first use by `triangles` (what high-water-mark coding
    /// needs).
    pub uv: Vec<[u16; 2]>,
    /// Vertex heights, metres.
    pub heights: Vec<f64>,
    /// Unit vertex normals in the Earth-centred, Earth-fixed frame.
    pub normals: Vec<[f32; 3]>,
    /// Triangles, counter-clockwise seen from above.
    pub triangles: Vec<[u32; 3]>,
}

/// The whole tileset: per level the tiles it has, and every tile.
#[derive(Debug, Clone)]
pub struct Tileset {
    /// Per level, level 0 first, the rectangles of tiles it has (one down to the level
    /// matching the grid's spacing, which cover the survey; the partial levels below it
    /// as many as their tiles need).
    pub levels: Vec<Vec<TileRange>>,
    /// WGS 84 bounds of the survey [west, south, east, north].
    pub bounds: [f64; 4],
    /// The tiles, level by level, rows from the south, columns from the west.
    pub tiles: Vec<TerrainTile>,
    /// Vertical tolerance the meshes were extracted with, metres.
    pub tolerance_m: f64,
}

/// Tile span of level `z`, degrees.
pub fn tile_degrees(z: u32) -> f64 {
    180.0 / f64::from(1u32 << z)
}

/// [west, south, east, north] of tile (z, x, y).
pub fn tile_bounds(z: u32, x: u32, y: u32) -> [f64; 4] {
    let s = tile_degrees(z);
    [
        -180.0 + f64::from(x) * s,
        -90.0 + f64::from(y) * s,
        -180.0 + f64::from(x + 1) * s,
        -90.0 + f64::from(y + 1) * s,
    ]
}

/// The finest level whose lattice is not finer than the grid's spacing of `cell_m` metres
/// (between 1 and 2 cells per lattice step: no invented detail, and a quarter of the samples
/// of the next level): the spacing of level z is about 2πR/(2·2^z·64) north–south.
pub fn finest_level(cell_m: f64) -> u32 {
    let metres_per_degree = WGS84_A * std::f64::consts::PI / 180.0;
    let z0 = tile_degrees(0) / TILE_INTERVALS as f64 * metres_per_degree;
    let z = (z0 / cell_m).log2().floor();
    if z.is_finite() {
        z.clamp(0.0, f64::from(MAX_LEVEL)) as u32
    } else {
        0
    }
}

/// Tiles of level `z` over `bounds` (both root tiles at level 0).
pub fn tile_range(z: u32, bounds: [f64; 4]) -> TileRange {
    if z == 0 {
        return TileRange {
            z,
            x: [0, 1],
            y: [0, 0],
        };
    }
    let s = tile_degrees(z);
    let (nx, ny) = (2u32 << z, 1u32 << z);
    let cell =
        |v: f64, origin: f64, n: u32| (((v - origin) / s).floor().max(0.0) as u32).min(n - 1);
    TileRange {
        z,
        x: [cell(bounds[0], -180.0, nx), cell(bounds[2], -180.0, nx)],
        y: [cell(bounds[1], -90.0, ny), cell(bounds[3], -90.0, ny)],
    }
}

/// WGS 84 bounds of `set`'s outer extent, from 64 points per side of its outline.
pub fn survey_bounds(set: &TileSet, t: &ToWgs84) -> Option<[f64; 4]> {
    let [x0, y0] = set.corner;
    let x1 = x0 + set.samples[0] as f64 * set.cell_size[0];
    let y1 = y0 + set.samples[1] as f64 * set.cell_size[1];
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for k in 0..=64 {
        let f = k as f64 / 64.0;
        let (x, y) = (x0 + f * (x1 - x0), y0 + f * (y1 - y0));
        for (px, py) in [(x, y0), (x, y1), (x0, y), (x1, y)] {
            let [lon, lat] = t.forward(px, py)?;
            b = [b[0].min(lon), b[1].min(lat), b[2].max(lon), b[3].max(lat)];
        }
    }
    Some(b)
}

/// The error `[output] quantized_mesh` gives when `set` cannot make a tileset (no CRS, a CRS
/// the reprojection cannot handle, holes); None when it can.
pub fn check(set: &TileSet) -> Result<ToWgs84> {
    let key = |m: String| Error::key("output.quantized_mesh", m);
    let crs = set.crs.as_ref().ok_or_else(|| {
        key("a Cesium tileset needs the survey's CRS: the input states none; set [input] crs = \"EPSG:n\"".into())
    })?;
    let t = ToWgs84::new(crs).map_err(|e| key(format!("{e}; the Cesium tileset needs it")))?;
    survey_bounds(set, &t)
        .ok_or_else(|| key("the grid's outline falls outside the CRS's projection".into()))?;
    let holes = set.holes();
    if holes > 0 {
        return Err(key(format!(
            "the heightfield has {holes} masked hole samples; terrain tiles need a filled heightfield \
             (choose a fill fallback other than \"nodata\")"
        )));
    }
    Ok(t)
}

/// The source grid: heights in metres, and where a CRS position falls in it.
struct Source<'a> {
    /// The grid's heights, row-major from the south-west (`grid[j * cols + i]`): a flat
    /// slice, for the bilinear lookups that are most of the adaptive level's time.
    grid: Vec<f32>,
    cols: usize,
    rows: usize,
    set: &'a TileSet,
    to_wgs84: &'a ToWgs84,
    unit: f64,
    bounds: [f64; 4],
}

impl Source<'_> {
    /// Fractional grid sample coordinates of (lon, lat), or None outside the projection.
    fn grid_ij(&self, lon: f64, lat: f64) -> Option<[f64; 2]> {
        let [x, y] = self.to_wgs84.inverse(lon, lat)?;
        Some([
            (x - self.set.corner[0]) / self.set.cell_size[0] - 0.5,
            (y - self.set.corner[1]) / self.set.cell_size[1] - 0.5,
        ])
    }

    /// Height in metres at fractional grid coordinates, bilinear, clamped to the grid.
    fn height(&self, [fi, fj]: [f64; 2]) -> f64 {
        let (rows, cols) = (self.rows, self.cols);
        let fi = fi.clamp(0.0, (cols - 1) as f64);
        let fj = fj.clamp(0.0, (rows - 1) as f64);
        let (i0, j0) = ((fi as usize).min(cols - 2), (fj as usize).min(rows - 2));
        let (di, dj) = (fi - i0 as f64, fj - j0 as f64);
        let at = j0 * cols + i0;
        let (south, north) = (&self.grid[at..at + 2], &self.grid[at + cols..at + cols + 2]);
        let h = |row: &[f32], k: usize| f64::from(row[k]);
        let v = (h(south, 0) * (1.0 - di) + h(south, 1) * di) * (1.0 - dj)
            + (h(north, 0) * (1.0 - di) + h(north, 1) * di) * dj;
        (self.set.z_offset + v) * self.unit
    }
}

/// Heights of tile (z, x, y)'s lattice with a one-sample apron: `(n + 3)²` values, index
/// `(j + 1) * (n + 3) + (i + 1)` for lattice (i, j), i, j in −1..=n+1.
fn tile_heights(src: &Source<'_>, z: u32, x: u32, y: u32) -> Vec<f64> {
    let n = TILE_INTERVALS;
    let w = n + 3;
    let step = tile_degrees(z) / n as f64;
    // Global lattice index → degrees: the same integers in both tiles of a shared border.
    let gi0 = (x as usize * n) as f64;
    let gj0 = (y as usize * n) as f64;
    let lonlat = |i: isize, j: isize| {
        [
            -180.0 + (gi0 + i as f64) * step,
            -90.0 + (gj0 + j as f64) * step,
        ]
    };
    let mut out = vec![0.0; w * w];
    let mut put = |i: isize, j: isize, ij: [f64; 2]| {
        out[(j + 1) as usize * w + (i + 1) as usize] = src.height(ij);
    };
    if tile_degrees(z) <= LATTICE_MAX_DEGREES {
        let m = n / LATTICE + 1;
        // A lattice point outside the projection (never the case this close to a survey)
        // falls back to the grid's centre rather than failing the whole tileset.
        let centre = [(src.cols / 2) as f64, (src.rows / 2) as f64];
        let mut lat_ij = vec![[0.0; 2]; m * m];
        for b in 0..m {
            for a in 0..m {
                let [lon, lat] = lonlat((a * LATTICE) as isize, (b * LATTICE) as isize);
                lat_ij[b * m + a] = src.grid_ij(lon, lat).unwrap_or(centre);
            }
        }
        for j in -1..=(n as isize + 1) {
            for i in -1..=(n as isize + 1) {
                // The lattice cell holding (i, j) (apron samples extrapolate the edge cells).
                let a = ((i.max(0) as usize) / LATTICE).min(m - 2);
                let b = ((j.max(0) as usize) / LATTICE).min(m - 2);
                let fa = (i - (a * LATTICE) as isize) as f64 / LATTICE as f64;
                let fb = (j - (b * LATTICE) as isize) as f64 / LATTICE as f64;
                let p = |a: usize, b: usize| lat_ij[b * m + a];
                let mut ij = [0.0; 2];
                for (k, v) in ij.iter_mut().enumerate() {
                    *v = (p(a, b)[k] * (1.0 - fa) + p(a + 1, b)[k] * fa) * (1.0 - fb)
                        + (p(a, b + 1)[k] * (1.0 - fa) + p(a + 1, b + 1)[k] * fa) * fb;
                }
                put(i, j, ij);
            }
        }
    } else {
        let [bw, bs, be, bn] = src.bounds;
        for j in -1..=(n as isize + 1) {
            for i in -1..=(n as isize + 1) {
                let [lon, lat] = lonlat(i, j);
                // Far from the survey the projection may be undefined: clamp to its bounds.
                let ij = src
                    .grid_ij(lon.clamp(bw, be), lat.clamp(bs, bn))
                    .unwrap_or([0.0, 0.0]);
                put(i, j, ij);
            }
        }
    }
    out
}

/// A tile's lattice lines on the ellipsoid, for its vertex normals: per column the sine and
/// cosine of the longitude, per row those of the latitude and the metres per radian east
/// (prime vertical radius × cos φ) and north (meridian radius). Computed once per tile, not
/// per vertex (the trigonometry was most of the normals' time).
struct Frame {
    lon: Vec<[f64; 2]>,
    lat: Vec<[f64; 4]>,
    /// Lattice step, radians.
    step: f64,
}

impl Frame {
    fn new(z: u32, bounds: [f64; 4]) -> Frame {
        let n = TILE_INTERVALS;
        let e2 = WGS84_F * (2.0 - WGS84_F);
        let at = |lo: f64, hi: f64, k: usize| (lo + (hi - lo) * k as f64 / n as f64).to_radians();
        Frame {
            lon: (0..=n)
                .map(|i| {
                    let (s, c) = at(bounds[0], bounds[2], i).sin_cos();
                    [s, c]
                })
                .collect(),
            lat: (0..=n)
                .map(|j| {
                    let (sp, cp) = at(bounds[1], bounds[3], j).sin_cos();
                    let s2 = 1.0 - e2 * sp * sp;
                    let prime_vertical = WGS84_A / s2.sqrt();
                    let meridian = WGS84_A * (1.0 - e2) / (s2 * s2.sqrt());
                    [sp, cp, prime_vertical * cp.max(1e-9), meridian]
                })
                .collect(),
            step: tile_degrees(z).to_radians() / n as f64,
        }
    }

    /// Unit normal in ECEF at lattice (i, j) of the tile whose apron heights are `h`.
    fn normal(&self, h: &[f64], i: usize, j: usize) -> [f32; 3] {
        let w = TILE_INTERVALS + 3;
        let at = |di: isize, dj: isize| {
            h[(j as isize + 1 + dj) as usize * w + (i as isize + 1 + di) as usize]
        };
        let [sl, cl] = self.lon[i];
        let [sp, cp, east, north] = self.lat[j];
        let dx = (at(1, 0) - at(-1, 0)) / (2.0 * self.step * east);
        let dy = (at(0, 1) - at(0, -1)) / (2.0 * self.step * north);
        ecef_normal((sl, cl), (sp, cp), dx, dy)
    }
}

/// The unit normal in the Earth-fixed frame of a surface with slopes `dx` (east) and `dy`
/// (north) at the longitude and latitude whose sines and cosines are given.
fn ecef_normal((sl, cl): (f64, f64), (sp, cp): (f64, f64), dx: f64, dy: f64) -> [f32; 3] {
    let len = (dx * dx + dy * dy + 1.0).sqrt();
    let (ne, nn, nu) = (-dx / len, -dy / len, 1.0 / len);
    [
        (-sl * ne - sp * cl * nn + cp * cl * nu) as f32,
        (cl * ne - sp * sl * nn + cp * sl * nu) as f32,
        (cp * nn + sp * nu) as f32,
    ]
}

/// A level's lattice as a tile set (degrees, metres) and each tile's apron heights.
struct LevelSet {
    set: TileSet,
    aprons: Vec<Vec<f64>>,
}

/// The tiles of range `r` as a [`LevelSet`].
fn level_set(src: &Source<'_>, r: &TileRange) -> LevelSet {
    let n = TILE_INTERVALS;
    let grid = [
        (r.x[1] - r.x[0] + 1) as usize,
        (r.y[1] - r.y[0] + 1) as usize,
    ];
    let step = tile_degrees(r.z) / n as f64;
    let aprons: Vec<Vec<f64>> = (0..grid[0] * grid[1])
        .into_par_iter()
        .map(|k| {
            let (col, row) = (k % grid[0], k / grid[0]);
            tile_heights(src, r.z, r.x[0] + col as u32, r.y[0] + row as u32)
        })
        .collect();
    let tiles = aprons
        .iter()
        .enumerate()
        .map(|(k, h)| {
            let (col, row) = (k % grid[0], k / grid[0]);
            let heights =
                Array2::from_shape_fn((n + 1, n + 1), |(j, i)| h[(j + 1) * (n + 3) + i + 1] as f32);
            let (lo, hi) = heights
                .iter()
                .fold((f32::INFINITY, f32::NEG_INFINITY), |a, &v| {
                    (a.0.min(v), a.1.max(v))
                });
            Tile {
                col,
                row,
                origin: [col * n, row * n],
                valid: [n + 1, n + 1],
                heights,
                holes: 0,
                z_range: Some([lo, hi]),
            }
        })
        .collect();
    let set = TileSet {
        layout: crate::terrain::SetLayout {
            tile_size: n + 1,
            grid,
            samples: [grid[0] * n + 1, grid[1] * n + 1],
            source_samples: [grid[0] * n + 1, grid[1] * n + 1],
            preset: crate::terrain::Preset::None,
            corner: [
                tile_bounds(r.z, r.x[0], r.y[0])[0] - 0.5 * step,
                tile_bounds(r.z, r.x[0], r.y[0])[1] - 0.5 * step,
            ],
            cell_size: [step, step],
            z_offset: 0.0,
            crs: None,
        },
        tiles,
    };
    LevelSet { set, aprons }
}

/// Quantized u or v of lattice index `k` (0..=64): exact at both edges.
pub fn lattice_uv(k: u16) -> u16 {
    (f64::from(k) * f64::from(tin::Q) / TILE_INTERVALS as f64).round() as u16
}

/// One triangulated lattice tile as the encoder wants it: vertices renumbered by first use.
fn terrain_tile(
    r: &TileRange,
    set: &TileSet,
    tri: &TileTriangulation,
    apron: &[f64],
) -> TerrainTile {
    let tile = &set.tiles[tri.tile];
    let (x, y) = (r.x[0] + tile.col as u32, r.y[0] + tile.row as u32);
    let bounds = tile_bounds(r.z, x, y);
    let frame = Frame::new(r.z, bounds);
    by_first_use([r.z, x, y], bounds, &tri.triangles, tri.uv.len(), |v| {
        // No padding in these sets: every vertex is a lattice sample.
        let [i, j] = tri.uv[v].map(|c| c as usize);
        (
            [lattice_uv(i as u16), lattice_uv(j as u16)],
            f64::from(tri.z[v]),
            frame.normal(apron, i, j),
        )
    })
}

/// Tile `zxy` of the triangles `triangles` over `n` vertices, its vertices renumbered in the
/// order of their first use (what the encoder's high-water-mark coding needs), each made by
/// `vertex` (quantized u and v, height, normal) when first used.
fn by_first_use(
    zxy: [u32; 3],
    bounds: [f64; 4],
    triangles: &[[u32; 3]],
    n: usize,
    mut vertex: impl FnMut(usize) -> ([u16; 2], f64, [f32; 3]),
) -> TerrainTile {
    let mut remap = vec![u32::MAX; n];
    let mut out = TerrainTile {
        zxy,
        bounds,
        uv: Vec::new(),
        heights: Vec::new(),
        normals: Vec::new(),
        triangles: Vec::with_capacity(triangles.len()),
    };
    for f in triangles {
        out.triangles.push(f.map(|v| {
            let slot = &mut remap[v as usize];
            if *slot == u32::MAX {
                *slot = out.uv.len() as u32;
                let (uv, h, normal) = vertex(v as usize);
                out.uv.push(uv);
                out.heights.push(h);
                out.normals.push(normal);
            }
            *slot
        }));
    }
    out
}

/// The grid's surface for the adaptive triangulations: `Source`'s bilinear heights.
impl tin::Surface for Source<'_> {
    fn at(&self, p: [f64; 2]) -> f64 {
        self.height(p)
    }

    fn node(&self, i: i64, j: i64) -> f64 {
        let i = i.clamp(0, self.cols as i64 - 1) as usize;
        let j = j.clamp(0, self.rows as i64 - 1) as usize;
        (self.set.z_offset + f64::from(self.grid[j * self.cols + i])) * self.unit
    }

    fn size(&self) -> [usize; 2] {
        [self.cols, self.rows]
    }
}

/// The tiles of range `r` (the grid's level) as adaptive triangulations of the grid's own
/// bilinear surface ([`tin`]), each within `tolerance` metres of it everywhere. The level's
/// points every 1/`tin::M` of a tile are projected once, and each side shared by two tiles is
/// simplified once, so both take the same edge vertices.
fn tin_level(src: &Source<'_>, r: &TileRange, tolerance: f64) -> Vec<TerrainTile> {
    let nx = (r.x[1] - r.x[0] + 1) as usize;
    let ny = (r.y[1] - r.y[0] + 1) as usize;
    let m = tin::M;
    let step = tile_degrees(r.z) / m as f64;
    // The level's points every 1/M of a tile, projected once (the tiles' maps and sides): a
    // point outside the projection (never the case this close to a survey) falls back to the
    // grid's centre rather than failing the whole tileset.
    let centre = [(src.cols / 2) as f64, (src.rows / 2) as f64];
    let (px, py) = (nx * m + 1, ny * m + 1);
    let points: Vec<[f64; 2]> = (0..px * py)
        .into_par_iter()
        .map(|k| {
            let (a, b) = (k % px, k / px);
            let lon = -180.0 + (r.x[0] as usize * m + a) as f64 * step;
            let lat = -90.0 + (r.y[0] as usize * m + b) as f64 * step;
            src.grid_ij(lon, lat).unwrap_or(centre)
        })
        .collect();
    let point = |a: usize, b: usize| points[b * px + a];
    // Tile (a, b)'s map: its points every 1/M of the tile.
    let tile_map = |a: usize, b: usize| {
        let mut pts = [[0.0; 2]; (tin::M + 1) * (tin::M + 1)];
        for (q, p) in pts.iter_mut().enumerate() {
            *p = point(a * m + q % (m + 1), b * m + q / (m + 1));
        }
        tin::TileMap::new(pts)
    };
    // Dense tiles (see `cells`): the tiles whose footprint lies inside the grid and whose
    // grid bends beyond the tolerance at `DENSE_SHARE` of its nodes or more. The others (at
    // the survey's edge, or smooth enough for far fewer vertices) take the greedy path.
    let [cols, rows] = tin::Surface::size(src).map(|n| n as f64);
    let dense: Vec<bool> = (0..nx * ny)
        .into_par_iter()
        .map(|k| {
            let (a, b) = (k % nx, k / nx);
            let inside = [(0, 0), (m, 0), (0, m), (m, m)].iter().all(|&(da, db)| {
                let p = point(a * m + da, b * m + db);
                p[0] >= 4.0 && p[1] >= 4.0 && p[0] <= cols - 5.0 && p[1] <= rows - 5.0
            });
            inside && cells::roughness(src, &tile_map(a, b), tolerance) >= DENSE_SHARE
        })
        .collect();
    let is_dense = |a: usize, b: usize| a < nx && b < ny && dense[b * nx + a];
    // The sides running east (row b, column a at b·nx + a), then those running north
    // (column a, row b at nx·(ny + 1) + a·ny + b), each made once for both its tiles: with a
    // vertex at every grid line it crosses when a dense tile has it, else simplified in one
    // dimension.
    let east_runs = nx * (ny + 1);
    let sides: Vec<cells::DenseSide> = (0..east_runs + (nx + 1) * ny)
        .into_par_iter()
        .map(|k| {
            let (line, dense): (Vec<[f64; 2]>, bool) = if k < east_runs {
                let (a, b) = (k % nx, k / nx);
                (
                    (0..=m).map(|i| point(a * m + i, b * m)).collect(),
                    is_dense(a, b) || (b > 0 && is_dense(a, b - 1)),
                )
            } else {
                let (a, b) = ((k - east_runs) / ny, (k - east_runs) % ny);
                (
                    (0..=m).map(|j| point(a * m, b * m + j)).collect(),
                    is_dense(a, b) || (a > 0 && is_dense(a - 1, b)),
                )
            };
            if dense {
                cells::DenseSide::dense(src, &line, tolerance)
            } else {
                cells::DenseSide::simple(src, &line, tolerance)
            }
        })
        .collect();
    let east_run = |a: usize, b: usize| &sides[b * nx + a];
    let north_run = |a: usize, b: usize| &sides[east_runs + a * ny + b];
    (0..nx * ny)
        .into_par_iter()
        .map(|k| {
            let (a, b) = (k % nx, k / nx);
            let (x, y) = (r.x[0] + a as u32, r.y[0] + b as u32);
            let bounds = tile_bounds(r.z, x, y);
            let map = tile_map(a, b);
            let aspect = (0.5 * (bounds[1] + bounds[3])).to_radians().cos();
            let tile_sides = [
                east_run(a, b),
                north_run(a + 1, b),
                north_run(a, b),
                east_run(a, b + 1),
            ];
            let t = dense[k]
                .then(|| cells::dense_tile(src, &map, tile_sides, aspect, tolerance))
                .flatten()
                .unwrap_or_else(|| {
                    // The tile's area in grid cells bounds the vertices the grid's samples
                    // can need; the guard sits well above it.
                    let c = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
                        .map(|(u, v)| map.grid(u, v));
                    let cross = |p: [f64; 2], q: [f64; 2], o: [f64; 2]| {
                        ((p[0] - o[0]) * (q[1] - o[1]) - (p[1] - o[1]) * (q[0] - o[0])).abs()
                    };
                    let cells = 0.5 * (cross(c[1], c[2], c[0]) + cross(c[1], c[2], c[3]));
                    let max_vertices = 4 * cells as usize + 4096;
                    tin::triangulate(
                        src,
                        &map,
                        tile_sides.map(|s| &s.verts[..]),
                        aspect,
                        tolerance,
                        max_vertices,
                    )
                });
            tin_tile(src, [r.z, x, y], bounds, &map, &t)
        })
        .collect()
}

/// One adaptive triangulation as the encoder wants it: vertices renumbered by first use, each
/// normal from the grid's surface around the vertex (its gradient over ±½ cell, taken to east
/// and north through the tile's map).
fn tin_tile(
    src: &Source<'_>,
    zxy: [u32; 3],
    bounds: [f64; 4],
    map: &tin::TileMap,
    t: &tin::TileTin,
) -> TerrainTile {
    // The ellipsoid's frame at the tile's centre, and the map's Jacobian there: over a tile
    // of tens of metres they turn by a few millionths of a radian, far below the normals'
    // oct coding (and the per-vertex trigonometry was most of their time).
    let span = tile_degrees(zxy[0]).to_radians();
    let e2 = WGS84_F * (2.0 - WGS84_F);
    let lon = 0.5 * (bounds[0] + bounds[2]);
    let lat = 0.5 * (bounds[1] + bounds[3]);
    let (sp, cp) = lat.to_radians().sin_cos();
    let sl_cl = lon.to_radians().sin_cos();
    let s2 = 1.0 - e2 * sp * sp;
    let east = WGS84_A / s2.sqrt() * cp.max(1e-9) * span;
    let north = WGS84_A * (1.0 - e2) / (s2 * s2.sqrt()) * span;
    let [ju, jv] = map.jacobian(0.5, 0.5);
    let normal = |k: usize| {
        let p = t.p[k];
        let gx = src.height([p[0] + 0.5, p[1]]) - src.height([p[0] - 0.5, p[1]]);
        let gy = src.height([p[0], p[1] + 0.5]) - src.height([p[0], p[1] - 0.5]);
        let dx = (gx * ju[0] + gy * ju[1]) / east;
        let dy = (gx * jv[0] + gy * jv[1]) / north;
        ecef_normal(sl_cl, (sp, cp), dx, dy)
    };
    by_first_use(zxy, bounds, &t.triangles, t.uv.len(), |k| {
        // Heights as f32, the encoder's header precision: the decoded extremes are then the
        // header's min and max exactly.
        (t.uv[k], f64::from(t.h[k] as f32), normal(k))
    })
}

/// The tileset of `set` from level 0 down to the level matching its spacing. The coarser
/// levels' meshes are within `tolerance_m` metres (vertically) of their lattice's heights;
/// the most detailed level's, adaptive triangulations of the grid's own samples, within it
/// of the grid's bilinear surface everywhere (when its tiles are at most
/// [`LATTICE_MAX_DEGREES`] wide, as for any grid of cells finer than about 15 m; coarser
/// grids keep the lattice there too).
pub fn tileset(set: &TileSet, tolerance_m: f64) -> Result<Tileset> {
    tileset_with(set, tolerance_m, true)
}

/// [`tileset`], or with `adaptive` false the lattice meshes on the most detailed level too
/// (`[output] quantized_mesh_lattice`): within the tolerance of the lattice's resampled
/// heights only, not of the grid's surface at walls, but far faster and smaller on surveys
/// whose surface needs nearly every sample (tree cover at 0.5 m).
pub fn tileset_with(set: &TileSet, tolerance_m: f64, adaptive: bool) -> Result<Tileset> {
    let to_wgs84 = check(set)?;
    let bounds = survey_bounds(set, &to_wgs84)
        .ok_or_else(|| Error::Internal("survey bounds after check".into()))?;
    let unit = set.crs.as_ref().map_or(1.0, |c| c.metres_per_unit());
    let grid = set.assemble();
    let (rows, cols) = grid.dim();
    let src = Source {
        grid: grid.into_iter().collect(),
        cols,
        rows,
        set,
        to_wgs84: &to_wgs84,
        unit,
        bounds,
    };
    let cell_m = set.cell_size[0].min(set.cell_size[1]) * unit;
    ExtractParams {
        tolerance: tolerance_m,
        ..ExtractParams::default()
    }
    .validate()?;
    let finest = finest_level(cell_m);
    let mut levels = Vec::new();
    let mut tiles = Vec::new();
    for z in 0..=finest {
        let r = tile_range(z, bounds);
        if adaptive && z == finest && tile_degrees(z) <= LATTICE_MAX_DEGREES {
            tiles.par_extend(tin_level(&src, &r, tolerance_m));
        } else {
            let ls = level_set(&src, &r);
            let meshes = triangulate(&ls, &quadtree::vertical_error(&ls.set), tolerance_m)?;
            tiles.par_extend(
                meshes
                    .par_iter()
                    .map(|tri| terrain_tile(&r, &ls.set, tri, &ls.aprons[tri.tile])),
            );
        }
        levels.push(vec![r]);
    }
    Ok(Tileset {
        levels,
        bounds,
        tiles,
        tolerance_m,
    })
}

/// The meshes of `ls`'s tiles under the tolerance criterion with the error tree `err`.
fn triangulate(
    ls: &LevelSet,
    err: &[NodeValues],
    tolerance_m: f64,
) -> Result<Vec<TileTriangulation>> {
    // The tolerance criterion reads the vertical error tree only: Röttger's d2 (which only
    // the view-dependent criterion reads) is not computed for these sets.
    let no_d2 = Quadtree {
        c: 0.0,
        k: 0.0,
        d2: Vec::new(),
    };
    let criterion = Criterion::Tolerance {
        max_error: tolerance_m,
    };
    let refiner = Refiner::new(&ls.set, &no_d2, Some(err), criterion)?;
    extract::extract(&ls.set, &refiner)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiling_scheme() {
        assert_eq!(tile_bounds(0, 1, 0), [0.0, -90.0, 180.0, 90.0]);
        assert_eq!(tile_bounds(1, 0, 1), [-180.0, 0.0, -90.0, 90.0]);
        let r = tile_range(3, [-123.1, 44.0, -123.0, 44.1]);
        // 22.5° tiles: −123.1 is in column 2, 44° in row 5.
        assert_eq!((r.x, r.y), ([2, 2], [5, 5]));
        assert_eq!(tile_range(0, [10.0, 10.0, 11.0, 11.0]).x, [0, 1]);
        // 1 m: level 18 has 1.19 m steps (2πR/(2·2^z·64)), level 19 0.60 m.
        assert_eq!(finest_level(1.0), 18);
        assert_eq!(finest_level(1.2), 17);
        assert_eq!(finest_level(1e9), 0);
    }

    #[test]
    fn normal_of_flat_ground_is_the_ellipsoid_normal() {
        let h = vec![5.0; (TILE_INTERVALS + 3).pow(2)];
        let n = Frame::new(10, tile_bounds(10, 0, 512)).normal(&h, 0, 0);
        // (−180°, 0°): the normal is −x.
        assert!(
            (n[0] + 1.0).abs() < 1e-6 && n[1].abs() < 1e-6 && n[2].abs() < 1e-6,
            "{n:?}"
        );
    }
}
