//! Runs a pipeline file: reads the inputs, runs the configured stages in order, writes the
//! outputs into a staged directory that replaces the previous output only when everything
//! succeeded, and returns a summary of what each stage did.

use crate::config::LoadedPipeline;
use crate::error::{Error, Result};
use crate::fsutil::{normalize_lexically, Keep, StagedDir};
use crate::points::{self, Bounds, LasWriteOptions, PointCloud, SourceInfo};
use crate::progress::Progress;
use crate::terrain::{self, Heightfield};
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

/// What a run leaves for the stages that follow the grid (tiles, outputs, the Delaunay
/// baseline, assets) and for library users.
#[derive(Debug)]
pub struct RunContext {
    /// All points read (after the class filter and the cap), in file order.
    pub cloud: PointCloud,
    /// Per point of `cloud`: kept by noise removal (None when `[denoise]` is off).
    pub keep: Option<Vec<bool>>,
    /// The filled grid.
    pub grid: Heightfield,
}

impl RunContext {
    /// The points that survived noise removal, as a new cloud.
    pub fn denoised(&self) -> PointCloud {
        match &self.keep {
            Some(k) => self.cloud.select(k),
            None => self.cloud.clone(),
        }
    }
}

/// A finished run: its summary and what it computed.
#[derive(Debug)]
pub struct RunOutput {
    /// What each stage did.
    pub summary: RunSummary,
    /// The data the stages produced.
    pub context: RunContext,
}

/// Runs `pipeline`, reporting progress to `progress`, and returns the summary.
pub fn run(pipeline: &LoadedPipeline, progress: &dyn Progress) -> Result<RunSummary> {
    run_with_context(pipeline, progress).map(|o| o.summary)
}

/// Runs `pipeline` and returns the summary with the data: read → denoise → resample → fill →
/// tiles → quadtree → meshes and tile outputs (EXR, manifest, heightmaps, previews).
/// Outputs are written into a staged directory that replaces the output directory only when
/// every stage succeeded.
pub fn run_with_context(pipeline: &LoadedPipeline, progress: &dyn Progress) -> Result<RunOutput> {
    pipeline.check_stages()?;
    let files = pipeline.input_files()?;
    let cfg = &pipeline.config;
    let opts = cfg.input.read_options();
    let staged = stage_output_dir(pipeline, &files)?;

    let t = Instant::now();
    let cloud = points::read_all(&files, &opts, progress)?;
    let read_s = t.elapsed().as_secs_f64();
    if cloud.is_empty() {
        return Err(crate::memory::empty_input(pipeline, &cloud));
    }
    // The memory the stages will need, before they allocate it.
    crate::memory::estimate_pipeline(pipeline, &cloud)?
        .check(crate::memory::budget())
        .map_err(|(key, message)| pipeline.key_error(&key, message))?;
    let mut summary = read_summary(pipeline, &files, &cloud, read_s);

    // Noise removal, resampling and hole filling.
    let g = terrain::grid_stages(
        &cloud,
        cfg.denoise.enabled.then_some(&cfg.denoise),
        &cfg.resample,
        cfg.fill.enabled.then_some(&cfg.fill),
        progress,
    )
    .map_err(|e| pipeline.param_error(e))?;
    let keep = match g.denoised {
        Some(d) => Some(report_denoise(
            pipeline,
            &cloud,
            &opts,
            d,
            g.seconds[0],
            &staged,
            &mut summary,
        )?),
        None => None,
    };
    summary
        .stages
        .push(resample_report(&g.resampled, g.seconds[1]));
    let grid = g.resampled.grid;
    // Hole filling.
    if let Some(f) = g.filled {
        summary.stages.push(fill_report(pipeline, &f, g.seconds[2]));
    }

    // Tiles, quadtree metrics, meshes and the tile outputs (issue 4).
    let (reports, files) = tile_stages(pipeline, &grid, staged.path(), progress)?;
    summary.stages.extend(reports);
    summary.files.extend(files);

    // The Delaunay baseline and its comparison report ([baseline], issue 5).
    if cfg.baseline.enabled {
        run_baseline(
            pipeline,
            &cloud,
            keep.as_deref(),
            &grid,
            &staged,
            &mut summary,
            progress,
        )?;
    }

    // Assets stand on the filled grid ([[assets]], issue 6).
    if !cfg.assets.is_empty() {
        run_assets(pipeline, &grid, &staged, &mut summary)?;
    }

    staged.commit()?;
    Ok(RunOutput {
        summary,
        context: RunContext { cloud, keep, grid },
    })
}

/// The checks of the asset entries and output names, then the output directory checked,
/// locked and staged, all before any point is read. The pipeline file, the inputs `files` and
/// the asset inputs are kept out of harm's way.
fn stage_output_dir(pipeline: &LoadedPipeline, files: &[PathBuf]) -> Result<StagedDir> {
    let cfg = &pipeline.config;
    let out_dir = pipeline.output_dir();
    // Cheap checks of the asset entries before any work.
    crate::assets::validate(&cfg.assets, &pipeline.base_dir())
        .map_err(|(key, message)| pipeline.key_error(&key, message))?;
    crate::outnames::check(cfg).map_err(|(key, message)| pipeline.key_error(&key, message))?;
    // The output directory is checked, locked and staged before any point is read.
    let base = pipeline.base_dir();
    let asset_inputs: Vec<PathBuf> = cfg.assets.iter().map(|a| base.join(&a.input)).collect();
    let mut keep = vec![Keep {
        what: "pipeline file",
        path: &pipeline.path,
    }];
    keep.extend(files.iter().map(|path| Keep {
        what: "input file",
        path,
    }));
    keep.extend(asset_inputs.iter().map(|path| Keep {
        what: "asset input",
        path,
    }));
    StagedDir::new(&out_dir, &base, &keep)
}

/// A figure of a stage report: (name, value).
fn fig(k: &str, v: String) -> (String, String) {
    (k.to_string(), v)
}

/// The run summary as the read leaves it: the inputs, the points, and the read's report.
fn read_summary(
    pipeline: &LoadedPipeline,
    files: &[PathBuf],
    cloud: &PointCloud,
    read_s: f64,
) -> RunSummary {
    let bounds = cloud.bounds();
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

/// Noise removal's report, after writing the removed points to `noise.las` when
/// `denoise.write_removed` asks for it. Returns the keep mask.
fn report_denoise(
    pipeline: &LoadedPipeline,
    cloud: &PointCloud,
    opts: &points::ReadOptions,
    d: terrain::Denoised,
    seconds: f64,
    staged: &StagedDir,
    summary: &mut RunSummary,
) -> Result<Vec<bool>> {
    let st = &d.settings;
    let mut figures = vec![
        fig("points in", cloud.len().to_string()),
        fig("points out", d.kept.to_string()),
        fig("removed", d.removed().to_string()),
        fig("sparse", d.removed_sparse.to_string()),
        fig("low layers", d.removed_low.to_string()),
        fig(
            "voxel",
            format!("{:.3} × {:.3}", st.voxel_size, st.voxel_height),
        ),
        fig("min_points", st.min_points.to_string()),
    ];
    if pipeline.config.denoise.write_removed {
        let removed: Vec<bool> = d.keep.iter().map(|k| !k).collect();
        let path = staged.path().join(NOISE_FILE);
        // LAS/LAZ inputs of one point format: the removed records, byte for byte.
        if !points::write_selected_records(
            &path,
            &cloud.sources,
            opts,
            &removed,
            points::LOW_NOISE_CLASS,
        )? {
            let noise = cloud.select(&removed);
            let opts = LasWriteOptions {
                crs: cloud.crs().cloned(),
                classification: Some(points::LOW_NOISE_CLASS),
                ..Default::default()
            };
            points::write_las(&path, &noise, &opts)?;
        }
        summary.files.push(NOISE_FILE.into());
        figures.push(fig("written", NOISE_FILE.into()));
    }
    summary.stages.push(StageReport {
        stage: "denoise".into(),
        seconds,
        figures,
    });
    Ok(d.keep)
}

/// Resampling's report.
fn resample_report(r: &terrain::Resampled, seconds: f64) -> StageReport {
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
fn fill_report(pipeline: &LoadedPipeline, f: &terrain::FillReport, seconds: f64) -> StageReport {
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

/// The Delaunay baseline ([baseline], issue 5): the TIN of the denoised points, its mesh and
/// comparison report written into the staged directory, its measurements and report added to
/// `summary`.
fn run_baseline(
    pipeline: &LoadedPipeline,
    cloud: &PointCloud,
    keep: Option<&[bool]>,
    grid: &Heightfield,
    staged: &StagedDir,
    summary: &mut RunSummary,
    progress: &dyn Progress,
) -> Result<()> {
    let cfg = &pipeline.config;
    let grid_s: f64 = summary
        .stages
        .iter()
        .filter(|s| {
            matches!(
                s.stage.as_str(),
                "denoise" | "resample" | "fill" | "tiles" | "quadtree" | "extract" | "write"
            )
        })
        .map(|s| s.seconds)
        .sum();
    progress.start("baseline (Delaunay)", 0);
    let grid_peak = crate::bench::peak_rss();
    crate::bench::reset_peak_rss();
    let t = Instant::now();
    let fill = cfg.fill.enabled.then_some(&cfg.fill);
    let b = terrain::delaunay::baseline(
        cloud,
        keep,
        grid,
        grid_s,
        &cfg.baseline,
        &cfg.resample,
        fill,
    );
    let seconds = t.elapsed().as_secs_f64();
    progress.finish();
    let (mut report, tin) = b?;
    report.grid_peak_mb = grid_peak.map(|p| p as f64 / 1e6);
    report.tin_peak_mb = crate::bench::peak_rss().map(|p| p as f64 / 1e6);
    let b = &cfg.baseline;
    let in_staged = |key: &str, name: &str| -> Result<std::path::PathBuf> {
        let p = staged.path().join(name);
        // Checked up front (outnames); this catches what that check cannot foresee.
        if p.exists() {
            return Err(pipeline.key_error(
                key,
                format!("`{name}` collides with another output of the run"),
            ));
        }
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
        }
        Ok(p)
    };
    if !b.mesh.is_empty() {
        let origin = [grid.corner[0], grid.corner[1], grid.z_offset];
        let mesh = tin.to_mesh(origin);
        let path = in_staged("baseline.mesh", &b.mesh)?;
        let glb = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("glb"));
        if glb {
            let mpu = grid.crs.as_ref().map_or(1.0, |c| c.metres_per_unit());
            let bytes = crate::output::glb::glb_bytes(&mesh, "tin", mpu)?;
            crate::fsutil::write_bytes_atomic(&path, &bytes)?;
        } else {
            crate::mesh::io::write(&mesh, &path)?;
        }
        summary.files.push(b.mesh.clone());
    }
    drop(tin);
    let json = serde_json::to_vec_pretty(&report).map_err(|e| Error::Internal(e.to_string()))?;
    crate::fsutil::write_bytes_atomic(&in_staged("baseline.report", &b.report)?, &json)?;
    summary.files.push(b.report.clone());
    let acc = |s: &Option<terrain::accuracy::ErrorStats>| {
        s.map_or("—".into(), |s| format!("{:.3} m", s.rmse))
    };
    let mb = |m: Option<f64>| m.map_or("—".into(), |m| format!("{m:.0} MB"));
    summary.baseline = Some(BaselineMeasurements {
        prepare_s: report.prepare_s,
        build_s: report.build_s,
        grid_s: report.grid_s,
        ratio: report.ratio,
        rasterise_s: report.rasterise_s,
        grid_peak_mb: report.grid_peak_mb,
        tin_peak_mb: report.tin_peak_mb,
    });
    summary.stages.push(StageReport {
        stage: "baseline".into(),
        seconds,
        figures: vec![
            fig("method", format!("{:?}", report.method).to_lowercase()),
            fig("vertices", report.vertices.to_string()),
            fig("triangles", report.triangles.to_string()),
            fig("merged", report.merged.to_string()),
            fig("build", format!("{:.3} s", report.build_s)),
            fig("Delaunay / grid", format!("{:.1}", report.ratio)),
            fig("grid − TIN rmse", format!("{:.3} m", report.raster.rmse_m)),
            fig("held-out rmse grid", acc(&report.grid_accuracy)),
            fig("held-out rmse TIN", acc(&report.tin_accuracy)),
            fig("peak memory grid", mb(report.grid_peak_mb)),
            fig("peak memory TIN", mb(report.tin_peak_mb)),
        ],
    });
    Ok(())
}

/// The `[[assets]]` entries (issue 6), each set down on the filled grid and written into the
/// staged directory; their results and report added to `summary`.
fn run_assets(
    pipeline: &LoadedPipeline,
    grid: &Heightfield,
    staged: &StagedDir,
    summary: &mut RunSummary,
) -> Result<()> {
    let origin = [grid.corner[0], grid.corner[1], grid.z_offset];
    let t = Instant::now();
    for (i, a) in pipeline.config.assets.iter().enumerate() {
        if staged.path().join(&a.output).exists() {
            return Err(pipeline.key_error(
                &format!("assets[{i}].output"),
                format!(
                    "`{}` collides with another output of the run",
                    a.output.display()
                ),
            ));
        }
        let r =
            crate::assets::run_asset(a, &pipeline.base_dir(), staged.path(), Some(grid), origin)?;
        summary.files.push(r.output.display().to_string());
        summary.assets.push(r);
    }
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
    let mut set = tiles::tile(hf, &cfg.tiles)?;
    if let (None, Some(Ok(crs))) = (
        &set.crs,
        cfg.input.crs.as_deref().map(crate::geo::crs_from_key),
    ) {
        set.crs = Some(crs);
    }
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
/// The removed-noise file written with `denoise.write_removed = true`.
pub const NOISE_FILE: &str = "noise.las";
