//! The run: the one place that spells the stage order. read → denoise → resample → fill →
//! tiles → quadtree → extract → write, then the Delaunay baseline and the assets; each stage
//! timed and reported. `bench terrain` and `bench table1` time these same functions
//! ([`grid_stages`], [`tile_stages`]).

use super::memory::{empty_input, estimate_pipeline, peak_rss, reset_peak_rss};
use super::plan::Plan;
use super::report::{
    fig, fill_report, read_summary, resample_report, BaselineMeasurements, RunSummary, StageReport,
};
use crate::config::{LoadedPipeline, Pipeline};
use crate::error::{Error, Result};
use crate::fsutil::StagedDir;
use crate::outnames::NOISE_FILE;
use crate::points::{self, LasWriteOptions, PointCloud};
use crate::progress::Progress;
use crate::terrain::{self, Denoised, FillReport, Heightfield, Quadtree, Resampled, TileSet};
use std::path::Path;
use std::time::Instant;

/// What a run leaves for the stages that follow the grid (tiles, outputs, the Delaunay
/// baseline, assets) and for library users.
#[derive(Debug)]
pub struct RunContext {
    /// All points read (after the class filter and the cap), in file order, with the
    /// attribute columns the run's stages needed ([`read_columns`]; the others are empty).
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
    // Streamed through temporary bricks when `[scale]` asks or the input would not fit.
    if let Some(summary) = super::stream::run_if_streaming(pipeline, progress)? {
        return Ok(summary);
    }
    run_with_context(pipeline, progress).map(|o| o.summary)
}

/// Runs `pipeline` and returns the summary with the data: read → denoise → resample → fill →
/// tiles → quadtree → meshes and tile outputs (EXR, manifest, heightmaps, previews), then
/// the baseline and the assets. Outputs are written into a staged directory that replaces
/// the output directory only when every stage succeeded.
pub fn run_with_context(pipeline: &LoadedPipeline, progress: &dyn Progress) -> Result<RunOutput> {
    let plan = Plan::new(pipeline)?;
    let cfg = &pipeline.config;
    let staged = plan.stage_output_dir()?;
    let (cloud, bounds, mut summary) = read(&plan, progress)?;
    let g = grid_stages_with_bounds(&cloud, Some(bounds), cfg, progress)
        .map_err(|e| pipeline.param_error(e))?;
    let (keep, grid) = report_grid(pipeline, &cloud, g, &staged, &mut summary)?;
    // The tiles and their d2 are dropped here, before the baseline measures its memory.
    let TileStages { reports, files, .. } = tile_stages(cfg, &grid, staged.path(), progress)?;
    summary.stages.extend(reports);
    summary.files.extend(files);
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
    if !cfg.assets.is_empty() {
        run_assets(pipeline, &grid, &staged, &mut summary)?;
    }
    staged.commit()?;
    Ok(RunOutput {
        summary,
        context: RunContext { cloud, keep, grid },
    })
}

/// The read: every input into one cloud, refused when empty or when the stages would need
/// more memory than the budget; returns the cloud, its tight bounds (measured by the
/// readers as they decode, so that the estimate, the report and noise removal make no pass
/// of their own over the columns) and the summary as the read leaves it.
fn read(
    plan: &Plan<'_>,
    progress: &dyn Progress,
) -> Result<(PointCloud, crate::points::Bounds, RunSummary)> {
    let pipeline = plan.pipeline;
    let mut opts = pipeline.config.input.read_options();
    opts.columns = read_columns(&pipeline.config);
    let t = Instant::now();
    let (cloud, bounds) = points::read_all_with_bounds(&plan.inputs, &opts, progress)?;
    let read_s = t.elapsed().as_secs_f64();
    if cloud.is_empty() {
        return Err(empty_input(pipeline, &cloud));
    }
    // The memory the stages will need, before they allocate it.
    estimate_pipeline(pipeline, &cloud, &bounds)?
        .check(crate::memory::budget())
        .map_err(|e| pipeline.param_error(e))?;
    let summary = read_summary(pipeline, &plan.inputs, &cloud, bounds, read_s);
    Ok((cloud, bounds, summary))
}

/// The attribute columns a run of `cfg` reads besides x, y and z: none when no stage looks
/// at them (noise removal, resampling, filling and the tile stages take x, y and z only), so
/// that the reader neither decodes nor stores them (17 of the 99 MB a 3.4 M-point cloud
/// takes); all when ground classification (the file's own classes), the Delaunay baseline
/// (its ground points by class) or `denoise.write_removed` (the removed points' attributes)
/// is on.
pub fn read_columns(cfg: &Pipeline) -> points::Columns {
    if cfg.ground.enabled || cfg.baseline.enabled || cfg.denoise.write_removed {
        points::Columns::ALL
    } else {
        points::Columns::XYZ
    }
}

/// What [`grid_stages`] leaves: each stage's result and its wall time.
#[derive(Debug)]
pub struct GridStages {
    /// Noise removal's result (`None` when it was off).
    pub denoised: Option<Denoised>,
    /// The resampled grid, filled in place when filling was on.
    pub resampled: Resampled,
    /// Hole filling's report (`None` when it was off).
    pub filled: Option<FillReport>,
    /// Seconds spent in denoise, resample and fill (0 for a stage that was off).
    pub seconds: [f64; 3],
    /// Ground classification's flags per point and report (`None` when `[ground]` is off).
    pub ground: Option<(Vec<bool>, crate::classify::ClassifyReport)>,
}

/// The grid stages of `cfg` on `cloud`: denoise (when `[denoise]` is on), resample and fill
/// (when `[fill]` is on). Resampling keeps its per-cell sums in noise removal's sorted-key
/// buffer, already mapped, instead of faulting in a fresh one.
pub fn grid_stages(
    cloud: &PointCloud,
    cfg: &Pipeline,
    progress: &dyn Progress,
) -> Result<GridStages> {
    grid_stages_with_bounds(cloud, None, cfg, progress)
}

/// [`grid_stages`] given the tight bounds of all of `cloud`'s points, as the reader measured
/// them ([`points::read_with_bounds`]), so that noise removal need not measure them again;
/// resampling takes the kept points' bounds that noise removal found.
pub fn grid_stages_with_bounds(
    cloud: &PointCloud,
    bounds: Option<crate::points::Bounds>,
    cfg: &Pipeline,
    progress: &dyn Progress,
) -> Result<GridStages> {
    let mut seconds = [0.0; 3];
    let mut scratch: Vec<u64> = Vec::new();
    let denoised = if cfg.denoise.enabled {
        progress.start("denoise", 0);
        let t = Instant::now();
        let mpu = cloud.crs().map_or(1.0, |c| c.metres_per_unit());
        let d = terrain::denoise::denoise_reusing(cloud, &cfg.denoise, mpu, &mut scratch, bounds);
        seconds[0] = t.elapsed().as_secs_f64();
        progress.finish();
        Some(d?)
    } else {
        None
    };
    let keep = denoised.as_ref().map(|d| d.keep.as_slice());
    let ground = if cfg.ground.enabled {
        progress.start("ground", 0);
        let g = crate::classify::ground_of(cloud, keep, &cfg.ground);
        progress.finish();
        Some(g?)
    } else {
        None
    };
    // With `surface = "ground"` the grid is built from the ground points (which are all
    // kept by noise removal) alone.
    let keep = match &ground {
        Some((g, _)) if cfg.ground.surface == terrain::ground::Surface::Ground => {
            Some(g.as_slice())
        }
        _ => keep,
    };
    progress.start("resample", 0);
    let t = Instant::now();
    // Noise removal's kept bounds hold when its flags are the ones resampling takes.
    let known = match (&denoised, &ground) {
        (Some(d), None) => d.kept_bounds.map(|b| (b, d.kept)),
        _ => None,
    };
    let r = terrain::resample::resample_reusing(cloud, keep, &cfg.resample, &mut scratch, known);
    drop(scratch);
    seconds[1] = t.elapsed().as_secs_f64();
    progress.finish();
    let mut resampled = r?;
    let filled = if cfg.fill.enabled {
        progress.start("fill", 0);
        let t = Instant::now();
        let f = terrain::fill(&mut resampled.grid, &cfg.fill);
        seconds[2] = t.elapsed().as_secs_f64();
        progress.finish();
        Some(f?)
    } else {
        None
    };
    Ok(GridStages {
        denoised,
        resampled,
        filled,
        seconds,
        ground,
    })
}

/// The grid stages' reports added to `summary` (and the removed points written when asked);
/// returns the keep mask and the filled grid.
fn report_grid(
    pipeline: &LoadedPipeline,
    cloud: &PointCloud,
    g: GridStages,
    staged: &StagedDir,
    summary: &mut RunSummary,
) -> Result<(Option<Vec<bool>>, Heightfield)> {
    let keep = match g.denoised {
        Some(d) => Some(report_denoise(
            pipeline,
            cloud,
            d,
            g.seconds[0],
            staged,
            summary,
        )?),
        None => None,
    };
    let keep = match g.ground {
        Some((ground, r)) => {
            report_ground(pipeline, cloud, &ground, r, staged, summary)?;
            match pipeline.config.ground.surface {
                terrain::ground::Surface::Ground => Some(ground),
                terrain::ground::Surface::All => keep,
            }
        }
        None => keep,
    };
    summary
        .stages
        .push(resample_report(&g.resampled, g.seconds[1]));
    if let Some(f) = &g.filled {
        summary.stages.push(fill_report(pipeline, f, g.seconds[2]));
    }
    Ok((keep, g.resampled.grid))
}

/// Ground classification's report, after writing the classified points to
/// `classified.las` when `ground.write_classified` asks for it.
fn report_ground(
    pipeline: &LoadedPipeline,
    cloud: &PointCloud,
    ground: &[bool],
    r: crate::classify::ClassifyReport,
    staged: &StagedDir,
    summary: &mut RunSummary,
) -> Result<()> {
    let cfg = &pipeline.config.ground;
    let mut figures = vec![
        fig("points", r.points.to_string()),
        fig("ground", r.ground.to_string()),
    ];
    match &r.settings {
        Some(s) => figures.push(fig(
            "settings",
            format!(
                "cell {} m, window {} m, slope {}, threshold {} m, scalar {} m",
                s.cell_size, s.window, s.slope, s.threshold, s.scalar
            ),
        )),
        None => figures.push(fig("source", "the file's own class 2".into())),
    }
    if cfg.write_classified {
        let name = crate::classify::CLASSIFIED_FILE;
        let opts = pipeline.config.input.read_options();
        crate::classify::write_classified(&staged.path().join(name), cloud, &opts, ground)
            .map_err(|e| pipeline.key_error("ground.write_classified", e.to_string()))?;
        summary.files.push(name.into());
        figures.push(fig("written", name.into()));
    }
    summary.stages.push(StageReport {
        stage: "ground".into(),
        seconds: r.seconds,
        figures,
    });
    Ok(())
}

/// Noise removal's report, after writing the removed points to `noise.las` when
/// `denoise.write_removed` asks for it. Returns the keep mask.
fn report_denoise(
    pipeline: &LoadedPipeline,
    cloud: &PointCloud,
    d: Denoised,
    seconds: f64,
    staged: &StagedDir,
    summary: &mut RunSummary,
) -> Result<Vec<bool>> {
    let opts = &pipeline.config.input.read_options();
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
    // The grid pipeline end to end: every stage so far but the read.
    let grid_s: f64 = summary
        .stages
        .iter()
        .filter(|s| s.stage != "read")
        .map(|s| s.seconds)
        .sum();
    progress.start("baseline (Delaunay)", 0);
    let grid_peak = peak_rss();
    reset_peak_rss();
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
    report.tin_peak_mb = peak_rss().map(|p| p as f64 / 1e6);
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
        let mpu = grid.crs.as_ref().map_or(1.0, |c| c.metres_per_unit());
        crate::mesh::io::write_named(&mesh, &path, "tin", mpu)?;
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

/// What [`tile_stages`] leaves: one report per stage, the files written, and the products
/// (for the benchmarks, which time mesh extraction beside the run).
#[derive(Debug)]
pub struct TileStages {
    /// One report per stage, in order.
    pub reports: Vec<StageReport>,
    /// The files written, relative to the directory, sorted.
    pub files: Vec<String>,
    /// The tiles.
    pub set: TileSet,
    /// Their quadtree d2.
    pub quadtree: Quadtree,
}

/// The stages after hole filling: tiles → quadtree → extract (when an output wants meshes)
/// → outputs (meshes, EXR, heightmaps, previews, manifest) written into `dir`.
pub fn tile_stages(
    cfg: &Pipeline,
    hf: &Heightfield,
    dir: &Path,
    progress: &dyn Progress,
) -> Result<TileStages> {
    use crate::terrain::{quadtree, tiles};
    let mut reports = Vec::new();
    let t = Instant::now();
    let mut set = tiles::tile(hf, &cfg.tiles)?;
    with_input_crs(cfg, &mut set);
    reports.push(tiles_report(&set, t.elapsed().as_secs_f64()));
    // Refuse before the work.
    check_products(cfg, &set)?;
    let t = Instant::now();
    let qt = quadtree::build(&set, &cfg.quadtree)?;
    reports.push(quadtree_report(&qt, t.elapsed().as_secs_f64()));
    product_stages(cfg, set, qt, reports, dir, progress)
}

/// What the outputs need of the tiles, checked before the quadtree and the writers run: a
/// mesh needs a filled heightfield, the Cesium tileset a CRS it can reproject.
fn check_products(cfg: &Pipeline, set: &TileSet) -> Result<()> {
    if cfg.output.wants_meshes() {
        crate::terrain::extract::check_no_holes(set)?;
    }
    if cfg.output.quantized_mesh {
        crate::geo::tms::check(set)?;
    }
    Ok(())
}

/// `[input] crs` given to a tile set whose inputs named none.
pub fn with_input_crs(cfg: &Pipeline, set: &mut TileSet) {
    if let (None, Some(Ok(crs))) = (
        &set.crs,
        cfg.input.crs.as_deref().map(crate::geo::crs_from_key),
    ) {
        set.layout.crs = Some(crs);
    }
}

/// The tiles stage's report.
pub fn tiles_report(set: &TileSet, seconds: f64) -> StageReport {
    tiles_report_with(set, set.holes(), seconds)
}

/// The tiles stage's report, with the set's hole samples counted already.
pub fn tiles_report_with(set: &TileSet, holes: usize, seconds: f64) -> StageReport {
    StageReport {
        stage: "tiles".into(),
        seconds,
        figures: vec![
            ("tile size".into(), set.tile_size.to_string()),
            ("tiles".into(), format!("{}×{}", set.grid[0], set.grid[1])),
            (
                "samples".into(),
                format!("{}×{}", set.samples[0], set.samples[1]),
            ),
            ("holes".into(), holes.to_string()),
        ],
    }
}

/// The quadtree stage's report.
pub fn quadtree_report(qt: &Quadtree, seconds: f64) -> StageReport {
    StageReport {
        stage: "quadtree".into(),
        seconds,
        figures: vec![
            ("C".into(), qt.c.to_string()),
            ("K".into(), qt.k.to_string()),
        ],
    }
}

/// The stages after the quadtree, on tiles and d2 however they were made (in memory or by
/// shards): extract (when an output wants meshes) → outputs written into `dir`; their
/// reports appended to `reports`.
pub fn product_stages(
    cfg: &Pipeline,
    set: TileSet,
    qt: Quadtree,
    mut reports: Vec<StageReport>,
    dir: &Path,
    progress: &dyn Progress,
) -> Result<TileStages> {
    check_products(cfg, &set)?;
    cfg.output.validate()?;
    let meshes = if cfg.output.wants_meshes() {
        let t = Instant::now();
        let m = crate::terrain::extract::extract_meshes(&set, &qt, &cfg.extract)?;
        reports.push(StageReport {
            stage: "extract".into(),
            seconds: t.elapsed().as_secs_f64(),
            figures: vec![("triangles".into(), m.triangles.to_string())],
        });
        Some(m)
    } else {
        None
    };
    let t = Instant::now();
    let products = crate::output::TerrainProducts {
        set: &set,
        quadtree: &qt,
        meshes: meshes.as_ref(),
    };
    let mut files = crate::output::write_terrain(dir, &products, &cfg.output, progress)?;
    reports.push(StageReport {
        stage: "write".into(),
        seconds: t.elapsed().as_secs_f64(),
        figures: vec![("files".into(), files.len().to_string())],
    });
    if cfg.output.quantized_mesh {
        let t = Instant::now();
        let ts = crate::geo::tms::tileset_with(
            &set,
            cfg.output.quantized_mesh_tolerance,
            !cfg.output.quantized_mesh_lattice,
        )?;
        let written = crate::output::qmesh::write(dir, &ts)?;
        reports.push(StageReport {
            stage: "quantized-mesh".into(),
            seconds: t.elapsed().as_secs_f64(),
            figures: vec![
                ("levels".into(), ts.levels.len().to_string()),
                ("tiles".into(), written.len().saturating_sub(1).to_string()),
            ],
        });
        files.extend(written);
        files.sort();
    }
    drop(meshes);
    Ok(TileStages {
        reports,
        files,
        set,
        quadtree: qt,
    })
}
