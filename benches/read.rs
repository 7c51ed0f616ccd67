//! Reading benchmarks (issue 2's figures):
//! - `read_las/*`: a 3,408,187-point LAS (the paper's largest case, made by the generator)
//!   decoded by terratile, by `las::Reader` (points as structs, then columns), and a plain
//!   parallel copy of the file's bytes out of a fresh map. Targets: terratile ≥ 4× las-rs in
//!   points/s and ≥ 70 % of the copy's throughput.
//! - `parse_xyz`: XYZ text parsing, MB/s (target ≥ 150 MB/s on 2 cores).
//!
//! `TERRATILE_BENCH_LAS=path` benchmarks that file instead of the generated one.

mod common;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use std::path::Path;
use terratile::generate::{generate, GenerateParams};
use terratile::points::{self, parse_xyz, ReadOptions};
use terratile::NoProgress;

fn read_las(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = common::paper_las(dir.path());
    let bytes = std::fs::metadata(&path).expect("stat").len();
    let mut g = c.benchmark_group("read_las");
    g.sample_size(10);
    g.throughput(Throughput::Bytes(bytes));
    g.bench_function("copy", |b| {
        b.iter(|| black_box(terratile::bench::copy_file_bytes(&path).expect("copy")))
    });
    g.bench_function("terratile", |b| {
        b.iter(|| {
            black_box(points::read(&path, &ReadOptions::default(), &NoProgress).expect("read"))
        })
    });
    g.bench_function("las_rs", |b| {
        b.iter(|| black_box(terratile::bench::read_with_las_rs(&path).expect("las-rs")))
    });
    g.finish();
}

fn xyz(c: &mut Criterion) {
    let scene = generate(&GenerateParams {
        seed: 2,
        points: 1_000_000,
        ..Default::default()
    })
    .expect("generate");
    let mut text = String::with_capacity(32 << 20);
    text.push_str("x y z\n");
    for i in 0..scene.cloud.len() {
        use std::fmt::Write;
        let _ = writeln!(
            text,
            "{:.3} {:.3} {:.3}",
            scene.cloud.x[i], scene.cloud.y[i], scene.cloud.z[i]
        );
    }
    let mut g = c.benchmark_group("parse_xyz");
    g.sample_size(20);
    g.throughput(Throughput::Bytes(text.len() as u64));
    g.bench_function("terratile", |b| {
        b.iter(|| {
            black_box(
                parse_xyz(Path::new("bench.xyz"), text.as_bytes(), &NoProgress).expect("parse"),
            )
        })
    });
    g.finish();
}

criterion_group!(benches, read_las, xyz);
criterion_main!(benches);
