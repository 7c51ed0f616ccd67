//! A streamed run's finished tiles out of memory: each grid shard's tile heights go to a
//! temporary file as the shard finishes (they are final then: the merge changes d2 only),
//! and come back one shard at a time when the tile encoders write them. What stays in
//! memory is each tile's summary (place, valid extent, holes, height range), its d2 for the
//! merge, and the hole count: the writers' global figures (the 16-bit encoding's height
//! range, the manifest) come from those.
//!
//! Used only when every output is written tile by tile (`output::writes_tile_by_tile`):
//! meshes, previews, `dem.tif` and the quantized-mesh tileset read the whole set.

use crate::error::{Error, Result};
use crate::fsutil::write_bytes_atomic;
use crate::output::{SetSummary, TerrainProducts, TileWriter};
use crate::progress::Progress;
use crate::shard::store::is_numbered;
use crate::shard::ShardOutput;
use crate::terrain::{Quadtree, TileSet};
use ndarray::Array2;
use std::path::{Path, PathBuf};

/// The temporary file of shard `i`'s tile heights.
fn path_of(dir: &Path, i: usize) -> PathBuf {
    dir.join(format!("tiles-{i}.bin"))
}

/// True for the names of the files this module writes.
pub fn is_spill_name(name: &str) -> bool {
    is_numbered(name, "tiles-")
}

/// The tiles the run has written to disk: per shard, the set indices of its tiles in the
/// order its file holds them; and the set's hole samples, counted while the heights were
/// at hand.
#[derive(Debug, Default)]
pub struct Spilled {
    shards: Vec<(usize, Vec<usize>)>,
    /// Hole samples of the whole grid, as `TileSet::holes` counts them.
    pub holes: usize,
}

impl Spilled {
    /// Writes shard `i`'s tile heights (little-endian f32, tile after tile, row-major) to
    /// its file in `dir`, atomically, and leaves its tiles without heights. `grid`: tiles of
    /// the whole set in x and y.
    pub fn put(
        &mut self,
        dir: &Path,
        i: usize,
        out: &mut ShardOutput,
        grid: [usize; 2],
    ) -> Result<()> {
        let cells: usize = out.tiles.iter().map(|t| t.heights.len()).sum();
        let mut bytes = Vec::with_capacity(cells * 4);
        let mut order = Vec::with_capacity(out.tiles.len());
        for t in &mut out.tiles {
            self.holes += t.owned_holes(grid);
            for &h in t.height_slice() {
                bytes.extend_from_slice(&h.to_le_bytes());
            }
            t.heights = Array2::zeros((0, 0));
            order.push(t.row * grid[0] + t.col);
        }
        write_bytes_atomic(&path_of(dir, i), &bytes)?;
        self.shards.push((i, order));
        Ok(())
    }

    /// Writes every tile with `writer`: for each shard in turn, reads its file back into
    /// `set`'s tiles (removing the file), encodes them and drops their heights again.
    pub fn write(
        &self,
        dir: &Path,
        out_dir: &Path,
        set: &mut TileSet,
        quadtree: &Quadtree,
        writer: &mut TileWriter,
        progress: &dyn Progress,
    ) -> Result<()> {
        let n = set.tile_size;
        for (i, order) in &self.shards {
            let p = path_of(dir, *i);
            let bytes = std::fs::read(&p).map_err(|e| Error::io(&p, e))?;
            if bytes.len() != order.len() * n * n * 4 {
                return Err(Error::Internal(format!(
                    "{}: {} bytes, expected {} tiles of {n}² heights",
                    p.display(),
                    bytes.len(),
                    order.len()
                )));
            }
            std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
            for (chunk, &t) in bytes.chunks_exact(n * n * 4).zip(order) {
                let v: Vec<f32> = chunk
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                    .collect();
                set.tiles[t].heights = Array2::from_shape_vec((n, n), v)
                    .map_err(|e| Error::Internal(e.to_string()))?;
            }
            drop(bytes);
            let products = TerrainProducts {
                set,
                quadtree,
                meshes: None,
            };
            writer.write(out_dir, &products, order, progress)?;
            for &t in order {
                set.tiles[t].heights = Array2::zeros((0, 0));
            }
        }
        Ok(())
    }
}

/// Writes the tile encoders' files and the manifest of `set` (whose tiles are on disk,
/// `spilled`) into `out_dir`; returns the files written, sorted.
pub fn write_spilled(
    tmp: &Path,
    out_dir: &Path,
    mut set: TileSet,
    quadtree: &Quadtree,
    spilled: &Spilled,
    out: &crate::output::OutputConfig,
    progress: &dyn Progress,
) -> Result<Vec<String>> {
    out.validate()?;
    let summary = SetSummary::with_holes(&set, quadtree, None, spilled.holes);
    let mut writer = TileWriter::new(out_dir, summary, out)?;
    progress.start("writing tiles", set.tiles.len() as u64);
    spilled.write(tmp, out_dir, &mut set, quadtree, &mut writer, progress)?;
    progress.finish();
    let products = TerrainProducts {
        set: &set,
        quadtree,
        meshes: None,
    };
    writer.finish(out_dir, &products, out)
}
