//! Mesh files in and out: Wavefront OBJ ([`obj`]) and Stanford PLY ([`ply`]). The format is
//! recognised from the content (`ply` magic) and otherwise from the extension; writes are
//! atomic (temporary sibling, then rename), so a failed write never leaves a partial file.
//!
//! Colours are stored in files as display (sRGB-encoded) values, as every tool writes them;
//! [`TriMesh::colors`] holds linear values, converted on the way in and out.

pub mod obj;
pub mod ply;

use super::TriMesh;
use crate::error::{Error, Result};
use crate::fsutil::write_atomic;
use serde::Serialize;
use std::io::Write;
use std::path::Path;

/// A mesh file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MeshFormat {
    /// Wavefront OBJ text.
    Obj,
    /// PLY, ASCII.
    PlyAscii,
    /// PLY, binary little endian.
    PlyBinaryLe,
    /// PLY, binary big endian.
    PlyBinaryBe,
}

impl std::fmt::Display for MeshFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            MeshFormat::Obj => "OBJ",
            MeshFormat::PlyAscii => "PLY ascii",
            MeshFormat::PlyBinaryLe => "PLY binary little endian",
            MeshFormat::PlyBinaryBe => "PLY binary big endian",
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
    /// Things a user should know (e.g. a non-standard file read by a documented rule).
    pub warnings: Vec<String>,
}

/// Reads an OBJ or PLY file.
pub fn read(path: &Path) -> Result<TriMesh> {
    read_with_info(path).map(|(m, _)| m)
}

/// Reads an OBJ or PLY file and reports what was in it.
pub fn read_with_info(path: &Path) -> Result<(TriMesh, ReadInfo)> {
    let map = crate::points::map_file(path)?;
    if map.starts_with(b"ply") && matches!(map.get(3), Some(b'\n' | b'\r')) {
        return ply::parse_ply(path, &map);
    }
    match extension(path).as_deref() {
        Some("obj") => obj::parse_obj(path, &map),
        Some("ply") => Err(Error::format(
            path,
            0,
            "not a PLY file: it does not start with `ply`",
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
                obj::parse_obj(path, &map)
            } else {
                Err(Error::format(
                    path,
                    0,
                    "unknown mesh format: expected an OBJ (.obj) or PLY (.ply) file",
                ))
            }
        }
    }
}

/// Reads a mesh that a stage will work on: it must have triangles. Returns the mesh and the
/// reader's warnings.
pub fn read_surface(path: &Path) -> Result<(TriMesh, Vec<String>)> {
    let (m, info) = read_with_info(path)?;
    if m.triangle_count() == 0 {
        return Err(Error::Data {
            stage: "mesh",
            message: format!("{}: the mesh has no triangles", path.display()),
        });
    }
    Ok((m, info.warnings))
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
        }
        .and_then(|()| w.flush())
        .map_err(|e| Error::io(path, e))
    })
}
