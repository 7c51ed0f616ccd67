//! The streaming run's bucketing pass (issue 16): 1 M generated points, each's raw integers
//! recovered and appended to its brick file through the fixed-size buffers (`bucket`), and
//! every brick read back into input order (`load`). Reference in the same run: copying the
//! same coordinates (`copy`), the floor of any pass over them.

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use terratile::generate::{generate, GenerateParams};
use terratile::shard::bricks::{self, BrickLattice, BrickWriter, SourceTransform};

const SCALE: f64 = 0.01;

fn bench_bucketing(c: &mut Criterion) {
    let mut cloud = generate(&GenerateParams {
        points: 1_000_000,
        ..Default::default()
    })
    .expect("generated scene")
    .cloud;
    // On a LAS lattice of 1 cm, as a file's points are.
    for v in [&mut cloud.x, &mut cloud.y, &mut cloud.z] {
        for x in v.iter_mut() {
            *x = SCALE * f64::from((*x / SCALE).round() as i32);
        }
    }
    let lattice = BrickLattice::new(&cloud.bounds(), 64);
    let sources = [SourceTransform {
        first: 0,
        scale: [SCALE; 3],
        offset: [0.0; 3],
    }];
    let mut g = c.benchmark_group("bucketing");
    g.sample_size(10);
    g.bench_function("copy", |b| {
        b.iter(|| black_box((cloud.x.clone(), cloud.y.clone(), cloud.z.clone())))
    });
    let dir = tempfile::tempdir().expect("temporary directory");
    let bucket = |d: &std::path::Path| -> Vec<u64> {
        let mut w = BrickWriter::new(d, lattice, 1 << 16);
        for i in 0..cloud.len() {
            let (x, y, z) = (cloud.x[i], cloud.y[i], cloud.z[i]);
            let raw = [x, y, z].map(|v| bricks::raw_of(v, SCALE, 0.0).expect("on the lattice"));
            w.push(x, y, raw, i as u64).expect("written");
        }
        w.finish().expect("finished")
    };
    g.bench_function("bucket", |b| {
        b.iter(|| {
            let d = tempfile::tempdir_in(dir.path()).expect("directory");
            black_box(bucket(d.path()))
        })
    });
    let counts = bucket(dir.path());
    let all: Vec<usize> = (0..lattice.count()).collect();
    g.bench_function("load", |b| {
        b.iter(|| {
            black_box(
                bricks::load(
                    dir.path(),
                    &all,
                    &counts,
                    &sources,
                    bricks::Order::Input,
                    |_, _, _| true,
                )
                .expect("loaded")
                .len(),
            )
        })
    });
    g.finish();
}

criterion_group!(benches, bench_bucketing);
criterion_main!(benches);
