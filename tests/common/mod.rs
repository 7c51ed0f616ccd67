//! Shared helpers of the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// `../shared/data` next to the repository (CI has it there), or `$TERRATILE_DATA`.
/// A newcomer's clone lacks it: the test says it skips and returns None. Under `CI=true`
/// a missing data directory fails the test instead.
pub fn shared_data() -> Option<PathBuf> {
    let dir = std::env::var_os("TERRATILE_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if dir.is_dir() {
        return Some(dir);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!(
            "CI=true but the shared data directory {} is missing",
            dir.display()
        );
    }
    eprintln!(
        "skipping: shared data not found at {} (set TERRATILE_DATA)",
        dir.display()
    );
    None
}

/// A file under the shared data's `lidar/` or `meshes/` folder.
pub fn data_file(rel: &str) -> Option<PathBuf> {
    let p = shared_data()?.join(rel);
    if p.is_file() {
        return Some(p);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("CI=true but {} is missing", p.display());
    }
    eprintln!("skipping: {} not found", p.display());
    None
}

/// Every LAS/LAZ file in the shared `lidar/` folder, sorted.
pub fn lidar_files() -> Vec<PathBuf> {
    let Some(dir) = shared_data() else {
        return Vec::new();
    };
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir.join("lidar"))
        .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    v.retain(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("las" | "laz")));
    v.sort();
    v
}
