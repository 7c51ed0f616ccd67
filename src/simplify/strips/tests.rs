use super::progressive::{engine_input, ref_offset};
use super::stripify::triangle_set;
use super::*;
use super::{filter, format};
use crate::mesh::TriMesh;
use crate::simplify::prep::Prepared;
use crate::simplify::qem::{self, Collapse};
use crate::simplify::test_meshes::grid;
use glam::Vec3;
use proptest::prelude::*;
use std::path::Path;

fn all_params() -> Vec<StripParams> {
    let mut v = Vec::new();
    for join in [Join::Restart, Join::Degenerate] {
        for window in [0, 1, 8] {
            v.push(StripParams { join, window });
        }
    }
    v
}

/// Random triangles over a few vertices: shared edges, both orientations, non-manifold
/// edges, repeated and degenerate triangles.
fn random_tris() -> impl Strategy<Value = Vec<[u32; 3]>> {
    prop::collection::vec(prop::array::uniform3(0u32..12), 0..60)
}

/// The triangles of a strip with random vertices merged into others (what collapses do).
fn collapsed_strip() -> impl Strategy<Value = (Vec<u32>, Join)> {
    (
        random_tris(),
        prop::collection::vec((0u32..12, 0u32..12), 0..8),
        any::<bool>(),
    )
        .prop_map(|(tris, merges, restart)| {
            let join = if restart {
                Join::Restart
            } else {
                Join::Degenerate
            };
            let mut s = stripify(&tris, &StripParams { join, window: 8 });
            for (p, q) in merges {
                for v in &mut s {
                    if *v == p {
                        *v = q;
                    }
                }
            }
            (s, join)
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]

    #[test]
    fn unstripify_gives_back_the_triangles(tris in random_tris()) {
        for p in all_params() {
            let s = stripify(&tris, &p);
            prop_assert_eq!(triangle_set(unstripify(&s)), triangle_set(tris.iter().copied()));
            if p.join == Join::Degenerate {
                prop_assert!(!s.contains(&RESTART));
            }
        }
    }

    #[test]
    fn stripify_equals_its_slow_twin(tris in random_tris()) {
        for p in all_params() {
            prop_assert_eq!(stripify(&tris, &p), super::stripify_twin::stripify_twin(&tris, &p));
        }
    }

    #[test]
    fn dtfs_and_stss_keep_the_triangles((s, join) in collapsed_strip()) {
        // The twin: the unstripified list, degenerate triangles dropped (unstripify does).
        let want = triangle_set(unstripify(&s));
        let d = dtfs(&s, join);
        prop_assert_eq!(triangle_set(unstripify(&d)), want.clone());
        let (mut scratch, mut w) = (Vec::new(), Vec::new());
        for window in [1, 3, 16] {
            filter::dtfs_window_into(&s, join, window, &mut scratch, &mut w);
            prop_assert_eq!(triangle_set(unstripify(&w)), want.clone());
        }
        filter::dtfs_window_into(&s, join, 1, &mut scratch, &mut w);
        prop_assert_eq!(&w, &d);
        let t = stss(&s, join);
        prop_assert_eq!(triangle_set(unstripify(&t)), want.clone());
        prop_assert!(t.len() <= s.len());
        if join == Join::Degenerate {
            prop_assert!(!d.contains(&RESTART) && !t.contains(&RESTART));
        }
    }
}

/// Three vertices of valence above 255 (where the window's choice reads the exact
/// valences rather than the 8-bit ones) and triangles made of them alone, whose valences
/// differ only above 255: the same strips as the slow twin.
#[test]
fn stripify_with_valences_above_255_equals_its_slow_twin() {
    let mut tris = vec![[0, 1, 2], [2, 1, 0], [0, 2, 1], [1, 0, 2]];
    for i in 0..300 {
        tris.push([0, 1, 3 + i]);
        tris.push([1, 2, 303 + i]);
        if i < 280 {
            tris.push([2, 0, 603 + i]);
        }
        if i % 50 == 0 {
            tris.push([0, 1, 2]);
        }
    }
    for p in all_params() {
        let s = stripify(&tris, &p);
        assert_eq!(s, super::stripify_twin::stripify_twin(&tris, &p), "{p:?}");
        assert_eq!(triangle_set(unstripify(&s)), triangle_set(tris.clone()));
    }
}

#[test]
fn a_grid_strips_to_about_one_index_per_triangle() {
    let m = grid(20);
    for p in all_params() {
        let s = stripify(&m.indices, &p);
        let per = s.len() as f64 / m.indices.len() as f64;
        let bound = if p.window == 0 { 1.6 } else { 3.5 };
        assert!(per < bound, "{p:?}: {per} indices per triangle");
        assert_eq!(
            triangle_set(unstripify(&s)),
            triangle_set(m.indices.clone())
        );
    }
}

#[test]
fn the_collapse_log_equals_the_slow_twins() {
    let m = grid(12);
    let params = qem::QemParams::plain(30, qem::Placement::Endpoint);
    let (r, fast) = qem::simplify_logged(&m, &params).unwrap();
    let prep = Prepared::new(&m);
    let mut c = Collapse::new(&prep, &params);
    c.record = true;
    c.run_slow(30);
    assert!(fast.len() > 100);
    assert_eq!(fast, c.steps);
    assert_eq!(r.report.collapses, fast.len());
    // Without `record` nothing is kept.
    let mut c = Collapse::new(&prep, &params);
    c.run_fast(30);
    assert!(c.steps.is_empty());
}

/// Triangles as position triples (orientation kept), for comparing meshes whose vertices
/// are numbered differently.
fn geometric(m: &TriMesh) -> Vec<[[u32; 3]; 3]> {
    let mut v: Vec<[[u32; 3]; 3]> = m
        .indices
        .iter()
        .map(|t| {
            let p = t.map(|i| m.positions[i as usize].to_array().map(f32::to_bits));
            let k = (0..3).min_by_key(|&k| p[k]).unwrap();
            [p[k], p[(k + 1) % 3], p[(k + 2) % 3]]
        })
        .collect();
    v.sort_unstable();
    v
}

fn check_levels(m: &TriMesh, params: &ProgressiveParams, engine_levels: &[usize]) {
    let p = progressive(m, params).unwrap();
    let n = p.splits.len();
    assert!(n > 0);
    let (canon, qp) = engine_input(m, params);
    let full = triangle_set(canon.indices.iter().copied());
    // Every level, both encodings, one decoder moving up: the drawn strips agree, and the
    // full level is the original.
    let mut dn = Decoder::new(&p, Encoding::Naive);
    let mut de = Decoder::new(&p, Encoding::Encoded);
    let mut levels = vec![unstripify(dn.strip())];
    loop {
        assert_eq!(dn.strip(), de.strip(), "level {}", dn.level());
        let (a, b) = (dn.refine(), de.refine());
        assert_eq!(a, b);
        if !a {
            break;
        }
        levels.push(unstripify(dn.strip()));
    }
    assert_eq!(dn.level(), n);
    let last = p.mesh_at(n, Encoding::Encoded);
    assert_eq!(geometric(&last), geometric(&canon));
    assert_eq!(last.indices.len(), full.len());
    // Coarsening back gives the same strips.
    while de.coarsen() {
        let l = de.level();
        assert_eq!(
            triangle_set(unstripify(de.strip())),
            triangle_set(levels[l].clone())
        );
    }
    assert_eq!(de.strip(), p.base.as_slice());
    // A level equals the engine's mesh after n − k collapses.
    let mut counts = vec![0usize; n + 1];
    for (k, l) in levels.iter().enumerate() {
        counts[k] = l.len();
    }
    for &k in engine_levels {
        let k = k.min(n);
        let target = counts[k] as u64;
        let r = qem::simplify(
            &canon,
            &qem::QemParams {
                triangles: target,
                ..qp.clone()
            },
        )
        .unwrap();
        assert_eq!(r.report.collapses, n - k, "level {k}");
        let ours = p.mesh_at(k, Encoding::Naive);
        assert_eq!(geometric(&ours), geometric(&r.mesh), "level {k}");
    }
}

#[test]
fn every_level_of_a_grid_is_the_engines_mesh() {
    let m = grid(16);
    for strip in all_params() {
        for order in [StripOrder::Full, StripOrder::Hierarchical] {
            let params = ProgressiveParams {
                strip,
                order,
                ..ProgressiveParams::default()
            };
            check_levels(&m, &params, &[0, 1, 7, 100, 300, usize::MAX]);
        }
    }
}

#[test]
fn attributes_travel_with_the_restored_vertex() {
    let mut m = grid(8);
    m.colors = Some(m.positions.iter().map(|p| [p.x, p.y, p.z, 1.0]).collect());
    let p = progressive(&m, &ProgressiveParams::default()).unwrap();
    let c = p.vertices.colors.as_ref().unwrap();
    for (v, pos) in p.vertices.positions.iter().enumerate() {
        assert_eq!(c[v], [pos.x, pos.y, pos.z, 1.0]);
    }
    let bytes = format::encode(&p, Encoding::Encoded);
    let (q, _) = format::decode(&bytes, Path::new("t.tps")).unwrap();
    assert_eq!(q.vertices.colors, p.vertices.colors);
}

#[test]
fn e_ps_updates_fewer_slots_than_naive() {
    let m = grid(30);
    let p = progressive(&m, &ProgressiveParams::default()).unwrap();
    let (naive, enc) = p.mean_updates();
    assert!(enc < naive, "{enc} vs {naive}");
    assert!(p.base_slots.iter().any(|&v| ref_offset(v).is_some()));
}

/// The paper's Fig. 2 example, counted as the paper counts it (Table 3: the offsets a
/// split restores): in the triangle p q r, q collapses into p, then p into r. Naive-PS
/// writes p over q's slot, so p's split restores two slots; E-PS writes q's slot as R−1 (a
/// reference to p's slot), so p's split restores one, and q's split one in both forms.
#[test]
fn the_papers_figure_2_counts() {
    // Stream ids: r = 0 (the base vertex), p = 1 (split 0, kept r), q = 2 (split 1, kept p).
    let vertices = TriMesh {
        positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
        ..TriMesh::default()
    };
    let p = Progressive::from_full(vertices, 1, vec![1, 2, 0], &[0, 1], 1);
    assert_eq!(p.naive(0), [0, 1]);
    assert_eq!(p.naive(1), [1]);
    assert_eq!(p.encoded(0), [(0, progressive::ref_slot(2))]);
    assert_eq!(p.encoded(1), [(1, progressive::ref_slot(-1))]);
    assert_eq!(p.mean_updates(), (1.5, 1.0));
    // The base strip shows r three times, and names it once.
    assert_eq!(p.base, vec![0, 0, 0]);
    assert_eq!(
        p.base_slots,
        vec![progressive::ref_slot(2), progressive::ref_slot(-1), 0]
    );
}

/// E-PS also refers to a neighbour that shows the removed vertex (it shows the kept one
/// after the collapse): in the strip p a p b (a swap repeats p), p collapses into q, which
/// is two slots away from one of p's slots only; the other refers to that one.
#[test]
fn e_ps_chains_through_the_removed_vertexs_own_slots() {
    // Stream ids: a = 0, b = 1, q = 2 base; p = 3 (split 0, kept q).
    let vertices = TriMesh {
        positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
        ..TriMesh::default()
    };
    let full = vec![3, 0, 3, 1, 2];
    let p = Progressive::from_full(vertices, 3, full.clone(), &[2], 2);
    assert_eq!(p.naive(0), [0, 2]);
    // Slot 2 refers to q at +2, slot 0 to slot 2 at +2.
    let r = progressive::ref_slot(2);
    assert_eq!(p.encoded(0), [(0, r), (2, r)]);
    // Both forms decode to the same strips.
    for e in [Encoding::Naive, Encoding::Encoded] {
        let mut d = Decoder::new(&p, e);
        assert_eq!(d.strip(), [2, 0, 2, 1, 2]);
        d.set_level(1);
        assert_eq!(d.strip(), full.as_slice());
        d.set_level(0);
        assert_eq!(d.strip(), [2, 0, 2, 1, 2]);
    }
}

#[test]
fn the_stream_round_trips() {
    let m = grid(10);
    for encoding in [Encoding::Naive, Encoding::Encoded] {
        let p = progressive(&m, &ProgressiveParams::default()).unwrap();
        let bytes = format::encode(&p, encoding);
        let (q, e) = format::decode(&bytes, Path::new("t.tps")).unwrap();
        assert_eq!(e, encoding);
        assert_eq!(q.base, p.base);
        assert_eq!(q.base_slots, p.base_slots);
        assert_eq!(q.splits.len(), p.splits.len());
        for i in 0..p.splits.len() {
            assert_eq!(q.splits[i].kept, p.splits[i].kept);
            assert_eq!(q.naive(i), p.naive(i));
            assert_eq!(q.encoded(i), p.encoded(i));
        }
        assert_eq!(q.vertices.positions, p.vertices.positions);
    }
}

#[test]
fn bad_streams_are_refused_with_their_offset() {
    let m = grid(6);
    let p = progressive(&m, &ProgressiveParams::default()).unwrap();
    let good = format::encode(&p, Encoding::Encoded);
    let path = Path::new("x.tps");
    let msg = |b: &[u8]| format::decode(b, path).unwrap_err().to_string();
    let mut b = good.clone();
    b[0] = b'X';
    assert!(
        msg(&b).contains("byte 0: not a progressive strip stream"),
        "{}",
        msg(&b)
    );
    let mut b = good.clone();
    b[4] = 9;
    assert!(msg(&b).contains("byte 4: version 9"), "{}", msg(&b));
    assert!(msg(&good[..good.len() - 1]).contains("truncated"));
    assert!(msg(&good[..10]).contains("byte 0: truncated"));
    // Counts past the end.
    let mut b = good.clone();
    b[16..20].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(msg(&b).contains("byte 28: truncated"), "{}", msg(&b));
    // A split that names a vertex not yet present.
    let first = 28 + 4 * p.base.len() + 12 * p.base_vertices as usize;
    let mut b = good.clone();
    b[first + 12..first + 16].copy_from_slice(&(p.base_vertices + 3).to_le_bytes());
    assert!(msg(&b).contains("not yet present"), "{}", msg(&b));
    assert!(
        msg(&b).contains(&format!("byte {}", first + 12)),
        "{}",
        msg(&b)
    );
    // An offset out of range.
    let mut b = good.clone();
    b[first + 20..first + 24].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(msg(&b).contains("out of range"), "{}", msg(&b));
    let mut b = good.clone();
    b.push(0);
    assert!(msg(&b).contains("trailing"), "{}", msg(&b));
}

#[test]
fn mutated_streams_never_panic() {
    let m = grid(5);
    let p = progressive(&m, &ProgressiveParams::default()).unwrap();
    for encoding in [Encoding::Naive, Encoding::Encoded] {
        let good = format::encode(&p, encoding);
        let mut rng = crate::rng::SplitMix64::new(7);
        for _ in 0..3000 {
            let mut b = good.clone();
            for _ in 0..1 + rng.next_u64() % 4 {
                let i = (rng.next_u64() % b.len() as u64) as usize;
                match rng.next_u64() % 3 {
                    0 => b[i] = rng.next_u64() as u8,
                    1 => b[i] ^= 1 << (rng.next_u64() % 8),
                    _ => b.truncate(i),
                }
                if b.is_empty() {
                    break;
                }
            }
            if let Ok((q, e)) = format::decode(&b, Path::new("m.tps")) {
                // Whatever passes decodes to every level without a panic.
                let mut d = Decoder::new(&q, e);
                d.set_level(usize::MAX);
                d.set_level(0);
                assert_eq!(d.strip(), q.base.as_slice());
            }
        }
    }
}

#[test]
fn bad_parameters_are_refused() {
    let m = grid(3);
    for r in [0.0, 1.0, -0.5, f64::NAN, 2.0] {
        let e = progressive(
            &m,
            &ProgressiveParams {
                base_ratio: r,
                ..ProgressiveParams::default()
            },
        )
        .unwrap_err();
        assert!(e.to_string().contains("base_ratio"), "{e}");
    }
    let flat = TriMesh {
        positions: vec![Vec3::ZERO; 3],
        indices: vec![[0, 1, 2]],
        ..TriMesh::default()
    };
    assert!(progressive(&flat, &ProgressiveParams::default()).is_err());
}

/// The flat stripifier writes the same indices as its slow twin on every shared mesh, in
/// the file's order and after meshoptimizer's vertex-cache order, for every join and window
/// (`TERRATILE_DATA`, else ../shared/data; skipped without it).
#[test]
fn stripify_equals_its_slow_twin_on_the_shared_meshes() {
    let dir = std::env::var_os("TERRATILE_DATA")
        .map_or_else(
            || Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
            Into::into,
        )
        .join("meshes");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        eprintln!("skipping: {} not found", dir.display());
        return;
    };
    let mut names: Vec<_> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "obj" || x == "ply"))
        .collect();
    names.sort();
    for path in names {
        let m = crate::mesh::io::read(&path).unwrap();
        let flat: Vec<u32> = m.indices.iter().flatten().copied().collect();
        let opt = meshopt::optimize_vertex_cache(&flat, m.vertex_count());
        let opt: Vec<[u32; 3]> = opt.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        for tris in [&m.indices, &opt] {
            for p in all_params() {
                assert!(
                    stripify(tris, &p) == super::stripify_twin::stripify_twin(tris, &p),
                    "{} {p:?}",
                    path.display()
                );
            }
        }
    }
}
