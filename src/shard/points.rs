//! The point half of a sharded run, in one process: noise removal by windows of voxel
//! columns (each with its halo, the voxel height chosen from the windows' summed counts),
//! the grid fixed from the kept points' bounds and count (a reduction: min, max and a sum,
//! the same in any order), and each tile block resampled from the kept points of its cells
//! and halo; then the grid half ([`super::run_with`]). A streaming driver runs the same
//! calls on points read back from temporary files instead of slices of one cloud.

use super::{run_with, Merged, ShardLayout};
use crate::error::{Error, Result};
use crate::points::Crs;
use crate::terrain::denoise::{self, ColumnWindow, DenoiseParams, Frame};
use crate::terrain::fill::FillParams;
use crate::terrain::quadtree::QuadtreeParams;
use crate::terrain::resample::{self, GridSpec, ResampleParams};
use crate::terrain::tiles::TileParams;
use crate::terrain::Heightfield;

/// The settings of a terrain run's stages, as the pipeline file gives them.
#[derive(Debug, Clone, Default)]
pub struct Stages {
    /// Noise removal (`None`: off).
    pub denoise: Option<DenoiseParams>,
    /// Metres per horizontal unit of the data (for the default `low_gap`).
    pub metres_per_unit: f64,
    /// The grid.
    pub resample: ResampleParams,
    /// Hole filling (`None`: off).
    pub fill: Option<FillParams>,
    /// Tiles.
    pub tiles: TileParams,
    /// Quadtree.
    pub quadtree: QuadtreeParams,
}

/// What a sharded run of points gives.
#[derive(Debug, Clone)]
pub struct PointRun {
    /// One flag per input point (None: noise removal off).
    pub keep: Option<Vec<bool>>,
    /// Voxel height in mean spacings that noise removal chose (1 when off or given).
    pub height_steps: u32,
    /// The grid.
    pub spec: GridSpec,
    /// Tiles, d2 and vertical error of the whole set.
    pub merged: Merged,
}

/// The points `idx` of `x`, `y`, `z`, in order.
/// The parts of a shard's noise-removal input that every window shares.
struct Base<'a> {
    frame: &'a Frame,
    params: &'a DenoiseParams,
    metres_per_unit: f64,
}

impl<'a> Base<'a> {
    fn with(
        &self,
        x: &'a [f64],
        y: &'a [f64],
        z: &'a [f64],
        owned: &'a ColumnWindow,
    ) -> denoise::ShardInput<'a> {
        denoise::ShardInput {
            x,
            y,
            z,
            frame: self.frame,
            params: self.params,
            metres_per_unit: self.metres_per_unit,
            owned,
        }
    }
}

fn gather(x: &[f64], y: &[f64], z: &[f64], idx: &[usize]) -> [Vec<f64>; 3] {
    [
        idx.iter().map(|&i| x[i]).collect(),
        idx.iter().map(|&i| y[i]).collect(),
        idx.iter().map(|&i| z[i]).collect(),
    ]
}

/// Noise removal by square windows of `groups` × `groups` low-layer columns: the keep flag
/// of every point, as [`denoise::denoise_xyz`] gives them, and the voxel height steps.
pub fn denoise_sharded(
    x: &[f64],
    y: &[f64],
    z: &[f64],
    params: &DenoiseParams,
    metres_per_unit: f64,
    groups: u64,
) -> Result<(Vec<bool>, u32)> {
    let (bounds, points) = crate::terrain::bounds_of(x, y, z, None);
    let frame = Frame { bounds, points };
    let s = frame.settings(params, metres_per_unit)?;
    let [cx, cy] = frame.columns(&s);
    let side = groups.max(1) * frame.group(&s);
    let halo = frame.halo(&s);
    // Each point goes to every window whose read range (own columns and halo) holds it:
    // one pass, in input order.
    let n = [cx.div_ceil(side), cy.div_ceil(side)];
    let mut buckets: Vec<Vec<usize>> = vec![Vec::new(); (n[0] * n[1]) as usize];
    let reach = |c: u64, a: usize| c.saturating_sub(halo) / side..((c + halo) / side + 1).min(n[a]);
    for i in 0..x.len() {
        let (a, b) = frame.column(&s, x[i], y[i]);
        for wy in reach(b, 1) {
            for wx in reach(a, 0) {
                buckets[(wy * n[0] + wx) as usize].push(i);
            }
        }
    }
    let windows: Vec<(ColumnWindow, Vec<usize>)> = buckets
        .into_iter()
        .enumerate()
        .filter(|(_, idx)| !idx.is_empty())
        .map(|(k, idx)| {
            let (wx, wy) = (k as u64 % n[0], k as u64 / n[0]);
            let own = ColumnWindow {
                x: wx * side..((wx + 1) * side).min(cx),
                y: wy * side..((wy + 1) * side).min(cy),
            };
            (own, idx)
        })
        .collect();
    let base = Base {
        frame: &frame,
        params,
        metres_per_unit,
    };
    let mut sums: Vec<[usize; 3]> = Vec::new();
    for (own, idx) in &windows {
        let [wx, wy, wz] = gather(x, y, z, idx);
        let input = base.with(&wx, &wy, &wz, own);
        let c = denoise::shard_counts(&input)?;
        sums.resize(c.len(), [0; 3]);
        for (acc, c) in sums.iter_mut().zip(&c) {
            for k in 0..3 {
                acc[k] += c[k];
            }
        }
    }
    let q = denoise::choose_steps(params, &sums, points);
    let mut keep = vec![false; x.len()];
    for (own, idx) in &windows {
        let [wx, wy, wz] = gather(x, y, z, idx);
        let input = base.with(&wx, &wy, &wz, own);
        let d = denoise::shard_denoise(&input, q)?;
        for (&i, &k) in idx.iter().zip(&d.keep) {
            keep[i] |= k;
        }
    }
    Ok((keep, q))
}

/// The whole terrain run of `x`, `y`, `z` by shards: noise removal by windows of
/// `groups` × `groups` low-layer columns, then tile blocks of `block` tiles.
#[allow(clippy::too_many_arguments)]
pub fn run_points(
    x: &[f64],
    y: &[f64],
    z: &[f64],
    crs: Option<Crs>,
    stages: &Stages,
    groups: u64,
    block: [usize; 2],
) -> Result<PointRun> {
    let (keep, height_steps) = match &stages.denoise {
        Some(p) => {
            let (k, q) = denoise_sharded(x, y, z, p, stages.metres_per_unit, groups)?;
            (Some(k), q)
        }
        None => (None, 1),
    };
    // The reduction that fixes the grid: bounds and number of the kept points.
    let (kept_bounds, kept) = crate::terrain::bounds_of(x, y, z, keep.as_deref());
    if kept == 0 {
        return Err(Error::Data {
            stage: "resample",
            message: "no points to resample".into(),
        });
    }
    let spec = GridSpec::new(&stages.resample, &kept_bounds, kept)?;
    let layout = ShardLayout::new([spec.cols, spec.rows], &stages.tiles, block)?;
    let geo = Heightfield::empty(
        1,
        1,
        spec.corner,
        spec.cell_size,
        spec.z_offset,
        crs.clone(),
    );
    // Each kept point goes to every shard whose input cells hold its cell: one pass.
    let fill = stages.fill.as_ref();
    let [sx, sy] = layout.shards();
    let reach = |a: usize, count: usize, per: usize| -> Vec<Vec<usize>> {
        let mut v = vec![Vec::new(); layout.samples[a]];
        for k in 0..count {
            let shard = layout.shard(if a == 0 { k } else { k * per });
            for c in shard.input(&layout, a, fill) {
                v[c].push(k);
            }
        }
        v
    };
    let (along_x, along_y) = (reach(0, sx, 1), reach(1, sy, sx));
    let mut buckets: Vec<Vec<usize>> = vec![Vec::new(); layout.count()];
    for i in 0..x.len() {
        if keep.as_ref().is_some_and(|k| !k[i]) {
            continue;
        }
        let (a, b) = spec.cell(x[i], y[i]);
        for &r in &along_y[b] {
            for &c in &along_x[a] {
                buckets[r * sx + c].push(i);
            }
        }
    }
    let merged = run_with(
        &layout,
        &geo,
        fill,
        &stages.tiles,
        &stages.quadtree,
        |shard, window| {
            let [wx, wy, wz] = gather(x, y, z, &buckets[shard.index]);
            Ok(resample::resample_window(
                [&wx, &wy, &wz],
                None,
                &spec,
                window,
                stages.resample.method,
                crs.clone(),
            ))
        },
    )?;
    Ok(PointRun {
        keep,
        height_steps,
        spec,
        merged,
    })
}
