//! Regressions: file_outputs. The single-file commands (`convert`, `simplify`, `strips`,
//! `generate`) replaced whatever stood under their output name: a user's file, a symbolic
//! link, even their own input (`simplify a.obj a.obj` left a simplified `a.obj`). And
//! `generate -o a.xyz` wrote LAS bytes into the `.xyz` file, `convert … b.laz` uncompressed
//! LAS under a `.laz` name.

use crate::common::terratile;
use std::path::Path;

/// An n × n grid of quads as OBJ text (2 n² triangles).
fn grid_obj(n: usize) -> String {
    let mut s = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let z = ((i * 7 + j * 3) % 5) as f64 * 0.1;
            s += &format!("v {i} {j} {z}\n");
        }
    }
    let v = |i: usize, j: usize| j * (n + 1) + i + 1;
    for j in 0..n {
        for i in 0..n {
            s += &format!("f {} {} {}\n", v(i, j), v(i + 1, j), v(i + 1, j + 1));
            s += &format!("f {} {} {}\n", v(i, j), v(i + 1, j + 1), v(i, j + 1));
        }
    }
    s
}

fn read(dir: &Path, name: &str) -> Vec<u8> {
    std::fs::read(dir.join(name)).unwrap()
}

// `simplify a.obj a.obj` replaced the input with its simplification.
#[test]
fn simplify_into_its_own_input_is_refused() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("a.obj"), grid_obj(12)).unwrap();
    let before = read(d.path(), "a.obj");
    terratile(d.path(), &["simplify", "a.obj", "a.obj", "--ratio", "0.5"])
        .input_error(&["a.obj: the output is the input file"]);
    assert_eq!(read(d.path(), "a.obj"), before);
}

// `simplify`, `strips` and `convert` replaced a user's file under the output name.
#[test]
fn single_file_commands_keep_a_users_file() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("a.obj"), grid_obj(12)).unwrap();
    terratile(d.path(), &["generate", "-o", "s.las", "--points", "2000"]).ok();
    let cases: [(&str, &[&str]); 4] = [
        (
            "mine.obj",
            &["simplify", "a.obj", "mine.obj", "--ratio", "0.5"],
        ),
        (
            "mine.ply",
            &[
                "simplify", "a.obj", "mine.ply", "--method", "qem", "--ratio", "0.5",
            ],
        ),
        ("mine.tps", &["strips", "a.obj", "mine.tps"]),
        ("mine.las", &["convert", "s.las", "mine.las"]),
    ];
    for (name, args) in cases {
        std::fs::write(d.path().join(name), "the user's own file\n").unwrap();
        terratile(d.path(), args)
            .input_error(&[name, "already exists and terratile did not write it"]);
        assert_eq!(read(d.path(), name), b"the user's own file\n", "{args:?}");
    }
}

// A rerun into the name of the command's own earlier output must still work: terratile
// knows its files by their signature.
#[test]
fn a_rerun_replaces_terratiles_own_output() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("a.obj"), grid_obj(12)).unwrap();
    let runs: [&[&str]; 5] = [
        &["simplify", "a.obj", "b.obj", "--ratio", "0.5"],
        &["simplify", "a.obj", "b.ply", "--ratio", "0.5"],
        &["strips", "a.obj", "b.tps"],
        &["generate", "-o", "g.las", "--points", "2000"],
        &["generate", "-o", "g.xyz", "--points", "2000"],
    ];
    for args in runs {
        terratile(d.path(), args).ok();
        terratile(d.path(), args).ok();
    }
    terratile(d.path(), &["convert", "g.las", "c.las"]).ok();
    terratile(d.path(), &["convert", "g.las", "c.las"]).ok();
    terratile(
        d.path(),
        &["strips", "decode", "b.tps", "--level", "0", "l.obj"],
    )
    .ok();
    terratile(
        d.path(),
        &["strips", "decode", "b.tps", "--level", "0", "l.obj"],
    )
    .ok();
}

// A symbolic link under the output name was replaced by the file (the link was lost).
#[cfg(unix)]
#[test]
fn an_output_name_that_is_a_link_is_refused() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("a.obj"), grid_obj(12)).unwrap();
    terratile(d.path(), &["simplify", "a.obj", "b.obj", "--ratio", "0.5"]).ok();
    std::os::unix::fs::symlink("b.obj", d.path().join("l.obj")).unwrap();
    terratile(d.path(), &["simplify", "a.obj", "l.obj", "--ratio", "0.5"])
        .input_error(&["l.obj: is a symbolic link"]);
    assert!(d
        .path()
        .join("l.obj")
        .symlink_metadata()
        .unwrap()
        .file_type()
        .is_symlink());
}

// `generate -o a.xyz` wrote LAS bytes into the `.xyz` file (the format defaulted to LAS
// whatever the name said).
#[test]
fn generate_takes_the_format_from_the_name() {
    let d = tempfile::tempdir().unwrap();
    terratile(d.path(), &["generate", "-o", "a.xyz", "--points", "1000"]).ok();
    let text = String::from_utf8(read(d.path(), "a.xyz")).expect("XYZ is text");
    assert_eq!(
        text.lines().count(),
        1002,
        "comment, column names, 1000 points"
    );
    terratile(d.path(), &["generate", "-o", "b.las", "--format", "xyz"])
        .input_error(&["b.las: --format xyz does not match the file's extension"])
        .left_nothing("b.las");
}

// `generate` and `convert` wrote uncompressed LAS under a `.laz` name.
#[test]
fn uncompressed_las_is_not_named_laz() {
    let d = tempfile::tempdir().unwrap();
    terratile(d.path(), &["generate", "-o", "a.laz"])
        .input_error(&["a.laz: terratile writes uncompressed LAS; name it .las"])
        .left_nothing("a.laz");
    terratile(d.path(), &["generate", "-o", "a.las", "--points", "1000"]).ok();
    terratile(d.path(), &["convert", "a.las", "b.laz"])
        .input_error(&["b.laz: terratile writes uncompressed LAS"])
        .left_nothing("b.laz");
}

// A tiled `generate` replaced a user's file standing under one of its tile names; now every
// name is checked before the first file is written.
#[test]
fn tiled_generate_checks_every_name_first() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("t-0-1.las"), "mine\n").unwrap();
    terratile(
        d.path(),
        &[
            "generate", "-o", "t.las", "--tiles", "2x2", "--points", "4000",
        ],
    )
    .input_error(&["t-0-1.las: already exists"]);
    assert!(!d.path().join("t-0-0.las").exists());
    assert!(!d.path().join("t-1-0.las").exists());
}

// `bench table1 --plot` replaced any file under the plot's name, after minutes of measuring.
#[test]
fn bench_table1_keeps_an_existing_plot_file() {
    let d = tempfile::tempdir().unwrap();
    terratile(d.path(), &["generate", "-o", "a.las", "--points", "1000"]).ok();
    std::fs::write(d.path().join("t.png"), "mine\n").unwrap();
    terratile(d.path(), &["bench", "table1", "a.las", "--plot", "t.png"])
        .input_error(&["t.png: the plot file exists"]);
    assert_eq!(read(d.path(), "t.png"), b"mine\n");
}
