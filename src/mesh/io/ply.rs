//! Stanford PLY (Turk's format): ASCII and binary little/big endian; every scalar type
//! (`char uchar short ushort int uint float double` and their `int8`… aliases). Read from
//! the `vertex` element: x y z, normals (nx ny nz), colours (red green blue, optional alpha, or
//! r g b / diffuse_*), texture coordinates (u v, s t, texture_u texture_v); from `face`:
//! the `vertex_indices` (or `vertex_index`) list, polygons triangulated by ear clipping; from
//! `tristrips`: strips with −1 restarts. Other elements and properties are skipped.
//! Written: binary little endian (ASCII and big endian on request) with float positions,
//! normals and texture coordinates, uchar RGBA colours, and uint triangle indices.
//!
//! Errors name the byte offset (binary data) or the line (header and ASCII data).
//!
//! Element counts come from the header: before anything is reserved for an element, its
//! count times its smallest possible record (binary: the bytes of its scalars and list
//! counts; ASCII: one digit and one separator per property) must fit in the bytes that
//! follow, and an element without properties (zero-size records) is skipped whatever its
//! count, so no header can make the reader allocate or loop beyond what the file holds.

use super::{MeshFormat, Notes, ReadInfo, ReadOptions};
use crate::error::{Error, Result};
use crate::mesh::polygon::Triangulator;
use crate::mesh::{linear_to_srgb, srgb_to_linear, TriMesh};
use glam::{Vec2, Vec3};
use std::io::Write;
use std::path::Path;

/// PLY data encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// Text.
    Ascii,
    /// Binary, little endian (what most tools write).
    BinaryLittleEndian,
    /// Binary, big endian.
    BinaryBigEndian,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_float(self) -> bool {
        matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// The value that means "full intensity" for a colour of this type.
    fn colour_scale(self) -> f64 {
        match self {
            Scalar::U8 | Scalar::I8 => 255.0,
            Scalar::U16 | Scalar::I16 => 65535.0,
            Scalar::U32 | Scalar::I32 => u32::MAX as f64,
            Scalar::F32 | Scalar::F64 => 1.0,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    Coord(usize),
    Normal(usize),
    Colour(usize),
    Tex(usize),
    Indices,
    Skip,
}

#[derive(Debug, Clone)]
struct Property {
    kind: Kind,
    role: Role,
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    /// Header line of the `element` declaration.
    line: u64,
    count: usize,
    props: Vec<Property>,
}

/// Where the data reader is, for messages.
#[derive(Debug, Clone, Copy)]
enum Loc {
    Byte(u64),
    Line(u64),
}

fn err_at(path: &Path, loc: Loc, msg: impl Into<String>) -> Error {
    match loc {
        Loc::Byte(o) => Error::format(path, o, msg),
        Loc::Line(l) => Error::text(path, l, msg),
    }
}

/// Sequential access to element data, binary or text.
trait Source {
    /// Reads one value of type `ty`.
    fn value(&mut self, ty: Scalar) -> std::result::Result<f64, String>;
    /// Location of the next value.
    fn loc(&mut self) -> Loc;
    /// Bytes not read yet.
    fn remaining(&self) -> usize;
    /// The fewest bytes a value of `kind` takes (a list: its count alone).
    fn min_size(&self, kind: Kind) -> usize;
}

struct Binary<'a> {
    data: &'a [u8],
    pos: usize,
    base: usize,
    big: bool,
}

impl Source for Binary<'_> {
    #[inline]
    fn value(&mut self, ty: Scalar) -> std::result::Result<f64, String> {
        let n = ty.size();
        let Some(b) = self.data.get(self.pos..self.pos + n) else {
            return Err("the file ends early".into());
        };
        self.pos += n;
        macro_rules! get {
            ($t:ty) => {{
                let a = b.try_into().unwrap_or_default();
                if self.big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }
            }};
        }
        Ok(match ty {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => get!(i16) as f64,
            Scalar::U16 => get!(u16) as f64,
            Scalar::I32 => get!(i32) as f64,
            Scalar::U32 => get!(u32) as f64,
            Scalar::F32 => get!(f32) as f64,
            Scalar::F64 => get!(f64),
        })
    }

    fn loc(&mut self) -> Loc {
        Loc::Byte((self.base + self.pos) as u64)
    }

    fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.pos)
    }

    fn min_size(&self, kind: Kind) -> usize {
        match kind {
            Kind::Scalar(t) | Kind::List { count: t, .. } => t.size(),
        }
    }
}

struct Text<'a> {
    data: &'a [u8],
    pos: usize,
    line: u64,
}

impl Text<'_> {
    fn skip_space(&mut self) {
        while let Some(&b) = self.data.get(self.pos) {
            if b == b'\n' {
                self.line += 1;
            } else if !b.is_ascii_whitespace() {
                break;
            }
            self.pos += 1;
        }
    }
}

impl Source for Text<'_> {
    fn value(&mut self, ty: Scalar) -> std::result::Result<f64, String> {
        self.skip_space();
        let start = self.pos;
        while self
            .data
            .get(self.pos)
            .is_some_and(|b| !b.is_ascii_whitespace())
        {
            self.pos += 1;
        }
        let tok = &self.data[start..self.pos];
        if tok.is_empty() {
            return Err("the file ends early".into());
        }
        let shown = || String::from_utf8_lossy(tok).into_owned();
        if ty.is_float() {
            fast_float2::parse::<f64, _>(tok).map_err(|_| format!("`{}` is not a number", shown()))
        } else {
            let s =
                std::str::from_utf8(tok).map_err(|_| format!("`{}` is not an integer", shown()))?;
            s.parse::<i64>()
                .map(|v| v as f64)
                .map_err(|_| format!("`{}` is not an integer", shown()))
        }
    }

    fn loc(&mut self) -> Loc {
        self.skip_space();
        Loc::Line(self.line)
    }

    fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.pos)
    }

    /// One character and one separator (the file's last value may lack the separator,
    /// which the caller allows for).
    fn min_size(&self, _kind: Kind) -> usize {
        2
    }
}

fn role_of(element: &str, name: &str, kind: Kind) -> Role {
    match (element, kind) {
        ("vertex", Kind::Scalar(_)) => match name {
            "x" => Role::Coord(0),
            "y" => Role::Coord(1),
            "z" => Role::Coord(2),
            "nx" | "normal_x" => Role::Normal(0),
            "ny" | "normal_y" => Role::Normal(1),
            "nz" | "normal_z" => Role::Normal(2),
            "red" | "r" | "diffuse_red" => Role::Colour(0),
            "green" | "g" | "diffuse_green" => Role::Colour(1),
            "blue" | "b" | "diffuse_blue" => Role::Colour(2),
            "alpha" | "a" | "diffuse_alpha" => Role::Colour(3),
            "u" | "s" | "texture_u" | "texture_s" => Role::Tex(0),
            "v" | "t" | "texture_v" | "texture_t" => Role::Tex(1),
            _ => Role::Skip,
        },
        ("face" | "tristrips", Kind::List { .. })
            if name == "vertex_indices" || name == "vertex_index" =>
        {
            Role::Indices
        }
        _ => Role::Skip,
    }
}

struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    data_start: usize,
    data_line: u64,
}

fn parse_header(path: &Path, bytes: &[u8]) -> Result<Header> {
    let mut pos = 0usize;
    let mut line = 0u64;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        line += 1;
        let Some(nl) = bytes[pos..].iter().position(|&b| b == b'\n') else {
            return Err(Error::text(
                path,
                line,
                "the header has no `end_header` line",
            ));
        };
        let raw = &bytes[pos..pos + nl];
        pos += nl + 1;
        let text = std::str::from_utf8(raw)
            .map_err(|_| Error::text(path, line, "the header is not text"))?
            .trim();
        let mut w = text.split_ascii_whitespace();
        let bad = |m: String| Error::text(path, line, m);
        match w.next() {
            Some("ply") if line == 1 => {}
            Some("format") => {
                encoding = Some(match (w.next(), w.next()) {
                    (Some("ascii"), Some("1.0")) => Encoding::Ascii,
                    (Some("binary_little_endian"), Some("1.0")) => Encoding::BinaryLittleEndian,
                    (Some("binary_big_endian"), Some("1.0")) => Encoding::BinaryBigEndian,
                    _ => return Err(bad(format!("unsupported format line `{text}`"))),
                });
            }
            Some("comment" | "obj_info") | None => {}
            Some("element") => {
                let (Some(name), Some(count)) = (w.next(), w.next()) else {
                    return Err(bad("an element line needs a name and a count".into()));
                };
                let count: usize = count
                    .parse()
                    .map_err(|_| bad(format!("element count `{count}` is not a number")))?;
                elements.push(Element {
                    name: name.to_string(),
                    line,
                    count,
                    props: Vec::new(),
                });
            }
            Some("property") => {
                let Some(el) = elements.last_mut() else {
                    return Err(bad("a property before any element".into()));
                };
                let ty = |s: Option<&str>| {
                    let s = s.unwrap_or("");
                    Scalar::parse(s).ok_or_else(|| bad(format!("unknown property type `{s}`")))
                };
                let first = w.next();
                let (kind, name) = if first == Some("list") {
                    let count = ty(w.next())?;
                    let item = ty(w.next())?;
                    if count.is_float() {
                        return Err(bad("a list count must be an integer type".into()));
                    }
                    (Kind::List { count, item }, w.next())
                } else {
                    (Kind::Scalar(ty(first)?), w.next())
                };
                let Some(name) = name else {
                    return Err(bad("a property needs a name".into()));
                };
                let role = role_of(&el.name, name, kind);
                el.props.push(Property { kind, role });
            }
            Some("end_header") => break,
            Some(other) if line == 1 => {
                return Err(bad(format!("not a PLY file (starts with `{other}`)")));
            }
            Some(other) => return Err(bad(format!("unknown header keyword `{other}`"))),
        }
    }
    let Some(encoding) = encoding else {
        return Err(Error::text(path, line, "the header has no `format` line"));
    };
    Ok(Header {
        encoding,
        elements,
        data_start: pos,
        data_line: line + 1,
    })
}

/// What the data pass collects before triangulation.
#[derive(Default)]
struct Collected {
    positions: Vec<Vec3>,
    normals: Option<Vec<Vec3>>,
    colors: Option<Vec<[f32; 4]>>,
    uvs: Option<Vec<Vec2>>,
    polys: Vec<u32>,
    starts: Vec<usize>,
    strips: Vec<[u32; 3]>,
    faces_in_file: usize,
    skipped_faces: usize,
}

fn read_data<S: Source>(
    path: &Path,
    header: &Header,
    src: &mut S,
    notes: &mut Notes,
) -> Result<Collected> {
    let nverts = header
        .elements
        .iter()
        .find(|e| e.name == "vertex")
        .map_or(0, |e| e.count);
    let mut c = Collected {
        starts: vec![0],
        ..Default::default()
    };
    let mut strip: Vec<i64> = Vec::new();
    let mut drops = Drops::default();
    for el in &header.elements {
        let is_vertex = el.name == "vertex";
        if !check_element_size(path, el, src, is_vertex)? {
            continue;
        }
        let (colour_scale, has_alpha) = if is_vertex {
            start_vertex_columns(path, el, &mut c)?
        } else {
            ([1.0f64; 4], false)
        };
        let what = if is_vertex {
            "vertex"
        } else {
            el.name.as_str()
        };
        for i in 0..el.count {
            let at = src.loc();
            let ends = |m: String| err_at(path, at, format!("{what} {i} of {}: {m}", el.count));
            let mut r = VertexRecord {
                p: [0.0; 3],
                n: [0.0; 3],
                col: [1.0; 4],
                t: [0.0; 2],
            };
            for prop in &el.props {
                match prop.kind {
                    Kind::Scalar(ty) => {
                        let v = src.value(ty).map_err(&ends)?;
                        match prop.role {
                            Role::Coord(k) => r.p[k] = v,
                            Role::Normal(k) => r.n[k] = v,
                            Role::Colour(k) => r.col[k] = v / colour_scale[k],
                            Role::Tex(k) => r.t[k] = v,
                            _ => {}
                        }
                    }
                    Kind::List { count, item } => {
                        let len = src.value(count).map_err(&ends)?;
                        if len < 0.0 {
                            return Err(ends(format!("negative list length {len}")));
                        }
                        let len = len as usize;
                        if prop.role != Role::Indices {
                            for _ in 0..len {
                                src.value(item).map_err(&ends)?;
                            }
                            continue;
                        }
                        if el.name == "tristrips" {
                            strip.clear();
                            for _ in 0..len {
                                strip.push(src.value(item).map_err(&ends)? as i64);
                            }
                            c.faces_in_file += 1;
                            strip_triangles(&strip, nverts, &mut c.strips).map_err(&ends)?;
                            continue;
                        }
                        if len < 3 {
                            notes.lenient(
                                "short face",
                                ends(format!(
                                    "a face needs at least 3 vertices, this one has {len}"
                                )),
                                "skipped",
                            )?;
                            for _ in 0..len {
                                src.value(item).map_err(&ends)?;
                            }
                            c.skipped_faces += 1;
                            continue;
                        }
                        for _ in 0..len {
                            let v = src.value(item).map_err(&ends)?;
                            if !(v >= 0.0 && v < nverts as f64) || v.fract() != 0.0 {
                                return Err(ends(format!(
                                    "face uses vertex {v} but there are {nverts} vertices"
                                )));
                            }
                            c.polys.push(v as u32);
                        }
                        c.starts.push(c.polys.len());
                        c.faces_in_file += 1;
                    }
                }
            }
            if is_vertex {
                push_vertex(&mut c, &r, has_alpha, &ends, &mut drops, notes)?;
            }
        }
    }
    drops.apply(&mut c);
    Ok(c)
}

/// Checks that `el`'s records can fit in the data left (at their smallest size). Returns
/// false for an element with zero-size records, which has nothing to read (a vertex element
/// without properties still goes on, to be refused for its missing x y z).
fn check_element_size<S: Source>(
    path: &Path,
    el: &Element,
    src: &S,
    is_vertex: bool,
) -> Result<bool> {
    let record: usize = el.props.iter().map(|p| src.min_size(p.kind)).sum();
    if record == 0 {
        // No properties: zero-size records, nothing to read whatever the count (a
        // vertex element without x y z is refused below).
        return Ok(is_vertex);
    }
    if el.count.saturating_mul(record) > src.remaining().saturating_add(1) {
        return Err(Error::text(
            path,
            el.line,
            format!(
                "element `{}` declares {} records of at least {record} bytes each, but only {} bytes of data follow",
                el.name,
                el.count,
                src.remaining()
            ),
        ));
    }
    Ok(true)
}

/// Checks that the vertex element `el` has x y z and reserves the columns it has. Returns the
/// scale of each colour channel (by its type) and whether there is an alpha channel.
fn start_vertex_columns(path: &Path, el: &Element, c: &mut Collected) -> Result<([f64; 4], bool)> {
    let has = |pred: fn(Role) -> bool| el.props.iter().any(|p| pred(p.role));
    let (mut colour_scale, mut has_alpha) = ([1.0f64; 4], false);
    for k in 0..3 {
        if !el.props.iter().any(|p| p.role == Role::Coord(k)) {
            return Err(Error::format(
                path,
                0,
                format!(
                    "the vertex element has no `{}` property",
                    ["x", "y", "z"][k]
                ),
            ));
        }
    }
    c.positions.reserve(el.count);
    if has(|r| matches!(r, Role::Normal(_))) {
        c.normals = Some(Vec::with_capacity(el.count));
    }
    if has(|r| matches!(r, Role::Colour(_))) {
        c.colors = Some(Vec::with_capacity(el.count));
        for p in &el.props {
            if let (Role::Colour(k), Kind::Scalar(t)) = (p.role, p.kind) {
                colour_scale[k] = t.colour_scale();
                has_alpha |= k == 3;
            }
        }
    }
    if has(|r| matches!(r, Role::Tex(_))) {
        c.uvs = Some(Vec::with_capacity(el.count));
    }
    Ok((colour_scale, has_alpha))
}

/// One vertex record's values: position, normal, colour (scaled to 0..1), texture coordinate.
struct VertexRecord {
    p: [f64; 3],
    n: [f64; 3],
    col: [f64; 4],
    t: [f64; 2],
}

/// The attribute columns found to hold a non-finite value (reported once each, dropped at
/// the end).
#[derive(Default)]
struct Drops {
    normals: bool,
    colours: bool,
    uvs: bool,
}

impl Drops {
    /// Drops the columns found bad.
    fn apply(&self, c: &mut Collected) {
        if self.normals {
            c.normals = None;
        }
        if self.colours {
            c.colors = None;
        }
        if self.uvs {
            c.uvs = None;
        }
    }
}

/// Appends vertex `r` to `c`'s columns: a non-finite position is an error (`ends` names the
/// vertex); a non-finite normal, colour or texture coordinate drops that column (leniently).
#[inline]
fn push_vertex(
    c: &mut Collected,
    r: &VertexRecord,
    has_alpha: bool,
    ends: &impl Fn(String) -> Error,
    drops: &mut Drops,
    notes: &mut Notes,
) -> Result<()> {
    let (p, n, col, t) = (r.p, r.n, r.col, r.t);
    let pos = Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32);
    if !pos.is_finite() {
        return Err(ends(format!(
            "non-finite coordinate ({}, {}, {}): NaN or infinite positions are not allowed",
            p[0], p[1], p[2]
        )));
    }
    c.positions.push(pos);
    let bad = |what: &str, v: &[f64]| ends(format!("{what} {v:?} is not finite"));
    if c.normals.is_some() && !drops.normals && !n.iter().all(|x| x.is_finite()) {
        notes.lenient("normal", bad("normal", &n), "normals dropped")?;
        drops.normals = true;
    }
    if c.colors.is_some() && !drops.colours && !col.iter().all(|x| x.is_finite()) {
        notes.lenient("colour", bad("colour", &col), "colours dropped")?;
        drops.colours = true;
    }
    if c.uvs.is_some() && !drops.uvs && !t.iter().all(|x| x.is_finite()) {
        notes.lenient(
            "texture coordinate",
            bad("texture coordinate", &t),
            "texture coordinates dropped",
        )?;
        drops.uvs = true;
    }
    if let Some(nn) = c.normals.as_mut() {
        nn.push(Vec3::new(n[0] as f32, n[1] as f32, n[2] as f32));
    }
    if let Some(cc) = c.colors.as_mut() {
        let l = |x: f64| srgb_to_linear((x as f32).clamp(0.0, 1.0));
        let a = if has_alpha {
            (col[3] as f32).clamp(0.0, 1.0)
        } else {
            1.0
        };
        cc.push([l(col[0]), l(col[1]), l(col[2]), a]);
    }
    if let Some(uv) = c.uvs.as_mut() {
        uv.push(Vec2::new(t[0] as f32, t[1] as f32));
    }
    Ok(())
}

/// Triangles of one strip (−1 restarts a strip); triangles with a repeated corner (the
/// joins between strips) are dropped, as every strip reader does.
fn strip_triangles(
    strip: &[i64],
    nverts: usize,
    out: &mut Vec<[u32; 3]>,
) -> std::result::Result<(), String> {
    for run in strip.split(|&v| v == -1) {
        for &v in run {
            if v < 0 || v as usize >= nverts {
                return Err(format!(
                    "strip uses vertex {v} but there are {nverts} vertices"
                ));
            }
        }
        for k in 2..run.len() {
            let (a, b, c) = (run[k - 2] as u32, run[k - 1] as u32, run[k] as u32);
            if a == b || b == c || a == c {
                continue;
            }
            out.push(if k % 2 == 0 { [a, b, c] } else { [b, a, c] });
        }
    }
    Ok(())
}

/// Parses a PLY file's bytes (`path` is for messages), leniently.
pub fn parse_ply(path: &Path, bytes: &[u8]) -> Result<(TriMesh, ReadInfo)> {
    parse_ply_with(path, bytes, &ReadOptions::default())
}

/// Parses a PLY file's bytes (`path` is for messages) as `opts` say.
pub fn parse_ply_with(
    path: &Path,
    bytes: &[u8],
    opts: &ReadOptions,
) -> Result<(TriMesh, ReadInfo)> {
    let mut notes = Notes::new(opts);
    let header = parse_header(path, bytes)?;
    let data = &bytes[header.data_start..];
    let c = match header.encoding {
        Encoding::Ascii => read_data(
            path,
            &header,
            &mut Text {
                data,
                pos: 0,
                line: header.data_line,
            },
            &mut notes,
        )?,
        enc => read_data(
            path,
            &header,
            &mut Binary {
                data,
                pos: 0,
                base: header.data_start,
                big: enc == Encoding::BinaryBigEndian,
            },
            &mut notes,
        )?,
    };
    if c.positions.len() > u32::MAX as usize {
        return Err(Error::format(path, 0, "more than 2^32 - 1 vertices"));
    }
    let mut mesh = TriMesh {
        positions: c.positions,
        indices: Vec::with_capacity(c.polys.len() / 3 + c.strips.len()),
        normals: c.normals,
        colors: c.colors,
        uvs: c.uvs,
    };
    let mut tri = Triangulator::default();
    for (f, w) in c.starts.windows(2).enumerate() {
        super::triangulate(
            &mut tri,
            &mesh.positions,
            &c.polys[w[0]..w[1]],
            &mut mesh.indices,
            &mut notes,
            |m| Error::format(path, 0, format!("polygon {f}: {m}")),
        )?;
    }
    mesh.indices.extend_from_slice(&c.strips);
    let format = match header.encoding {
        Encoding::Ascii => MeshFormat::PlyAscii,
        Encoding::BinaryLittleEndian => MeshFormat::PlyBinaryLe,
        Encoding::BinaryBigEndian => MeshFormat::PlyBinaryBe,
    };
    Ok((
        mesh,
        ReadInfo {
            format,
            faces_in_file: c.faces_in_file,
            warnings: notes.into_lines(),
            skipped_faces: c.skipped_faces,
        },
    ))
}

/// Writes `mesh` as PLY in `encoding`: float x y z [nx ny nz] [texture_u texture_v], uchar
/// red green blue alpha (sRGB) when it has colours, and a `face` element of uchar-counted
/// uint index lists.
pub fn write_ply(mesh: &TriMesh, w: &mut dyn Write, encoding: Encoding) -> std::io::Result<()> {
    let fmt = match encoding {
        Encoding::Ascii => "ascii",
        Encoding::BinaryLittleEndian => "binary_little_endian",
        Encoding::BinaryBigEndian => "binary_big_endian",
    };
    let mut head = format!(
        "ply\nformat {fmt} 1.0\ncomment written by terratile\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n",
        mesh.vertex_count()
    );
    if mesh.normals.is_some() {
        head.push_str("property float nx\nproperty float ny\nproperty float nz\n");
    }
    if mesh.colors.is_some() {
        head.push_str(
            "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n",
        );
    }
    if mesh.uvs.is_some() {
        head.push_str("property float texture_u\nproperty float texture_v\n");
    }
    head.push_str(&format!(
        "element face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        mesh.triangle_count()
    ));
    w.write_all(head.as_bytes())?;
    let byte = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
    let colour = |c: [f32; 4]| {
        [
            byte(linear_to_srgb(c[0])),
            byte(linear_to_srgb(c[1])),
            byte(linear_to_srgb(c[2])),
            byte(c[3]),
        ]
    };
    if encoding == Encoding::Ascii {
        for i in 0..mesh.vertex_count() {
            let p = mesh.positions[i];
            write!(w, "{} {} {}", p.x, p.y, p.z)?;
            if let Some(n) = &mesh.normals {
                write!(w, " {} {} {}", n[i].x, n[i].y, n[i].z)?;
            }
            if let Some(c) = &mesh.colors {
                let [r, g, b, a] = colour(c[i]);
                write!(w, " {r} {g} {b} {a}")?;
            }
            if let Some(t) = &mesh.uvs {
                write!(w, " {} {}", t[i].x, t[i].y)?;
            }
            writeln!(w)?;
        }
        for [a, b, c] in &mesh.indices {
            writeln!(w, "3 {a} {b} {c}")?;
        }
        return Ok(());
    }
    let big = encoding == Encoding::BinaryBigEndian;
    let f = |x: f32| {
        if big {
            x.to_be_bytes()
        } else {
            x.to_le_bytes()
        }
    };
    let u = |x: u32| {
        if big {
            x.to_be_bytes()
        } else {
            x.to_le_bytes()
        }
    };
    let mut rec: Vec<u8> = Vec::with_capacity(64);
    for i in 0..mesh.vertex_count() {
        rec.clear();
        let p = mesh.positions[i];
        for x in [p.x, p.y, p.z] {
            rec.extend_from_slice(&f(x));
        }
        if let Some(n) = &mesh.normals {
            for x in [n[i].x, n[i].y, n[i].z] {
                rec.extend_from_slice(&f(x));
            }
        }
        if let Some(c) = &mesh.colors {
            rec.extend_from_slice(&colour(c[i]));
        }
        if let Some(t) = &mesh.uvs {
            rec.extend_from_slice(&f(t[i].x));
            rec.extend_from_slice(&f(t[i].y));
        }
        w.write_all(&rec)?;
    }
    for t in &mesh.indices {
        rec.clear();
        rec.push(3);
        for &v in t {
            rec.extend_from_slice(&u(v));
        }
        w.write_all(&rec)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> TriMesh {
        TriMesh {
            positions: vec![
                Vec3::new(0.1, -2.5e-7, 3.0e6),
                Vec3::new(1.0 / 3.0, 0.0, -0.0),
                Vec3::new(7.0, 8.0, 9.5),
                Vec3::new(-1.0, 2.0, 3.0),
            ],
            indices: vec![[0, 1, 2], [0, 2, 3]],
            normals: Some(vec![Vec3::X, Vec3::Y, Vec3::new(0.6, 0.0, 0.8), Vec3::Z]),
            colors: Some(
                [
                    [255u8, 0, 7, 255],
                    [1, 2, 3, 4],
                    [128, 64, 32, 16],
                    [0, 0, 0, 0],
                ]
                .iter()
                .map(|c| {
                    let l = |x: u8| srgb_to_linear(x as f32 / 255.0);
                    [l(c[0]), l(c[1]), l(c[2]), c[3] as f32 / 255.0]
                })
                .collect(),
            ),
            uvs: Some(vec![
                Vec2::new(0.25, 0.5),
                Vec2::ZERO,
                Vec2::ONE,
                Vec2::new(-3.0, 1e-3),
            ]),
        }
    }

    #[test]
    fn round_trips_in_every_encoding() {
        let m = sample();
        for enc in [
            Encoding::Ascii,
            Encoding::BinaryLittleEndian,
            Encoding::BinaryBigEndian,
        ] {
            let mut buf = Vec::new();
            write_ply(&m, &mut buf, enc).unwrap();
            let (back, info) = parse_ply(Path::new("t.ply"), &buf).unwrap();
            assert_eq!(info.faces_in_file, 2);
            assert_eq!(back.positions, m.positions, "{enc:?}");
            assert_eq!(back.indices, m.indices);
            assert_eq!(back.normals, m.normals);
            assert_eq!(back.uvs, m.uvs);
            let (a, b) = (back.colors.unwrap(), m.colors.clone().unwrap());
            for (x, y) in a.iter().zip(&b) {
                for k in 0..4 {
                    assert!((x[k] - y[k]).abs() < 1e-6, "{enc:?} {x:?} {y:?}");
                }
            }
        }
    }

    fn ascii(body: &str) -> String {
        format!(
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty double y\n\
             property double z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n\
             element face 1\nproperty list uchar int vertex_indices\nend_header\n{body}"
        )
    }

    #[test]
    fn ascii_polygons_and_colours() {
        let text =
            ascii("0 0 0 255 0 0\n1 0 0 0 255 0\n1 1 0 0 0 255\n0 1 0 10 10 10\n4 0 1 2 3\n");
        let (m, info) = parse_ply(Path::new("a.ply"), text.as_bytes()).unwrap();
        assert_eq!(info.format, MeshFormat::PlyAscii);
        assert_eq!(m.indices.len(), 2);
        assert_eq!(m.colors.as_ref().unwrap()[0], [1.0, 0.0, 0.0, 1.0]);
        assert!((m.area() - 1.0).abs() < 1e-9);
    }

    #[test]
    fn tristrips_with_restarts() {
        let text = "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n\
                    property float z\nelement tristrips 1\nproperty list int int vertex_indices\n\
                    end_header\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n2 2 0\n7 0 1 2 3 -1 2 4\n";
        let (m, _) = parse_ply(Path::new("s.ply"), text.as_bytes()).unwrap();
        assert_eq!(m.indices, vec![[0, 1, 2], [2, 1, 3]]);
    }

    #[test]
    fn bad_files_name_line_or_byte() {
        let p = Path::new("b.ply");
        let e = |b: &[u8]| parse_ply(p, b).unwrap_err().to_string();
        let s =
            e(ascii("0 0 0 1 1 1\n1 0 0 1 1 1\n1 1 0 1 1 1\n0 1 0 1 1 1\n3 0 1 9\n").as_bytes());
        assert!(
            s.starts_with("b.ply:17: face 0 of 1: face uses vertex 9 but there are 4"),
            "{s}"
        );
        // A face with 2 vertices: skipped with a warning, an error when strict.
        let two = ascii("0 0 0 1 1 1\n1 0 0 1 1 1\n1 1 0 1 1 1\n0 1 0 1 1 1\n2 0 1\n");
        let (m, info) = parse_ply(p, two.as_bytes()).unwrap();
        assert_eq!((m.indices.len(), info.skipped_faces), (0, 1));
        assert!(
            info.warnings[0].starts_with(
                "b.ply:17: face 0 of 1: a face needs at least 3 vertices, this one has 2: skipped"
            ),
            "{:?}",
            info.warnings
        );
        let strict = ReadOptions { strict: true };
        let s = parse_ply_with(p, two.as_bytes(), &strict)
            .unwrap_err()
            .to_string();
        assert!(
            s.contains("a face needs at least 3 vertices, this one has 2"),
            "{s}"
        );
        let s =
            e(ascii("0 0 0 1 1 1\nnan 0 0 1 1 1\n0 0 0 1 1 1\n0 0 0 1 1 1\n3 0 1 2\n").as_bytes());
        assert!(
            s.starts_with("b.ply:14: vertex 1 of 4: non-finite coordinate"),
            "{s}"
        );
        // Too few bytes for the declared records: refused at the element's header line.
        let s = e(ascii("0 0 0 1 1 1\n").as_bytes());
        assert_eq!(
            s,
            "b.ply:3: element `vertex` declares 4 records of at least 12 bytes each, but only 12 bytes of data follow"
        );
        // Enough bytes for the smallest records but not for these: where it ends.
        let s = e(ascii("0.25 0.25 0.25 1 1 1\n1 0 0 1 1 1\n1 1 0 1 1 1\n3 0 1\n").as_bytes());
        assert!(
            s.starts_with("b.ply:16: vertex 3 of 4: the file ends early"),
            "{s}"
        );
        let s = e(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty quad x\nend_header\n");
        assert!(
            s.starts_with("b.ply:4: unknown property type `quad`"),
            "{s}"
        );
        let s = e(b"ply\nformat ascii 1.0\nelement vertex 1\n");
        assert!(s.contains("no `end_header`"), "{s}");
        // Binary: truncated inside the first face, reported at its byte offset.
        let mut buf = Vec::new();
        write_ply(&sample(), &mut buf, Encoding::BinaryLittleEndian).unwrap();
        let head = buf.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let rec = 3 * 4 + 3 * 4 + 4 + 2 * 4;
        let s = e(&buf[..head + 4 * rec + 3]);
        assert_eq!(
            s,
            format!(
                "b.ply: byte {}: face 0 of 2: the file ends early",
                head + 4 * rec
            )
        );
        let s = e(&buf[..head + rec + 5]);
        assert_eq!(
            s,
            format!("b.ply:4: element `vertex` declares 4 records of at least {rec} bytes each, but only {} bytes of data follow", rec + 5)
        );
    }
}
