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

/// This thread's time on a CPU so far, in nanoseconds (`CLOCK_THREAD_CPUTIME_ID`), or
/// None. (`/proc/thread-self/schedstat` is only brought up to date at scheduler ticks, 4 ms
/// here: single calls of a few ms read as 0 or a whole tick.)
#[cfg(unix)]
fn thread_cpu_ns() -> Option<u64> {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes the timespec it is given, which lives on this stack.
    let r = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    (r == 0).then(|| ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64)
}

#[cfg(not(unix))]
fn thread_cpu_ns() -> Option<u64> {
    None
}

/// CPU time per call of meshoptimizer's stripify and ours on one thread (both are
/// single-threaded), the two taking turns over `rounds` rounds so that the machine's load
/// falls on both alike.
fn stripify_cpu(mesh: &terratile::mesh::TriMesh, flat: &[u32], rounds: u32) {
    let (mut theirs, mut ours) = (0u64, 0u64);
    for _ in 0..rounds {
        let Some(t0) = thread_cpu_ns() else {
            return;
        };
        black_box(meshopt::stripify(flat, mesh.vertex_count(), RESTART).unwrap());
        let t1 = thread_cpu_ns().unwrap_or(t0);
        black_box(stripify(&mesh.indices, &StripParams::default()));
        let t2 = thread_cpu_ns().unwrap_or(t1);
        theirs += t1 - t0;
        ours += t2 - t1;
    }
    let ms = |ns: u64| ns as f64 / 1e6 / rounds as f64;
    println!(
        "bunny stripify CPU time, one thread, {rounds} calls each: meshopt {:.3} ms, \
         terratile {:.3} ms per call ({:.2}x)",
        ms(theirs),
        ms(ours),
        ours as f64 / theirs.max(1) as f64
    );
}

/// CPU time per call of the quadric run alone and of the whole progressive build (which
/// includes it), both in a pool of one thread (the quadric engine's setup is parallel), taking
/// turns as above.
fn progressive_cpu(mesh: &terratile::mesh::TriMesh, params: &ProgressiveParams, rounds: u32) {
    let Ok(pool) = rayon::ThreadPoolBuilder::new().num_threads(1).build() else {
        return;
    };
    pool.install(|| progressive_cpu_here(mesh, params, rounds));
}

fn progressive_cpu_here(mesh: &terratile::mesh::TriMesh, params: &ProgressiveParams, rounds: u32) {
    let (canon, qparams) = engine_input(mesh, params);
    let (mut qem_ns, mut ours) = (0u64, 0u64);
    for _ in 0..rounds {
        let Some(t0) = thread_cpu_ns() else {
            return;
        };
        black_box(qem::simplify_logged(&canon, &qparams).unwrap());
        let t1 = thread_cpu_ns().unwrap_or(t0);
        black_box(progressive(mesh, params).unwrap());
        let t2 = thread_cpu_ns().unwrap_or(t1);
        qem_ns += t1 - t0;
        ours += t2 - t1;
    }
    let ms = |ns: u64| ns as f64 / 1e6 / rounds as f64;
    println!(
        "bunny progressive CPU time, one thread, {rounds} calls each: quadric run {:.1} ms, \
         progressive strips {:.1} ms per call ({:.2}x)",
        ms(qem_ns),
        ms(ours),
        ours as f64 / qem_ns.max(1) as f64
    );
}

fn strips(c: &mut Criterion) {
    let Some(mesh) = load("bunny.obj") else {
        return;
    };
    let flat: Vec<u32> = mesh.indices.iter().flatten().copied().collect();
    stripify_cpu(&mesh, &flat, 100);
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
    progressive_cpu(&mesh, &params, 10);
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
