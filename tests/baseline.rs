//! Issue 5: the Delaunay baseline as a pipeline stage (`[baseline]`), its validity on real
//! data, `bench table1` (JSON, plot, skipped counts) and its bad inputs.

use crate::common;

use common::{fixture_las, run_pipeline, terratile, write_xyz};
use std::path::Path;
use terratile::points::{self, ReadOptions};
use terratile::terrain::delaunay::{self, TinMethod};
use terratile::NoProgress;

#[test]
fn baseline_stage_writes_the_tin_and_the_report() {
    let d = tempfile::tempdir().unwrap();
    let r = run_pipeline(d.path(), &fixture_las(), "[baseline]\nenabled = true\n");
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    let files: Vec<&str> = v["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap())
        .collect();
    // The tile outputs come first; the baseline adds its two files at the end.
    assert_eq!(
        files[files.len() - 2..],
        ["tin.ply", "baseline.json"],
        "{}",
        r.context()
    );
    assert!(files.contains(&"manifest.json"), "{}", r.context());
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.path().join("out/baseline.json")).unwrap())
            .unwrap();
    let mesh = terratile::mesh::io::read(&d.path().join("out/tin.ply")).unwrap();
    assert_eq!(
        mesh.vertex_count() as u64,
        report["vertices"].as_u64().unwrap()
    );
    assert_eq!(
        mesh.triangle_count() as u64,
        report["triangles"].as_u64().unwrap()
    );
    assert!(
        report["merged"].as_u64().unwrap() > 0,
        "the fixture's trees share positions"
    );
    assert_eq!(
        report["method"], "incremental",
        "the generator writes scan lines"
    );
    // Times and memory vary from run to run: the run summary has them, the report not.
    for key in ["build_s", "grid_s", "ratio"] {
        assert!(report.get(key).is_none(), "{key} in baseline.json");
        assert!(v["baseline"][key].as_f64().unwrap() > 0.0, "{key}");
    }
    // Grid and TIN of the same points agree closely over open terrain.
    let rmse = report["raster"]["rmse_m"].as_f64().unwrap();
    assert!(rmse > 0.0 && rmse < 2.0, "grid − TIN RMSE {rmse} m");
    assert!(report["holdout"].as_u64().unwrap() > 1000);
    let g = report["grid_accuracy"]["rmse"].as_f64().unwrap();
    let t = report["tin_accuracy"]["rmse"].as_f64().unwrap();
    assert!(
        g.is_finite() && t.is_finite() && g < 2.0 * t,
        "grid {g} m, TIN {t} m"
    );
    let stage = v["stages"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["stage"] == "baseline")
        .unwrap();
    assert!(stage["figures"].to_string().contains("triangles"));
}

#[test]
fn baseline_obj_and_no_holdout() {
    let d = tempfile::tempdir().unwrap();
    run_pipeline(
        d.path(),
        &fixture_las(),
        "[baseline]\nenabled = true\nmesh = \"surface/tin.obj\"\nholdout = 0\nmethod = \"bulk\"\n",
    )
    .ok();
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.path().join("out/baseline.json")).unwrap())
            .unwrap();
    assert!(report["grid_accuracy"].is_null());
    assert_eq!(report["method"], "bulk");
    let mesh = terratile::mesh::io::read(&d.path().join("out/surface/tin.obj")).unwrap();
    assert_eq!(
        mesh.triangle_count() as u64,
        report["triangles"].as_u64().unwrap()
    );
}

#[test]
fn baseline_glb_reads_back_and_grid_time_counts_the_tile_stages() {
    let d = tempfile::tempdir().unwrap();
    let r = run_pipeline(
        d.path(),
        &fixture_las(),
        "[baseline]\nenabled = true\nmesh = \"tin.glb\"\nholdout = 0\n",
    );
    r.ok();
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.path().join("out/baseline.json")).unwrap())
            .unwrap();
    let glb = std::fs::read(d.path().join("out/tin.glb")).unwrap();
    let g = gltf::Gltf::from_slice(&glb).unwrap();
    let prim = g.meshes().next().unwrap().primitives().next().unwrap();
    let reader = prim.reader(|_| g.blob.as_deref());
    let tris = reader.read_indices().unwrap().into_u32().count() / 3;
    assert_eq!(tris as u64, report["triangles"].as_u64().unwrap());
    assert_eq!(
        reader.read_positions().unwrap().count() as u64,
        report["vertices"].as_u64().unwrap()
    );
    // The baseline's grid time is the grid pipeline end to end: every stage from denoise to
    // the written tiles.
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    let grid_stages: f64 = v["stages"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|s| !matches!(s["stage"].as_str(), Some("read" | "baseline")))
        .map(|s| s["seconds"].as_f64().unwrap())
        .sum();
    let names: Vec<&str> = common::stage_names(&v);
    for stage in ["tiles", "quadtree", "write"] {
        assert!(names.contains(&stage), "{names:?}");
    }
    let grid_s = v["baseline"]["grid_s"].as_f64().unwrap();
    assert!(
        (grid_s - grid_stages).abs() <= 1e-6 * grid_stages.max(1.0),
        "{grid_s} vs {grid_stages}: {names:?}"
    );
}

#[test]
fn bad_baseline_parameters() {
    let d = tempfile::tempdir().unwrap();
    run_pipeline(
        d.path(),
        &fixture_las(),
        "[baseline]\nenabled = true\nholdout = 0.7\n",
    )
    .input_error(&["p.toml:7:1: baseline.holdout: 0.7:", "[0, 0.5)"]);
    run_pipeline(
        d.path(),
        &fixture_las(),
        "[baseline]\nenabled = true\nmesh = \"tin.stl\"\n",
    )
    .input_error(&["baseline.mesh: \"tin.stl\":", ".ply", ".obj", ".glb"]);
    run_pipeline(
        d.path(),
        &fixture_las(),
        "[baseline]\nenabled = true\nmethod = \"fast\"\n",
    )
    .input_error(&["baseline.method", "unknown variant"]);
    for (key, value) in [
        ("mesh", "../tin.ply"),
        ("report", "/tmp/baseline.json"),
        ("report", "a/../../b.json"),
    ] {
        run_pipeline(
            d.path(),
            &fixture_las(),
            &format!("[baseline]\nenabled = true\n{key} = \"{value}\"\n"),
        )
        .input_error(&[
            &format!("baseline.{key}: \"{value}\":"),
            "must be a relative path inside the output directory",
        ]);
    }
}

#[test]
fn delaunay_refuses_collinear_or_too_few_points_while_the_grid_works() {
    let d = tempfile::tempdir().unwrap();
    // 300 points on a diagonal line: a grid has area to cover, a triangulation has none.
    let line: Vec<(f64, f64, f64)> = (0..300)
        .map(|i| (500_000.0 + i as f64, 5_400_000.0 + i as f64, 200.0))
        .collect();
    // Two distinct positions, repeated: the grid still has its two cells.
    let two: Vec<(f64, f64, f64)> = (0..20)
        .map(|i| {
            if i % 2 == 0 {
                (10.0, 10.0, 5.0)
            } else {
                (40.0, 30.0, 7.0)
            }
        })
        .collect();
    for (name, pts, refusal) in [
        (
            "line.xyz",
            line,
            "delaunay: all 300 distinct points are collinear",
        ),
        (
            "two.xyz",
            two,
            "delaunay: 2 distinct point(s): a triangulation needs at least three",
        ),
    ] {
        write_xyz(d.path(), name, &pts);
        run_pipeline(d.path(), name, "").ok();
        std::fs::remove_dir_all(d.path().join("out")).unwrap();
        run_pipeline(d.path(), name, "[baseline]\nenabled = true\n").input_error(&[refusal]);
    }
}

#[test]
fn delaunay_is_valid_on_real_data() {
    // CSite4: first and last returns share x and y for a third of the points.
    let Some(p) = common::data_file("lidar/CSite4_orig-utm.laz") else {
        return;
    };
    let c = points::read(&p, &ReadOptions::default(), &NoProgress).unwrap();
    let pts = delaunay::prepare(&c.x, &c.y, &c.z, None).unwrap();
    assert!(pts.merged > 50_000, "{} merged", pts.merged);
    for m in [TinMethod::Bulk, TinMethod::Incremental] {
        let tin = delaunay::triangulate(&pts, m).unwrap();
        delaunay::validate(&pts, &tin, 200).unwrap_or_else(|e| panic!("{m:?}: {e}"));
    }
}

#[test]
fn table1_json_plot_and_skipped_counts() {
    let d = tempfile::tempdir().unwrap();
    let r = terratile(
        d.path(),
        &[
            "bench",
            "table1",
            &fixture_las(),
            "--counts",
            "2000,20000,99999999",
            "--repeat",
            "1",
            "--json",
            "--plot",
            "t1.png",
        ],
    );
    r.ok();
    assert!(
        r.stderr.contains("skipping 99999999 points") && r.stderr.contains("holds 55050"),
        "{}",
        r.context()
    );
    let rows: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), 2);
    for (row, n) in rows.iter().zip([2000, 20000]) {
        assert_eq!(row["points"], n);
        for key in ["grid_s", "delaunay_s", "ratio", "grid_rmse", "tin_rmse"] {
            let x = row[key].as_f64().unwrap_or_else(|| panic!("{key}: {row}"));
            assert!(x.is_finite() && x > 0.0, "{key} = {x}");
        }
        // The grid time is end to end: with one repetition, the sum of its six stages.
        let stages: f64 = [
            "denoise_s",
            "resample_s",
            "fill_s",
            "tiles_s",
            "quadtree_s",
            "write_s",
        ]
        .iter()
        .map(|k| row[k].as_f64().unwrap_or_else(|| panic!("{k}: {row}")))
        .sum();
        let grid_s = row["grid_s"].as_f64().unwrap();
        assert!((grid_s - stages).abs() <= 1e-9 * grid_s, "{row}");
        assert!(row["write_s"].as_f64().unwrap() > 0.0, "{row}");
        let ratio = row["delaunay_s"].as_f64().unwrap() / row["grid_s"].as_f64().unwrap();
        assert!((row["ratio"].as_f64().unwrap() - ratio).abs() < 1e-9 * ratio);
        // Memory comes from a fresh process per method (Linux /proc).
        if Path::new("/proc/self/status").exists() {
            assert!(row["delaunay_peak_mb"].as_f64().unwrap() > 0.0, "{row}");
            assert!(row["grid_peak_mb"].is_number(), "{row}");
        }
        assert!(row["triangles"].as_u64().unwrap() > n as u64);
    }
    let png = std::fs::read(d.path().join("t1.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    let img = image::load_from_memory(&png).unwrap();
    assert!(img.width() > 500 && img.height() > 300);
}

#[test]
fn table1_bad_counts() {
    let d = tempfile::tempdir().unwrap();
    let f = fixture_las();
    for (counts, needle) in [
        ("0", "0 is not a point count"),
        ("12,abc", "`abc` is not a point count"),
        ("1e5", "`1e5` is not a point count"),
    ] {
        let r = terratile(d.path(), &["bench", "table1", &f, "--counts", counts]);
        assert_eq!(r.code, 2, "{}", r.context());
        assert!(r.stderr.contains(needle), "{}", r.context());
    }
    terratile(
        d.path(),
        &["bench", "table1", &f, "--counts", "60000,70000"],
    )
    .input_error(&["holds 55050 points, fewer than every count asked for (60000, 70000)"]);
}
