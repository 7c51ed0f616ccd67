//! Progressive strips on the Stanford bunny (issue 13): our stripify against meshoptimizer's
//! (target: within 2×), building the progressive strips against the quadric run alone
//! (within 1.5×), and decoding: all splits (≥ 10 M strip-index updates per second), and a
//! switch of 100 levels against stripifying that level's mesh from scratch.
//!
//! Run: `cargo bench --bench strips` (needs ../shared/data or TERRATILE_DATA).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};

mod common;

use common::load;
use std::hint::black_box;
use terratile::simplify::qem;
use terratile::simplify::strips::progressive::engine_input;
use terratile::simplify::strips::{
    progressive, stripify, Decoder, Encoding, ProgressiveParams, StripParams, RESTART,
};

fn strips(c: &mut Criterion) {
    let Some(mesh) = load("bunny.obj") else {
        return;
    };
    let flat: Vec<u32> = mesh.indices.iter().flatten().copied().collect();
    let mut g = c.benchmark_group("bunny_stripify");
    g.sample_size(10);
    g.bench_function("meshopt_stripify", |b| {
        b.iter(|| black_box(meshopt::stripify(&flat, mesh.vertex_count(), RESTART).unwrap()))
    });
    g.bench_function("terratile_stripify", |b| {
        b.iter(|| black_box(stripify(&mesh.indices, &StripParams::default())))
    });
    g.finish();

    let params = ProgressiveParams::default();
    let mut g = c.benchmark_group("bunny_progressive_5pct");
    g.sample_size(10);
    let (canon, qparams) = engine_input(&mesh, &params);
    g.bench_function("qem_alone", |b| {
        b.iter(|| black_box(qem::simplify_logged(&canon, &qparams).unwrap()))
    });
    g.bench_function("progressive_strips", |b| {
        b.iter(|| black_box(progressive(&mesh, &params).unwrap()))
    });
    g.finish();

    let p = progressive(&mesh, &params).unwrap();
    let n = p.splits.len();
    let mut probe = Decoder::new(&p, Encoding::Encoded);
    probe.set_level(n);
    let mut g = c.benchmark_group("bunny_decode");
    g.sample_size(10);
    // Throughput: the strip indices written by applying every split.
    g.throughput(Throughput::Elements(probe.updates));
    g.bench_function("all_splits_encoded", |b| {
        b.iter(|| {
            let mut d = Decoder::new(&p, Encoding::Encoded);
            d.set_level(n);
            black_box(d.updates)
        })
    });
    g.throughput(Throughput::Elements(1));
    let mut d = Decoder::new(&p, Encoding::Encoded);
    let (lo, hi) = (n / 2, n / 2 + 100);
    d.set_level(lo);
    g.bench_function("switch_100_levels", |b| {
        b.iter(|| {
            d.set_level(hi);
            d.set_level(lo);
            black_box(d.strip().len())
        })
    });
    let mid = p.mesh_at(hi, Encoding::Encoded);
    g.bench_function("restripify_the_level", |b| {
        b.iter(|| black_box(stripify(&mid.indices, &StripParams::default())))
    });
    g.finish();
}

criterion_group!(benches, strips);
criterion_main!(benches);
