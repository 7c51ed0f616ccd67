//! glTF 2.0 binary (.glb) for a [`TriMesh`]: one scene, one node, one mesh, one triangle
//! primitive with POSITION, NORMAL (when present) and u32 indices in one buffer.
//!
//! Written by hand rather than through `gltf-json`: the document is five fixed objects, and
//! the container is two length-prefixed chunks; `serde_json` (already a dependency) writes the
//! JSON. The tests read every file back with the `gltf` crate, which validates it.
//!
//! glTF is y-up: terratile's x east, y north, z up become glTF (x, z, −y), a rotation, so the
//! counter-clockwise winding is kept. glTF's unit is the metre: positions are scaled by the
//! CRS's metres per unit (Oregon Lambert in international feet: × 0.3048).

use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use serde_json::json;

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;

/// `mesh` (z up, in units of `metres_per_unit` metres) as a .glb file named `name` inside,
/// positions in metres.
pub fn glb_bytes(mesh: &TriMesh, name: &str, metres_per_unit: f64) -> Result<Vec<u8>> {
    let list: Vec<u32> = mesh.indices.iter().flatten().copied().collect();
    glb_primitive(mesh, &list, TRIANGLES, name, metres_per_unit)
}

/// glTF's primitive mode for a triangle list.
pub const TRIANGLES: u32 = 4;
/// glTF's primitive mode for a triangle strip (no restart index: glTF forbids the maximum
/// index value, so strips are joined by repeated indices).
pub const TRIANGLE_STRIP: u32 = 5;

/// [`glb_bytes`] with the primitive's `indices` and `mode` given ([`TRIANGLES`] or
/// [`TRIANGLE_STRIP`]); `mesh.indices` is not used.
pub fn glb_primitive(
    mesh: &TriMesh,
    indices: &[u32],
    mode: u32,
    name: &str,
    metres_per_unit: f64,
) -> Result<Vec<u8>> {
    let n = mesh.positions.len();
    if indices.contains(&u32::MAX) {
        return Err(Error::Internal(format!(
            "glb: mesh `{name}` has a restart index, which glTF forbids"
        )));
    }
    if n == 0 || indices.is_empty() {
        return Err(Error::Internal(format!("glb: mesh `{name}` is empty")));
    }
    let y_up = |v: glam::Vec3| [v.x, v.z, -v.y];
    let m = metres_per_unit as f32;
    let mut bin: Vec<u8> = Vec::with_capacity(n * 24 + indices.len() * 4);
    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    for p in &mesh.positions {
        let q = y_up(*p * m);
        for k in 0..3 {
            min[k] = min[k].min(q[k]);
            max[k] = max[k].max(q[k]);
            bin.extend_from_slice(&q[k].to_le_bytes());
        }
    }
    let positions_len = bin.len();
    let mut views = vec![
        json!({"buffer": 0, "byteOffset": 0, "byteLength": positions_len, "target": ARRAY_BUFFER}),
    ];
    let mut accessors = vec![json!({
        "bufferView": 0, "componentType": FLOAT, "count": n, "type": "VEC3",
        "min": min, "max": max,
    })];
    let mut attributes = serde_json::Map::new();
    attributes.insert("POSITION".into(), json!(0));
    if let Some(normals) = &mesh.normals {
        let start = bin.len();
        for v in normals {
            for c in y_up(*v) {
                bin.extend_from_slice(&c.to_le_bytes());
            }
        }
        views.push(json!({"buffer": 0, "byteOffset": start, "byteLength": bin.len() - start, "target": ARRAY_BUFFER}));
        accessors.push(json!({"bufferView": views.len() - 1, "componentType": FLOAT, "count": n, "type": "VEC3"}));
        attributes.insert("NORMAL".into(), json!(accessors.len() - 1));
    }
    let start = bin.len();
    for i in indices {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    views.push(json!({"buffer": 0, "byteOffset": start, "byteLength": bin.len() - start, "target": ELEMENT_ARRAY_BUFFER}));
    accessors.push(json!({
        "bufferView": views.len() - 1, "componentType": UNSIGNED_INT,
        "count": indices.len(), "type": "SCALAR",
    }));
    let index_accessor = accessors.len() - 1;
    let doc = json!({
        "asset": {"version": "2.0", "generator": concat!("terratile ", env!("CARGO_PKG_VERSION"))},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": name}],
        "meshes": [{"name": name, "primitives": [{"attributes": attributes, "indices": index_accessor, "mode": mode}]}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    let text = serde_json::to_vec(&doc).map_err(|e| Error::Internal(e.to_string()))?;
    Ok(glb_container(&text, &bin))
}

/// The .glb container: the 12-byte header, then the JSON chunk (padded with spaces) and the
/// binary chunk (padded with zeros), each to 4 bytes.
pub fn glb_container(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |len: usize| len.next_multiple_of(4) - len;
    let (json_len, bin_len) = (json.len() + pad(json.len()), bin.len() + pad(bin.len()));
    let total = 12 + 8 + json_len + 8 + bin_len;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json_len as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(json);
    out.resize(out.len() + pad(json.len()), b' ');
    out.extend_from_slice(&(bin_len as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(bin);
    out.resize(out.len() + pad(bin.len()), 0);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn a_quad_reads_back_through_the_gltf_crate() {
        let mesh = crate::testing::quad();
        let bytes = glb_bytes(&mesh, "tile_000_000", 1.0).unwrap();
        assert_eq!(bytes.len() % 4, 0);
        let g = gltf::Gltf::from_slice(&bytes).unwrap();
        let blob = g.blob.as_deref().unwrap();
        let m = g.meshes().next().unwrap();
        let p = m.primitives().next().unwrap();
        let reader = p.reader(|_| Some(blob));
        let pos: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
        assert_eq!(pos[1], [2.0, 1.5, 0.0]);
        assert_eq!(pos[2], [2.0, 1.0, -3.0]);
        let nor: Vec<[f32; 3]> = reader.read_normals().unwrap().collect();
        assert_eq!(nor[0], [0.0, 1.0, 0.0]);
        let idx: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
        assert_eq!(idx, vec![0, 1, 2, 0, 2, 3]);
        // Counter-clockwise seen from +y (up) in glTF.
        let [a, b, c] = [pos[0], pos[1], pos[2]].map(Vec3::from);
        assert!((b - a).cross(c - a).y > 0.0);
    }
}
