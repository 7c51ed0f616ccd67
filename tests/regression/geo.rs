//! Georeferencing: bad CRS input (issue 17).

use crate::common::*;

/// `[input] crs` naming a code the EPSG table lacks: one line at the key, exit 2, nothing
/// written (it used not to exist; an unknown code must not reach the encoders).
#[test]
fn input_crs_unknown_epsg_code_is_refused_at_its_key() {
    let d = default_job();
    edit_pipeline(d.path(), "[input]\n", "[input]\ncrs = \"EPSG:99999\"\n");
    terratile(d.path(), &["run", "--quiet"])
        .input_error(&["pipeline.toml:", "input.crs", "EPSG:99999"])
        .left_nothing("out");
}

/// `[input] crs` that is not `EPSG:n` at all.
#[test]
fn input_crs_not_an_epsg_code_is_refused_at_its_key() {
    let d = default_job();
    edit_pipeline(d.path(), "[input]\n", "[input]\ncrs = \"+proj=utm\\n\"\n");
    terratile(d.path(), &["run", "--quiet"])
        .input_error(&["input.crs", "EPSG:n", "\\n"])
        .left_nothing("out");
}

/// Partial quantized-mesh levels held every tile in memory with no bound: on autzen_full
/// `quantized_mesh_max_level = 24` grew past 15 GB before it was killed. A level that could
/// pass the memory budget is now refused at the key, exit 2, nothing written.
#[test]
fn quantized_mesh_partial_levels_are_bounded_by_the_memory_budget() {
    let d = default_job();
    edit_pipeline(d.path(), "[input]\n", "[input]\ncrs = \"EPSG:32610\"\n");
    edit_pipeline(
        d.path(),
        "[output]\n",
        "[output]\nquantized_mesh = true\nquantized_mesh_max_level = 24\n",
    );
    terratile(d.path(), &["run", "--quiet", "--max-memory", "60MiB"])
        .input_error(&[
            "output.quantized_mesh_max_level = 24",
            "more tiles",
            "memory budget",
        ])
        .left_nothing("out");
}
