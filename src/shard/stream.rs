//! The single-machine streaming driver of `terratile run` (see `docs/scale.md`): the same
//! shard code as the in-memory run, fed from temporary files instead of one cloud.
//!
//! 1. **Scan**: the headers of all inputs (bounds, counts, CRS); decides whether the run
//!    fits the memory budget in memory (`[scale] mode = "auto"`).
//! 2. **Bucket**: one read of every input in file order (LAS from its memory map, LAZ
//!    through the chunk decoder, batch by batch), each point appended to its brick
//!    ([`super::bricks`]) through fixed-size buffers; the exact bounds and number of the
//!    points are reduced on the way (noise removal's lattice).
//! 3. **Denoise windows**: square windows of low-layer columns, each reading the bricks its
//!    columns and halo overlap: the counts at every voxel height (summed, the height
//!    chosen), then the keep flags of its own points ([`denoise::shard_counts`],
//!    [`denoise::shard_denoise`]); the kept points' bounds and number fix the grid.
//! 4. **Grid shards**: blocks of tiles, each resampling the kept points of the bricks its
//!    cells and halo overlap ([`resample::resample_window`]), then [`super::prepare`],
//!    [`super::complete_coarse`], [`super::finish`] and [`super::merge`]; the tiles are
//!    written by the in-memory run's own output stages.
//!
//! Windows and shards run in parallel, as many at once as the budget allows. Temporary
//! files live in one directory beside the output (`.NAME.stream`, or under
//! `[scale] temp_dir`), marked by a `job.txt` that names the inputs and settings: terratile
//! removes only directories with that marker and only the file names it writes, on success,
//! on failure and on SIGINT/SIGTERM. After a crash (the process killed outright) the next
//! run with the same inputs and settings resumes: a finished bucketing pass (`bricks.json`
//! present) and every finished denoise window (its `keep-…` file present: files are written
//! under a temporary name and renamed when complete) are not redone.

use super::bricks::{self, BrickLattice, BrickPoints, BrickWriter, SourceTransform};
use super::direct::{self, FileBox, Files};
use super::reuse;
use super::{complete_coarse, finish_with, merge, prepare, prepared_spill};
use super::{ShardLayout, ShardOutput};
use crate::config::LoadedPipeline;
use crate::error::{Error, Result};
use crate::fsutil::write_bytes_atomic;
use crate::pipeline::{peak_rss, Plan, RunSummary, StageReport};
use crate::points::{self, Bounds, Crs, PointCloud, SourceInfo};
use crate::progress::Progress;
use crate::terrain::denoise::{self, ColumnWindow, Frame};
use crate::terrain::fill::{Fallback, FillReport};
use crate::terrain::resample::{self, GridSpec};
use crate::terrain::Heightfield;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// How `terratile run` holds the points.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// In memory when the estimate fits the budget, else streamed.
    #[default]
    Auto,
    /// Always in memory.
    Memory,
    /// Always streamed.
    Stream,
}

/// How the streamed run's windows and shards get their points.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ReadMode {
    /// Directly from the files when the inputs are uncompressed LAS tiles small enough that
    /// each point is decoded at most [`DIRECT_MAX_READS`] times, else through bricks.
    #[default]
    Auto,
    /// Always through temporary bricks.
    Bricks,
    /// Always directly from the input files, by their points' bounds.
    Direct,
}

/// Reads per point (estimated from the headers) up to which `read = "auto"` reads LAS tiles
/// directly: decoding a LAS record costs about what reading a brick record back costs, and
/// the bricks cost one write and at least two reads of every point.
pub const DIRECT_MAX_READS: f64 = 8.0;

/// `[scale]`
#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ScaleConfig {
    /// `auto` (default), `memory` or `stream`.
    #[serde(default)]
    pub mode: Mode,
    /// The memory budget of the choice and of the streaming run, e.g. `"4GiB"` (default:
    /// `--max-memory`, else half of the machine's memory). `--max-memory` wins.
    #[serde(default)]
    pub memory_budget: Option<String>,
    /// Directory for the temporary files (default: beside the output directory).
    #[serde(default)]
    pub temp_dir: Option<PathBuf>,
    /// `auto` (default), `bricks` or `direct`: how windows and shards read their points.
    #[serde(default)]
    pub read: ReadMode,
}

impl ScaleConfig {
    /// Checks `memory_budget`.
    pub fn validate(&self) -> Result<()> {
        if let Some(s) = &self.memory_budget {
            crate::memory::parse_size(s)
                .map_err(|e| Error::param("scale", "memory_budget", s, e))?;
        }
        Ok(())
    }

    /// The budget in bytes: `--max-memory`, else `memory_budget`, else the default.
    pub fn budget(&self) -> u64 {
        match &self.memory_budget {
            Some(s) if !crate::memory::budget_is_set() => {
                crate::memory::parse_size(s).unwrap_or_else(|_| crate::memory::budget())
            }
            _ => crate::memory::budget(),
        }
    }
}

/// Bytes a point costs inside a window or shard: its record read back (20), coordinates
/// and sequence number (32), the sort into input order (12), noise removal's key and flags
/// (12) and the resampling's cell index (4), rounded up.
pub const SHARD_BYTES_PER_POINT: u64 = 96;

/// Bytes a cell of a grid shard's region costs: unfilled and filled heights, counts and
/// states, the pyramid and the tiles with their d2 and vertical error, rounded up.
pub const SHARD_BYTES_PER_CELL: u64 = 48;

/// Bytes a cell of a prepared shard holds between the two steps of the smooth fill: its
/// height (4), count (4) and state (1), and the pyramid above it (4/3), rounded up.
pub const PREPARED_BYTES_PER_CELL: u64 = 12;

/// Bytes of decoded points a pass read by bounds may keep for its later windows and shards
/// ([`reuse::PassReader`]): a quarter of the budget (the windows in flight have half).
/// `TERRATILE_REUSE=off` (for measurements) keeps nothing and reads one window a round: each
/// window decodes every file that meets it, as before the reader shared them.
fn reuse_cap(sizing: &Sizing) -> u64 {
    if reuse_off() {
        0
    } else {
        sizing.budget / 4
    }
}

fn reuse_off() -> bool {
    std::env::var("TERRATILE_REUSE").is_ok_and(|v| v == "off")
}

/// Windows a round of a pass read by bounds: those run at once, or one with reuse off.
fn reuse_round(sizing: &Sizing) -> usize {
    if reuse_off() {
        1
    } else {
        sizing.parallel
    }
}

/// Points of a brick at most (smaller when the budget makes windows smaller).
const BRICK_POINTS: u64 = 200_000;

/// Bytes of all bucketing write buffers together, at most.
const BUCKET_BUFFERS: u64 = 256 << 20;

/// Points decoded per batch while bucketing.
const BUCKET_BATCH: usize = 1 << 20;

/// The header facts of all inputs (pass 1).
#[derive(Debug, Clone)]
pub struct Scan {
    /// The inputs, as their headers describe them.
    pub sources: Vec<SourceInfo>,
    /// Union of the headers' boxes.
    pub bounds: Bounds,
    /// Points the headers announce (before the class filter and the cap).
    pub points: u64,
}

/// Reads the header of every input (LAS or LAZ; anything else cannot be streamed).
pub fn scan(pipeline: &LoadedPipeline, inputs: &[PathBuf]) -> Result<Scan> {
    let mut sources = Vec::new();
    let mut bounds = Bounds::EMPTY;
    let mut total = 0u64;
    for p in inputs {
        let map = points::map_file(p)?;
        let format = match pipeline.config.input.read_options().format {
            Some(f) => f,
            None => points::detect_format(p, &map)?,
        };
        if format == points::Format::Xyz {
            return Err(pipeline.key_error(
                "scale.mode",
                format!(
                    "{}: XYZ text cannot be streamed (no header with bounds and counts): \
                     convert it to LAS or run in memory",
                    p.display()
                ),
            ));
        }
        let h = points::LasHeader::parse(p, &map)?;
        bounds = bounds.union(h.bounds());
        total = total.saturating_add(h.point_count);
        sources.push(SourceInfo {
            path: p.clone(),
            format,
            version: Some(h.version),
            point_format: Some(h.point_format),
            record_length: Some(h.record_length),
            points_in_file: h.point_count,
            points_read: 0,
            scale: Some(h.scale),
            offset: Some(h.offset),
            header_bounds: Some(h.bounds()),
            crs: h.crs.clone(),
        });
    }
    Ok(Scan {
        sources,
        bounds,
        points: total,
    })
}

/// What the in-memory run would need for `scan`'s points (the estimate `terratile run`
/// refuses beyond the budget), from the headers alone.
pub fn estimate_in_memory(pipeline: &LoadedPipeline, scan: &Scan) -> u64 {
    let cfg = &pipeline.config;
    let n = scan.points.min(cfg.input.max_points.unwrap_or(u64::MAX));
    let cells = GridSpec::new(&cfg.resample, &scan.bounds, n.max(1) as usize)
        .map_or(n, |s| (s.cols as u64).saturating_mul(s.rows as u64));
    let denoise = cfg.denoise.enabled.then_some((0, 0));
    crate::memory::estimate_run(
        n,
        true,
        0,
        denoise,
        cells,
        "resample.cell_size",
        rayon::current_num_threads() as u64,
    )
    .total()
    .saturating_add(n.saturating_mul(crate::memory::DENOISE_BYTES_PER_POINT))
}

/// True when the grid and its tiles alone (which both modes hold) exceed `budget`.
fn grid_alone_exceeds(pipeline: &LoadedPipeline, scan: &Scan, budget: u64) -> bool {
    let cfg = &pipeline.config;
    let n = scan.points.min(cfg.input.max_points.unwrap_or(u64::MAX));
    GridSpec::new(&cfg.resample, &scan.bounds, n.max(1) as usize).is_ok_and(|s| {
        (s.cols as u64)
            .saturating_mul(s.rows as u64)
            .saturating_mul(crate::memory::GRID_BYTES_PER_CELL)
            > budget
    })
}

/// The first setting that needs every point in memory at once, as (key, why).
fn needs_memory(pipeline: &LoadedPipeline) -> Option<(&'static str, &'static str)> {
    let c = &pipeline.config;
    if c.ground.enabled {
        return Some(("ground.enabled", "ground classification"));
    }
    if c.baseline.enabled {
        return Some(("baseline.enabled", "the Delaunay baseline"));
    }
    if !c.assets.is_empty() {
        return Some(("assets", "placing assets on the whole grid"));
    }
    if c.denoise.enabled && c.denoise.write_removed {
        return Some(("denoise.write_removed", "writing the removed points"));
    }
    if c.fill.enabled && c.fill.fallback == Fallback::Mean {
        return Some(("fill.fallback", "the mean fallback (the whole grid's mean)"));
    }
    if c.fill.enabled && c.fill.fallback == Fallback::Membrane {
        return Some((
            "fill.fallback",
            "the membrane fill (solved over the whole grid)",
        ));
    }
    if c.tiles.preset == crate::terrain::tiles::Preset::Unreal {
        return Some((
            "tiles.preset",
            "the unreal preset (resamples the whole grid)",
        ));
    }
    None
}

/// Runs `pipeline` streamed when `[scale]` says so, or (`auto`) when the in-memory run
/// would not fit the budget; `None` when it should run in memory.
pub fn run_if_streaming(
    pipeline: &LoadedPipeline,
    progress: &dyn Progress,
) -> Result<Option<RunSummary>> {
    let scale = &pipeline.config.scale;
    if scale.mode == Mode::Memory {
        return Ok(None);
    }
    let plan = Plan::new(pipeline)?;
    let budget = scale.budget();
    if scale.mode == Mode::Auto {
        let any_text = plan.inputs.iter().any(|p| {
            points::map_file(p)
                .ok()
                .is_some_and(|m| !m.starts_with(b"LASF"))
        });
        if any_text {
            return Ok(None);
        }
        let s = scan(pipeline, &plan.inputs)?;
        let need = estimate_in_memory(pipeline, &s);
        if need <= budget || grid_alone_exceeds(pipeline, &s, budget) {
            // Streaming holds the tile set too: a grid beyond the budget is refused by the
            // in-memory run's own check, at its key.
            return Ok(None);
        }
        if let Some((key, why)) = needs_memory(pipeline) {
            return Err(pipeline.key_error(
                key,
                format!(
                    "the run needs about {} in memory, more than the budget of {}, and {why} \
                     cannot be streamed: turn it off or raise --max-memory",
                    crate::memory::human(need),
                    crate::memory::human(budget)
                ),
            ));
        }
    } else if let Some((key, why)) = needs_memory(pipeline) {
        return Err(pipeline.key_error(
            key,
            format!("{why} needs every point in memory: scale.mode = \"stream\" cannot run it"),
        ));
    }
    run_streaming(&plan, budget, progress).map(Some)
}

/// How many windows or shards run at once, and how many points each may hold.
#[derive(Debug, Clone, Copy)]
pub struct Sizing {
    /// The budget.
    pub budget: u64,
    /// Windows or shards at once.
    pub parallel: usize,
    /// Points per window or shard.
    pub points: u64,
}

impl Sizing {
    /// Half the budget for the windows and shards in flight (the rest for the tiles being
    /// assembled and the write buffers), one per worker thread at most.
    pub fn new(budget: u64) -> Sizing {
        let threads = rayon::current_num_threads().max(1);
        let share = budget / 2;
        let parallel = threads.min((share / (SHARD_BYTES_PER_POINT * 50_000)).max(1) as usize);
        Sizing {
            budget,
            parallel,
            points: (share / parallel as u64 / SHARD_BYTES_PER_POINT).max(1_000),
        }
    }
}

/// The run's temporary directory.
#[derive(Debug)]
struct TempDir {
    path: PathBuf,
    /// True when it was found from an earlier run with the same job.
    resumed: bool,
}

const JOB_FILE: &str = "job.txt";
const JOB_MAGIC: &str = "terratile streaming run v3\n";
/// What every version's marker starts with (an older run's directory is still ours).
const JOB_MARK: &str = "terratile streaming run v";
const BRICKS_FILE: &str = "bricks.json";

/// True for the names the streaming run writes in its directory.
fn is_ours(name: &str) -> bool {
    let window = |prefix: &str| {
        name.strip_prefix(prefix)
            .and_then(|r| r.strip_suffix(".bin"))
            .is_some_and(|r| r.bytes().all(|c| c.is_ascii_digit() || c == b'-'))
    };
    name == JOB_FILE
        || name == BRICKS_FILE
        || bricks::is_brick_name(name)
        || window("counts-")
        || window("keep-")
        || super::spill::is_spill_name(name)
        || super::prepared_spill::is_prepared_name(name)
}

impl TempDir {
    /// Opens (resuming when `job` matches) or creates the directory at `path`. A directory
    /// there without terratile's marker is refused, never touched.
    fn open(path: PathBuf, job: &str) -> Result<TempDir> {
        let marker = path.join(JOB_FILE);
        if path.exists() {
            let text = std::fs::read_to_string(&marker).unwrap_or_default();
            if !text.starts_with(JOB_MARK) {
                return Err(Error::Usage(format!(
                    "{}: exists and was not made by terratile's streaming run; remove it or set \
                     scale.temp_dir",
                    path.display()
                )));
            }
            let dir = TempDir {
                path,
                resumed: text == job,
            };
            if !dir.resumed {
                dir.clear()?;
            }
            crate::fsutil::register_work_dir(&dir.path, is_ours);
            write_bytes_atomic(&marker, job.as_bytes())?;
            return Ok(dir);
        }
        std::fs::create_dir_all(&path).map_err(|e| Error::io(&path, e))?;
        crate::fsutil::register_work_dir(&path, is_ours);
        write_bytes_atomic(&marker, job.as_bytes())?;
        Ok(TempDir {
            path,
            resumed: false,
        })
    }

    /// Removes the files it wrote (all but the marker).
    fn clear(&self) -> Result<()> {
        let rd = std::fs::read_dir(&self.path).map_err(|e| Error::io(&self.path, e))?;
        for e in rd.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name != JOB_FILE && is_ours(&name) {
                let p = e.path();
                std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
            }
        }
        Ok(())
    }

    /// Removes the files it wrote, then the directory if nothing else is left in it.
    fn remove(&self) {
        crate::fsutil::remove_owned_files(&self.path, is_ours);
        crate::fsutil::unregister_work_dir(&self.path);
    }
}

/// The temporary directory of a run into `out`: `.NAME.stream` beside it, or
/// `DIR/NAME.stream` under `[scale] temp_dir`.
fn temp_path(pipeline: &LoadedPipeline) -> PathBuf {
    let out = pipeline.output_dir();
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    match &pipeline.config.scale.temp_dir {
        Some(d) => pipeline.base_dir().join(d).join(format!("{name}.stream")),
        None => out.with_file_name(format!(".{name}.stream")),
    }
}

/// The job's identity: what the temporary files depend on (the inputs with their sizes and
/// modification times, the read and stage settings, the budget).
fn job_text(pipeline: &LoadedPipeline, inputs: &[PathBuf], budget: u64) -> String {
    let c = &pipeline.config;
    let mut s = String::from(JOB_MAGIC);
    for p in inputs {
        let m = std::fs::metadata(p).ok();
        let mtime = m
            .as_ref()
            .and_then(|m| m.modified().ok())
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .map_or(0, |d| d.as_nanos());
        let len = m.map_or(0, |m| m.len());
        s.push_str(&format!("input {} {len} {mtime}\n", p.display()));
    }
    s.push_str(&format!(
        "input {:?}\ndenoise {:?}\nbudget {budget}\nread {:?}\n",
        c.input, c.denoise, c.scale.read
    ));
    s
}

/// What bucketing leaves (`bricks.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Bucketed {
    lattice: BrickLattice,
    counts: Vec<u64>,
    sources: Vec<SourceTransform>,
    /// Points kept per input file.
    read: Vec<u64>,
    /// Exact bounds of all points (min x, y, z; max x, y, z).
    min: [f64; 3],
    max: [f64; 3],
    points: u64,
    bytes: u64,
    /// Read by bounds: each file's kept points' box (empty: read through the bricks).
    #[serde(default)]
    boxes: Vec<FileBox>,
    /// Points, boxes and bounds taken from the headers and not yet checked against the
    /// points (see [`counts_from_headers`]).
    #[serde(default)]
    unchecked_headers: bool,
}

impl Bucketed {
    /// The points with x in `x` and y in `y` (closed; ends may be infinite) that `wanted`
    /// accepts: from the bricks, in `order`, or from the files by bounds, in input order.
    fn load(
        &self,
        dir: &Path,
        files: &Files<'_>,
        x: [f64; 2],
        y: [f64; 2],
        order: bricks::Order,
        wanted: impl Fn(u64, f64, f64) -> bool,
    ) -> Result<BrickPoints> {
        if self.boxes.is_empty() {
            let cover = self.lattice.covering(x, y);
            bricks::load(dir, &cover, &self.counts, &self.sources, order, wanted)
        } else {
            direct::load(files, x, y, wanted)
        }
    }

    /// The inputs as [`direct::load`] reads them.
    fn files<'a>(&'a self, paths: &'a [PathBuf], opts: &'a points::ReadOptions) -> Files<'a> {
        Files {
            paths,
            sources: &self.sources,
            read: &self.read,
            boxes: &self.boxes,
            opts,
        }
    }
}

/// True when the run should read its points directly from the files (see [`ReadMode`]).
fn reads_directly(pipeline: &LoadedPipeline, sc: &Scan, sizing: &Sizing) -> bool {
    match pipeline.config.scale.read {
        ReadMode::Bricks => false,
        ReadMode::Direct => true,
        ReadMode::Auto => {
            let las = sc.sources.iter().all(|s| s.format == points::Format::Las);
            let files: Vec<(Bounds, u64)> = sc
                .sources
                .iter()
                .map(|s| (s.header_bounds.unwrap_or(Bounds::EMPTY), s.points_in_file))
                .collect();
            las && direct::amplification(&files, sizing.points)
                .is_some_and(|a| a <= DIRECT_MAX_READS)
        }
    }
}

/// Pass 2: every input into the bricks.
fn bucket(
    pipeline: &LoadedPipeline,
    scan: &Scan,
    dir: &Path,
    sizing: &Sizing,
    direct: bool,
    progress: &dyn Progress,
) -> Result<Bucketed> {
    let opts = pipeline.config.input.read_options();
    let brick_points = BRICK_POINTS.min(sizing.points / 16).max(1_000);
    let target = (scan.points / brick_points).clamp(1, 1 << 16) as usize;
    let lattice = BrickLattice::new(&scan.bounds, target);
    let buffer = (BUCKET_BUFFERS.min(sizing.budget / 8) / lattice.count() as u64) as usize;
    let mut w = BrickWriter::new(dir, lattice, buffer);
    let mut sources = Vec::new();
    let mut read = Vec::new();
    let mut seq = 0u64;
    let mut b = Bounds::EMPTY;
    let mut cloud = PointCloud::default();
    let mut raw: Vec<Option<(u32, [i32; 3])>> = Vec::new();
    let mut boxes = Vec::new();
    progress.start(
        if direct {
            "counting points"
        } else {
            "bucketing points"
        },
        scan.points,
    );
    for info in &scan.sources {
        let mut file_box = Bounds::EMPTY;
        let path = &info.path;
        let map = points::map_file(path)?;
        let mut o = opts.clone();
        if let Some(cap) = opts.max_points {
            o.max_points = Some(cap.saturating_sub(seq));
        }
        let first = seq;
        let (h, kept) = points::for_each_decoded(path, &map, &o, BUCKET_BATCH, &mut cloud, {
            |c: &PointCloud, h: &points::LasHeader| {
                let batch = crate::terrain::bounds_of(&c.x, &c.y, &c.z, None).0;
                b = b.union(batch);
                if direct {
                    // Read by bounds later: only the file's box and its points' number.
                    file_box = file_box.union(batch);
                    seq += c.len() as u64;
                    progress.advance(c.len() as u64);
                    return Ok(());
                }
                // Each point's brick and raw integers, in parallel over the batch (`None`:
                // the point does not round-trip its file's scale); then the appends, in order.
                raw.clear();
                (0..c.len())
                    .into_par_iter()
                    .with_min_len(1 << 14)
                    .map(|i| {
                        let (x, y, z) = (c.x[i], c.y[i], c.z[i]);
                        match [
                            bricks::raw_of(x, h.scale[0], h.offset[0]),
                            bricks::raw_of(y, h.scale[1], h.offset[1]),
                            bricks::raw_of(z, h.scale[2], h.offset[2]),
                        ] {
                            [Some(rx), Some(ry), Some(rz)] => {
                                Some((lattice.brick(x, y) as u32, [rx, ry, rz]))
                            }
                            _ => None,
                        }
                    })
                    .collect_into_vec(&mut raw);
                if let Some(i) = raw.iter().position(Option::is_none) {
                    return Err(Error::format(
                        path,
                        0,
                        format!("point {i} of a batch does not round-trip its scale"),
                    ));
                }
                for &(brick, r) in raw.iter().flatten() {
                    w.push_to(brick as usize, r, seq)?;
                    seq += 1;
                }
                progress.advance(c.len() as u64);
                Ok(())
            }
        })?;
        sources.push(SourceTransform {
            first,
            scale: h.scale,
            offset: h.offset,
        });
        read.push(kept);
        boxes.push(FileBox::of(&file_box));
    }
    progress.finish();
    let bytes = w.bytes;
    let counts = w.finish()?;
    let bytes = if direct {
        0
    } else {
        bytes.max(seq * bricks::RECORD as u64)
    };
    Ok(Bucketed {
        lattice,
        counts,
        sources,
        read,
        min: b.min,
        max: b.max,
        points: seq,
        bytes,
        boxes: if direct { boxes } else { Vec::new() },
        unchecked_headers: false,
    })
}

/// True when pass 2 may take each input's points and box from its header instead of
/// counting them (read by bounds, every header given, no class filter or point cap: then a
/// file keeps all its header's points): the noise-removal pass, which decodes every file
/// anyway, checks the headers against the points ([`reuse::HeaderCheck`]), and the run
/// counts after all when one does not match. Without noise removal there is no such pass.
fn counts_from_headers(pipeline: &LoadedPipeline, sc: &Scan, direct: bool) -> bool {
    let opts = pipeline.config.input.read_options();
    direct
        && pipeline.config.denoise.enabled
        && !opts.classes.is_active()
        && opts.max_points.is_none()
        && sc.sources.iter().all(|s| s.header_bounds.is_some())
}

/// The bucket report's `counted` figure when a header did not match its points.
const INEXACT: &str = "points (a header's box or count is not its points')";

/// Pass 2 from the headers alone (see [`counts_from_headers`]): what [`bucket`] would give
/// when every header is exact, and the check that tells whether they are.
fn bucket_from_headers(scan: &Scan, sizing: &Sizing) -> (Bucketed, reuse::HeaderCheck) {
    let brick_points = BRICK_POINTS.min(sizing.points / 16).max(1_000);
    let target = (scan.points / brick_points).clamp(1, 1 << 16) as usize;
    let lattice = BrickLattice::new(&scan.bounds, target);
    let mut first = 0u64;
    let mut sources = Vec::new();
    let mut b = Bounds::EMPTY;
    let mut header = Vec::new();
    for s in &scan.sources {
        let hb = s.header_bounds.unwrap_or(Bounds::EMPTY);
        let hb = if s.points_in_file == 0 {
            Bounds::EMPTY
        } else {
            hb
        };
        sources.push(SourceTransform {
            first,
            scale: s.scale.unwrap_or([1.0; 3]),
            offset: s.offset.unwrap_or([0.0; 3]),
        });
        first += s.points_in_file;
        b = b.union(hb);
        header.push((hb, s.points_in_file));
    }
    let bk = Bucketed {
        counts: vec![0; lattice.count()],
        lattice,
        sources,
        read: header.iter().map(|h| h.1).collect(),
        min: b.min,
        max: b.max,
        points: first,
        bytes: 0,
        boxes: header.iter().map(|h| FileBox::of(&h.0)).collect(),
        unchecked_headers: true,
    };
    (bk, reuse::HeaderCheck::new(header))
}

/// Keep flags by sequence number.
#[derive(Debug)]
struct KeepBits(Vec<u64>);

impl KeepBits {
    fn get(&self, i: u64) -> bool {
        (self.0[(i / 64) as usize] >> (i % 64)) & 1 == 1
    }
    /// `n` flags, all set.
    fn all(n: u64) -> KeepBits {
        let mut v = vec![u64::MAX; n.div_ceil(64) as usize];
        if !n.is_multiple_of(64) {
            if let Some(last) = v.last_mut() {
                *last = (1 << (n % 64)) - 1;
            }
        }
        KeepBits(v)
    }
    fn clear(&mut self, i: u64) {
        self.0[(i / 64) as usize] &= !(1 << (i % 64));
    }
    fn count(&self) -> u64 {
        self.0.iter().map(|w| u64::from(w.count_ones())).sum()
    }
}

/// What the denoise pass leaves.
struct DenoisePass {
    keep: KeepBits,
    /// The kept points' exact bounds (the grid's).
    bounds: Bounds,
    windows: usize,
    resumed: usize,
    steps: u32,
    /// Points decoded from the inputs by the pass (read by bounds), and the most bytes of
    /// decoded points waiting for later windows.
    decoded: u64,
    stored: u64,
}

fn write_u64s(path: &Path, v: &[u64]) -> Result<()> {
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    write_bytes_atomic(path, &bytes)
}

fn read_u64s(path: &Path) -> Option<Vec<u64>> {
    let b = std::fs::read(path).ok()?;
    (b.len() % 8 == 0).then(|| {
        b.chunks_exact(8)
            .map(|c| u64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
            .collect()
    })
}

/// Words before the sequence numbers in a window's keep file: the voxel height steps, the
/// points of its own columns failing the count, and the kept points' bounds (six f64 bit
/// patterns). The sequence numbers that follow are those of its own removed points.
const KEEP_HEAD: usize = 8;

/// A window's keep file, read back: (steps, failing, kept bounds, kept sequence numbers).
fn read_keep(path: &Path) -> Option<(u64, u64, Bounds, Vec<u64>)> {
    let mut v = read_u64s(path)?;
    if v.len() < KEEP_HEAD {
        return None;
    }
    let f = |i: usize| f64::from_bits(v[i]);
    let b = Bounds {
        min: [f(2), f(3), f(4)],
        max: [f(5), f(6), f(7)],
    };
    let (q, failing) = (v[0], v[1]);
    v.drain(..KEEP_HEAD);
    Some((q, failing, b, v))
}

/// Pass 3a: noise removal by windows of low-layer columns read from the bricks.
///
/// Each window is read once and filtered at voxel height steps 1 (the height the
/// in-memory run tries first, and the only one when `voxel_height` is given): its keep
/// flags, its points failing the count and its kept points' bounds are saved. When the
/// failing points of all windows are within the automatic height's budget, that is the
/// in-memory run's choice and the pass is done (the common case). Otherwise the counts at
/// every height are taken (`shard_counts`, one more read per window), the sums pick the
/// height (`choose_steps`), and the windows are filtered again at that height.
#[allow(clippy::too_many_arguments)]
fn denoise_pass(
    pipeline: &LoadedPipeline,
    dir: &Path,
    bk: &Bucketed,
    files: &Files<'_>,
    mpu: f64,
    sizing: &Sizing,
    check: Option<&reuse::HeaderCheck>,
    progress: &dyn Progress,
) -> Result<DenoisePass> {
    let params = &pipeline.config.denoise;
    let frame = Frame {
        bounds: Bounds {
            min: bk.min,
            max: bk.max,
        },
        points: bk.points as usize,
    };
    let s = frame
        .settings(params, mpu)
        .map_err(|e| pipeline.param_error(e))?;
    let [cx, cy] = frame.columns(&s);
    let group = frame.group(&s);
    let halo = frame.halo(&s);
    // Windows of `groups` × `groups` low-layer columns holding about `sizing.points` points
    // with their halo.
    let area = (frame.bounds.size()[0] * frame.bounds.size()[1]).max(1e-9);
    let density = bk.points as f64 / area;
    let side_world = (sizing.points as f64 / density.max(1e-12)).sqrt();
    let group_world = group as f64 * s.voxel_size;
    let groups = ((side_world / group_world).floor() as u64)
        .saturating_sub(2 * halo.div_ceil(group))
        .max(1);
    let side = groups * group;
    let n = [cx.div_ceil(side), cy.div_ceil(side)];
    let count = (n[0] * n[1]) as usize;
    let window = |k: usize| {
        let (wx, wy) = (k as u64 % n[0], k as u64 / n[0]);
        ColumnWindow {
            x: wx * side..((wx + 1) * side).min(cx),
            y: wy * side..((wy + 1) * side).min(cy),
        }
    };
    let inv = s.voxel_size;
    // The points a window reads: its columns and the halo, as `denoise_sharded` buckets them
    // (in brick order: noise removal does not depend on the order of its points), and the
    // world range that holds them (one column of margin for rounding).
    let columns = |k: usize| {
        let own = window(k);
        let rx = own.x.start.saturating_sub(halo)..(own.x.end + halo).min(cx);
        let ry = own.y.start.saturating_sub(halo)..(own.y.end + halo).min(cy);
        (rx, ry)
    };
    let range = |k: usize| -> reuse::Range2 {
        let (rx, ry) = columns(k);
        let world = |r: &std::ops::Range<u64>, a: usize, c: u64| {
            let lo = frame.bounds.min[a] + (r.start as f64 - 1.0) * inv;
            let hi = if r.end >= c {
                f64::INFINITY
            } else {
                frame.bounds.min[a] + (r.end as f64 + 1.0) * inv
            };
            [lo, hi]
        };
        (world(&rx, 0, cx), world(&ry, 1, cy))
    };
    let wanted = |k: usize, _: u64, x: f64, y: f64| {
        let (rx, ry) = columns(k);
        let (a, b) = frame.column(&s, x, y);
        rx.contains(&a) && ry.contains(&b)
    };
    let load = |k: usize| -> Result<BrickPoints> {
        let (x, y) = range(k);
        bk.load(dir, files, x, y, bricks::Order::Bricks, |q, x, y| {
            wanted(k, q, x, y)
        })
    };
    let decoded = std::sync::atomic::AtomicU64::new(0);
    let stored = std::sync::atomic::AtomicU64::new(0);
    let name = |kind: &str, k: usize| dir.join(format!("{kind}-{groups}-{k:07}.bin"));
    // Runs `f` on each window of `ks` with its points, `sizing.parallel` at a time: from the
    // bricks, or by bounds with each file decoded about once for the whole list.
    let run_batch =
        |ks: &[usize], f: &(dyn Fn(usize, BrickPoints) -> Result<()> + Sync)| -> Result<()> {
            if bk.boxes.is_empty() {
                for chunk in ks.chunks(sizing.parallel) {
                    chunk.par_iter().try_for_each(|&k| f(k, load(k)?))?;
                    progress.advance(chunk.len() as u64);
                }
                return Ok(());
            }
            let ranges = (0..count).map(range).collect();
            let reader = reuse::PassReader::new(
                *files,
                ranges,
                ks.to_vec(),
                reuse_round(sizing),
                reuse_cap(sizing),
                wanted,
            )
            .with_check(check);
            let out = (0..reader.rounds()).try_for_each(|r| {
                let pts = reader.load(r)?;
                let ws = reader.round_windows(r);
                ws.par_iter().zip(pts).try_for_each(|(&k, p)| f(k, p))?;
                progress.advance(ws.len() as u64);
                Ok(())
            });
            decoded.fetch_add(reader.decoded(), std::sync::atomic::Ordering::Relaxed);
            stored.fetch_max(reader.stored_peak(), std::sync::atomic::Ordering::Relaxed);
            out
        };
    let crash_after: Option<usize> = std::env::var("TERRATILE_STREAM_CRASH_AFTER")
        .ok()
        .and_then(|v| v.parse().ok());
    let written = std::sync::atomic::AtomicUsize::new(0);
    // One window filtered at `q`: its keep file (saved: resumable).
    let keep_of = |k: usize, q: u32, p: BrickPoints| -> Result<()> {
        let own = window(k);
        let mut out = vec![q as u64, 0];
        let mut kept = Bounds::EMPTY;
        let mut seqs = Vec::new();
        if !p.is_empty() {
            let input = p.shard_input(&frame, params, mpu, &own);
            let d = denoise::shard_denoise(&input, q)?;
            out[1] = d.removed_sparse as u64;
            kept = crate::terrain::bounds_of(&p.x, &p.y, &p.z, Some(&d.keep)).0;
            // The removed points of its own columns (about 1 % of them: a small file where
            // the kept ones would be most of the input); the windows' own columns partition
            // the points, so every point not removed by its window is kept.
            for (i, &k) in d.keep.iter().enumerate() {
                if !k {
                    let (a, b) = frame.column(&s, p.x[i], p.y[i]);
                    if own.x.contains(&a) && own.y.contains(&b) {
                        seqs.push(p.seq[i]);
                    }
                }
            }
        }
        out.extend(kept.min.iter().chain(&kept.max).map(|v| v.to_bits()));
        out.extend(seqs);
        write_u64s(&name("keep", k), &out)?;
        let w = written.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1;
        if crash_after.is_some_and(|c| w >= c) {
            // A test's stand-in for the process being killed outright: no clean-up at all.
            eprintln!("terratile: TERRATILE_STREAM_CRASH_AFTER={w}: stopping without clean-up");
            std::process::exit(101);
        }
        Ok(())
    };
    // Windows whose keep file at `q` is already there (a resumed run) are not redone.
    let keep_at = |q: u32, label: &str| -> Result<usize> {
        let done = |k: &usize| read_keep(&name("keep", *k)).is_some_and(|v| v.0 == q as u64);
        let todo: Vec<usize> = (0..count).filter(|k| !done(k)).collect();
        progress.start(label, todo.len() as u64);
        run_batch(&todo, &|k, p| keep_of(k, q, p))?;
        progress.finish();
        Ok(count - todo.len())
    };
    let mut resumed = keep_at(1, "denoise")?;
    let failing: u64 = (0..count)
        .map(|k| read_keep(&name("keep", k)).map_or(0, |v| v.1))
        .sum();
    let mut q = 1;
    if denoise::choose_steps(params, &[[failing as usize; 3]], frame.points) != 1 {
        // More than the budget fails at q = 1: the counts at every height decide.
        let counts_of = |k: usize, p: BrickPoints| -> Result<()> {
            let path = name("counts", k);
            let own = window(k);
            let c = if p.is_empty() {
                Vec::new()
            } else {
                let input = p.shard_input(&frame, params, mpu, &own);
                denoise::shard_counts(&input)?
            };
            let flat: Vec<u64> = c.iter().flat_map(|c| c.map(|v| v as u64)).collect();
            write_u64s(&path, &flat)
        };
        // Windows whose counts are already there (a resumed run) are not redone.
        let todo: Vec<usize> = (0..count)
            .filter(|&k| read_u64s(&name("counts", k)).is_none())
            .collect();
        progress.start("denoise: counts", todo.len() as u64);
        run_batch(&todo, &counts_of)?;
        progress.finish();
        let mut sums: Vec<[usize; 3]> = Vec::new();
        for k in 0..count {
            let flat = read_u64s(&name("counts", k))
                .ok_or_else(|| Error::Internal(format!("denoise window {k}: counts missing")))?;
            let c: Vec<[usize; 3]> = flat
                .chunks_exact(3)
                .map(|c| [c[0] as usize, c[1] as usize, c[2] as usize])
                .collect();
            sums.resize(sums.len().max(c.len()), [0; 3]);
            for (acc, c) in sums.iter_mut().zip(&c) {
                for i in 0..3 {
                    acc[i] += c[i];
                }
            }
        }
        q = denoise::choose_steps(params, &sums, frame.points);
        if q != 1 {
            resumed = keep_at(q, "denoise: keep flags")?;
        }
    }
    let mut keep = KeepBits::all(bk.points);
    let mut bounds = Bounds::EMPTY;
    for k in 0..count {
        let (_, _, b, seqs) = read_keep(&name("keep", k))
            .ok_or_else(|| Error::Internal(format!("denoise window {k}: keep flags missing")))?;
        bounds = bounds.union(b);
        for s in seqs {
            keep.clear(s);
        }
    }
    Ok(DenoisePass {
        keep,
        bounds,
        windows: count,
        resumed,
        steps: q,
        decoded: decoded.into_inner(),
        stored: stored.into_inner(),
    })
}

/// Tiles per shard side for `sizing`: the shard's region with its one-tile ring within the
/// points (one point a cell, the √N rule's mean) and cells it may hold.
fn block_for(sizing: &Sizing, tile_step: usize) -> usize {
    let per_cell = SHARD_BYTES_PER_POINT + SHARD_BYTES_PER_CELL;
    let cells = sizing.points * SHARD_BYTES_PER_POINT / per_cell;
    let side = (cells as f64).sqrt() / tile_step as f64;
    (side.floor() as usize).saturating_sub(2).max(1)
}

/// What the grid pass leaves: the layout, the merged tiles, whether the prepared shards were
/// kept in memory, the bytes of prepared shards spilled (when they were), and the points
/// decoded by bounds with the most bytes of decoded points kept waiting.
type GridPass = (ShardLayout, super::Merged, bool, Option<u64>, [u64; 2]);

/// Runs the grid shards over the kept points of the bricks and merges them.
#[allow(clippy::too_many_arguments)]
fn grid_pass(
    pipeline: &LoadedPipeline,
    dir: &Path,
    bk: &Bucketed,
    files: &Files<'_>,
    keep: Option<&KeepBits>,
    spec: &GridSpec,
    crs: Option<Crs>,
    sizing: &Sizing,
    mut spill: Option<&mut super::spill::Spilled>,
    progress: &dyn Progress,
) -> Result<GridPass> {
    let cfg = &pipeline.config;
    let fill = cfg.fill.enabled.then_some(&cfg.fill);
    let step = cfg.tiles.tile_size() - 1;
    let b = block_for(sizing, step);
    let layout = ShardLayout::new([spec.cols, spec.rows], &cfg.tiles, [b, b])
        .map_err(|e| pipeline.param_error(e))?;
    let geo = Heightfield::empty(
        1,
        1,
        spec.corner,
        spec.cell_size,
        spec.z_offset,
        crs.clone(),
    );
    // The unfilled cells `ci` × `cj` of the grid, from the kept points of the bricks they
    // overlap (in input order: the resampling sums in it).
    // A shard's input cells, the world range that holds their points (one cell of margin
    // for rounding) and the test of each point: kept, and in one of the cells.
    let input_cells = |i: usize| {
        let shard = layout.shard(i);
        (shard.input(&layout, 0, fill), shard.input(&layout, 1, fill))
    };
    let range = |i: usize| -> reuse::Range2 {
        let (ci, cj) = input_cells(i);
        let world = |r: &std::ops::Range<usize>, a: usize, n: usize| {
            let lo = spec.corner[a] + (r.start as f64 - 1.0) * spec.cell_size[a];
            let hi = if r.end >= n {
                f64::INFINITY
            } else {
                spec.corner[a] + (r.end as f64 + 1.0) * spec.cell_size[a]
            };
            [lo, hi]
        };
        (world(&ci, 0, spec.cols), world(&cj, 1, spec.rows))
    };
    let wanted = |i: usize, s: u64, x: f64, y: f64| {
        let (ci, cj) = input_cells(i);
        keep.is_none_or(|k| k.get(s)) && ci.contains(&spec.col(x)) && cj.contains(&spec.row(y))
    };
    // Shard `i` prepared from its points (`None`: read from the bricks now): the unfilled
    // cells of its input from the kept points (in input order: the resampling sums in it).
    let prepared_of = |i: usize, p: Option<BrickPoints>| -> Result<super::Prepared> {
        let shard = layout.shard(i);
        let (ci, cj) = input_cells(i);
        let offset = [ci.start, cj.start];
        let p = match p {
            Some(p) => p,
            None => {
                let (x, y) = range(i);
                bk.load(dir, files, x, y, bricks::Order::Input, |s, x, y| {
                    wanted(i, s, x, y)
                })?
            }
        };
        let cells = resample::resample_window(
            [&p.x, &p.y, &p.z],
            None,
            spec,
            [ci, cj],
            cfg.resample.method,
            crs.clone(),
        );
        drop(p);
        prepare(&layout, &shard, &cells, offset, fill)
    };
    let smooth = fill.is_some_and(|f| f.fallback == Fallback::Smooth);
    let n = layout.count();
    let all: Vec<usize> = (0..n).collect();
    // Read by bounds: each input decoded about once for all shards, in the chunks below.
    let reader = (!bk.boxes.is_empty()).then(|| {
        reuse::PassReader::new(
            *files,
            (0..n).map(range).collect(),
            all.clone(),
            reuse_round(sizing),
            reuse_cap(sizing),
            wanted,
        )
    });
    // The points of chunk `r` of `all`, when the reader serves them.
    let points_of = |r: usize, len: usize| -> Result<Vec<Option<BrickPoints>>> {
        match &reader {
            Some(rd) if rd.round() == sizing.parallel => {
                Ok(rd.load(r)?.into_iter().map(Some).collect())
            }
            // Reuse off: one shard a round.
            Some(rd) => (0..len)
                .map(|j| Ok(rd.load(r * sizing.parallel + j)?.pop()))
                .collect(),
            None => Ok((0..len).map(|_| None).collect()),
        }
    };
    // With the smooth fill every shard's coarse cells come first; the prepared shards wait
    // for the second step in memory when they fit the budget, else each in its own
    // temporary file (`prepared_spill`): either way every shard is prepared once.
    let keep_prepared = {
        let [w, h] = layout.samples;
        let ring = (b + 2) * (b + 2);
        (w * h) as u64 * PREPARED_BYTES_PER_CELL * ring as u64 / (b * b) as u64 <= sizing.budget / 2
    };
    let mut kept: Vec<Option<super::Prepared>> = (0..n).map(|_| None).collect();
    let spilled = std::sync::atomic::AtomicU64::new(0);
    let coarse = if smooth {
        progress.start("grid shards: coarse level", n as u64);
        let mut cells = Vec::new();
        for (r, chunk) in all.chunks(sizing.parallel).enumerate() {
            let pts = points_of(r, chunk.len())?;
            let got = chunk
                .par_iter()
                .zip(pts)
                .map(|(&i, pts)| {
                    let p = prepared_of(i, pts)?;
                    let c = p.coarse(&layout);
                    if keep_prepared {
                        return Ok((c, Some(p)));
                    }
                    let bytes = prepared_spill::put(dir, &p)?;
                    spilled.fetch_add(bytes, std::sync::atomic::Ordering::Relaxed);
                    Ok((c, None))
                })
                .collect::<Result<Vec<_>>>()?;
            for ((c, p), &i) in got.into_iter().zip(chunk) {
                cells.extend(c);
                kept[i] = p;
            }
            progress.advance(chunk.len() as u64);
        }
        progress.finish();
        complete_coarse(&layout, &cells)?
    } else {
        Vec::new()
    };
    let spill_prepared = smooth && !keep_prepared;
    progress.start("grid shards", n as u64);
    let mut outputs: Vec<ShardOutput> = Vec::with_capacity(n);
    for (r, chunk) in all.chunks(sizing.parallel).enumerate() {
        let taken: Vec<Option<super::Prepared>> = chunk.iter().map(|&i| kept[i].take()).collect();
        // Without the smooth fill this loop is the one that reads the points.
        let pts = if smooth {
            (0..chunk.len()).map(|_| None).collect()
        } else {
            points_of(r, chunk.len())?
        };
        let got: Vec<ShardOutput> = chunk
            .par_iter()
            .zip(taken)
            .zip(pts)
            .map(|((&i, p), pts)| {
                let p = match p {
                    Some(p) => p,
                    None if spill_prepared => {
                        prepared_spill::take(dir, &layout, i, fill, crs.as_ref())?
                    }
                    None => prepared_of(i, pts)?,
                };
                // The extraction builds its own vertical error from the merged tiles.
                finish_with(&layout, p, &coarse, &cfg.tiles, &cfg.quadtree, false)
            })
            .collect::<Result<_>>()?;
        for (mut out, &i) in got.into_iter().zip(chunk) {
            if let Some(s) = spill.as_deref_mut() {
                // Final heights: to disk until the writers take them, shard by shard.
                s.put(dir, i, &mut out, layout.tiles)?;
            }
            outputs.push(out);
        }
        progress.advance(chunk.len() as u64);
    }
    progress.finish();
    let merged = merge(&layout, &geo, &cfg.tiles, &cfg.quadtree, outputs)?;
    let spilled = spill_prepared.then(|| spilled.into_inner());
    let reads = reader.map_or([0, 0], |r| [r.decoded(), r.stored_peak()]);
    Ok((layout, merged, smooth && keep_prepared, spilled, reads))
}

fn fig(k: &str, v: impl ToString) -> (String, String) {
    (k.to_string(), v.to_string())
}

/// Seconds of CPU (user and system) the process has used, all threads together: fields 14
/// and 15 of `/proc/self/stat`, in the kernel's fixed user-visible tick of 1/100 s (`None`
/// where it cannot be read). On a machine shared with other work, a pass's CPU time says
/// what it costs where its wall time says how long it waited.
fn cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The command name (field 2) is in parentheses and may hold spaces: count after it.
    let rest = &s[s.rfind(')')? + 1..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?;
    Some(ticks as f64 / 100.0)
}

/// When a pass started: wall clock and CPU time.
struct Clock {
    wall: Instant,
    cpu: Option<f64>,
}

impl Clock {
    fn start() -> Clock {
        Clock {
            wall: Instant::now(),
            cpu: cpu_seconds(),
        }
    }
}

/// A pass's report: its figures, then its CPU seconds and the peak memory so far.
fn report(stage: &str, t: Clock, mut figures: Vec<(String, String)>) -> StageReport {
    if let (Some(a), Some(b)) = (t.cpu, cpu_seconds()) {
        figures.push(fig("cpu s", format!("{:.2}", b - a)));
    }
    if let Some(p) = peak_rss() {
        figures.push(fig("peak memory", crate::memory::human(p)));
    }
    StageReport {
        stage: stage.into(),
        seconds: t.wall.elapsed().as_secs_f64(),
        figures,
    }
}

/// The streaming run of `plan` within `budget` bytes.
pub fn run_streaming(plan: &Plan<'_>, budget: u64, progress: &dyn Progress) -> Result<RunSummary> {
    let pipeline = plan.pipeline;
    let staged = plan.stage_output_dir()?;
    let t = Clock::start();
    let sc = scan(pipeline, &plan.inputs)?;
    let mut stages = vec![report(
        "scan",
        t,
        vec![
            fig("files", sc.sources.len()),
            fig("points in headers", sc.points),
            fig(
                "in-memory estimate",
                crate::memory::human(estimate_in_memory(pipeline, &sc)),
            ),
            fig("budget", crate::memory::human(budget)),
        ],
    )];
    let sizing = Sizing::new(budget);
    let tmp = TempDir::open(
        temp_path(pipeline),
        &job_text(pipeline, &plan.inputs, budget),
    )?;
    let result = stream_passes(pipeline, &sc, &tmp, &sizing, &staged, &mut stages, progress);
    // On failure as on success, the temporary files go (a crash leaves them to resume).
    tmp.remove();
    let (files, bk) = result?;
    staged.commit()?;
    let mut inputs = sc.sources;
    for (s, r) in inputs.iter_mut().zip(&bk.read) {
        s.points_read = *r;
        s.path = crate::fsutil::normalize_lexically(&s.path);
    }
    let crs = inputs.iter().find_map(|s| s.crs.as_ref()).map(|c| c.text());
    Ok(RunSummary {
        inputs,
        points: bk.points,
        bounds: Some(Bounds {
            min: bk.min,
            max: bk.max,
        }),
        crs,
        stages,
        output_dir: crate::fsutil::normalize_lexically(&pipeline.output_dir()),
        files,
        assets: Vec::new(),
        baseline: None,
    })
}

/// Passes 2 to 4 and the outputs, into `staged`; returns the files written and the buckets.
fn stream_passes(
    pipeline: &LoadedPipeline,
    sc: &Scan,
    tmp: &TempDir,
    sizing: &Sizing,
    staged: &crate::fsutil::StagedDir,
    stages: &mut Vec<StageReport>,
    progress: &dyn Progress,
) -> Result<(Vec<String>, Bucketed)> {
    let cfg = &pipeline.config;
    let dir = &tmp.path;
    let t = Clock::start();
    let done = dir.join(BRICKS_FILE);
    let previous: Option<Bucketed> = tmp
        .resumed
        .then(|| std::fs::read(&done).ok())
        .flatten()
        .and_then(|b| serde_json::from_slice(&b).ok());
    let resumed = previous.is_some();
    let save = |b: &Bucketed| -> Result<()> {
        let json = serde_json::to_vec(b).map_err(|e| Error::Internal(e.to_string()))?;
        write_bytes_atomic(&done, &json)
    };
    let direct = reads_directly(pipeline, sc, sizing);
    // The points counted from the headers are checked by the noise-removal pass (a resumed
    // run checks them again: its finished windows' files separately). The first file with
    // points is checked first, alone: writers that take the header's box from the points
    // before they are rounded to the file's scale (the `las` crate's, so `terratile
    // generate`'s) never match, and are counted at once.
    let mut inexact = false;
    let (mut bk, check) = match previous {
        Some(b) if b.unchecked_headers => (b, Some(bucket_from_headers(sc, sizing).1)),
        Some(b) => (b, None),
        None => {
            tmp.clear()?;
            let headers = counts_from_headers(pipeline, sc, direct)
                .then(|| bucket_from_headers(sc, sizing))
                .filter(|(b, c)| {
                    let paths: Vec<PathBuf> = sc.sources.iter().map(|s| s.path.clone()).collect();
                    let opts = cfg.input.read_options();
                    let first = b.read.iter().position(|&n| n > 0);
                    let exact = first.is_none_or(|f| {
                        c.check_file(&b.files(&paths, &opts), f).is_ok() && !c.failed()
                    });
                    inexact = !exact;
                    exact
                });
            match headers {
                Some((b, c)) => {
                    save(&b)?;
                    (b, Some(c))
                }
                None => {
                    let b = bucket(pipeline, sc, dir, sizing, direct, progress)?;
                    save(&b)?;
                    (b, None)
                }
            }
        }
    };
    if bk.points == 0 {
        return Err(pipeline.key_error(
            "input.paths",
            "the inputs hold no points (after the class filter)",
        ));
    }
    stages.push(report(
        "bucket",
        t,
        vec![
            fig("points", bk.points),
            fig(
                "read",
                if bk.boxes.is_empty() {
                    "bricks"
                } else {
                    "by bounds"
                },
            ),
            fig(
                "bricks",
                if bk.boxes.is_empty() {
                    bk.lattice.count()
                } else {
                    0
                },
            ),
            fig("temporary", crate::memory::human(bk.bytes)),
            fig("resumed", resumed),
            fig(
                "counted",
                if check.is_some() {
                    "from the headers"
                } else if inexact {
                    INEXACT
                } else {
                    "points"
                },
            ),
        ],
    ));
    let crs: Option<Crs> = sc.sources.iter().find_map(|s| s.crs.clone());
    let paths: Vec<PathBuf> = sc.sources.iter().map(|s| s.path.clone()).collect();
    let opts = cfg.input.read_options();
    let mpu = crs.as_ref().map_or(1.0, |c| c.metres_per_unit());
    let all_bounds = Bounds {
        min: bk.min,
        max: bk.max,
    };
    let (keep, kept_bounds, kept) = if cfg.denoise.enabled {
        let t = Clock::start();
        let pass = |bk: &Bucketed, check| {
            let files = bk.files(&paths, &opts);
            denoise_pass(pipeline, dir, bk, &files, mpu, sizing, check, progress)
        };
        let first = pass(&bk, check.as_ref());
        if let (Some(c), Ok(_)) = (&check, &first) {
            c.check_the_rest(&bk.files(&paths, &opts))?;
        }
        let d = match &check {
            Some(c) if c.failed() || (first.is_ok() && !c.passed()) => {
                // A header did not match its points: count them, and run the pass again.
                drop(first);
                progress.finish();
                let tc = Clock::start();
                tmp.clear()?;
                bk = bucket(pipeline, sc, dir, sizing, direct, progress)?;
                save(&bk)?;
                stages.push(report(
                    "bucket",
                    tc,
                    vec![fig("points", bk.points), fig("counted", INEXACT)],
                ));
                pass(&bk, None)?
            }
            Some(_) => {
                let d = first?;
                bk.unchecked_headers = false;
                save(&bk)?;
                d
            }
            None => first?,
        };
        let kept = d.keep.count();
        let b = d.bounds;
        stages.push(report(
            "denoise",
            t,
            vec![
                fig("points in", bk.points),
                fig("points out", kept),
                fig("removed", bk.points - kept),
                fig("windows", d.windows),
                fig("windows resumed", d.resumed),
                fig("voxel height steps", d.steps),
            ],
        ));
        if !bk.boxes.is_empty() {
            let f = &mut stages.last_mut().expect("just pushed").figures;
            f.push(fig("points decoded", d.decoded));
            f.push(fig(
                "decoded per point",
                format!("{:.2}", d.decoded as f64 / bk.points as f64),
            ));
            f.push(fig("decoded kept waiting", crate::memory::human(d.stored)));
        }
        (Some(d.keep), b, kept)
    } else {
        (None, all_bounds, bk.points)
    };
    if kept == 0 {
        return Err(Error::Data {
            stage: "resample",
            message: "no points to resample".into(),
        });
    }
    let spec = GridSpec::new(&cfg.resample, &kept_bounds, kept as usize)
        .map_err(|e| pipeline.param_error(e))?;
    let files = bk.files(&paths, &opts);
    let t = Clock::start();
    // With only tile-by-tile outputs, the finished tiles leave memory shard by shard.
    let mut spilled =
        crate::output::writes_tile_by_tile(&cfg.output).then(super::spill::Spilled::default);
    let (layout, merged, kept_prepared, spilled_prepared, reads) = grid_pass(
        pipeline,
        dir,
        &bk,
        &files,
        keep.as_ref(),
        &spec,
        crs,
        sizing,
        spilled.as_mut(),
        progress,
    )?;
    drop(keep);
    let mut figures = vec![
        fig("grid", format!("{}×{}", spec.cols, spec.rows)),
        fig("shards", layout.count()),
        fig(
            "tiles per shard",
            format!("{}×{}", layout.block[0], layout.block[1]),
        ),
        fig("prepared shards kept", kept_prepared),
        fig("prepared shards spilled", spilled_prepared.is_some()),
    ];
    if !bk.boxes.is_empty() {
        figures.push(fig("points decoded", reads[0]));
        figures.push(fig(
            "decoded per point",
            format!("{:.2}", reads[0] as f64 / bk.points as f64),
        ));
        figures.push(fig("decoded kept waiting", crate::memory::human(reads[1])));
    }
    if let Some(b) = spilled_prepared {
        figures.push(fig("prepared spill", crate::memory::human(b)));
    }
    if let Some(f) = &merged.fill {
        figures.extend(fill_figures(f));
    }
    stages.push(report("grid shards", t, figures));
    let super::Merged {
        mut set, quadtree, ..
    } = merged;
    crate::pipeline::with_input_crs(cfg, &mut set);
    let files = match &spilled {
        Some(sp) => {
            stages.push(crate::pipeline::tiles_report_with(&set, sp.holes, 0.0));
            stages.push(crate::pipeline::quadtree_report(&quadtree, 0.0));
            let t = Clock::start();
            let tiles = set.tiles.len();
            let written = super::spill::write_spilled(
                dir,
                staged.path(),
                set,
                &quadtree,
                sp,
                &cfg.output,
                progress,
            )?;
            stages.push(report(
                "write",
                t,
                vec![
                    fig("files", written.len()),
                    fig("tiles written by shard", tiles),
                ],
            ));
            written
        }
        None => {
            let reports = vec![
                crate::pipeline::tiles_report(&set, 0.0),
                crate::pipeline::quadtree_report(&quadtree, 0.0),
            ];
            let ts = crate::pipeline::product_stages(
                cfg,
                set,
                quadtree,
                reports,
                staged.path(),
                progress,
            )?;
            stages.extend(ts.reports);
            ts.files
        }
    };
    stages.push(StageReport {
        stage: "stream".into(),
        seconds: 0.0,
        figures: vec![
            fig("parallel", sizing.parallel),
            fig("points per shard", sizing.points),
            fig(
                "peak memory",
                peak_rss().map_or("—".into(), crate::memory::human),
            ),
        ],
    });
    Ok((files, bk))
}

fn fill_figures(f: &FillReport) -> Vec<(String, String)> {
    vec![
        fig("measured", f.measured),
        fig("interpolated", f.interpolated),
        fig("fallback", f.fallback),
        fig("empty", f.empty),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_our_names_are_ours() {
        for n in [
            "job.txt",
            "bricks.json",
            "brick-0000012.bin",
            "counts-3-0000001.bin",
            "keep-3-0000001.bin",
            "tiles-12.bin",
            "prepared-7.bin",
        ] {
            assert!(is_ours(n), "{n}");
        }
        for n in [
            "notes.txt",
            "brick-12.bin",
            "keep-x.bin",
            "tile_0_0.exr",
            "tiles-.bin",
            "tiles-1-2.bin",
        ] {
            assert!(!is_ours(n), "{n}");
        }
    }

    #[test]
    fn sizing_respects_the_budget() {
        let s = Sizing::new(64 << 20);
        assert!(s.parallel as u64 * s.points * SHARD_BYTES_PER_POINT <= 32 << 20);
        assert!(block_for(&s, 256) >= 1);
    }
}
