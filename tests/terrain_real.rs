//! The terrain stages on every real tile in ../shared/data/lidar: noise removal with injected
//! outliers and with the real ones SOURCES.md names, the fast paths against their slow twins,
//! byte-identical results for 1, 2 and 8 threads, and the vertical accuracy of the grid and
//! of the Delaunay surface at held-out points. Run with `--nocapture` to see the tables.

use crate::common;

use std::path::Path;
use terratile::points::{self, PointCloud, ReadOptions};
use terratile::terrain::accuracy::{holdout, ErrorStats};
use terratile::terrain::delaunay::{self, TinMethod};
use terratile::terrain::reference;
use terratile::terrain::{
    denoise, fill, resample, DenoiseParams, FillParams, Heightfield, ResampleParams,
};
use terratile::NoProgress;
use terratile::SplitMix64;

fn name(p: &Path) -> String {
    p.file_name().unwrap().to_string_lossy().into_owned()
}

fn read(p: &Path, max_points: Option<u64>) -> PointCloud {
    let opts = ReadOptions {
        max_points,
        ..Default::default()
    };
    points::read(p, &opts, &NoProgress).unwrap()
}

/// Metres per horizontal unit. simple.las carries no CRS, but SOURCES.md says it is Autzen in
/// international feet, like the two other Autzen files (whose CRS says so).
fn metres_per_unit(p: &Path, c: &PointCloud) -> f64 {
    if name(p) == "simple.las" {
        0.3048
    } else {
        c.crs().map_or(1.0, |c| c.metres_per_unit())
    }
}

/// The real outliers SOURCES.md names: FSite5's 187 points at 615–899 m and its one point at
/// 124 m; CSite4's 52 lowest points (z ≤ 270.80, "below the 0.01 % quantile 270.8 m").
fn named_outliers(file: &str, c: &PointCloud) -> Vec<usize> {
    let pick = |f: &dyn Fn(f64) -> bool| (0..c.len()).filter(|&i| f(c.z[i])).collect::<Vec<_>>();
    if file.starts_with("FSite5") {
        let v = pick(&|z| !(130.0..=600.0).contains(&z));
        assert_eq!(v.len(), 188, "FSite5: 187 high points and one low one");
        v
    } else if file.starts_with("CSite4") {
        let mut idx: Vec<usize> = (0..c.len()).collect();
        idx.sort_by(|&a, &b| c.z[a].total_cmp(&c.z[b]));
        idx.truncate(52);
        assert!(c.z[idx[51]] <= 270.8 + 1e-9);
        idx
    } else {
        Vec::new()
    }
}

/// The cloud's coordinates with 1 % extra points uniform in the bounding box extended by
/// 50 m above and below (seeded); returns (x, y, z, genuine count).
fn inject(c: &PointCloud, mpu: f64, seed: u64) -> (Vec<f64>, Vec<f64>, Vec<f64>, usize) {
    let b = c.bounds();
    let e = 50.0 / mpu;
    let n = c.len();
    let extra = ((n as f64) * 0.01).round() as usize;
    let mut rng = SplitMix64::new(seed);
    let (mut x, mut y, mut z) = (c.x.clone(), c.y.clone(), c.z.clone());
    for _ in 0..extra {
        x.push(rng.range(b.min[0], b.max[0]));
        y.push(rng.range(b.min[1], b.max[1]));
        z.push(rng.range(b.min[2] - e, b.max[2] + e));
    }
    (x, y, z, n)
}

/// One file's noise figures with the default parameters.
#[derive(Debug)]
struct NoiseRow {
    file: String,
    points: usize,
    injected: usize,
    /// Share of the injected points removed, %.
    injected_removed: f64,
    /// Share of the injected points outside the data's z range removed, %.
    outside_removed: f64,
    /// Share of the genuine points removed with the injection, %.
    genuine_removed: f64,
    /// Share of the points removed from the file as it is, %.
    plain_removed: f64,
    named: usize,
    named_removed: usize,
    height_steps: u32,
}

fn noise_row(p: &Path) -> NoiseRow {
    let c = read(p, None);
    let file = name(p);
    let mpu = metres_per_unit(p, &c);
    let params = DenoiseParams::default();
    let plain = denoise(&c, &params, mpu).unwrap();
    let named = named_outliers(&file, &c);
    let named_removed = named.iter().filter(|&&i| !plain.keep[i]).count();
    let (x, y, z, n) = inject(&c, mpu, 42);
    let d = terratile::terrain::denoise::denoise_xyz(&x, &y, &z, &params, mpu).unwrap();
    let b = c.bounds();
    let outside: Vec<usize> = (n..x.len())
        .filter(|&i| z[i] < b.min[2] || z[i] > b.max[2])
        .collect();
    let pct = |k: usize, of: usize| 100.0 * k as f64 / of.max(1) as f64;
    NoiseRow {
        file,
        points: n,
        injected: x.len() - n,
        injected_removed: pct((n..x.len()).filter(|&i| !d.keep[i]).count(), x.len() - n),
        outside_removed: pct(
            outside.iter().filter(|&&i| !d.keep[i]).count(),
            outside.len(),
        ),
        genuine_removed: pct((0..n).filter(|&i| !d.keep[i]).count(), n),
        plain_removed: pct(plain.removed(), n),
        named: named.len(),
        named_removed,
        height_steps: d.settings.height_steps,
    }
}

fn print_noise(rows: &[NoiseRow]) {
    println!("| file | points | injected | injected removed | of them outside the z range | genuine removed (injected run) | removed from the file as is | named outliers removed | voxel height (spacings) |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for r in rows {
        println!(
            "| {} | {} | {} | {:.2} % | {:.2} % | {:.2} % | {:.2} % | {} / {} | {} |",
            r.file,
            r.points,
            r.injected,
            r.injected_removed,
            r.outside_removed,
            r.genuine_removed,
            r.plain_removed,
            r.named_removed,
            r.named,
            r.height_steps
        );
    }
}

/// What the defaults achieve on each tile, as floors for the injected points removed (the
/// measured figure rounded down to a whole percent). The issue asks for 99 % everywhere;
/// that is not reachable by any density test on these tiles (see docs/notes/terrain.md and
/// `noise_injection_issue_bound` below), so these floors guard against regressions while the
/// genuine-point and named-outlier bounds are the issue's own.
fn injected_floor(file: &str) -> Option<f64> {
    Some(match file {
        f if f.starts_with("CSite4") => 97.0,
        f if f.starts_with("FSite5") => 98.0,
        "autzen_trim.las" => 96.0,
        "autzen_full.laz" => 97.0,
        "Topography.laz" => 91.0,
        "bcts_3.laz" => 91.0,
        // 1,065 points 37 m apart: no density test can tell 11 injected points from the
        // data (see the notes); only the genuine-side bounds apply.
        "simple.las" => return None,
        _ => 90.0,
    })
}

#[test]
fn noise_on_real_tiles() {
    let files = common::lidar_files();
    let rows: Vec<NoiseRow> = files.iter().map(|p| noise_row(p)).collect();
    print_noise(&rows);
    for r in &rows {
        assert!(
            r.genuine_removed <= 1.0,
            "{}: {:.2} % of the genuine points removed",
            r.file,
            r.genuine_removed
        );
        assert!(
            r.plain_removed <= 1.0,
            "{}: {:.2} % of the file removed",
            r.file,
            r.plain_removed
        );
        assert_eq!(r.named_removed, r.named, "{}: named outliers kept", r.file);
        if let Some(floor) = injected_floor(&r.file) {
            assert!(
                r.outside_removed >= 99.0,
                "{}: {:.2} % of the injected points outside the data's z range removed",
                r.file,
                r.outside_removed
            );
            assert!(
                r.injected_removed >= floor,
                "{}: {:.2} % of the injected points removed, below {floor} %",
                r.file,
                r.injected_removed
            );
        }
    }
}

/// The issue's acceptance as written: ≥ 99 % of the injected points and ≤ 1 % of the genuine
/// ones removed on every tile. It fails on every tile: the injected points that land inside
/// the vegetation and building volume are as dense there as the genuine points (an oracle
/// k-nearest-neighbour test removes at most 98.6 % of them on autzen_trim and 98.3 % on CSite4
/// at 1 % genuine loss; see docs/notes/terrain.md). Kept, unweakened, as the record of the gap (README: Known gaps).
#[test]
#[ignore = "not reachable by a density test on these tiles: see docs/notes/terrain.md; run with --ignored"]
fn noise_injection_issue_bound() {
    let rows: Vec<NoiseRow> = common::lidar_files().iter().map(|p| noise_row(p)).collect();
    print_noise(&rows);
    let failing: Vec<&NoiseRow> = rows
        .iter()
        .filter(|r| r.injected_removed < 99.0 || r.genuine_removed > 1.0)
        .collect();
    assert!(
        failing.is_empty(),
        "below the issue's bound: {:?}",
        failing.iter().map(|r| &r.file).collect::<Vec<_>>()
    );
}

/// Fast paths equal their slow twins on every real tile (the first 200,000 points of the big
/// ones, to keep the HashMap twin quick; CSite4, whose low layers exercise every rule, whole).
#[test]
fn fast_paths_equal_reference_on_real_tiles() {
    for p in common::lidar_files() {
        let file = name(&p);
        if file == "autzen_full.laz" {
            continue; // the same survey as autzen_trim, too big for the HashMap twin
        }
        let cap = if file.starts_with("CSite4") {
            None
        } else {
            Some(200_000)
        };
        let c = read(&p, cap);
        let mpu = metres_per_unit(&p, &c);
        let params = DenoiseParams::default();
        let d = denoise(&c, &params, mpu).unwrap();
        let slow = reference::denoise(&c.x, &c.y, &c.z, &params, mpu).unwrap();
        assert!(d.keep == slow, "{file}: denoise differs from its twin");
        for method in ["mean", "min", "max"] {
            let rp: ResampleParams = toml::from_str(&format!("method = \"{method}\"")).unwrap();
            let fast = resample(&c, Some(&d.keep), &rp).unwrap().grid;
            let slow = reference::resample(&c, Some(&d.keep), &rp).unwrap();
            assert!(
                reference::same_grid(&fast, &slow),
                "{file}: resample {method} differs"
            );
        }
        let grid = resample(&c, Some(&d.keep), &ResampleParams::default())
            .unwrap()
            .grid;
        for fallback in ["smooth", "mean", "nodata"] {
            let fp: FillParams =
                toml::from_str(&format!("fallback = \"{fallback}\"\nradius = 4")).unwrap();
            let mut fast = grid.clone();
            fill(&mut fast, &fp).unwrap();
            let slow = reference::fill(&grid, &fp).unwrap();
            assert!(
                reference::same_grid(&fast, &slow),
                "{file}: fill {fallback} differs"
            );
        }
    }
}

fn stages(c: &PointCloud, mpu: f64) -> (Vec<bool>, Heightfield) {
    let d = denoise(c, &DenoiseParams::default(), mpu).unwrap();
    let mut g = resample(c, Some(&d.keep), &ResampleParams::default())
        .unwrap()
        .grid;
    fill(&mut g, &FillParams::default()).unwrap();
    (d.keep, g)
}

#[test]
fn same_bytes_for_1_2_and_8_threads_on_real_data() {
    let Some(p) = common::data_file("lidar/CSite4_orig-utm.laz") else {
        return;
    };
    let c = read(&p, None);
    let run = |t: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
            .install(|| stages(&c, 1.0))
    };
    let (k1, g1) = run(1);
    for t in [2, 8] {
        let (k, g) = run(t);
        assert!(k == k1, "{t} threads: noise flags differ");
        assert!(reference::same_grid(&g, &g1), "{t} threads: grid differs");
    }
}

/// One tile's accuracy: the grid and the TIN built from 98 % of the denoised points, scored
/// at the other 2 % (seeded), in metres.
struct AccuracyRow {
    file: String,
    grid: [usize; 2],
    grid_all: ErrorStats,
    tin_all: ErrorStats,
    grid_ground: Option<ErrorStats>,
    tin_ground: Option<ErrorStats>,
}

fn accuracy_row(p: &Path) -> AccuracyRow {
    let c = read(p, None);
    let mpu = metres_per_unit(p, &c);
    let d = denoise(&c, &DenoiseParams::default(), mpu).unwrap();
    let (train, test) = holdout(c.len(), Some(&d.keep), 0.02, 2026);
    let mut g = resample(&c, Some(&train), &ResampleParams::default()).unwrap();
    fill(&mut g.grid, &FillParams::default()).unwrap();
    let tin_points = delaunay::prepare(&c.x, &c.y, &c.z, Some(&train)).unwrap();
    let tin = delaunay::triangulate(&tin_points, TinMethod::Incremental).unwrap();
    let s = delaunay::score_holdout(&c, &test, &g.grid, &tin, mpu);
    AccuracyRow {
        file: name(p),
        grid: [g.spec.cols, g.spec.rows],
        grid_all: s.grid,
        tin_all: s.tin,
        grid_ground: s.grid_ground,
        tin_ground: s.tin_ground,
    }
}

fn cell(s: &Option<ErrorStats>) -> String {
    s.map_or("—".into(), |s| format!("{:.3} / {:.3}", s.rmse, s.p95))
}

/// The accuracy table of the notes. The grid has about one point per cell, so it smooths what
/// the TIN reproduces point by point; its RMSE stays within twice the TIN's on every tile.
#[test]
fn accuracy_on_real_tiles() {
    println!("| file | grid | held out | grid RMSE / P95, all (m) | TIN RMSE / P95, all (m) | grid RMSE / P95, ground (m) | TIN RMSE / P95, ground (m) |");
    println!("| --- | --- | ---: | ---: | ---: | ---: | ---: |");
    for p in common::lidar_files() {
        if name(&p) == "autzen_full.laz" {
            continue; // 10.6 M points: see accuracy_on_autzen_full
        }
        let r = accuracy_row(&p);
        print_accuracy(&r);
        check_accuracy(&r);
    }
}

fn print_accuracy(r: &AccuracyRow) {
    println!(
        "| {} | {} × {} | {} | {} | {} | {} | {} |",
        r.file,
        r.grid[0],
        r.grid[1],
        r.grid_all.n + r.grid_all.missing,
        cell(&Some(r.grid_all)),
        cell(&Some(r.tin_all)),
        cell(&r.grid_ground),
        cell(&r.tin_ground)
    );
}

fn check_accuracy(r: &AccuracyRow) {
    assert!(
        r.grid_all.rmse.is_finite() && r.tin_all.rmse.is_finite(),
        "{}",
        r.file
    );
    // Held-out points fall inside the grid unless they lie beyond the training points' box.
    assert!(
        r.grid_all.missing * 100 <= r.grid_all.n.max(100),
        "{}: {} held-out points off the grid",
        r.file,
        r.grid_all.missing
    );
    assert!(
        r.grid_all.rmse <= 2.0 * r.tin_all.rmse,
        "{}: grid RMSE {:.3} m vs TIN {:.3} m",
        r.file,
        r.grid_all.rmse,
        r.tin_all.rmse
    );
}

/// The same on autzen_full (10.65 M points; about a minute): `cargo test --release --test
/// tests -- --ignored terrain_real::accuracy_on_autzen_full --nocapture`.
#[test]
#[ignore = "10.65 M points, about a minute; run with --ignored"]
fn accuracy_on_autzen_full() {
    let Some(p) = common::data_file("lidar/autzen_full.laz") else {
        return;
    };
    let r = accuracy_row(&p);
    print_accuracy(&r);
    check_accuracy(&r);
}
