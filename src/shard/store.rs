//! The on-disk form of a shard job's result (`terratile shard`), read back by the jobs of
//! the next phase and by `terratile merge`.
//!
//! The cheapest honest format: a fixed 40-byte header, then a payload of little-endian
//! values and arrays, each array preceded by its length (u64). Hand-written rather than a
//! serialisation crate because the payload is a handful of flat numeric arrays whose exact
//! bits matter (f32/f64 written as their bit patterns, so a result reads back bit for bit)
//! and because every length read must be bounded by the bytes the file holds (a corrupt
//! length never makes an allocation the file cannot justify).
//!
//! Header (all little-endian):
//!
//! | bytes | field                                                          |
//! |-------|----------------------------------------------------------------|
//! | 0–7   | magic `TTSHARD1`                                               |
//! | 8–11  | phase (1 count, 2 keep, 3 prepare, 4 finish)                   |
//! | 12–15 | CRC-32 of the plan file the job ran under                      |
//! | 16–23 | job index                                                      |
//! | 24–31 | payload length in bytes                                        |
//! | 32–35 | CRC-32 (IEEE, as zlib computes it) of the payload              |
//! | 36–39 | zero                                                           |
//!
//! A result is written to a temporary sibling and renamed into place
//! (`fsutil::write_bytes_atomic`): a killed job leaves no half result, and a rerun replaces
//! the file with the same bytes.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

const MAGIC: &[u8; 8] = b"TTSHARD1";
const HEADER: usize = 40;

/// A result being built: the payload of little-endian values, after room for the header
/// (filled in by `save`, so the payload, hundreds of MB for a large shard, is never copied).
#[derive(Debug)]
pub struct Writer {
    buf: Vec<u8>,
}

impl Default for Writer {
    fn default() -> Self {
        Writer {
            buf: vec![0; HEADER],
        }
    }
}

impl Writer {
    /// A u64.
    pub fn u64(&mut self, v: u64) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// An f64, as its bits.
    pub fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }

    /// A length-prefixed array of u8.
    pub fn bytes(&mut self, v: &[u8]) {
        self.buf.reserve(8 + v.len());
        self.u64(v.len() as u64);
        self.buf.extend_from_slice(v);
    }

    /// A length-prefixed array of u32.
    pub fn u32s(&mut self, v: impl ExactSizeIterator<Item = u32>) {
        self.buf.reserve(8 + 4 * v.len());
        self.u64(v.len() as u64);
        for x in v {
            self.buf.extend_from_slice(&x.to_le_bytes());
        }
    }

    /// A length-prefixed array of f32, as their bits.
    pub fn f32s(&mut self, v: impl ExactSizeIterator<Item = f32>) {
        self.u32s(v.map(f32::to_bits));
    }

    /// A length-prefixed array of u64.
    pub fn u64s(&mut self, v: impl ExactSizeIterator<Item = u64>) {
        self.buf.reserve(8 + 8 * v.len());
        self.u64(v.len() as u64);
        for x in v {
            self.u64(x);
        }
    }

    /// Writes the result atomically to `path` (its directory created).
    pub fn save(self, path: &Path, phase: u32, plan: u32, index: u64) -> Result<()> {
        let mut out = self.buf;
        let payload = &out[HEADER..];
        let (len, crc) = (payload.len() as u64, crc32(payload));
        let mut head = Vec::with_capacity(HEADER);
        head.extend_from_slice(MAGIC);
        head.extend_from_slice(&phase.to_le_bytes());
        head.extend_from_slice(&plan.to_le_bytes());
        head.extend_from_slice(&index.to_le_bytes());
        head.extend_from_slice(&len.to_le_bytes());
        head.extend_from_slice(&crc.to_le_bytes());
        head.extend_from_slice(&[0; 4]);
        out[..HEADER].copy_from_slice(&head);
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        }
        crate::fsutil::write_bytes_atomic(path, &out)
    }
}

fn crc32(b: &[u8]) -> u32 {
    let mut c = flate2::Crc::new();
    c.update(b);
    c.sum()
}

/// A result being read: every value checked against the bytes left, every error one line
/// naming the file and the byte offset.
#[derive(Debug)]
pub struct Reader {
    path: PathBuf,
    /// The file, mapped: a job is a fresh process, and reading hundreds of MB into a new
    /// buffer made the kernel zero every page of it first (40 % of a `finish` job's page
    /// faults); mapped pages come straight from the page cache.
    bytes: memmap2::Mmap,
    pos: usize,
}

impl Reader {
    /// Opens the result at `path`, checking its header (magic, phase, plan, index, length,
    /// checksum).
    pub fn open(path: &Path, phase: u32, plan: u32, index: u64) -> Result<Reader> {
        let bad = |at: u64, m: &str| Err(Error::format(path, at, m.to_string()));
        match std::fs::metadata(path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(Error::Usage(format!(
                    "{}: no result of this job yet (run its `terratile shard` first)",
                    path.display()
                )))
            }
            Ok(m) if m.is_file() && m.len() < HEADER as u64 => {
                return bad(0, "not a terratile shard result (no TTSHARD1 header)");
            }
            _ => {}
        }
        let bytes = crate::fsutil::map_file(path)?;
        if bytes.len() < HEADER || &bytes[..8] != MAGIC {
            return bad(0, "not a terratile shard result (no TTSHARD1 header)");
        }
        let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().unwrap_or([0; 4]));
        let u64_at = |o: usize| u64::from_le_bytes(bytes[o..o + 8].try_into().unwrap_or([0; 8]));
        if u32_at(8) != phase {
            return bad(8, "a result of another phase");
        }
        if u32_at(12) != plan {
            return bad(
                12,
                "made under another plan (plan the run again or rerun this job)",
            );
        }
        if u64_at(16) != index {
            return bad(16, "the result of another job index");
        }
        if u64_at(24) != (bytes.len() - HEADER) as u64 {
            return bad(
                24,
                "payload length differs from the file's size (truncated?)",
            );
        }
        if u32_at(32) != crc32(&bytes[HEADER..]) {
            return bad(
                32,
                "checksum mismatch: the result is corrupt (rerun this job)",
            );
        }
        Ok(Reader {
            path: path.to_path_buf(),
            bytes,
            pos: HEADER,
        })
    }

    fn err(&self, m: impl Into<String>) -> Error {
        Error::format(&self.path, self.pos as u64, m)
    }

    fn take(&mut self, n: usize) -> Result<&[u8]> {
        if self.bytes.len() - self.pos < n {
            return Err(self.err(format!(
                "{n} bytes expected, {} left",
                self.bytes.len() - self.pos
            )));
        }
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    /// A u64.
    pub fn u64(&mut self) -> Result<u64> {
        let b = self.take(8)?;
        Ok(u64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
    }

    /// A u64 that must fit a usize no larger than `max` (`what` names it in the error).
    pub fn usize(&mut self, max: usize, what: &str) -> Result<usize> {
        let v = self.u64()?;
        match usize::try_from(v) {
            Ok(v) if v <= max => Ok(v),
            _ => Err(self.err(format!("{what} {v} is out of range (at most {max})"))),
        }
    }

    /// An f64.
    pub fn f64(&mut self) -> Result<f64> {
        self.u64().map(f64::from_bits)
    }

    /// The length of an array of `size`-byte elements, checked against the bytes left.
    fn len(&mut self, size: usize) -> Result<usize> {
        let left = (self.bytes.len() - self.pos - 8.min(self.bytes.len() - self.pos)) / size;
        self.usize(left, "array length")
    }

    /// A length-prefixed array of u8.
    pub fn bytes(&mut self) -> Result<Vec<u8>> {
        let n = self.len(1)?;
        Ok(self.take(n)?.to_vec())
    }

    /// A length-prefixed array of u32.
    pub fn u32s(&mut self) -> Result<Vec<u32>> {
        let n = self.len(4)?;
        Ok(self
            .take(4 * n)?
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }

    /// A length-prefixed array of f32.
    pub fn f32s(&mut self) -> Result<Vec<f32>> {
        Ok(self.u32s()?.into_iter().map(f32::from_bits).collect())
    }

    /// A length-prefixed array of u64.
    pub fn u64s(&mut self) -> Result<Vec<u64>> {
        let n = self.len(8)?;
        (0..n).map(|_| self.u64()).collect()
    }

    /// An error at the current offset, for a value that reads but does not fit.
    pub fn invalid(&self, m: impl Into<String>) -> Error {
        self.err(m)
    }

    /// Checks that every byte was read.
    pub fn end(&self) -> Result<()> {
        if self.pos != self.bytes.len() {
            return Err(self.err("trailing bytes after the result"));
        }
        Ok(())
    }
}

/// True for `name` = `prefix`, a decimal shard index, `.bin`: a per-shard temporary file.
pub(crate) fn is_numbered(name: &str, prefix: &str) -> bool {
    name.strip_prefix(prefix)
        .and_then(|r| r.strip_suffix(".bin"))
        .is_some_and(|r| !r.is_empty() && r.bytes().all(|c| c.is_ascii_digit()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_corruption() {
        let dir = std::env::temp_dir().join(format!("tt-store-{}", std::process::id()));
        let p = dir.join("r.bin");
        let mut w = Writer::default();
        w.u64(7);
        w.f64(-0.0);
        w.f32s([1.5f32, f32::NAN].into_iter());
        w.bytes(&[1, 2, 3]);
        w.save(&p, 2, 99, 3).unwrap();
        let mut r = Reader::open(&p, 2, 99, 3).unwrap();
        assert_eq!(r.u64().unwrap(), 7);
        assert_eq!(r.f64().unwrap().to_bits(), (-0.0f64).to_bits());
        let f = r.f32s().unwrap();
        assert_eq!((f[0], f[1].is_nan()), (1.5, true));
        assert_eq!(r.bytes().unwrap(), [1, 2, 3]);
        r.end().unwrap();
        assert!(Reader::open(&p, 1, 99, 3).is_err(), "phase");
        assert!(Reader::open(&p, 2, 98, 3).is_err(), "plan");
        assert!(Reader::open(&p, 2, 99, 4).is_err(), "index");
        // One flipped payload bit, then a truncation: both refused with the offset.
        let mut b = std::fs::read(&p).unwrap();
        b[HEADER + 3] ^= 1;
        std::fs::write(&p, &b).unwrap();
        let e = Reader::open(&p, 2, 99, 3).unwrap_err().to_string();
        assert!(e.contains("byte 32: checksum"), "{e}");
        std::fs::write(&p, &b[..b.len() - 1]).unwrap();
        let e = Reader::open(&p, 2, 99, 3).unwrap_err().to_string();
        assert!(e.contains("byte 24"), "{e}");
        // A huge array length inside a valid checksum is refused, not allocated.
        let mut w = Writer::default();
        w.u64(u64::MAX / 2);
        w.save(&p, 1, 1, 0).unwrap();
        let mut r = Reader::open(&p, 1, 1, 0).unwrap();
        assert!(r.f32s().unwrap_err().to_string().contains("out of range"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
