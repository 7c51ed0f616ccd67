//! Byte-level decoding of LAS point records (formats 0–10) straight from mapped bytes into
//! the struct-of-arrays cloud: fixed-size chunks decoded in parallel, each writing its own
//! disjoint slice of the output columns. No allocation per point; one pass when nothing is
//! filtered, two (count, then decode) when a class filter or a cap is set.
//!
//! Layout (LAS 1.4 R15, Tables 7–17): X, Y, Z as i32 at bytes 0, 4, 8; intensity u16 at 12.
//! Formats 0–5: byte 14 = return number (bits 0–2) | number of returns (bits 3–5),
//! byte 15 = classification (bits 0–4) | flags. Formats 6–10: byte 14 = return number
//! (bits 0–3) | number of returns (bits 4–7), byte 16 = classification (all 8 bits).

use super::las_header::LasHeader;
use super::{Bounds, ClassFilter, Columns, PointCloud};
use rayon::prelude::*;

/// Records per parallel work unit: 64 Ki records is 1.3–4.4 MB of input, large enough to
/// amortise scheduling and small enough to balance two to dozens of cores.
pub(crate) const CHUNK: usize = 1 << 16;

/// How to find the fields in one record.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Layout {
    /// Record length in bytes.
    pub len: usize,
    /// Point formats 6–10 (extended bit layout).
    pub extended: bool,
    /// Scale factors.
    pub scale: [f64; 3],
    /// Offsets.
    pub offset: [f64; 3],
    /// The attribute columns to decode and store (x, y and z always are).
    pub columns: Columns,
}

impl Layout {
    /// The layout of the records `h` describes, decoding `columns`.
    pub(crate) fn of(h: &LasHeader, columns: Columns) -> Layout {
        Layout {
            len: h.record_length as usize,
            extended: h.point_format >= 6,
            scale: h.scale,
            offset: h.offset,
            columns,
        }
    }

    #[inline(always)]
    fn class(&self, r: &[u8]) -> u8 {
        if self.extended {
            r[16]
        } else {
            r[15] & 0x1F
        }
    }
}

/// Output slices of one chunk; an attribute column not asked for is empty.
struct Out<'a> {
    x: &'a mut [f64],
    y: &'a mut [f64],
    z: &'a mut [f64],
    class: &'a mut [u8],
    ret: &'a mut [u8],
    nret: &'a mut [u8],
    intensity: &'a mut [u16],
}

impl<'a> Out<'a> {
    /// Splits off the first `n` entries of every column.
    fn take(&mut self, n: usize) -> Out<'a> {
        fn split<'a, T>(s: &mut &'a mut [T], n: usize) -> &'a mut [T] {
            if s.is_empty() {
                // A column not asked for.
                return &mut [];
            }
            let (head, tail) = std::mem::take(s).split_at_mut(n);
            *s = tail;
            head
        }
        Out {
            x: split(&mut self.x, n),
            y: split(&mut self.y, n),
            z: split(&mut self.z, n),
            class: split(&mut self.class, n),
            ret: split(&mut self.ret, n),
            nret: split(&mut self.nret, n),
            intensity: split(&mut self.intensity, n),
        }
    }
}

#[inline(always)]
fn i32_at(r: &[u8], at: usize) -> i32 {
    i32::from_le_bytes([r[at], r[at + 1], r[at + 2], r[at + 3]])
}

/// Decodes one record into slot `k` of `out`: x, y, z, and the attribute columns of
/// `l.columns`.
#[inline(always)]
fn put(l: &Layout, r: &[u8], out: &mut Out<'_>, k: usize) {
    // Same expression as `las::Transform::direct`, so the values are bit-identical to las-rs.
    out.x[k] = l.scale[0] * f64::from(i32_at(r, 0)) + l.offset[0];
    out.y[k] = l.scale[1] * f64::from(i32_at(r, 4)) + l.offset[1];
    out.z[k] = l.scale[2] * f64::from(i32_at(r, 8)) + l.offset[2];
    if l.columns.intensity {
        out.intensity[k] = u16::from_le_bytes([r[12], r[13]]);
    }
    let b = r[14];
    if l.columns.returns {
        (out.ret[k], out.nret[k]) = if l.extended {
            (b & 0x0F, b >> 4)
        } else {
            (b & 0x07, (b >> 3) & 0x07)
        };
    }
    if l.columns.class {
        out.class[k] = l.class(r);
    }
}

/// Decodes x, y and z only of every record of `recs` into `out` (same length): the hot loop
/// when no attribute column is asked for (the terrain stages read nothing else).
fn decode_xyz(l: &Layout, recs: &[u8], out: &mut Out<'_>) {
    let [sx, sy, sz] = l.scale;
    let [ox, oy, oz] = l.offset;
    let cols = out.x.iter_mut().zip(out.y.iter_mut()).zip(out.z.iter_mut());
    for (r, ((x, y), z)) in recs.chunks_exact(l.len).zip(cols) {
        let r: &[u8; 12] = match r.first_chunk() {
            Some(r) => r,
            None => return,
        };
        *x = sx * f64::from(i32_at(r, 0)) + ox;
        *y = sy * f64::from(i32_at(r, 4)) + oy;
        *z = sz * f64::from(i32_at(r, 8)) + oz;
    }
}

/// Decodes every record of `recs` into `out` (same length, every column asked for): the
/// unfiltered hot loop, written
/// with zipped iterators so that no index is bounds-checked.
fn decode_dense(l: &Layout, recs: &[u8], out: &mut Out<'_>) {
    let [sx, sy, sz] = l.scale;
    let [ox, oy, oz] = l.offset;
    let cols = out
        .x
        .iter_mut()
        .zip(out.y.iter_mut())
        .zip(out.z.iter_mut())
        .zip(out.intensity.iter_mut())
        .zip(
            out.ret
                .iter_mut()
                .zip(out.nret.iter_mut())
                .zip(out.class.iter_mut()),
        );
    let ext = l.extended;
    for (r, ((((x, y), z), i), ((ret, nret), class))) in recs.chunks_exact(l.len).zip(cols) {
        let r: &[u8; 17] = match r.first_chunk() {
            Some(r) => r,
            None => return,
        };
        *x = sx * f64::from(i32_at(r, 0)) + ox;
        *y = sy * f64::from(i32_at(r, 4)) + oy;
        *z = sz * f64::from(i32_at(r, 8)) + oz;
        *i = u16::from_le_bytes([r[12], r[13]]);
        let b = r[14];
        if ext {
            *ret = b & 0x0F;
            *nret = b >> 4;
            *class = r[16];
        } else {
            *ret = b & 0x07;
            *nret = (b >> 3) & 0x07;
            *class = r[15] & 0x1F;
        }
    }
}

/// The smallest and largest of `v` (∞ and −∞ when empty), over eight lanes so that the
/// compiler can keep them in vector registers: `f64::min` and `max` (which also handle NaN,
/// which a decoded coordinate never is) do not vectorise and wait on each other's latency.
/// Run on a chunk just decoded, while it is still in the cache, this costs a fraction of a
/// separate pass over the whole columns.
fn min_max(v: &[f64]) -> (f64, f64) {
    let mut lo = [f64::INFINITY; 8];
    let mut hi = [f64::NEG_INFINITY; 8];
    let mut lanes = v.chunks_exact(8);
    for c in &mut lanes {
        for k in 0..8 {
            lo[k] = if c[k] < lo[k] { c[k] } else { lo[k] };
            hi[k] = if c[k] > hi[k] { c[k] } else { hi[k] };
        }
    }
    for (k, &x) in lanes.remainder().iter().enumerate() {
        lo[k] = lo[k].min(x);
        hi[k] = hi[k].max(x);
    }
    (
        lo.into_iter().fold(f64::INFINITY, f64::min),
        hi.into_iter().fold(f64::NEG_INFINITY, f64::max),
    )
}

/// The bounds of the decoded points of one chunk.
fn chunk_bounds(out: &Out<'_>) -> Bounds {
    let (x, y, z) = (min_max(out.x), min_max(out.y), min_max(out.z));
    Bounds {
        min: [x.0, y.0, z.0],
        max: [x.1, y.1, z.1],
    }
}

/// Extends `v` with zeros to `len`. A fresh column is allocated zeroed (calloc), so the OS
/// hands out zero pages lazily and the parallel decoder touches each page first, instead of
/// a serial zero-filling pass over the whole output.
fn grow<T: Copy + Default>(v: &mut Vec<T>, len: usize) {
    if v.is_empty() && v.capacity() < len {
        *v = zeroed(len);
    } else {
        v.resize(len, T::default());
    }
}

fn zeroed<T: Copy + Default>(len: usize) -> Vec<T> {
    vec![T::default(); len]
}

/// The part of column `v` from `start` on when it is `wanted`, else nothing.
fn tail<T>(v: &mut [T], start: usize, wanted: bool) -> &mut [T] {
    if wanted {
        &mut v[start..]
    } else {
        &mut []
    }
}

/// Decodes `records` (whole records, `layout.len` bytes each) into `cloud`'s columns,
/// keeping the points `filter` keeps, at most `cap` of them. Returns the number kept and
/// their tight bounds (measured chunk by chunk as they are decoded, so that the stages after
/// the read need no pass of their own over the columns to find them).
pub(crate) fn decode(
    records: &[u8],
    layout: &Layout,
    filter: &ClassFilter,
    cap: Option<u64>,
    cloud: &mut PointCloud,
) -> (usize, Bounds) {
    let len = layout.len;
    let n = records.len() / len;
    let cap = cap.map_or(usize::MAX, |c| usize::try_from(c).unwrap_or(usize::MAX));
    let chunks: Vec<&[u8]> = records[..n * len].chunks(CHUNK * len).collect();

    // Points kept per chunk.
    let mut kept: Vec<usize> = if filter.is_active() {
        chunks
            .par_iter()
            .map(|c| {
                c.chunks_exact(len)
                    .filter(|r| filter.keeps(layout.class(r)))
                    .count()
            })
            .collect()
    } else {
        chunks.iter().map(|c| c.len() / len).collect()
    };
    let mut total = 0usize;
    for k in kept.iter_mut() {
        *k = (*k).min(cap - total);
        total += *k;
    }

    let start = cloud.len();
    grow(&mut cloud.x, start + total);
    grow(&mut cloud.y, start + total);
    grow(&mut cloud.z, start + total);
    let cols = layout.columns;
    if cols.class {
        grow(&mut cloud.classification, start + total);
    }
    if cols.returns {
        grow(&mut cloud.return_number, start + total);
        grow(&mut cloud.number_of_returns, start + total);
    }
    if cols.intensity {
        grow(&mut cloud.intensity, start + total);
    }
    let mut rest = Out {
        x: &mut cloud.x[start..],
        y: &mut cloud.y[start..],
        z: &mut cloud.z[start..],
        class: tail(&mut cloud.classification, start, cols.class),
        ret: tail(&mut cloud.return_number, start, cols.returns),
        nret: tail(&mut cloud.number_of_returns, start, cols.returns),
        intensity: tail(&mut cloud.intensity, start, cols.intensity),
    };
    let tasks: Vec<(&[u8], Out<'_>)> = chunks
        .iter()
        .zip(&kept)
        .filter(|(_, &k)| k > 0)
        .map(|(c, &k)| (*c, rest.take(k)))
        .collect();

    let bounds = tasks
        .into_par_iter()
        .map(|(recs, mut out)| {
            let want = out.x.len();
            if !filter.is_active() && layout.columns == Columns::ALL {
                decode_dense(layout, &recs[..want * len], &mut out);
            } else if !filter.is_active() && layout.columns == Columns::XYZ {
                decode_xyz(layout, &recs[..want * len], &mut out);
            } else if !filter.is_active() {
                for (k, r) in recs[..want * len].chunks_exact(len).enumerate() {
                    put(layout, r, &mut out, k);
                }
            } else {
                let mut k = 0;
                for r in recs.chunks_exact(len) {
                    if filter.keeps(layout.class(r)) {
                        put(layout, r, &mut out, k);
                        k += 1;
                        if k == want {
                            break;
                        }
                    }
                }
            }
            chunk_bounds(&out)
        })
        .reduce(|| Bounds::EMPTY, Bounds::union);
    (total, bounds)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` records of `len` bytes with varied fields (a small linear congruential stream).
    fn records(n: usize, len: usize) -> Vec<u8> {
        let mut s = 0x2545_f491_4f6c_dd1du64;
        (0..n * len)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 56) as u8
            })
            .collect()
    }

    fn layout(len: usize, extended: bool, columns: Columns) -> Layout {
        Layout {
            len,
            extended,
            scale: [0.01, 0.02, 0.001],
            offset: [100.0, -5.0, 0.5],
            columns,
        }
    }

    /// Every column mask, with and without a class filter and a cap, in both bit layouts,
    /// across several chunks: x, y, z and the bounds as with every column, each asked-for
    /// column as the full decode has it, the others empty.
    #[test]
    fn a_column_mask_leaves_out_exactly_its_columns() {
        for (len, extended) in [(20, false), (30, true)] {
            let recs = records(CHUNK * 2 + 777, len);
            for filter in [ClassFilter::default(), ClassFilter::new(None, &[1, 2, 3])] {
                for cap in [None, Some(CHUNK as u64 + 5)] {
                    let mut all = PointCloud::default();
                    let want = decode(
                        &recs,
                        &layout(len, extended, Columns::ALL),
                        &filter,
                        cap,
                        &mut all,
                    );
                    for bits in 0..8u8 {
                        let columns = Columns {
                            class: bits & 1 != 0,
                            returns: bits & 2 != 0,
                            intensity: bits & 4 != 0,
                        };
                        let mut c = PointCloud::default();
                        let got =
                            decode(&recs, &layout(len, extended, columns), &filter, cap, &mut c);
                        assert_eq!(got, want, "{columns:?}");
                        assert_eq!((&c.x, &c.y, &c.z), (&all.x, &all.y, &all.z));
                        let empty_or = |wanted: bool, v: &[u8], w: &[u8]| {
                            if wanted {
                                assert_eq!(v, w, "{columns:?}");
                            } else {
                                assert!(v.is_empty(), "{columns:?}");
                            }
                        };
                        empty_or(columns.class, &c.classification, &all.classification);
                        empty_or(columns.returns, &c.return_number, &all.return_number);
                        empty_or(
                            columns.returns,
                            &c.number_of_returns,
                            &all.number_of_returns,
                        );
                        if columns.intensity {
                            assert_eq!(c.intensity, all.intensity);
                        } else {
                            assert!(c.intensity.is_empty());
                        }
                    }
                }
            }
        }
    }
}
