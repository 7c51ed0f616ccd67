//! Triangle meshes for model assets (and terrain tile meshes): the indexed [`TriMesh`], its
//! bounds, validation and cleaning; adjacency on demand ([`adjacency`]), OBJ/PLY I/O
//! ([`io`]), a BVH for closest-point queries ([`bvh`]) and the Metro-style error
//! ([`mod@hausdorff`], after Cignoni et al.'s Metro).

pub mod adjacency;
pub mod bvh;
pub mod hausdorff;
pub mod intersect;
pub mod io;
pub mod polygon;

pub use adjacency::{Adjacency, EdgeFaces, VertexFaces};
pub use bvh::Bvh;
pub use hausdorff::{hausdorff, HausdorffParams, HausdorffReport};

use crate::error::{Error, Result};
use glam::{DVec3, Vec2, Vec3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// An indexed triangle mesh: flat arrays, no per-element heap objects. Optional attributes
/// are per vertex and, when present, have one entry per position.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub indices: Vec<[u32; 3]>,
    /// Per-vertex normals.
    pub normals: Option<Vec<Vec3>>,
    /// Per-vertex colours, linear RGBA in [0, 1].
    pub colors: Option<Vec<[f32; 4]>>,
    /// Per-vertex texture coordinates.
    pub uvs: Option<Vec<Vec2>>,
}

/// An axis-aligned box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// Smallest corner.
    pub min: Vec3,
    /// Largest corner.
    pub max: Vec3,
}

impl Aabb {
    /// The box around `points`; None when there are none.
    pub fn of(points: impl IntoIterator<Item = Vec3>) -> Option<Aabb> {
        let mut it = points.into_iter();
        let first = it.next()?;
        let (min, max) = it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p)));
        Some(Aabb { min, max })
    }

    /// Edge lengths.
    pub fn size(&self) -> Vec3 {
        self.max - self.min
    }

    /// Centre point.
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Length of the diagonal (computed in f64).
    pub fn diagonal(&self) -> f64 {
        (self.max.as_dvec3() - self.min.as_dvec3()).length()
    }

    /// True when `p` lies inside or on the box.
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }
}

/// What [`TriMesh::clean`] removed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct CleanReport {
    /// Triangles with a repeated corner or zero area.
    pub degenerate: usize,
    /// Triangles over the same three vertices as an earlier one (either orientation).
    pub duplicate: usize,
    /// Vertices no triangle uses.
    pub unreferenced: usize,
}

impl TriMesh {
    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    /// Bounds of the vertices that triangles use (unreferenced vertices are not part of the
    /// surface, so they do not count); None for a mesh without triangles.
    pub fn bounds(&self) -> Option<Aabb> {
        let used = self.referenced();
        Aabb::of(
            self.positions
                .iter()
                .zip(&used)
                .filter(|(_, u)| **u)
                .map(|(p, _)| *p),
        )
    }

    /// Diagonal of [`TriMesh::bounds`] (0 for a mesh without triangles).
    pub fn diagonal(&self) -> f64 {
        self.bounds().map_or(0.0, |b| b.diagonal())
    }

    /// Which vertices at least one triangle uses.
    pub fn referenced(&self) -> Vec<bool> {
        let mut used = vec![false; self.positions.len()];
        for t in &self.indices {
            for &v in t {
                if let Some(u) = used.get_mut(v as usize) {
                    *u = true;
                }
            }
        }
        used
    }

    /// Corner positions of triangle `f` in f64.
    #[inline]
    pub fn corners(&self, f: usize) -> [DVec3; 3] {
        let [a, b, c] = self.indices[f];
        [
            self.positions[a as usize].as_dvec3(),
            self.positions[b as usize].as_dvec3(),
            self.positions[c as usize].as_dvec3(),
        ]
    }

    /// Twice the area times the unit normal of triangle `f` (the cross product of two edges).
    #[inline]
    pub fn face_cross(&self, f: usize) -> DVec3 {
        let [a, b, c] = self.corners(f);
        (b - a).cross(c - a)
    }

    /// Area of triangle `f`.
    #[inline]
    pub fn face_area(&self, f: usize) -> f64 {
        0.5 * self.face_cross(f).length()
    }

    /// Unit normal of triangle `f` (zero for a degenerate triangle).
    #[inline]
    pub fn face_normal(&self, f: usize) -> DVec3 {
        self.face_cross(f).normalize_or_zero()
    }

    /// Area of every triangle, in parallel.
    pub fn face_areas(&self) -> Vec<f64> {
        (0..self.indices.len())
            .into_par_iter()
            .map(|f| self.face_area(f))
            .collect()
    }

    /// Total surface area.
    pub fn area(&self) -> f64 {
        self.face_areas().iter().sum()
    }

    /// Area-weighted vertex normals from the triangles (zero for unreferenced vertices).
    pub fn compute_vertex_normals(&self) -> Vec<Vec3> {
        let mut acc = vec![DVec3::ZERO; self.positions.len()];
        for f in 0..self.indices.len() {
            let n = self.face_cross(f);
            for &v in &self.indices[f] {
                acc[v as usize] += n;
            }
        }
        acc.into_iter()
            .map(|n| n.normalize_or_zero().as_vec3())
            .collect()
    }

    /// Checks the invariants every stage relies on: indices in range, finite positions,
    /// attribute arrays as long as the positions. `what` names the mesh in the message.
    pub fn validate(&self, what: &str) -> Result<()> {
        let n = self.positions.len();
        let data = |message: String| Error::Data {
            stage: "mesh",
            message: format!("{what}: {message}"),
        };
        if n > u32::MAX as usize {
            return Err(data(format!(
                "{n} vertices: at most 2^32 - 1 are supported"
            )));
        }
        if let Some((i, p)) = self
            .positions
            .iter()
            .enumerate()
            .find(|(_, p)| !p.is_finite())
        {
            return Err(data(format!("vertex {i} has a non-finite coordinate {p}")));
        }
        if let Some((f, t)) = self
            .indices
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&v| v as usize >= n))
        {
            return Err(data(format!(
                "triangle {f} uses vertex {:?} but there are {n} vertices",
                t
            )));
        }
        let check = |name: &str, len: Option<usize>| match len {
            Some(l) if l != n => Err(data(format!("{l} {name} for {n} vertices"))),
            _ => Ok(()),
        };
        check("normals", self.normals.as_ref().map(Vec::len))?;
        check("colours", self.colors.as_ref().map(Vec::len))?;
        check("texture coordinates", self.uvs.as_ref().map(Vec::len))?;
        Ok(())
    }

    /// Removes degenerate triangles (a repeated corner, or zero area), duplicate triangles
    /// (the same three vertices as an earlier triangle, in either orientation; the first is
    /// kept) and unreferenced vertices. Order of what remains is kept.
    pub fn clean(&mut self) -> CleanReport {
        let mut report = CleanReport::default();
        let mut seen: FxHashMap<[u32; 3], ()> = FxHashMap::default();
        seen.reserve(self.indices.len());
        let mut keep = Vec::with_capacity(self.indices.len());
        for f in 0..self.indices.len() {
            let t = self.indices[f];
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || self.face_cross(f) == DVec3::ZERO {
                report.degenerate += 1;
                continue;
            }
            let mut key = t;
            key.sort_unstable();
            if seen.insert(key, ()).is_some() {
                report.duplicate += 1;
                continue;
            }
            keep.push(t);
        }
        self.indices = keep;
        report.unreferenced = self.remove_unreferenced();
        report
    }

    /// Drops vertices no triangle uses (renumbering the rest in order); returns how many.
    pub fn remove_unreferenced(&mut self) -> usize {
        let used = self.referenced();
        let removed = used.iter().filter(|u| !**u).count();
        if removed == 0 {
            return 0;
        }
        let mut map = vec![u32::MAX; used.len()];
        let mut next = 0u32;
        for (v, u) in used.iter().enumerate() {
            if *u {
                map[v] = next;
                next += 1;
            }
        }
        fn keep<T: Copy>(v: &[T], used: &[bool]) -> Vec<T> {
            v.iter()
                .zip(used)
                .filter(|(_, u)| **u)
                .map(|(x, _)| *x)
                .collect()
        }
        self.positions = keep(&self.positions, &used);
        self.normals = self.normals.as_deref().map(|a| keep(a, &used));
        self.colors = self.colors.as_deref().map(|a| keep(a, &used));
        self.uvs = self.uvs.as_deref().map(|a| keep(a, &used));
        for t in &mut self.indices {
            for v in t {
                *v = map[*v as usize];
            }
        }
        removed
    }

    /// For each vertex, the first vertex with a bit-identical position. Files split vertices
    /// at UV or normal seams; topology (adjacency, vertex weights) is about the surface, so
    /// the simplifiers work on these welded ids.
    pub fn weld_map(&self) -> Vec<u32> {
        let mut first: FxHashMap<[u32; 3], u32> = FxHashMap::default();
        first.reserve(self.positions.len());
        self.positions
            .iter()
            .enumerate()
            .map(|(i, p)| {
                // -0.0 and 0.0 are the same place.
                let key = [
                    (p.x + 0.0).to_bits(),
                    (p.y + 0.0).to_bits(),
                    (p.z + 0.0).to_bits(),
                ];
                *first.entry(key).or_insert(i as u32)
            })
            .collect()
    }

    /// The triangles with every index replaced by its welded id ([`TriMesh::weld_map`]).
    pub fn welded_indices(&self, weld: &[u32]) -> Vec<[u32; 3]> {
        self.indices
            .iter()
            .map(|t| t.map(|v| weld[v as usize]))
            .collect()
    }
}

/// Linear RGB(A) component from an sRGB-encoded one (files store display values).
#[inline]
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// sRGB-encoded component from a linear one.
#[inline]
pub fn linear_to_srgb(c: f32) -> f32 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.003_130_8 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad() -> TriMesh {
        TriMesh {
            positions: vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(9.0, 9.0, 9.0),
            ],
            indices: vec![[0, 1, 2], [0, 2, 3]],
            ..Default::default()
        }
    }

    #[test]
    fn bounds_ignore_unreferenced_vertices() {
        let m = quad();
        let b = m.bounds().unwrap();
        assert_eq!(b.min, Vec3::ZERO);
        assert_eq!(b.max, Vec3::new(1.0, 1.0, 0.0));
        assert!((m.diagonal() - 2f64.sqrt()).abs() < 1e-12);
        assert!((m.area() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn clean_removes_degenerate_duplicate_and_unreferenced() {
        let mut m = quad();
        m.colors = Some((0..5).map(|i| [i as f32 / 4.0, 0.0, 0.0, 1.0]).collect());
        m.indices.push([2, 1, 0]); // duplicate, flipped
        m.indices.push([0, 0, 1]); // repeated corner
        m.positions.push(Vec3::new(2.0, 0.0, 0.0));
        m.indices.push([0, 1, 5]); // collinear: zero area
        let r = m.clean();
        assert_eq!(
            r,
            CleanReport {
                degenerate: 2,
                duplicate: 1,
                unreferenced: 2
            }
        );
        assert_eq!(m.indices, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.colors.as_ref().unwrap()[3][0], 0.75);
        m.validate("quad").unwrap();
    }

    #[test]
    fn validate_names_the_problem() {
        let mut m = quad();
        m.indices.push([0, 1, 7]);
        let e = m.validate("q").unwrap_err().to_string();
        assert!(e.contains("triangle 2 uses vertex"), "{e}");
        let mut m = quad();
        m.positions[1].x = f32::NAN;
        assert!(m
            .validate("q")
            .unwrap_err()
            .to_string()
            .contains("non-finite"));
    }

    #[test]
    fn weld_joins_split_seam_vertices() {
        let mut m = quad();
        m.positions.push(Vec3::new(1.0, 0.0, 0.0));
        m.positions.push(Vec3::new(-0.0, 0.0, 0.0));
        let w = m.weld_map();
        assert_eq!(w, vec![0, 1, 2, 3, 4, 1, 0]);
    }

    #[test]
    fn srgb_round_trips_bytes() {
        for k in 0..=255u32 {
            let s = k as f32 / 255.0;
            let back = (linear_to_srgb(srgb_to_linear(s)) * 255.0).round() as u32;
            assert_eq!(back, k);
        }
    }
}
