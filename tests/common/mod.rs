//! Shared helpers of the integration tests.

use std::path::{Path, PathBuf};

/// `../shared/data` next to the repository (CI has it there), or `$TERRATILE_DATA`.
/// A newcomer's clone lacks it: the test says it skips and returns None. Under `CI=true`
/// a missing data directory fails the test instead.
pub fn shared_data() -> Option<PathBuf> {
    let dir = std::env::var_os("TERRATILE_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if dir.is_dir() {
        return Some(dir);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!(
            "CI=true but the shared data directory {} is missing",
            dir.display()
        );
    }
    eprintln!(
        "skipping: shared data not found at {} (set TERRATILE_DATA)",
        dir.display()
    );
    None
}

/// A file under the shared data's `lidar/` or `meshes/` folder.
pub fn data_file(rel: &str) -> Option<PathBuf> {
    let p = shared_data()?.join(rel);
    if p.is_file() {
        return Some(p);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("CI=true but {} is missing", p.display());
    }
    eprintln!("skipping: {} not found", p.display());
    None
}

/// Every LAS/LAZ file in the shared `lidar/` folder, sorted.
pub fn lidar_files() -> Vec<PathBuf> {
    let Some(dir) = shared_data() else {
        return Vec::new();
    };
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir.join("lidar"))
        .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    v.retain(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("las" | "laz")));
    v.sort();
    v
}

/// One run of the real binary.
#[derive(Debug)]
pub struct Run {
    /// The command line, for failure messages.
    pub cmd: String,
    /// Working directory.
    pub dir: PathBuf,
    /// Exit code (-1 if killed by a signal).
    pub code: i32,
    /// Standard output.
    pub stdout: String,
    /// Standard error.
    pub stderr: String,
}

impl Run {
    /// The run of `terratile ARGS` in `dir` that gave `out`.
    pub fn from_output(dir: &Path, args: &[&str], out: std::process::Output) -> Run {
        Run {
            cmd: format!("terratile {}", args.join(" ")),
            dir: dir.to_path_buf(),
            code: out.status.code().unwrap_or(-1),
            stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
            stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
        }
    }

    /// Everything a reader of a failed test needs: command, directory listing, output.
    pub fn context(&self) -> String {
        let mut listing = String::new();
        for e in walk(&self.dir) {
            listing.push_str(&format!(
                "    {}\n",
                e.strip_prefix(&self.dir).unwrap_or(&e).display()
            ));
        }
        format!(
            "command: {}\ndir: {}\n{listing}exit: {}\nstdout:\n{}\nstderr:\n{}",
            self.cmd,
            self.dir.display(),
            self.code,
            self.stdout,
            self.stderr
        )
    }

    /// Asserts success.
    pub fn ok(&self) -> &Run {
        assert_eq!(self.code, 0, "expected success\n{}", self.context());
        self
    }

    /// Asserts a bad-input failure: exit 2 and one stderr line containing every needle.
    pub fn input_error(&self, needles: &[&str]) -> &Run {
        assert_eq!(self.code, 2, "expected exit code 2\n{}", self.context());
        let lines: Vec<&str> = self
            .stderr
            .lines()
            .filter(|l| !l.trim().is_empty())
            .collect();
        assert_eq!(
            lines.len(),
            1,
            "expected one error line\n{}",
            self.context()
        );
        for n in needles {
            assert!(
                self.stderr.contains(n),
                "stderr lacks `{n}`\n{}",
                self.context()
            );
        }
        assert!(
            !self.stderr.contains("panicked"),
            "panic\n{}",
            self.context()
        );
        self
    }

    /// Asserts that the command left nothing behind: no `out` (file or directory, relative
    /// to the run's directory) and no temporary files.
    pub fn left_nothing(&self, out: &str) -> &Run {
        assert!(
            !self.dir.join(out).exists(),
            "no {out} expected\n{}",
            self.context()
        );
        no_temporaries(&self.dir, &self.context());
        self
    }
}

/// Asserts that no file under `dir` is a temporary (`*.tmp-*`) left by an atomic write or a
/// staged output directory.
pub fn no_temporaries(dir: &Path, context: &str) {
    let stray: Vec<_> = walk(dir)
        .into_iter()
        .filter(|p| p.to_string_lossy().contains(".tmp-"))
        .collect();
    assert!(
        stray.is_empty(),
        "temporary files left: {stray:?}\n{context}"
    );
}

/// Every file under `dir`, sorted.
pub fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        if let Ok(rd) = std::fs::read_dir(&d) {
            for e in rd.flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p.clone());
                }
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// Runs `terratile ARGS` in `dir` (quietly, without progress bars).
pub fn terratile(dir: &Path, args: &[&str]) -> Run {
    run_with(
        std::process::Command::new(env!("CARGO_BIN_EXE_terratile")),
        dir,
        args,
    )
}

/// Runs `cmd ARGS` (the terratile binary, or a wrapper around it) in `dir`.
pub fn run_with(mut cmd: std::process::Command, dir: &Path, args: &[&str]) -> Run {
    let out = cmd
        .args(args)
        .current_dir(dir)
        .env_remove("RUST_BACKTRACE")
        .output()
        .expect("the terratile binary runs");
    Run::from_output(dir, args, out)
}

/// The repository root.
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Copies the default job (pipeline.toml and fixtures/) into a fresh temporary directory.
pub fn default_job() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(
        repo().join("pipeline.toml"),
        dir.path().join("pipeline.toml"),
    )
    .unwrap();
    std::fs::create_dir(dir.path().join("fixtures")).unwrap();
    for e in std::fs::read_dir(repo().join("fixtures"))
        .unwrap()
        .flatten()
    {
        std::fs::copy(e.path(), dir.path().join("fixtures").join(e.file_name())).unwrap();
    }
    dir
}

/// The stage names of a run summary printed with `--json`, in order.
pub fn stage_names(summary: &serde_json::Value) -> Vec<&str> {
    summary["stages"]
        .as_array()
        .expect("a stages array")
        .iter()
        .map(|s| s["stage"].as_str().expect("a stage name"))
        .collect()
}

/// The fixture LAS tile of the default job, as an absolute path.
pub fn fixture_las() -> String {
    repo().join("fixtures/survey-0-0.las").display().to_string()
}

/// Writes `dir/p.toml`: `input` into `out`, with `extra` TOML appended (it may go on with
/// `[output]` keys before its first table).
pub fn write_pipeline(dir: &Path, input: &str, extra: &str) {
    let text = format!("[input]\npaths = [{input:?}]\n[output]\ndir = \"out\"\n{extra}");
    std::fs::write(dir.join("p.toml"), text).unwrap();
}

/// Runs `terratile run -q p.toml` in `dir`.
pub fn run_p_toml(dir: &Path) -> Run {
    terratile(dir, &["run", "-q", "p.toml"])
}

/// Writes `p.toml` as [`write_pipeline`] does and runs it (`-q --json`); a failing run must
/// leave no output directory.
pub fn run_pipeline(dir: &Path, input: &str, extra: &str) -> Run {
    write_pipeline(dir, input, extra);
    let r = terratile(dir, &["run", "-q", "--json", "p.toml"]);
    if r.code != 0 {
        r.left_nothing("out");
    }
    r
}

/// Writes `pts` as an XYZ text file (with a header line) at `dir/name`.
pub fn write_xyz(dir: &Path, name: &str, pts: &[(f64, f64, f64)]) {
    let mut s = String::from("x y z\n");
    for (x, y, z) in pts {
        s.push_str(&format!("{x} {y} {z}\n"));
    }
    std::fs::write(dir.join(name), s).unwrap();
}

/// Runs `terratile simplify INPUT OUTPUT ARGS` in `dir`.
pub fn simplify(dir: &Path, input: &str, output: &str, args: &[&str]) -> Run {
    let mut a = vec!["simplify", input, output];
    a.extend_from_slice(args);
    terratile(dir, &a)
}

/// Replaces `from` by `to` in the job's pipeline.toml (which must contain it).
pub fn edit_pipeline(dir: &Path, from: &str, to: &str) {
    let p = dir.join("pipeline.toml");
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(text.contains(from), "pipeline.toml lacks `{from}`");
    std::fs::write(&p, text.replace(from, to)).unwrap();
}

/// The Python interpreter of a virtual environment `target/NAME/venv` with `packages`
/// installed from the registry, built on first use (a marker file names the package set, so
/// adding a package makes an older environment install it); None, after saying why the
/// caller's test skips, when that is impossible (no python3, no registry).
pub fn python_venv(name: &str, packages: &[&str], what: &str) -> Option<PathBuf> {
    use std::process::Command;
    let _one_at_a_time = environment_lock();
    let root = repo().join("target").join(name);
    let py = root.join("venv/bin/python");
    let ready = root.join(format!("venv/.terratile-ready-{}", packages.join("-")));
    if ready.is_file() {
        return Some(py);
    }
    let _ = std::fs::create_dir_all(&root);
    let skip = |why: String| {
        eprintln!("skipping: no Python environment with {what} ({why})");
        None
    };
    let stderr = |o: &std::process::Output| String::from_utf8_lossy(&o.stderr).into_owned();
    match Command::new("python3")
        .args(["-m", "venv"])
        .arg(root.join("venv"))
        .output()
    {
        Ok(o) if o.status.success() => {}
        Ok(o) => return skip(format!("python3 -m venv: {}", stderr(&o))),
        Err(e) => return skip(format!("python3: {e}")),
    }
    match Command::new(&py)
        .args(["-m", "pip", "install", "--quiet"])
        .args(packages)
        .output()
    {
        Ok(o) if o.status.success() => {
            let _ = std::fs::write(&ready, b"");
            Some(py)
        }
        Ok(o) => skip(format!("pip install: {}", stderr(&o))),
        Err(e) => skip(format!("pip: {e}")),
    }
}

/// Held while a test builds a Python or Node environment under `target/`: tests run on
/// several threads, and two installs into one directory (or one test reading a package
/// another is still unpacking) break both.
pub fn environment_lock() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|p| p.into_inner())
}

/// The height at (x, y) of the plane through the triangle `p` (corners as x, y, z), if
/// (x, y) lies in the triangle's footprint (within 1e-9 in barycentric coordinates).
pub fn height_in_triangle(p: [[f64; 3]; 3], x: f64, y: f64) -> Option<f64> {
    let det = (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
    let l1 = ((x - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (y - p[0][1])) / det;
    let l2 = ((p[1][0] - p[0][0]) * (y - p[0][1]) - (x - p[0][0]) * (p[1][1] - p[0][1])) / det;
    let l0 = 1.0 - l1 - l2;
    (l0 >= -1e-9 && l1 >= -1e-9 && l2 >= -1e-9).then(|| l0 * p[0][2] + l1 * p[1][2] + l2 * p[2][2])
}

/// `target/DIR/node_modules` with npm package `spec` (`name@version`), installed on first
/// use; None (after saying why) without npm or the registry.
pub fn npm_env(dir: &str, spec: &str) -> Option<PathBuf> {
    let _one_at_a_time = environment_lock();
    let root = repo().join("target").join(dir);
    let modules = root.join("node_modules");
    // Written after a complete install: a package.json alone may be a half-unpacked one.
    let ready = root.join(format!(".terratile-ready-{}", spec.replace('/', "+")));
    if ready.is_file() {
        return Some(modules);
    }
    let _ = std::fs::create_dir_all(&root);
    let _ = std::fs::write(root.join("package.json"), b"{\"private\": true}\n");
    let o = std::process::Command::new("npm")
        .current_dir(&root)
        .args(["install", "--no-audit", "--no-fund", spec])
        .output();
    match o {
        Ok(o) if o.status.success() => {
            let _ = std::fs::write(&ready, b"");
            Some(modules)
        }
        Ok(o) => {
            eprintln!(
                "skipping: npm install {spec} failed: {}",
                String::from_utf8_lossy(&o.stderr)
            );
            None
        }
        Err(e) => {
            eprintln!("skipping: no npm ({e})");
            None
        }
    }
}

/// Asserts that the trees `a` and `b` hold the same files with the same bytes.
pub fn same_tree(a: &Path, b: &Path) {
    let rel = |d: &Path| -> Vec<PathBuf> {
        walk(d)
            .into_iter()
            .map(|p| p.strip_prefix(d).unwrap().to_path_buf())
            .collect()
    };
    let (fa, fb) = (rel(a), rel(b));
    assert_eq!(
        fa,
        fb,
        "{} and {} list different files",
        a.display(),
        b.display()
    );
    assert!(fa.len() > 3, "too few outputs in {}", a.display());
    for f in fa.iter().filter(|f| a.join(f).is_file()) {
        assert!(
            std::fs::read(a.join(f)).unwrap() == std::fs::read(b.join(f)).unwrap(),
            "{} differs",
            f.display()
        );
    }
}
