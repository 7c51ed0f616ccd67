//! `bench terrain`: the grid stages of Kim & Shin (read, denoise, resample, fill) against the
//! Delaunay triangulation of the same denoised points (spade, bulk loading and incremental
//! insertion in file order), in one process, with the peak memory of each side. The tile
//! stages follow (tiles, quadtree d2, writing the EXR tiles with the default compression, the
//! manifest and the 16-bit heightmaps), so that `total_s` is the whole pipeline from file to
//! written tiles; mesh extraction at the default tolerance is timed beside it.
//!
//! Every stage and each Delaunay build is also timed in CPU seconds (user + system, all
//! threads of the process: `CLOCK_PROCESS_CPUTIME_ID`), because on a shared machine the wall
//! times move with whatever else runs while CPU time moves much less; `total_cpu_ratio` is
//! the faster Delaunay's CPU time over the whole pipeline's. Our stages use every core and
//! spade one, so on an idle machine the wall ratio is up to the thread count times the CPU
//! ratio.

use super::median;
use crate::config::Pipeline;
use crate::error::{Error, Result};
use crate::output::OutputConfig;
use crate::pipeline::{
    grid_stages_with_bounds, peak_rss, product_stages, reset_peak_rss, with_input_crs, TileStages,
};
use crate::points::{self, PointCloud, ReadOptions};
use crate::progress::{NoProgress, Progress};
use crate::terrain::delaunay::{self, TinMethod};
use crate::terrain::extract::extract_meshes;
use crate::terrain::Heightfield;
use serde::Serialize;
use std::path::Path;
use std::sync::{Mutex, MutexGuard};
use std::time::Instant;

/// Result of `bench terrain`.
#[derive(Debug, Clone, Serialize)]
pub struct TerrainBench {
    /// The file measured.
    pub file: String,
    /// Points read.
    pub points: u64,
    /// Bytes of the uncompressed point records (points × record length).
    pub record_bytes: u64,
    /// Points left after noise removal.
    pub kept: u64,
    /// Grid columns and rows.
    pub grid: [usize; 2],
    /// Median seconds to map and decode the file.
    pub read_s: f64,
    /// Median seconds of noise removal.
    pub denoise_s: f64,
    /// Median seconds of resampling.
    pub resample_s: f64,
    /// Median seconds of hole filling.
    pub fill_s: f64,
    /// Median seconds of denoise + resample + fill (summed per run, then the median).
    pub stages_s: f64,
    /// Seconds to centre the denoised points and merge those sharing x and y.
    pub tin_prepare_s: f64,
    /// Median seconds of spade's bulk loading.
    pub delaunay_bulk_s: f64,
    /// Median seconds of spade's incremental insertion in file order.
    pub delaunay_incremental_s: f64,
    /// The faster of the two ("Delaunay time").
    pub delaunay_s: f64,
    /// Which one was faster.
    pub delaunay_method: String,
    /// Delaunay time / (denoise + resample + fill) time.
    pub stages_ratio: f64,
    /// TIN vertices (distinct points).
    pub tin_vertices: usize,
    /// TIN triangles.
    pub tin_triangles: usize,
    /// Points merged into another one with the same x and y.
    pub tin_merged: usize,
    /// Peak resident memory of read + denoise + resample + fill (mapped file pages included),
    /// in MB (10^6 bytes); None where /proc is unavailable.
    pub grid_peak_mb: Option<f64>,
    /// grid_peak_mb in units of the uncompressed point record bytes.
    pub grid_peak_per_record_bytes: Option<f64>,
    /// Peak resident memory while building the TIN (the point cloud it is built from
    /// included), in MB.
    pub delaunay_peak_mb: Option<f64>,
    /// Median seconds to cut the filled grid into tiles.
    pub tiles_s: f64,
    /// Median seconds of the quadtree d2 (propagated and reconciled).
    pub quadtree_s: f64,
    /// Median seconds to write the EXR tiles (default compression), the manifest and the
    /// 16-bit PNG and RAW heightmaps.
    pub write_s: f64,
    /// Median seconds to extract the tile meshes at the default tolerance (vertical error
    /// tree included); not part of `total_s`.
    pub extract_s: f64,
    /// Median seconds of the whole pipeline from file to written tiles: read + denoise +
    /// resample + fill + tiles + quadtree + write.
    pub total_s: f64,
    /// Delaunay time / whole-pipeline time.
    pub total_ratio: f64,
    /// Tile size and tile grid.
    pub tiling: [usize; 3],
    /// EXR compression used (the default).
    pub exr_compression: String,
    /// Bytes written (EXR, manifest, heightmaps).
    pub written_bytes: u64,
    /// Surface triangles of the extracted tile meshes.
    pub mesh_triangles: usize,
    /// Repetitions (medians are reported).
    pub repeats: usize,
    /// Worker threads of the grid stages.
    pub threads: usize,
    /// Median CPU seconds (user + system, all threads) of each step of the whole pipeline:
    /// read, denoise, resample, fill, tiles, quadtree, write.
    pub stage_cpu_s: [f64; 7],
    /// Median CPU seconds of the whole pipeline (summed per run, then the median).
    pub total_cpu_s: f64,
    /// Median CPU seconds of spade's bulk loading and of its incremental insertion.
    pub delaunay_cpu_s: [f64; 2],
    /// The faster Delaunay's CPU time / the whole pipeline's CPU time.
    pub total_cpu_ratio: f64,
    /// Median CPU seconds of each step's serial part (the calling thread's own CPU time).
    pub stage_serial_cpu_s: [f64; 7],
    /// The whole pipeline's wall time on an otherwise idle machine as the CPU times predict
    /// it: per step, the serial part plus the rest spread over `threads` workers (an
    /// estimate: it assumes the parallel parts balance and ignores memory bandwidth).
    pub idle_estimate_s: f64,
    /// The faster Delaunay's CPU time (one thread: its wall time when idle) / idle_estimate_s.
    pub idle_ratio_estimate: f64,
}

/// CPU seconds used so far, user + system: by the whole process (all threads), and by the
/// calling thread. The pipeline's stages run on the calling thread and hand their parallel
/// parts to rayon's workers, where the calling thread waits without using CPU: its own CPU
/// time in a stage is the stage's serial part.
#[cfg(unix)]
fn cpu_now() -> [f64; 2] {
    use rustix::time::{clock_gettime, ClockId};
    let s = |id| {
        let t = clock_gettime(id);
        t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
    };
    [s(ClockId::ProcessCPUTime), s(ClockId::ThreadCPUTime)]
}

/// No CPU clocks here: CPU times read 0.
#[cfg(not(unix))]
fn cpu_now() -> [f64; 2] {
    [0.0; 2]
}

/// The CPU seconds (process, calling thread) since `start`.
fn cpu_since(start: [f64; 2]) -> [f64; 2] {
    let now = cpu_now();
    [now[0] - start[0], now[1] - start[1]]
}

/// The CPU time of each step the pipeline announces to its progress (`grid_stages` opens
/// and closes one per stage around exactly what it times).
#[derive(Default)]
struct StageClock {
    open: Mutex<Option<(String, [f64; 2])>>,
    done: Mutex<Vec<(String, [f64; 2])>>,
}

fn locked<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl StageClock {
    /// CPU seconds (all threads, calling thread) of the step `label` (0 if it did not run).
    fn cpu(&self, label: &str) -> [f64; 2] {
        locked(&self.done)
            .iter()
            .find(|(l, _)| l == label)
            .map_or([0.0; 2], |(_, c)| *c)
    }
}

impl Progress for StageClock {
    fn start(&self, label: &str, _: u64) {
        *locked(&self.open) = Some((label.to_string(), cpu_now()));
    }
    fn advance(&self, _: u64) {}
    fn finish(&self) {
        if let Some((label, c0)) = locked(&self.open).take() {
            locked(&self.done).push((label, cpu_since(c0)));
        }
    }
}

/// One run of the grid stages.
struct GridRun {
    cloud: PointCloud,
    keep: Vec<bool>,
    grid: [usize; 2],
    hf: Heightfield,
    t: [f64; 4],
    /// CPU seconds (all threads, calling thread) of the same four steps.
    cpu: [[f64; 2]; 4],
}

/// One run of the tile stages on a filled grid.
struct TileRun {
    /// tiles, quadtree, write, extract.
    t: [f64; 4],
    /// CPU seconds (all threads, calling thread) of tiles, quadtree, write.
    cpu: [[f64; 2]; 3],
    tiling: [usize; 3],
    bytes: u64,
    triangles: usize,
}

/// Total size of the files under `dir`.
fn dir_bytes(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .map(|e| {
                    let p = e.path();
                    if p.is_dir() {
                        dir_bytes(&p)
                    } else {
                        e.metadata().map_or(0, |m| m.len())
                    }
                })
                .sum()
        })
        .unwrap_or(0)
}

/// The pipeline's stages with every table at its default, writing what the default
/// pipeline writes but previews and meshes (EXR with the default compression, manifest,
/// PNG and RAW heightmaps).
fn bench_pipeline() -> Pipeline {
    Pipeline {
        output: OutputConfig {
            relief: false,
            wireframe: false,
            meshes: Vec::new(),
            ..Default::default()
        },
        ..Default::default()
    }
}

/// The runs' output directories under the system's temporary directory, removed (untimed)
/// when the benchmark ends, whether it succeeded or not.
struct RunDirs(std::path::PathBuf);

impl RunDirs {
    fn new() -> RunDirs {
        RunDirs(std::env::temp_dir().join(format!("terratile-bench-{}", std::process::id())))
    }

    /// A fresh directory for run `run`.
    fn run(&self, run: usize) -> Result<std::path::PathBuf> {
        let dir = self.0.join(format!("run-{run}"));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        Ok(dir)
    }
}

impl Drop for RunDirs {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Runs the pipeline's tile stages on `hf` into a fresh directory of `dirs`, then extracts
/// the meshes beside them. Every run's files stay until the benchmark ends: removing them
/// between runs made the next run's file creation slower (ext4 without a journal, as on
/// this machine, skips recently deleted inodes when it allocates one, so each new file
/// scanned past the hundreds the previous run had just deleted), which a run writing into
/// a fresh directory does not pay.
///
/// The steps are `tile_stages`' own calls, made here one by one to read the CPU clock
/// between them.
fn tile_run(hf: &Heightfield, dirs: &RunDirs, run: usize) -> Result<TileRun> {
    use crate::terrain::{quadtree, tiles};
    let dir = dirs.run(run)?;
    let cfg = bench_pipeline();
    let mut marks = vec![(cpu_now(), Instant::now())];
    let mut set = tiles::tile(hf, &cfg.tiles)?;
    with_input_crs(&cfg, &mut set);
    marks.push((cpu_now(), Instant::now()));
    let qt = quadtree::build(&set, &cfg.quadtree)?;
    marks.push((cpu_now(), Instant::now()));
    let written = product_stages(&cfg, set, qt, Vec::new(), &dir, &NoProgress);
    marks.push((cpu_now(), Instant::now()));
    let bytes = dir_bytes(&dir);
    let TileStages { set, quadtree, .. } = written?;
    let t4 = Instant::now();
    let triangles = if set.holes() == 0 {
        extract_meshes(&set, &quadtree, &cfg.extract)?.triangles
    } else {
        0
    };
    let extract_s = t4.elapsed().as_secs_f64();
    let wall = |k: usize| (marks[k + 1].1 - marks[k].1).as_secs_f64();
    let cpu = |k: usize| {
        let (a, b) = (marks[k].0, marks[k + 1].0);
        [b[0] - a[0], b[1] - a[1]]
    };
    Ok(TileRun {
        t: [wall(0), wall(1), wall(2), extract_s],
        cpu: [cpu(0), cpu(1), cpu(2)],
        tiling: [set.tile_size, set.grid[0], set.grid[1]],
        bytes,
        triangles,
    })
}

fn grid_run(path: &Path) -> Result<GridRun> {
    let c0 = cpu_now();
    let t0 = Instant::now();
    // The columns `terratile run` reads for this pipeline (x, y and z only).
    let opts = ReadOptions {
        columns: crate::pipeline::read_columns(&bench_pipeline()),
        ..Default::default()
    };
    let (cloud, bounds) = points::read_with_bounds(path, &opts, &NoProgress)?;
    let t1 = Instant::now();
    let read_cpu = cpu_since(c0);
    let clock = StageClock::default();
    let g = grid_stages_with_bounds(&cloud, Some(bounds), &bench_pipeline(), &clock)?;
    let Some(d) = g.denoised else {
        return Err(Error::Internal(
            "denoise was asked for and did not run".into(),
        ));
    };
    let r = g.resampled;
    Ok(GridRun {
        cloud,
        keep: d.keep,
        grid: [r.spec.cols, r.spec.rows],
        hf: r.grid,
        t: [
            (t1 - t0).as_secs_f64(),
            g.seconds[0],
            g.seconds[1],
            g.seconds[2],
        ],
        cpu: [
            read_cpu,
            clock.cpu("denoise"),
            clock.cpu("resample"),
            clock.cpu("fill"),
        ],
    })
}

/// The Delaunay side's medians over `repeats` runs of each method.
struct DelaunayRuns {
    prepare_s: f64,
    bulk_s: f64,
    incremental_s: f64,
    /// CPU seconds, bulk then incremental.
    cpu_s: [f64; 2],
    vertices: usize,
    triangles: usize,
    merged: usize,
    peak: Option<u64>,
}

/// Triangulates the grid run's kept (denoised) points with both of spade's methods,
/// `repeats` times each, with the peak memory of this side alone.
fn delaunay_runs(last: &GridRun, repeats: usize) -> Result<DelaunayRuns> {
    reset_peak_rss();
    let t = Instant::now();
    let tin_points = delaunay::prepare(
        &last.cloud.x,
        &last.cloud.y,
        &last.cloud.z,
        Some(&last.keep),
    )?;
    let prepare_s = t.elapsed().as_secs_f64();
    let (mut bulk, mut incr) = (Vec::new(), Vec::new());
    let (mut bulk_cpu, mut incr_cpu) = (Vec::new(), Vec::new());
    let (mut vertices, mut triangles) = (0, 0);
    for _ in 0..repeats {
        for (method, out, out_cpu) in [
            (TinMethod::Bulk, &mut bulk, &mut bulk_cpu),
            (TinMethod::Incremental, &mut incr, &mut incr_cpu),
        ] {
            let (c, t) = (cpu_now(), Instant::now());
            let tin = delaunay::triangulate(&tin_points, method)?;
            out.push(t.elapsed().as_secs_f64());
            out_cpu.push(cpu_since(c)[0]);
            vertices = tin.vertices();
            triangles = tin.triangles();
        }
    }
    Ok(DelaunayRuns {
        prepare_s,
        bulk_s: median(bulk),
        incremental_s: median(incr),
        cpu_s: [median(bulk_cpu), median(incr_cpu)],
        vertices,
        triangles,
        merged: tin_points.merged,
        peak: peak_rss(),
    })
}

/// Runs the benchmark on `path`, `repeats` times each (medians reported).
pub fn terrain(path: &Path, repeats: usize) -> Result<TerrainBench> {
    let repeats = repeats.max(1);
    // The first run also measures the grid side's peak memory, from a fresh start (without
    // a reset, the peak is the process's so far, which at this point is the same run).
    reset_peak_rss();
    let mut runs = vec![grid_run(path)?];
    let grid_peak = peak_rss();
    // The tile stages run after the peak above is taken, so that it stays the grid stages'.
    let dirs = RunDirs::new();
    let mut tile_runs = vec![tile_run(&runs[0].hf, &dirs, 0)?];
    for k in 1..repeats {
        let last = grid_run(path)?;
        tile_runs.push(tile_run(&last.hf, &dirs, k)?);
        runs.push(last);
    }
    let tcol = |k: usize| median(tile_runs.iter().map(|r| r.t[k]).collect());
    // Per run, the seven steps' CPU seconds (all threads, calling thread).
    let run_cpu: Vec<[[f64; 2]; 7]> = runs
        .iter()
        .zip(&tile_runs)
        .map(|(g, t)| std::array::from_fn(|k| if k < 4 { g.cpu[k] } else { t.cpu[k - 4] }))
        .collect();
    let cpu_col = |k: usize, c: usize| median(run_cpu.iter().map(|r| r[k][c]).collect());
    let stage_cpu_s: [f64; 7] = std::array::from_fn(|k| cpu_col(k, 0));
    let stage_serial_cpu_s: [f64; 7] = std::array::from_fn(|k| cpu_col(k, 1));
    let total_cpu_s = median(
        run_cpu
            .iter()
            .map(|r| r.iter().map(|c| c[0]).sum())
            .collect(),
    );
    let threads = rayon::current_num_threads();
    let idle_estimate_s = median(
        run_cpu
            .iter()
            .map(|r| {
                r.iter()
                    .map(|c| c[1] + (c[0] - c[1]).max(0.0) / threads as f64)
                    .sum()
            })
            .collect(),
    );
    let total_s = median(
        runs.iter()
            .zip(&tile_runs)
            .map(|(g, t)| g.t.iter().sum::<f64>() + t.t[0] + t.t[1] + t.t[2])
            .collect(),
    );
    drop(dirs);
    let tile_last = tile_runs
        .last()
        .ok_or_else(|| Error::Internal("no run".into()))?;
    let (tiling, written_bytes, mesh_triangles) =
        (tile_last.tiling, tile_last.bytes, tile_last.triangles);
    let last = runs.pop().ok_or_else(|| Error::Internal("no run".into()))?;
    let mut times: Vec<[f64; 4]> = runs.iter().map(|r| r.t).collect();
    times.push(last.t);
    drop(runs);
    let col = |k: usize| median(times.iter().map(|t| t[k]).collect());
    let stages_s = median(times.iter().map(|t| t[1] + t[2] + t[3]).collect());
    let points = last.cloud.len() as u64;
    let record_length = last
        .cloud
        .sources
        .first()
        .and_then(|s| s.record_length)
        .map(u64::from);
    let kept = last.keep.iter().filter(|&&k| k).count() as u64;

    let tin = delaunay_runs(&last, repeats)?;
    let delaunay_peak = tin.peak;
    let (b, i) = (tin.bulk_s, tin.incremental_s);
    let (delaunay_s, method) = if i <= b {
        (i, "incremental")
    } else {
        (b, "bulk")
    };
    let delaunay_cpu_s = tin.cpu_s;
    let mb = |v: u64| v as f64 / 1e6;
    let record_bytes = record_length.map_or(0, |l| l * points);
    Ok(TerrainBench {
        file: path.display().to_string(),
        points,
        record_bytes,
        kept,
        grid: last.grid,
        read_s: col(0),
        denoise_s: col(1),
        resample_s: col(2),
        fill_s: col(3),
        stages_s,
        tin_prepare_s: tin.prepare_s,
        delaunay_bulk_s: b,
        delaunay_incremental_s: i,
        delaunay_s,
        delaunay_method: method.into(),
        stages_ratio: delaunay_s / stages_s,
        tin_vertices: tin.vertices,
        tin_triangles: tin.triangles,
        tin_merged: tin.merged,
        grid_peak_mb: grid_peak.map(mb),
        grid_peak_per_record_bytes: grid_peak
            .filter(|_| record_bytes > 0)
            .map(|p| p as f64 / record_bytes as f64),
        delaunay_peak_mb: delaunay_peak.map(mb),
        tiles_s: tcol(0),
        quadtree_s: tcol(1),
        write_s: tcol(2),
        extract_s: tcol(3),
        total_s,
        total_ratio: delaunay_s / total_s,
        tiling,
        exr_compression: crate::output::exr::ExrCompression::default().name().into(),
        written_bytes,
        mesh_triangles,
        repeats,
        threads,
        stage_cpu_s,
        total_cpu_s,
        delaunay_cpu_s,
        total_cpu_ratio: delaunay_cpu_s[0].min(delaunay_cpu_s[1]) / total_cpu_s,
        stage_serial_cpu_s,
        idle_estimate_s,
        idle_ratio_estimate: delaunay_cpu_s[0].min(delaunay_cpu_s[1]) / idle_estimate_s,
    })
}

/// One stage's line of the bench's text report: wall seconds, CPU seconds, then `note` (if
/// any) after three spaces.
fn stage_line(
    f: &mut std::fmt::Formatter<'_>,
    stage: &str,
    seconds: f64,
    cpu_s: f64,
    note: &str,
) -> std::fmt::Result {
    write!(f, "  {stage:<19}{seconds:>8.3} s   cpu {cpu_s:.3} s")?;
    if !note.is_empty() {
        write!(f, "   {note}")?;
    }
    writeln!(f)
}

impl std::fmt::Display for TerrainBench {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{}: {} points ({:.1} MB of point records), {} kept, grid {} × {}",
            self.file,
            self.points,
            self.record_bytes as f64 / 1e6,
            self.kept,
            self.grid[0],
            self.grid[1]
        )?;
        let c = &self.stage_cpu_s;
        stage_line(f, "read", self.read_s, c[0], "")?;
        stage_line(f, "denoise", self.denoise_s, c[1], "")?;
        stage_line(f, "resample", self.resample_s, c[2], "")?;
        stage_line(f, "fill", self.fill_s, c[3], "")?;
        writeln!(f, "  denoise+resample+fill {:>5.3} s", self.stages_s)?;
        writeln!(
            f,
            "  delaunay bulk      {:>8.3} s   incremental {:.3} s   ({} vertices, {} triangles, {} merged; prepare {:.3} s)",
            self.delaunay_bulk_s,
            self.delaunay_incremental_s,
            self.tin_vertices,
            self.tin_triangles,
            self.tin_merged,
            self.tin_prepare_s
        )?;
        writeln!(
            f,
            "  stages_ratio (Delaunay {} / grid stages): {:.1}",
            self.delaunay_method, self.stages_ratio
        )?;
        let [size, cols, rows] = self.tiling;
        stage_line(
            f,
            "tiles",
            self.tiles_s,
            c[4],
            &format!("({} tiles of {size}², {cols} × {rows})", cols * rows),
        )?;
        stage_line(f, "quadtree d2", self.quadtree_s, c[5], "")?;
        stage_line(
            f,
            "write",
            self.write_s,
            c[6],
            &format!(
                "(EXR {}, manifest, PNG + RAW heightmaps: {:.1} MB)",
                self.exr_compression,
                self.written_bytes as f64 / 1e6
            ),
        )?;
        writeln!(f, "  total, file to written tiles {:>6.3} s", self.total_s)?;
        writeln!(
            f,
            "  total_ratio (Delaunay {} / whole pipeline): {:.1}",
            self.delaunay_method, self.total_ratio
        )?;
        writeln!(
            f,
            "  CPU (user + system, all threads): whole pipeline {:.3} s, Delaunay bulk {:.3} s, incremental {:.3} s; total_cpu_ratio {:.1}",
            self.total_cpu_s, self.delaunay_cpu_s[0], self.delaunay_cpu_s[1], self.total_cpu_ratio
        )?;
        let sc = &self.stage_serial_cpu_s;
        writeln!(
            f,
            "  serial part (calling thread's CPU): read {:.3}, denoise {:.3}, resample {:.3}, fill {:.3}, tiles {:.3}, quadtree {:.3}, write {:.3} s",
            sc[0], sc[1], sc[2], sc[3], sc[4], sc[5], sc[6]
        )?;
        writeln!(
            f,
            "  idle-machine estimate (serial parts + the rest over {} threads): {:.3} s, ratio {:.1}",
            self.threads, self.idle_estimate_s, self.idle_ratio_estimate
        )?;
        writeln!(
            f,
            "  (beside it) mesh extraction at the default tolerance {:.3} s, {} triangles",
            self.extract_s, self.mesh_triangles
        )?;
        if let (Some(p), Some(r)) = (self.grid_peak_mb, self.grid_peak_per_record_bytes) {
            writeln!(
                f,
                "  peak memory of read+stages: {p:.1} MB = {r:.2} × the point record bytes"
            )?;
        }
        if let Some(p) = self.delaunay_peak_mb {
            writeln!(f, "  peak memory while triangulating: {p:.1} MB")?;
        }
        writeln!(
            f,
            "  (median of {} runs, {} threads)",
            self.repeats, self.threads
        )
    }
}
