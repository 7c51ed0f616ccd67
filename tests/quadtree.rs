//! The quadtree metrics and CLOD extraction against slow twins and invariants: d2 equals its
//! definition (brute force, random and real tiles), the propagation inequality holds for
//! every node and across tile borders, meshes are conforming inside each tile and along every
//! shared border, and view-independent meshes are within the tolerance of every sample.

use crate::common;

use crate::tiles_support::*;
use proptest::prelude::*;
use terratile::terrain::extract::{self, Criterion, ExtractParams, Refiner, TileTriangulation};
use terratile::terrain::quadtree::{self, build, NodeValues, Quadtree, QuadtreeParams};
use terratile::terrain::tiles::TileSet;

/// A shared survey's filled heightfield in tiles of 65 samples, when the data is there.
fn real_tiles(rel: &str) -> Option<TileSet> {
    let path = common::data_file(rel)?;
    Some(tiles_of(
        &heightfield_from_points(&read_points(&path), true),
        65,
    ))
}

/// autzen_trim's tiles of 65 samples and their quadtree with the default C.
fn autzen_quadtree() -> Option<(TileSet, Quadtree)> {
    let set = real_tiles("lidar/autzen_trim.las")?;
    let qt = build(&set, &QuadtreeParams::default()).unwrap();
    Some((set, qt))
}

/// d2 of every node of every tile equals the brute force, and non-centre samples hold 0.
fn check_d2_against_brute_force(set: &TileSet, c: f64) {
    let qt = build(
        set,
        &QuadtreeParams {
            min_resolution_c: c,
        },
    )
    .unwrap();
    let brute = brute_force_tree(set, qt.k as f32, d2_definition);
    let mut d = 2;
    let mut checked = 0;
    while d < set.tile_size {
        for n in nodes_of(set, d) {
            let fast = value_at(set, &qt.d2, n);
            assert_eq!(
                fast.to_bits(),
                brute[&n].to_bits(),
                "node {n:?}: fast {fast} brute {}",
                brute[&n]
            );
            checked += 1;
        }
        d *= 2;
    }
    assert_eq!(checked, brute.len());
    // Every sample that is no node's centre holds 0.
    for (t, m) in qt.d2.iter().enumerate() {
        for ((j, i), v) in m.to_matrix().indexed_iter() {
            let last = set.tile_size - 1;
            let centre =
                i > 0 && j > 0 && i < last && j < last && i.trailing_zeros() == j.trailing_zeros();
            if !centre {
                assert_eq!(*v, 0.0, "tile {t} sample ({i},{j}) is no centre");
            }
        }
    }
}

/// d2(N) ≥ K · d2(Q) for every node N and every node Q one level lower that N contains or
/// borders, wherever Q is (this tile or a neighbour).
fn check_propagation(set: &TileSet, m: &[NodeValues], k: f32) -> usize {
    let mut pairs = 0;
    let mut d = 4;
    while d < set.tile_size {
        for n in nodes_of(set, d) {
            let vn = value_at(set, m, n);
            for q in lower_candidates(n) {
                let (w, h) = (
                    set.grid[0] * (set.tile_size - 1),
                    set.grid[1] * (set.tile_size - 1),
                );
                if q.0 + q.2 > w || q.1 + q.2 > h || !contains_or_borders(n, q) {
                    continue;
                }
                let vq = value_at(set, m, q);
                assert!(vn >= k * vq, "node {n:?} = {vn} < K · {vq} of {q:?}");
                pairs += 1;
            }
        }
        d *= 2;
    }
    pairs
}

fn refiner_for<'a>(
    set: &'a TileSet,
    qt: &'a quadtree::Quadtree,
    err: &'a [NodeValues],
    crit: Criterion,
) -> Refiner<'a> {
    Refiner::new(set, qt, Some(err), crit).unwrap()
}

fn check_meshes(set: &TileSet, tris: &[TileTriangulation]) {
    for t in tris {
        if let Err(e) = check_conforming(set, t) {
            panic!("{e}");
        }
    }
    if let Err(e) = check_borders(set, tris) {
        panic!("{e}");
    }
}

#[test]
fn d2_equals_brute_force_on_random_tiles() {
    for (seed, cols, rows, rough) in [
        (1, 130, 129, 0.3),
        (2, 200, 70, 2.0),
        (3, 65, 65, 0.0),
        (4, 150, 190, 5.0),
    ] {
        let set = tiles_of(&synthetic(cols, rows, seed, rough), 65);
        check_d2_against_brute_force(&set, 9.0);
    }
    // Another C.
    let set = tiles_of(&synthetic(140, 100, 5, 1.0), 65);
    check_d2_against_brute_force(&set, 3.5);
}

#[test]
fn d2_equals_brute_force_on_real_tiles() {
    let Some(set) = real_tiles("lidar/Topography.laz") else {
        return;
    };
    assert!(set.tiles.len() >= 9, "{:?}", set.grid);
    check_d2_against_brute_force(&set, 9.0);
}

#[test]
fn vertical_error_matches_an_explicit_fan_evaluation() {
    // Independent twin: build each fan variant's triangles and test every sample with
    // barycentric coordinates.
    let hf = synthetic(65, 65, 11, 1.5);
    let set = tiles_of(&hf, 65);
    let (w, _, g) = global_grid(&set);
    let mut d = 2;
    while d < set.tile_size {
        for n in nodes_of(&set, d) {
            let fast = quadtree::raw_vertical_error(&g, w, n.0 + d / 2, n.1 + d / 2, d / 2);
            let slow = explicit_fan_error(&g, w, n);
            assert!(
                (fast - slow).abs() <= 1e-9 * slow.max(1.0),
                "{n:?}: {fast} vs {slow}"
            );
        }
        d *= 2;
    }
}

fn explicit_fan_error(g: &[f32], w: usize, n: (usize, usize, usize)) -> f64 {
    let (x0, y0, d) = n;
    let r = d / 2;
    let h = |i: usize, j: usize| g[j * w + i] as f64;
    let c = (x0 + r, y0 + r);
    let ring = [
        (x0, y0),
        (x0 + r, y0),
        (x0 + d, y0),
        (x0 + d, y0 + r),
        (x0 + d, y0 + d),
        (x0 + r, y0 + d),
        (x0, y0 + d),
        (x0, y0 + r),
    ];
    let mut worst = 0.0f64;
    for mask in 0..16u32 {
        let pts: Vec<(usize, usize)> = ring
            .iter()
            .enumerate()
            .filter(|(k, _)| k % 2 == 0 || mask & (1 << (k / 2)) != 0)
            .map(|(_, p)| *p)
            .collect();
        for j in y0..=y0 + d {
            for i in x0..=x0 + d {
                let p = [i as f64, j as f64];
                for k in 0..pts.len() {
                    let (a, b) = (pts[k], pts[(k + 1) % pts.len()]);
                    let (pc, pa, pb) = (
                        [c.0 as f64, c.1 as f64],
                        [a.0 as f64, a.1 as f64],
                        [b.0 as f64, b.1 as f64],
                    );
                    let a2 = area2(pc, pa, pb);
                    let (wc, wa, wb) = (
                        area2(p, pa, pb) / a2,
                        area2(pc, p, pb) / a2,
                        area2(pc, pa, p) / a2,
                    );
                    if wc < -1e-12 || wa < -1e-12 || wb < -1e-12 {
                        continue;
                    }
                    let z = wc * h(c.0, c.1) + wa * h(a.0, a.1) + wb * h(b.0, b.1);
                    worst = worst.max((h(i, j) - z).abs());
                }
            }
        }
    }
    worst
}

#[test]
fn vertical_error_tree_matches_brute_force_propagation() {
    let set = tiles_of(&synthetic(150, 120, 21, 1.0), 65);
    let fast = quadtree::vertical_error(&set);
    let brute = brute_force_tree(&set, 1.0, |g, w, n| {
        let r = n.2 / 2;
        let v = quadtree::raw_vertical_error(g, w, n.0 + r, n.1 + r, r);
        let f = v as f32;
        if (f as f64) < v {
            f32::from_bits(f.to_bits() + 1)
        } else {
            f
        }
    });
    for (n, v) in &brute {
        assert_eq!(value_at(&set, &fast, *n), *v, "{n:?}");
    }
    check_propagation(&set, &fast, 1.0);
}

#[test]
fn tolerance_meshes_hold_every_sample_on_real_tiles() {
    let mut files = Vec::new();
    for f in [
        "lidar/Topography.laz",
        "lidar/autzen_trim.las",
        "lidar/CSite4_orig-utm.laz",
    ] {
        if let Some(p) = common::data_file(f) {
            files.push(p);
        }
    }
    for path in files {
        let hf = heightfield_from_points(&read_points(&path), true);
        for size in [65, 257] {
            let set = tiles_of(&hf, size);
            let qt = build(&set, &QuadtreeParams::default()).unwrap();
            let err = quadtree::vertical_error(&set);
            check_propagation(&set, &qt.d2, qt.k as f32);
            let (lo, hi) = set.z_range().unwrap();
            for tol in [0.05, 0.5, 2.0, (hi - lo) / 4.0] {
                let r = refiner_for(&set, &qt, &err, Criterion::Tolerance { max_error: tol });
                let tris = extract::extract(&set, &r).unwrap();
                check_meshes(&set, &tris);
                let mut worst = 0.0f64;
                let mut count = 0;
                for t in &tris {
                    worst = worst.max(max_vertical_error(&set, t).unwrap());
                    count += t.triangles.len();
                }
                assert!(
                    worst <= tol * (1.0 + 1e-6),
                    "{}: tile size {size}: error {worst} > tolerance {tol}",
                    path.display()
                );
                eprintln!(
                    "{} size {size} tol {tol:.3}: {count} triangles, max vertical error {worst:.4}",
                    path.file_name().unwrap().to_string_lossy()
                );
            }
        }
    }
}

#[test]
fn view_dependent_meshes_are_crack_free_on_real_tiles() {
    let Some((set, qt)) = autzen_quadtree() else {
        return;
    };
    let err = quadtree::vertical_error(&set);
    let (lo, hi) = set.z_range().unwrap();
    let [x0, y0] = set.corner;
    let ext = [
        set.samples[0] as f64 * set.cell_size[0],
        set.samples[1] as f64 * set.cell_size[1],
    ];
    for (fx, fy, dz, c) in [
        (0.5, 0.5, 50.0, 25.0),
        (0.0, 0.0, 10.0, 5.0),
        (1.2, -0.3, 300.0, 100.0),
        (0.3, 0.8, 1.0, 2.0),
    ] {
        let eye = [x0 + fx * ext[0], y0 + fy * ext[1], hi + dz];
        let crit = Criterion::View {
            eye,
            min_resolution_c: qt.c,
            desired_resolution_c: c,
            z_ref: 0.5 * (lo + hi),
        };
        let tris = extract::extract(&set, &refiner_for(&set, &qt, &err, crit)).unwrap();
        check_meshes(&set, &tris);
    }
}

fn arb_case() -> impl Strategy<Value = (usize, usize, u64, f64, usize)> {
    (
        66usize..220,
        66usize..220,
        any::<u64>(),
        0.0f64..6.0,
        0usize..3,
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, .. ProptestConfig::default() })]

    /// Random terrains and tilings: the propagation inequality holds for every node, across
    /// tile borders too, and meshes of every criterion are conforming inside each tile and
    /// along every shared border.
    #[test]
    fn propagation_and_crack_freedom(case in arb_case(), tol in 0.01f64..20.0, eye in (-0.5f64..1.5, -0.5f64..1.5, 0.0f64..400.0), c in 0.5f64..200.0) {
        let (cols, rows, seed, rough, _) = case;
        let set = tiles_of(&synthetic(cols, rows, seed, rough), 65);
        let qt = build(&set, &QuadtreeParams::default()).unwrap();
        let err = quadtree::vertical_error(&set);
        check_propagation(&set, &qt.d2, qt.k as f32);
        check_propagation(&set, &err, 1.0);
        let r = refiner_for(&set, &qt, &err, Criterion::Tolerance { max_error: tol });
        let tris = extract::extract(&set, &r).unwrap();
        check_meshes(&set, &tris);
        for t in &tris {
            let e = max_vertical_error(&set, t).unwrap();
            prop_assert!(e <= tol * (1.0 + 1e-6), "error {} > {}", e, tol);
        }
        let (lo, hi) = set.z_range().unwrap();
        let ext = [set.samples[0] as f64 * set.cell_size[0], set.samples[1] as f64 * set.cell_size[1]];
        let eye = [set.corner[0] + eye.0 * ext[0], set.corner[1] + eye.1 * ext[1], hi + eye.2];
        let crit = Criterion::View { eye, min_resolution_c: qt.c, desired_resolution_c: c, z_ref: 0.5 * (lo + hi) };
        let tris = extract::extract(&set, &refiner_for(&set, &qt, &err, crit)).unwrap();
        check_meshes(&set, &tris);
    }

    /// d2 of random small tile sets equals the brute force, whatever C.
    #[test]
    fn d2_brute_force_random(cols in 66usize..150, rows in 66usize..150, seed in any::<u64>(), c in 2.1f64..40.0) {
        let set = tiles_of(&synthetic(cols, rows, seed, 1.0), 65);
        check_d2_against_brute_force(&set, c);
    }
}

#[test]
fn extract_params_map_metres_to_height_units() {
    // Autzen is in international feet: 0.3048 m per unit.
    let Some((set, qt)) = autzen_quadtree() else {
        return;
    };
    let p = ExtractParams {
        tolerance: 0.3048,
        ..Default::default()
    };
    match p.criterion(&set, &qt).unwrap() {
        Criterion::Tolerance { max_error } => {
            assert!((max_error - 1.0).abs() < 1e-9, "{max_error}")
        }
        other => panic!("{other:?}"),
    }
}
