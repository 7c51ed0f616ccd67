//! Noise removal with the voxel-count pseudo-grid of Kim & Shin §2.1 (after Cho et
//! al. 2004), plus one per-column rule for detached low layers.
//!
//! **Pseudo-grid.** The bounding box is cut into voxels `voxel_size` wide (x and y) and
//! `voxel_height` tall. A point is noise when its voxel holds fewer than `min_points` points,
//! or, with `neighbourhood = true` (the default, as LAStools' `lasnoise` does), when the 3×3×3
//! block of voxels around its voxel does: counting the block spares genuine points that sit
//! near a voxel face, so the voxels can be small and the slab of space that passes the test
//! around a surface stays thin.
//!
//! **Data-derived defaults.** With the mean spacing s = sqrt(bbox area / N): voxel_size =
//! [`VOXEL_SIZE_FACTOR`]·s, so a flat, evenly sampled surface puts (voxel_size / s)² = 9
//! points in each voxel and 81 in a 3×3×3 block, and `min_points` defaults to a third of the
//! voxel's (a 27th of the block's) count: 3. The voxel height adapts to the survey's vertical
//! structure: it is q·s for the smallest whole q from 1 to [`MAX_HEIGHT_STEPS`] at which the
//! count test removes at most [`HEIGHT_LOSS`] of the points, not counting those isolated even
//! in the tallest voxels (noise at any height). Bare ground, roofs and most surveys get q = 1
//! (a thin slab passes around the surface); a dense forest, whose returns spread through the
//! crowns, gets taller voxels instead of losing its canopy.
//!
//! **Detached low layers.** Multipath reflections put dense, flat patches of points tens of
//! metres *below* the ground (CSite4 of the ISPRS test has a patch of 36 points 21 m under
//! the ground around it): locally dense, so no count test can remove them. Nothing real is
//! measured under the ground by an airborne scanner, so terratile also looks at the
//! z-profile of each column of about `low_gap` × `low_gap` (with its 8 neighbours): points
//! below an empty vertical gap of at least `low_gap` that hold less than `low_fraction` of
//! the window's points are removed. Only *low* layers are judged so; high ones (birds, haze)
//! are sparse and fail the count test, while detached high layers are often real (power
//! lines, bridges). The profiles are built from the points that passed the count, so
//! scattered noise cannot fill the gap that detaches a layer.
//!
//! **Speed.** One counting sort of the points by voxel column (parallel histogram, parallel
//! stable scatter), a small sort by layer inside each column, then per column a walk over its
//! voxels; only a voxel holding fewer than `min_points` looks at its 8 neighbour columns (a
//! merge-walk, since layers only grow). O(N), integer arithmetic only, so the result is the
//! same for every thread count. Memory: 8 bytes per point for the sorted keys, 2 for flags,
//! and 4 bytes per column per worker for the histograms.

use crate::error::{Error, Result};
use crate::points::{Bounds, PointCloud};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};

/// Default horizontal voxel edge in units of the mean point spacing.
pub const VOXEL_SIZE_FACTOR: f64 = 3.0;
/// Default vertical voxel edge in units of the mean point spacing.
pub const VOXEL_HEIGHT_FACTOR: f64 = 1.0;
/// Default `min_points` = this fraction of the points a flat, evenly sampled surface puts in
/// one voxel (with the neighbourhood, the same number is a 27th of its 3×3×3 block).
pub const MIN_POINTS_FRACTION: f64 = 1.0 / 3.0;
/// The automatic voxel height is at most this many mean spacings.
pub const MAX_HEIGHT_STEPS: u32 = 8;
/// The automatic voxel height is the smallest whole number of mean spacings at which the
/// count test removes at most this fraction of all points, not counting the points that are
/// isolated even in the tallest voxels (those are noise at any height).
pub const HEIGHT_LOSS: f64 = 0.01;
/// Default `low_gap` in metres (converted to the data's units through its CRS).
pub const LOW_GAP_METRES: f64 = 10.0;
/// Default `low_fraction`.
pub const LOW_FRACTION: f64 = 0.1;

/// `[denoise]`: the voxel-count noise filter.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct DenoiseParams {
    /// Run the stage (default true).
    pub enabled: bool,
    /// Horizontal voxel edge in the data's units (default 3 × mean point spacing).
    pub voxel_size: Option<f64>,
    /// Vertical voxel edge in the data's units (default 1 × mean point spacing).
    pub voxel_height: Option<f64>,
    /// A point is kept when its voxel (or 3×3×3 block) holds at least this many points
    /// (default: a 27th of what a flat, evenly sampled surface puts there; 3 with the other
    /// defaults).
    pub min_points: Option<u32>,
    /// Count the 3×3×3 block of voxels around a point's voxel instead of the voxel alone
    /// (default true).
    pub neighbourhood: bool,
    /// Remove detached low layers (multipath below the ground; default true).
    pub low_layers: bool,
    /// Smallest empty vertical gap, in the data's units, that detaches a low layer
    /// (default 10 m, converted through the CRS).
    pub low_gap: Option<f64>,
    /// A detached low layer is noise when it holds less than this fraction of the points of
    /// its column window (default 0.1).
    pub low_fraction: f64,
    /// Write the removed points to `noise.las` in the output directory, class 7 (default
    /// false).
    pub write_removed: bool,
}

impl Default for DenoiseParams {
    fn default() -> Self {
        DenoiseParams {
            enabled: true,
            voxel_size: None,
            voxel_height: None,
            min_points: None,
            neighbourhood: true,
            low_layers: true,
            low_gap: None,
            low_fraction: LOW_FRACTION,
            write_removed: false,
        }
    }
}

/// The settings a run used, after the data-derived defaults were filled in.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DenoiseSettings {
    /// Mean point spacing sqrt(bbox area / N), in data units.
    pub spacing: f64,
    /// Horizontal voxel edge.
    pub voxel_size: f64,
    /// Vertical voxel edge.
    pub voxel_height: f64,
    /// The automatic voxel height in mean spacings (1 when `voxel_height` was given).
    pub height_steps: u32,
    /// Minimum count of the voxel or block.
    pub min_points: u32,
    /// Whether the 3×3×3 block was counted.
    pub neighbourhood: bool,
    /// Gap that detaches a low layer (None: rule off).
    pub low_gap: Option<f64>,
    /// Fraction below which a detached low layer is noise.
    pub low_fraction: f64,
    /// Edge of the columns the low-layer rule looks at (a whole number of voxel columns).
    pub low_column: f64,
}

/// What noise removal decided.
#[derive(Debug, Clone, PartialEq)]
pub struct Denoised {
    /// One flag per input point: true to keep.
    pub keep: Vec<bool>,
    /// Points kept.
    pub kept: usize,
    /// Points removed by the count test.
    pub removed_sparse: usize,
    /// Points removed as detached low layers (and not already by the count test).
    pub removed_low: usize,
    /// Occupied voxels.
    pub voxels: usize,
    /// The settings used.
    pub settings: DenoiseSettings,
    /// The tight bounds of the kept points (what [`super::bounds_of`] measures over them),
    /// found while their flags were set, so that resampling needs no pass of its own (None
    /// for a shard).
    pub kept_bounds: Option<Bounds>,
}

impl Denoised {
    /// Points removed in all.
    pub fn removed(&self) -> usize {
        self.removed_sparse + self.removed_low
    }
}

fn check_positive(param: &'static str, v: Option<f64>) -> Result<()> {
    match v {
        Some(x) if !(x > 0.0 && x.is_finite()) => Err(Error::param(
            "denoise",
            param,
            x,
            "must be a positive, finite length in the data's units",
        )),
        _ => Ok(()),
    }
}

impl DenoiseParams {
    /// Checks the values a user can get wrong, before any data is read.
    pub fn validate(&self) -> Result<()> {
        check_positive("voxel_size", self.voxel_size)?;
        check_positive("voxel_height", self.voxel_height)?;
        check_positive("low_gap", self.low_gap)?;
        if self.min_points == Some(0) {
            return Err(Error::param(
                "denoise",
                "min_points",
                0,
                "must be at least 1",
            ));
        }
        if !(self.low_fraction > 0.0 && self.low_fraction <= 1.0) {
            return Err(Error::param(
                "denoise",
                "low_fraction",
                self.low_fraction,
                "must be in (0, 1]",
            ));
        }
        Ok(())
    }

    /// Fills in the data-derived defaults for `n` points in `bounds`, whose horizontal unit
    /// is `metres_per_unit` metres.
    pub fn resolve(
        &self,
        bounds: &Bounds,
        n: usize,
        metres_per_unit: f64,
    ) -> Result<DenoiseSettings> {
        self.validate()?;
        let [w, h, _] = bounds.size();
        let area = w * h;
        let spacing = if n > 0 && area > 0.0 && area.is_finite() {
            (area / n as f64).sqrt()
        } else {
            0.0
        };
        let derived = |param: &'static str, factor: f64, given: Option<f64>| -> Result<f64> {
            match given {
                Some(v) => Ok(v),
                None if spacing > 0.0 => Ok(factor * spacing),
                None if !area.is_finite() => Err(Error::param(
                    "denoise",
                    param,
                    "auto",
                    format!(
                        "the points span a range too large to measure (x {w}, y {h}): some \
                         coordinates are near the limits of a 64-bit float"
                    ),
                )),
                None => Err(Error::param(
                    "denoise",
                    param,
                    "auto",
                    format!(
                        "the points span a zero-width range (x {w}, y {h}): no mean spacing to \
                         derive it from; all points lie on one line or one spot"
                    ),
                )),
            }
        };
        let voxel_size = derived("voxel_size", VOXEL_SIZE_FACTOR, self.voxel_size)?;
        let voxel_height = derived("voxel_height", VOXEL_HEIGHT_FACTOR, self.voxel_height)?;
        let min_points = self.min_points.unwrap_or_else(|| {
            // What a flat surface sampled at the mean spacing puts in the counted block.
            let per_voxel = if spacing > 0.0 {
                (voxel_size / spacing).powi(2)
            } else {
                9.0
            };
            // A third of a flat voxel's points is a 27th of its 3×3×3 block (9 voxels' worth):
            // one number serves both counting modes.
            ((per_voxel * MIN_POINTS_FRACTION).round() as u32).max(2)
        });
        let low_gap = self.low_layers.then(|| {
            self.low_gap
                .unwrap_or(LOW_GAP_METRES / metres_per_unit.max(f64::MIN_POSITIVE))
        });
        let ratio = low_gap.map_or(1.0, |g| (g / voxel_size).round().max(1.0));
        Ok(DenoiseSettings {
            spacing,
            voxel_size,
            voxel_height,
            height_steps: 1,
            min_points,
            neighbourhood: self.neighbourhood,
            low_gap,
            low_fraction: self.low_fraction,
            low_column: ratio * voxel_size,
        })
    }
}

/// The voxel lattice over a bounding box.
///
/// When the box holds far more voxel columns than the points could occupy (one point far
/// from the rest stretches it), empty runs of low-layer columns are squeezed out: along each
/// axis the occupied low-layer column indices are renumbered so that a gap of two or more
/// empty low-layer columns becomes exactly two. Both the 3×3 voxel neighbourhood and the
/// 3×3 low-layer window only relate columns at most one low-layer column apart, so every
/// count and every floor is unchanged, while the bookkeeping is bounded by the points, not
/// by the box. (`reference::denoise` works on the uncompressed indices, [`Lattice::raw_cell`].)
#[derive(Debug, Clone)]
pub(crate) struct Lattice {
    origin: [f64; 3],
    inv: [f64; 3],
    /// Uncompressed columns along x and y.
    raw: [u64; 2],
    /// Columns along x and y (after compression).
    pub ncx: u32,
    pub ncy: u32,
    /// Voxel columns per low-layer column, along each axis.
    pub ratio: u32,
    /// Voxel layers per low-layer slab (half the gap).
    pub slab: u32,
    /// Per axis: the occupied uncompressed low-layer column indices, sorted, and their
    /// compressed numbers (`None`: no compression).
    squeeze: Option<std::sync::Arc<[Squeeze; 2]>>,
}

/// One axis of a compressed lattice: occupied uncompressed low-layer column indices, sorted,
/// and their compressed numbers.
type Squeeze = (Vec<u64>, Vec<u32>);

/// The uncompressed voxel column index of coordinate `v` on a lattice from `origin` with
/// `inv` = 1 / voxel edge and `raw` columns (the last one takes the points on the far edge).
#[inline(always)]
fn raw_index(v: f64, origin: f64, inv: f64, raw: u64) -> u64 {
    (((v - origin) * inv) as u64).min(raw - 1)
}

/// Uncompressed voxel columns along x and y of the lattice of `s` over `b`.
fn raw_columns(b: &Bounds, s: &DenoiseSettings) -> [f64; 2] {
    let [w, h, _] = b.size();
    [
        (w / s.voxel_size).floor() + 1.0,
        (h / s.voxel_size).floor() + 1.0,
    ]
}

/// Voxel columns per low-layer column of the settings `s`.
fn group_ratio(s: &DenoiseSettings) -> u32 {
    (s.low_column / s.voxel_size).round().clamp(1.0, 1e9) as u32
}

/// Above this many voxel columns per point (and 2^20 in all) the lattice is compressed.
const SQUEEZE_COLUMNS_PER_POINT: u64 = 4;

impl Lattice {
    /// The lattice of `s` over `b`, compressed when needed for the points `x`, `y`.
    pub(crate) fn new(b: &Bounds, s: &DenoiseSettings, x: &[f64], y: &[f64]) -> Result<Lattice> {
        Lattice::squeezed_above(
            b,
            s,
            x,
            y,
            (x.len() as u64 * SQUEEZE_COLUMNS_PER_POINT).max(1 << 20),
        )
    }

    /// [`Lattice::new`], compressed whenever the box holds more than `limit` columns (a
    /// shard's points occupy a small part of the whole run's lattice: 0 squeezes always).
    fn squeezed_above(
        b: &Bounds,
        s: &DenoiseSettings,
        x: &[f64],
        y: &[f64],
        limit: u64,
    ) -> Result<Lattice> {
        let [w, h, d] = b.size();
        let [fx, fy] = raw_columns(b, s);
        let ncz = (d / s.voxel_height).floor() + 1.0;
        if ncz > u32::MAX as f64 / 2.0 {
            return Err(Error::param(
                "denoise",
                "voxel_height",
                s.voxel_height,
                format!("too small for a z range of {d}: more than 2^31 voxel layers"),
            ));
        }
        if fx * fy >= 1.8e19 || (fx * fy).is_nan() {
            return Err(Error::param(
                "denoise",
                "voxel_size",
                s.voxel_size,
                format!("too small for an extent of {w} × {h}: more than 2^64 voxel columns"),
            ));
        }
        let ratio = group_ratio(s);
        let slab = s.low_gap.map_or(1, |g| {
            ((g / 2.0) / s.voxel_height).ceil().clamp(1.0, 1e9) as u32
        });
        let mut lat = Lattice {
            origin: b.min,
            inv: [1.0 / s.voxel_size, 1.0 / s.voxel_size, 1.0 / s.voxel_height],
            raw: [fx as u64, fy as u64],
            ncx: 0,
            ncy: 0,
            ratio,
            slab,
            squeeze: None,
        };
        if fx * fy > limit as f64 {
            let axis = |v: &[f64], a: usize| {
                let mut groups: Vec<u64> = v
                    .par_iter()
                    .map(|&c| lat.raw_index(c, a) / ratio as u64)
                    .collect();
                groups.par_sort_unstable();
                groups.dedup();
                let mut numbers = Vec::with_capacity(groups.len());
                let mut next = 0u64;
                for (k, &g) in groups.iter().enumerate() {
                    if k > 0 {
                        next += (g - groups[k - 1]).min(2);
                    }
                    numbers.push(next.min(u32::MAX as u64) as u32);
                }
                // Columns: the last low-layer column's members, whole.
                let cols = (next + 1).saturating_mul(ratio as u64);
                (groups, numbers, cols)
            };
            let (gx, nx, cx) = axis(x, 0);
            let (gy, ny, cy) = axis(y, 1);
            lat.squeeze = Some(std::sync::Arc::new([(gx, nx), (gy, ny)]));
            lat.set_columns(cx as f64, cy as f64, w, h, s)?;
        } else {
            lat.set_columns(fx, fy, w, h, s)?;
        }
        Ok(lat)
    }

    fn set_columns(&mut self, cx: f64, cy: f64, w: f64, h: f64, s: &DenoiseSettings) -> Result<()> {
        if cx * cy > u32::MAX as f64 / 2.0 {
            return Err(Error::param(
                "denoise",
                "voxel_size",
                s.voxel_size,
                format!(
                    "too small for an extent of {w} × {h}: more than 2^31 occupied voxel columns"
                ),
            ));
        }
        self.ncx = cx as u32;
        self.ncy = cy as u32;
        Ok(())
    }

    /// The uncompressed column index of coordinate `v` along axis `a` (0 x, 1 y).
    #[inline(always)]
    fn raw_index(&self, v: f64, a: usize) -> u64 {
        raw_index(v, self.origin[a], self.inv[a], self.raw[a])
    }

    /// The uncompressed (column i, column j, layer) of a point.
    #[cfg(any(test, feature = "testing"))]
    pub(crate) fn raw_cell(&self, x: f64, y: f64, z: f64) -> (u64, u64, u32) {
        (
            self.raw_index(x, 0),
            self.raw_index(y, 1),
            ((z - self.origin[2]) * self.inv[2]) as u32,
        )
    }

    /// Column index (x fastest) of a point.
    #[inline(always)]
    fn column(&self, x: f64, y: f64) -> u32 {
        if let Some(sq) = &self.squeeze {
            let r = self.ratio as u64;
            let index = |v: f64, a: usize| {
                let i = self.raw_index(v, a);
                let (groups, numbers) = &sq[a];
                let k = groups.partition_point(|&g| g < i / r);
                (numbers[k.min(numbers.len() - 1)] as u64 * r + i % r) as u32
            };
            return index(y, 1) * self.ncx + index(x, 0);
        }
        let i = (((x - self.origin[0]) * self.inv[0]) as u32).min(self.ncx - 1);
        let j = (((y - self.origin[1]) * self.inv[1]) as u32).min(self.ncy - 1);
        j * self.ncx + i
    }

    /// Column index (x fastest) and layer of a point.
    #[inline(always)]
    pub(crate) fn locate(&self, x: f64, y: f64, z: f64) -> (u32, u32) {
        (
            self.column(x, y),
            ((z - self.origin[2]) * self.inv[2]) as u32,
        )
    }

    /// Voxel columns of the (compressed) lattice.
    pub(crate) fn column_count(&self) -> u64 {
        self.ncx as u64 * self.ncy as u64
    }

    fn columns(&self) -> usize {
        self.ncx as usize * self.ncy as usize
    }

    /// Low-layer columns along x.
    fn groups_x(&self) -> u32 {
        self.ncx.div_ceil(self.ratio)
    }

    /// The low-layer column holding voxel column `c`.
    fn group_of(&self, c: usize) -> usize {
        let (ci, cj) = (c as u32 % self.ncx, c as u32 / self.ncx);
        ((cj / self.ratio) * self.groups_x() + ci / self.ratio) as usize
    }
}

/// The voxel columns and low-layer columns noise removal will use on `cloud` (after
/// squeezing out empty space), for the memory estimate; errors as [`denoise`] would give.
/// `bounds`, when given, must be the tight bounds of all of `cloud`'s points (as the reader
/// measured them); otherwise they are measured here.
pub fn lattice_size(
    cloud: &PointCloud,
    params: &DenoiseParams,
    metres_per_unit: f64,
    bounds: Option<&Bounds>,
) -> Result<(u64, u64)> {
    let (x, y, z) = (&cloud.x, &cloud.y, &cloud.z);
    let bounds = bounds
        .copied()
        .unwrap_or_else(|| super::bounds_of(x, y, z, None).0);
    let settings = params.resolve(&bounds, x.len(), metres_per_unit)?;
    let lat = Lattice::new(&bounds, &settings, x, y)?;
    let groups = lat.groups_x() as u64 * lat.ncy.div_ceil(lat.ratio) as u64;
    Ok((lat.column_count(), groups))
}

/// Runs the noise filter on `cloud`. `metres_per_unit` converts the default `low_gap`.
pub fn denoise(
    cloud: &PointCloud,
    params: &DenoiseParams,
    metres_per_unit: f64,
) -> Result<Denoised> {
    denoise_xyz(&cloud.x, &cloud.y, &cloud.z, params, metres_per_unit)
}

/// [`denoise`] that leaves its sorted keys (8 bytes per point, already faulted in) in
/// `scratch` for the next stage to reuse instead of freeing them
/// ([`super::resample::resample_reusing`]). `bounds`, when given, must be the tight bounds of
/// all of `cloud`'s points (as the reader measured them: [`crate::points::read_with_bounds`]);
/// otherwise they are measured here.
pub(crate) fn denoise_reusing(
    cloud: &PointCloud,
    params: &DenoiseParams,
    metres_per_unit: f64,
    scratch: &mut Vec<u64>,
    bounds: Option<Bounds>,
) -> Result<Denoised> {
    denoise_into(
        [&cloud.x, &cloud.y, &cloud.z],
        params,
        metres_per_unit,
        scratch,
        bounds,
    )
}

/// [`denoise`] on bare coordinate columns.
pub fn denoise_xyz(
    x: &[f64],
    y: &[f64],
    z: &[f64],
    params: &DenoiseParams,
    metres_per_unit: f64,
) -> Result<Denoised> {
    denoise_into([x, y, z], params, metres_per_unit, &mut Vec::new(), None)
}

fn denoise_into(
    [x, y, z]: [&[f64]; 3],
    params: &DenoiseParams,
    metres_per_unit: f64,
    scratch: &mut Vec<u64>,
    bounds: Option<Bounds>,
) -> Result<Denoised> {
    let n = x.len();
    if n == 0 {
        return Err(Error::Data {
            stage: "denoise",
            message: "no points to filter".into(),
        });
    }
    let bounds = bounds.unwrap_or_else(|| super::bounds_of(x, y, z, None).0);
    let mut st = setup(x, y, z, &bounds, n, params, metres_per_unit)?;
    let Setup {
        settings,
        lat,
        sorted,
    } = &mut st;

    // The count test, at the chosen (or adapted) voxel height; flags follow the sorted keys.
    let mut dense = vec![false; n];
    let s = *settings;
    let pass = |q: u32, coarse: Option<&[bool]>, flags: &mut [bool]| {
        count_pass(sorted, lat, &s, q, coarse, flags, None)
    };
    let (sparse, voxels) = if params.voxel_height.is_some() {
        let (failing, _, voxels) = pass(1, None, &mut dense);
        (failing, voxels)
    } else {
        // Points isolated even in voxels MAX_HEIGHT_STEPS·s tall are noise at any height;
        // the others decide how tall the voxels must be. The coarse pass is only needed when
        // the count removes more than the budget in all.
        let budget = (HEIGHT_LOSS * n as f64).floor() as usize;
        let mut coarse: Option<Vec<bool>> = None;
        let mut q = 1;
        let (failing, voxels) = loop {
            let (mut failing, mut lost, mut voxels) = pass(q, coarse.as_deref(), &mut dense);
            if failing > budget && coarse.is_none() && q < MAX_HEIGHT_STEPS {
                let mut c = vec![false; n];
                pass(MAX_HEIGHT_STEPS, None, &mut c);
                coarse = Some(c);
                (failing, lost, voxels) = pass(q, coarse.as_deref(), &mut dense);
            } else if coarse.is_none() {
                lost = failing;
            }
            if lost <= budget || q == MAX_HEIGHT_STEPS {
                break (failing, voxels);
            }
            q += 1;
        };
        settings.height_steps = q;
        settings.voxel_height *= q as f64;
        (failing, voxels)
    };

    finish(st, dense, sparse, voxels, None, scratch, Some([x, y, z]))
}

/// What the count passes work on: the settings, the lattice and the points sorted by column.
struct Setup {
    settings: DenoiseSettings,
    lat: Lattice,
    sorted: ColumnSort,
}

/// The settings, lattice and sorted points of `x`, `y`, `z` for a run over `bounds` holding
/// `points` points in all (a shard's points are part of them).
#[allow(clippy::too_many_arguments)]
fn setup(
    x: &[f64],
    y: &[f64],
    z: &[f64],
    bounds: &Bounds,
    points: usize,
    params: &DenoiseParams,
    metres_per_unit: f64,
) -> Result<Setup> {
    let n = x.len();
    if n > u32::MAX as usize {
        return Err(Error::Data {
            stage: "denoise",
            message: format!("{n} points: at most 2^32 − 1 per run"),
        });
    }
    let settings = params.resolve(bounds, points, metres_per_unit)?;
    let lat = if points > n {
        // A shard: the whole run's lattice, its empty space squeezed out (which changes no
        // count and no floor) so that its bookkeeping is bounded by its own points.
        Lattice::squeezed_above(bounds, &settings, x, y, 0)?
    } else {
        Lattice::new(bounds, &settings, x, y)?
    };
    let sorted = sort_by_column(x, y, z, &lat);
    Ok(Setup {
        settings,
        lat,
        sorted,
    })
}

/// The low-layer rule and the keep flags, after the count test left `dense` (one flag per
/// sorted key; `sparse` points failed it, in `voxels` occupied voxels). With `owned` (one
/// flag per column: a shard's own columns), only points of owned columns are kept and
/// counted; the others only lend their counts and profiles. With `coords` (the points'
/// coordinates, not for a shard) the kept points' bounds are found on the way.
fn finish(
    setup: Setup,
    dense: Vec<bool>,
    sparse: usize,
    voxels: usize,
    owned: Option<&[bool]>,
    scratch: &mut Vec<u64>,
    coords: Option<[&[f64]; 3]>,
) -> Result<Denoised> {
    let Setup {
        settings,
        lat,
        sorted,
    } = setup;
    let n = dense.len();
    // The low-layer floors, from the points that passed the count (scattered noise would
    // otherwise fill the very gaps that detach a low layer).
    let floors = if settings.low_gap.is_some() {
        low_floors(&sorted, &dense, &lat, settings.low_fraction)
    } else {
        Vec::new()
    };

    // Points below the floor's first layer of their column are a detached low layer.
    let floor = |c: usize| {
        if floors.is_empty() {
            0
        } else {
            floors[lat.group_of(c)].saturating_mul(lat.slab)
        }
    };
    // The kept points' keys of column `c` whose floor is `f`, in (layer, index) order.
    let kept_above = |c: usize, f: u32| {
        let range = sorted.starts[c] as usize..sorted.starts[c + 1] as usize;
        sorted.keys[range.clone()]
            .iter()
            .zip(&dense[range])
            .filter(move |(&key, &d)| d && layer(key) >= f)
            .map(|(&key, _)| key)
    };
    let kept_keys = |c: usize| kept_above(c, floor(c));

    // The flags back in input order.
    let keep: Vec<AtomicBool> = (0..n)
        .into_par_iter()
        .map(|_| AtomicBool::new(false))
        .collect();
    // Row by row of voxel columns, so that each column's floor comes from a running
    // low-layer column number instead of [`Lattice::group_of`]'s four integer divisions
    // per column (the counts are sums and the extremes minima and maxima: any split of the
    // work gives the same).
    let (nx, r) = (lat.ncx as usize, lat.ratio as usize);
    let (low, extremes) = (0..lat.ncy as usize)
        .into_par_iter()
        .fold(
            || (0usize, Extremes::NONE),
            |(mut low, mut ext), cj| {
                let group_row = (cj / r) * lat.groups_x() as usize;
                for ci in 0..nx {
                    let c = cj * nx + ci;
                    if owned.is_some_and(|o| !o[c]) {
                        continue;
                    }
                    let floor = if floors.is_empty() {
                        0
                    } else {
                        floors[group_row + ci / r].saturating_mul(lat.slab)
                    };
                    let range = sorted.starts[c] as usize..sorted.starts[c + 1] as usize;
                    let mut layers = (u32::MAX, 0);
                    for (&key, &d) in sorted.keys[range.clone()].iter().zip(&dense[range]) {
                        if !d {
                            continue;
                        }
                        if layer(key) < floor {
                            low += 1;
                        } else {
                            keep[index(key)].store(true, Relaxed);
                            layers = (layers.0.min(layer(key)), layer(key));
                        }
                    }
                    if let (Some([_, _, z]), true) = (coords, layers.0 != u32::MAX) {
                        ext.column([ci as u32, cj as u32], layers, z, kept_above(c, floor));
                    }
                }
                (low, ext)
            },
        )
        .reduce(|| (0, Extremes::NONE), |a, b| (a.0 + b.0, a.1.merge(&b.1)));
    let keep: Vec<bool> = keep.into_iter().map(AtomicBool::into_inner).collect();
    let kept_bounds = coords
        .filter(|_| extremes.z[0].0 != u32::MAX)
        .map(|[x, y, _]| extremes.bounds(&lat, x, y, kept_keys));
    drop((dense, floors));
    let own_points = match owned {
        None => n,
        Some(o) => (0..lat.columns())
            .filter(|&c| o[c])
            .map(|c| (sorted.starts[c + 1] - sorted.starts[c]) as usize)
            .sum(),
    };
    *scratch = sorted.keys;
    let kept = own_points - sparse - low;
    if kept == 0 && owned.is_none() {
        return Err(Error::Data {
            stage: "denoise",
            message: format!(
                "every one of the {n} points was removed as noise (voxel_size {:.4}, voxel_height {:.4}, \
                 min_points {}): lower denoise.min_points, enlarge the voxels or set denoise.enabled = false",
                settings.voxel_size, settings.voxel_height, settings.min_points
            ),
        });
    }
    Ok(Denoised {
        keep,
        kept,
        removed_sparse: sparse,
        removed_low: low,
        voxels,
        settings,
        kept_bounds,
    })
}

/// The point index of a sorted key.
#[inline(always)]
fn index(key: u64) -> usize {
    (key & 0xFFFF_FFFF) as usize
}

/// Where the kept points' extremes lie, gathered column by column while their flags are set:
/// the smallest and largest column index along x and y holding a kept point, and the
/// lowest and highest layer with the smallest and largest z there. A point's column index
/// and layer never decrease as its coordinate grows (each is the floor of a scaled offset,
/// clamped, and squeezing the lattice keeps the order of the columns), so every extreme lies
/// at the extreme index: only the points there are read, not a pass over all coordinates.
#[derive(Debug, Clone, Copy)]
struct Extremes {
    /// Smallest and largest column index along x, then along y.
    col: [u32; 4],
    /// (lowest layer, smallest z in it), (highest layer, largest z in it).
    z: [(u32, f64); 2],
}

impl Extremes {
    const NONE: Extremes = Extremes {
        col: [u32::MAX, 0, u32::MAX, 0],
        z: [(u32::MAX, f64::INFINITY), (0, f64::NEG_INFINITY)],
    };

    fn low(&mut self, layer: u32, z: f64) {
        let e = &mut self.z[0];
        if layer < e.0 {
            *e = (layer, z);
        } else if layer == e.0 {
            e.1 = e.1.min(z);
        }
    }

    fn high(&mut self, layer: u32, z: f64) {
        let e = &mut self.z[1];
        if layer > e.0 {
            *e = (layer, z);
        } else if layer == e.0 {
            e.1 = e.1.max(z);
        }
    }

    /// Column (ci, cj) holding kept points in `layers` (lowest, highest), whose keys `kept` gives
    /// in (layer, index) order: z is read only where a layer reaches an extreme so far.
    fn column(
        &mut self,
        [ci, cj]: [u32; 2],
        layers: (u32, u32),
        z: &[f64],
        kept: impl DoubleEndedIterator<Item = u64> + Clone,
    ) {
        self.col = [
            self.col[0].min(ci),
            self.col[1].max(ci),
            self.col[2].min(cj),
            self.col[3].max(cj),
        ];
        if layers.0 <= self.z[0].0 {
            for key in kept.clone().take_while(|&k| layer(k) == layers.0) {
                self.low(layers.0, z[index(key)]);
            }
        }
        if layers.1 >= self.z[1].0 {
            for key in kept.rev().take_while(|&k| layer(k) == layers.1) {
                self.high(layers.1, z[index(key)]);
            }
        }
    }

    fn merge(mut self, o: &Extremes) -> Extremes {
        self.col = [
            self.col[0].min(o.col[0]),
            self.col[1].max(o.col[1]),
            self.col[2].min(o.col[2]),
            self.col[3].max(o.col[3]),
        ];
        self.low(o.z[0].0, o.z[0].1);
        self.high(o.z[1].0, o.z[1].1);
        self
    }

    /// The kept points' bounds: x and y from the kept points of the extreme columns (`kept`
    /// gives a column's kept keys), z as gathered.
    fn bounds<I: Iterator<Item = u64>>(
        &self,
        lat: &Lattice,
        x: &[f64],
        y: &[f64],
        kept: impl Fn(usize) -> I,
    ) -> Bounds {
        let mut b = Bounds {
            min: [f64::INFINITY, f64::INFINITY, self.z[0].1],
            max: [f64::NEG_INFINITY, f64::NEG_INFINITY, self.z[1].1],
        };
        let [i0, i1, j0, j1] = self.col.map(|v| v as usize);
        let nx = lat.ncx as usize;
        for j in j0..=j1 {
            kept(j * nx + i0).for_each(|k| b.min[0] = b.min[0].min(x[index(k)]));
            kept(j * nx + i1).for_each(|k| b.max[0] = b.max[0].max(x[index(k)]));
        }
        for i in i0..=i1 {
            kept(j0 * nx + i).for_each(|k| b.min[1] = b.min[1].min(y[index(k)]));
            kept(j1 * nx + i).for_each(|k| b.max[1] = b.max[1].max(y[index(k)]));
        }
        b
    }
}

/// The count test with voxels `q` layers tall: sets `flags` (one per sorted key) to true
/// where the point's voxel, or its 3×3×3 block, holds at least `min_points` points.
/// Returns (points failing, points failing here but passing in `coarse`, occupied voxels).
fn count_pass(
    t: &ColumnSort,
    lat: &Lattice,
    s: &DenoiseSettings,
    q: u32,
    coarse: Option<&[bool]>,
    flags: &mut [bool],
    owned: Option<&[bool]>,
) -> (usize, usize, usize) {
    let m = s.min_points as usize;
    let column = |c: usize, flags: &mut [bool]| -> (usize, usize, usize) {
        let own = t.column(c);
        if own.is_empty() {
            return (0, 0, 0);
        }
        let base = t.starts[c] as usize;
        // The 8 neighbour columns, fetched only when a voxel needs them.
        let mut neigh: [&[u64]; 8] = [&[]; 8];
        let mut nn = usize::MAX;
        let (mut failing, mut lost, mut voxels) = (0, 0, 0);
        let mut a = 0;
        while a < own.len() {
            // The voxel k: keys a..b with layers in [k·q, (k+1)·q). Bounds stay in fine
            // layers so that no loop divides.
            // (Integer division is slow; q is 1 for most surveys.)
            let k = if q == 1 {
                layer(own[a])
            } else {
                layer(own[a]) / q
            };
            let top = (k + 1).saturating_mul(q);
            let mut b = a + 1;
            while b < own.len() && layer(own[b]) < top {
                b += 1;
            }
            voxels += 1;
            // The block holds the voxel: a voxel that passes alone needs no neighbours
            // (most voxels of a surface).
            let mut count = b - a;
            if s.neighbourhood && count < m {
                // Layers [(k−1)·q, (k+2)·q) of the 3×3 columns, the own column first
                // (its keys just below and above the voxel).
                let lo = k.saturating_sub(1) * q;
                let hi = (k + 2).saturating_mul(q);
                count += own[..a]
                    .iter()
                    .rev()
                    .take_while(|&&key| layer(key) >= lo)
                    .count();
                count += own[b..].iter().take_while(|&&key| layer(key) < hi).count();
                if count < m && nn == usize::MAX {
                    let (ci, cj) = (c as u32 % lat.ncx, c as u32 / lat.ncx);
                    nn = 0;
                    for nj in cj.saturating_sub(1)..(cj + 2).min(lat.ncy) {
                        for ni in ci.saturating_sub(1)..(ci + 2).min(lat.ncx) {
                            if (ni, nj) != (ci, cj) {
                                neigh[nn] = t.column((nj * lat.ncx + ni) as usize);
                                nn += 1;
                            }
                        }
                    }
                }
                // A neighbour's start only moves on (layers grow), and the walk stops
                // once the block holds min_points (starts left behind catch up later).
                if count < m {
                    for seg in neigh[..nn].iter_mut() {
                        let skip = seg.iter().take_while(|&&key| layer(key) < lo).count();
                        *seg = &seg[skip..];
                        count += seg.iter().take_while(|&&key| layer(key) < hi).count();
                        if count >= m {
                            break;
                        }
                    }
                }
            }
            let pass = count >= m;
            flags[a..b].fill(pass);
            if !pass {
                failing += b - a;
                if let Some(f) = coarse {
                    lost += f[base + a..base + b].iter().filter(|&&p| p).count();
                }
            }
            a = b;
        }
        // A shard counts its own columns only; its halo's flags are still set.
        if owned.is_some_and(|o| !o[c]) {
            return (0, 0, 0);
        }
        (failing, lost, voxels)
    };
    column_blocks(flags, &t.starts)
        .into_par_iter()
        .map(|(cols, flags)| {
            let base = t.starts[cols.start] as usize;
            cols.fold((0, 0, 0), |acc, c| {
                let r = t.starts[c] as usize - base..t.starts[c + 1] as usize - base;
                let f = column(c, &mut flags[r]);
                (acc.0 + f.0, acc.1 + f.1, acc.2 + f.2)
            })
        })
        .reduce(|| (0, 0, 0), |p, q| (p.0 + q.0, p.1 + q.1, p.2 + q.2))
}

/// `v` cut into blocks of whole columns (`starts` as in [`ColumnSort`]): the columns of each
/// block and its part of `v`. A few blocks per worker (rayon balances them) instead of one
/// slice per column: building hundreds of thousands of slices was a serial pass and a fresh
/// allocation of 16 bytes per column.
fn column_blocks<'a, T>(
    v: &'a mut [T],
    starts: &[u32],
) -> Vec<(std::ops::Range<usize>, &'a mut [T])> {
    let cols = starts.len().saturating_sub(1);
    let blocks = (rayon::current_num_threads() * 64).clamp(1, cols.max(1));
    let mut rest = v;
    let mut out = Vec::with_capacity(blocks);
    for b in 0..blocks {
        let (c0, c1) = (b * cols / blocks, (b + 1) * cols / blocks);
        let (head, tail) = rest.split_at_mut((starts[c1] - starts[c0]) as usize);
        out.push((c0..c1, head));
        rest = tail;
    }
    out
}

/// Layer (voxel height index) of a sorted key.
#[inline(always)]
fn layer(key: u64) -> u32 {
    (key >> 32) as u32
}

/// Points grouped by voxel column, each column sorted by (layer, point index); a key is
/// `layer << 32 | index`.
pub(crate) struct ColumnSort {
    keys: Vec<u64>,
    starts: Vec<u32>,
}

impl ColumnSort {
    #[inline(always)]
    fn column(&self, c: usize) -> &[u64] {
        &self.keys[self.starts[c] as usize..self.starts[c + 1] as usize]
    }
}

/// Counting sort of the points by column (stable, so the output does not depend on how the
/// work was split), then a sort by layer inside each column.
fn sort_by_column(x: &[f64], y: &[f64], z: &[f64], lat: &Lattice) -> ColumnSort {
    let n = x.len();
    let cols = lat.columns();
    let chunks = rayon::current_num_threads().clamp(1, 64);
    let chunk = n.div_ceil(chunks).max(1);
    // Pass 1: one histogram per chunk.
    let mut hist: Vec<Vec<u32>> = (0..n.div_ceil(chunk))
        .into_par_iter()
        .map(|t| {
            let mut h = vec![0u32; cols];
            let r = t * chunk..((t + 1) * chunk).min(n);
            for i in r {
                h[lat.column(x[i], y[i]) as usize] += 1;
            }
            h
        })
        .collect();
    // Offsets: column-major over chunks, so each chunk's points of a column follow the
    // previous chunk's (stability). A prefix sum in blocks of columns: each block's total
    // (in parallel), the blocks' bases (a short serial scan), then each block's offsets from
    // its base (in parallel); the serial scan over every column kept the workers waiting.
    let mut starts = vec![0u32; cols + 1];
    let block = cols.div_ceil(rayon::current_num_threads() * 8).max(1 << 12);
    let totals: Vec<u32> = (0..cols.div_ceil(block))
        .into_par_iter()
        .map(|b| {
            let r = b * block..((b + 1) * block).min(cols);
            hist.iter().map(|h| h[r.clone()].iter().sum::<u32>()).sum()
        })
        .collect();
    let mut bases = Vec::with_capacity(totals.len());
    let mut total = 0u32;
    for t in totals {
        bases.push(total);
        total += t;
    }
    let mut parts: Vec<Vec<&mut [u32]>> = bases.iter().map(|_| Vec::new()).collect();
    for h in hist.iter_mut() {
        for (part, s) in parts.iter_mut().zip(h.chunks_mut(block)) {
            part.push(s);
        }
    }
    starts[..cols]
        .par_chunks_mut(block)
        .zip(parts)
        .zip(bases)
        .for_each(|((st, mut hs), mut acc)| {
            for (k, s) in st.iter_mut().enumerate() {
                *s = acc;
                for h in hs.iter_mut() {
                    let v = h[k];
                    h[k] = acc;
                    acc += v;
                }
            }
        });
    starts[cols] = total;
    // Pass 2: scatter. Chunks write disjoint slots; atomics make that safe without `unsafe`
    // (relaxed stores compile to plain stores).
    let out: Vec<AtomicU64> = (0..n).into_par_iter().map(|_| AtomicU64::new(0)).collect();
    hist.par_iter_mut().enumerate().for_each(|(t, cursor)| {
        for i in t * chunk..((t + 1) * chunk).min(n) {
            let (c, k) = lat.locate(x[i], y[i], z[i]);
            let slot = &mut cursor[c as usize];
            out[*slot as usize].store((k as u64) << 32 | i as u64, Relaxed);
            *slot += 1;
        }
    });
    drop(hist);
    let mut keys: Vec<u64> = out.into_iter().map(AtomicU64::into_inner).collect();
    // Sort inside each column by (layer, index): keys are unique, so unstable sorting is
    // deterministic.
    column_blocks(&mut keys, &starts)
        .into_par_iter()
        .for_each(|(cols, block)| {
            let base = starts[cols.start] as usize;
            for c in cols {
                block[starts[c] as usize - base..starts[c + 1] as usize - base].sort_unstable();
            }
        });
    ColumnSort { keys, starts }
}

/// Per low-layer column: the first slab that is not noise (points in lower slabs are a
/// detached low layer). A low-layer column is `ratio` × `ratio` voxel columns; its window is
/// itself and its 8 neighbours.
fn low_floors(t: &ColumnSort, dense: &[bool], lat: &Lattice, fraction: f64) -> Vec<u32> {
    let r = lat.ratio;
    let (gx, gy) = (lat.groups_x(), lat.ncy.div_ceil(r));
    let members = |g: u32| {
        let (gi, gj) = (g % gx, g / gx);
        (gj * r..((gj + 1) * r).min(lat.ncy)).flat_map(move |j| {
            (gi * r..((gi + 1) * r).min(lat.ncx)).map(move |i| (j * lat.ncx + i) as usize)
        })
    };
    let window = |g: u32| {
        let (gi, gj) = (g % gx, g / gx);
        (gj.saturating_sub(1)..(gj + 2).min(gy))
            .flat_map(move |j| (gi.saturating_sub(1)..(gi + 2).min(gx)).map(move |i| j * gx + i))
    };
    // Lowest and highest slab holding a point that passed the count, per low-layer column. A
    // window whose points span fewer than four slabs has no gap of two empty slabs: most
    // windows are settled by this alone.
    let span: Vec<(u32, u32)> = (0..gx * gy)
        .into_par_iter()
        .map(|g| {
            let (mut lo, mut hi) = (u32::MAX, 0);
            for c in members(g) {
                let range = t.starts[c] as usize..t.starts[c + 1] as usize;
                let (keys, ok) = (&t.keys[range.clone()], &dense[range]);
                if let Some(p) = ok.iter().position(|&d| d) {
                    lo = lo.min(layer(keys[p]));
                }
                if let Some(p) = ok.iter().rposition(|&d| d) {
                    hi = hi.max(layer(keys[p]));
                }
            }
            (lo, hi)
        })
        .collect();
    let open: Vec<bool> = (0..gx * gy)
        .into_par_iter()
        .map(|g| {
            let (lo, hi) = window(g).fold((u32::MAX, 0), |(lo, hi), w| {
                (lo.min(span[w as usize].0), hi.max(span[w as usize].1))
            });
            lo != u32::MAX && hi / lat.slab >= lo / lat.slab + 3
        })
        .collect();
    // Profiles of the points that passed the count, of the low-layer columns some open
    // window needs: counts per slab over the column's own slab range (from `span`), so that
    // a window's profile is the sum of its columns' counts at their offsets, in slab order
    // without a sort (a sort of each column's and each window's (slab, count) runs was most
    // of this step's time).
    let needed = |g: u32| window(g).any(|w| open[w as usize]);
    let slabs = |(lo, hi): (u32, u32)| lo / lat.slab..hi / lat.slab + 1;
    let profiles: Vec<Vec<u32>> = (0..gx * gy)
        .into_par_iter()
        .map(|g| {
            let (lo, hi) = span[g as usize];
            if lo == u32::MAX || !needed(g) {
                return Vec::new();
            }
            let range = slabs((lo, hi));
            let mut counts = vec![0u32; range.len()];
            for c in members(g) {
                let r = t.starts[c] as usize..t.starts[c + 1] as usize;
                let (keys, ok) = (&t.keys[r.clone()], &dense[r]);
                let mut a = 0;
                while a < keys.len() {
                    let s = layer(keys[a]) / lat.slab;
                    let top = (s + 1).saturating_mul(lat.slab);
                    let mut b = a;
                    let mut count = 0;
                    while b < keys.len() && layer(keys[b]) < top {
                        count += ok[b] as u32;
                        b += 1;
                    }
                    // Points that passed lie within the span (others may lie beyond it).
                    if count > 0 {
                        counts[(s - range.start) as usize] += count;
                    }
                    a = b;
                }
            }
            counts
        })
        .collect();
    (0..gx * gy)
        .into_par_iter()
        .map_init(
            || (Vec::new(), Vec::new()),
            |(sum, runs): &mut (Vec<u32>, Vec<(u32, u32)>), g| {
                if !open[g as usize] {
                    return 0;
                }
                let (lo, hi) = window(g).fold((u32::MAX, 0), |(lo, hi), w| {
                    (lo.min(span[w as usize].0), hi.max(span[w as usize].1))
                });
                let range = slabs((lo, hi));
                sum.clear();
                sum.resize(range.len(), 0);
                for w in window(g) {
                    let p = &profiles[w as usize];
                    if !p.is_empty() {
                        let at = (span[w as usize].0 / lat.slab - range.start) as usize;
                        for (a, &c) in sum[at..at + p.len()].iter_mut().zip(p) {
                            *a += c;
                        }
                    }
                }
                runs.clear();
                runs.extend(
                    (range.start..)
                        .zip(sum.iter().copied())
                        .filter(|&(_, c)| c > 0),
                );
                floor_of(runs, fraction)
            },
        )
        .collect()
}

/// The floor of a window profile: the slab just above the highest gap of two or more empty
/// slabs below which fewer than `fraction` of the window's points lie (0 if none).
pub(crate) fn floor_of(profile: &[(u32, u32)], fraction: f64) -> u32 {
    let total: u64 = profile.iter().map(|r| r.1 as u64).sum();
    let limit = fraction * total as f64;
    let mut below = 0u64;
    let mut floor = 0;
    for w in profile.windows(2) {
        below += w[0].1 as u64;
        if (below as f64) >= limit {
            break;
        }
        if w[1].0 - w[0].0 > 2 {
            floor = w[1].0;
        }
    }
    floor
}

/// The global figures noise removal of a shard needs, known before any point is read
/// against its neighbours: the bounds and number of all points of the run. The voxel
/// lattice is anchored at the bounds' minimum corner and the data-derived defaults come
/// from the mean spacing over them, so every shard sees the lattice of the whole run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Frame {
    /// Bounds of all points.
    pub bounds: Bounds,
    /// Number of all points.
    pub points: usize,
}

/// Voxel columns a shard owns: uncompressed column indices of the global lattice along x
/// and y, half-open.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ColumnWindow {
    /// Columns along x.
    pub x: std::ops::Range<u64>,
    /// Columns along y.
    pub y: std::ops::Range<u64>,
}

impl Frame {
    /// The settings of the whole run (data-derived defaults from all points).
    pub fn settings(
        &self,
        params: &DenoiseParams,
        metres_per_unit: f64,
    ) -> Result<DenoiseSettings> {
        params.resolve(&self.bounds, self.points, metres_per_unit)
    }

    /// Uncompressed voxel columns of the lattice along x and y.
    pub fn columns(&self, s: &DenoiseSettings) -> [u64; 2] {
        raw_columns(&self.bounds, s).map(|c| c as u64)
    }

    /// The uncompressed voxel column (i, j) of a point: the expression the lattice uses.
    pub fn column(&self, s: &DenoiseSettings, x: f64, y: f64) -> (u64, u64) {
        let [cx, cy] = self.columns(s);
        let inv = 1.0 / s.voxel_size;
        (
            raw_index(x, self.bounds.min[0], inv, cx),
            raw_index(y, self.bounds.min[1], inv, cy),
        )
    }

    /// Voxel columns per low-layer column (owned windows aligned to it keep every
    /// low-layer window whole).
    pub fn group(&self, s: &DenoiseSettings) -> u64 {
        group_ratio(s) as u64
    }

    /// Voxel columns a shard reads beyond its own on every side: one low-layer column and
    /// one voxel column when the low-layer rule is on (a floor reads the profiles of the 8
    /// neighbour low-layer columns, built from count flags that read one voxel column
    /// further), one voxel column for the 3×3×3 count, none for the voxel alone.
    pub fn halo(&self, s: &DenoiseSettings) -> u64 {
        match (s.low_gap.is_some(), s.neighbourhood) {
            (true, _) => self.group(s) + 1,
            (false, true) => 1,
            (false, false) => 0,
        }
    }
}

/// What a shard's noise removal reads: its points (own columns and halo, in input order),
/// the global frame and parameters, and which voxel columns the shard owns.
#[derive(Clone, Copy)]
pub struct ShardInput<'a> {
    /// x of the shard's points.
    pub x: &'a [f64],
    /// y of the shard's points.
    pub y: &'a [f64],
    /// z of the shard's points.
    pub z: &'a [f64],
    /// The global lattice's frame.
    pub frame: &'a Frame,
    /// The run's noise-removal parameters.
    pub params: &'a DenoiseParams,
    /// Metres per horizontal unit of the input.
    pub metres_per_unit: f64,
    /// The voxel columns the shard owns.
    pub owned: &'a ColumnWindow,
}

/// A shard's points set up against the global lattice, with its owned columns flagged.
fn shard_setup(input: &ShardInput) -> Result<(Setup, Vec<bool>)> {
    let ShardInput {
        x,
        y,
        z,
        frame,
        params,
        metres_per_unit,
        owned,
    } = *input;
    let setup = setup(
        x,
        y,
        z,
        &frame.bounds,
        frame.points,
        params,
        metres_per_unit,
    )?;
    let mut own = vec![false; setup.lat.columns()];
    for (&x, &y) in x.iter().zip(y) {
        let (i, j) = (setup.lat.raw_index(x, 0), setup.lat.raw_index(y, 1));
        if owned.x.contains(&i) && owned.y.contains(&j) {
            own[setup.lat.column(x, y) as usize] = true;
        }
    }
    Ok((setup, own))
}

/// The count test of a shard (its own points and its halo's) at every voxel height the
/// automatic choice may try, q = 1…[`MAX_HEIGHT_STEPS`] (only q = 1 when `voxel_height` is
/// given): per q, (points failing, points failing but passing at the tallest voxels,
/// occupied voxels), over the shard's own columns. Summed over all shards, they are what
/// the in-memory run counts; [`choose_steps`] picks q from the sums.
pub fn shard_counts(input: &ShardInput) -> Result<Vec<[usize; 3]>> {
    let (x, params) = (input.x, input.params);
    let (
        Setup {
            settings,
            lat,
            sorted,
        },
        own,
    ) = shard_setup(input)?;
    let n = x.len();
    let mut dense = vec![false; n];
    if params.voxel_height.is_some() {
        let (f, l, v) = count_pass(&sorted, &lat, &settings, 1, None, &mut dense, Some(&own));
        return Ok(vec![[f, l, v]]);
    }
    let mut coarse = vec![false; n];
    count_pass(
        &sorted,
        &lat,
        &settings,
        MAX_HEIGHT_STEPS,
        None,
        &mut coarse,
        None,
    );
    Ok((1..=MAX_HEIGHT_STEPS)
        .map(|q| {
            let (f, l, v) = count_pass(
                &sorted,
                &lat,
                &settings,
                q,
                Some(&coarse),
                &mut dense,
                Some(&own),
            );
            [f, l, v]
        })
        .collect())
}

/// The voxel height steps q the in-memory run picks, from the counts of [`shard_counts`]
/// summed over all shards of a run of `points` points: the first q at which the points
/// failing (not counting those isolated even in the tallest voxels) are within the budget.
pub fn choose_steps(params: &DenoiseParams, counts: &[[usize; 3]], points: usize) -> u32 {
    if params.voxel_height.is_some() {
        return 1;
    }
    let budget = (HEIGHT_LOSS * points as f64).floor() as usize;
    // At q = 1 the in-memory run first compares all failing points, then (over the budget)
    // the ones the tallest voxels keep; lost ≤ failing, so the second test decides both.
    counts
        .iter()
        .position(|c| c[1] <= budget)
        .map_or(MAX_HEIGHT_STEPS, |k| k as u32 + 1)
}

/// Noise removal of a shard at voxel height steps `q` (from [`choose_steps`]): the keep flags
/// of the shard's points (true only for kept points of its own columns) and the figures
/// over its own columns. The flags of its own points are those the in-memory run gives them.
pub fn shard_denoise(input: &ShardInput, q: u32) -> Result<Denoised> {
    let (x, params) = (input.x, input.params);
    let (mut st, own) = shard_setup(input)?;
    let mut dense = vec![false; x.len()];
    let (sparse, _, voxels) = count_pass(
        &st.sorted,
        &st.lat,
        &st.settings,
        q,
        None,
        &mut dense,
        Some(&own),
    );
    if params.voxel_height.is_none() {
        st.settings.height_steps = q;
        st.settings.voxel_height *= q as f64;
    }
    finish(st, dense, sparse, voxels, Some(&own), &mut Vec::new(), None)
}

/// [`shard_counts`] and [`shard_denoise`] at q = 1 from one setup of the shard's points
/// (the sort by column is shared): what a shard job computes when it cannot wait for the
/// other shards' counts. The counts are only taken with an automatic voxel height (they
/// are empty when `voxel_height` is given, since q is then 1 whatever they say).
pub fn shard_counts_and_denoise(input: &ShardInput) -> Result<(Vec<[usize; 3]>, Denoised)> {
    let n = input.x.len();
    let (st, own) = shard_setup(input)?;
    let mut dense = vec![false; n];
    let mut counts = Vec::new();
    let (t, lat, s) = (&st.sorted, &st.lat, &st.settings);
    if input.params.voxel_height.is_none() {
        let mut coarse = vec![false; n];
        count_pass(t, lat, s, MAX_HEIGHT_STEPS, None, &mut coarse, None);
        for q in 1..=MAX_HEIGHT_STEPS {
            let (f, l, v) = count_pass(t, lat, s, q, Some(&coarse), &mut dense, Some(&own));
            counts.push([f, l, v]);
        }
    }
    // Last, so that `dense` holds the flags at q = 1.
    let (sparse, _, voxels) = count_pass(t, lat, s, 1, None, &mut dense, Some(&own));
    let d = finish(st, dense, sparse, voxels, Some(&own), &mut Vec::new(), None)?;
    Ok((counts, d))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::reference;

    fn scene(seed: u64, n: u64) -> crate::generate::Scene {
        crate::generate::generate(&crate::generate::GenerateParams {
            seed,
            points: n,
            outliers_per_million: 2000,
            ..Default::default()
        })
        .unwrap()
    }

    /// The kept bounds noise removal found are those a pass over the kept points measures.
    fn kept_bounds_hold(c: &PointCloud, d: &Denoised) {
        let (b, n) = crate::terrain::bounds_of(&c.x, &c.y, &c.z, Some(&d.keep));
        assert_eq!(n, d.kept);
        assert_eq!(d.kept_bounds, Some(b));
    }

    #[test]
    fn fast_equals_slow_on_generated_scenes() {
        for (seed, nb, low) in [
            (1, true, true),
            (2, false, true),
            (3, true, false),
            (4, false, false),
        ] {
            let s = scene(seed, 20_000);
            let c = &s.cloud;
            let p = DenoiseParams {
                neighbourhood: nb,
                low_layers: low,
                ..Default::default()
            };
            let fast = denoise(c, &p, 1.0).unwrap();
            let slow = reference::denoise(&c.x, &c.y, &c.z, &p, 1.0).unwrap();
            assert_eq!(fast.keep, slow, "seed {seed} nb {nb} low {low}");
            assert_eq!(fast.kept, slow.iter().filter(|k| **k).count());
            kept_bounds_hold(c, &fast);
        }
    }

    #[test]
    fn squeezed_lattice_equals_the_slow_twin() {
        // One far-away point, and a second copy of the scene far away: the lattice is
        // squeezed (the box holds ~1e12 voxel columns) and must decide exactly as the
        // uncompressed reference does, with given and with derived voxel sizes.
        let s = scene(5, 20_000);
        let mut far = s.cloud.clone();
        far.x.push(far.x[0] + 1e12);
        far.y.push(far.y[0]);
        far.z.push(far.z[0]);
        let mut twin = s.cloud.clone();
        for i in 0..s.cloud.len() {
            twin.x.push(s.cloud.x[i] + 1e9);
            twin.y.push(s.cloud.y[i] - 3e8);
            twin.z.push(s.cloud.z[i]);
        }
        for (name, c) in [("far", &far), ("twin", &twin)] {
            for p in [
                DenoiseParams {
                    voxel_size: Some(1.5),
                    voxel_height: Some(1.0),
                    ..Default::default()
                },
                DenoiseParams {
                    voxel_size: Some(1.5),
                    ..Default::default()
                },
                DenoiseParams::default(),
            ] {
                let (bounds, _) = crate::terrain::bounds_of(&c.x, &c.y, &c.z, None);
                let st = p.resolve(&bounds, c.len(), 1.0).unwrap();
                let lat = Lattice::new(&bounds, &st, &c.x, &c.y).unwrap();
                if p.voxel_size.is_some() {
                    assert!(lat.squeeze.is_some(), "{name}: not squeezed");
                    assert!(lat.column_count() < 64 * c.len() as u64, "{name}");
                }
                let fast = denoise(c, &p, 1.0);
                let slow = reference::denoise(&c.x, &c.y, &c.z, &p, 1.0);
                match (fast, slow) {
                    (Ok(f), Ok(sl)) => {
                        assert_eq!(f.keep, sl, "{name} {p:?}");
                        kept_bounds_hold(c, &f);
                    }
                    (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string()),
                    (a, b) => panic!("{name}: {a:?} vs {b:?}"),
                }
            }
        }
    }

    #[test]
    fn removes_a_dense_mirror_patch_under_the_ground() {
        // A multipath "mirror": 40 points on a flat 8 × 3 m patch 25 m under the terrain,
        // dense enough to pass any count test.
        let s = scene(11, 40_000);
        let mut c = s.cloud.clone();
        let [x0, y0, _, _] = s.extent;
        let (cx, cy) = (x0 + 60.0, y0 + 60.0);
        let ground = (0..c.len())
            .filter(|&i| (c.x[i] - cx).abs() < 5.0 && (c.y[i] - cy).abs() < 5.0)
            .map(|i| c.z[i])
            .fold(f64::INFINITY, f64::min);
        let first = c.len();
        for k in 0..40 {
            c.x.push(cx + (k % 10) as f64 * 0.8);
            c.y.push(cy + (k / 10) as f64 * 0.8);
            c.z.push(ground - 25.0 + (k % 3) as f64 * 0.05);
        }
        let d = denoise_xyz(&c.x, &c.y, &c.z, &DenoiseParams::default(), 1.0).unwrap();
        assert!(d.keep[first..].iter().all(|k| !k), "mirror points kept");
        assert!(d.removed_low >= 40, "{}", d.removed_low);
        kept_bounds_hold(&c, &d);
        assert_eq!(
            d.keep,
            reference::denoise(&c.x, &c.y, &c.z, &DenoiseParams::default(), 1.0).unwrap()
        );
        // Without the rule they survive the count.
        let off = DenoiseParams {
            low_layers: false,
            ..Default::default()
        };
        let d = denoise_xyz(&c.x, &c.y, &c.z, &off, 1.0).unwrap();
        assert!(d.keep[first..].iter().all(|&k| k));
    }

    #[test]
    fn removes_generated_outliers() {
        let s = scene(7, 50_000);
        let d = denoise(&s.cloud, &DenoiseParams::default(), 1.0).unwrap();
        let caught = s.outliers.iter().filter(|&&i| !d.keep[i as usize]).count();
        assert_eq!(caught, s.outliers.len(), "outliers kept");
        assert!(
            d.removed() < s.outliers.len() + s.cloud.len() / 100,
            "{}",
            d.removed()
        );
    }

    #[test]
    fn same_result_for_any_thread_count() {
        let s = scene(9, 30_000);
        let run = |t: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(t)
                .build()
                .unwrap()
                .install(|| denoise(&s.cloud, &DenoiseParams::default(), 1.0).unwrap())
        };
        let one = run(1);
        assert_eq!(one, run(2));
        assert_eq!(one, run(8));
    }

    #[test]
    fn floor_finds_the_highest_small_detached_layer() {
        // 3 points at slab 0, 4 at 10, then the main body at 20..22 with 100 points.
        let p = [(0, 3), (10, 4), (20, 50), (21, 30), (22, 20)];
        assert_eq!(floor_of(&p, 0.1), 20);
        // A big low layer is not detached noise.
        let p = [(0, 40), (20, 60)];
        assert_eq!(floor_of(&p, 0.1), 0);
        // Gaps of two slabs are not enough (adjacent-ish layers of one surface).
        let p = [(0, 1), (2, 100)];
        assert_eq!(floor_of(&p, 0.1), 0);
        assert_eq!(floor_of(&[], 0.1), 0);
    }

    #[test]
    fn bad_parameters_name_themselves() {
        let c = scene(1, 1000).cloud;
        for (p, key) in [
            (
                DenoiseParams {
                    voxel_size: Some(0.0),
                    ..Default::default()
                },
                "voxel_size",
            ),
            (
                DenoiseParams {
                    voxel_size: Some(f64::NAN),
                    ..Default::default()
                },
                "voxel_size",
            ),
            (
                DenoiseParams {
                    voxel_height: Some(-1.0),
                    ..Default::default()
                },
                "voxel_height",
            ),
            (
                DenoiseParams {
                    min_points: Some(0),
                    ..Default::default()
                },
                "min_points",
            ),
            (
                DenoiseParams {
                    low_gap: Some(0.0),
                    ..Default::default()
                },
                "low_gap",
            ),
            (
                DenoiseParams {
                    low_fraction: 1.5,
                    ..Default::default()
                },
                "low_fraction",
            ),
        ] {
            let e = denoise(&c, &p, 1.0).unwrap_err().to_string();
            assert!(e.starts_with(&format!("denoise: {key} = ")), "{e}");
        }
    }

    #[test]
    fn all_removed_is_an_error() {
        let c = scene(1, 1000).cloud;
        let p = DenoiseParams {
            min_points: Some(1_000_000),
            ..Default::default()
        };
        let e = denoise(&c, &p, 1.0).unwrap_err().to_string();
        assert!(
            e.starts_with("denoise: every one of the 1000 points was removed"),
            "{e}"
        );
    }

    #[test]
    fn points_on_a_line_have_no_spacing() {
        let x: Vec<f64> = (0..100).map(|i| i as f64).collect();
        let y = vec![5.0; 100];
        let z = vec![1.0; 100];
        let e = denoise_xyz(&x, &y, &z, &DenoiseParams::default(), 1.0)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("denoise: voxel_size = auto: the points span a zero-width range"),
            "{e}"
        );
    }
}
