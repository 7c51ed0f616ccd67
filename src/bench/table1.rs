//! `bench table1`: the paper's Table 1 (Kim & Shin §3) redone on a real survey. For each point
//! count, a seeded random subset of the file (file order kept) goes through the grid pipeline
//! and through spade's Delaunay triangulation (bulk loading and incremental insertion), the
//! three interleaved and repeated; the table gives the median times, the peak memory each
//! method needs beyond the points, the triangle count, and the vertical RMSE of both surfaces
//! at 2 % held-out points, beside the paper's figures (Pentium IV: 34,379 points 0.094 s …
//! 3,408,187 points 63.7 s; Delaunay "more than 12 hours").

use super::median;
use crate::config::Pipeline;
use crate::error::{Error, Result};
use crate::output::OutputConfig;
use crate::pipeline::{
    current_rss, grid_stages, peak_rss, reset_peak_rss, stage_seconds, tile_stages,
};
use crate::points::{self, PointCloud, ReadOptions};
use crate::progress::NoProgress;
use crate::rng::SplitMix64;
use crate::terrain::accuracy::{holdout, ErrorStats};
use crate::terrain::delaunay::{self, TinMethod};
use crate::terrain::{denoise, fill, resample, DenoiseParams, FillParams, ResampleParams};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The paper's Table 1: points and seconds of its grid pipeline (Pentium IV).
pub const PAPER: [(u64, f64); 4] = [
    (34_379, 0.094),
    (430_674, 8.9),
    (1_626_972, 28.7),
    (3_408_187, 63.7),
];

/// The paper's Delaunay time: "more than 12 hours" at every size.
pub const PAPER_DELAUNAY_S: f64 = 12.0 * 3600.0;

/// One row of the table.
#[derive(Debug, Clone, Serialize)]
pub struct Table1Row {
    /// Points in the subset.
    pub points: u64,
    /// Median seconds of the grid pipeline end to end (denoise + resample + fill + tiles +
    /// quadtree + writing EXR tiles, heightmaps and manifest).
    pub grid_s: f64,
    /// Median seconds of noise removal.
    pub denoise_s: f64,
    /// Median seconds of resampling.
    pub resample_s: f64,
    /// Median seconds of hole filling.
    pub fill_s: f64,
    /// Median seconds of cutting the grid into tiles.
    pub tiles_s: f64,
    /// Median seconds of the quadtree error metrics (d2).
    pub quadtree_s: f64,
    /// Median seconds of writing the EXR tiles, heightmaps (PNG, RAW) and manifest.
    pub write_s: f64,
    /// Median seconds of the faster Delaunay build.
    pub delaunay_s: f64,
    /// Median seconds of spade's bulk loading.
    pub delaunay_bulk_s: f64,
    /// Median seconds of spade's incremental insertion in file order.
    pub delaunay_incremental_s: f64,
    /// The faster method.
    pub delaunay_method: String,
    /// delaunay_s / grid_s.
    pub ratio: f64,
    /// Peak memory the grid pipeline needs beyond the points, MB (measured in a fresh process
    /// by the CLI).
    pub grid_peak_mb: Option<f64>,
    /// Peak memory the faster Delaunay build needs beyond the points, MB.
    pub delaunay_peak_mb: Option<f64>,
    /// Grid cells (columns × rows).
    pub grid_cells: usize,
    /// TIN triangles.
    pub triangles: usize,
    /// Vertical RMSE of the grid at the held-out points, metres.
    pub grid_rmse: f64,
    /// Vertical RMSE of the TIN at the held-out points, metres.
    pub tin_rmse: f64,
    /// Held-out points scored.
    pub holdout: usize,
    /// The paper's grid time for this count, if it is one of the paper's.
    pub paper_grid_s: Option<f64>,
}

/// The whole benchmark.
#[derive(Debug, Clone, Serialize)]
pub struct Table1 {
    /// The file.
    pub file: String,
    /// Points it holds.
    pub file_points: u64,
    /// One row per count, in the order given.
    pub rows: Vec<Table1Row>,
    /// Counts skipped because the file holds fewer points.
    pub skipped: Vec<u64>,
    /// Repetitions (medians reported).
    pub repeats: usize,
    /// Worker threads of the grid pipeline.
    pub threads: usize,
}

/// The paper's counts, the default of `--counts`.
pub fn paper_counts() -> Vec<u64> {
    PAPER.iter().map(|p| p.0).collect()
}

/// The pipeline `bench table1` runs: every table at its default, writing the tiled EXR files
/// (heights and d2), the 16-bit PNG and RAW heightmaps and the manifest, the outputs a game
/// engine takes in; neither previews nor tile meshes (the TIN it is compared with is not
/// written either).
fn table1_pipeline(dir: &Path) -> Pipeline {
    Pipeline {
        output: OutputConfig {
            dir: dir.to_path_buf(),
            exr: true,
            manifest: true,
            png: true,
            raw: true,
            relief: false,
            wireframe: false,
            meshes: Vec::new(),
            ..OutputConfig::default()
        },
        ..Pipeline::default()
    }
}

/// Seconds spent by the grid pipeline end to end on `cloud` (denoise, resample, fill, tiles,
/// quadtree, writing the outputs into `dir`, which must exist), and its grid size.
fn grid_pipeline(cloud: &PointCloud, dir: &Path) -> Result<([f64; 6], usize)> {
    let cfg = table1_pipeline(dir);
    let g = grid_stages(cloud, &cfg, &NoProgress)?;
    drop(g.denoised);
    let r = g.resampled;
    let t = tile_stages(&cfg, &r.grid, dir, &NoProgress)?;
    let s = |stage: &str| stage_seconds(&t.reports, stage);
    Ok((
        [
            g.seconds[0],
            g.seconds[1],
            g.seconds[2],
            s("tiles"),
            s("quadtree"),
            s("write"),
        ],
        r.spec.cols * r.spec.rows,
    ))
}

/// A directory for the grid pipeline's outputs, removed with everything in it when dropped.
struct ScratchDir(PathBuf);

impl ScratchDir {
    fn new(tag: &str) -> Result<ScratchDir> {
        let p = std::env::temp_dir().join(format!("terratile-{tag}-{}", std::process::id()));
        if p.exists() {
            std::fs::remove_dir_all(&p).map_err(|e| Error::io(&p, e))?;
        }
        std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
        Ok(ScratchDir(p))
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        // Best effort: a leftover temporary directory is not worth failing the benchmark.
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Runs `f` and returns its result with the peak resident memory it added above what was
/// resident before it (None where /proc cannot say).
fn with_peak<T>(f: impl FnOnce() -> Result<T>) -> Result<(T, Option<f64>)> {
    let base = current_rss();
    let ok = reset_peak_rss();
    let v = f()?;
    let peak = peak_rss();
    let delta = match (ok, base, peak) {
        (true, Some(b), Some(p)) => Some(p.saturating_sub(b) as f64 / 1e6),
        _ => None,
    };
    Ok((v, delta))
}

/// Measures the peak memory one method needs beyond the points, for a subset of `count`
/// points: given (count, method) with method `grid`, `bulk` or `incremental`, returns MB.
/// The CLI runs [`table1_memory`] in a fresh process for each, because in this process the
/// allocator keeps freed memory resident and earlier runs would hide later needs.
pub type MemoryProbe<'a> = &'a dyn Fn(u64, &str) -> Result<Option<f64>>;

/// The subset `table1` uses for `count` (seeded, file order kept).
fn subset(all: &PointCloud, count: u64, seed: u64) -> PointCloud {
    let idx = SplitMix64::new(seed ^ count).sample_indices(all.len(), count as usize);
    all.gather(&idx)
}

/// One memory measurement (see [`MemoryProbe`]), meant to run alone in its process: reads
/// `path`, takes the subset, drops the rest, then runs `method` once and returns the peak
/// resident memory it added, in MB (None where /proc cannot say).
pub fn table1_memory(path: &Path, count: u64, seed: u64, method: &str) -> Result<Option<f64>> {
    let all = points::read(path, &ReadOptions::default(), &NoProgress)?;
    let mpu = all.crs().map_or(1.0, |c| c.metres_per_unit());
    if count > all.len() as u64 {
        return Err(Error::Usage(format!(
            "{}: holds {} points, not {count}",
            path.display(),
            all.len()
        )));
    }
    let cloud = subset(&all, count, seed);
    drop(all);
    match method {
        "grid" => {
            let dir = ScratchDir::new("table1")?;
            Ok(with_peak(|| grid_pipeline(&cloud, &dir.0))?.1)
        }
        "bulk" | "incremental" => {
            let d = denoise(&cloud, &DenoiseParams::default(), mpu)?;
            let p = delaunay::prepare(&cloud.x, &cloud.y, &cloud.z, Some(&d.keep))?;
            drop(d);
            let m = if method == "bulk" {
                TinMethod::Bulk
            } else {
                TinMethod::Incremental
            };
            Ok(with_peak(|| delaunay::triangulate(&p, m).map(|t| t.triangles()))?.1)
        }
        other => Err(Error::Usage(format!(
            "unknown method `{other}`: grid, bulk or incremental"
        ))),
    }
}

/// Runs the benchmark on `path` for each of `counts` (seeded subsets), `repeats` times each.
/// `memory` measures each method's peak memory (see [`MemoryProbe`]); without it the peaks
/// are measured in this process (first repetition only; underestimates after the first
/// count).
pub fn table1(
    path: &Path,
    counts: &[u64],
    repeats: usize,
    seed: u64,
    memory: Option<MemoryProbe>,
) -> Result<Table1> {
    let repeats = repeats.max(1);
    if let Some(&bad) = counts.iter().find(|&&c| c < 3) {
        return Err(Error::Usage(format!(
            "--counts: {bad} is not a usable point count (at least 3)"
        )));
    }
    let all = points::read(path, &ReadOptions::default(), &NoProgress)?;
    let mpu = all.crs().map_or(1.0, |c| c.metres_per_unit());
    let n = all.len() as u64;
    let dir = ScratchDir::new("table1")?;
    let (mut rows, mut skipped) = (Vec::new(), Vec::new());
    for &count in counts {
        if count > n {
            skipped.push(count);
            continue;
        }
        let cloud = subset(&all, count, seed);
        // The denoised points the Delaunay side triangulates (noise removal is not timed
        // twice: the TIN is built from the grid's own denoised points).
        let d = denoise(&cloud, &DenoiseParams::default(), mpu)?;
        let tin_points = delaunay::prepare(&cloud.x, &cloud.y, &cloud.z, Some(&d.keep))?;
        let (mut grid_t, mut bulk, mut incr) = (Vec::new(), Vec::new(), Vec::new());
        let mut grid_peak = None::<f64>;
        let mut tin_peaks = [None::<f64>; 2];
        let (mut cells, mut triangles) = (0, 0);
        for _ in 0..repeats {
            let ((t, c), peak) = with_peak(|| grid_pipeline(&cloud, &dir.0))?;
            grid_t.push(t);
            cells = c;
            grid_peak = max_opt(grid_peak, peak);
            for (k, (method, out)) in [
                (TinMethod::Bulk, &mut bulk),
                (TinMethod::Incremental, &mut incr),
            ]
            .into_iter()
            .enumerate()
            {
                let (secs, peak) = with_peak(|| {
                    let t = Instant::now();
                    let tin = delaunay::triangulate(&tin_points, method)?;
                    let secs = t.elapsed().as_secs_f64();
                    triangles = tin.triangles();
                    Ok(secs)
                })?;
                out.push(secs);
                tin_peaks[k] = max_opt(tin_peaks[k], peak);
            }
        }
        let col = |k: usize| median(grid_t.iter().map(|t| t[k]).collect());
        let grid_s = median(grid_t.iter().map(|t| t.iter().sum()).collect());
        let (b, i) = (median(bulk), median(incr));
        let (delaunay_s, method) = if i <= b {
            (i, "incremental")
        } else {
            (b, "bulk")
        };
        // The faster method's memory is the Delaunay build's.
        let tin_peak = match memory {
            Some(probe) => {
                grid_peak = probe(count, "grid")?;
                probe(count, method)?
            }
            None => tin_peaks[usize::from(method == "incremental")],
        };
        // Accuracy: both surfaces from 98 % of the denoised points, scored at the rest.
        let (train, test) = holdout(cloud.len(), Some(&d.keep), 0.02, seed);
        let mut g = resample(&cloud, Some(&train), &ResampleParams::default())?.grid;
        fill(&mut g, &FillParams::default())?;
        let tin = delaunay::triangulate(
            &delaunay::prepare(&cloud.x, &cloud.y, &cloud.z, Some(&train))?,
            TinMethod::Auto,
        )?;
        let xy: Vec<[f64; 2]> = test
            .iter()
            .map(|&k| [cloud.x[k as usize], cloud.y[k as usize]])
            .collect();
        let truth: Vec<f64> = test.iter().map(|&k| cloud.z[k as usize]).collect();
        let tz = tin.z_at_many(&xy);
        let gz: Vec<Option<f64>> = xy.iter().map(|&[x, y]| g.sample_bilinear(x, y)).collect();
        let grid_err = ErrorStats::of(gz.into_iter().zip(truth.iter().copied())).scaled(mpu);
        let tin_err = ErrorStats::of(tz.into_iter().zip(truth.iter().copied())).scaled(mpu);
        rows.push(Table1Row {
            points: count,
            grid_s,
            denoise_s: col(0),
            resample_s: col(1),
            fill_s: col(2),
            tiles_s: col(3),
            quadtree_s: col(4),
            write_s: col(5),
            delaunay_s,
            delaunay_bulk_s: b,
            delaunay_incremental_s: i,
            delaunay_method: method.into(),
            ratio: delaunay_s / grid_s,
            grid_peak_mb: grid_peak,
            delaunay_peak_mb: tin_peak,
            grid_cells: cells,
            triangles,
            grid_rmse: grid_err.rmse,
            tin_rmse: tin_err.rmse,
            holdout: test.len(),
            paper_grid_s: PAPER.iter().find(|p| p.0 == count).map(|p| p.1),
        });
    }
    if rows.is_empty() {
        return Err(Error::Usage(format!(
            "{}: holds {n} points, fewer than every count asked for ({})",
            path.display(),
            counts
                .iter()
                .map(u64::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    Ok(Table1 {
        file: path.display().to_string(),
        file_points: n,
        rows,
        skipped,
        repeats,
        threads: rayon::current_num_threads(),
    })
}

fn max_opt(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.max(b)),
        (a, b) => a.or(b),
    }
}

fn mb(v: Option<f64>) -> String {
    v.map_or("—".into(), |v| format!("{v:.0}"))
}

impl std::fmt::Display for Table1 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{} ({} points): median of {} runs, {} threads; memory is what each method needs beyond the points",
            self.file, self.file_points, self.repeats, self.threads
        )?;
        writeln!(f)?;
        writeln!(f, "| points | grid s (denoise / resample / fill / tiles / quadtree / write) | Delaunay s (bulk / incremental) | Delaunay / grid | grid MB | Delaunay MB | grid cells | triangles | grid RMSE m | TIN RMSE m | paper grid s | paper Delaunay |")?;
        writeln!(
            f,
            "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
        )?;
        for r in &self.rows {
            writeln!(
                f,
                "| {} | {:.3} ({:.3} / {:.3} / {:.3} / {:.3} / {:.3} / {:.3}) | {:.3} ({:.3} / {:.3}) | {:.1} | {} | {} | {} | {} | {:.3} | {:.3} | {} | {} |",
                r.points,
                r.grid_s,
                r.denoise_s,
                r.resample_s,
                r.fill_s,
                r.tiles_s,
                r.quadtree_s,
                r.write_s,
                r.delaunay_s,
                r.delaunay_bulk_s,
                r.delaunay_incremental_s,
                r.ratio,
                mb(r.grid_peak_mb),
                mb(r.delaunay_peak_mb),
                r.grid_cells,
                r.triangles,
                r.grid_rmse,
                r.tin_rmse,
                r.paper_grid_s.map_or("—".into(), |s| format!("{s}")),
                if r.paper_grid_s.is_some() { "> 12 h" } else { "—" },
            )?;
        }
        Ok(())
    }
}
