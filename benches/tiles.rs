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
//! - `quantized_mesh`: the Cesium tileset of the same survey (levels resampled, triangulated at
//!   0.5 m, then every tile encoded and gzipped), against the EXR tiles' encoding as reference.

mod common;

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use terratile::mesh::io::MeshFormat;
use terratile::output::exr::{encode_tile, ExrCompression};
use terratile::points::{self, ReadOptions};
use terratile::terrain::extract::{self, ExtractParams, Refiner};
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

/// What a refiner at the default 0.5 m tolerance borrows: CSite4 tiled at 257, its
/// quadtree, its vertical error tree and the criterion.
struct Csite4 {
    set: TileSet,
    qt: quadtree::Quadtree,
    err: Vec<quadtree::NodeValues>,
    crit: extract::Criterion,
}

impl Csite4 {
    fn load() -> Option<Csite4> {
        let set = common::real_set("CSite4_orig-utm.laz", 257, false)?;
        let qt = build(&set, &QuadtreeParams::default()).expect("d2");
        let err = quadtree::vertical_error(&set);
        let crit = ExtractParams::default()
            .criterion(&set, &qt)
            .expect("criterion");
        Some(Csite4 { set, qt, err, crit })
    }

    fn refiner(&self) -> Refiner<'_> {
        Refiner::new(&self.set, &self.qt, Some(&self.err), self.crit).expect("refiner")
    }
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
    let Some(set) = common::real_set("CSite4_orig-utm.laz", 257, false) else {
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
    let Some(cs) = Csite4::load() else {
        return;
    };
    let set = &cs.set;
    let mut g = c.benchmark_group("extract");
    g.sample_size(10);
    g.bench_function("vertical_error_tree", |b| {
        b.iter(|| black_box(quadtree::vertical_error(set)))
    });
    let r = cs.refiner();
    g.bench_function("tolerance_0.5m", |b| {
        b.iter(|| black_box(extract::extract(set, &r).expect("extract")))
    });
    g.finish();
}

fn mesh_encoding(c: &mut Criterion) {
    let Some(cs) = Csite4::load() else {
        return;
    };
    let meshes: Vec<_> = extract::extract(&cs.set, &cs.refiner())
        .expect("extract")
        .iter()
        .map(|t| extract::to_trimesh(&cs.set, t))
        .collect();
    let mut g = c.benchmark_group("mesh_encoding");
    g.sample_size(10);
    for f in [MeshFormat::PlyBinaryLe, MeshFormat::Obj, MeshFormat::Glb] {
        let bytes: usize = meshes
            .iter()
            .map(|m| f.encode(m, "tile", 1.0).expect("encode").len())
            .sum();
        eprintln!("{}: {bytes} bytes over {} tiles", f.ext(), meshes.len());
        g.bench_function(f.ext(), |b| {
            b.iter(|| {
                for m in &meshes {
                    black_box(f.encode(m, "tile", 1.0).expect("encode"));
                }
            })
        });
    }
    g.finish();
}

fn quantized_mesh(c: &mut Criterion) {
    let Some(set) = common::real_set("CSite4_orig-utm.laz", 257, false) else {
        return;
    };
    let qt = build(&set, &QuadtreeParams::default()).expect("d2");
    let ts = terratile::geo::tms::tileset(&set, 0.5).expect("tileset");
    eprintln!(
        "quantized_mesh: {} levels, {} tiles",
        ts.levels.len(),
        ts.tiles.len()
    );
    let mut g = c.benchmark_group("quantized_mesh");
    g.sample_size(10);
    common::exr_tiles_reference(&mut g, &set, &qt);
    g.bench_function("tileset", |b| {
        b.iter(|| black_box(terratile::geo::tms::tileset(&set, 0.5).expect("tileset")))
    });
    g.bench_function("encode_tiles", |b| {
        b.iter(|| {
            ts.tiles
                .iter()
                .map(|t| black_box(terratile::output::qmesh::encode_tile(t)).len())
                .sum::<usize>()
        })
    });
    g.finish();
}

criterion_group!(
    benches,
    d2_vs_decode,
    exr_compression,
    extraction,
    mesh_encoding,
    quantized_mesh
);
criterion_main!(benches);
