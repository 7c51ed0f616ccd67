//! What the criterion benchmarks share.

use std::path::{Path, PathBuf};
use terratile::generate::{generate, write_scene, GenerateParams, OutFormat};

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
    write_scene(&scene, &path, &[OutFormat::Las], (1, 1)).expect("write");
    path
}
