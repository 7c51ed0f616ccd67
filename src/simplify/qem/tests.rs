use super::engine::{error, optimal};
use super::*;
use crate::mesh::adjacency::EdgeFaces;
use crate::simplify::quadric::Quadric;
use glam::{DVec3, Vec3};

use crate::simplify::test_meshes::grid;

/// A closed, bumpy UV sphere.
fn sphere(n: usize) -> TriMesh {
    let mut m = TriMesh::default();
    m.positions.push(Vec3::new(0.0, 0.0, 1.0));
    for j in 1..n {
        let th = std::f32::consts::PI * j as f32 / n as f32;
        for i in 0..2 * n {
            let ph = std::f32::consts::PI * i as f32 / n as f32;
            let r = 1.0 + 0.15 * (3.0 * ph).sin() * (2.0 * th).cos();
            m.positions.push(Vec3::new(
                r * th.sin() * ph.cos(),
                r * th.sin() * ph.sin(),
                r * th.cos(),
            ));
        }
    }
    m.positions.push(Vec3::new(0.0, 0.0, -1.0));
    let ring = |j: usize, i: usize| (1 + (j - 1) * 2 * n + i % (2 * n)) as u32;
    let south = m.positions.len() as u32 - 1;
    for i in 0..2 * n {
        m.indices.push([0, ring(1, i), ring(1, i + 1)]);
        for j in 1..n - 1 {
            m.indices
                .push([ring(j, i), ring(j + 1, i), ring(j + 1, i + 1)]);
            m.indices
                .push([ring(j, i), ring(j + 1, i + 1), ring(j, i + 1)]);
        }
        m.indices.push([ring(n - 1, i), south, ring(n - 1, i + 1)]);
    }
    m
}

/// The fast collapse path and its slow twin, each run on `m` with `p` down to `target`.
fn fast_and_slow<'m>(m: &'m TriMesh, p: &QemParams, target: u64) -> (Collapse<'m>, Collapse<'m>) {
    let prep = Prepared::new(m);
    let mut fast = Collapse::new(&prep, p);
    fast.run_fast(target as usize);
    let mut slow = Collapse::new(&prep, p);
    slow.run_slow(target as usize);
    (fast, slow)
}

fn params(triangles: u64, placement: Placement) -> QemParams {
    QemParams::plain(triangles, placement)
}

/// Both engines: the tests of an invariant run on each.
const ENGINES: [Engine; 2] = [Engine::Heap, Engine::Passes];

/// Every placement, for the tests that run each.
const PLACEMENTS: [Placement; 3] = [
    Placement::Optimal,
    Placement::Endpoint,
    Placement::TwoLocalMappings,
];

/// [`params`] with `engine`.
fn on(engine: Engine, triangles: u64, placement: Placement) -> QemParams {
    QemParams {
        engine,
        ..params(triangles, placement)
    }
}

#[test]
fn a_plane_quadric_is_zero_on_its_plane() {
    let n = DVec3::new(1.0, 2.0, -2.0).normalize();
    let q = Quadric::plane(n, -0.7, 3.0);
    // Points on n·x = 0.7.
    let u = n.any_orthonormal_vector();
    let v = n.cross(u);
    for (s, t) in [(0.0, 0.0), (3.0, -1.0), (-20.0, 5.5)] {
        let p = n * 0.7 + u * s + v * t;
        assert!(q.eval(p) < 1e-12, "{}", q.eval(p));
    }
    // Off the plane: weight × distance².
    let p = n * 1.7;
    assert!((q.eval(p) - 3.0).abs() < 1e-12);
}

#[test]
fn two_crossing_planes_have_their_optimum_on_their_line() {
    // Planes z = 0 and x = 1 (line x = 1, z = 0): the placement must land on it, and
    // between the endpoints' projections is as good as anywhere on it (A is singular along
    // y: the fallback picks the best of endpoints and midpoint, all on the line here).
    let q = Quadric::plane(DVec3::Z, 0.0, 1.0) + Quadric::plane(DVec3::X, -1.0, 2.0);
    let (a, b) = (DVec3::new(1.0, -1.0, 0.0), DVec3::new(1.0, 3.0, 0.0));
    let p = optimal(&q, a, b);
    assert!((p.x - 1.0).abs() < 1e-12 && p.z.abs() < 1e-12, "{p}");
    assert!(q.eval(p) < 1e-12);
    // Endpoints off the line: the best of them and the midpoint, never a far point.
    let (a, b) = (DVec3::new(1.2, 0.0, 0.1), DVec3::new(0.9, 1.0, -0.05));
    let p = optimal(&q, a, b);
    let mid = 0.5 * (a + b);
    assert!(q.eval(p) <= q.eval(a).min(q.eval(b)).min(q.eval(mid)) + 1e-15);
}

#[test]
fn cube_corners_are_recovered_exactly() {
    // The three faces of a unit cube at each corner meet there: the quadric of the corner's
    // three planes (any weights) has the corner as its exact minimiser.
    for corner in 0..8 {
        let c = DVec3::new(
            (corner & 1) as f64,
            ((corner >> 1) & 1) as f64,
            ((corner >> 2) & 1) as f64,
        );
        let q = Quadric::plane(DVec3::X, -c.x, 1.5)
            + Quadric::plane(DVec3::Y, -c.y, 0.25)
            + Quadric::plane(DVec3::Z, -c.z, 4.0);
        let p = optimal(&q, DVec3::splat(0.5), DVec3::splat(0.3));
        assert!((p - c).length() < 1e-12, "{corner}: {p} vs {c}");
        assert!(error(&q, p) < 1e-9);
    }
}

/// A cube with each face split into a k × k grid: collapsing it far keeps the corners.
fn cube(k: usize) -> TriMesh {
    let mut m = TriMesh::default();
    let mut add_face = |o: Vec3, u: Vec3, v: Vec3| {
        let base = m.positions.len() as u32;
        for j in 0..=k {
            for i in 0..=k {
                m.positions
                    .push(o + u * (i as f32 / k as f32) + v * (j as f32 / k as f32));
            }
        }
        let id = |i: usize, j: usize| base + (j * (k + 1) + i) as u32;
        for j in 0..k {
            for i in 0..k {
                m.indices.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                m.indices.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
    };
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    add_face(Vec3::ZERO, y, x); // bottom, outward -z
    add_face(z, x, y); // top
    add_face(Vec3::ZERO, x, z); // y = 0
    add_face(y, z, x); // y = 1
    add_face(Vec3::ZERO, z, y); // x = 0
    add_face(x, y, z); // x = 1
    m
}

#[test]
fn a_cube_collapses_to_its_corners() {
    let m = cube(4);
    let r = simplify(&m, &params(12, Placement::Optimal)).unwrap();
    assert_eq!(r.mesh.triangle_count(), 12, "{:?}", r.report);
    let mut corners: Vec<[i32; 3]> = r
        .mesh
        .positions
        .iter()
        .map(|p| [0, 1, 2].map(|k| (p[k] * 1e4).round() as i32))
        .collect();
    corners.sort_unstable();
    corners.dedup();
    assert_eq!(corners.len(), 8);
    for c in &corners {
        assert!(c.iter().all(|&x| x == 0 || x == 10000), "{c:?}");
    }
    assert!(r.report.max_error < 1e-6, "{}", r.report.max_error);
}

fn assert_closed_manifold(m: &TriMesh) {
    let ef = EdgeFaces::new(&m.indices);
    for e in 0..ef.len() as u32 {
        assert_eq!(ef.faces(e).len(), 2, "edge {:?}", ef.edge(e));
    }
}

#[test]
fn the_heap_equals_the_slow_twin() {
    for (m, target) in [
        (grid(6), 10u64),
        (grid(9), 40),
        (sphere(6), 20),
        (sphere(8), 8),
        (cube(3), 12),
    ] {
        for placement in PLACEMENTS {
            for (merge, cost) in [
                (QuadricMerge::Sum, Cost::Quadric),
                (QuadricMerge::Mean, Cost::Quadric),
                (QuadricMerge::Sum, Cost::Distance),
            ] {
                for (lock_border, check_intersections) in
                    [(false, false), (true, false), (false, true)]
                {
                    let p = QemParams {
                        merge,
                        lock_border,
                        cost,
                        check_intersections,
                        ..params(target, placement)
                    };
                    let (fast, slow) = fast_and_slow(&m, &p, target);
                    assert_eq!(fast.log, slow.log, "{placement} {merge} {lock_border}");
                    let (a, b) = (fast.finish(), slow.finish());
                    assert_eq!(a.mesh.positions, b.mesh.positions);
                    assert_eq!(a.mesh.indices, b.mesh.indices);
                    // The twin counts no rejections (it never pops a candidate).
                    assert_eq!(a.report.max_error, b.report.max_error);
                    assert_eq!(a.report.collapses, b.report.collapses);
                }
            }
        }
    }
}

#[test]
fn a_closed_surface_stays_a_closed_manifold() {
    let m = sphere(16);
    for engine in ENGINES {
        for target in [400, 100, 20, 4] {
            let r = simplify(&m, &on(engine, target, Placement::Optimal)).unwrap();
            assert_closed_manifold(&r.mesh);
            assert!(r.mesh.triangle_count() as u64 <= target.max(4) + 1);
        }
    }
}

#[test]
fn lock_border_keeps_the_border_exactly() {
    let m = grid(12);
    let on_border = |p: &Vec3| p.x == 0.0 || p.x == 1.0 || p.y == 0.0 || p.y == 1.0;
    let border_in: Vec<Vec3> = m.positions.iter().copied().filter(on_border).collect();
    for engine in ENGINES {
        let p = QemParams {
            lock_border: true,
            ..on(engine, 60, Placement::Optimal)
        };
        let r = simplify(&m, &p).unwrap();
        // Every border vertex of the input is still there, unmoved.
        for b in &border_in {
            assert!(r.mesh.positions.contains(b), "{engine}: {b}");
        }
    }
}

#[test]
fn max_error_stops_the_collapse() {
    let m = sphere(12);
    for engine in ENGINES {
        let p = QemParams {
            max_error: Some(0.01),
            ..on(engine, 1, Placement::Optimal)
        };
        let r = simplify(&m, &p).unwrap();
        assert!(!r.report.target_reached, "{:?}", r.report);
        assert!(r.report.max_error <= 0.01);
        assert!(r.mesh.triangle_count() < m.triangle_count());
        let loose = simplify(
            &m,
            &QemParams {
                max_error: Some(0.1),
                ..p
            },
        )
        .unwrap();
        assert!(loose.mesh.triangle_count() < r.mesh.triangle_count());
    }
}

#[test]
fn non_manifold_parts_are_left_alone() {
    // Three sheets on one edge: the edge's vertices are never moved.
    let mut m = grid(6);
    let n = m.positions.len() as u32;
    m.positions.push(Vec3::new(0.5, 0.5, 1.0));
    m.positions.push(Vec3::new(0.5, 0.5, -1.0));
    // Grid vertex (3,3) and (4,3).
    let (a, b) = (3 * 7 + 3, 3 * 7 + 4);
    m.indices.push([a, b, n]);
    m.indices.push([b, a, n + 1]);
    for engine in ENGINES {
        let r = simplify(&m, &on(engine, 10, Placement::Optimal)).unwrap();
        assert!(r.report.non_manifold_vertices >= 2);
        for v in [a, b] {
            assert!(r.mesh.positions.contains(&m.positions[v as usize]));
        }
    }
}

#[test]
fn bad_parameters_are_refused() {
    let m = grid(3);
    let e = simplify(&m, &params(0, Placement::Optimal)).unwrap_err();
    assert!(e.to_string().contains("triangles"), "{e}");
    let e = simplify(
        &m,
        &QemParams {
            max_error: Some(-1.0),
            ..params(5, Placement::Optimal)
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("max_error"), "{e}");
    let empty = TriMesh::default();
    assert!(simplify(&empty, &params(5, Placement::Optimal)).is_err());
}

#[test]
fn colours_are_interpolated() {
    let mut m = grid(8);
    m.colors = Some(m.positions.iter().map(|p| [p.x, p.y, 0.5, 1.0]).collect());
    let r = simplify(&m, &params(20, Placement::Optimal)).unwrap();
    let c = r.mesh.colors.as_ref().unwrap();
    assert_eq!(c.len(), r.mesh.vertex_count());
    // The colour field is x, y: interpolation keeps it close to the position.
    for (p, c) in r.mesh.positions.iter().zip(c) {
        assert!(
            (p.x - c[0]).abs() < 0.2 && (p.y - c[1]).abs() < 0.2,
            "{p} {c:?}"
        );
    }
}

/// Two bumpy spheres, one inside the other a hair apart, simplified hard: with the
/// intersection check no pair of faces without a common vertex meets in the output (the
/// exact checker of `compare --check-folds` says so); without it the count is printed.
#[test]
fn the_intersection_check_keeps_nested_spheres_apart() {
    let outer = sphere(12);
    let mut m = outer.clone();
    let base = m.positions.len() as u32;
    m.positions
        .extend(outer.positions.iter().map(|p| *p * 0.97));
    m.indices
        .extend(outer.indices.iter().map(|t| t.map(|i| i + base)));
    assert!(crate::mesh::intersect::self_intersections(&m).is_empty());
    let mut unchecked = 0;
    for placement in PLACEMENTS {
        for (engine, target) in ENGINES
            .into_iter()
            .flat_map(|e| [200u64, 60, 24].map(|t| (e, t)))
        {
            let mut found = [0usize; 2];
            for (k, check) in [false, true].into_iter().enumerate() {
                let p = QemParams {
                    check_intersections: check,
                    ..on(engine, target, placement)
                };
                let r = simplify(&m, &p).unwrap();
                found[k] = crate::mesh::intersect::self_intersections(&r.mesh).len();
            }
            println!(
                "{engine} {placement} -> {target}: {} pairs unchecked, {} checked",
                found[0], found[1]
            );
            assert_eq!(found[1], 0, "{engine} {placement} {target}");
            unchecked += found[0];
        }
    }
    // The fixture is one where the check matters.
    assert!(unchecked > 0);
}

#[test]
fn saliency_weights_keep_the_twin_and_spare_the_salient_part() {
    // Weights that vary over the surface: the fast path still equals the twin; weights of
    // 1 everywhere are plain QEM; a heavy half keeps more of its vertices.
    for (m, target) in [(grid(9), 40), (sphere(8), 20)] {
        let cx = m.bounds().unwrap().center().x;
        let heavy = |p: Vec3| if p.x > cx { 1.0 } else { 0.05 };
        let w: Vec<f64> = m.positions.iter().map(|&p| heavy(p)).collect();
        let rules = [super::WeightRule::Cost, super::WeightRule::Quadric];
        for (placement, rule) in [Placement::Optimal, Placement::Endpoint]
            .into_iter()
            .flat_map(|p| rules.map(|r| (p, r)))
        {
            let p = QemParams {
                weights: Some(w.clone().into()),
                weight_rule: rule,
                ..params(target, placement)
            };
            let (fast, slow) = fast_and_slow(&m, &p, target);
            assert_eq!(fast.log, slow.log, "{placement} {rule}");
            let ones = QemParams {
                weights: Some(vec![1.0; m.vertex_count()].into()),
                weight_rule: rule,
                ..params(target, placement)
            };
            let plain = simplify(&m, &params(target, placement)).unwrap();
            let one = simplify(&m, &ones).unwrap();
            assert_eq!(plain.mesh.positions, one.mesh.positions);
            assert_eq!(plain.mesh.indices, one.mesh.indices);
            let weighted = simplify(&m, &p).unwrap();
            let kept = |r: &QemResult| {
                r.mesh
                    .positions
                    .iter()
                    .filter(|p| heavy(**p) == 1.0)
                    .count()
            };
            assert!(kept(&weighted) > kept(&plain), "{placement} {rule}");
        }
    }
    let bad = QemParams {
        weights: Some(vec![0.0; 3].into()),
        ..params(1, Placement::Optimal)
    };
    assert!(simplify(&sphere(4), &bad).is_err());
}

/// Two bumpy grids side by side, 0.02 apart across x = 1.
fn two_grids() -> TriMesh {
    let mut m = grid(6);
    let base = m.positions.len() as u32;
    let right = grid(6);
    m.positions.extend(
        right
            .positions
            .iter()
            .map(|p| *p + Vec3::new(1.02, 0.0, 0.0)),
    );
    m.indices
        .extend(right.indices.iter().map(|t| t.map(|i| i + base)));
    m
}

/// The connected parts of `m` (vertices joined by its triangles; unused vertices aside).
fn parts(m: &TriMesh) -> usize {
    let mut root: Vec<u32> = (0..m.vertex_count() as u32).collect();
    fn find(r: &mut [u32], mut v: u32) -> u32 {
        while r[v as usize] != v {
            r[v as usize] = r[r[v as usize] as usize];
            v = r[v as usize];
        }
        v
    }
    for t in &m.indices {
        for k in 1..3 {
            let (a, b) = (find(&mut root, t[0]), find(&mut root, t[k]));
            root[a.max(b) as usize] = a.min(b);
        }
    }
    let mut used: Vec<u32> = m
        .indices
        .iter()
        .flatten()
        .map(|&v| find(&mut root, v))
        .collect();
    used.sort_unstable();
    used.dedup();
    used.len()
}

#[test]
fn pair_contraction_joins_separate_parts() {
    let m = two_grids();
    assert_eq!(parts(&m), 2);
    for placement in PLACEMENTS {
        let off = simplify(&m, &params(30, placement)).unwrap();
        assert_eq!(parts(&off.mesh), 2, "{placement}");
        let p = QemParams {
            pair_distance: 0.05,
            ..params(30, placement)
        };
        let on = simplify(&m, &p).unwrap();
        assert_eq!(parts(&on.mesh), 1, "{placement}");
        assert!(on.mesh.triangle_count() <= 30, "{placement}");
        // The contraction keeps every triangle: a join is a vertex shared by both sides.
        let xs = |x: f32| {
            on.mesh.indices.iter().any(|t| {
                t.iter().all(|&v| {
                    let px = on.mesh.positions[v as usize].x;
                    if x < 1.0 {
                        px <= 1.011
                    } else {
                        px >= 1.009
                    }
                })
            })
        };
        assert!(xs(0.0) && xs(2.0), "{placement}");
    }
    // Pairs further apart than the distance are not candidates.
    let p = QemParams {
        pair_distance: 0.01,
        ..params(30, Placement::Optimal)
    };
    assert_eq!(parts(&simplify(&m, &p).unwrap().mesh), 2);
}

#[test]
fn pair_contraction_keeps_the_slow_twin() {
    let m = two_grids();
    for placement in PLACEMENTS {
        for (target, d, check_intersections) in
            [(40u64, 0.05, false), (20, 0.2, false), (30, 0.05, true)]
        {
            let p = QemParams {
                pair_distance: d,
                check_intersections,
                ..params(target, placement)
            };
            let (fast, slow) = fast_and_slow(&m, &p, target);
            assert!(!fast.pair_ends.is_empty());
            assert_eq!(fast.log, slow.log, "{placement} {target} {d}");
            let (a, b) = (fast.finish(), slow.finish());
            assert_eq!(a.mesh.positions, b.mesh.positions);
            assert_eq!(a.mesh.indices, b.mesh.indices);
        }
    }
}

#[test]
fn pair_distance_is_checked() {
    let m = two_grids();
    for d in [-0.1, f64::NAN, f64::INFINITY] {
        let p = QemParams {
            pair_distance: d,
            ..params(30, Placement::Optimal)
        };
        let e = simplify(&m, &p).unwrap_err();
        assert!(e.to_string().contains("pair_distance"), "{e}");
    }
    // Every vertex within reach of every other: more pairs than allowed, an error.
    let p = QemParams {
        pair_distance: 10.0,
        ..params(30, Placement::Optimal)
    };
    let e = simplify(&m, &p).unwrap_err();
    assert!(e.to_string().contains("candidate vertex pairs"), "{e}");
}

/// The pass engine reaches the same triangle count as the heap engine (both stop only at
/// the target or where no valid collapse is left), on closed, open and cube meshes, for
/// each placement, with and without the intersection check.
#[test]
fn both_engines_reach_the_target() {
    for (m, target) in [
        (grid(9), 40u64),
        (grid(12), 8),
        (sphere(8), 20),
        (sphere(16), 60),
        (cube(3), 12),
    ] {
        for placement in PLACEMENTS {
            for check in [false, true] {
                let r = ENGINES.map(|e| {
                    let p = QemParams {
                        check_intersections: check,
                        ..on(e, target, placement)
                    };
                    simplify(&m, &p).unwrap()
                });
                let what = format!("{placement} check {check} -> {target}");
                assert_eq!(
                    r[0].report.target_reached, r[1].report.target_reached,
                    "{what}: {:?}",
                    r[1].report
                );
                if r[1].report.target_reached {
                    // A collapse removes at most two triangles.
                    let t = r[1].mesh.triangle_count() as u64;
                    assert!(t <= target && t + 2 >= target, "{what}: {t}");
                } else {
                    assert!(r[1].mesh.triangle_count() <= r[0].mesh.triangle_count() + 4);
                }
            }
        }
    }
}

/// The pass engine with the intersection check, on random bumpy spheres nested a random
/// hair apart: no face of the output folds over against the input and no two faces
/// without a common vertex meet, whatever the placement and the target.
mod passes_proptest {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(12))]
        #[test]
        fn no_folds_and_no_self_intersections_with_the_check(
            n in 6usize..11,
            gap in 0.9f32..0.99,
            ratio in 0.05f64..0.6,
            placement in prop_oneof![
                Just(Placement::Optimal),
                Just(Placement::Endpoint),
                Just(Placement::TwoLocalMappings),
            ],
        ) {
            let outer = sphere(n);
            let mut m = outer.clone();
            let base = m.positions.len() as u32;
            m.positions.extend(outer.positions.iter().map(|p| *p * gap));
            m.indices.extend(outer.indices.iter().map(|t| t.map(|i| i + base)));
            prop_assume!(crate::mesh::intersect::self_intersections(&m).is_empty());
            let target = ((m.triangle_count() as f64 * ratio) as u64).max(8);
            let p = QemParams {
                check_intersections: true,
                ..on(Engine::Passes, target, placement)
            };
            let r = simplify(&m, &p).unwrap();
            let bvh = crate::mesh::Bvh::new(&m);
            prop_assert_eq!(crate::mesh::intersect::fold_overs(&m, &bvh, &r.mesh).len(), 0);
            prop_assert_eq!(crate::mesh::intersect::self_intersections(&r.mesh).len(), 0);
        }
    }
}
