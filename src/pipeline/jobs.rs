//! The sharded run as separate jobs, for any engine (Dask, Slurm job arrays, Kubernetes
//! Indexed Jobs, a shell loop): `terratile plan`, `terratile shard`, `terratile merge`.
//!
//! A plan (`DIR/plan.json`) fixes what every job must agree on: the pipeline file and the
//! inputs (with their sizes and modification times, so a job refuses inputs changed since),
//! the number of all points and their bounds (the noise-removal lattice, from a counting
//! pass), and a grid of `sx × sy` shards. Every job then runs the very functions of the
//! in-process sharded run ([`crate::shard::points`], [`crate::shard::prepare`], [`crate::shard::finish`],
//! [`crate::shard::merge`]) on its part and writes its result to `DIR/shards/K/PHASE.bin`
//! ([`crate::shard::store`]), atomically.
//!
//! The job graph has four phases of `jobs = sx · sy` jobs each and a merge, because the run
//! has three global reductions that a job cannot compute alone (see `docs/scale.md`):
//!
//! 1. `count`: noise removal's count at every voxel height over a window of voxel columns
//!    (plus its halo); reduced by every `keep` job to the voxel height (`choose_steps`).
//! 2. `keep`: the keep flags of the window's own points; reduced by every later job to the
//!    kept points' bounds and number, which fix the grid (`GridSpec::new`).
//! 3. `prepare`: a block of tiles: its cells resampled from the kept points of its cells and
//!    halo, interpolated, and the smooth fill's pyramid up to one cell per tile; reduced by
//!    every `finish` job to the coarse level (`complete_coarse`).
//! 4. `finish`: the fill's pull down, the tiles, d2 and the vertical error of the block.
//! 5. `merge`: d2 and the vertical error across blocks, then meshes and every output file,
//!    as `terratile run` writes them.
//!
//! The reductions are tiny (a few numbers per job) and exact (sums, minima, maxima, a fixed
//! order), so each consumer recomputes them from the results it reads instead of needing a
//! reduction job. A job whose index has no window or block (the grid is smaller than the
//! shard grid) writes an empty result, so every phase is an array of exactly `jobs` jobs.
//! Each job reads its inputs one file at a time and keeps only the points its window or
//! block needs: its memory is one input file plus its own points, not the survey.

use crate::config::LoadedPipeline;
use crate::error::{Error, Result};
use crate::points::{self, Bounds, PointCloud, ReadOptions};
use crate::shard::points::Stages;
use crate::shard::prepared_spill::{read_prepared_from, write_prepared};
use crate::shard::store::{Reader, Writer};
use crate::shard::{complete_coarse, finish, is_smooth, merge, prepare, Prepared, ShardLayout};
use crate::shard::{Shard, ShardOutput};
use crate::terrain::denoise::{self, ColumnWindow, DenoiseSettings, Frame};
use crate::terrain::fill::FillReport;
use crate::terrain::quadtree::NodeValues;
use crate::terrain::resample::{self, GridSpec};
use crate::terrain::tiles::{Preset, Tile};
use crate::terrain::{Fallback, Heightfield};
use crate::NoProgress;
use ndarray::Array2;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The plan's file name inside the work directory.
pub const PLAN_FILE: &str = "plan.json";
const FORMAT: &str = "terratile shard plan 1";

/// Points decoded per batch when a job reads an input (1/4 Mi points: a few MB of buffer,
/// reused from file to file).
const READ_BATCH: usize = 1 << 18;

/// The phases of the job graph, in order (each an array of `jobs` jobs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Noise removal's counts per voxel height.
    Count = 1,
    /// Noise removal's keep flags.
    Keep = 2,
    /// Resampling, interpolation and the fill pyramid of a block of tiles.
    Prepare = 3,
    /// The fill's pull down, tiles, d2 and vertical error of a block.
    Finish = 4,
}

impl Phase {
    /// All phases, in order.
    pub const ALL: [Phase; 4] = [Phase::Count, Phase::Keep, Phase::Prepare, Phase::Finish];

    /// Its name on the command line and in file names.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Count => "count",
            Phase::Keep => "keep",
            Phase::Prepare => "prepare",
            Phase::Finish => "finish",
        }
    }

    /// The phase named `s`.
    pub fn parse(s: &str) -> Result<Phase> {
        Phase::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| {
                Error::Usage(format!(
                    "--phase {}: expected count, keep, prepare or finish",
                    crate::one_line(s)
                ))
            })
    }
}

/// An input file as the plan saw it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Stamp {
    /// The file.
    pub path: PathBuf,
    /// Its size in bytes.
    pub bytes: u64,
    /// Its modification time, nanoseconds since the Unix epoch.
    pub modified_ns: u64,
}

impl Stamp {
    fn of(path: &Path) -> Result<Stamp> {
        let m = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
        let modified_ns = m
            .modified()
            .ok()
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .map_or(0, |d| d.as_nanos() as u64);
        Ok(Stamp {
            path: path.to_path_buf(),
            bytes: m.len(),
            modified_ns,
        })
    }
}

/// The plan file: what every job of one run agrees on.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct JobPlan {
    /// `terratile shard plan 1`.
    pub format: String,
    /// The pipeline file (absolute).
    pub pipeline: PathBuf,
    /// CRC-32 of the pipeline file's text when planned.
    pub pipeline_crc: u32,
    /// The inputs, in reading order.
    pub inputs: Vec<Stamp>,
    /// Shards along x and y.
    pub shards: [usize; 2],
    /// Jobs per phase (`shards[0] · shards[1]`), indices 0 to `jobs − 1`.
    pub jobs: usize,
    /// The phases, in order (each one array of `jobs` jobs), then `merge`.
    pub phases: Vec<String>,
    /// Points read (after the class filter and the cap).
    pub points: usize,
    /// Their bounds (min x, y, z, max x, y, z), for reading.
    pub bounds: [f64; 6],
    /// The same bounds as f64 bit patterns: what the jobs use.
    pub bounds_bits: [u64; 6],
    /// Metres per horizontal unit of the inputs (their CRS), as f64 bits.
    pub metres_per_unit_bits: u64,
    /// Each input's points read (after the class filter and the cap), in reading order.
    #[serde(default)]
    pub input_points: Vec<u64>,
    /// Each input's points' x/y box (min x, min y, max x, max y, as f64 bit patterns): a
    /// job skips the files whose box misses its read range. Without these (a plan of an
    /// older build) every job reads every input.
    #[serde(default)]
    pub input_boxes: Vec<[u64; 4]>,
}

impl JobPlan {
    fn bounds(&self) -> Bounds {
        let b = self.bounds_bits.map(f64::from_bits);
        Bounds {
            min: [b[0], b[1], b[2]],
            max: [b[3], b[4], b[5]],
        }
    }
}

fn crc32(b: &[u8]) -> u32 {
    let mut c = flate2::Crc::new();
    c.update(b);
    c.sum()
}

/// What the pipeline asks that a sharded run cannot do: refused with one line at its key.
fn check_supported(p: &LoadedPipeline) -> Result<()> {
    let c = &p.config;
    let refusals = [
        (
            c.ground.enabled,
            "ground.enabled",
            "ground classification reads all points at once",
        ),
        (
            c.baseline.enabled,
            "baseline.enabled",
            "the Delaunay baseline triangulates all points at once",
        ),
        (
            !c.assets.is_empty(),
            "assets",
            "assets are set down on the whole grid",
        ),
        (
            c.denoise.enabled && c.denoise.write_removed,
            "denoise.write_removed",
            "the removed points are written from the whole cloud",
        ),
        (
            c.fill.enabled && c.fill.fallback == Fallback::Mean,
            "fill.fallback",
            "the mean fallback needs the whole grid's mean",
        ),
        (
            c.fill.enabled && c.fill.fallback == Fallback::Membrane,
            "fill.fallback",
            "the membrane fill is solved over the whole grid",
        ),
        (
            c.tiles.preset == Preset::Unreal,
            "tiles.preset",
            "the unreal preset resamples the whole grid",
        ),
    ];
    match refusals.into_iter().find(|r| r.0) {
        Some((_, key, why)) => Err(p.key_error(
            key,
            format!(
                "{why}: the sharded run (plan/shard/merge) does not do it; use `terratile run`"
            ),
        )),
        None => Ok(()),
    }
}

/// Reads every input in order, one file at a time, with the pipeline's class filter and cap
/// (as `points::read_all` applies them), and hands each file's points to `f`.
fn for_each_input(
    paths: &[PathBuf],
    opts: &ReadOptions,
    mut f: impl FnMut(PointCloud) -> Result<()>,
) -> Result<()> {
    let mut read = 0u64;
    for p in paths {
        let mut o = opts.clone();
        if let Some(cap) = opts.max_points {
            o.max_points = Some(cap.saturating_sub(read));
        }
        let c = points::read(p, &o, &NoProgress)?;
        read += c.len() as u64;
        f(c)?;
    }
    Ok(())
}

/// Reads one input with the pipeline's class filter and at most `cap` points, LAS and LAZ a
/// batch at a time into `batch` (one reused buffer: a job is a fresh process, and reading
/// each input whole into a new cloud made the kernel zero every page of it again), and
/// hands `f` each batch; returns the points read.
fn each_batch(
    path: &Path,
    opts: &ReadOptions,
    cap: Option<u64>,
    batch: &mut PointCloud,
    mut f: impl FnMut(&PointCloud) -> Result<()>,
) -> Result<u64> {
    let o = ReadOptions {
        max_points: cap,
        ..opts.clone()
    };
    let map = points::map_file(path)?;
    let format = match o.format {
        Some(format) => format,
        None => points::detect_format(path, &map)?,
    };
    if format == points::Format::Xyz {
        let c = points::read_bytes(path, &map, &o, &NoProgress)?;
        f(&c)?;
        return Ok(c.len() as u64);
    }
    Ok(points::for_each_decoded(path, &map, &o, READ_BATCH, batch, |c, _| f(c))?.1)
}

/// `terratile plan`: checks the pipeline, counts the inputs' points and their bounds, and
/// writes `dir/plan.json` for `shards` jobs per phase (the largest `sx × sy ≤ shards` with
/// `sx = ⌊√shards⌋`). Planning again with the same pipeline and inputs writes the same plan,
/// so finished job results stay valid (a rerun resumes).
pub fn plan(pipeline: &Path, dir: &Path, shards: usize) -> Result<JobPlan> {
    if shards == 0 {
        return Err(Error::Usage("--shards must be at least 1".into()));
    }
    let loaded = crate::config::load(pipeline)?;
    let checked = crate::pipeline::Plan::new(&loaded)?;
    check_supported(&loaded)?;
    let plan_path = dir.join(PLAN_FILE);
    if plan_path.exists() && read_plan(&plan_path).is_err() {
        return Err(Error::Usage(format!(
            "{}: exists and is not a terratile plan: choose another --out directory",
            plan_path.display()
        )));
    }
    let opts = loaded.config.input.read_options();
    let mut bounds = Bounds::EMPTY;
    let mut n = 0usize;
    let mut sources = Vec::new();
    let (mut input_points, mut input_boxes) = (Vec::new(), Vec::new());
    // The sources (and their CRS) from the headers alone; the points batch by batch.
    let headers = ReadOptions {
        max_points: Some(0),
        ..opts.clone()
    };
    for_each_input(&checked.inputs, &headers, |c| {
        sources.extend(c.sources);
        Ok(())
    })?;
    let mut batch = PointCloud::default();
    for p in &checked.inputs {
        let mut b = Bounds::EMPTY;
        let cap = opts.max_points.map(|c| c.saturating_sub(n as u64));
        let k = each_batch(p, &opts, cap, &mut batch, |c| {
            b = b.union(crate::terrain::bounds_of(&c.x, &c.y, &c.z, None).0);
            Ok(())
        })?;
        bounds = bounds.union(b);
        n += k as usize;
        input_points.push(k);
        input_boxes.push([b.min[0], b.min[1], b.max[0], b.max[1]].map(f64::to_bits));
    }
    let seen = PointCloud {
        sources,
        ..Default::default()
    };
    if n == 0 {
        return Err(crate::pipeline::empty_input(&loaded, &seen));
    }
    let mpu = seen.crs().map_or(1.0, |c| c.metres_per_unit());
    // The largest square side within `shards` (in integers, whatever the float root says).
    let sx = (1..=shards)
        .take_while(|s| s * s <= shards)
        .last()
        .unwrap_or(1);
    let sy = shards / sx;
    let abs = std::path::absolute(&loaded.path).map_err(|e| Error::io(&loaded.path, e))?;
    let inputs = checked
        .inputs
        .iter()
        .map(|p| {
            let a = std::path::absolute(p).map_err(|e| Error::io(p, e))?;
            Stamp::of(&a)
        })
        .collect::<Result<Vec<_>>>()?;
    let flat = [
        bounds.min[0],
        bounds.min[1],
        bounds.min[2],
        bounds.max[0],
        bounds.max[1],
        bounds.max[2],
    ];
    let plan = JobPlan {
        format: FORMAT.into(),
        pipeline: abs,
        pipeline_crc: crc32(loaded.text.as_bytes()),
        inputs,
        shards: [sx, sy],
        jobs: sx * sy,
        phases: Phase::ALL.iter().map(|p| p.name().to_string()).collect(),
        points: n,
        bounds: flat,
        bounds_bits: flat.map(f64::to_bits),
        metres_per_unit_bits: mpu.to_bits(),
        input_points,
        input_boxes,
    };
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let text = serde_json::to_string_pretty(&plan).map_err(|e| Error::Internal(e.to_string()))?;
    crate::fsutil::write_bytes_atomic(&plan_path, format!("{text}\n").as_bytes())?;
    Ok(plan)
}

fn read_plan(path: &Path) -> Result<(JobPlan, u32)> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(Error::Usage(format!(
                "{}: no plan here (run `terratile plan PIPELINE --out DIR` first)",
                path.display()
            )))
        }
        Err(e) => return Err(Error::io(path, e)),
    };
    let plan: JobPlan = serde_json::from_slice(&bytes)
        .map_err(|e| Error::text(path, e.line() as u64, format!("not a terratile plan: {e}")))?;
    if plan.format != FORMAT {
        return Err(Error::text(
            path,
            1,
            format!("format `{}`: expected `{FORMAT}`", plan.format),
        ));
    }
    if plan.jobs != plan.shards[0] * plan.shards[1] || plan.jobs == 0 {
        return Err(Error::text(
            path,
            1,
            "jobs differs from shards[0] × shards[1]",
        ));
    }
    Ok((plan, crc32(&bytes)))
}

/// A job's view of the run: the plan, the pipeline and the stages' settings.
struct Run {
    dir: PathBuf,
    plan: JobPlan,
    plan_crc: u32,
    pipeline: LoadedPipeline,
    stages: Stages,
    inputs: Vec<PathBuf>,
}

impl Run {
    /// The plan at `at` (its work directory or the plan file), checked against the pipeline
    /// and inputs as they are now.
    fn open(at: &Path) -> Result<Run> {
        let (dir, file) = if at.is_dir() {
            (at.to_path_buf(), at.join(PLAN_FILE))
        } else {
            let d = at.parent().unwrap_or(Path::new(".")).to_path_buf();
            (d, at.to_path_buf())
        };
        let (plan, plan_crc) = read_plan(&file)?;
        let pipeline = crate::config::load(&plan.pipeline)?;
        if crc32(pipeline.text.as_bytes()) != plan.pipeline_crc {
            return Err(Error::Usage(format!(
                "{}: the pipeline changed since {} was planned: plan again",
                plan.pipeline.display(),
                file.display()
            )));
        }
        check_supported(&pipeline)?;
        for s in &plan.inputs {
            let now = Stamp::of(&s.path)?;
            if now != *s {
                return Err(Error::Usage(format!(
                    "{}: changed since {} was planned (size or modification time): plan again",
                    s.path.display(),
                    file.display()
                )));
            }
        }
        let c = &pipeline.config;
        let stages = Stages {
            denoise: c.denoise.enabled.then(|| c.denoise.clone()),
            metres_per_unit: f64::from_bits(plan.metres_per_unit_bits),
            resample: c.resample.clone(),
            fill: c.fill.enabled.then(|| c.fill.clone()),
            tiles: c.tiles.clone(),
            quadtree: c.quadtree.clone(),
        };
        let inputs = plan.inputs.iter().map(|s| s.path.clone()).collect();
        Ok(Run {
            dir,
            plan,
            plan_crc,
            pipeline,
            stages,
            inputs,
        })
    }

    /// Reads, in input order, the inputs whose points' box (from the plan) meets `x` × `y`
    /// (closed ranges; ends may be infinite), handing `f` each one's index and its points
    /// batch by batch; `skipped` gets the index of every other. A file that gives another
    /// number of points than the plan counted is refused, naming it.
    ///
    /// LAS and LAZ are decoded a batch at a time into one reused buffer: a job is a fresh
    /// process, and reading each input whole into a new cloud made the kernel zero every page
    /// of it again (half of a `prepare` job's time went to page faults).
    fn each_input_in(
        &self,
        x: [f64; 2],
        y: [f64; 2],
        mut skipped: impl FnMut(usize),
        mut f: impl FnMut(usize, &PointCloud) -> Result<()>,
    ) -> Result<()> {
        let opts = self.pipeline.config.input.read_options();
        let n = self.inputs.len();
        let known = self.plan.input_points.len() == n && self.plan.input_boxes.len() == n;
        let mut read = 0u64;
        let mut batch = PointCloud::default();
        for (i, p) in self.inputs.iter().enumerate() {
            if known {
                let b = self.plan.input_boxes[i].map(f64::from_bits);
                let fb = crate::shard::direct::FileBox {
                    min: [b[0], b[1]],
                    max: [b[2], b[3]],
                };
                if self.plan.input_points[i] == 0 || !fb.meets(x, y) {
                    read += self.plan.input_points[i];
                    skipped(i);
                    continue;
                }
            }
            let cap = opts.max_points.map(|c| c.saturating_sub(read));
            let got = each_batch(p, &opts, cap, &mut batch, |c| f(i, c))?;
            if known && got != self.plan.input_points[i] {
                return Err(Error::Usage(format!(
                    "{}: gives {got} points where the plan counted {}: plan again",
                    p.display(),
                    self.plan.input_points[i]
                )));
            }
            read += got;
        }
        Ok(())
    }

    /// The CRS as the in-memory run takes it: the first input that states one (headers
    /// only: no point is read).
    fn input_crs(&self) -> Result<Option<crate::points::Crs>> {
        let opts = ReadOptions {
            max_points: Some(0),
            ..self.pipeline.config.input.read_options()
        };
        let mut crs = None;
        for_each_input(&self.inputs, &opts, |c| {
            if crs.is_none() {
                crs = c.crs().cloned();
            }
            Ok(())
        })?;
        Ok(crs)
    }

    fn result(&self, phase: Phase, index: usize) -> PathBuf {
        self.dir
            .join("shards")
            .join(index.to_string())
            .join(format!("{}.bin", phase.name()))
    }

    fn open_result(&self, phase: Phase, index: usize) -> Result<Reader> {
        Reader::open(
            &self.result(phase, index),
            phase as u32,
            self.plan_crc,
            index as u64,
        )
    }

    fn save(&self, phase: Phase, index: usize, w: Writer) -> Result<()> {
        w.save(
            &self.result(phase, index),
            phase as u32,
            self.plan_crc,
            index as u64,
        )
    }

    /// Shard index `k`'s place in the shard grid.
    fn place(&self, k: usize) -> [usize; 2] {
        [k % self.plan.shards[0], k / self.plan.shards[0]]
    }

    /// Stage errors located at their keys in the pipeline file.
    fn at_key(&self, e: Error) -> Error {
        self.pipeline.param_error(e)
    }
}

/// Noise removal's windows: the voxel-column lattice cut into the plan's shard grid, each
/// side a whole number of low-layer columns.
struct Windows {
    frame: Frame,
    settings: DenoiseSettings,
    side: [u64; 2],
    n: [u64; 2],
    columns: [u64; 2],
    halo: u64,
}

impl Windows {
    fn of(run: &Run) -> Result<Option<Windows>> {
        let Some(params) = &run.stages.denoise else {
            return Ok(None);
        };
        let frame = Frame {
            bounds: run.plan.bounds(),
            points: run.plan.points,
        };
        let settings = frame
            .settings(params, run.stages.metres_per_unit)
            .map_err(|e| run.at_key(e))?;
        let columns = frame.columns(&settings);
        let g = frame.group(&settings).max(1);
        let side = [0, 1].map(|a| {
            (columns[a].div_ceil(run.plan.shards[a] as u64))
                .div_ceil(g)
                .max(1)
                * g
        });
        let n = [0, 1].map(|a| columns[a].div_ceil(side[a]));
        let halo = frame.halo(&settings);
        Ok(Some(Windows {
            frame,
            settings,
            side,
            n,
            columns,
            halo,
        }))
    }

    /// The columns window `[wx, wy]` owns (None: no such window).
    fn own(&self, [wx, wy]: [usize; 2]) -> Option<ColumnWindow> {
        let (wx, wy) = (wx as u64, wy as u64);
        (wx < self.n[0] && wy < self.n[1]).then(|| ColumnWindow {
            x: wx * self.side[0]..((wx + 1) * self.side[0]).min(self.columns[0]),
            y: wy * self.side[1]..((wy + 1) * self.side[1]).min(self.columns[1]),
        })
    }

    /// The window owning a point's column (as `[wx, wy]`).
    fn owner(&self, x: f64, y: f64) -> [usize; 2] {
        let (a, b) = self.frame.column(&self.settings, x, y);
        [(a / self.side[0]) as usize, (b / self.side[1]) as usize]
    }

    /// The points of one window: (own columns and halo) in input order, which it owns, and
    /// how many it owns of each input (reading only the inputs its range meets).
    #[allow(clippy::type_complexity)]
    fn gather(
        &self,
        run: &Run,
        own: &ColumnWindow,
    ) -> Result<([Vec<f64>; 3], Vec<bool>, Vec<u64>)> {
        let h = self.halo;
        let reads = |c: u64, r: &std::ops::Range<u64>| c + h >= r.start && c < r.end + h;
        // The world range of the columns read, one column wider on each side for rounding
        // (the last column reaches to infinity: columns are clamped).
        let world = |r: &std::ops::Range<u64>, a: usize| {
            let (lo, hi) = (r.start.saturating_sub(h), r.end + h);
            let vs = self.settings.voxel_size;
            let min = self.frame.bounds.min[a];
            [
                min + (lo as f64 - 1.0) * vs,
                if hi >= self.columns[a] {
                    f64::INFINITY
                } else {
                    min + (hi as f64 + 1.0) * vs
                },
            ]
        };
        let mut xyz = [Vec::new(), Vec::new(), Vec::new()];
        let mut owned = Vec::new();
        let mut per_input = vec![0u64; run.inputs.len()];
        run.each_input_in(
            world(&own.x, 0),
            world(&own.y, 1),
            |_| {},
            |f, c| {
                for i in 0..c.len() {
                    let (a, b) = self.frame.column(&self.settings, c.x[i], c.y[i]);
                    if reads(a, &own.x) && reads(b, &own.y) {
                        xyz[0].push(c.x[i]);
                        xyz[1].push(c.y[i]);
                        xyz[2].push(c.z[i]);
                        let o = own.x.contains(&a) && own.y.contains(&b);
                        owned.push(o);
                        per_input[f] += u64::from(o);
                    }
                }
                Ok(())
            },
        )?;
        Ok((xyz, owned, per_input))
    }

    fn input<'a>(
        &'a self,
        run: &'a Run,
        xyz: &'a [Vec<f64>; 3],
        own: &'a ColumnWindow,
    ) -> Option<denoise::ShardInput<'a>> {
        Some(denoise::ShardInput {
            x: &xyz[0],
            y: &xyz[1],
            z: &xyz[2],
            frame: &self.frame,
            params: run.stages.denoise.as_ref()?,
            metres_per_unit: run.stages.metres_per_unit,
            owned: own,
        })
    }
}

/// A window's noise removal as a `keep` result holds it: the voxel height steps, one keep
/// flag per point the window owns (in input order, packed eight to a byte), the number and
/// bounds of its kept points, and how many of its flags belong to each input (`prepare`
/// skips the flags of the inputs it does not read).
struct WindowKeep {
    q: u64,
    owned: usize,
    packed: Vec<u8>,
    kept: usize,
    bounds: Bounds,
    per_input: Vec<u64>,
}

impl WindowKeep {
    /// A window with no points (or noise removal off).
    fn empty(run: &Run, q: u32) -> WindowKeep {
        WindowKeep {
            q: q as u64,
            owned: 0,
            packed: Vec::new(),
            kept: 0,
            bounds: Bounds::EMPTY,
            per_input: vec![0; run.inputs.len()],
        }
    }

    /// From the keep flags of a window's gathered points (own and halo: only own points
    /// can be kept) and which of them it owns.
    fn of(q: u32, keep: &[bool], owned: &[bool], xyz: &[Vec<f64>; 3], per: Vec<u64>) -> Self {
        let (bounds, kept) = crate::terrain::bounds_of(&xyz[0], &xyz[1], &xyz[2], Some(keep));
        let mut packed = Vec::new();
        let mut n = 0usize;
        for (&k, _) in keep.iter().zip(owned).filter(|(_, &o)| o) {
            if n.is_multiple_of(8) {
                packed.push(0u8);
            }
            if k {
                packed[n / 8] |= 1 << (n % 8);
            }
            n += 1;
        }
        WindowKeep {
            q: q as u64,
            owned: n,
            packed,
            kept,
            bounds,
            per_input: per,
        }
    }

    fn put(&self, w: &mut Writer) {
        w.u64(self.q);
        w.u64(self.owned as u64);
        w.bytes(&self.packed);
        w.u64(self.kept as u64);
        for v in self.bounds.min.iter().chain(&self.bounds.max) {
            w.f64(*v);
        }
        w.u64s(self.per_input.iter().copied());
    }

    /// Read back (and checked against the run's points and inputs).
    fn get(r: &mut Reader, run: &Run) -> Result<WindowKeep> {
        let q = r.u64()?;
        let owned = r.usize(run.plan.points, "owned points")?;
        let packed = r.bytes()?;
        if packed.len() != owned.div_ceil(8) {
            return Err(r.invalid("keep flags do not match the number of owned points"));
        }
        let kept = r.usize(owned, "kept points")?;
        let mut b = [0.0; 6];
        for v in &mut b {
            *v = r.f64()?;
        }
        let per_input = r.u64s()?;
        if per_input.len() != run.inputs.len() || per_input.iter().sum::<u64>() != owned as u64 {
            return Err(r.invalid("the flags per input do not match the inputs"));
        }
        Ok(WindowKeep {
            q,
            owned,
            packed,
            kept,
            bounds: Bounds {
                min: [b[0], b[1], b[2]],
                max: [b[3], b[4], b[5]],
            },
            per_input,
        })
    }
}

/// The result of `count`: noise removal's (failing, failing but coarse-passing, voxels)
/// per voxel height over the window's own points (none when `voxel_height` is given), then
/// the window filtered at voxel height steps 1 as a `keep` result holds it.
///
/// The filter at q = 1 is the answer unless more than the automatic height's budget fails
/// at that height over the whole survey (most surveys: `keep` then copies it and reads no
/// point); the counts are taken from the same sorted points for the other case, since a job
/// cannot wait for the other windows' counts to know whether it is needed.
fn job_count(run: &Run, k: usize) -> Result<Writer> {
    let mut w = Writer::default();
    let win = Windows::of(run)?;
    let own = win.as_ref().and_then(|w| w.own(run.place(k)));
    let (Some(win), Some(own)) = (win, own) else {
        w.u64s(std::iter::empty());
        WindowKeep::empty(run, 1).put(&mut w);
        return Ok(w);
    };
    let (xyz, owned, per) = win.gather(run, &own)?;
    let (counts, keep) = match win.input(run, &xyz, &own) {
        Some(input) if !xyz[0].is_empty() => {
            let (c, d) = denoise::shard_counts_and_denoise(&input)?;
            (c, WindowKeep::of(1, &d.keep, &owned, &xyz, per))
        }
        _ => (Vec::new(), WindowKeep::empty(run, 1)),
    };
    let flat: Vec<u64> = counts.iter().flatten().map(|&c| c as u64).collect();
    w.u64s(flat.into_iter());
    keep.put(&mut w);
    Ok(w)
}

/// The voxel height steps the windows' counts choose (all `count` results read).
fn chosen_steps(run: &Run) -> Result<u32> {
    let Some(params) = &run.stages.denoise else {
        return Ok(1);
    };
    let mut sums: Vec<[usize; 3]> = Vec::new();
    for k in 0..run.plan.jobs {
        let mut r = run.open_result(Phase::Count, k)?;
        let c = r.u64s()?;
        if c.len() % 3 != 0 {
            return Err(r.invalid("counts are not whole triples"));
        }
        // The window's filter at q = 1 follows (read by its own `keep` job).
        let c: Vec<[usize; 3]> = c
            .chunks_exact(3)
            .map(|t| [t[0] as usize, t[1] as usize, t[2] as usize])
            .collect();
        if sums.len() < c.len() {
            sums.resize(c.len(), [0; 3]);
        }
        for (acc, c) in sums.iter_mut().zip(&c) {
            for i in 0..3 {
                acc[i] += c[i];
            }
        }
    }
    Ok(denoise::choose_steps(params, &sums, run.plan.points))
}

/// The result of `keep`: the window's noise removal at the chosen voxel height
/// ([`WindowKeep`]). At q = 1 it is the one its `count` job wrote; otherwise the window's
/// points are read and filtered again at q.
fn job_keep(run: &Run, k: usize) -> Result<Writer> {
    let q = chosen_steps(run)?;
    let mut w = Writer::default();
    if q == 1 {
        let mut r = run.open_result(Phase::Count, k)?;
        r.u64s()?;
        let keep = WindowKeep::get(&mut r, run)?;
        r.end()?;
        if keep.q != 1 {
            return Err(r.invalid(format!("a filter at voxel height steps {}", keep.q)));
        }
        keep.put(&mut w);
        return Ok(w);
    }
    let win = Windows::of(run)?;
    let own = win.as_ref().and_then(|w| w.own(run.place(k)));
    let keep = match (win, own) {
        (Some(win), Some(own)) => {
            let (xyz, owned, per) = win.gather(run, &own)?;
            match win.input(run, &xyz, &own) {
                Some(input) if !xyz[0].is_empty() => {
                    let keep = denoise::shard_denoise(&input, q)?.keep;
                    WindowKeep::of(q, &keep, &owned, &xyz, per)
                }
                _ => WindowKeep {
                    per_input: per,
                    ..WindowKeep::empty(run, q)
                },
            }
        }
        _ => WindowKeep::empty(run, q),
    };
    keep.put(&mut w);
    Ok(w)
}

/// Every window's keep flags (None: noise removal off) and the kept points' bounds and
/// number: the reduction that fixes the grid.
struct Kept {
    flags: Option<Vec<(Vec<u8>, usize)>>,
    /// Per window, how many of its flags belong to each input.
    per_input: Vec<Vec<u64>>,
    bounds: Bounds,
    points: usize,
}

fn kept(run: &Run, with_flags: bool) -> Result<Kept> {
    if run.stages.denoise.is_none() {
        return Ok(Kept {
            flags: None,
            per_input: Vec::new(),
            bounds: run.plan.bounds(),
            points: run.plan.points,
        });
    }
    let mut flags = Vec::new();
    let mut per_input = Vec::new();
    let (mut bounds, mut points) = (Bounds::EMPTY, 0usize);
    for k in 0..run.plan.jobs {
        let mut r = run.open_result(Phase::Keep, k)?;
        let wk = WindowKeep::get(&mut r, run)?;
        r.end()?;
        points += wk.kept;
        per_input.push(wk.per_input);
        bounds = bounds.union(wk.bounds);
        if with_flags {
            flags.push((wk.packed, wk.owned));
        }
    }
    Ok(Kept {
        flags: with_flags.then_some(flags),
        per_input,
        bounds,
        points,
    })
}

/// The grid and its shard layout, from the kept points' reduction.
fn grid(run: &Run, kept: &Kept) -> Result<(GridSpec, ShardLayout)> {
    if kept.points == 0 {
        return Err(Error::Data {
            stage: "resample",
            message: "no points to resample".into(),
        });
    }
    let spec = GridSpec::new(&run.stages.resample, &kept.bounds, kept.points)
        .map_err(|e| run.at_key(e))?;
    let samples = [spec.cols, spec.rows];
    let tiles = ShardLayout::new(samples, &run.stages.tiles, [1, 1])
        .map_err(|e| run.at_key(e))?
        .tiles;
    let block = [0, 1].map(|a| tiles[a].div_ceil(run.plan.shards[a]));
    let layout = ShardLayout::new(samples, &run.stages.tiles, block).map_err(|e| run.at_key(e))?;
    Ok((spec, layout))
}

/// The block of tiles job `k` computes (None: the grid has fewer blocks than jobs).
fn block_of(run: &Run, layout: &ShardLayout, k: usize) -> Option<Shard> {
    let [c, r] = run.place(k);
    let [sx, sy] = layout.shards();
    (c < sx && r < sy).then(|| layout.shard(r * sx + c))
}

/// The result of `prepare`: the block's region interpolated and its fill pyramid (as
/// [`prepare`] leaves them) and the coarse cells it owns.
fn job_prepare(run: &Run, k: usize) -> Result<Writer> {
    let kept = kept(run, true)?;
    let (spec, layout) = grid(run, &kept)?;
    let mut w = Writer::default();
    let Some(shard) = block_of(run, &layout, k) else {
        w.u64(0);
        return Ok(w);
    };
    let fill = run.stages.fill.as_ref();
    let (ci, cj) = (shard.input(&layout, 0, fill), shard.input(&layout, 1, fill));
    let win = Windows::of(run)?;
    // Each window's flags are taken in input order, as its `keep` job wrote them.
    let cursor = vec![0usize; run.plan.jobs];
    let mut xyz = [Vec::new(), Vec::new(), Vec::new()];
    let crs = run.input_crs()?;
    // The world range of the cells read, one cell wider on each side for rounding (the last
    // cell reaches to infinity: cells are clamped).
    let world = |r: &std::ops::Range<usize>, a: usize, n: usize| {
        [
            spec.corner[a] + (r.start as f64 - 1.0) * spec.cell_size[a],
            if r.end >= n {
                f64::INFINITY
            } else {
                spec.corner[a] + (r.end as f64 + 1.0) * spec.cell_size[a]
            },
        ]
    };
    let (wx, wy) = (world(&ci, 0, spec.cols), world(&cj, 1, spec.rows));
    // An input not read: each window's cursor passes over its flags of that input.
    let skip = |f: usize, cursor: &mut Vec<usize>| {
        for (c, per) in cursor.iter_mut().zip(&kept.per_input) {
            *c += per[f] as usize;
        }
    };
    let cursor = std::cell::RefCell::new(cursor);
    run.each_input_in(
        wx,
        wy,
        |f| skip(f, &mut cursor.borrow_mut()),
        |_, c: &PointCloud| {
            let mut cursor = cursor.borrow_mut();
            for i in 0..c.len() {
                if let (Some(win), Some(flags)) = (&win, &kept.flags) {
                    let [wx, wy] = win.owner(c.x[i], c.y[i]);
                    let j = wy * run.plan.shards[0] + wx;
                    let ((packed, n), at) = (&flags[j], cursor[j]);
                    if at >= *n {
                        return Err(Error::Usage(format!(
                            "{}: holds fewer keep flags than the inputs' points (inputs changed?)",
                            run.result(Phase::Keep, j).display()
                        )));
                    }
                    cursor[j] += 1;
                    if packed[at / 8] & (1 << (at % 8)) == 0 {
                        continue;
                    }
                }
                let (a, b) = spec.cell(c.x[i], c.y[i]);
                if ci.contains(&a) && cj.contains(&b) {
                    xyz[0].push(c.x[i]);
                    xyz[1].push(c.y[i]);
                    xyz[2].push(c.z[i]);
                }
            }
            Ok(())
        },
    )?;
    let cells = resample::resample_window(
        [&xyz[0], &xyz[1], &xyz[2]],
        None,
        &spec,
        [ci.clone(), cj.clone()],
        run.stages.resample.method,
        crs,
    );
    drop(xyz);
    let p =
        prepare(&layout, &shard, &cells, [ci.start, cj.start], fill).map_err(|e| run.at_key(e))?;
    w.u64(1);
    // The coarse cells first: every `finish` job reads them from every result, and only
    // its own block's prepared region after them.
    let coarse = p.coarse(&layout);
    w.u64s(coarse.iter().map(|c| c.0 as u64));
    w.f32s(coarse.iter().map(|c| c.1));
    write_prepared(&mut w, &p);
    Ok(w)
}

/// A block's coarse cells: (index into the layout's coarse grid, value).
type CoarseCells = Vec<(usize, f32)>;

/// A `prepare` result opened and read up to its prepared region: the block (None: no
/// block) and its coarse cells.
fn open_prepared(
    run: &Run,
    layout: &ShardLayout,
    k: usize,
) -> Result<(Reader, Option<Shard>, CoarseCells)> {
    let mut r = run.open_result(Phase::Prepare, k)?;
    let shard = block_of(run, layout, k);
    let present = r.usize(1, "block flag")? == 1;
    match shard.filter(|_| present) {
        Some(shard) => {
            let idx = r.u64s()?;
            let val = r.f32s()?;
            if idx.len() != val.len() {
                return Err(r.invalid("coarse cells and values differ in number"));
            }
            let coarse = idx.into_iter().map(|i| i as usize).zip(val).collect();
            Ok((r, Some(shard), coarse))
        }
        None if present => Err(r.invalid("a block where the layout has none")),
        None => {
            r.end()?;
            Ok((r, None, Vec::new()))
        }
    }
}

/// A `prepare` result read back: the prepared block (None: no block).
fn read_prepared(run: &Run, layout: &ShardLayout, k: usize) -> Result<Option<Prepared>> {
    let (mut r, shard, _) = open_prepared(run, layout, k)?;
    let Some(shard) = shard else {
        return Ok(None);
    };
    let p = read_prepared_from(&mut r, layout, shard, run.stages.fill.clone())?;
    r.end()?;
    Ok(Some(p))
}

/// The result of `finish`: the block's tiles, their d2 and vertical error as propagated
/// within the block, and its fill figures.
fn job_finish(run: &Run, k: usize) -> Result<Writer> {
    let kept = kept(run, false)?;
    let (_, layout) = grid(run, &kept)?;
    let fill = run.stages.fill.as_ref();
    let mut coarse = Vec::new();
    if is_smooth(fill) {
        let mut cells = Vec::new();
        for j in 0..run.plan.jobs {
            cells.extend(open_prepared(run, &layout, j)?.2);
        }
        coarse = complete_coarse(&layout, &cells)?;
    }
    let mut w = Writer::default();
    let Some(p) = read_prepared(run, &layout, k)? else {
        // No tiles, no fill figures.
        w.u64(0);
        w.u64(0);
        return Ok(w);
    };
    let out = finish(&layout, p, &coarse, &run.stages.tiles, &run.stages.quadtree)
        .map_err(|e| run.at_key(e))?;
    w.u64(out.tiles.len() as u64);
    for ((t, d), e) in out.tiles.iter().zip(&out.d2).zip(&out.vertical_error) {
        for v in [
            t.col,
            t.row,
            t.origin[0],
            t.origin[1],
            t.valid[0],
            t.valid[1],
        ] {
            w.u64(v as u64);
        }
        w.u64(t.holes as u64);
        let z: Vec<f32> = t.z_range.iter().flatten().copied().collect();
        w.f32s(z.into_iter());
        w.f32s(t.heights.iter().copied());
        for v in [d, e] {
            let k = (v.size() - 1).trailing_zeros();
            for m in 1..=k {
                w.f32s(v.level(m).iter().copied());
            }
        }
    }
    match out.fill {
        Some(f) => {
            w.u64(1);
            for v in [f.measured, f.interpolated, f.fallback, f.empty] {
                w.u64(v as u64);
            }
        }
        None => w.u64(0),
    }
    Ok(w)
}

fn read_output(run: &Run, layout: &ShardLayout, k: usize) -> Result<Option<ShardOutput>> {
    let mut r = run.open_result(Phase::Finish, k)?;
    let n = r.usize(layout.tiles[0] * layout.tiles[1], "tiles")?;
    let t = layout.tile_size;
    let levels = (t - 1).trailing_zeros();
    let mut out = ShardOutput {
        tiles: Vec::with_capacity(n),
        d2: Vec::with_capacity(n),
        vertical_error: Vec::with_capacity(n),
        fill: None,
    };
    // Indices, origins and extents are within the grid; holes within a tile.
    let max = layout.samples[0].max(layout.samples[1]) + t * t;
    for _ in 0..n {
        let mut f = [0usize; 7];
        for v in &mut f {
            *v = r.usize(max, "tile figure")?;
        }
        let z = r.f32s()?;
        let z_range = match z[..] {
            [] => None,
            [lo, hi] => Some([lo, hi]),
            _ => return Err(r.invalid("a height range of neither 0 nor 2 values")),
        };
        let heights = r.f32s()?;
        let heights = Array2::from_shape_vec((t, t), heights)
            .map_err(|_| r.invalid("tile heights do not fit the tile size"))?;
        let mut node = || -> Result<NodeValues> {
            let lv = (0..levels).map(|_| r.f32s()).collect::<Result<Vec<_>>>()?;
            NodeValues::from_levels(t, lv).ok_or_else(|| r.invalid("node values of another size"))
        };
        let (d, e) = (node()?, node()?);
        out.tiles.push(Tile {
            col: f[0],
            row: f[1],
            origin: [f[2], f[3]],
            valid: [f[4], f[5]],
            heights,
            holes: f[6],
            z_range,
        });
        out.d2.push(d);
        out.vertical_error.push(e);
    }
    if r.usize(1, "fill flag")? == 1 {
        let mut v = [0usize; 4];
        for x in &mut v {
            *x = r.usize(usize::MAX, "fill figure")?;
        }
        out.fill = Some(FillReport {
            measured: v[0],
            interpolated: v[1],
            fallback: v[2],
            empty: v[3],
        });
    }
    r.end()?;
    Ok((n > 0 || out.fill.is_some()).then_some(out))
}

/// The job index from `--index`, else `SLURM_ARRAY_TASK_ID`, else `JOB_COMPLETION_INDEX`
/// (Kubernetes Indexed Jobs).
pub fn job_index(given: Option<usize>) -> Result<usize> {
    if let Some(i) = given {
        return Ok(i);
    }
    for var in ["SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX"] {
        if let Ok(v) = std::env::var(var) {
            return v.trim().parse().map_err(|_| {
                Error::Usage(format!("{var} = {}: not a job index", crate::one_line(&v)))
            });
        }
    }
    Err(Error::Usage(
        "no job index: give --index, or run under a Slurm array (SLURM_ARRAY_TASK_ID) or a \
         Kubernetes Indexed Job (JOB_COMPLETION_INDEX)"
            .into(),
    ))
}

/// `terratile shard`: runs job `index` of `phase` under the plan at `at` (its work
/// directory or plan file) and writes its result; returns the result's path.
pub fn shard(at: &Path, phase: Phase, index: usize) -> Result<PathBuf> {
    let run = Run::open(at)?;
    if index >= run.plan.jobs {
        return Err(Error::Usage(format!(
            "--index {index}: the plan {} has jobs 0 to {}",
            run.dir.join(PLAN_FILE).display(),
            run.plan.jobs - 1
        )));
    }
    let w = match phase {
        Phase::Count => job_count(&run, index)?,
        Phase::Keep => job_keep(&run, index)?,
        Phase::Prepare => job_prepare(&run, index)?,
        Phase::Finish => job_finish(&run, index)?,
    };
    run.save(phase, index, w)?;
    Ok(run.result(phase, index))
}

/// What `terratile merge` did.
#[derive(Debug, Serialize)]
pub struct MergeSummary {
    /// The output directory.
    pub output: PathBuf,
    /// Tiles (columns, rows).
    pub tiles: [usize; 2],
    /// Files written, relative to the output directory.
    pub files: Vec<String>,
}

/// `terratile merge`: the shards' tiles put together, d2 and the vertical error finished
/// across their borders, then meshes and every output as `terratile run` writes them, into
/// a staged directory that replaces the output only when all is written.
pub fn merge_run(at: &Path) -> Result<MergeSummary> {
    let run = Run::open(at)?;
    let checked = crate::pipeline::Plan::new(&run.pipeline)?;
    let kept = kept(&run, false)?;
    let (spec, layout) = grid(&run, &kept)?;
    let mut outputs = Vec::new();
    for k in 0..run.plan.jobs {
        if let Some(o) = read_output(&run, &layout, k)? {
            outputs.push(o);
        }
    }
    let crs = run.input_crs()?;
    let geo = Heightfield::empty(1, 1, spec.corner, spec.cell_size, spec.z_offset, crs);
    let cfg = &run.pipeline.config;
    let staged = checked.stage_output_dir()?;
    let merged = merge(&layout, &geo, &cfg.tiles, &cfg.quadtree, outputs)?;
    let mut set = merged.set;
    crate::pipeline::with_input_crs(cfg, &mut set);
    // The in-memory run's own product stages (extract, writers, the Cesium tileset).
    let done = crate::pipeline::product_stages(
        cfg,
        set,
        merged.quadtree,
        Vec::new(),
        staged.path(),
        &NoProgress,
    )?;
    let (set, files) = (done.set, done.files);
    let output = staged.commit()?;
    Ok(MergeSummary {
        output,
        tiles: set.grid,
        files,
    })
}
