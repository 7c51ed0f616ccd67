//! Mesh simplification for model assets: vertex clustering (SPEC §7, [`cluster`]) on top of
//! reusable error quadrics ([`quadric`]). Later stages (QEM with saliency, fold-free
//! placement, progressive strips) live beside them.

pub mod cluster;
pub mod quadric;

pub use cluster::{
    simplify, Method, RefineBox, Representative, Simplified, SimplifyParams, SimplifyReport,
};
pub use quadric::Quadric;

use crate::error::Result;
use crate::mesh::{self, HausdorffParams, HausdorffReport};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What [`simplify_file`] did.
#[derive(Debug, Clone, Serialize)]
pub struct FileReport {
    /// The input mesh.
    pub input: PathBuf,
    /// The output mesh.
    pub output: PathBuf,
    /// Things the reader noticed about the input (e.g. a 0-based OBJ).
    pub warnings: Vec<String>,
    /// What the simplification did.
    #[serde(flatten)]
    pub report: SimplifyReport,
    /// Seconds spent simplifying (reading and writing excluded).
    pub seconds: f64,
    /// The error of the result against the input, when measured.
    pub error: Option<HausdorffReport>,
}

/// Reads `input`, simplifies it as `params` say, writes `output` (OBJ or binary PLY by
/// extension; nothing is written when anything fails) and, with `error`, measures the
/// result against the input.
pub fn simplify_file(
    input: &Path,
    output: &Path,
    params: &SimplifyParams,
    error: Option<&HausdorffParams>,
) -> Result<FileReport> {
    simplify_file_with(
        input,
        output,
        params,
        error,
        &mesh::io::ReadOptions::default(),
    )
}

/// [`simplify_file`], reading `input` as `read` says (e.g. strictly).
pub fn simplify_file_with(
    input: &Path,
    output: &Path,
    params: &SimplifyParams,
    error: Option<&HausdorffParams>,
    read: &mesh::io::ReadOptions,
) -> Result<FileReport> {
    // Check what can be checked before the work: the target, the output format, the
    // measurement's samples.
    params.target(1)?;
    mesh::io::MeshFormat::for_output(output)?;
    error.map(HausdorffParams::validate).transpose()?;
    let (m, warnings) = mesh::io::read_surface_with(input, read)?;
    let t = Instant::now();
    let s = simplify(&m, params)?;
    let seconds = t.elapsed().as_secs_f64();
    mesh::io::write(&s.mesh, output)?;
    let error = error.map(|p| mesh::hausdorff(&m, &s.mesh, p)).transpose()?;
    Ok(FileReport {
        input: input.to_path_buf(),
        output: output.to_path_buf(),
        warnings,
        report: s.report,
        seconds,
        error,
    })
}

impl std::fmt::Display for FileReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let r = &self.report;
        writeln!(
            f,
            "{} → {}: {} method, {} representative",
            self.input.display(),
            self.output.display(),
            r.method,
            r.representative
        )?;
        writeln!(
            f,
            "triangles {} → {} ({:.1} %), vertices {} → {}, {} clusters ({} stranded split), scale {:.6}, {:.1} ms",
            r.triangles_in,
            r.triangles_out,
            100.0 * r.triangles_out as f64 / r.triangles_in.max(1) as f64,
            r.vertices_in,
            r.vertices_out,
            r.clusters,
            r.stranded_split,
            r.scale,
            self.seconds * 1e3
        )?;
        if let Some(e) = &self.error {
            write!(f, "{e}")?;
        }
        Ok(())
    }
}
