//! Georeferencing: bad CRS input (issue 17).

use crate::common::*;

/// Runs the default job with `[input] crs = CRS` (TOML string syntax) and expects one error
/// line holding every needle, exit 2, nothing written.
fn input_crs_is_refused(crs: &str, needles: &[&str]) {
    let d = default_job();
    edit_pipeline(d.path(), "[input]\n", &format!("[input]\ncrs = {crs}\n"));
    terratile(d.path(), &["run", "--quiet"])
        .input_error(needles)
        .left_nothing("out");
}

/// `[input] crs` naming a code the EPSG table lacks: one line at the key, exit 2, nothing
/// written (it used not to exist; an unknown code must not reach the encoders).
#[test]
fn input_crs_unknown_epsg_code_is_refused_at_its_key() {
    input_crs_is_refused(
        "\"EPSG:99999\"",
        &["pipeline.toml:", "input.crs", "EPSG:99999"],
    );
}

/// `[input] crs` that is not `EPSG:n` at all.
#[test]
fn input_crs_not_an_epsg_code_is_refused_at_its_key() {
    input_crs_is_refused("\"+proj=utm\\n\"", &["input.crs", "EPSG:n", "\\n"]);
}

/// The Cesium tileset's most detailed level resampled the grid on a geographic lattice turned
/// against it, which cut corners at walls (4.5 m off at autzen_trim's buildings for a 0.5 m
/// tolerance) unless partial levels down to level 24 were asked for, at a cost of thousands of
/// tiles. Its tiles are now adaptive triangulations of the grid's own surface: over a UTM grid
/// of 0.5 m cells with a 6 m block turned against the grid, every point of the most detailed
/// tiles over the grid is within the tolerance of the grid's bilinear surface.
#[test]
fn quantized_mesh_most_detailed_level_holds_the_grid_at_walls() {
    use terratile::terrain::{tiles, CellState, Heightfield};
    let crs = terratile::geo::crs_from_key("EPSG:32632").unwrap();
    let (cols, rows, cell) = (300, 260, 0.5);
    let corner = [420_000.0, 5_400_000.0];
    let mut hf = Heightfield::empty(cols, rows, corner, [cell, cell], 0.0, Some(crs.clone()));
    let (c, s) = (0.4f64.cos(), 0.4f64.sin());
    let h = |i: usize, j: usize| {
        let (x, y) = (i as f64 - 150.0, j as f64 - 130.0);
        let (u, v) = (c * x + s * y, -s * x + c * y);
        let block = if u.abs() < 50.0 && v.abs() < 30.0 {
            6.0
        } else {
            0.0
        };
        100.0 + 0.01 * i as f64 + block
    };
    for j in 0..rows {
        for i in 0..cols {
            hf.heights[[j, i]] = h(i, j) as f32;
            hf.state[[j, i]] = CellState::Measured;
        }
    }
    let set = tiles::tile(&hf, &tiles::TileParams::default()).unwrap();
    let tolerance = 0.25;
    let to = terratile::geo::ToWgs84::new(&crs).unwrap();
    let grid = |lon: f64, lat: f64| {
        let [x, y] = to.inverse(lon, lat).unwrap();
        let (fi, fj) = ((x - corner[0]) / cell - 0.5, (y - corner[1]) / cell - 0.5);
        let inside =
            (0.0..=(cols - 1) as f64).contains(&fi) && (0.0..=(rows - 1) as f64).contains(&fj);
        inside.then(|| {
            let (i0, j0) = ((fi as usize).min(cols - 2), (fj as usize).min(rows - 2));
            let (di, dj) = (fi - i0 as f64, fj - j0 as f64);
            let g = |i: usize, j: usize| f64::from(hf.heights[[j, i]]);
            (g(i0, j0) * (1.0 - di) + g(i0 + 1, j0) * di) * (1.0 - dj)
                + (g(i0, j0 + 1) * (1.0 - di) + g(i0 + 1, j0 + 1) * di) * dj
        })
    };
    // The worst distance from the grid's surface at random points over the most detailed
    // tiles, and how many points were checked.
    let worst_of = |ts: &terratile::geo::tms::Tileset| {
        let finest = ts.levels.len() as u32 - 1;
        let mut rng = terratile::SplitMix64::new(7);
        let (mut checked, mut worst) = (0, 0.0f64);
        for t in ts.tiles.iter().filter(|t| t.zxy[0] == finest) {
            let [w, so, e, n] = t.bounds;
            for _ in 0..400 {
                let (u, v) = (rng.range(0.0, 32767.0), rng.range(0.0, 32767.0));
                let Some(want) = grid(w + (e - w) * u / 32767.0, so + (n - so) * v / 32767.0)
                else {
                    continue;
                };
                let mesh = t
                    .triangles
                    .iter()
                    .find_map(|f| {
                        let p = f.map(|k| {
                            let q = t.uv[k as usize];
                            [f64::from(q[0]), f64::from(q[1]), t.heights[k as usize]]
                        });
                        height_in_triangle(p, u, v)
                    })
                    .expect("the tile's triangles cover it");
                worst = worst.max((mesh - want).abs());
                checked += 1;
            }
        }
        (checked, worst)
    };
    let (checked, worst) = worst_of(&terratile::geo::tms::tileset(&set, tolerance).unwrap());
    assert!(checked > 1000, "{checked} points over the grid");
    // 1 mm for the projection's curvature over a tile.
    assert!(
        worst <= tolerance + 1e-3,
        "{worst} m from the grid's surface"
    );
    // `quantized_mesh_lattice = true` keeps the lattice there: it is within the tolerance of
    // the lattice's heights only, and cuts the block's corners.
    let lattice = terratile::geo::tms::tileset_with(&set, tolerance, false).unwrap();
    let (_, lattice_worst) = worst_of(&lattice);
    assert!(
        lattice_worst > tolerance,
        "the lattice level is within {lattice_worst} m: the switch changes nothing"
    );
}
