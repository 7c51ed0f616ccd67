//! Mesh files in and out: Wavefront OBJ ([`obj`]) and Stanford PLY ([`ply`]), and glTF
//! binary ([`glb`], read only: terratile's tile meshes and other glb files). The format is
//! recognised from the content (`ply` or `glTF` magic) and otherwise from the extension;
//! writes are atomic (temporary sibling, then rename), so a failed write never leaves a
//! partial file.
//!
//! Reading is lenient by default, like the tools users compare us with (trimesh, MeshLab):
//! an unusable attribute (texture coordinates, normals or colours with an index out of range
//! or a value that is not a finite number) is dropped and a face with fewer than 3 vertices
//! is skipped, each with a warning; what would corrupt the geometry (a vertex index out of
//! range, a NaN position) is always an error. [`ReadOptions::strict`] makes every one of
//! those an error.
//!
//! Every count a header declares is checked against the bytes that follow before anything
//! is allocated from it.
//!
//! Colours are stored in files as display (sRGB-encoded) values, as every tool writes them;
//! [`TriMesh::colors`] holds linear values, converted on the way in and out.

pub mod glb;
mod glb_write;
pub mod obj;
pub mod ply;

pub use glb_write::{glb_bytes, glb_container, glb_primitive, TRIANGLES, TRIANGLE_STRIP};

use super::TriMesh;
use crate::error::{Error, Result};
use crate::fsutil::write_atomic;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::Path;

/// A mesh file format: what a mesh file was read as, and what the pipeline writes tile and
/// baseline meshes as. In a pipeline file (`output.meshes`) the three formats terratile
/// writes are named by their extension: `ply` (binary little endian), `obj` and `glb`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MeshFormat {
    /// PLY, binary little endian.
    #[serde(rename(deserialize = "ply"))]
    PlyBinaryLe,
    /// Wavefront OBJ text.
    Obj,
    /// glTF 2.0 binary.
    Glb,
    /// PLY, ASCII.
    #[serde(skip_deserializing)]
    PlyAscii,
    /// PLY, binary big endian.
    #[serde(skip_deserializing)]
    PlyBinaryBe,
}

impl std::fmt::Display for MeshFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            MeshFormat::Obj => "OBJ",
            MeshFormat::PlyAscii => "PLY ascii",
            MeshFormat::PlyBinaryLe => "PLY binary little endian",
            MeshFormat::PlyBinaryBe => "PLY binary big endian",
            MeshFormat::Glb => "glTF binary",
        })
    }
}

impl MeshFormat {
    /// The format to write for `path`'s extension: `.obj` → OBJ, `.ply` → binary little
    /// endian PLY.
    pub fn for_output(path: &Path) -> Result<MeshFormat> {
        match extension(path).as_deref() {
            Some("obj") => Ok(MeshFormat::Obj),
            Some("ply") => Ok(MeshFormat::PlyBinaryLe),
            _ => Err(Error::Usage(format!(
                "{}: unknown mesh format: the file name must end in .obj or .ply",
                path.display()
            ))),
        }
    }

    /// The tile meshes written by default: glb alone. Game engines and 3-D tools import it
    /// directly (Unity through glTFast, Unreal, Godot, Blender), it is the smallest of the
    /// three (about a third of OBJ's bytes) and the fastest to write; writing all three made
    /// autzen_full's 56 MB of LAZ into 1.1 GB of output.
    pub const DEFAULT_TILE: [MeshFormat; 1] = [MeshFormat::Glb];

    /// File extension.
    pub fn ext(self) -> &'static str {
        match self {
            MeshFormat::PlyBinaryLe | MeshFormat::PlyAscii | MeshFormat::PlyBinaryBe => "ply",
            MeshFormat::Obj => "obj",
            MeshFormat::Glb => "glb",
        }
    }

    /// `mesh` encoded in this format (`name` labels it where the format has names). Its
    /// positions are in units of `metres_per_unit` metres: PLY and OBJ keep them, glb writes
    /// metres (glTF's unit).
    pub fn encode(self, mesh: &TriMesh, name: &str, metres_per_unit: f64) -> Result<Vec<u8>> {
        let mut out = Vec::new();
        let io = |e: std::io::Error| Error::Internal(format!("{name}: {e}"));
        match self {
            MeshFormat::PlyBinaryLe => {
                ply::write_ply(mesh, &mut out, ply::Encoding::BinaryLittleEndian).map_err(io)?
            }
            MeshFormat::PlyAscii => {
                ply::write_ply(mesh, &mut out, ply::Encoding::Ascii).map_err(io)?
            }
            MeshFormat::PlyBinaryBe => {
                ply::write_ply(mesh, &mut out, ply::Encoding::BinaryBigEndian).map_err(io)?
            }
            MeshFormat::Obj => {
                // About 40 bytes a `v`/`vn` line and 48 an `f` line: reserving saves the
                // copies of a doubling buffer (a tenth of the writing time).
                let lines = mesh.vertex_count()
                    * (1 + usize::from(mesh.normals.is_some()) + usize::from(mesh.uvs.is_some()));
                out.reserve(40 * lines + 48 * mesh.triangle_count());
                obj::write_obj(mesh, &mut out).map_err(io)?
            }
            MeshFormat::Glb => out = glb_bytes(mesh, name, metres_per_unit)?,
        }
        Ok(out)
    }
}

fn extension(path: &Path) -> Option<String> {
    path.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
}

/// What reading a mesh file found besides the mesh.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReadInfo {
    /// The file's format.
    pub format: MeshFormat,
    /// Faces as written in the file (polygons before triangulation; strips count once).
    pub faces_in_file: usize,
    /// Things a user should know (e.g. a non-standard file read by a documented rule, an
    /// attribute dropped): one line each, repeats of one kind counted into the first.
    pub warnings: Vec<String>,
    /// Faces skipped (fewer than 3 vertices), not in `faces_in_file`.
    pub skipped_faces: usize,
}

/// How to read a mesh file.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReadOptions {
    /// Refuse what the default reading drops or skips with a warning (an unusable texture
    /// coordinate, normal or colour, a face with fewer than 3 vertices).
    pub strict: bool,
}

/// Warnings of one read: one line each; further warnings of a kind already noted are
/// counted into the first one (`… (and N more)`), so a file with a million bad faces gives
/// one line, not a million.
#[derive(Debug, Default)]
pub(crate) struct Notes {
    strict: bool,
    items: Vec<(&'static str, String, usize)>,
}

impl Notes {
    pub(crate) fn new(opts: &ReadOptions) -> Notes {
        Notes {
            strict: opts.strict,
            items: Vec::new(),
        }
    }

    /// A problem the lenient reading gets past by `action` (e.g. "face skipped"): an error
    /// when strict, otherwise a warning (`error: action`) of kind `kind`.
    pub(crate) fn lenient(&mut self, kind: &'static str, error: Error, action: &str) -> Result<()> {
        if self.strict {
            return Err(error);
        }
        self.note(kind, || format!("{error}: {action}"));
        Ok(())
    }

    /// A warning of kind `kind` (the text is made only for the first of its kind).
    pub(crate) fn note(&mut self, kind: &'static str, text: impl FnOnce() -> String) {
        match self.items.iter_mut().find(|(k, _, _)| *k == kind) {
            Some(item) => item.2 += 1,
            None => self.items.push((kind, text(), 0)),
        }
    }

    pub(crate) fn into_lines(self) -> Vec<String> {
        self.items
            .into_iter()
            .map(|(_, text, more)| {
                if more == 0 {
                    text
                } else {
                    format!("{text} (and {more} more)")
                }
            })
            .collect()
    }
}

/// Polygons with more corners than this are split as a fan from their first corner instead
/// of by ear clipping, whose time grows with the square of the corners or worse (a
/// 20,000-corner face took seconds; a few MB of one face would take hours). A fan is exact
/// for convex polygons, which such faces (caps of CAD models) usually are; a warning says so
/// and `strict` refuses the file.
pub const MAX_EAR_CORNERS: usize = 1024;

/// Triangulates `poly` into `out` (by ear clipping, or as a fan above [`MAX_EAR_CORNERS`]
/// with a note; `err` is where the face is, for the note).
pub(crate) fn triangulate(
    tri: &mut crate::mesh::polygon::Triangulator,
    positions: &[glam::Vec3],
    poly: &[u32],
    out: &mut Vec<[u32; 3]>,
    notes: &mut Notes,
    err: impl FnOnce(String) -> Error,
) -> Result<()> {
    if poly.len() <= MAX_EAR_CORNERS {
        tri.triangulate(positions, poly, out);
        return Ok(());
    }
    notes.lenient(
        "fan",
        err(format!(
            "a face with {} corners (more than {MAX_EAR_CORNERS})",
            poly.len()
        )),
        "triangulated as a fan",
    )?;
    for k in 1..poly.len() - 1 {
        out.push([poly[0], poly[k], poly[k + 1]]);
    }
    Ok(())
}

/// Reads an OBJ, PLY or glb file.
pub fn read(path: &Path) -> Result<TriMesh> {
    read_with_info(path).map(|(m, _)| m)
}

/// Reads an OBJ, PLY or glb file and reports what was in it.
pub fn read_with_info(path: &Path) -> Result<(TriMesh, ReadInfo)> {
    read_with(path, &ReadOptions::default())
}

/// Reads an OBJ, PLY or glb file as `opts` say and reports what was in it.
pub fn read_with(path: &Path, opts: &ReadOptions) -> Result<(TriMesh, ReadInfo)> {
    let map = crate::fsutil::map_file(path)?;
    if map.starts_with(b"ply") && matches!(map.get(3), Some(b'\n' | b'\r')) {
        return ply::parse_ply_with(path, &map, opts);
    }
    if map.starts_with(b"glTF") {
        return glb::parse_glb(path, &map, opts);
    }
    match extension(path).as_deref() {
        Some("obj") => obj::parse_obj_with(path, &map, opts),
        Some("ply") => Err(Error::format(
            path,
            0,
            "not a PLY file: it does not start with `ply`",
        )),
        Some("glb") => Err(Error::format(
            path,
            0,
            "not a glb file: it does not start with `glTF`",
        )),
        _ => {
            // Not PLY by content; OBJ is the other text format we know. Guess only when the
            // file starts like one, otherwise say what we expected.
            let head = &map[..map.len().min(4096)];
            let looks_obj = head
                .split(|&b| b == b'\n')
                .map(|l| l.trim_ascii_start())
                .any(|l| l.starts_with(b"v ") || l.starts_with(b"f "));
            if looks_obj {
                obj::parse_obj_with(path, &map, opts)
            } else {
                Err(Error::format(
                    path,
                    0,
                    "unknown mesh format: expected an OBJ (.obj), PLY (.ply) or glTF binary (.glb) file",
                ))
            }
        }
    }
}

/// Reads a mesh that a stage will work on: it must have triangles. Returns the mesh and the
/// reader's warnings.
pub fn read_surface(path: &Path) -> Result<(TriMesh, Vec<String>)> {
    read_surface_with(path, &ReadOptions::default())
}

/// [`read_surface`] as `opts` say.
pub fn read_surface_with(path: &Path, opts: &ReadOptions) -> Result<(TriMesh, Vec<String>)> {
    let (m, info) = read_with(path, opts)?;
    if m.triangle_count() == 0 {
        return Err(Error::Data {
            stage: "mesh",
            message: format!("{}: the mesh has no triangles", path.display()),
        });
    }
    Ok((m, info.warnings))
}

/// Writes `mesh` to `path` atomically: glTF binary for a `.glb` name (positions scaled to
/// metres by `metres_per_unit`, `name` inside the file), otherwise OBJ or binary PLY by
/// extension as [`write`] does.
pub fn write_named(mesh: &TriMesh, path: &Path, name: &str, metres_per_unit: f64) -> Result<()> {
    if extension(path).as_deref() == Some("glb") {
        let bytes = glb_bytes(mesh, name, metres_per_unit)?;
        return crate::fsutil::write_bytes_atomic(path, &bytes);
    }
    write(mesh, path)
}

/// Writes `mesh` to `path`, OBJ or binary PLY by extension, atomically.
pub fn write(mesh: &TriMesh, path: &Path) -> Result<()> {
    write_as(mesh, path, MeshFormat::for_output(path)?)
}

/// Writes `mesh` to `path` in `format`, atomically.
pub fn write_as(mesh: &TriMesh, path: &Path, format: MeshFormat) -> Result<()> {
    mesh.validate(&path.display().to_string())?;
    write_atomic(path, |w| {
        match format {
            MeshFormat::Obj => obj::write_obj(mesh, w),
            MeshFormat::PlyAscii => ply::write_ply(mesh, w, ply::Encoding::Ascii),
            MeshFormat::PlyBinaryLe => ply::write_ply(mesh, w, ply::Encoding::BinaryLittleEndian),
            MeshFormat::PlyBinaryBe => ply::write_ply(mesh, w, ply::Encoding::BinaryBigEndian),
            MeshFormat::Glb => {
                let name = path
                    .file_stem()
                    .map_or("mesh".into(), |s| s.to_string_lossy());
                // Model units as they are: a mesh asset has no CRS to convert from.
                match glb_bytes(mesh, &name, 1.0) {
                    Ok(bytes) => w.write_all(&bytes),
                    Err(e) => Err(std::io::Error::other(e.to_string())),
                }
            }
        }
        .and_then(|()| w.flush())
        .map_err(|e| Error::io(path, e))
    })
}
