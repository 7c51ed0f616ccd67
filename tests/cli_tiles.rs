//! The CLI on the tile stages' bad input (issue 4): a tile size that is not 2^k + 1 or out of
//! range, a tolerance ≤ 0 — each a one-line error naming the pipeline key, exit code 2, and
//! no output directory.

use crate::common;

use common::{default_job, edit_pipeline as edit, terratile};
use std::path::Path;

/// Puts `table` (a header line and keys) into the default job's pipeline.toml in place of
/// the table of the same name, so that the keys given are the only ones it has.
fn with_table(dir: &Path, table: &str) {
    let p = dir.join("pipeline.toml");
    let header = table.lines().next().unwrap();
    let mut text = String::new();
    let mut skipping = false;
    for line in std::fs::read_to_string(&p).unwrap().lines() {
        if line.starts_with('[') {
            skipping = line.trim() == header;
        }
        if !skipping {
            text.push_str(line);
            text.push('\n');
        }
    }
    text.push('\n');
    text.push_str(table);
    text.push('\n');
    std::fs::write(&p, text).unwrap();
}

/// The run fails with the needles on one line, exit 2, and leaves nothing behind.
fn refused(dir: &Path, needles: &[&str]) {
    terratile(dir, &["run", "-q"])
        .input_error(needles)
        .left_nothing("out");
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

/// Each bad tile-stage value: refused at its key, nothing written.
#[test]
fn bad_tile_parameters() {
    const RANGE: &str = "between 65 and 4097";
    const TOL: &str = "must be > 0 metres";
    let cases: &[(&str, &[&str])] = &[
        (
            "[tiles]\nsize = 300",
            &["pipeline.toml:", "tiles.size", "300: must be 2^k + 1"],
        ),
        (
            "[tiles]\nsize = 256",
            &["pipeline.toml:", "tiles.size", "256: must be 2^k + 1"],
        ),
        (
            "[tiles]\nsize = 1000",
            &["pipeline.toml:", "tiles.size", "1000: must be 2^k + 1"],
        ),
        ("[tiles]\nsize = 33", &["tiles.size", RANGE]),
        ("[tiles]\nsize = 17", &["tiles.size", RANGE]),
        ("[tiles]\nsize = 8193", &["tiles.size", RANGE]),
        ("[tiles]\nsize = 16385", &["tiles.size", RANGE]),
        ("[extract]\ntolerance = 0", &["extract.tolerance", TOL]),
        ("[extract]\ntolerance = -0.5", &["extract.tolerance", TOL]),
        ("[extract]\ntolerance = 0.0", &["extract.tolerance", TOL]),
        ("[extract]\ntolerance = nan", &["extract.tolerance", TOL]),
        (
            "[quadtree]\nmin_resolution_c = 2",
            &["quadtree.min_resolution_c"],
        ),
        ("[extract]\nskirt_depth = -1", &["extract.skirt_depth"]),
        (
            "[extract]\ndesired_resolution_c = 0",
            &["extract.desired_resolution_c"],
        ),
        ("[output]\npreview_size = 3", &["output.preview_size"]),
        ("[tiles]\npreset = \"godot\"", &["tiles.preset"]),
        ("[output]\nmeshes = [\"stl\"]", &["output.meshes"]),
        (
            "[output]\nexr_compression = \"b44\"",
            &["output.exr_compression"],
        ),
    ];
    for (table, needles) in cases {
        let d = default_job();
        with_table(d.path(), table);
        refused(d.path(), needles);
    }
}

/// Every file under `dir` with its bytes, by relative path.
fn snapshot(dir: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    common::walk(dir)
        .into_iter()
        .filter(|p| p.is_file())
        .map(|p| {
            let rel = p
                .strip_prefix(dir)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/");
            (rel, std::fs::read(&p).unwrap())
        })
        .collect()
}

#[test]
fn default_pipeline_writes_the_whole_set() {
    let d = default_job();
    let r = terratile(d.path(), &["run", "-q", "--json"]);
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    let out = d.path().join("out");
    let files = snapshot(&out);
    let m: serde_json::Value = serde_json::from_slice(&files["manifest.json"]).unwrap();
    let tiles = m["tiles"].as_array().unwrap();
    assert!(tiles.len() >= 2, "{}", r.context());
    for t in tiles {
        // One mesh format by default: glb (engines import it; the smallest of the three).
        for kind in ["exr", "png", "raw", "glb"] {
            let f = t["files"][kind]
                .as_str()
                .unwrap_or_else(|| panic!("no {kind}\n{}", r.context()));
            assert!(files.contains_key(f), "{f} missing\n{}", r.context());
        }
        for kind in ["ply", "obj"] {
            assert!(t["files"][kind].is_null(), "{kind}\n{}", r.context());
        }
        assert!(t["triangles"].as_u64().unwrap() > 0);
    }
    for f in ["preview/relief.png", "preview/wireframe.png"] {
        assert!(files.contains_key(f), "{f}\n{}", r.context());
        image::load_from_memory(&files[f]).unwrap();
    }
    // The summary lists what is on disk, and the stages ran in order.
    let mut listed: Vec<String> = v["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap().to_string())
        .collect();
    listed.sort();
    // Every file but the marker that lets the next run replace the directory.
    assert!(files.contains_key(".terratile"), "{}", r.context());
    let outputs: Vec<String> = files
        .keys()
        .filter(|k| *k != ".terratile")
        .cloned()
        .collect();
    assert_eq!(listed, outputs);
    let stages: Vec<&str> = common::stage_names(&v);
    assert!(
        stages.ends_with(&["tiles", "quadtree", "extract", "write"]),
        "{stages:?}"
    );
    // The grid the manifest describes is the run's: the fixture's CRS, no holes.
    assert_eq!(m["crs"]["epsg"], 32632);
    assert_eq!(m["grid"]["holes"], 0);
}

#[test]
fn same_bytes_for_any_thread_count() {
    let mut first: Option<std::collections::BTreeMap<String, Vec<u8>>> = None;
    for threads in ["1", "2", "8"] {
        let d = default_job();
        terratile(d.path(), &["--threads", threads, "run", "-q"]).ok();
        let s = snapshot(&d.path().join("out"));
        if let Some(f) = &first {
            assert_eq!(f.keys().collect::<Vec<_>>(), s.keys().collect::<Vec<_>>());
            for (k, v) in &s {
                assert!(f[k] == *v, "{k} differs with {threads} threads");
            }
        }
        first = Some(s);
    }
}

#[test]
fn holes_asked_for_as_meshes() {
    let d = default_job();
    edit(d.path(), "fallback = \"smooth\"", "fallback = \"nodata\"");
    refused(
        d.path(),
        &[
            "extract:",
            "masked hole samples",
            "meshes need a filled heightfield",
        ],
    );
    // Without meshes and wireframe the holes are kept and masked.
    with_table(d.path(), "[output]\nmeshes = []\nwireframe = false");
    let r = terratile(d.path(), &["run", "-q"]);
    r.ok();
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.path().join("out/manifest.json")).unwrap())
            .unwrap();
    assert!(m["grid"]["holes"].as_u64().unwrap() > 0, "{}", r.context());
    assert_eq!(m["heightmaps"]["nodata"], 0);
    assert!(!d.path().join("out/meshes").exists());
}

#[test]
fn output_directory_that_cannot_be_written() {
    let d = default_job();
    // A file where a directory is needed: refused whoever runs the test (root included).
    std::fs::write(d.path().join("blocker"), b"not a directory").unwrap();
    edit(d.path(), "dir = \"out\"", "dir = \"blocker/out\"");
    let r = terratile(d.path(), &["run", "-q"]);
    r.input_error(&[
        "blocker: is a file, so the output directory",
        "blocker/out cannot be created",
    ]);
    assert_eq!(
        std::fs::read(d.path().join("blocker")).unwrap(),
        b"not a directory"
    );
    common::no_temporaries(d.path(), "");
}

#[test]
fn a_failed_run_leaves_the_previous_output_as_it_was() {
    let d = default_job();
    terratile(d.path(), &["run", "-q"]).ok();
    let before = snapshot(&d.path().join("out"));
    // The second run fails after reading and gridding (the holes refuse meshes).
    edit(d.path(), "fallback = \"smooth\"", "fallback = \"nodata\"");
    terratile(d.path(), &["run", "-q"]).input_error(&["masked hole samples"]);
    assert!(before == snapshot(&d.path().join("out")), "out/ changed");
    common::no_temporaries(d.path(), "");
}
