//! XYZ/CSV text: x y z are the first three numeric columns, separated by spaces,
//! tabs or commas; `#` starts a comment line; one optional header line before the data.
//!
//! The mapped file is cut into chunks at line ends and the chunks are parsed in parallel with
//! `fast-float2` (an Eisel–Lemire parser working on bytes, no UTF-8 pass). A bad line stops
//! the read with its 1-based line number.

use super::{Format, PointCloud, SourceInfo};
use crate::error::{Error, Result};
use crate::progress::Progress;
use rayon::prelude::*;
use std::path::Path;

/// Bytes of text per parallel work unit (cut at the next line end).
const CHUNK_BYTES: usize = 1 << 20;

#[derive(Debug)]
struct LineError {
    /// 0-based line index within the chunk.
    line: u64,
    message: String,
}

#[derive(Default)]
struct Parsed {
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
}

#[inline(always)]
fn is_sep(b: u8) -> bool {
    b == b' ' || b == b'\t' || b == b',' || b == b';'
}

/// Parses one line's first three numbers.
#[inline]
fn parse_line(line: &[u8]) -> std::result::Result<Option<[f64; 3]>, String> {
    let mut p = 0;
    let n = line.len();
    while p < n && (line[p] == b' ' || line[p] == b'\t') {
        p += 1;
    }
    if p == n || line[p] == b'#' {
        return Ok(None);
    }
    let mut v = [0.0f64; 3];
    for (k, slot) in v.iter_mut().enumerate() {
        if k > 0 {
            // One separator run: blanks, at most one comma/semicolon among them.
            let mut hard = 0;
            while p < n && is_sep(line[p]) {
                if line[p] == b',' || line[p] == b';' {
                    hard += 1;
                }
                p += 1;
            }
            if hard > 1 {
                return Err(format!("empty column {} (two separators in a row)", k + 1));
            }
        }
        if p == n || line[p] == b'#' {
            return Err(format!("expected 3 numbers (x y z), found {k}"));
        }
        let (val, used) = fast_float2::parse_partial::<f64, _>(&line[p..]).map_err(|_| {
            let tok: String = line[p..]
                .iter()
                .take_while(|&&b| !is_sep(b))
                .take(24)
                .map(|&b| b as char)
                .collect();
            format!("column {}: `{tok}` is not a number", k + 1)
        })?;
        p += used;
        if p < n && !is_sep(line[p]) {
            let tok: String = line[p - used..]
                .iter()
                .take_while(|&&b| !is_sep(b))
                .take(24)
                .map(|&b| b as char)
                .collect();
            return Err(format!("column {}: `{tok}` is not a number", k + 1));
        }
        if !val.is_finite() {
            return Err(format!("column {}: {val} is not a finite number", k + 1));
        }
        *slot = val;
    }
    Ok(Some(v))
}

fn parse_chunk(text: &[u8]) -> std::result::Result<Parsed, LineError> {
    let mut out = Parsed::default();
    let guess = text.len() / 24;
    out.x.reserve(guess);
    out.y.reserve(guess);
    out.z.reserve(guess);
    for (i, line) in text.split(|&b| b == b'\n').enumerate() {
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        match parse_line(line) {
            Ok(Some([x, y, z])) => {
                out.x.push(x);
                out.y.push(y);
                out.z.push(z);
            }
            Ok(None) => {}
            Err(message) => {
                return Err(LineError {
                    line: i as u64,
                    message,
                })
            }
        }
    }
    Ok(out)
}

/// Splits `text` into chunks of about `CHUNK_BYTES`, each ending just after a `\n`.
fn split_lines(text: &[u8]) -> Vec<&[u8]> {
    let mut chunks = Vec::with_capacity(text.len() / CHUNK_BYTES + 1);
    let mut rest = text;
    while rest.len() > CHUNK_BYTES {
        match rest[CHUNK_BYTES..].iter().position(|&b| b == b'\n') {
            Some(p) => {
                let (a, b) = rest.split_at(CHUNK_BYTES + p + 1);
                chunks.push(a);
                rest = b;
            }
            None => break,
        }
    }
    if !rest.is_empty() {
        chunks.push(rest);
    }
    chunks
}

/// Where the data starts: after a BOM, leading comments/blank lines and one header line
/// (a first non-comment line that does not start with a number). Returns (byte offset,
/// lines skipped).
fn data_start(text: &[u8]) -> (usize, u64) {
    let mut at = if text.starts_with(b"\xEF\xBB\xBF") {
        3
    } else {
        0
    };
    let mut lines = 0u64;
    while at < text.len() {
        let end = text[at..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(text.len(), |p| at + p + 1);
        let line = &text[at..end];
        let t: &[u8] = line.trim_ascii();
        if t.is_empty() || t.starts_with(b"#") {
            at = end;
            lines += 1;
            continue;
        }
        let numeric = fast_float2::parse_partial::<f64, _>(t).is_ok();
        if !numeric {
            // The header line: skip it, once.
            return (end, lines + 1);
        }
        return (at, lines);
    }
    (at, lines)
}

/// Parses XYZ/CSV text from `text` (the mapped file `path`).
pub fn parse_xyz(path: &Path, text: &[u8], progress: &dyn Progress) -> Result<PointCloud> {
    let (start, skipped) = data_start(text);
    let chunks = split_lines(&text[start..]);
    progress.start(&format!("parsing {}", path.display()), chunks.len() as u64);
    let parsed: Vec<std::result::Result<Parsed, LineError>> = chunks
        .par_iter()
        .map(|c| {
            let r = parse_chunk(c);
            progress.advance(1);
            r
        })
        .collect();
    progress.finish();
    let mut total = 0usize;
    for (ci, p) in parsed.iter().enumerate() {
        match p {
            Ok(p) => total += p.x.len(),
            Err(e) => {
                let before: u64 = chunks[..ci]
                    .iter()
                    .map(|c| c.iter().filter(|&&b| b == b'\n').count() as u64)
                    .sum();
                return Err(Error::text(
                    path,
                    skipped + before + e.line + 1,
                    e.message.clone(),
                ));
            }
        }
    }
    if total == 0 {
        return Err(Error::text(
            path,
            skipped + 1,
            "no points: the file holds no line with three numbers",
        ));
    }
    let mut cloud = PointCloud::default();
    cloud.reserve_exact(total, super::Columns::XYZ);
    for p in parsed.into_iter().flatten() {
        cloud.x.extend_from_slice(&p.x);
        cloud.y.extend_from_slice(&p.y);
        cloud.z.extend_from_slice(&p.z);
    }
    cloud.sources.push(SourceInfo {
        path: path.to_path_buf(),
        format: Format::Xyz,
        version: None,
        point_format: None,
        record_length: None,
        points_in_file: total as u64,
        points_read: total as u64,
        scale: None,
        offset: None,
        header_bounds: None,
        crs: None,
    });
    Ok(cloud)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn separators_and_comments() {
        assert_eq!(parse_line(b"1 2 3").unwrap(), Some([1.0, 2.0, 3.0]));
        assert_eq!(parse_line(b"1,2,3,99").unwrap(), Some([1.0, 2.0, 3.0]));
        assert_eq!(
            parse_line(b"\t1.5\t-2e3 , 3").unwrap(),
            Some([1.5, -2000.0, 3.0])
        );
        assert_eq!(parse_line(b"  # note").unwrap(), None);
        assert_eq!(parse_line(b"").unwrap(), None);
        assert!(parse_line(b"1 2").unwrap_err().contains("found 2"));
        assert!(parse_line(b"1 x 3").unwrap_err().contains("`x`"));
        assert!(parse_line(b"1 2 nan").unwrap_err().contains("finite"));
        assert!(parse_line(b"1 2 inf").unwrap_err().contains("finite"));
        assert!(parse_line(b"1 2 3abc").unwrap_err().contains("3abc"));
        assert!(parse_line(b"1,,2,3").is_err());
    }

    #[test]
    fn header_line_is_skipped_once() {
        assert_eq!(data_start(b"# c\nx y z\n1 2 3\n"), (10, 2));
        assert_eq!(data_start(b"1 2 3\n"), (0, 0));
    }
}
