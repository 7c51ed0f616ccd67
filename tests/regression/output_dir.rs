//! Regressions: output_dir. A run replaced whatever its output directory held (inputs, the
//! pipeline file, a user's files), the swap of staged output was two renames, concurrent
//! runs mixed, killed runs left staging behind, and outputs overwrote each other.

use crate::common::{self, no_temporaries, terratile, walk};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A job directory with a generated survey of `points` points at `rel` inside it.
fn job(points: u64, rel: &str) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    terratile(
        dir.path(),
        &["generate", "-o", rel, "--points", &points.to_string()],
    )
    .ok();
    dir
}

fn write(dir: &Path, rel: &str, text: &str) {
    let p = dir.join(rel);
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, text).unwrap();
}

/// `dir/p.toml` reading the job's `a.las`, with `extra` TOML appended.
fn a_las_pipeline(dir: &Path, extra: &str) {
    write(
        dir,
        "p.toml",
        &format!("[input]\npaths=[\"a.las\"]\n{extra}"),
    );
}

/// A job with a generated `a.las` of `points` points and a `p.toml` reading it, with `extra`
/// TOML appended.
fn a_las_job(points: u64, extra: &str) -> tempfile::TempDir {
    let root = job(points, "a.las");
    a_las_pipeline(root.path(), extra);
    root
}

/// Every file under `dir` with its bytes, to show that a refused run changed nothing.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    walk(dir)
        .into_iter()
        .filter(|p| p.is_file())
        .map(|p| {
            let b = std::fs::read(&p).unwrap();
            (p, b)
        })
        .collect()
}

/// A whole output: the marker, and every file its manifest lists present.
fn assert_complete_output(out: &Path, context: &str) {
    assert!(
        out.join(".terratile").is_file(),
        "no marker in {out:?}\n{context}"
    );
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
    for tile in manifest["tiles"].as_array().unwrap() {
        for (_, v) in tile["files"].as_object().unwrap() {
            let rel = v.as_str().unwrap();
            assert!(out.join(rel).is_file(), "{rel} missing\n{context}");
        }
    }
}

#[test]
fn run_deleted_its_own_input_in_the_output_dir() {
    // The reproduction: `dir = "data"` with the input in data/ left data/ holding
    // only outputs, exit 0.
    let Some(las) = common::data_file("lidar/simple.las") else {
        return;
    };
    let root = tempfile::tempdir().unwrap();
    let t = root.path().join("t");
    std::fs::create_dir_all(t.join("data")).unwrap();
    std::fs::copy(&las, t.join("data/simple.las")).unwrap();
    write(
        &t,
        "p.toml",
        "[input]\npaths=[\"data/*.las\"]\n[output]\ndir=\"data\"\n",
    );
    let before = snapshot(root.path());
    let r = terratile(root.path(), &["run", "t/p.toml"]);
    r.input_error(&["t/data", "holds the input file", "simple.las"]);
    assert_eq!(snapshot(root.path()), before, "{}", r.context());
    no_temporaries(root.path(), &r.context());
}

#[test]
fn output_dir_dot_dotdot_empty_or_the_pipeline_dir_was_replaced() {
    // `dir = "."`, `".."`, `""` and `"../<own dir>"` named the pipeline's own directory (or
    // its parent): the run deleted everything there, or failed after the work with "Device or
    // resource busy". Now refused before any point is read.
    let root = job(2_000, "t/data/a.las");
    write(root.path(), "keep.txt", "a user's file\n");
    for dir in [".", "..", "", "../t", "./", "data/.."] {
        write(
            root.path(),
            "t/p.toml",
            &format!("[input]\npaths=[\"data/*.las\"]\n[output]\ndir=\"{dir}\"\n"),
        );
        let before = snapshot(root.path());
        let r = terratile(root.path(), &["run", "t/p.toml"]);
        r.input_error(&["the pipeline file's", "refusing"]);
        assert_eq!(
            snapshot(root.path()),
            before,
            "dir = {dir:?}\n{}",
            r.context()
        );
        no_temporaries(root.path(), &r.context());
    }
}

#[test]
fn output_dir_of_unrelated_files_was_replaced() {
    // A directory of a user's files was replaced whole. Only a directory holding terratile's
    // marker, an empty one or a new one may be replaced.
    let root = a_las_job(2_000, "[output]\ndir=\"mine\"\n");
    write(root.path(), "mine/notes.txt", "a user's notes\n");
    let before = snapshot(root.path());
    let r = terratile(root.path(), &["run", "p.toml"]);
    r.input_error(&["mine", "terratile did not write", ".terratile"]);
    assert_eq!(snapshot(root.path()), before, "{}", r.context());
    // An empty directory is taken, and the output carries the marker; the next run replaces it.
    std::fs::remove_file(root.path().join("mine/notes.txt")).unwrap();
    common::run_p_toml(root.path()).ok();
    assert_complete_output(&root.path().join("mine"), "");
    write(root.path(), "mine/stale.txt", "left from before\n");
    let r = common::run_p_toml(root.path());
    r.ok();
    assert!(
        !root.path().join("mine/stale.txt").exists(),
        "{}",
        r.context()
    );
    assert!(!root.path().join(".mine.lock").exists(), "{}", r.context());
    // A file in place of the directory.
    write(root.path(), "f.txt", "a user's file\n");
    a_las_pipeline(root.path(), "[output]\ndir=\"f.txt\"\n");
    terratile(root.path(), &["run", "p.toml"]).input_error(&["f.txt", "is a file"]);
    assert_eq!(
        std::fs::read(root.path().join("f.txt")).unwrap(),
        b"a user's file\n"
    );
}

#[test]
fn asset_input_or_pipeline_inside_the_output_dir_was_deleted() {
    // An asset model (or the pipeline file) kept inside a terratile-written output directory
    // was deleted with it by the next run.
    let root = a_las_job(2_000, "");
    let p = root.path();
    common::run_p_toml(p).ok();
    write(
        p,
        "out/rock.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n",
    );
    let extent = "[[assets]]\ninput = \"out/rock.obj\"\noutput = \"rock.ply\"\n\
                  place = { x = 0.0, y = 0.0 }\n";
    a_las_pipeline(p, extent);
    let before = snapshot(p);
    let r = terratile(p, &["run", "p.toml"]);
    r.input_error(&["out", "holds the asset input", "rock.obj"]);
    assert_eq!(snapshot(p), before, "{}", r.context());
    // The pipeline file itself inside the output directory.
    write(
        p,
        "out/p2.toml",
        "[input]\npaths=[\"../a.las\"]\n[output]\ndir=\".\"\n",
    );
    let r = terratile(p, &["run", "out/p2.toml"]);
    r.input_error(&["out"]);
    assert!(p.join("out/p2.toml").is_file(), "{}", r.context());
}

#[cfg(unix)]
#[test]
fn input_reached_through_a_symlink_inside_the_output_dir_was_deleted() {
    // `data` is a link to the output directory: the input's real place is inside it.
    let root = job(2_000, "out/a.las");
    let p = root.path();
    std::os::unix::fs::symlink("out", p.join("data")).unwrap();
    write(p, "p.toml", "[input]\npaths=[\"data/a.las\"]\n");
    let r = terratile(p, &["run", "p.toml"]);
    r.input_error(&["out", "holds the input file"]);
    assert!(p.join("out/a.las").is_file(), "{}", r.context());
    // And a link inside the output directory to an input outside it.
    let root = job(2_000, "a.las");
    let p = root.path();
    std::fs::create_dir(p.join("out")).unwrap();
    std::os::unix::fs::symlink("../a.las", p.join("out/link.las")).unwrap();
    write(p, "p.toml", "[input]\npaths=[\"out/link.las\"]\n");
    let r = terratile(p, &["run", "p.toml"]);
    r.input_error(&["out", "holds the input file"]);
    assert!(p.join("out/link.las").exists(), "{}", r.context());
}

#[test]
fn asset_output_overwrote_a_terrain_tile() {
    // `[[assets]] output = "meshes/tile_000_000.ply"` silently replaced a terrain tile that
    // the manifest still listed. Now refused before the work, naming the key. (PLY tile
    // meshes are asked for: the default mesh format is glb alone.)
    let root = job(2_000, "a.las");
    let p = root.path();
    write(p, "rock.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    a_las_pipeline(
        p,
        "[output]\nmeshes = [\"ply\", \"glb\"]\n\
         [[assets]]\ninput = \"rock.obj\"\n\
         output = \"meshes/tile_000_000.ply\"\nplace = { x = 0.0, y = 0.0 }\n",
    );
    let r = terratile(p, &["run", "p.toml"]);
    r.input_error(&[
        "p.toml:",
        "assets[0].output",
        "tile_000_000.ply",
        "output.meshes",
    ]);
    r.left_nothing("out");
}

#[test]
fn baseline_report_named_like_a_written_directory_named_the_staging_path() {
    // `baseline.report = "tiles"` failed after the work with an error naming the staging
    // directory (`.out.tmp-PID/tiles`). Now an up-front config error naming the key.
    let root = a_las_job(2_000, "[baseline]\nenabled = true\nreport = \"tiles\"\n");
    let p = root.path();
    let r = terratile(p, &["run", "p.toml"]);
    r.input_error(&["p.toml:", "baseline.report", "tiles", "output.exr"]);
    assert!(!r.stderr.contains(".tmp-"), "{}", r.context());
    r.left_nothing("out");
}

#[test]
fn summary_paths_were_not_normalised() {
    // The summary showed `pipes/../runs/out` and `pipes/../data/a.las`.
    let root = job(2_000, "data/a.las");
    let p = root.path();
    std::fs::create_dir(p.join("pipes")).unwrap();
    write(
        p,
        "p.toml",
        "[input]\npaths=[\"pipes/../data/a.las\"]\n[output]\ndir=\"pipes/../runs/out\"\n",
    );
    let r = terratile(p, &["run", "p.toml"]);
    r.ok();
    assert!(r.stdout.contains("output: runs/out ("), "{}", r.context());
    assert!(r.stdout.contains("  data/a.las ("), "{}", r.context());
    assert!(!r.stdout.contains("/.."), "{}", r.context());
}

/// Sends `signal` (`TERM`, `INT`, `KILL`) to `child`.
fn signal(child: &Child, signal: &str) {
    let ok = Command::new("kill")
        .args([&format!("-{signal}"), &child.id().to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok, "kill -{signal} failed");
}

fn spawn_run(dir: &Path, pipeline: &str) -> Child {
    Command::new(env!("CARGO_BIN_EXE_terratile"))
        .args(["run", "-q", pipeline])
        .current_dir(dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Waits until `dir` holds a staging directory, i.e. the run is writing.
fn wait_for_staging(dir: &Path, child: &mut Child) -> bool {
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(60) {
        if child.try_wait().unwrap().is_some() {
            return false;
        }
        let staging = std::fs::read_dir(dir)
            .unwrap()
            .flatten()
            .any(|e| e.file_name().to_string_lossy().starts_with(".out.tmp-"));
        if staging {
            return true;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    panic!("no staging directory appeared in {dir:?}");
}

/// Runs `p.toml` in `dir` and sends it SIG`sig` `delay` after its staging directory
/// appeared; its output, or None if it finished before it began writing.
fn run_signalled(dir: &Path, sig: &str, delay: Duration) -> Option<std::process::Output> {
    let mut child = spawn_run(dir, "p.toml");
    if !wait_for_staging(dir, &mut child) {
        return None;
    }
    std::thread::sleep(delay);
    signal(&child, sig);
    Some(child.wait_with_output().unwrap())
}

#[cfg(unix)]
#[test]
fn interrupted_run_left_its_staging_directory() {
    // SIGINT/SIGTERM during a run left `.out.tmp-PID` (up to 1.1 GB). Now the handler removes
    // what this process created and exits 130/143; the previous output stays.
    let root = a_las_job(1_500_000, "[output]\npreview_size = 4096\n");
    let p = root.path();
    common::run_p_toml(p).ok();
    let before = snapshot(&p.join("out"));
    for (sig, code) in [("TERM", 143), ("INT", 130)] {
        // Signalled while reading (staging exists from the start) and again later.
        for delay_ms in [0u64, 300] {
            let Some(out) = run_signalled(p, sig, Duration::from_millis(delay_ms)) else {
                continue;
            };
            let stderr = String::from_utf8_lossy(&out.stderr);
            // It may have finished first on a fast machine; then it is a normal success.
            let status = out.status.code();
            assert!(
                status == Some(code) || status == Some(0),
                "SIG{sig}: exit {status:?}\n{stderr}"
            );
            if status == Some(code) {
                assert_eq!(
                    snapshot(&p.join("out")),
                    before,
                    "SIG{sig} changed the output"
                );
                assert!(stderr.contains(&format!("SIG{sig}")), "{stderr}");
            }
            no_temporaries(p, &stderr);
            assert!(!p.join(".out.lock").exists(), "lock left after SIG{sig}");
        }
    }
}

#[cfg(unix)]
#[test]
fn killed_swap_left_no_output_directory() {
    // The swap was two renames: kill -9 between them left no output at all. Now one
    // renameat2(RENAME_EXCHANGE) on Linux: whenever the run is killed, a whole output (old or
    // new) is in place, and the next run clears the dead run's staging.
    let root = a_las_job(400_000, "");
    let p = root.path();
    common::run_p_toml(p).ok();
    let t = Instant::now();
    common::run_p_toml(p).ok();
    let run_ms = t.elapsed().as_millis() as u64;
    for step in 0..8 {
        run_signalled(p, "KILL", Duration::from_millis(run_ms * step / 8));
        assert_complete_output(&p.join("out"), &format!("killed at step {step}"));
    }
    let r = common::run_p_toml(p);
    r.ok();
    no_temporaries(p, &r.context());
    assert_complete_output(&p.join("out"), &r.context());
}

#[test]
fn stale_staging_of_dead_runs_was_never_removed() {
    // `.out.tmp-PID` directories and `convert`'s `.NAME.tmp-PID` files of killed runs stayed
    // forever. A run now removes those of dead processes, and nothing else.
    let root = a_las_job(2_000, "");
    let p = root.path();
    common::run_p_toml(p).ok();
    let dead = {
        let mut c = Command::new("true").spawn().unwrap();
        let pid = c.id();
        c.wait().unwrap();
        pid
    };
    let alive = std::process::id();
    let stale = [
        format!(".out.tmp-{dead}/tiles/tile_000_000.exr"),
        format!(".out.old-{dead}/manifest.json"),
        format!(".b.las.tmp-{dead}"),
    ];
    let kept = [
        format!(".out.tmp-{alive}/x"),
        format!(".outer.tmp-{dead}/x"),
        format!(".out.tmp-{dead}x/x"),
        format!("out.tmp-{dead}/x"),
        ".out.tmp-/x".to_string(),
        "notes.txt".to_string(),
    ];
    for f in stale.iter().chain(&kept) {
        write(p, f, "x");
    }
    let r = common::run_p_toml(p);
    r.ok();
    for f in &stale[..2] {
        let top = f.split('/').next().unwrap();
        assert!(!p.join(top).exists(), "{top} left\n{}", r.context());
    }
    for f in &kept {
        assert!(p.join(f).exists(), "{f} removed\n{}", r.context());
    }
    let r = terratile(p, &["convert", "a.las", "b.las"]);
    r.ok();
    assert!(!p.join(&stale[2]).exists(), "{}", r.context());
    assert!(p.join(format!(".out.tmp-{alive}/x")).exists());
}

#[cfg(unix)]
#[test]
fn concurrent_runs_into_one_directory_mixed() {
    // Two runs into one directory could fail with "Directory not empty" or mix. Now a lock:
    // the second fails cleanly with one line while the first holds it.
    let root = a_las_job(2_000, "");
    let p = root.path();
    // Held by another process (this test): refused before any work, nothing touched.
    {
        let lock = std::fs::File::create(p.join(".out.lock")).unwrap();
        rustix::fs::flock(&lock, rustix::fs::FlockOperation::LockExclusive).unwrap();
        let r = terratile(p, &["run", "p.toml"]);
        r.input_error(&["out", "another terratile run"]);
        assert!(!p.join("out").exists(), "{}", r.context());
        drop(lock);
        common::run_p_toml(p).ok();
    }

    // Two real processes at once, several times: each exits 0, or 2 with the one lock line; the
    // output is always whole.
    let root = a_las_job(1_000_000, "");
    let p = root.path();
    let mut refused = 0;
    for _ in 0..3 {
        let a = spawn_run(p, "p.toml");
        let b = spawn_run(p, "p.toml");
        for c in [a, b] {
            let out = c.wait_with_output().unwrap();
            let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
            match out.status.code() {
                Some(0) => {}
                Some(2) => {
                    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
                    assert!(stderr.contains("another terratile run"), "{stderr}");
                    refused += 1;
                }
                other => panic!("exit {other:?}: {stderr}"),
            }
        }
        assert_complete_output(&p.join("out"), "after two concurrent runs");
        no_temporaries(p, "after two concurrent runs");
    }
    assert!(refused > 0, "two runs started together never met the lock");
}

#[cfg(unix)]
#[test]
fn interrupted_convert_left_its_temporary_file() {
    // `convert` killed by SIGINT/SIGTERM left `.OUT.tmp-PID` beside its output. Now removed;
    // the output is either absent or whole (it is renamed into place in one step).
    let root = job(3_000_000, "big.las");
    let p = root.path();
    for sig in ["TERM", "INT"] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_terratile"))
            .args(["convert", "big.las", "c.las"])
            .current_dir(p)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let start = Instant::now();
        while child.try_wait().unwrap().is_none() && start.elapsed() < Duration::from_secs(60) {
            let writing = std::fs::read_dir(p)
                .unwrap()
                .flatten()
                .any(|e| e.file_name().to_string_lossy().starts_with(".c.las.tmp-"));
            if writing {
                signal(&child, sig);
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        let code = out.status.code();
        let expected = if sig == "TERM" { 143 } else { 130 };
        assert!(
            code == Some(expected) || code == Some(0),
            "exit {code:?}\n{stderr}"
        );
        no_temporaries(p, &stderr);
        if p.join("c.las").exists() {
            terratile(p, &["info", "c.las"]).ok();
            std::fs::remove_file(p.join("c.las")).unwrap();
        }
    }
}
