//! Saliency for the quadric simplifier (An's thesis, "Mesh simplification with hybrid
//! saliency"): what the shape says ([`mesh`]: curvature and Lee et al.'s mesh saliency).
//! The per-vertex maps become the weight H of [`crate::simplify::qem::QemParams::weights`].

pub mod image;
pub mod itti;
pub mod mesh;
pub mod render;
