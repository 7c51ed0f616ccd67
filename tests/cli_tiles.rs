//! The CLI on the tile stages' bad input (issue 4): a tile size that is not 2^k + 1 or out of
//! range, a tolerance ≤ 0 — each a one-line error naming the pipeline key, exit code 2, and
//! no output directory.

mod common;

use common::{default_job, terratile};
use std::path::Path;

/// Appends `table` to the default job's pipeline.toml.
fn with_table(dir: &Path, table: &str) {
    let p = dir.join("pipeline.toml");
    let mut text = std::fs::read_to_string(&p).unwrap();
    text.push('\n');
    text.push_str(table);
    text.push('\n');
    std::fs::write(&p, text).unwrap();
}

/// The run fails with the needles on one line, exit 2, and leaves nothing behind.
fn refused(dir: &Path, needles: &[&str]) {
    let r = terratile(dir, &["run", "-q"]);
    r.input_error(needles);
    assert!(!dir.join("out").exists(), "no output\n{}", r.context());
    let leftovers: Vec<_> = common::walk(dir)
        .into_iter()
        .filter(|p| p.to_string_lossy().contains(".tmp-"))
        .collect();
    assert!(
        leftovers.is_empty(),
        "no temporary files: {leftovers:?}\n{}",
        r.context()
    );
}

#[test]
fn tile_size_not_two_to_the_k_plus_one() {
    for size in ["300", "256", "1000"] {
        let d = default_job();
        with_table(d.path(), &format!("[tiles]\nsize = {size}"));
        refused(
            d.path(),
            &[
                "pipeline.toml:",
                "tiles.size",
                &format!("{size}: must be 2^k + 1"),
            ],
        );
    }
}

#[test]
fn tile_size_out_of_range() {
    for size in ["33", "17", "8193", "16385"] {
        let d = default_job();
        with_table(d.path(), &format!("[tiles]\nsize = {size}"));
        refused(d.path(), &["tiles.size", "between 65 and 4097"]);
    }
}

#[test]
fn tile_size_line_is_named() {
    let d = default_job();
    with_table(d.path(), "[tiles]\npreset = \"unity\"\nsize = 100");
    let text = std::fs::read_to_string(d.path().join("pipeline.toml")).unwrap();
    let line = text.lines().position(|l| l == "size = 100").unwrap() + 1;
    refused(
        d.path(),
        &[&format!("pipeline.toml:{line}:1: tiles.size: 100")],
    );
}

#[test]
fn tolerance_not_positive() {
    for tol in ["0", "-0.5", "0.0", "nan"] {
        let d = default_job();
        with_table(d.path(), &format!("[extract]\ntolerance = {tol}"));
        refused(d.path(), &["extract.tolerance", "must be > 0 metres"]);
    }
}

#[test]
fn other_tile_parameters_are_checked() {
    for (table, key) in [
        (
            "[quadtree]\nmin_resolution_c = 2",
            "quadtree.min_resolution_c",
        ),
        ("[extract]\nskirt_depth = -1", "extract.skirt_depth"),
        (
            "[extract]\ndesired_resolution_c = 0",
            "extract.desired_resolution_c",
        ),
        ("[output]\npreview_size = 3", "output.preview_size"),
        ("[tiles]\npreset = \"godot\"", "tiles.preset"),
        ("[output]\nmeshes = [\"stl\"]", "output.meshes"),
        (
            "[output]\nexr_compression = \"b44\"",
            "output.exr_compression",
        ),
    ] {
        let d = default_job();
        // [output] exists already in the default pipeline: put the key into it.
        if let Some(rest) = table.strip_prefix("[output]\n") {
            let p = d.path().join("pipeline.toml");
            let text = std::fs::read_to_string(&p)
                .unwrap()
                .replace("[output]\n", &format!("[output]\n{rest}\n"));
            std::fs::write(&p, text).unwrap();
        } else {
            with_table(d.path(), table);
        }
        refused(d.path(), &[key]);
    }
}
