//! `terratile convert`: LAS/LAZ to uncompressed LAS with every record passed through byte for
//! byte (all attributes kept), optionally cut to the first N points or a seeded random
//! sample of N. This is how the benchmark inputs are made from the real LAZ tiles.

use super::las_records::{self, Layout};
use super::{map_file, raw_records, write_raw_las, ClassFilter, PointCloud};
use crate::error::{Error, Result};
use crate::rng::SplitMix64;
use std::path::Path;

/// Which records `convert` keeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Selection {
    /// Every record.
    All,
    /// The first `n` records in file order.
    First(u64),
    /// `n` records drawn uniformly without replacement with `seed`, kept in file order.
    Sample {
        /// How many.
        n: u64,
        /// Seed of the draw.
        seed: u64,
    },
}

/// Converts `input` (LAS or LAZ) to an uncompressed LAS at `output`; returns points written.
pub fn convert(input: &Path, output: &Path, selection: Selection) -> Result<u64> {
    let map = map_file(input)?;
    let (h, records) = raw_records(input, &map)?;
    let picked = select(input, &h, &records, selection)?;
    let out: &[u8] = picked.as_deref().unwrap_or(&records);
    let layout = Layout {
        len: h.record_length as usize,
        extended: h.point_format >= 6,
        scale: h.scale,
        offset: h.offset,
        // Only the count and the bounds are wanted from the decoded points.
        columns: super::Columns::XYZ,
    };
    let mut cloud = PointCloud::default();
    let (_, bounds) = las_records::decode(out, &layout, &ClassFilter::default(), None, &mut cloud);
    write_raw_las(output, &h, out, &bounds)?;
    Ok(cloud.len() as u64)
}

/// Converts `input` (LAS or LAZ) to a COPC 1.0 file at `output` (see [`super::copc`]).
pub fn convert_copc(
    input: &Path,
    output: &Path,
    selection: Selection,
) -> Result<super::copc::CopcWritten> {
    let map = map_file(input)?;
    let (h, records) = raw_records(input, &map)?;
    let picked = select(input, &h, &records, selection)?;
    super::copc::write_copc(&h, picked.as_deref().unwrap_or(&records), output)
}

/// The records `selection` keeps: `None` for all of them.
fn select(
    input: &Path,
    h: &super::LasHeader,
    records: &[u8],
    selection: Selection,
) -> Result<Option<Vec<u8>>> {
    let len = h.record_length as usize;
    let total = h.point_count;
    Ok(match selection {
        Selection::All => None,
        Selection::First(n) => {
            if n > total {
                return Err(Error::Usage(format!(
                    "{}: asked for the first {n} points, the file holds {total}",
                    input.display()
                )));
            }
            Some(records[..n as usize * len].to_vec())
        }
        Selection::Sample { n, seed } => {
            if n > total {
                return Err(Error::Usage(format!(
                    "{}: asked for a sample of {n} points, the file holds {total}",
                    input.display()
                )));
            }
            let idx = SplitMix64::new(seed).sample_indices(total as usize, n as usize);
            let mut buf = Vec::with_capacity(idx.len() * len);
            for &i in &idx {
                buf.extend_from_slice(&records[i as usize * len..(i as usize + 1) * len]);
            }
            Some(buf)
        }
    })
}
