//! The void fill (issue 15): `[fill] fallback = "membrane"` on a 4097² grid with 40 % of its
//! cells empty (half in discs of 3 to 40 cells radius, half scattered), beside the push-pull
//! `smooth` fallback on the same grid. The target: ≤ 0.3 s on 2 cores.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use std::hint::black_box;
use terratile::terrain::largevoid::voids_grid;
use terratile::terrain::{fill, Fallback, FillParams};

fn void_fill(c: &mut Criterion) {
    let grid = voids_grid(1, 4097, 0.4);
    let mut g = c.benchmark_group("void_fill_4097");
    g.sample_size(10);
    for (name, fallback) in [
        ("membrane", Fallback::Membrane),
        ("smooth", Fallback::Smooth),
    ] {
        let p = FillParams {
            fallback,
            ..Default::default()
        };
        g.bench_function(name, |b| {
            b.iter_batched_ref(
                || grid.clone(),
                |h| black_box(fill(h, &p).expect("fill")),
                BatchSize::LargeInput,
            )
        });
    }
    g.finish();
}

criterion_group!(benches, void_fill);
criterion_main!(benches);
