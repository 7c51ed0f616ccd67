//! Ground classification on real data: the ISPRS filter-test reference samples (labelled by
//! hand: class 2 ground, 0 object) scored against their labels, and the vendor-classified
//! files against the vendor's class 2. The scores are computed here from the labels and the
//! classifier's output, not by the classifier. Run with `--nocapture` to see the tables.

use crate::common;

use std::path::{Path, PathBuf};
use std::time::Instant;
use terratile::points::{self, PointCloud, ReadOptions};
use terratile::terrain::ground::{classify, GroundParams, Scores};
use terratile::NoProgress;

const SAMPLES: [&str; 8] = [
    "samp11", "samp12", "samp21", "samp31", "samp41", "samp51", "samp53", "samp61",
];

fn read(p: &Path) -> PointCloud {
    points::read(p, &ReadOptions::default(), &NoProgress).unwrap()
}

fn isprs(s: &str) -> Option<PathBuf> {
    common::data_file(&format!("lidar/isprs/{s}-utm.laz"))
}

/// Our scores on one labelled file, and the seconds the classification took.
fn score(p: &Path) -> (Scores, f64) {
    let c = read(p);
    let mpu = c.crs().map_or(1.0, |c| c.metres_per_unit());
    let t = Instant::now();
    let g = classify(&c.x, &c.y, &c.z, None, &GroundParams::default(), mpu).unwrap();
    let secs = t.elapsed().as_secs_f64();
    let truth: Vec<bool> = c.classification.iter().map(|&k| k == 2).collect();
    (Scores::of(&g.ground, &truth), secs)
}

/// Mean kappa and total error over the eight samples, one default parameter set. The bars
/// are what the defaults reach today (mean kappa 84.8 %, total error 4.10 %), so that a
/// change that makes them worse fails; the target (kappa ≥ 88 %) is not reached yet.
#[test]
fn isprs_scores() {
    let mut rows = Vec::new();
    for s in SAMPLES {
        let Some(p) = isprs(s) else { return };
        let (sc, secs) = score(&p);
        println!(
            "{s}  type I {:5.2} %  type II {:5.2} %  total {:5.2} %  kappa {:5.2} %  {:.3} s",
            100.0 * sc.type1,
            100.0 * sc.type2,
            100.0 * sc.total,
            100.0 * sc.kappa,
            secs
        );
        rows.push(sc);
    }
    let n = rows.len() as f64;
    let kappa = rows.iter().map(|s| s.kappa).sum::<f64>() / n;
    let total = rows.iter().map(|s| s.total).sum::<f64>() / n;
    println!(
        "mean  kappa {:.2} %  total {:.2} %",
        100.0 * kappa,
        100.0 * total
    );
    assert!(kappa >= 0.845, "mean kappa {kappa}");
    assert!(total <= 0.045, "mean total error {total}");
}

/// `terratile classify` writes the input's records in order with only the class changed,
/// and refuses bad requests with one line, exit 2 and no output.
#[test]
fn classify_cli() {
    let dir = common::default_job();
    let d = dir.path();
    let las = "fixtures/survey-0-0.las";
    if !d.join(las).exists() {
        let names: Vec<_> = common::walk(&d.join("fixtures"));
        panic!("fixture names changed: {names:?}");
    }
    let r = common::terratile(d, &["classify", las, "out.las", "--json"]);
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    assert!(v["ground"].as_u64().unwrap() > 0, "{v}");
    let a = read(&d.join(las));
    let b = read(&d.join("out.las"));
    assert_eq!((a.x.len(), &a.x, &a.y, &a.z), (b.x.len(), &b.x, &b.y, &b.z));
    assert_eq!(a.intensity, b.intensity);
    assert_eq!(a.return_number, b.return_number);
    let ground = b.classification.iter().filter(|&&c| c == 2).count();
    assert_eq!(ground as u64, v["ground"].as_u64().unwrap());
    assert!(b.classification.iter().all(|&c| c == 1 || c == 2));
    // Same file in and out; an existing output; a compressed name; XYZ input with an
    // output; a slope of 0 and NaN; scoring a file without class 2.
    common::terratile(d, &["classify", las, las]).input_error(&["the input file"]);
    common::terratile(d, &["classify", las, "out.las"]).input_error(&["already exists"]);
    common::terratile(d, &["classify", las, "x.laz"])
        .input_error(&["uncompressed LAS"])
        .left_nothing("x.laz");
    let xyz = common::walk(&d.join("fixtures"))
        .into_iter()
        .find(|p| p.extension().is_some_and(|e| e == "xyz"))
        .unwrap();
    let xyz = xyz.to_string_lossy().into_owned();
    common::terratile(d, &["classify", &xyz, "x.las"])
        .input_error(&["no classification field"])
        .left_nothing("x.las");
    for s in ["--slope=0", "--slope=NaN", "--slope=-1"] {
        common::terratile(d, &["classify", las, "x.las", s])
            .input_error(&["slope"])
            .left_nothing("x.las");
    }
    common::terratile(d, &["classify", "out.las", "--score"]).ok();
    std::fs::write(d.join("flat.xyz"), "0 0 1\n1 0 1\n0 1 1\n").unwrap();
    common::terratile(d, &["classify", "flat.xyz", "--score"]).input_error(&["no class 2"]);
}

/// A survey that is all objects: no ground can be found, a clear error.
#[test]
fn no_ground_found() {
    let x: Vec<f64> = vec![0.0; 10];
    let y: Vec<f64> = vec![0.0; 10];
    let z: Vec<f64> = vec![f64::NAN; 10];
    let r = classify(&x, &y, &z, None, &GroundParams::default(), 1.0);
    assert!(r.is_err());
    let e = classify(&[], &[], &[], None, &GroundParams::default(), 1.0).unwrap_err();
    assert!(e.to_string().contains("no points"), "{e}");
}

/// `pipeline` (the default job's file, which lists `[ground]` off) with the stage on and
/// the line `from` of its table replaced by `to`.
fn ground_on(pipeline: &str, from: &str, to: &str) -> String {
    let at = pipeline
        .find("[ground]")
        .expect("pipeline.toml has a [ground] table");
    let (head, table) = pipeline.split_at(at);
    let table = table
        .replacen("enabled = false", "enabled = true", 1)
        .replacen(from, to, 1);
    format!("{head}{table}")
}

/// `[ground]` in a pipeline: the stage runs between denoise and resample, writes
/// `classified.las` when asked, and refuses `write_classified` on XYZ input (exit 2, the
/// output directory not created).
#[test]
fn pipeline_ground_stage() {
    let dir = common::default_job();
    let d = dir.path();
    let base = std::fs::read_to_string(d.join("pipeline.toml")).unwrap();
    let with = |paths: &str, out: &str| {
        let mut s = base.replace("dir = \"out\"", &format!("dir = \"{out}\""));
        if !paths.is_empty() {
            s = s.replace(
                "paths = [\"fixtures/*.las\", \"fixtures/*.xyz\"]",
                &format!("paths = [{paths}]"),
            );
        }
        ground_on(&s, "write_classified = false", "write_classified = true")
    };
    std::fs::write(d.join("las.toml"), with("\"fixtures/*.las\"", "out_las")).unwrap();
    let r = common::terratile(d, &["run", "las.toml", "--json"]);
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    let names = common::stage_names(&v);
    let at = |n: &str| names.iter().position(|s| *s == n).unwrap();
    assert!(
        at("denoise") < at("ground") && at("ground") < at("resample"),
        "{names:?}"
    );
    let c = read(&d.join("out_las/classified.las"));
    let src = read(&d.join("fixtures/survey-0-0.las"));
    assert_eq!(c.x, src.x);
    assert!(c.classification.contains(&2) && c.classification.contains(&1));
    std::fs::write(d.join("both.toml"), with("", "out_both")).unwrap();
    common::terratile(d, &["run", "both.toml"])
        .input_error(&["ground.write_classified", "no classification field"])
        .left_nothing("out_both");
    std::fs::write(
        d.join("bad.toml"),
        ground_on(
            &base.replace("dir = \"out\"", "dir = \"out_bad\""),
            "# window = 18.0",
            "window = -3",
        ),
    )
    .unwrap();
    common::terratile(d, &["run", "bad.toml"])
        .input_error(&["ground", "window"])
        .left_nothing("out_bad");
}
