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
    validate_tile_stages(pipeline)?;
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

/// Checks the parameters of the tile stages and outputs before any work, naming the
/// pipeline key of a bad value (`tiles.size`, `extract.tolerance`, …).
pub fn validate_tile_stages(pipeline: &LoadedPipeline) -> Result<()> {
    let cfg = &pipeline.config;
    let at_key = |e: Error| match e {
        Error::Param {
            stage,
            param,
            value,
            message,
        } => pipeline.key_error(&format!("{stage}.{param}"), format!("{value}: {message}")),
        other => other,
    };
    cfg.tiles.validate().map_err(at_key)?;
    cfg.quadtree.validate().map_err(at_key)?;
    cfg.extract.validate().map_err(at_key)?;
    crate::output::validate(&cfg.output).map_err(at_key)?;
    Ok(())
}

/// The stages after hole filling: tiles → quadtree → outputs (meshes, EXR, heightmaps,
/// previews, manifest) written into `dir`. Returns one report per stage and the files.
pub fn tile_stages(
    pipeline: &LoadedPipeline,
    hf: &crate::terrain::Heightfield,
    dir: &std::path::Path,
    progress: &dyn Progress,
) -> Result<(Vec<StageReport>, Vec<String>)> {
    use crate::terrain::{quadtree, tiles};
    let cfg = &pipeline.config;
    let mut reports = Vec::new();
    let t = Instant::now();
    let set = tiles::tile(hf, &cfg.tiles)?;
    reports.push(StageReport {
        stage: "tiles".into(),
        seconds: t.elapsed().as_secs_f64(),
        figures: vec![
            ("tile size".into(), set.tile_size.to_string()),
            ("tiles".into(), format!("{}×{}", set.grid[0], set.grid[1])),
            (
                "samples".into(),
                format!("{}×{}", set.samples[0], set.samples[1]),
            ),
            ("holes".into(), set.holes().to_string()),
        ],
    });
    if crate::output::wants_meshes(&cfg.output) {
        // Refuse before the work: a mesh needs a filled heightfield.
        crate::terrain::extract::check_no_holes(&set)?;
    }
    let t = Instant::now();
    let qt = quadtree::build(&set, &cfg.quadtree)?;
    reports.push(StageReport {
        stage: "quadtree".into(),
        seconds: t.elapsed().as_secs_f64(),
        figures: vec![
            ("C".into(), qt.c.to_string()),
            ("K".into(), qt.k.to_string()),
        ],
    });
    let w = crate::output::write_terrain(dir, &set, &qt, &cfg.extract, &cfg.output, progress)?;
    if crate::output::wants_meshes(&cfg.output) {
        reports.push(StageReport {
            stage: "extract".into(),
            seconds: w.extract_s,
            figures: vec![("triangles".into(), w.triangles.to_string())],
        });
    }
    reports.push(StageReport {
        stage: "write".into(),
        seconds: w.write_s,
        figures: vec![("files".into(), w.files.len().to_string())],
    });
    Ok((reports, w.files))
}
