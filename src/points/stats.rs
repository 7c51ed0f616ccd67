//! Summary statistics of a cloud for `terratile info`: bounds, class and return histograms,
//! mean point spacing.

use super::{Bounds, PointCloud};
use rayon::prelude::*;
use serde::Serialize;

/// Counts per value of a u8 attribute, listing only values that occur.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Histogram(pub Vec<(u8, u64)>);

impl Histogram {
    /// Counts the values of `col` in parallel.
    pub fn of(col: &[u8]) -> Histogram {
        let counts = col
            .par_chunks(1 << 16)
            .fold(
                || [0u64; 256],
                |mut h, c| {
                    for &v in c {
                        h[v as usize] += 1;
                    }
                    h
                },
            )
            .reduce(
                || [0u64; 256],
                |mut a, b| {
                    for (x, y) in a.iter_mut().zip(b) {
                        *x += y;
                    }
                    a
                },
            );
        Histogram(
            counts
                .iter()
                .enumerate()
                .filter(|(_, &n)| n > 0)
                .map(|(v, &n)| (v as u8, n))
                .collect(),
        )
    }

    /// The count for value `v`.
    pub fn get(&self, v: u8) -> u64 {
        self.0.iter().find(|(k, _)| *k == v).map_or(0, |(_, n)| *n)
    }
}

/// What `terratile info` reports about the points of a cloud.
#[derive(Debug, Clone, Serialize)]
pub struct CloudStats {
    /// Number of points.
    pub points: u64,
    /// Tight bounds of the points (None for an empty cloud).
    pub bounds: Option<Bounds>,
    /// Points per ASPRS class (empty if the source has no classes).
    pub classes: Histogram,
    /// Points per return number (empty if the source has none).
    pub returns: Histogram,
    /// Mean point spacing s = sqrt(bbox area / N), in the data's horizontal units.
    pub mean_spacing: Option<f64>,
}

impl CloudStats {
    /// Computes the statistics.
    pub fn of(cloud: &PointCloud) -> CloudStats {
        let bounds = (!cloud.is_empty()).then(|| cloud.bounds());
        CloudStats {
            points: cloud.len() as u64,
            bounds,
            classes: Histogram::of(&cloud.classification),
            returns: Histogram::of(&cloud.return_number),
            mean_spacing: bounds.and_then(|b| mean_spacing(&b, cloud.len())),
        }
    }
}

/// Mean spacing sqrt(area / N) of `n` points spread over the xy extent of `b`; None when the
/// extent has no area.
pub fn mean_spacing(b: &Bounds, n: usize) -> Option<f64> {
    let [w, h, _] = b.size();
    let area = w * h;
    (n > 0 && area > 0.0 && area.is_finite()).then(|| (area / n as f64).sqrt())
}

/// ASPRS standard class names (LAS 1.4 R15 Table 17).
pub fn class_name(c: u8) -> &'static str {
    match c {
        0 => "never classified",
        1 => "unclassified",
        2 => "ground",
        3 => "low vegetation",
        4 => "medium vegetation",
        5 => "high vegetation",
        6 => "building",
        7 => "low point (noise)",
        8 => "model key point",
        9 => "water",
        10 => "rail",
        11 => "road surface",
        12 => "overlap",
        13 => "wire guard",
        14 => "wire conductor",
        15 => "transmission tower",
        16 => "wire connector",
        17 => "bridge deck",
        18 => "high noise",
        _ => "user defined",
    }
}

/// Everything `terratile info` says about one file.
#[derive(Debug, Clone, Serialize)]
pub struct FileInfo {
    /// Header facts.
    pub source: super::SourceInfo,
    /// Point statistics.
    pub stats: CloudStats,
}

impl FileInfo {
    /// Reads `path` whole and summarises it.
    pub fn of(
        path: &std::path::Path,
        opts: &super::ReadOptions,
        progress: &dyn crate::progress::Progress,
    ) -> crate::Result<FileInfo> {
        let cloud = super::read(path, opts, progress)?;
        let stats = CloudStats::of(&cloud);
        let source = cloud
            .sources
            .into_iter()
            .next()
            .ok_or_else(|| crate::Error::Internal("reader returned no source".into()))?;
        Ok(FileInfo { source, stats })
    }
}

impl std::fmt::Display for FileInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = &self.source;
        writeln!(f, "{}", s.path.display())?;
        write!(f, "  format        {}", s.format)?;
        if let Some((a, b)) = s.version {
            write!(f, " {a}.{b}")?;
        }
        if let Some(pf) = s.point_format {
            write!(f, ", point format {pf}")?;
        }
        if let Some(rl) = s.record_length {
            write!(f, " ({rl}-byte records)")?;
        }
        writeln!(f)?;
        writeln!(
            f,
            "  points        {} ({} in file)",
            self.stats.points, s.points_in_file
        )?;
        if let Some(b) = &self.stats.bounds {
            for (k, axis) in ["x", "y", "z"].iter().enumerate() {
                writeln!(f, "  {axis}             {:.3} .. {:.3}", b.min[k], b.max[k])?;
            }
        }
        if let (Some(sc), Some(of)) = (s.scale, s.offset) {
            writeln!(f, "  scale         {} {} {}", sc[0], sc[1], sc[2])?;
            writeln!(f, "  offset        {} {} {}", of[0], of[1], of[2])?;
        }
        match &s.crs {
            Some(c) => {
                let t = c.text();
                let short: String = t.chars().take(120).collect();
                writeln!(
                    f,
                    "  crs           {short}{}",
                    if t.chars().count() > 120 { "…" } else { "" }
                )?;
                if let Some(u) = &c.unit {
                    writeln!(f, "  units         {} ({} m)", u.name, u.metres)?;
                }
            }
            None => writeln!(f, "  crs           none in the file")?,
        }
        if let Some(sp) = self.stats.mean_spacing {
            writeln!(f, "  mean spacing  {sp:.3} (sqrt(bbox area / points))")?;
        }
        if !self.stats.classes.0.is_empty() {
            writeln!(f, "  classes")?;
            for (c, n) in &self.stats.classes.0 {
                writeln!(f, "    {c:>3} {:<20} {n:>12}", class_name(*c))?;
            }
        }
        if !self.stats.returns.0.is_empty() {
            writeln!(f, "  returns")?;
            for (r, n) in &self.stats.returns.0 {
                writeln!(f, "    {r:>3} {n:>12}")?;
            }
        }
        Ok(())
    }
}
