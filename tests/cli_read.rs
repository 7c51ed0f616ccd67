//! The CLI on reading: `info`, `generate`, `convert`, `bench read`, `run`, and every kind of
//! bad input the foundation issue lists — each a one-line error naming the file and where,
//! exit code 2, no panic and no output.

use crate::common;

use common::{terratile, Run};
use std::path::{Path, PathBuf};

/// A small valid LAS 1.2 (point format 0) made by the generator, returned as bytes.
fn small_las(dir: &Path) -> Vec<u8> {
    terratile(
        dir,
        &[
            "generate",
            "-q",
            "-o",
            "small.las",
            "--points",
            "500",
            "--size",
            "40x40",
        ],
    )
    .ok();
    std::fs::read(dir.join("small.las")).unwrap()
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// `info FILE` and `convert FILE out.las` both fail with the needles, and convert writes
/// nothing.
fn bad_point_file(dir: &Path, name: &str, needles: &[&str]) {
    let mut with_name = vec![name];
    with_name.extend_from_slice(needles);
    terratile(dir, &["info", "-q", name]).input_error(&with_name);
    let r: Run = terratile(dir, &["convert", "-q", name, "converted.las"]);
    if name.ends_with(".las") || name.ends_with(".laz") {
        // convert reads LAS/LAZ only, so it may word a bad signature differently.
        r.input_error(&[name, "byte"]).left_nothing("converted.las");
    }
}

fn patched(base: &[u8], at: usize, bytes: &[u8]) -> Vec<u8> {
    let mut v = base.to_vec();
    v[at..at + bytes.len()].copy_from_slice(bytes);
    v
}

#[test]
fn empty_file() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "empty.las", b"");
    bad_point_file(d.path(), "empty.las", &["byte 0", "empty file"]);
}

#[test]
fn truncated_header() {
    let d = tempfile::tempdir().unwrap();
    let las = small_las(d.path());
    write(d.path(), "short.las", &las[..150]);
    bad_point_file(d.path(), "short.las", &["byte 150", "truncated header"]);
}

#[test]
fn truncated_point_records() {
    let d = tempfile::tempdir().unwrap();
    let las = small_las(d.path());
    // Cut the last record in half: 499 whole records remain.
    let cut = las.len() - 10;
    write(d.path(), "cut.las", &las[..cut]);
    let offset = u32::from_le_bytes(las[96..100].try_into().unwrap()) as usize;
    let at = offset + 499 * 20;
    bad_point_file(
        d.path(),
        "cut.las",
        &[
            &format!("byte {at}"),
            "truncated point records",
            "promises 500",
            "holds 499",
        ],
    );
}

/// A header field patched to a bad value: `info` and `convert` name the field's byte.
#[test]
fn patched_header_fields() {
    let d = tempfile::tempdir().unwrap();
    let las = small_las(d.path());
    let cases: [(&str, usize, &[u8], &[&str]); 7] = [
        (
            "sig.las",
            0,
            &[0x00, 0x01, 0x02, 0x03],
            &["byte 0", "unrecognised format"],
        ),
        (
            "v2.las",
            24,
            &[2, 0],
            &["byte 24", "unsupported LAS version 2.0"],
        ),
        (
            "v15.las",
            24,
            &[1, 5],
            &["byte 25", "unsupported LAS version 1.5"],
        ),
        (
            "pf11.las",
            104,
            &[11],
            &["byte 104", "point data record format 11"],
        ),
        ("pf6.las", 104, &[6], &["byte 104", "needs LAS 1.4"]),
        (
            "scale.las",
            139,
            &0f64.to_le_bytes(),
            &["byte 139", "y scale factor is 0"],
        ),
        (
            "len.las",
            105,
            &12u16.to_le_bytes(),
            &[
                "byte 105",
                "record length 12 is too short for point format 0",
            ],
        ),
    ];
    for (name, at, bytes, needles) in cases {
        write(d.path(), name, &patched(&las, at, bytes));
        bad_point_file(d.path(), name, needles);
    }
    // With the format forced, the LAS reader names the signature.
    terratile(d.path(), &["info", "-q", "--format", "las", "sig.las"]).input_error(&[
        "sig.las",
        "byte 0",
        "signature",
    ]);
}

#[test]
fn corrupt_laz() {
    let Some(f) = common::data_file("lidar/Topography.laz") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(f).unwrap();
    // Keep the header, VLRs and chunk table pointer, lose most of the compressed data.
    let offset = u32::from_le_bytes(bytes[96..100].try_into().unwrap()) as usize;
    write(d.path(), "cut.laz", &bytes[..offset + 5000]);
    bad_point_file(d.path(), "cut.laz", &["cut.laz", "byte"]);
}

#[test]
fn xyz_errors_name_the_line() {
    let d = tempfile::tempdir().unwrap();
    let cases: [(&str, &str, &str); 5] = [
        (
            "few.xyz",
            "x y z\n1 2 3\n4 5\n",
            "few.xyz:3: expected 3 numbers (x y z), found 2",
        ),
        (
            "word.xyz",
            "# c\n1 2 3\n1 two 3\n",
            "word.xyz:3: column 2: `two` is not a number",
        ),
        (
            "nan.xyz",
            "1 2 3\n1 2 NaN\n",
            "nan.xyz:2: column 3: NaN is not a finite number",
        ),
        (
            "inf.xyz",
            "1,2,3\n4,inf,6\n",
            "inf.xyz:2: column 2: inf is not a finite number",
        ),
        ("none.xyz", "# nothing\n", "none.xyz:2: no points"),
    ];
    for (name, text, needle) in cases {
        write(d.path(), name, text.as_bytes());
        terratile(d.path(), &["info", "-q", name]).input_error(&[needle]);
    }
}

#[test]
fn xyz_error_lines_count_across_parallel_chunks() {
    let d = tempfile::tempdir().unwrap();
    let mut text = String::from("x,y,z\n");
    for i in 0..200_000 {
        text.push_str(&format!("{i}.5,{}.25,{}\n", i * 2, i % 97));
    }
    text.push_str("1,2\n");
    write(d.path(), "big.xyz", text.as_bytes());
    terratile(d.path(), &["info", "-q", "big.xyz"])
        .input_error(&["big.xyz:200002: expected 3 numbers"]);
}

#[test]
fn missing_input_file() {
    let d = tempfile::tempdir().unwrap();
    terratile(d.path(), &["info", "-q", "nope.las"]).input_error(&["nope.las", "No such file"]);
}

fn pipeline(dir: &Path, text: &str) -> Run {
    write(dir, "p.toml", text.as_bytes());
    let r = common::run_p_toml(dir);
    r.left_nothing("out");
    r
}

#[test]
fn pipeline_unknown_key() {
    let d = tempfile::tempdir().unwrap();
    pipeline(d.path(), "[input]\npaths = [\"a.las\"]\nclases = [2]\n")
        .input_error(&["p.toml:3:1: input.clases: unknown field `clases`"]);
    pipeline(
        d.path(),
        "[input]\npaths = [\"a.las\"]\n[outptu]\ndir = \"x\"\n",
    )
    .input_error(&["p.toml:3:", "outptu", "unknown field"]);
}

#[test]
fn pipeline_wrong_type() {
    let d = tempfile::tempdir().unwrap();
    pipeline(d.path(), "[input]\npaths = \"a.las\"\n")
        .input_error(&["p.toml:2:9: input.paths: invalid type: string"]);
    pipeline(d.path(), "[input]\npaths = []\ndrop_classes = [7, 300]\n")
        .input_error(&["p.toml:3:", "input.drop_classes"]);
}

#[test]
fn pipeline_missing_input_and_empty_glob() {
    let d = tempfile::tempdir().unwrap();
    pipeline(d.path(), "[input]\npaths = [\"gone.las\"]\n")
        .input_error(&["p.toml:2:1: input.paths", "gone.las does not exist"]);
    pipeline(d.path(), "[input]\npaths = [\"tiles/*.laz\"]\n").input_error(&[
        "p.toml:2:1: input.paths",
        "glob `tiles/*.laz` matches no file",
    ]);
    terratile(d.path(), &["run", "-q", "absent.toml"]).input_error(&["absent.toml"]);
}

#[test]
fn info_matches_what_generate_wrote() {
    let d = tempfile::tempdir().unwrap();
    terratile(
        d.path(),
        &[
            "generate", "-q", "-o", "g.las", "--points", "5000", "--seed", "4",
        ],
    )
    .ok();
    let r = terratile(d.path(), &["info", "--json", "g.las"]);
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    let f = &v[0];
    assert_eq!(f["stats"]["points"], 5000);
    assert_eq!(f["source"]["format"], "las");
    assert_eq!(f["source"]["version"], serde_json::json!([1, 2]));
    assert_eq!(f["source"]["crs"]["epsg"], 32632);
    let classes: u64 = f["stats"]["classes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c[1].as_u64().unwrap())
        .sum();
    assert_eq!(classes, 5000);
    assert!(f["stats"]["mean_spacing"].as_f64().unwrap() > 0.5);
    let text = terratile(d.path(), &["info", "g.las"]);
    text.ok();
    assert!(
        text.stdout.contains("points        5000"),
        "{}",
        text.context()
    );
    assert!(text.stdout.contains("EPSG:32632"));
}

#[test]
fn bench_read_reports_the_ratio() {
    let d = tempfile::tempdir().unwrap();
    small_las(d.path());
    let r = terratile(
        d.path(),
        &["bench", "read", "small.las", "--json", "--repeat", "1"],
    );
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    assert!(v["ratio"].as_f64().unwrap() > 0.0);
    assert_eq!(v["points"], 500);
}

#[test]
fn convert_keeps_records_and_samples() {
    let d = tempfile::tempdir().unwrap();
    small_las(d.path());
    terratile(
        d.path(),
        &["convert", "-q", "small.las", "first.las", "--first", "100"],
    )
    .ok();
    terratile(
        d.path(),
        &[
            "convert",
            "-q",
            "small.las",
            "sample.las",
            "--sample",
            "100",
            "--seed",
            "5",
        ],
    )
    .ok();
    let opts = terratile::ReadOptions::default();
    let all = terratile::points::read(&d.path().join("small.las"), &opts, &terratile::NoProgress)
        .unwrap();
    let first = terratile::points::read(&d.path().join("first.las"), &opts, &terratile::NoProgress)
        .unwrap();
    let sample =
        terratile::points::read(&d.path().join("sample.las"), &opts, &terratile::NoProgress)
            .unwrap();
    assert_eq!(first.x[..], all.x[..100]);
    assert_eq!(first.classification[..], all.classification[..100]);
    assert_eq!(sample.len(), 100);
    assert!(sample.x.iter().all(|x| all.x.contains(x)));
    assert_eq!(sample.crs(), all.crs());
    terratile(
        d.path(),
        &["convert", "-q", "small.las", "big.las", "--first", "501"],
    )
    .input_error(&["small.las", "holds 500"]);
}

#[test]
fn default_job_runs_from_a_copy() {
    let job = common::default_job();
    let r = terratile(job.path(), &["run", "--json"]);
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    assert_eq!(v["inputs"].as_array().unwrap().len(), 2);
    assert_eq!(v["points"], 110_000);
}
