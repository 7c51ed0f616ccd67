//! Readers against las-rs: every real tile, every LAS version and point format, LAZ, class
//! filter and cap, thread-count independence, and the generator's round trip.

use crate::common;

use std::path::Path;
use terratile::points::{self, ClassFilter, Format, PointCloud, ReadOptions};
use terratile::NoProgress;

/// Reads with las-rs: every point's x, y, z, class, returns and intensity.
fn read_las_rs(path: &Path) -> PointCloud {
    let mut r = las::Reader::from_path(path).unwrap();
    let data = r.read_all().unwrap();
    let mut c = PointCloud::default();
    for p in data.points() {
        let p = p.unwrap();
        c.x.push(p.x);
        c.y.push(p.y);
        c.z.push(p.z);
        c.classification.push(u8::from(p.classification));
        c.return_number.push(p.return_number);
        c.number_of_returns.push(p.number_of_returns);
        c.intensity.push(p.intensity);
    }
    c
}

fn assert_same_points(ours: &PointCloud, reference: &PointCloud, what: &str) {
    assert_eq!(ours.len(), reference.len(), "{what}: point count");
    for i in 0..ours.len() {
        assert!(
            ours.x[i].to_bits() == reference.x[i].to_bits()
                && ours.y[i].to_bits() == reference.y[i].to_bits()
                && ours.z[i].to_bits() == reference.z[i].to_bits(),
            "{what}: point {i}: ours ({}, {}, {}) las-rs ({}, {}, {})",
            ours.x[i],
            ours.y[i],
            ours.z[i],
            reference.x[i],
            reference.y[i],
            reference.z[i]
        );
    }
    assert_eq!(
        ours.classification, reference.classification,
        "{what}: classes"
    );
    assert_eq!(
        ours.return_number, reference.return_number,
        "{what}: return numbers"
    );
    assert_eq!(
        ours.number_of_returns, reference.number_of_returns,
        "{what}: number of returns"
    );
    assert_eq!(ours.intensity, reference.intensity, "{what}: intensity");
}

#[test]
fn every_real_tile_matches_las_rs_and_its_header() {
    let files = common::lidar_files();
    if files.is_empty() {
        return;
    }
    for f in &files {
        let ours = points::read(f, &ReadOptions::default(), &NoProgress).unwrap();
        let reference = read_las_rs(f);
        assert_same_points(&ours, &reference, &f.display().to_string());

        let h = las::Reader::from_path(f).unwrap().header().clone();
        assert_eq!(
            ours.len() as u64,
            h.number_of_points(),
            "{}: header count",
            f.display()
        );
        let src = &ours.sources[0];
        assert_eq!(src.points_in_file, h.number_of_points());
        let hb = h.bounds();
        let b = ours.bounds();
        let t = h.transforms();
        let scale = [t.x.scale, t.y.scale, t.z.scale];
        let (hmin, hmax) = (
            [hb.min.x, hb.min.y, hb.min.z],
            [hb.max.x, hb.max.y, hb.max.z],
        );
        for k in 0..3 {
            assert!(
                (b.min[k] - hmin[k]).abs() <= scale[k] && (b.max[k] - hmax[k]).abs() <= scale[k],
                "{}: axis {k}: points span {}..{}, header says {}..{}",
                f.display(),
                b.min[k],
                b.max[k],
                hmin[k],
                hmax[k]
            );
        }
        let expected = if f.extension().is_some_and(|e| e == "laz") {
            Format::Laz
        } else {
            Format::Las
        };
        assert_eq!(src.format, expected);
    }
}

#[test]
fn point_cloud_costs_at_most_30_bytes_per_point() {
    for rel in ["lidar/autzen_trim.las", "lidar/bcts_3.laz"] {
        let Some(f) = common::data_file(rel) else {
            return;
        };
        let c = points::read(&f, &ReadOptions::default(), &NoProgress).unwrap();
        let per_point = c.heap_bytes() as f64 / c.len() as f64;
        assert!(per_point <= 30.0, "{rel}: {per_point} bytes per point");
        assert_eq!(
            c.heap_bytes(),
            29 * c.len(),
            "{rel}: columns are allocated exactly"
        );
    }
}

/// `got` holds exactly the points `want` of `all`, in that order.
fn assert_selection(got: &PointCloud, all: &PointCloud, want: &[usize]) {
    assert_eq!(got.len(), want.len());
    assert!(want
        .iter()
        .enumerate()
        .all(|(k, &i)| { got.x[k] == all.x[i] && got.y[k] == all.y[i] && got.z[k] == all.z[i] }));
}

#[test]
fn class_filter_and_cap_match_a_plain_filter() {
    let Some(f) = common::data_file("lidar/autzen_trim.las") else {
        return;
    };
    let all = read_las_rs(&f);
    let opts = ReadOptions {
        classes: ClassFilter::new(Some(&[2]), &[]),
        ..Default::default()
    };
    let ground = points::read(&f, &opts, &NoProgress).unwrap();
    let want: Vec<usize> = (0..all.len())
        .filter(|&i| all.classification[i] == 2)
        .collect();
    assert_selection(&ground, &all, &want);

    let capped = ReadOptions {
        classes: ClassFilter::new(None, &[1]),
        max_points: Some(1000),
        ..Default::default()
    };
    let c = points::read(&f, &capped, &NoProgress).unwrap();
    assert_eq!(c.len(), 1000);
    assert!(c.classification.iter().all(|&k| k != 1));
    assert_eq!(c.x[999], all.x[want[999]]);
}

#[test]
fn laz_cap_and_filter_cross_batches() {
    let Some(f) = common::data_file("lidar/bcts_3.laz") else {
        return;
    };
    let all = points::read(&f, &ReadOptions::default(), &NoProgress).unwrap();
    let opts = ReadOptions {
        classes: ClassFilter::new(Some(&[2]), &[]),
        max_points: Some(30_000),
        ..Default::default()
    };
    let c = points::read(&f, &opts, &NoProgress).unwrap();
    let want: Vec<usize> = (0..all.len())
        .filter(|&i| all.classification[i] == 2)
        .take(30_000)
        .collect();
    assert_selection(&c, &all, &want);
}

#[test]
fn reading_does_not_depend_on_thread_count() {
    let Some(f) = common::data_file("lidar/CSite4_orig-utm.laz") else {
        return;
    };
    let read_with = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
            .install(|| points::read(&f, &ReadOptions::default(), &NoProgress).unwrap())
    };
    let one = read_with(1);
    for n in [2, 8] {
        let other = read_with(n);
        assert_same_points(&other, &one, &format!("{n} threads"));
    }
}

/// Writes `n` points in `version`/`format` with las-rs (optionally LAZ-compressed).
fn write_with_las_rs(path: &Path, version: (u8, u8), format: u8, compressed: bool, n: usize) {
    let mut b = las::Builder::from(version);
    let mut fmt = las::point::Format::new(format).unwrap();
    fmt.is_compressed = compressed;
    b.point_format = fmt;
    b.transforms = las::Vector {
        x: las::Transform {
            scale: 0.001,
            offset: 500_000.0,
        },
        y: las::Transform {
            scale: 0.001,
            offset: 5_000_000.0,
        },
        z: las::Transform {
            scale: 0.01,
            offset: 0.0,
        },
    };
    let header = b.into_header().unwrap();
    let mut w = las::Writer::from_path(path, header).unwrap();
    let max_ret = if format >= 6 {
        15
    } else if version.1 >= 4 {
        7
    } else {
        5
    };
    let max_class = if format >= 6 { 255 } else { 31 };
    let mut rng = terratile::SplitMix64::new(format as u64 * 31 + version.1 as u64);
    for i in 0..n {
        let nret = 1 + rng.below(max_ret) as u8;
        let class = loop {
            let c = rng.below(max_class + 1) as u8;
            // las-rs refuses to write class 12 (overlap), which it models as a flag.
            if c != 12 {
                break c;
            }
        };
        let mut p = las::Point {
            x: 500_000.0 + rng.range(0.0, 1000.0),
            y: 5_000_000.0 + rng.range(0.0, 1000.0),
            z: rng.range(-50.0, 3000.0),
            intensity: rng.below(65536) as u16,
            return_number: 1 + rng.below(nret as u64) as u8,
            number_of_returns: nret,
            classification: las::point::Classification::new(class).unwrap(),
            ..Default::default()
        };
        if fmt.has_gps_time {
            p.gps_time = Some(i as f64);
        }
        if fmt.has_color {
            p.color = Some(las::Color::new(1, 2, 3));
        }
        if fmt.has_nir {
            p.nir = Some(7);
        }
        if fmt.has_waveform {
            p.waveform = Some(las::raw::point::Waveform::default());
        }
        w.write_point(p).unwrap();
    }
    w.close().unwrap();
}

macro_rules! version_format_tests {
    ($($name:ident: $ver:expr, $fmt:expr, $laz:expr;)*) => {$(
        #[test]
        fn $name() {
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join(if $laz { "p.laz" } else { "p.las" });
            write_with_las_rs(&path, $ver, $fmt, $laz, 70_001);
            let ours = points::read(&path, &ReadOptions::default(), &NoProgress).unwrap();
            assert_same_points(&ours, &read_las_rs(&path), stringify!($name));
            let s = &ours.sources[0];
            assert_eq!(s.version, Some($ver));
            assert_eq!(s.point_format, Some($fmt));
            assert_eq!(s.format, if $laz { Format::Laz } else { Format::Las });
        }
    )*};
}

version_format_tests! {
    las_1_0_pf0: (1, 0), 0, false;
    las_1_0_pf1: (1, 0), 1, false;
    las_1_1_pf1: (1, 1), 1, false;
    las_1_2_pf2: (1, 2), 2, false;
    las_1_2_pf3: (1, 2), 3, false;
    las_1_3_pf4: (1, 3), 4, false;
    las_1_3_pf5: (1, 3), 5, false;
    las_1_4_pf0: (1, 4), 0, false;
    las_1_4_pf6: (1, 4), 6, false;
    las_1_4_pf7: (1, 4), 7, false;
    las_1_4_pf8: (1, 4), 8, false;
    las_1_4_pf9: (1, 4), 9, false;
    las_1_4_pf10: (1, 4), 10, false;
    laz_1_2_pf1: (1, 2), 1, true;
    laz_1_2_pf3: (1, 2), 3, true;
    laz_1_4_pf6: (1, 4), 6, true;
    laz_1_4_pf7: (1, 4), 7, true;
    laz_1_4_pf8: (1, 4), 8, true;
}

#[test]
fn generated_las_and_xyz_read_back_exactly() {
    use terratile::generate::{write_survey, GenerateParams, OutFormat, Survey};
    let dir = tempfile::tempdir().unwrap();
    let survey = Survey::new(
        &GenerateParams {
            seed: 3,
            points: 20_000,
            ..Default::default()
        },
        (2, 1),
    )
    .unwrap();
    let mut written = Vec::new();
    let counts = write_survey(
        &survey,
        &dir.path().join("s.las"),
        &[OutFormat::Las, OutFormat::Xyz],
        |p, c| written.push((p.to_path_buf(), c.clone())),
    )
    .unwrap();
    assert_eq!(written.len(), 2);
    assert_eq!(counts.len(), 2);
    let total: usize = written.iter().map(|(_, c)| c.len()).sum();
    assert_eq!(total, 20_000);
    for (path, expected) in &written {
        let back = points::read(path, &ReadOptions::default(), &NoProgress).unwrap();
        assert_eq!(back.len(), expected.len(), "{}", path.display());
        assert!(back
            .x
            .iter()
            .zip(&expected.x)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
        assert!(back
            .y
            .iter()
            .zip(&expected.y)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
        assert!(back
            .z
            .iter()
            .zip(&expected.z)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
        assert_eq!(back.classification, expected.classification);
        assert_eq!(back.return_number, expected.return_number);
        assert_eq!(back.intensity, expected.intensity);
    }
    // The LAS tile carries the scene's CRS.
    let las = points::read(&written[0].0, &ReadOptions::default(), &NoProgress).unwrap();
    assert_eq!(las.crs().unwrap().epsg, Some(32632));
}

#[test]
fn generator_is_deterministic_and_has_the_scene_features() {
    use terratile::generate::{generate, GenerateParams};
    let p = GenerateParams {
        seed: 9,
        points: 50_000,
        ..Default::default()
    };
    let a = generate(&p).unwrap();
    let b = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| generate(&p).unwrap());
    assert_eq!(a.cloud.x, b.cloud.x);
    assert_eq!(a.cloud.z, b.cloud.z);
    let h = points::Histogram::of(&a.cloud.classification);
    assert!(h.get(2) > 30_000, "mostly ground: {h:?}");
    assert!(h.get(5) > 500, "trees: {h:?}");
    assert!(h.get(6) > 500, "buildings: {h:?}");
    let multi = a.cloud.number_of_returns.iter().filter(|&&n| n > 1).count();
    assert!(multi > 500, "trees give several returns");
    assert_eq!(a.outliers.len(), 3, "60 per million of 50 000");
    let ground_med = {
        let mut z: Vec<f64> = a.cloud.z.clone();
        z.sort_by(f64::total_cmp);
        z[z.len() / 2]
    };
    for &i in &a.outliers {
        assert!((a.cloud.z[i as usize] - ground_med).abs() > 10.0);
    }
}

/// The bounds the reader measures while decoding are the cloud's own (every real tile, with a
/// class filter and a cap crossing LAZ batches too), and XYZ's are measured after the parse.
#[test]
fn bounds_measured_while_reading_are_the_clouds() {
    let filtered = ReadOptions {
        classes: ClassFilter::new(None, &[1]),
        max_points: Some(1_500_000),
        ..Default::default()
    };
    let mut files = common::lidar_files();
    files.push(common::repo().join("fixtures/survey-1-0.xyz"));
    files.push(common::repo().join("fixtures/survey-0-0.las"));
    for f in &files {
        for opts in [&ReadOptions::default(), &filtered] {
            let (c, b) = points::read_with_bounds(f, opts, &NoProgress).unwrap();
            let want = c.bounds();
            for k in 0..3 {
                assert!(
                    b.min[k].to_bits() == want.min[k].to_bits()
                        && b.max[k].to_bits() == want.max[k].to_bits(),
                    "{}: axis {k}: {b:?} vs {want:?}",
                    f.display()
                );
            }
        }
    }
}

/// The bounds `read_all_with_bounds` gathers file by file (what `terratile run` hands to its
/// memory estimate, its read report and noise removal) are those of the whole cloud it
/// returns: LAS and XYZ together, and with a cap that ends inside the second file and leaves
/// the third empty.
#[test]
fn bounds_of_several_files_are_the_whole_clouds() {
    let files = [
        common::repo().join("fixtures/survey-0-0.las"),
        common::repo().join("fixtures/survey-1-0.xyz"),
        common::repo().join("fixtures/survey-0-0.las"),
    ];
    let first = points::read(&files[0], &ReadOptions::default(), &NoProgress)
        .unwrap()
        .len() as u64;
    for cap in [None, Some(first + 7)] {
        let opts = ReadOptions {
            max_points: cap,
            ..Default::default()
        };
        let (c, b) = points::read_all_with_bounds(&files, &opts, &NoProgress).unwrap();
        let all = points::read_all(&files, &opts, &NoProgress).unwrap();
        assert_eq!(c.len(), all.len(), "cap {cap:?}");
        assert_eq!(cap.map_or(c.len() as u64, |_| first + 7), c.len() as u64);
        let want = all.bounds();
        for k in 0..3 {
            assert!(
                b.min[k].to_bits() == want.min[k].to_bits()
                    && b.max[k].to_bits() == want.max[k].to_bits(),
                "cap {cap:?}: axis {k}: {b:?} vs {want:?}"
            );
        }
    }
}
