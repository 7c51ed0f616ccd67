//! The Delaunay baseline of Kim & Shin §3: a 2.5-D Delaunay triangulation (TIN) of
//! the denoised points, built with `spade`, against which the grid pipeline's time, memory
//! and accuracy are measured; as the `[baseline]` stage ([`baseline`]) it writes the TIN as a
//! mesh and a report, and [`Tin::rasterise`] samples it on the pipeline's grid so that the two
//! surfaces can be compared cell by cell.
//!
//! Coordinates are taken relative to the centre of the points' bounding box, so that the
//! f64 predicates work on small numbers (UTM eastings of 500 000 m would waste 19 bits).
//! Points sharing x and y (first and last return of one pulse: a third of the ISPRS points)
//! are merged before triangulating, their z averaged; spade itself would keep one of them
//! (`bulk_load` keeps the first, `insert` overwrites with the last), which makes the surface
//! depend on the order. The merged points keep the order of their first occurrence, so
//! incremental insertion still follows the file order (on spatially sorted files such as
//! autzen_full that is much faster than bulk loading: each insertion starts its walk next to
//! the previous vertex).

use super::accuracy::{holdout, ErrorStats};
use super::heightfield::{CellState, Heightfield};
use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use glam::Vec3;
use ndarray::Axis;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use spade::handles::FixedVertexHandle;
use spade::{DelaunayTriangulation, HasPosition, Point2, PositionInTriangulation, Triangulation};

/// A TIN vertex: position relative to the centre, and height.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TinVertex {
    /// x, y relative to [`TinPoints::centre`].
    pub p: Point2<f64>,
    /// World z (mean z of the points merged into this vertex).
    pub z: f64,
}

impl HasPosition for TinVertex {
    type Scalar = f64;
    fn position(&self) -> Point2<f64> {
        self.p
    }
}

/// The points a TIN is built from.
#[derive(Debug, Clone)]
pub struct TinPoints {
    /// Distinct points, in order of first occurrence.
    pub vertices: Vec<TinVertex>,
    /// World x, y subtracted from every point.
    pub centre: [f64; 2],
    /// Input points merged into another one (shared x and y).
    pub merged: usize,
}

/// How to build the triangulation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TinMethod {
    /// Whichever is faster for the input: incremental insertion when the points are
    /// spatially coherent in file order, bulk loading otherwise.
    #[default]
    Auto,
    /// spade's bulk loading (sorts the points along a space-filling order first).
    Bulk,
    /// Insertion one by one, in file order.
    Incremental,
}

/// A built TIN.
pub struct Tin {
    /// The triangulation (vertex positions relative to `centre`).
    pub tri: DelaunayTriangulation<TinVertex>,
    /// World x, y of the origin of the triangulation's coordinates.
    pub centre: [f64; 2],
}

impl std::fmt::Debug for Tin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tin")
            .field("vertices", &self.tri.num_vertices())
            .field("triangles", &self.tri.num_inner_faces())
            .field("centre", &self.centre)
            .finish()
    }
}

/// Centres the points whose `keep` flag is set (all when `None`) and merges those that share
/// x and y (z averaged).
pub fn prepare(x: &[f64], y: &[f64], z: &[f64], keep: Option<&[bool]>) -> Result<TinPoints> {
    let (b, n) = super::bounds_of(x, y, z, keep);
    if n == 0 {
        return Err(Error::Data {
            stage: "delaunay",
            message: "no points to triangulate".into(),
        });
    }
    let centre = [(b.min[0] + b.max[0]) / 2.0, (b.min[1] + b.max[1]) / 2.0];
    // (x bits, y bits, index) of the centred points; + 0.0 turns −0.0 into 0.0 so that equal
    // positions have equal bits.
    let mut keyed: Vec<(u64, u64, u32)> = (0..x.len() as u32)
        .into_par_iter()
        .filter(|&i| keep.is_none_or(|k| k[i as usize]))
        .map(|i| {
            let (px, py) = (
                x[i as usize] - centre[0] + 0.0,
                y[i as usize] - centre[1] + 0.0,
            );
            (px.to_bits(), py.to_bits(), i)
        })
        .collect();
    keyed.par_sort_unstable();
    // Runs of equal position: one vertex each, at the run's first (lowest) index.
    let mut merged: Vec<(u32, TinVertex)> = keyed
        .par_chunk_by(|a, b| a.0 == b.0 && a.1 == b.1)
        .map(|run| {
            let first = run[0].2;
            let zsum: f64 = run.iter().map(|r| z[r.2 as usize]).sum();
            let v = TinVertex {
                p: Point2::new(f64::from_bits(run[0].0), f64::from_bits(run[0].1)),
                z: zsum / run.len() as f64,
            };
            (first, v)
        })
        .collect();
    drop(keyed);
    merged.par_sort_unstable_by_key(|m| m.0);
    let vertices: Vec<TinVertex> = merged.into_par_iter().map(|m| m.1).collect();
    Ok(TinPoints {
        merged: n - vertices.len(),
        vertices,
        centre,
    })
}

/// The faster method for these points, judged from their order: incremental insertion
/// starts each walk at the previous vertex, so it wins when consecutive points are close
/// (scan lines, Morton-sorted files); on shuffled points its walks cross the survey and bulk
/// loading (which sorts first) wins. "Close": the median distance between consecutive points
/// is at most [`COHERENT_STEPS`] mean spacings.
pub fn choose_method(points: &TinPoints) -> TinMethod {
    let v = &points.vertices;
    if v.len() < 2 {
        return TinMethod::Incremental;
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in v {
        lo = [lo[0].min(p.p.x), lo[1].min(p.p.y)];
        hi = [hi[0].max(p.p.x), hi[1].max(p.p.y)];
    }
    let spacing = ((hi[0] - lo[0]) * (hi[1] - lo[1]) / v.len() as f64).sqrt();
    // Up to 100 000 consecutive pairs, evenly spread through the file.
    let stride = (v.len() / 100_000).max(1);
    let mut d: Vec<f64> = (1..v.len())
        .step_by(stride)
        .map(|i| (v[i].p.x - v[i - 1].p.x).hypot(v[i].p.y - v[i - 1].p.y))
        .collect();
    d.sort_by(f64::total_cmp);
    let median = d[d.len() / 2];
    if spacing > 0.0 && median > COHERENT_STEPS * spacing {
        TinMethod::Bulk
    } else {
        TinMethod::Incremental
    }
}

/// See [`choose_method`].
pub const COHERENT_STEPS: f64 = 10.0;

/// Builds the TIN of `points` with `method` (`Auto`: [`choose_method`]).
pub fn triangulate(points: &TinPoints, method: TinMethod) -> Result<Tin> {
    let method = match method {
        TinMethod::Auto => choose_method(points),
        m => m,
    };
    if points.vertices.len() < 3 {
        return Err(Error::Data {
            stage: "delaunay",
            message: format!(
                "{} distinct point(s): a triangulation needs at least three",
                points.vertices.len()
            ),
        });
    }
    let err = |e: spade::InsertionError| Error::Data {
        stage: "delaunay",
        message: format!("spade refused a point: {e}"),
    };
    let tri = match method {
        TinMethod::Bulk => {
            DelaunayTriangulation::bulk_load(points.vertices.clone()).map_err(err)?
        }
        TinMethod::Auto | TinMethod::Incremental => {
            let mut t = DelaunayTriangulation::new();
            for v in &points.vertices {
                t.insert(*v).map_err(err)?;
            }
            t
        }
    };
    if tri.num_inner_faces() == 0 {
        return Err(Error::Data {
            stage: "delaunay",
            message: format!(
                "all {} distinct points are collinear: they span no triangle",
                points.vertices.len()
            ),
        });
    }
    Ok(Tin {
        tri,
        centre: points.centre,
    })
}

impl Tin {
    /// Number of vertices.
    pub fn vertices(&self) -> usize {
        self.tri.num_vertices()
    }

    /// Number of triangles.
    pub fn triangles(&self) -> usize {
        self.tri.num_inner_faces()
    }

    /// World z at (x, y) by linear interpolation in the triangle holding it; None outside
    /// the convex hull.
    pub fn z_at(&self, x: f64, y: f64) -> Option<f64> {
        let hint = self.tri.vertices().next()?.fix();
        self.interpolate(x, y, hint).0
    }

    /// [`Tin::z_at`] for many points, in parallel; each worker walks from the vertex it found
    /// last, so points in a sensible order are cheap.
    pub fn z_at_many(&self, xy: &[[f64; 2]]) -> Vec<Option<f64>> {
        let Some(first) = self.tri.vertices().next().map(|v| v.fix()) else {
            return vec![None; xy.len()];
        };
        xy.par_chunks(4096)
            .flat_map_iter(|chunk| {
                let mut hint = first;
                chunk
                    .iter()
                    .map(|&[x, y]| {
                        let (z, h) = self.interpolate(x, y, hint);
                        hint = h;
                        z
                    })
                    .collect::<Vec<_>>()
            })
            .collect()
    }

    /// z at world (x, y) linearly inside the triangle (or along the edge, or at the vertex)
    /// holding it, located by a walk from `hint`; returns the vertex to start the next walk.
    fn interpolate(
        &self,
        x: f64,
        y: f64,
        hint: FixedVertexHandle,
    ) -> (Option<f64>, FixedVertexHandle) {
        let p = Point2::new(x - self.centre[0], y - self.centre[1]);
        match self.tri.locate_with_hint(p, hint) {
            PositionInTriangulation::OnVertex(v) => (Some(self.tri.vertex(v).data().z), v),
            PositionInTriangulation::OnEdge(e) => {
                let e = self.tri.directed_edge(e);
                let [a, b] = [e.from(), e.to()];
                let (pa, pb) = (a.position(), b.position());
                let len2 = (pb.x - pa.x).powi(2) + (pb.y - pa.y).powi(2);
                let t = ((p.x - pa.x) * (pb.x - pa.x) + (p.y - pa.y) * (pb.y - pa.y)) / len2;
                (Some(a.data().z * (1.0 - t) + b.data().z * t), a.fix())
            }
            PositionInTriangulation::OnFace(f) => {
                let [a, b, c] = self.tri.face(f).vertices();
                let (pa, pb, pc) = (a.position(), b.position(), c.position());
                let d = (pb.x - pa.x) * (pc.y - pa.y) - (pc.x - pa.x) * (pb.y - pa.y);
                let wb = ((p.x - pa.x) * (pc.y - pa.y) - (pc.x - pa.x) * (p.y - pa.y)) / d;
                let wc = ((pb.x - pa.x) * (p.y - pa.y) - (p.x - pa.x) * (pb.y - pa.y)) / d;
                let z = a.data().z * (1.0 - wb - wc) + b.data().z * wb + c.data().z * wc;
                (Some(z), a.fix())
            }
            PositionInTriangulation::OutsideOfConvexHull(e) => {
                (None, self.tri.directed_edge(e).from().fix())
            }
            PositionInTriangulation::NoTriangulation => (None, hint),
        }
    }

    /// The TIN sampled at the cell centres of a grid shaped like `like` (same corner, cell
    /// size, z offset and CRS): linear inside each triangle; cells outside the convex hull
    /// are holes (NaN, `Empty`). Other cells are `Measured` with count 0. Rows in parallel,
    /// each walking from the vertex found last, so the result is the same for any thread
    /// count (location is exact).
    pub fn rasterise(&self, like: &Heightfield) -> Heightfield {
        let (rows, cols) = like.heights.dim();
        let mut out = Heightfield::empty(
            cols,
            rows,
            like.corner,
            like.cell_size,
            like.z_offset,
            like.crs.clone(),
        );
        let Some(first) = self.tri.vertices().next().map(|v| v.fix()) else {
            return out;
        };
        out.heights
            .axis_iter_mut(Axis(0))
            .into_par_iter()
            .zip(out.state.axis_iter_mut(Axis(0)))
            .enumerate()
            .for_each(|(j, (mut h, mut s))| {
                let mut hint = first;
                for i in 0..cols {
                    let [x, y] = like.centre(i, j);
                    let (z, next) = self.interpolate(x, y, hint);
                    hint = next;
                    if let Some(z) = z {
                        h[i] = (z - like.z_offset) as f32;
                        s[i] = CellState::Measured;
                    }
                }
            });
        out
    }

    /// The TIN as an indexed mesh, positions relative to `origin` (world x, y, z subtracted,
    /// so that f32 keeps centimetres on UTM coordinates), triangles counter-clockwise seen
    /// from above.
    pub fn to_mesh(&self, origin: [f64; 3]) -> TriMesh {
        let (dx, dy) = (self.centre[0] - origin[0], self.centre[1] - origin[1]);
        let positions = self
            .tri
            .vertices()
            .map(|v| {
                let p = v.position();
                Vec3::new(
                    (p.x + dx) as f32,
                    (p.y + dy) as f32,
                    (v.data().z - origin[2]) as f32,
                )
            })
            .collect();
        let indices = self
            .tri
            .inner_faces()
            .map(|f| f.vertices().map(|v| v.fix().index() as u32))
            .collect();
        TriMesh {
            positions,
            indices,
            ..Default::default()
        }
    }
}

/// `[baseline]`: the Delaunay baseline as a pipeline stage (off by default).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct BaselineParams {
    /// Run the baseline (default false).
    pub enabled: bool,
    /// `auto` (default: incremental insertion for spatially coherent files, bulk loading
    /// otherwise), `bulk` or `incremental`.
    pub method: TinMethod,
    /// The TIN mesh in the output directory: `.ply` (binary), `.obj` or `.glb` (glTF
    /// binary, y up); empty for none (default `tin.ply`).
    pub mesh: String,
    /// The comparison report in the output directory (default `baseline.json`).
    pub report: String,
    /// Share of the denoised points held out to score both surfaces (default 0.02; 0 to
    /// skip the accuracy comparison).
    pub holdout: f64,
    /// Seed of the hold-out draw (default 1).
    pub seed: u64,
}

impl Default for BaselineParams {
    fn default() -> Self {
        BaselineParams {
            enabled: false,
            method: TinMethod::Auto,
            mesh: "tin.ply".into(),
            report: "baseline.json".into(),
            holdout: 0.02,
            seed: 1,
        }
    }
}

impl BaselineParams {
    /// Checks the values a user can get wrong, before any data is read.
    pub fn validate(&self) -> Result<()> {
        if !(0.0..0.5).contains(&self.holdout) {
            return Err(Error::param(
                "baseline",
                "holdout",
                self.holdout,
                "must be in [0, 0.5)",
            ));
        }
        if !self.mesh.is_empty() {
            let ext = std::path::Path::new(&self.mesh)
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase);
            if !matches!(ext.as_deref(), Some("ply" | "obj" | "glb")) {
                return Err(Error::param(
                    "baseline",
                    "mesh",
                    format!("\"{}\"", self.mesh),
                    "the TIN mesh is written as .ply (binary), .obj or .glb",
                ));
            }
        }
        if self.report.is_empty() {
            return Err(Error::param(
                "baseline",
                "report",
                "\"\"",
                "name the report file",
            ));
        }
        // Both files belong inside the run's (staged) output directory: an absolute path or
        // `..` would write outside it, past the atomic commit.
        for (param, name) in [("mesh", &self.mesh), ("report", &self.report)] {
            let p = std::path::Path::new(name);
            if p.is_absolute()
                || p.components()
                    .any(|c| matches!(c, std::path::Component::ParentDir))
            {
                return Err(Error::param(
                    "baseline",
                    param,
                    format!("\"{name}\""),
                    "must be a relative path inside the output directory",
                ));
            }
        }
        Ok(())
    }
}

/// Differences between the grid and the rasterised TIN over the cells both cover.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct RasterDiff {
    /// Cells compared.
    pub cells: usize,
    /// Cells of the grid outside the TIN's convex hull (or holes of the grid).
    pub uncovered: usize,
    /// Root mean square of grid − TIN, metres.
    pub rmse_m: f64,
    /// 95th percentile of |grid − TIN|, metres.
    pub p95_m: f64,
    /// Largest |grid − TIN|, metres.
    pub max_m: f64,
    /// Mean of grid − TIN, metres (positive: the grid lies above).
    pub mean_m: f64,
}

/// What the baseline computed (times in seconds, errors in metres). Times, their ratio and
/// memory differ from run to run: they are not serialised (the report file is a
/// deterministic output); the run summary carries them (the pipeline's `BaselineMeasurements`).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct BaselineReport {
    /// The method used (`auto` resolved).
    pub method: TinMethod,
    /// Denoised points triangulated.
    pub points: usize,
    /// Points merged into another with the same x and y (z averaged).
    pub merged: usize,
    /// TIN vertices.
    pub vertices: usize,
    /// TIN triangles.
    pub triangles: usize,
    /// Seconds to centre and merge the points.
    #[serde(skip)]
    pub prepare_s: f64,
    /// Seconds to build the triangulation.
    #[serde(skip)]
    pub build_s: f64,
    /// Seconds of the grid pipeline of the same run: every stage from denoise to the written
    /// tiles (the read excluded).
    #[serde(skip)]
    pub grid_s: f64,
    /// build_s / grid_s.
    #[serde(skip)]
    pub ratio: f64,
    /// Seconds to rasterise the TIN onto the grid.
    #[serde(skip)]
    pub rasterise_s: f64,
    /// Grid cells against the rasterised TIN.
    pub raster: RasterDiff,
    /// Points held out for the accuracy comparison.
    pub holdout: usize,
    /// The grid built without the held-out points, scored at them.
    pub grid_accuracy: Option<ErrorStats>,
    /// The TIN built without the held-out points, scored at them.
    pub tin_accuracy: Option<ErrorStats>,
    /// The same for held-out ground points (class 2), when the data is classified.
    pub grid_accuracy_ground: Option<ErrorStats>,
    /// See `grid_accuracy_ground`.
    pub tin_accuracy_ground: Option<ErrorStats>,
    /// Peak resident memory of the run before the baseline (read and grid stages), MB.
    #[serde(skip)]
    pub grid_peak_mb: Option<f64>,
    /// Peak resident memory while building the TIN (the points included), MB.
    #[serde(skip)]
    pub tin_peak_mb: Option<f64>,
}

/// Runs the baseline on the points of `cloud` kept by noise removal (`keep`), against the
/// run's filled `grid` (made with `resample` and `fill`, which the accuracy comparison
/// repeats without the held-out points). `grid_s` is the grid pipeline's time (every stage from
/// denoise to the written tiles). Returns the
/// report and the TIN (for the mesh output).
pub fn baseline(
    cloud: &crate::points::PointCloud,
    keep: Option<&[bool]>,
    grid: &Heightfield,
    grid_s: f64,
    params: &BaselineParams,
    resample: &super::ResampleParams,
    fill: Option<&super::FillParams>,
) -> Result<(BaselineReport, Tin)> {
    params.validate()?;
    let mpu = cloud.crs().map_or(1.0, |c| c.metres_per_unit());
    let t = std::time::Instant::now();
    let points = prepare(&cloud.x, &cloud.y, &cloud.z, keep)?;
    let prepare_s = t.elapsed().as_secs_f64();
    let method = match params.method {
        TinMethod::Auto => choose_method(&points),
        m => m,
    };
    let t = std::time::Instant::now();
    let tin = triangulate(&points, method)?;
    let build_s = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let raster = tin.rasterise(grid);
    let rasterise_s = t.elapsed().as_secs_f64();
    let mut diffs: Vec<f64> = Vec::new();
    let mut uncovered = 0;
    for (((g, gs), r), rs) in grid
        .heights
        .iter()
        .zip(grid.state.iter())
        .zip(raster.heights.iter())
        .zip(raster.state.iter())
    {
        if gs.has_height() && rs.has_height() {
            diffs.push((*g as f64 - *r as f64) * mpu);
        } else {
            uncovered += 1;
        }
    }
    let mean_m = diffs.iter().sum::<f64>() / diffs.len().max(1) as f64;
    let stats = ErrorStats::of(diffs.iter().map(|&d| (Some(d), 0.0)));
    let kept_n = keep.map_or(cloud.len(), |k| k.iter().filter(|&&b| b).count());
    let mut report = BaselineReport {
        method,
        points: kept_n,
        merged: points.merged,
        vertices: tin.vertices(),
        triangles: tin.triangles(),
        prepare_s,
        build_s,
        grid_s,
        ratio: build_s / grid_s,
        rasterise_s,
        raster: RasterDiff {
            cells: stats.n,
            uncovered,
            rmse_m: stats.rmse,
            p95_m: stats.p95,
            max_m: stats.max,
            mean_m,
        },
        ..Default::default()
    };
    if params.holdout > 0.0 {
        let (train, test) = holdout(cloud.len(), keep, params.holdout, params.seed);
        let mut g = super::resample(cloud, Some(&train), resample)?.grid;
        if let Some(f) = fill {
            super::fill(&mut g, f)?;
        }
        let tin_train = triangulate(
            &prepare(&cloud.x, &cloud.y, &cloud.z, Some(&train))?,
            method,
        )?;
        let scores = score_holdout(cloud, &test, &g, &tin_train, mpu);
        report.holdout = test.len();
        report.grid_accuracy = Some(scores.grid);
        report.tin_accuracy = Some(scores.tin);
        report.grid_accuracy_ground = scores.grid_ground;
        report.tin_accuracy_ground = scores.tin_ground;
    }
    Ok((report, tin))
}

/// A grid and a TIN scored at the same held-out points, in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HoldoutScores {
    /// The grid at every held-out point.
    pub grid: ErrorStats,
    /// The TIN at every held-out point.
    pub tin: ErrorStats,
    /// The grid at the held-out ground points (class 2), when the data is classified.
    pub grid_ground: Option<ErrorStats>,
    /// The TIN at the held-out ground points, when the data is classified.
    pub tin_ground: Option<ErrorStats>,
}

/// Scores `grid` (bilinear) and `tin` at the held-out points `test` of `cloud` (neither
/// built from them) against their own heights; `mpu` turns the data's units into metres.
pub fn score_holdout(
    cloud: &crate::points::PointCloud,
    test: &[u32],
    grid: &Heightfield,
    tin: &Tin,
    mpu: f64,
) -> HoldoutScores {
    let xy: Vec<[f64; 2]> = test
        .iter()
        .map(|&i| [cloud.x[i as usize], cloud.y[i as usize]])
        .collect();
    let tz = tin.z_at_many(&xy);
    let gz: Vec<Option<f64>> = xy
        .iter()
        .map(|&[x, y]| grid.sample_bilinear(x, y))
        .collect();
    let truth: Vec<f64> = test.iter().map(|&i| cloud.z[i as usize]).collect();
    let score = |pred: &[Option<f64>], sel: &dyn Fn(usize) -> bool| {
        ErrorStats::of(
            (0..test.len())
                .filter(|&k| sel(test[k] as usize))
                .map(|k| (pred[k], truth[k])),
        )
        .scaled(mpu)
    };
    let classified = cloud.classification.contains(&2);
    let ground = |i: usize| cloud.classification[i] == 2;
    HoldoutScores {
        grid: score(&gz, &|_| true),
        tin: score(&tz, &|_| true),
        grid_ground: classified.then(|| score(&gz, &ground)),
        tin_ground: classified.then(|| score(&tz, &ground)),
    }
}

/// Checks that `tin` is a valid Delaunay triangulation of `points`: every distinct point a
/// vertex and nothing else, the Euler relation of a triangulated point set (V − E + F = 1 and
/// F = 2V − 2 − H with H hull vertices), no triangle of zero area or clockwise, and the
/// empty-circumcircle property for about `sample` triangles spread over the mesh, each against
/// every vertex (an in-circle determinant above a tolerance relative to the triangle's size).
/// O(sample · V); for tests and audits.
pub fn validate(points: &TinPoints, tin: &Tin, sample: usize) -> std::result::Result<(), String> {
    let t = &tin.tri;
    let (v, e, f, h) = (
        t.num_vertices(),
        t.num_undirected_edges(),
        t.num_inner_faces(),
        t.convex_hull_size(),
    );
    if v != points.vertices.len() {
        return Err(format!(
            "{v} vertices for {} distinct points",
            points.vertices.len()
        ));
    }
    if v as i64 - e as i64 + f as i64 != 1 {
        return Err(format!("Euler: V − E + F = {v} − {e} + {f} ≠ 1"));
    }
    if f + 2 + h != 2 * v {
        return Err(format!(
            "{f} triangles for {v} points with {h} on the hull (want 2V − 2 − H)"
        ));
    }
    let mut want: Vec<(u64, u64)> = points
        .vertices
        .iter()
        .map(|q| (q.p.x.to_bits(), q.p.y.to_bits()))
        .collect();
    let mut got: Vec<(u64, u64)> = t
        .vertices()
        .map(|q| (q.position().x.to_bits(), q.position().y.to_bits()))
        .collect();
    want.sort_unstable();
    got.sort_unstable();
    if want != got {
        return Err("the vertices are not the points".into());
    }
    let all: Vec<Point2<f64>> = t.vertices().map(|q| q.position()).collect();
    let step = (f / sample.max(1)).max(1);
    for (k, face) in t.inner_faces().enumerate() {
        let [a, b, c] = face.positions();
        let area2 = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
        if area2 <= 0.0 {
            return Err(format!("triangle {k} has zero area or is clockwise"));
        }
        if k % step != 0 {
            continue;
        }
        let scale = (b.x - a.x)
            .hypot(b.y - a.y)
            .max((c.x - a.x).hypot(c.y - a.y));
        for q in &all {
            let (ax, ay) = (a.x - q.x, a.y - q.y);
            let (bx, by) = (b.x - q.x, b.y - q.y);
            let (cx, cy) = (c.x - q.x, c.y - q.y);
            let det = (ax * ax + ay * ay) * (bx * cy - cx * by)
                - (bx * bx + by * by) * (ax * cy - cx * ay)
                + (cx * cx + cy * cy) * (ax * by - bx * ay);
            if det > 1e-9 * scale.powi(4) {
                return Err(format!(
                    "a vertex lies inside the circumcircle of triangle {k}"
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn duplicates_merge_with_mean_z_in_first_order() {
        let x = [10.0, 11.0, 10.0, 12.0, 11.0];
        let y = [5.0, 5.0, 5.0, 7.0, 5.0];
        let z = [1.0, 2.0, 3.0, 4.0, 6.0];
        let p = prepare(&x, &y, &z, None).unwrap();
        assert_eq!(p.merged, 2);
        let zs: Vec<f64> = p.vertices.iter().map(|v| v.z).collect();
        assert_eq!(zs, vec![2.0, 4.0, 4.0]);
        assert_eq!(p.centre, [11.0, 6.0]);
        let tin = triangulate(&p, TinMethod::Incremental).unwrap();
        assert_eq!(tin.triangles(), 1);
        assert_eq!(tin.z_at(10.0, 5.0), Some(2.0));
    }

    #[test]
    fn bulk_and_incremental_give_the_same_surface() {
        let mut rng = crate::rng::SplitMix64::new(3);
        let n = 2000;
        let x: Vec<f64> = (0..n).map(|_| 500_000.0 + rng.range(0.0, 100.0)).collect();
        let y: Vec<f64> = (0..n).map(|_| 5_400_000.0 + rng.range(0.0, 80.0)).collect();
        let z: Vec<f64> = x.iter().zip(&y).map(|(x, y)| 0.1 * x - 0.05 * y).collect();
        let p = prepare(&x, &y, &z, None).unwrap();
        let a = triangulate(&p, TinMethod::Bulk).unwrap();
        let b = triangulate(&p, TinMethod::Incremental).unwrap();
        assert_eq!(a.triangles(), b.triangles());
        // A plane is reproduced exactly (to rounding) inside the hull.
        for k in 0..100 {
            let (qx, qy) = (500_010.0 + k as f64 * 0.7, 5_400_010.0 + k as f64 * 0.5);
            let want = 0.1 * qx - 0.05 * qy;
            assert!((a.z_at(qx, qy).unwrap() - want).abs() < 1e-6);
            assert!((b.z_at(qx, qy).unwrap() - want).abs() < 1e-6);
        }
        assert!(a.z_at(0.0, 0.0).is_none());
    }

    fn check_valid(points: &TinPoints, tin: &Tin, sample: usize) {
        if let Err(e) = validate(points, tin, sample) {
            panic!("{e}");
        }
    }

    #[test]
    fn valid_delaunay_with_duplicates_and_both_methods() {
        let s = crate::generate::generate(&crate::generate::GenerateParams {
            seed: 4,
            points: 6000,
            ..Default::default()
        })
        .unwrap();
        let c = &s.cloud;
        // First and last returns share x and y in the generator's trees: duplicates to merge.
        let p = prepare(&c.x, &c.y, &c.z, None).unwrap();
        assert!(p.merged > 0, "the generated trees have shared positions");
        for m in [TinMethod::Bulk, TinMethod::Incremental, TinMethod::Auto] {
            let tin = triangulate(&p, m).unwrap();
            check_valid(&p, &tin, 60);
        }
    }

    #[test]
    fn auto_prefers_incremental_for_coherent_order_and_bulk_for_shuffled() {
        let n = 40_000;
        let side = 200usize;
        // A serpentine scan: consecutive points one spacing apart.
        let mut x = Vec::with_capacity(n);
        let mut y = Vec::with_capacity(n);
        for j in 0..side {
            for i in 0..side {
                let i = if j % 2 == 0 { i } else { side - 1 - i };
                x.push(i as f64 + 0.1 * (j as f64).sin());
                y.push(j as f64);
            }
        }
        let z = vec![0.0; x.len()];
        let p = prepare(&x, &y, &z, None).unwrap();
        assert_eq!(choose_method(&p), TinMethod::Incremental);
        let mut rng = crate::rng::SplitMix64::new(1);
        let mut idx: Vec<usize> = (0..x.len()).collect();
        for i in (1..idx.len()).rev() {
            idx.swap(i, rng.below(i as u64 + 1) as usize);
        }
        let (xs, ys): (Vec<f64>, Vec<f64>) = idx.iter().map(|&i| (x[i], y[i])).unzip();
        let p = prepare(&xs, &ys, &z, None).unwrap();
        assert_eq!(choose_method(&p), TinMethod::Bulk);
    }

    /// A grid of `cols` × `rows` unit cells with `f` at the centres of the cells `keep` picks.
    fn grid_of(
        cols: usize,
        rows: usize,
        f: &dyn Fn(f64, f64) -> f64,
        keep: &dyn Fn(usize, usize) -> bool,
    ) -> (Heightfield, Vec<[f64; 3]>) {
        let mut hf = Heightfield::empty(cols, rows, [1000.0, 2000.0], [1.0, 1.0], 0.0, None);
        let mut pts = Vec::new();
        for j in 0..rows {
            for i in 0..cols {
                if keep(i, j) {
                    let [x, y] = hf.centre(i, j);
                    let z = f(x, y);
                    hf.heights[[j, i]] = z as f32;
                    hf.counts[[j, i]] = 1;
                    hf.state[[j, i]] = CellState::Measured;
                    pts.push([x, y, z]);
                }
            }
        }
        (hf, pts)
    }

    fn tin_of(pts: &[[f64; 3]]) -> Tin {
        let (x, (y, z)): (Vec<f64>, (Vec<f64>, Vec<f64>)) =
            pts.iter().map(|p| (p[0], (p[1], p[2]))).unzip();
        triangulate(&prepare(&x, &y, &z, None).unwrap(), TinMethod::Auto).unwrap()
    }

    #[test]
    fn rasterised_tin_and_grid_agree_on_a_plane() {
        // Points on a checkerboard: the fill interpolates the other cells from their row and
        // column neighbours (exact on a plane), the TIN linearly (exact on a plane).
        let plane = |x: f64, y: f64| 0.25 * (x - 1000.0) - 0.1 * (y - 2000.0) + 300.0;
        let (mut hf, pts) = grid_of(41, 33, &plane, &|i, j| (i + j) % 2 == 0);
        crate::terrain::fill(&mut hf, &crate::terrain::FillParams::default()).unwrap();
        let raster = tin_of(&pts).rasterise(&hf);
        assert!(
            raster.state.iter().all(|s| *s == CellState::Measured),
            "the hull holds every centre"
        );
        // Inside the border every filled cell has both pairs (Kim & Shin's fill formula, exact on a
        // plane); border cells miss one neighbour and use inverse-distance weights instead.
        for j in 1..32 {
            for i in 1..40 {
                let (a, b) = (hf.heights[[j, i]], raster.heights[[j, i]]);
                assert!((a - b).abs() <= 1e-4, "({i}, {j}): {a} vs {b}");
            }
        }
    }

    #[test]
    fn rasterised_tin_and_grid_agree_on_piecewise_linear_terrain() {
        // A pyramid and a ridge sampled at every cell centre: grid cells are the samples, and
        // the TIN passes through every sample.
        let f = |x: f64, y: f64| {
            80.0 - (x - 1020.0).abs() - 0.5 * (y - 2015.0).abs() + (x - 1010.0).max(0.0) * 0.3
        };
        let (hf, pts) = grid_of(40, 30, &f, &|_, _| true);
        let raster = tin_of(&pts).rasterise(&hf);
        assert_eq!(raster.state, hf.state);
        for (a, b) in hf.heights.iter().zip(raster.heights.iter()) {
            assert!((a - b).abs() <= 1e-5, "{a} vs {b}");
        }
        // And the rasterisation is the same for any thread count.
        let tin = tin_of(&pts);
        let one = crate::testing::on_threads(1, || tin.rasterise(&hf));
        let eight = crate::testing::on_threads(8, || tin.rasterise(&hf));
        assert!(crate::terrain::reference::same_grid(&one, &eight));
    }

    #[test]
    fn mesh_has_every_vertex_and_triangle() {
        let plane = |x: f64, y: f64| 0.5 * x + y;
        let (_, pts) = grid_of(10, 8, &plane, &|_, _| true);
        let tin = tin_of(&pts);
        let m = tin.to_mesh([1000.0, 2000.0, 0.0]);
        assert_eq!(m.vertex_count(), 80);
        assert_eq!(m.triangle_count(), tin.triangles());
        for t in &m.indices {
            let [a, b, c] = t.map(|k| m.positions[k as usize]);
            assert!((b - a).cross(c - a).z > 0.0, "counter-clockwise from above");
        }
        assert!(m
            .positions
            .iter()
            .all(|p| p.x >= 0.0 && p.x <= 10.0 && p.y >= 0.0 && p.y <= 8.0));
    }

    #[test]
    fn too_few_or_collinear_points_are_refused() {
        let p = prepare(&[1.0, 1.0, 2.0], &[1.0, 1.0, 2.0], &[0.0; 3], None).unwrap();
        let e = triangulate(&p, TinMethod::Bulk).unwrap_err().to_string();
        assert!(e.starts_with("delaunay: 2 distinct point(s)"), "{e}");
        let x: Vec<f64> = (0..10).map(|i| i as f64).collect();
        let p = prepare(&x, &x, &x, None).unwrap();
        for m in [TinMethod::Bulk, TinMethod::Incremental] {
            let e = triangulate(&p, m).unwrap_err().to_string();
            assert!(
                e.starts_with("delaunay: all 10 distinct points are collinear"),
                "{e}"
            );
        }
    }
}
