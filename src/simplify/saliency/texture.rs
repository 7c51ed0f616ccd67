//! A texture baked into vertex colours, so that the image saliency renders what a textured
//! model shows (the rasteriser draws Gouraud vertex colours, not textures).
//!
//! Each vertex takes the texel under its own UV, bilinear between the four nearest texel
//! centres, the texture repeating outside [0, 1] (OBJ's default wrap) and v = 0 at the
//! image's bottom row (OBJ's convention). The readers split a vertex at a UV seam into one
//! copy per UV, so this is the per-corner colour: the copies of a seam vertex keep their own
//! sides' colours and every triangle is drawn with the colours its own UVs point at, as the
//! texture shows it (averaging the copies would blur a colour edge that runs along the seam
//! into both sides). Texels are turned from sRGB to linear before they are interpolated:
//! mesh colours are linear.

use crate::error::{Error, Result};
use crate::mesh::{srgb_to_linear, TriMesh};
use std::path::Path;

/// A decoded texture: linear RGB, row 0 at the top.
#[derive(Debug, Clone)]
pub struct Texture {
    width: usize,
    height: usize,
    texels: Vec<[f32; 3]>,
}

impl Texture {
    /// Reads a PNG (any bit depth and channel layout the `image` crate decodes; alpha is
    /// ignored).
    pub fn read(path: &Path) -> Result<Texture> {
        let img = image::ImageReader::open(path)
            .map_err(|e| Error::io(path, e))?
            .with_guessed_format()
            .map_err(|e| Error::io(path, e))?
            .decode()
            .map_err(|e| Error::format(path, 0, format!("not a readable image: {e}")))?
            .into_rgb32f();
        let (width, height) = (img.width() as usize, img.height() as usize);
        let texels = img
            .pixels()
            .map(|p| p.0.map(|c| srgb_to_linear(c.clamp(0.0, 1.0))))
            .collect();
        Texture::new(width, height, texels)
            .ok_or_else(|| Error::format(path, 0, "the image has no pixels"))
    }

    /// A texture of `width` × `height` linear texels, row 0 at the top; `None` when empty or
    /// when the sizes do not match.
    pub fn new(width: usize, height: usize, texels: Vec<[f32; 3]>) -> Option<Texture> {
        (width > 0 && height > 0 && texels.len() == width * height).then_some(Texture {
            width,
            height,
            texels,
        })
    }

    /// The bilinear colour at texture coordinates (u, v), repeating.
    pub fn sample(&self, u: f32, v: f32) -> [f32; 3] {
        // Texel centres sit at (i + 0.5) / width; v = 0 is the bottom row.
        let x = u.rem_euclid(1.0) as f64 * self.width as f64 - 0.5;
        let y = (1.0 - v.rem_euclid(1.0) as f64) * self.height as f64 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let wrap = |i: f64, n: usize| (i as i64).rem_euclid(n as i64) as usize;
        let (xa, xb) = (wrap(x0, self.width), wrap(x0 + 1.0, self.width));
        let (ya, yb) = (wrap(y0, self.height), wrap(y0 + 1.0, self.height));
        let t = |x: usize, y: usize| self.texels[y * self.width + x];
        let (a, b, c, d) = (t(xa, ya), t(xb, ya), t(xa, yb), t(xb, yb));
        std::array::from_fn(|k| {
            let top = a[k] + (b[k] - a[k]) * fx;
            let bottom = c[k] + (d[k] - c[k]) * fx;
            top + (bottom - top) * fy
        })
    }
}

/// Replaces `mesh`'s vertex colours by `texture` under each vertex's UV (opaque). A mesh
/// without UVs is refused: there is nothing to look up.
pub fn bake(mesh: &mut TriMesh, texture: &Texture) -> Result<()> {
    let Some(uvs) = &mesh.uvs else {
        return Err(Error::Data {
            stage: "saliency",
            message: "a texture needs texture coordinates (vt) in the mesh, and it has none".into(),
        });
    };
    let colors = uvs
        .iter()
        .map(|uv| {
            let [r, g, b] = texture.sample(uv.x, uv.y);
            [r, g, b, 1.0]
        })
        .collect();
    mesh.colors = Some(colors);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Vec2, Vec3};

    /// 2 × 2 texels: top row red, green; bottom row blue, white.
    fn checker() -> Texture {
        let t = vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0; 3]];
        Texture::new(2, 2, t).unwrap()
    }

    #[test]
    fn texel_centres_are_exact_and_between_them_is_bilinear() {
        let t = checker();
        // v = 0 is the bottom row: (0.25, 0.25) is the blue texel's centre.
        assert_eq!(t.sample(0.25, 0.25), [0.0, 0.0, 1.0]);
        assert_eq!(t.sample(0.25, 0.75), [1.0, 0.0, 0.0]);
        assert_eq!(t.sample(0.75, 0.75), [0.0, 1.0, 0.0]);
        // Halfway between the four centres: their mean.
        let c = t.sample(0.5, 0.5);
        for (k, want) in [0.5f32, 0.5, 0.5].into_iter().enumerate() {
            assert!((c[k] - want).abs() < 1e-6, "{c:?}");
        }
        // Halfway between red and green along the top row.
        let c = t.sample(0.5, 0.75);
        assert!((c[0] - 0.5).abs() < 1e-6 && (c[1] - 0.5).abs() < 1e-6 && c[2] == 0.0);
        // Repeating: u = 1.25 is u = 0.25, and the left edge blends with the right column.
        assert_eq!(t.sample(1.25, 0.25), t.sample(0.25, 0.25));
        let e = t.sample(0.0, 0.75);
        assert!(
            (e[0] - 0.5).abs() < 1e-6 && (e[1] - 0.5).abs() < 1e-6,
            "{e:?}"
        );
    }

    #[test]
    fn bake_gives_each_seam_copy_its_own_colour() {
        let t = checker();
        let mut m = TriMesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::ZERO],
            indices: vec![[0, 1, 2], [3, 2, 1]],
            uvs: Some(vec![
                Vec2::new(0.25, 0.25),
                Vec2::new(0.75, 0.75),
                Vec2::new(0.25, 0.75),
                // A second copy of vertex 0 at another UV.
                Vec2::new(0.75, 0.25),
            ]),
            ..TriMesh::default()
        };
        bake(&mut m, &t).unwrap();
        let c = m.colors.unwrap();
        assert_eq!(c[0], [0.0, 0.0, 1.0, 1.0]);
        assert_eq!(c[3], [1.0, 1.0, 1.0, 1.0]);
        assert_eq!(c[1], [0.0, 1.0, 0.0, 1.0]);
        let mut bare = TriMesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            indices: vec![[0, 1, 2]],
            ..TriMesh::default()
        };
        assert!(bake(&mut bare, &t).is_err());
    }
}
