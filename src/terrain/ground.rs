//! Ground classification: which points are bare earth, for surveys that arrive unclassified.
//!
//! The method is SMRF, the simple morphological filter of Pingel, Clarke & McBride ("An
//! improved simple morphological filter for the terrain classification of airborne LIDAR
//! data", 2013), chosen over cloth simulation (Zhang et al. 2016) and progressive TIN
//! densification (Axelsson 2000) because every step of it is a grid operation of linear
//! cost, which is what the speed target needs (10 M points in about a second), and because
//! it scored best of the three with a single parameter set on the ISPRS filter test. Steps:
//!
//! 1. the minimum surface: the lowest point of every cell of a grid of `cell_size`; empty
//!    cells stay unknown (not inpainted: see step 3);
//! 2. low outliers: cells more than 5 × `cell_size` below the closing of their measured
//!    3 × 3 neighbourhood are dropped (multipath returns under the ground);
//! 3. the progressive opening of the measured cells (an empty cell within one point spacing
//!    of a point takes the nearest point's height, `ground_refine::nearest_fill`; a wider
//!    gap is each pass's identity, so a window judges a point only once it reaches the
//!    point's neighbours): openings by square windows of radius 1, 2, … cells up to
//!    `window`, each applied to the previous one; a cell that one opening lowers by more
//!    than `slope` × the window radius is an object cell; then hysteresis (the two-threshold
//!    linking of Canny, "A computational approach to edge detection", 1986): a connected
//!    region of object cells stays an object only when it holds a cell some opening lowers
//!    by more than `sure_slope` × the radius; other regions are terrain the low threshold
//!    cut (quarry rims, embankments, crests of steep slopes) and are ground again; then
//!    object cells held up by ground at their height in two opposite directions are ground
//!    again too (`ground_refine::readmit_supported`: crests cut along their line);
//! 4. the provisional DEM: the minimum surface without the object, low and empty cells,
//!    inpainted;
//! 5. the final test: a point is ground when it lies within `threshold` +
//!    `scalar` × (the DEM's slope at the point) of the DEM, interpolated bilinearly;
//! 6. ours: a ground point more than a small tolerance above the least-squares plane of
//!    the ground points around it is an object after all (`ground_plane`: low vegetation
//!    the wide final test lets through).
//!
//! Where this differs from the paper: the windows are squares (separable, so an erosion
//! costs three comparisons a cell whatever its size; van Herk 1992, Gil & Werman 1993)
//! instead of discs; the inpainting is the membrane surface instead of the spring
//! metaphor of D'Errico's inpaint_nans, and the openings work on the measured cells, not on
//! the inpainted minimum surface (on the ISPRS samples: mean kappa 84.8 % → 86.3 %, the
//! sparse quarry samp53 52.8 % → 63.3 %); the final test is one-sided above the DEM and twice as
//! wide below it (a point below the provisional ground is ground unless far below: the
//! minimum surface is already the lowest return of its cell); the hysteresis of step 3 is
//! ours (a single slope is either too low for steep terrain, cutting its rims, or too high
//! for flat towns, leaving low buildings: on the ISPRS samples it raised the mean kappa from
//! 83.8 % with the single slope 0.25 to 84.8 %); and the cell is derived from the point
//! spacing.
//!
//! Every length is given in metres and converted to the data's units with the CRS's
//! metres-per-unit (Autzen is in international feet).

use super::ground_plane as plane;
use super::ground_refine as refine;
use super::voidfill;
use crate::error::{Error, Result};
use crate::points::Bounds;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU32, Ordering};

/// The ground classification method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum GroundMethod {
    /// Simple morphological filter (Pingel, Clarke & McBride 2013).
    #[default]
    Smrf,
}

/// What the heightfield is built from when ground classification is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Surface {
    /// The ground points only: a bare-earth terrain model (DTM), the default: a game places
    /// buildings and trees as assets on the ground.
    #[default]
    Ground,
    /// Every point: a surface model (DSM) with roofs and crowns.
    All,
}

/// `[ground]`: ground classification.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct GroundParams {
    /// Run the stage.
    pub enabled: bool,
    /// The method (`smrf`).
    pub method: GroundMethod,
    /// `ground` (DTM, default) or `all` (DSM): the points the heightfield is built from.
    pub surface: Surface,
    /// Write the input points with class 2 (ground) / 1 (not ground) to
    /// `<output>/classified.las`.
    pub write_classified: bool,
    /// Take the points the file already classifies as ground (class 2) instead of
    /// classifying; files without class 2 points are classified.
    pub trust_existing: bool,
    /// Edge of the grid cells in metres (default: derived from the point spacing).
    pub cell_size: Option<f64>,
    /// Largest window radius of the progressive opening in metres: objects up to about
    /// twice this wide are removed (default 18 m).
    pub window: Option<f64>,
    /// Terrain slope the opening tolerates, rise over run (default 0.2).
    pub slope: Option<f64>,
    /// Slope of the hysteresis: a region of object cells stays an object only when the
    /// opening lowers one of its cells by more than this slope × the window radius (default
    /// 0.5; a value ≤ `slope` turns the hysteresis off).
    pub sure_slope: Option<f64>,
    /// Elevation threshold of the final test in metres (default 0.5 m).
    pub threshold: Option<f64>,
    /// Elevation scalar of the final test: metres of tolerance added per unit of the
    /// terrain slope at the point (default 1.25 m).
    pub scalar: Option<f64>,
    /// Empty cells within this many point spacings of a point take the nearest point's
    /// height before the openings (default 1; 0 turns the gap fill off).
    pub gap_fill: Option<f64>,
    /// Radius of the crest test in point spacings (or cells, when a cell is wider): an
    /// object cell is ground again when ground cells this near reach its height in two
    /// opposite directions (default 1.5; 0 turns the test off).
    pub support_radius: Option<f64>,
    /// Height tolerance of a supporting ground cell in metres (default 0.3 m) …
    pub support_tolerance: Option<f64>,
    /// … plus this many metres per metre of distance to it (default 0.2).
    pub support_slope: Option<f64>,
    /// How far the openings' windows reach past the grid's edge, as a share of `window`
    /// (default 0: not at all; 1: the outside is a gap like any other).
    pub edge_reach: Option<f64>,
    /// Radius of the last step's plane fit, point spacings (default 2.5; 0 turns the step
    /// off): a ground point above the plane of its ground neighbours is an object.
    pub plane_radius: Option<f64>,
    /// Height above that plane beyond which a point is an object, metres (default 0.25) …
    pub plane_threshold: Option<f64>,
    /// … plus this many times the plane's RMS misfit (default 2) …
    pub plane_rms: Option<f64>,
    /// … plus this many point spacings per unit of the plane's slope (default 0.15).
    pub plane_slope: Option<f64>,
    /// Rounds of the plane step (default 2).
    pub plane_rounds: Option<usize>,
}

impl Default for GroundParams {
    fn default() -> Self {
        GroundParams {
            enabled: false,
            method: GroundMethod::Smrf,
            surface: Surface::Ground,
            write_classified: false,
            trust_existing: false,
            cell_size: None,
            window: None,
            slope: None,
            sure_slope: None,
            threshold: None,
            scalar: None,
            gap_fill: None,
            support_radius: None,
            support_tolerance: None,
            support_slope: None,
            edge_reach: None,
            plane_radius: None,
            plane_threshold: None,
            plane_rms: None,
            plane_slope: None,
            plane_rounds: None,
        }
    }
}

/// Default (and smallest default) cell edge, metres: SMRF's 1 m. Sparser surveys than one
/// point per 16 m² get a quarter of their point spacing.
pub const DEFAULT_CELL: f64 = 1.0;
/// Default slope tolerance of the opening, rise over run.
pub const DEFAULT_SLOPE: f64 = 0.2;
/// Default slope of the hysteresis (an object region must hold a cell this steep a cut).
pub const DEFAULT_SURE_SLOPE: f64 = 0.5;
/// Default largest window radius, metres.
pub const DEFAULT_WINDOW: f64 = 18.0;
/// Default elevation threshold, metres.
pub const DEFAULT_THRESHOLD: f64 = 0.5;
/// Default elevation scalar, metres per unit slope.
pub const DEFAULT_SCALAR: f64 = 1.25;
/// Default reach of the openings past the grid's edge, share of `window`.
pub const DEFAULT_EDGE_REACH: f64 = 0.0;
/// Largest grid the stage builds (cells): a cell size this fine for the extent is refused.
pub const MAX_CELLS: usize = 1 << 30;

/// The parameters as used, every default resolved, in metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GroundSettings {
    /// Cell edge, metres.
    pub cell_size: f64,
    /// Largest window radius, metres.
    pub window: f64,
    /// Slope, rise over run.
    pub slope: f64,
    /// Hysteresis slope, rise over run.
    pub sure_slope: f64,
    /// Elevation threshold, metres.
    pub threshold: f64,
    /// Elevation scalar, metres per unit slope.
    pub scalar: f64,
    /// Reach of the gap fill, point spacings.
    pub gap_fill: f64,
    /// Radius of the crest test, point spacings.
    pub support_radius: f64,
    /// Height tolerance of a supporting cell, metres.
    pub support_tolerance: f64,
    /// Added tolerance per metre of distance, metres per metre.
    pub support_slope: f64,
    /// Reach of the windows past the grid's edge, share of `window`.
    pub edge_reach: f64,
    /// Radius of the plane step, point spacings (0: off).
    pub plane_radius: f64,
    /// Height above the plane that makes an object, metres …
    pub plane_threshold: f64,
    /// … plus this many times the plane's RMS misfit …
    pub plane_rms: f64,
    /// … plus this many point spacings per unit of its slope.
    pub plane_slope: f64,
    /// Rounds of the plane step.
    pub plane_rounds: usize,
}

/// The result of [`classify`].
#[derive(Debug, Clone)]
pub struct Ground {
    /// Per input point: classified as ground.
    pub ground: Vec<bool>,
    /// Number of ground points.
    pub ground_count: usize,
    /// The settings used.
    pub settings: GroundSettings,
    /// Grid size (cols, rows) of the minimum surface.
    pub grid: [usize; 2],
}

/// Which values a key takes, and what its error says otherwise.
type Rule = (fn(f64) -> bool, &'static str);
/// A positive, finite number.
const POSITIVE: Rule = (
    |v| v > 0.0 && v.is_finite(),
    "must be a positive, finite number",
);
/// A finite number ≥ 0.
const NON_NEGATIVE: Rule = (|v| v >= 0.0 && v.is_finite(), "must be a finite number ≥ 0");
/// A share, 0 to 1.
const SHARE: Rule = (|v| (0.0..=1.0).contains(&v), "must be a number from 0 to 1");

impl GroundParams {
    /// Checks the values a user can get wrong, before any data is read: the first key
    /// whose value breaks its rule is named.
    pub fn validate(&self) -> Result<()> {
        let keys = [
            ("cell_size", self.cell_size, POSITIVE),
            ("window", self.window, POSITIVE),
            ("slope", self.slope, POSITIVE),
            ("sure_slope", self.sure_slope, POSITIVE),
            ("threshold", self.threshold, POSITIVE),
            ("gap_fill", self.gap_fill, NON_NEGATIVE),
            ("support_radius", self.support_radius, NON_NEGATIVE),
            ("support_tolerance", self.support_tolerance, NON_NEGATIVE),
            ("support_slope", self.support_slope, NON_NEGATIVE),
            ("plane_radius", self.plane_radius, NON_NEGATIVE),
            ("plane_threshold", self.plane_threshold, NON_NEGATIVE),
            ("plane_rms", self.plane_rms, NON_NEGATIVE),
            ("plane_slope", self.plane_slope, NON_NEGATIVE),
            ("edge_reach", self.edge_reach, SHARE),
            ("scalar", self.scalar, NON_NEGATIVE),
        ];
        for (name, v, (ok, what)) in keys {
            if let Some(v) = v.filter(|v| !ok(*v)) {
                return Err(Error::param("ground", name, v, what));
            }
        }
        Ok(())
    }
}

/// A grid of `cell` (data units) over a box, corner at `origin`.
#[derive(Debug, Clone, Copy)]
struct Grid {
    cols: usize,
    rows: usize,
    origin: [f64; 2],
    cell: f64,
}

impl Grid {
    /// Cell coordinates (fractional, cell centres at whole numbers) of world (x, y).
    #[inline]
    fn at(&self, x: f64, y: f64) -> (f64, f64) {
        (
            (x - self.origin[0]) / self.cell - 0.5,
            (y - self.origin[1]) / self.cell - 0.5,
        )
    }

    #[inline]
    fn index(&self, x: f64, y: f64) -> usize {
        let i = (((x - self.origin[0]) / self.cell) as usize).min(self.cols - 1);
        let j = (((y - self.origin[1]) / self.cell) as usize).min(self.rows - 1);
        j * self.cols + i
    }
}

/// Order-preserving map of an f32 to a u32 (for an atomic minimum).
#[inline]
fn key(v: f32) -> u32 {
    let b = v.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

#[inline]
fn unkey(k: u32) -> f32 {
    f32::from_bits(if k & 0x8000_0000 != 0 {
        k & 0x7fff_ffff
    } else {
        !k
    })
}

/// Points per parallel work item of the per-point passes.
const POINT_CHUNK: usize = 1 << 15;

/// Surveys of fewer points than this are classified on one thread ([`classify`]).
const SEQUENTIAL_POINTS: usize = 1 << 14;

/// One worker for the surveys of fewer than [`SEQUENTIAL_POINTS`] points, made once.
fn sequential_pool() -> Option<&'static rayon::ThreadPool> {
    static POOL: std::sync::OnceLock<Option<rayon::ThreadPool>> = std::sync::OnceLock::new();
    POOL.get_or_init(|| rayon::ThreadPoolBuilder::new().num_threads(1).build().ok())
        .as_ref()
}

/// Classifies the points (x, y, z) whose `keep` flag is set (all when `None`) into ground and
/// not ground. `metres_per_unit` converts the data's units to metres (1 for metric data).
/// Errors: bad parameters, no points, a grid too large, or no ground found.
///
/// A survey of fewer than [`SEQUENTIAL_POINTS`] points (the smallest ISPRS samples, a grid of
/// about 15,000 cells) is classified on one worker: its parallel passes are so short that
/// handing their halves between two threads cost more than they saved (samp21: 5.7 ms of
/// CPU time on one thread against 8 ms of wall time on two). Every step gives the same
/// result for any thread count, so the result is the same.
pub fn classify(
    x: &[f64],
    y: &[f64],
    z: &[f64],
    keep: Option<&[bool]>,
    params: &GroundParams,
    metres_per_unit: f64,
) -> Result<Ground> {
    let run = || classify_here([x, y, z], keep, params, metres_per_unit);
    match sequential_pool() {
        Some(pool) if x.len() < SEQUENTIAL_POINTS && rayon::current_num_threads() > 1 => {
            pool.install(run)
        }
        _ => run(),
    }
}

/// [`classify`] on the current thread pool.
fn classify_here(
    [x, y, z]: [&[f64]; 3],
    keep: Option<&[bool]>,
    params: &GroundParams,
    metres_per_unit: f64,
) -> Result<Ground> {
    params.validate()?;
    let (b, n) = super::bounds_of(x, y, z, keep);
    if n == 0 {
        return Err(Error::param(
            "ground",
            "enabled",
            "true",
            "no points to classify",
        ));
    }
    let Scale {
        grid,
        mpu,
        spacing_m,
        cell_m,
    } = Scale::of(&b, n, params.cell_size, metres_per_unit)?;
    let (cols, rows, cell) = (grid.cols, grid.rows, grid.cell);
    let zref = b.min[2];
    // 1. Minimum surface, heights in metres above zref.
    let zmin = min_surface(x, y, z, keep, &grid, zref, mpu);
    let empty: Vec<bool> = zmin.par_iter().map(|v| v.is_nan()).collect();
    // 2. Low outliers.
    let low = low_outliers(&zmin, cols, rows, cell_m);
    // The measured cells that are not low; every other cell unknown (+∞, the erosion's
    // identity): not inpainted, see `progressive_object_mask`.
    let mut base: Vec<f32> = zmin
        .par_iter()
        .zip(&low)
        .map(|(v, l)| if *l || v.is_nan() { f32::INFINITY } else { *v })
        .collect();
    // The gaps between points (up to one spacing) take the nearest height: see
    // `ground_refine`.
    let gap_fill = params.gap_fill.unwrap_or(refine::DEFAULT_GAP_FILL);
    if gap_fill > 0.0 {
        let reach = refine::fill_reach(gap_fill * spacing_m, cell_m);
        refine::nearest_fill(&mut base, cols, rows, reach);
    }
    let window_m = params.window.unwrap_or(DEFAULT_WINDOW);
    let radius = ((window_m / cell_m).ceil() as usize).max(1);
    let slope = params.slope.unwrap_or(DEFAULT_SLOPE);
    let sure_slope = params.sure_slope.unwrap_or(DEFAULT_SURE_SLOPE);
    // 3. Progressive opening, then hysteresis over the measured cells.
    let edge_reach = params.edge_reach.unwrap_or(DEFAULT_EDGE_REACH);
    let pad = ((edge_reach * radius as f64).round() as usize).min(radius);
    let (mut object, sure) = progressive_object_mask(
        &base,
        [cols, rows],
        radius,
        pad,
        [slope, sure_slope],
        cell_m,
    );
    if sure_slope > slope {
        hysteresis(&mut object, &sure, &empty, cols, rows);
    }
    // Crests, rims and embankments the openings cut are ground again where ground holds them
    // up on two opposite sides: see `ground_refine`.
    let support = readmit_crests(
        params,
        &mut object,
        [&empty, &low],
        &zmin,
        [cols, rows],
        [spacing_m, cell_m],
    );
    // 4. Provisional DEM.
    let surf = provisional_dem(&zmin, [&empty, &low, &object], [cols, rows], cell_m)?;
    // 5. Final test per point.
    let threshold = params.threshold.unwrap_or(DEFAULT_THRESHOLD);
    let scalar = params.scalar.unwrap_or(DEFAULT_SCALAR);
    let (mut ground, count) = final_test(
        [x, y, z],
        keep,
        &grid,
        &surf,
        [zref, mpu],
        [threshold, scalar],
    );
    // 6. Points above the plane of their ground neighbours: see `ground_plane`.
    let test = plane::PlaneTest {
        radius: params.plane_radius.unwrap_or(plane::DEFAULT_RADIUS),
        threshold: params.plane_threshold.unwrap_or(plane::DEFAULT_THRESHOLD),
        rms: params.plane_rms.unwrap_or(plane::DEFAULT_RMS),
        slope: params.plane_slope.unwrap_or(plane::DEFAULT_SLOPE),
        rounds: params.plane_rounds.unwrap_or(plane::DEFAULT_ROUNDS),
    };
    let mut count = count;
    if test.radius > 0.0 && test.rounds > 0 {
        let cells = plane::Cells {
            cols,
            rows,
            origin: grid.origin,
            cell,
            zref,
            mpu,
        };
        count -= plane::drop_above_plane(x, y, z, &mut ground, &cells, spacing_m, cell_m, &test);
    }
    if count == 0 {
        return Err(Error::param(
            "ground",
            "enabled",
            "true",
            "no ground found: no point lies on the provisional ground surface",
        ));
    }
    Ok(Ground {
        ground,
        ground_count: count,
        settings: GroundSettings {
            cell_size: cell_m,
            window: window_m,
            slope,
            sure_slope,
            threshold,
            scalar,
            gap_fill,
            support_radius: support.radius,
            support_tolerance: support.tolerance,
            support_slope: support.slope,
            edge_reach,
            plane_radius: test.radius,
            plane_threshold: test.threshold,
            plane_rms: test.rms,
            plane_slope: test.slope,
            plane_rounds: test.rounds,
        },
        grid: [cols, rows],
    })
}

/// The classifier's lattice and scales for one survey.
struct Scale {
    grid: Grid,
    /// Metres per data unit.
    mpu: f64,
    /// Mean point spacing in metres (from the bounds' area and the count).
    spacing_m: f64,
    /// Cell size in metres.
    cell_m: f64,
}

impl Scale {
    /// The grid of `cell_size` metres (default: a quarter of the mean spacing, at least
    /// [`DEFAULT_CELL`]) over bounds `b` of `n` points; an error when it would hold more
    /// than [`MAX_CELLS`] cells.
    fn of(b: &Bounds, n: usize, cell_size: Option<f64>, metres_per_unit: f64) -> Result<Scale> {
        let mpu = if metres_per_unit > 0.0 && metres_per_unit.is_finite() {
            metres_per_unit
        } else {
            1.0
        };
        let area_m2 = ((b.max[0] - b.min[0]) * (b.max[1] - b.min[1])).max(0.0) * mpu * mpu;
        let spacing_m = (area_m2 / n as f64).sqrt();
        let cell_m = cell_size.unwrap_or((spacing_m / 4.0).max(DEFAULT_CELL));
        let cell = cell_m / mpu;
        let cols = (((b.max[0] - b.min[0]) / cell).floor() as usize).saturating_add(1);
        let rows = (((b.max[1] - b.min[1]) / cell).floor() as usize).saturating_add(1);
        if cols.saturating_mul(rows) > MAX_CELLS {
            return Err(Error::param(
                "ground",
                "cell_size",
                cell_m,
                format!(
                    "makes a grid of {cols} × {rows} cells for this survey, more than {MAX_CELLS}"
                ),
            ));
        }
        let grid = Grid {
            cols,
            rows,
            origin: [b.min[0], b.min[1]],
            cell,
        };
        Ok(Scale {
            grid,
            mpu,
            spacing_m,
            cell_m,
        })
    }
}

/// The crests, rims and embankments the openings cut become ground again where ground
/// holds them up on two opposite sides (`ground_refine`); returns the settings used (radius
/// in spacings).
fn readmit_crests(
    params: &GroundParams,
    object: &mut [bool],
    [empty, low]: [&[bool]; 2],
    zmin: &[f32],
    [cols, rows]: [usize; 2],
    [spacing_m, cell_m]: [f64; 2],
) -> refine::Support {
    let support = refine::Support {
        radius: params
            .support_radius
            .unwrap_or(refine::DEFAULT_SUPPORT_RADIUS),
        tolerance: params
            .support_tolerance
            .unwrap_or(refine::DEFAULT_SUPPORT_TOLERANCE),
        slope: params
            .support_slope
            .unwrap_or(refine::DEFAULT_SUPPORT_SLOPE),
    };
    if support.radius > 0.0 {
        let live: Vec<bool> = empty.par_iter().zip(low).map(|(e, l)| !e && !l).collect();
        let radius_m = support.radius * spacing_m.max(cell_m);
        let in_metres = refine::Support {
            radius: radius_m,
            ..support
        };
        refine::readmit_supported(object, &live, zmin, cols, rows, cell_m, in_metres);
    }
    support
}

/// SMRF's provisional DEM: the minimum surface without its empty, low and object cells,
/// inpainted, with its slope beside each height (the per-point test reads both at the same
/// four cells). An error when no cell is left.
fn provisional_dem(
    zmin: &[f32],
    [empty, low, object]: [&[bool]; 3],
    [cols, rows]: [usize; 2],
    cell_m: f64,
) -> Result<Vec<[f32; 2]>> {
    let mut dem: Vec<f32> = (0..zmin.len())
        .into_par_iter()
        .map(|k| {
            if empty[k] || low[k] || object[k] {
                f32::NAN
            } else {
                zmin[k]
            }
        })
        .collect();
    if dem.iter().all(|v| v.is_nan()) {
        return Err(Error::param(
            "ground",
            "enabled",
            "true",
            "no ground found: every cell of the minimum surface is an object or an outlier",
        ));
    }
    inpaint(&mut dem, cols, rows);
    let grad = slope_map(&dem, cols, rows, cell_m);
    // Height and slope side by side: the per-point test reads both at the same four cells.
    Ok(dem.par_iter().zip(&grad).map(|(d, g)| [*d, *g]).collect())
}

/// SMRF's low outliers: a cell far (5 cells' width) below the closing of its measured 3 × 3
/// neighbourhood (an empty cell is the identity of each pass, see `progressive_object_mask`).
fn low_outliers(zmin: &[f32], cols: usize, rows: usize, cell_m: f64) -> Vec<bool> {
    let neg: Vec<f32> = zmin
        .par_iter()
        .map(|v| if v.is_nan() { f32::INFINITY } else { -v })
        .collect();
    let closed = open(&neg, cols, rows, 1);
    let low_limit = (5.0 * cell_m) as f32;
    neg.par_iter()
        .zip(&closed)
        .map(|(n, o)| n - o > low_limit)
        .collect()
}

/// SMRF's final test per point: ground where the point lies within `threshold + scalar ×
/// slope` above the provisional DEM (`surf`: height and slope per cell, read bilinearly)
/// and not more than twice that below it. Returns the flags and how many are set.
fn final_test(
    [x, y, z]: [&[f64]; 3],
    keep: Option<&[bool]>,
    grid: &Grid,
    surf: &[[f32; 2]],
    [zref, mpu]: [f64; 2],
    [threshold, scalar]: [f64; 2],
) -> (Vec<bool>, usize) {
    let mut ground = vec![false; x.len()];
    let count: usize = ground
        .par_chunks_mut(POINT_CHUNK)
        .enumerate()
        .map(|(c, out)| {
            let s = c * POINT_CHUNK;
            let mut count = 0;
            for (k, g) in out.iter_mut().enumerate() {
                let p = s + k;
                if keep.is_some_and(|kp| !kp[p]) {
                    continue;
                }
                let (fi, fj) = grid.at(x[p], y[p]);
                let [d, s] = bilinear2(surf, grid.cols, grid.rows, fi, fj);
                let h = ((z[p] - zref) * mpu) as f32 - d;
                let t = (threshold + scalar * s as f64) as f32;
                if h <= t && h >= -2.0 * t {
                    *g = true;
                    count += 1;
                }
            }
            count
        })
        .sum();
    (ground, count)
}

/// The lowest point of every cell, in metres above `zref` (NaN: no point).
fn min_surface(
    x: &[f64],
    y: &[f64],
    z: &[f64],
    keep: Option<&[bool]>,
    grid: &Grid,
    zref: f64,
    mpu: f64,
) -> Vec<f32> {
    let cells: Vec<AtomicU32> = (0..grid.cols * grid.rows)
        .into_par_iter()
        .map(|_| AtomicU32::new(u32::MAX))
        .collect();
    (0..x.len().div_ceil(POINT_CHUNK))
        .into_par_iter()
        .for_each(|c| {
            for p in c * POINT_CHUNK..((c + 1) * POINT_CHUNK).min(x.len()) {
                if keep.is_some_and(|k| !k[p]) {
                    continue;
                }
                let v = ((z[p] - zref) * mpu) as f32;
                cells[grid.index(x[p], y[p])].fetch_min(key(v), Ordering::Relaxed);
            }
        });
    cells
        .into_par_iter()
        .map(|a| {
            let k = a.into_inner();
            if k == u32::MAX {
                f32::NAN
            } else {
                unkey(k)
            }
        })
        .collect()
}

/// Membrane inpainting of the NaN cells (to 1 cm: the tests that follow are in decimetres).
fn inpaint(z: &mut [f32], cols: usize, rows: usize) {
    voidfill::membrane_fill(z, cols, rows, 1e-2);
}

/// Cells that some opening of the progressive series lowers by more than the slope
/// threshold (slope × radius × cell), for the two slopes `[slope, sure_slope]`: the object
/// cells and the sure object cells.
///
/// The series opens each opening again with the next window (the paper's order), but an
/// opening by a square of radius r of the opening by radius r − 1 is the opening by radius
/// r of the base (the squares are nested: a square of radius r is a union of squares of
/// radius r − 1, so the openings form a granulometry; Matheron 1975), and the erosion by a
/// square of radius r is the erosion of the radius r − 1 erosion by the 3 × 3 square. So
/// each step erodes the previous erosion by 3 × 3 (two short passes) and dilates it once by
/// radius r: two passes of the running extremum instead of four. Min and max are exact, so
/// the result is the same bits as opening the previous opening (tested against that).
///
/// The base holds the measured cells only; an unknown cell is +∞, the erosion's identity, so
/// a window's erosion is the lowest measured cell in it (+∞ where it holds none, which the
/// dilation's maximum then carries; the opening of a measured cell is always finite, at most
/// its own height). In a survey sparser than the grid a window judges a cell only once it
/// reaches the cell's measured neighbours: the first window that matters spans the point
/// spacing, whatever the cell. Inpainting before the opening (the paper's order) made every
/// isolated point a spike of the membrane between points, and on a convex break (a quarry's
/// rim, the crest of an embankment) the 3 × 3 opening cut those spikes like vegetation. The
/// flags of unknown cells mean nothing (they are left out of the DEM and of the hysteresis).
///
/// The base is padded with `p` unknown cells on every side (`edge_reach`), so that the
/// windows centred up to `p` cells past the grid's edge (holding only the cells inside it)
/// take part in the opening as they would around a gap inside the survey. Clipped at the
/// edge (`p` = 0), a slope rising to the edge loses its top row to the larger windows: the
/// windows centred beyond the edge, the only ones whose minimum is the edge cell itself, are
/// missing; padded, a building cut by the edge looks like a plateau to them.
fn progressive_object_mask(
    base: &[f32],
    [cols, rows]: [usize; 2],
    radius: usize,
    p: usize,
    slopes: [f64; 2],
    cell_m: f64,
) -> (Vec<bool>, Vec<bool>) {
    if p == 0 {
        return progressive_object_mask_clipped(base, cols, rows, radius, slopes, cell_m);
    }
    let (pc, pr) = (cols + 2 * p, rows + 2 * p);
    let mut padded = vec![f32::INFINITY; pc * pr];
    padded
        .par_chunks_mut(pc)
        .skip(p)
        .zip(base.par_chunks(cols))
        .for_each(|(out, row)| out[p..p + cols].copy_from_slice(row));
    let (object, sure) = progressive_object_mask_clipped(&padded, pc, pr, radius, slopes, cell_m);
    let crop = |m: Vec<bool>| -> Vec<bool> {
        m.chunks(pc)
            .skip(p)
            .take(rows)
            .flat_map(|row| row[p..p + cols].iter().copied())
            .collect()
    };
    (crop(object), crop(sure))
}

/// [`progressive_object_mask`] with the windows clipped at the grid's edge.
///
/// Every pass runs down the columns with whole rows as the vectors (contiguous, and
/// vectorised by the compiler): the erosion by 3 × 3 in the grid's own layout, the
/// dilation's vertical pass there too, then one transpose, and its horizontal pass down the
/// columns of the transposed grid, where the openings are kept and compared (the masks are
/// transposed back once at the end). A horizontal pass along the rows is a chain of
/// dependent comparisons per row, which no vector unit shortens; on the ISPRS samples it
/// was half of the opening's time.
fn progressive_object_mask_clipped(
    base: &[f32],
    cols: usize,
    rows: usize,
    radius: usize,
    slopes: [f64; 2],
    cell_m: f64,
) -> (Vec<bool>, Vec<bool>) {
    let n = base.len();
    // Transposed layout (`rows` columns, `cols` rows): the current opening and the masks.
    let mut object_t = vec![false; n];
    let mut sure_t = vec![false; n];
    let mut cur_t = vec![0.0f32; n];
    transpose(base, &mut cur_t, cols, rows);
    let mut eroded = base.to_vec();
    let (mut tmp, mut tmp_t, mut next_t) = (vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]);
    for r in 1..=radius {
        erode3(&mut eroded, &mut tmp, cols, rows);
        run_down(
            &eroded,
            &mut tmp,
            cols,
            rows,
            r,
            f32::NEG_INFINITY,
            f32::max,
        );
        transpose(&tmp, &mut tmp_t, cols, rows);
        run_down(
            &tmp_t,
            &mut next_t,
            rows,
            cols,
            r,
            f32::NEG_INFINITY,
            f32::max,
        );
        let t = slopes.map(|s| (s * r as f64 * cell_m) as f32);
        object_t
            .par_chunks_mut(CHUNK)
            .zip(sure_t.par_chunks_mut(CHUNK))
            .zip(cur_t.par_chunks(CHUNK).zip(next_t.par_chunks(CHUNK)))
            .for_each(|((o, su), (c, nx))| {
                for (((o, su), c), nx) in o.iter_mut().zip(su.iter_mut()).zip(c).zip(nx) {
                    let d = c - nx;
                    *o |= d > t[0];
                    *su |= d > t[1];
                }
            });
        std::mem::swap(&mut cur_t, &mut next_t);
    }
    let mut object = vec![false; n];
    let mut sure = vec![false; n];
    transpose(&object_t, &mut object, rows, cols);
    transpose(&sure_t, &mut sure, rows, cols);
    (object, sure)
}

/// Erodes `z` in place by the 3 × 3 square (clipped at the border): the minimum of each
/// cell and its neighbours, a row pass into `tmp`, then a column pass back.
fn erode3(z: &mut [f32], tmp: &mut [f32], cols: usize, rows: usize) {
    let band = band_rows(rows, cols);
    tmp.par_chunks_mut(band * cols)
        .zip(z.par_chunks(band * cols))
        .for_each(|(out, src)| {
            for (out, row) in out.chunks_mut(cols).zip(src.chunks(cols)) {
                min3_along(row, out);
            }
        });
    let tmp = &*tmp;
    z.par_chunks_mut(band * cols)
        .enumerate()
        .for_each(|(b, out)| {
            for (dj, out) in out.chunks_mut(cols).enumerate() {
                let j = b * band + dj;
                let (a, c) = (j.saturating_sub(1), (j + 1).min(rows - 1));
                let (ra, rj, rc) = (
                    &tmp[a * cols..(a + 1) * cols],
                    &tmp[j * cols..(j + 1) * cols],
                    &tmp[c * cols..(c + 1) * cols],
                );
                for (((o, a), b), c) in out.iter_mut().zip(ra).zip(rj).zip(rc) {
                    *o = a.min(*b).min(*c);
                }
            }
        });
}

/// The minimum of each cell of `row` and its two neighbours (clipped at the ends) into `out`.
fn min3_along(row: &[f32], out: &mut [f32]) {
    let n = row.len();
    if n == 1 {
        out[0] = row[0];
        return;
    }
    out[0] = row[0].min(row[1]);
    out[n - 1] = row[n - 2].min(row[n - 1]);
    for (((o, a), b), c) in out[1..n - 1]
        .iter_mut()
        .zip(&row[..n - 2])
        .zip(&row[1..n - 1])
        .zip(&row[2..])
    {
        *o = a.min(*b).min(*c);
    }
}

/// Cells per parallel task of the passes cell by cell.
const CHUNK: usize = 1 << 14;

/// Rows per parallel task of the passes over a grid `width` cells wide: about 2¹⁴ cells a
/// task, so that a small grid (the ISPRS samples hold 10⁴–2 × 10⁵ cells) is not cut into
/// tasks shorter than handing them to another thread costs.
fn band_rows(height: usize, width: usize) -> usize {
    (CHUNK / width.max(1)).clamp(1, height.max(1))
}

/// `dst` = `src` transposed: `src` is `height` rows of `width` cells, `dst` gets `width` rows
/// of `height`.
fn transpose<T: Copy + Send + Sync>(src: &[T], dst: &mut [T], width: usize, height: usize) {
    // Destination rows in blocks of 16: the reads of a block are 16 contiguous cells of each
    // source row.
    const BLOCK: usize = 16;
    let band = band_rows(width, height).next_multiple_of(BLOCK);
    dst.par_chunks_mut(band * height)
        .enumerate()
        .for_each(|(b, out)| {
            for (q, block) in out.chunks_mut(BLOCK * height).enumerate() {
                let i0 = b * band + q * BLOCK;
                let w = block.len() / height;
                for j in 0..height {
                    let src_row = &src[j * width + i0..j * width + i0 + w];
                    for (di, v) in src_row.iter().enumerate() {
                        block[di * height + j] = *v;
                    }
                }
            }
        });
}

/// Running min (or max) over windows of 2r + 1 rows down each column of the `height` ×
/// `width` grid `src` into `dst` (clipped at the top and bottom: the column is padded with
/// the operation's identity): van Herk / Gil-Werman, three comparisons a cell whatever r,
/// with whole rows as the vectors. `op` is generic (not a function pointer) so that it is
/// inlined. The padded column of n = height + 2r cells is cut into blocks of 2r + 1; g runs
/// forward from each block's start, h backward from its end, and the window of padded rows
/// p..=p + 2r is op(h[p], g[p + 2r]). The output rows are computed in bands, in parallel,
/// each from the padded rows it needs.
fn run_down(
    src: &[f32],
    dst: &mut [f32],
    width: usize,
    height: usize,
    r: usize,
    identity: f32,
    op: impl Fn(f32, f32) -> f32 + Sync + Copy,
) {
    let w = 2 * r + 1;
    let n = height + 2 * r;
    // A band recomputes up to a block at each end: at least four blocks a band.
    let band = band_rows(height, width).max(4 * w).min(height);
    // Padded row p is source row p − r, or the identity outside.
    let row = |p: usize| -> Option<&[f32]> {
        (p >= r && p < r + height).then(|| &src[(p - r) * width..(p - r + 1) * width])
    };
    dst.par_chunks_mut(band * width).enumerate().for_each_init(
        || (Vec::new(), vec![0.0f32; width], vec![0.0f32; width]),
        |(g, run, h), (b, out)| {
            let (b0, b1) = (b * band, b * band + out.len() / width);
            // g at padded rows b0 + 2r .. b1 + 2r, run from the start of the block of the
            // first.
            let (g0, g1) = (b0 + 2 * r, b1 + 2 * r);
            g.resize((g1 - g0) * width, 0.0);
            for p in (g0 / w) * w..g1 {
                match row(p) {
                    Some(v) if p % w != 0 => {
                        for (a, v) in run.iter_mut().zip(v) {
                            *a = op(*a, *v);
                        }
                    }
                    Some(v) => run.copy_from_slice(v),
                    None if p % w != 0 => {}
                    None => run.iter_mut().for_each(|a| *a = identity),
                }
                if p >= g0 {
                    g[(p - g0) * width..(p - g0 + 1) * width].copy_from_slice(run);
                }
            }
            // h backward from the end of the block of the band's last row; each output
            // row as it passes.
            let end = (((b1 - 1) / w + 1) * w).min(n);
            for p in (b0..end).rev() {
                let block_end = p + 1 == n || (p + 1) % w == 0;
                match row(p) {
                    Some(v) if !block_end => {
                        for (a, v) in h.iter_mut().zip(v) {
                            *a = op(*a, *v);
                        }
                    }
                    Some(v) => h.copy_from_slice(v),
                    None if !block_end => {}
                    None => h.iter_mut().for_each(|a| *a = identity),
                }
                if p < b1 {
                    let gp = &g[(p - b0) * width..(p - b0 + 1) * width];
                    let o = &mut out[(p - b0) * width..(p - b0 + 1) * width];
                    for ((o, h), g) in o.iter_mut().zip(h.iter()).zip(gp) {
                        *o = op(*h, *g);
                    }
                }
            }
        },
    );
}

/// Grey-scale opening by a square window of radius `r` cells (side 2r + 1, clipped at the
/// grid's border).
fn open(z: &[f32], cols: usize, rows: usize, r: usize) -> Vec<f32> {
    let n = z.len();
    let (mut a, mut b) = (vec![0.0f32; n], vec![0.0f32; n]);
    // Erosion: down the columns, then down the columns of the transpose; the dilation the
    // same way back.
    run_down(z, &mut a, cols, rows, r, f32::INFINITY, f32::min);
    transpose(&a, &mut b, cols, rows);
    run_down(&b, &mut a, rows, cols, r, f32::INFINITY, f32::min);
    run_down(&a, &mut b, rows, cols, r, f32::NEG_INFINITY, f32::max);
    transpose(&b, &mut a, rows, cols);
    run_down(&a, &mut b, cols, rows, r, f32::NEG_INFINITY, f32::max);
    b
}

/// Hysteresis: the object cells with a point (not `empty`) form regions by 4-connection; a
/// region without a `sure` cell is ground again. Empty cells keep their flag (they hold no
/// point, and only steer the DEM's inpainting). A sequential flood fill: it touches only
/// object cells, a small share of the grid, and its result does not depend on the order.
fn hysteresis(object: &mut [bool], sure: &[bool], empty: &[bool], cols: usize, rows: usize) {
    let live = |k: usize, o: &[bool]| o[k] && !empty[k];
    let mut seen = vec![false; object.len()];
    let (mut stack, mut region) = (Vec::new(), Vec::new());
    for s in 0..object.len() {
        if !live(s, object) || seen[s] {
            continue;
        }
        seen[s] = true;
        stack.push(s);
        region.clear();
        let mut keep = false;
        while let Some(k) = stack.pop() {
            region.push(k);
            keep |= sure[k];
            let (i, j) = (k % cols, k / cols);
            let nb = [
                (i > 0).then(|| k - 1),
                (i + 1 < cols).then(|| k + 1),
                (j > 0).then(|| k - cols),
                (j + 1 < rows).then(|| k + cols),
            ];
            for m in nb.into_iter().flatten() {
                if live(m, object) && !seen[m] {
                    seen[m] = true;
                    stack.push(m);
                }
            }
        }
        if !keep {
            for &k in &region {
                object[k] = false;
            }
        }
    }
}

/// Slope magnitude (rise over run) of every cell from central differences (one-sided at the
/// border).
fn slope_map(z: &[f32], cols: usize, rows: usize, cell_m: f64) -> Vec<f32> {
    let c = cell_m as f32;
    let mut g = vec![0.0f32; z.len()];
    g.par_chunks_mut(cols).enumerate().for_each(|(j, out)| {
        let (j0, j1) = (j.saturating_sub(1), (j + 1).min(rows - 1));
        for (i, o) in out.iter_mut().enumerate() {
            let (i0, i1) = (i.saturating_sub(1), (i + 1).min(cols - 1));
            let gx = if i1 > i0 {
                (z[j * cols + i1] - z[j * cols + i0]) / ((i1 - i0) as f32 * c)
            } else {
                0.0
            };
            let gy = if j1 > j0 {
                (z[j1 * cols + i] - z[j0 * cols + i]) / ((j1 - j0) as f32 * c)
            } else {
                0.0
            };
            *o = (gx * gx + gy * gy).sqrt();
        }
    });
    g
}

/// Bilinear interpolation of a cell-centred grid of value pairs at fractional cell
/// coordinates (clamped to the grid). After the clamp the coordinates are ≥ 0, so the
/// truncating cast is the floor (no call to libm's `floor`, which the baseline x86-64 target
/// does not inline).
#[inline]
fn bilinear2(z: &[[f32; 2]], cols: usize, rows: usize, fi: f64, fj: f64) -> [f32; 2] {
    let fi = fi.clamp(0.0, (cols - 1) as f64);
    let fj = fj.clamp(0.0, (rows - 1) as f64);
    let (i0, j0) = (fi as usize, fj as usize);
    let (i1, j1) = ((i0 + 1).min(cols - 1), (j0 + 1).min(rows - 1));
    let (tx, ty) = ((fi - i0 as f64) as f32, (fj - j0 as f64) as f32);
    let (c00, c10) = (z[j0 * cols + i0], z[j0 * cols + i1]);
    let (c01, c11) = (z[j1 * cols + i0], z[j1 * cols + i1]);
    std::array::from_fn(|k| {
        let a = c00[k] * (1.0 - tx) + c10[k] * tx;
        let b = c01[k] * (1.0 - tx) + c11[k] * tx;
        a * (1.0 - ty) + b * ty
    })
}

/// Ground classification scores against a reference (Sithole & Vosselman 2004): type I
/// (ground called object, share of the reference ground), type II (object called ground,
/// share of the reference objects), total error and Cohen's kappa, all as fractions.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Scores {
    /// Reference ground classified as object / reference ground.
    pub type1: f64,
    /// Reference object classified as ground / reference objects.
    pub type2: f64,
    /// Misclassified / all.
    pub total: f64,
    /// Cohen's kappa.
    pub kappa: f64,
    /// Points scored.
    pub points: usize,
}

impl Scores {
    /// Scores `ours` against `truth` (both per point: ground or not).
    pub fn of(ours: &[bool], truth: &[bool]) -> Scores {
        let (mut a, mut b, mut c, mut d) = (0usize, 0usize, 0usize, 0usize);
        for (o, t) in ours.iter().zip(truth) {
            match (t, o) {
                (true, true) => a += 1,
                (true, false) => b += 1,
                (false, true) => c += 1,
                (false, false) => d += 1,
            }
        }
        let n = (a + b + c + d) as f64;
        let (af, bf, cf, df) = (a as f64, b as f64, c as f64, d as f64);
        let po = (af + df) / n;
        let pe = ((af + bf) * (af + cf) + (cf + df) * (bf + df)) / (n * n);
        Scores {
            type1: if a + b > 0 { bf / (af + bf) } else { 0.0 },
            type2: if c + d > 0 { cf / (cf + df) } else { 0.0 },
            total: (bf + cf) / n,
            kappa: if pe < 1.0 {
                (po - pe) / (1.0 - pe)
            } else {
                1.0
            },
            points: a + b + c + d,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// The slow twin of [`open`]: a plain scan of every window.
    fn open_slow(z: &[f32], cols: usize, rows: usize, r: usize) -> Vec<f32> {
        let scan = |z: &[f32], init: f32, op: fn(f32, f32) -> f32| -> Vec<f32> {
            let mut out = vec![0.0; z.len()];
            for j in 0..rows {
                for i in 0..cols {
                    let mut v = init;
                    for jj in j.saturating_sub(r)..=(j + r).min(rows - 1) {
                        for ii in i.saturating_sub(r)..=(i + r).min(cols - 1) {
                            v = op(v, z[jj * cols + ii]);
                        }
                    }
                    out[j * cols + i] = v;
                }
            }
            out
        };
        let e = scan(z, f32::INFINITY, f32::min);
        scan(&e, f32::NEG_INFINITY, f32::max)
    }

    #[test]
    fn opening_equals_the_window_scan() {
        let mut rng = SplitMix64::new(7);
        for (cols, rows) in [(1, 1), (3, 1), (1, 5), (17, 9), (70, 33), (130, 71)] {
            // Some cells unknown (+∞, the erosion's identity), as `classify` passes them.
            let z: Vec<f32> = (0..cols * rows)
                .map(|_| {
                    if rng.unit() < 0.5 {
                        f32::INFINITY
                    } else {
                        rng.range(0.0, 10.0) as f32
                    }
                })
                .collect();
            for r in [1, 2, 3, 5, 9, 40] {
                assert_eq!(
                    open(&z, cols, rows, r),
                    open_slow(&z, cols, rows, r),
                    "{cols}×{rows} r {r}"
                );
            }
        }
    }

    /// The progressive mask (incremental erosions, one dilation a step) equals the paper's
    /// series: each window opens the previous opening, every opening a plain window scan.
    #[test]
    fn progressive_mask_equals_opening_the_previous_opening() {
        let mut rng = SplitMix64::new(11);
        // Dense grids, and sparse ones whose unknown cells are +∞ (as `classify` passes them).
        for ((cols, rows), unknown) in [(1, 1), (5, 1), (1, 7), (23, 17), (70, 41)]
            .into_iter()
            .flat_map(|s| [(s, 0.0), (s, 0.8)])
        {
            let z: Vec<f32> = (0..cols * rows)
                .map(|_| {
                    if rng.unit() < unknown {
                        f32::INFINITY
                    } else {
                        rng.range(0.0, 10.0) as f32
                    }
                })
                .collect();
            let (radius, slopes, cell) = (9, [0.15, 0.3], 1.0);
            for pad in [0, 4, radius] {
                // The grid inside `pad` unknown cells on every side (outside is a gap).
                let (pc, pr) = (cols + 2 * pad, rows + 2 * pad);
                let inside = |k: usize| {
                    let (i, j) = (k % pc, k / pc);
                    (pad..pad + cols).contains(&i) && (pad..pad + rows).contains(&j)
                };
                let mut cur = vec![f32::INFINITY; pc * pr];
                for k in (0..pc * pr).filter(|&k| inside(k)) {
                    cur[k] = z[(k / pc - pad) * cols + k % pc - pad];
                }
                let (mut object, mut sure) = (vec![false; pc * pr], vec![false; pc * pr]);
                for r in 1..=radius {
                    let next = open_slow(&cur, pc, pr, r);
                    for k in 0..pc * pr {
                        object[k] |= cur[k] - next[k] > (slopes[0] * r as f64 * cell) as f32;
                        sure[k] |= cur[k] - next[k] > (slopes[1] * r as f64 * cell) as f32;
                    }
                    cur = next;
                }
                let crop = |m: Vec<bool>| -> Vec<bool> {
                    (0..pc * pr).filter(|&k| inside(k)).map(|k| m[k]).collect()
                };
                let fast = progressive_object_mask(&z, [cols, rows], radius, pad, slopes, cell);
                assert_eq!(fast, (crop(object), crop(sure)), "{cols}×{rows} pad {pad}");
            }
        }
    }

    /// A plane rising to the grid's edge (steeper than the slope threshold) has no object
    /// cell: the windows beyond the edge hold its top row.
    #[test]
    fn a_slope_up_to_the_edge_is_not_cut() {
        let (cols, rows) = (40, 30);
        let z: Vec<f32> = (0..cols * rows)
            .map(|k| 0.6 * (k % cols) as f32 + 0.1 * (k / cols) as f32)
            .collect();
        let (object, sure) = progressive_object_mask(&z, [cols, rows], 12, 12, [0.2, 0.5], 1.0);
        assert!(!object.iter().any(|o| *o) && !sure.iter().any(|s| *s));
    }

    /// Two regions of object cells: one holds a sure cell and stays, the other does not and
    /// is ground again; an empty cell neither links regions nor loses its flag.
    #[test]
    fn hysteresis_keeps_regions_with_a_sure_cell() {
        // 6 × 3: region A = (0..2, row 0), region B = (3..6, row 0), linked only through the
        // empty cell 2; cell 4 of row 2 is an object alone.
        let (cols, rows) = (6, 3);
        let mut object = vec![false; cols * rows];
        for k in [0, 1, 2, 3, 4, 5, 16] {
            object[k] = true;
        }
        let mut empty = vec![false; cols * rows];
        empty[2] = true;
        let mut sure = vec![false; cols * rows];
        sure[1] = true;
        hysteresis(&mut object, &sure, &empty, cols, rows);
        let got: Vec<usize> = (0..cols * rows).filter(|&k| object[k]).collect();
        assert_eq!(got, vec![0, 1, 2]);
    }

    #[test]
    fn key_orders_like_f32() {
        let v = [-1e9f32, -3.5, -0.0, 0.0, 1e-30, 2.0, 7e20];
        for w in v.windows(2) {
            assert!(key(w[0]) <= key(w[1]));
            assert_eq!(unkey(key(w[0])), w[0]);
        }
    }

    /// Gently sloping ground with a few boxes (buildings) and noise-free points.
    fn scene(seed: u64) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<bool>) {
        let mut rng = SplitMix64::new(seed);
        let (mut x, mut y, mut z, mut t) = (vec![], vec![], vec![], vec![]);
        for _ in 0..40_000 {
            let (px, py) = (rng.range(0.0, 200.0), rng.range(0.0, 200.0));
            let g = 100.0 + 0.05 * px + 3.0 * (py / 40.0).sin();
            let building = ((px / 50.0).fract() < 0.4) && ((py / 50.0).fract() < 0.4);
            x.push(px);
            y.push(py);
            z.push(if building { g + 8.0 } else { g });
            t.push(!building);
        }
        (x, y, z, t)
    }

    #[test]
    fn buildings_are_not_ground() {
        let (x, y, z, truth) = scene(3);
        let g = classify(&x, &y, &z, None, &GroundParams::default(), 1.0).unwrap();
        let s = Scores::of(&g.ground, &truth);
        assert!(s.kappa > 0.95, "{s:?}");
    }

    #[test]
    fn same_result_for_any_thread_count() {
        let (x, y, z, _) = scene(5);
        let run = |t: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(t)
                .build()
                .unwrap()
                .install(|| {
                    classify(&x, &y, &z, None, &GroundParams::default(), 1.0)
                        .unwrap()
                        .ground
                })
        };
        let one = run(1);
        assert_eq!(one, run(2));
        assert_eq!(one, run(8));
    }

    #[test]
    fn small_survey_on_one_worker_equals_the_parallel_passes() {
        let (mut x, mut y, mut z, _) = scene(9);
        for v in [&mut x, &mut y, &mut z] {
            v.truncate(SEQUENTIAL_POINTS - 1);
        }
        let p = GroundParams::default();
        let parallel = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap()
            .install(|| classify_here([&x, &y, &z], None, &p, 1.0).unwrap().ground);
        assert_eq!(
            classify(&x, &y, &z, None, &p, 1.0).unwrap().ground,
            parallel
        );
    }

    #[test]
    fn kappa_of_a_known_table() {
        // 80 ground of which 8 missed, 20 objects of which 4 called ground.
        let truth: Vec<bool> = (0..100).map(|i| i < 80).collect();
        let ours: Vec<bool> = (0..100).map(|i| (8..84).contains(&i)).collect();
        let s = Scores::of(&ours, &truth);
        assert!((s.type1 - 0.1).abs() < 1e-12);
        assert!((s.type2 - 0.2).abs() < 1e-12);
        assert!((s.total - 0.12).abs() < 1e-12);
        // po = 0.88, pe = 0.8·0.76 + 0.2·0.24 = 0.656, kappa = 0.224/0.344.
        assert!((s.kappa - 0.224 / 0.344).abs() < 1e-12);
    }

    #[test]
    fn bad_parameters() {
        for (k, v) in [
            ("slope", 0.0),
            ("window", -1.0),
            ("cell_size", f64::NAN),
            ("threshold", 0.0),
        ] {
            let mut p = GroundParams::default();
            match k {
                "slope" => p.slope = Some(v),
                "window" => p.window = Some(v),
                "cell_size" => p.cell_size = Some(v),
                _ => p.threshold = Some(v),
            }
            let e = p.validate().unwrap_err().to_string();
            assert!(e.contains(k), "{e}");
        }
    }
}
