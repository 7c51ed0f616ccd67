//! Test inputs for the tile stages: heightfields from real points (a plain per-cell mean and a
//! naive hole dilation, test-only: the real resampler and filler are the terrain stages'),
//! synthetic heightfields, and slow, obvious checkers of meshes.

use std::collections::{HashMap, HashSet};
use std::path::Path;
use terratile::points::{self, PointCloud, ReadOptions};
use terratile::terrain::extract::TileTriangulation;
use terratile::terrain::heightfield::choose_z_offset;
use terratile::terrain::tiles::{tile, TileParams, TileSet};
use terratile::terrain::{CellState, Heightfield};
use terratile::NoProgress;
use terratile::SplitMix64;

/// Tiles of `size` samples, no preset.
pub fn sized(size: usize) -> TileParams {
    TileParams {
        size: Some(size),
        ..Default::default()
    }
}

/// `hf` cut into tiles of `size` samples (the one tiling helper of the tests).
pub fn tiles_of(hf: &Heightfield, size: usize) -> TileSet {
    tile(hf, &sized(size)).unwrap()
}

/// Reads a point file with default options.
pub fn read_points(path: &Path) -> PointCloud {
    points::read(path, &ReadOptions::default(), &NoProgress).expect("read test data")
}

/// N × N grid (N = round(√points)) of per-cell mean heights; holes stay empty unless `fill`,
/// which grows the measured cells into the holes ring by ring (mean of the 4-neighbours
/// already known), the whole grid at once per ring so the order does not matter.
pub fn heightfield_from_points(cloud: &PointCloud, fill: bool) -> Heightfield {
    let b = cloud.bounds();
    let n = (cloud.len() as f64).sqrt().round().max(2.0) as usize;
    let size = [
        (b.max[0] - b.min[0]) / n as f64,
        (b.max[1] - b.min[1]) / n as f64,
    ];
    let z_offset = choose_z_offset(b.min[2], b.max[2]);
    let mut hf = Heightfield::empty(
        n,
        n,
        [b.min[0], b.min[1]],
        size,
        z_offset,
        cloud.crs().cloned(),
    );
    let mut sum = vec![0.0f64; n * n];
    for k in 0..cloud.len() {
        let i = (((cloud.x[k] - b.min[0]) / size[0]) as usize).min(n - 1);
        let j = (((cloud.y[k] - b.min[1]) / size[1]) as usize).min(n - 1);
        sum[j * n + i] += cloud.z[k] - z_offset;
        hf.counts[[j, i]] += 1;
    }
    for j in 0..n {
        for i in 0..n {
            let c = hf.counts[[j, i]];
            if c > 0 {
                hf.heights[[j, i]] = (sum[j * n + i] / c as f64) as f32;
                hf.state[[j, i]] = CellState::Measured;
            }
        }
    }
    if fill {
        loop {
            let mut changes = Vec::new();
            for j in 0..n {
                for i in 0..n {
                    if hf.state[[j, i]].has_height() {
                        continue;
                    }
                    let mut s = 0.0f64;
                    let mut c = 0;
                    for (di, dj) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
                        let (a, b) = (i as i64 + di, j as i64 + dj);
                        if a >= 0 && b >= 0 && (a as usize) < n && (b as usize) < n {
                            let (a, b) = (a as usize, b as usize);
                            if hf.state[[b, a]].has_height() {
                                s += hf.heights[[b, a]] as f64;
                                c += 1;
                            }
                        }
                    }
                    if c > 0 {
                        changes.push((i, j, (s / c as f64) as f32));
                    }
                }
            }
            if changes.is_empty() {
                break;
            }
            for (i, j, h) in changes {
                hf.heights[[j, i]] = h;
                hf.state[[j, i]] = CellState::Interpolated;
            }
        }
    }
    hf
}

/// A rough synthetic terrain: a few random waves, a cliff, spikes and noise.
pub fn synthetic(cols: usize, rows: usize, seed: u64, roughness: f64) -> Heightfield {
    let mut rng = SplitMix64::new(seed);
    let mut hf = Heightfield::empty(cols, rows, [500_000.0, 5_400_000.0], [1.0, 1.3], 0.0, None);
    let waves: Vec<[f64; 4]> = (0..4)
        .map(|_| {
            [
                rng.range(0.01, 0.3),
                rng.range(0.01, 0.3),
                rng.range(0.5, 8.0),
                rng.range(0.0, 6.3),
            ]
        })
        .collect();
    let cliff = rng.range(0.0, cols as f64);
    for j in 0..rows {
        for i in 0..cols {
            let (x, y) = (i as f64, j as f64);
            let mut z = 100.0;
            for w in &waves {
                z += w[2] * (w[0] * x + w[1] * y + w[3]).sin();
            }
            if x > cliff + 0.3 * y {
                z += 7.0;
            }
            z += roughness * rng.normal();
            if rng.below(500) == 0 {
                z += rng.range(-30.0, 30.0);
            }
            hf.heights[[j, i]] = z as f32;
            hf.state[[j, i]] = CellState::Measured;
        }
    }
    hf
}

/// Twice the signed area of a triangle given by local sample coordinates.
pub fn area2(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// Checks that a tile's surface is a conforming triangulation of its valid rectangle: every
/// triangle counter-clockwise, each directed edge used once, an edge without its reverse only
/// on the rectangle's outline (a T-junction or a crack inside leaves such an edge inside), and
/// the areas adding up to the rectangle's.
pub fn check_conforming(set: &TileSet, tri: &TileTriangulation) -> Result<(), String> {
    let tile = &set.tiles[tri.tile];
    let (w, h) = ((tile.valid[0] - 1) as f64, (tile.valid[1] - 1) as f64);
    let surface = &tri.triangles[..tri.surface_triangles];
    let mut directed: HashSet<(u32, u32)> = HashSet::new();
    let mut area = 0.0;
    for f in surface {
        let [a, b, c] = f.map(|v| tri.uv[v as usize]);
        let a2 = area2(a, b, c);
        if a2 <= 0.0 {
            return Err(format!(
                "tile {}: triangle {f:?} is not counter-clockwise ({a2})",
                tri.tile
            ));
        }
        area += a2 / 2.0;
        for e in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
            if !directed.insert(e) {
                return Err(format!(
                    "tile {}: edge {e:?} used twice in one direction",
                    tri.tile
                ));
            }
        }
    }
    let on_outline = |p: [f64; 2]| p[0] == 0.0 || p[1] == 0.0 || p[0] == w || p[1] == h;
    for &(a, b) in &directed {
        if directed.contains(&(b, a)) {
            continue;
        }
        let (pa, pb) = (tri.uv[a as usize], tri.uv[b as usize]);
        let same_line = (pa[0] == pb[0] && (pa[0] == 0.0 || pa[0] == w))
            || (pa[1] == pb[1] && (pa[1] == 0.0 || pa[1] == h));
        if !(on_outline(pa) && on_outline(pb) && same_line) {
            return Err(format!(
                "tile {}: open edge {pa:?} → {pb:?} inside the tile (T-junction or crack)",
                tri.tile
            ));
        }
    }
    if (area - w * h).abs() > 1e-6 * w * h {
        return Err(format!(
            "tile {}: triangles cover {area}, the tile {}",
            tri.tile,
            w * h
        ));
    }
    Ok(())
}

/// Open (outline) edges of a tile on its side `side` (0 west, 1 east, 2 south, 3 north) as
/// global sample intervals along that side, with the heights of their ends.
pub fn side_edges(
    set: &TileSet,
    tri: &TileTriangulation,
    side: usize,
) -> Vec<(f64, f64, f32, f32)> {
    let tile = &set.tiles[tri.tile];
    let last = (set.tile_size - 1) as f64;
    let surface = &tri.triangles[..tri.surface_triangles];
    let directed: HashSet<(u32, u32)> = surface
        .iter()
        .flat_map(|f| [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])])
        .collect();
    let mut out = Vec::new();
    for &(a, b) in &directed {
        if directed.contains(&(b, a)) {
            continue;
        }
        let (pa, pb) = (tri.uv[a as usize], tri.uv[b as usize]);
        let (axis, value) = match side {
            0 => (0, 0.0),
            1 => (0, last),
            2 => (1, 0.0),
            _ => (1, last),
        };
        if pa[axis] == value && pb[axis] == value {
            let other = 1 - axis;
            let base = tile.origin[other] as f64;
            let (mut s, mut e) = (base + pa[other], base + pb[other]);
            let (mut za, mut zb) = (tri.z[a as usize], tri.z[b as usize]);
            if s > e {
                std::mem::swap(&mut s, &mut e);
                std::mem::swap(&mut za, &mut zb);
            }
            out.push((s, e, za, zb));
        }
    }
    out.sort_by(|x, y| x.0.total_cmp(&y.0));
    out
}

/// Walks every shared border of neighbouring tiles: the edges of both sides must be the same
/// segments with the same heights (no crack, no T-junction across the seam).
pub fn check_borders(set: &TileSet, tris: &[TileTriangulation]) -> Result<usize, String> {
    let mut walked = 0;
    for row in 0..set.grid[1] {
        for col in 0..set.grid[0] {
            // The east neighbour (this tile's side 1 against its side 0), then the north one
            // (side 3 against side 2).
            for (c, r, side, other) in [(col + 1, row, 1, 0), (col, row + 1, 3, 2)] {
                if c >= set.grid[0] || r >= set.grid[1] {
                    continue;
                }
                let (a, b) = (set.index(col, row), set.index(c, r));
                let (ea, eb) = (
                    side_edges(set, &tris[a], side),
                    side_edges(set, &tris[b], other),
                );
                if ea != eb {
                    return Err(format!(
                        "seam between tiles ({col},{row}) and ({c},{r}) differs:\n{ea:?}\n{eb:?}"
                    ));
                }
                walked += ea.len();
            }
        }
    }
    Ok(walked)
}

/// Largest vertical distance between a valid sample of the tile and the mesh, checking every
/// sample against every triangle that covers it; errors if a sample is not covered.
pub fn max_vertical_error(set: &TileSet, tri: &TileTriangulation) -> Result<f64, String> {
    let tile = &set.tiles[tri.tile];
    let [vw, vh] = tile.valid;
    let mut worst = vec![f64::NAN; vw * vh];
    for f in &tri.triangles[..tri.surface_triangles] {
        let [a, b, c] = f.map(|v| tri.uv[v as usize]);
        let [za, zb, zc] = f.map(|v| tri.z[v as usize] as f64);
        let a2 = area2(a, b, c);
        let (i0, i1) = (
            a[0].min(b[0]).min(c[0]).ceil() as usize,
            a[0].max(b[0]).max(c[0]).floor() as usize,
        );
        let (j0, j1) = (
            a[1].min(b[1]).min(c[1]).ceil() as usize,
            a[1].max(b[1]).max(c[1]).floor() as usize,
        );
        for j in j0..=j1.min(vh - 1) {
            for i in i0..=i1.min(vw - 1) {
                let p = [i as f64, j as f64];
                let (wa, wb, wc) = (
                    area2(p, b, c) / a2,
                    area2(a, p, c) / a2,
                    area2(a, b, p) / a2,
                );
                let eps = -1e-9;
                if wa < eps || wb < eps || wc < eps {
                    continue;
                }
                let z = wa * za + wb * zb + wc * zc;
                let e = (tile.heights[[j, i]] as f64 - z).abs();
                let slot = &mut worst[j * vw + i];
                *slot = if slot.is_nan() { e } else { slot.max(e) };
            }
        }
    }
    let mut max = 0.0f64;
    for (k, e) in worst.iter().enumerate() {
        if e.is_nan() {
            return Err(format!(
                "tile {}: sample {:?} not covered by the mesh",
                tri.tile,
                (k % vw, k / vw)
            ));
        }
        max = max.max(*e);
    }
    Ok(max)
}

/// A global node: lower-left sample (x0, y0) in the whole grid and edge length d.
pub type Node = (usize, usize, usize);

/// The padded global grid the tiles make together (tiles overlap on their shared borders).
pub fn global_grid(set: &TileSet) -> (usize, usize, Vec<f32>) {
    let step = set.tile_size - 1;
    let (w, h) = (set.grid[0] * step + 1, set.grid[1] * step + 1);
    let mut g = vec![f32::NAN; w * h];
    for t in &set.tiles {
        for j in 0..set.tile_size {
            for i in 0..set.tile_size {
                g[(t.origin[1] + j) * w + t.origin[0] + i] = t.heights[[j, i]];
            }
        }
    }
    (w, h, g)
}

/// Does node q (one level lower) lie inside node n or share a piece of n's outline?
pub fn contains_or_borders(n: Node, q: Node) -> bool {
    let (nx0, ny0, d) = n;
    let (qx0, qy0, s) = q;
    let (nx1, ny1, qx1, qy1) = (nx0 + d, ny0 + d, qx0 + s, qy0 + s);
    let inside = qx0 >= nx0 && qx1 <= nx1 && qy0 >= ny0 && qy1 <= ny1;
    let overlap_x = qx0.max(nx0) < qx1.min(nx1);
    let overlap_y = qy0.max(ny0) < qy1.min(ny1);
    let touch_x = qx1 == nx0 || qx0 == nx1;
    let touch_y = qy1 == ny0 || qy0 == ny1;
    inside || (touch_x && overlap_y) || (touch_y && overlap_x)
}

/// Candidates one level lower around node n (a 4 × 4 window of aligned positions); the
/// predicate decides which count.
pub fn lower_candidates(n: Node) -> Vec<Node> {
    let (x0, y0, d) = n;
    let s = d / 2;
    let mut v = Vec::new();
    for dy in [-1i64, 0, 1, 2] {
        for dx in [-1i64, 0, 1, 2] {
            let (x, y) = (x0 as i64 + dx * s as i64, y0 as i64 + dy * s as i64);
            if x >= 0 && y >= 0 {
                v.push((x as usize, y as usize, s));
            }
        }
    }
    v
}

/// The mirror pairs of nodes of size d across shared tile borders (each pair once).
pub fn mirror_pairs(set: &TileSet, d: usize) -> Vec<(Node, Node)> {
    let step = set.tile_size - 1;
    let (w, h) = (set.grid[0] * step, set.grid[1] * step);
    let mut v = Vec::new();
    for y0 in (0..h).step_by(d) {
        for x0 in (0..w).step_by(d) {
            if (x0 + d).is_multiple_of(step) && x0 + d < w {
                v.push(((x0, y0, d), (x0 + d, y0, d)));
            }
            if (y0 + d).is_multiple_of(step) && y0 + d < h {
                v.push(((x0, y0, d), (x0, y0 + d, d)));
            }
        }
    }
    v
}

/// All global nodes of size d.
pub fn nodes_of(set: &TileSet, d: usize) -> Vec<Node> {
    let step = set.tile_size - 1;
    let (w, h) = (set.grid[0] * step, set.grid[1] * step);
    let mut v = Vec::new();
    for y0 in (0..h).step_by(d) {
        for x0 in (0..w).step_by(d) {
            v.push((x0, y0, d));
        }
    }
    v
}

/// The stored value of global node n in per-tile matrices.
pub fn value_at(set: &TileSet, m: &[terratile::terrain::quadtree::NodeValues], n: Node) -> f32 {
    let step = set.tile_size - 1;
    let (x0, y0, d) = n;
    let (col, row) = (x0 / step, y0 / step);
    let t = set.index(col, row);
    let (ci, cj) = (x0 - col * step + d / 2, y0 - row * step + d / 2);
    m[t].get(ci, cj)
}

/// Brute force of the propagated, reconciled metric: level by level over global nodes, `raw`
/// of each, max with `k` × every lower node it contains or borders, then mirror pairs across
/// tile borders take their max until nothing changes.
pub fn brute_force_tree(
    set: &TileSet,
    k: f32,
    raw: impl Fn(&[f32], usize, Node) -> f32,
) -> HashMap<Node, f32> {
    let (w, _, g) = global_grid(set);
    let mut val: HashMap<Node, f32> = HashMap::new();
    let mut d = 2;
    while d < set.tile_size {
        let nodes = nodes_of(set, d);
        let mut level: HashMap<Node, f32> = HashMap::new();
        for &n in &nodes {
            let mut v = raw(&g, w, n);
            if d > 2 {
                for q in lower_candidates(n) {
                    if let Some(&qv) = val.get(&q) {
                        if contains_or_borders(n, q) {
                            v = v.max(k * qv);
                        }
                    }
                }
            }
            level.insert(n, v);
        }
        let pairs = mirror_pairs(set, d);
        loop {
            let mut changed = false;
            for &(a, b) in &pairs {
                let m = level[&a].max(level[&b]);
                for x in [a, b] {
                    if level[&x] != m {
                        level.insert(x, m);
                        changed = true;
                    }
                }
            }
            if !changed {
                break;
            }
        }
        val.extend(level);
        d *= 2;
    }
    val
}

/// d2 of global node n straight from its definition (f32, as stored).
pub fn d2_definition(g: &[f32], w: usize, n: Node) -> f32 {
    let (x0, y0, d) = n;
    let r = d / 2;
    let h = |i: usize, j: usize| g[j * w + i];
    let (cx, cy) = (x0 + r, y0 + r);
    // (point, corner a, corner b): 4 edge midpoints, then the centre on both diagonals.
    let cases = [
        ((cx, y0), (x0, y0), (x0 + d, y0)),
        ((cx, y0 + d), (x0, y0 + d), (x0 + d, y0 + d)),
        ((x0, cy), (x0, y0), (x0, y0 + d)),
        ((x0 + d, cy), (x0 + d, y0), (x0 + d, y0 + d)),
        ((cx, cy), (x0, y0), (x0 + d, y0 + d)),
        ((cx, cy), (x0 + d, y0), (x0, y0 + d)),
    ];
    let mut worst = f32::NAN;
    for (p, a, b) in cases {
        let dh = (h(p.0, p.1) - 0.5 * (h(a.0, a.1) + h(b.0, b.1))).abs();
        worst = worst.max(dh);
    }
    if worst.is_nan() {
        0.0
    } else {
        worst / d as f32
    }
}
