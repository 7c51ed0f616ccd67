//! Quadric edge collapse (Garland & Heckbert, "Surface Simplification Using Quadric Error
//! Metrics", 1997): one collapse engine
//! with the cost, the placement and the validity checks as separate, pluggable parts, so
//! that the saliency-weighted cost (`simplify::saliency`) and progressive strips
//! (`simplify::strips`) reuse it.
//!
//! The engine works on the welded topology of [`Prepared`] (seams are not holes) with the
//! area-weighted plane quadrics it computes; border edges add a plane through the edge
//! perpendicular to its triangle, weighted by the squared edge length (so the border term
//! scales like the area term and a border vertex pays for moving off its border line).
//!
//! Order: every edge (a, b) has a cost — the quadric error at the placed point — and the
//! engine repeatedly collapses the *valid* edge of least (cost, a, b). The fast path keeps
//! the candidates in an indexed heap (one entry per edge, its key changed in place). A
//! collapse of (a, b) into `s` changes the faces, the position and the quadric of `s` and
//! the faces of its neighbours N(s), and nothing else. The cost of an edge depends only on
//! its endpoints' quadrics and positions, so only the edges of `s` get a new cost. The
//! validity of an edge depends only on its endpoints' faces and their corners' positions,
//! so it can change only for edges touching {s} ∪ N(s): an edge refused when it came up
//! leaves the heap, is marked refused, and is put back when a collapse touches it. The heap
//! therefore holds, with their current cost, exactly the edges that are not known to be
//! invalid. The slow twin ([`simplify_slow`], tests) recomputes every edge's cost and
//! validity at every step and takes the least: the
//! same sequence, by the argument above (tested).
//!
//! Validity checks before each collapse ([`Checks`]): the link condition (the common
//! neighbours of a and b are exactly the far corners of the triangles on the edge, so the
//! result stays a manifold where the input was one; an inner edge between two border
//! vertices is refused, it would pinch the surface), no duplicate triangle created, no
//! triangle normal flipped against the current mesh, no triangle of (nearly) zero area, and
//! the error bound. Vertices on non-manifold edges or with non-disk fans are never moved:
//! non-manifold input is simplified where it is manifold and left alone where it is not.
//!
//! Hand-written rather than taken from a crate: the engine must expose its cost, placement
//! and checks for the later stages and keep a slow twin; meshoptimizer (the reference in the
//! tests) is a C++ library with a fixed cost.

mod edges;
mod engine;
mod guard;
mod heap;
mod pairs;
pub mod tlm;

pub use engine::{simplify_slow, Checks, Collapse, CollapseStep, Held};

use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use crate::simplify::prep::Prepared;
use serde::{Deserialize, Serialize};

/// Where the vertex of a collapsed edge goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Placement {
    /// The minimiser of the summed quadric (a 3 × 3 solve), or, when the system is
    /// ill-conditioned, the best of the two endpoints and the midpoint.
    #[default]
    Optimal,
    /// The better of the two endpoints (the output's vertices are a subset of the input's).
    Endpoint,
    /// Fold-free placement by two local mappings (Liu, Geng & Zhou 2004; see [`tlm`]): a
    /// point on a line along a direction every surviving face faces, inside the kernel of
    /// the projected link, at the least quadric error on that line.
    TwoLocalMappings,
}

impl std::fmt::Display for Placement {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Placement::Optimal => "optimal",
            Placement::Endpoint => "endpoint",
            Placement::TwoLocalMappings => "two-local-mappings",
        })
    }
}

/// How the quadric of a collapsed edge's vertex is formed from its endpoints'.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum QuadricMerge {
    /// Q = Q₁ + Q₂ (Garland & Heckbert).
    #[default]
    Sum,
    /// Q = (Q₁ + Q₂) / 2 (An's 2014 thesis on hybrid saliency).
    Mean,
}

impl std::fmt::Display for QuadricMerge {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            QuadricMerge::Sum => "sum",
            QuadricMerge::Mean => "mean",
        })
    }
}

/// The cost by which collapses are ordered (a per-vertex saliency weight,
/// [`QemParams::weights`], multiplies either).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Cost {
    /// Q(p): the area-weighted sum of squared plane distances (Garland & Heckbert). Small
    /// triangles cost little, so fine detail goes first; lowest mean error in our table.
    #[default]
    Quadric,
    /// Q(p) / W: the mean squared distance to the planes, whatever their area (as
    /// meshoptimizer orders). Lower max error on cow and armadillo, higher on bunny's holes.
    Distance,
}

/// How per-vertex saliency weights H ([`QemParams::weights`]) enter the collapse order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum WeightRule {
    /// An's thesis (eq. 4.1–4.2): C(e) = Q(e) · (H_a + H_b) / 2, and the collapsed vertex
    /// keeps that mean.
    #[default]
    Cost,
    /// Lee, Varshney & Jacobs ("Mesh Saliency", 2005): every vertex's quadric is multiplied
    /// by its H before any collapse, so the merged quadrics carry the weight of every plane
    /// they hold (a salient region keeps its weight however its vertices merge, where the
    /// mean of eq. 4.2 dilutes it with each unsalient neighbour), and the placement leans
    /// to the salient planes too.
    Quadric,
}

impl std::fmt::Display for WeightRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            WeightRule::Cost => "cost",
            WeightRule::Quadric => "quadric",
        })
    }
}

/// How the engine orders its collapses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Engine {
    /// In passes, as meshoptimizer does: each pass costs every edge once, sorts them, and
    /// collapses them in that order up to an error goal, skipping an edge whose vertex a
    /// collapse of the same pass has already moved (its cost is stale). No heap, no
    /// re-evaluation; the validity checks still run on each collapse against the mesh as
    /// it is then, so every guarantee of the heap engine holds. Faster (bunny → 10 %: about
    /// 0.6–0.8 × the heap engine's time) but its symmetric max error is within 1.2 ×
    /// meshoptimizer's on 19 of the 24 cases of the quality table against 21 (the same
    /// Metro mean wins, 22): not the default.
    Passes,
    /// Greedy: an indexed heap always collapses the valid edge of least current cost (the
    /// exact order of Garland & Heckbert; equal to the slow twin). The default: it meets
    /// the quality criteria best.
    #[default]
    Heap,
}

impl std::fmt::Display for Engine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Engine::Passes => "passes",
            Engine::Heap => "heap",
        })
    }
}

/// Parameters of a quadric edge collapse.
#[derive(Debug, Clone, PartialEq)]
pub struct QemParams {
    /// Stop at (or just below) this many triangles.
    pub triangles: u64,
    /// Accept no collapse whose error (the root mean square distance to the merged quadric's
    /// planes, [`Collapse::error`]) exceeds this, in model units.
    pub max_error: Option<f64>,
    /// Vertex placement.
    pub placement: Placement,
    /// Quadric merge rule.
    pub merge: QuadricMerge,
    /// Never move a border vertex.
    pub lock_border: bool,
    /// The order of the collapses.
    pub cost: Cost,
    /// Refuse any collapse after which a moved face would meet a face it shares no vertex
    /// with (exact predicates; placed points are rounded to f32 first).
    pub check_intersections: bool,
    /// Per-input-vertex saliency weights H in (0, 1] (An's thesis, eq. 4.1–4.2): the cost of
    /// an edge is multiplied by the mean H of its endpoints, and the collapsed vertex takes
    /// that mean. A welded vertex takes the largest H of its copies. `None`: plain QEM.
    pub weights: Option<std::sync::Arc<[f64]>>,
    /// Also contract vertex pairs that share no edge but lie closer than this, in model
    /// units (Garland & Heckbert's pair contraction: it joins separate parts); 0: off.
    pub pair_distance: f64,
    /// Collapse across UV seams and colour or normal discontinuities (their vertices then
    /// take interpolated attributes and the discontinuity is lost); false: seam vertices
    /// are never moved.
    pub collapse_seams: bool,
    /// How `weights` enter the order (the cost, as the thesis, or the quadrics).
    pub weight_rule: WeightRule,
    /// The order of the collapses: in passes or by a heap.
    pub engine: Engine,
}

impl QemParams {
    /// Plain QEM down to `triangles` with `placement`: no error bound, summed quadrics,
    /// quadric cost, border free, no intersection check, no weights, the heap engine (the
    /// exact greedy order, which its slow twin reproduces and the progressive strips
    /// replay).
    pub fn plain(triangles: u64, placement: Placement) -> QemParams {
        QemParams {
            triangles,
            max_error: None,
            placement,
            merge: QuadricMerge::Sum,
            lock_border: false,
            cost: Cost::Quadric,
            check_intersections: false,
            weights: None,
            pair_distance: 0.0,
            collapse_seams: false,
            weight_rule: WeightRule::Cost,
            engine: Engine::Heap,
        }
    }
}

/// What a quadric edge collapse did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct QemReport {
    /// The placement.
    pub placement: Placement,
    /// The quadric merge rule.
    pub quadric_merge: QuadricMerge,
    /// The triangle count aimed at.
    pub target: u64,
    /// Whether it was reached (false: no valid collapse was left before).
    pub target_reached: bool,
    /// Collapses done.
    pub collapses: usize,
    /// Candidates refused by a validity check when they came up.
    pub rejected: usize,
    /// The largest error accepted ([`Collapse::error`]), in model units.
    pub max_error: f64,
    /// Vertices left alone because the input is not a manifold there.
    pub non_manifold_vertices: usize,
}

/// A simplified mesh and what was done.
#[derive(Debug, Clone)]
pub struct QemResult {
    /// The result.
    pub mesh: TriMesh,
    /// Figures.
    pub report: QemReport,
}

/// Simplifies `mesh` by quadric edge collapse as `params` say. The mesh must be valid (see
/// [`TriMesh::validate`]) and have triangles.
pub fn simplify(mesh: &TriMesh, params: &QemParams) -> Result<QemResult> {
    check(mesh, params)?;
    let prep = Prepared::new(mesh);
    let mut c = Collapse::new(&prep, params);
    c.pairs_ok()?;
    c.run(params.triangles as usize);
    Ok(c.finish())
}

/// [`simplify`] that also returns the collapse sequence (for replaying it on strips).
pub fn simplify_logged(
    mesh: &TriMesh,
    params: &QemParams,
) -> Result<(QemResult, Vec<CollapseStep>)> {
    check(mesh, params)?;
    let prep = Prepared::new(mesh);
    let mut c = Collapse::new(&prep, params);
    c.pairs_ok()?;
    c.record = true;
    c.run(params.triangles as usize);
    let steps = std::mem::take(&mut c.steps);
    Ok((c.finish(), steps))
}

/// The checks shared by the fast path and the twin.
pub(crate) fn check(mesh: &TriMesh, params: &QemParams) -> Result<()> {
    mesh.validate("the input mesh")?;
    if mesh.triangle_count() == 0 {
        return Err(Error::Data {
            stage: "simplify",
            message: "the mesh has no triangles".into(),
        });
    }
    if params.triangles == 0 {
        return Err(Error::param(
            "simplify",
            "triangles",
            0,
            "must be at least 1",
        ));
    }
    if let Some(w) = &params.weights {
        if w.len() != mesh.vertex_count() {
            return Err(Error::param(
                "simplify",
                "weights",
                w.len(),
                "must hold one weight per input vertex",
            ));
        }
        if let Some(x) = w.iter().find(|x| !(x.is_finite() && **x > 0.0)) {
            return Err(Error::param(
                "simplify",
                "weights",
                x,
                "must be finite numbers > 0",
            ));
        }
    }
    let d = params.pair_distance;
    if !(d.is_finite() && d >= 0.0) {
        return Err(Error::param(
            "simplify",
            "pair_distance",
            d,
            "must be a number >= 0 (0: no pair contraction)",
        ));
    }
    if let Some(e) = params.max_error {
        if !(e.is_finite() && e >= 0.0) {
            return Err(Error::param(
                "simplify",
                "max_error",
                e,
                "must be a number >= 0",
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
