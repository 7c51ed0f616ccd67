//! Shards: the unit of work of a sharded terrain run (see `docs/scale.md`).
//!
//! A shard is a rectangular block of whole output tiles plus the halo of input it needs.
//! This module holds the layout of shards over a tile grid and the grid half of a shard's
//! work: hole filling, tiling and the quadtree metrics of its tiles, computed by the very
//! stage functions of the in-memory run (`fill::fill`, `tiles::tile`, `quadtree::build`,
//! `quadtree::vertical_error`) on the shard's cells, then a merge that finishes d2 and the
//! vertical error across shard borders (`quadtree::merge`). The result is bit-identical
//! to the in-memory run for any block size, from one tile to the whole grid.
//!
//! Halos, from the stages' code: the fill's interpolation reads measured cells up to
//! `radius` cells away along rows and columns, so a shard's fill input is its region widened
//! by that many cells. The smooth fallback's push-pull pyramid is made shard-local with a
//! coarse global level: the shard computes pyramid levels 1…k (tiles of 2^k + 1 samples)
//! over its own tiles plus a ring of one tile (aligned to 2^k, so every one of those cells is
//! the global one), level k (one cell per tile) is completed globally from all shards'
//! values ([`complete_coarse`], a tiny array), and the shard pulls back down locally: a
//! cell's bilinear interpolation reads the level above within one cell, which the ring
//! holds at every level. The `mean` fallback needs a global mean in a fixed summation order
//! and is not available here yet; the `unreal` preset resamples the whole grid and is
//! refused.

use crate::error::{Error, Result};
use crate::terrain::fill::{self, Fallback, FillParams, FillReport};
use crate::terrain::quadtree::{self, NodeValues, Quadtree, QuadtreeParams};
use crate::terrain::tiles::{self, Preset, SetLayout, Tile, TileParams, TileSet};
use crate::terrain::{CellState, Heightfield};
use ndarray::s;
use serde::{Deserialize, Serialize};
use std::ops::Range;

pub mod bricks;
pub mod direct;
pub mod points;
pub mod prepared_spill;
pub mod reuse;
pub mod scale_bench;
pub mod settings;
pub mod store;
#[cfg(test)]
mod tests;

/// How a grid of samples is cut into tiles and the tiles into shards.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardLayout {
    /// Samples of the whole grid (columns, rows).
    pub samples: [usize; 2],
    /// Samples per tile side (2^k + 1).
    pub tile_size: usize,
    /// Tiles of the whole grid (columns, rows).
    pub tiles: [usize; 2],
    /// Tiles per shard (columns, rows); the last shards of a row or column may hold fewer.
    pub block: [usize; 2],
}

impl ShardLayout {
    /// The layout of `samples` cut into tiles as `params` says, `block` tiles per shard
    /// (clamped to the tile grid).
    pub fn new(samples: [usize; 2], params: &TileParams, block: [usize; 2]) -> Result<Self> {
        params.validate()?;
        if params.preset == Preset::Unreal {
            return Err(Error::param(
                "tiles",
                "preset",
                "unreal",
                "the unreal preset resamples the whole grid to an engine size before tiling, \
                 which a sharded run cannot do: run it in memory",
            ));
        }
        if samples[0] < 2 || samples[1] < 2 {
            return Err(Error::Data {
                stage: "tiles",
                message: format!(
                    "the heightfield has {}×{} samples; tiles need at least 2×2",
                    samples[0], samples[1]
                ),
            });
        }
        if block[0] == 0 || block[1] == 0 {
            return Err(Error::param(
                "shard",
                "block",
                format!("[{}, {}]", block[0], block[1]),
                "a shard holds at least one tile along each axis",
            ));
        }
        let t = params.tile_size();
        let tiles = [
            tiles::tiles_for(samples[0], t),
            tiles::tiles_for(samples[1], t),
        ];
        Ok(ShardLayout {
            samples,
            tile_size: t,
            tiles,
            block: [block[0].min(tiles[0]), block[1].min(tiles[1])],
        })
    }

    /// Distance between tile origins, 2^k.
    pub fn step(&self) -> usize {
        self.tile_size - 1
    }

    /// Shards along each axis.
    pub fn shards(&self) -> [usize; 2] {
        [
            self.tiles[0].div_ceil(self.block[0]),
            self.tiles[1].div_ceil(self.block[1]),
        ]
    }

    /// Number of shards.
    pub fn count(&self) -> usize {
        self.shards()[0] * self.shards()[1]
    }

    /// Shard `index` (row by row from the south-west).
    pub fn shard(&self, index: usize) -> Shard {
        let [sx, _] = self.shards();
        let (c, r) = (index % sx, index / sx);
        let span =
            |k: usize, a: usize| k * self.block[a]..((k + 1) * self.block[a]).min(self.tiles[a]);
        Shard {
            index,
            tiles: [span(c, 0), span(r, 1)],
        }
    }

    /// Cells of the smooth fill's coarse level (2^k × 2^k blocks): one per tile, and one
    /// more along an axis whose last sample starts a block of its own.
    pub fn coarse(&self) -> [usize; 2] {
        [
            self.samples[0].div_ceil(self.step()),
            self.samples[1].div_ceil(self.step()),
        ]
    }
}

/// One shard: a block of tiles.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Shard {
    /// Its index in the layout.
    pub index: usize,
    /// Tile columns and rows it holds.
    pub tiles: [Range<usize>; 2],
}

impl Shard {
    /// Coarse-level blocks (2^k cells) it owns along axis `a`.
    fn blocks(&self, l: &ShardLayout, a: usize) -> Range<usize> {
        let t = &self.tiles[a];
        let end = if t.end == l.tiles[a] {
            l.coarse()[a]
        } else {
            t.end
        };
        t.start..end
    }

    /// Cells it owns along axis `a` (owned cells of all shards partition the grid).
    pub fn owned(&self, l: &ShardLayout, a: usize) -> Range<usize> {
        let b = self.blocks(l, a);
        b.start * l.step()..(b.end * l.step()).min(l.samples[a])
    }

    /// Samples of its tiles along axis `a` (the last one shared with the next shard).
    pub fn samples(&self, l: &ShardLayout, a: usize) -> Range<usize> {
        let t = &self.tiles[a];
        t.start * l.step()..(t.end * l.step() + 1).min(l.samples[a])
    }

    /// The cells whose filled heights it computes along axis `a`: its samples, or with the
    /// smooth fill its blocks and a ring of one block (tile) around them.
    pub fn region(&self, l: &ShardLayout, a: usize, smooth: bool) -> Range<usize> {
        if !smooth {
            return self.samples(l, a);
        }
        let b = self.blocks(l, a);
        b.start.saturating_sub(1) * l.step()..((b.end + 1) * l.step()).min(l.samples[a])
    }

    /// The cells its fill reads along axis `a`: the region widened by the fill's halo.
    pub fn input(&self, l: &ShardLayout, a: usize, fill: Option<&FillParams>) -> Range<usize> {
        let region = self.region(l, a, is_smooth(fill));
        let halo = fill.map_or(0, fill_halo);
        region.start.saturating_sub(halo)..(region.end + halo).min(l.samples[a])
    }
}

/// The interpolation's halo in cells: `radius` rounded down, as `fill` reads it.
pub fn fill_halo(p: &FillParams) -> usize {
    p.radius.floor().clamp(0.0, fill::MAX_RADIUS as f64) as usize
}

/// True when the fill runs and its fallback is the smooth push-pull pyramid.
pub fn is_smooth(fill: Option<&FillParams>) -> bool {
    fill.is_some_and(|f| f.fallback == Fallback::Smooth)
}

/// The cells `i` × `j` of `hf`, with their georeference.
pub fn crop(hf: &Heightfield, i: Range<usize>, j: Range<usize>) -> Heightfield {
    let corner = [
        hf.corner[0] + i.start as f64 * hf.cell_size[0],
        hf.corner[1] + j.start as f64 * hf.cell_size[1],
    ];
    Heightfield {
        heights: hf.heights.slice(s![j.clone(), i.clone()]).to_owned(),
        counts: hf.counts.slice(s![j.clone(), i.clone()]).to_owned(),
        state: hf.state.slice(s![j, i]).to_owned(),
        corner,
        cell_size: hf.cell_size,
        z_offset: hf.z_offset,
        crs: hf.crs.clone(),
    }
}

/// A shard after its first step: its region's cells interpolated, and for the smooth fill
/// the pyramid levels 1…k of the region.
#[derive(Debug, Clone)]
pub struct Prepared {
    shard: Shard,
    /// The region's cells; `offset` is the global index of its cell (0, 0).
    local: Heightfield,
    offset: [usize; 2],
    /// Pyramid levels 1…k over `local` (smooth fill only).
    pyramid: Vec<(Vec<f32>, usize, usize)>,
    fill: Option<FillParams>,
}

/// First step of a shard: interpolates the holes of its region. `input` holds (at least) the
/// cells [`Shard::input`] names, its cell (0, 0) being global cell `offset`; the unfilled
/// heights of the resampled grid.
pub fn prepare(
    layout: &ShardLayout,
    shard: &Shard,
    input: &Heightfield,
    offset: [usize; 2],
    fill: Option<&FillParams>,
) -> Result<Prepared> {
    let whole_grid = |f: &FillParams| match f.fallback {
        Fallback::Mean => Some((
            "mean",
            "the mean of the whole grid is not available to a shard yet",
        )),
        Fallback::Membrane => Some((
            "membrane",
            "the membrane is solved over the whole grid, not shard by shard",
        )),
        _ => None,
    };
    if let Some((value, why)) = fill.and_then(whole_grid) {
        return Err(Error::param(
            "fill",
            "fallback",
            value,
            format!("{why}: use smooth or nodata"),
        ));
    }
    let smooth = is_smooth(fill);
    let region = [
        shard.region(layout, 0, smooth),
        shard.region(layout, 1, smooth),
    ];
    prepare_region(layout, shard, input, offset, fill, region)
}

/// [`prepare`] over the cells `region` (its start aligned to 2^k along both axes).
fn prepare_region(
    layout: &ShardLayout,
    shard: &Shard,
    input: &Heightfield,
    offset: [usize; 2],
    fill: Option<&FillParams>,
    region: [Range<usize>; 2],
) -> Result<Prepared> {
    let smooth = is_smooth(fill);
    let dims = [input.cols(), input.rows()];
    for a in 0..2 {
        if offset[a] > region[a].start || offset[a] + dims[a] < region[a].end {
            return Err(Error::Internal(format!(
                "shard {}: its input (cells {}..{} along axis {a}) does not cover its region {:?}",
                shard.index,
                offset[a],
                offset[a] + dims[a],
                region[a]
            )));
        }
    }
    let mut hf = input.clone();
    if let Some(f) = fill {
        // The interpolation only: the fallback needs the whole grid (see `finish`).
        let interpolate = FillParams {
            fallback: Fallback::Nodata,
            ..f.clone()
        };
        fill::fill(&mut hf, &interpolate)?;
    }
    let local_range = |a: usize| region[a].start - offset[a]..region[a].end - offset[a];
    let local = crop(&hf, local_range(0), local_range(1));
    let mut pyramid: Vec<(Vec<f32>, usize, usize)> = Vec::new();
    if smooth {
        let (rows, cols) = local.heights.dim();
        let level0 = local.heights.as_slice().unwrap_or(&[]);
        for _ in 0..layout.step().trailing_zeros() {
            let next = match pyramid.last() {
                Some((v, h, w)) => fill::push_level(v, *h, *w),
                None => fill::push_level(level0, rows, cols),
            };
            pyramid.push(next);
        }
    }
    Ok(Prepared {
        shard: shard.clone(),
        local,
        offset: [region[0].start, region[1].start],
        pyramid,
        fill: fill.cloned(),
    })
}

impl Prepared {
    /// The coarse-level cells this shard owns: (index into the layout's coarse grid, row by
    /// row, value; NaN where its block holds no height). Empty without the smooth fill.
    pub fn coarse(&self, layout: &ShardLayout) -> Vec<(usize, f32)> {
        let Some((top, _, tw)) = self.pyramid.last() else {
            return Vec::new();
        };
        let step = layout.step();
        let [b0, b1] = [self.offset[0] / step, self.offset[1] / step];
        let cw = layout.coarse()[0];
        let mut out = Vec::new();
        for bj in self.shard.blocks(layout, 1) {
            for bi in self.shard.blocks(layout, 0) {
                out.push((bj * cw + bi, top[(bj - b1) * tw + (bi - b0)]));
            }
        }
        out
    }
}

/// The coarse level completed: the shards' coarse cells gathered into the layout's coarse
/// grid (NaN where nothing is known) and filled by the same push-pull as the whole grid.
pub fn complete_coarse(layout: &ShardLayout, cells: &[(usize, f32)]) -> Result<Vec<f32>> {
    let [cw, ch] = layout.coarse();
    let mut hf = Heightfield::empty(cw, ch, [0.0, 0.0], [1.0, 1.0], 0.0, None);
    let heights = hf
        .heights
        .as_slice_mut()
        .ok_or_else(|| Error::Internal("coarse level not contiguous".into()))?;
    for &(k, v) in cells {
        *heights
            .get_mut(k)
            .ok_or_else(|| Error::Internal(format!("coarse cell {k} outside {cw}×{ch}")))? = v;
    }
    fill::push_pull(&mut hf);
    Ok(hf.heights.iter().copied().collect())
}

/// What a shard hands to the merge: its tiles (global indices and origins), their d2 and
/// vertical error as propagated within the shard, and its fill figures over its own cells.
#[derive(Debug, Clone)]
pub struct ShardOutput {
    /// The shard's tiles.
    pub tiles: Vec<Tile>,
    /// d2 of each tile, reconciled within the shard only.
    pub d2: Vec<NodeValues>,
    /// Vertical error of each tile, reconciled within the shard only (empty when
    /// [`finish_with`] left it out).
    pub vertical_error: Vec<NodeValues>,
    /// Fill figures over the cells the shard owns (`None`: fill off).
    pub fill: Option<FillReport>,
}

/// Second step of a shard: the fallback (pulled down from the completed coarse level for
/// the smooth fill), the tiles and their quadtree metrics.
pub fn finish(
    layout: &ShardLayout,
    prepared: Prepared,
    coarse: &[f32],
    tiles: &TileParams,
    quadtree: &QuadtreeParams,
) -> Result<ShardOutput> {
    finish_with(layout, prepared, coarse, tiles, quadtree, true)
}

/// [`finish`], with the vertical error tree only when `vertical_error` is true (the mesh
/// extraction builds its own from the merged tiles, so a driver that only hands the tiles on
/// leaves it out: `ShardOutput::vertical_error` is then empty).
pub fn finish_with(
    layout: &ShardLayout,
    prepared: Prepared,
    coarse: &[f32],
    tiles: &TileParams,
    quadtree: &QuadtreeParams,
    vertical_error: bool,
) -> Result<ShardOutput> {
    let Prepared {
        shard,
        mut local,
        offset,
        mut pyramid,
        fill,
    } = prepared;
    let step = layout.step();
    if let Some((top, th, tw)) = pyramid.last_mut() {
        let cw = layout.coarse()[0];
        let [b0, b1] = [offset[0] / step, offset[1] / step];
        for j in 0..*th {
            for i in 0..*tw {
                top[j * *tw + i] = coarse[(b1 + j) * cw + b0 + i];
            }
        }
        let cols = local.cols();
        if let Some(h0) = local.heights.as_slice_mut() {
            fill::pull_down(h0, cols, pyramid);
        }
        fill::mark_fallback(&mut local);
    }
    let report = fill.as_ref().map(|f| {
        let own = |a: usize| {
            let r = shard.owned(layout, a);
            r.start - offset[a]..r.end - offset[a]
        };
        let mut r = FillReport::default();
        for s in local.state.slice(s![own(1), own(0)]) {
            match s {
                CellState::Measured => r.measured += 1,
                CellState::Interpolated => r.interpolated += 1,
                CellState::Fallback => r.fallback += 1,
                CellState::Empty => r.empty += 1,
            }
        }
        if f.fallback == Fallback::Smooth {
            // As `fill` reports it: every cell the interpolation left goes to the fallback.
            (r.fallback, r.empty) = (r.fallback + r.empty, 0);
        }
        r
    });
    let cut = |a: usize| {
        let r = shard.samples(layout, a);
        r.start - offset[a]..r.end - offset[a]
    };
    let sub = crop(&local, cut(0), cut(1));
    let mut set = tiles::tile(&sub, tiles)?;
    let [c0, r0] = [shard.tiles[0].start, shard.tiles[1].start];
    for t in &mut set.tiles {
        t.col += c0;
        t.row += r0;
        t.origin = [t.origin[0] + c0 * step, t.origin[1] + r0 * step];
    }
    let d2 = quadtree::build(&set, quadtree)?.d2;
    let vertical_error = if vertical_error {
        quadtree::vertical_error(&set)
    } else {
        Vec::new()
    };
    Ok(ShardOutput {
        tiles: set.tiles,
        d2,
        vertical_error,
        fill: report,
    })
}

/// The whole tile set put together from its shards, with d2 and the vertical error
/// finished across shard borders.
#[derive(Debug, Clone)]
pub struct Merged {
    /// All tiles, as `tiles::tile` cuts the whole grid.
    pub set: TileSet,
    /// d2 of every tile, as `quadtree::build` computes it on the whole set.
    pub quadtree: Quadtree,
    /// The vertical error of every tile, as `quadtree::vertical_error` computes it (empty
    /// when the shards left it out).
    pub vertical_error: Vec<NodeValues>,
    /// Fill figures of the whole grid (`None`: fill off).
    pub fill: Option<FillReport>,
}

/// The bits of every node value, level by level.
fn node_bits(v: &NodeValues) -> Vec<u32> {
    let k = (v.size() - 1).trailing_zeros();
    (1..=k)
        .flat_map(|m| v.level(m).iter().map(|x| x.to_bits()).collect::<Vec<_>>())
        .collect()
}

impl Merged {
    /// Where `self` and `other` differ, bit for bit, in the set's geometry, the fill
    /// figures, each tile's placement and heights, d2 and vertical error (None: nowhere).
    pub fn difference(&self, other: &Merged) -> Option<String> {
        let (sa, sb) = (&self.set, &other.set);
        if (
            sa.tile_size,
            sa.grid,
            sa.samples,
            sa.corner,
            sa.cell_size,
            sa.z_offset,
        ) != (
            sb.tile_size,
            sb.grid,
            sb.samples,
            sb.corner,
            sb.cell_size,
            sb.z_offset,
        ) {
            return Some("set geometry".into());
        }
        if self.fill != other.fill {
            return Some(format!("fill report {:?} vs {:?}", self.fill, other.fill));
        }
        let heights = |t: &Tile| t.heights.iter().map(|h| h.to_bits()).collect::<Vec<_>>();
        for (k, (x, y)) in sa.tiles.iter().zip(&sb.tiles).enumerate() {
            if (x.col, x.row, x.origin, x.valid, x.holes)
                != (y.col, y.row, y.origin, y.valid, y.holes)
            {
                return Some(format!("tile {k} placement"));
            }
            if heights(x) != heights(y) {
                return Some(format!("tile {k} heights"));
            }
            if node_bits(&self.quadtree.d2[k]) != node_bits(&other.quadtree.d2[k]) {
                return Some(format!("tile {k} d2"));
            }
            if node_bits(&self.vertical_error[k]) != node_bits(&other.vertical_error[k]) {
                return Some(format!("tile {k} vertical error"));
            }
        }
        None
    }
}

/// Merges the outputs of every shard of `layout`. `grid` gives the whole grid's
/// georeference (its heights are not read).
pub fn merge(
    layout: &ShardLayout,
    grid: &Heightfield,
    tiles: &TileParams,
    quadtree: &QuadtreeParams,
    outputs: Vec<ShardOutput>,
) -> Result<Merged> {
    quadtree.validate()?;
    let n = layout.tiles[0] * layout.tiles[1];
    let mut slots: Vec<Option<(Tile, NodeValues, Option<NodeValues>)>> =
        (0..n).map(|_| None).collect();
    let mut fill: Option<FillReport> = None;
    for out in outputs {
        if let Some(f) = out.fill {
            let acc = fill.get_or_insert_with(FillReport::default);
            acc.measured += f.measured;
            acc.interpolated += f.interpolated;
            acc.fallback += f.fallback;
            acc.empty += f.empty;
        }
        let mut errors = out.vertical_error.into_iter();
        for (t, d) in out.tiles.into_iter().zip(out.d2) {
            let e = errors.next();
            let k = t.row * layout.tiles[0] + t.col;
            match slots.get_mut(k) {
                Some(slot @ None) => *slot = Some((t, d, e)),
                _ => {
                    return Err(Error::Internal(format!(
                        "tile ({}, {}) given twice or outside the grid",
                        t.col, t.row
                    )))
                }
            }
        }
    }
    let mut set_tiles = Vec::with_capacity(n);
    let mut d2 = Vec::with_capacity(n);
    let mut err = Vec::with_capacity(n);
    for (k, slot) in slots.into_iter().enumerate() {
        let (t, d, e) = slot.ok_or_else(|| {
            Error::Internal(format!(
                "tile ({}, {}) missing: not every shard was merged",
                k % layout.tiles[0],
                k / layout.tiles[0]
            ))
        })?;
        set_tiles.push(t);
        d2.push(d);
        err.extend(e);
    }
    if err.len() != d2.len() {
        // Some shard left the vertical error out: the merged set has none.
        err.clear();
    }
    let k = quadtree.k();
    quadtree::merge(layout.tiles, k as f32, &mut d2);
    quadtree::merge(layout.tiles, 1.0, &mut err);
    let set = TileSet {
        layout: SetLayout {
            tile_size: layout.tile_size,
            grid: layout.tiles,
            samples: layout.samples,
            source_samples: layout.samples,
            preset: tiles.preset,
            corner: grid.corner,
            cell_size: grid.cell_size,
            z_offset: grid.z_offset,
            crs: grid.crs.clone(),
        },
        tiles: set_tiles,
    };
    Ok(Merged {
        set,
        quadtree: Quadtree {
            c: quadtree.min_resolution_c,
            k,
            d2,
        },
        vertical_error: err,
        fill,
    })
}

/// Runs every shard of `layout` in this process over the resampled (unfilled) grid `grid`
/// and merges them: the sharded run's grid half, for tests and the in-memory driver.
pub fn run_all(
    layout: &ShardLayout,
    grid: &Heightfield,
    fill: Option<&FillParams>,
    tiles: &TileParams,
    quadtree: &QuadtreeParams,
) -> Result<Merged> {
    run_with(layout, grid, fill, tiles, quadtree, |_, [ci, cj]| {
        Ok(crop(grid, ci, cj))
    })
}

/// Runs every shard of `layout` in this process, each shard's input (the unfilled cells it
/// names, columns and rows) made by `input`, and merges them. `geo` gives the whole grid's
/// georeference.
pub fn run_with(
    layout: &ShardLayout,
    geo: &Heightfield,
    fill: Option<&FillParams>,
    tiles: &TileParams,
    quadtree: &QuadtreeParams,
    input: impl Fn(&Shard, [Range<usize>; 2]) -> Result<Heightfield>,
) -> Result<Merged> {
    let prepared: Vec<Prepared> = (0..layout.count())
        .map(|i| {
            let shard = layout.shard(i);
            let (ci, cj) = (shard.input(layout, 0, fill), shard.input(layout, 1, fill));
            let offset = [ci.start, cj.start];
            let cells = input(&shard, [ci, cj])?;
            prepare(layout, &shard, &cells, offset, fill)
        })
        .collect::<Result<_>>()?;
    let cells: Vec<(usize, f32)> = prepared.iter().flat_map(|p| p.coarse(layout)).collect();
    let coarse = if is_smooth(fill) {
        complete_coarse(layout, &cells)?
    } else {
        Vec::new()
    };
    let outputs = prepared
        .into_iter()
        .map(|p| finish(layout, p, &coarse, tiles, quadtree))
        .collect::<Result<Vec<_>>>()?;
    merge(layout, geo, tiles, quadtree, outputs)
}
