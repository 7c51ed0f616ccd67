//! The saliency stages (issue 12): mesh saliency on cow (5,804 triangles) and bunny
//! (69,451), multi-view image saliency (N = 36: 614 views of 256 × 256) on cow, and the
//! weighted against the unweighted quadric simplifier on bunny → 10 % once H is known.
//! Targets: mesh saliency ≤ 0.05 s on 5,000 triangles and ≤ 0.5 s on bunny; image
//! saliency ≤ 1.5 s on 5,000 triangles; weighted QEM within 1.2× of plain.
//!
//! Run: `cargo bench --bench saliency` (needs ../shared/data or TERRATILE_DATA).

use criterion::{criterion_group, criterion_main, Criterion};

mod common;

use common::load;
use std::hint::black_box;
use terratile::simplify::qem;
use terratile::simplify::saliency::{self, image::ViewParams};

fn mesh_saliency(c: &mut Criterion) {
    let mut g = c.benchmark_group("mesh_saliency");
    g.sample_size(10);
    for name in ["cow.obj", "bunny.obj"] {
        let Some(m) = load(name) else { return };
        g.bench_function(name, |b| {
            b.iter(|| black_box(saliency::mesh::mesh_saliency(&m)))
        });
    }
    g.finish();
}

fn image_saliency(c: &mut Criterion) {
    let Some(m) = load("cow.obj") else { return };
    let mut g = c.benchmark_group("image_saliency");
    g.sample_size(10);
    g.bench_function("cow.obj N=36 256px", |b| {
        b.iter(|| black_box(saliency::image::image_saliency(&m, &ViewParams::default()).unwrap()))
    });
    g.finish();
}

fn weighted_qem(c: &mut Criterion) {
    let Some(m) = load("bunny.obj") else { return };
    // The default weighting of the mesh saliency (the hybrid's image part would make the
    // setup long; H's origin does not change the engine's work), in the default rule and
    // the default two phases (H and the salient vertices known before).
    let d = saliency::Weighting::default();
    let values = saliency::mesh::mesh_saliency(&m).saliency;
    let h = d
        .weights(&m, &values)
        .expect("bunny's mesh saliency varies");
    let salient = d.salient(&m, &values);
    let plain = qem::QemParams::plain(m.triangle_count() as u64 / 10, qem::Placement::Optimal);
    let weighted = qem::QemParams {
        weight_rule: qem::WeightRule::Quadric,
        ..plain.clone()
    };
    let mut g = c.benchmark_group("qem_bunny_10pct");
    g.sample_size(10);
    g.bench_function("plain", |b| {
        b.iter(|| black_box(qem::simplify(&m, &plain).unwrap()))
    });
    g.bench_function("weighted", |b| {
        b.iter(|| {
            black_box(saliency::phases::simplify(&m, &weighted, &h, &salient, d.phases).unwrap())
        })
    });
    g.finish();
}

criterion_group!(benches, mesh_saliency, image_saliency, weighted_qem);
criterion_main!(benches);
