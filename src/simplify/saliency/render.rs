//! A small software rasteriser for the multi-view image saliency and the pictures: one
//! perspective camera, a depth buffer, Gouraud-shaded vertex colours lit by one directional
//! light, every triangle two-sided. Hand-written: the Rust rasterisers on crates.io are
//! either GPU front ends (wgpu and friends, which need a device the CI machine does not
//! have) or toy crates; what is needed here is ~150 lines, deterministic to the bit, and
//! must report which pixels a depth test lets through.
//!
//! The cameras of the saliency look at the bbox centre from 1.4 diagonals away, so every
//! point is at least 0.9 diagonals in front of the eye: no near-plane clipping is needed,
//! and [`Camera::project`] refuses (skips) triangles with a corner behind the eye.

use crate::mesh::TriMesh;
use glam::DVec3;

/// A perspective camera looking at `target` with a square image of `size` pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// The eye.
    pub eye: DVec3,
    /// Right, up and forward unit vectors.
    pub right: DVec3,
    /// Up.
    pub up: DVec3,
    /// Forward (from the eye to the target).
    pub forward: DVec3,
    /// Image side in pixels.
    pub size: usize,
    /// Focal length in pixels.
    pub focal: f64,
}

impl Camera {
    /// A camera at `eye` looking at `target` with vertical field of view `fov` (radians);
    /// `up` is the world's z axis unless the view is along it (then y).
    pub fn look_at(eye: DVec3, target: DVec3, fov: f64, size: usize) -> Camera {
        let forward = (target - eye).normalize();
        let world_up = if forward.cross(DVec3::Z).length() > 1e-6 {
            DVec3::Z
        } else {
            DVec3::Y
        };
        let right = forward.cross(world_up).normalize();
        let up = right.cross(forward);
        Camera {
            eye,
            right,
            up,
            forward,
            size,
            focal: 0.5 * size as f64 / (0.5 * fov).tan(),
        }
    }

    /// Screen position (pixels, y down) and depth along the view axis of `p`; `None`
    /// behind the eye.
    #[inline]
    pub fn project(&self, p: DVec3) -> Option<(f64, f64, f64)> {
        let d = p - self.eye;
        let z = d.dot(self.forward);
        if z <= 0.0 {
            return None;
        }
        let h = 0.5 * self.size as f64;
        Some((
            h + self.focal * d.dot(self.right) / z,
            h - self.focal * d.dot(self.up) / z,
            z,
        ))
    }

    /// The unit direction of the ray through pixel centre (x + ½, y + ½).
    pub fn ray(&self, x: usize, y: usize) -> DVec3 {
        let h = 0.5 * self.size as f64;
        let sx = (x as f64 + 0.5 - h) / self.focal;
        let sy = (h - (y as f64 + 0.5)) / self.focal;
        (self.forward + sx * self.right + sy * self.up).normalize()
    }
}

/// A rendered image: colour, depth along the view axis (∞ where nothing is), and the
/// triangle seen, row-major from the top-left.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Image side.
    pub size: usize,
    /// Linear RGB in [0, 1].
    pub rgb: Vec<[f32; 3]>,
    /// Depth along the view axis.
    pub depth: Vec<f64>,
    /// The triangle seen (`u32::MAX`: background).
    pub triangle: Vec<u32>,
}

/// The background colour (a mid grey, so that the silhouette is an edge of moderate
/// contrast whatever the model's colour).
pub const BACKGROUND: [f32; 3] = [0.5, 0.5, 0.5];
/// Ambient share of the lighting.
const AMBIENT: f32 = 0.25;

/// The light direction (towards the light) for `cam`: fixed in the camera's frame, from the
/// viewer's upper left, so that every view is lit as a viewer would light it.
pub fn light(cam: &Camera) -> DVec3 {
    (-cam.forward + 0.5 * cam.up - 0.5 * cam.right).normalize()
}

/// Per-vertex shaded colours for `cam`: `base` × (ambient + diffuse |n · l|).
pub fn shade(normals: &[glam::Vec3], base: &[[f32; 3]], cam: &Camera) -> Vec<[f32; 3]> {
    let l = light(cam).as_vec3();
    normals
        .iter()
        .zip(base)
        .map(|(n, c)| {
            let k = AMBIENT + (1.0 - AMBIENT) * n.dot(l).abs();
            c.map(|x| x * k)
        })
        .collect()
}

/// Renders `mesh` with per-vertex (already shaded) `colors` through `cam`.
pub fn render(mesh: &TriMesh, colors: &[[f32; 3]], cam: &Camera) -> Frame {
    let n = cam.size;
    let mut f = Frame {
        size: n,
        rgb: vec![BACKGROUND; n * n],
        depth: vec![f64::INFINITY; n * n],
        triangle: vec![u32::MAX; n * n],
    };
    let proj: Vec<Option<(f64, f64, f64)>> = mesh
        .positions
        .iter()
        .map(|p| cam.project(p.as_dvec3()))
        .collect();
    for (t, tri) in mesh.indices.iter().enumerate() {
        let [Some(a), Some(b), Some(c)] = tri.map(|v| proj[v as usize]) else {
            continue;
        };
        let area = edge(a, b, c.0, c.1);
        if area == 0.0 || !area.is_finite() {
            continue;
        }
        let (x0, x1) = (a.0.min(b.0).min(c.0), a.0.max(b.0).max(c.0));
        let (y0, y1) = (a.1.min(b.1).min(c.1), a.1.max(b.1).max(c.1));
        if x1 < 0.0 || y1 < 0.0 || x0 >= n as f64 || y0 >= n as f64 {
            continue;
        }
        // Pixel centres (i + ½) in [x0, x1].
        let lo = |v: f64| (v - 0.5).ceil().max(0.0) as usize;
        let hi = |v: f64| ((v - 0.5).floor() as i64).min(n as i64 - 1);
        let (ix0, iy0, ix1, iy1) = (lo(x0), lo(y0), hi(x1), hi(y1));
        let cols = tri.map(|v| colors[v as usize]);
        let inv_z = [1.0 / a.2, 1.0 / b.2, 1.0 / c.2];
        for y in iy0 as i64..=iy1 {
            let py = y as f64 + 0.5;
            for x in ix0 as i64..=ix1 {
                let px = x as f64 + 0.5;
                let w =
                    [edge(b, c, px, py), edge(c, a, px, py), edge(a, b, px, py)].map(|w| w / area);
                if w.iter().any(|&w| w < 0.0) {
                    continue;
                }
                // Perspective-correct: 1/z is linear in screen space.
                let iz = w[0] * inv_z[0] + w[1] * inv_z[1] + w[2] * inv_z[2];
                let z = 1.0 / iz;
                let i = y as usize * n + x as usize;
                if z < f.depth[i] {
                    f.depth[i] = z;
                    f.triangle[i] = t as u32;
                    let k = [0, 1, 2].map(|j| (w[j] * inv_z[j] * z) as f32);
                    f.rgb[i] = std::array::from_fn(|ch| {
                        k[0] * cols[0][ch] + k[1] * cols[1][ch] + k[2] * cols[2][ch]
                    });
                }
            }
        }
    }
    f
}

/// Twice the signed area of (a, b, (x, y)) in screen space.
#[inline]
fn edge(a: (f64, f64, f64), b: (f64, f64, f64), x: f64, y: f64) -> f64 {
    (b.0 - a.0) * (y - a.1) - (b.1 - a.1) * (x - a.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use glam::Vec3;

    /// The brute-force twin: one ray per pixel centre against every triangle (Möller and
    /// Trumbore), the nearest hit's depth along the view axis.
    fn ray_cast(mesh: &TriMesh, cam: &Camera) -> Vec<f64> {
        let n = cam.size;
        let mut out = vec![f64::INFINITY; n * n];
        for y in 0..n {
            for x in 0..n {
                let d = cam.ray(x, y);
                for t in 0..mesh.triangle_count() {
                    let [p0, p1, p2] = mesh.corners(t);
                    let (e1, e2) = (p1 - p0, p2 - p0);
                    let h = d.cross(e2);
                    let det = e1.dot(h);
                    if det.abs() < 1e-14 {
                        continue;
                    }
                    let s = cam.eye - p0;
                    let u = s.dot(h) / det;
                    let q = s.cross(e1);
                    let v = d.dot(q) / det;
                    let tt = e2.dot(q) / det;
                    if u >= 0.0 && v >= 0.0 && u + v <= 1.0 && tt > 0.0 {
                        let z = tt * d.dot(cam.forward);
                        out[y * n + x] = out[y * n + x].min(z);
                    }
                }
            }
        }
        out
    }

    #[test]
    fn depth_and_coverage_equal_a_ray_cast() {
        let mut rng = SplitMix64::new(7);
        let mut total = 0;
        let mut differ = 0;
        for scene in 0..6 {
            // Random overlapping triangles in the unit cube.
            let mut m = TriMesh::default();
            for _ in 0..12 {
                let base = m.positions.len() as u32;
                let c = Vec3::new(rng.unit() as f32, rng.unit() as f32, rng.unit() as f32);
                for _ in 0..3 {
                    let d =
                        Vec3::new(rng.unit() as f32, rng.unit() as f32, rng.unit() as f32) - 0.5;
                    m.positions.push(c + 0.6 * d);
                }
                m.indices.push([base, base + 1, base + 2]);
            }
            let eye = DVec3::new(0.5, 0.5, 0.5)
                + 2.0 * DVec3::new(1.0, 0.3 + scene as f64 * 0.2, 0.7).normalize();
            let cam = Camera::look_at(eye, DVec3::splat(0.5), 0.9, 48);
            let white = vec![[1.0; 3]; m.vertex_count()];
            let f = render(&m, &white, &cam);
            let r = ray_cast(&m, &cam);
            for (a, b) in f.depth.iter().zip(&r) {
                total += 1;
                if a.is_finite() != b.is_finite() {
                    differ += 1;
                } else if a.is_finite() && (a - b).abs() > 1e-4 * b {
                    // A pixel centre on a shared edge or a crossing line may take either.
                    differ += 1;
                }
            }
        }
        // Only pixels whose centre lies on an edge may disagree.
        assert!(differ * 200 < total, "{differ} of {total}");
    }
}
