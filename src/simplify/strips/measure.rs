//! The paper's figures: indices sent to the GPU at each level (unfiltered, STSS, DTFS, and
//! a triangle-list progressive mesh), split sizes, and the vertex-cache miss ratio.

use super::filter::{dtfs_into, stss};
use super::progressive::{Decoder, Encoding, Progressive};
use super::stripify::{each_triangle, Join, RESTART};
use serde::Serialize;

/// Indices a renderer sends at one level.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LevelIndices {
    /// Splits applied.
    pub level: usize,
    /// Triangles drawn (three distinct vertices).
    pub triangles: usize,
    /// The strip as decoded (degenerate triangles and all).
    pub unfiltered: usize,
    /// After STSS.
    pub stss: usize,
    /// After DTFS (restarts included).
    pub dtfs: usize,
    /// The restarts among them (what separate draw calls per strip would not send).
    pub dtfs_restarts: usize,
    /// A triangle list of the same triangles (3 per triangle).
    pub list: usize,
}

/// [`LevelIndices`] at `levels` (ascending), decoded in place from the base up.
pub fn gpu_indices(p: &Progressive, levels: &[usize], join: Join) -> Vec<LevelIndices> {
    let mut d = Decoder::new(p, Encoding::Encoded);
    let mut buf = Vec::new();
    levels
        .iter()
        .map(|&l| {
            d.set_level(l);
            let mut triangles = 0;
            each_triangle(d.strip(), |_| triangles += 1);
            dtfs_into(d.strip(), join, &mut buf);
            LevelIndices {
                level: d.level(),
                triangles,
                unfiltered: d.strip().len(),
                stss: stss(d.strip(), join).len(),
                dtfs: buf.len(),
                dtfs_restarts: buf.iter().filter(|&&v| v == RESTART).count(),
                list: 3 * triangles,
            }
        })
        .collect()
}

/// `count` levels evenly spaced from the base (0) to the full level, both included.
pub fn even_levels(p: &Progressive, count: usize) -> Vec<usize> {
    let n = p.splits.len();
    let count = count.max(2);
    let mut v: Vec<usize> = (0..count).map(|i| i * n / (count - 1)).collect();
    v.dedup();
    v
}
