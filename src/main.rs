//! The `terratile` command: parses arguments (clap), draws progress (indicatif), prints one
//! line per error and exits 2 on bad input, 1 on internal failure. All work is in the library.

use clap::{Args, Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Mutex;
use terratile::points::{self, ClassFilter, Format, ReadOptions};
use terratile::Progress;
use terratile::{one_line, Error, Result};

/// `print!` that survives a reader going away: `terratile … | head -1` closes the pipe, and
/// `print!` would panic on the broken pipe. Here the process ends quietly with success, as a
/// Unix filter does; any other failure to write standard output is one error line, exit 1.
macro_rules! out {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        if let Err(e) = write!(std::io::stdout().lock(), $($arg)*) {
            stdout_failed(e);
        }
    }};
}

/// `println!` with [`out!`]'s handling of a closed pipe.
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        if let Err(e) = writeln!(std::io::stdout().lock(), $($arg)*) {
            stdout_failed(e);
        }
    }};
}

fn stdout_failed(e: std::io::Error) -> ! {
    if e.kind() == std::io::ErrorKind::BrokenPipe {
        std::process::exit(0);
    }
    eprintln!(
        "terratile: writing to standard output: {}",
        one_line(&e.to_string())
    );
    std::process::exit(1);
}

/// terratile: airborne LIDAR point clouds to crack-free tiled terrain for game engines.
#[derive(Parser, Debug)]
#[command(name = "terratile", version, about, long_about = None)]
struct Cli {
    /// Worker threads (default: one per core).
    #[arg(long, global = true, value_name = "N")]
    threads: Option<usize>,
    /// No progress bars (results, warnings and errors are still printed).
    #[arg(long, short, global = true)]
    quiet: bool,
    /// Memory budget, e.g. 8GiB (default: half of physical memory).
    #[arg(long, global = true, value_name = "SIZE", value_parser = terratile::parse_size)]
    max_memory: Option<u64>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run a pipeline file (default ./pipeline.toml).
    Run {
        /// The pipeline file.
        #[arg(default_value = "pipeline.toml")]
        pipeline: PathBuf,
        /// Print the run summary as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Describe point cloud files: format, counts, bounds, CRS, classes, returns, spacing.
    Info {
        /// LAS, LAZ or XYZ files.
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Print JSON (one array) instead of text.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        read: ReadArgs,
    },
    /// Generate a synthetic airborne-LIDAR survey (terrain, ridge, cliff, buildings, trees,
    /// a lake hole, scan-line density, outliers).
    Generate(GenerateArgs),
    /// Convert LAS/LAZ to uncompressed LAS, optionally cut to N points (first N or a seeded
    /// random sample); records pass through unchanged. With --copc, writes COPC 1.0
    /// (cloud-optimised LAZ, point format 6/7/8) instead.
    Convert {
        /// Input LAS or LAZ.
        input: PathBuf,
        /// Output LAS (with --copc: a COPC file, named .copc.laz).
        output: PathBuf,
        /// Write COPC 1.0: LAZ 1.4 in octree nodes, readable by bounds.
        #[arg(long)]
        copc: bool,
        /// Keep only the first N points.
        #[arg(long, value_name = "N", conflicts_with = "sample")]
        first: Option<u64>,
        /// Keep a random sample of N points (file order kept).
        #[arg(long, value_name = "N")]
        sample: Option<u64>,
        /// Seed of the sample.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Classify the ground points of a LAS/LAZ file (SMRF) and write it as LAS with class 2
    /// (ground) / 1 (other); prints the counts and the time.
    Classify(ClassifyArgs),
    /// Measure terratile against references in the same process.
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Simplify a mesh (OBJ or PLY) by vertex clustering; prints triangles in/out, the time
    /// and the Hausdorff error against the input.
    Simplify(SimplifyArgs),
    /// Progressive triangle strips: `strips IN OUT.tps` builds a stream (base mesh plus
    /// vertex splits); `strips decode IN.tps --level L OUT` writes the mesh of a level.
    Strips(StripsArgs),
    /// Measure the Metro-style Hausdorff error between two meshes (OBJ or PLY): both
    /// one-sided errors and the symmetric one, max and mean, absolute and in % of the
    /// original's bounding-box diagonal.
    Compare(CompareArgs),
    /// Per-vertex curvature, mesh saliency, multi-view image saliency (max, min, mean) and
    /// the hybrid saliency of a mesh, written to DIR as saliency.ply (one float property
    /// per map, hybrid-coloured vertices) and one PNG per map (front and back, colour bar).
    Saliency {
        /// The mesh (.obj, .ply or .glb).
        input: PathBuf,
        /// The output directory (must not exist or be empty).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// N: the camera angles 2πk/N in both directions (default 36).
        #[arg(long, value_name = "N", default_value_t = 36)]
        views: u32,
        /// Rendered image side for the image saliency, in pixels.
        #[arg(long, value_name = "PX", default_value_t = 256)]
        view_size: u32,
        /// Side of each view in the PNG pictures, in pixels.
        #[arg(long, value_name = "PX", default_value_t = 512)]
        picture_size: u32,
        /// A texture (PNG) baked into the vertex colours at each vertex's UV before the
        /// image saliency renders the mesh.
        #[arg(long, value_name = "PNG")]
        texture: Option<PathBuf>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Plan a sharded run for any job engine: checks the pipeline, counts the inputs'
    /// points and writes DIR/plan.json (see `shard` and `merge`, and docs/scale.md).
    Plan {
        /// The pipeline file.
        pipeline: PathBuf,
        /// The work directory (created; shared by every job of the run).
        #[arg(long, visible_alias = "work", value_name = "DIR")]
        out: PathBuf,
        /// Jobs per phase (the largest sx × sy grid of shards within N).
        #[arg(long, value_name = "N", default_value_t = 4)]
        shards: usize,
        /// Print the plan as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Run one job of a planned sharded run: phase count, keep, prepare or finish, job index
    /// from --index, SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX.
    Shard {
        /// The work directory (or its plan.json).
        plan: PathBuf,
        /// The phase: count, keep, prepare or finish (in this order, each phase after all
        /// jobs of the one before).
        #[arg(long)]
        phase: String,
        /// The job index, 0 to jobs − 1.
        #[arg(long, visible_alias = "id", value_name = "K")]
        index: Option<usize>,
    },
    /// Merge a sharded run (after every finish job): writes the outputs `run` writes.
    Merge {
        /// The work directory (or its plan.json).
        plan: PathBuf,
        /// Print the summary as JSON.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
struct StripsArgs {
    #[command(subcommand)]
    decode: Option<StripsCommand>,
    /// The mesh (OBJ, PLY or glb).
    #[arg(required = true)]
    input: Option<PathBuf>,
    /// The stream to write (.tps).
    #[arg(required = true)]
    output: Option<PathBuf>,
    /// The base mesh's share of the triangles, in (0, 1).
    #[arg(long, default_value_t = 0.05)]
    base_ratio: f64,
    /// The form of the split records.
    #[arg(long, value_enum, default_value = "encoded")]
    encoding: EncodingArg,
    /// The full strip's order: `hierarchical` (from the base mesh up) or `paper` (the full
    /// mesh stripified on its own, as the progressive-strips paper).
    #[arg(long, value_enum, default_value = "hierarchical")]
    order: OrderArg,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
enum OrderArg {
    Hierarchical,
    Paper,
}

#[derive(clap::Subcommand, Debug)]
enum StripsCommand {
    /// Write the mesh of one level of a stream (OBJ or PLY by the extension; .glb: one
    /// TRIANGLE_STRIP primitive).
    Decode {
        /// The stream (.tps).
        input: PathBuf,
        /// Splits to apply: 0 for the base mesh, `full` for all.
        #[arg(long)]
        level: String,
        /// The mesh to write.
        output: PathBuf,
    },
}

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
enum EncodingArg {
    Naive,
    Encoded,
}

#[derive(Args, Debug)]
struct CompareArgs {
    /// The original mesh.
    original: PathBuf,
    /// The simplified mesh.
    simplified: PathBuf,
    /// Area samples per direction (default: 10 per triangle, at least 200,000; at most
    /// 100,000,000).
    #[arg(long, value_name = "N")]
    samples: Option<u64>,
    /// Also render the original coloured by each vertex's distance to the simplified
    /// surface (blue 0 → red at the 99th percentile), front and back, into this new PNG.
    #[arg(long, value_name = "OUT.png")]
    heatmap: Option<PathBuf>,
    /// Refuse files that are read with a warning by default (unusable texture
    /// coordinates, normals or colours; faces with fewer than 3 vertices).
    #[arg(long)]
    strict: bool,
    /// Also count fold-overs (simplified faces more than 90° from the original's
    /// normal at the nearest point) and self-intersecting faces (non-adjacent pairs
    /// that meet, exact predicates), and the original's own self-intersections.
    #[arg(long)]
    check_folds: bool,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

#[derive(Args, Debug)]
#[command(group(clap::ArgGroup::new("target").required(true).multiple(true).args(["ratio", "triangles", "cell_size", "threshold", "max_error"])))]
struct SimplifyArgs {
    /// Input mesh (.obj or .ply).
    input: PathBuf,
    /// Output mesh (.obj, or .ply for binary PLY).
    output: PathBuf,
    /// Clustering method, or `qem` for quadric edge collapse.
    #[arg(long, value_enum, default_value = "octree")]
    method: MethodArg,
    /// QEM: vertex placement (default optimal).
    #[arg(long, value_enum)]
    placement: Option<PlacementArg>,
    /// QEM: merge the endpoints' quadrics by their sum (default) or mean.
    #[arg(long, value_enum)]
    quadric_merge: Option<MergeArg>,
    /// QEM: never move a border vertex.
    #[arg(long)]
    lock_border: bool,
    /// QEM: refuse every collapse after which a moved face would intersect a face it
    /// shares no vertex with (exact predicates through a box hierarchy).
    #[arg(long)]
    check_intersections: bool,
    /// QEM: also contract vertex pairs closer than D (model units) that share no edge,
    /// joining separate parts (default 0: off).
    #[arg(long, value_name = "D", allow_negative_numbers = true)]
    pair_distance: Option<f64>,
    /// QEM: collapse across UV seams and colour/normal discontinuities (default: keep them).
    #[arg(long)]
    collapse_seams: bool,
    /// QEM: weight the cost by saliency: none (default), mesh, image or hybrid.
    #[arg(long, value_enum)]
    saliency: Option<SaliencyArg>,
    /// QEM with saliency: the least weight H, in (0, 1] (default 0.02).
    #[arg(long, value_name = "H", allow_negative_numbers = true)]
    h_min: Option<f64>,
    /// QEM with saliency: how the weights enter: quadric (default; Lee et al.'s weighted
    /// quadrics) or cost (An's thesis: the cost times the mean weight).
    #[arg(long, value_enum)]
    saliency_rule: Option<SaliencyRuleArg>,
    /// QEM with image or hybrid saliency: N, the camera angles 2πk/N (default 36).
    #[arg(long, value_name = "N")]
    views: Option<u32>,
    /// QEM with image or hybrid saliency: rendered image side in pixels (default 256).
    #[arg(long, value_name = "PX")]
    view_size: Option<u32>,
    /// QEM: accept no collapse with a larger error: model units, or `P%` of the bbox diagonal.
    #[arg(long, value_name = "E", allow_hyphen_values = true)]
    max_error: Option<String>,
    /// QEM: order the collapses by a heap (default; the exact greedy order) or in passes
    /// (as meshoptimizer: faster, a larger max error on some meshes).
    #[arg(long, value_enum)]
    engine: Option<EngineArg>,
    /// Keep this fraction of the triangles, in (0, 1].
    #[arg(long, value_name = "R", allow_negative_numbers = true)]
    ratio: Option<f64>,
    /// Keep about this many triangles.
    #[arg(long, value_name = "T")]
    triangles: Option<u64>,
    /// Uniform/floating: cell edge length in model units.
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    cell_size: Option<f64>,
    /// Octree: split cells scoring above this (area × Dv × normal variation, model units³).
    #[arg(long, value_name = "T", allow_negative_numbers = true)]
    threshold: Option<f64>,
    /// Where each cluster's vertex goes (default quadric).
    #[arg(long, value_enum)]
    representative: Option<RepresentativeArg>,
    /// Octree: cells FACTOR (default 4) times smaller in XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX[,FACTOR] (repeatable).
    #[arg(long, value_name = "BOX", value_parser = parse_refine_box)]
    refine: Vec<terratile::simplify::RefineBox>,
    /// Leave clusters that keep no triangle as they are (thin parts may vanish) instead of
    /// cutting them in two.
    #[arg(long)]
    no_split_stranded: bool,
    /// Area samples per direction for the error (default: 10 per triangle, at least 200,000;
    /// at most 100,000,000).
    #[arg(long, value_name = "N")]
    samples: Option<u64>,
    /// Refuse an input that is read with a warning by default (unusable texture coordinates,
    /// normals or colours; faces with fewer than 3 vertices).
    #[arg(long)]
    strict: bool,
    /// Do not measure the error.
    #[arg(long)]
    no_error: bool,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
enum MethodArg {
    Uniform,
    Floating,
    Octree,
    Qem,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
enum SaliencyArg {
    None,
    Mesh,
    Image,
    Hybrid,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
enum SaliencyRuleArg {
    Quadric,
    Cost,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
enum PlacementArg {
    Optimal,
    Endpoint,
    TwoLocalMappings,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
enum EngineArg {
    Passes,
    Heap,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
enum MergeArg {
    Sum,
    Mean,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
enum RepresentativeArg {
    Centroid,
    Important,
    Quadric,
}

fn parse_refine_box(s: &str) -> std::result::Result<terratile::simplify::RefineBox, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| {
            x.trim()
                .parse::<f64>()
                .map_err(|_| format!("`{}` is not a number", one_line(x)))
        })
        .collect::<std::result::Result<_, _>>()?;
    if v.len() != 6 && v.len() != 7 {
        return Err(format!(
            "`{}`: expected XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX[,FACTOR]",
            one_line(s)
        ));
    }
    Ok(terratile::simplify::RefineBox {
        min: [v[0], v[1], v[2]],
        max: [v[3], v[4], v[5]],
        factor: v.get(6).copied().unwrap_or(4.0),
    })
}

#[derive(Subcommand, Debug)]
enum BenchCommand {
    /// Time decoding FILE against a plain parallel copy of its bytes from a fresh map.
    Read {
        /// The file (LAS, LAZ or XYZ).
        file: PathBuf,
        /// Repetitions (the median is reported).
        #[arg(long, default_value_t = 5)]
        repeat: usize,
        /// Also time las::Reader on the same file.
        #[arg(long)]
        las_rs: bool,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Time read, denoise, resample and fill on FILE against spade's Delaunay triangulation
    /// of the same denoised points (bulk loading and incremental insertion), with the peak
    /// memory of each side; then tiles, quadtree and writing the tiles (the whole pipeline).
    Terrain {
        /// The file (LAS, LAZ or XYZ).
        file: PathBuf,
        /// Repetitions (the median is reported).
        #[arg(long, default_value_t = 3)]
        repeat: usize,
        /// Print JSON (`stages_ratio` = Delaunay time / (denoise + resample + fill) time;
        /// `total_ratio` = Delaunay time / whole pipeline from file to written tiles).
        #[arg(long)]
        json: bool,
    },
    /// The paper's Table 1 on FILE: for each count, a seeded random subset timed through the
    /// grid pipeline and spade's Delaunay build (interleaved, median of --repeat), with
    /// memory, triangle counts and the RMSE of both surfaces at 2 % held-out points.
    Table1 {
        /// The survey (LAS, LAZ or XYZ).
        file: PathBuf,
        /// Point counts, comma-separated (default: the paper's 34379,430674,1626972,3408187).
        #[arg(long, value_delimiter = ',', value_parser = parse_count)]
        counts: Option<Vec<u64>>,
        /// Repetitions (the median is reported; at least 3 for the table).
        #[arg(long, default_value_t = 3)]
        repeat: usize,
        /// Seed of the subsets and the hold-out.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Print the rows as JSON instead of the markdown table.
        #[arg(long)]
        json: bool,
        /// Also draw time against points, log–log, into this PNG.
        #[arg(long, value_name = "FILE.png")]
        plot: Option<PathBuf>,
    },
    /// The streaming run against the in-memory run on generated surveys (tiles of at most
    /// 10 M points in a temporary directory): wall time, points/s, peak RSS, identical bytes.
    Scale {
        /// Survey sizes in points (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "10000000,100000000", value_parser = parse_count)]
        points: Vec<u64>,
        /// Memory budget of the streaming run.
        #[arg(long, default_value = "1GiB")]
        budget: String,
        /// Where the temporary surveys go (default: the system's temporary directory).
        #[arg(long)]
        dir: Option<PathBuf>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// (Internal: one memory measurement of `table1`, run in a fresh process.)
    #[command(hide = true)]
    Table1Memory {
        file: PathBuf,
        #[arg(long)]
        count: u64,
        #[arg(long)]
        seed: u64,
        #[arg(long)]
        method: String,
    },
}

/// A `--counts` entry: a positive whole number.
fn parse_count(s: &str) -> std::result::Result<u64, String> {
    match s.trim().parse::<u64>() {
        Ok(0) => Err("0 is not a point count".into()),
        Ok(n) => Ok(n),
        Err(_) => Err(format!(
            "`{}` is not a point count (a whole number such as 430674)",
            one_line(s)
        )),
    }
}

#[derive(Args, Debug, Clone)]
struct ReadArgs {
    /// Keep only these classes (comma-separated, e.g. 2).
    #[arg(long, value_delimiter = ',', value_name = "CLASSES")]
    keep_classes: Option<Vec<u8>>,
    /// Drop these classes (comma-separated, e.g. 7,18).
    #[arg(long, value_delimiter = ',', value_name = "CLASSES")]
    drop_classes: Vec<u8>,
    /// Read at most N points.
    #[arg(long, value_name = "N")]
    max_points: Option<u64>,
    /// Force the input format instead of recognising it.
    #[arg(long, value_enum)]
    format: Option<FormatArg>,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
enum FormatArg {
    Las,
    Laz,
    Xyz,
}

impl ReadArgs {
    fn options(&self) -> ReadOptions {
        ReadOptions {
            format: self.format.map(|f| match f {
                FormatArg::Las => Format::Las,
                FormatArg::Laz => Format::Laz,
                FormatArg::Xyz => Format::Xyz,
            }),
            classes: ClassFilter::new(self.keep_classes.as_deref(), &self.drop_classes),
            max_points: self.max_points,
            ..Default::default()
        }
    }
}

#[derive(Args, Debug)]
struct GenerateArgs {
    /// Output file (.las or .xyz); with --tiles, files NAME-C-R.ext beside it.
    #[arg(short, long)]
    output: PathBuf,
    /// Seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Exact number of points.
    #[arg(long, default_value_t = 100_000)]
    points: u64,
    /// Scene size in metres, WIDTHxHEIGHT (default: sized for 1.5 points/m²).
    #[arg(long, value_parser = parse_pair::<f64>)]
    size: Option<(f64, f64)>,
    /// Split into COLSxROWS tiles.
    #[arg(long, value_parser = parse_pair::<usize>, default_value = "1x1")]
    tiles: (usize, usize),
    /// Output format(s), cycled over the tiles: las, xyz or e.g. las,xyz (default: from the
    /// output's extension, `.xyz` for XYZ text, LAS otherwise).
    #[arg(long, value_delimiter = ',')]
    format: Vec<GenFormat>,
    /// Outliers per million points.
    #[arg(long, default_value_t = 60)]
    outliers_per_million: u32,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
enum GenFormat {
    Las,
    Xyz,
}

fn parse_pair<T: std::str::FromStr>(s: &str) -> std::result::Result<(T, T), String> {
    let (a, b) = s
        .split_once(['x', 'X', ','])
        .ok_or_else(|| format!("`{}`: expected AxB", one_line(s)))?;
    let p = |v: &str| {
        v.trim()
            .parse::<T>()
            .map_err(|_| format!("`{}`: `{}` is not a number", one_line(s), one_line(v)))
    };
    Ok((p(a)?, p(b)?))
}

/// indicatif bars behind the library's `Progress`; hidden when quiet or not on a terminal.
struct Bars {
    bar: Mutex<Option<ProgressBar>>,
    quiet: bool,
}

impl Bars {
    fn new(quiet: bool) -> Bars {
        Bars {
            bar: Mutex::new(None),
            quiet,
        }
    }
}

impl Progress for Bars {
    fn start(&self, label: &str, total: u64) {
        if self.quiet {
            return;
        }
        let bar = if total > 0 {
            ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr())
        } else {
            ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr())
        };
        let style =
            ProgressStyle::with_template("{msg:40} [{elapsed_precise}] {wide_bar} {percent:>3}%")
                .unwrap_or_else(|_| ProgressStyle::default_bar());
        bar.set_style(style);
        bar.set_message(terratile::bar_label(label, 40));
        if let Ok(mut b) = self.bar.lock() {
            *b = Some(bar);
        }
    }
    fn advance(&self, n: u64) {
        if let Ok(b) = self.bar.lock() {
            if let Some(b) = b.as_ref() {
                b.inc(n);
            }
        }
    }
    fn finish(&self) {
        if let Ok(mut b) = self.bar.lock() {
            if let Some(b) = b.take() {
                b.finish_and_clear();
            }
        }
    }
}

/// `terratile classify` arguments.
#[derive(clap::Args, Debug)]
struct ClassifyArgs {
    /// Input LAS, LAZ (or XYZ, without OUT).
    input: PathBuf,
    /// Output LAS (a new file): the input's records with class 2 / 1.
    output: Option<PathBuf>,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
    /// Score against the file's own class 2: type I, type II, total error, kappa.
    #[arg(long)]
    score: bool,
    /// Cell edge, metres (default: 1, or a quarter of the point spacing when larger).
    #[arg(long, value_name = "M")]
    cell_size: Option<f64>,
    /// Largest window radius, metres (default 18).
    #[arg(long, value_name = "M")]
    window: Option<f64>,
    /// Slope tolerance, rise over run (default 0.2).
    #[arg(long)]
    slope: Option<f64>,
    /// Hysteresis slope: an object region needs a cell cut this steeply (default 0.5).
    #[arg(long)]
    sure_slope: Option<f64>,
    /// Elevation threshold, metres (default 0.5).
    #[arg(long, value_name = "M")]
    threshold: Option<f64>,
    /// Elevation scalar, metres per unit slope (default 1.25).
    #[arg(long, value_name = "M")]
    scalar: Option<f64>,
    /// Empty cells within this many point spacings take the nearest height before the
    /// openings (default 1; 0: off).
    #[arg(long, value_name = "SPACINGS")]
    gap_fill: Option<f64>,
    /// Radius of the crest test, point spacings (default 1.5; 0: off).
    #[arg(long, value_name = "SPACINGS")]
    support_radius: Option<f64>,
    /// Height tolerance of a supporting ground cell, metres (default 0.3).
    #[arg(long, value_name = "M")]
    support_tolerance: Option<f64>,
    /// Tolerance added per metre of distance to the supporting cell (default 0.2).
    #[arg(long)]
    support_slope: Option<f64>,
    /// Reach of the openings past the grid's edge, share of the window (default 0).
    #[arg(long)]
    edge_reach: Option<f64>,
    /// Radius of the last step's plane fit, point spacings (default 2.5; 0: off).
    #[arg(long, value_name = "SPACINGS")]
    plane_radius: Option<f64>,
    /// Height above that plane that makes a point an object, metres (default 0.25).
    #[arg(long, value_name = "M")]
    plane_threshold: Option<f64>,
    /// Tolerance added per metre of the plane's RMS misfit (default 2).
    #[arg(long)]
    plane_rms: Option<f64>,
    /// Tolerance added per unit of the plane's slope, point spacings (default 0.15).
    #[arg(long, value_name = "SPACINGS")]
    plane_slope: Option<f64>,
    /// Rounds of the plane step (default 2).
    #[arg(long, value_name = "N")]
    plane_rounds: Option<usize>,
}

fn classify(a: ClassifyArgs, progress: &dyn Progress) -> Result<()> {
    let params = terratile::terrain::ground::GroundParams {
        enabled: true,
        cell_size: a.cell_size,
        window: a.window,
        slope: a.slope,
        sure_slope: a.sure_slope,
        threshold: a.threshold,
        scalar: a.scalar,
        gap_fill: a.gap_fill,
        support_radius: a.support_radius,
        support_tolerance: a.support_tolerance,
        support_slope: a.support_slope,
        edge_reach: a.edge_reach,
        plane_radius: a.plane_radius,
        plane_threshold: a.plane_threshold,
        plane_rms: a.plane_rms,
        plane_slope: a.plane_slope,
        plane_rounds: a.plane_rounds,
        ..Default::default()
    };
    if let Some(o) = &a.output {
        terratile::remove_stale_temps(o);
    }
    let r = terratile::classify::classify_file(
        &a.input,
        a.output.as_deref(),
        &params,
        a.score,
        progress,
    )?;
    if a.json {
        return print_json(&r);
    }
    outln!(
        "{}: {} points, {} ground ({:.1} %), {:.3} s",
        a.input.display(),
        r.points,
        r.ground,
        100.0 * r.ground as f64 / r.points.max(1) as f64,
        r.seconds
    );
    if let Some(s) = r.score {
        outln!(
            "type I {:.2} %  type II {:.2} %  total {:.2} %  kappa {:.2} %",
            100.0 * s.type1,
            100.0 * s.type2,
            100.0 * s.total,
            100.0 * s.kappa
        );
    }
    if let Some(o) = r.output {
        outln!("{}: written", o.display());
    }
    Ok(())
}

fn print_json<T: serde::Serialize>(v: &T) -> Result<()> {
    let s = serde_json::to_string_pretty(v).map_err(|e| Error::Internal(e.to_string()))?;
    outln!("{s}");
    Ok(())
}

/// A command's report: its JSON with `--json`, else its text (which ends with its newline).
fn print_report<T: serde::Serialize + std::fmt::Display>(json: bool, r: &T) -> Result<()> {
    if json {
        print_json(r)
    } else {
        out!("{r}");
        Ok(())
    }
}

/// The process-wide effects of the global options: the memory budget and the worker threads
/// (refused outside 1 to `memory::max_threads`), and the clean-up of this process's files on
/// SIGINT/SIGTERM.
fn configure(max_memory: Option<u64>, threads: Option<usize>) -> Result<()> {
    if let Some(m) = max_memory {
        terratile::set_budget(m);
    }
    if let Some(n) = threads {
        if n == 0 {
            return Err(Error::Usage("--threads must be at least 1".into()));
        }
        let max = terratile::max_threads();
        if n > max {
            return Err(Error::Usage(format!(
                "--threads {n}: at most {max} (eight per core of this machine, at least 64)"
            )));
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .map_err(|e| Error::Internal(e.to_string()))?;
    }
    // SIGINT/SIGTERM remove this process's staging and temporary files, then exit 130/143.
    terratile::clean_up_on_signals()
}

/// One memory figure of `bench table1`: a fresh process runs `bench table1-memory` for one
/// method at `count` points of `file`, so that its peak is that method's alone.
fn table1_memory_probe(
    file: &std::path::Path,
    seed: u64,
    count: u64,
    method: &str,
) -> Result<Option<f64>> {
    let exe = std::env::current_exe().map_err(|e| Error::Internal(e.to_string()))?;
    let out = std::process::Command::new(exe)
        .args(["bench", "table1-memory", "--count", &count.to_string()])
        .args(["--seed", &seed.to_string(), "--method", method])
        .arg(file)
        .output()
        .map_err(|e| Error::Internal(format!("memory probe: {e}")))?;
    if !out.status.success() {
        return Err(Error::Internal(format!(
            "memory probe: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    Ok(String::from_utf8_lossy(&out.stdout)
        .trim()
        .parse::<f64>()
        .ok())
}

fn run(cli: Cli) -> Result<()> {
    configure(cli.max_memory, cli.threads)?;
    let bars = Bars::new(cli.quiet);
    let progress: &dyn Progress = &bars;
    match cli.command {
        Command::Run { pipeline, json } => {
            let loaded = terratile::config::load(&pipeline)?;
            let summary = terratile::pipeline::run(&loaded, progress)?;
            print_report(json, &summary)?;
        }
        Command::Info { files, json, read } => {
            let opts = read.options();
            let mut infos = Vec::new();
            for f in &files {
                infos.push(points::FileInfo::of(f, &opts, progress)?);
            }
            if json {
                print_json(&infos)?;
            } else {
                for i in &infos {
                    out!("{i}");
                }
            }
        }
        Command::Generate(g) => {
            progress.start("generating", 0);
            let r = generate(&g);
            progress.finish();
            r?
        }
        Command::Convert {
            input,
            output,
            first,
            sample,
            seed,
            copc,
        } => {
            let sel = match (first, sample) {
                (Some(n), _) => points::Selection::First(n),
                (None, Some(n)) => points::Selection::Sample { n, seed },
                (None, None) => points::Selection::All,
            };
            terratile::check_file_output(&output, &[&input])?;
            if copc {
                refuse_non_laz_name(&output)?;
            } else {
                refuse_laz_name(&output)?;
            }
            // `.NAME.tmp-PID` files that killed runs left beside the output.
            terratile::remove_stale_temps(&output);
            progress.start(&format!("converting {}", input.display()), 0);
            if copc {
                let w = points::convert_copc(&input, &output, sel);
                progress.finish();
                let w = w?;
                outln!(
                    "{}: {} points, COPC point format {}, {} octree nodes in {} levels",
                    output.display(),
                    w.points,
                    w.point_format,
                    w.nodes,
                    w.levels
                );
            } else {
                let n = points::convert(&input, &output, sel);
                progress.finish();
                let n = n?;
                outln!("{}: {n} points", output.display());
            }
        }
        Command::Bench(cmd) => bench(cmd)?,
        Command::Classify(a) => classify(a, progress)?,
        Command::Simplify(a) => simplify(a)?,
        Command::Strips(a) => strips(a)?,
        Command::Compare(a) => compare(a)?,
        Command::Saliency {
            input,
            out,
            views,
            view_size,
            picture_size,
            texture,
            json,
        } => {
            let views = terratile::simplify::saliency::image::ViewParams {
                views,
                size: view_size,
            };
            let r = terratile::simplify::saliency::saliency_file(
                &input,
                &out,
                &views,
                picture_size,
                texture.as_deref(),
            )?;
            print_report(json, &r)?;
        }
        Command::Plan {
            pipeline,
            out,
            shards,
            json,
        } => {
            let p = terratile::pipeline::jobs::plan(&pipeline, &out, shards)?;
            if json {
                print_json(&p)?;
            } else {
                outln!(
                    "{}: {} points, {} jobs per phase ({}), then merge",
                    out.join(terratile::pipeline::jobs::PLAN_FILE).display(),
                    p.points,
                    p.jobs,
                    p.phases.join(", ")
                );
            }
        }
        Command::Shard { plan, phase, index } => {
            let phase = terratile::pipeline::jobs::Phase::parse(&phase)?;
            let index = terratile::pipeline::jobs::job_index(index)?;
            let r = terratile::pipeline::jobs::shard(&plan, phase, index)?;
            outln!("{}", r.display());
        }
        Command::Merge { plan, json } => {
            let m = terratile::pipeline::jobs::merge_run(&plan)?;
            if json {
                print_json(&m)?;
            } else {
                outln!(
                    "{}: {}×{} tiles, {} files",
                    m.output.display(),
                    m.tiles[0],
                    m.tiles[1],
                    m.files.len()
                );
            }
        }
    }
    Ok(())
}

/// `terratile compare`: the Hausdorff error between two meshes, with an optional heatmap.
fn compare(a: CompareArgs) -> Result<()> {
    let CompareArgs {
        original,
        simplified,
        samples,
        heatmap,
        strict,
        check_folds,
        json,
    } = a;
    if let Some(out) = &heatmap {
        if out.exists() {
            return Err(Error::Usage(format!(
                "{}: the heatmap file exists (terratile does not overwrite it)",
                out.display()
            )));
        }
    }
    let params = terratile::mesh::HausdorffParams {
        samples: samples.unwrap_or(0),
    };
    let read = terratile::mesh::io::ReadOptions { strict };
    let r = terratile::mesh::hausdorff::compare_files(
        &original,
        &simplified,
        &params,
        &read,
        check_folds,
    )?;
    for w in &r.warnings {
        eprintln!("terratile: warning: {}", one_line(w));
    }
    let heat = match &heatmap {
        Some(out) => {
            let load = |p: &PathBuf| terratile::mesh::io::read_surface_with(p, &read);
            let (a, b) = (load(&original)?.0, load(&simplified)?.0);
            Some(terratile::simplify::saliency::pictures::write_heatmap(
                &a, &b, 512, out,
            )?)
        }
        None => None,
    };
    if json {
        match &heat {
            Some(h) => print_json(&serde_json::json!({ "compare": r, "heatmap": h }))?,
            None => print_json(&r)?,
        }
    } else {
        out!("{r}");
        if let Some(h) = &heat {
            outln!(
                "heatmap {}: red at {:.6}, vertex distance max {:.6}, mean {:.6}",
                h.file.display(),
                h.red_at,
                h.max,
                h.mean
            );
        }
    }
    Ok(())
}

/// `terratile bench …`: the read, terrain and Table 1 benchmarks.
fn bench(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Read {
            file,
            repeat,
            las_rs,
            json,
        } => {
            let r = terratile::bench::read(&file, &ReadOptions::default(), repeat, las_rs)?;
            print_report(json, &r)?;
        }
        BenchCommand::Terrain { file, repeat, json } => {
            let r = terratile::bench::terrain(&file, repeat)?;
            print_report(json, &r)?;
        }
        BenchCommand::Table1 {
            file,
            counts,
            repeat,
            seed,
            json,
            plot,
        } => {
            if let Some(p) = &plot {
                // Checked before the minutes of measuring; a PNG carries no signature
                // terratile could know it by, so any existing file is kept.
                if p.symlink_metadata().is_ok() {
                    return Err(Error::Usage(format!(
                        "{}: the plot file exists (terratile does not overwrite it)",
                        p.display()
                    )));
                }
            }
            let counts = counts.unwrap_or_else(terratile::bench::paper_counts);
            // Each memory figure comes from a fresh process running one method once.
            let probe = |count: u64, method: &str| table1_memory_probe(&file, seed, count, method);
            let t = terratile::bench::table1(&file, &counts, repeat, seed, Some(&probe))?;
            for s in &t.skipped {
                let line = format!(
                    "bench table1: skipping {s} points: {} holds {}",
                    file.display(),
                    t.file_points
                );
                eprintln!("terratile: {}", one_line(&line));
            }
            if let Some(p) = &plot {
                terratile::bench::plot_table1(&t, p)?;
            }
            if json {
                print_json(&t.rows)?;
            } else {
                out!("{t}");
            }
        }
        BenchCommand::Scale {
            points,
            budget,
            dir,
            json,
        } => {
            let dir = dir.unwrap_or_else(std::env::temp_dir);
            let rows = terratile::shard::scale_bench::bench_scale(&points, &budget, &dir)?;
            if json {
                print_json(&rows)?;
            } else {
                out!("{}", terratile::shard::scale_bench::table(&rows));
            }
        }
        BenchCommand::Table1Memory {
            file,
            count,
            seed,
            method,
        } => {
            let mb = terratile::bench::table1_memory(&file, count, seed, &method)?;
            outln!("{}", mb.map_or("none".into(), |m| m.to_string()));
        }
    }
    Ok(())
}

fn simplify(a: SimplifyArgs) -> Result<()> {
    use terratile::simplify::{Method, Representative, SimplifyParams};
    let params = SimplifyParams {
        method: match a.method {
            MethodArg::Uniform => Method::Uniform,
            MethodArg::Floating => Method::Floating,
            MethodArg::Octree => Method::Octree,
            MethodArg::Qem => Method::Qem,
        },
        ratio: a.ratio,
        triangles: a.triangles,
        cell_size: a.cell_size,
        threshold: a.threshold,
        representative: a.representative.map(|r| match r {
            RepresentativeArg::Centroid => Representative::Centroid,
            RepresentativeArg::Important => Representative::Important,
            RepresentativeArg::Quadric => Representative::Quadric,
        }),
        refine: a.refine,
        theta_avg_weight: None,
        theta_max_weight: None,
        split_stranded: a.no_split_stranded.then_some(false),
        placement: a.placement.map(|p| match p {
            PlacementArg::Optimal => terratile::simplify::Placement::Optimal,
            PlacementArg::Endpoint => terratile::simplify::Placement::Endpoint,
            PlacementArg::TwoLocalMappings => terratile::simplify::Placement::TwoLocalMappings,
        }),
        quadric_merge: a.quadric_merge.map(|m| match m {
            MergeArg::Sum => terratile::simplify::QuadricMerge::Sum,
            MergeArg::Mean => terratile::simplify::QuadricMerge::Mean,
        }),
        lock_border: a.lock_border.then_some(true),
        check_intersections: a.check_intersections.then_some(true),
        pair_distance: a.pair_distance,
        collapse_seams: a.collapse_seams.then_some(true),
        max_error: None,
        max_error_pct: None,
        saliency: a.saliency.map(|s| {
            use terratile::simplify::saliency::Saliency;
            match s {
                SaliencyArg::None => Saliency::None,
                SaliencyArg::Mesh => Saliency::Mesh,
                SaliencyArg::Image => Saliency::Image,
                SaliencyArg::Hybrid => Saliency::Hybrid,
            }
        }),
        saliency_h_min: a.h_min,
        saliency_rule: a.saliency_rule.map(|r| match r {
            SaliencyRuleArg::Quadric => terratile::simplify::qem::WeightRule::Quadric,
            SaliencyRuleArg::Cost => terratile::simplify::qem::WeightRule::Cost,
        }),
        saliency_views: a.views,
        saliency_view_size: a.view_size,
        engine: a.engine.map(|e| match e {
            EngineArg::Passes => terratile::simplify::qem::Engine::Passes,
            EngineArg::Heap => terratile::simplify::qem::Engine::Heap,
        }),
    };
    let mut params = params;
    if let Some(e) = &a.max_error {
        let (text, pct) = match e.trim().strip_suffix('%') {
            Some(t) => (t, true),
            None => (e.trim(), false),
        };
        let v: f64 = text.trim().parse().map_err(|_| {
            Error::Usage(format!(
                "--max-error: `{e}` is not a number (model units) or a percentage like 0.5%"
            ))
        })?;
        if pct {
            params.max_error_pct = Some(v);
        } else {
            params.max_error = Some(v);
        }
    }
    let error = (!a.no_error).then(|| terratile::mesh::HausdorffParams {
        samples: a.samples.unwrap_or(0),
    });
    terratile::check_file_output(&a.output, &[&a.input])?;
    terratile::remove_stale_temps(&a.output);
    let read = terratile::mesh::io::ReadOptions { strict: a.strict };
    let r = terratile::simplify::simplify_file_with(
        &a.input,
        &a.output,
        &params,
        error.as_ref(),
        &read,
    )?;
    for w in &r.warnings {
        eprintln!("terratile: warning: {}", one_line(w));
    }
    print_report(a.json, &r)
}

fn strips(a: StripsArgs) -> Result<()> {
    use terratile::simplify::strips::{format, Encoding, ProgressiveParams, StripOrder};
    if let Some(StripsCommand::Decode {
        input,
        level,
        output,
    }) = a.decode
    {
        terratile::check_file_output(&output, &[&input])?;
        terratile::remove_stale_temps(&output);
        let (l, t) = format::decode_file(&input, &level, &output)?;
        outln!("level {l}: {t} triangles");
        return Ok(());
    }
    let (Some(input), Some(output)) = (a.input, a.output) else {
        return Err(Error::Usage("strips: IN and OUT.tps are needed".into()));
    };
    if !(a.base_ratio > 0.0 && a.base_ratio < 1.0) {
        return Err(Error::Usage(format!(
            "--base-ratio: {} is not in (0, 1)",
            a.base_ratio
        )));
    }
    let params = ProgressiveParams {
        base_ratio: a.base_ratio,
        order: match a.order {
            OrderArg::Hierarchical => StripOrder::Hierarchical,
            OrderArg::Paper => StripOrder::Full,
        },
        ..ProgressiveParams::default()
    };
    let encoding = match a.encoding {
        EncodingArg::Naive => Encoding::Naive,
        EncodingArg::Encoded => Encoding::Encoded,
    };
    terratile::check_file_output(&output, &[&input])?;
    terratile::remove_stale_temps(&output);
    let r = format::build_file(&input, &output, &params, encoding)?;
    out!("{r}");
    Ok(())
}

/// `convert` and `generate` write uncompressed LAS: a `.laz` name would promise compression
/// that readers then fail to find.
fn refuse_laz_name(output: &Path) -> Result<()> {
    let laz = output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("laz"));
    if laz {
        return Err(Error::Usage(format!(
            "{}: terratile writes uncompressed LAS; name it .las",
            output.display()
        )));
    }
    Ok(())
}

/// `convert --copc` writes compressed COPC: any name but `.laz` would hide that.
fn refuse_non_laz_name(output: &Path) -> Result<()> {
    let laz = output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("laz"));
    if !laz {
        return Err(Error::Usage(format!(
            "{}: COPC is compressed LAZ; name it .copc.laz",
            output.display()
        )));
    }
    Ok(())
}

fn generate(g: &GenerateArgs) -> Result<()> {
    use terratile::generate::{self as gen, GenerateParams, OutFormat};
    if g.tiles.0 == 0 || g.tiles.1 == 0 {
        return Err(Error::Usage("--tiles: at least 1x1".into()));
    }
    gen::check_bounds(g.points, g.size.map(|(w, h)| [w, h]), g.tiles)?;
    let params = GenerateParams {
        seed: g.seed,
        points: g.points,
        size: g.size.map(|(w, h)| [w, h]),
        outliers_per_million: g.outliers_per_million,
        ..Default::default()
    };
    let ext = g
        .output
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    let named = match ext.as_deref() {
        Some("xyz") => Some(OutFormat::Xyz),
        Some("las") => Some(OutFormat::Las),
        _ => None,
    };
    let mut formats: Vec<OutFormat> = g
        .format
        .iter()
        .map(|f| match f {
            GenFormat::Las => OutFormat::Las,
            GenFormat::Xyz => OutFormat::Xyz,
        })
        .collect();
    if formats.is_empty() {
        refuse_laz_name(&g.output)?;
        formats.push(named.unwrap_or(OutFormat::Las));
    }
    // One file takes the name as given: its extension must not promise the other format.
    if g.tiles == (1, 1) && named.is_some_and(|n| n != formats[0]) {
        return Err(Error::Usage(format!(
            "{}: --format {} does not match the file's extension",
            g.output.display(),
            match formats[0] {
                OutFormat::Las => "las",
                OutFormat::Xyz => "xyz",
            }
        )));
    }
    if let Some(parent) = g.output.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    // The whole survey is planned (and, with tiles, its returns counted) before the first
    // file is written; the tiles are then made and written one at a time.
    let survey = gen::Survey::new(&params, g.tiles)?;
    gen::write_survey(&survey, &g.output, &formats, |p, c| {
        outln!("{}: {} points", p.display(), c.len());
    })?;
    Ok(())
}

/// A command-line error from clap as one line: clap's message and its list of possible
/// values, without the usage block and the `--help` hint (which span two to three more
/// lines). Argument values are escaped before rendering, so a line break or an escape
/// sequence in an argument is written `\n`, `\u{1b}`, never echoed raw. `e` must come from
/// a command with plain styles (clap's own styling would be ESC sequences too).
fn clap_error_line(mut e: clap::Error) -> String {
    use clap::error::{ContextValue, ErrorKind};
    if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand {
        return "a command is required: run, info, generate, convert, bench, simplify or compare \
                (see terratile --help)"
            .into();
    }
    let escaped: Vec<_> = e
        .context()
        .filter_map(|(k, v)| match v {
            ContextValue::String(s) => Some((k, ContextValue::String(one_line(s).into_owned()))),
            ContextValue::Strings(v) => Some((
                k,
                ContextValue::Strings(v.iter().map(|s| one_line(s).into_owned()).collect()),
            )),
            _ => None,
        })
        .collect();
    for (k, v) in escaped {
        e.insert(k, v);
    }
    let text = e.render().ansi().to_string();
    let head = text.split("\nUsage:").next().unwrap_or(&text);
    let parts: Vec<&str> = head
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with("For more information"))
        .collect();
    let line = parts.join(" ").replace(" tip: ", "; tip: ");
    let line = line.strip_prefix("error: ").unwrap_or(&line);
    format!("{} (see terratile --help)", one_line(line))
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) {
                // `--help` and `--version` print as clap lays them out, exit 0.
                let _ = e.print();
                return ExitCode::from(e.exit_code() as u8);
            }
            // The same error again without styles, to be made one line.
            use clap::CommandFactory;
            let plain = Cli::command()
                .styles(clap::builder::Styles::plain())
                .try_get_matches()
                .err()
                .unwrap_or(e);
            eprintln!("terratile: {}", clap_error_line(plain));
            return ExitCode::from(2);
        }
    };
    // A panic is a bug; it too is reported on one line (the default hook takes two or more,
    // and echoes its message raw). The word `panicked` stays, for whoever greps for it.
    std::panic::set_hook(Box::new(|info| {
        let msg = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_default();
        let at = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        eprintln!(
            "terratile: internal error: panicked{at}: {} (this is a bug; please report it with the input)",
            one_line(&msg)
        );
        // With RUST_BACKTRACE set, the backtrace follows (asked for, so many lines are fine).
        let bt = std::backtrace::Backtrace::capture();
        if bt.status() == std::backtrace::BacktraceStatus::Captured {
            eprintln!("{bt}");
        }
    }));
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run(cli)));
    match outcome {
        Ok(Ok(())) => ExitCode::SUCCESS,
        Ok(Err(e)) => {
            // One line whatever the input held (file names, TOML values, file content).
            eprintln!("terratile: {}", one_line(&e.to_string()));
            ExitCode::from(e.exit_code() as u8)
        }
        // The panic hook has printed the line.
        Err(_) => ExitCode::from(1),
    }
}
