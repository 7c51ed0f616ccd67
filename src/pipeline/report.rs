//! What a run reports: [`RunSummary`] (inputs, points, one [`StageReport`] per stage with
//! its figures, files written, assets, the baseline's measurements) and the functions that
//! turn each stage's result into its figures.

use crate::config::LoadedPipeline;
use crate::fsutil::normalize_lexically;
use crate::points::{Bounds, PointCloud, SourceInfo};
use crate::terrain;
use serde::Serialize;
use std::path::PathBuf;

/// What one stage did.
#[derive(Debug, Clone, Serialize)]
pub struct StageReport {
    /// Stage name (`read`, `denoise`, …).
    pub stage: String,
    /// Wall time in seconds.
    pub seconds: f64,
    /// Stage-specific figures, in display order (`points in`, `cells filled`, …).
    pub figures: Vec<(String, String)>,
}

/// What a run did.
#[derive(Debug, Clone, Serialize)]
pub struct RunSummary {
    /// The input files with their header facts.
    pub inputs: Vec<SourceInfo>,
    /// Points read (after class filter and cap).
    pub points: u64,
    /// Bounds of the points read.
    pub bounds: Option<Bounds>,
    /// CRS text of the first input that has one.
    pub crs: Option<String>,
    /// One report per stage, in order.
    pub stages: Vec<StageReport>,
    /// The output directory.
    pub output_dir: PathBuf,
    /// Files written, relative to the output directory.
    pub files: Vec<String>,
    /// Every `[[assets]]` entry: what was simplified, its error and where it was placed.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub assets: Vec<crate::assets::AssetReport>,
    /// The Delaunay baseline's times and memory (with `[baseline]`): measurements differ
    /// from run to run, so they are reported here and not in `baseline.json`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub baseline: Option<BaselineMeasurements>,
}

/// The run-to-run varying figures of the Delaunay baseline (seconds, MB).
#[derive(Debug, Clone, Serialize)]
pub struct BaselineMeasurements {
    /// Seconds to centre and merge the points.
    pub prepare_s: f64,
    /// Seconds to build the triangulation.
    pub build_s: f64,
    /// Seconds of the grid pipeline of the same run (every stage from denoise to writing).
    pub grid_s: f64,
    /// build_s / grid_s.
    pub ratio: f64,
    /// Seconds to rasterise the TIN onto the grid.
    pub rasterise_s: f64,
    /// Peak resident memory of the run before the baseline, MB.
    pub grid_peak_mb: Option<f64>,
    /// Peak resident memory while building the TIN (the points included), MB.
    pub tin_peak_mb: Option<f64>,
}

impl std::fmt::Display for RunSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "inputs:")?;
        for s in &self.inputs {
            writeln!(
                f,
                "  {} ({}{}): {} of {} points",
                s.path.display(),
                s.format,
                s.version
                    .map(|(a, b)| format!(" {a}.{b}"))
                    .unwrap_or_default(),
                s.points_read,
                s.points_in_file
            )?;
        }
        if let Some(b) = &self.bounds {
            writeln!(
                f,
                "points: {}  bounds x {:.2}..{:.2}  y {:.2}..{:.2}  z {:.2}..{:.2}",
                self.points, b.min[0], b.max[0], b.min[1], b.max[1], b.min[2], b.max[2]
            )?;
        }
        if let Some(c) = &self.crs {
            let short: String = c.chars().take(100).collect();
            writeln!(f, "crs: {short}{}", if c.len() > 100 { "…" } else { "" })?;
        }
        writeln!(f, "stages:")?;
        for s in &self.stages {
            let figs: Vec<String> = s.figures.iter().map(|(k, v)| format!("{k} {v}")).collect();
            writeln!(
                f,
                "  {:<10} {:>8.3} s  {}",
                s.stage,
                s.seconds,
                figs.join(", ")
            )?;
        }
        if !self.assets.is_empty() {
            writeln!(f, "assets:")?;
        }
        for a in &self.assets {
            write!(
                f,
                "  {}: {} → {} triangles",
                crate::simplify::InOut(&a.input, &a.output),
                a.triangles_in,
                a.triangles_out
            )?;
            if let (Some(m), Some(e)) = (a.method, &a.error) {
                write!(
                    f,
                    " ({m}), error max {:.3} % mean {:.3} % of its diagonal",
                    e.max_pct, e.mean_pct
                )?;
            }
            writeln!(
                f,
                ", at ({:.2}, {:.2}, {:.2}){}",
                a.position[0],
                a.position[1],
                a.position[2],
                if a.on_terrain {
                    ""
                } else {
                    " (no terrain: base at z = 0)"
                }
            )?;
            for w in &a.warnings {
                writeln!(f, "    warning: {w}")?;
            }
        }
        writeln!(
            f,
            "output: {} ({} files)",
            self.output_dir.display(),
            self.files.len()
        )
    }
}

/// A figure of a stage report: (name, value).
pub(super) fn fig(k: &str, v: String) -> (String, String) {
    (k.to_string(), v)
}

/// The run summary as the read leaves it: the inputs, the points (whose tight `bounds` the
/// reader measured), and the read's report.
pub(super) fn read_summary(
    pipeline: &LoadedPipeline,
    files: &[PathBuf],
    cloud: &PointCloud,
    bounds: Bounds,
    read_s: f64,
) -> RunSummary {
    let mut inputs = cloud.sources.clone();
    for s in &mut inputs {
        s.path = normalize_lexically(&s.path);
    }
    RunSummary {
        inputs,
        points: cloud.len() as u64,
        bounds: Some(bounds),
        crs: cloud.crs().map(|c| c.text()),
        stages: vec![StageReport {
            stage: "read".into(),
            seconds: read_s,
            figures: vec![
                ("files".into(), files.len().to_string()),
                ("points".into(), cloud.len().to_string()),
            ],
        }],
        output_dir: normalize_lexically(&pipeline.output_dir()),
        baseline: None,
        files: Vec::new(),
        assets: Vec::new(),
    }
}

/// Resampling's report.
pub(super) fn resample_report(r: &terrain::Resampled, seconds: f64) -> StageReport {
    let grid = &r.grid;
    let [_, measured, _, _] = grid.census();
    let cells = grid.cols() * grid.rows();
    StageReport {
        stage: "resample".into(),
        seconds,
        figures: vec![
            fig("points", r.points.to_string()),
            fig("grid", format!("{} × {}", r.spec.cols, r.spec.rows)),
            fig(
                "cell",
                format!("{:.3} × {:.3}", r.spec.cell_size[0], r.spec.cell_size[1]),
            ),
            fig("measured", measured.to_string()),
            fig(
                "empty",
                format!(
                    "{} ({:.1} %)",
                    cells - measured,
                    100.0 * (cells - measured) as f64 / cells as f64
                ),
            ),
        ],
    }
}

/// Hole filling's report.
pub(super) fn fill_report(
    pipeline: &LoadedPipeline,
    f: &terrain::FillReport,
    seconds: f64,
) -> StageReport {
    StageReport {
        stage: "fill".into(),
        seconds,
        figures: vec![
            fig("measured", f.measured.to_string()),
            fig("interpolated", f.interpolated.to_string()),
            fig(
                "fallback",
                format!("{} ({:?})", f.fallback, pipeline.config.fill.fallback).to_lowercase(),
            ),
            fig("left empty", f.empty.to_string()),
        ],
    }
}

/// Seconds of the stage named `stage` in `reports` (0 when it did not run).
pub fn stage_seconds(reports: &[StageReport], stage: &str) -> f64 {
    reports
        .iter()
        .find(|r| r.stage == stage)
        .map_or(0.0, |r| r.seconds)
}
