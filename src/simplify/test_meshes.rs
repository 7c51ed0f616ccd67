//! Small meshes the simplifiers' unit tests share (clustering and the collapse engine alike).

use crate::mesh::TriMesh;
use glam::Vec3;

/// A bumpy open grid of n × n quads (two triangles each) over the unit square.
pub(crate) fn grid(n: usize) -> TriMesh {
    let mut m = TriMesh::default();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f32 / n as f32, j as f32 / n as f32);
            m.positions
                .push(Vec3::new(x, y, 0.1 * (6.0 * x).sin() * (4.0 * y).cos()));
        }
    }
    let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    for j in 0..n {
        for i in 0..n {
            m.indices.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            m.indices.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    m
}
