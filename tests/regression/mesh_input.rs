//! Regressions: mesh_input (issue 14, meshes): header-driven allocations and spins in the
//! PLY reader, files peers read that we refused, `compare` on glb, `--samples` bounds.
//! Every command runs under an 8 GiB address-space cap (`prlimit --as`) when `prlimit` is
//! there, as the acceptance asks.

use crate::common::{self, Run};
use std::path::Path;
use std::time::{Duration, Instant};

use crate::mesh_corpus as corpus;

use corpus::Expect;

/// `terratile ARGS` in `dir` under `prlimit --as=8GiB` (plain when prlimit is missing).
fn capped(dir: &Path, args: &[&str]) -> Run {
    let bin = env!("CARGO_BIN_EXE_terratile");
    let has_prlimit = std::process::Command::new("prlimit")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    let cmd = if has_prlimit {
        let mut c = std::process::Command::new("prlimit");
        c.arg("--as=8589934592").arg(bin);
        c
    } else {
        std::process::Command::new(bin)
    };
    common::run_with(cmd, dir, args)
}

fn write_case(dir: &Path, name: &str) {
    let case = corpus::cases()
        .into_iter()
        .find(|c| c.name == name)
        .unwrap_or_else(|| panic!("no corpus case {name}"));
    std::fs::write(dir.join(name), case.bytes).unwrap();
}

/// Warning lines (`terratile: warning: …`) of a run.
fn warnings(r: &Run) -> Vec<&str> {
    r.stderr
        .lines()
        .filter(|l| l.starts_with("terratile: warning: "))
        .collect()
}

/// `compare FILE FILE` on one corpus case: what the corpus says, within 20 s.
fn check_case(name: &str) {
    let dir = tempfile::tempdir().unwrap();
    write_case(dir.path(), name);
    let expect = corpus::cases()
        .into_iter()
        .find(|c| c.name == name)
        .unwrap()
        .expect;
    let t = Instant::now();
    let lenient = capped(dir.path(), &["compare", name, name, "--samples", "2000"]);
    let strict = capped(
        dir.path(),
        &["compare", name, name, "--samples", "2000", "--strict"],
    );
    assert!(
        t.elapsed() < Duration::from_secs(20),
        "{name}: took {:?}",
        t.elapsed()
    );
    match expect {
        Expect::Refused(needle) => {
            lenient.input_error(&[name, needle]);
            strict.input_error(&[name, needle]);
        }
        Expect::Lenient(warning, refusal) => {
            lenient.ok();
            // One line per kind of problem; this one among them.
            let w = warnings(&lenient);
            assert!(
                w.iter().any(|l| l.contains(warning)),
                "{}",
                lenient.context()
            );
            strict.input_error(&[refusal]);
        }
        Expect::Clean => {
            lenient.ok();
            strict.ok();
            assert!(warnings(&lenient).is_empty(), "{}", lenient.context());
        }
    }
}

/// `element vertex 1000000000000` made the PLY reader reserve 12 TB and abort (exit 134,
/// "memory allocation … failed", no file name).
#[test]
fn ply_vertex_count_of_10_to_12_reserved_12_tb_and_aborted() {
    check_case("vertex_1e12.ply");
}

/// A PLY element with no properties and 10^18 records made the reader loop forever.
#[test]
fn ply_element_without_properties_and_10_to_18_records_spun_forever() {
    check_case("empty_element_1e18.ply");
}

/// A binary PLY face count of 10^18 is refused from the header, not read until the file ends.
#[test]
fn ply_face_count_of_10_to_18_is_refused_from_the_header() {
    check_case("faces_1e18.ply");
}

/// `simplify` on a PLY with a vertex count of 2^62 panicked ("capacity overflow"), exit 1.
#[test]
fn simplify_on_ply_with_2_to_62_vertices_panicked() {
    let dir = tempfile::tempdir().unwrap();
    write_case(dir.path(), "vertex_2e62.ply");
    capped(
        dir.path(),
        &["simplify", "vertex_2e62.ply", "out.ply", "--ratio", "0.5"],
    )
    .input_error(&[
        "vertex_2e62.ply:3:",
        "element `vertex` declares 4611686018427387904 records",
    ])
    .left_nothing("out.ply");
}

/// A texture-coordinate index out of range (trimesh's cubevt.obj) was refused; trimesh
/// and MeshLab read the file. Now the texture coordinates are dropped with a warning.
#[test]
fn obj_texture_index_out_of_range_was_refused() {
    check_case("texture_index_out_of_range.obj");
}

/// A normal index out of range mid-file (face_in_group_name_mid_file.obj) was refused.
#[test]
fn obj_normal_index_out_of_range_was_refused() {
    check_case("normal_index_out_of_range.obj");
}

/// A `nan` vertex colour (nancolor.obj) was refused as if it were a coordinate.
#[test]
fn obj_nan_vertex_colour_was_refused() {
    check_case("nan_colour.obj");
}

/// A face with two indices (notenoughindices.obj) refused the whole file.
#[test]
fn obj_face_with_two_indices_was_refused() {
    check_case("two_index_faces.obj");
}

/// The OBJ line continuation `\` (wallhole.obj) was not followed.
#[test]
fn obj_line_continuation_was_not_followed() {
    check_case("line_continuation.obj");
    let dir = tempfile::tempdir().unwrap();
    write_case(dir.path(), "line_continuation.obj");
    let r = capped(
        dir.path(),
        &[
            "compare",
            "line_continuation.obj",
            "line_continuation.obj",
            "--json",
            "--samples",
            "2000",
        ],
    );
    let v: serde_json::Value = serde_json::from_str(&r.ok().stdout).unwrap();
    assert_eq!(v["triangles"][0], 2, "{}", r.context());
}

/// PLY: a NaN colour is dropped and a 2-vertex face skipped, like the OBJ cases.
#[test]
fn ply_nan_colour_and_short_face_were_refused() {
    check_case("nan_colour_short_face.ply");
}

/// What would corrupt the geometry stays an error, lenient or strict.
#[test]
fn bad_vertex_indices_and_nan_positions_stay_errors() {
    for name in [
        "vertex_index_out_of_range.obj",
        "nan_position.obj",
        "nan_position.ply",
    ] {
        check_case(name);
    }
}

/// Every corpus file gives what the corpus says (the cases above and the glb ones).
#[test]
fn the_bad_mesh_corpus_reads_as_documented() {
    for c in corpus::cases() {
        check_case(c.name);
    }
}

/// `compare` could not read terratile's own `.glb` tile meshes.
#[test]
fn compare_could_not_read_our_own_glb() {
    let job = common::default_job();
    let pipeline = job.path().join("pipeline.toml");
    let text = std::fs::read_to_string(&pipeline).unwrap();
    let text = text
        .lines()
        .map(|l| {
            if l.trim_start().starts_with("meshes =") {
                "meshes = [\"obj\", \"glb\"]".to_string()
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    std::fs::write(&pipeline, text).unwrap();
    common::terratile(job.path(), &["run", "pipeline.toml", "-q"]).ok();
    let meshes = job.path().join("out/meshes");
    let mut glbs: Vec<_> = std::fs::read_dir(&meshes)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "glb"))
        .collect();
    glbs.sort();
    assert!(!glbs.is_empty(), "no glb tiles in {}", meshes.display());
    for glb in glbs {
        let obj = glb.with_extension("obj");
        let r = capped(
            &meshes,
            &[
                "compare",
                obj.to_str().unwrap(),
                glb.to_str().unwrap(),
                "--json",
                "--samples",
                "20000",
            ],
        );
        let v: serde_json::Value =
            serde_json::from_str(&r.ok().stdout).unwrap_or_else(|e| panic!("{e}\n{}", r.context()));
        // The same tile in two formats: the same triangles at the same places.
        assert_eq!(v["triangles"][0], v["triangles"][1], "{}", r.context());
        assert!(v["triangles"][0].as_u64().unwrap() > 0);
        // (Distances are computed, so "zero" is a rounding error's worth.)
        assert!(
            v["error"]["max"].as_f64().unwrap() < 1e-9,
            "{}",
            r.context()
        );
        assert!(v["warnings"].as_array().unwrap().is_empty());
    }
}

/// `--samples 1e11` (simplify, compare) ran for a minute and aborted; now refused up front.
#[test]
fn samples_of_10_to_11_ran_a_minute_and_aborted() {
    let dir = tempfile::tempdir().unwrap();
    write_case(dir.path(), "line_continuation.obj");
    let t = Instant::now();
    capped(
        dir.path(),
        &[
            "compare",
            "line_continuation.obj",
            "line_continuation.obj",
            "--samples",
            "100000000000",
        ],
    )
    .input_error(&["--samples 100000000000", "at most 100000000"]);
    capped(
        dir.path(),
        &[
            "simplify",
            "line_continuation.obj",
            "out.obj",
            "--ratio",
            "0.5",
            "--samples",
            "100000000000",
        ],
    )
    .input_error(&["--samples 100000000000", "at most 100000000"])
    .left_nothing("out.obj");
    assert!(t.elapsed() < Duration::from_secs(10), "{:?}", t.elapsed());
}

/// `strict = true` in an `[[assets]]` entry refuses what the default reading warns about;
/// without it the run reads the model and the summary carries the warning.
#[test]
fn asset_strict_refuses_what_lenient_reading_warns_about() {
    let job = common::default_job();
    write_case(job.path(), "two_index_faces.obj");
    let base = std::fs::read_to_string(job.path().join("pipeline.toml")).unwrap();
    let asset = |strict: bool| {
        format!(
            "{base}\n[[assets]]\ninput = \"two_index_faces.obj\"\noutput = \"assets/m.ply\"\n\
             strict = {strict}\n[assets.place]\nx = 513160\ny = 5403100\nup = \"z\"\n"
        )
    };
    std::fs::write(job.path().join("lenient.toml"), asset(false)).unwrap();
    std::fs::write(job.path().join("strict.toml"), asset(true)).unwrap();
    let r = common::terratile(job.path(), &["run", "lenient.toml", "--json", "-q"]);
    let v: serde_json::Value =
        serde_json::from_str(&r.ok().stdout).unwrap_or_else(|e| panic!("{e}\n{}", r.context()));
    let w = v["assets"][0]["warnings"].as_array().unwrap();
    assert_eq!(w.len(), 1, "{}", r.context());
    assert!(
        w[0].as_str()
            .unwrap()
            .contains("this one has 2: skipped (and 1 more)"),
        "{w:?}"
    );
    common::terratile(job.path(), &["run", "strict.toml", "-q"])
        .input_error(&["two_index_faces.obj:5:", "a face needs at least 3 vertices"]);
}
