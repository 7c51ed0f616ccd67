//! Slow, obvious implementations of the terrain stages — the "twins" the fast paths are
//! tested against, on generated data and on the real tiles. They follow the same
//! definitions (Kim & Shin §2.1–§2.3 and the module docs of [denoise](mod@super::denoise),
//! [resample](mod@super::resample) and [fill](mod@super::fill)) in the plainest way: voxel
//! counts in a `HashMap`, neighbourhoods by 27 look-ups, cell means by sorting the points by
//! cell, neighbours by walking cell by cell. The fast paths must equal them exactly. Not for
//! production use: they are single-threaded and allocate freely.

use super::denoise::{DenoiseParams, DenoiseSettings, Lattice, HEIGHT_LOSS, MAX_HEIGHT_STEPS};
use super::fill::{mark_fallback, push_pull, sample_mean, Fallback, FillParams, Neighbours};
use super::heightfield::{CellState, Heightfield};
use super::resample::{CellMethod, GridSpec, ResampleParams};
use crate::error::Result;
use crate::points::{Bounds, PointCloud};
use std::collections::HashMap;

/// Noise removal: one flag per point, true to keep.
pub fn denoise(
    x: &[f64],
    y: &[f64],
    z: &[f64],
    params: &DenoiseParams,
    metres_per_unit: f64,
) -> Result<Vec<bool>> {
    let mut b = Bounds::EMPTY;
    for i in 0..x.len() {
        b.add([x[i], y[i], z[i]]);
    }
    let s = params.resolve(&b, x.len(), metres_per_unit)?;
    let lat = Lattice::new(&b, &s, x, y)?;
    // (column i, column j, layer) of every point in the uncompressed lattice.
    let fine: Vec<(i64, i64, i64)> = (0..x.len())
        .map(|i| {
            let (ci, cj, k) = lat.raw_cell(x[i], y[i], z[i]);
            (ci as i64, cj as i64, k as i64)
        })
        .collect();
    let count_test = |q: i64| -> Vec<bool> {
        let mut counts: HashMap<(i64, i64, i64), usize> = HashMap::new();
        for &(i, j, k) in &fine {
            *counts.entry((i, j, k / q)).or_default() += 1;
        }
        fine.iter()
            .map(|&(i, j, k)| {
                let k = k / q;
                let count = if s.neighbourhood {
                    let mut t = 0;
                    for di in -1..=1 {
                        for dj in -1..=1 {
                            for dk in -1..=1 {
                                t += counts.get(&(i + di, j + dj, k + dk)).copied().unwrap_or(0);
                            }
                        }
                    }
                    t
                } else {
                    counts[&(i, j, k)]
                };
                count >= s.min_points as usize
            })
            .collect()
    };
    // The voxel height: given, or the smallest number of layers at which at most
    // HEIGHT_LOSS of the points fail the count while passing it in the tallest voxels.
    let dense = if params.voxel_height.is_some() {
        count_test(1)
    } else {
        let coarse = count_test(MAX_HEIGHT_STEPS as i64);
        let budget = (HEIGHT_LOSS * x.len() as f64).floor() as usize;
        let mut q = 1;
        loop {
            let d = count_test(q);
            let lost = d.iter().zip(&coarse).filter(|(d, c)| !**d && **c).count();
            if lost <= budget || q == MAX_HEIGHT_STEPS as i64 {
                break d;
            }
            q += 1;
        }
    };
    if s.low_gap.is_none() {
        return Ok(dense);
    }
    // Detached low layers: per low-layer column window, the slabs of the points that passed
    // the count, sorted; the floor is the slab above the highest gap of more than two slabs
    // with fewer than low_fraction of the window's points below it.
    let r = lat.ratio as i64;
    let mut slabs_by_group: HashMap<(i64, i64), Vec<u32>> = HashMap::new();
    for (p, &(i, j, k)) in fine.iter().enumerate() {
        if dense[p] {
            slabs_by_group
                .entry((i / r, j / r))
                .or_default()
                .push(k as u32 / lat.slab);
        }
    }
    let mut floors: HashMap<(i64, i64), u32> = HashMap::new();
    Ok(fine
        .iter()
        .enumerate()
        .map(|(p, &(i, j, k))| {
            let g = (i / r, j / r);
            let floor = *floors.entry(g).or_insert_with(|| {
                let mut slabs: Vec<u32> = Vec::new();
                for di in -1..=1 {
                    for dj in -1..=1 {
                        if let Some(v) = slabs_by_group.get(&(g.0 + di, g.1 + dj)) {
                            slabs.extend_from_slice(v);
                        }
                    }
                }
                slabs.sort_unstable();
                let limit = s.low_fraction * slabs.len() as f64;
                let mut floor = 0;
                for n in 1..slabs.len() {
                    if (n as f64) >= limit {
                        break;
                    }
                    if slabs[n] - slabs[n - 1] > 2 {
                        floor = slabs[n];
                    }
                }
                floor
            });
            dense[p] && k as u32 / lat.slab >= floor
        })
        .collect())
}

/// The settings [`denoise`] starts from (before the voxel height adapts).
pub fn denoise_settings(
    x: &[f64],
    y: &[f64],
    z: &[f64],
    params: &DenoiseParams,
    metres_per_unit: f64,
) -> Result<DenoiseSettings> {
    let mut b = Bounds::EMPTY;
    for i in 0..x.len() {
        b.add([x[i], y[i], z[i]]);
    }
    params.resolve(&b, x.len(), metres_per_unit)
}

/// Resampling: the kept points sorted by cell (ties in file order), each run of one cell
/// reduced to its mean (summed in file order), min or max.
pub fn resample(
    c: &PointCloud,
    keep: Option<&[bool]>,
    params: &ResampleParams,
) -> Result<Heightfield> {
    let idx: Vec<usize> = (0..c.len())
        .filter(|&i| keep.is_none_or(|k| k[i]))
        .collect();
    let mut b = Bounds::EMPTY;
    for &i in &idx {
        b.add([c.x[i], c.y[i], c.z[i]]);
    }
    let spec = GridSpec::new(params, &b, idx.len())?;
    let mut by_cell: Vec<(usize, usize)> = idx
        .iter()
        .map(|&i| {
            let (ci, cj) = spec.cell(c.x[i], c.y[i]);
            (cj * spec.cols + ci, i)
        })
        .collect();
    by_cell.sort();
    let mut hf = Heightfield::empty(
        spec.cols,
        spec.rows,
        spec.corner,
        spec.cell_size,
        spec.z_offset,
        c.crs().cloned(),
    );
    for run in by_cell.chunk_by(|a, b| a.0 == b.0) {
        let cell = run[0].0;
        let (ci, cj) = (cell % spec.cols, cell / spec.cols);
        let zs: Vec<f64> = run.iter().map(|&(_, i)| c.z[i]).collect();
        let v = match params.method {
            CellMethod::Mean => zs.iter().fold(0.0, |a, &z| a + z) / zs.len() as f64,
            CellMethod::Min => zs.iter().copied().fold(f64::INFINITY, f64::min),
            CellMethod::Max => zs.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        };
        hf.heights[[cj, ci]] = (v - spec.z_offset) as f32;
        hf.counts[[cj, ci]] = zs.len() as u32;
        hf.state[[cj, ci]] = CellState::Measured;
    }
    Ok(hf)
}

/// Hole filling: for every empty cell, walk left, right, down and up cell by cell to the
/// nearest measured cell within the radius, combine as Kim & Shin §2.3, then the fallback.
pub fn fill(hf: &Heightfield, params: &FillParams) -> Result<Heightfield> {
    params.validate()?;
    let mut out = hf.clone();
    let (rows, cols) = hf.heights.dim();
    let r = params.radius.floor() as i64;
    let [dx, dy] = hf.cell_size;
    let find = |j: usize, i: usize, dj: i64, di: i64, unit: f64| {
        for d in 1..=r {
            let (jj, ii) = (j as i64 + dj * d, i as i64 + di * d);
            if jj < 0 || ii < 0 || jj >= rows as i64 || ii >= cols as i64 {
                return None;
            }
            if hf.state[[jj as usize, ii as usize]] == CellState::Measured {
                return Some((
                    d as f64 * unit,
                    hf.heights[[jj as usize, ii as usize]] as f64,
                ));
            }
        }
        None
    };
    let mut missing = false;
    for j in 0..rows {
        for i in 0..cols {
            if hf.state[[j, i]] != CellState::Empty {
                continue;
            }
            let n = Neighbours {
                left: find(j, i, 0, -1, dx),
                right: find(j, i, 0, 1, dx),
                down: find(j, i, -1, 0, dy),
                up: find(j, i, 1, 0, dy),
            };
            // The membrane fill leaves a cell without both complete pairs to the membrane.
            let cross = n.left.is_some() && n.right.is_some() && n.down.is_some() && n.up.is_some();
            match n.interpolate() {
                Some(_) if params.fallback == Fallback::Membrane && !cross => missing = true,
                Some(v) => {
                    out.heights[[j, i]] = v as f32;
                    out.state[[j, i]] = CellState::Interpolated;
                }
                None => missing = true,
            }
        }
    }
    if missing {
        match params.fallback {
            Fallback::Nodata => {}
            Fallback::Mean => {
                let mean = sample_mean(hf) as f32;
                for (h, s) in out.heights.iter_mut().zip(out.state.iter_mut()) {
                    if *s == CellState::Empty {
                        *h = mean;
                        *s = CellState::Fallback;
                    }
                }
            }
            Fallback::Smooth => push_pull(&mut out),
            Fallback::Membrane => {
                let cols = out.cols();
                for (h, s) in out.heights.iter_mut().zip(out.state.iter()) {
                    if *s == CellState::Empty {
                        *h = f32::NAN;
                    }
                }
                if let Some(h) = out.heights.as_slice_mut() {
                    let tol = super::voidfill::default_tolerance(h);
                    super::voidfill::membrane_fill(h, cols, rows, tol);
                }
                mark_fallback(&mut out);
            }
        }
    }
    Ok(out)
}

/// True when two grids have the same shape, georeference, states, counts and height bits.
pub fn same_grid(a: &Heightfield, b: &Heightfield) -> bool {
    a.heights.shape() == b.heights.shape()
        && a.heights
            .iter()
            .zip(b.heights.iter())
            .all(|(p, q)| p.to_bits() == q.to_bits())
        && a.counts == b.counts
        && a.state == b.state
        && a.corner == b.corner
        && a.cell_size == b.cell_size
        && a.z_offset == b.z_offset
}
