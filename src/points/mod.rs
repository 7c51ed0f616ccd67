//! Point clouds in: the struct-of-arrays [`PointCloud`], its bounds, and the readers for
//! LAS/LAZ (memory-mapped, records decoded in parallel) and XYZ/CSV text.
//!
//! Formats are recognised from the content: a `LASF` signature is LAS, or LAZ when the point
//! format carries the compression bit or a LASzip VLR is present; anything else that looks
//! like text is XYZ.

mod convert;
pub mod copc;
mod crs;
mod las_header;
mod las_read;
mod las_records;
mod las_write;
mod stats;
mod xyz;

pub use convert::{convert, convert_copc, Selection};
pub use crs::{Crs, LinearUnit, VerticalCrs};
pub use las_header::{LasHeader, Vlr};
pub(crate) use las_read::for_each_decoded;
pub use las_read::raw_records;
pub use las_write::{
    write_las, write_raw_las, write_reclassified_raw, write_reclassified_records,
    write_selected_records, LasWriteOptions,
};
pub use stats::{class_name, CloudStats, FileInfo, Histogram};
pub use xyz::parse_xyz;

use crate::error::{Error, Result};
use crate::progress::Progress;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// ASPRS class 7, "low point (noise)": the class terratile gives the points noise removal
/// drops when it writes them out (LAS 1.4 R15, Table 17).
pub const LOW_NOISE_CLASS: u8 = 7;

/// Point coordinates in world units (f64) plus the per-point attributes later stages need,
/// stored column by column.
///
/// Cost per point: x, y, z (3 × 8 bytes), classification (1), return number (1), number of
/// returns (1) and intensity (2): 29 bytes when the source has every attribute. Attributes
/// the source lacks (XYZ text) are empty columns and cost nothing.
#[derive(Debug, Clone, Default)]
pub struct PointCloud {
    /// Easting.
    pub x: Vec<f64>,
    /// Northing.
    pub y: Vec<f64>,
    /// Height.
    pub z: Vec<f64>,
    /// ASPRS class per point (2 ground, 7 low noise, 18 high noise, …); empty if unknown.
    pub classification: Vec<u8>,
    /// Return number (1-based) per point; empty if unknown.
    pub return_number: Vec<u8>,
    /// Number of returns of the pulse per point; empty if unknown.
    pub number_of_returns: Vec<u8>,
    /// Pulse return intensity per point; empty if unknown.
    pub intensity: Vec<u16>,
    /// Where the points came from, one entry per source file.
    pub sources: Vec<SourceInfo>,
}

/// What a reader learned about one input file from its header.
#[derive(Debug, Clone, Serialize)]
pub struct SourceInfo {
    /// The file.
    pub path: PathBuf,
    /// Its format.
    pub format: Format,
    /// LAS version (major, minor), for LAS/LAZ.
    pub version: Option<(u8, u8)>,
    /// LAS point data record format (0–10), for LAS/LAZ.
    pub point_format: Option<u8>,
    /// LAS point record length in bytes.
    pub record_length: Option<u16>,
    /// Points the file holds (header count for LAS/LAZ, data lines for XYZ).
    pub points_in_file: u64,
    /// Points kept after the class filter and the cap.
    pub points_read: u64,
    /// Scale factors (x, y, z), for LAS/LAZ.
    pub scale: Option<[f64; 3]>,
    /// Offsets (x, y, z), for LAS/LAZ.
    pub offset: Option<[f64; 3]>,
    /// Bounds as the header states them (LAS/LAZ).
    pub header_bounds: Option<Bounds>,
    /// Coordinate reference system from the VLRs, if any.
    pub crs: Option<Crs>,
}

/// Point cloud file formats terratile reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// ASPRS LAS 1.0–1.4, uncompressed.
    Las,
    /// LASzip-compressed LAS.
    Laz,
    /// Text: x y z first three numeric columns.
    Xyz,
}

impl std::fmt::Display for Format {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Format::Las => "LAS",
            Format::Laz => "LAZ",
            Format::Xyz => "XYZ",
        })
    }
}

/// An axis-aligned 3-D box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Bounds {
    /// Minimum x, y, z.
    pub min: [f64; 3],
    /// Maximum x, y, z.
    pub max: [f64; 3],
}

impl Bounds {
    /// The empty box (min = +∞, max = −∞), the identity of [`Bounds::union`].
    pub const EMPTY: Bounds = Bounds {
        min: [f64::INFINITY; 3],
        max: [f64::NEG_INFINITY; 3],
    };

    /// True when no point has been added.
    pub fn is_empty(&self) -> bool {
        self.min[0] > self.max[0]
    }

    /// Grows the box to hold `p`.
    #[inline]
    pub fn add(&mut self, p: [f64; 3]) {
        for (k, v) in p.into_iter().enumerate() {
            self.min[k] = self.min[k].min(v);
            self.max[k] = self.max[k].max(v);
        }
    }

    /// The smallest box holding both.
    pub fn union(self, o: Bounds) -> Bounds {
        let mut b = self;
        for k in 0..3 {
            b.min[k] = b.min[k].min(o.min[k]);
            b.max[k] = b.max[k].max(o.max[k]);
        }
        b
    }

    /// Extent along each axis.
    pub fn size(&self) -> [f64; 3] {
        [
            self.max[0] - self.min[0],
            self.max[1] - self.min[1],
            self.max[2] - self.min[2],
        ]
    }
}

/// Which classes to keep: a 256-entry table built from keep/drop lists.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClassFilter {
    keep: [bool; 256],
    active: bool,
    keep_list_given: bool,
}

impl Default for ClassFilter {
    fn default() -> Self {
        ClassFilter {
            keep: [true; 256],
            active: false,
            keep_list_given: false,
        }
    }
}

impl ClassFilter {
    /// Keep only `keep` (all classes if `None`), then drop every class in `drop`.
    pub fn new(keep: Option<&[u8]>, drop: &[u8]) -> ClassFilter {
        let mut table = [keep.is_none(); 256];
        if let Some(keep) = keep {
            for &c in keep {
                table[c as usize] = true;
            }
        }
        for &c in drop {
            table[c as usize] = false;
        }
        ClassFilter {
            active: table.iter().any(|k| !k),
            keep: table,
            keep_list_given: keep.is_some(),
        }
    }

    /// True if points of class `c` are kept.
    #[inline(always)]
    pub fn keeps(&self, c: u8) -> bool {
        self.keep[c as usize]
    }

    /// True if some class is filtered out.
    pub fn is_active(&self) -> bool {
        self.active
    }

    /// True if the filter was given an explicit keep list.
    pub fn has_keep_list(&self) -> bool {
        self.keep_list_given
    }
}

/// Reader options: format override, class filter, point cap, attribute columns.
#[derive(Debug, Clone, Default)]
pub struct ReadOptions {
    /// Force a format instead of recognising it from the content.
    pub format: Option<Format>,
    /// Which classes to keep.
    pub classes: ClassFilter,
    /// Keep at most this many points (the first ones in file order, after the class filter).
    pub max_points: Option<u64>,
    /// Which attribute columns to fill besides x, y and z (default all).
    pub columns: Columns,
}

/// Which attribute columns of a [`PointCloud`] a reader fills besides x, y and z. A column
/// left out is neither decoded nor stored: it stays empty, as for XYZ text, which has none.
/// The terrain stages read x, y and z only; the class filter reads the records' classes
/// whatever this says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Columns {
    /// `classification`.
    pub class: bool,
    /// `return_number` and `number_of_returns`.
    pub returns: bool,
    /// `intensity`.
    pub intensity: bool,
}

impl Columns {
    /// Every attribute column.
    pub const ALL: Columns = Columns {
        class: true,
        returns: true,
        intensity: true,
    };
    /// None: x, y and z only.
    pub const XYZ: Columns = Columns {
        class: false,
        returns: false,
        intensity: false,
    };
}

impl Default for Columns {
    fn default() -> Self {
        Columns::ALL
    }
}

impl PointCloud {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// True if there are no points.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Reserves room for exactly `additional` more points in the coordinate columns and
    /// in the attribute columns of `attributes` too (an XYZ file has none: those columns stay
    /// empty). The one place that sizes the columns ahead of a reader.
    pub(crate) fn reserve_exact(&mut self, additional: usize, attributes: Columns) {
        self.x.reserve_exact(additional);
        self.y.reserve_exact(additional);
        self.z.reserve_exact(additional);
        if attributes.class {
            self.classification.reserve_exact(additional);
        }
        if attributes.returns {
            self.return_number.reserve_exact(additional);
            self.number_of_returns.reserve_exact(additional);
        }
        if attributes.intensity {
            self.intensity.reserve_exact(additional);
        }
    }

    /// The tight bounding box of the points (computed in parallel).
    pub fn bounds(&self) -> Bounds {
        self.x
            .par_iter()
            .zip(&self.y)
            .zip(&self.z)
            .fold(
                || Bounds::EMPTY,
                |mut b, ((&x, &y), &z)| {
                    b.add([x, y, z]);
                    b
                },
            )
            .reduce(|| Bounds::EMPTY, Bounds::union)
    }

    /// The CRS of the first source that has one.
    pub fn crs(&self) -> Option<&Crs> {
        self.sources.iter().find_map(|s| s.crs.as_ref())
    }

    /// Bytes held by the point columns (what the ≤ 30 bytes/point budget counts).
    pub fn heap_bytes(&self) -> usize {
        self.x.capacity() * 8
            + self.y.capacity() * 8
            + self.z.capacity() * 8
            + self.classification.capacity()
            + self.return_number.capacity()
            + self.number_of_returns.capacity()
            + self.intensity.capacity() * 2
    }

    /// Appends `other`'s points; an attribute column survives only if both clouds have it.
    pub fn append(&mut self, mut other: PointCloud) {
        let n = self.len();
        fn merge<T: Copy>(a: &mut Vec<T>, b: Vec<T>, n: usize, m: usize) {
            if a.len() == n && b.len() == m {
                a.extend_from_slice(&b);
            } else {
                *a = Vec::new();
            }
        }
        if n == 0 && self.sources.is_empty() {
            std::mem::swap(self, &mut other);
            return;
        }
        let m = other.len();
        self.x.extend_from_slice(&other.x);
        self.y.extend_from_slice(&other.y);
        self.z.extend_from_slice(&other.z);
        merge(&mut self.classification, other.classification, n, m);
        merge(&mut self.return_number, other.return_number, n, m);
        merge(&mut self.number_of_returns, other.number_of_returns, n, m);
        merge(&mut self.intensity, other.intensity, n, m);
        self.sources.append(&mut other.sources);
    }

    /// A new cloud with the points whose `keep` flag is set, in order (parallel gather).
    pub fn select(&self, keep: &[bool]) -> PointCloud {
        assert_eq!(
            keep.len(),
            self.len(),
            "select: mask length differs from cloud"
        );
        let idx: Vec<u32> = keep
            .iter()
            .enumerate()
            .filter_map(|(i, &k)| k.then_some(i as u32))
            .collect();
        self.gather(&idx)
    }

    /// A new cloud with the points at `idx`, in that order (parallel gather).
    pub fn gather(&self, idx: &[u32]) -> PointCloud {
        fn col<T: Copy + Send + Sync>(src: &[T], idx: &[u32]) -> Vec<T> {
            if src.is_empty() {
                return Vec::new();
            }
            idx.par_iter().map(|&i| src[i as usize]).collect()
        }
        PointCloud {
            x: col(&self.x, idx),
            y: col(&self.y, idx),
            z: col(&self.z, idx),
            classification: col(&self.classification, idx),
            return_number: col(&self.return_number, idx),
            number_of_returns: col(&self.number_of_returns, idx),
            intensity: col(&self.intensity, idx),
            sources: self.sources.clone(),
        }
    }
}

/// Recognises a file's format from its first bytes.
pub fn detect_format(path: &Path, head: &[u8]) -> Result<Format> {
    if head.is_empty() {
        return Err(Error::format(path, 0, "empty file"));
    }
    if head.starts_with(b"LASF") {
        return Ok(if las_header::looks_compressed(head) {
            Format::Laz
        } else {
            Format::Las
        });
    }
    // Text: the first kilobyte is printable ASCII (or bytes ≥ 0x80) with line breaks. Bytes
    // that are not UTF-8 are left to the XYZ parser, which names the line they spoil.
    let probe = &head[..head.len().min(1024)];
    let bad = probe
        .iter()
        .position(|&b| !(b == b'\n' || b == b'\r' || b == b'\t' || b >= 0x20) || b == 0x7f);
    match bad {
        None => Ok(Format::Xyz),
        Some(at) => Err(Error::format(
            path,
            at as u64,
            format!(
                "unrecognised format: no LASF signature, and byte 0x{:02x} is not text",
                probe[at]
            ),
        )),
    }
}

pub use crate::fsutil::{map_file, not_a_regular_file};

/// Reads one point cloud file (LAS, LAZ or XYZ; recognised from its content).
///
/// ```
/// use terratile::points::{self, ClassFilter, ReadOptions};
/// let path = std::env::temp_dir().join(format!("doc-read-{}.xyz", std::process::id()));
/// std::fs::write(&path, "x y z\n1 2 3\n4 5 6.5\n").unwrap();
/// let cloud = points::read(&path, &ReadOptions::default(), &terratile::NoProgress).unwrap();
/// assert_eq!(cloud.z, [3.0, 6.5]);
/// assert!(cloud.classification.is_empty(), "text carries no classes");
/// # std::fs::remove_file(&path).unwrap();
/// ```
pub fn read(path: &Path, opts: &ReadOptions, progress: &dyn Progress) -> Result<PointCloud> {
    let map = map_file(path)?;
    let cloud = read_bytes(path, &map, opts, progress);
    // Unmapping the file takes the kernel one serial pass over its page-table entries
    // (about 9 ms for a 90 MB file, most of this step's serial time): a rayon worker does it
    // while the caller goes on to the next stage.
    rayon::spawn(move || drop(map));
    cloud
}

/// [`read`], also returning the tight bounds of the points read, the same as
/// [`PointCloud::bounds`] gives: a LAS or LAZ reader measures them chunk by chunk while it
/// decodes (the chunks are still in the cache), which saves the first stage its own pass over
/// the whole columns; for XYZ they are measured afterwards.
pub fn read_with_bounds(
    path: &Path,
    opts: &ReadOptions,
    progress: &dyn Progress,
) -> Result<(PointCloud, Bounds)> {
    let map = map_file(path)?;
    let read = read_bytes_bounds(path, &map, opts, progress);
    // As in `read`: a worker unmaps the file.
    rayon::spawn(move || drop(map));
    let (cloud, bounds) = read?;
    let bounds = bounds.unwrap_or_else(|| cloud.bounds());
    Ok((cloud, bounds))
}

/// [`read`] on the bytes of a file already in memory; `path` names it in messages.
pub fn read_bytes(
    path: &Path,
    map: &[u8],
    opts: &ReadOptions,
    progress: &dyn Progress,
) -> Result<PointCloud> {
    read_bytes_bounds(path, map, opts, progress).map(|(cloud, _)| cloud)
}

/// [`read_bytes`] with the points' bounds where the reader measured them (LAS, LAZ).
fn read_bytes_bounds(
    path: &Path,
    map: &[u8],
    opts: &ReadOptions,
    progress: &dyn Progress,
) -> Result<(PointCloud, Option<Bounds>)> {
    if map.is_empty() {
        return Err(Error::format(path, 0, "empty file"));
    }
    let format = match opts.format {
        Some(f) => f,
        None => detect_format(path, map)?,
    };
    match format {
        Format::Las | Format::Laz => las_read::read_las_bounds(path, map, opts, progress, None)
            .map(|(cloud, b)| (cloud, Some(b))),
        Format::Xyz => {
            if opts.classes.has_keep_list() {
                return Err(Error::Usage(format!(
                    "{}: a keep-classes filter is set, but XYZ text has no classification",
                    path.display()
                )));
            }
            let mut cloud = parse_xyz(path, map, progress)?;
            if let Some(cap) = opts.max_points {
                cloud.truncate(cap as usize);
            }
            Ok((cloud, None))
        }
    }
}

/// The decompressed point records of a LAZ file, kept by [`read_keeping_records`].
#[derive(Debug, Clone)]
pub struct RawRecords {
    /// The file's header.
    pub header: LasHeader,
    /// Every record of the file in file order, `header.record_length` bytes each.
    pub records: Vec<u8>,
}

/// [`read`], also keeping the decompressed records of a LAZ file when every record becomes a
/// point (no class filter, no cap), so that a writer of those records need not decode the
/// file again (`terratile classify IN OUT`). `None` for LAS (its records are in the file
/// already, mapped without decoding), XYZ, or a filtered or capped read.
pub fn read_keeping_records(
    path: &Path,
    opts: &ReadOptions,
    progress: &dyn Progress,
) -> Result<(PointCloud, Option<RawRecords>)> {
    let map = map_file(path)?;
    let laz = opts.format.is_none_or(|f| f == Format::Laz)
        && !map.is_empty()
        && detect_format(path, &map)? == Format::Laz;
    if !laz || opts.classes.is_active() || opts.max_points.is_some() {
        return Ok((read_bytes(path, &map, opts, progress)?, None));
    }
    let mut records = Vec::new();
    let cloud = las_read::read_las_keeping(path, &map, opts, progress, Some(&mut records))?;
    let header = LasHeader::parse(path, &map)?;
    Ok((cloud, Some(RawRecords { header, records })))
}

/// Reads several files into one cloud (adjacent tiles of one survey), in the order given.
pub fn read_all(
    paths: &[PathBuf],
    opts: &ReadOptions,
    progress: &dyn Progress,
) -> Result<PointCloud> {
    read_all_with_bounds(paths, opts, progress).map(|(cloud, _)| cloud)
}

/// [`read_all`], also returning the tight bounds of all the points read, as
/// [`read_with_bounds`] measures them file by file ([`Bounds::EMPTY`] when none was read):
/// the run's memory estimate, its read report and noise removal take them instead of each
/// making its own pass over the columns.
pub fn read_all_with_bounds(
    paths: &[PathBuf],
    opts: &ReadOptions,
    progress: &dyn Progress,
) -> Result<(PointCloud, Bounds)> {
    let mut cloud = PointCloud::default();
    let mut bounds = Bounds::EMPTY;
    for p in paths {
        let mut o = opts.clone();
        if let Some(cap) = opts.max_points {
            o.max_points = Some(cap.saturating_sub(cloud.len() as u64));
        }
        let (c, b) = read_with_bounds(p, &o, progress)?;
        if !c.is_empty() {
            bounds = bounds.union(b);
        }
        cloud.append(c);
    }
    Ok((cloud, bounds))
}

impl PointCloud {
    /// Keeps the first `n` points.
    pub fn truncate(&mut self, n: usize) {
        if n >= self.len() {
            return;
        }
        self.x.truncate(n);
        self.y.truncate(n);
        self.z.truncate(n);
        for c in [
            &mut self.classification,
            &mut self.return_number,
            &mut self.number_of_returns,
        ] {
            c.truncate(n);
        }
        self.intensity.truncate(n);
        if let Some(s) = self.sources.last_mut() {
            s.points_read = s.points_read.min(n as u64);
        }
    }
}
