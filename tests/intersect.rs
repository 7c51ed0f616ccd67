//! The self-intersection checker (BVH + exact predicates) against its O(n²) brute-force
//! twin on every shared mesh, and `compare --check-folds` end to end.

use crate::common;

use terratile::mesh::intersect::{self_intersections, self_intersections_brute};
use terratile::mesh::{io, TriMesh};

fn load(name: &str) -> Option<TriMesh> {
    Some(io::read(&common::data_file(&format!("meshes/{name}"))?).unwrap())
}

/// Every shared mesh: the BVH checker's pairs equal the brute force's. The O(n²) twin is
/// run up to 25,000 triangles (dragon_10k: 3 s on 2 cores); bunny (69k: 43 s), armadillo
/// (100k) and igea (269k) are left to the BVH checker here, and `--ignored` runs the
/// twin on them too (igea's takes several minutes).
#[test]
fn checker_equals_brute_force_on_shared_meshes() {
    check_shared(25_000);
}

#[test]
#[ignore]
fn checker_equals_brute_force_on_the_largest_shared_meshes() {
    check_shared(usize::MAX);
}

fn check_shared(limit: usize) {
    for name in [
        "cow.obj",
        "spot.obj",
        "pirate.obj",
        "triceratops.obj",
        "triceratops_source_polygons.obj",
        "fandisk.obj",
        "dragon_10k.obj",
        "colored_airplane.ply",
        "bunny.obj",
        "armadillo.obj",
        "igea.ply",
    ] {
        let Some(m) = load(name) else { return };
        let t = std::time::Instant::now();
        let fast = self_intersections(&m);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        if m.triangle_count() > limit {
            println!(
                "{name}: {} pairs ({ms:.0} ms, brute force skipped)",
                fast.len()
            );
            continue;
        }
        let t = std::time::Instant::now();
        let slow = self_intersections_brute(&m);
        let slow_ms = t.elapsed().as_secs_f64() * 1e3;
        println!(
            "{name}: {} pairs ({ms:.0} ms; brute force {slow_ms:.0} ms)",
            fast.len()
        );
        assert_eq!(fast, slow, "{name}");
    }
}

/// The `folds` object of `compare ORIGINAL SIMPLIFIED --check-folds --json` run in `dir`.
fn folds(dir: &std::path::Path, original: &str, simplified: &str) -> serde_json::Value {
    let r = common::terratile(
        dir,
        &["compare", original, simplified, "--check-folds", "--json"],
    );
    r.ok();
    let mut v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    v["folds"].take()
}

/// `compare --check-folds` on a mesh against itself: no fold-over, and the input's own
/// self-intersections reported on both sides (text and JSON).
#[test]
fn compare_check_folds_reports_counts() {
    let Some(cow) = common::data_file("meshes/cow.obj") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let c = cow.to_str().unwrap();
    let f = folds(dir.path(), c, c);
    assert_eq!(f["fold_overs"].as_array().unwrap().len(), 0, "{f}");
    assert_eq!(
        f["self_intersecting_pairs"], f["original_self_intersecting_pairs"],
        "{f}"
    );
    let r = common::terratile(dir.path(), &["compare", c, c, "--check-folds"]);
    r.ok();
    assert!(r.stdout.contains("fold-overs: 0 faces"), "{}", r.stdout);
    assert!(r.stdout.contains("self-intersections: "), "{}", r.stdout);
}

/// `simplify --method qem --check-intersections` and `compare --check-folds` end to end:
/// on bunny at 2 % (whose unchecked output has fold-overs) the checked output has none and
/// no self-intersecting face.
#[test]
fn checked_qem_output_passes_the_checker() {
    let Some(bunny) = common::data_file("meshes/bunny.obj") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let b = bunny.to_str().unwrap();
    let mut counts = Vec::new();
    for check in [false, true] {
        let mut args = vec![
            "simplify", b, "out.obj", "--method", "qem", "--ratio", "0.02",
        ];
        if check {
            args.push("--check-intersections");
        }
        common::terratile(dir.path(), &args).ok();
        let f = folds(dir.path(), b, "out.obj");
        counts.push((
            f["fold_overs"].as_array().unwrap().len(),
            f["self_intersecting_pairs"].as_u64().unwrap(),
        ));
        std::fs::remove_file(dir.path().join("out.obj")).unwrap();
    }
    assert!(counts[0].0 > 0, "{counts:?}");
    assert_eq!(counts[1], (0, 0), "{counts:?}");
}
