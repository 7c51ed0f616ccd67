//! COPC: `terratile convert --copc` writes COPC 1.0 that other readers read back (the `las`
//! crate's `CopcReader`, and laspy's `CopcReader` in a Python environment this test builds
//! under `target/copc-py`), with the same points as the input; the same bytes for any
//! thread count.

use crate::common::{data_file, fixture_las, python_venv, run_with, terratile};
use std::path::{Path, PathBuf};

/// A point's identity for multiset comparisons: stored coordinates and the attributes
/// point format 6/7 keep from any input.
type Key = (i64, i64, i64, u16, u8, u8, u8, u64, [u16; 3]);

fn key(p: &las::Point, t: &las::Vector<las::Transform>) -> Key {
    let raw = |v: f64, t: las::Transform| ((v - t.offset) / t.scale).round() as i64;
    let c = p.color.unwrap_or_default();
    (
        raw(p.x, t.x),
        raw(p.y, t.y),
        raw(p.z, t.z),
        p.intensity,
        p.return_number,
        p.number_of_returns,
        u8::from(p.classification),
        p.gps_time.unwrap_or(0.0).to_bits(),
        [c.red, c.green, c.blue],
    )
}

/// The input's points, sorted.
fn input_keys(path: &Path) -> Vec<Key> {
    let mut r = las::Reader::from_path(path).unwrap();
    let t = *r.header().transforms();
    let all = r.read_all().unwrap();
    let mut v: Vec<Key> = all.points().map(|p| key(&p.unwrap(), &t)).collect();
    v.sort_unstable();
    v
}

/// Converts `input` to `dir/NAME.copc.laz` with `threads` rayon threads.
fn convert(dir: &Path, input: &str, threads: &str) -> PathBuf {
    let out = dir.join(format!("t{threads}.copc.laz"));
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_terratile"));
    cmd.env("RAYON_NUM_THREADS", threads);
    let o = out.to_string_lossy().into_owned();
    run_with(cmd, dir, &["convert", input, &o, "--copc"]).ok();
    out
}

/// The checks every written file passes: deterministic, COPC info VLR at byte 375, the
/// hierarchy's nodes cover the points once, each inside its node's cube, and a query of
/// everything gives the input's points.
fn check_copc(dir: &Path, input: &str) -> PathBuf {
    let one = convert(dir, input, "1");
    let two = convert(dir, input, "2");
    let bytes = std::fs::read(&one).unwrap();
    assert!(
        bytes == std::fs::read(&two).unwrap(),
        "bytes depend on threads"
    );
    assert_eq!(&bytes[24..26], &[1, 4], "LAS 1.4");
    assert_eq!(&bytes[375 + 2..375 + 6], b"copc", "info VLR first, at 375");
    assert_eq!(u16::from_le_bytes([bytes[375 + 18], bytes[375 + 19]]), 1);
    assert!(matches!(bytes[104] & 0x3F, 6..=8), "point format 6, 7 or 8");

    let mut r = las::CopcReader::from_path(&one).unwrap();
    let t = *r.header().transforms();
    let entries: Vec<las::copc::Entry> = r.hierarchy_entries().collect();
    let total: i64 = entries.iter().map(|e| i64::from(e.point_count)).sum();
    assert_eq!(total as u64, r.header().number_of_points());
    let info = r.header().copc_info_vlr().unwrap();
    for e in &entries {
        let b = e.key.bounds(&info);
        let pts = r.read_entry(e).unwrap();
        assert_eq!(pts.len(), e.point_count as usize);
        for p in pts.points() {
            let p = p.unwrap();
            assert!(
                p.x >= b.min.x && p.x <= b.max.x && p.y >= b.min.y && p.y <= b.max.y,
                "a point of node {:?} outside its cube",
                e.key
            );
        }
    }
    let all = r
        .query(las::LodSelection::All, las::BoundsSelection::All)
        .unwrap();
    let mut got: Vec<Key> = all.points().map(|p| key(&p.unwrap(), &t)).collect();
    got.sort_unstable();
    assert!(
        got == input_keys(Path::new(input)),
        "{input}: points differ"
    );
    one
}

#[test]
fn copc_reads_back_with_the_same_points() {
    let dir = tempfile::tempdir().unwrap();
    check_copc(dir.path(), &fixture_las());
    for rel in ["lidar/autzen_trim.las", "lidar/CSite4_orig-utm.laz"] {
        if let Some(f) = data_file(rel) {
            let dir = tempfile::tempdir().unwrap();
            check_copc(dir.path(), &f.to_string_lossy());
        }
    }
}

/// laspy's COPC reader (lazrs backend) reads the file: every point, and a bounds query
/// gives exactly the points inside.
#[test]
fn copc_reads_back_in_laspy() {
    let Some(f) = data_file("lidar/autzen_trim.las") else {
        return;
    };
    let Some(py) = python_venv("copc-py", &["laspy[lazrs]"], "laspy") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = check_copc(dir.path(), &f.to_string_lossy());
    let script = r#"
import sys, laspy, numpy as np
from laspy import CopcReader, Bounds
src = laspy.read(sys.argv[1])
with CopcReader.open(sys.argv[2]) as r:
    every = r.query()
    assert len(every) == len(src.points), (len(every), len(src.points))
    a = np.sort(np.array(every.X, dtype=np.int64) * 1000003 + np.array(every.Y, dtype=np.int64))
    b = np.sort(np.array(src.X, dtype=np.int64) * 1000003 + np.array(src.Y, dtype=np.int64))
    assert (a == b).all()
    lo = np.array([src.header.mins[0] + 100, src.header.mins[1] + 100])
    hi = lo + 200
    part = r.query(Bounds(mins=lo, maxs=hi))
    x, y = np.array(src.x), np.array(src.y)
    inside = ((x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])).sum()
    assert len(part) == inside, (len(part), inside)
print("ok", len(every))
"#;
    let o = std::process::Command::new(py)
        .args(["-c", script])
        .arg(&f)
        .arg(&out)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success() && text.starts_with("ok 110000"),
        "{text}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn copc_needs_a_laz_name() {
    let dir = tempfile::tempdir().unwrap();
    let i = fixture_las();
    terratile(dir.path(), &["convert", &i, "out.las", "--copc"]).input_error(&["copc.laz"]);
}
