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

/// Features bucketed on a square grid of `cell` metres by the cells their bounding box
/// covers, in insertion order, so that a query visits only the features near a point.
struct FeatureGrid {
    cell: f64,
    cols: usize,
    rows: usize,
    cells: Vec<Vec<u32>>,
}

impl FeatureGrid {
    fn new(w: f64, h: f64, cell: f64) -> FeatureGrid {
        let cols = (w / cell).ceil() as usize + 1;
        let rows = (h / cell).ceil() as usize + 1;
        FeatureGrid {
            cell,
            cols,
            rows,
            cells: vec![Vec::new(); cols * rows],
        }
    }

    /// The cells (column range, row range) that `[c − r, c + r]` covers, clamped to the grid.
    fn span(
        &self,
        c: [f64; 2],
        r: [f64; 2],
    ) -> (
        std::ops::RangeInclusive<usize>,
        std::ops::RangeInclusive<usize>,
    ) {
        let lo = |v: f64| (v / self.cell).floor().max(0.0) as usize;
        let hi = |v: f64, n: usize| ((v / self.cell).max(0.0) as usize).min(n - 1);
        (
            lo(c[0] - r[0]).min(self.cols - 1)..=hi(c[0] + r[0], self.cols),
            lo(c[1] - r[1]).min(self.rows - 1)..=hi(c[1] + r[1], self.rows),
        )
    }

    fn insert(&mut self, k: usize, c: [f64; 2], r: [f64; 2]) {
        let (cs, rs) = self.span(c, r);
        for row in rs {
            for col in cs.clone() {
                self.cells[row * self.cols + col].push(k as u32);
            }
        }
    }

    /// Every feature whose box may meet `[c − r, c + r]` (some more than once).
    fn near(&self, c: [f64; 2], r: [f64; 2]) -> impl Iterator<Item = usize> + '_ {
        let (cs, rs) = self.span(c, r);
        rs.flat_map(move |row| {
            cs.clone().flat_map(move |col| {
                self.cells[row * self.cols + col]
                    .iter()
                    .map(|&k| k as usize)
            })
        })
    }

    /// The features whose box covers the cell of (u, v), in insertion order.
    fn at(&self, u: f64, v: f64) -> &[u32] {
        let c = ((u / self.cell).max(0.0) as usize).min(self.cols - 1);
        let r = (v / self.cell).max(0.0) as usize;
        self.cells
            .get(r * self.cols + c)
            .map_or(&[][..], |v| v.as_slice())
    }
}

/// The largest building half-size and tree radius `World::new` draws (for grid queries).
const MAX_HALF: f64 = 15.0;
const MAX_TREE_R: f64 = 6.0;

/// The terrain and objects of a scene, in local metres (origin at the south-west corner).
struct World {
    w: f64,
    h: f64,
    buildings: Vec<Building>,
    trees: Vec<Tree>,
    /// Buildings and trees bucketed on 20 m cells, so that placing a feature and finding
    /// the feature under a return cost the same on a survey of 10⁹ points as on 10⁵.
    building_grid: FeatureGrid,
    tree_grid: FeatureGrid,
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
            building_grid: FeatureGrid::new(w, h, 20.0),
            tree_grid: FeatureGrid::new(w, h, 20.0),
            lake,
        };
        let area = w * h;
        let n_buildings = ((area / 12_000.0).round() as usize).max(2);
        let n_trees = ((area / 1_200.0).round() as usize).max(8);
        // Placement gives up after this many tries; the bound grows with the count asked
        // for, so a large survey is as built-up as a small one.
        let mut tries = 0;
        while world.buildings.len() < n_buildings && tries < (20 * n_buildings).max(10_000) {
            tries += 1;
            let half = [rng.range(6.0, MAX_HALF), rng.range(5.0, 12.0)];
            let c = [
                rng.range(half[0] + 2.0, w - half[0] - 2.0),
                rng.range(half[1] + 2.0, h - half[1] - 2.0),
            ];
            if !world.clear_of_features(c, half[0].max(half[1]) + 4.0) {
                continue;
            }
            let roof = world.ground(c[0], c[1]) + rng.range(5.0, 14.0);
            world.building_grid.insert(world.buildings.len(), c, half);
            world.buildings.push(Building { c, half, roof });
        }
        tries = 0;
        while world.trees.len() < n_trees && tries < (20 * n_trees).max(100_000) {
            tries += 1;
            let r = rng.range(2.5, MAX_TREE_R);
            let c = [rng.range(0.0, w), rng.range(0.0, h)];
            if !world.clear_of_features(c, r + 1.0) {
                continue;
            }
            let h = rng.range(8.0, 20.0);
            world.tree_grid.insert(world.trees.len(), c, [r, r]);
            world.trees.push(Tree { c, r, h });
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
        !(in_lake || near_cliff || self.near_building(c, r) || self.near_tree(c, r))
    }

    /// True if a building's footprint, grown by `r`, holds `c` (through the feature grid).
    fn near_building(&self, c: [f64; 2], r: f64) -> bool {
        let reach = MAX_HALF + r;
        self.building_grid.near(c, [reach, reach]).any(|k| {
            let b = &self.buildings[k];
            (c[0] - b.c[0]).abs() < b.half[0] + r && (c[1] - b.c[1]).abs() < b.half[1] + r
        })
    }

    /// True if a tree's crown, grown by `r / 2`, holds `c` (through the feature grid).
    fn near_tree(&self, c: [f64; 2], r: f64) -> bool {
        let reach = MAX_TREE_R + r * 0.5;
        self.tree_grid.near(c, [reach, reach]).any(|k| {
            let t = &self.trees[k];
            (c[0] - t.c[0]).hypot(c[1] - t.c[1]) < t.r + r * 0.5
        })
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
        // Buildings never overlap (placement keeps them 4 m apart): at most one matches.
        self.building_grid.at(u, v).iter().find_map(|&k| {
            let b = &self.buildings[k as usize];
            ((u - b.c[0]).abs() < b.half[0] && (v - b.c[1]).abs() < b.half[1]).then_some(b)
        })
    }

    fn tree_at(&self, u: f64, v: f64) -> Option<(&Tree, f64)> {
        self.tree_grid.at(u, v).iter().find_map(|&k| {
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

/// A rectangle of the scene in local metres, `[u0, u1) × [v0, v1)`.
#[derive(Debug, Clone, Copy)]
struct Rect {
    u0: f64,
    u1: f64,
    v0: f64,
    v1: f64,
}

/// The returns of one scan line (at `v0`) inside `rect`. The pulses start at `rect.u0`, so
/// that each tile of a survey scans its part of a line from its own seed, with no state
/// carried from the tile to its west.
fn scan_line(world: &World, rect: Rect, v0: f64, spacing: f64, seed: u64, out: &mut Vec<Ret>) {
    let mut rng = SplitMix64::new(seed);
    // Along the line the pulse spacing follows the mirror: dense at the swath edges, sparse
    // in the middle (swath 150 m), as oscillating-mirror scanners produce.
    let swath = 150.0;
    let mut u = rect.u0 + rng.range(0.0, spacing);
    while u < rect.u1 {
        let phase = (u / swath * std::f64::consts::PI).sin().abs();
        let step = spacing * (0.6 + 0.8 * phase);
        let pu = u + rng.range(-0.2, 0.2) * step;
        let pv = v0 + rng.range(-0.25, 0.25) * spacing;
        u += step;
        if pu < rect.u0 || pu >= rect.u1 || pv < rect.v0 || pv >= rect.v1 {
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
/// Bytes `generate` holds per point of the tile being made, at its peak: the scan returns
/// (about 1.1 per point, 40 bytes each), the sample's indices and the cloud (29 bytes), plus
/// the LAS being built.
pub const BYTES_PER_POINT: u64 = 120;

/// Bytes of `generate`'s memory at its peak for `points` points in `tiles` tiles over an area
/// of `area` m²: one tile at a time (the largest a quarter above the mean, since tiles share
/// the points by their returns and a lake has none), plus the feature index (two grids of
/// 20 m cells, 24 bytes each).
pub fn memory_needed(points: u64, area: f64, tiles: (usize, usize)) -> u64 {
    let n = (tiles.0 as u64 * tiles.1 as u64).max(1);
    let per_tile = if n == 1 {
        points
    } else {
        points.div_ceil(n).saturating_mul(5) / 4
    };
    let cells = (area / 400.0) as u64;
    per_tile
        .saturating_mul(BYTES_PER_POINT)
        .saturating_add(cells.saturating_mul(48))
}

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
    if let Some([w, h]) = size {
        if w * h > MAX_AREA {
            return Err(Error::Usage(format!(
                "--size {w}x{h}: at most {MAX_AREA:e} m² (200 km × 200 km)"
            )));
        }
    }
    let area = size.map_or(points as f64 / 1.5, |[w, h]| w * h);
    let need = memory_needed(points, area, tiles);
    let budget = crate::memory::budget();
    if need > budget {
        return Err(Error::Usage(format!(
            "--points {points}: needs about {}, more than the memory budget of {} (fewer points, more --tiles, or raise --max-memory)",
            crate::memory::human(need),
            crate::memory::human(budget)
        )));
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

/// Multipliers that decorrelate the seeds of scan lines, passes and tile columns.
const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;
const PASS_MIX: u64 = 0xD1B5_4A32_D192_ED03;
const COLUMN_MIX: u64 = 0xA24B_AED4_963E_E407;
/// Most passes of scan lines a scene adds when a large lake leaves too few returns.
const MAX_PASSES: u64 = 8;

/// A survey being generated: the world and the scan plan that all its tiles share, and how
/// many points each tile gets. Tiles are made one at a time ([`Survey::tile`]), so a survey
/// of 10⁹ points needs the memory of one tile, not of the whole.
///
/// Each tile scans the lines that cross it, each line's part from its own seed (line, pass,
/// tile column), so a tile does not depend on the others. The points are then shared out
/// exactly: a first pass counts every tile's returns, each tile keeps its share of the
/// `points` asked for in proportion to them (largest remainders; the outliers likewise),
/// and a seeded sample of its own returns gives it that many. A one-tile survey skips the
/// count and is the scene [`generate`] has always made.
pub struct Survey {
    params: GenerateParams,
    world: World,
    tiles: (usize, usize),
    spacing: f64,
    lines: usize,
    line_seed: u64,
    /// The generator's state after the world and the line seed: one tile samples with it.
    rng: SplitMix64,
    /// Seed of each tile's own sample when there are several.
    tile_seed: u64,
    /// Passes of scan lines every tile runs; `None` for one tile, which adds passes until it
    /// has enough returns.
    passes: Option<u64>,
    /// Points of each tile (outliers included), row-major from the south-west.
    points: Vec<u64>,
    /// Outliers of each tile.
    outliers: Vec<u64>,
}

/// `total` shared out in proportion to `weights` by largest remainders (ties to the lower
/// index); each share at most its weight, so with `total` ≥ the weights' sum every share is
/// its weight.
fn apportion(total: u64, weights: &[u64]) -> Vec<u64> {
    let sum: u128 = weights.iter().map(|&w| w as u128).sum();
    if sum == 0 || total as u128 >= sum {
        return weights
            .iter()
            .map(|&w| if sum == 0 { 0 } else { w })
            .collect();
    }
    let exact: Vec<(u64, u128)> = weights
        .iter()
        .map(|&w| {
            let q = total as u128 * w as u128;
            ((q / sum) as u64, q % sum)
        })
        .collect();
    let mut share: Vec<u64> = exact.iter().map(|e| e.0).collect();
    let left = total - share.iter().sum::<u64>();
    let mut order: Vec<usize> = (0..weights.len()).collect();
    order.sort_by(|&a, &b| exact[b].1.cmp(&exact[a].1).then(a.cmp(&b)));
    for &t in order.iter().take(left as usize) {
        share[t] += 1;
    }
    share
}

impl Survey {
    /// Plans a survey of `params.points` points cut into `tiles` = (columns, rows) tiles.
    pub fn new(params: &GenerateParams, tiles: (usize, usize)) -> Result<Survey> {
        if params.points < MIN_POINTS {
            return Err(Error::param(
                "generate",
                "points",
                params.points,
                "at least 100 points",
            ));
        }
        if tiles.0 == 0 || tiles.1 == 0 {
            return Err(Error::param(
                "generate",
                "tiles",
                format!("{}x{}", tiles.0, tiles.1),
                "at least 1x1",
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
        let n_out =
            ((params.points as u128 * params.outliers_per_million as u128) / 1_000_000) as u64;
        let mut survey = Survey {
            params: params.clone(),
            world,
            tiles,
            spacing,
            lines,
            line_seed,
            rng,
            tile_seed: 0,
            passes: None,
            points: vec![params.points],
            outliers: vec![n_out],
        };
        if tiles != (1, 1) {
            survey.tile_seed = survey.rng.next_u64();
            let n = tiles.0 * tiles.1;
            let count = |pass: u64| -> Vec<u64> {
                (0..n)
                    .map(|t| survey.pass_returns(t, pass, None) as u64)
                    .collect()
            };
            let mut returns = count(0);
            let mut pass = 1;
            while returns.iter().sum::<u64>() < params.points && pass < MAX_PASSES {
                for (r, more) in returns.iter_mut().zip(count(pass)) {
                    *r += more;
                }
                pass += 1;
            }
            survey.passes = Some(pass);
            survey.points = apportion(params.points, &returns);
            survey.outliers = apportion(n_out, &survey.points);
        }
        Ok(survey)
    }

    /// Number of tiles.
    pub fn len(&self) -> usize {
        self.tiles.0 * self.tiles.1
    }

    /// Always false: a survey has at least one tile.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// (column, row) of tile `t`, (0, 0) at the south-west.
    pub fn position(&self, t: usize) -> (usize, usize) {
        (t % self.tiles.0, t / self.tiles.0)
    }

    /// Points tile `t` gets (it may get fewer when a scene yields too few returns).
    pub fn points(&self, t: usize) -> u64 {
        self.points[t]
    }

    fn rect(&self, t: usize) -> Rect {
        let (c, r) = self.position(t);
        let [w, h] = [self.world.w, self.world.h];
        // The same expression on both sides of a seam: tiles partition the scene exactly.
        let edge = |k: usize, n: usize, len: f64| {
            if k == n {
                len
            } else {
                k as f64 * len / n as f64
            }
        };
        Rect {
            u0: edge(c, self.tiles.0, w),
            u1: edge(c + 1, self.tiles.0, w),
            v0: edge(r, self.tiles.1, h),
            v1: edge(r + 1, self.tiles.1, h),
        }
    }

    /// The returns of one pass of scan lines in tile `t`, appended to `out`, or only counted
    /// when `out` is `None`. Returns how many.
    fn pass_returns(&self, t: usize, pass: u64, out: Option<&mut Vec<Ret>>) -> usize {
        let rect = self.rect(t);
        let column = (self.position(t).0 as u64).wrapping_mul(COLUMN_MIX);
        let s = self.spacing;
        let offset = if pass == 0 {
            0.5
        } else {
            0.5 / (pass as f64 + 1.0)
        };
        // Lines whose returns (within ±s/4 of the line) can fall in the tile's rows.
        let first = ((rect.v0 / s - offset - 0.25).floor() - 1.0).max(0.0) as usize;
        let end = (((rect.v1 / s - offset + 0.25).ceil() + 1.0).max(0.0) as usize).min(self.lines);
        let line = |k: usize, out: &mut Vec<Ret>| {
            let seed = if pass == 0 {
                self.line_seed ^ (k as u64).wrapping_mul(GOLDEN)
            } else {
                self.line_seed ^ pass.wrapping_mul(PASS_MIX) ^ k as u64
            };
            let v0 = (k as f64 + offset) * s;
            scan_line(&self.world, rect, v0, s, seed ^ column, out);
        };
        let range = first.min(end)..end;
        match out {
            None => range
                .into_par_iter()
                .map_init(Vec::new, |buf, k| {
                    buf.clear();
                    line(k, buf);
                    buf.len()
                })
                .sum(),
            Some(out) => {
                let before = out.len();
                let rets: Vec<Ret> = range
                    .into_par_iter()
                    .map(|k| {
                        let mut buf = Vec::new();
                        line(k, &mut buf);
                        buf
                    })
                    .flatten_iter()
                    .collect();
                out.extend(rets);
                out.len() - before
            }
        }
    }

    /// Generates tile `t`: its points in scan order, its outliers, its extent.
    pub fn tile(&self, t: usize) -> Scene {
        let params = &self.params;
        let target = self.points[t];
        let mut rets = Vec::new();
        let mut pass = 0;
        loop {
            self.pass_returns(t, pass, Some(&mut rets));
            pass += 1;
            let done = match self.passes {
                Some(p) => pass >= p,
                // Too few (an unlucky scene with a big lake): densify by offset passes.
                None => rets.len() as u64 >= target || pass >= MAX_PASSES,
            };
            if done {
                break;
            }
        }
        let mut rng = if self.passes.is_none() {
            self.rng.clone()
        } else {
            SplitMix64::new(self.tile_seed ^ (t as u64 + 1).wrapping_mul(GOLDEN))
        };
        let rect = self.rect(t);
        let n_out = self.outliers[t] as usize;
        let keep = rng.sample_indices(rets.len(), target as usize - n_out);
        let mut cloud = PointCloud::default();
        let n = target as usize;
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
        // Outliers sit at evenly spread positions in scan order, half high (birds, haze:
        // 80–250 m up), half low (multipath: 15–60 m down).
        let mut outliers = Vec::with_capacity(n_out);
        let every = n.checked_div(n_out).unwrap_or(usize::MAX);
        let mut kept = keep.iter();
        for i in 0..n {
            if n_out > 0 && i % every == every / 2 && outliers.len() < n_out {
                let u = rng.range(rect.u0, rect.u1);
                let v = rng.range(rect.v0, rect.v1);
                let g = self.world.ground(u, v);
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
        Scene {
            cloud,
            outliers,
            extent: [ox + rect.u0, oy + rect.v0, ox + rect.u1, oy + rect.v1],
        }
    }
}

/// Generates a scene (a one-tile [`Survey`]).
///
/// ```
/// use terratile::generate::{generate, GenerateParams};
/// let scene = generate(&GenerateParams { seed: 5, points: 2_000, ..Default::default() }).unwrap();
/// assert_eq!(scene.cloud.len(), 2_000);
/// assert!(scene.cloud.classification.contains(&2), "ground points");
/// ```
pub fn generate(params: &GenerateParams) -> Result<Scene> {
    Ok(Survey::new(params, (1, 1))?.tile(0))
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

/// Writes one cloud as `format` to `path`, rounded first to what the format stores (so the
/// cloud returned equals what reading the file gives back) and with its source recorded.
pub fn write_cloud(path: &Path, mut cloud: PointCloud, format: OutFormat) -> Result<PointCloud> {
    let opts = LasWriteOptions {
        crs: Some(scene_crs()),
        ..Default::default()
    };
    quantize(&mut cloud, format, &opts);
    match format {
        OutFormat::Las => crate::points::write_las(path, &cloud, &opts)?,
        OutFormat::Xyz => write_xyz(path, &cloud)?,
    }
    cloud.sources = vec![SourceInfo {
        path: path.to_path_buf(),
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
    Ok(cloud)
}

/// Writes a survey to `out` (or, with tiles, to `stem-C-R.ext` beside it), one tile at a
/// time, cycling through `formats` tile by tile; `each` sees every file as it is written,
/// with its (rounded) cloud. Returns the files and their point counts.
///
/// Every name is checked before the first file is written, and if a later tile fails (a
/// full disk), the files this call wrote are removed again: no half-written set.
pub fn write_survey(
    survey: &Survey,
    out: &Path,
    formats: &[OutFormat],
    mut each: impl FnMut(&Path, &PointCloud),
) -> Result<Vec<(PathBuf, u64)>> {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    let path_of = |k: usize| {
        let ext = match formats[k % formats.len()] {
            OutFormat::Las => "las",
            OutFormat::Xyz => "xyz",
        };
        if survey.len() == 1 {
            out.to_path_buf()
        } else {
            let (c, r) = survey.position(k);
            out.with_file_name(format!("{stem}-{c}-{r}.{ext}"))
        }
    };
    for k in 0..survey.len() {
        crate::fsutil::check_file_output(&path_of(k), &[])?;
    }
    let mut written: Vec<(PathBuf, u64)> = Vec::new();
    for k in 0..survey.len() {
        let path = path_of(k);
        match write_cloud(&path, survey.tile(k).cloud, formats[k % formats.len()]) {
            Ok(cloud) => {
                each(&path, &cloud);
                written.push((path, cloud.len() as u64));
            }
            Err(e) => {
                for (p, _) in &written {
                    let _ = std::fs::remove_file(p);
                }
                return Err(e);
            }
        }
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn apportion_is_exact_and_proportional() {
        assert_eq!(apportion(10, &[3, 3, 3, 3]), vec![3, 3, 2, 2]);
        assert_eq!(apportion(7, &[0, 5, 5]), vec![0, 4, 3]);
        assert_eq!(
            apportion(100, &[10, 20]),
            vec![10, 20],
            "capped at the weights"
        );
        assert_eq!(apportion(0, &[3, 4]), vec![0, 0]);
        assert_eq!(apportion(5, &[0, 0]), vec![0, 0]);
        let w = [1_000_003, 999_989, 17, 1_234_567];
        let s = apportion(1_000_000, &w);
        assert_eq!(s.iter().sum::<u64>(), 1_000_000);
        let sum: u64 = w.iter().sum();
        for (a, b) in s.iter().zip(w) {
            let exact = 1_000_000.0 * b as f64 / sum as f64;
            assert!((*a as f64 - exact).abs() < 1.0, "{a} vs {exact}");
        }
    }

    /// The feature grid finds what a plain scan over every feature finds.
    #[test]
    fn feature_lookups_equal_a_plain_scan() {
        let mut rng = SplitMix64::new(4);
        let world = World::new(900.0, 700.0, &mut rng);
        assert!(world.buildings.len() > 20 && world.trees.len() > 200);
        for _ in 0..20_000 {
            let (u, v) = (rng.range(0.0, 900.0), rng.range(0.0, 700.0));
            let b = world
                .buildings
                .iter()
                .find(|b| (u - b.c[0]).abs() < b.half[0] && (v - b.c[1]).abs() < b.half[1]);
            assert_eq!(
                world.building_at(u, v).map(|b| b.c),
                b.map(|b| b.c),
                "({u}, {v})"
            );
            let t = world
                .trees
                .iter()
                .find(|t| (u - t.c[0]).hypot(v - t.c[1]) < t.r);
            assert_eq!(world.tree_at(u, v).map(|t| t.0.c), t.map(|t| t.c));
            let r = rng.range(1.0, 20.0);
            let c = [u, v];
            let plain_b = world.buildings.iter().any(|b| {
                (c[0] - b.c[0]).abs() < b.half[0] + r && (c[1] - b.c[1]).abs() < b.half[1] + r
            });
            let plain_t = world
                .trees
                .iter()
                .any(|t| (c[0] - t.c[0]).hypot(c[1] - t.c[1]) < t.r + r * 0.5);
            let grid = (world.near_building(c, r), world.near_tree(c, r));
            assert_eq!(grid, (plain_b, plain_t), "({u}, {v}) r {r}");
        }
    }

    #[test]
    fn tiles_share_the_points_exactly_and_stay_in_their_extent() {
        let p = GenerateParams {
            seed: 12,
            points: 60_000,
            outliers_per_million: 500,
            ..Default::default()
        };
        let survey = Survey::new(&p, (3, 2)).unwrap();
        let mut total = 0;
        let mut outliers = 0;
        for t in 0..survey.len() {
            let a = survey.tile(t);
            let b = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap()
                .install(|| survey.tile(t));
            assert_eq!(a.cloud.x, b.cloud.x, "tile {t}: same points on one thread");
            assert_eq!(a.cloud.z, b.cloud.z);
            assert_eq!(a.cloud.len() as u64, survey.points(t));
            let [x0, y0, x1, y1] = a.extent;
            assert!((0..a.cloud.len())
                .all(|i| (x0..x1).contains(&a.cloud.x[i]) && (y0..y1).contains(&a.cloud.y[i])));
            // Densities agree within a few per cent (the lake takes its tile's returns).
            let density = a.cloud.len() as f64 / ((x1 - x0) * (y1 - y0));
            assert!(
                (1.2..1.8).contains(&density),
                "tile {t}: {density} points/m²"
            );
            total += a.cloud.len();
            outliers += a.outliers.len();
        }
        assert_eq!(total, 60_000);
        assert_eq!(outliers, 30, "500 per million of 60 000");
        // One tile is the scene `generate` makes.
        let one = Survey::new(&p, (1, 1)).unwrap().tile(0);
        let g = generate(&p).unwrap();
        assert_eq!(one.cloud.x, g.cloud.x);
        assert_eq!(one.outliers, g.outliers);
    }

    #[test]
    fn memory_is_that_of_one_tile() {
        let one = memory_needed(1_000_000_000, 1e9 / 1.5, (1, 1));
        let hundred = memory_needed(1_000_000_000, 1e9 / 1.5, (10, 10));
        assert!(one > 100 << 30, "{one}");
        assert!(hundred < 2 << 30, "{hundred}");
    }
}
