//! The Cesium quantized-mesh tileset decoded by an independent decoder: HERE's npm
//! `@here/quantized-mesh-decoder`, installed by this test into `target/geo-node` from the npm
//! registry (it skips, saying why, without Node or the registry). The decoded tiles are
//! checked against the EXR tiles' heights: header consistent with the vertices, edges of
//! neighbouring tiles identical, every vertex on our heightfield, every lattice point of the
//! most detailed tiles within the tolerance, and at random points (ours, and CesiumJS's
//! heights) the most detailed tile within the tolerance of the grid's own bilinear surface.
//! The most detailed level is an adaptive triangulation of the grid's surface (vertices
//! anywhere on the tile's 32767² quantized positions); the coarser levels are lattice tiles
//! (vertices on a 64 × 64 lattice).

use super::exr_grid;
use crate::common::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

const A: f64 = 6_378_137.0;
const F: f64 = 1.0 / 298.257_223_563;

/// Height of the decoded mesh `d` at (lon, lat) inside it (barycentric), None if no
/// triangle holds the point.
fn mesh_height_at(d: &Decoded, lon: f64, lat: f64) -> Option<f64> {
    let s = d.bounds[2] - d.bounds[0];
    let (x, y) = (
        (lon - d.bounds[0]) / s * 32767.0,
        (lat - d.bounds[1]) / s * 32767.0,
    );
    d.triangles.iter().find_map(|t| {
        let p = t.map(|k| [d.uv[k][0] as f64, d.uv[k][1] as f64, d.pos[k][2]]);
        let det =
            (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
        let l1 = ((x - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (y - p[0][1])) / det;
        let l2 = ((p[1][0] - p[0][0]) * (y - p[0][1]) - (x - p[0][0]) * (p[1][1] - p[0][1])) / det;
        let l0 = 1.0 - l1 - l2;
        (l0 >= -1e-9 && l1 >= -1e-9 && l2 >= -1e-9)
            .then(|| l0 * p[0][2] + l1 * p[1][2] + l2 * p[2][2])
    })
}

/// The tiles by (z, x, y), and the deepest one holding (lon, lat): the tile CesiumJS's
/// `sampleTerrainMostDetailed` reads there (the most detailed level `layer.json` lists at
/// the point).
struct Tiles<'a> {
    by: BTreeMap<[u32; 3], &'a Decoded>,
    levels: u32,
}

impl Tiles<'_> {
    fn deepest(&self, lon: f64, lat: f64) -> Option<&Decoded> {
        (0..self.levels).rev().find_map(|z| {
            let s = 180.0 / f64::from(1u32 << z);
            let (x, y) = (((lon + 180.0) / s) as u32, ((lat + 90.0) / s) as u32);
            self.by.get(&[z, x, y]).copied()
        })
    }
}

/// A point over the grid and the heights there: the decoded mesh's of the deepest tile
/// holding it (and that tile's level and height quantisation step) and the heightfield's
/// (bilinear on the grid).
struct Point {
    lon: f64,
    lat: f64,
    z: u32,
    mesh: f64,
    grid: f64,
    step: f64,
}

/// `count` points drawn uniformly (seed `seed`) over the survey's WGS 84 `bounds` where the
/// grid is.
fn random_points(
    fd: &Field,
    tiles: &Tiles,
    bounds: [f64; 4],
    count: usize,
    seed: u64,
) -> Vec<Point> {
    let [w, s, e, n] = bounds;
    let mut rng = terratile::SplitMix64::new(seed);
    let mut pts = Vec::new();
    while pts.len() < count {
        let lon = rng.range(w, e);
        let lat = rng.range(s, n);
        let Some(grid) = fd.at(lon, lat) else {
            continue;
        };
        let tile = tiles.deepest(lon, lat).expect("a tile over the grid");
        pts.push(Point {
            lon,
            lat,
            z: tile.z,
            mesh: mesh_height_at(tile, lon, lat).expect("covered"),
            grid,
            step: tile.step,
        });
    }
    pts
}

/// The heights of the tileset's most detailed tiles at `count` random points against the
/// grid's own bilinear surface: each within the tolerance (plus the tile's height
/// quantisation step and 1 mm for the projection's curvature over a tile). Says how they are
/// distributed (worst, 99th percentile, share within the tolerance) and which levels hold
/// the points.
fn at_random_points(
    fd: &Field,
    tiles: &Tiles,
    bounds: [f64; 4],
    count: usize,
    tolerance: f64,
    capped: bool,
) -> String {
    let pts = random_points(fd, tiles, bounds, count, 18);
    for p in &pts {
        assert_eq!(
            p.z + 1,
            tiles.levels,
            "the most detailed level covers the survey"
        );
        assert!(
            capped || (p.mesh - p.grid).abs() <= tolerance + p.step + 1e-3,
            "mesh {} m at ({}, {}) on level {}, the heightfield {} m",
            p.mesh,
            p.lon,
            p.lat,
            p.z,
            p.grid,
        );
    }
    let mut off: Vec<f64> = pts.iter().map(|p| (p.mesh - p.grid).abs()).collect();
    off.sort_by(f64::total_cmp);
    let mut on_level = BTreeMap::new();
    for p in &pts {
        *on_level.entry(p.z).or_insert(0) += 1;
    }
    format!(
        "at {count} random points the most detailed tiles lie within {:.3} m of the \
         heightfield's bilinear surface, {:.3} m at the 99th percentile, {:.1} % within the \
         tolerance; points per level {on_level:?}",
        off[count - 1],
        off[count * 99 / 100],
        100.0 * off.iter().filter(|&&e| e <= tolerance).count() as f64 / count as f64,
    )
}

/// CesiumJS (its `CesiumTerrainProvider` and `sampleTerrainMostDetailed`) at 100 random points
/// over the grid, under Node (npm `@cesium/engine`) and, where there is a Chromium, in a
/// headless browser (npm `cesium`'s browser build, tests/geo/cesium_browser.mjs): the height of
/// our decoded most detailed tile there (within 1 mm), within the tolerance of the grid's
/// bilinear surface.
fn check_cesium(terrain: &Path, tiles: &Tiles, bounds: [f64; 4], fd: &Field, tolerance: f64) {
    let Some(modules) = npm_env("cesium-node", "@cesium/engine@26.3.0") else {
        return;
    };
    let pts = random_points(fd, tiles, bounds, 100, 17);
    let file = terrain.with_file_name("points.json");
    let list: Vec<[f64; 2]> = pts.iter().map(|p| [p.lon, p.lat]).collect();
    std::fs::write(&file, serde_json::to_vec(&list).unwrap()).unwrap();
    let o = Command::new("node")
        .arg(repo().join("tests/geo/cesium_sample.mjs"))
        .arg(&modules)
        .arg(terrain)
        .arg(&file)
        .output()
        .unwrap();
    let node = cesium_heights(&o, &pts, "CesiumJS under Node", tolerance);
    // The same in a browser: CesiumJS's browser build in headless Chromium.
    let Some(chromium) = chromium() else { return };
    let Some(web) = npm_env("cesium-web", "cesium@1.145.0") else {
        return;
    };
    let o = Command::new("node")
        .arg(repo().join("tests/geo/cesium_browser.mjs"))
        .arg(&chromium)
        .arg(&web)
        .arg(terrain)
        .arg(&file)
        .output()
        .unwrap();
    let browser = cesium_heights(&o, &pts, "CesiumJS in headless Chromium", tolerance);
    // One library, one tileset: the browser's heights are Node's.
    for (b, n) in browser.iter().zip(&node) {
        assert!((b - n).abs() < 1e-6, "Chromium {b} m, Node {n} m");
    }
}

/// The heights a CesiumJS script printed for `pts` (lon, lat, our mesh's height, our grid's,
/// the tile's height step): each within 1 mm plus the step of our decoded mesh; says how far
/// they are from the mesh and the heightfield.
fn cesium_heights(o: &std::process::Output, pts: &[Point], who: &str, tolerance: f64) -> Vec<f64> {
    assert!(
        o.status.success(),
        "{who}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let r: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(r["hasVertexNormals"], true, "{who}");
    let heights: Vec<f64> = r["heights"]
        .as_array()
        .unwrap()
        .iter()
        .map(|h| h.as_f64().unwrap())
        .collect();
    assert_eq!(heights.len(), pts.len(), "{who}");
    let (mut worst_mesh, mut worst_grid): (f64, f64) = (0.0, 0.0);
    let mut within = 0;
    for (&h, p) in heights.iter().zip(pts) {
        worst_mesh = worst_mesh.max((h - p.mesh).abs());
        worst_grid = worst_grid.max((h - p.grid).abs());
        within += usize::from((h - p.grid).abs() <= tolerance);
        assert!(
            (h - p.mesh).abs() <= 1e-3 + p.step,
            "{who}: {h} m at ({}, {}), our mesh {} m",
            p.lon,
            p.lat,
            p.mesh
        );
        // The criterion: the grid's own bilinear surface, within the tolerance plus the
        // height quantisation step; 1 mm allows for the projection's curvature over a tile.
        assert!(
            (h - p.grid).abs() <= tolerance + p.step + 1e-3,
            "{who}: {h} m at ({}, {}) (level {}), the heightfield {} m",
            p.lon,
            p.lat,
            p.z,
            p.grid
        );
    }
    let browser = r["userAgent"]
        .as_str()
        .map(|u| format!(" ({u}, CesiumJS {})", r["cesium"].as_str().unwrap_or("?")))
        .unwrap_or_default();
    eprintln!(
        "{who}{browser}: sampleTerrainMostDetailed at {} points within {worst_mesh:.4} m of our \
         decoded mesh, {worst_grid:.3} m of the heightfield's bilinear surface ({within} within \
         the tolerance of {tolerance} m)",
        pts.len()
    );
    heights
}

/// The Chromium for the browser check: `TERRATILE_CHROMIUM`, else `chromium` or
/// `chromium-browser` on the PATH (Debian's `chromium` package; `.ci/run` installs it where
/// it can); None (after saying why) without one.
fn chromium() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("TERRATILE_CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH").unwrap_or_default();
    let found = std::env::split_paths(&path)
        .flat_map(|d| [d.join("chromium"), d.join("chromium-browser")])
        .find(|p| p.is_file());
    if found.is_none() {
        eprintln!(
            "skipping the CesiumJS browser check: no chromium on the PATH (Debian: apt-get \
             install chromium; or set TERRATILE_CHROMIUM)"
        );
    }
    found
}

fn ecef(lon: f64, lat: f64, h: f64) -> [f64; 3] {
    let (lon, lat) = (lon.to_radians(), lat.to_radians());
    let e2 = F * (2.0 - F);
    let n = A / (1.0 - e2 * lat.sin().powi(2)).sqrt();
    [
        (n + h) * lat.cos() * lon.cos(),
        (n + h) * lat.cos() * lon.sin(),
        (n * (1.0 - e2) + h) * lat.sin(),
    ]
}

/// The smallest magnitude, along unit scaled-space direction `d`, of a horizon occlusion
/// point that keeps scaled-space position `p` visible (Cesium's `EllipsoidalOccluder`
/// construction, written from its description).
fn occlusion_magnitude(p: [f64; 3], d: [f64; 3]) -> f64 {
    let m2 = p.iter().map(|c| c * c).sum::<f64>();
    let m = m2.sqrt();
    let dir = p.map(|c| c / m);
    let (m2, m) = (m2.max(1.0), m.max(1.0));
    let cos_a = dir[0] * d[0] + dir[1] * d[1] + dir[2] * d[2];
    let cross = [
        dir[1] * d[2] - dir[2] * d[1],
        dir[2] * d[0] - dir[0] * d[2],
        dir[0] * d[1] - dir[1] * d[0],
    ];
    let sin_a = cross.iter().map(|c| c * c).sum::<f64>().sqrt();
    let cos_b = 1.0 / m;
    let sin_b = (m2 - 1.0).sqrt() * cos_b;
    1.0 / (cos_a * cos_b - sin_a * sin_b)
}

struct Decoded {
    z: u32,
    x: u32,
    y: u32,
    bounds: [f64; 4],
    /// lon, lat, metres.
    pos: Vec<[f64; 3]>,
    uv: Vec<[u64; 2]>,
    triangles: Vec<[usize; 3]>,
    step: f64,
    /// On the most detailed level: an adaptive triangulation, vertices anywhere (else on the
    /// 64 × 64 lattice).
    tin: bool,
}

fn decoded(t: &Value) -> Decoded {
    let n = |k: &str| t[k].as_u64().unwrap() as u32;
    let (z, x, y) = (n("z"), n("x"), n("y"));
    let s = 180.0 / f64::from(1u32 << z);
    let bounds = [
        -180.0 + f64::from(x) * s,
        -90.0 + f64::from(y) * s,
        -180.0 + f64::from(x + 1) * s,
        -90.0 + f64::from(y + 1) * s,
    ];
    let h = &t["header"];
    let (lo, hi) = (
        h["minHeight"].as_f64().unwrap(),
        h["maxHeight"].as_f64().unwrap(),
    );
    let arr = |k: &str| -> Vec<u64> {
        t[k].as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap())
            .collect()
    };
    let (u, v, q) = (arr("u"), arr("v"), arr("h"));
    let pos = (0..u.len())
        .map(|k| {
            [
                bounds[0] + s * u[k] as f64 / 32767.0,
                bounds[1] + s * v[k] as f64 / 32767.0,
                lo + (hi - lo) * q[k] as f64 / 32767.0,
            ]
        })
        .collect();
    let tri = arr("triangles");
    Decoded {
        z,
        x,
        y,
        bounds,
        pos,
        uv: u.iter().zip(&v).map(|(&a, &b)| [a, b]).collect(),
        triangles: tri
            .chunks(3)
            .map(|c| [c[0] as usize, c[1] as usize, c[2] as usize])
            .collect(),
        step: (hi - lo) / 32767.0,
        tin: false,
    }
}

/// Our heightfield in metres at (lon, lat): bilinear on the EXR grid; None outside it.
struct Field {
    to_crs: terratile::geo::ToWgs84,
    grid: Vec<f32>,
    cols: usize,
    rows: usize,
    corner: [f64; 2],
    cell: [f64; 2],
    z_offset: f64,
    unit: f64,
}

impl Field {
    fn at(&self, lon: f64, lat: f64) -> Option<f64> {
        let [x, y] = self.to_crs.inverse(lon, lat)?;
        let fi = (x - self.corner[0]) / self.cell[0] - 0.5;
        let fj = (y - self.corner[1]) / self.cell[1] - 0.5;
        if !(fi >= 0.0 && fj >= 0.0 && fi <= (self.cols - 1) as f64 && fj <= (self.rows - 1) as f64)
        {
            return None;
        }
        let (i0, j0) = (
            (fi as usize).min(self.cols - 2),
            (fj as usize).min(self.rows - 2),
        );
        let (di, dj) = (fi - i0 as f64, fj - j0 as f64);
        // exr_grid is north row first.
        let h = |i: usize, j: usize| f64::from(self.grid[(self.rows - 1 - j) * self.cols + i]);
        let v = (h(i0, j0) * (1.0 - di) + h(i0 + 1, j0) * di) * (1.0 - dj)
            + (h(i0, j0 + 1) * (1.0 - di) + h(i0 + 1, j0 + 1) * di) * dj;
        Some((self.z_offset + v) * self.unit)
    }
}

fn field(out: &Path, m: &Value, crs: terratile::points::Crs) -> Field {
    let (cols, rows, grid) = exr_grid(out, m);
    let g = &m["grid"];
    let f = |v: &Value| v.as_f64().unwrap();
    Field {
        to_crs: terratile::geo::ToWgs84::new(&crs).unwrap(),
        grid,
        cols,
        rows,
        corner: [f(&g["corner"][0]), f(&g["corner"][1])],
        cell: [f(&g["cell_size"][0]), f(&g["cell_size"][1])],
        z_offset: f(&g["z_offset"]),
        unit: crs.metres_per_unit(),
    }
}

/// Checks one tile's header against its decoded vertices and its vertices against `fd`;
/// returns how many vertices lay on the grid.
fn check_tile(t: &Value, d: &Decoded, fd: &Field) -> usize {
    let h = &t["header"];
    let g = |k: &str| h[k].as_f64().unwrap();
    let ctx = format!("tile {}/{}/{}", d.z, d.x, d.y);
    assert_eq!(t["gzipped"], true, "{ctx}");
    assert!(!d.pos.is_empty() && !d.triangles.is_empty(), "{ctx}");
    assert!(
        d.triangles.iter().flatten().all(|&k| k < d.pos.len()),
        "{ctx}"
    );
    assert_eq!(t["normals"].as_array().unwrap().len(), d.pos.len(), "{ctx}");
    // min/max height: the decoded extremes.
    let lo = d.pos.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min);
    let hi = d.pos.iter().map(|p| p[2]).fold(f64::NEG_INFINITY, f64::max);
    assert!(
        (lo - g("minHeight")).abs() < 1e-6 && (hi - g("maxHeight")).abs() < 1e-3,
        "{ctx}"
    );
    // Bounding sphere holds every vertex; the horizon occlusion point keeps every vertex
    // visible.
    let c = [
        g("boundingSphereCenterX"),
        g("boundingSphereCenterY"),
        g("boundingSphereCenterZ"),
    ];
    let r = g("boundingSphereRadius");
    let hp = [
        g("horizonOcclusionPointX"),
        g("horizonOcclusionPointY"),
        g("horizonOcclusionPointZ"),
    ];
    let hm = hp.iter().map(|v| v * v).sum::<f64>().sqrt();
    let dir = hp.map(|v| v / hm);
    let b = A * (1.0 - F);
    for p in &d.pos {
        let e = ecef(p[0], p[1], p[2]);
        let dist = ((e[0] - c[0]).powi(2) + (e[1] - c[1]).powi(2) + (e[2] - c[2]).powi(2)).sqrt();
        assert!(
            dist <= r * (1.0 + 1e-9) + 1e-6,
            "{ctx}: vertex {dist} m from the centre, radius {r}"
        );
        let need = occlusion_magnitude([e[0] / A, e[1] / A, e[2] / b], dir);
        assert!(
            need <= 0.0 || hm >= need * (1.0 - 1e-9),
            "{ctx}: occlusion point {hm} < {need}"
        );
    }
    // Edge lists: exactly the vertices on each side.
    for (k, side) in [("west", 0usize), ("south", 1), ("east", 2), ("north", 3)] {
        let want: std::collections::BTreeSet<usize> =
            d.uv.iter()
                .enumerate()
                .filter(|(_, p)| match side {
                    0 => p[0] == 0,
                    1 => p[1] == 0,
                    2 => p[0] == 32767,
                    _ => p[1] == 32767,
                })
                .map(|(i, _)| i)
                .collect();
        let got: std::collections::BTreeSet<usize> = t[k]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap() as usize)
            .collect();
        assert_eq!(got, want, "{ctx}: {k} edge");
    }
    // Every vertex over the grid is the grid's height there (bilinear), within the height
    // quantisation step and f32 rounding (and, on the most detailed level, 1 mm for the
    // projection's curvature over a tile). The coarser levels' vertices are samples of a
    // 64 × 64 lattice: the position is taken at the lattice point its u, v quantize (a
    // quantized position is up to 1/65534 of the tile off, which on a slope would hide the
    // height's accuracy); the most detailed level's are where u, v say.
    let mut on = 0;
    let s = d.bounds[2] - d.bounds[0];
    for (p, q) in d.pos.iter().zip(&d.uv) {
        let k = lattice_coords(d, *q);
        if !d.tin {
            assert_eq!(
                k.map(|v| (v * 32767.0 / 64.0).round() as u64),
                *q,
                "{ctx}: vertex off the lattice"
            );
        }
        let (lon, lat) = (d.bounds[0] + s * k[0] / 64.0, d.bounds[1] + s * k[1] / 64.0);
        if let Some(want) = fd.at(lon, lat) {
            on += 1;
            assert!(
                (p[2] - want).abs() <= d.step + 1e-3,
                "{ctx}: vertex ({lon}, {lat}) at {} m, grid {want} m",
                p[2]
            );
        }
    }
    on
}

/// A vertex's position in lattice units (0..=64): on the coarser levels the lattice point
/// its u, v quantize (checked in `check_tile`), on the most detailed level u, v themselves.
fn lattice_coords(d: &Decoded, q: [u64; 2]) -> [f64; 2] {
    let k = q.map(|c| c as f64 * 64.0 / 32767.0);
    if d.tin {
        k
    } else {
        k.map(f64::round)
    }
}

/// The mesh's height at every 64×64 lattice point of a tile, by barycentric interpolation
/// (None where no triangle covers it: a crack or a hole).
fn mesh_heights(d: &Decoded) -> BTreeMap<[u64; 2], f64> {
    let mut out = BTreeMap::new();
    for t in &d.triangles {
        let p = t.map(|k| {
            let [u, v] = lattice_coords(d, d.uv[k]);
            [u, v, d.pos[k][2]]
        });
        let (x0, x1) = (
            p.iter().map(|q| q[0]).fold(f64::INFINITY, f64::min),
            p.iter().map(|q| q[0]).fold(0.0, f64::max),
        );
        let (y0, y1) = (
            p.iter().map(|q| q[1]).fold(f64::INFINITY, f64::min),
            p.iter().map(|q| q[1]).fold(0.0, f64::max),
        );
        let det =
            (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
        assert!(
            det > 0.0,
            "tile {}/{}/{}: triangle not counter-clockwise",
            d.z,
            d.x,
            d.y
        );
        for j in (y0 - 1e-6).ceil() as u64..=(y1 + 1e-6).floor() as u64 {
            for i in (x0 - 1e-6).ceil() as u64..=(x1 + 1e-6).floor() as u64 {
                let (x, y) = (i as f64, j as f64);
                let l1 = ((x - p[0][0]) * (p[2][1] - p[0][1])
                    - (p[2][0] - p[0][0]) * (y - p[0][1]))
                    / det;
                let l2 = ((p[1][0] - p[0][0]) * (y - p[0][1])
                    - (x - p[0][0]) * (p[1][1] - p[0][1]))
                    / det;
                let l0 = 1.0 - l1 - l2;
                if l0 >= -1e-9 && l1 >= -1e-9 && l2 >= -1e-9 {
                    out.insert([i, j], l0 * p[0][2] + l1 * p[1][2] + l2 * p[2][2]);
                }
            }
        }
    }
    out
}

/// One survey through `quantized_mesh = true`, decoded and checked. With `capped` the most
/// detailed tiles may have stopped at the per-tile vertex guard (see the README), so their
/// distance from the grid is measured and said, not asserted.
fn check_tileset(
    file: &str,
    crs: terratile::points::Crs,
    tolerance: f64,
    cesium: bool,
    capped: bool,
) {
    let Some(input) = data_file(file) else { return };
    let Some(modules) = npm_env("geo-node", "@here/quantized-mesh-decoder@1.2.8") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let toml = format!(
        "[input]\npaths = [{:?}]\n[output]\ndir = \"out\"\npng = false\nraw = false\n\
         relief = false\nwireframe = false\nmeshes = []\nquantized_mesh = true\n\
         quantized_mesh_tolerance = {tolerance}\n",
        input.to_str().unwrap(),
    );
    std::fs::write(d.path().join("p.toml"), toml).unwrap();
    terratile(d.path(), &["run", "p.toml", "--quiet"]).ok();
    let out = d.path().join("out");
    let m: Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
    // The manifest points at the tileset (and is valid against the schema where the Python
    // environment can be built).
    let layer = m["grid_files"]["cesium_terrain"].as_str().unwrap();
    assert_eq!(layer, "terrain/layer.json");
    assert!(out.join(layer).is_file());
    if let Some(py) = super::python_env() {
        super::assert_schema_valid(&py, &[out.join("manifest.json")]);
    }
    let fd = field(&out, &m, crs);
    let o = Command::new("node")
        .arg(repo().join("tests/geo/decode_terrain.mjs"))
        .arg(&modules)
        .arg(out.join("terrain"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: Value = serde_json::from_slice(&o.stdout).unwrap();
    let tiles = r["tiles"].as_array().unwrap();
    let files = walk(&out.join("terrain"))
        .iter()
        .filter(|p| p.extension().is_some_and(|e| e == "terrain"))
        .count();
    // Every file is a tile layer.json lists, and the other way round.
    assert_eq!(files, tiles.len());
    let levels = r["layer"]["available"].as_array().unwrap().len() as u32;
    assert_eq!(r["layer"]["available"][0][0]["endX"], 1, "two root tiles");
    let dec: Vec<Decoded> = tiles
        .iter()
        .map(|t| {
            let d = decoded(t);
            Decoded {
                tin: d.z + 1 == levels,
                ..d
            }
        })
        .collect();
    let on: usize = tiles
        .iter()
        .zip(&dec)
        .map(|(t, d)| check_tile(t, d, &fd))
        .sum();
    assert!(on > 0, "no vertex over the grid");
    // Neighbours of one level: the same edge vertices (position, and height within both
    // tiles' quantisation steps).
    let by: BTreeMap<[u32; 3], &Decoded> = dec.iter().map(|d| ([d.z, d.x, d.y], d)).collect();
    let mut shared = 0;
    for d in &dec {
        for (n, mine, theirs, axis) in [
            ([d.z, d.x + 1, d.y], 32767, 0, 0),
            ([d.z, d.x, d.y + 1], 32767, 0, 1),
        ] {
            let Some(nb) = by.get(&n) else { continue };
            let edge = |t: &Decoded, at: u64| -> Vec<(u64, f64)> {
                let mut v: Vec<(u64, f64)> =
                    t.uv.iter()
                        .zip(&t.pos)
                        .filter(|(p, _)| p[axis] == at)
                        .map(|(p, q)| (p[1 - axis], q[2]))
                        .collect();
                v.sort_by_key(|a| a.0);
                v
            };
            let (a, b) = (edge(d, mine), edge(nb, theirs));
            assert_eq!(
                a.iter().map(|p| p.0).collect::<Vec<_>>(),
                b.iter().map(|p| p.0).collect::<Vec<_>>(),
                "edge between {:?} and {n:?}",
                [d.z, d.x, d.y]
            );
            for (p, q) in a.iter().zip(&b) {
                assert!((p.1 - q.1).abs() <= d.step + nb.step + 1e-6);
            }
            shared += 1;
        }
    }
    // Every tile's mesh covers every lattice point; where the tile is the most detailed one
    // (no child tile listed there), within the tolerance (plus height quantisation) of our
    // heightfield.
    let mut checked = 0;
    let mut worst: f64 = 0.0;
    for d in &dec {
        let mh = mesh_heights(d);
        assert_eq!(
            mh.len(),
            65 * 65,
            "tile {}/{}/{}: lattice not covered",
            d.z,
            d.x,
            d.y
        );
        let s = d.bounds[2] - d.bounds[0];
        for (ij, h) in mh {
            // The children holding the point (two or four on the lines between them).
            let covered = (0..4u32).any(|q| {
                let (qx, qy) = (u64::from(q % 2), u64::from(q / 2));
                (ij[0] >= 32 * qx && ij[0] <= 32 * (qx + 1))
                    && (ij[1] >= 32 * qy && ij[1] <= 32 * (qy + 1))
                    && by.contains_key(&[d.z + 1, 2 * d.x + qx as u32, 2 * d.y + qy as u32])
            });
            let lon = d.bounds[0] + s * ij[0] as f64 / 64.0;
            let lat = d.bounds[1] + s * ij[1] as f64 / 64.0;
            if let (false, Some(want)) = (covered, fd.at(lon, lat)) {
                worst = worst.max((h - want).abs());
                assert!(
                    capped || (h - want).abs() <= tolerance + d.step + 1e-3,
                    "{file}: tile {}/{}/{}: mesh {h} vs grid {want}",
                    d.z,
                    d.x,
                    d.y
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 0);
    let tiles_by = Tiles { by, levels };
    let b = &r["layer"]["bounds"];
    let bounds = [0, 1, 2, 3].map(|k| b[k].as_f64().unwrap());
    eprintln!(
        "{file}: {}",
        at_random_points(&fd, &tiles_by, bounds, 2000, tolerance, capped)
    );
    if cesium {
        check_cesium(&out.join("terrain"), &tiles_by, bounds, &fd, tolerance);
    }
    let per_level: Vec<usize> = (0..levels)
        .map(|z| dec.iter().filter(|d| d.z == z).count())
        .collect();
    eprintln!(
        "{file}: {} tiles (per level {per_level:?}), {levels} levels, {on} vertices on the grid, \
         {shared} shared edges, {checked} lattice points of the most detailed tiles, worst \
         {worst:.3} m (tolerance {tolerance} m)",
        tiles.len()
    );
}

/// Oregon Lambert in feet through its ESRI WKT (heights converted to metres): the most
/// detailed tiles within the tolerance of the grid's own surface everywhere, by our decoder
/// and by CesiumJS's `sampleTerrainMostDetailed`.
#[test]
fn quantized_mesh_decodes_and_matches_autzen() {
    let Some(input) = data_file("lidar/autzen_trim.las") else {
        return;
    };
    let info = terratile(&repo(), &["info", input.to_str().unwrap(), "--json"]);
    let v: Value = serde_json::from_str(&info.stdout).unwrap();
    let crs = terratile::points::Crs {
        wkt: Some(v[0]["source"]["crs"]["wkt"].as_str().unwrap().into()),
        epsg: None,
        geotiff: None,
        unit: Some(terratile::points::LinearUnit {
            name: "foot".into(),
            metres: 0.3048,
        }),
        vertical: None,
    };
    check_tileset("lidar/autzen_trim.las", crs, 0.5, true, false);
}

/// UTM zone by EPSG code, buildings and trees at 0.25 m: every check but the grid criterion
/// on the most detailed level, which is measured: in its trees the grid's bilinear surface
/// twists within cells, and tiles reach the per-tile vertex guard before 0.25 m (README).
#[test]
fn quantized_mesh_decodes_and_matches_csite4() {
    let crs = terratile::geo::crs_from_key("EPSG:32632").unwrap();
    check_tileset("lidar/CSite4_orig-utm.laz", crs, 0.25, false, true);
}

/// `quantized_mesh` on data without a CRS: one line naming the key, exit 2, nothing written.
#[test]
fn quantized_mesh_without_crs_is_refused() {
    let d = default_job();
    let p = d.path().join("pipeline.toml");
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(text.contains("[output]\n"));
    let text = text
        .replacen("[output]\n", "[output]\nquantized_mesh = true\n", 1)
        .replacen("\"fixtures/*.las\", ", "", 1);
    std::fs::write(&p, text).unwrap();
    terratile(d.path(), &["run", "--quiet"])
        .input_error(&["output.quantized_mesh", "[input] crs"])
        .left_nothing("out");
}

/// The default job reduced to its XYZ file (which states no CRS) with `[input] crs = CODE`
/// and `extra` under `[output]`.
fn xyz_job(code: &str, extra: &str) -> tempfile::TempDir {
    let d = default_job();
    let p = d.path().join("pipeline.toml");
    let text = std::fs::read_to_string(&p)
        .unwrap()
        .replacen("\"fixtures/*.las\", ", "", 1)
        .replacen("[input]\n", &format!("[input]\ncrs = \"{code}\"\n"), 1)
        .replacen("[output]\n", &format!("[output]\n{extra}"), 1);
    std::fs::write(&p, text).unwrap();
    d
}

/// A CRS the reprojection cannot handle (New Zealand Map Grid: proj4rs has no `nzmg`):
/// `quantized_mesh` is refused in one line naming the CRS and the key, nothing written.
#[test]
fn quantized_mesh_with_unsupported_crs_is_refused() {
    let d = xyz_job("EPSG:27200", "quantized_mesh = true\n");
    terratile(d.path(), &["run", "--quiet"])
        .input_error(&[
            "output.quantized_mesh",
            "EPSG:27200",
            "nzmg",
            "cannot be reprojected",
        ])
        .left_nothing("out");
}

/// The same CRS with only the GeoTIFF asked: the documented fallback, the outputs that need no
/// reprojection are written, and the manifest says why there are no WGS 84 figures.
#[test]
fn unsupported_crs_still_writes_the_geotiff_and_says_why() {
    let d = xyz_job("EPSG:27200", "");
    let p = d.path().join("pipeline.toml");
    let text =
        std::fs::read_to_string(&p)
            .unwrap()
            .replacen("geotiff = false", "geotiff = true", 1);
    std::fs::write(&p, text).unwrap();
    terratile(d.path(), &["run", "--quiet"]).ok();
    let out = d.path().join("out");
    assert!(out.join("dem.tif").is_file());
    let m: Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
    let g = &m["geographic"];
    assert!(g["wgs84_bounds"].is_null(), "{g}");
    let why = g["unsupported"].as_str().unwrap();
    assert!(why.contains("EPSG:27200") && why.contains("nzmg"), "{why}");
}
