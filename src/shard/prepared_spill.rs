//! A streamed run's prepared grid shards on disk between the two steps of the smooth fill.
//!
//! The smooth fill needs the coarse level of every shard before any shard can finish, so a
//! prepared shard (its region's cells resampled and interpolated, and its fill pyramid)
//! waits between the two steps. When all of them fit half the memory budget they wait in
//! memory; when they do not, each goes to a temporary file as soon as it is prepared and
//! comes back when it finishes, so every point is read and resampled once whatever the
//! survey's size (preparing the shards again would read and resample their points twice).
//!
//! The file is a shard job's `prepare` result without its block flag and coarse cells
//! ([`write_prepared`] / [`read_prepared_from`], which the jobs' results use too, through the result format of
//! [`super::store`]: header, checksum, every length bounded by the file), not a second
//! serialisation. Files are written atomically, named `prepared-I.bin` in the run's
//! temporary directory (removed with it on success, failure and interruption), and each is
//! removed as soon as it is read back.

use super::store::{Reader, Writer};
use super::{Prepared, Shard, ShardLayout};
use crate::error::{Error, Result};
use crate::points::Crs;
use crate::terrain::{CellState, Heightfield};
use ndarray::Array2;
use std::path::{Path, PathBuf};

/// The result format's phase field: a `prepare` result's.
const PHASE: u32 = 3;
/// The result format's plan field: no plan (the run's temporary directory is its own).
const PLAN: u32 = 0;

/// The temporary file of prepared shard `i`.
fn path_of(dir: &Path, i: usize) -> PathBuf {
    dir.join(format!("prepared-{i}.bin"))
}

/// True for the names of the files this module writes.
pub fn is_prepared_name(name: &str) -> bool {
    super::store::is_numbered(name, "prepared-")
}

/// Writes prepared shard `p` to its file in `dir`, atomically; returns the file's bytes.
pub fn put(dir: &Path, p: &Prepared) -> Result<u64> {
    let mut w = Writer::default();
    write_prepared(&mut w, p);
    let i = p.shard.index;
    w.save(&path_of(dir, i), PHASE, PLAN, i as u64)?;
    let path = path_of(dir, i);
    std::fs::metadata(&path)
        .map(|m| m.len())
        .map_err(|e| Error::io(&path, e))
}

/// Reads prepared shard `i` of `layout` back from its file in `dir` (its cells in `crs`)
/// and removes the file.
pub fn take(
    dir: &Path,
    layout: &ShardLayout,
    i: usize,
    fill: Option<&crate::terrain::fill::FillParams>,
    crs: Option<&Crs>,
) -> Result<Prepared> {
    let path = path_of(dir, i);
    let mut r = Reader::open(&path, PHASE, PLAN, i as u64)?;
    let mut p = read_prepared_from(&mut r, layout, layout.shard(i), fill.cloned())?;
    r.end()?;
    drop(r);
    p.local.crs = crs.cloned();
    std::fs::remove_file(&path).map_err(|e| Error::io(&path, e))?;
    Ok(p)
}

fn put_heightfield(w: &mut Writer, hf: &Heightfield) {
    let (rows, cols) = hf.heights.dim();
    w.u64(rows as u64);
    w.u64(cols as u64);
    w.f32s(hf.heights.iter().copied());
    w.u32s(hf.counts.iter().copied());
    w.bytes(&hf.state.iter().map(|s| *s as u8).collect::<Vec<_>>());
    for v in [hf.corner, hf.cell_size].iter().flatten() {
        w.f64(*v);
    }
    w.f64(hf.z_offset);
}

fn get_heightfield(r: &mut Reader, max_cells: usize) -> Result<Heightfield> {
    let rows = r.usize(max_cells, "rows")?;
    let cols = r.usize(max_cells, "columns")?;
    let shape = |r: &Reader, n: usize| -> Result<()> {
        if n != rows * cols {
            return Err(r.invalid(format!("{n} cells for {rows}×{cols}")));
        }
        Ok(())
    };
    let heights = r.f32s()?;
    shape(r, heights.len())?;
    let counts = r.u32s()?;
    shape(r, counts.len())?;
    let state = r.bytes()?;
    shape(r, state.len())?;
    let state = state
        .into_iter()
        .map(|s| match s {
            0 => Ok(CellState::Empty),
            1 => Ok(CellState::Measured),
            2 => Ok(CellState::Interpolated),
            3 => Ok(CellState::Fallback),
            _ => Err(r.invalid(format!("cell state {s}"))),
        })
        .collect::<Result<Vec<_>>>()?;
    let mut f = [0.0; 5];
    for v in &mut f {
        *v = r.f64()?;
    }
    let arr = |v| Array2::from_shape_vec((rows, cols), v);
    let bad = |_| r.invalid("cells do not fit their shape");
    Ok(Heightfield {
        heights: arr(heights).map_err(bad)?,
        counts: Array2::from_shape_vec((rows, cols), counts).map_err(bad)?,
        state: Array2::from_shape_vec((rows, cols), state).map_err(bad)?,
        corner: [f[0], f[1]],
        cell_size: [f[2], f[3]],
        z_offset: f[4],
        crs: None,
    })
}

/// A prepared shard's region and fill pyramid, as [`read_prepared_from`] reads them back
/// bit for bit.
pub(crate) fn write_prepared(w: &mut Writer, p: &Prepared) {
    put_heightfield(w, &p.local);
    w.u64(p.offset[0] as u64);
    w.u64(p.offset[1] as u64);
    w.u64(p.pyramid.len() as u64);
    for (v, h, wd) in &p.pyramid {
        w.u64(*h as u64);
        w.u64(*wd as u64);
        w.f32s(v.iter().copied());
    }
}

/// A prepared shard written by [`write_prepared`], for `shard` of `layout` with the fill
/// `fill` (every length checked against the layout and the bytes left).
pub(crate) fn read_prepared_from(
    r: &mut Reader,
    layout: &ShardLayout,
    shard: Shard,
    fill: Option<crate::terrain::fill::FillParams>,
) -> Result<Prepared> {
    let max_cells = layout.samples[0].max(layout.samples[1]);
    let local = get_heightfield(r, max_cells)?;
    let offset = [r.usize(max_cells, "offset")?, r.usize(max_cells, "offset")?];
    let levels = r.usize(64, "pyramid levels")?;
    let mut pyramid = Vec::with_capacity(levels);
    for _ in 0..levels {
        let (h, wd) = (r.usize(max_cells, "rows")?, r.usize(max_cells, "columns")?);
        let v = r.f32s()?;
        if v.len() != h * wd {
            return Err(r.invalid("pyramid level does not fit its shape"));
        }
        pyramid.push((v, h, wd));
    }
    Ok(Prepared {
        shard,
        local,
        offset,
        pyramid,
        fill,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_our_names_are_ours() {
        assert!(is_prepared_name("prepared-0.bin"));
        assert!(is_prepared_name("prepared-123.bin"));
        for n in [
            "prepared-.bin",
            "prepared-1-2.bin",
            "prepared-1.bin.tmp",
            "tiles-1.bin",
        ] {
            assert!(!is_prepared_name(n), "{n}");
        }
    }
}
