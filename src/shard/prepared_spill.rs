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
//! (`jobs::write_prepared` / `jobs::read_prepared_from` through the result format of
//! [`super::store`]: header, checksum, every length bounded by the file), not a second
//! serialisation. Files are written atomically, named `prepared-I.bin` in the run's
//! temporary directory (removed with it on success, failure and interruption), and each is
//! removed as soon as it is read back.

use super::jobs::{read_prepared_from, write_prepared};
use super::store::{Reader, Writer};
use super::{Prepared, ShardLayout};
use crate::error::{Error, Result};
use crate::points::Crs;
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
    super::spill::is_numbered(name, "prepared-")
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
