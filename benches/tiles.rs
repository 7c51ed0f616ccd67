//! Tile-stage benchmarks (issue 4's figures):
//! - `d2_vs_decode`: Röttger d2 (raw, propagated, reconciled) of a 4097 × 4097 grid against
//!   decoding the 3,408,187-point LAS of the paper's largest case (made by the generator, or
//!   `TERRATILE_BENCH_LAS=path`). Target: d2 faster than the decode.
//! - `exr_compression`: encoding the EXR tiles (257²) of a real survey with each lossless
//!   compression; the sizes are printed once (they decided the default).
//! - `extract`: view-independent extraction at 0.5 m over the same survey, vertical error
//!   tree included.
//! - `mesh_encoding`: the same survey's tile meshes (0.5 m) encoded as binary PLY, OBJ and
//!   GLB, all tiles: what each mesh format adds to a run.

mod common;

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use std::path::Path;
use terratile::output::exr::{encode_tile, ExrCompression};
use terratile::output::MeshFormat;
use terratile::points::{self, ReadOptions};
use terratile::terrain::extract::{self, ExtractParams, Refiner};
use terratile::terrain::heightfield::choose_z_offset;
use terratile::terrain::quadtree::{self, build, QuadtreeParams};
use terratile::terrain::tiles::{tile, TileParams, TileSet};
use terratile::terrain::{CellState, Heightfield};
use terratile::NoProgress;

/// A rough 4097² terrain (waves and noise), deterministic.
fn grid_4097() -> TileSet {
    let n = 4097;
    let mut hf = Heightfield::empty(n, n, [0.0, 0.0], [1.0, 1.0], 0.0, None);
    let mut s = 0x2545_F491_4F6C_DD1Du64;
    for j in 0..n {
        for i in 0..n {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let noise = (s >> 40) as f32 / (1u64 << 24) as f32;
            hf.heights[[j, i]] =
                100.0 + 20.0 * ((i as f32) * 0.01).sin() * ((j as f32) * 0.013).cos() + noise;
            hf.state[[j, i]] = CellState::Measured;
        }
    }
    tile(
        &hf,
        &TileParams {
            size: Some(4097),
            ..Default::default()
        },
    )
    .expect("tile")
}

/// Per-cell mean grid of a real survey, holes grown shut (benchmark input only; the
/// pipeline's own resampler and filler are the terrain stages').
fn real_set(rel: &str, size: usize) -> Option<TileSet> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/lidar")
        .join(rel);
    if !path.is_file() {
        eprintln!("skipping: {} not found", path.display());
        return None;
    }
    let c = points::read(&path, &ReadOptions::default(), &NoProgress).ok()?;
    let b = c.bounds();
    let n = (c.len() as f64).sqrt().round() as usize;
    let cell = [
        (b.max[0] - b.min[0]) / n as f64,
        (b.max[1] - b.min[1]) / n as f64,
    ];
    let zo = choose_z_offset(b.min[2], b.max[2]);
    let mut hf = Heightfield::empty(n, n, [b.min[0], b.min[1]], cell, zo, c.crs().cloned());
    let mut sum = vec![0.0f64; n * n];
    for k in 0..c.len() {
        let i = (((c.x[k] - b.min[0]) / cell[0]) as usize).min(n - 1);
        let j = (((c.y[k] - b.min[1]) / cell[1]) as usize).min(n - 1);
        sum[j * n + i] += c.z[k] - zo;
        hf.counts[[j, i]] += 1;
    }
    for j in 0..n {
        for i in 0..n {
            if hf.counts[[j, i]] > 0 {
                hf.heights[[j, i]] = (sum[j * n + i] / hf.counts[[j, i]] as f64) as f32;
                hf.state[[j, i]] = CellState::Measured;
            }
        }
    }
    loop {
        let mut fills = Vec::new();
        for j in 0..n {
            for i in 0..n {
                if hf.state[[j, i]].has_height() {
                    continue;
                }
                let mut acc = (0.0f32, 0);
                for (a, bb) in [
                    (i.wrapping_sub(1), j),
                    (i + 1, j),
                    (i, j.wrapping_sub(1)),
                    (i, j + 1),
                ] {
                    if a < n && bb < n && hf.state[[bb, a]].has_height() {
                        acc = (acc.0 + hf.heights[[bb, a]], acc.1 + 1);
                    }
                }
                if acc.1 > 0 {
                    fills.push((i, j, acc.0 / acc.1 as f32));
                }
            }
        }
        if fills.is_empty() {
            break;
        }
        for (i, j, h) in fills {
            hf.heights[[j, i]] = h;
            hf.state[[j, i]] = CellState::Interpolated;
        }
    }
    tile(
        &hf,
        &TileParams {
            size: Some(size),
            ..Default::default()
        },
    )
    .ok()
}

fn d2_vs_decode(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("tempdir");
    let las = common::paper_las(dir.path());
    let set = grid_4097();
    let mut g = c.benchmark_group("d2_vs_decode");
    g.sample_size(10);
    g.bench_function("quadtree_d2_4097", |b| {
        b.iter(|| black_box(build(&set, &QuadtreeParams::default()).expect("d2")))
    });
    g.bench_function("decode_las_3408187", |b| {
        b.iter(|| {
            black_box(points::read(&las, &ReadOptions::default(), &NoProgress).expect("read"))
        })
    });
    g.finish();
}

fn exr_compression(c: &mut Criterion) {
    let Some(set) = real_set("CSite4_orig-utm.laz", 257) else {
        return;
    };
    let qt = build(&set, &QuadtreeParams::default()).expect("d2");
    let mut g = c.benchmark_group("exr_compression");
    g.sample_size(10);
    for comp in ExrCompression::ALL {
        let bytes: usize = (0..set.tiles.len())
            .map(|t| encode_tile(&set, &qt, t, comp).expect("encode").len())
            .sum();
        eprintln!(
            "exr {:>5}: {} tiles, {:.2} MB ({:.2} bytes/sample)",
            comp.name(),
            set.tiles.len(),
            bytes as f64 / 1e6,
            bytes as f64 / (set.tiles.len() * set.tile_size * set.tile_size) as f64
        );
        g.bench_function(comp.name(), |b| {
            b.iter(|| {
                for t in 0..set.tiles.len() {
                    black_box(encode_tile(&set, &qt, t, comp).expect("encode"));
                }
            })
        });
    }
    g.finish();
}

fn extraction(c: &mut Criterion) {
    let Some(set) = real_set("CSite4_orig-utm.laz", 257) else {
        return;
    };
    let qt = build(&set, &QuadtreeParams::default()).expect("d2");
    let crit = ExtractParams::default()
        .criterion(&set, &qt)
        .expect("criterion");
    let mut g = c.benchmark_group("extract");
    g.sample_size(10);
    g.bench_function("vertical_error_tree", |b| {
        b.iter(|| black_box(quadtree::vertical_error(&set)))
    });
    let err = quadtree::vertical_error(&set);
    let r = Refiner::new(&set, &qt, Some(&err), crit).expect("refiner");
    g.bench_function("tolerance_0.5m", |b| {
        b.iter(|| black_box(extract::extract(&set, &r).expect("extract")))
    });
    g.finish();
}

fn mesh_encoding(c: &mut Criterion) {
    let Some(set) = real_set("CSite4_orig-utm.laz", 257) else {
        return;
    };
    let qt = build(&set, &QuadtreeParams::default()).expect("d2");
    let crit = ExtractParams::default()
        .criterion(&set, &qt)
        .expect("criterion");
    let err = quadtree::vertical_error(&set);
    let r = Refiner::new(&set, &qt, Some(&err), crit).expect("refiner");
    let meshes: Vec<_> = extract::extract(&set, &r)
        .expect("extract")
        .iter()
        .map(|t| extract::to_trimesh(&set, t))
        .collect();
    let mut g = c.benchmark_group("mesh_encoding");
    g.sample_size(10);
    for f in [MeshFormat::Ply, MeshFormat::Obj, MeshFormat::Glb] {
        let bytes: usize = meshes
            .iter()
            .map(|m| f.encode(m, "tile").expect("encode").len())
            .sum();
        eprintln!("{}: {bytes} bytes over {} tiles", f.ext(), meshes.len());
        g.bench_function(f.ext(), |b| {
            b.iter(|| {
                for m in &meshes {
                    black_box(f.encode(m, "tile").expect("encode"));
                }
            })
        });
    }
    g.finish();
}

criterion_group!(
    benches,
    d2_vs_decode,
    exr_compression,
    extraction,
    mesh_encoding
);
criterion_main!(benches);
