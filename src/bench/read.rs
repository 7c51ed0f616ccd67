//! `bench read`: decoding a point file against a plain copy of its bytes.

use super::median;
use crate::error::{Error, Result};
use crate::points::{self, map_file, ReadOptions};
use crate::progress::NoProgress;
use rayon::prelude::*;
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// Result of `bench read`.
#[derive(Debug, Clone, Serialize)]
pub struct ReadBench {
    /// The file measured.
    pub file: String,
    /// Its format.
    pub format: String,
    /// Points decoded.
    pub points: u64,
    /// File size in bytes (what both sides move).
    pub bytes: u64,
    /// Median seconds to map and decode the file into a PointCloud.
    pub decode_s: f64,
    /// Median seconds to map the file afresh and copy its bytes into a new buffer (parallel).
    pub copy_s: f64,
    /// Decode throughput, MB/s of file bytes.
    pub decode_mb_s: f64,
    /// Copy throughput, MB/s.
    pub copy_mb_s: f64,
    /// Decode throughput / copy throughput.
    pub ratio: f64,
    /// Points per second of our decoder.
    pub points_per_s: f64,
    /// Points per second of `las::Reader` on the same file, when asked for.
    pub las_rs_points_per_s: Option<f64>,
    /// Our points/s over las::Reader's.
    pub speedup_vs_las_rs: Option<f64>,
    /// Repetitions (medians are reported).
    pub repeats: usize,
}

/// Maps `path` afresh and copies every byte into a new buffer with all threads; returns a
/// checksum so the copy cannot be optimised away.
pub fn copy_file_bytes(path: &Path) -> Result<u64> {
    let map = map_file(path)?;
    let mut dst = vec![0u8; map.len()];
    dst.par_chunks_mut(1 << 20)
        .zip(map.par_chunks(1 << 20))
        .for_each(|(d, s)| d.copy_from_slice(s));
    Ok(dst.iter().step_by(4096).map(|&b| b as u64).sum())
}

/// The reference reader: `las::Reader` reads every record and each becomes a `las::Point`,
/// whose x, y, z and class go into columns, as a las-rs user would build them.
pub fn read_with_las_rs(path: &Path) -> Result<points::PointCloud> {
    let err = |e: las::Error| Error::Usage(format!("{}: las::Reader: {e}", path.display()));
    let mut r = las::Reader::from_path(path).map_err(err)?;
    let data = r.read_all().map_err(err)?;
    let mut c = points::PointCloud::default();
    let n = data.len();
    c.x.reserve_exact(n);
    c.y.reserve_exact(n);
    c.z.reserve_exact(n);
    c.classification.reserve_exact(n);
    for p in data.points() {
        let p = p.map_err(err)?;
        c.x.push(p.x);
        c.y.push(p.y);
        c.z.push(p.z);
        c.classification.push(u8::from(p.classification));
    }
    Ok(c)
}

/// Times decoding `path` against copying its bytes, `repeats` times each, interleaved.
pub fn read(
    path: &Path,
    opts: &ReadOptions,
    repeats: usize,
    compare_las_rs: bool,
) -> Result<ReadBench> {
    let repeats = repeats.max(1);
    let bytes = std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .len();
    // Warm the page cache so that both sides read from memory, not disk.
    let first = points::read(path, opts, &NoProgress)?;
    let points = first.len() as u64;
    let format = first
        .sources
        .first()
        .map(|s| s.format.to_string())
        .unwrap_or_default();
    drop(first);
    let (mut dec, mut cp, mut lr) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..repeats {
        let t = Instant::now();
        std::hint::black_box(copy_file_bytes(path)?);
        cp.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let c = points::read(path, opts, &NoProgress)?;
        std::hint::black_box(&c);
        drop(c);
        dec.push(t.elapsed().as_secs_f64());
        if compare_las_rs {
            let t = Instant::now();
            std::hint::black_box(read_with_las_rs(path)?);
            lr.push(t.elapsed().as_secs_f64());
        }
    }
    let decode_s = median(dec);
    let copy_s = median(cp);
    let mb = bytes as f64 / 1e6;
    let las_rs_points_per_s = (!lr.is_empty()).then(|| points as f64 / median(lr));
    let points_per_s = points as f64 / decode_s;
    Ok(ReadBench {
        file: path.display().to_string(),
        format,
        points,
        bytes,
        decode_s,
        copy_s,
        decode_mb_s: mb / decode_s,
        copy_mb_s: mb / copy_s,
        ratio: copy_s / decode_s,
        points_per_s,
        las_rs_points_per_s,
        speedup_vs_las_rs: las_rs_points_per_s.map(|l| points_per_s / l),
        repeats,
    })
}

impl std::fmt::Display for ReadBench {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{} ({}, {} points, {:.1} MB)",
            self.file,
            self.format,
            self.points,
            self.bytes as f64 / 1e6
        )?;
        writeln!(
            f,
            "  decode  {:>8.4} s  {:>8.0} MB/s  {:>6.1} M points/s",
            self.decode_s,
            self.decode_mb_s,
            self.points_per_s / 1e6
        )?;
        writeln!(
            f,
            "  copy    {:>8.4} s  {:>8.0} MB/s",
            self.copy_s, self.copy_mb_s
        )?;
        writeln!(f, "  ratio decode/copy throughput: {:.2}", self.ratio)?;
        if let (Some(l), Some(s)) = (self.las_rs_points_per_s, self.speedup_vs_las_rs) {
            writeln!(
                f,
                "  las::Reader {:>6.1} M points/s; terratile is {s:.1}x faster",
                l / 1e6
            )?;
        }
        writeln!(f, "  (median of {} runs)", self.repeats)
    }
}
