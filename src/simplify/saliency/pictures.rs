//! Pictures of the per-vertex maps: a PLY with a float vertex property per map (and vertex
//! colours of the hybrid for viewers), and PNG renderings, front and back, coloured by a
//! map, with a colour bar (An's thesis, Fig. 3.8 and 3.9).

use super::render::{render, Camera};
use super::Maps;
use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use glam::DVec3;
use std::path::Path;

/// The maps' names, as the PLY properties and PNG files are named.
pub const NAMES: [&str; 6] = [
    "curvature",
    "mesh_saliency",
    "image_max",
    "image_min",
    "image_mean",
    "hybrid",
];

/// The maps in [`NAMES`] order.
pub fn columns(m: &Maps) -> [&[f64]; 6] {
    [
        &m.curvature,
        &m.mesh_saliency,
        &m.image.max,
        &m.image.min,
        &m.image.mean,
        &m.hybrid,
    ]
}

/// A blue → cyan → green → yellow → red ramp of `t` in [0, 1] (linear RGB).
pub fn ramp(t: f64) -> [f32; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [0.02, 0.05, 0.6],
        [0.0, 0.6, 0.8],
        [0.1, 0.75, 0.1],
        [0.95, 0.85, 0.05],
        [0.85, 0.05, 0.02],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    } * 4.0;
    let i = (t.floor() as usize).min(3);
    let f = (t - i as f64) as f32;
    std::array::from_fn(|c| STOPS[i][c] + (STOPS[i + 1][c] - STOPS[i][c]) * f)
}

/// `values` scaled to [0, 1] by their 99th percentile (a few extreme curvatures would
/// otherwise paint everything blue).
pub fn scaled(values: &[f64]) -> Vec<f64> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    let top = v
        .get(((v.len() as f64 - 1.0) * 0.99) as usize)
        .copied()
        .unwrap_or(0.0);
    values
        .iter()
        .map(|&x| if top > 0.0 { (x / top).min(1.0) } else { 0.0 })
        .collect()
}

/// Binary little-endian PLY: positions, uchar colours of the hybrid, one float per map.
pub fn write_ply(mesh: &TriMesh, maps: &Maps, out: &Path) -> Result<()> {
    let mut head = format!(
        "ply\nformat binary_little_endian 1.0\ncomment terratile saliency\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n",
        mesh.vertex_count()
    );
    for n in NAMES {
        head.push_str(&format!("property float {n}\n"));
    }
    head.push_str(&format!(
        "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.triangle_count()
    ));
    let mut buf = head.into_bytes();
    let cols = columns(maps);
    for (v, p) in mesh.positions.iter().enumerate() {
        for x in p.to_array() {
            buf.extend(x.to_le_bytes());
        }
        let c = ramp(maps.hybrid[v]);
        buf.extend(c.map(|x| (crate::mesh::linear_to_srgb(x) * 255.0).round() as u8));
        for col in cols {
            buf.extend((col[v] as f32).to_le_bytes());
        }
    }
    for t in &mesh.indices {
        buf.push(3);
        for &i in t {
            buf.extend((i as i32).to_le_bytes());
        }
    }
    crate::fsutil::write_bytes_atomic(out, &buf)
}

/// Renders `mesh` coloured by `values` (scaled by [`scaled`]) from the front (+z) and the
/// back (−z), side by side, with a colour bar on the right; `size` pixels per view.
pub fn write_png(mesh: &TriMesh, values: &[f64], size: usize, out: &Path) -> Result<()> {
    let s = scaled(values);
    let colors: Vec<[f32; 3]> = s.iter().map(|&x| ramp(x)).collect();
    let b = mesh.bounds().expect("a mesh with triangles has bounds");
    let (centre, diag) = (b.center().as_dvec3(), b.diagonal());
    let fov = 2.0 * (0.5 / super::image::RADIUS).asin() * 1.05;
    let normals = mesh
        .normals
        .clone()
        .unwrap_or_else(|| mesh.compute_vertex_normals());
    let bar = size / 12;
    let width = 2 * size + bar;
    let mut img = image::RgbImage::from_pixel(width as u32, size as u32, image::Rgb([255; 3]));
    for (k, dir) in [DVec3::Z, -DVec3::Z].into_iter().enumerate() {
        let cam = Camera::look_at(
            centre + super::image::RADIUS * diag * dir,
            centre,
            fov,
            size,
        );
        let shaded = super::render::shade(&normals, &colors, &cam);
        let f = render(mesh, &shaded, &cam);
        for y in 0..size {
            for x in 0..size {
                let i = y * size + x;
                if f.triangle[i] != u32::MAX {
                    let c =
                        f.rgb[i].map(|c| (crate::mesh::linear_to_srgb(c) * 255.0).round() as u8);
                    img.put_pixel((k * size + x) as u32, y as u32, image::Rgb(c));
                }
            }
        }
    }
    // The bar: top = 1 (the 99th percentile and above), bottom = 0, inset by a margin.
    let margin = size / 10;
    for y in margin..size - margin {
        let t = 1.0 - (y - margin) as f64 / (size - 2 * margin - 1).max(1) as f64;
        let c = ramp(t).map(|c| (crate::mesh::linear_to_srgb(c) * 255.0).round() as u8);
        for x in 2 * size + bar / 4..2 * size + 3 * bar / 4 {
            img.put_pixel(x as u32, y as u32, image::Rgb(c));
        }
    }
    let mut bytes = Vec::new();
    image::DynamicImage::ImageRgb8(img)
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .map_err(|e| Error::Data {
            stage: "saliency",
            message: format!("PNG encoding failed: {e}"),
        })?;
    crate::fsutil::write_bytes_atomic(out, &bytes)
}

/// What `terratile compare --heatmap` drew.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Heatmap {
    /// The PNG written.
    pub file: std::path::PathBuf,
    /// The distance shown red (the 99th percentile of the vertices' distances), in model
    /// units; 0 is blue.
    pub red_at: f64,
    /// The largest and the mean distance of the original's vertices to the other surface.
    pub max: f64,
    /// The mean.
    pub mean: f64,
}

/// Renders `original` coloured by the distance of each of its vertices to the surface of
/// `simplified` (Metro's error map, An's thesis Fig. 5.8 and 5.9), front and back, into the
/// PNG `out`, which must not exist (a user's file is never overwritten).
pub fn write_heatmap(
    original: &TriMesh,
    simplified: &TriMesh,
    size: usize,
    out: &Path,
) -> Result<Heatmap> {
    use rayon::prelude::*;
    if out.exists() {
        return Err(Error::Usage(format!(
            "{}: the heatmap file exists (terratile does not overwrite it)",
            out.display()
        )));
    }
    if original.triangle_count() == 0 || simplified.triangle_count() == 0 {
        return Err(Error::Data {
            stage: "compare",
            message: "a mesh without triangles has no error map".into(),
        });
    }
    let bvh = crate::mesh::Bvh::new(simplified);
    let d: Vec<f64> = original
        .positions
        .par_iter()
        .map(|p| {
            bvh.closest(p.as_dvec3(), None, f64::INFINITY)
                .map_or(0.0, |h| h.dist2.sqrt())
        })
        .collect();
    write_png(original, &d, size, out)?;
    let mut sorted = d.clone();
    sorted.sort_by(f64::total_cmp);
    Ok(Heatmap {
        file: out.to_path_buf(),
        red_at: sorted[((sorted.len() as f64 - 1.0) * 0.99) as usize],
        max: sorted.last().copied().unwrap_or(0.0),
        mean: d.iter().sum::<f64>() / d.len().max(1) as f64,
    })
}
