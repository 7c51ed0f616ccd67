//! `terratile bench scale`: the streaming run against the in-memory run on generated
//! surveys of given sizes. For each size, `terratile generate` writes tiles of at most
//! 10 M points into a temporary directory, then `terratile run` runs the same pipeline in a
//! fresh process in each mode (`[scale] mode = "stream"` with the given budget, then
//! `"memory"`), timed, its peak resident memory read from `/proc/PID/status` (`VmHWM`,
//! polled until the process ends), and the two output directories compared byte for byte.
//! The outputs are the heightmaps and the manifest (writing meshes and images is the same
//! code in both modes and would only dilute the comparison).

use crate::error::{Error, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// One run of one mode.
#[derive(Debug, Clone, Serialize)]
pub struct ModeRun {
    /// `stream` or `memory`.
    pub mode: String,
    /// Wall time, seconds.
    pub seconds: f64,
    /// Points per second.
    pub points_per_s: f64,
    /// Peak resident memory, bytes (`None`: /proc unreadable).
    pub peak_rss: Option<u64>,
    /// The run failed: its last message.
    pub error: Option<String>,
}

/// One survey size.
#[derive(Debug, Clone, Serialize)]
pub struct SizeRow {
    /// Points.
    pub points: u64,
    /// Bytes of the generated LAS tiles.
    pub input_bytes: u64,
    /// The streaming run, then the in-memory run.
    pub runs: Vec<ModeRun>,
    /// True when both runs wrote the same files with the same bytes.
    pub identical: bool,
}

fn exe() -> Result<PathBuf> {
    std::env::current_exe().map_err(|e| Error::Internal(format!("own executable: {e}")))
}

/// Runs `cmd` to its end, polling its peak resident memory.
fn measured(mut cmd: std::process::Command) -> Result<(f64, Option<u64>, Option<String>)> {
    let t = Instant::now();
    let mut child = cmd
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .map_err(|e| Error::Internal(format!("starting terratile: {e}")))?;
    let status = format!("/proc/{}/status", child.id());
    let mut peak = None;
    let code = loop {
        if let Some(kb) = crate::memory::proc_kb(&status, "VmHWM:") {
            peak = Some(peak.unwrap_or(0).max(kb));
        }
        match child.try_wait() {
            Ok(Some(s)) => break s,
            Ok(None) => std::thread::sleep(Duration::from_millis(20)),
            Err(e) => return Err(Error::Internal(format!("waiting for terratile: {e}"))),
        }
    };
    let seconds = t.elapsed().as_secs_f64();
    let mut err = String::new();
    if let Some(mut e) = child.stderr.take() {
        use std::io::Read;
        let _ = e.read_to_string(&mut err);
    }
    let error = (!code.success()).then(|| err.lines().last().unwrap_or("failed").to_string());
    Ok((seconds, peak, error))
}

fn pipeline_text(mode: &str, budget: &str) -> String {
    format!(
        "[input]\npaths = [\"tiles/*.las\"]\n[output]\ndir = \"out_{mode}\"\nexr = false\n\
         png = false\nrelief = false\nwireframe = false\ngeotiff = false\nmeshes = []\n\
         raw = true\nmanifest = true\n[scale]\nmode = \"{mode}\"\nmemory_budget = \"{budget}\"\n"
    )
}

fn files_of(d: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![d.to_path_buf()];
    while let Some(p) = stack.pop() {
        if let Ok(rd) = std::fs::read_dir(&p) {
            for e in rd.flatten() {
                if e.path().is_dir() {
                    stack.push(e.path());
                } else {
                    out.push(e.path().strip_prefix(d).unwrap_or(&e.path()).to_path_buf());
                }
            }
        }
    }
    out.sort();
    out
}

/// True when `a` and `b` hold the same files with the same bytes.
pub fn same_tree(a: &Path, b: &Path) -> bool {
    let (fa, fb) = (files_of(a), files_of(b));
    !fa.is_empty()
        && fa == fb
        && fa
            .iter()
            .all(|f| std::fs::read(a.join(f)).ok() == std::fs::read(b.join(f)).ok())
}

/// Measures each size of `sizes` in a fresh directory under `dir` (removed afterwards),
/// streaming within `budget` (e.g. `1GiB`).
pub fn bench_scale(sizes: &[u64], budget: &str, dir: &Path) -> Result<Vec<SizeRow>> {
    crate::memory::parse_size(budget).map_err(Error::Usage)?;
    let mut rows = Vec::new();
    for &n in sizes {
        // A directory of our own (created here, so removing it removes nothing else).
        let work = dir.join(format!("terratile-bench-scale-{}-{n}", std::process::id()));
        std::fs::create_dir(&work).map_err(|e| Error::io(&work, e))?;
        let row = measure_size(n, budget, &work);
        let _ = std::fs::remove_dir_all(&work);
        rows.push(row?);
    }
    Ok(rows)
}

/// One size, in the fresh directory `d`.
fn measure_size(n: u64, budget: &str, d: &Path) -> Result<SizeRow> {
    {
        let tiles_dir = d.join("tiles");
        std::fs::create_dir(&tiles_dir).map_err(|e| Error::io(&tiles_dir, e))?;
        let cols = n.div_ceil(10_000_000).max(1);
        let mut g = std::process::Command::new(exe()?);
        g.current_dir(d)
            .args(["generate", "-q", "-o", "tiles/s.las"]);
        g.args(["--points", &n.to_string(), "--tiles", &format!("{cols}x1")]);
        if let (_, _, Some(e)) = measured(g)? {
            return Err(Error::Internal(format!("generate {n} points: {e}")));
        }
        let input_bytes = files_of(&tiles_dir)
            .iter()
            .filter_map(|f| std::fs::metadata(tiles_dir.join(f)).ok())
            .map(|m| m.len())
            .sum();
        let mut runs = Vec::new();
        for mode in ["stream", "memory"] {
            let p = d.join(format!("{mode}.toml"));
            std::fs::write(&p, pipeline_text(mode, budget)).map_err(|e| Error::io(&p, e))?;
            let mut c = std::process::Command::new(exe()?);
            c.current_dir(d).args(["run", "-q"]).arg(&p);
            let (seconds, peak_rss, error) = measured(c)?;
            runs.push(ModeRun {
                mode: mode.into(),
                seconds,
                points_per_s: n as f64 / seconds,
                peak_rss,
                error,
            });
        }
        let identical = same_tree(&d.join("out_memory"), &d.join("out_stream"));
        Ok(SizeRow {
            points: n,
            input_bytes,
            runs,
            identical,
        })
    }
}

/// The rows as a text table.
pub fn table(rows: &[SizeRow]) -> String {
    let mut s = String::from("points        mode    wall s   points/s     peak RSS   identical\n");
    for r in rows {
        for m in &r.runs {
            let rss = m.peak_rss.map_or("—".into(), crate::memory::human);
            let tail = match &m.error {
                Some(e) => format!("failed: {e}"),
                None => r.identical.to_string(),
            };
            s.push_str(&format!(
                "{:<13} {:<7} {:>7.1} {:>10.0} {:>12}   {tail}\n",
                r.points, m.mode, m.seconds, m.points_per_s, rss
            ));
        }
    }
    s
}
