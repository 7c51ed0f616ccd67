//! Multi-view image saliency (An's thesis, §3.4.1): the mesh rendered by [`super::render`]
//! from cameras on a sphere of radius 1.4 × the bbox diagonal around the bbox centre, at
//! α = 2πk₁/N, β = 2πk₂/N (x = sin α cos β, y = sin α sin β, z = cos α; positions that
//! coincide, like the N poles, are kept once); the Itti–Koch saliency ([`super::itti`]) of
//! each view; each vertex takes the value under it in a view where it is visible and 0 in
//! the others; per vertex the max, min and mean over all views. Views are independent:
//! they are rendered and filtered in parallel, and the per-vertex sums are fixed-point
//! integers, so the result is the same bits for any thread count.
//!
//! Visibility: a vertex is visible when its depth is within two pixel footprints (at its
//! depth) of the depth buffer under it: the buffer holds the nearest surface at the pixel
//! centre, up to half a pixel away from the vertex, so on a slope it is nearer than the
//! vertex by up to that slope times the footprint.

use super::itti;
use super::render::{render, shade, Camera};
use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use glam::DVec3;
use rayon::prelude::*;

/// The camera sphere's radius in bbox diagonals.
pub const RADIUS: f64 = 1.4;
/// The grey of meshes without colours (linear).
pub const GREY: [f32; 3] = [0.7, 0.7, 0.7];
/// Smallest and largest image side.
pub const SIZE_RANGE: (u32, u32) = (16, 4096);
/// Fixed-point scale of the per-vertex sums.
const FIXED: f64 = (1u64 << 32) as f64;

/// Parameters of the multi-view image saliency.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ViewParams {
    /// N: angles 2πk/N in both directions (≥ 2).
    pub views: u32,
    /// Image side in pixels, in [16, 4096].
    pub size: u32,
}

impl Default for ViewParams {
    fn default() -> ViewParams {
        ViewParams {
            views: 36,
            size: 256,
        }
    }
}

impl ViewParams {
    /// Refuses N < 2 and sizes outside [16, 4096].
    pub fn validate(&self) -> Result<()> {
        if self.views < 2 {
            return Err(Error::param(
                "saliency",
                "views",
                self.views,
                "must be at least 2",
            ));
        }
        if !(SIZE_RANGE.0..=SIZE_RANGE.1).contains(&self.size) {
            return Err(Error::param(
                "saliency",
                "view_size",
                self.size,
                "must be between 16 and 4096 pixels",
            ));
        }
        Ok(())
    }
}

/// Per-vertex image saliency over all views, in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct ImageSaliency {
    /// The largest value over the views.
    pub max: Vec<f64>,
    /// The smallest (0 unless the vertex is visible in every view).
    pub min: Vec<f64>,
    /// The mean over all views.
    pub mean: Vec<f64>,
    /// The number of distinct views rendered.
    pub views: usize,
}

/// The camera positions: N × N angle pairs, coinciding positions dropped (first kept).
pub fn eyes(centre: DVec3, radius: f64, n: u32) -> Vec<DVec3> {
    let mut seen = rustc_hash::FxHashSet::default();
    let mut out = Vec::new();
    let step = 2.0 * std::f64::consts::PI / n as f64;
    for i in 0..n {
        for j in 0..n {
            let (a, b) = (step * i as f64, step * j as f64);
            let d = DVec3::new(a.sin() * b.cos(), a.sin() * b.sin(), a.cos());
            // Positions equal up to rounding are one: compare on a 1e-9 lattice.
            let key = (d * 1e9).round().as_i64vec3().to_array();
            if seen.insert(key) {
                out.push(centre + radius * d);
            }
        }
    }
    out
}

/// The cameras of the multi-view saliency for `mesh`.
pub fn cameras(mesh: &TriMesh, p: &ViewParams) -> Vec<Camera> {
    let b = mesh.bounds().expect("a mesh with triangles has bounds");
    let (centre, diag) = (b.center().as_dvec3(), b.diagonal());
    // The bbox fits in a sphere of radius diag / 2: a field of view that holds it.
    let fov = 2.0 * (0.5 / RADIUS).asin() * 1.05;
    eyes(centre, RADIUS * diag, p.views)
        .into_iter()
        .map(|e| Camera::look_at(e, centre, fov, p.size as usize))
        .collect()
}

/// The base colours: the mesh's vertex colours or grey.
pub fn base_colors(mesh: &TriMesh) -> Vec<[f32; 3]> {
    match &mesh.colors {
        Some(c) => c.iter().map(|c| [c[0], c[1], c[2]]).collect(),
        None => vec![GREY; mesh.vertex_count()],
    }
}

/// The multi-view image saliency of `mesh` (which must have triangles and a non-zero
/// bbox diagonal).
pub fn image_saliency(mesh: &TriMesh, p: &ViewParams) -> Result<ImageSaliency> {
    p.validate()?;
    let cams = cameras(mesh, p);
    let normals = mesh
        .normals
        .clone()
        .unwrap_or_else(|| mesh.compute_vertex_normals());
    let base = base_colors(mesh);
    let nv = mesh.vertex_count();
    let referenced = mesh.referenced();
    let zero = || (vec![0u64; nv], vec![0.0f32; nv], vec![f32::INFINITY; nv]);
    let (sum, max, min) = cams
        .par_iter()
        .fold(zero, |(mut sum, mut max, mut min), cam| {
            let v = view(mesh, &normals, &base, cam, &referenced);
            for i in 0..nv {
                let x = v[i];
                sum[i] += (x as f64 * FIXED) as u64;
                max[i] = max[i].max(x);
                min[i] = min[i].min(x);
            }
            (sum, max, min)
        })
        .reduce(zero, |mut a, b| {
            for i in 0..nv {
                a.0[i] += b.0[i];
                a.1[i] = a.1[i].max(b.1[i]);
                a.2[i] = a.2[i].min(b.2[i]);
            }
            a
        });
    let k = cams.len() as f64;
    Ok(ImageSaliency {
        max: max.iter().map(|&x| x as f64).collect(),
        min: min
            .iter()
            .map(|&x| if x.is_finite() { x as f64 } else { 0.0 })
            .collect(),
        mean: sum.iter().map(|&s| s as f64 / FIXED / k).collect(),
        views: cams.len(),
    })
}

/// One view: per vertex the saliency under it where visible, else 0.
pub fn view(
    mesh: &TriMesh,
    normals: &[glam::Vec3],
    base: &[[f32; 3]],
    cam: &Camera,
    referenced: &[bool],
) -> Vec<f32> {
    let colors = shade(normals, base, cam);
    let frame = render(mesh, &colors, cam);
    let map = itti::saliency(&frame.rgb, cam.size as u32);
    let n = cam.size;
    // One pixel's footprint per unit depth.
    let footprint = 1.0 / cam.focal;
    mesh.positions
        .iter()
        .zip(referenced)
        .map(|(p, &used)| {
            let Some((x, y, z)) = cam.project(p.as_dvec3()).filter(|_| used) else {
                return 0.0;
            };
            if !(x >= 0.0 && y >= 0.0 && x < n as f64 && y < n as f64) {
                return 0.0;
            }
            let d = frame.depth[y as usize * n + x as usize];
            if z <= d + 2.0 * footprint * z {
                map.at(x / n as f64, y / n as f64)
            } else {
                0.0
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simplify::test_meshes::icosphere;

    #[test]
    fn duplicate_camera_positions_are_dropped() {
        // N = 4: α ∈ {0, 90°, 180°, 270°}: the two poles once each, the equator's 4 points
        // (α = 270° repeats α = 90° at β + 180°).
        assert_eq!(eyes(DVec3::ZERO, 1.0, 4).len(), 6);
        assert_eq!(eyes(DVec3::ZERO, 1.0, 2).len(), 2);
        // N = 36: 17 rings of 36 and the two poles.
        assert_eq!(eyes(DVec3::ZERO, 1.0, 36).len(), 17 * 36 + 2);
    }

    #[test]
    fn the_same_bits_for_any_thread_count() {
        let m = icosphere(3, 1.0);
        let p = ViewParams { views: 6, size: 64 };
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| image_saliency(&m, &p).unwrap());
        let two = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap()
            .install(|| image_saliency(&m, &p).unwrap());
        assert_eq!(one, two);
    }

    #[test]
    fn a_vertex_hidden_from_every_view_gets_zero() {
        // A small sphere inside a big one: the inner one is never visible.
        let outer = icosphere(3, 1.0);
        let inner = icosphere(1, 0.3);
        let mut m = outer.clone();
        let base = m.positions.len() as u32;
        m.positions.extend(&inner.positions);
        m.indices
            .extend(inner.indices.iter().map(|t| t.map(|v| v + base)));
        // A red patch on the outer sphere makes some saliency.
        let mut colors = vec![[0.7, 0.7, 0.7, 1.0]; m.vertex_count()];
        for (c, p) in colors.iter_mut().zip(&m.positions) {
            if p.z > 0.8 {
                *c = [0.9, 0.1, 0.1, 1.0];
            }
        }
        m.colors = Some(colors);
        let s = image_saliency(&m, &ViewParams { views: 8, size: 64 }).unwrap();
        assert!(s.max[base as usize..].iter().all(|&x| x == 0.0));
        assert!(s.max[..base as usize].iter().any(|&x| x > 0.0));
        for i in 0..m.vertex_count() {
            assert!(s.min[i] <= s.mean[i] + 1e-9 && s.mean[i] <= s.max[i] + 1e-9);
        }
    }

    #[test]
    fn bad_parameters_are_refused() {
        for (views, size) in [(1, 256), (0, 256), (36, 15), (36, 4097)] {
            assert!(ViewParams { views, size }.validate().is_err());
        }
        assert!(ViewParams { views: 2, size: 16 }.validate().is_ok());
    }
}
