//! Reading by bounds: the streaming run's alternative to bricks for tiled surveys.
//!
//! A survey delivered as many small tiles is already bucketed: each file holds the points of
//! one small box. Then a window or shard can read the few files whose points meet its read
//! range instead of bricks, and the bucketing pass (20 bytes of temporary disk a point,
//! written once and read back at least twice) becomes a counting pass that writes nothing:
//! each file's kept points are counted (their sequence numbers) and their exact x/y box is
//! taken. The box is the points' own, not the header's, so a file whose header box is wrong
//! is still read wherever its points are.
//!
//! A file is read whole (LAS records are not sorted in space), so each point is decoded once
//! per window or shard whose range meets its file's box: [`amplification`] estimates that
//! factor from the headers before the run, and the streaming run reads directly only when it
//! is small and the files are uncompressed LAS (decoding a LAS record costs about what
//! reading a brick record back costs; a LAZ record costs several times more, so compressed
//! surveys are bucketed unless `[scale] read = "direct"` says otherwise).
//!
//! The points come in input order (file order, then record order), which is both orders
//! [`super::bricks::load`] gives, with the same sequence numbers and the very f64 values the
//! in-memory reader gives (the same decoder, the same class filter and point cap).

use super::bricks::{BrickPoints, SourceTransform};
use crate::error::{Error, Result};
use crate::points::copc::{self, NodeChunk};
use crate::points::{self, Bounds, PointCloud, ReadOptions};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Records decoded per batch while reading a file by bounds.
const BATCH: usize = 1 << 18;

/// A piece of an input read on its own: a COPC file's octree node (see
/// [`crate::points::copc`]), whose points are the records of its chunk, so that a window
/// decodes only the nodes whose box meets its range.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Part {
    /// The input file's index.
    pub file: usize,
    /// The node's chunk (`None`: the whole file, not COPC).
    pub node: Option<NodeChunk>,
}

/// One input file's kept points: their exact x/y box (empty: no point kept).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FileBox {
    /// Minimum x and y.
    pub min: [f64; 2],
    /// Maximum x and y.
    pub max: [f64; 2],
}

impl FileBox {
    /// The x/y part of `b`.
    pub fn of(b: &Bounds) -> FileBox {
        FileBox {
            min: [b.min[0], b.min[1]],
            max: [b.max[0], b.max[1]],
        }
    }

    /// True when a point of the box may have x in `x` and y in `y` (closed ranges; an end
    /// may be infinite). An empty box (min > max) meets nothing.
    pub fn meets(&self, x: [f64; 2], y: [f64; 2]) -> bool {
        self.min[0] <= self.max[0]
            && self.min[1] <= self.max[1]
            && self.min[0] <= x[1]
            && self.max[0] >= x[0]
            && self.min[1] <= y[1]
            && self.max[1] >= y[0]
    }
}

/// The inputs as the counting pass left them, in units: the files, or when `parts` is not
/// empty, the parts it lists (COPC nodes, each file's in file order, then the files in input
/// order), the unit's figures below then being the part's.
#[derive(Debug, Clone, Copy)]
pub struct Files<'a> {
    /// The input files, in input order.
    pub paths: &'a [PathBuf],
    /// The units when not the files.
    pub parts: &'a [Part],
    /// Each file's first sequence number and transform.
    pub sources: &'a [SourceTransform],
    /// Each file's kept points.
    pub read: &'a [u64],
    /// Each file's box.
    pub boxes: &'a [FileBox],
    /// The read options (class filter, point cap) of the run.
    pub opts: &'a ReadOptions,
}

impl Files<'_> {
    /// The units: files or parts.
    pub fn units(&self) -> usize {
        if self.parts.is_empty() {
            self.paths.len()
        } else {
            self.parts.len()
        }
    }

    /// The file of unit `i`.
    pub fn path(&self, i: usize) -> &Path {
        match self.parts.get(i) {
            Some(p) => &self.paths[p.file],
            None => &self.paths[i],
        }
    }

    /// Decodes file `i` whole, calling `each(seq, x, y, z)` for every point it keeps in
    /// record order, with the sequence numbers the counting pass gave it. A file that gives
    /// another number of points than the counting pass (changed since) is refused, naming
    /// it. Returns the points decoded.
    pub fn decode_each(
        &self,
        i: usize,
        cloud: &mut PointCloud,
        each: impl FnMut(u64, f64, f64, f64),
    ) -> Result<u64> {
        let kept = self.decode_each_unchecked(i, cloud, each)?;
        if kept != self.read[i] {
            return Err(changed_during_run(self.path(i), kept, self.read[i]));
        }
        Ok(kept)
    }

    /// [`Self::decode_each`] without the check of the number of points: returns the points
    /// kept, whatever the counting pass (or the header) said.
    pub fn decode_each_unchecked(
        &self,
        i: usize,
        cloud: &mut PointCloud,
        mut each: impl FnMut(u64, f64, f64, f64),
    ) -> Result<u64> {
        let path = self.path(i);
        let first = self.sources[i].first;
        let mut o = self.opts.clone();
        if let Some(cap) = self.opts.max_points {
            o.max_points = Some(cap.saturating_sub(first));
        }
        let map = points::map_file(path)?;
        let mut seq = first;
        if let Some(node) = self.parts.get(i).and_then(|p| p.node) {
            let h = points::LasHeader::parse(path, &map)?;
            let kept = copc::decode_node(path, &map, &h, &node, &o, o.max_points, cloud)?;
            for k in 0..cloud.len() {
                each(seq, cloud.x[k], cloud.y[k], cloud.z[k]);
                seq += 1;
            }
            return Ok(kept);
        }
        let (_, kept) = points::for_each_decoded(path, &map, &o, BATCH, cloud, |c, _| {
            for k in 0..c.len() {
                each(seq, c.x[k], c.y[k], c.z[k]);
                seq += 1;
            }
            Ok(())
        })?;
        Ok(kept)
    }
}

/// The counting pass over a COPC file's nodes (`layout`'s): each node's kept points and
/// their exact box, the first node's first sequence number being `first`. The nodes are
/// decoded in parallel unless a point cap may end inside one (then in order, each capped).
pub fn count_nodes(
    path: &Path,
    map: &[u8],
    h: &points::LasHeader,
    layout: &copc::CopcLayout,
    opts: &ReadOptions,
    first: u64,
) -> Result<Vec<(u64, Bounds)>> {
    use rayon::prelude::*;
    let one = |nd: &NodeChunk, cap: Option<u64>, cloud: &mut PointCloud| -> Result<(u64, Bounds)> {
        let kept = copc::decode_node(path, map, h, nd, opts, cap, cloud)?;
        let b = crate::terrain::bounds_of(&cloud.x, &cloud.y, &cloud.z, None).0;
        Ok((kept, if kept == 0 { Bounds::EMPTY } else { b }))
    };
    match opts.max_points {
        None => layout
            .nodes
            .par_iter()
            .map_init(PointCloud::default, |cloud, nd| one(nd, None, cloud))
            .collect(),
        Some(cap) => {
            let (mut seq, mut cloud) = (first, PointCloud::default());
            let mut out = Vec::with_capacity(layout.nodes.len());
            for nd in &layout.nodes {
                let left = cap.saturating_sub(seq);
                let r = if left == 0 {
                    (0, Bounds::EMPTY)
                } else {
                    one(nd, Some(left), &mut cloud)?
                };
                seq += r.0;
                out.push(r);
            }
            Ok(out)
        }
    }
}

/// The points of the files whose box meets `x` × `y` that `wanted(seq, x, y)` accepts, in
/// input order. A file that gives another number of points than the counting pass (changed
/// since) is refused, naming it.
pub fn load(
    f: &Files<'_>,
    x: [f64; 2],
    y: [f64; 2],
    wanted: impl Fn(u64, f64, f64) -> bool,
) -> Result<BrickPoints> {
    let mut p = BrickPoints::default();
    let mut cloud = PointCloud::default();
    for i in 0..f.units() {
        if f.read[i] == 0 || !f.boxes[i].meets(x, y) {
            continue;
        }
        f.decode_each(i, &mut cloud, |seq, px, py, pz| {
            if wanted(seq, px, py) {
                p.push(px, py, pz, seq);
            }
        })?;
    }
    Ok(p)
}

/// The error of a file that gives `kept` points where the counting pass counted `counted`.
fn changed_during_run(path: &std::path::Path, kept: u64, counted: u64) -> Error {
    Error::format(
        path,
        0,
        format!(
            "gives {kept} points where the first pass of this run counted {counted}: it \
             changed during the run"
        ),
    )
}

/// About how many times each point is decoded when windows holding `window_points` points
/// read the files of `boxes` (header boxes and point counts) by bounds: a box of w × h meets
/// about (w / s + 1)(h / s + 1) windows of side s, for a random placement. `None` when the
/// boxes say nothing (no points, a degenerate survey).
pub fn amplification(files: &[(Bounds, u64)], window_points: u64) -> Option<f64> {
    let all = files.iter().fold(Bounds::EMPTY, |b, (f, _)| b.union(*f));
    let total: u64 = files.iter().map(|f| f.1).sum();
    let [w, h, _] = all.size();
    let area = w * h;
    if total == 0 || area.is_nan() || area <= 0.0 || area.is_infinite() {
        return None;
    }
    let side = (window_points as f64 * w * h / total as f64).sqrt();
    let reads: f64 = files
        .iter()
        .map(|(b, n)| {
            let [fw, fh, _] = b.size();
            *n as f64 * (fw.max(0.0) / side + 1.0) * (fh.max(0.0) / side + 1.0)
        })
        .sum();
    Some(reads / total as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn b(x0: f64, y0: f64, x1: f64, y1: f64) -> Bounds {
        Bounds {
            min: [x0, y0, 0.0],
            max: [x1, y1, 1.0],
        }
    }

    #[test]
    fn boxes_meet_closed_ranges() {
        let f = FileBox::of(&b(0.0, 0.0, 10.0, 5.0));
        assert!(f.meets([10.0, 20.0], [5.0, f64::INFINITY]), "corner touch");
        assert!(!f.meets([10.5, 20.0], [0.0, 1.0]));
        assert!(!f.meets([0.0, 1.0], [-3.0, -0.1]));
        assert!(FileBox::of(&b(3.0, 3.0, 3.0, 3.0)).meets([3.0, 3.0], [0.0, 9.0]));
        assert!(!FileBox::of(&Bounds::EMPTY).meets(
            [f64::NEG_INFINITY, f64::INFINITY],
            [f64::NEG_INFINITY, f64::INFINITY]
        ));
    }

    #[test]
    fn amplification_of_tiles_and_of_one_file() {
        // 10 × 10 tiles of 1000 × 1000 with 1 M points each; windows of 1 M points have the
        // tile's side: each tile meets about 4 windows.
        let tiles: Vec<(Bounds, u64)> = (0..100)
            .map(|k| {
                let (i, j) = ((k % 10) as f64, (k / 10) as f64);
                (
                    b(
                        i * 1000.0,
                        j * 1000.0,
                        (i + 1.0) * 1000.0,
                        (j + 1.0) * 1000.0,
                    ),
                    1_000_000,
                )
            })
            .collect();
        let a = amplification(&tiles, 1_000_000).unwrap();
        assert!((a - 4.0).abs() < 1e-9, "{a}");
        // One file of the same survey: every window reads it all.
        let one = [(b(0.0, 0.0, 10_000.0, 10_000.0), 100_000_000)];
        assert!(amplification(&one, 1_000_000).unwrap() > 100.0);
        assert_eq!(amplification(&[], 5), None);
    }

    /// A file that gives another number of points than the counting pass counted (changed
    /// between the passes) is refused with one line naming it, from every reader by bounds.
    #[test]
    fn a_file_changed_since_the_count_is_refused_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tile.las");
        let cloud = PointCloud {
            x: vec![1.0, 2.0, 3.0],
            y: vec![1.0, 2.0, 3.0],
            z: vec![0.0, 0.5, 1.0],
            ..PointCloud::default()
        };
        crate::points::write_las(&path, &cloud, &Default::default()).unwrap();
        let paths = [path.clone()];
        let sources = [SourceTransform {
            first: 0,
            scale: [0.01; 3],
            offset: [0.0; 3],
        }];
        let boxes = [FileBox::of(&b(1.0, 1.0, 3.0, 3.0))];
        let opts = ReadOptions::default();
        for (counted, ok) in [(3, true), (5, false)] {
            let read = [counted];
            let files = Files {
                paths: &paths,
                parts: &[],
                sources: &sources,
                read: &read,
                boxes: &boxes,
                opts: &opts,
            };
            let mut seqs = Vec::new();
            let r = files.decode_each(0, &mut PointCloud::default(), |seq, _, _, _| seqs.push(seq));
            let all = [f64::NEG_INFINITY, f64::INFINITY];
            let l = load(&files, all, all, |_, _, _| true);
            if ok {
                assert_eq!((r.unwrap(), seqs), (3, vec![0, 1, 2]));
                assert_eq!(l.unwrap().seq, vec![0, 1, 2]);
            } else {
                for e in [r.unwrap_err(), l.unwrap_err()] {
                    let m = e.to_string();
                    assert!(
                        m.contains("tile.las") && m.contains("changed during the run"),
                        "{m}"
                    );
                    assert!(!m.contains('\n'), "{m}");
                }
            }
        }
    }

    /// A COPC file read by node: a small window decodes a few nodes (fewer points than the
    /// file holds) and gets exactly the points, values and sequence numbers that the whole
    /// file read as plain LAZ gives inside its range (the slow twin), with a class filter.
    #[test]
    fn copc_nodes_read_by_bounds_equal_the_whole_file() {
        let dir = tempfile::tempdir().unwrap();
        let (las, copc) = (dir.path().join("a.las"), dir.path().join("a.copc.laz"));
        let mut rng = crate::rng::SplitMix64::new(3);
        let n = 240_000;
        let cloud = PointCloud {
            x: (0..n).map(|_| rng.range(0.0, 2000.0)).collect(),
            y: (0..n).map(|_| rng.range(0.0, 1000.0)).collect(),
            z: (0..n).map(|_| rng.range(0.0, 30.0)).collect(),
            classification: (0..n).map(|i| [1, 2, 7][i % 3]).collect(),
            ..PointCloud::default()
        };
        crate::points::write_las(&las, &cloud, &Default::default()).unwrap();
        points::convert_copc(&las, &copc, points::Selection::All).unwrap();
        let opts = ReadOptions {
            classes: crate::points::ClassFilter::new(None, &[7]),
            ..ReadOptions::default()
        };
        let map = points::map_file(&copc).unwrap();
        let h = points::LasHeader::parse(&copc, &map).unwrap();
        let l = copc::layout(&copc, &map, &h).unwrap().unwrap();
        assert!(l.nodes.len() > 4);
        let counted = count_nodes(&copc, &map, &h, &l, &opts, 0).unwrap();
        let mut first = 0;
        let (mut sources, mut read, mut boxes, mut parts) = (vec![], vec![], vec![], vec![]);
        for (nd, (kept, b)) in l.nodes.iter().zip(counted) {
            sources.push(SourceTransform {
                first,
                scale: h.scale,
                offset: h.offset,
            });
            first += kept;
            read.push(kept);
            boxes.push(FileBox::of(&b));
            parts.push(Part {
                file: 0,
                node: Some(*nd),
            });
        }
        let paths = [copc.clone()];
        let files = Files {
            paths: &paths,
            parts: &parts,
            sources: &sources,
            read: &read,
            boxes: &boxes,
            opts: &opts,
        };
        let whole = points::read(&copc, &opts, &crate::NoProgress).unwrap();
        assert_eq!(first, whole.len() as u64);
        let (x, y) = ([300.0, 500.0], [200.0, 400.0]);
        let got = load(&files, x, y, |_, px, py| {
            px >= x[0] && px <= x[1] && py >= y[0] && py <= y[1]
        })
        .unwrap();
        let want: Vec<u64> = (0..whole.len())
            .filter(|&i| {
                let (px, py) = (whole.x[i], whole.y[i]);
                px >= x[0] && px <= x[1] && py >= y[0] && py <= y[1]
            })
            .map(|i| i as u64)
            .collect();
        assert!(!want.is_empty());
        assert_eq!(got.seq, want);
        for (k, &s) in got.seq.iter().enumerate() {
            let s = s as usize;
            assert_eq!(
                [got.x[k], got.y[k], got.z[k]],
                [whole.x[s], whole.y[s], whole.z[s]]
            );
        }
        let decoded: u64 = (0..files.units())
            .filter(|&i| boxes[i].meets(x, y))
            .map(|i| read[i])
            .sum();
        assert!(decoded < first / 2, "{decoded} of {first}");
    }
}
