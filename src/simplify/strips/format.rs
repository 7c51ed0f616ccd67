//! The `.tps` stream: progressive strips in the order a client needs them (docs/strips.md).
//!
//! All numbers little-endian.
//!
//! ```text
//! header   28 bytes: magic "TTPS", version u16 (2), flags u16 (bit 0: E-PS records,
//!          bit 1: normals, bit 2: colours, bit 3: UVs), vertices u32, base vertices u32,
//!          strip length u32, splits u32 (= vertices − base vertices), triangles u32 (of
//!          the full mesh)
//! strip    strip length × u32: the base strip; a vertex id, 0xFFFFFFFF (restart) or,
//!          with E-PS, 0xFFFFFFF0 + k + 2 (a reference to the slot k ∈ {−2, −1, 1, 2} away)
//! vertices base vertices × vertex record
//! splits   per split, coarse to fine: vertex record (the restored vertex), kept u32,
//!          count u32, then count × offset u32 (ascending) and, with E-PS, count × u8 code
//!          (what the slot holds at the coarser level: 0 the kept vertex, 1..4 the
//!          reference R−2, R−1, R+1, R+2)
//! vertex   position 3 × f32, then normal 3 × f32, colour 4 × f32 (linear RGBA), UV 2 × f32
//! record   when the flags say so
//! ```
//!
//! The reader checks everything before it trusts it (counts against the bytes left, ids
//! against the vertices present, offsets against the strip, references against their
//! targets) and then replays the records once: each split must undo exactly the collapse
//! that its kept vertex and offsets describe. Errors name the byte offset.

use super::progressive::{
    ref_offset, ref_slot, show, vertex_floats, Encoding, Progressive, REF_BASE,
};
use super::stripify::RESTART;
use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use glam::{Vec2, Vec3};
use std::path::Path;

const MAGIC: &[u8; 4] = b"TTPS";
const VERSION: u16 = 2;
const HEADER: usize = 28;
const F_ENCODED: u16 = 1;
const F_NORMALS: u16 = 2;
const F_COLORS: u16 = 4;
const F_UVS: u16 = 8;

/// Codes of E-PS slots in the records: 0 the kept vertex, then R−2, R−1, R+1, R+2.
const CODES: [i32; 4] = [-2, -1, 1, 2];

fn vertex_bytes(flags: u16) -> usize {
    12 + if flags & F_NORMALS != 0 { 12 } else { 0 }
        + if flags & F_COLORS != 0 { 16 } else { 0 }
        + if flags & F_UVS != 0 { 8 } else { 0 }
}

fn put_vertex(out: &mut Vec<u8>, m: &TriMesh, v: usize) {
    vertex_floats(m, v, |xs| {
        for x in xs {
            out.extend_from_slice(&x.to_le_bytes());
        }
    });
}

/// The stream of `p` with records in `encoding`.
pub fn encode(p: &Progressive, encoding: Encoding) -> Vec<u8> {
    let m = &p.vertices;
    let mut flags = 0;
    if encoding == Encoding::Encoded {
        flags |= F_ENCODED;
    }
    if m.normals.is_some() {
        flags |= F_NORMALS;
    }
    if m.colors.is_some() {
        flags |= F_COLORS;
    }
    if m.uvs.is_some() {
        flags |= F_UVS;
    }
    let mut out = Vec::new();
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&flags.to_le_bytes());
    for x in [
        m.vertex_count(),
        p.base_vertices as usize,
        p.base.len(),
        p.splits.len(),
        p.triangles,
    ] {
        out.extend_from_slice(&(x as u32).to_le_bytes());
    }
    let base = match encoding {
        Encoding::Naive => &p.base,
        Encoding::Encoded => &p.base_slots,
    };
    for &v in base {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in 0..p.base_vertices as usize {
        put_vertex(&mut out, m, v);
    }
    for (i, s) in p.splits.iter().enumerate() {
        put_vertex(&mut out, m, p.base_vertices as usize + i);
        out.extend_from_slice(&s.kept.to_le_bytes());
        match encoding {
            Encoding::Naive => {
                let naive = p.naive(i);
                out.extend_from_slice(&(naive.len() as u32).to_le_bytes());
                for &o in naive {
                    out.extend_from_slice(&o.to_le_bytes());
                }
            }
            Encoding::Encoded => {
                let encoded = p.encoded(i);
                out.extend_from_slice(&(encoded.len() as u32).to_le_bytes());
                for &(o, _) in encoded {
                    out.extend_from_slice(&o.to_le_bytes());
                }
                for &(_, was) in encoded {
                    let code = match ref_offset(was) {
                        None => 0u8,
                        Some(k) => 1 + CODES.iter().position(|&c| c == k).unwrap_or(0) as u8,
                    };
                    out.push(code);
                }
            }
        }
    }
    out
}

/// A cursor that names the offset of what it cannot read.
struct Cursor<'b> {
    b: &'b [u8],
    at: usize,
    path: &'b Path,
}

impl Cursor<'_> {
    fn err(&self, at: usize, message: impl Into<String>) -> Error {
        Error::format(self.path, at as u64, message)
    }

    fn need(&self, n: u64, what: &str) -> Result<()> {
        let left = (self.b.len() - self.at) as u64;
        if n > left {
            return Err(self.err(
                self.at,
                format!("truncated: {what} needs {n} bytes, {left} left"),
            ));
        }
        Ok(())
    }

    fn u32(&mut self) -> Result<u32> {
        self.need(4, "a number")?;
        let v = u32::from_le_bytes(self.b[self.at..self.at + 4].try_into().unwrap_or([0; 4]));
        self.at += 4;
        Ok(v)
    }

    fn f32(&mut self) -> Result<f32> {
        let at = self.at;
        let v = f32::from_bits(self.u32()?);
        if !v.is_finite() {
            return Err(self.err(at, "a coordinate is not a finite number"));
        }
        Ok(v)
    }

    fn vertex(&mut self, m: &mut TriMesh) -> Result<()> {
        m.positions
            .push(Vec3::new(self.f32()?, self.f32()?, self.f32()?));
        if let Some(a) = m.normals.as_mut() {
            a.push(Vec3::new(self.f32()?, self.f32()?, self.f32()?));
        }
        if let Some(a) = m.colors.as_mut() {
            a.push([self.f32()?, self.f32()?, self.f32()?, self.f32()?]);
        }
        if let Some(a) = m.uvs.as_mut() {
            a.push(Vec2::new(self.f32()?, self.f32()?));
        }
        Ok(())
    }
}

/// Reads a `.tps` stream (`path` names it in errors).
pub fn decode(bytes: &[u8], path: &Path) -> Result<(Progressive, Encoding)> {
    let mut c = Cursor {
        b: bytes,
        at: 0,
        path,
    };
    let h = read_header(&mut c)?;
    let encoding = h.encoding;
    let (slots, base) = read_base_strip(&mut c, &h)?;
    let mut m = TriMesh {
        normals: (h.flags & F_NORMALS != 0).then(Vec::new),
        colors: (h.flags & F_COLORS != 0).then(Vec::new),
        uvs: (h.flags & F_UVS != 0).then(Vec::new),
        ..TriMesh::default()
    };
    m.positions.reserve(h.vertices as usize);
    for _ in 0..h.base_vertices {
        c.vertex(&mut m)?;
    }
    // Splits, checked against the strip as they are replayed forward.
    let mut replay = Replay {
        drawn: base.clone(),
        state: slots.clone(),
        stack: Vec::new(),
    };
    let mut splits = Vec::with_capacity(h.n_splits as usize);
    let mut at_of = Vec::with_capacity(h.n_splits as usize);
    for i in 0..h.n_splits {
        let rec = c.at;
        at_of.push(rec);
        splits.push(read_split(&mut c, &h, i, &mut m, &mut replay)?);
    }
    if c.at != bytes.len() {
        return Err(c.err(c.at, "trailing bytes after the last split"));
    }
    // The records must be the inverses of collapses: rebuild them from the full strip by
    // collapsing again, and compare.
    let kept: Vec<u32> = splits.iter().map(|s| s.kept).collect();
    let rebuilt = Progressive::from_full(
        m,
        h.base_vertices,
        replay.drawn,
        &kept,
        h.triangles as usize,
    );
    check_rebuilt(&c, &rebuilt, &splits, &at_of, encoding)?;
    Ok((rebuilt, encoding))
}

/// The fixed-size header of a stream, as read and checked by [`read_header`].
struct Header {
    flags: u16,
    vertices: u32,
    base_vertices: u32,
    len: u32,
    n_splits: u32,
    triangles: u32,
    encoding: Encoding,
}

/// Reads and checks the header (magic, version, flags, counts), and checks that the stream
/// is long enough for the strip, the vertices and the splits it announces.
fn read_header(c: &mut Cursor<'_>) -> Result<Header> {
    let bytes = c.b;
    c.need(HEADER as u64, "the header")?;
    if &bytes[..4] != MAGIC {
        return Err(c.err(0, "not a progressive strip stream (bad magic)"));
    }
    let version = u16::from_le_bytes([bytes[4], bytes[5]]);
    if version != VERSION {
        return Err(c.err(
            4,
            format!("version {version} is not supported (only {VERSION})"),
        ));
    }
    let flags = u16::from_le_bytes([bytes[6], bytes[7]]);
    if flags & !(F_ENCODED | F_NORMALS | F_COLORS | F_UVS) != 0 {
        return Err(c.err(6, format!("unknown flags {flags:#06x}")));
    }
    c.at = 8;
    let vertices = c.u32()?;
    let base_vertices = c.u32()?;
    let len = c.u32()?;
    let n_splits = c.u32()?;
    let triangles = c.u32()?;
    if vertices >= REF_BASE {
        return Err(c.err(8, format!("{vertices} vertices are too many")));
    }
    if base_vertices > vertices || n_splits != vertices - base_vertices {
        return Err(c.err(
            20,
            format!("{n_splits} splits do not take {base_vertices} base vertices to {vertices}"),
        ));
    }
    let encoding = if flags & F_ENCODED != 0 {
        Encoding::Encoded
    } else {
        Encoding::Naive
    };
    let vb = vertex_bytes(flags) as u64;
    c.need(
        4 * len as u64 + vb * base_vertices as u64 + (vb + 8) * n_splits as u64,
        "the strip, the vertices and the splits",
    )?;
    Ok(Header {
        flags,
        vertices,
        base_vertices,
        len,
        n_splits,
        triangles,
        encoding,
    })
}

/// Reads the base strip's slots and resolves their references: returns the slots as stored
/// and the vertex each slot shows.
fn read_base_strip(c: &mut Cursor<'_>, h: &Header) -> Result<(Vec<u32>, Vec<u32>)> {
    let (len, base_vertices, encoding) = (h.len, h.base_vertices, h.encoding);
    let strip_at = c.at;
    let mut slots = Vec::with_capacity(len as usize);
    for i in 0..len as usize {
        let v = c.u32()?;
        let ok = v < base_vertices
            || v == RESTART
            || encoding == Encoding::Encoded
                && ref_offset(v).is_some_and(|k| {
                    let j = i as i64 + k as i64;
                    (0..len as i64).contains(&j)
                });
        if !ok {
            return Err(c.err(
                strip_at + 4 * i,
                format!("strip slot {i} holds {v}, not a base vertex, a restart or a reference"),
            ));
        }
        slots.push(v);
    }
    let base = resolve(&slots).map_err(|i| {
        c.err(
            strip_at + 4 * i,
            format!("strip slot {i}: its references go round in a circle or end at a restart"),
        )
    })?;
    Ok((slots, base))
}

/// The base strip as the splits read so far have left it: `drawn` is the vertex each slot
/// shows, `state` what each slot holds (references included), `stack` scratch for [`show`].
struct Replay {
    drawn: Vec<u32>,
    state: Vec<u32>,
    stack: Vec<u32>,
}

/// A split record as read: the kept vertex, and the offsets (Naive-PS) or the offsets with
/// their slot codes (E-PS), whichever the stream holds.
#[derive(Default)]
struct Record {
    kept: u32,
    naive: Vec<u32>,
    encoded: Vec<(u32, u32)>,
}

/// Reads split `i` (its vertex into `m`, its kept vertex, offsets and, encoded, slot
/// codes), checks it against the strip and replays it on `r`.
fn read_split(
    c: &mut Cursor<'_>,
    h: &Header,
    i: u32,
    m: &mut TriMesh,
    r: &mut Replay,
) -> Result<Record> {
    let (len, encoding) = (h.len, h.encoding);
    c.vertex(m)?;
    let v = h.base_vertices + i;
    let kept_at = c.at;
    let kept = c.u32()?;
    if kept >= v {
        return Err(c.err(
            kept_at,
            format!("split {i} refers to vertex {kept}, not yet present ({v} are)"),
        ));
    }
    let count_at = c.at;
    let count = c.u32()?;
    let each = if encoding == Encoding::Encoded { 5 } else { 4 };
    c.need(each * count as u64, "the split's offsets")?;
    let mut offs = Vec::with_capacity(count as usize);
    for k in 0..count as usize {
        let o = c.u32()?;
        if o >= len || offs.last().is_some_and(|&l| o <= l) {
            return Err(c.err(
                count_at + 4 + 4 * k,
                format!("split {i}: offset {o} is out of range or out of order"),
            ));
        }
        if r.drawn[o as usize] != kept {
            return Err(c.err(
                count_at + 4 + 4 * k,
                format!("split {i}: strip slot {o} does not show the kept vertex {kept}"),
            ));
        }
        offs.push(o);
    }
    let mut split = Record {
        kept,
        ..Record::default()
    };
    match encoding {
        Encoding::Naive => {
            for &o in &offs {
                r.drawn[o as usize] = v;
            }
            split.naive = offs;
        }
        Encoding::Encoded => {
            let codes_at = c.at;
            for (k, &o) in offs.iter().enumerate() {
                let code = c.b[codes_at + k];
                let was = match code {
                    0 => kept,
                    1..=4 => ref_slot(CODES[code as usize - 1]),
                    _ => {
                        return Err(c.err(
                            codes_at + k,
                            format!("split {i}: slot code {code} is not 0..4"),
                        ))
                    }
                };
                if r.state[o as usize] != was {
                    return Err(c.err(
                        codes_at + k,
                        format!("split {i}: strip slot {o} does not hold what the record says"),
                    ));
                }
                split.encoded.push((o, was));
            }
            c.at += offs.len();
            for &o in &offs {
                r.state[o as usize] = v;
                show(&r.state, &mut r.drawn, &mut r.stack, o, v);
            }
        }
    }
    Ok(split)
}

/// Checks that the splits as read are the ones rebuilt by collapsing the full strip again;
/// `at_of` holds each record's byte offset.
fn check_rebuilt(
    c: &Cursor<'_>,
    rebuilt: &Progressive,
    splits: &[Record],
    at_of: &[usize],
    encoding: Encoding,
) -> Result<()> {
    for (i, b) in splits.iter().enumerate().take(rebuilt.splits.len()) {
        let same = match encoding {
            Encoding::Naive => rebuilt.naive(i) == b.naive.as_slice(),
            Encoding::Encoded => rebuilt.encoded(i) == b.encoded.as_slice(),
        };
        if !same {
            return Err(c.err(
                at_of[i],
                format!(
                    "split {i} does not undo a collapse of its vertex into vertex {}",
                    b.kept
                ),
            ));
        }
    }
    Ok(())
}

/// The drawn strip of E-PS `slots`, or the first slot whose references do not end at a
/// vertex.
fn resolve(slots: &[u32]) -> std::result::Result<Vec<u32>, usize> {
    const PENDING: u32 = u32::MAX - 1;
    let mut out: Vec<u32> = slots
        .iter()
        .map(|&v| if ref_offset(v).is_some() { PENDING } else { v })
        .collect();
    let mut path = Vec::new();
    for i in 0..slots.len() {
        let mut j = i;
        path.clear();
        while out[j] == PENDING {
            if path.len() > slots.len() {
                return Err(i);
            }
            path.push(j);
            let k = ref_offset(slots[j]).unwrap_or(0);
            j = (j as i64 + k as i64) as usize;
        }
        let v = out[j];
        if v == RESTART && !path.is_empty() {
            return Err(i);
        }
        for &p in &path {
            out[p] = v;
        }
    }
    Ok(out)
}

/// What `terratile strips` did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct BuildReport {
    /// Triangles of the full mesh.
    pub triangles: usize,
    /// Vertices of the base mesh and of the full mesh.
    pub base_vertices: u32,
    /// All vertices.
    pub vertices: usize,
    /// Splits in the stream.
    pub splits: usize,
    /// Length of the base strip.
    pub strip_len: usize,
    /// Mean strip slots restored per split, Naive-PS and E-PS.
    pub mean_updates: (f64, f64),
    /// Bytes written.
    pub bytes: usize,
}

impl std::fmt::Display for BuildReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "triangles {}, vertices {} (base {}), splits {}, strip {} indices",
            self.triangles, self.vertices, self.base_vertices, self.splits, self.strip_len
        )?;
        writeln!(
            f,
            "slots per split: naive {:.2}, encoded {:.2}; {} bytes",
            self.mean_updates.0, self.mean_updates.1, self.bytes
        )
    }
}

/// Reads the mesh at `input`, builds its progressive strips and writes the stream to
/// `output` (atomically).
pub fn build_file(
    input: &Path,
    output: &Path,
    params: &super::ProgressiveParams,
    encoding: Encoding,
) -> Result<BuildReport> {
    let mesh = crate::mesh::io::read(input)?;
    let p = super::progressive(&mesh, params)?;
    let bytes = encode(&p, encoding);
    crate::fsutil::write_bytes_atomic(output, &bytes)?;
    Ok(BuildReport::of(&p, bytes.len()))
}

impl BuildReport {
    /// The report of `p` written as `bytes` bytes.
    pub fn of(p: &Progressive, bytes: usize) -> BuildReport {
        BuildReport {
            triangles: p.triangles,
            base_vertices: p.base_vertices,
            vertices: p.vertices.vertex_count(),
            splits: p.splits.len(),
            strip_len: p.base.len(),
            mean_updates: p.mean_updates(),
            bytes,
        }
    }
}

/// A level of a stream: a number of splits, or all of them.
pub fn parse_level(text: &str, splits: usize) -> Result<usize> {
    if text == "full" {
        return Ok(splits);
    }
    match text.parse::<usize>() {
        Ok(l) if l <= splits => Ok(l),
        _ => Err(Error::Usage(format!(
            "--level: `{text}` is not a level of this stream (0 to {splits}, or full)"
        ))),
    }
}

/// Decodes the stream at `input` to `level` (see [`parse_level`]) and writes that mesh to
/// `output`: OBJ or PLY by its extension, or for `.glb` one `TRIANGLE_STRIP` primitive (see
/// [`glb_at`]); returns (level, triangles).
pub fn decode_file(input: &Path, level: &str, output: &Path) -> Result<(usize, usize)> {
    let bytes = std::fs::read(input).map_err(|e| Error::io(input, e))?;
    let (p, encoding) = decode(&bytes, input)?;
    let l = parse_level(level, p.splits.len())?;
    let m = p.mesh_at(l, encoding);
    if output.extension().and_then(|e| e.to_str()) == Some("glb") {
        let name = output
            .file_stem()
            .map_or("mesh".into(), |s| s.to_string_lossy());
        crate::fsutil::write_bytes_atomic(output, &glb_at(&p, l, encoding, &name, 1.0)?)?;
    } else {
        crate::mesh::io::write(&m, output)?;
    }
    Ok((l, m.triangle_count()))
}

/// The mesh of `p` at `level` as a glTF binary with one `TRIANGLE_STRIP` primitive (mode 5):
/// the vertices present at that level and the decoded strip after DTFS. glTF forbids the
/// restart index, so strips are joined by repeated indices. Positions scaled by
/// `metres_per_unit`, turned y-up as the other glTF files.
pub fn glb_at(
    p: &Progressive,
    level: usize,
    encoding: Encoding,
    name: &str,
    metres_per_unit: f64,
) -> Result<Vec<u8>> {
    let mut d = super::Decoder::new(p, encoding);
    d.set_level(level);
    let n = d.vertex_count();
    let v = &p.vertices;
    let vertices = crate::mesh::TriMesh {
        positions: v.positions[..n].to_vec(),
        indices: Vec::new(),
        normals: v.normals.as_ref().map(|a| a[..n].to_vec()),
        colors: None,
        uvs: None,
    };
    let strip = super::filter::dtfs(d.strip(), super::Join::Degenerate);
    crate::mesh::io::glb_primitive(
        &vertices,
        &strip,
        crate::mesh::io::TRIANGLE_STRIP,
        name,
        metres_per_unit,
    )
}
