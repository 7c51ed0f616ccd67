//! COPC: `terratile convert --copc` writes COPC 1.0 that other readers read back (the `las`
//! crate's `CopcReader`, and laspy's `CopcReader` in a Python environment this test builds
//! under `target/copc-py`), with the same points as the input; the same bytes for any
//! thread count.

use crate::common::{data_file, fixture_las, python_venv, run_with, same_tree, terratile};
use serde_json::Value;
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

/// Converts the shared file `rel` to COPC in `dir`; None (skipping) without the data.
fn copc_of(dir: &Path, rel: &str) -> Option<(PathBuf, PathBuf)> {
    let f = data_file(rel)?;
    let out = dir.join("in.copc.laz");
    let o = out.to_string_lossy().into_owned();
    terratile(dir, &["convert", &f.to_string_lossy(), &o, "--copc"]).ok();
    Some((f, out))
}

/// Runs `input` as `NAME.toml` (output `out_NAME`) with `[scale]` `mode`, `budget` and
/// `read`; returns the JSON summary.
fn run(dir: &Path, name: &str, input: &Path, mode: &str, budget: &str, read: &str) -> Value {
    let text = format!(
        "[input]\npaths = [{:?}]\n[output]\ndir = \"out_{name}\"\n[scale]\nmode = \"{mode}\"\n\
         memory_budget = \"{budget}\"\nread = \"{read}\"\n",
        input.to_string_lossy()
    );
    let p = dir.join(format!("{name}.toml"));
    std::fs::write(&p, text).unwrap();
    let r = terratile(dir, &["run", "-q", "--json", &p.to_string_lossy()]);
    serde_json::from_str(&r.ok().stdout).unwrap()
}

/// A figure of a stage in a run's summary.
fn figure(s: &Value, stage: &str, key: &str) -> Option<String> {
    s["stages"]
        .as_array()?
        .iter()
        .find(|st| st["stage"] == stage)?["figures"]
        .as_array()?
        .iter()
        .find(|f| f[0] == key)
        .and_then(|f| f[1].as_str().map(str::to_string))
}

/// The streaming run on a COPC file with `read = "direct"` reads it node by node (the counting pass once, then
/// each window only the nodes its range meets) and writes the bytes of the in-memory run on
/// the same file and on the original file's points, for several shard sizes; the plain LAZ
/// read by bounds decodes the whole file in every window.
fn stream_by_nodes(rel: &str) {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let Some((orig, copc)) = copc_of(d, rel) else {
        return;
    };
    run(d, "orig", &orig, "memory", "1GiB", "auto");
    run(d, "memory", &copc, "memory", "1GiB", "auto");
    same_tree(&d.join("out_orig"), &d.join("out_memory"));
    let points: f64 = figure(
        &run(d, "count", &copc, "stream", "1GiB", "direct"),
        "bucket",
        "points",
    )
    .unwrap()
    .parse()
    .unwrap();
    for budget in ["12MiB", "24MiB", "64MiB"] {
        let name = format!("s{budget}");
        let s = run(d, &name, &copc, "stream", budget, "direct");
        assert_eq!(figure(&s, "bucket", "read").as_deref(), Some("by bounds"));
        same_tree(&d.join("out_memory"), &d.join(format!("out_{name}")));
        let windows: f64 = figure(&s, "denoise", "windows").unwrap().parse().unwrap();
        let decoded: f64 = figure(&s, "denoise", "points decoded")
            .unwrap()
            .parse()
            .unwrap();
        if windows > 1.0 {
            // Each window decodes its nodes only: far fewer than the whole file each time.
            assert!(
                decoded < 0.75 * windows * points,
                "{decoded} of {points} x {windows}"
            );
        }
    }
    // `auto` buckets a COPC file as it does LAZ (cheaper in CPU), with the same bytes.
    let s = run(d, "auto", &copc, "stream", "12MiB", "auto");
    assert_eq!(figure(&s, "bucket", "read").as_deref(), Some("bricks"));
    same_tree(&d.join("out_memory"), &d.join("out_auto"));
    // The same file as plain LAZ read by bounds: every window decodes all of it.
    let laz = d.join("plain.laz");
    std::fs::copy(&orig, &laz).unwrap();
    if orig.extension().is_some_and(|e| e == "laz") {
        let s = run(d, "plain", &laz, "stream", "12MiB", "direct");
        let c = run(d, "copc12", &copc, "stream", "12MiB", "direct");
        let dec = |s: &Value| -> f64 {
            figure(s, "denoise", "points decoded")
                .unwrap()
                .parse()
                .unwrap()
        };
        assert!(dec(&c) < dec(&s), "COPC {} vs LAZ {}", dec(&c), dec(&s));
    }
}

#[test]
fn stream_reads_copc_by_nodes_on_csite4() {
    stream_by_nodes("lidar/CSite4_orig-utm.laz");
}

#[test]
fn stream_reads_copc_by_nodes_on_autzen_trim() {
    stream_by_nodes("lidar/autzen_trim.las");
}

/// Shard jobs (plan, shard, merge) on a COPC file write the in-memory run's bytes.
#[test]
fn shard_jobs_on_copc_equal_memory() {
    let dir = tempfile::tempdir().unwrap();
    for rel in ["lidar/autzen_trim.las", "lidar/CSite4_orig-utm.laz"] {
        if let Some((_, copc)) = copc_of(dir.path(), rel) {
            let kept = dir.path().join(format!("{}.copc.laz", rel.len()));
            std::fs::rename(&copc, &kept).unwrap();
            crate::shard_jobs::check_identical(&kept, "[tiles]\nsize = 129\n", 4);
        }
    }
}

/// A broken COPC hierarchy (a page past the end of the file, a node whose chunk lies past
/// it, a file cut inside the hierarchy) is one line and exit 2 in a streaming run.
#[test]
fn bad_copc_is_one_line_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let Some((_, copc)) = copc_of(d, "lidar/CSite4_orig-utm.laz") else {
        return;
    };
    let b = std::fs::read(&copc).unwrap();
    let info = 375 + 54;
    let u64_at = |b: &[u8], at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap());
    let (root, size) = (u64_at(&b, info + 40) as usize, u64_at(&b, info + 48));
    let mut past = b.clone();
    past[root + 32 * 2 + 16..root + 32 * 2 + 24]
        .copy_from_slice(&(b.len() as u64 + 9).to_le_bytes());
    let mut page = b.clone();
    page[info + 48..info + 56].copy_from_slice(&(size + 3200).to_le_bytes());
    let cut = b[..b.len() - 100].to_vec();
    for (name, bytes, needle) in [
        ("past", past, "outside the point data"),
        ("page", page, "hierarchy page"),
        ("cut", cut, "EVLR"),
    ] {
        let f = d.join(format!("{name}.copc.laz"));
        std::fs::write(&f, bytes).unwrap();
        let text = format!(
            "[input]\npaths = [{:?}]\n[output]\ndir = \"out_{name}\"\n[scale]\nmode = \"stream\"\n",
            f.to_string_lossy()
        );
        std::fs::write(d.join("bad.toml"), text).unwrap();
        terratile(d, &["run", "-q", "bad.toml"])
            .input_error(&[needle])
            .left_nothing(&format!("out_{name}"));
    }
}
