//! The streaming run's temporary *bricks*: every point of the inputs, bucketed by a square
//! world-space lattice into one file per brick, as raw LAS integer coordinates plus the
//! point's sequence number in the whole input (file order of the inputs, then record order).
//!
//! A record is 20 bytes: X, Y, Z (i32, little-endian, on the scale and offset of the point's
//! own file) and the sequence number (u64). The integers are recovered from the decoded
//! coordinates and checked to give back the very same f64 bits, so a brick read back gives
//! the stages exactly the values the in-memory reader gives them; the sequence number puts
//! any set of points back into input order, the order the in-memory stages sum in.
//!
//! Bucketing holds one fixed-size write buffer per brick (appended to its file when full),
//! so its memory is `bricks × buffer`, whatever the input's size.

use crate::error::{Error, Result};
use crate::points::Bounds;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Bytes of one brick record.
pub const RECORD: usize = 20;

/// A square lattice of bricks over the x/y plane. A point's brick is clamped to the lattice,
/// so the first and last bricks of a row or column reach to infinity: no point is lost when
/// a header's box is not exact.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BrickLattice {
    /// South-west corner.
    pub origin: [f64; 2],
    /// Side of a brick, in horizontal units.
    pub side: f64,
    /// Bricks along x and y.
    pub n: [usize; 2],
}

impl BrickLattice {
    /// About `target` bricks of equal side over `b` (at least one).
    pub fn new(b: &Bounds, target: usize) -> BrickLattice {
        let [w, h, _] = b.size();
        let (w, h) = (w.max(1e-9), h.max(1e-9));
        let side = (w * h / target.max(1) as f64).sqrt().max(1e-9);
        let n = [
            ((w / side).floor() as usize + 1).max(1),
            ((h / side).floor() as usize + 1).max(1),
        ];
        BrickLattice {
            origin: [b.min[0], b.min[1]],
            side,
            n,
        }
    }

    /// Number of bricks.
    pub fn count(&self) -> usize {
        self.n[0] * self.n[1]
    }

    /// The brick column (a = 0) or row (a = 1) of coordinate `v`, clamped (NaN: 0).
    #[inline]
    fn index(&self, v: f64, a: usize) -> usize {
        let t = ((v - self.origin[a]) / self.side).floor();
        if t >= 0.0 {
            (t as usize).min(self.n[a] - 1)
        } else {
            0
        }
    }

    /// The brick of a point.
    #[inline]
    pub fn brick(&self, x: f64, y: f64) -> usize {
        self.index(y, 1) * self.n[0] + self.index(x, 0)
    }

    /// Every brick that may hold a point with x in `x` and y in `y` (closed ranges; an end
    /// may be infinite). The index is monotone in the coordinate, so this is exact.
    pub fn covering(&self, x: [f64; 2], y: [f64; 2]) -> Vec<usize> {
        let (i0, i1) = (self.index(x[0], 0), self.index(x[1], 0));
        let (j0, j1) = (self.index(y[0], 1), self.index(y[1], 1));
        let mut v = Vec::with_capacity((i1 + 1 - i0) * (j1 + 1 - j0));
        for j in j0..=j1 {
            for i in i0..=i1 {
                v.push(j * self.n[0] + i);
            }
        }
        v
    }
}

/// One input file's place in the sequence and its coordinate transform.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SourceTransform {
    /// Sequence number of its first kept point.
    pub first: u64,
    /// Scale factors (x, y, z).
    pub scale: [f64; 3],
    /// Offsets (x, y, z).
    pub offset: [f64; 3],
}

/// The raw integer of `v` on `scale` and `offset`, if it gives `v` back bit for bit with the
/// LAS reader's expression (`scale * X + offset`).
#[inline]
pub fn raw_of(v: f64, scale: f64, offset: f64) -> Option<i32> {
    let r = ((v - offset) / scale).round();
    if !(i32::MIN as f64..=i32::MAX as f64).contains(&r) {
        return None;
    }
    let i = r as i32;
    (scale * f64::from(i) + offset == v).then_some(i)
}

/// The path of brick `b` in `dir`.
pub fn brick_path(dir: &Path, b: usize) -> PathBuf {
    dir.join(format!("brick-{b:07}.bin"))
}

/// True for the names [`brick_path`] gives (what clean-up may remove).
pub fn is_brick_name(name: &str) -> bool {
    name.len() == "brick-0000000.bin".len()
        && name.starts_with("brick-")
        && name.ends_with(".bin")
        && name[6..13].bytes().all(|c| c.is_ascii_digit())
}

/// Appends records to the bricks' files through one fixed-size buffer per brick.
#[derive(Debug)]
pub struct BrickWriter {
    dir: PathBuf,
    lattice: BrickLattice,
    buffers: Vec<Vec<u8>>,
    capacity: usize,
    /// Records per brick.
    pub counts: Vec<u64>,
    /// Bytes written to files so far.
    pub bytes: u64,
}

impl BrickWriter {
    /// A writer into `dir` with `buffer` bytes per brick (rounded to whole records, at least
    /// 64 records).
    pub fn new(dir: &Path, lattice: BrickLattice, buffer: usize) -> BrickWriter {
        let capacity = (buffer / RECORD).max(64) * RECORD;
        BrickWriter {
            dir: dir.to_path_buf(),
            lattice,
            buffers: vec![Vec::new(); lattice.count()],
            capacity,
            counts: vec![0; lattice.count()],
            bytes: 0,
        }
    }

    /// Adds the point with raw integers `raw` and sequence number `seq` at (x, y).
    #[inline]
    pub fn push(&mut self, x: f64, y: f64, raw: [i32; 3], seq: u64) -> Result<()> {
        self.push_to(self.lattice.brick(x, y), raw, seq)
    }

    /// Adds the point with raw integers `raw` and sequence number `seq` to brick `b` (the
    /// lattice's brick of the point, found beforehand).
    #[inline]
    pub fn push_to(&mut self, b: usize, raw: [i32; 3], seq: u64) -> Result<()> {
        let buf = &mut self.buffers[b];
        if buf.capacity() == 0 {
            buf.reserve_exact(self.capacity);
        }
        buf.extend_from_slice(&raw[0].to_le_bytes());
        buf.extend_from_slice(&raw[1].to_le_bytes());
        buf.extend_from_slice(&raw[2].to_le_bytes());
        buf.extend_from_slice(&seq.to_le_bytes());
        self.counts[b] += 1;
        if buf.len() >= self.capacity {
            self.flush(b)?;
        }
        Ok(())
    }

    fn flush(&mut self, b: usize) -> Result<()> {
        let buf = &mut self.buffers[b];
        if buf.is_empty() {
            return Ok(());
        }
        let path = brick_path(&self.dir, b);
        let _creating = crate::fsutil::creating();
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(|e| Error::io(&path, e))?;
        f.write_all(buf).map_err(|e| Error::io(&path, e))?;
        self.bytes += buf.len() as u64;
        buf.clear();
        Ok(())
    }

    /// Writes every buffer out and syncs the files; returns the records per brick.
    pub fn finish(mut self) -> Result<Vec<u64>> {
        for b in 0..self.buffers.len() {
            self.flush(b)?;
            if self.counts[b] > 0 {
                let path = brick_path(&self.dir, b);
                std::fs::File::open(&path)
                    .and_then(|f| f.sync_all())
                    .map_err(|e| Error::io(&path, e))?;
            }
        }
        Ok(self.counts)
    }
}

/// Points read back from bricks: coordinates and sequence numbers, in input order.
#[derive(Debug, Clone, Default)]
pub struct BrickPoints {
    /// Easting.
    pub x: Vec<f64>,
    /// Northing.
    pub y: Vec<f64>,
    /// Height.
    pub z: Vec<f64>,
    /// Sequence number in the whole input.
    pub seq: Vec<u64>,
}

impl BrickPoints {
    /// Appends one point.
    pub fn push(&mut self, x: f64, y: f64, z: f64, seq: u64) {
        self.x.push(x);
        self.y.push(y);
        self.z.push(z);
        self.seq.push(seq);
    }

    /// The points as a noise-removal window's input: `owned` its own voxel columns, the rest
    /// of the points its halo.
    pub fn shard_input<'a>(
        &'a self,
        frame: &'a crate::terrain::denoise::Frame,
        params: &'a crate::terrain::denoise::DenoiseParams,
        metres_per_unit: f64,
        owned: &'a crate::terrain::denoise::ColumnWindow,
    ) -> crate::terrain::denoise::ShardInput<'a> {
        crate::terrain::denoise::ShardInput {
            x: &self.x,
            y: &self.y,
            z: &self.z,
            frame,
            params,
            metres_per_unit,
            owned,
        }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// True when there are none.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
}

/// The order [`load`] gives the points in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Order {
    /// Input order (by sequence number): what a stage that sums in input order needs.
    Input,
    /// Brick by brick, each brick in input order: enough for a stage whose result does not
    /// depend on the order of its points (noise removal counts and compares).
    Bricks,
}

/// The points of `bricks` in `dir` that `wanted(seq, x, y)` accepts, in `order`.
/// `counts` gives each brick's records (a brick file of another length is refused).
pub fn load(
    dir: &Path,
    bricks: &[usize],
    counts: &[u64],
    sources: &[SourceTransform],
    order: Order,
    wanted: impl Fn(u64, f64, f64) -> bool,
) -> Result<BrickPoints> {
    let mut p = BrickPoints::default();
    let total: u64 = bricks
        .iter()
        .map(|&b| counts.get(b).copied().unwrap_or(0))
        .sum();
    let cap = total as usize;
    p.x.reserve(cap);
    p.y.reserve(cap);
    p.z.reserve(cap);
    p.seq.reserve(cap);
    // Where each brick's points start in `p` (each brick is in input order).
    let mut runs = vec![0usize];
    // The source of the previous record: consecutive records are mostly of one file.
    let mut src = 0usize;
    for &b in bricks {
        let n = counts.get(b).copied().unwrap_or(0);
        if n == 0 {
            continue;
        }
        let path = brick_path(dir, b);
        let bytes = std::fs::read(&path).map_err(|e| Error::io(&path, e))?;
        if bytes.len() as u64 != n * RECORD as u64 {
            return Err(Error::format(
                &path,
                bytes.len() as u64,
                format!(
                    "temporary brick holds {} bytes, {} records of {RECORD} were written",
                    bytes.len(),
                    n
                ),
            ));
        }
        for r in bytes.chunks_exact(RECORD) {
            let int = |k: usize| i32::from_le_bytes([r[k], r[k + 1], r[k + 2], r[k + 3]]);
            let seq = u64::from_le_bytes(r[12..20].try_into().unwrap_or([0; 8]));
            let in_src = |i: usize| {
                sources[i].first <= seq && sources.get(i + 1).is_none_or(|n| seq < n.first)
            };
            if !in_src(src) {
                src = sources.partition_point(|s| s.first <= seq).max(1) - 1;
            }
            let s = &sources[src];
            // The LAS reader's expression, so the bits are the reader's.
            let x = s.scale[0] * f64::from(int(0)) + s.offset[0];
            let y = s.scale[1] * f64::from(int(4)) + s.offset[1];
            if !wanted(seq, x, y) {
                continue;
            }
            p.x.push(x);
            p.y.push(y);
            p.z.push(s.scale[2] * f64::from(int(8)) + s.offset[2]);
            p.seq.push(seq);
        }
        if p.len() > *runs.last().unwrap_or(&0) {
            runs.push(p.len());
        }
    }
    if order == Order::Input && p.seq.windows(2).any(|w| w[0] > w[1]) {
        p = merge_runs(p, &runs);
    }
    Ok(p)
}

/// The points of `p` in sequence order, each of the ranges `runs[i]..runs[i + 1]` being in
/// sequence order already: a k-way merge that takes from the run of the smallest head every
/// point below the next run's head at once (points of a scan line fall in one brick, so the
/// runs interleave in long stretches: about n + stretches · log k steps, where a sort is
/// n log n).
fn merge_runs(p: BrickPoints, runs: &[usize]) -> BrickPoints {
    use std::cmp::Reverse;
    use std::collections::BinaryHeap;
    let mut next: Vec<usize> = runs[..runs.len() - 1].to_vec();
    let mut heap: BinaryHeap<Reverse<(u64, usize)>> = next
        .iter()
        .enumerate()
        .filter(|&(r, &i)| i < runs[r + 1])
        .map(|(r, &i)| Reverse((p.seq[i], r)))
        .collect();
    let mut idx: Vec<u32> = Vec::with_capacity(p.len());
    while let Some(Reverse((_, r))) = heap.pop() {
        let bound = heap.peek().map_or(u64::MAX, |Reverse((s, _))| *s);
        let end = runs[r + 1];
        let mut i = next[r];
        while i < end && p.seq[i] < bound {
            idx.push(i as u32);
            i += 1;
        }
        next[r] = i;
        if i < end {
            heap.push(Reverse((p.seq[i], r)));
        }
    }
    let g = |v: &[f64]| idx.iter().map(|&i| v[i as usize]).collect::<Vec<f64>>();
    BrickPoints {
        x: g(&p.x),
        y: g(&p.y),
        z: g(&p.z),
        seq: idx.iter().map(|&i| p.seq[i as usize]).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_round_trips_only_exact_values() {
        let (s, o) = (0.01, 500_000.0);
        for i in [-2_000_000, -1, 0, 1, 123_456_789] {
            let v = s * f64::from(i) + o;
            assert_eq!(raw_of(v, s, o), Some(i));
        }
        assert_eq!(raw_of(500_000.005, s, o), None);
    }

    #[test]
    fn covering_holds_every_point_of_the_range() {
        let b = Bounds {
            min: [10.0, 20.0, 0.0],
            max: [110.0, 70.0, 1.0],
        };
        let l = BrickLattice::new(&b, 50);
        assert!(l.count() >= 25);
        let mut rng = crate::SplitMix64::new(7);
        let mut u = || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        for _ in 0..2000 {
            let x = 130.0 * u();
            let y = 10.0 + 70.0 * u();
            let c = l.covering([x - 3.0, x + 3.0], [y - 1.0, f64::INFINITY]);
            assert!(c.contains(&l.brick(x, y)));
        }
    }

    #[test]
    fn merged_runs_equal_a_sort() {
        // The slow twin: sort every point by its sequence number.
        let mut rng = crate::SplitMix64::new(11);
        for k in [1usize, 2, 5, 17] {
            let mut seqs: Vec<Vec<u64>> = vec![Vec::new(); k];
            for s in 0..5000u64 {
                // Stretches of one run, as scan lines give them.
                let r =
                    ((s / (1 + rng.next_u64() % 40)) as usize + (rng.next_u64() % 3) as usize) % k;
                seqs[r].push(s);
            }
            let mut p = BrickPoints::default();
            let mut runs = vec![0];
            for run in &seqs {
                for &s in run {
                    p.x.push(s as f64);
                    p.y.push(-(s as f64));
                    p.z.push(0.5 * s as f64);
                    p.seq.push(s);
                }
                runs.push(p.len());
            }
            let m = merge_runs(p.clone(), &runs);
            let mut idx: Vec<usize> = (0..p.len()).collect();
            idx.sort_by_key(|&i| p.seq[i]);
            assert_eq!(
                m.seq,
                idx.iter().map(|&i| p.seq[i]).collect::<Vec<_>>(),
                "k {k}"
            );
            assert_eq!(m.x, idx.iter().map(|&i| p.x[i]).collect::<Vec<_>>());
            assert_eq!(m.y, idx.iter().map(|&i| p.y[i]).collect::<Vec<_>>());
            assert_eq!(m.z, idx.iter().map(|&i| p.z[i]).collect::<Vec<_>>());
        }
    }

    #[test]
    fn brick_names_are_recognised() {
        let p = brick_path(Path::new("/t"), 42);
        let name = p.file_name().unwrap().to_str().unwrap();
        assert!(is_brick_name(name));
        assert!(!is_brick_name("brick-12.bin"));
        assert!(!is_brick_name("mine.bin"));
    }
}
