//! Ground classification on real data: the ISPRS filter-test reference samples (labelled by
//! hand: class 2 ground, 0 object) scored against their labels, and the vendor-classified
//! files against the vendor's class 2. The scores are computed here from the labels and the
//! classifier's output, not by the classifier. Run with `--nocapture` to see the tables.

mod common;

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
/// are what the defaults reach today (mean kappa 83.8 %, total error 4.47 %), so that a
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
    assert!(kappa >= 0.835, "mean kappa {kappa}");
    assert!(total <= 0.05, "mean total error {total}");
}
