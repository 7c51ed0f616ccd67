//! glTF 2.0 binary (.glb) in: terratile's own tile meshes and other glb files with embedded
//! data. The `gltf` crate parses and validates the container and the JSON document (a
//! well-kept crate; it was already used to check the files we write); the vertex data are
//! read here rather than through its accessor iterators, because those compute byte ranges
//! from the document's counts without overflow checks and a sparse accessor without a
//! buffer view makes them produce `count` values from nothing: every range below is checked
//! against the bytes of the BIN chunk before anything is read or allocated.
//!
//! Read: the default scene's node tree (or every mesh as it is when there is no scene),
//! node transforms applied; triangle, strip and fan primitives with float POSITION, and
//! NORMAL, TEXCOORD_0 and COLOR_0 (float or normalised unsigned) when every primitive has
//! them; u8/u16/u32 indices. glTF's y-up axes become terratile's z-up ones (x, y, z) →
//! (x, −z, y), the inverse of the tile writer's rotation, so a tile reads back in the
//! coordinates of its OBJ and PLY twins. Glb colours are linear already.
//!
//! Refused: external or data-URI buffers, sparse accessors, quantised positions, an index
//! out of range, a non-finite position, a node reached twice (the hierarchy must be a tree),
//! and scenes that instance more vertex data than 8 times the file's size (a small file
//! could otherwise ask for any amount of memory). Points and lines are skipped with a
//! warning; an unusable attribute is dropped with a warning (an error with `strict`).

use super::{MeshFormat, Notes, ReadInfo, ReadOptions};
use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use glam::{DMat3, DMat4, DVec3, Vec2, Vec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::{Mode, Semantic};
use std::path::Path;

/// Instanced vertex bytes allowed per byte of file.
const INSTANCE_FACTOR: usize = 8;

/// Accessor data checked against the BIN chunk.
struct Data<'a> {
    bytes: &'a [u8],
    stride: usize,
    count: usize,
    ty: DataType,
    dims: Dimensions,
    normalized: bool,
}

impl Data<'_> {
    /// Component `k` of element `i` as f64 (normalised integers scaled to [0, 1]).
    fn get(&self, i: usize, k: usize) -> f64 {
        let size = self.ty.size();
        let at = i * self.stride + k * size;
        let b = &self.bytes[at..at + size];
        let (v, max) = match self.ty {
            DataType::I8 => (b[0] as i8 as f64, 127.0),
            DataType::U8 => (b[0] as f64, 255.0),
            DataType::I16 => (i16::from_le_bytes([b[0], b[1]]) as f64, 32767.0),
            DataType::U16 => (u16::from_le_bytes([b[0], b[1]]) as f64, 65535.0),
            DataType::U32 => (u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64, 1.0),
            DataType::F32 => (f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64, 1.0),
        };
        if self.normalized {
            (v / max).max(-1.0)
        } else {
            v
        }
    }
}

fn components(d: Dimensions) -> usize {
    d.multiplicity()
}

/// What one accessor is, for messages.
fn what(a: &gltf::Accessor, role: &str) -> String {
    format!("accessor {} ({role})", a.index())
}

struct Reader<'a> {
    path: &'a Path,
    blob: &'a [u8],
    /// File offset of the BIN chunk's data (for messages).
    bin_at: u64,
}

impl<'a> Reader<'a> {
    fn err(&self, at: u64, msg: String) -> Error {
        Error::format(self.path, at, msg)
    }

    /// The bytes of accessor `a`, every range checked.
    fn data(&self, a: &gltf::Accessor, role: &str) -> Result<Data<'a>> {
        let name = what(a, role);
        if a.sparse().is_some() {
            return Err(self.err(
                self.bin_at,
                format!("{name}: sparse accessors are not supported"),
            ));
        }
        let Some(view) = a.view() else {
            return Err(self.err(self.bin_at, format!("{name} has no buffer view")));
        };
        let buffer = view.buffer();
        if !matches!(buffer.source(), gltf::buffer::Source::Bin) {
            return Err(self.err(
                self.bin_at,
                format!(
                    "{name}: buffer {} is external; only data embedded in the .glb is read",
                    buffer.index()
                ),
            ));
        }
        let elem = a.size();
        let stride = view.stride().unwrap_or(elem);
        let count = a.count();
        let at = self.bin_at + view.offset() as u64 + a.offset() as u64;
        let view_end = view.offset().checked_add(view.length());
        let Some(view_bytes) = view_end.and_then(|e| self.blob.get(view.offset()..e)) else {
            return Err(self.err(
                at,
                format!(
                    "{name}: buffer view {} ({} bytes at {}) lies outside the {} bytes of binary data",
                    view.index(),
                    view.length(),
                    view.offset(),
                    self.blob.len()
                ),
            ));
        };
        if stride < elem {
            return Err(self.err(
                at,
                format!("{name}: stride {stride} is shorter than its {elem}-byte elements"),
            ));
        }
        let need = match count {
            0 => Some(0),
            n => (n - 1)
                .checked_mul(stride)
                .and_then(|x| x.checked_add(elem))
                .and_then(|x| x.checked_add(a.offset())),
        };
        let bytes = match need {
            Some(n) if n <= view_bytes.len() => &view_bytes[a.offset().min(view_bytes.len())..n.max(a.offset())],
            _ => {
                return Err(self.err(
                    at,
                    format!(
                        "{name}: {count} elements of {elem} bytes (stride {stride}) do not fit in its buffer view of {} bytes",
                        view_bytes.len()
                    ),
                ))
            }
        };
        Ok(Data {
            bytes,
            stride,
            count,
            ty: a.data_type(),
            dims: a.dimensions(),
            normalized: a.normalized(),
        })
    }
}

/// A primitive's vertex data before the merge.
struct Part {
    positions: Vec<Vec3>,
    normals: Option<Vec<Vec3>>,
    uvs: Option<Vec<Vec2>>,
    colors: Option<Vec<[f32; 4]>>,
    triangles: Vec<[u32; 3]>,
}

/// Parses a glb file's bytes (`path` is for messages) as `opts` say.
pub fn parse_glb(path: &Path, bytes: &[u8], opts: &ReadOptions) -> Result<(TriMesh, ReadInfo)> {
    let mut notes = Notes::new(opts);
    let gltf = load_document(path, bytes)?;
    let reader = Reader {
        path,
        blob: gltf.blob.as_deref().unwrap_or(&[]),
        bin_at: bin_offset(bytes),
    };
    let instances = mesh_instances(path, &gltf.document)?;
    check_instanced_size(&reader, &instances, bytes.len())?;
    let mut parts: Vec<Part> = Vec::new();
    for (mesh, m) in &instances {
        for prim in mesh.primitives() {
            if let Some(part) = read_primitive(&reader, &mut notes, mesh, &prim, m)? {
                parts.push(part);
            }
        }
    }
    let mesh = merge_parts(path, parts, &mut notes)?;
    let info = ReadInfo {
        format: MeshFormat::Glb,
        faces_in_file: mesh.indices.len(),
        warnings: notes.into_lines(),
        skipped_faces: 0,
    };
    Ok((mesh, info))
}

/// The container and its JSON document, parsed and validated.
fn load_document(path: &Path, bytes: &[u8]) -> Result<gltf::Gltf> {
    let invalid = |e: gltf::Error| {
        Error::format(
            path,
            0,
            format!("not a valid glb file: {}", one_line(&e.to_string())),
        )
    };
    // Parsed without validation first: gltf-json 1.4's validation indexes the accessors
    // with a primitive's POSITION before it checks that index (a panic on a bad file), so
    // that one reference is checked here, then the crate validates the rest.
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice_without_validation(bytes).map_err(invalid)?;
    let root = document.into_json();
    check_attribute_accessors(path, &root)?;
    Ok(gltf::Gltf {
        document: gltf::Document::from_json(root).map_err(invalid)?,
        blob,
    })
}

/// Every primitive attribute names an existing accessor (see `load_document`).
fn check_attribute_accessors(path: &Path, root: &gltf::json::Root) -> Result<()> {
    for (i, m) in root.meshes.iter().enumerate() {
        for (j, p) in m.primitives.iter().enumerate() {
            for (semantic, a) in &p.attributes {
                if a.value() >= root.accessors.len() {
                    let semantic = match semantic {
                        gltf::json::validation::Checked::Valid(s) => s.to_string(),
                        gltf::json::validation::Checked::Invalid => "?".into(),
                    };
                    return Err(Error::format(
                        path,
                        0,
                        format!(
                            "not a valid glb file: meshes[{i}].primitives[{j}].attributes.{semantic} = {} but there are {} accessors",
                            a.value(),
                            root.accessors.len()
                        ),
                    ));
                }
            }
        }
    }
    Ok(())
}

/// File offset of the BIN chunk's data: 12-byte header, 8-byte JSON chunk header, the
/// JSON, then the BIN chunk's 8-byte header.
fn bin_offset(bytes: &[u8]) -> u64 {
    let json_len = bytes
        .get(12..16)
        .map_or(0, |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as u64);
    20 + json_len + 8
}

/// Mesh instances with their world transforms: the default (or first) scene's node tree,
/// or every mesh untransformed when there is no scene.
fn mesh_instances<'a>(
    path: &Path,
    doc: &'a gltf::Document,
) -> Result<Vec<(gltf::Mesh<'a>, DMat4)>> {
    let mut instances: Vec<(gltf::Mesh, DMat4)> = Vec::new();
    let Some(scene) = doc.default_scene().or_else(|| doc.scenes().next()) else {
        instances.extend(doc.meshes().map(|m| (m, DMat4::IDENTITY)));
        return Ok(instances);
    };
    let mut seen = vec![false; doc.nodes().len()];
    let mut stack: Vec<(gltf::Node, DMat4)> = scene.nodes().map(|n| (n, DMat4::IDENTITY)).collect();
    stack.reverse();
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut seen[node.index()], true) {
            return Err(Error::format(
                path,
                0,
                format!(
                    "node {} is reached twice: the node hierarchy must be a tree",
                    node.index()
                ),
            ));
        }
        let local = node.transform().matrix();
        let m = parent * DMat4::from_cols_array_2d(&local.map(|c| c.map(f64::from)));
        if let Some(mesh) = node.mesh() {
            instances.push((mesh, m));
        }
        let first = stack.len();
        stack.extend(node.children().map(|c| (c, m)));
        stack[first..].reverse();
    }
    Ok(instances)
}

/// Refuses scenes that instance more position bytes than `INSTANCE_FACTOR` times the file.
fn check_instanced_size(
    reader: &Reader,
    instances: &[(gltf::Mesh, DMat4)],
    file_len: usize,
) -> Result<()> {
    let mut instanced = 0usize;
    for (mesh, _) in instances {
        for p in mesh.primitives() {
            if let Some(a) = p.get(&Semantic::Positions) {
                // A count its buffer view cannot hold is the first thing to report.
                let d = reader.data(&a, "POSITION")?;
                instanced = instanced.saturating_add(d.count.saturating_mul(12));
            }
        }
    }
    if instanced > INSTANCE_FACTOR.saturating_mul(file_len) {
        return Err(Error::format(
            reader.path,
            0,
            format!(
                "the scene instances {instanced} bytes of vertex positions, more than {INSTANCE_FACTOR} times the file's {file_len} bytes"
            ),
        ));
    }
    Ok(())
}

/// glTF's y-up axes to terratile's z-up ones: (x, y, z) → (x, −z, y).
fn z_up(v: DVec3) -> Vec3 {
    Vec3::new(v.x as f32, -v.z as f32, v.y as f32)
}

/// One primitive of a mesh instance with world transform `m`; None when it is skipped
/// (not triangles, or no POSITION).
fn read_primitive(
    reader: &Reader,
    notes: &mut Notes,
    mesh: &gltf::Mesh,
    prim: &gltf::Primitive,
    m: &DMat4,
) -> Result<Option<Part>> {
    let path = reader.path;
    let here = format!("mesh {} primitive {}", mesh.index(), prim.index());
    if !matches!(
        prim.mode(),
        Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
    ) {
        notes.note("not triangles", || {
            format!(
                "{}: {here}: {:?} primitives skipped (not triangles)",
                path.display(),
                prim.mode()
            )
        });
        return Ok(None);
    }
    let Some(pa) = prim.get(&Semantic::Positions) else {
        notes.note("no positions", || {
            format!("{}: {here} has no POSITION: skipped", path.display())
        });
        return Ok(None);
    };
    let positions = read_positions(reader, &pa, m, &here)?;
    let n = positions.len();
    // Optional attributes: None when absent; dropped (with a note) when unusable.
    let normals = prim
        .get(&Semantic::Normals)
        .map(|a| read_normals(reader, &a, m, n));
    let normals = usable(notes, normals, "normal", "normals dropped")?;
    let uvs = prim
        .get(&Semantic::TexCoords(0))
        .map(|a| read_uvs(reader, &a, n));
    let uvs = usable(
        notes,
        uvs,
        "texture coordinate",
        "texture coordinates dropped",
    )?;
    let colors = prim
        .get(&Semantic::Colors(0))
        .map(|a| read_colors(reader, &a, n));
    let colors = usable(notes, colors, "colour", "colours dropped")?;
    let corners = read_corners(reader, prim, n, &here)?;
    let (triangles, leftover) = triangulate(prim.mode(), &corners);
    if leftover > 0 {
        notes.lenient(
            "short face",
            reader.err(
                reader.bin_at,
                format!("{here}: {leftover} indices left over after the last triangle"),
            ),
            "ignored",
        )?;
    }
    Ok(Some(Part {
        positions,
        normals,
        uvs,
        colors,
        triangles,
    }))
}

/// An optional attribute: None when absent, Some(values) as read, or Some(empty) once its
/// error has been noted (an error itself with `strict`).
fn usable<T>(
    notes: &mut Notes,
    got: Option<Result<Vec<T>>>,
    kind: &'static str,
    action: &str,
) -> Result<Option<Vec<T>>> {
    match got {
        None => Ok(None),
        Some(Ok(v)) => Ok(Some(v)),
        Some(Err(e)) => {
            notes.lenient(kind, e, action)?;
            Ok(Some(Vec::new()))
        }
    }
}

/// Float VEC3 positions, transformed by `m` into z-up world coordinates, all finite.
fn read_positions(
    reader: &Reader,
    pa: &gltf::Accessor,
    m: &DMat4,
    here: &str,
) -> Result<Vec<Vec3>> {
    let pd = reader.data(pa, "POSITION")?;
    if pd.ty != DataType::F32 || pd.dims != Dimensions::Vec3 {
        return Err(reader.err(
            reader.bin_at,
            format!(
                "{}: POSITION must be float VEC3, not {:?} {:?}",
                what(pa, "POSITION"),
                pd.ty,
                pd.dims
            ),
        ));
    }
    let mut positions = Vec::with_capacity(pd.count);
    for i in 0..pd.count {
        let local = DVec3::new(pd.get(i, 0), pd.get(i, 1), pd.get(i, 2));
        let p = z_up(m.transform_point3(local));
        if !p.is_finite() {
            return Err(reader.err(
                reader.bin_at,
                format!(
                    "{here}: vertex {i} has a non-finite position: NaN or infinite positions are not allowed"
                ),
            ));
        }
        positions.push(p);
    }
    Ok(positions)
}

/// `n` float VEC3 normals, transformed by the inverse transpose of `m`, unit length, z-up.
fn read_normals(reader: &Reader, a: &gltf::Accessor, m: &DMat4, n: usize) -> Result<Vec<Vec3>> {
    let nm = DMat3::from_mat4(*m).inverse().transpose();
    let d = reader.data(a, "NORMAL")?;
    if d.ty != DataType::F32 || d.dims != Dimensions::Vec3 || d.count != n {
        return Err(reader.err(
            reader.bin_at,
            format!(
                "{}: NORMAL must be float VEC3 with one per vertex",
                what(a, "NORMAL")
            ),
        ));
    }
    (0..n)
        .map(|i| {
            let v = nm * DVec3::new(d.get(i, 0), d.get(i, 1), d.get(i, 2));
            let v = z_up(v.normalize_or_zero());
            if v.is_finite() {
                Ok(v)
            } else {
                Err(reader.err(
                    reader.bin_at,
                    format!("{}: normal {i} is not finite", what(a, "NORMAL")),
                ))
            }
        })
        .collect()
}

/// Float or normalised unsigned, the types glTF allows for texture coordinates and colours.
fn float_or_unorm(d: &Data) -> bool {
    d.ty == DataType::F32 || (d.normalized && matches!(d.ty, DataType::U8 | DataType::U16))
}

/// `n` VEC2 texture coordinates, all finite.
fn read_uvs(reader: &Reader, a: &gltf::Accessor, n: usize) -> Result<Vec<Vec2>> {
    let d = reader.data(a, "TEXCOORD_0")?;
    if !float_or_unorm(&d) || d.dims != Dimensions::Vec2 || d.count != n {
        return Err(reader.err(
            reader.bin_at,
            format!(
                "{}: TEXCOORD_0 must be VEC2 float or normalised unsigned, one per vertex",
                what(a, "TEXCOORD_0")
            ),
        ));
    }
    (0..n)
        .map(|i| {
            let v = Vec2::new(d.get(i, 0) as f32, d.get(i, 1) as f32);
            if v.is_finite() {
                Ok(v)
            } else {
                Err(reader.err(
                    reader.bin_at,
                    format!(
                        "{}: texture coordinate {i} is not finite",
                        what(a, "TEXCOORD_0")
                    ),
                ))
            }
        })
        .collect()
}

/// `n` VEC3 or VEC4 colours as linear RGBA (alpha 1 when absent), clamped to [0, 1].
fn read_colors(reader: &Reader, a: &gltf::Accessor, n: usize) -> Result<Vec<[f32; 4]>> {
    let d = reader.data(a, "COLOR_0")?;
    let k = components(d.dims);
    if !float_or_unorm(&d) || !matches!(d.dims, Dimensions::Vec3 | Dimensions::Vec4) || d.count != n
    {
        return Err(reader.err(
            reader.bin_at,
            format!(
                "{}: COLOR_0 must be VEC3 or VEC4 float or normalised unsigned, one per vertex",
                what(a, "COLOR_0")
            ),
        ));
    }
    (0..n)
        .map(|i| {
            let mut c = [1f32; 4];
            for (j, x) in c.iter_mut().enumerate().take(k) {
                *x = d.get(i, j) as f32;
            }
            if c.iter().all(|x| x.is_finite()) {
                Ok(c.map(|x| x.clamp(0.0, 1.0)))
            } else {
                Err(reader.err(
                    reader.bin_at,
                    format!("{}: colour {i} is not finite", what(a, "COLOR_0")),
                ))
            }
        })
        .collect()
}

/// The primitive's corner list: its unsigned indices, each below `n`, or 0..n.
fn read_corners(reader: &Reader, prim: &gltf::Primitive, n: usize, here: &str) -> Result<Vec<u32>> {
    let Some(a) = prim.indices() else {
        return Ok((0..n as u32).collect());
    };
    let d = reader.data(&a, "indices")?;
    if !matches!(d.ty, DataType::U8 | DataType::U16 | DataType::U32)
        || d.dims != Dimensions::Scalar
        || d.normalized
    {
        return Err(reader.err(
            reader.bin_at,
            format!("{}: indices must be unsigned SCALAR", what(&a, "indices")),
        ));
    }
    let mut v = Vec::with_capacity(d.count);
    for i in 0..d.count {
        let x = d.get(i, 0);
        if x >= n as f64 {
            return Err(reader.err(
                reader.bin_at,
                format!("{here}: index {i} is {x} but the primitive has {n} vertices"),
            ));
        }
        v.push(x as u32);
    }
    Ok(v)
}

/// Triangles from a triangle list, strip or fan, and how many corners were left over.
fn triangulate(mode: Mode, corners: &[u32]) -> (Vec<[u32; 3]>, usize) {
    let mut triangles = Vec::with_capacity(corners.len() / 3);
    match mode {
        Mode::Triangles => {
            triangles.extend(corners.chunks_exact(3).map(|t| [t[0], t[1], t[2]]));
        }
        Mode::TriangleStrip => {
            for (k, w) in corners.windows(3).enumerate() {
                // A repeated index is how a strip swaps or joins strips (glTF has no
                // restart index): that triangle draws nothing and is not the mesh's.
                if w[0] == w[1] || w[1] == w[2] || w[0] == w[2] {
                    continue;
                }
                triangles.push(if k % 2 == 0 {
                    [w[0], w[1], w[2]]
                } else {
                    [w[1], w[0], w[2]]
                });
            }
        }
        _ => {
            for k in 1..corners.len().saturating_sub(1) {
                triangles.push([corners[0], corners[k], corners[k + 1]]);
            }
        }
    }
    // A list leaves its last `len % 3` corners over; a strip or fan of one or two corners
    // leaves them all, a longer one none.
    let leftover = match mode {
        Mode::Triangles => corners.len() % 3,
        _ if corners.len() < 3 => corners.len(),
        _ => 0,
    };
    (triangles, leftover)
}

/// Whether every primitive has an attribute (`len` gives its length), usable; notes when
/// some have it and others lack it.
fn keep_attribute(
    path: &Path,
    parts: &[Part],
    len: impl Fn(&Part) -> Option<usize>,
    name: &str,
    notes: &mut Notes,
) -> bool {
    let have: Vec<Option<usize>> = parts.iter().map(len).collect();
    let all = !parts.is_empty()
        && have
            .iter()
            .zip(parts)
            .all(|(h, p)| *h == Some(p.positions.len()));
    let some = have.iter().any(|h| h.is_some_and(|n| n > 0));
    if some && !all && have.iter().all(|h| h.is_none_or(|n| n > 0)) {
        notes.note("partial attribute", || {
            format!(
                "{}: {name} are missing on some primitives: dropped",
                path.display()
            )
        });
    }
    all
}

/// The primitives as one mesh: an attribute survives when every primitive has it, usable.
fn merge_parts(path: &Path, parts: Vec<Part>, notes: &mut Notes) -> Result<TriMesh> {
    let total: usize = parts.iter().map(|p| p.positions.len()).sum();
    if total > u32::MAX as usize {
        return Err(Error::format(path, 0, "more than 2^32 - 1 vertices"));
    }
    let mut keep =
        |len: fn(&Part) -> Option<usize>, name| keep_attribute(path, &parts, len, name, notes);
    let with_normals = keep(|p| p.normals.as_ref().map(Vec::len), "normals");
    let with_uvs = keep(|p| p.uvs.as_ref().map(Vec::len), "texture coordinates");
    let with_colors = keep(|p| p.colors.as_ref().map(Vec::len), "colours");
    let mut mesh = TriMesh {
        positions: Vec::with_capacity(total),
        indices: Vec::new(),
        normals: with_normals.then(|| Vec::with_capacity(total)),
        colors: with_colors.then(|| Vec::with_capacity(total)),
        uvs: with_uvs.then(|| Vec::with_capacity(total)),
    };
    for p in parts {
        let base = mesh.positions.len() as u32;
        mesh.positions.extend_from_slice(&p.positions);
        mesh.indices
            .extend(p.triangles.iter().map(|t| t.map(|i| i + base)));
        if let (Some(out), Some(v)) = (mesh.normals.as_mut(), p.normals) {
            out.extend(v);
        }
        if let (Some(out), Some(v)) = (mesh.uvs.as_mut(), p.uvs) {
            out.extend(v);
        }
        if let (Some(out), Some(v)) = (mesh.colors.as_mut(), p.colors) {
            out.extend(v);
        }
    }
    Ok(mesh)
}

/// `s` on one line (the crate's validation errors may list several problems).
fn one_line(s: &str) -> String {
    s.split(['\n', '\r'])
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join("; ")
        .trim_end_matches(';')
        .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::quad;

    #[test]
    fn the_tile_writer_reads_back_exactly() {
        let m = quad();
        let bytes = crate::mesh::io::glb_bytes(&m, "t", 1.0).unwrap();
        let (back, info) = parse_glb(Path::new("t.glb"), &bytes, &ReadOptions::default()).unwrap();
        assert_eq!(info.format, MeshFormat::Glb);
        assert!(info.warnings.is_empty(), "{:?}", info.warnings);
        assert_eq!(back.positions, m.positions);
        assert_eq!(back.indices, m.indices);
        assert_eq!(back.normals, m.normals);
    }

    #[test]
    fn damaged_ranges_are_errors_naming_the_file() {
        let bytes = crate::mesh::io::glb_bytes(&quad(), "t", 1.0).unwrap();
        // Grow the position accessor's count past its buffer view: same JSON length.
        let mut bad = bytes.clone();
        let at = bad.windows(10).position(|w| w == b"\"count\":4,").unwrap();
        bad[at + 8] = b'9';
        let e = parse_glb(Path::new("t.glb"), &bad, &ReadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.glb: byte "), "{e}");
        assert!(e.contains("do not fit in its buffer view"), "{e}");
    }
}
