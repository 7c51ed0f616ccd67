//! The CLI on the terrain stages: `run` with `[denoise]`, `[resample]` and `[fill]`, the
//! removed-noise file, `bench terrain`, and every bad input issue 3 lists — each one clear
//! line naming the stage (or key), parameter and value, exit code 2, and no output.

use crate::common;

use common::{terratile, Run};
use std::path::Path;
use terratile::points::{self, ReadOptions};
use terratile::NoProgress;

/// A pipeline over the fixture LAS tile with `extra` appended; runs it and checks that a
/// failing run leaves no output directory.
fn run_with(dir: &Path, extra: &str) -> Run {
    let job = common::repo().join("fixtures/survey-0-0.las");
    let text = format!(
        "[input]\npaths = [\"{}\"]\n[output]\ndir = \"out\"\n{extra}",
        job.display()
    );
    std::fs::write(dir.join("p.toml"), text).unwrap();
    let r = terratile(dir, &["run", "-q", "--json", "p.toml"]);
    if r.code != 0 {
        r.left_nothing("out");
    }
    r
}

#[test]
fn radius_zero_negative_or_nan() {
    let d = tempfile::tempdir().unwrap();
    for (v, shown) in [("0", "0"), ("-2.5", "-2.5"), ("nan", "NaN")] {
        run_with(d.path(), &format!("[fill]\nradius = {v}\n")).input_error(&[
            "p.toml:6:1: fill.radius:",
            shown,
            "must be a positive number of cells",
        ]);
    }
}

#[test]
fn voxel_size_zero_negative_or_nan() {
    let d = tempfile::tempdir().unwrap();
    for (key, v, shown) in [
        ("voxel_size", "0", "0"),
        ("voxel_size", "-1", "-1"),
        ("voxel_size", "nan", "NaN"),
        ("voxel_height", "0.0", "0"),
        ("voxel_height", "nan", "NaN"),
    ] {
        run_with(d.path(), &format!("[denoise]\n{key} = {v}\n")).input_error(&[
            &format!("p.toml:6:1: denoise.{key}:"),
            shown,
            "must be a positive",
        ]);
    }
}

#[test]
fn grid_override_of_zero_cells() {
    let d = tempfile::tempdir().unwrap();
    run_with(d.path(), "[resample]\nsize = [0, 100]\n").input_error(&[
        "p.toml:6:1: resample.size:",
        "[0, 100]",
        "at least one cell",
    ]);
    run_with(d.path(), "[resample]\ncell_size = 0\n").input_error(&["resample.cell_size:", "0"]);
    run_with(d.path(), "[resample]\nsize = [10, -1]\n").input_error(&["resample.size"]);
}

#[test]
fn every_point_removed_as_noise() {
    let d = tempfile::tempdir().unwrap();
    run_with(d.path(), "[denoise]\nmin_points = 100000000\n").input_error(&[
        "denoise: every one of the 55057 points was removed as noise",
        "min_points 100000000",
    ]);
}

fn xyz(dir: &Path, name: &str, pts: &[(f64, f64, f64)]) {
    let mut s = String::from("x y z\n");
    for (x, y, z) in pts {
        s.push_str(&format!("{x} {y} {z}\n"));
    }
    std::fs::write(dir.join(name), s).unwrap();
}

fn run_file(dir: &Path, file: &str, extra: &str) -> Run {
    std::fs::write(
        dir.join("p.toml"),
        format!("[input]\npaths = [\"{file}\"]\n{extra}"),
    )
    .unwrap();
    let r = terratile(dir, &["run", "-q", "p.toml"]);
    r.left_nothing("out");
    r
}

#[test]
fn points_on_one_line_or_one_spot() {
    let d = tempfile::tempdir().unwrap();
    let line: Vec<(f64, f64, f64)> = (0..200)
        .map(|i| (500_000.0 + i as f64, 5_400_000.0, 300.0))
        .collect();
    xyz(d.path(), "line.xyz", &line);
    run_file(d.path(), "line.xyz", "").input_error(&[
        "p.toml:1:1: denoise.voxel_size: auto:",
        "zero-width range",
        "one line or one spot",
    ]);
    // Without noise removal the grid is what refuses it.
    run_file(d.path(), "line.xyz", "[denoise]\nenabled = false\n")
        .input_error(&["resample: y range = 0:", "all 200 points share y = 5400000"]);
    let spot: Vec<(f64, f64, f64)> = (0..50).map(|i| (7.5, 2.5, i as f64)).collect();
    xyz(d.path(), "spot.xyz", &spot);
    run_file(d.path(), "spot.xyz", "[denoise]\nenabled = false\n")
        .input_error(&["resample: x range = 0:", "x = 7.5"]);
    run_file(d.path(), "spot.xyz", "")
        .input_error(&["p.toml:1:1: denoise.voxel_size: auto:", "zero-width"]);
}

#[test]
fn run_reports_every_stage_and_writes_the_removed_points() {
    let d = tempfile::tempdir().unwrap();
    let r = run_with(d.path(), "[denoise]\nwrite_removed = true\n");
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    let stages: Vec<&str> = common::stage_names(&v);
    assert_eq!(
        stages,
        ["read", "denoise", "resample", "fill", "tiles", "quadtree", "extract", "write"],
        "{}",
        r.context()
    );
    let figure = |stage: usize, key: &str| -> String {
        v["stages"][stage]["figures"]
            .as_array()
            .unwrap()
            .iter()
            .find(|f| f[0] == key)
            .unwrap_or_else(|| panic!("no `{key}` in stage {stage}\n{}", r.context()))[1]
            .as_str()
            .unwrap()
            .to_string()
    };
    let removed: usize = figure(1, "removed").parse().unwrap();
    assert!(removed > 0, "the fixture has outliers\n{}", r.context());
    assert_eq!(figure(1, "points in"), "55057");
    assert!(figure(2, "grid").contains(" × "));
    let filled: usize = figure(3, "interpolated").parse().unwrap();
    assert!(filled > 0);
    assert_eq!(v["files"][0], "noise.las");
    let noise = points::read(
        &d.path().join("out/noise.las"),
        &ReadOptions::default(),
        &NoProgress,
    )
    .unwrap();
    assert_eq!(noise.len(), removed);
    assert!(noise.classification.iter().all(|&c| c == 7));
    assert_eq!(noise.crs().and_then(|c| c.epsg), Some(32632));
}

#[test]
fn bench_terrain_json() {
    let d = tempfile::tempdir().unwrap();
    let las = common::repo().join("fixtures/survey-0-0.las");
    let r = terratile(
        d.path(),
        &[
            "bench",
            "terrain",
            "--repeat",
            "1",
            "--json",
            las.to_str().unwrap(),
        ],
    );
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    for key in [
        "read_s",
        "denoise_s",
        "resample_s",
        "fill_s",
        "stages_s",
        "delaunay_bulk_s",
        "delaunay_incremental_s",
        "stages_ratio",
        "quadtree_s",
        "write_s",
        "total_s",
        "total_ratio",
    ] {
        let x = v[key]
            .as_f64()
            .unwrap_or_else(|| panic!("{key}\n{}", r.context()));
        assert!(x.is_finite() && x > 0.0, "{key} = {x}");
    }
    let ratio = v["delaunay_s"].as_f64().unwrap() / v["stages_s"].as_f64().unwrap();
    assert!((v["stages_ratio"].as_f64().unwrap() - ratio).abs() < 1e-9 * ratio);
    // The whole pipeline: the grid stages and read, then tiles, quadtree and writing.
    let total = v["total_s"].as_f64().unwrap();
    assert!(total > v["stages_s"].as_f64().unwrap() + v["read_s"].as_f64().unwrap() * 0.5);
    let ratio = v["delaunay_s"].as_f64().unwrap() / total;
    assert!((v["total_ratio"].as_f64().unwrap() - ratio).abs() < 1e-9 * ratio);
    assert!(v["written_bytes"].as_u64().unwrap() > 0);
    assert_eq!(v["exr_compression"], "none");
    assert_eq!(v["points"], 55057);
    assert!(v["tin_triangles"].as_u64().unwrap() > 100_000);
}
