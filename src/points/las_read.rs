//! LAS and LAZ into a [`PointCloud`]: the header through [`LasHeader`], the records through
//! [`super::las_records`]. LAZ is decompressed by the `laz` crate's parallel chunk
//! decompressor in batches, and each batch goes through the same record decoder as LAS.

use super::las_header::LasHeader;
use super::las_records::{self, Layout};
use super::{Format, PointCloud, ReadOptions, SourceInfo};
use crate::error::{Error, Result};
use crate::progress::Progress;
use std::borrow::Cow;
use std::io::{Cursor, Seek, SeekFrom};
use std::path::Path;

/// Points decompressed per LAZ batch: 1 Mi points is 20–67 MB of records, enough to keep
/// every core busy on LASzip chunks (50 000 points each) without holding the whole file.
const LAZ_BATCH: u64 = 1 << 20;

/// A LAS or LAZ file into a cloud, also appending every decompressed record of a LAZ file to
/// `keep` when given (the batches are decompressed straight into it, so nothing is copied): a writer that needs
/// the records then does not decode the file a second time. Uncompressed records are not
/// kept (they are in the mapped file already).
pub(crate) fn read_las_keeping(
    path: &Path,
    bytes: &[u8],
    opts: &ReadOptions,
    progress: &dyn Progress,
    keep: Option<&mut Vec<u8>>,
) -> Result<PointCloud> {
    read_las_bounds(path, bytes, opts, progress, keep).map(|(cloud, _)| cloud)
}

/// [`read_las_keeping`], also returning the tight bounds of the points read (measured while
/// decoding).
pub(crate) fn read_las_bounds(
    path: &Path,
    bytes: &[u8],
    opts: &ReadOptions,
    progress: &dyn Progress,
    mut keep: Option<&mut Vec<u8>>,
) -> Result<(PointCloud, super::Bounds)> {
    let h = LasHeader::parse(path, bytes)?;
    if opts.format == Some(Format::Las) && h.compressed {
        return Err(Error::format(
            path,
            super::las_header::off::POINT_FORMAT,
            "format is set to las, but the point data is LASzip-compressed",
        ));
    }
    let layout = Layout::of(&h, opts.columns);
    let mut cloud = PointCloud::default();
    let mut bounds = super::Bounds::EMPTY;
    let wanted = opts
        .max_points
        .map_or(h.point_count, |c| c.min(h.point_count));
    let fits = || {
        crate::memory::check_alloc(wanted.saturating_mul(crate::memory::POINT_BYTES), || {
            format!("{}: {wanted} points", path.display())
        })
    };

    if !h.compressed {
        let records = uncompressed_records(path, bytes, &h)?;
        fits()?;
        progress.start(&format!("reading {}", path.display()), h.point_count);
        bounds =
            las_records::decode(records, &layout, &opts.classes, opts.max_points, &mut cloud).1;
        progress.advance(h.point_count);
    } else {
        // Reserved only once the chunk table vouches for the header's point count.
        let mut dec = LazDecoder::new(path, bytes, &h)?;
        fits()?;
        if keep.is_some() {
            let n = wanted.saturating_mul(h.record_length as u64);
            crate::memory::check_alloc(n, || {
                format!("{}: {wanted} decompressed records", path.display())
            })?;
        }
        progress.start(&format!("reading {}", path.display()), h.point_count);
        cloud.reserve_exact(wanted as usize, opts.columns);
        let mut buf = Vec::new();
        let mut done = 0u64;
        while done < h.point_count {
            let left = opts
                .max_points
                .map(|c| c.saturating_sub(cloud.len() as u64));
            if left == Some(0) {
                break;
            }
            let n = LAZ_BATCH.min(h.point_count - done);
            let batch = match keep.as_deref_mut() {
                Some(out) => {
                    let at = out.len();
                    out.resize(at + n as usize * dec.item_size, 0);
                    dec.decompress(&mut out[at..])?;
                    &out[at..]
                }
                None => {
                    dec.next_batch(n, &mut buf)?;
                    &buf[..]
                }
            };
            let (_, b) = las_records::decode(batch, &layout, &opts.classes, left, &mut cloud);
            bounds = bounds.union(b);
            done += n;
            progress.advance(n);
        }
    }
    progress.finish();
    cloud.sources.push(SourceInfo {
        path: path.to_path_buf(),
        format: if h.compressed {
            Format::Laz
        } else {
            Format::Las
        },
        version: Some(h.version),
        point_format: Some(h.point_format),
        record_length: Some(h.record_length),
        points_in_file: h.point_count,
        points_read: cloud.len() as u64,
        scale: Some(h.scale),
        offset: Some(h.offset),
        header_bounds: Some(h.bounds()),
        crs: h.crs.clone(),
    });
    Ok((cloud, bounds))
}

/// The point record bytes of an uncompressed LAS, checked against the header's promise.
fn uncompressed_records<'a>(path: &Path, bytes: &'a [u8], h: &LasHeader) -> Result<&'a [u8]> {
    let len = h.record_length as u64;
    let start = h.offset_to_points;
    let avail = (bytes.len() as u64).saturating_sub(start);
    let whole = avail / len;
    if whole < h.point_count {
        return Err(Error::format(
            path,
            start + whole * len,
            format!(
                "truncated point records: the header promises {} points of {len} bytes from byte {start}, the file holds {whole}",
                h.point_count
            ),
        ));
    }
    Ok(&bytes[start as usize..(start + h.point_count * len) as usize])
}

/// Batched parallel LASzip decompression over a memory map.
struct LazDecoder<'a> {
    path: &'a Path,
    inner: laz::ParLasZipDecompressor<Cursor<&'a [u8]>>,
    item_size: usize,
    offset: u64,
}

impl<'a> LazDecoder<'a> {
    fn new(path: &'a Path, bytes: &'a [u8], h: &LasHeader) -> Result<LazDecoder<'a>> {
        let at = h.offset_to_points;
        let vlr = h.laszip_vlr().ok_or_else(|| {
            Error::format(
                path,
                super::las_header::off::POINT_FORMAT,
                "compressed point format, but no LASzip VLR",
            )
        })?;
        let laz_vlr = guard(path, at, || laz::LazVlr::read_from(vlr.data.as_slice()))?
            .map_err(|e| Error::format(path, at, format!("unreadable LASzip VLR: {e}")))?;
        check_chunk_table(path, bytes, h)?;
        // The chunk table's entries, checked against the bytes present and the header's
        // point count before the decompressor sizes its buffers from them.
        let table = {
            let mut c = Cursor::new(bytes);
            c.seek(SeekFrom::Start(at))
                .map_err(|e| Error::io(path, e))?;
            guard(path, at, || {
                laz::laszip::ChunkTable::read_from(&mut c, &laz_vlr)
            })?
            .map_err(|e| Error::format(path, at, format!("unreadable LAZ chunk table: {e}")))?
        };
        let data = (bytes.len() as u64).saturating_sub(at + 8);
        let (mut points, mut stored) = (0u64, 0u64);
        // The decompressor holds a whole chunk's records; no chunk may be larger than the
        // file's points (or 1 Mi points, for a file smaller than its chunk size).
        let max_chunk = h.point_count.max(1 << 20);
        for (k, e) in table.as_ref().iter().enumerate() {
            if e.point_count > max_chunk {
                return Err(Error::format(
                    path,
                    at,
                    format!(
                        "LAZ chunk {k} claims {} points, more than the file's {} (or 2^20)",
                        e.point_count, h.point_count
                    ),
                ));
            }
            stored = stored.saturating_add(e.byte_count);
            points = points.saturating_add(e.point_count);
            if stored > data {
                return Err(Error::format(
                    path,
                    at,
                    format!(
                        "LAZ chunk table: chunks 0 to {k} claim {stored} bytes, the file holds {data} after byte {}",
                        at + 8
                    ),
                ));
            }
        }
        if points < h.point_count {
            let field = if h.raw.number_of_point_records == 0 {
                super::las_header::off::COUNT_14
            } else {
                super::las_header::off::COUNT_LEGACY
            };
            return Err(Error::format(
                path,
                field,
                format!(
                    "the header promises {} points, the LAZ chunk table holds at most {points}",
                    h.point_count
                ),
            ));
        }
        let item_size = laz_vlr.items_size() as usize;
        if item_size != h.record_length as usize {
            return Err(Error::format(
                path,
                super::las_header::off::RECORD_LENGTH,
                format!(
                    "point record length {} disagrees with the LASzip items ({item_size} bytes)",
                    h.record_length
                ),
            ));
        }
        let mut cursor = Cursor::new(bytes);
        cursor
            .seek(SeekFrom::Start(at))
            .map_err(|e| Error::io(path, e))?;
        let inner = guard(path, at, || {
            laz::ParLasZipDecompressor::new(cursor, laz_vlr)
        })?
        .map_err(|e| Error::format(path, at, format!("unreadable LAZ chunk table: {e}")))?;
        Ok(LazDecoder {
            path,
            inner,
            item_size,
            offset: at,
        })
    }

    fn next_batch(&mut self, n: u64, buf: &mut Vec<u8>) -> Result<()> {
        buf.resize(n as usize * self.item_size, 0);
        self.decompress(buf)
    }

    /// Decompresses the next `buf.len() / item_size` records into `buf`.
    fn decompress(&mut self, buf: &mut [u8]) -> Result<()> {
        let (path, at) = (self.path, self.offset);
        let inner = &mut self.inner;
        guard(path, at, || inner.decompress_many(buf))?.map_err(|e| {
            Error::format(
                path,
                at,
                format!("corrupt or truncated LAZ point data: {e}"),
            )
        })
    }
}

/// Checks the LASzip chunk table's size before the `laz` crate allocates it: a corrupt chunk
/// count would otherwise ask for gigabytes. Every chunk holds at least one point and one byte.
fn check_chunk_table(path: &Path, bytes: &[u8], h: &LasHeader) -> Result<()> {
    let at = h.offset_to_points as usize;
    let read_i64 = |p: usize| {
        bytes
            .get(p..p + 8)
            .map(|b| i64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
    };
    let mut table = read_i64(at).ok_or_else(|| {
        Error::format(path, at as u64, "truncated LAZ data: no chunk table offset")
    })?;
    if table <= at as i64 {
        // The writer could not seek back: LASzip then stores the offset in the last 8 bytes.
        table = read_i64(bytes.len().saturating_sub(8)).unwrap_or(0);
    }
    if table <= at as i64 || table as u64 + 8 > bytes.len() as u64 {
        return Err(Error::format(
            path,
            at as u64,
            format!(
                "LAZ chunk table offset {table} lies outside the file ({} bytes)",
                bytes.len()
            ),
        ));
    }
    let t = table as usize;
    let chunks = u32::from_le_bytes(bytes[t + 4..t + 8].try_into().unwrap_or([0; 4])) as u64;
    let limit = h.point_count.max(1).min(bytes.len() as u64);
    if chunks > limit {
        return Err(Error::format(
            path,
            table as u64 + 4,
            format!("LAZ chunk table claims {chunks} chunks, more than the file can hold"),
        ));
    }
    Ok(())
}

/// Runs LASzip code, turning a panic inside the decompressor (which a corrupt file can
/// provoke) into a format error instead of an abort.
fn guard<T>(path: &Path, at: u64, f: impl FnOnce() -> T) -> Result<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f))
        .map_err(|_| Error::format(path, at, "corrupt LAZ point data: the decompressor failed"))
}

/// The header and the uncompressed point record bytes of a LAS or LAZ file, for tools that
/// pass records through unchanged (`terratile convert`).
pub fn raw_records<'a>(path: &Path, bytes: &'a [u8]) -> Result<(LasHeader, Cow<'a, [u8]>)> {
    let h = LasHeader::parse(path, bytes)?;
    if !h.compressed {
        let r = uncompressed_records(path, bytes, &h)?;
        return Ok((h, Cow::Borrowed(r)));
    }
    let mut dec = LazDecoder::new(path, bytes, &h)?;
    crate::memory::check_alloc(h.point_count.saturating_mul(h.record_length as u64), || {
        format!("{}: {} decompressed points", path.display(), h.point_count)
    })?;
    // In batches, so that memory grows only as far as the data really decompresses.
    let mut out = Vec::new();
    let mut buf = Vec::new();
    let mut done = 0u64;
    while done < h.point_count {
        let n = LAZ_BATCH.min(h.point_count - done);
        dec.next_batch(n, &mut buf)?;
        out.extend_from_slice(&buf);
        done += n;
    }
    Ok((h, Cow::Owned(out)))
}

/// Calls `f` with the point records of a LAS or LAZ file in file order, in batches of whole
/// records (the mapped bytes for LAS, decompressed batches of [`LAZ_BATCH`] for LAZ).
pub(crate) fn for_each_batch(
    path: &Path,
    bytes: &[u8],
    h: &LasHeader,
    mut f: impl FnMut(&[u8]) -> Result<bool>,
) -> Result<()> {
    if !h.compressed {
        f(uncompressed_records(path, bytes, h)?)?;
        return Ok(());
    }
    let mut dec = LazDecoder::new(path, bytes, h)?;
    let mut buf = Vec::new();
    let mut done = 0u64;
    while done < h.point_count {
        let n = LAZ_BATCH.min(h.point_count - done);
        dec.next_batch(n, &mut buf)?;
        if !f(&buf)? {
            break;
        }
        done += n;
    }
    Ok(())
}

/// Reads a LAS or LAZ file in batches of at most `batch` records, each decoded into `cloud`
/// (cleared first) by the same record decoder as [`read_las_keeping`], with the class filter and
/// `opts.max_points`; calls `f` with every non-empty batch in file order. For the streaming
/// run, which never holds a whole file's points. Returns the header and the points kept.
pub(crate) fn for_each_decoded(
    path: &Path,
    bytes: &[u8],
    opts: &ReadOptions,
    batch: usize,
    cloud: &mut PointCloud,
    mut f: impl FnMut(&PointCloud, &LasHeader) -> Result<()>,
) -> Result<(LasHeader, u64)> {
    let h = LasHeader::parse(path, bytes)?;
    let layout = Layout::of(&h, opts.columns);
    let mut kept = 0u64;
    for_each_batch(path, bytes, &h, |records| {
        for part in records.chunks(batch.max(1) * layout.len) {
            let left = opts.max_points.map(|c| c.saturating_sub(kept));
            if left == Some(0) {
                return Ok(false);
            }
            cloud.x.clear();
            cloud.y.clear();
            cloud.z.clear();
            cloud.classification.clear();
            cloud.return_number.clear();
            cloud.number_of_returns.clear();
            cloud.intensity.clear();
            kept += las_records::decode(part, &layout, &opts.classes, left, cloud).0 as u64;
            if !cloud.is_empty() {
                f(cloud, &h)?;
            }
        }
        Ok(true)
    })?;
    Ok((h, kept))
}
