//! The Cloud-Optimized GeoTIFF of a whole grid (issue 17's figure: autzen_full's 3253² grid
//! with overviews in at most 0.5 s on 2 cores): `output::georef::dem_geotiff` (gathering the
//! grid north row first, the overviews, the predictor and DEFLATE of every tile, the file
//! layout) against the reference measured in the same run, encoding the same grid's
//! uncompressed EXR tiles.
//!
//! `cargo bench --bench geotiff`; without the shared data it says it skips.

mod common;

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use terratile::output::georef::dem_geotiff;
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
    let mut g = c.benchmark_group("geotiff_autzen_full");
    g.sample_size(10);
    common::exr_tiles_reference(&mut g, &set, &qt);
    g.bench_function("dem_geotiff", |b| {
        b.iter(|| black_box(dem_geotiff(&set).expect("geotiff")))
    });
    g.finish();
}

criterion_group!(benches, geotiff);
criterion_main!(benches);
