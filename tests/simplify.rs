//! The clustering simplifiers on the shared meshes, the paper's comparison on its own model,
//! and property tests of the output's invariants.

use crate::common;

use proptest::prelude::*;
use terratile::mesh::{hausdorff, io, Adjacency, HausdorffParams, TriMesh};
use terratile::simplify::{simplify, Method, Representative, SimplifyParams};

const METHODS: [Method; 3] = [Method::Uniform, Method::Floating, Method::Octree];

fn load(name: &str) -> Option<TriMesh> {
    Some(io::read(&common::data_file(&format!("meshes/{name}"))?).unwrap())
}

/// The shared mesh `name` and its simplification by `method` at `ratio`.
fn load_simplified(name: &str, method: Method, ratio: f64) -> Option<(TriMesh, TriMesh)> {
    let m = load(name)?;
    let s = simplify(&m, &SimplifyParams::ratio(method, ratio)).unwrap();
    Some((m, s.mesh))
}

/// What every output must satisfy.
fn check_output(input: &TriMesh, out: &TriMesh, what: &str) {
    out.validate(what).unwrap();
    let mut clean = out.clone();
    let r = clean.clean();
    assert_eq!(
        (r.degenerate, r.duplicate, r.unreferenced),
        (0, 0, 0),
        "{what}: {r:?}"
    );
    assert!(out.triangle_count() <= input.triangle_count(), "{what}");
    assert_eq!(
        out.normals.is_some(),
        input.normals.is_some(),
        "{what}: normals"
    );
    assert_eq!(
        out.colors.is_some(),
        input.colors.is_some(),
        "{what}: colours"
    );
    assert_eq!(out.uvs.is_some(), input.uvs.is_some(), "{what}: uvs");
    // Output vertices lie near the input surface's box.
    let (bi, bo) = (input.bounds().unwrap(), out.bounds().unwrap());
    let slack = 0.05 * bi.diagonal() as f32;
    assert!(
        bo.min.cmpge(bi.min - slack).all() && bo.max.cmple(bi.max + slack).all(),
        "{what}: {bo:?} outside {bi:?}"
    );
}

#[test]
fn every_method_on_the_small_shared_meshes() {
    let p = HausdorffParams { samples: 50_000 };
    for name in [
        "triceratops.obj",
        "cow.obj",
        "fandisk.obj",
        "spot.obj",
        "pirate.obj",
        "colored_airplane.ply",
    ] {
        let Some(m) = load(name) else { return };
        for method in METHODS {
            let s = simplify(&m, &SimplifyParams::ratio(method, 0.1))
                .unwrap_or_else(|e| panic!("{name} {method}: {e}"));
            let what = format!("{name} {method}");
            check_output(&m, &s.mesh, &what);
            let target = (m.triangle_count() as f64 * 0.1).round();
            let got = s.mesh.triangle_count() as f64;
            assert!(
                (got - target).abs() <= 0.15 * target,
                "{what}: {got} for {target}"
            );
            let e = hausdorff(&m, &s.mesh, &p).unwrap();
            assert!(e.max_pct.is_finite() && e.max_pct < 20.0, "{what}: {e:?}");
            assert!(e.mean_pct < e.max_pct, "{what}: {e:?}");
        }
    }
}

#[test]
fn attributes_are_carried_over() {
    let Some((spot, s)) = load_simplified("spot.obj", Method::Octree, 0.2) else {
        return;
    };
    // Output UVs are averages of input ones: inside the input's range (spot's own UVs
    // stray slightly outside [0, 1], e.g. v = 1.00065).
    let uv = s.uvs.as_ref().unwrap();
    let input = spot.uvs.as_ref().unwrap();
    let (lo, hi) = input.iter().fold(
        (
            glam::Vec2::splat(f32::INFINITY),
            glam::Vec2::splat(f32::NEG_INFINITY),
        ),
        |(lo, hi), t| (lo.min(*t), hi.max(*t)),
    );
    assert!(
        lo.min_element() > -0.1 && hi.max_element() < 1.1,
        "{lo} {hi}"
    );
    assert!(uv
        .iter()
        .all(|t| t.cmpge(lo - 1e-6).all() && t.cmple(hi + 1e-6).all()));
    // Seams survive: some output positions carry two different uvs.
    let w = s.weld_map();
    assert!(
        w.iter().enumerate().any(|(i, &r)| r as usize != i),
        "seam vertices kept apart"
    );
    let Some((_, s)) = load_simplified("colored_airplane.ply", Method::Uniform, 0.2) else {
        return;
    };
    let c = s.colors.as_ref().unwrap();
    assert!(
        c.iter().any(|c| c[2] > c[0] + 0.1),
        "the blue ramp survives"
    );
    assert!(c.iter().all(|c| c.iter().all(|x| (0.0..=1.0).contains(x))));
    let Some((_, s)) = load_simplified("pirate.obj", Method::Floating, 0.3) else {
        return;
    };
    let n = s.normals.as_ref().unwrap();
    assert!(
        n.iter().all(|n| n.length() < 1.0001),
        "unit or zero normals"
    );
}

#[test]
fn bunny_at_ten_percent_keeps_its_shape() {
    let Some(m) = load("bunny.obj") else { return };
    for method in [Method::Uniform, Method::Octree] {
        let s = simplify(&m, &SimplifyParams::ratio(method, 0.1)).unwrap();
        check_output(&m, &s.mesh, &format!("bunny {method}"));
        let e = hausdorff(&m, &s.mesh, &HausdorffParams { samples: 200_000 }).unwrap();
        // Unreferenced vertices are not part of the surface: the diagonal is the surface's.
        assert!((e.diagonal - 0.2502).abs() < 5e-4, "{}", e.diagonal);
        assert!(e.max_pct < 2.0 && e.mean_pct < 0.2, "bunny {method}: {e:?}");
        // The base's holes stay open: border quadrics keep them.
        assert!(
            Adjacency::new(&s.mesh).boundary_edge_count() > 0,
            "bunny {method}"
        );
    }
}

/// The error of `method` on `m` at `triangles`, the count checked within 3 %.
fn error_at(m: &TriMesh, method: Method, triangles: u64) -> terratile::mesh::HausdorffReport {
    let s = simplify(m, &SimplifyParams::triangles(method, triangles)).unwrap();
    let n = s.mesh.triangle_count() as f64;
    assert!(
        (n - triangles as f64).abs() <= 0.03 * triangles as f64,
        "{method}: {n} for {triangles}"
    );
    hausdorff(m, &s.mesh, &HausdorffParams::default()).unwrap()
}

/// The paper's Table 1 redone (seed 000 §IV): triceratops, 5,660 → about 1,850 triangles,
/// the quadric representative for every method, symmetric error (SPEC §8). The adaptive
/// octree has the smallest max, E_avg (the paper's mean) and Metro mean, with max ≤ 1 % and
/// Metro mean ≤ 0.06 % of the diagonal; floating cells beat the uniform grid in both means,
/// as in the paper. Not asserted because it does not hold: floating cells' max (1.18 % with
/// stranded clusters split, 1.77 % without; a front claw thinner than half a cell) is above
/// the grid's (1.0 %), and E_avg ≤ 0.06 % (no method comes near, nor does meshoptimizer's
/// edge collapse at 1,850 triangles; docs/notes/mesh.md).
#[test]
fn paper_comparison_on_triceratops() {
    let Some(m) = load("triceratops.obj") else {
        return;
    };
    let u = error_at(&m, Method::Uniform, 1850);
    let f = error_at(&m, Method::Floating, 1850);
    let o = error_at(&m, Method::Octree, 1850);
    assert!(o.max_pct <= 1.0, "octree max {:.3} %", o.max_pct);
    assert!(
        o.sample_mean_pct <= 0.06,
        "octree mean {:.4} %",
        o.sample_mean_pct
    );
    for (name, x) in [("uniform", &u), ("floating", &f)] {
        assert!(o.max_pct < x.max_pct, "max: octree {o:?} {name} {x:?}");
        assert!(o.mean_pct < x.mean_pct, "E_avg: octree {o:?} {name} {x:?}");
        assert!(
            o.sample_mean_pct < x.sample_mean_pct,
            "mean: octree {o:?} {name} {x:?}"
        );
    }
    assert!(f.mean_pct < u.mean_pct && f.sample_mean_pct < u.sample_mean_pct);
    // All three are far below the paper's figures (max 2.78–3.10 %, mean 0.89–1.35 %).
    for (name, e) in [("uniform", u), ("floating", f), ("octree", o)] {
        assert!(e.max_pct < 2.78 && e.mean_pct < 0.89, "{name}: {e:?}");
    }
}

/// Floating cells cut triceratops' claws into chains of slabs where no three clusters meet;
/// without the stranded-cluster split the claw tips vanish (max 1.77 %, docs/notes/octree.md).
/// With it no cluster is left without a triangle and the max falls, the means do not rise.
#[test]
fn splitting_stranded_clusters_keeps_the_claws() {
    let Some(m) = load("triceratops.obj") else {
        return;
    };
    for ratio in [0.33, 0.10] {
        let t = (m.triangle_count() as f64 * ratio).round() as u64;
        let mut p = SimplifyParams::triangles(Method::Floating, t);
        let split = simplify(&m, &p).unwrap();
        p.split_stranded = Some(false);
        let plain = simplify(&m, &p).unwrap();
        assert!(split.report.stranded_split > 0, "{:?}", split.report);
        assert_eq!(split.report.clusters, split.mesh.vertex_count());
        assert!(plain.report.clusters > plain.mesh.vertex_count());
        let h = HausdorffParams::default();
        let (es, ep) = (
            hausdorff(&m, &split.mesh, &h).unwrap(),
            hausdorff(&m, &plain.mesh, &h).unwrap(),
        );
        assert!(
            es.max_pct < 0.7 * ep.max_pct,
            "{ratio}: split {es:?} plain {ep:?}"
        );
        assert!(
            es.sample_mean_pct <= ep.sample_mean_pct,
            "{ratio}: split {es:?} plain {ep:?}"
        );
    }
}

/// The octree's lead is not a triceratops accident: on the cow (organic, thin legs) and
/// fandisk (CAD: flat faces, sharp creases) at 33 % and 10 % it also has the smallest E_avg
/// and Metro mean of the three methods, and a smaller max than the uniform grid. Its max is
/// also below floating cells' except on the cow at 10 % (580 triangles), where floating
/// cells, whose stranded clusters are split, keep the thin parts better: 2.33 % against the
/// octree's 3.67 % (bunny and the table: docs/notes/mesh.md).
#[test]
fn octree_leads_on_other_meshes() {
    for name in ["cow.obj", "fandisk.obj"] {
        let Some(m) = load(name) else { return };
        for ratio in [0.33, 0.10] {
            let t = (m.triangle_count() as f64 * ratio).round() as u64;
            let o = error_at(&m, Method::Octree, t);
            for method in [Method::Uniform, Method::Floating] {
                let x = error_at(&m, method, t);
                let what = format!("{name} {ratio}: octree {o:?}, {method} {x:?}");
                let cow_floating_10 =
                    name == "cow.obj" && ratio == 0.10 && method == Method::Floating;
                if !cow_floating_10 {
                    assert!(o.max_pct < x.max_pct, "max, {what}");
                }
                assert!(o.mean_pct < x.mean_pct, "E_avg, {what}");
                assert!(o.sample_mean_pct < x.sample_mean_pct, "mean, {what}");
            }
        }
    }
}

#[test]
fn quadric_representative_beats_the_centroid() {
    // The measurement behind the default, on one mesh the tests can afford.
    let Some(m) = load("cow.obj") else { return };
    let p = HausdorffParams { samples: 100_000 };
    let err = |rep| {
        let mut params = SimplifyParams::ratio(Method::Uniform, 0.25);
        params.representative = Some(rep);
        let s = simplify(&m, &params).unwrap();
        hausdorff(&m, &s.mesh, &p).unwrap()
    };
    let (c, q) = (err(Representative::Centroid), err(Representative::Quadric));
    assert!(q.mean < c.mean, "quadric {} centroid {}", q.mean, c.mean);
}

/// A random bumpy grid, possibly with a hole and a duplicated seam.
fn arb_mesh() -> impl Strategy<Value = TriMesh> {
    (
        4usize..14,
        4usize..14,
        prop::collection::vec(-0.3f32..0.3, 200),
        any::<bool>(),
    )
        .prop_map(|(nx, ny, bumps, hole)| {
            let mut m = TriMesh::default();
            for j in 0..=ny {
                for i in 0..=nx {
                    let z = bumps[(i * 7 + j * 13) % bumps.len()];
                    m.positions.push(glam::Vec3::new(i as f32, j as f32, z));
                }
            }
            let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
            for j in 0..ny {
                for i in 0..nx {
                    if hole && i == nx / 2 && j == ny / 2 {
                        continue;
                    }
                    m.indices.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                    m.indices.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
                }
            }
            m.uvs = Some(
                m.positions
                    .iter()
                    .map(|p| glam::Vec2::new(p.x / nx as f32, p.y / ny as f32))
                    .collect(),
            );
            m
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn outputs_are_valid_for_any_mesh(m in arb_mesh(), ratio in 0.05f64..1.0, method in 0usize..3) {
        let method = METHODS[method];
        match simplify(&m, &SimplifyParams::ratio(method, ratio)) {
            Ok(s) => check_output(&m, &s.mesh, &format!("{method} {ratio}")),
            // A tiny target may collapse everything: that is a clear error, not a panic.
            Err(e) => prop_assert!(e.to_string().contains("no triangle is left"), "{e}"),
        }
    }

    #[test]
    fn hausdorff_directions_swap(a in arb_mesh(), b in arb_mesh()) {
        let p = HausdorffParams { samples: 2_000 };
        let ab = hausdorff(&a, &b, &p).unwrap();
        let ba = hausdorff(&b, &a, &p).unwrap();
        prop_assert_eq!(ab.forward.max, ba.backward.max);
        prop_assert_eq!(ab.forward.mean, ba.backward.mean);
        prop_assert!(ab.max >= ab.mean);
    }
}

/// The table of docs/notes/mesh.md: four meshes, 33 % and 10 %, every method and representative.
/// Run: `cargo test --release --test tests -- --ignored --nocapture clustering_table`.
#[test]
#[ignore]
fn clustering_table() {
    let reps: Vec<Representative> = match std::env::var("REPS").as_deref() {
        Ok("all") => vec![
            Representative::Quadric,
            Representative::Centroid,
            Representative::Important,
        ],
        _ => vec![Representative::Quadric],
    };
    println!(
        "| mesh | ratio | rep | method | triangles | ms | max % | mean (E_avg) % | Metro mean % |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for name in ["triceratops.obj", "bunny.obj", "cow.obj", "fandisk.obj"] {
        let Some(m) = load(name) else { return };
        for ratio in [0.33, 0.10] {
            for &rep in &reps {
                for method in METHODS {
                    let mut p = SimplifyParams::ratio(method, ratio);
                    if name == "triceratops.obj" && ratio == 0.33 {
                        p = SimplifyParams::triangles(method, 1850);
                    }
                    p.representative = Some(rep);
                    let t = std::time::Instant::now();
                    let s = simplify(&m, &p).unwrap();
                    let ms = t.elapsed().as_secs_f64() * 1e3;
                    let e = hausdorff(&m, &s.mesh, &HausdorffParams::default()).unwrap();
                    println!(
                        "| {name} | {ratio} | {rep} | {method} | {} | {ms:.1} | {:.3} | {:.4} | {:.4} |",
                        s.mesh.triangle_count(),
                        e.max_pct,
                        e.mean_pct,
                        e.sample_mean_pct
                    );
                }
            }
            // References: meshoptimizer's edge collapse (QEM) and its own grid clustering
            // at the same target, measured the same way.
            let target = if name == "triceratops.obj" && ratio == 0.33 {
                1850
            } else {
                (m.triangle_count() as f64 * ratio).round() as usize
            };
            for (what, s) in meshopt_references(&m, target) {
                let e = hausdorff(&m, &s, &HausdorffParams::default()).unwrap();
                println!(
                    "| {name} | {ratio} | — | {what} | {} | — | {:.3} | {:.4} | {:.4} |",
                    s.triangle_count(),
                    e.max_pct,
                    e.mean_pct,
                    e.sample_mean_pct
                );
            }
        }
    }
}

/// meshoptimizer's `simplify` (edge collapse) and `simplify_sloppy` (grid clustering) at
/// `target` triangles, as meshes over `m`'s vertices.
fn meshopt_references(m: &TriMesh, target: usize) -> Vec<(&'static str, TriMesh)> {
    let bytes = meshopt::typed_to_bytes(&m.positions);
    let indices: Vec<u32> = m.indices.iter().flatten().copied().collect();
    let adapter = meshopt::VertexDataAdapter::new(bytes, 12, 0).unwrap();
    let collapse = meshopt::simplify(
        &indices,
        &adapter,
        target * 3,
        1.0,
        meshopt::SimplifyOptions::None,
        None,
    );
    let sloppy = meshopt::simplify_sloppy(&indices, &adapter, target * 3, 1.0, None);
    [
        ("meshopt edge collapse", collapse),
        ("meshopt sloppy", sloppy),
    ]
    .into_iter()
    .map(|(what, idx)| {
        let mut s = TriMesh {
            positions: m.positions.clone(),
            indices: idx.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
            ..TriMesh::default()
        };
        s.remove_unreferenced();
        (what, s)
    })
    .collect()
}

/// meshoptimizer's `simplifyWithUpdate` (edge collapse that moves the kept vertices, its
/// counterpart of an optimal placement) at `target` triangles. Through the raw binding: the
/// safe wrapper of meshopt 0.6 does not expose it.
fn meshopt_with_update(m: &TriMesh, target: usize) -> TriMesh {
    let mut positions: Vec<f32> = m.positions.iter().flat_map(|p| p.to_array()).collect();
    let mut indices: Vec<u32> = m.indices.iter().flatten().copied().collect();
    let mut err = 0f32;
    // SAFETY: the pointers are to live vectors of the stated lengths and strides; no
    // attributes, no locks.
    let n = unsafe {
        meshopt::ffi::meshopt_simplifyWithUpdate(
            indices.as_mut_ptr(),
            indices.len(),
            positions.as_mut_ptr(),
            m.vertex_count(),
            12,
            std::ptr::null_mut(),
            0,
            std::ptr::null(),
            0,
            std::ptr::null(),
            target * 3,
            1.0,
            0,
            &mut err,
        )
    };
    indices.truncate(n);
    let mut s = TriMesh {
        positions: positions
            .chunks_exact(3)
            .map(|p| glam::Vec3::new(p[0], p[1], p[2]))
            .collect(),
        indices: indices
            .chunks_exact(3)
            .map(|t| [t[0], t[1], t[2]])
            .collect(),
        ..TriMesh::default()
    };
    s.remove_unreferenced();
    s
}

/// The quadric edge collapse against meshoptimizer on six meshes at four ratios: symmetric
/// max and Metro mean (area-sampled mean distance, both directions) in % of the bbox
/// diagonal, and the issue's criteria counted against meshoptimizer's best.
/// Run: `cargo test --release --test tests -- --ignored --nocapture qem_table`.
#[test]
#[ignore]
fn qem_table() {
    use terratile::mesh::intersect::{fold_overs, self_intersections};
    use terratile::simplify::Placement;
    println!("| mesh | ratio | method | triangles | ms | max % | Metro mean % | fold-overs | self-int. faces (pairs) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let (mut mean_wins, mut max_ok, mut cases) = (0, 0, 0);
    let mut clean = 0;
    let (mut dist_mean_wins, mut dist_max_ok) = (0, 0);
    let (mut pass_mean_wins, mut pass_max_ok) = (0, 0);
    let (mut tlm_sum, mut opt_sum) = (0.0, 0.0);
    for name in [
        "bunny.obj",
        "armadillo.obj",
        "triceratops.obj",
        "cow.obj",
        "fandisk.obj",
        "dragon_10k.obj",
    ] {
        let Some(m) = load(name) else { return };
        let bvh = terratile::mesh::Bvh::new(&m);
        let own = self_intersections(&m);
        println!(
            "| {name} | input | | {} | | | | | {} ({}) |",
            m.triangle_count(),
            terratile::mesh::intersect::faces_of(&own).len(),
            own.len()
        );
        for ratio in [0.5, 0.1, 0.02, 0.005] {
            let target = ((m.triangle_count() as f64 * ratio).round() as usize).max(1);
            let row = |what: &str, s: &TriMesh, ms: f64| {
                let e = hausdorff(&m, s, &HausdorffParams::default()).unwrap();
                let folds = fold_overs(&m, &bvh, s).len();
                let pairs = self_intersections(s);
                println!(
                    "| {name} | {ratio} | {what} | {} | {ms:.1} | {:.3} | {:.4} | {folds} | {} ({}) |",
                    s.triangle_count(),
                    e.max_pct,
                    e.sample_mean_pct,
                    terratile::mesh::intersect::faces_of(&pairs).len(),
                    pairs.len()
                );
                (e.max_pct, e.sample_mean_pct, folds, pairs.len())
            };
            let mut ours = Vec::new();
            let mut all_clean = true;
            for check in [false, true] {
                for placement in [
                    Placement::Optimal,
                    Placement::Endpoint,
                    Placement::TwoLocalMappings,
                ] {
                    let mut p = SimplifyParams::triangles(Method::Qem, target as u64);
                    p.placement = Some(placement);
                    p.check_intersections = check.then_some(true);
                    let t = std::time::Instant::now();
                    let s = simplify(&m, &p).unwrap();
                    let ms = t.elapsed().as_secs_f64() * 1e3;
                    let what = format!("qem {placement}{}", if check { " +check" } else { "" });
                    let r = row(&what, &s.mesh, ms);
                    if check {
                        // Pairs may only be the input's own (faces never moved).
                        all_clean &= r.2 == 0 && r.3 <= own.len();
                    }
                    ours.push(r);
                }
            }
            clean += all_clean as usize;
            // The pass engine (meshoptimizer's order), optimal placement, beside the
            // default heap engine.
            let mut p = SimplifyParams::triangles(Method::Qem, target as u64);
            p.engine = Some(terratile::simplify::qem::Engine::Passes);
            let t = std::time::Instant::now();
            let s = simplify(&m, &p).unwrap();
            let ms = t.elapsed().as_secs_f64() * 1e3;
            let passes = row("qem optimal, pass engine", &s.mesh, ms);
            // The distance-ordered cost (engine API only), optimal placement.
            let q = terratile::simplify::qem::QemParams {
                cost: terratile::simplify::qem::Cost::Distance,
                ..terratile::simplify::qem::QemParams::plain(target as u64, Placement::Optimal)
            };
            let t = std::time::Instant::now();
            let s = terratile::simplify::qem::simplify(&m, &q).unwrap();
            let ms = t.elapsed().as_secs_f64() * 1e3;
            let dist = row("qem optimal, distance cost", &s.mesh, ms);
            let bytes = meshopt::typed_to_bytes(&m.positions);
            let indices: Vec<u32> = m.indices.iter().flatten().copied().collect();
            let adapter = meshopt::VertexDataAdapter::new(bytes, 12, 0).unwrap();
            let mut best = (f64::INFINITY, f64::INFINITY);
            for (what, opt) in [
                ("meshopt simplify", meshopt::SimplifyOptions::None),
                ("meshopt LockBorder", meshopt::SimplifyOptions::LockBorder),
            ] {
                let t = std::time::Instant::now();
                let idx = meshopt::simplify(&indices, &adapter, target * 3, 1.0, opt, None);
                let ms = t.elapsed().as_secs_f64() * 1e3;
                let mut s = TriMesh {
                    positions: m.positions.clone(),
                    indices: idx.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
                    ..TriMesh::default()
                };
                s.remove_unreferenced();
                let (mx, mn, _, _) = row(what, &s, ms);
                best = (best.0.min(mx), best.1.min(mn));
            }
            let t = std::time::Instant::now();
            let s = meshopt_with_update(&m, target);
            let ms = t.elapsed().as_secs_f64() * 1e3;
            let (mx, mn, _, _) = row("meshopt withUpdate", &s, ms);
            best = (best.0.min(mx), best.1.min(mn));
            cases += 1;
            // ours: optimal, endpoint, two local mappings; then the same with the check.
            tlm_sum += ours[2].1;
            opt_sum += ours[0].1;
            pass_mean_wins += (passes.1 <= best.1) as usize;
            pass_max_ok += (passes.0 <= 1.2 * best.0) as usize;
            mean_wins += (ours[0].1 <= best.1) as usize;
            max_ok += (ours[0].0 <= 1.2 * best.0) as usize;
            dist_mean_wins += (dist.1 <= best.1) as usize;
            dist_max_ok += (dist.0 <= 1.2 * best.0) as usize;
        }
    }
    println!(
        "\noptimal: Metro mean <= meshopt's best on {mean_wins}/{cases}; max <= 1.2 x meshopt's best on {max_ok}/{cases}"
    );
    println!(
        "optimal, pass engine: Metro mean <= meshopt's best on {pass_mean_wins}/{cases}; max <= 1.2 x on {pass_max_ok}/{cases}"
    );
    println!(
        "with the intersection check, both placements: 0 fold-overs and no self-intersecting pair beyond the input's own count on {clean}/{cases}"
    );
    println!(
        "two local mappings: mean over the cases of the Metro mean / optimal's: {:.3}",
        tlm_sum / opt_sum
    );
    println!(
        "optimal, distance cost: Metro mean <= meshopt's best on {dist_mean_wins}/{cases}; max <= 1.2 x on {dist_max_ok}/{cases}"
    );
}

/// A closed tetrahedron: no collapse of it is valid (each would leave two copies of one
/// triangle).
const TETRA: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n";

/// A bumpy open grid as OBJ, with `extra` appended.
pub(crate) fn grid_obj(n: usize, extra: &str) -> String {
    let mut s = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
            s += &format!("v {x} {y} {}\n", 0.1 * (6.0 * x).sin() * (4.0 * y).cos());
        }
    }
    let id = |i: usize, j: usize| j * (n + 1) + i + 1;
    for j in 0..n {
        for i in 0..n {
            s += &format!("f {} {} {}\n", id(i, j), id(i + 1, j), id(i + 1, j + 1));
            s += &format!("f {} {} {}\n", id(i, j), id(i + 1, j + 1), id(i, j + 1));
        }
    }
    s + extra
}

#[test]
fn qem_refuses_bad_parameters() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("m.obj"), grid_obj(4, "")).unwrap();
    for (args, needle) in [
        (&["--ratio", "0.5", "--max-error", "-1"][..], "max_error"),
        (&["--max-error", "-0.5%"][..], "max_error_pct"),
        (&["--max-error", "abc"][..], "--max-error"),
        (&["--ratio", "1.5"][..], "ratio"),
        (&["--triangles", "0"][..], "triangles"),
        (&["--ratio", "0.5", "--triangles", "3"][..], "ratio"),
        (&["--cell-size", "0.1"][..], "cell_size"),
    ] {
        let mut a = vec!["simplify", "m.obj", "out.obj", "--method", "qem"];
        a.extend_from_slice(args);
        let r = common::terratile(d.path(), &a);
        r.input_error(&[needle]);
        r.left_nothing("out.obj");
    }
    // An unknown placement is a usage error (clap's own message).
    let r = common::simplify(
        d.path(),
        "m.obj",
        "out.obj",
        &[
            "--method",
            "qem",
            "--ratio",
            "0.5",
            "--placement",
            "nearest",
        ],
    );
    assert_eq!(r.code, 2, "{}", r.context());
    assert!(r.stderr.contains("nearest"), "{}", r.context());
    r.left_nothing("out.obj");
    // QEM keys with a clustering method.
    let r = common::simplify(
        d.path(),
        "m.obj",
        "out.obj",
        &["--ratio", "0.5", "--lock-border"],
    );
    r.input_error(&["lock_border"]);
}

/// `--engine passes` and `--engine heap` both reach the target from the CLI, with the
/// intersection check on; an unknown engine is a usage error.
#[test]
fn qem_engines_from_the_cli() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("m.obj"), grid_obj(12, "")).unwrap();
    for engine in ["passes", "heap"] {
        let out = format!("{engine}.obj");
        let r = common::simplify(
            d.path(),
            "m.obj",
            &out,
            &[
                "--method",
                "qem",
                "--triangles",
                "40",
                "--check-intersections",
                "--engine",
                engine,
                "--no-error",
            ],
        );
        r.ok();
        let m = io::read(&d.path().join(&out)).unwrap();
        assert!(
            (38..=40).contains(&m.triangle_count()),
            "{engine}: {}",
            m.triangle_count()
        );
    }
    let r = common::simplify(
        d.path(),
        "m.obj",
        "x.obj",
        &["--method", "qem", "--ratio", "0.5", "--engine", "queue"],
    );
    assert_eq!(r.code, 2, "{}", r.context());
    r.left_nothing("x.obj");
}

#[test]
fn qem_stops_with_a_warning_where_no_collapse_is_valid() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("t.obj"), TETRA).unwrap();
    let r = common::simplify(
        d.path(),
        "t.obj",
        "out.obj",
        &["--method", "qem", "--triangles", "1", "--no-error"],
    );
    r.ok();
    assert!(
        r.stderr.contains("warning") && r.stderr.contains("target 1"),
        "{}",
        r.context()
    );
    let out = io::read(&d.path().join("out.obj")).unwrap();
    assert_eq!(out.triangle_count(), 4);
}

#[test]
fn qem_leaves_non_manifold_parts_alone_and_counts_them() {
    // Two extra triangles on one inner edge of the grid: three triangles on that edge.
    let d = tempfile::tempdir().unwrap();
    let extra = "v 0.5 0.5 1\nv 0.5 0.5 -1\nf 13 14 26\nf 14 13 27\n";
    std::fs::write(d.path().join("m.obj"), grid_obj(4, extra)).unwrap();
    let r = common::simplify(
        d.path(),
        "m.obj",
        "out.obj",
        &["--method", "qem", "--ratio", "0.3", "--json", "--no-error"],
    );
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    assert!(
        v["qem"]["non_manifold_vertices"].as_u64().unwrap() >= 2,
        "{}",
        r.stdout
    );
    let out = io::read(&d.path().join("out.obj")).unwrap();
    let input = io::read(&d.path().join("m.obj")).unwrap();
    for v in [12, 13] {
        assert!(out.positions.contains(&input.positions[v]));
    }
}

#[test]
fn qem_lock_border_keeps_bunny_holes_exactly() {
    let Some(m) = load("bunny.obj") else { return };
    let adj = Adjacency::new(&m);
    let border_in: Vec<u32> = adj
        .edge_faces
        .boundary_edges()
        .flat_map(|e| adj.edge_faces.edge(e))
        .collect();
    let mut p = SimplifyParams::ratio(Method::Qem, 0.1);
    p.lock_border = Some(true);
    let s = simplify(&m, &p).unwrap();
    check_output(&m, &s.mesh, "qem lock_border");
    for v in border_in {
        assert!(s.mesh.positions.contains(&m.positions[v as usize]), "{v}");
    }
}

#[test]
fn qem_runs_as_an_asset_and_its_keys_are_checked() {
    let dir = common::default_job();
    let d = dir.path();
    std::fs::write(d.join("m.obj"), grid_obj(12, "")).unwrap();
    let base = std::fs::read_to_string(d.join("pipeline.toml")).unwrap();
    let entry = |simplify: &str| {
        format!(
            "{base}\n[[assets]]\ninput = \"m.obj\"\noutput = \"assets/m.obj\"\n\
             simplify = {simplify}\nplace = {{ x = 513050.0, y = 5403100.0 }}\n"
        )
    };
    for (bad, needle) in [
        (
            r#"{ method = "qem", ratio = 0.2, placement = "nearest" }"#,
            "nearest",
        ),
        (
            r#"{ method = "qem", ratio = 0.2, max_error = -1.0 }"#,
            "max_error",
        ),
        (
            r#"{ method = "octree", ratio = 0.2, lock_border = true }"#,
            "lock_border",
        ),
    ] {
        std::fs::write(d.join("pipeline.toml"), entry(bad)).unwrap();
        let r = common::terratile(d, &["run"]);
        r.input_error(&["assets[0]", needle]);
    }
    std::fs::write(
        d.join("pipeline.toml"),
        entry(r#"{ method = "qem", ratio = 0.2, lock_border = true }"#),
    )
    .unwrap();
    let r = common::terratile(d, &["run", "--json"]);
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    assert_eq!(v["assets"][0]["method"], "qem", "{}", r.stdout);
    let out = io::read(&d.join("out/assets/m.obj")).unwrap();
    assert!(
        out.triangle_count() <= 58 && out.triangle_count() > 0,
        "{}",
        out.triangle_count()
    );
}

/// Issue 12's evaluation: saliency-weighted QEM against plain QEM at the same triangle
/// count: the Metro mean error (original → simplified, % of the diagonal) over the whole
/// surface and over the 20 % most salient area of the original. That area has one fixed
/// definition for every row: the triangles with the highest mean *raw* hybrid saliency of
/// their corners (An's classes A–E as `hybrid::hybrid` gives them, before any of the
/// weighting's smoothing), most salient first, until a fifth of the area. Rows: plain QEM,
/// then the weights (`saliency::Weighting::weights` of the map) in the
/// quadrics from the hybrid, the mesh and the mean image saliency, and the hybrid through
/// the thesis' rule (the cost times the mean weight). Spot's texture is baked into vertex
/// colours first, and spot is simplified with `collapse_seams` in every row (its UV seams
/// would otherwise lock the vertices along them and stop QEM near 580 triangles).
/// Long (the multi-view saliency of five meshes): `cargo test --release --test tests
/// simplify::saliency_table -- --ignored --nocapture`. SALIENCY_H_MIN, SALIENCY_SMOOTH (σ
/// in ε), SALIENCY_SPREAD (0 or 1), SALIENCY_POWER, SALIENCY_AREA (0 or 1), SALIENCY_PLATEAU,
/// SALIENCY_RULE (quadric or cost: the first three columns), SALIENCY_TOP and SALIENCY_GAP
/// (a step in the weight at the top share of the area) try other weightings;
/// SALIENCY_MESHES=cow,spot picks meshes and SALIENCY_KINDS=hybrid the columns;
/// SALIENCY_AREA_NORM (γ, [`area_normalised`]) tries weights divided by vertex area^γ and
/// SALIENCY_CACHE=DIR keeps the maps between trials ([`cached_maps`]); SALIENCY_PHASES
/// sets the two phases' share (0: one weighted run), SALIENCY_CARRY=max their weight
/// carried from phase 1 to phase 2 ([`phases::Carry`]) and SALIENCY_MERGE=mean merges the
/// weighted rows' quadrics by An's eq. 4.3; SALIENCY_CURVATURE (class A's curvature
/// averaged over σ in ε first), SALIENCY_SHARES (four class bounds) and SALIENCY_RANGES
/// (ten numbers, the classes' output ranges) make the hybrid with other classes, which
/// moves the measured salient fifth with it unless SALIENCY_MEASURE=default (the fifth of
/// the default hybrid, the weights of the other one). The last column is each simplification's seconds (weights known), for the speed
/// ratio of weighted to plain QEM.
#[test]
#[ignore]
fn saliency_table() {
    use terratile::simplify::qem::{self, WeightRule};
    use terratile::simplify::saliency::{hybrid, phases, texture, Weighting};
    let env = |k: &str| std::env::var(k).ok().and_then(|s| s.parse::<f64>().ok());
    let d = Weighting::default();
    let w = Weighting {
        h_min: env("SALIENCY_H_MIN").unwrap_or(d.h_min),
        smooth: env("SALIENCY_SMOOTH").unwrap_or(d.smooth),
        spread: env("SALIENCY_SPREAD").map_or(d.spread, |x| x != 0.0),
        power: env("SALIENCY_POWER").unwrap_or(d.power),
        area_rank: env("SALIENCY_AREA").map_or(d.area_rank, |x| x != 0.0),
        plateau: env("SALIENCY_PLATEAU").unwrap_or(d.plateau),
        top: env("SALIENCY_TOP").unwrap_or(d.top),
        gap: env("SALIENCY_GAP").unwrap_or(d.gap),
        phases: env("SALIENCY_PHASES").unwrap_or(d.phases),
    };
    // SALIENCY_KINDS=hybrid: only plain and hybrid rows (quicker trials).
    let kinds = std::env::var("SALIENCY_KINDS").ok();
    let run_kind = |k: &str| {
        k == "none"
            || kinds
                .as_deref()
                .is_none_or(|o| o.split(',').any(|x| x == k))
    };
    let rule = match std::env::var("SALIENCY_RULE").as_deref() {
        Ok("cost") => WeightRule::Cost,
        _ => WeightRule::Quadric,
    };
    // SALIENCY_AREA_NORM=γ: each weight also times (mean vertex area / the vertex's
    // area)^γ, so that a finely tessellated salient feature (whose quadrics, area-weighted,
    // are small) is not collapsed first for its small triangles.
    let area_norm = env("SALIENCY_AREA_NORM").unwrap_or(0.0);
    // SALIENCY_MERGE=mean: the weighted rows merge quadrics by the mean of An's eq. 4.3
    // (plain QEM keeps the sum: the baseline does not move).
    let merge = match std::env::var("SALIENCY_MERGE").as_deref() {
        Ok("mean") => terratile::simplify::QuadricMerge::Mean,
        _ => terratile::simplify::QuadricMerge::Sum,
    };
    // SALIENCY_CARRY=max: phase 2's weight of a vertex is the largest of those merged into
    // it in phase 1 (default: the mean).
    let carry = match std::env::var("SALIENCY_CARRY").as_deref() {
        Ok("max") => phases::Carry::Max,
        _ => phases::Carry::default(),
    };
    // SALIENCY_CURVATURE (σ in ε of class A's curvature), SALIENCY_SHARES=a,b,c,d and
    // SALIENCY_RANGES=lo,hi,... (ten numbers): other hybrid classes, for the measure's
    // salient fifth too unless SALIENCY_MEASURE=default.
    let classes_smooth = env("SALIENCY_CURVATURE").unwrap_or(hybrid::CURVATURE_SMOOTH);
    let list = |k: &str| {
        std::env::var(k).ok().map(|s| {
            s.split(',')
                .map(|x| x.trim().parse::<f64>().unwrap())
                .collect::<Vec<_>>()
        })
    };
    let mut classes = hybrid::Classes::default();
    if let Some(v) = list("SALIENCY_SHARES") {
        classes.shares = (v[0], v[1], v[2], v[3]);
    }
    if let Some(v) = list("SALIENCY_RANGES") {
        for (k, r) in classes.ranges.iter_mut().enumerate() {
            *r = (v[2 * k], v[2 * k + 1]);
        }
    }
    let only = std::env::var("SALIENCY_MESHES").ok();
    let wanted = |n: &str| {
        only.as_deref()
            .is_none_or(|o| o.split(',').any(|k| n.starts_with(k)))
    };
    let mut cases: Vec<(String, TriMesh, Vec<u64>)> = Vec::new();
    let p5k = qem::QemParams::plain(5000, terratile::simplify::Placement::Optimal);
    if wanted("armadillo") {
        let Some(arm) = load("armadillo.obj") else {
            return;
        };
        // The thesis' armadillo of 5,000 triangles: plain QEM from the full model.
        let arm5k = qem::simplify(&arm, &p5k).unwrap().mesh;
        cases.push(("armadillo 5k".into(), arm5k, vec![1000, 500]));
    }
    for name in ["bunny.obj", "cow.obj", "spot.obj"] {
        if !wanted(name) {
            continue;
        }
        let Some(mut m) = load(name) else { return };
        if name == "spot.obj" {
            let t = texture::Texture::read(&common::data_file("meshes/spot_texture.png").unwrap())
                .unwrap();
            texture::bake(&mut m, &t).unwrap();
        }
        let t = m.triangle_count() as u64;
        cases.push((name.into(), m, vec![t / 10, t / 50]));
    }
    println!(
        "{w:?} {rule} area_norm {area_norm} merge {merge} carry {carry:?} \
         class curvature σ {classes_smooth} ε {classes:?}"
    );
    println!("| mesh | triangles | weights | whole (%) | salient 20 % (%) | salient vs plain | whole vs plain | QEM s |");
    println!("|---|---|---|---|---|---|---|---|");
    for (name, m, targets) in cases {
        let t = std::time::Instant::now();
        let maps = cached_maps(&name, &m);
        let [_, mesh_saliency, _, _, image_mean] = maps.clone();
        let hybrid = hybrid_of(&m, &maps, classes_smooth, &classes);
        eprintln!("{name}: maps in {:.2} s", t.elapsed().as_secs_f64());
        // SALIENCY_MEASURE=default: the salient fifth of the default hybrid whatever the
        // classes the weights are made from.
        let salient = if std::env::var("SALIENCY_MEASURE").as_deref() == Ok("default") {
            let d = hybrid_of(&m, &maps, hybrid::CURVATURE_SMOOTH, &Default::default());
            salient_fifth(&m, &d)
        } else {
            salient_fifth(&m, &hybrid)
        };
        let diag = m.diagonal();
        let hp = HausdorffParams { samples: 0 };
        // Each map's weights and the weighting's salient vertices (for the two phases).
        let weights = |v: &[f64]| {
            w.weights(&m, v)
                .map(|h| (area_normalised(&m, h, area_norm), w.salient(&m, v)))
        };
        let (wh, wm, wi) = (
            weights(&hybrid),
            weights(&mesh_saliency),
            weights(&image_mean),
        );
        for &target in &targets {
            let mut plain = [0.0; 2];
            for (kind, ws, rule) in [
                ("none", None, WeightRule::Quadric),
                ("hybrid", wh.as_ref(), rule),
                ("mesh", wm.as_ref(), rule),
                ("image", wi.as_ref(), rule),
                ("hybrid, thesis rule", wh.as_ref(), WeightRule::Cost),
            ] {
                if !run_kind(kind) {
                    continue;
                }
                let p = qem::QemParams {
                    triangles: target,
                    weights: ws.map(|x| x.0.clone().into()),
                    weight_rule: rule,
                    collapse_seams: name == "spot.obj",
                    merge: if ws.is_some() { merge } else { p5k.merge },
                    ..p5k.clone()
                };
                let t = std::time::Instant::now();
                // As `Weighting::simplify`: two phases for weights in the quadrics.
                let s = match ws {
                    Some((h, sal)) if w.phases > 0.0 && rule == WeightRule::Quadric => {
                        phases::simplify_carrying(&m, &p, h, sal, w.phases, carry)
                            .unwrap()
                            .mesh
                    }
                    _ => qem::simplify(&m, &p).unwrap().mesh,
                };
                let secs = t.elapsed().as_secs_f64();
                let bvh = terratile::mesh::Bvh::new(&s);
                let e =
                    [&m, &salient].map(|part| hausdorff::one_sided(part, &bvh, &hp, diag).mean_pct);
                if kind == "none" {
                    plain = e;
                }
                let rel = |i: usize| 100.0 * (e[i] / plain[i] - 1.0);
                println!(
                    "| {name} | {} | {kind} | {:.4} | {:.4} | {:+.1} % | {:+.1} % | {secs:.3} |",
                    s.triangle_count(),
                    e[0],
                    e[1],
                    rel(1),
                    rel(0),
                );
            }
        }
    }
}

#[test]
fn qem_refuses_bad_meshes_and_pair_distances() {
    let d = tempfile::tempdir().unwrap();
    let cases = [
        (
            "index.obj",
            format!("{}f 1 2 999\n", grid_obj(2, "")),
            "index.obj",
        ),
        (
            "nan.obj",
            grid_obj(2, "").replacen("v 0 0", "v nan 0", 1),
            "nan.obj",
        ),
        (
            "empty.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\n".to_string(),
            "triangles",
        ),
    ];
    for (name, text, needle) in &cases {
        std::fs::write(d.path().join(name), text).unwrap();
        let r = common::terratile(
            d.path(),
            &[
                "simplify", name, "out.obj", "--method", "qem", "--ratio", "0.5",
            ],
        );
        r.input_error(&[needle]);
        r.left_nothing("out.obj");
    }
    std::fs::write(d.path().join("m.obj"), grid_obj(12, "")).unwrap();
    const QEM: &[&str] = &["--method", "qem", "--ratio", "0.5"];
    let cases: [(&[&str], &[&str], &str); 5] = [
        (QEM, &["--pair-distance", "-1"], "pair_distance"),
        (QEM, &["--pair-distance", "nan"], "pair_distance"),
        // Every vertex within reach of every other: more candidate pairs than allowed.
        (QEM, &["--pair-distance", "100"], "candidate vertex pairs"),
        // QEM keys with the default clustering method.
        (
            &["--ratio", "0.5"],
            &["--pair-distance", "0.1"],
            "pair_distance",
        ),
        (&["--ratio", "0.5"], &["--collapse-seams"], "collapse_seams"),
    ];
    for (method, args, needle) in cases {
        let mut a = vec!["simplify", "m.obj", "out.obj"];
        a.extend_from_slice(method);
        a.extend_from_slice(args);
        let r = common::terratile(d.path(), &a);
        r.input_error(&[needle]);
        r.left_nothing("out.obj");
    }
}

/// The border edges of `m` (edges of one triangle) as position pairs.
fn border_segments(m: &TriMesh) -> Vec<[glam::Vec3; 2]> {
    let adj = Adjacency::new(m);
    adj.edge_faces
        .boundary_edges()
        .map(|e| adj.edge_faces.edge(e).map(|v| m.positions[v as usize]))
        .collect()
}

/// The distance from `p` to the nearest of `segs`.
fn to_segments(p: glam::Vec3, segs: &[[glam::Vec3; 2]]) -> f64 {
    let p = p.as_dvec3();
    segs.iter()
        .map(|[a, b]| {
            let (a, b) = (a.as_dvec3(), b.as_dvec3());
            let e = b - a;
            let t = if e.length_squared() > 0.0 {
                ((p - a).dot(e) / e.length_squared()).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (a + e * t - p).length()
        })
        .fold(f64::INFINITY, f64::min)
}

/// Borders under QEM: with `lock_border` every border edge is kept exactly (same segments,
/// same length); with the default boundary quadrics and an error bound E, every output
/// border vertex lies within E of the input's border (the README's bound), and the border
/// length changes little. On the bumpy grid and on bunny's holes.
#[test]
fn qem_borders_move_within_the_error_bound() {
    let grid: TriMesh = {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("g.obj"), grid_obj(40, "")).unwrap();
        io::read(&d.path().join("g.obj")).unwrap()
    };
    let mut meshes = vec![("grid", grid)];
    if let Some(b) = load("bunny.obj") {
        meshes.push(("bunny", b));
    }
    let key = |s: &[glam::Vec3; 2]| {
        let mut k = s.map(|p| p.to_array().map(f32::to_bits));
        k.sort_unstable();
        k
    };
    let length =
        |segs: &[[glam::Vec3; 2]]| -> f64 { segs.iter().map(|[a, b]| a.distance(*b) as f64).sum() };
    for (name, m) in &meshes {
        let segs_in = border_segments(m);
        let len_in = length(&segs_in);
        let diag = m.diagonal();
        // Locked: the same border segments.
        let mut p = SimplifyParams::ratio(Method::Qem, 0.05);
        p.lock_border = Some(true);
        let s = simplify(m, &p).unwrap().mesh;
        let mut a: Vec<_> = segs_in.iter().map(key).collect();
        let mut b: Vec<_> = border_segments(&s).iter().map(key).collect();
        a.sort_unstable();
        b.sort_unstable();
        assert_eq!(a, b, "{name}: lock_border keeps every border edge");
        // Free, with an error bound.
        for pct in [0.05, 0.2, 1.0] {
            let e = pct * 0.01 * diag;
            let mut p = SimplifyParams::ratio(Method::Qem, 0.01);
            p.max_error_pct = Some(pct);
            let r = simplify(m, &p).unwrap();
            let out = border_segments(&r.mesh);
            let moved = out
                .iter()
                .flatten()
                .map(|&v| to_segments(v, &segs_in))
                .fold(0.0, f64::max);
            let len = length(&out);
            println!(
                "{name} E = {pct} %: {} triangles, border vertices within {:.3} E of the \
                 input border, border length {:.4} × the input's",
                r.mesh.triangle_count(),
                moved / e,
                len / len_in
            );
            assert!(moved <= e * (1.0 + 1e-9), "{name} {pct} %: {moved} > {e}");
            assert!((len / len_in - 1.0).abs() < 0.1, "{name} {pct} %");
        }
    }
}

/// spot's UV seams stay seams under QEM (the seam vertices keep one output vertex per UV
/// copy), and with `collapse_seams` they are collapsed across like any vertex: one output
/// vertex per position, and the collapse goes further.
#[test]
fn qem_keeps_spot_uv_seams_unless_told() {
    let Some(spot) = load("spot.obj") else { return };
    let run = |collapse: bool| {
        let mut p = SimplifyParams::ratio(Method::Qem, 0.05);
        p.collapse_seams = collapse.then_some(true);
        simplify(&spot, &p).unwrap().mesh
    };
    let kept = run(false);
    let split = |m: &TriMesh| {
        m.weld_map()
            .iter()
            .enumerate()
            .filter(|&(i, &r)| r as usize != i)
            .count()
    };
    assert!(split(&kept) > 0, "seam vertices kept apart");
    let merged = run(true);
    check_output(&spot, &merged, "qem collapse_seams");
    assert_eq!(split(&merged), 0, "no seam copies left");
    assert!(
        merged.triangle_count() < kept.triangle_count(),
        "{} vs {}",
        merged.triangle_count(),
        kept.triangle_count()
    );
    let uv = merged.uvs.as_ref().unwrap();
    assert!(uv.iter().all(|t| t.is_finite()));
}

/// The triangles of `m` with the highest mean `h` of their corners, most salient first,
/// until a fifth of the area.
/// The hybrid, mesh saliency and mean image saliency of `m` ([`saliency::maps`] with the
/// default views); with SALIENCY_CACHE=DIR read from or written to DIR/NAME.maps (raw f64
/// little endian, for repeated trials of the weighting: the maps do not depend on it).
fn cached_maps(name: &str, m: &TriMesh) -> [Vec<f64>; 5] {
    use terratile::simplify::saliency::{self, image::ViewParams};
    let n = m.vertex_count();
    let file = std::env::var("SALIENCY_CACHE")
        .ok()
        .map(|d| std::path::Path::new(&d).join(format!("{name}.maps5")));
    if let Some(bytes) = file.as_ref().and_then(|f| std::fs::read(f).ok()) {
        if bytes.len() == 5 * 8 * n {
            let v: Vec<f64> = bytes
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
                .collect();
            return [0, 1, 2, 3, 4].map(|k| v[k * n..(k + 1) * n].to_vec());
        }
    }
    let maps = saliency::maps(m, &ViewParams::default()).unwrap();
    let out = [
        maps.curvature,
        maps.mesh_saliency,
        maps.image.max,
        maps.image.min,
        maps.image.mean,
    ];
    if let Some(f) = file {
        let bytes: Vec<u8> = out.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        std::fs::create_dir_all(f.parent().unwrap()).unwrap();
        std::fs::write(f, bytes).unwrap();
    }
    out
}

/// The hybrid of `maps` ([`cached_maps`]) with class A's curvature smoothed over σ =
/// `smooth` ε and `classes`.
fn hybrid_of(
    m: &TriMesh,
    maps: &[Vec<f64>; 5],
    smooth: f64,
    classes: &terratile::simplify::saliency::hybrid::Classes,
) -> Vec<f64> {
    use terratile::simplify::saliency::hybrid;
    let c = hybrid::class_curvature(m, &maps[0], smooth);
    let [_, ms, max, min, mean] = maps;
    hybrid::hybrid_with([&c, ms, max, min, mean], classes).0
}

/// A third of each triangle's area at each of its corners.
fn vertex_areas(m: &TriMesh) -> Vec<f64> {
    let mut a = vec![0.0f64; m.vertex_count()];
    for (f, t) in m.indices.iter().enumerate() {
        for &v in t {
            a[v as usize] += m.face_area(f) / 3.0;
        }
    }
    a
}

/// `h` times (mean vertex area / vertex area)^`gamma` (a third of each triangle's area at
/// its corners; a vertex without area keeps its weight); `h` itself for `gamma` = 0.
fn area_normalised(m: &TriMesh, h: Vec<f64>, gamma: f64) -> Vec<f64> {
    if gamma == 0.0 {
        return h;
    }
    let a = vertex_areas(m);
    let mean = a.iter().sum::<f64>() / a.iter().filter(|&&x| x > 0.0).count().max(1) as f64;
    h.iter()
        .zip(&a)
        .map(|(&w, &x)| {
            if x > 0.0 {
                w * (mean / x).powf(gamma)
            } else {
                w
            }
        })
        .collect()
}

fn salient_fifth(m: &TriMesh, h: &[f64]) -> TriMesh {
    let score: Vec<f64> = m
        .indices
        .iter()
        .map(|t| t.iter().map(|&v| h[v as usize]).sum::<f64>() / 3.0)
        .collect();
    let mut order: Vec<usize> = (0..m.triangle_count()).collect();
    order.sort_by(|&a, &b| score[b].total_cmp(&score[a]).then(a.cmp(&b)));
    let (total, mut acc) = (m.area(), 0.0);
    let mut salient = TriMesh {
        positions: m.positions.clone(),
        ..TriMesh::default()
    };
    for f in order {
        if acc >= 0.2 * total {
            break;
        }
        acc += m.face_area(f);
        salient.indices.push(m.indices[f]);
    }
    salient
}

#[test]
fn compare_heatmap_draws_the_error_and_never_overwrites() {
    // A bumpy grid against its plain QEM simplification: the PNG is written, the JSON
    // names it with the distances, and a second run refuses to overwrite it (exit 2).
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("m.obj"), grid_obj(12, "")).unwrap();
    let mut m = io::read(&d.path().join("m.obj")).unwrap();
    for p in &mut m.positions {
        p.z = (3.0 * p.x).sin() * (2.0 * p.y).cos();
    }
    io::write(&m, &d.path().join("m.obj")).unwrap();
    let s = simplify(&m, &SimplifyParams::ratio(Method::Qem, 0.2)).unwrap();
    io::write(&s.mesh, &d.path().join("s.obj")).unwrap();
    let args = ["compare", "m.obj", "s.obj", "--heatmap", "h.png", "--json"];
    let r = common::terratile(d.path(), &args);
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    let (mean, max) = (
        v["heatmap"]["mean"].as_f64().unwrap(),
        v["heatmap"]["max"].as_f64().unwrap(),
    );
    assert!(mean > 0.0 && max >= mean, "{}", r.stdout);
    assert!(v["compare"]["error"].is_object(), "{}", r.stdout);
    let png = std::fs::read(d.path().join("h.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    let r = common::terratile(d.path(), &args);
    r.input_error(&["h.png", "exists"]);
    assert_eq!(std::fs::read(d.path().join("h.png")).unwrap(), png);
}
