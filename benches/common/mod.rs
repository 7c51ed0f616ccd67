//! What the criterion benchmarks share (each uses a part of it).
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use terratile::generate::{generate, write_cloud, GenerateParams, OutFormat};
use terratile::mesh::{io, TriMesh};

/// The paper's largest case (seed 003, Table 1).
pub const PAPER_POINTS: u64 = 3_408_187;

/// The LAS the benchmarks decode: `TERRATILE_BENCH_LAS` when set (e.g. a real tile made with
/// `terratile convert autzen_full.laz x.las --sample 3408187`), else a generated survey of
/// [`PAPER_POINTS`] points written into `dir`.
pub fn paper_las(dir: &Path) -> PathBuf {
    if let Some(p) = std::env::var_os("TERRATILE_BENCH_LAS") {
        return PathBuf::from(p);
    }
    let scene = generate(&GenerateParams {
        seed: 1,
        points: PAPER_POINTS,
        ..Default::default()
    })
    .expect("generate");
    let path = dir.join("paper.las");
    write_cloud(&path, scene.cloud, OutFormat::Las).expect("write");
    path
}

/// The mesh `name` of the shared data (`TERRATILE_DATA`, else `../shared/data`) under
/// `meshes/`, or `None` (and a note) when it is not there.
pub fn load(name: &str) -> Option<TriMesh> {
    let dir = std::env::var_os("TERRATILE_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    let path = dir.join("meshes").join(name);
    if !path.is_file() {
        eprintln!(
            "skipping: {} not found (set TERRATILE_DATA)",
            path.display()
        );
        return None;
    }
    Some(io::read(&path).expect("a readable mesh"))
}

/// A real survey of the shared data's `lidar/` through the pipeline's own grid stages
/// (default resampling, holes filled, noise removal when `denoise`), tiled at `size`; `None`
/// (and a note) when it is not there.
pub fn real_set(
    rel: &str,
    size: usize,
    denoise: bool,
) -> Option<terratile::terrain::tiles::TileSet> {
    use terratile::points::{self, ReadOptions};
    use terratile::terrain::tiles::{tile, TileParams};
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/lidar")
        .join(rel);
    if !path.is_file() {
        eprintln!("skipping: {} not found", path.display());
        return None;
    }
    let c = points::read(&path, &ReadOptions::default(), &terratile::NoProgress).ok()?;
    let mut cfg = terratile::config::Pipeline::default();
    cfg.denoise.enabled = denoise;
    let g = terratile::pipeline::grid_stages(&c, &cfg, &terratile::NoProgress).ok()?;
    tile(
        &g.resampled.grid,
        &TileParams {
            size: Some(size),
            ..Default::default()
        },
    )
    .ok()
}

/// The reference the output benchmarks are measured against in the same run: encoding every
/// EXR tile of `set` (uncompressed), as `exr_tiles_reference` in group `g`.
pub fn exr_tiles_reference(
    g: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    set: &terratile::terrain::tiles::TileSet,
    qt: &terratile::terrain::quadtree::Quadtree,
) {
    use terratile::output::exr::{encode_tile, ExrCompression};
    g.bench_function("exr_tiles_reference", |b| {
        b.iter(|| {
            for t in 0..set.tiles.len() {
                std::hint::black_box(
                    encode_tile(set, qt, t, ExrCompression::None).expect("encode"),
                );
            }
        })
    });
}

/// A criterion measurement of the process's CPU time (all threads, user and system; the
/// kernel's per-process clock, in nanoseconds) instead of the wall clock: on a machine
/// shared with other work it says what a run costs where the wall clock says how long it
/// waited. Values are nanoseconds, printed as durations.
pub struct CpuTime(criterion::measurement::WallTime);

impl Default for CpuTime {
    fn default() -> CpuTime {
        CpuTime(criterion::measurement::WallTime)
    }
}

fn cpu_now() -> std::time::Duration {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::ProcessCPUTime);
    std::time::Duration::new(t.tv_sec as u64, t.tv_nsec as u32)
}

impl criterion::measurement::Measurement for CpuTime {
    type Intermediate = std::time::Duration;
    type Value = std::time::Duration;

    fn start(&self) -> Self::Intermediate {
        cpu_now()
    }

    fn end(&self, i: Self::Intermediate) -> Self::Value {
        cpu_now().saturating_sub(i)
    }

    fn add(&self, v1: &Self::Value, v2: &Self::Value) -> Self::Value {
        *v1 + *v2
    }

    fn zero(&self) -> Self::Value {
        std::time::Duration::ZERO
    }

    fn to_f64(&self, value: &Self::Value) -> f64 {
        value.as_nanos() as f64
    }

    fn formatter(&self) -> &dyn criterion::measurement::ValueFormatter {
        // The wall clock's: its values are nanoseconds too.
        self.0.formatter()
    }
}
