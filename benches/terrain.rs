//! Terrain stage benchmarks (issue 3): denoise, resample and fill on a generated survey of the
//! paper's largest size (3,408,187 points), and each fast path beside its slow twin
//! (`terrain::reference`) on 200,000 points. The targets are ratios measured in one
//! process by `terratile bench terrain` (Delaunay time / stages time ≥ 10).
//!
//! `TERRATILE_BENCH_LAS=path` benchmarks that file instead of the generated survey.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use terratile::generate::{generate, GenerateParams};
use terratile::points::{self, PointCloud, ReadOptions};
use terratile::terrain::{
    denoise, fill, reference, resample, DenoiseParams, FillParams, Heightfield, ResampleParams,
};
use terratile::NoProgress;

fn survey(points: u64) -> PointCloud {
    if let Some(p) = std::env::var_os("TERRATILE_BENCH_LAS") {
        let opts = ReadOptions {
            max_points: Some(points),
            ..Default::default()
        };
        return points::read(std::path::Path::new(&p), &opts, &NoProgress).expect("read");
    }
    generate(&GenerateParams {
        seed: 1,
        points,
        ..Default::default()
    })
    .expect("generate")
    .cloud
}

/// The survey of `points` points with the default stages' inputs: the denoise keep mask and
/// the resampled (unfilled) grid.
fn stage_inputs(points: u64) -> (PointCloud, Vec<bool>, Heightfield) {
    let cloud = survey(points);
    let keep = denoise(&cloud, &DenoiseParams::default(), 1.0)
        .expect("denoise")
        .keep;
    let grid = resample(&cloud, Some(&keep), &ResampleParams::default())
        .expect("resample")
        .grid;
    (cloud, keep, grid)
}

fn stages(c: &mut Criterion) {
    let (cloud, keep, grid) = stage_inputs(3_408_187);
    let mut g = c.benchmark_group("terrain");
    g.sample_size(10);
    g.throughput(Throughput::Elements(cloud.len() as u64));
    g.bench_function("denoise", |b| {
        b.iter(|| black_box(denoise(&cloud, &DenoiseParams::default(), 1.0).expect("denoise")))
    });
    g.bench_function("resample", |b| {
        b.iter(|| {
            black_box(resample(&cloud, Some(&keep), &ResampleParams::default()).expect("resample"))
        })
    });
    g.bench_function("fill", |b| {
        b.iter(|| {
            let mut h = grid.clone();
            black_box(fill(&mut h, &FillParams::default()).expect("fill"))
        })
    });
    g.finish();
}

fn twins(c: &mut Criterion) {
    let (cloud, keep, grid) = stage_inputs(200_000);
    let mut g = c.benchmark_group("twins_200k");
    g.sample_size(10);
    g.bench_function("denoise_fast", |b| {
        b.iter(|| black_box(denoise(&cloud, &DenoiseParams::default(), 1.0)))
    });
    g.bench_function("denoise_reference", |b| {
        b.iter(|| {
            black_box(reference::denoise(
                &cloud.x,
                &cloud.y,
                &cloud.z,
                &DenoiseParams::default(),
                1.0,
            ))
        })
    });
    g.bench_function("resample_fast", |b| {
        b.iter(|| black_box(resample(&cloud, Some(&keep), &ResampleParams::default())))
    });
    g.bench_function("resample_reference", |b| {
        b.iter(|| {
            black_box(reference::resample(
                &cloud,
                Some(&keep),
                &ResampleParams::default(),
            ))
        })
    });
    g.bench_function("fill_fast", |b| {
        b.iter(|| {
            let mut h = grid.clone();
            black_box(fill(&mut h, &FillParams::default()))
        })
    });
    g.bench_function("fill_reference", |b| {
        b.iter(|| black_box(reference::fill(&grid, &FillParams::default())))
    });
    g.finish();
}

criterion_group!(benches, stages, twins);
criterion_main!(benches);
