//! The CLI on the terrain stages: `run` with `[denoise]`, `[resample]` and `[fill]`, the
//! removed-noise file, `bench terrain`, and every bad input issue 3 lists — each one clear
//! line naming the stage (or key), parameter and value, exit code 2, and no output.

use crate::common;

use common::{terratile, write_xyz, Run};
use std::path::Path;
use terratile::points::{self, ReadOptions};
use terratile::NoProgress;

/// A pipeline over the fixture LAS tile with `extra` appended, run.
fn run_with(dir: &Path, extra: &str) -> Run {
    common::run_pipeline(dir, &common::fixture_las(), extra)
}

/// Each bad stage value: one line naming the key (and its line) or the stage, nothing
/// written.
#[test]
fn bad_stage_parameters() {
    const RADIUS: &str = "must be a positive number of cells";
    let cases: &[(&str, &[&str])] = &[
        (
            "[fill]\nradius = 0\n",
            &["p.toml:6:1: fill.radius:", "0", RADIUS],
        ),
        (
            "[fill]\nradius = -2.5\n",
            &["p.toml:6:1: fill.radius:", "-2.5", RADIUS],
        ),
        (
            "[fill]\nradius = nan\n",
            &["p.toml:6:1: fill.radius:", "NaN", RADIUS],
        ),
        (
            "[denoise]\nvoxel_size = 0\n",
            &["p.toml:6:1: denoise.voxel_size:", "0", "must be a positive"],
        ),
        (
            "[denoise]\nvoxel_size = -1\n",
            &[
                "p.toml:6:1: denoise.voxel_size:",
                "-1",
                "must be a positive",
            ],
        ),
        (
            "[denoise]\nvoxel_size = nan\n",
            &[
                "p.toml:6:1: denoise.voxel_size:",
                "NaN",
                "must be a positive",
            ],
        ),
        (
            "[denoise]\nvoxel_height = 0.0\n",
            &[
                "p.toml:6:1: denoise.voxel_height:",
                "0",
                "must be a positive",
            ],
        ),
        (
            "[denoise]\nvoxel_height = nan\n",
            &[
                "p.toml:6:1: denoise.voxel_height:",
                "NaN",
                "must be a positive",
            ],
        ),
        (
            "[resample]\nsize = [0, 100]\n",
            &[
                "p.toml:6:1: resample.size:",
                "[0, 100]",
                "at least one cell",
            ],
        ),
        ("[resample]\ncell_size = 0\n", &["resample.cell_size:", "0"]),
        ("[resample]\nsize = [10, -1]\n", &["resample.size"]),
        (
            "[denoise]\nmin_points = 100000000\n",
            &[
                "denoise: every one of the 55050 points was removed as noise",
                "min_points 100000000",
            ],
        ),
    ];
    let d = tempfile::tempdir().unwrap();
    for (extra, needles) in cases {
        run_with(d.path(), extra).input_error(needles);
    }
}

fn run_file(dir: &Path, file: &str, extra: &str) -> Run {
    std::fs::write(
        dir.join("p.toml"),
        format!("[input]\npaths = [\"{file}\"]\n{extra}"),
    )
    .unwrap();
    let r = common::run_p_toml(dir);
    r.left_nothing("out");
    r
}

#[test]
fn points_on_one_line_or_one_spot() {
    let d = tempfile::tempdir().unwrap();
    let line: Vec<(f64, f64, f64)> = (0..200)
        .map(|i| (500_000.0 + i as f64, 5_400_000.0, 300.0))
        .collect();
    write_xyz(d.path(), "line.xyz", &line);
    run_file(d.path(), "line.xyz", "").input_error(&[
        "p.toml:1:1: denoise.voxel_size: auto:",
        "zero-width range",
        "one line or one spot",
    ]);
    // Without noise removal the grid is what refuses it.
    run_file(d.path(), "line.xyz", "[denoise]\nenabled = false\n")
        .input_error(&["resample: y range = 0:", "all 200 points share y = 5400000"]);
    let spot: Vec<(f64, f64, f64)> = (0..50).map(|i| (7.5, 2.5, i as f64)).collect();
    write_xyz(d.path(), "spot.xyz", &spot);
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
    assert_eq!(figure(1, "points in"), "55050");
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
    assert_eq!(v["points"], 55050);
    assert!(v["tin_triangles"].as_u64().unwrap() > 100_000);
    // CPU times: with one run, the steps add up to the total; a step's serial part (the
    // calling thread's clock) is part of it; the idle estimate lies between the CPU time
    // spread over the threads and the CPU time.
    let f = |k: &str| {
        v[k].as_f64()
            .unwrap_or_else(|| panic!("{k}\n{}", r.context()))
    };
    let cpu: Vec<f64> = serde_json::from_value(v["stage_cpu_s"].clone()).unwrap();
    let serial: Vec<f64> = serde_json::from_value(v["stage_serial_cpu_s"].clone()).unwrap();
    assert_eq!((cpu.len(), serial.len()), (7, 7));
    let total_cpu = f("total_cpu_s");
    assert!(total_cpu > 0.0 && (cpu.iter().sum::<f64>() - total_cpu).abs() < 1e-9);
    for (c, s) in cpu.iter().zip(&serial) {
        assert!(*s >= 0.0 && *s <= c + 1e-3, "serial {s} of a step of {c} s");
    }
    let threads = f("threads");
    let idle = f("idle_estimate_s");
    assert!(idle >= total_cpu / threads - 1e-9 && idle <= total_cpu + 1e-3);
    let delaunay: Vec<f64> = serde_json::from_value(v["delaunay_cpu_s"].clone()).unwrap();
    let faster = delaunay[0].min(delaunay[1]);
    assert!(faster > 0.0);
    assert!((f("total_cpu_ratio") - faster / total_cpu).abs() < 1e-9 * faster / total_cpu);
    assert!((f("idle_ratio_estimate") - faster / idle).abs() < 1e-9 * faster / idle);
}
