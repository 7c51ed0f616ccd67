//! The streaming run of `terratile run` (`[scale]`): byte-identical outputs to the in-memory
//! run on real surveys and on a glob of generated tiles, with a budget small enough that
//! several denoise windows and grid shards are used; the automatic choice; clean-up of the
//! temporary files on failure and on SIGINT; resume after a crash; a directory that is not
//! terratile's is never touched.

use crate::common::{data_file, terratile, walk, Run};
use std::path::{Path, PathBuf};

/// Writes `NAME.toml` in `dir`: `inputs`, output `out_NAME`, `[scale]` with `mode` and a
/// budget, plus `extra` TOML.
fn pipeline(dir: &Path, name: &str, inputs: &[&str], mode: &str, extra: &str) -> PathBuf {
    let paths: Vec<String> = inputs.iter().map(|p| format!("{p:?}")).collect();
    let text = format!(
        "[input]\npaths = [{}]\n[output]\ndir = \"out_{name}\"\n[scale]\nmode = \"{mode}\"\n\
         memory_budget = \"16MiB\"\n{extra}",
        paths.join(", ")
    );
    let p = dir.join(format!("{name}.toml"));
    std::fs::write(&p, text).unwrap();
    p
}

fn run_json(dir: &Path, toml: &Path, env: &[(&str, &str)]) -> Run {
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_terratile"));
    for (k, v) in env {
        cmd.env(k, v);
    }
    let p = toml.to_string_lossy().into_owned();
    crate::common::run_with(cmd, dir, &["run", "-q", "--json", &p])
}

fn summary(r: &Run) -> serde_json::Value {
    serde_json::from_str(&r.stdout).unwrap_or_else(|e| panic!("{e}\n{}", r.context()))
}

/// The figure `key` of stage `stage` in a JSON summary.
fn figure(s: &serde_json::Value, stage: &str, key: &str) -> Option<String> {
    let st = s["stages"]
        .as_array()?
        .iter()
        .find(|x| x["stage"] == stage)?;
    st["figures"]
        .as_array()?
        .iter()
        .find(|f| f[0] == key)
        .and_then(|f| f[1].as_str().map(String::from))
}

/// Asserts that the run's bucket stage read its inputs by bounds (no bricks).
fn assert_read_by_bounds(sum: &serde_json::Value, r: &Run) {
    assert_eq!(
        figure(sum, "bucket", "read").as_deref(),
        Some("by bounds"),
        "{}",
        r.context()
    );
}

/// Asserts that two output directories hold the same files with the same bytes.
fn same_tree(a: &Path, b: &Path) {
    let rel = |d: &Path| -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = walk(d)
            .into_iter()
            .filter(|p| p.is_file())
            .map(|p| p.strip_prefix(d).unwrap().to_path_buf())
            .collect();
        v.sort();
        v
    };
    let (fa, fb) = (rel(a), rel(b));
    assert_eq!(
        fa,
        fb,
        "different files in {} and {}",
        a.display(),
        b.display()
    );
    assert!(!fa.is_empty());
    for f in &fa {
        let (x, y) = (
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
        );
        assert!(x == y, "{} differs between memory and stream", f.display());
    }
}

/// Asserts that the run's grid was cut into more than one shard.
fn assert_several_shards(sum: &serde_json::Value, r: &Run) {
    let shards: usize = figure(sum, "grid shards", "shards")
        .unwrap()
        .parse()
        .unwrap();
    assert!(shards > 1, "one shard only\n{}", r.context());
}

/// No temporary directory of the streaming run is left in `dir`.
fn no_stream_dir(dir: &Path, r: &Run) {
    let left: Vec<_> = walk(dir)
        .into_iter()
        .filter(|p| p.to_string_lossy().ends_with(".stream"))
        .collect();
    assert!(left.is_empty(), "left {left:?}\n{}", r.context());
}

/// Memory and stream runs of `inputs` in `dir`; asserts identical outputs and that the
/// streaming run used several windows and shards; returns the stream summary.
fn equivalent(dir: &Path, inputs: &[&str], extra: &str) -> serde_json::Value {
    let m = pipeline(dir, "memory", inputs, "memory", extra);
    let s = pipeline(dir, "stream", inputs, "stream", extra);
    let rm = run_json(dir, &m, &[]);
    rm.ok();
    let rs = run_json(dir, &s, &[]);
    rs.ok();
    let sum = summary(&rs);
    assert!(
        figure(&sum, "bucket", "bricks").is_some(),
        "{}",
        rs.context()
    );
    assert_several_shards(&sum, &rs);
    if !extra.contains("[denoise]") {
        let w: usize = figure(&sum, "denoise", "windows").unwrap().parse().unwrap();
        assert!(w > 1, "one denoise window only\n{}", rs.context());
    }
    same_tree(&dir.join("out_memory"), &dir.join("out_stream"));
    no_stream_dir(dir, &rs);
    sum
}

fn real(rel: &str) -> Option<String> {
    data_file(rel).map(|p| p.to_string_lossy().into_owned())
}

/// The default pipeline streamed and in memory on one real survey (skipped without the data).
fn stream_equals_memory_on(rel: &str) {
    let Some(f) = real(rel) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    equivalent(dir.path(), &[&f], "");
}

#[test]
fn stream_equals_memory_on_csite4() {
    stream_equals_memory_on("lidar/CSite4_orig-utm.laz");
}

#[test]
fn stream_equals_memory_on_autzen_trim() {
    stream_equals_memory_on("lidar/autzen_trim.las");
}

#[test]
fn stream_equals_memory_on_fsite5() {
    stream_equals_memory_on("lidar/FSite5_orig-utm.laz");
}

#[test]
fn stream_equals_memory_on_bcts_3_with_taller_voxels() {
    // More than 1 % of bcts_3's points fail the count at voxels one spacing tall: the run
    // reads every window again for the counts at every height and filters at the chosen one
    // (the first read at height 1 is then not the answer).
    let Some(f) = real("lidar/bcts_3.laz") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let s = equivalent(dir.path(), &[&f], "");
    let q: u32 = figure(&s, "denoise", "voxel height steps")
        .unwrap()
        .parse()
        .unwrap();
    assert!(q > 1, "voxel height steps {q}");
}

/// Generated tiles of one survey in `dir/tiles`.
fn tiles(dir: &Path, points: &str) {
    std::fs::create_dir(dir.join("tiles")).unwrap();
    terratile(
        dir,
        &[
            "generate",
            "-o",
            "tiles/s.las",
            "--points",
            points,
            "--tiles",
            "2x2",
        ],
    )
    .ok();
}

#[test]
fn stream_equals_memory_on_a_glob_of_tiles() {
    for extra in ["", "[fill]\nradius = 2.0\n", "[denoise]\nenabled = false\n"] {
        let dir = tempfile::tempdir().unwrap();
        tiles(dir.path(), "300000");
        equivalent(dir.path(), &["tiles/*.las"], extra);
    }
}

#[test]
fn both_smooth_fill_paths_equal_memory() {
    // Under 16 MiB the prepared grid shards do not fit half the budget: each goes to its own
    // temporary file after the first step and is read back for the second (every shard
    // prepared once). Under 64 MiB they fit and are kept in memory between the steps. Both
    // give the in-memory bytes, and no spilled shard is left behind.
    for (budget, kept) in [("16MiB", "false"), ("64MiB", "true")] {
        let dir = tempfile::tempdir().unwrap();
        tiles(dir.path(), "300000");
        let m = pipeline(dir.path(), "memory", &["tiles/*.las"], "memory", "");
        let s = pipeline(dir.path(), "stream", &["tiles/*.las"], "stream", "");
        let text = std::fs::read_to_string(&s).unwrap();
        std::fs::write(&s, text.replace("\"16MiB\"", &format!("{budget:?}"))).unwrap();
        run_json(dir.path(), &m, &[]).ok();
        let r = run_json(dir.path(), &s, &[]);
        r.ok();
        let sum = summary(&r);
        let got = figure(&sum, "grid shards", "prepared shards kept");
        assert_eq!(got.as_deref(), Some(kept), "{budget}\n{}", r.context());
        let spilled = figure(&sum, "grid shards", "prepared shards spilled");
        let want = if kept == "true" { "false" } else { "true" };
        assert_eq!(spilled.as_deref(), Some(want), "{budget}\n{}", r.context());
        let bytes = figure(&sum, "grid shards", "prepared spill");
        assert_eq!(bytes.is_some(), want == "true", "{budget}\n{}", r.context());
        let shards: usize = figure(&sum, "grid shards", "shards")
            .unwrap()
            .parse()
            .unwrap();
        assert!(shards > 1, "{budget}: one shard only\n{}", r.context());
        same_tree(
            &dir.path().join("out_memory"),
            &dir.path().join("out_stream"),
        );
        no_stream_dir(dir.path(), &r);
    }
}

#[test]
fn auto_streams_only_beyond_the_budget() {
    let dir = tempfile::tempdir().unwrap();
    tiles(dir.path(), "200000");
    let p = pipeline(dir.path(), "auto", &["tiles/*.las"], "auto", "");
    let r = run_json(dir.path(), &p, &[]);
    r.ok();
    assert!(
        figure(&summary(&r), "bucket", "bricks").is_some(),
        "{}",
        r.context()
    );
    // `--max-memory` wins over `memory_budget`: with 4 GiB the run stays in memory.
    let args = ["run", "-q", "--json", "--max-memory", "4GiB", "auto.toml"];
    let r = terratile(dir.path(), &args);
    r.ok();
    let s = summary(&r);
    assert!(figure(&s, "read", "points").is_some(), "{}", r.context());
    // A stage that needs every point cannot be streamed: one line naming its key.
    let p = pipeline(
        dir.path(),
        "ground",
        &["tiles/*.las"],
        "auto",
        "[ground]\nenabled = true\n",
    );
    run_json(dir.path(), &p, &[]).input_error(&["ground.enabled", "cannot be streamed"]);
    no_stream_dir(dir.path(), &r);
}

#[test]
fn a_failed_stream_removes_its_temporary_files() {
    let dir = tempfile::tempdir().unwrap();
    tiles(dir.path(), "200000");
    // The last tile loses its last records: the headers scan fine, bucketing fails on it
    // after the first tiles' bricks are written.
    let mut last: Vec<PathBuf> = walk(&dir.path().join("tiles"))
        .into_iter()
        .filter(|p| p.is_file())
        .collect();
    last.sort();
    let victim = last.last().unwrap();
    let bytes = std::fs::read(victim).unwrap();
    std::fs::write(victim, &bytes[..bytes.len() - 1000]).unwrap();
    let p = pipeline(dir.path(), "stream", &["tiles/*.las"], "stream", "");
    let r = run_json(dir.path(), &p, &[]);
    r.input_error(&["truncated point records"]);
    r.left_nothing("out_stream");
    no_stream_dir(dir.path(), &r);
}

#[test]
fn a_crashed_stream_resumes_its_finished_windows() {
    let dir = tempfile::tempdir().unwrap();
    tiles(dir.path(), "300000");
    let p = pipeline(dir.path(), "stream", &["tiles/*.las"], "stream", "");
    // The test hook stops the process outright after two denoise windows, as a kill would.
    let r = run_json(dir.path(), &p, &[("TERRATILE_STREAM_CRASH_AFTER", "2")]);
    assert_eq!(r.code, 101, "{}", r.context());
    let tmp = dir.path().join(".out_stream.stream");
    assert!(tmp.join("bricks.json").is_file(), "{}", r.context());
    let r = run_json(dir.path(), &p, &[]);
    r.ok();
    let s = summary(&r);
    assert_eq!(figure(&s, "bucket", "resumed").as_deref(), Some("true"));
    let resumed: usize = figure(&s, "denoise", "windows resumed")
        .unwrap()
        .parse()
        .unwrap();
    assert!(resumed >= 2, "{}", r.context());
    no_stream_dir(dir.path(), &r);
    // What a resumed run writes is what the in-memory run writes.
    let m = pipeline(dir.path(), "memory", &["tiles/*.las"], "memory", "");
    run_json(dir.path(), &m, &[]).ok();
    same_tree(
        &dir.path().join("out_memory"),
        &dir.path().join("out_stream"),
    );
    // Changed settings do not resume: the old files are dropped, not reused.
    let r = run_json(dir.path(), &p, &[("TERRATILE_STREAM_CRASH_AFTER", "1")]);
    assert_eq!(r.code, 101, "{}", r.context());
    std::fs::write(
        &p,
        std::fs::read_to_string(&p).unwrap() + "[denoise]\nmin_points = 4\n",
    )
    .unwrap();
    let r = run_json(dir.path(), &p, &[]);
    r.ok();
    assert_eq!(
        figure(&summary(&r), "bucket", "resumed").as_deref(),
        Some("false")
    );
}

#[test]
fn a_directory_that_is_not_terratiles_is_refused_and_kept() {
    let dir = tempfile::tempdir().unwrap();
    tiles(dir.path(), "50000");
    let tmp = dir.path().join(".out_stream.stream");
    std::fs::create_dir(&tmp).unwrap();
    std::fs::write(tmp.join("mine.txt"), "user data").unwrap();
    let p = pipeline(dir.path(), "stream", &["tiles/*.las"], "stream", "");
    run_json(dir.path(), &p, &[]).input_error(&["not made by terratile"]);
    assert_eq!(
        std::fs::read_to_string(tmp.join("mine.txt")).unwrap(),
        "user data"
    );
}

/// Runs a streamed job on autzen_trim and sends SIGINT once bricks are being written;
/// `user_file` is first dropped into the temporary directory. Returns the job's directory and
/// the temporary directory, or None where the run could not be interrupted in time.
#[cfg(unix)]
fn interrupted_stream(user_file: Option<&str>) -> Option<(tempfile::TempDir, PathBuf)> {
    interrupted_stream_at("brick-", user_file)
}

/// [`interrupted_stream`], signalled once a temporary file whose name holds `at` exists.
#[cfg(unix)]
fn interrupted_stream_at(
    at: &str,
    user_file: Option<&str>,
) -> Option<(tempfile::TempDir, PathBuf)> {
    let f = real("lidar/autzen_trim.las")?;
    let dir = tempfile::tempdir().unwrap();
    // LAS tiles are read by bounds (no bricks) unless bricks are asked for.
    let extra = if at == "brick-" {
        "read = \"bricks\"\n"
    } else {
        ""
    };
    let p = pipeline(dir.path(), "stream", &[&f], "stream", extra);
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_terratile"))
        .args(["run", "-q"])
        .arg(&p)
        .current_dir(dir.path())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let tmp = dir.path().join(".out_stream.stream");
    let t = std::time::Instant::now();
    // Signalled once the bricks (or the files named by `at`) are being written.
    while !walk(&tmp).iter().any(|p| p.to_string_lossy().contains(at)) {
        if t.elapsed().as_secs() > 60 || child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    if let Some(name) = user_file {
        let _ = std::fs::write(tmp.join(name), "user data");
    }
    if child.try_wait().unwrap().is_some() {
        eprintln!("skipped: the run finished before it could be interrupted");
        return None;
    }
    let ok = std::process::Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(ok.success());
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130));
    assert!(!dir.path().join("out_stream").exists());
    Some((dir, tmp))
}

#[cfg(unix)]
#[test]
fn sigint_removes_the_temporary_files() {
    let Some((_dir, tmp)) = interrupted_stream(None) else {
        return;
    };
    assert!(!tmp.exists(), "temporary directory left after SIGINT");
}

/// Interrupted while the grid shards are prepared (16 MiB: they do not fit, so each goes
/// to its own `prepared-I.bin`), the run removes those files with the others.
#[cfg(unix)]
#[test]
fn sigint_removes_the_spilled_prepared_shards() {
    let Some((_dir, tmp)) = interrupted_stream_at("prepared-", None) else {
        return;
    };
    assert!(!tmp.exists(), "temporary directory left after SIGINT");
}

/// The signal handler removed the streaming run's temporary directory whole
/// (`remove_dir_all`), a file someone else had put in it too; it now removes only the names
/// the run writes, and the directory only when nothing else is left. (The handler first
/// waits for the files being written and stops new ones, so no brick or prepared shard is
/// created after its last pass: under load `sigint_removes_the_spilled_prepared_shards`
/// found a `prepared-I.bin` written after it.)
#[cfg(unix)]
#[test]
fn sigint_keeps_a_foreign_file_in_the_temporary_directory() {
    let Some((_dir, tmp)) = interrupted_stream(Some("notes.txt")) else {
        return;
    };
    assert_eq!(
        std::fs::read_to_string(tmp.join("notes.txt")).unwrap(),
        "user data"
    );
    assert!(!tmp.join("job.txt").exists(), "the run's marker is removed");
}

/// `equivalent` with `[input]` extended by `input` (TOML lines) in both pipelines.
fn equivalent_with_input(dir: &Path, inputs: &[&str], input: &str, extra: &str) {
    let m = pipeline(dir, "memory", inputs, "memory", extra);
    let s = pipeline(dir, "stream", inputs, "stream", extra);
    for p in [&m, &s] {
        let text = std::fs::read_to_string(p).unwrap();
        std::fs::write(
            p,
            text.replacen("[input]\n", &format!("[input]\n{input}"), 1),
        )
        .unwrap();
    }
    run_json(dir, &m, &[]).ok();
    let r = run_json(dir, &s, &[]);
    r.ok();
    let sum = summary(&r);
    assert_read_by_bounds(&sum, &r);
    same_tree(&dir.join("out_memory"), &dir.join("out_stream"));
    no_stream_dir(dir, &r);
}

#[test]
fn reading_by_bounds_equals_memory() {
    // Tiles read directly (no bricks): every window and shard decodes the files whose points'
    // box meets its range. With the class filter and a point cap that ends inside the third
    // tile, the sequence numbers (input order, the resampling's summing order) must still be
    // those of the in-memory reader.
    let read = "read = \"direct\"\n";
    for (input, extra) in [
        ("", read.to_string()),
        (
            "drop_classes = [5]\nmax_points = 180000\n",
            format!("{read}[fill]\nradius = 2.0\n"),
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        tiles(dir.path(), "300000");
        equivalent_with_input(dir.path(), &["tiles/*.las"], input, &extra);
    }
    // One LAZ file, forced: every window reads the whole file.
    if let Some(f) = real("lidar/CSite4_orig-utm.laz") {
        let dir = tempfile::tempdir().unwrap();
        equivalent_with_input(dir.path(), &[&f], "", read);
    }
}

/// A directory with `tiles/`: 4 × 4 generated LAS tiles of 25,000 points.
fn tiles_4x4() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("tiles")).unwrap();
    let gen = [
        "generate",
        "-o",
        "tiles/s.las",
        "--points",
        "400000",
        "--tiles",
        "4x4",
    ];
    terratile(dir.path(), &gen).ok();
    dir
}

#[test]
fn auto_reads_las_tiles_by_bounds_and_writes_no_bricks() {
    // 4 × 4 LAS tiles of 25,000 points under a budget whose windows hold about a tile: each
    // point is read about four times, so the run reads by bounds and its temporary
    // directory holds no brick. A single file of the same points is bucketed.
    let dir = tiles_4x4();
    let s = pipeline(dir.path(), "stream", &["tiles/*.las"], "stream", "");
    let text = std::fs::read_to_string(&s).unwrap();
    std::fs::write(&s, text.replace("\"16MiB\"", "\"10MiB\"")).unwrap();
    let r = run_json(dir.path(), &s, &[]);
    r.ok();
    let sum = summary(&r);
    assert_read_by_bounds(&sum, &r);
    assert_eq!(
        figure(&sum, "bucket", "temporary").as_deref(),
        Some("0 bytes")
    );
    assert_eq!(figure(&sum, "bucket", "bricks").as_deref(), Some("0"));
    let m = pipeline(dir.path(), "memory", &["tiles/*.las"], "memory", "");
    run_json(dir.path(), &m, &[]).ok();
    same_tree(
        &dir.path().join("out_memory"),
        &dir.path().join("out_stream"),
    );
    terratile(
        dir.path(),
        &["generate", "-o", "one.las", "--points", "400000"],
    )
    .ok();
    let one = pipeline(dir.path(), "one", &["one.las"], "stream", "");
    let text = std::fs::read_to_string(&one).unwrap();
    std::fs::write(&one, text.replace("\"16MiB\"", "\"10MiB\"")).unwrap();
    let r = run_json(dir.path(), &one, &[]);
    r.ok();
    let read = figure(&summary(&r), "bucket", "read");
    assert_eq!(read.as_deref(), Some("bricks"), "{}", r.context());
}

#[test]
fn reading_by_bounds_decodes_a_tile_once_for_all_its_windows() {
    // 4 × 4 LAS tiles under windows of about a tile: read one window at a time
    // (`TERRATILE_REUSE=off`, as before the pass reader) each point is decoded about four
    // times a pass; the pass reader decodes a file once for the windows it meets and keeps
    // the parts of later windows, so it decodes fewer points, with the same outputs.
    let dir = tiles_4x4();
    let decoded = |sum: &serde_json::Value, stage: &str| -> u64 {
        figure(sum, stage, "points decoded")
            .unwrap()
            .parse()
            .unwrap()
    };
    let mut got = Vec::new();
    for reuse in ["on", "off"] {
        let s = pipeline(
            dir.path(),
            reuse,
            &["tiles/*.las"],
            "stream",
            "read = \"direct\"\n",
        );
        let text = std::fs::read_to_string(&s).unwrap();
        std::fs::write(&s, text.replace("\"16MiB\"", "\"10MiB\"")).unwrap();
        let r = run_json(dir.path(), &s, &[("TERRATILE_REUSE", reuse)]);
        r.ok();
        let sum = summary(&r);
        assert_read_by_bounds(&sum, &r);
        assert_several_shards(&sum, &r);
        got.push([decoded(&sum, "denoise"), decoded(&sum, "grid shards")]);
    }
    let points = 400_000;
    assert!(got[1][0] > points && got[1][1] > points, "{got:?}");
    assert!(got[0][0] < got[1][0] && got[0][1] < got[1][1], "{got:?}");
    same_tree(&dir.path().join("out_on"), &dir.path().join("out_off"));
}

#[test]
fn tiles_written_shard_by_shard_equal_memory() {
    // With only tile-by-tile outputs (no meshes, previews or dem.tif) each grid shard's
    // heights go to a temporary file as the shard finishes and come back one shard at a time
    // for the encoders: the same bytes as the in-memory run, the 16-bit encoding (whose range
    // is the whole set's) and the manifest (hole counts, per-tile files) included. With the
    // nodata fallback the tiles keep holes.
    let out = "exr = true\npng = true\nraw = true\ngeotiff_tiles = true\nmeshes = []\n\
               relief = false\nwireframe = false\n";
    for (extra, holes) in [
        ("", false),
        ("[fill]\nradius = 2.0\nfallback = \"nodata\"\n", true),
    ] {
        let dir = tempfile::tempdir().unwrap();
        tiles(dir.path(), "300000");
        let m = pipeline(dir.path(), "memory", &["tiles/*.las"], "memory", extra);
        let s = pipeline(dir.path(), "stream", &["tiles/*.las"], "stream", extra);
        for p in [&m, &s] {
            let text = std::fs::read_to_string(p).unwrap();
            std::fs::write(
                p,
                text.replacen("[output]\n", &format!("[output]\n{out}"), 1),
            )
            .unwrap();
        }
        run_json(dir.path(), &m, &[]).ok();
        let r = run_json(dir.path(), &s, &[]);
        r.ok();
        let sum = summary(&r);
        let written = figure(&sum, "write", "tiles written by shard");
        assert!(written.is_some_and(|n| n != "0"), "{}", r.context());
        assert_several_shards(&sum, &r);
        let h: usize = figure(&sum, "tiles", "holes").unwrap().parse().unwrap();
        assert_eq!(h > 0, holes, "holes {h}\n{}", r.context());
        same_tree(
            &dir.path().join("out_memory"),
            &dir.path().join("out_stream"),
        );
        no_stream_dir(dir.path(), &r);
    }
}

/// The names of the stages of a JSON summary with the figure `key` of each.
fn figures_of(s: &serde_json::Value, stage: &str, key: &str) -> Vec<String> {
    s["stages"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|x| x["stage"] == stage)
        .filter_map(|x| {
            x["figures"]
                .as_array()?
                .iter()
                .find(|f| f[0] == key)
                .and_then(|f| f[1].as_str().map(String::from))
        })
        .collect()
}

#[test]
fn points_counted_from_exact_headers_and_recounted_when_a_header_box_is_wrong() {
    // Read by bounds with noise removal on, the run takes each tile's points and box from
    // its header instead of a counting pass when the headers are exact (terratile's LAS
    // writer makes them so), and the noise-removal pass checks them against the points. A
    // header whose maximum x is widened by half a unit (its points all inside still) would
    // give the noise-removal lattice another spacing if believed: in the first file, its
    // own check before the pass finds it; in a later one, the pass's check; either way the
    // run counts the points (and runs the pass again). The outputs are always those of the
    // in-memory run.
    let dir = tiles_4x4();
    let s = pipeline(dir.path(), "stream", &["tiles/*.las"], "stream", "");
    let m = pipeline(dir.path(), "memory", &["tiles/*.las"], "memory", "");
    let run_both = || {
        let r = run_json(dir.path(), &s, &[]);
        r.ok();
        run_json(dir.path(), &m, &[]).ok();
        same_tree(
            &dir.path().join("out_memory"),
            &dir.path().join("out_stream"),
        );
        let sum = summary(&r);
        assert_read_by_bounds(&sum, &r);
        no_stream_dir(dir.path(), &r);
        figures_of(&sum, "bucket", "counted")
    };
    assert_eq!(run_both(), ["from the headers"]);
    let mut tiles: Vec<PathBuf> = walk(&dir.path().join("tiles"))
        .into_iter()
        .filter(|p| p.is_file())
        .collect();
    tiles.sort();
    let widen = |t: &Path| {
        let mut bytes = std::fs::read(t).unwrap();
        let max_x = f64::from_le_bytes(bytes[179..187].try_into().unwrap());
        bytes[179..187].copy_from_slice(&(max_x + 0.5).to_le_bytes());
        std::fs::write(t, bytes).unwrap();
    };
    let first = std::fs::read(&tiles[0]).unwrap();
    widen(&tiles[0]);
    let counted = run_both();
    assert!(
        counted.last().is_some_and(|c| c.contains("not its points")),
        "{counted:?}"
    );
    std::fs::write(&tiles[0], first).unwrap();
    assert_eq!(run_both(), ["from the headers"]);
    widen(&tiles[5]);
    let counted = run_both();
    assert_eq!(counted.len(), 2, "{counted:?}");
    assert_eq!(counted[0], "from the headers");
    assert!(counted[1].contains("not its points"), "{counted:?}");
}
