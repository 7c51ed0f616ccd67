//! Triangle meshes for model assets (and terrain tile meshes): the indexed [`TriMesh`].

use glam::{Vec2, Vec3};

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

impl TriMesh {
    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }
}
