//! The Cloud-Optimized GeoTIFF of a whole grid (issue 17's figure: autzen_full's 3253² grid
//! with overviews in at most 0.5 s on 2 cores): `output::georef::dem_geotiff` (gathering the
//! grid north row first, the overviews, the predictor and DEFLATE of every tile, the file
//! layout) against the reference measured in the same run, encoding the same grid's
//! uncompressed EXR tiles.
//!
//! Also the Cesium quantized-mesh tileset of the same grid ([`quantized_mesh`]).
//!
//! `cargo bench --bench geotiff`; without the shared data it says it skips.

mod common;

use criterion::{criterion_group, criterion_main, Criterion};
use rayon::prelude::*;
use std::hint::black_box;
use terratile::geo::tms::tileset;
use terratile::output::georef::dem_geotiff;
use terratile::output::qmesh::encode_tile;
use terratile::terrain::quadtree::{build, QuadtreeParams};

fn geotiff(c: &mut Criterion) {
    // The pipeline's defaults: noise removal on, 257-sample tiles (3253 × 3253 samples).
    let Some(set) = common::real_set("autzen_full.laz", 257, true) else {
        return;
    };
    let qt = build(&set, &QuadtreeParams::default()).expect("d2");
    let bytes = dem_geotiff(&set).expect("geotiff").len();
    eprintln!(
        "geotiff: {} × {} samples, {:.2} MB ({:.2} bytes/sample), {} rayon threads",
        set.samples[0],
        set.samples[1],
        bytes as f64 / 1e6,
        bytes as f64 / (set.samples[0] * set.samples[1]) as f64,
        rayon::current_num_threads()
    );
    // Five encodings, CPU and wall time per encoding (the wall times below the other
    // processes of a shared machine can inflate).
    per_run("geotiff", "encoding", 5, || {
        black_box(dem_geotiff(&set).expect("geotiff"));
    });
    let mut g = c.benchmark_group("geotiff_autzen_full");
    g.sample_size(10);
    common::exr_tiles_reference(&mut g, &set, &qt);
    g.bench_function("dem_geotiff", |b| {
        b.iter(|| black_box(dem_geotiff(&set).expect("geotiff")))
    });
    g.finish();
}

/// Runs `f` `n` times and prints its CPU time (process user + system time, Linux), which the
/// other processes of a shared machine cannot inflate, and its wall time, per run.
fn per_run(name: &str, what: &str, n: u32, mut f: impl FnMut()) {
    let Some(t0) = cpu_seconds() else { return };
    let wall = std::time::Instant::now();
    for _ in 0..n {
        f();
    }
    if let Some(t1) = cpu_seconds() {
        eprintln!(
            "{name}: {:.3} CPU-s and {:.3} s of wall time per {what}",
            (t1 - t0) / f64::from(n),
            wall.elapsed().as_secs_f64() / f64::from(n)
        );
    }
}

/// This process's user + system CPU time in seconds, from /proc/self/stat (clock ticks of
/// 10 ms, the kernel's USER_HZ); None elsewhere.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may hold spaces) in parentheses: utime and stime
    // are the 12th and 13th.
    let rest = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// The Cesium tileset of the same grid (issue 17's figure: autzen_full's quantized-mesh
/// tileset in at most 2 s on 2 cores): `geo::tms::tileset` (the coarser levels' lattices,
/// heights, error trees, meshes and normals; the most detailed level's adaptive
/// triangulations of the grid) and `output::qmesh::encode_tile` of every tile (quantisation
/// and gzip), in memory: the files' creation is the file system's (measured apart in the
/// README).
fn quantized_mesh(c: &mut Criterion) {
    let Some(set) = common::real_set("autzen_full.laz", 257, true) else {
        return;
    };
    let qt = build(&set, &QuadtreeParams::default()).expect("d2");
    let tileset_and_tiles = || {
        let ts = tileset(&set, 0.5).expect("tileset");
        let bytes: usize = ts.tiles.par_iter().map(|t| encode_tile(t).len()).sum();
        (ts.tiles.len(), bytes)
    };
    let (tiles, bytes) = tileset_and_tiles();
    eprintln!(
        "quantized_mesh: {tiles} tiles, {:.2} MB, {} rayon threads",
        bytes as f64 / 1e6,
        rayon::current_num_threads()
    );
    per_run("quantized_mesh", "tileset", 3, || {
        black_box(tileset_and_tiles());
    });
    let mut g = c.benchmark_group("quantized_mesh_autzen_full");
    g.sample_size(10);
    common::exr_tiles_reference(&mut g, &set, &qt);
    g.bench_function("tileset_and_tiles", |b| {
        b.iter(|| black_box(tileset_and_tiles()))
    });
    g.finish();
}

criterion_group!(benches, geotiff, quantized_mesh);
criterion_main!(benches);
