//! Mesh simplification for model assets: vertex clustering ([`cluster`]) on top of
//! reusable error quadrics ([`quadric`]). Later stages (QEM with saliency, fold-free
//! placement, progressive strips) live beside them.

pub mod cluster;
pub mod prep;
pub mod qem;
pub mod quadric;
pub mod saliency;
pub mod strips;
pub mod target;
#[cfg(test)]
mod test_meshes;

pub use cluster::{Method, RefineBox, Representative, Simplified, SimplifyParams, SimplifyReport};
pub use qem::{Placement, QemReport, QuadricMerge};
pub use quadric::Quadric;

use crate::error::Result;
use crate::mesh::{self, HausdorffParams, HausdorffReport};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Simplifies `mesh` as `params` say: vertex clustering ([`cluster::simplify`]) or, with
/// `method = "qem"`, quadric edge collapse ([`qem::simplify`]).
pub fn simplify(mesh: &mesh::TriMesh, params: &SimplifyParams) -> Result<Simplified> {
    if params.method != Method::Qem {
        return cluster::simplify(mesh, params);
    }
    mesh.validate("the input mesh")?;
    let triangles = match params.target(mesh.triangle_count())? {
        target::Target::Triangles(t) => t,
        // `SimplifyParams::target` gives QEM a triangle count only.
        target::Target::Scale(_) => 1,
    };
    let diag = mesh.diagonal();
    let p = qem::QemParams {
        triangles,
        max_error: params
            .max_error
            .or(params.max_error_pct.map(|pct| pct * 0.01 * diag)),
        placement: params.placement.unwrap_or_default(),
        merge: params.quadric_merge.unwrap_or_default(),
        lock_border: params.lock_border.unwrap_or(false),
        cost: qem::Cost::default(),
        check_intersections: params.check_intersections.unwrap_or(false),
        weights: None,
        pair_distance: params.pair_distance.unwrap_or(0.0),
        collapse_seams: params.collapse_seams.unwrap_or(false),
        weight_rule: params.saliency_rule.unwrap_or(qem::WeightRule::Quadric),
        engine: params.engine.unwrap_or_default(),
    };
    let r = match params.saliency {
        Some(kind) => {
            let views = params.views();
            views.validate()?;
            let h_min = params.saliency_h_min.unwrap_or(saliency::H_MIN);
            saliency::check_h_min(h_min)?;
            let w = saliency::Weighting {
                h_min,
                ..saliency::Weighting::default()
            };
            match saliency::values(mesh, kind, &views)? {
                Some(v) => w.simplify(mesh, &p, &v)?,
                None => qem::simplify(mesh, &p)?,
            }
        }
        None => qem::simplify(mesh, &p)?,
    };
    let report = SimplifyReport {
        method: Method::Qem,
        representative: None,
        triangles_in: mesh.triangle_count(),
        triangles_out: r.mesh.triangle_count(),
        vertices_in: mesh.vertex_count(),
        vertices_out: r.mesh.vertex_count(),
        clusters: 0,
        stranded_split: 0,
        scale: r.report.max_error,
        evaluations: r.report.collapses,
        qem: Some(r.report),
    };
    Ok(Simplified {
        mesh: r.mesh,
        report,
    })
}

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
    let mut warnings = warnings;
    if let Some(q) = &s.report.qem {
        let asked = params.ratio.is_some() || params.triangles.is_some();
        if asked && !q.target_reached {
            warnings.push(format!(
                "no valid collapse is left at {} triangles (target {}): stopped there",
                s.mesh.triangle_count(),
                q.target
            ));
        }
    }
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

/// A simplified file's input and output paths as the reports print them: `input → output`.
pub(crate) struct InOut<'a>(pub &'a Path, pub &'a Path);

impl std::fmt::Display for InOut<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} → {}", self.0.display(), self.1.display())
    }
}

impl std::fmt::Display for FileReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let r = &self.report;
        if let Some(q) = &r.qem {
            writeln!(
                f,
                "{}: qem method, {} placement, {} quadric merge",
                InOut(&self.input, &self.output),
                q.placement,
                q.quadric_merge
            )?;
            writeln!(
                f,
                "triangles {} → {} ({:.1} %, target {}{}), vertices {} → {}, {} collapses ({} refused), largest error accepted {:.6}, {} non-manifold vertices left alone, {:.1} ms",
                r.triangles_in,
                r.triangles_out,
                100.0 * r.triangles_out as f64 / r.triangles_in.max(1) as f64,
                q.target,
                if q.target_reached { "" } else { ", not reached" },
                r.vertices_in,
                r.vertices_out,
                q.collapses,
                q.rejected,
                q.max_error,
                q.non_manifold_vertices,
                self.seconds * 1e3
            )?;
        } else {
            writeln!(
                f,
                "{}: {} method, {} representative",
                InOut(&self.input, &self.output),
                r.method,
                r.representative.unwrap_or(Representative::Quadric)
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
        }
        if let Some(e) = &self.error {
            write!(f, "{e}")?;
        }
        Ok(())
    }
}
