//! The single-machine streaming driver of `terratile run` (see `docs/scale.md`): the same
//! shard code as the in-memory run, fed from temporary files instead of one cloud.
//!
//! 1. **Scan**: the headers of all inputs (bounds, counts, CRS); decides whether the run
//!    fits the memory budget in memory (`[scale] mode = "auto"`).
//! 2. **Bucket**: one read of every input in file order (LAS from its memory map, LAZ
//!    through the chunk decoder, batch by batch), each point appended to its brick
//!    ([`crate::shard::bricks`]) through fixed-size buffers; the exact bounds and number of the
//!    points are reduced on the way (noise removal's lattice).
//! 3. **Denoise windows**: square windows of low-layer columns, each reading the bricks its
//!    columns and halo overlap: the counts at every voxel height (summed, the height
//!    chosen), then the keep flags of its own points ([`denoise::shard_counts`],
//!    [`denoise::shard_denoise`]); the kept points' bounds and number fix the grid.
//! 4. **Grid shards**: blocks of tiles, each resampling the kept points of the bricks its
//!    cells and halo overlap ([`resample::resample_window`]), then [`crate::shard::prepare`],
//!    [`crate::shard::complete_coarse`], [`crate::shard::finish`] and [`crate::shard::merge`]; the tiles are
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

use super::spill;
use crate::config::LoadedPipeline;
use crate::error::{Error, Result};
use crate::fsutil::write_bytes_atomic;
use crate::pipeline::{peak_rss, Plan, RunSummary, StageReport};
use crate::points::{self, Bounds, Crs, PointCloud, SourceInfo};
use crate::progress::Progress;
use crate::shard::bricks::{self, BrickLattice, BrickPoints, BrickWriter, SourceTransform};
use crate::shard::direct::{self, FileBox, Files};
use crate::shard::reuse;
use crate::shard::settings::{Mode, ReadMode, DIRECT_MAX_READS};
use crate::shard::{complete_coarse, finish_with, merge, prepare, prepared_spill};
use crate::shard::{Merged, Prepared, ShardLayout, ShardOutput};
use crate::terrain::denoise::{self, ColumnWindow, DenoiseSettings, Frame};
use crate::terrain::fill::{Fallback, FillParams, FillReport};
use crate::terrain::resample::{self, GridSpec};
use crate::terrain::Heightfield;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::Instant;

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
        // A COPC input's hierarchy is checked here, before any pass relies on it.
        points::copc::layout(p, &map, &h)?;
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
        || spill::is_spill_name(name)
        || prepared_spill::is_prepared_name(name)
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
    /// Read by bounds when some input is COPC: the units (octree nodes, whole files) the
    /// figures above are of; empty: the figures are the files'.
    #[serde(default)]
    parts: Vec<direct::Part>,
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
            parts: &self.parts,
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
            // COPC files are LAZ here: read by node (`read = "direct"`) they decode about
            // 7 points a point on a survey in one file, 2.4 times the CPU of the bricks
            // (docs/scale.md), so `auto` buckets them.
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

/// True for a COPC input read by node (one that cannot be read is not: the scan says why).
fn is_copc(s: &SourceInfo) -> bool {
    let Ok(map) = points::map_file(&s.path) else {
        return false;
    };
    points::LasHeader::parse(&s.path, &map)
        .is_ok_and(|h| points::copc::layout(&s.path, &map, &h).is_ok_and(|l| l.is_some()))
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
    let mut parts = Vec::new();
    for (fi, info) in scan.sources.iter().enumerate() {
        let mut file_box = Bounds::EMPTY;
        let path = &info.path;
        let map = points::map_file(path)?;
        if direct {
            // A COPC input is counted node by node, and read so (see `direct::Part`).
            let h = points::LasHeader::parse(path, &map)?;
            if let Some(l) = points::copc::layout(path, &map, &h)? {
                let counted = direct::count_nodes(path, &map, &h, &l, &opts, seq)?;
                for (nd, (kept, nb)) in l.nodes.iter().zip(counted) {
                    parts.push(direct::Part {
                        file: fi,
                        node: Some(*nd),
                    });
                    sources.push(SourceTransform {
                        first: seq,
                        scale: h.scale,
                        offset: h.offset,
                    });
                    read.push(kept);
                    boxes.push(FileBox::of(&nb));
                    b = b.union(nb);
                    seq += kept;
                }
                progress.advance(h.point_count);
                continue;
            }
            parts.push(direct::Part {
                file: fi,
                node: None,
            });
        }
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
        parts: if parts.iter().any(|p| p.node.is_some()) {
            parts
        } else {
            Vec::new()
        },
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
        && !sc.sources.iter().any(is_copc)
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
        parts: Vec::new(),
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

/// The windows of the denoise pass: squares of `groups` × `groups` low-layer column groups,
/// each read with its halo, and what they read from.
struct DenoiseWindows<'a> {
    params: &'a denoise::DenoiseParams,
    dir: &'a Path,
    bk: &'a Bucketed,
    files: Files<'a>,
    mpu: f64,
    sizing: &'a Sizing,
    check: Option<&'a reuse::HeaderCheck>,
    progress: &'a dyn Progress,
    frame: Frame,
    s: DenoiseSettings,
    /// Low-layer columns of the survey in x and y.
    columns: [u64; 2],
    halo: u64,
    groups: u64,
    /// Columns per window side.
    side: u64,
    /// Windows in x and y, and all of them.
    n: [u64; 2],
    count: usize,
    decoded: AtomicU64,
    stored: AtomicU64,
    crash_after: Option<usize>,
    written: AtomicUsize,
}

impl<'a> DenoiseWindows<'a> {
    /// Windows holding about `sizing.points` points with their halo.
    #[allow(clippy::too_many_arguments)]
    fn new(
        pipeline: &'a LoadedPipeline,
        dir: &'a Path,
        bk: &'a Bucketed,
        files: &Files<'a>,
        mpu: f64,
        sizing: &'a Sizing,
        check: Option<&'a reuse::HeaderCheck>,
        progress: &'a dyn Progress,
    ) -> Result<Self> {
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
        let area = (frame.bounds.size()[0] * frame.bounds.size()[1]).max(1e-9);
        let density = bk.points as f64 / area;
        let side_world = (sizing.points as f64 / density.max(1e-12)).sqrt();
        let group_world = group as f64 * s.voxel_size;
        let groups = ((side_world / group_world).floor() as u64)
            .saturating_sub(2 * halo.div_ceil(group))
            .max(1);
        let side = groups * group;
        let n = [cx.div_ceil(side), cy.div_ceil(side)];
        Ok(DenoiseWindows {
            params,
            dir,
            bk,
            files: *files,
            mpu,
            sizing,
            check,
            progress,
            frame,
            s,
            columns: [cx, cy],
            halo,
            groups,
            side,
            n,
            count: (n[0] * n[1]) as usize,
            decoded: AtomicU64::new(0),
            stored: AtomicU64::new(0),
            crash_after: std::env::var("TERRATILE_STREAM_CRASH_AFTER")
                .ok()
                .and_then(|v| v.parse().ok()),
            written: AtomicUsize::new(0),
        })
    }

    /// Window `k`'s own columns.
    fn window(&self, k: usize) -> ColumnWindow {
        let ([cx, cy], n, side) = (self.columns, self.n, self.side);
        let (wx, wy) = (k as u64 % n[0], k as u64 / n[0]);
        ColumnWindow {
            x: wx * side..((wx + 1) * side).min(cx),
            y: wy * side..((wy + 1) * side).min(cy),
        }
    }

    /// The columns window `k` reads: its own and the halo, as `denoise_sharded` buckets them
    /// (in brick order: noise removal does not depend on the order of its points).
    fn read_columns(&self, k: usize) -> (std::ops::Range<u64>, std::ops::Range<u64>) {
        let ([cx, cy], halo) = (self.columns, self.halo);
        let own = self.window(k);
        let rx = own.x.start.saturating_sub(halo)..(own.x.end + halo).min(cx);
        let ry = own.y.start.saturating_sub(halo)..(own.y.end + halo).min(cy);
        (rx, ry)
    }

    /// The world range that holds window `k`'s points (one column of margin for rounding).
    fn range(&self, k: usize) -> reuse::Range2 {
        let (rx, ry) = self.read_columns(k);
        let inv = self.s.voxel_size;
        let world = |r: &std::ops::Range<u64>, a: usize, c: u64| {
            let lo = self.frame.bounds.min[a] + (r.start as f64 - 1.0) * inv;
            let hi = if r.end >= c {
                f64::INFINITY
            } else {
                self.frame.bounds.min[a] + (r.end as f64 + 1.0) * inv
            };
            [lo, hi]
        };
        (
            world(&rx, 0, self.columns[0]),
            world(&ry, 1, self.columns[1]),
        )
    }

    /// True when window `k` reads the point at (`x`, `y`).
    fn wanted(&self, k: usize, x: f64, y: f64) -> bool {
        let (rx, ry) = self.read_columns(k);
        let (a, b) = self.frame.column(&self.s, x, y);
        rx.contains(&a) && ry.contains(&b)
    }

    /// Window `k`'s points from the bricks.
    fn load(&self, k: usize) -> Result<BrickPoints> {
        let (x, y) = self.range(k);
        let files = self.files;
        self.bk
            .load(self.dir, &files, x, y, bricks::Order::Bricks, |_, x, y| {
                self.wanted(k, x, y)
            })
    }

    /// Window `k`'s file of `kind`.
    fn name(&self, kind: &str, k: usize) -> PathBuf {
        self.dir.join(format!("{kind}-{}-{k:07}.bin", self.groups))
    }

    /// Runs `f` on each window of `ks` with its points, `sizing.parallel` at a time: from the
    /// bricks, or by bounds with each file decoded about once for the whole list.
    fn run_batch(
        &self,
        ks: &[usize],
        f: &(dyn Fn(usize, BrickPoints) -> Result<()> + Sync),
    ) -> Result<()> {
        if self.bk.boxes.is_empty() {
            for chunk in ks.chunks(self.sizing.parallel) {
                chunk.par_iter().try_for_each(|&k| f(k, self.load(k)?))?;
                self.progress.advance(chunk.len() as u64);
            }
            return Ok(());
        }
        let ranges = (0..self.count).map(|k| self.range(k)).collect();
        let reader = reuse::PassReader::new(
            self.files,
            ranges,
            ks.to_vec(),
            reuse_round(self.sizing),
            reuse_cap(self.sizing),
            |k: usize, _: u64, x: f64, y: f64| self.wanted(k, x, y),
        )
        .with_check(self.check);
        let out = (0..reader.rounds()).try_for_each(|r| {
            let pts = reader.load(r)?;
            let ws = reader.round_windows(r);
            ws.par_iter().zip(pts).try_for_each(|(&k, p)| f(k, p))?;
            self.progress.advance(ws.len() as u64);
            Ok(())
        });
        self.decoded.fetch_add(reader.decoded(), Ordering::Relaxed);
        self.stored
            .fetch_max(reader.stored_peak(), Ordering::Relaxed);
        out
    }

    /// Window `k` filtered at `q` from its points `p`: its keep file (saved: resumable).
    fn keep_of(&self, k: usize, q: u32, p: BrickPoints) -> Result<()> {
        let own = self.window(k);
        let mut out = vec![q as u64, 0];
        let mut kept = Bounds::EMPTY;
        let mut seqs = Vec::new();
        if !p.is_empty() {
            let input = p.shard_input(&self.frame, self.params, self.mpu, &own);
            let d = denoise::shard_denoise(&input, q)?;
            out[1] = d.removed_sparse as u64;
            kept = crate::terrain::bounds_of(&p.x, &p.y, &p.z, Some(&d.keep)).0;
            // The removed points of its own columns (about 1 % of them: a small file where
            // the kept ones would be most of the input); the windows' own columns partition
            // the points, so every point not removed by its window is kept.
            for (i, &k) in d.keep.iter().enumerate() {
                if !k {
                    let (a, b) = self.frame.column(&self.s, p.x[i], p.y[i]);
                    if own.x.contains(&a) && own.y.contains(&b) {
                        seqs.push(p.seq[i]);
                    }
                }
            }
        }
        out.extend(kept.min.iter().chain(&kept.max).map(|v| v.to_bits()));
        out.extend(seqs);
        write_u64s(&self.name("keep", k), &out)?;
        let w = self.written.fetch_add(1, Ordering::SeqCst) + 1;
        if self.crash_after.is_some_and(|c| w >= c) {
            // A test's stand-in for the process being killed outright: no clean-up at all.
            eprintln!("terratile: TERRATILE_STREAM_CRASH_AFTER={w}: stopping without clean-up");
            std::process::exit(101);
        }
        Ok(())
    }

    /// Every window filtered at `q`; returns how many were resumed: windows whose keep file
    /// at `q` is already there (a resumed run) are not redone.
    fn keep_at(&self, q: u32, label: &str) -> Result<usize> {
        let done = |k: &usize| read_keep(&self.name("keep", *k)).is_some_and(|v| v.0 == q as u64);
        let todo: Vec<usize> = (0..self.count).filter(|k| !done(k)).collect();
        self.progress.start(label, todo.len() as u64);
        self.run_batch(&todo, &|k, p| self.keep_of(k, q, p))?;
        self.progress.finish();
        Ok(self.count - todo.len())
    }

    /// Window `k`'s counts at every voxel height from its points `p`, saved.
    fn counts_of(&self, k: usize, p: BrickPoints) -> Result<()> {
        let path = self.name("counts", k);
        let own = self.window(k);
        let c = if p.is_empty() {
            Vec::new()
        } else {
            let input = p.shard_input(&self.frame, self.params, self.mpu, &own);
            denoise::shard_counts(&input)?
        };
        let flat: Vec<u64> = c.iter().flat_map(|c| c.map(|v| v as u64)).collect();
        write_u64s(&path, &flat)
    }

    /// The counts at every voxel height summed over all windows (windows whose counts are
    /// already there, in a resumed run, are not redone).
    fn summed_counts(&self) -> Result<Vec<[usize; 3]>> {
        let todo: Vec<usize> = (0..self.count)
            .filter(|&k| read_u64s(&self.name("counts", k)).is_none())
            .collect();
        self.progress.start("denoise: counts", todo.len() as u64);
        self.run_batch(&todo, &|k, p| self.counts_of(k, p))?;
        self.progress.finish();
        let mut sums: Vec<[usize; 3]> = Vec::new();
        for k in 0..self.count {
            let flat = read_u64s(&self.name("counts", k))
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
        Ok(sums)
    }

    /// The keep flags of all points and the kept points' bounds, from the windows' files.
    fn gather(&self) -> Result<(KeepBits, Bounds)> {
        let mut keep = KeepBits::all(self.bk.points);
        let mut bounds = Bounds::EMPTY;
        for k in 0..self.count {
            let (_, _, b, seqs) = read_keep(&self.name("keep", k)).ok_or_else(|| {
                Error::Internal(format!("denoise window {k}: keep flags missing"))
            })?;
            bounds = bounds.union(b);
            for s in seqs {
                keep.clear(s);
            }
        }
        Ok((keep, bounds))
    }
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
    let w = DenoiseWindows::new(pipeline, dir, bk, files, mpu, sizing, check, progress)?;
    let mut resumed = w.keep_at(1, "denoise")?;
    let failing: u64 = (0..w.count)
        .map(|k| read_keep(&w.name("keep", k)).map_or(0, |v| v.1))
        .sum();
    let mut q = 1;
    if denoise::choose_steps(w.params, &[[failing as usize; 3]], w.frame.points) != 1 {
        // More than the budget fails at q = 1: the counts at every height decide.
        let sums = w.summed_counts()?;
        q = denoise::choose_steps(w.params, &sums, w.frame.points);
        if q != 1 {
            resumed = w.keep_at(q, "denoise: keep flags")?;
        }
    }
    let (keep, bounds) = w.gather()?;
    Ok(DenoisePass {
        keep,
        bounds,
        windows: w.count,
        resumed,
        steps: q,
        decoded: w.decoded.into_inner(),
        stored: w.stored.into_inner(),
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
type GridPass = (ShardLayout, Merged, bool, Option<u64>, [u64; 2]);

/// The grid shards of the streamed run: their layout over the grid, and where each reads its
/// kept points from.
struct GridShards<'a> {
    cfg: &'a crate::config::Pipeline,
    dir: &'a Path,
    bk: &'a Bucketed,
    files: Files<'a>,
    keep: Option<&'a KeepBits>,
    spec: &'a GridSpec,
    crs: Option<Crs>,
    sizing: &'a Sizing,
    progress: &'a dyn Progress,
    fill: Option<&'a FillParams>,
    layout: ShardLayout,
    /// Tiles per shard side.
    block: usize,
}

impl GridShards<'_> {
    /// Shard `i`'s input cells (its region with the fill's halo).
    fn input_cells(&self, i: usize) -> (std::ops::Range<usize>, std::ops::Range<usize>) {
        let shard = self.layout.shard(i);
        (
            shard.input(&self.layout, 0, self.fill),
            shard.input(&self.layout, 1, self.fill),
        )
    }

    /// The world range that holds shard `i`'s points (one cell of margin for rounding).
    fn range(&self, i: usize) -> reuse::Range2 {
        let spec = self.spec;
        let (ci, cj) = self.input_cells(i);
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
    }

    /// True when shard `i` reads the point with sequence number `s` at (`x`, `y`): kept, and
    /// in one of its input cells.
    fn wanted(&self, i: usize, s: u64, x: f64, y: f64) -> bool {
        let (ci, cj) = self.input_cells(i);
        self.keep.is_none_or(|k| k.get(s))
            && ci.contains(&self.spec.col(x))
            && cj.contains(&self.spec.row(y))
    }

    /// Shard `i` prepared from its points (`None`: read from the bricks now): the unfilled
    /// cells of its input from the kept points (in input order: the resampling sums in it).
    fn prepared_of(&self, i: usize, p: Option<BrickPoints>) -> Result<Prepared> {
        let shard = self.layout.shard(i);
        let (ci, cj) = self.input_cells(i);
        let offset = [ci.start, cj.start];
        let p = match p {
            Some(p) => p,
            None => {
                let (x, y) = self.range(i);
                let files = self.files;
                self.bk
                    .load(self.dir, &files, x, y, bricks::Order::Input, |s, x, y| {
                        self.wanted(i, s, x, y)
                    })?
            }
        };
        let cells = resample::resample_window(
            [&p.x, &p.y, &p.z],
            None,
            self.spec,
            [ci, cj],
            self.cfg.resample.method,
            self.crs.clone(),
        );
        drop(p);
        prepare(&self.layout, &shard, &cells, offset, self.fill)
    }

    /// The points of round `r` (`len` shards), when a reader by bounds serves them.
    fn points_of<W: Fn(usize, u64, f64, f64) -> bool + Sync>(
        &self,
        reader: Option<&reuse::PassReader<'_, W>>,
        r: usize,
        len: usize,
    ) -> Result<Vec<Option<BrickPoints>>> {
        match reader {
            Some(rd) if rd.round() == self.sizing.parallel => {
                Ok(rd.load(r)?.into_iter().map(Some).collect())
            }
            // Reuse off: one shard a round.
            Some(rd) => (0..len)
                .map(|j| Ok(rd.load(r * self.sizing.parallel + j)?.pop()))
                .collect(),
            None => Ok((0..len).map(|_| None).collect()),
        }
    }

    /// True when the prepared shards of the smooth fill fit half the budget and wait for its
    /// second step in memory.
    fn keeps_prepared(&self) -> bool {
        let b = self.block;
        let [w, h] = self.layout.samples;
        let ring = (b + 2) * (b + 2);
        (w * h) as u64 * PREPARED_BYTES_PER_CELL * ring as u64 / (b * b) as u64
            <= self.sizing.budget / 2
    }

    /// The smooth fill's first step: every shard prepared once, its coarse cells completed
    /// into the global coarse level; each prepared shard left in `kept` (when it is kept in
    /// memory) or in its temporary file (its bytes added to `spilled`).
    fn coarse_level<W: Fn(usize, u64, f64, f64) -> bool + Sync>(
        &self,
        reader: Option<&reuse::PassReader<'_, W>>,
        keep_prepared: bool,
        kept: &mut [Option<Prepared>],
        spilled: &AtomicU64,
    ) -> Result<Vec<f32>> {
        let n = self.layout.count();
        let all: Vec<usize> = (0..n).collect();
        self.progress.start("grid shards: coarse level", n as u64);
        let mut cells = Vec::new();
        for (r, chunk) in all.chunks(self.sizing.parallel).enumerate() {
            let pts = self.points_of(reader, r, chunk.len())?;
            let got = chunk
                .par_iter()
                .zip(pts)
                .map(|(&i, pts)| {
                    let p = self.prepared_of(i, pts)?;
                    let c = p.coarse(&self.layout);
                    if keep_prepared {
                        return Ok((c, Some(p)));
                    }
                    let bytes = prepared_spill::put(self.dir, &p)?;
                    spilled.fetch_add(bytes, Ordering::Relaxed);
                    Ok((c, None))
                })
                .collect::<Result<Vec<_>>>()?;
            for ((c, p), &i) in got.into_iter().zip(chunk) {
                cells.extend(c);
                kept[i] = p;
            }
            self.progress.advance(chunk.len() as u64);
        }
        self.progress.finish();
        complete_coarse(&self.layout, &cells)
    }

    /// Every shard finished (tiles, d2) from its prepared region: kept in `kept`, spilled
    /// (`spill_prepared`), or prepared now from its points; the final heights go to `spill`
    /// when the outputs are written tile by tile.
    fn finish_all<W: Fn(usize, u64, f64, f64) -> bool + Sync>(
        &self,
        reader: Option<&reuse::PassReader<'_, W>>,
        kept: &mut [Option<Prepared>],
        coarse: &[f32],
        (smooth, spill_prepared): (bool, bool),
        mut spill: Option<&mut spill::Spilled>,
    ) -> Result<Vec<ShardOutput>> {
        let n = self.layout.count();
        let all: Vec<usize> = (0..n).collect();
        self.progress.start("grid shards", n as u64);
        let mut outputs: Vec<ShardOutput> = Vec::with_capacity(n);
        for (r, chunk) in all.chunks(self.sizing.parallel).enumerate() {
            let taken: Vec<Option<Prepared>> = chunk.iter().map(|&i| kept[i].take()).collect();
            // Without the smooth fill this loop is the one that reads the points.
            let pts = if smooth {
                (0..chunk.len()).map(|_| None).collect()
            } else {
                self.points_of(reader, r, chunk.len())?
            };
            let got: Vec<ShardOutput> = chunk
                .par_iter()
                .zip(taken)
                .zip(pts)
                .map(|((&i, p), pts)| {
                    let p = match p {
                        Some(p) => p,
                        None if spill_prepared => prepared_spill::take(
                            self.dir,
                            &self.layout,
                            i,
                            self.fill,
                            self.crs.as_ref(),
                        )?,
                        None => self.prepared_of(i, pts)?,
                    };
                    // The extraction builds its own vertical error from the merged tiles.
                    let (tiles, quadtree) = (&self.cfg.tiles, &self.cfg.quadtree);
                    finish_with(&self.layout, p, coarse, tiles, quadtree, false)
                })
                .collect::<Result<_>>()?;
            for (mut out, &i) in got.into_iter().zip(chunk) {
                if let Some(s) = spill.as_deref_mut() {
                    // Final heights: to disk until the writers take them, shard by shard.
                    s.put(self.dir, i, &mut out, self.layout.tiles)?;
                }
                outputs.push(out);
            }
            self.progress.advance(chunk.len() as u64);
        }
        self.progress.finish();
        Ok(outputs)
    }
}

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
    spill: Option<&mut spill::Spilled>,
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
    let g = GridShards {
        cfg,
        dir,
        bk,
        files: *files,
        keep,
        spec,
        crs,
        sizing,
        progress,
        fill,
        layout,
        block: b,
    };
    let smooth = fill.is_some_and(|f| f.fallback == Fallback::Smooth);
    let n = layout.count();
    // Read by bounds: each input decoded about once for all shards, in rounds of
    // `sizing.parallel` shards.
    let reader = (!bk.boxes.is_empty()).then(|| {
        reuse::PassReader::new(
            *files,
            (0..n).map(|i| g.range(i)).collect(),
            (0..n).collect(),
            reuse_round(sizing),
            reuse_cap(sizing),
            |i: usize, s: u64, x: f64, y: f64| g.wanted(i, s, x, y),
        )
    });
    // With the smooth fill every shard's coarse cells come first; the prepared shards wait
    // for the second step in memory when they fit the budget, else each in its own
    // temporary file (`prepared_spill`): either way every shard is prepared once.
    let keep_prepared = g.keeps_prepared();
    let mut kept: Vec<Option<Prepared>> = (0..n).map(|_| None).collect();
    let spilled = AtomicU64::new(0);
    let coarse = if smooth {
        g.coarse_level(reader.as_ref(), keep_prepared, &mut kept, &spilled)?
    } else {
        Vec::new()
    };
    let spill_prepared = smooth && !keep_prepared;
    let outputs = g.finish_all(
        reader.as_ref(),
        &mut kept,
        &coarse,
        (smooth, spill_prepared),
        spill,
    )?;
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

/// What bucketing leaves besides the buckets: the check of the headers' counts (when the
/// points were counted from the headers), whether the first file's header failed it, and
/// whether a finished bucketing was resumed.
struct Bucketing {
    bk: Bucketed,
    check: Option<reuse::HeaderCheck>,
    inexact: bool,
    resumed: bool,
}

impl Bucketing {
    fn figures(&self) -> Vec<(String, String)> {
        let bk = &self.bk;
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
            fig("resumed", self.resumed),
            fig(
                "counted",
                if self.check.is_some() {
                    "from the headers"
                } else if self.inexact {
                    INEXACT
                } else {
                    "points"
                },
            ),
        ]
    }
}

/// What the passes of one streamed run share.
struct Passes<'a> {
    pipeline: &'a LoadedPipeline,
    sc: &'a Scan,
    tmp: &'a TempDir,
    sizing: &'a Sizing,
    progress: &'a dyn Progress,
    /// Read by bounds from the inputs (else through bricks).
    direct: bool,
    paths: Vec<PathBuf>,
    opts: points::ReadOptions,
}

impl Passes<'_> {
    /// Saves the buckets (`bricks.json`): a resumed run starts after them.
    fn save(&self, b: &Bucketed) -> Result<()> {
        let json = serde_json::to_vec(b).map_err(|e| Error::Internal(e.to_string()))?;
        write_bytes_atomic(&self.tmp.path.join(BRICKS_FILE), &json)
    }

    /// The points counted, every one into its brick.
    fn count_points(&self) -> Result<Bucketed> {
        let (pipeline, sc, sizing) = (self.pipeline, self.sc, self.sizing);
        let b = bucket(
            pipeline,
            sc,
            &self.tmp.path,
            sizing,
            self.direct,
            self.progress,
        )?;
        self.save(&b)?;
        Ok(b)
    }

    /// Pass 2: the buckets of a finished earlier run, or from the headers, or counted.
    ///
    /// The points counted from the headers are checked by the noise-removal pass (a resumed
    /// run checks them again: its finished windows' files separately). The first file with
    /// points is checked first, alone: writers that take the header's box from the points
    /// before they are rounded to the file's scale (the `las` crate's, so `terratile
    /// generate`'s) never match, and are counted at once.
    fn bucket(&self) -> Result<Bucketing> {
        let (sc, tmp) = (self.sc, self.tmp);
        let previous: Option<Bucketed> = tmp
            .resumed
            .then(|| std::fs::read(tmp.path.join(BRICKS_FILE)).ok())
            .flatten()
            .and_then(|b| serde_json::from_slice(&b).ok());
        let resumed = previous.is_some();
        let mut inexact = false;
        let (bk, check) = match previous {
            Some(b) if b.unchecked_headers => (b, Some(bucket_from_headers(sc, self.sizing).1)),
            Some(b) => (b, None),
            None => {
                tmp.clear()?;
                let headers = counts_from_headers(self.pipeline, sc, self.direct)
                    .then(|| bucket_from_headers(sc, self.sizing))
                    .filter(|(b, c)| {
                        let first = b.read.iter().position(|&n| n > 0);
                        let exact = first.is_none_or(|f| {
                            c.check_file(&b.files(&self.paths, &self.opts), f).is_ok()
                                && !c.failed()
                        });
                        inexact = !exact;
                        exact
                    });
                match headers {
                    Some((b, c)) => {
                        self.save(&b)?;
                        (b, Some(c))
                    }
                    None => (self.count_points()?, None),
                }
            }
        };
        Ok(Bucketing {
            bk,
            check,
            inexact,
            resumed,
        })
    }

    /// Pass 3a with its report: the keep flags, the kept points' bounds and their number.
    /// Points counted from headers that do not match them are counted again, and the pass
    /// runs again.
    fn denoise(
        &self,
        b: &mut Bucketing,
        mpu: f64,
        stages: &mut Vec<StageReport>,
    ) -> Result<(Option<KeepBits>, Bounds, u64)> {
        let (pipeline, sizing, progress) = (self.pipeline, self.sizing, self.progress);
        let dir = &self.tmp.path;
        let t = Clock::start();
        let pass = |bk: &Bucketed, check| {
            let files = bk.files(&self.paths, &self.opts);
            denoise_pass(pipeline, dir, bk, &files, mpu, sizing, check, progress)
        };
        let check = &b.check;
        let first = pass(&b.bk, check.as_ref());
        if let (Some(c), Ok(_)) = (check, &first) {
            c.check_the_rest(&b.bk.files(&self.paths, &self.opts))?;
        }
        let d = match check {
            Some(c) if c.failed() || (first.is_ok() && !c.passed()) => {
                // A header did not match its points: count them, and run the pass again.
                drop(first);
                progress.finish();
                let tc = Clock::start();
                self.tmp.clear()?;
                b.bk = self.count_points()?;
                stages.push(report(
                    "bucket",
                    tc,
                    vec![fig("points", b.bk.points), fig("counted", INEXACT)],
                ));
                pass(&b.bk, None)?
            }
            Some(_) => {
                let d = first?;
                b.bk.unchecked_headers = false;
                self.save(&b.bk)?;
                d
            }
            None => first?,
        };
        let bk = &b.bk;
        let kept = d.keep.count();
        let figures = vec![
            fig("points in", bk.points),
            fig("points out", kept),
            fig("removed", bk.points - kept),
            fig("windows", d.windows),
            fig("windows resumed", d.resumed),
            fig("voxel height steps", d.steps),
        ];
        let mut r = report("denoise", t, figures);
        if !bk.boxes.is_empty() {
            // After the CPU time and peak memory, as the report has always listed them.
            r.figures
                .extend(decoded_figures(d.decoded, d.stored, bk.points));
        }
        stages.push(r);
        Ok((Some(d.keep), d.bounds, kept))
    }
}

/// The figures of a pass read by bounds: points decoded, per point, and the most bytes of
/// decoded points kept waiting.
fn decoded_figures(decoded: u64, stored: u64, points: u64) -> Vec<(String, String)> {
    vec![
        fig("points decoded", decoded),
        fig(
            "decoded per point",
            format!("{:.2}", decoded as f64 / points as f64),
        ),
        fig("decoded kept waiting", crate::memory::human(stored)),
    ]
}

/// The grid pass's figures.
fn grid_figures(
    spec: &GridSpec,
    bk: &Bucketed,
    pass: &GridPass,
    fill: Option<&FillReport>,
) -> Vec<(String, String)> {
    let (layout, _, kept_prepared, spilled_prepared, reads) = pass;
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
        figures.extend(decoded_figures(reads[0], reads[1], bk.points));
    }
    if let Some(b) = spilled_prepared {
        figures.push(fig("prepared spill", crate::memory::human(*b)));
    }
    if let Some(f) = fill {
        figures.extend(fill_figures(f));
    }
    figures
}

/// The outputs of the merged tiles into `staged`, with the reports of the tiling, the
/// quadtree and the writing; returns the files written.
fn write_outputs(
    pipeline: &LoadedPipeline,
    dir: &Path,
    merged: Merged,
    spilled: Option<spill::Spilled>,
    staged: &crate::fsutil::StagedDir,
    stages: &mut Vec<StageReport>,
    progress: &dyn Progress,
) -> Result<Vec<String>> {
    let cfg = &pipeline.config;
    let Merged {
        mut set, quadtree, ..
    } = merged;
    crate::pipeline::with_input_crs(cfg, &mut set);
    let Some(sp) = spilled else {
        let reports = vec![
            crate::pipeline::tiles_report(&set, 0.0),
            crate::pipeline::quadtree_report(&quadtree, 0.0),
        ];
        let ts =
            crate::pipeline::product_stages(cfg, set, quadtree, reports, staged.path(), progress)?;
        stages.extend(ts.reports);
        return Ok(ts.files);
    };
    stages.push(crate::pipeline::tiles_report_with(&set, sp.holes, 0.0));
    stages.push(crate::pipeline::quadtree_report(&quadtree, 0.0));
    let t = Clock::start();
    let tiles = set.tiles.len();
    let written = spill::write_spilled(
        dir,
        staged.path(),
        set,
        &quadtree,
        &sp,
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
    Ok(written)
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
    let ps = Passes {
        pipeline,
        sc,
        tmp,
        sizing,
        progress,
        direct: reads_directly(pipeline, sc, sizing),
        paths: sc.sources.iter().map(|s| s.path.clone()).collect(),
        opts: cfg.input.read_options(),
    };
    let mut b = ps.bucket()?;
    if b.bk.points == 0 {
        return Err(pipeline.key_error(
            "input.paths",
            "the inputs hold no points (after the class filter)",
        ));
    }
    stages.push(report("bucket", t, b.figures()));
    let crs: Option<Crs> = sc.sources.iter().find_map(|s| s.crs.clone());
    let mpu = crs.as_ref().map_or(1.0, |c| c.metres_per_unit());
    let all_bounds = Bounds {
        min: b.bk.min,
        max: b.bk.max,
    };
    let (keep, kept_bounds, kept) = if cfg.denoise.enabled {
        ps.denoise(&mut b, mpu, stages)?
    } else {
        (None, all_bounds, b.bk.points)
    };
    let bk = b.bk;
    if kept == 0 {
        return Err(Error::Data {
            stage: "resample",
            message: "no points to resample".into(),
        });
    }
    let spec = GridSpec::new(&cfg.resample, &kept_bounds, kept as usize)
        .map_err(|e| pipeline.param_error(e))?;
    let files = bk.files(&ps.paths, &ps.opts);
    let t = Clock::start();
    // With only tile-by-tile outputs, the finished tiles leave memory shard by shard.
    let mut spilled = crate::output::writes_tile_by_tile(&cfg.output).then(spill::Spilled::default);
    let pass = grid_pass(
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
    let figures = grid_figures(&spec, &bk, &pass, pass.1.fill.as_ref());
    stages.push(report("grid shards", t, figures));
    let files = write_outputs(pipeline, dir, pass.1, spilled, staged, stages, progress)?;
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
