//! Reading by bounds, each input about once per pass.
//!
//! [`super::direct::load`] decodes, for one window or shard, every file whose box meets its
//! read range, whole: a file is decoded once per window that meets it. On a survey of 10 × 10
//! tiles under windows of about a tile's size that is about 4 decodes a point per pass, and
//! when the inputs do not stay in the page cache (19 GiB at 1 B points) each decode reads the
//! file from disk again.
//!
//! A [`PassReader`] serves one pass: the windows in the order the pass runs them, in rounds
//! of windows run at once. A round decodes each file its windows need once (the files in
//! parallel), and hands each decoded point to every window whose read range holds it: the
//! windows of the round, and the later windows of the pass, whose parts wait in a store
//! until their round. The store is bounded (`cap` bytes, 32 bytes a point): a file's parts
//! for later windows are kept soonest window first while the estimate (the share of the
//! file's box inside the window's range, times its points) fits; a later window whose part
//! was not kept decodes the file again when its turn comes. So each file is decoded once per
//! pass when the store holds the parts in flight (windows aligned with the tiles, or a small
//! overlap), and never more often than by [`super::direct::load`].
//!
//! A window's points are the ones `wanted(window, seq, x, y)` accepts, in input order (its
//! parts are put together file by file, each in record order): the very points, values,
//! sequence numbers and order [`super::direct::load`] gives, so the outputs do not change.

use super::bricks::BrickPoints;
use super::direct::Files;
use crate::error::{Error, Result};
use crate::points::{Bounds, PointCloud};
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Mutex;

/// The inputs' header figures (points and box), taken for exact before any point is read,
/// checked against the points as a pass decodes them: the streaming run's count from the
/// headers (`stream`), which saves the counting pass's full read of the survey. A file
/// checks when it gives exactly its header's number of points and its points' box (x, y, z,
/// minimum and maximum, as `terrain::bounds_of` reduces them) has the very bits of its
/// header's. A run whose check fails counts the points after all and starts the pass again.
pub struct HeaderCheck {
    /// Each file's header box and points.
    header: Vec<(Bounds, u64)>,
    /// Files decoded and found exact.
    seen: Mutex<Vec<bool>>,
    failed: AtomicBool,
}

impl HeaderCheck {
    /// A check of the files whose headers give `header` (box, points), in input order.
    pub fn new(header: Vec<(Bounds, u64)>) -> HeaderCheck {
        let n = header.len();
        HeaderCheck {
            header,
            seen: Mutex::new(vec![false; n]),
            failed: AtomicBool::new(false),
        }
    }

    /// True once some decoded file did not match its header.
    pub fn failed(&self) -> bool {
        self.failed.load(Ordering::SeqCst)
    }

    /// True when every file with points was decoded and matched its header.
    pub fn passed(&self) -> bool {
        !self.failed()
            && self.seen.lock().is_ok_and(|seen| {
                seen.iter()
                    .zip(&self.header)
                    .all(|(&s, (_, n))| s || *n == 0)
            })
    }

    /// Decodes the files with points that no pass has checked yet (those a resumed run's
    /// finished windows read) and checks them.
    pub fn check_the_rest(&self, files: &Files<'_>) -> Result<()> {
        let rest: Vec<usize> = {
            let seen = self.seen.lock().map_err(|_| poisoned())?;
            (0..seen.len())
                .filter(|&f| !seen[f] && self.header[f].1 > 0)
                .collect()
        };
        rest.into_iter().try_for_each(|f| self.check_file(files, f))
    }

    /// Decodes file `f` and checks it against its header.
    pub fn check_file(&self, files: &Files<'_>, f: usize) -> Result<()> {
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        let kept = files.decode_each_unchecked(f, &mut PointCloud::default(), |_, x, y, z| {
            lo = [lo[0].min(x), lo[1].min(y), lo[2].min(z)];
            hi = [hi[0].max(x), hi[1].max(y), hi[2].max(z)];
        })?;
        self.record(f, &Bounds { min: lo, max: hi }, kept);
        Ok(())
    }

    /// Records that file `f` gave `points` points in the box `b`.
    fn record(&self, f: usize, b: &Bounds, points: u64) {
        let (h, n) = &self.header[f];
        let bits = |b: &Bounds| [b.min, b.max].map(|v| v.map(f64::to_bits));
        if points != *n || (points > 0 && bits(b) != bits(h)) {
            self.failed.store(true, Ordering::SeqCst);
        } else if let Ok(mut seen) = self.seen.lock() {
            seen[f] = true;
        }
    }
}

/// Bytes a stored point costs: x, y, z and its sequence number.
pub const STORED_BYTES_PER_POINT: u64 = 32;

/// A window's read range: x and y, closed, ends possibly infinite.
pub type Range2 = ([f64; 2], [f64; 2]);

/// Parts waiting for later windows, by (window, file).
#[derive(Default)]
struct Store {
    parts: HashMap<(usize, usize), BrickPoints>,
    bytes: u64,
}

/// One pass's reads by bounds (see the module's documentation).
pub struct PassReader<'a, W> {
    files: Files<'a>,
    /// Each window's read range, by window index.
    ranges: Vec<Range2>,
    /// The windows in the order the pass runs them.
    order: Vec<usize>,
    /// Windows per round.
    round: usize,
    /// Per file, the positions in `order` of the windows whose range meets its box.
    meets: Vec<Vec<usize>>,
    wanted: W,
    cap: u64,
    store: Mutex<Store>,
    decoded: AtomicU64,
    stored_peak: AtomicU64,
    check: Option<&'a HeaderCheck>,
}

/// The share of `[lo, hi]` (a box's extent along one axis) inside the range `r`.
fn share(lo: f64, hi: f64, r: [f64; 2]) -> f64 {
    let (a, b) = (lo.max(r[0]), hi.min(r[1]));
    if b < a {
        0.0
    } else if hi > lo {
        (b - a) / (hi - lo)
    } else {
        1.0
    }
}

impl<'a, W> PassReader<'a, W>
where
    W: Fn(usize, u64, f64, f64) -> bool + Sync,
{
    /// A reader for the windows `order` (indices into `ranges`) run `round` at a time, with
    /// at most about `cap` bytes of parts waiting for later windows.
    pub fn new(
        files: Files<'a>,
        ranges: Vec<Range2>,
        order: Vec<usize>,
        round: usize,
        cap: u64,
        wanted: W,
    ) -> Self {
        let meets = files
            .boxes
            .iter()
            .enumerate()
            .map(|(f, b)| {
                if files.read[f] == 0 {
                    return Vec::new();
                }
                (0..order.len())
                    .filter(|&p| {
                        let (x, y) = ranges[order[p]];
                        b.meets(x, y)
                    })
                    .collect()
            })
            .collect();
        PassReader {
            files,
            ranges,
            order,
            round: round.max(1),
            meets,
            wanted,
            cap,
            store: Mutex::new(Store::default()),
            decoded: AtomicU64::new(0),
            stored_peak: AtomicU64::new(0),
            check: None,
        }
    }

    /// Checks the files against their headers as they are decoded: a file that does not
    /// match stops the pass (an error; [`HeaderCheck::failed`] tells it from others).
    pub fn with_check(mut self, check: Option<&'a HeaderCheck>) -> Self {
        self.check = check;
        self
    }

    /// Points decoded so far (every decode of a file counts all its kept points).
    pub fn decoded(&self) -> u64 {
        self.decoded.load(Ordering::Relaxed)
    }

    /// The most bytes the store held at once.
    pub fn stored_peak(&self) -> u64 {
        self.stored_peak.load(Ordering::Relaxed)
    }

    /// Windows per round.
    pub fn round(&self) -> usize {
        self.round
    }

    /// The rounds of the pass: chunks of the order.
    pub fn rounds(&self) -> usize {
        self.order.len().div_ceil(self.round)
    }

    /// The windows of round `r`.
    pub fn round_windows(&self, r: usize) -> &[usize] {
        let n = self.order.len();
        &self.order[(r * self.round).min(n)..((r + 1) * self.round).min(n)]
    }

    /// Estimated points of file `f` inside the range of the window at position `p`.
    fn estimate(&self, f: usize, p: usize) -> u64 {
        let b = &self.files.boxes[f];
        let (x, y) = self.ranges[self.order[p]];
        let s = share(b.min[0], b.max[0], x) * share(b.min[1], b.max[1], y);
        (self.files.read[f] as f64 * s).ceil() as u64
    }

    /// The points of round `r`'s windows, in the order of [`Self::round_windows`]. Rounds
    /// must be loaded in order, each once.
    pub fn load(&self, r: usize) -> Result<Vec<BrickPoints>> {
        let first = r * self.round;
        let end = ((r + 1) * self.round).min(self.order.len());
        let here = first..end;
        // Parts already waiting, and the files to decode with the windows that get them.
        let mut waiting: Vec<HashMap<usize, BrickPoints>> = vec![HashMap::new(); end - first];
        let mut decode: HashMap<usize, Vec<usize>> = HashMap::new();
        let mut store = self.store.lock().map_err(|_| poisoned())?;
        for (f, ps) in self.meets.iter().enumerate() {
            for &p in ps.iter().filter(|p| here.contains(p)) {
                match store.parts.remove(&(p, f)) {
                    Some(part) => {
                        store.bytes -= part.x.len() as u64 * STORED_BYTES_PER_POINT;
                        waiting[p - first].insert(f, part);
                    }
                    None => decode.entry(f).or_default().push(p),
                }
            }
        }
        // Each decoded file's parts for later windows, soonest first, while they fit.
        let mut planned = store.bytes;
        let mut jobs: Vec<(usize, Vec<usize>)> = decode.into_iter().collect();
        jobs.sort_unstable();
        for (f, dest) in &mut jobs {
            for &p in self.meets[*f].iter().filter(|&&p| p >= end) {
                if store.parts.contains_key(&(p, *f)) {
                    continue;
                }
                let bytes = self.estimate(*f, p) * STORED_BYTES_PER_POINT;
                if planned + bytes <= self.cap {
                    planned += bytes;
                    dest.push(p);
                }
            }
        }
        drop(store);
        let decoded: Vec<(usize, Vec<(usize, BrickPoints)>)> = jobs
            .par_iter()
            .map(|(f, dest)| Ok((*f, self.decode(*f, dest)?)))
            .collect::<Result<_>>()?;
        let mut store = self.store.lock().map_err(|_| poisoned())?;
        for (f, parts) in decoded {
            for (p, part) in parts {
                if here.contains(&p) {
                    waiting[p - first].insert(f, part);
                } else {
                    store.bytes += part.x.len() as u64 * STORED_BYTES_PER_POINT;
                    store.parts.insert((p, f), part);
                }
            }
        }
        self.stored_peak.fetch_max(store.bytes, Ordering::Relaxed);
        drop(store);
        // Each window's parts, file by file in input order.
        Ok(waiting
            .into_iter()
            .map(|mut parts| {
                let mut fs: Vec<usize> = parts.keys().copied().collect();
                fs.sort_unstable();
                let n = fs.iter().map(|f| parts[f].x.len()).sum();
                let mut out = BrickPoints {
                    x: Vec::with_capacity(n),
                    y: Vec::with_capacity(n),
                    z: Vec::with_capacity(n),
                    seq: Vec::with_capacity(n),
                };
                for f in fs {
                    if let Some(p) = parts.remove(&f) {
                        out.x.extend(p.x);
                        out.y.extend(p.y);
                        out.z.extend(p.z);
                        out.seq.extend(p.seq);
                    }
                }
                out
            })
            .collect())
    }

    /// Decodes file `f` once and gives each window at the positions `dest` the points in its
    /// range that it wants. A file that gives another number of points than the counting
    /// pass (changed since) is refused, naming it.
    fn decode(&self, f: usize, dest: &[usize]) -> Result<Vec<(usize, BrickPoints)>> {
        if self.check.is_some_and(HeaderCheck::failed) {
            // The pass starts again after a count: the files not started yet wait.
            return Err(Error::Internal("a header did not match its points".into()));
        }
        let mut cloud = PointCloud::default();
        let mut parts: Vec<(usize, BrickPoints)> =
            dest.iter().map(|&p| (p, BrickPoints::default())).collect();
        let windows: Vec<(usize, Range2)> = dest
            .iter()
            .map(|&p| (self.order[p], self.ranges[self.order[p]]))
            .collect();
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        let checking = self.check.is_some();
        let each = |seq, px: f64, py: f64, pz: f64| {
            if checking {
                // The same reduction as `terrain::bounds_of` (min and max of finite values).
                lo = [lo[0].min(px), lo[1].min(py), lo[2].min(pz)];
                hi = [hi[0].max(px), hi[1].max(py), hi[2].max(pz)];
            }
            for ((w, (rx, ry)), (_, part)) in windows.iter().zip(parts.iter_mut()) {
                // The range first (a few comparisons), then the window's own test.
                if px >= rx[0]
                    && px <= rx[1]
                    && py >= ry[0]
                    && py <= ry[1]
                    && (self.wanted)(*w, seq, px, py)
                {
                    part.push(px, py, pz, seq);
                }
            }
        };
        let kept = match self.check {
            None => self.files.decode_each(f, &mut cloud, each)?,
            Some(c) => {
                let kept = self.files.decode_each_unchecked(f, &mut cloud, each)?;
                c.record(f, &Bounds { min: lo, max: hi }, kept);
                if c.failed() {
                    return Err(Error::Internal(format!(
                        "{}: its points do not match its header's box and count",
                        self.files.path(f).display()
                    )));
                }
                kept
            }
        };
        self.decoded.fetch_add(kept, Ordering::Relaxed);
        Ok(parts)
    }
}

fn poisoned() -> Error {
    Error::Internal("the pass reader's store lock is poisoned".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shares_of_ranges() {
        assert_eq!(share(0.0, 10.0, [5.0, f64::INFINITY]), 0.5);
        assert_eq!(share(0.0, 10.0, [11.0, 12.0]), 0.0);
        assert_eq!(share(3.0, 3.0, [0.0, 5.0]), 1.0);
        assert_eq!(share(0.0, 10.0, [f64::NEG_INFINITY, f64::INFINITY]), 1.0);
    }
}
