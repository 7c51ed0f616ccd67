//! Ground classification on real data: the ISPRS filter-test reference samples (labelled by
//! hand: class 2 ground, 0 object) scored against their labels, and the vendor-classified
//! files against the vendor's class 2. The scores are computed here from the labels and the
//! classifier's output, not by the classifier. Run with `--nocapture` to see the tables.

use crate::common;

use std::path::{Path, PathBuf};
use std::time::Instant;
use terratile::points::{self, Bounds, PointCloud, ReadOptions};
use terratile::terrain::ground::{classify, GroundParams, Scores};
use terratile::terrain::resample::{resample_window, GridSpec};
use terratile::terrain::{CellMethod, Fallback, FillParams, ResampleParams};
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

/// Our ground flags on one labelled file, the seconds the classification took, and the
/// file's labels (class 2: ground).
fn ours(c: &PointCloud) -> (Vec<bool>, f64, Vec<bool>) {
    let mpu = c.crs().map_or(1.0, |c| c.metres_per_unit());
    // The best of five runs: a classification takes milliseconds, so one run on the shared
    // machine measures the scheduler as much as the work (CSF's seconds-long run less so).
    let (mut g, mut secs) = (None, f64::INFINITY);
    for _ in 0..5 {
        let t = Instant::now();
        g = Some(classify(&c.x, &c.y, &c.z, None, &GroundParams::default(), mpu).unwrap());
        secs = secs.min(t.elapsed().as_secs_f64());
    }
    let g = g.unwrap();
    let truth: Vec<bool> = c.classification.iter().map(|&k| k == 2).collect();
    (g.ground, secs, truth)
}

/// The DTM of the points flagged in `ground`: the default grid of the whole sample (√N × √N
/// over all its points' bounds, cell means), its holes filled as the pipeline fills a DTM
/// (`fallback = "membrane"`). Both DTMs of a sample share the grid.
fn dtm(c: &PointCloud, ground: &[bool]) -> Vec<f32> {
    let mut b = Bounds::EMPTY;
    for k in 0..c.len() {
        b = b.union(Bounds {
            min: [c.x[k], c.y[k], c.z[k]],
            max: [c.x[k], c.y[k], c.z[k]],
        });
    }
    let spec = GridSpec::new(&ResampleParams::default(), &b, c.len()).unwrap();
    let mut hf = resample_window(
        [&c.x, &c.y, &c.z],
        Some(ground),
        &spec,
        [0..spec.cols, 0..spec.rows],
        CellMethod::Mean,
        None,
    );
    let fill_dtm = FillParams {
        fallback: Fallback::Membrane,
        ..Default::default()
    };
    terratile::terrain::fill(&mut hf, &fill_dtm).unwrap();
    hf.heights.iter().copied().collect()
}

/// RMSE and 95th percentile of |difference| in metres between the DTM of our ground points
/// and that of the reference ground points.
fn dtm_errors(c: &PointCloud, ours: &[bool], truth: &[bool]) -> (f64, f64) {
    let mpu = c.crs().map_or(1.0, |c| c.metres_per_unit());
    let (a, b) = (dtm(c, ours), dtm(c, truth));
    let mut d: Vec<f64> = a
        .iter()
        .zip(&b)
        .map(|(p, q)| (*p as f64 - *q as f64).abs() * mpu)
        .collect();
    assert!(d.iter().all(|x| x.is_finite()), "a DTM kept a hole");
    let rmse = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
    d.sort_by(f64::total_cmp);
    let p95 = d[((d.len() - 1) as f64 * 0.95).round() as usize];
    (rmse, p95)
}

/// The sample whose CSF run fits the default suite (6 s here; CSF took 39 s on samp11, 28 s
/// on samp12 and 22 s on samp61); the ignored `isprs_scores_all_csf` runs CSF on all eight.
const CSF_CHEAP: [&str; 1] = ["samp21"];

/// The pip package `cloth-simulation-filter` (Zhang et al. 2016) with its defaults on one
/// sample: its ground flags and the seconds of its `setPointCloud` + `do_filtering`
/// (measured inside Python: the interpreter's start and the file transfer are not counted,
/// as ours excludes reading the file). The best of up to five runs, as ours is the best of
/// five: runs stop once they have taken 2 s in all, so a sample CSF takes seconds on runs
/// once (its first run's extra costs are then a small share of its time).
fn csf(py: &Path, c: &PointCloud) -> (Vec<bool>, f64) {
    let dir = tempfile::tempdir().unwrap();
    let mut xyz = Vec::with_capacity(c.len() * 24);
    for k in 0..c.len() {
        for v in [c.x[k], c.y[k], c.z[k]] {
            xyz.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::write(dir.path().join("xyz.f64"), xyz).unwrap();
    let out = std::process::Command::new(py)
        .current_dir(dir.path())
        .args(["-c", CSF_SCRIPT, "xyz.f64", "ground.u8"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "CSF failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let secs: f64 = stdout
        .lines()
        .filter_map(|l| l.strip_prefix("seconds "))
        .next_back()
        .and_then(|v| v.trim().parse().ok())
        .expect("CSF printed its time");
    let flags = std::fs::read(dir.path().join("ground.u8")).unwrap();
    assert_eq!(flags.len(), c.len());
    (flags.iter().map(|&f| f == 1).collect(), secs)
}

/// Runs CSF with the package's defaults (cloth resolution 1, rigidness 3, threshold 0.5,
/// slope post-processing on, 500 iterations, time step 0.65); the cloth is not exported.
const CSF_SCRIPT: &str = r#"
import sys, time
import numpy as np
import CSF
xyz = np.fromfile(sys.argv[1], dtype="<f8").reshape(-1, 3)
secs, spent = float("inf"), 0.0
for _ in range(5):
    t = time.perf_counter()
    csf = CSF.CSF()
    csf.setPointCloud(xyz)
    ground, other = CSF.VecInt(), CSF.VecInt()
    csf.do_filtering(ground, other, False)
    run = time.perf_counter() - t
    secs, spent = min(secs, run), spent + run
    if spent > 2.0:
        break
flags = np.zeros(len(xyz), dtype=np.uint8)
flags[np.array(list(ground), dtype=np.int64)] = 1
flags.tofile(sys.argv[2])
print("seconds", secs)
"#;

fn row(name: &str, sc: &Scores, secs: f64, dtm: Option<(f64, f64)>) -> String {
    let dtm = dtm.map_or(String::new(), |(r, p)| format!(" | {r:8.3} | {p:8.3}"));
    format!(
        "| {name:<14} | {:6.2} | {:6.2} | {:6.2} | {:6.2} | {secs:8.3}{dtm} |",
        100.0 * sc.type1,
        100.0 * sc.type2,
        100.0 * sc.total,
        100.0 * sc.kappa,
    )
}

/// Scores ours (and CSF on `csf_on`) on the eight samples, prints the table (type I, type II,
/// total, kappa in %, seconds; DTM RMSE and 95th percentile in metres for ours) and returns
/// our scores, and CSF's per sample with both times.
fn isprs_table(csf_on: &[&str]) -> Vec<Scores> {
    let py = common::python_venv(
        "csf",
        &["cloth-simulation-filter", "numpy"],
        "cloth-simulation-filter",
    );
    println!(
        "| sample         | type I | type II | total | kappa | seconds | DTM RMSE m | DTM p95 m |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let (mut rows, mut theirs, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
    for s in SAMPLES {
        let Some(p) = isprs(s) else { return rows };
        let c = read(&p);
        let (g, secs, truth) = ours(&c);
        let sc = Scores::of(&g, &truth);
        println!("{}", row(s, &sc, secs, Some(dtm_errors(&c, &g, &truth))));
        if let (Some(py), true) = (&py, csf_on.contains(&s)) {
            let (cg, csecs) = csf(py, &c);
            let csc = Scores::of(&cg, &truth);
            let dtm = dtm_errors(&c, &cg, &truth);
            println!("{}", row(&format!("{s} CSF"), &csc, csecs, Some(dtm)));
            theirs.push(csc);
            ratios.push((csecs, secs));
        }
        rows.push(sc);
    }
    let mean = |v: &[Scores], f: fn(&Scores) -> f64| v.iter().map(f).sum::<f64>() / v.len() as f64;
    println!(
        "ours: mean kappa {:.2} %, total {:.2} %",
        100.0 * mean(&rows, |s| s.kappa),
        100.0 * mean(&rows, |s| s.total)
    );
    if !theirs.is_empty() {
        let (c, o) = ratios
            .iter()
            .fold((0.0, 0.0), |a, r| (a.0 + r.0, a.1 + r.1));
        let worst = ratios
            .iter()
            .map(|r| r.0 / r.1)
            .fold(f64::INFINITY, f64::min);
        println!(
            "CSF on {} samples: mean kappa {:.2} %, total {:.2} %; CSF {c:.2} s vs ours {o:.3} s: {:.0}× (slowest ratio of a sample {worst:.0}×)",
            theirs.len(),
            100.0 * mean(&theirs, |s| s.kappa),
            100.0 * mean(&theirs, |s| s.total),
            c / o
        );
    }
    rows
}

/// Mean kappa and total error over the eight samples, one default parameter set, beside
/// CSF on the samples where it is quick (the table and the speed ratio are printed; run
/// with `--nocapture`). The bars are the issue's target (mean kappa ≥ 88 %, total error
/// ≤ 5 %) and what the defaults reach today (88.07 %, 3.30 %), so that a change that makes
/// them worse fails.
#[test]
fn isprs_scores() {
    let rows = isprs_table(&CSF_CHEAP);
    if rows.len() < SAMPLES.len() {
        return;
    }
    let n = rows.len() as f64;
    let kappa = rows.iter().map(|s| s.kappa).sum::<f64>() / n;
    let total = rows.iter().map(|s| s.total).sum::<f64>() / n;
    assert!(kappa >= 0.88, "mean kappa {kappa}");
    assert!(total <= 0.034, "mean total error {total}");
}

/// [`isprs_scores`] with CSF on all eight samples (minutes: CSF takes tens of seconds on the
/// large ones).
#[test]
#[ignore]
fn isprs_scores_all_csf() {
    isprs_table(&SAMPLES);
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
    for (key, s) in [
        ("gap_fill", "--gap-fill=-1"),
        ("support_radius", "--support-radius=NaN"),
        ("support_tolerance", "--support-tolerance=-0.1"),
        ("support_slope", "--support-slope=inf"),
        ("plane_radius", "--plane-radius=-1"),
        ("plane_threshold", "--plane-threshold=NaN"),
        ("plane_rms", "--plane-rms=-2"),
        ("plane_slope", "--plane-slope=inf"),
        ("edge_reach", "--edge-reach=1.5"),
    ] {
        common::terratile(d, &["classify", las, "x.las", s])
            .input_error(&[key])
            .left_nothing("x.las");
    }
    // The refinement keys take effect on a sparse survey with crests (samp61; the dense
    // fixture has neither gaps nor crests for them to give back).
    if let Some(p) = isprs("samp61") {
        let p = p.to_string_lossy().into_owned();
        let count = |extra: &[&str]| -> u64 {
            let mut args = vec!["classify", &p, "--json"];
            args.extend_from_slice(extra);
            let r = common::terratile(d, &args);
            r.ok();
            let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
            v["ground"].as_u64().unwrap()
        };
        let default = count(&[]);
        assert_ne!(
            count(&["--gap-fill=0"]),
            default,
            "gap_fill changes nothing"
        );
        assert_ne!(
            count(&["--support-radius=0"]),
            default,
            "support_radius changes nothing"
        );
        assert_ne!(
            count(&["--support-tolerance=5"]),
            default,
            "support_tolerance changes nothing"
        );
        for key in [
            "--plane-radius=0",
            "--plane-threshold=1",
            "--plane-rms=0",
            "--plane-slope=2",
            "--plane-rounds=1",
            "--edge-reach=1",
        ] {
            assert_ne!(count(&[key]), default, "{key} changes nothing");
        }
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

/// `terratile classify IN.laz OUT.las` writes the records it kept from its one decode of the
/// LAZ: the same bytes as the writer that decodes the input again (the path a LAS input, a
/// filtered read or several sources still take).
#[test]
fn classify_laz_writes_the_records_of_its_one_decode() {
    for s in ["samp21", "samp41"] {
        let Some(p) = isprs(s) else { return };
        let dir = tempfile::tempdir().unwrap();
        let ours = dir.path().join("ours.las");
        let r = common::terratile(
            dir.path(),
            &["classify", &p.to_string_lossy(), &ours.to_string_lossy()],
        );
        r.ok();
        let opts = ReadOptions::default();
        let c = points::read(&p, &opts, &NoProgress).unwrap();
        let (g, _) = terratile::classify::ground_of(&c, None, &GroundParams::default()).unwrap();
        let twice = dir.path().join("twice.las");
        terratile::classify::write_classified(&twice, &c, &opts, &g).unwrap();
        assert!(
            std::fs::read(&ours).unwrap() == std::fs::read(&twice).unwrap(),
            "{s}: the one-decode output differs from the re-decoding writer's"
        );
        // Kept only when every record becomes a point.
        let (k, raw) = points::read_keeping_records(&p, &opts, &NoProgress).unwrap();
        let raw = raw.expect("a plain LAZ read keeps its records");
        assert_eq!((&k.x, &k.z), (&c.x, &c.z));
        assert_eq!(
            raw.records.len(),
            c.len() * raw.header.record_length as usize
        );
        let filtered = ReadOptions {
            classes: points::ClassFilter::new(Some(&[2]), &[]),
            ..Default::default()
        };
        let (_, raw) = points::read_keeping_records(&p, &filtered, &NoProgress).unwrap();
        assert!(raw.is_none(), "a filtered read keeps no records");
    }
}
