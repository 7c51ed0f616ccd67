//! Saliency for the quadric simplifier (An's thesis, "Mesh simplification with hybrid
//! saliency"): what the shape says ([`mesh`]: curvature and Lee et al.'s mesh saliency).
//! The per-vertex maps become the weight H of [`crate::simplify::qem::QemParams::weights`].

pub mod hybrid;
pub mod image;
pub mod itti;
pub mod mesh;
pub mod render;

use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use serde::{Deserialize, Serialize};

/// Which saliency weights the quadric simplifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Saliency {
    /// Plain QEM.
    #[default]
    None,
    /// Lee et al.'s mesh saliency.
    Mesh,
    /// The mean multi-view image saliency.
    Image,
    /// An's hybrid saliency.
    Hybrid,
}

impl std::fmt::Display for Saliency {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Saliency::None => "none",
            Saliency::Mesh => "mesh",
            Saliency::Image => "image",
            Saliency::Hybrid => "hybrid",
        })
    }
}

/// The default lower end of the weights H ∈ [h_min, 1]: the least salient edge costs a
/// tenth of the most salient one at the same quadric error.
pub const H_MIN: f64 = 0.1;

/// Refuses h_min outside (0, 1].
pub fn check_h_min(h_min: f64) -> Result<()> {
    if h_min > 0.0 && h_min <= 1.0 {
        Ok(())
    } else {
        Err(Error::param(
            "simplify",
            "saliency_h_min",
            h_min,
            "must be in (0, 1]",
        ))
    }
}

/// Every per-vertex map, in the input's vertex order.
#[derive(Debug, Clone, PartialEq)]
pub struct Maps {
    /// |mean curvature| (1 / model units).
    pub curvature: Vec<f64>,
    /// Lee et al.'s mesh saliency.
    pub mesh_saliency: Vec<f64>,
    /// Image saliency over the views: max, min, mean (each in [0, 1]).
    pub image: image::ImageSaliency,
    /// The hybrid saliency in [0, 1].
    pub hybrid: Vec<f64>,
    /// The hybrid class of each vertex (0–4 for A–E).
    pub class: Vec<u8>,
}

/// All maps of `mesh` (which must be valid and have triangles).
pub fn maps(mesh: &TriMesh, views: &image::ViewParams) -> Result<Maps> {
    let m = mesh::mesh_saliency(mesh);
    let image = image::image_saliency(mesh, views)?;
    let (hybrid, class) = hybrid::hybrid(
        &m.curvature,
        &m.saliency,
        &image.max,
        &image.min,
        &image.mean,
    );
    Ok(Maps {
        curvature: m.curvature,
        mesh_saliency: m.saliency,
        image,
        hybrid,
        class,
    })
}

/// The weights H ∈ [h_min, 1] of `kind` for `mesh` (`None`: plain QEM, also when the
/// saliency is the same everywhere).
pub fn weights(
    mesh: &TriMesh,
    kind: Saliency,
    h_min: f64,
    views: &image::ViewParams,
) -> Result<Option<Vec<f64>>> {
    check_h_min(h_min)?;
    let values = match kind {
        Saliency::None => return Ok(None),
        Saliency::Mesh => mesh::mesh_saliency(mesh).saliency,
        Saliency::Image => image::image_saliency(mesh, views)?.mean,
        Saliency::Hybrid => maps(mesh, views)?.hybrid,
    };
    Ok(hybrid::weights(&values, h_min))
}
