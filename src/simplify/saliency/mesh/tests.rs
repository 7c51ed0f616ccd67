use super::*;
use crate::simplify::test_meshes::{grid, icosphere};
use glam::Vec3;

/// The slow, obvious twin of [`gaussians`]: every pair of points, by a plain scan.
fn gaussians_slow(pos: &[DVec3], c: &[f64], eps: f64) -> Vec<[f64; 8]> {
    pos.iter()
        .map(|&p| {
            std::array::from_fn(|s| {
                let sigma = SIGMAS[s] * eps;
                let (mut num, mut den) = (0.0, 0.0);
                for (q, &cq) in pos.iter().zip(c) {
                    let d2 = (*q - p).length_squared();
                    if d2.sqrt() < 2.0 * sigma {
                        let g = (-d2 / (2.0 * sigma * sigma)).exp();
                        num += g * cq;
                        den += g;
                    }
                }
                num / den
            })
        })
        .collect()
}

#[test]
fn curvature_of_a_sphere_is_one_over_r() {
    for r in [1.0f32, 7.5] {
        let m = icosphere(4, r);
        let c = curvature(&m);
        for (v, &x) in c.iter().enumerate() {
            let want = 1.0 / r as f64;
            assert!((x - want).abs() < 0.01 * want, "vertex {v}: {x} vs {want}");
        }
    }
}

#[test]
fn curvature_and_saliency_of_a_plane_are_zero() {
    let mut m = grid(12);
    for p in &mut m.positions {
        p.z = 0.3 * p.x - 0.2 * p.y;
    }
    let s = mesh_saliency(&m);
    assert!(s.curvature.iter().all(|&x| x < 1e-6), "{:?}", s.curvature);
    let top = s.saliency.iter().cloned().fold(0.0, f64::max);
    assert!(top < 1e-6, "{top}");
}

#[test]
fn the_grid_equals_the_all_pairs_twin() {
    for (m, stretch) in [
        (grid(30), 1.0f32),
        (grid(25), 0.02),
        (icosphere(3, 2.0), 1.0),
    ] {
        let mut m = m;
        // A thin dimension makes most of the grid's cells empty.
        for p in &mut m.positions {
            p.y *= stretch;
        }
        let w = Welded::new(&m);
        let c = welded_curvature(&w);
        let e = eps(&w.pos);
        // Large ε too, so that neighbourhoods span many cells and the whole mesh.
        for e in [e, 5.0 * e, 40.0 * e] {
            let fast = gaussians(&w.pos, &c, e);
            let slow = gaussians_slow(&w.pos, &c, e);
            for (v, (a, b)) in fast.iter().zip(&slow).enumerate() {
                for s in 0..8 {
                    assert!(
                        (a[s] - b[s]).abs() <= 1e-12 * b[s].abs().max(1.0),
                        "{v} {s}"
                    );
                }
            }
            let nb = w.neighbours();
            let (sf, ss) = (combine(&fast, &nb), combine(&slow, &nb));
            for (a, b) in sf.iter().zip(&ss) {
                assert!(
                    (a - b).abs() <= 1e-9 * b.abs().max(1.0),
                    "{stretch} {e} {a} {b}"
                );
            }
        }
    }
}

#[test]
fn a_bump_on_a_plane_is_the_salient_place() {
    // A plane with one small Gaussian bump at (0.3, 0.6).
    let mut m = grid(60);
    let at = Vec3::new(0.3, 0.6, 0.0);
    for p in &mut m.positions {
        let d2 = (p.x - at.x).powi(2) + (p.y - at.y).powi(2);
        p.z = 0.02 * (-d2 / (2.0 * 0.02f32.powi(2))).exp();
    }
    let s = mesh_saliency(&m);
    let (v, _) = s
        .saliency
        .iter()
        .enumerate()
        .fold((0, 0.0), |b, (i, &x)| if x > b.1 { (i, x) } else { b });
    let p = m.positions[v];
    assert!((p.x - at.x).hypot(p.y - at.y) < 0.08, "{p}");
    // Far from the bump it is nothing.
    for (p, &x) in m.positions.iter().zip(&s.saliency) {
        if (p.x - at.x).hypot(p.y - at.y) > 0.3 {
            assert!(x < 1e-6, "{p}: {x}");
        }
    }
}

#[test]
fn welded_copies_share_their_value() {
    // The sphere with one vertex duplicated (a seam): both copies carry the same values.
    let mut m = icosphere(2, 1.0);
    let dup = m.positions.len() as u32;
    m.positions.push(m.positions[5]);
    for t in m.indices.iter_mut().take(40) {
        for v in t.iter_mut() {
            if *v == 5 {
                *v = dup;
            }
        }
    }
    let s = mesh_saliency(&m);
    assert_eq!(s.curvature[5], s.curvature[dup as usize]);
    assert_eq!(s.saliency[5], s.saliency[dup as usize]);
}

#[test]
fn face_max_gives_each_vertex_its_most_salient_triangle() {
    // A fan of four triangles around vertex 0, one of them with a salient corner (vertex 2),
    // plus a seam copy (5) of vertex 1 in the last triangle.
    let m = TriMesh {
        positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, -Vec3::X, -Vec3::Y, Vec3::X],
        indices: vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]],
        ..TriMesh::default()
    };
    let values = [0.0, 0.0, 3.0, 0.0, 0.0, 0.6];
    let f = face_max(&m, &values);
    // The copies of vertex 1 take their larger value, 0.6; triangle means 1.2, 1, 0, 0.2.
    let near = |a: f64, b: f64| (a - b).abs() < 1e-12;
    assert!(near(f[0], 1.2) && near(f[2], 1.2), "{f:?}");
    assert!(near(f[3], 1.0) && near(f[4], 0.2), "{f:?}");
    assert!(near(f[1], 1.2) && f[1] == f[5], "{f:?}");
}
