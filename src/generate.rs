//! Synthetic airborne-LIDAR-like surveys from a seed (`terratile generate`): rolling terrain
//! with a ridge and a cliff, flat-roofed buildings, trees with several returns, a lake that
//! returns nothing (a real hole), point density varying along the scan lines, and a few high
//! and low outliers. Everything is a deterministic function of the seed and the parameters,
//! whatever the thread count: scan lines are generated in parallel, each from its own stream.
//!
//! Classes follow ASPRS: 2 ground, 5 high vegetation, 6 building; the outliers are left
//! unclassified (1), as in real deliveries, and their indices are returned for tests.

use crate::error::{Error, Result};
use crate::points::{Crs, LasWriteOptions, LinearUnit, PointCloud, SourceInfo};
use crate::rng::SplitMix64;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// What to generate.
#[derive(Debug, Clone)]
pub struct GenerateParams {
    /// Seed of every random choice.
    pub seed: u64,
    /// Exact number of points to produce.
    pub points: u64,
    /// Scene width and height in metres; `None` sizes the scene for 1.5 points/m².
    pub size: Option<[f64; 2]>,
    /// World coordinates of the scene's south-west corner (UTM zone 32N, like the ISPRS data).
    pub origin: [f64; 2],
    /// Outliers per million points (half high, half low).
    pub outliers_per_million: u32,
}

impl Default for GenerateParams {
    fn default() -> Self {
        GenerateParams {
            seed: 1,
            points: 100_000,
            size: None,
            origin: [513_000.0, 5_403_000.0],
            outliers_per_million: 60,
        }
    }
}

/// A generated survey.
#[derive(Debug, Clone)]
pub struct Scene {
    /// The points, in scan order.
    pub cloud: PointCloud,
    /// Indices of the injected outliers.
    pub outliers: Vec<u32>,
    /// Scene extent (min x, min y, max x, max y).
    pub extent: [f64; 4],
}

#[derive(Debug, Clone, Copy)]
struct Building {
    c: [f64; 2],
    half: [f64; 2],
    roof: f64,
}

#[derive(Debug, Clone, Copy)]
struct Tree {
    c: [f64; 2],
    r: f64,
    h: f64,
}

/// The terrain and objects of a scene, in local metres (origin at the south-west corner).
struct World {
    w: f64,
    h: f64,
    buildings: Vec<Building>,
    trees: Vec<Tree>,
    /// Trees bucketed on a coarse grid for fast lookup.
    tree_grid: Vec<Vec<u32>>,
    tree_cell: f64,
    tree_cols: usize,
    lake: ([f64; 2], [f64; 2]),
}

fn smoothstep(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl World {
    fn new(w: f64, h: f64, rng: &mut SplitMix64) -> World {
        let lake = ([0.25 * w, 0.3 * h], [0.09 * w, 0.07 * h]);
        let mut world = World {
            w,
            h,
            buildings: Vec::new(),
            trees: Vec::new(),
            tree_grid: Vec::new(),
            tree_cell: 20.0,
            tree_cols: 1,
            lake,
        };
        let area = w * h;
        let n_buildings = ((area / 12_000.0).round() as usize).max(2);
        let n_trees = ((area / 1_200.0).round() as usize).max(8);
        let mut tries = 0;
        while world.buildings.len() < n_buildings && tries < 10_000 {
            tries += 1;
            let half = [rng.range(6.0, 15.0), rng.range(5.0, 12.0)];
            let c = [
                rng.range(half[0] + 2.0, w - half[0] - 2.0),
                rng.range(half[1] + 2.0, h - half[1] - 2.0),
            ];
            if !world.clear_of_features(c, half[0].max(half[1]) + 4.0) {
                continue;
            }
            let roof = world.ground(c[0], c[1]) + rng.range(5.0, 14.0);
            world.buildings.push(Building { c, half, roof });
        }
        tries = 0;
        while world.trees.len() < n_trees && tries < 100_000 {
            tries += 1;
            let r = rng.range(2.5, 6.0);
            let c = [rng.range(0.0, w), rng.range(0.0, h)];
            if !world.clear_of_features(c, r + 1.0) {
                continue;
            }
            let h = rng.range(8.0, 20.0);
            world.trees.push(Tree { c, r, h });
        }
        world.tree_cols = (w / world.tree_cell).ceil() as usize + 1;
        let rows = (h / world.tree_cell).ceil() as usize + 1;
        world.tree_grid = vec![Vec::new(); world.tree_cols * rows];
        for (k, t) in world.trees.iter().enumerate() {
            let (c0, c1) = (
                ((t.c[0] - t.r) / world.tree_cell).floor().max(0.0) as usize,
                ((t.c[0] + t.r) / world.tree_cell) as usize,
            );
            let (r0, r1) = (
                ((t.c[1] - t.r) / world.tree_cell).floor().max(0.0) as usize,
                ((t.c[1] + t.r) / world.tree_cell) as usize,
            );
            for r in r0..=r1.min(rows - 1) {
                for c in c0..=c1.min(world.tree_cols - 1) {
                    world.tree_grid[r * world.tree_cols + c].push(k as u32);
                }
            }
        }
        world
    }

    fn clear_of_features(&self, c: [f64; 2], r: f64) -> bool {
        let in_lake = {
            let (lc, lr) = self.lake;
            let dx = (c[0] - lc[0]) / (lr[0] + r);
            let dy = (c[1] - lc[1]) / (lr[1] + r);
            dx * dx + dy * dy < 1.0
        };
        let near_cliff = self.cliff_distance(c[0], c[1]).abs() < r + 3.0 && c[0] > 0.5 * self.w;
        let near_building = self.buildings.iter().any(|b| {
            (c[0] - b.c[0]).abs() < b.half[0] + r && (c[1] - b.c[1]).abs() < b.half[1] + r
        });
        let near_tree = self
            .trees
            .iter()
            .any(|t| (c[0] - t.c[0]).hypot(c[1] - t.c[1]) < t.r + r * 0.5);
        !(in_lake || near_cliff || near_building || near_tree)
    }

    /// Signed distance to the cliff line (positive on the high side).
    fn cliff_distance(&self, u: f64, v: f64) -> f64 {
        // Line through (0.55w, 0.75h) and (0.95w, 0.55h).
        let (ax, ay, bx, by) = (0.55 * self.w, 0.75 * self.h, 0.95 * self.w, 0.55 * self.h);
        let (dx, dy) = (bx - ax, by - ay);
        let len = dx.hypot(dy);
        ((u - ax) * dy - (v - ay) * dx) / len
    }

    /// Bare-earth height at (u, v).
    fn ground(&self, u: f64, v: f64) -> f64 {
        let (w, h) = (self.w, self.h);
        let rolling =
            6.0 * (u / 45.0).sin() * (v / 60.0).cos() + 4.0 * ((u + v) / 80.0).sin() + 0.03 * u;
        // Ridge along (0.05w, 0.85h) → (0.6w, 0.55h), Gaussian profile.
        let (ax, ay, bx, by) = (0.05 * w, 0.85 * h, 0.6 * w, 0.55 * h);
        let (dx, dy) = (bx - ax, by - ay);
        let t = (((u - ax) * dx + (v - ay) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
        let d = (u - ax - t * dx).hypot(v - ay - t * dy);
        let ridge = 12.0 * (-(d * d) / (2.0 * 18.0 * 18.0)).exp() * (1.0 - (2.0 * t - 1.0).powi(4));
        // Cliff: an 8 m drop over 1.5 m, only on the east half.
        let cd = self.cliff_distance(u, v);
        let east = smoothstep((u - 0.5 * w) / 10.0);
        let cliff = -8.0 * smoothstep(0.5 - cd / 1.5) * east;
        // Lake basin, 2 m deep.
        let (lc, lr) = self.lake;
        let q = ((u - lc[0]) / lr[0]).powi(2) + ((v - lc[1]) / lr[1]).powi(2);
        let basin = -2.0 * smoothstep(1.5 - q);
        200.0 + rolling + ridge + cliff + basin
    }

    fn in_lake(&self, u: f64, v: f64) -> bool {
        let (lc, lr) = self.lake;
        ((u - lc[0]) / lr[0]).powi(2) + ((v - lc[1]) / lr[1]).powi(2) < 1.0
    }

    fn building_at(&self, u: f64, v: f64) -> Option<&Building> {
        self.buildings
            .iter()
            .find(|b| (u - b.c[0]).abs() < b.half[0] && (v - b.c[1]).abs() < b.half[1])
    }

    fn tree_at(&self, u: f64, v: f64) -> Option<(&Tree, f64)> {
        let c = ((u / self.tree_cell).max(0.0) as usize).min(self.tree_cols - 1);
        let r = (v / self.tree_cell).max(0.0) as usize;
        let cell = self.tree_grid.get(r * self.tree_cols + c)?;
        cell.iter().find_map(|&k| {
            let t = &self.trees[k as usize];
            let d = (u - t.c[0]).hypot(v - t.c[1]);
            (d < t.r).then(|| (t, d / t.r))
        })
    }
}

/// Point attributes of one return, before quantisation.
struct Ret {
    p: [f64; 3],
    class: u8,
    ret: u8,
    nret: u8,
    intensity: u16,
}

impl Ret {
    /// A return at `p` of class `class`, number `ret.0` of `ret.1`.
    fn new(p: [f64; 3], class: u8, ret: (u8, u8), intensity: u16) -> Ret {
        Ret {
            p,
            class,
            ret: ret.0,
            nret: ret.1,
            intensity,
        }
    }
}

/// One scan line's returns.
fn scan_line(world: &World, v0: f64, spacing: f64, seed: u64, out: &mut Vec<Ret>) {
    let mut rng = SplitMix64::new(seed);
    // Along the line the pulse spacing follows the mirror: dense at the swath edges, sparse
    // in the middle (swath 150 m), as oscillating-mirror scanners produce.
    let swath = 150.0;
    let mut u = rng.range(0.0, spacing);
    while u < world.w {
        let phase = (u / swath * std::f64::consts::PI).sin().abs();
        let step = spacing * (0.6 + 0.8 * phase);
        let pu = u + rng.range(-0.2, 0.2) * step;
        let pv = v0 + rng.range(-0.25, 0.25) * spacing;
        u += step;
        if pu < 0.0 || pu >= world.w || pv < 0.0 || pv >= world.h {
            continue;
        }
        if world.in_lake(pu, pv) {
            continue; // water: no return
        }
        let g = world.ground(pu, pv) + 0.03 * rng.normal();
        if let Some(b) = world.building_at(pu, pv) {
            let z = b.roof + 0.02 * rng.normal();
            out.push(Ret::new([pu, pv, z], 6, (1, 1), 180 + rng.below(40) as u16));
            continue;
        }
        if let Some((t, rel)) = world.tree_at(pu, pv) {
            if rng.unit() < 0.75 {
                let top = world.ground(t.c[0], t.c[1]) + t.h * (1.0 - 0.6 * rel * rel);
                let canopy = top - rng.range(0.0, 1.5);
                let mid = rng.unit() < 0.4;
                let reaches_ground = rng.unit() < 0.7;
                let n = 1 + mid as u8 + reaches_ground as u8;
                out.push(Ret::new(
                    [pu, pv, canopy],
                    5,
                    (1, n),
                    40 + rng.below(60) as u16,
                ));
                if mid {
                    let z = rng.range(g + 1.0, canopy - 0.5).max(g + 0.5);
                    out.push(Ret::new([pu, pv, z], 5, (2, n), 20 + rng.below(40) as u16));
                }
                if reaches_ground {
                    out.push(Ret::new([pu, pv, g], 2, (n, n), 10 + rng.below(30) as u16));
                }
                continue;
            }
        }
        out.push(Ret::new([pu, pv, g], 2, (1, 1), 90 + rng.below(60) as u16));
    }
}

/// Most tiles `generate --tiles` writes (files in one directory).
pub const MAX_TILES: u64 = 65_536;
/// Fewest points a scene has (fewer cannot show its features).
pub const MIN_POINTS: u64 = 100;
/// Largest scene area in m² (200 km × 200 km): the tree index is one cell per 400 m².
pub const MAX_AREA: f64 = 4e10;
/// Bytes `generate` holds per point at its peak: the scan returns (about 1.1 per point,
/// 40 bytes each), the sample's indices and the cloud (29 bytes), plus the LAS being built.
pub const BYTES_PER_POINT: u64 = 120;

/// Checks `generate`'s counts against what the machine can do before any work: the points
/// against the memory budget, the area and the tile count against fixed bounds.
pub fn check_bounds(points: u64, size: Option<[f64; 2]>, tiles: (usize, usize)) -> Result<()> {
    // The point count first: the tile bound below is "no more than the points", which
    // would otherwise report a too-small count as too many tiles.
    if points < MIN_POINTS {
        return Err(Error::Usage(format!(
            "--points {points}: at least {MIN_POINTS}"
        )));
    }
    let need = points.saturating_mul(BYTES_PER_POINT);
    let budget = crate::memory::budget();
    if need > budget {
        return Err(Error::Usage(format!(
            "--points {points}: needs about {}, more than the memory budget of {} (fewer points, or raise --max-memory)",
            crate::memory::human(need),
            crate::memory::human(budget)
        )));
    }
    if let Some([w, h]) = size {
        if w * h > MAX_AREA {
            return Err(Error::Usage(format!(
                "--size {w}x{h}: at most {MAX_AREA:e} m² (200 km × 200 km)"
            )));
        }
    }
    let t = tiles.0 as u64 * tiles.1 as u64;
    if t > MAX_TILES.min(points) {
        return Err(Error::Usage(format!(
            "--tiles {}x{}: {t} tiles, at most {} (65536, and no more than the points)",
            tiles.0,
            tiles.1,
            MAX_TILES.min(points)
        )));
    }
    Ok(())
}

/// Generates a scene.
///
/// ```
/// use terratile::generate::{generate, GenerateParams};
/// let scene = generate(&GenerateParams { seed: 5, points: 2_000, ..Default::default() }).unwrap();
/// assert_eq!(scene.cloud.len(), 2_000);
/// assert!(scene.cloud.classification.contains(&2), "ground points");
/// ```
pub fn generate(params: &GenerateParams) -> Result<Scene> {
    if params.points < MIN_POINTS {
        return Err(Error::param(
            "generate",
            "points",
            params.points,
            "at least 100 points",
        ));
    }
    // Returns per pulse is about 1.1; the lake and the trees' misses take some pulses.
    let [w, h] = params.size.unwrap_or_else(|| {
        let side = (params.points as f64 / 1.5).sqrt();
        [side, side]
    });
    if !(w > 1.0 && h > 1.0 && w.is_finite() && h.is_finite()) || w * h > MAX_AREA {
        return Err(Error::param(
            "generate",
            "size",
            format!("{w}x{h}"),
            "width and height must be > 1 m, the area at most 4e10 m²",
        ));
    }
    let mut rng = SplitMix64::new(params.seed);
    let world = World::new(w, h, &mut rng);
    // Aim 6 % above the target, then thin to exactly `points` with a seeded sample.
    let spacing = (w * h * 1.06 / (params.points as f64 * 1.02)).sqrt();
    let lines = (h / spacing).ceil() as usize;
    let line_seed = rng.next_u64();
    let mut rets: Vec<Ret> = (0..lines)
        .into_par_iter()
        .map(|k| {
            let mut out = Vec::new();
            let v0 = (k as f64 + 0.5) * spacing;
            scan_line(
                &world,
                v0,
                spacing,
                line_seed ^ (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                &mut out,
            );
            out
        })
        .flatten_iter()
        .collect();
    // Too few (an unlucky scene with a big lake): densify by a second, offset pass.
    let mut pass = 1u64;
    while (rets.len() as u64) < params.points && pass < 8 {
        let extra: Vec<Ret> = (0..lines)
            .into_par_iter()
            .map(|k| {
                let mut out = Vec::new();
                let v0 = (k as f64 + 0.5 / (pass as f64 + 1.0)) * spacing;
                scan_line(
                    &world,
                    v0,
                    spacing,
                    line_seed ^ pass.wrapping_mul(0xD1B5_4A32_D192_ED03) ^ k as u64,
                    &mut out,
                );
                out
            })
            .flatten_iter()
            .collect();
        rets.extend(extra);
        pass += 1;
    }
    let n_out =
        ((params.points as u128 * params.outliers_per_million as u128) / 1_000_000) as usize;
    let keep = rng.sample_indices(rets.len(), params.points as usize - n_out);
    let mut cloud = PointCloud::default();
    let n = params.points as usize;
    cloud.x.reserve_exact(n);
    cloud.y.reserve_exact(n);
    cloud.z.reserve_exact(n);
    cloud.classification.reserve_exact(n);
    cloud.return_number.reserve_exact(n);
    cloud.number_of_returns.reserve_exact(n);
    cloud.intensity.reserve_exact(n);
    let [ox, oy] = params.origin;
    let push = |c: &mut PointCloud, r: &Ret| {
        c.x.push(ox + r.p[0]);
        c.y.push(oy + r.p[1]);
        c.z.push(r.p[2]);
        c.classification.push(r.class);
        c.return_number.push(r.ret);
        c.number_of_returns.push(r.nret);
        c.intensity.push(r.intensity);
    };
    // Outliers sit at evenly spread positions in scan order, half high (birds, haze: 80–250 m
    // up), half low (multipath: 15–60 m down).
    let mut outliers = Vec::with_capacity(n_out);
    let every = n.checked_div(n_out).unwrap_or(usize::MAX);
    let mut kept = keep.iter();
    for i in 0..n {
        if n_out > 0 && i % every == every / 2 && outliers.len() < n_out {
            let u = rng.range(0.0, w);
            let v = rng.range(0.0, h);
            let g = world.ground(u, v);
            let high = outliers.len() % 2 == 0;
            let z = if high {
                g + rng.range(80.0, 250.0)
            } else {
                g - rng.range(15.0, 60.0)
            };
            outliers.push(i as u32);
            push(
                &mut cloud,
                &Ret {
                    p: [u, v, z],
                    class: 1,
                    ret: 1,
                    nret: 1,
                    intensity: rng.below(30) as u16,
                },
            );
        } else if let Some(&k) = kept.next() {
            push(&mut cloud, &rets[k as usize]);
        }
    }
    Ok(Scene {
        cloud,
        outliers,
        extent: [ox, oy, ox + w, oy + h],
    })
}

/// The CRS of generated scenes: WGS 84 / UTM zone 32N, metres.
pub fn scene_crs() -> Crs {
    Crs {
        wkt: None,
        epsg: Some(32632),
        geotiff: None,
        unit: Some(LinearUnit {
            name: "metre".into(),
            metres: 1.0,
        }),
        vertical: None,
    }
}

/// Output format of `generate`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutFormat {
    /// LAS 1.2 point format 0, centimetre scale.
    Las,
    /// Text: `x y z` with two decimals.
    Xyz,
}

/// Rounds a cloud's coordinates to what `format` stores, so the in-memory cloud equals what
/// reading the written file gives back, bit for bit.
pub fn quantize(cloud: &mut PointCloud, format: OutFormat, opts: &LasWriteOptions) {
    match format {
        OutFormat::Las => {
            let off = opts.offset_for(&cloud.bounds());
            for (col, k) in [(&mut cloud.x, 0), (&mut cloud.y, 1), (&mut cloud.z, 2)] {
                let (s, o) = (opts.scale[k], off[k]);
                col.par_iter_mut()
                    .for_each(|v| *v = s * f64::from(((*v - o) / s).round() as i32) + o);
            }
        }
        OutFormat::Xyz => {
            for col in [&mut cloud.x, &mut cloud.y, &mut cloud.z] {
                col.par_iter_mut().for_each(|v| {
                    *v = format!("{v:.2}").parse().unwrap_or(*v);
                });
            }
            cloud.classification.clear();
            cloud.return_number.clear();
            cloud.number_of_returns.clear();
            cloud.intensity.clear();
        }
    }
}

/// Writes `cloud` as XYZ text (`x y z`, two decimals, one header line).
pub fn write_xyz(path: &Path, cloud: &PointCloud) -> Result<()> {
    use std::io::Write;
    crate::fsutil::write_atomic(path, |w| {
        let io = |e| Error::io(path, e);
        // The comment marks the file as terratile's (`fsutil::written_by_terratile`), so a
        // rerun may replace it; XYZ readers skip `#` lines.
        writeln!(w, "# terratile generate\nx y z").map_err(io)?;
        let mut line = String::with_capacity(64);
        for i in 0..cloud.len() {
            line.clear();
            use std::fmt::Write as _;
            let _ = writeln!(
                line,
                "{:.2} {:.2} {:.2}",
                cloud.x[i], cloud.y[i], cloud.z[i]
            );
            w.write_all(line.as_bytes()).map_err(io)?;
        }
        Ok(())
    })
}

/// Splits a scene into `cols` × `rows` tiles by position (tile (0, 0) at the south-west).
pub fn split_tiles(scene: &Scene, cols: usize, rows: usize) -> Vec<((usize, usize), PointCloud)> {
    let [x0, y0, x1, y1] = scene.extent;
    let (tw, th) = ((x1 - x0) / cols as f64, (y1 - y0) / rows as f64);
    let c = &scene.cloud;
    let mut ids: Vec<Vec<u32>> = vec![Vec::new(); cols * rows];
    for i in 0..c.len() {
        let tc = (((c.x[i] - x0) / tw).floor().max(0.0) as usize).min(cols - 1);
        let tr = (((c.y[i] - y0) / th).floor().max(0.0) as usize).min(rows - 1);
        ids[tr * cols + tc].push(i as u32);
    }
    ids.into_iter()
        .enumerate()
        .map(|(k, idx)| ((k % cols, k / cols), c.gather(&idx)))
        .collect()
}

/// Writes a scene to `out` (or, with tiles, to `stem-C-R.ext` beside it), cycling through
/// `formats` tile by tile. Returns the files written with their (quantised) clouds.
pub fn write_scene(
    scene: &Scene,
    out: &Path,
    formats: &[OutFormat],
    tiles: (usize, usize),
) -> Result<Vec<(PathBuf, PointCloud)>> {
    let opts = LasWriteOptions {
        crs: Some(scene_crs()),
        ..Default::default()
    };
    let parts = if tiles == (1, 1) {
        vec![((0, 0), scene.cloud.clone())]
    } else {
        split_tiles(scene, tiles.0, tiles.1)
    };
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    let path_of = |k: usize| {
        let ext = match formats[k % formats.len()] {
            OutFormat::Las => "las",
            OutFormat::Xyz => "xyz",
        };
        if tiles == (1, 1) {
            out.to_path_buf()
        } else {
            out.with_file_name(format!("{stem}-{}-{}.{ext}", k % tiles.0, k / tiles.0))
        }
    };
    // Every name is checked before the first file is written: no half-written set.
    for k in 0..tiles.0 * tiles.1 {
        crate::fsutil::check_file_output(&path_of(k), &[])?;
    }
    let mut written = Vec::new();
    for (k, (_, mut cloud)) in parts.into_iter().enumerate() {
        let format = formats[k % formats.len()];
        let path = path_of(k);
        quantize(&mut cloud, format, &opts);
        match format {
            OutFormat::Las => crate::points::write_las(&path, &cloud, &opts)?,
            OutFormat::Xyz => write_xyz(&path, &cloud)?,
        }
        cloud.sources = vec![SourceInfo {
            path: path.clone(),
            format: match format {
                OutFormat::Las => crate::points::Format::Las,
                OutFormat::Xyz => crate::points::Format::Xyz,
            },
            version: None,
            point_format: None,
            record_length: None,
            points_in_file: cloud.len() as u64,
            points_read: cloud.len() as u64,
            scale: None,
            offset: None,
            header_bounds: None,
            crs: None,
        }];
        written.push((path, cloud));
    }
    Ok(written)
}
