//! Ground classification (SMRF, `terrain::ground::classify`) on the paper's largest generated
//! survey (3,408,187 points: terrain, ridge, cliff, buildings, trees), or the LAS named by
//! `TERRATILE_BENCH_LAS`, with the copy of its coordinates into fresh vectors as the reference
//! measured in the same run (the classification should cost a few such copies, not more).

mod common;

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use terratile::points::{self, ReadOptions};
use terratile::terrain::ground::{classify, GroundParams};
use terratile::NoProgress;

fn ground(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = common::paper_las(dir.path());
    let cloud = points::read(&path, &ReadOptions::default(), &NoProgress).expect("read");
    let mpu = cloud.crs().map_or(1.0, |c| c.metres_per_unit());
    let mut g = c.benchmark_group("ground");
    g.sample_size(10);
    g.bench_function("copy_xyz_reference", |b| {
        b.iter(|| {
            let xyz = (cloud.x.clone(), cloud.y.clone(), cloud.z.clone());
            black_box(xyz)
        })
    });
    g.bench_function("classify", |b| {
        b.iter(|| {
            let r = classify(
                &cloud.x,
                &cloud.y,
                &cloud.z,
                None,
                &GroundParams::default(),
                mpu,
            )
            .expect("classify");
            black_box(r.ground_count)
        })
    });
    g.finish();
}

criterion_group!(benches, ground);
criterion_main!(benches);
