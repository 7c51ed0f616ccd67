//! Wavefront OBJ: `v x y z [r g b]`, `vt`, `vn` and `f` (any polygon, triangulated by ear
//! clipping in its Newell plane; `v`, `v/vt`, `v//vn`, `v/vt/vn` corners; 1-based and
//! negative indices). Groups, objects, materials, smoothing groups, lines and points are
//! not geometry a triangle mesh carries and are skipped.
//!
//! Vertices: a [`TriMesh`] has one index per vertex, an OBJ face corner up to three. Position
//! `k` keeps index `k` (so unreferenced vertices and the file's order survive a round trip);
//! the same position used with another texture coordinate or normal (a seam) becomes an
//! extra vertex appended at the end. An unreferenced vertex takes `vt`/`vn` of its own index
//! when the file has one of those per `v` (files written per vertex, like ours).
//!
//! Index 0 is invalid in OBJ, but some exporters write 0-based files. A file in which index
//! 0 occurs is read as 0-based (the only reading that uses every face) and a warning says
//! so; a vertex index past the end under that reading is an error, never a dropped face.
//!
//! A line ending in `\` continues on the next one (messages name the first line). Read
//! leniently (the default, see [`ReadOptions`]), texture coordinates, normals or vertex
//! colours that cannot be used (an index out of range, a value that is not a finite number)
//! are dropped for the whole mesh and a face with fewer than 3 vertices is skipped, each
//! with a warning naming the first line.

use super::{MeshFormat, Notes, ReadInfo, ReadOptions};
use crate::error::{Error, Result};
use crate::mesh::polygon::Triangulator;
use crate::mesh::{linear_to_srgb, srgb_to_linear, TriMesh};
use glam::{Vec2, Vec3};
use std::borrow::Cow;
use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

/// No attribute index at this corner.
const NONE: i64 = i64::MIN;
/// Unassigned (texture, normal) combination.
const UNSET: (u32, u32) = (u32::MAX - 1, u32::MAX - 1);

/// A face corner's raw index: `>= 0` as written (a positive 1-based index, or 0);
/// negative: an already resolved relative index `k` stored as `-(k + 1)`.
fn raw_index(tok: &[u8], count: usize, line: u64, path: &Path, what: &str) -> Result<i64> {
    if tok.is_empty() {
        return Ok(NONE);
    }
    let (neg, digits) = match tok[0] {
        b'-' => (true, &tok[1..]),
        b'+' => (false, &tok[1..]),
        _ => (false, tok),
    };
    if digits.is_empty() || digits.len() > 18 || !digits.iter().all(u8::is_ascii_digit) {
        return Err(Error::text(
            path,
            line,
            format!("`{}` is not a {what} index", String::from_utf8_lossy(tok)),
        ));
    }
    let n = digits.iter().fold(0i64, |a, &d| a * 10 + (d - b'0') as i64);
    if !neg {
        return Ok(n);
    }
    let k = count as i64 - n;
    if n == 0 || k < 0 {
        return Err(Error::text(
            path,
            line,
            format!("relative {what} index -{n} reaches before the first of the {count} {what}s defined so far"),
        ));
    }
    Ok(-(k + 1))
}

/// `v` emptied, its allocation kept for slices of another lifetime (the in-place collect of
/// the standard library reuses the buffer): the token list of one line borrows that line,
/// which may be a joined continuation that lives only for its iteration.
fn recycle<'b>(mut v: Vec<&[u8]>) -> Vec<&'b [u8]> {
    v.clear();
    v.into_iter().map(|_| &b""[..]).collect()
}

/// The logical lines of OBJ text: `(number of the first line, text)`, a line ending in `\`
/// (before an optional CR) joined with the next one by a space.
fn logical_lines(text: &[u8]) -> impl Iterator<Item = (u64, Cow<'_, [u8]>)> {
    let mut physical = text.split(|&b| b == b'\n').zip(1u64..);
    std::iter::from_fn(move || {
        let (raw, no) = physical.next()?;
        let body = raw.strip_suffix(b"\r").unwrap_or(raw);
        let Some(head) = body.strip_suffix(b"\\") else {
            return Some((no, Cow::Borrowed(raw)));
        };
        let mut joined = head.to_vec();
        for (raw, _) in physical.by_ref() {
            joined.push(b' ');
            let body = raw.strip_suffix(b"\r").unwrap_or(raw);
            match body.strip_suffix(b"\\") {
                Some(more) => joined.extend_from_slice(more),
                None => {
                    joined.extend_from_slice(body);
                    break;
                }
            }
        }
        Some((no, Cow::Owned(joined)))
    })
}

/// Parses attribute values (`vt`, `vn`, colours) of line `line`; `None` with the error when
/// one is missing, not a number or not finite.
fn parse_attr<const N: usize>(
    toks: &[&[u8]],
    line: u64,
    path: &Path,
    what: &str,
) -> std::result::Result<[f32; N], Error> {
    if toks.len() < N {
        return Err(Error::text(
            path,
            line,
            format!("a {what} needs {N} values, this one has {}", toks.len()),
        ));
    }
    let mut out = [0f32; N];
    for (o, t) in out.iter_mut().zip(toks) {
        let shown = || String::from_utf8_lossy(t);
        *o = fast_float2::parse(t).map_err(|_| {
            Error::text(
                path,
                line,
                format!("{what} value `{}` is not a number", shown()),
            )
        })?;
        if !o.is_finite() {
            return Err(Error::text(
                path,
                line,
                format!("{what} value `{}` is not a finite number", shown()),
            ));
        }
    }
    Ok(out)
}

fn parse_f32(tok: &[u8], line: u64, path: &Path) -> Result<f32> {
    let v: f32 = fast_float2::parse(tok).map_err(|_| {
        Error::text(
            path,
            line,
            format!("`{}` is not a number", String::from_utf8_lossy(tok)),
        )
    })?;
    if !v.is_finite() {
        return Err(Error::text(
            path,
            line,
            format!(
                "`{}` is not a finite number (NaN or infinite coordinates are not allowed)",
                String::from_utf8_lossy(tok)
            ),
        ));
    }
    Ok(v)
}

/// Parses OBJ text (`path` is for messages), leniently.
pub fn parse_obj(path: &Path, text: &[u8]) -> Result<(TriMesh, ReadInfo)> {
    parse_obj_with(path, text, &ReadOptions::default())
}

/// Parses OBJ text (`path` is for messages) as `opts` say.
pub fn parse_obj_with(path: &Path, text: &[u8], opts: &ReadOptions) -> Result<(TriMesh, ReadInfo)> {
    let mut notes = Notes::new(opts);
    let mut drops = Drops::default();
    let Scanned {
        positions,
        colors,
        mut any_color,
        mut texcoords,
        mut normals,
        mut corners,
        starts,
        lines,
        zero_line,
        skipped_elements,
        skipped_faces,
    } = scan(path, text, &mut notes, &mut drops)?;
    let zero_based = zero_line.is_some();
    if let Some(l) = zero_line {
        notes.note("0-based", || format!(
            "{}:{l}: face index 0 is invalid in OBJ (indices start at 1); the file is read as 0-based",
            path.display()
        ));
    }
    if skipped_elements > 0 {
        notes.note("elements", || {
            format!(
                "{}: {skipped_elements} line/point/curve elements skipped (not triangles)",
                path.display()
            )
        });
    }
    // Resolve raw indices; every corner is checked against its array's final length.
    let resolve = |raw: i64, len: usize, line: u64, what: &str| {
        resolve_index(path, zero_based, raw, len, line, what)
    };

    // Texture coordinates and normals out of range: the attribute is dropped (lenient) or
    // the file refused (strict), decided before any vertex is built.
    for (p, &line) in lines.iter().enumerate() {
        for c in &corners[starts[p]..starts[p + 1]] {
            if !drops.uvs {
                if let Err(e) = resolve(c[1], texcoords.len(), line, "texture coordinate") {
                    notes.lenient("texture coordinate", e, "texture coordinates dropped")?;
                    drops.uvs = true;
                }
            }
            if !drops.normals {
                if let Err(e) = resolve(c[2], normals.len(), line, "normal") {
                    notes.lenient("normal", e, "normals dropped")?;
                    drops.normals = true;
                }
            }
        }
    }
    if drops.uvs {
        texcoords.clear();
        corners.iter_mut().for_each(|c| c[1] = NONE);
    }
    if drops.normals {
        normals.clear();
        corners.iter_mut().for_each(|c| c[2] = NONE);
    }
    if drops.colours {
        any_color = false;
    }
    let has_vt = corners.iter().any(|c| c[1] != NONE);
    let has_vn = corners.iter().any(|c| c[2] != NONE);
    let npos = positions.len();
    let mut mesh = TriMesh {
        positions,
        colors: any_color.then(|| linear_colours(&colors, path, &mut notes)),
        uvs: has_vt.then(|| vec![Vec2::ZERO; npos]),
        normals: has_vn.then(|| vec![Vec3::ZERO; npos]),
        indices: Vec::with_capacity(corners.len().saturating_sub(2 * lines.len())),
    };

    // Corner → vertex id.
    let mut ids: Vec<u32> = Vec::with_capacity(corners.len());
    let mut combo = if has_vt || has_vn {
        vec![UNSET; npos]
    } else {
        Vec::new()
    };
    let mut extra: HashMap<(u32, u32, u32), u32> = HashMap::new();
    for (p, &line) in lines.iter().enumerate() {
        for c in &corners[starts[p]..starts[p + 1]] {
            let v = resolve(c[0], npos, line, "vertex")?;
            if !(has_vt || has_vn) {
                ids.push(v);
                continue;
            }
            let t = resolve(c[1], texcoords.len(), line, "texture coordinate")?;
            let n = resolve(c[2], normals.len(), line, "normal")?;
            let id = if combo[v as usize] == UNSET {
                combo[v as usize] = (t, n);
                set_attrs(&mut mesh, v, t, n, &texcoords, &normals);
                v
            } else if combo[v as usize] == (t, n) {
                v
            } else {
                *extra.entry((v, t, n)).or_insert_with(|| {
                    let id = mesh.positions.len() as u32;
                    mesh.positions.push(mesh.positions[v as usize]);
                    if let Some(c) = mesh.colors.as_mut() {
                        c.push(c[v as usize]);
                    }
                    if let Some(u) = mesh.uvs.as_mut() {
                        u.push(Vec2::ZERO);
                    }
                    if let Some(nn) = mesh.normals.as_mut() {
                        nn.push(Vec3::ZERO);
                    }
                    set_attrs(&mut mesh, id, t, n, &texcoords, &normals);
                    id
                })
            };
            ids.push(id);
        }
    }
    attrs_of_unreferenced(&mut mesh, &combo, &texcoords, &normals, npos);
    if mesh.positions.len() > u32::MAX as usize {
        return Err(Error::format(path, 0, "more than 2^32 - 1 vertices"));
    }
    let mut tri = Triangulator::default();
    for (p, &line) in lines.iter().enumerate() {
        super::triangulate(
            &mut tri,
            &mesh.positions,
            &ids[starts[p]..starts[p + 1]],
            &mut mesh.indices,
            &mut notes,
            |m| Error::text(path, line, m),
        )?;
    }
    let info = ReadInfo {
        format: MeshFormat::Obj,
        faces_in_file: lines.len(),
        warnings: notes.into_lines(),
        skipped_faces,
    };
    Ok((mesh, info))
}

/// What the line pass collects: the attribute arrays as written and the faces as raw corner
/// indices (polygon p is `corners[starts[p]..starts[p + 1]]`, from line `lines[p]`).
struct Scanned {
    positions: Vec<Vec3>,
    colors: Vec<[f32; 3]>,
    any_color: bool,
    texcoords: Vec<Vec2>,
    normals: Vec<Vec3>,
    corners: Vec<[i64; 3]>,
    starts: Vec<usize>,
    lines: Vec<u64>,
    /// The first line with a face index 0 (the file is then read as 0-based).
    zero_line: Option<u64>,
    skipped_elements: usize,
    skipped_faces: usize,
}

/// The attributes found bad (reported once each, then dropped).
#[derive(Default)]
struct Drops {
    uvs: bool,
    normals: bool,
    colours: bool,
}

/// The line pass: vertices, attributes and faces as written, indices not yet resolved.
fn scan(path: &Path, text: &[u8], notes: &mut Notes, drops: &mut Drops) -> Result<Scanned> {
    let mut skipped_faces = 0usize;
    let mut positions: Vec<Vec3> = Vec::new();
    let mut colors: Vec<[f32; 3]> = Vec::new();
    let mut any_color = false;
    let mut texcoords: Vec<Vec2> = Vec::new();
    let mut normals: Vec<Vec3> = Vec::new();
    // Polygon corners as raw (v, vt, vn); polygon p is corners[starts[p]..starts[p + 1]].
    let mut corners: Vec<[i64; 3]> = Vec::new();
    let mut starts: Vec<usize> = vec![0];
    let mut lines: Vec<u64> = Vec::new();
    let mut zero_line: Option<u64> = None;
    let mut skipped_elements = 0usize;
    let mut spare: Vec<&[u8]> = Vec::with_capacity(16);

    for (line_no, raw) in logical_lines(text) {
        let mut toks = recycle(std::mem::take(&mut spare));
        let line = match raw.iter().position(|&b| b == b'#') {
            Some(p) => &raw[..p],
            None => &raw[..],
        };
        toks.clear();
        toks.extend(
            line.split(|b| b.is_ascii_whitespace())
                .filter(|t| !t.is_empty()),
        );
        let Some((&key, args)) = toks.split_first() else {
            spare = recycle(toks);
            continue;
        };
        match key {
            b"v" => {
                if args.len() < 3 {
                    return Err(Error::text(path, line_no, "a vertex needs x, y and z"));
                }
                let p = Vec3::new(
                    parse_f32(args[0], line_no, path)?,
                    parse_f32(args[1], line_no, path)?,
                    parse_f32(args[2], line_no, path)?,
                );
                positions.push(p);
                // `v x y z w` has a weight, `v x y z r g b` a colour.
                if args.len() >= 6 {
                    let c = match parse_attr::<3>(&args[3..], line_no, path, "colour") {
                        Ok(c) => c,
                        Err(e) => {
                            if !drops.colours {
                                notes.lenient("colour", e, "vertex colours dropped")?;
                                drops.colours = true;
                            }
                            [1.0; 3]
                        }
                    };
                    if colors.len() < positions.len() - 1 {
                        colors.resize(positions.len() - 1, [1.0; 3]);
                    }
                    colors.push(c);
                    any_color = true;
                }
            }
            b"vt" => {
                // `vt u` alone means v = 0.
                let uv = if args.len() == 1 {
                    parse_attr::<1>(args, line_no, path, "texture coordinate").map(|[u]| [u, 0.0])
                } else {
                    parse_attr::<2>(args, line_no, path, "texture coordinate")
                };
                match uv {
                    Ok(uv) => texcoords.push(Vec2::from(uv)),
                    Err(e) => {
                        if !drops.uvs {
                            notes.lenient(
                                "texture coordinate",
                                e,
                                "texture coordinates dropped",
                            )?;
                            drops.uvs = true;
                        }
                        texcoords.push(Vec2::ZERO);
                    }
                }
            }
            b"vn" => match parse_attr::<3>(args, line_no, path, "normal") {
                Ok(n) => normals.push(Vec3::from(n)),
                Err(e) => {
                    if !drops.normals {
                        notes.lenient("normal", e, "normals dropped")?;
                        drops.normals = true;
                    }
                    normals.push(Vec3::ZERO);
                }
            },
            b"f" | b"fo" => {
                if args.len() < 3 {
                    notes.lenient(
                        "short face",
                        Error::text(
                            path,
                            line_no,
                            format!(
                                "a face needs at least 3 vertices, this one has {}",
                                args.len()
                            ),
                        ),
                        "skipped",
                    )?;
                    skipped_faces += 1;
                    spare = recycle(toks);
                    continue;
                }
                for tok in args {
                    let lens = [positions.len(), texcoords.len(), normals.len()];
                    let [v, t, n] = face_corner(tok, lens, line_no, path, notes, drops)?;
                    if (v == 0 || t == 0 || n == 0) && zero_line.is_none() {
                        zero_line = Some(line_no);
                    }
                    corners.push([v, t, n]);
                }
                starts.push(corners.len());
                lines.push(line_no);
            }
            b"l" | b"p" | b"curv" | b"curv2" | b"surf" => skipped_elements += 1,
            _ => {}
        }
        spare = recycle(toks);
    }
    if any_color && colors.len() < positions.len() {
        colors.resize(positions.len(), [1.0; 3]);
    }

    Ok(Scanned {
        positions,
        colors,
        any_color,
        texcoords,
        normals,
        corners,
        starts,
        lines,
        zero_line,
        skipped_elements,
        skipped_faces,
    })
}

/// One face corner (`v`, `v/t`, `v//n` or `v/t/n`) as raw indices, `NONE` where absent,
/// checked against the counts read so far (`lens`: vertices, texture coordinates, normals).
/// A bad texture coordinate or normal index drops that attribute (leniently).
fn face_corner(
    tok: &[u8],
    lens: [usize; 3],
    line_no: u64,
    path: &Path,
    notes: &mut Notes,
    drops: &mut Drops,
) -> Result<[i64; 3]> {
    let mut parts = tok.splitn(3, |&b| b == b'/');
    let v = raw_index(
        parts.next().unwrap_or(b""),
        lens[0],
        line_no,
        path,
        "vertex",
    )?;
    if v == NONE {
        return Err(Error::text(
            path,
            line_no,
            format!(
                "face corner `{}` has no vertex index",
                String::from_utf8_lossy(tok)
            ),
        ));
    }
    // A bad texture coordinate or normal index drops that attribute, with one note.
    let mut optional =
        |len: usize, kind: &'static str, dropped: &mut bool, action: &str| match raw_index(
            parts.next().unwrap_or(b""),
            len,
            line_no,
            path,
            kind,
        ) {
            Ok(i) => Ok(i),
            Err(e) => {
                if !*dropped {
                    notes.lenient(kind, e, action)?;
                    *dropped = true;
                }
                Ok(NONE)
            }
        };
    let t = optional(
        lens[1],
        "texture coordinate",
        &mut drops.uvs,
        "texture coordinates dropped",
    )?;
    let n = optional(lens[2], "normal", &mut drops.normals, "normals dropped")?;
    Ok([v, t, n])
}

/// A raw corner index resolved against its array's final length `len` (1-based, or 0-based
/// when `zero_based`; negative: from the end); `u32::MAX` for an absent one.
fn resolve_index(
    path: &Path,
    zero_based: bool,
    raw: i64,
    len: usize,
    line: u64,
    what: &str,
) -> Result<u32> {
    if raw == NONE {
        return Ok(u32::MAX);
    }
    let (idx, shown) = if raw >= 0 {
        (if zero_based { raw } else { raw - 1 }, raw)
    } else {
        (-raw - 1, -raw - 1 - len as i64)
    };
    if idx < 0 || idx >= len as i64 {
        let base = if zero_based {
            " (the file uses index 0, so it is read as 0-based)"
        } else {
            ""
        };
        return Err(Error::text(
            path,
            line,
            format!(
                "face {what} index {shown} is out of range: the file has {len} {}{base}",
                if what == "vertex" {
                    "vertices".to_string()
                } else {
                    format!("{what}s")
                }
            ),
        ));
    }
    Ok(idx as u32)
}

/// The vertex colours in linear RGBA: sRGB values in 0–1, or 0–255 when any is above 1.
fn linear_colours(colors: &[[f32; 3]], path: &Path, notes: &mut Notes) -> Vec<[f32; 4]> {
    let scale = if colors.iter().flatten().any(|&c| c > 1.0) {
        notes.note("0-255", || {
            format!(
                "{}: vertex colours above 1 read as 0–255 values",
                path.display()
            )
        });
        1.0 / 255.0
    } else {
        1.0
    };
    colors
        .iter()
        .map(|c| {
            let l = |x: f32| srgb_to_linear((x * scale).clamp(0.0, 1.0));
            [l(c[0]), l(c[1]), l(c[2]), 1.0]
        })
        .collect()
}

/// Files written per vertex (one `vt`/`vn` per `v`, as terratile writes them) give
/// unreferenced vertices their attributes too, so such files round-trip exactly: the vertices
/// no corner set (`combo` still `UNSET`) take the attribute of their own index.
fn attrs_of_unreferenced(
    mesh: &mut TriMesh,
    combo: &[(u32, u32)],
    texcoords: &[Vec2],
    normals: &[Vec3],
    npos: usize,
) {
    for (k, c) in combo.iter().enumerate() {
        if *c == UNSET {
            let t = if texcoords.len() == npos {
                k as u32
            } else {
                u32::MAX
            };
            let n = if normals.len() == npos {
                k as u32
            } else {
                u32::MAX
            };
            set_attrs(mesh, k as u32, t, n, texcoords, normals);
        }
    }
}

fn set_attrs(mesh: &mut TriMesh, id: u32, t: u32, n: u32, texcoords: &[Vec2], normals: &[Vec3]) {
    if t != u32::MAX {
        if let Some(u) = mesh.uvs.as_mut() {
            u[id as usize] = texcoords[t as usize];
        }
    }
    if n != u32::MAX {
        if let Some(nn) = mesh.normals.as_mut() {
            nn[id as usize] = normals[n as usize];
        }
    }
}

/// Lines formatted per parallel job (each job fills its own buffer; buffers are written in
/// order, so the bytes do not depend on the thread count).
const LINES_PER_JOB: usize = 16384;

/// Appends the shortest decimal text that reads back to the same `x`, without a trailing
/// `.0`. zmij (already in the tree through serde_json) finds it several times faster than
/// `{}` formatting, which dominated writing big terrain OBJs. The text may differ from `{}`:
/// exponents for very small or large magnitudes (`1e+15`), which OBJ readers accept, and on
/// exact ties another digit string of the same length (3135135.25 → `3135135.2`, `{}` gives
/// `3135135.3`); both read back to the same f32.
#[inline]
fn put_f32(out: &mut Vec<u8>, fb: &mut zmij::Buffer, x: f32) {
    let s = fb.format(x).as_bytes();
    out.extend_from_slice(s.strip_suffix(b".0").unwrap_or(s));
}

/// `f32`s separated by spaces after `tag`, then a newline.
#[inline]
fn put_line(out: &mut Vec<u8>, fb: &mut zmij::Buffer, tag: &[u8], xs: &[f32]) {
    out.extend_from_slice(tag);
    for &x in xs {
        out.push(b' ');
        put_f32(out, fb, x);
    }
    out.push(b'\n');
}

/// Formats `n` lines in parallel jobs of [`LINES_PER_JOB`] and writes them in order, a
/// window of a few jobs per thread at a time, so memory stays at the window's text rather
/// than the whole section's.
fn write_lines(
    w: &mut dyn Write,
    n: usize,
    line: impl Fn(&mut Vec<u8>, &mut zmij::Buffer, &mut itoa::Buffer, usize) + Sync,
) -> std::io::Result<()> {
    use rayon::prelude::*;
    let jobs = n.div_ceil(LINES_PER_JOB);
    let window = 4 * rayon::current_num_threads();
    for first in (0..jobs).step_by(window) {
        let texts: Vec<Vec<u8>> = (first..(first + window).min(jobs))
            .into_par_iter()
            .map(|j| {
                let (mut fb, mut ib) = (zmij::Buffer::new(), itoa::Buffer::new());
                let lines = j * LINES_PER_JOB..((j + 1) * LINES_PER_JOB).min(n);
                let mut out = Vec::with_capacity(lines.len() * 32);
                for i in lines {
                    line(&mut out, &mut fb, &mut ib, i);
                }
                out
            })
            .collect();
        for t in &texts {
            w.write_all(t)?;
        }
    }
    Ok(())
}

/// Writes `mesh` as OBJ: one `v` (with `r g b` when it has colours), `vt` and `vn` per
/// vertex, and `f` lines with shared indices. Numbers are printed in the shortest form that
/// reads back to the same f32, so a round trip is exact (colours up to the sRGB conversion;
/// alpha is not representable in OBJ). Lines are formatted in parallel.
pub fn write_obj(mesh: &TriMesh, w: &mut dyn Write) -> std::io::Result<()> {
    writeln!(
        w,
        "# terratile mesh: {} vertices, {} triangles",
        mesh.vertex_count(),
        mesh.triangle_count()
    )?;
    write_lines(w, mesh.positions.len(), |out, fb, _, i| {
        let p = mesh.positions[i];
        match &mesh.colors {
            Some(c) => {
                let s = |k: usize| linear_to_srgb(c[i][k]);
                put_line(out, fb, b"v", &[p.x, p.y, p.z, s(0), s(1), s(2)]);
            }
            None => put_line(out, fb, b"v", &p.to_array()),
        }
    })?;
    if let Some(uv) = &mesh.uvs {
        write_lines(w, uv.len(), |out, fb, _, i| {
            put_line(out, fb, b"vt", &uv[i].to_array())
        })?;
    }
    if let Some(n) = &mesh.normals {
        write_lines(w, n.len(), |out, fb, _, i| {
            put_line(out, fb, b"vn", &n[i].to_array())
        })?;
    }
    // Corner text: `a`, `a/a`, `a//a` or `a/a/a` (shared indices).
    let (t, n) = (mesh.uvs.is_some(), mesh.normals.is_some());
    let tail: &[u8] = match (t, n) {
        (false, false) => b"",
        (true, false) => b"/",
        (false, true) => b"//",
        (true, true) => b"/",
    };
    let repeats = if t && n { 2 } else { usize::from(t || n) };
    write_lines(w, mesh.indices.len(), |out, _, ib, f| {
        out.push(b'f');
        for v in mesh.indices[f] {
            let a = ib.format(v as u64 + 1).as_bytes();
            out.push(b' ');
            out.extend_from_slice(a);
            for r in 0..repeats {
                out.extend_from_slice(if r == 0 { tail } else { b"/" });
                out.extend_from_slice(a);
            }
        }
        out.push(b'\n');
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> Result<(TriMesh, ReadInfo)> {
        parse_obj(Path::new("t.obj"), s.as_bytes())
    }

    #[test]
    fn quads_negative_indices_and_attributes() {
        let (m, info) = parse(
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\n\
             f -4/-4/1 -3/-3/1 -2/-2/1 -1/-1/1\n",
        )
        .unwrap();
        assert_eq!(info.faces_in_file, 1);
        assert_eq!(m.indices.len(), 2);
        assert_eq!(m.uvs.as_ref().unwrap()[2], Vec2::new(1.0, 1.0));
        assert_eq!(m.normals.as_ref().unwrap()[3], Vec3::Z);
        assert!((m.area() - 1.0).abs() < 1e-9);
    }

    #[test]
    fn seams_split_vertices_but_keep_order() {
        let (m, _) = parse("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nvt 0 0\nvt 1 0\nvt 0 1\nvt 9 9\nf 1/1 2/2 3/3\nf 1/4 3/3 2/2\n")
            .unwrap();
        assert_eq!(
            m.positions.len(),
            5,
            "vertex 1 with a second uv is appended"
        );
        assert_eq!(m.positions[4], Vec3::ZERO);
        assert_eq!(m.uvs.as_ref().unwrap()[4], Vec2::new(9.0, 9.0));
        assert_eq!(m.indices, vec![[0, 1, 2], [4, 2, 1]]);
        assert_eq!(
            m.positions[3],
            Vec3::splat(5.0),
            "unreferenced vertex kept in place"
        );
    }

    #[test]
    fn colours_are_read_as_srgb() {
        let (m, _) = parse("v 0 0 0 1 0.5 0\nv 1 0 0\nv 0 1 0 0 0 1\nf 1 2 3\n").unwrap();
        let c = m.colors.unwrap();
        assert_eq!(c[1], [1.0, 1.0, 1.0, 1.0]);
        assert!((c[0][1] - srgb_to_linear(0.5)).abs() < 1e-7);
    }

    #[test]
    fn zero_based_files_are_read_with_a_warning() {
        let (m, info) = parse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n").unwrap();
        assert_eq!(m.indices, vec![[0, 1, 2]]);
        assert!(info.warnings[0].contains("0-based"), "{:?}", info.warnings);
        let e = parse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\nf 1 2 3\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("t.obj:5: face vertex index 3 is out of range"),
            "{e}"
        );
    }

    #[test]
    fn bad_files_name_the_line() {
        let cases = [
            (
                "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 4\n",
                "t.obj:4: face vertex index 4 is out of range",
            ),
            (
                "v 0 0 0\nv nan 0 0\n",
                "t.obj:2: `nan` is not a finite number",
            ),
            ("v 0 0\n", "t.obj:1: a vertex needs x, y and z"),
            ("v 0 0 0\nf 1 -2 1\n", "t.obj:2: relative vertex index -2"),
            ("v 0 0 x\n", "t.obj:1: `x` is not a number"),
            ("v 0 0 0\nf 1 a 1\n", "t.obj:2: `a` is not a vertex index"),
        ];
        for (text, want) in cases {
            let e = parse(text).unwrap_err().to_string();
            assert!(e.starts_with(want), "{text:?}: got {e}");
        }
    }

    #[test]
    fn lenient_reading_drops_attributes_and_skips_faces_strict_refuses() {
        let strict = ReadOptions { strict: true };
        let cases = [
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nf 1 2 3\nf 2 3\n",
                "t.obj:4: a face needs at least 3 vertices, this one has 2: skipped (and 1 more)",
            ),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n",
                "t.obj:5: face texture coordinate index 2 is out of range: the file has 1 texture coordinates: texture coordinates dropped",
            ),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//-2\n",
                "t.obj:5: relative normal index -2 reaches before the first of the 1 normals defined so far: normals dropped",
            ),
            (
                "v 0 0 0 1 0 0\nv 1 0 0 nan nan nan\nv 0 1 0 0 1 0\nf 1 2 3\n",
                "t.obj:2: colour value `nan` is not a finite number: vertex colours dropped",
            ),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 inf\nf 1//1 2//1 3//1\n",
                "t.obj:4: normal value `inf` is not a finite number: normals dropped",
            ),
        ];
        for (text, want) in cases {
            let (m, info) = parse(text).unwrap();
            assert_eq!(m.indices.len(), 1, "{text:?}");
            assert_eq!(info.warnings, vec![want.to_string()], "{text:?}");
            assert!(m.uvs.is_none() && m.normals.is_none() && m.colors.is_none());
            let e = parse_obj_with(Path::new("t.obj"), text.as_bytes(), &strict)
                .unwrap_err()
                .to_string();
            assert!(want.starts_with(&e), "{text:?}: strict gave {e}");
        }
    }

    #[test]
    fn huge_polygons_are_fans_with_a_warning() {
        let n = crate::mesh::io::MAX_EAR_CORNERS + 1;
        let mut text = String::new();
        for i in 0..n {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            text.push_str(&format!("v {} {} 0\n", a.cos(), a.sin()));
        }
        text.push('f');
        for i in 1..=n {
            text.push_str(&format!(" {i}"));
        }
        let (m, info) = parse(&text).unwrap();
        assert_eq!(m.indices.len(), n - 2);
        assert_eq!(
            info.warnings,
            vec![format!(
                "t.obj:{}: a face with {n} corners (more than 1024): triangulated as a fan",
                n + 1
            )]
        );
        let strict = ReadOptions { strict: true };
        assert!(parse_obj_with(Path::new("t.obj"), text.as_bytes(), &strict).is_err());
    }

    #[test]
    fn line_continuations_join_lines() {
        let (m, info) =
            parse("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 \\\r\n1 0\nf 1 2 \\\n 3 \\\n4\n").unwrap();
        assert_eq!(m.positions[3], Vec3::new(0.0, 1.0, 0.0));
        assert_eq!(info.faces_in_file, 1);
        assert_eq!(m.indices.len(), 2);
        // Messages name the first line of a continued one.
        let e = parse("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 \\\n 3 \\\n9\n")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.obj:4: face vertex index 9"), "{e}");
    }

    #[test]
    fn write_then_read_is_exact() {
        let m = TriMesh {
            positions: vec![
                Vec3::new(0.1, -2.5e-7, 3.0e6),
                Vec3::new(1.0 / 3.0, 0.0, -0.0),
                Vec3::new(7.0, 8.0, 9.5),
            ],
            indices: vec![[0, 1, 2]],
            normals: Some(vec![Vec3::X, Vec3::Y, Vec3::new(0.6, 0.0, 0.8)]),
            colors: None,
            uvs: Some(vec![Vec2::new(0.25, 0.5), Vec2::ZERO, Vec2::ONE]),
        };
        let mut buf = Vec::new();
        write_obj(&m, &mut buf).unwrap();
        let (back, _) = parse_obj(Path::new("x.obj"), &buf).unwrap();
        assert_eq!(back, m);
    }

    /// The obvious writer the fast one replaced: `{}` formatting, line by line.
    fn write_obj_slow(mesh: &TriMesh) -> Vec<u8> {
        let mut w = Vec::new();
        for (i, p) in mesh.positions.iter().enumerate() {
            match &mesh.colors {
                Some(c) => {
                    let c = c[i].map(linear_to_srgb);
                    writeln!(w, "v {} {} {} {} {} {}", p.x, p.y, p.z, c[0], c[1], c[2]).unwrap()
                }
                None => writeln!(w, "v {} {} {}", p.x, p.y, p.z).unwrap(),
            }
        }
        for t in mesh.uvs.iter().flatten() {
            writeln!(w, "vt {} {}", t.x, t.y).unwrap();
        }
        for n in mesh.normals.iter().flatten() {
            writeln!(w, "vn {} {} {}", n.x, n.y, n.z).unwrap();
        }
        for tri in &mesh.indices {
            let [a, b, c] = tri.map(|v| v + 1);
            match (mesh.uvs.is_some(), mesh.normals.is_some()) {
                (false, false) => writeln!(w, "f {a} {b} {c}"),
                (true, false) => writeln!(w, "f {a}/{a} {b}/{b} {c}/{c}"),
                (false, true) => writeln!(w, "f {a}//{a} {b}//{b} {c}//{c}"),
                (true, true) => writeln!(w, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}"),
            }
            .unwrap();
        }
        w
    }

    #[test]
    fn fast_writer_reads_back_like_the_slow_one() {
        // More lines than one parallel job, magnitudes from subnormal to huge, every
        // attribute combination.
        // Six jobs: more than one window on one thread.
        let n = 5 * LINES_PER_JOB + 17;
        let mut rng = crate::rng::SplitMix64::new(5);
        let mut f = |i: usize| {
            let scale = [1e-38f32, 1e-7, 1e-3, 1.0, 637_512.25, 3e12, 1e30][i % 7];
            (rng.unit() as f32 - 0.5) * scale
        };
        let positions: Vec<Vec3> = (0..n)
            .map(|i| Vec3::new(f(i), f(i + 1), f(i + 2)))
            .collect();
        let uvs: Vec<Vec2> = (0..n).map(|i| Vec2::new(f(i + 3), f(i + 4))).collect();
        let normals: Vec<Vec3> = (0..n).map(|i| Vec3::new(f(i), -0.0, 1.0)).collect();
        let colors: Vec<[f32; 4]> = (0..n)
            .map(|i| [0.0, 0.5, (i % 256) as f32 / 255.0, 1.0])
            .collect();
        let indices: Vec<[u32; 3]> = (0..n as u32 - 2).map(|i| [i, i + 1, i + 2]).collect();
        for (uv, nm, col) in [
            (false, false, false),
            (true, false, true),
            (false, true, false),
            (true, true, true),
        ] {
            let m = TriMesh {
                positions: positions.clone(),
                indices: indices.clone(),
                normals: nm.then(|| normals.clone()),
                colors: col.then(|| colors.clone()),
                uvs: uv.then(|| uvs.clone()),
            };
            let mut fast = Vec::new();
            write_obj(&m, &mut fast).unwrap();
            let (a, _) = parse_obj(Path::new("fast.obj"), &fast).unwrap();
            let slow = write_obj_slow(&m);
            let (b, _) = parse_obj(Path::new("slow.obj"), &slow).unwrap();
            assert_eq!(a, b, "{uv} {nm} {col}");
            // Integers print the same either way: the face lines are byte-identical.
            let faces = |text: &[u8]| -> Vec<Vec<u8>> {
                text.split(|&c| c == b'\n')
                    .filter(|l| l.starts_with(b"f "))
                    .map(|l| l.to_vec())
                    .collect()
            };
            assert_eq!(faces(&fast), faces(&slow), "{uv} {nm} {col}");
            assert_eq!(faces(&fast).len(), m.indices.len());
            if !col {
                assert_eq!(a, m);
            }
            // Same bytes on one thread.
            let mut single = Vec::new();
            crate::testing::on_threads(1, || write_obj(&m, &mut single)).unwrap();
            assert_eq!(single, fast);
        }
    }
}
