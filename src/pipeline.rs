//! Runs a pipeline file: reads the inputs, runs the configured stages in order, writes the
//! outputs into a staged directory that replaces the previous output only when everything
//! succeeded, and returns a summary of what each stage did.

use crate::config::LoadedPipeline;
use crate::error::{Error, Result};
use crate::points::{self, Bounds, SourceInfo};
use crate::progress::Progress;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

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
                "  {} → {}: {} → {} triangles",
                a.input.display(),
                a.output.display(),
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
        }
        writeln!(
            f,
            "output: {} ({} files)",
            self.output_dir.display(),
            self.files.len()
        )
    }
}

/// Runs `pipeline`, reporting progress to `progress`.
pub fn run(pipeline: &LoadedPipeline, progress: &dyn Progress) -> Result<RunSummary> {
    let files = pipeline.input_files()?;
    let cfg = &pipeline.config;
    let opts = cfg.input.read_options();
    let out_dir = pipeline.output_dir();
    // Cheap checks of the asset entries before any work.
    crate::assets::validate(&cfg.assets, &pipeline.base_dir())
        .map_err(|(key, message)| pipeline.key_error(&key, message))?;

    let t = Instant::now();
    let cloud = points::read_all(&files, &opts, progress)?;
    let read_s = t.elapsed().as_secs_f64();
    if cloud.is_empty() {
        return Err(Error::Data {
            stage: "read",
            message: "no points left after the class filter".into(),
        });
    }
    let bounds = cloud.bounds();
    let mut summary = RunSummary {
        inputs: cloud.sources.clone(),
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
        output_dir: out_dir.clone(),
        files: Vec::new(),
        assets: Vec::new(),
    };
    if !cfg.assets.is_empty() {
        // No terrain stage exists yet, so there is no heightfield: assets stand on z = 0.
        // When the terrain stages land, pass the run's filled Heightfield here (and its
        // corner and z offset as the origin).
        let heightfield: Option<&crate::terrain::heightfield::Heightfield> = None;
        let origin = heightfield.map_or([0.0; 3], |h| [h.corner[0], h.corner[1], h.z_offset]);
        let t = Instant::now();
        let staged = crate::fsutil::StagedDir::new(&out_dir)?;
        for a in &cfg.assets {
            let r = crate::assets::run_asset(
                a,
                &pipeline.base_dir(),
                staged.path(),
                heightfield,
                origin,
            )?;
            summary.files.push(r.output.display().to_string());
            summary.assets.push(r);
        }
        staged.commit()?;
        let tris: usize = summary.assets.iter().map(|a| a.triangles_out).sum();
        summary.stages.push(StageReport {
            stage: "assets".into(),
            seconds: t.elapsed().as_secs_f64(),
            figures: vec![
                ("assets".into(), summary.assets.len().to_string()),
                ("triangles".into(), tris.to_string()),
                (
                    "origin".into(),
                    format!("({}, {}, {})", origin[0], origin[1], origin[2]),
                ),
            ],
        });
    }
    Ok(summary)
}
