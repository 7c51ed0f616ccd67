//! The sharded terrain run against the in-memory one on every real tile in
//! ../shared/data/lidar: noise removal by windows of low-layer columns, the grid from the
//! kept points' reduction, tile blocks resampled, filled, tiled and merged, bit for bit
//! equal to the in-memory stages (keep flags, tile heights, d2, vertical error, fill
//! figures). autzen_full (10.6 M points) is `#[ignore]`d: run it with `--ignored`.

use crate::common;

use std::path::Path;
use terratile::points::{self, ReadOptions};
use terratile::shard::points::{run_points, Stages};
use terratile::shard::Merged;
use terratile::terrain::quadtree::{self, QuadtreeParams};
use terratile::terrain::tiles::{self, TileParams};
use terratile::terrain::{denoise, resample, DenoiseParams, FillParams};
use terratile::NoProgress;

fn check(p: &Path, configs: &[(u64, [usize; 2])]) {
    let c = points::read(p, &ReadOptions::default(), &NoProgress).unwrap();
    let name = p.file_name().unwrap().to_string_lossy().into_owned();
    // simple.las carries no CRS; SOURCES.md says international feet.
    let mpu = if name == "simple.las" {
        0.3048
    } else {
        c.crs().map_or(1.0, |c| c.metres_per_unit())
    };
    let stages = Stages {
        denoise: Some(DenoiseParams::default()),
        metres_per_unit: mpu,
        resample: Default::default(),
        fill: Some(FillParams::default()),
        tiles: TileParams {
            size: Some(129),
            ..Default::default()
        },
        quadtree: QuadtreeParams::default(),
    };
    // The in-memory stages (the pipeline runs them through buffer-reusing twins that their
    // unit tests hold to the same bits). simple.las has no CRS: its low gap is given in feet.
    let mut dp = DenoiseParams::default();
    if name == "simple.las" {
        dp.low_gap = Some(10.0 / mpu);
    }
    let st = Stages {
        denoise: Some(dp.clone()),
        ..stages
    };
    let t = std::time::Instant::now();
    let d = denoise(&c, &dp, mpu).unwrap();
    let mut hf = resample(&c, Some(&d.keep), &st.resample).unwrap().grid;
    let report = terratile::terrain::fill(&mut hf, st.fill.as_ref().unwrap()).unwrap();
    let set = tiles::tile(&hf, &st.tiles).unwrap();
    let want = Merged {
        quadtree: quadtree::build(&set, &st.quadtree).unwrap(),
        vertical_error: quadtree::vertical_error(&set),
        fill: Some(report),
        set,
    };
    let whole_s = t.elapsed().as_secs_f64();
    let keep = d.keep;
    for &(groups, block) in configs {
        let t = std::time::Instant::now();
        let got = run_points(&c.x, &c.y, &c.z, c.crs().cloned(), &st, groups, block).unwrap();
        let sharded_s = t.elapsed().as_secs_f64();
        assert!(
            got.keep.as_ref() == Some(&keep),
            "{name}: keep flags differ ({groups}, {block:?})"
        );
        assert_eq!(
            got.merged.difference(&want),
            None,
            "{name} ({groups}, {block:?})"
        );
        println!(
            "{name}: {} points, {}×{} tiles, denoise windows of {groups} low-layer columns, \
             blocks of {block:?} tiles: identical; in memory {whole_s:.2} s, sharded in one \
             process {sharded_s:.2} s ({:.2}×)",
            c.len(),
            want.set.grid[0],
            want.set.grid[1],
            sharded_s / whole_s
        );
    }
}

#[test]
fn real_tiles_shard_the_same() {
    for p in common::lidar_files() {
        if p.file_name().is_some_and(|n| n == "autzen_full.laz") {
            continue;
        }
        check(&p, &[(1, [1, 1]), (3, [2, 1])]);
    }
}

#[test]
#[ignore = "10.6 M points: a minute or more"]
fn autzen_full_shards_the_same() {
    if let Some(p) = common::data_file("lidar/autzen_full.laz") {
        check(&p, &[(4, [4, 4]), (16, [13, 13])]);
    }
}
