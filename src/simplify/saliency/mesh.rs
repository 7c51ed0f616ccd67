//! Per-vertex mean curvature and the mesh saliency of Lee, Varshney and Jacobs ("Mesh
//! Saliency", 2005), on the welded surface (vertices split at UV or normal seams are one
//! point of the surface: they get one value, copied to every copy).
//!
//! Curvature: the cotangent formula (Meyer, Desbrun, Schröder and Barr, "Discrete
//! Differential-Geometry Operators for Triangulated 2-Manifolds", 2003): the mean curvature
//! normal K(v) = 1/(2 A_mixed) Σ_j (cot α_j + cot β_j)(v − v_j), |H| = |K| / 2, with the
//! mixed Voronoi area. Chosen over Taubin's tensor estimate (what Lee et al. and An's
//! thesis used) because it is the Laplace–Beltrami operator itself, converges on a sphere to
//! 1/r under refinement (tested), is exactly zero on a plane, needs no per-vertex eigen
//! decomposition, and is the estimate most libraries use (libigl, CGAL, PMP), so figures are
//! comparable. The magnitude |H| is used: the sign depends on the face orientation, which
//! real meshes do not always keep consistent, and the thesis classifies by "high curvature".
//! Border vertices (where the formula sees a half fan) take the mean of their inner
//! neighbours' values (0 when none).
//!
//! Saliency: G(σ)(v) = Σ_{|x−v| < 2σ} c(x) e^{−|x−v|²/(2σ²)} / Σ e^{…}; per scale
//! |G(σ) − G(2σ)| for σ ∈ {2, 3, 4, 5, 6}·ε, ε = 0.3 % of the bbox diagonal; each map divided
//! by its maximum, then multiplied by (1 − m̄)², m̄ the mean of its local maxima other than
//! the global one (a vertex above all its edge neighbours); summed. Neighbourhoods come from
//! a uniform grid ([`super::grid`]), one query at the largest radius (24 ε) per vertex serving
//! all eight distinct σ, vertices in parallel; the all-pairs twin is in the tests.

use super::grid::Grid;
use crate::mesh::TriMesh;
use glam::DVec3;
use rayon::prelude::*;

/// ε as a fraction of the bbox diagonal.
pub const EPSILON: f64 = 0.003;
/// The centre scales σ / ε.
pub const SCALES: [f64; 5] = [2.0, 3.0, 4.0, 5.0, 6.0];
/// Every σ / ε the Gaussians need (centre scales and their doubles), ascending.
const SIGMAS: [f64; 8] = [2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0];
/// Index into [`SIGMAS`] of 2σ for each centre scale.
const DOUBLE: [usize; 5] = [2, 4, 5, 6, 7];

/// Curvature below this over the bbox diagonal (the curvature of a sphere a thousand
/// diagonals wide) counts as flat: the f32 positions of a tilted plane give the cotangent
/// formula values around 1e-6 / diagonal, which the saliency's normalisation would
/// otherwise blow up into features.
const FLAT: f64 = 1e-3;

/// A scale map whose maximum is below this fraction of the largest curvature is numerical
/// noise of a constant curvature (a sphere: Lee's saliency is zero there) and counts as 0.
const CONSTANT: f64 = 1e-6;

/// Values closer than this fraction of a map's maximum are equal when looking for local
/// maxima.
const TIE: f64 = 1e-9;

/// The welded surface: one point per distinct referenced position.
pub(crate) struct Welded {
    /// Input vertex → welded index (`u32::MAX` for unreferenced vertices).
    pub of: Vec<u32>,
    /// Positions by welded index.
    pub pos: Vec<DVec3>,
    /// Triangles over welded indices.
    pub faces: Vec<[u32; 3]>,
}

impl Welded {
    pub(crate) fn new(mesh: &TriMesh) -> Welded {
        let weld = mesh.weld_map();
        let mut dense = vec![u32::MAX; mesh.vertex_count()];
        let mut pos = Vec::new();
        let mut faces = Vec::with_capacity(mesh.indices.len());
        for t in &mesh.indices {
            faces.push(t.map(|v| {
                let w = weld[v as usize] as usize;
                if dense[w] == u32::MAX {
                    dense[w] = pos.len() as u32;
                    pos.push(mesh.positions[w].as_dvec3());
                }
                dense[w]
            }));
        }
        let of = weld.iter().map(|&w| dense[w as usize]).collect();
        Welded { of, pos, faces }
    }

    /// Per-welded-vertex values spread back to the input's vertices (0 for unreferenced).
    pub(crate) fn spread(&self, values: &[f64]) -> Vec<f64> {
        self.of
            .iter()
            .map(|&d| {
                if d == u32::MAX {
                    0.0
                } else {
                    values[d as usize]
                }
            })
            .collect()
    }

    /// Edge neighbours of every welded vertex (sorted, deduplicated).
    pub(crate) fn neighbours(&self) -> Vec<Vec<u32>> {
        let mut nb = vec![Vec::new(); self.pos.len()];
        for t in &self.faces {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                if a != b {
                    nb[a as usize].push(b);
                    nb[b as usize].push(a);
                }
            }
        }
        nb.par_iter_mut().for_each(|n| {
            n.sort_unstable();
            n.dedup();
        });
        nb
    }
}

/// |mean curvature| per input vertex (cotangent formula; see the module).
pub fn curvature(mesh: &TriMesh) -> Vec<f64> {
    let w = Welded::new(mesh);
    w.spread(&welded_curvature(&w))
}

pub(crate) fn welded_curvature(w: &Welded) -> Vec<f64> {
    let n = w.pos.len();
    let mut k = vec![DVec3::ZERO; n];
    let mut area = vec![0.0f64; n];
    // Border detection: an edge used by one triangle.
    let mut edges: Vec<(u32, u32)> = Vec::with_capacity(3 * w.faces.len());
    for t in &w.faces {
        let p = t.map(|v| w.pos[v as usize]);
        let cross = (p[1] - p[0]).cross(p[2] - p[0]);
        let a2 = cross.length();
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || a2 == 0.0 {
            continue;
        }
        let tri_area = 0.5 * a2;
        let mut cot = [0.0f64; 3];
        let mut obtuse = None;
        for i in 0..3 {
            let (j, l) = ((i + 1) % 3, (i + 2) % 3);
            let (u, v) = (p[j] - p[i], p[l] - p[i]);
            cot[i] = u.dot(v) / a2;
            if u.dot(v) < 0.0 {
                obtuse = Some(i);
            }
        }
        for (i, &ci) in cot.iter().enumerate() {
            let (j, l) = ((i + 1) % 3, (i + 2) % 3);
            let (vj, vl) = (t[j] as usize, t[l] as usize);
            // The angle at i weighs the opposite edge (j, l).
            k[vj] += ci * (p[j] - p[l]);
            k[vl] += ci * (p[l] - p[j]);
            let (a, b) = (t[j].min(t[l]), t[j].max(t[l]));
            edges.push((a, b));
        }
        for i in 0..3 {
            let (j, l) = ((i + 1) % 3, (i + 2) % 3);
            area[t[i] as usize] += match obtuse {
                None => {
                    (p[j] - p[i]).length_squared() * cot[l] / 8.0
                        + (p[l] - p[i]).length_squared() * cot[j] / 8.0
                }
                Some(o) if o == i => tri_area / 2.0,
                Some(_) => tri_area / 4.0,
            };
        }
    }
    edges.par_sort_unstable();
    let mut border = vec![false; n];
    let mut i = 0;
    while i < edges.len() {
        let mut j = i + 1;
        while j < edges.len() && edges[j] == edges[i] {
            j += 1;
        }
        if j - i == 1 {
            border[edges[i].0 as usize] = true;
            border[edges[i].1 as usize] = true;
        }
        i = j;
    }
    let flat = FLAT / (eps(&w.pos) / EPSILON);
    let mut c: Vec<f64> = (0..n)
        .map(|v| {
            let h = k[v].length() / (4.0 * area[v]);
            if area[v] > 0.0 && !border[v] && h >= flat {
                h
            } else {
                0.0
            }
        })
        .collect();
    if border.iter().any(|&b| b) {
        let nb = w.neighbours();
        for v in 0..n {
            if border[v] {
                let inner: Vec<f64> = nb[v]
                    .iter()
                    .filter(|&&u| !border[u as usize])
                    .map(|&u| c[u as usize])
                    .collect();
                c[v] = if inner.is_empty() {
                    0.0
                } else {
                    inner.iter().sum::<f64>() / inner.len() as f64
                };
            }
        }
    }
    c
}

/// Curvature and mesh saliency per input vertex.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshSaliency {
    /// |mean curvature|, in 1 / model units.
    pub curvature: Vec<f64>,
    /// Lee et al.'s saliency (the sum of the five normalised scale maps, ≥ 0).
    pub saliency: Vec<f64>,
}

/// Curvature and mesh saliency of `mesh` (see the module).
pub fn mesh_saliency(mesh: &TriMesh) -> MeshSaliency {
    let w = Welded::new(mesh);
    let c = welded_curvature(&w);
    let g = gaussians(&w.pos, &c, eps(&w.pos));
    let s = combine(&g, &w.neighbours());
    MeshSaliency {
        curvature: w.spread(&c),
        saliency: w.spread(&s),
    }
}

/// `values` (per input vertex) averaged with Gaussian weights e^{−d²/(2σ²)} over the points
/// of the welded surface within 2σ, σ = `sigma_eps` · ε (the same neighbourhoods as Lee's
/// G(σ)); welded copies take the largest of their values first. Parallel over vertices.
pub fn smooth(mesh: &TriMesh, values: &[f64], sigma_eps: f64) -> Vec<f64> {
    let w = Welded::new(mesh);
    let mut x = vec![f64::NEG_INFINITY; w.pos.len()];
    for (v, &d) in w.of.iter().enumerate() {
        if d != u32::MAX {
            x[d as usize] = x[d as usize].max(values[v]);
        }
    }
    let sigma = sigma_eps * eps(&w.pos);
    if sigma <= 0.0 {
        return w.spread(&x);
    }
    let grid = Grid::new(&w.pos, 2.0 * sigma);
    let xs: Vec<f64> = grid.items.iter().map(|&i| x[i as usize]).collect();
    let inv = -1.0 / (2.0 * sigma * sigma);
    let sorted: Vec<f64> = grid
        .pts
        .par_iter()
        .map(|&p| {
            let (mut num, mut den) = (0.0, 0.0);
            grid.each_within(p, 2.0 * sigma, |u, d2| {
                let g = (d2 * inv).exp();
                num += g * xs[u];
                den += g;
            });
            num / den
        })
        .collect();
    let mut out = vec![0.0f64; w.pos.len()];
    for (&i, g) in grid.items.iter().zip(sorted) {
        out[i as usize] = g;
    }
    w.spread(&out)
}

/// Every vertex takes the largest of the mean `values` of the triangles around it (over
/// the welded surface; welded copies take the largest of their values first): the saliency
/// of the most salient triangle the vertex bounds. Moving a vertex moves all its triangles,
/// so a vertex must be weighted as its most salient triangle is, not by its own value alone.
pub fn face_max(mesh: &TriMesh, values: &[f64]) -> Vec<f64> {
    let w = Welded::new(mesh);
    let mut x = vec![f64::NEG_INFINITY; w.pos.len()];
    for (v, &d) in w.of.iter().enumerate() {
        if d != u32::MAX {
            x[d as usize] = x[d as usize].max(values[v]);
        }
    }
    let mut out = vec![f64::NEG_INFINITY; w.pos.len()];
    for f in &w.faces {
        let mean = f.iter().map(|&v| x[v as usize]).sum::<f64>() / 3.0;
        for &v in f {
            out[v as usize] = out[v as usize].max(mean);
        }
    }
    w.spread(&out)
}

/// ε in model units: 0.3 % of the bbox diagonal of `pos`.
pub(crate) fn eps(pos: &[DVec3]) -> f64 {
    let (lo, hi) = pos.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    );
    if pos.is_empty() {
        0.0
    } else {
        EPSILON * (hi - lo).length()
    }
}

/// G(σ) for every σ of [`SIGMAS`], per vertex: `out[v][s]`.
///
/// Two exponentials per pair of points instead of one per σ: with e = exp(−d²/(2(12ε)²))
/// and b = exp(−d²/(2(40ε)²)), the Gaussians of σ = 12, 6, 4, 3, 2 ε are e, e⁴, e⁹, e¹⁶, e³⁶
/// and those of σ = 10, 8, 5 ε are b¹⁶, b²⁵, b⁶⁴, by repeated squaring (a relative error
/// of at most ~64 ulp, far below what the twin test allows).
pub(crate) fn gaussians(pos: &[DVec3], c: &[f64], eps: f64) -> Vec<[f64; 8]> {
    if eps <= 0.0 {
        // A single point (no extent): every average is the value itself.
        return c.iter().map(|&x| [x; 8]).collect();
    }
    let radius = 2.0 * SIGMAS[7] * eps;
    let grid = Grid::new(pos, radius);
    let cs: Vec<f64> = grid.items.iter().map(|&i| c[i as usize]).collect();
    let cut: [f64; 8] = SIGMAS.map(|s| (2.0 * s * eps).powi(2));
    let inv_e = -1.0 / (2.0 * (12.0 * eps).powi(2));
    let inv_b = -1.0 / (2.0 * (40.0 * eps).powi(2));
    let sorted: Vec<[f64; 8]> = grid
        .pts
        .par_iter()
        .map(|&p| {
            let mut num = [0.0f64; 8];
            let mut den = [0.0f64; 8];
            let mut add = |s: usize, g: f64, cu: f64| {
                num[s] += g * cu;
                den[s] += g;
            };
            grid.each_within(p, radius, |u, d2| {
                let cu = cs[u];
                let e = (d2 * inv_e).exp();
                add(7, e, cu);
                if d2 >= cut[6] {
                    return;
                }
                let b = (d2 * inv_b).exp();
                let b8 = b.powi(2).powi(2).powi(2);
                let b16 = b8 * b8;
                add(6, b16, cu);
                if d2 >= cut[5] {
                    return;
                }
                add(5, b16 * b8 * b, cu);
                if d2 >= cut[4] {
                    return;
                }
                let e4 = e.powi(2).powi(2);
                add(4, e4, cu);
                if d2 >= cut[3] {
                    return;
                }
                add(3, b16.powi(2).powi(2), cu);
                if d2 >= cut[2] {
                    return;
                }
                let e8 = e4 * e4;
                add(2, e8 * e, cu);
                if d2 >= cut[1] {
                    return;
                }
                let e16 = e8 * e8;
                add(1, e16, cu);
                if d2 >= cut[0] {
                    return;
                }
                add(0, e16 * e16 * e4, cu);
            });
            std::array::from_fn(|s| if den[s] > 0.0 { num[s] / den[s] } else { 0.0 })
        })
        .collect();
    let mut out = vec![[0.0f64; 8]; pos.len()];
    for (&i, g) in grid.items.iter().zip(sorted) {
        out[i as usize] = g;
    }
    out
}

/// Lee's combination of the per-vertex Gaussians: per centre scale |G(σ) − G(2σ)|,
/// normalised by its maximum, weighted by (1 − m̄)², summed.
pub(crate) fn combine(g: &[[f64; 8]], neighbours: &[Vec<u32>]) -> Vec<f64> {
    let mut total = vec![0.0f64; g.len()];
    let scale = g.iter().fold(0.0f64, |a, x| a.max(x[0].abs()));
    for (i, &d) in DOUBLE.iter().enumerate() {
        let m: Vec<f64> = g.iter().map(|x| (x[i] - x[d]).abs()).collect();
        let (mut top, mut arg) = (0.0f64, usize::MAX);
        for (v, &x) in m.iter().enumerate() {
            if x > top {
                (top, arg) = (x, v);
            }
        }
        if top <= CONSTANT * scale {
            continue;
        }
        // Local maxima other than the global one: above every edge neighbour by more than
        // rounding (a plateau has none; ties must not depend on the summation order).
        let tie = TIE * top;
        let (mut sum, mut count) = (0.0, 0usize);
        for (v, &x) in m.iter().enumerate() {
            if v != arg
                && !neighbours[v].is_empty()
                && neighbours[v].iter().all(|&u| m[u as usize] + tie < x)
            {
                sum += x / top;
                count += 1;
            }
        }
        let mean = if count > 0 { sum / count as f64 } else { 0.0 };
        let f = (1.0 - mean).powi(2) / top;
        for (t, &x) in total.iter_mut().zip(&m) {
            *t += x * f;
        }
    }
    total
}

#[cfg(test)]
mod tests;
