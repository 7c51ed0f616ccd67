//! Pictures of the terrain (Kim & Shin's Fig. 3 as images): a shaded-relief PNG of the
//! whole heightfield (hypsometric tint × Lambert hillshade, light from the north-west at 45°,
//! the usual cartographic convention), and the same picture with a CLOD mesh drawn over it
//! (anti-aliased lines, Xiaolin Wu) and the tile borders in red.
//!
//! Scale: the longer side gets `max_size` pixels, but a small grid is enlarged at most 4×
//! (beyond that the picture only gets blurrier). North is up. Holes are drawn flat blue-grey.

use crate::error::{Error, Result};
use crate::output::SetSummary;
use crate::terrain::TileTriangulation;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ExtendedColorType, ImageEncoder};
use ndarray::Array2;
use rayon::prelude::*;

/// An RGB picture of the terrain and how it maps to the grid.
#[derive(Debug, Clone)]
pub struct Picture {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Pixels per sample along x and y (they differ when cells are not square: the picture
    /// keeps the terrain's proportions).
    pub scale: [f64; 2],
    /// Rows of the grid (to flip y).
    rows: usize,
    /// RGB bytes, row 0 at the top (north).
    pub rgb: Vec<u8>,
}

impl Picture {
    /// Continuous pixel coordinates of global sample (i, j).
    pub fn to_pixel(&self, i: f64, j: f64) -> [f64; 2] {
        [
            (i + 0.5) * self.scale[0],
            (self.rows as f64 - j - 0.5) * self.scale[1],
        ]
    }

    /// The picture as PNG bytes.
    pub fn png(&self) -> Result<Vec<u8>> {
        let mut out = Vec::new();
        PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive)
            .write_image(
                &self.rgb,
                self.width as u32,
                self.height as u32,
                ExtendedColorType::Rgb8,
            )
            .map_err(|e| Error::Internal(format!("png encoding: {e}")))?;
        Ok(out)
    }
}

const HOLE: [f32; 3] = [150.0, 175.0, 200.0];
/// Hypsometric tint stops: (relative height, colour).
const TINT: [(f32, [f32; 3]); 5] = [
    (0.0, [74.0, 122.0, 66.0]),
    (0.3, [150.0, 172.0, 96.0]),
    (0.6, [214.0, 196.0, 130.0]),
    (0.85, [168.0, 132.0, 98.0]),
    (1.0, [245.0, 242.0, 236.0]),
];

fn tint(t: f32) -> [f32; 3] {
    let t = t.clamp(0.0, 1.0);
    for w in TINT.windows(2) {
        let ((a, ca), (b, cb)) = (w[0], w[1]);
        if t <= b {
            let f = (t - a) / (b - a);
            return [0, 1, 2].map(|k| ca[k] + f * (cb[k] - ca[k]));
        }
    }
    TINT[TINT.len() - 1].1
}

/// Bilinear weights at fractional sample coordinates, clamped to the grid: computed once per
/// pixel and applied to the height and shade grids.
struct Bilinear {
    idx: [usize; 4],
    w: [f32; 4],
    nearest: usize,
}

impl Bilinear {
    fn at(cols: usize, rows: usize, i: f64, j: f64) -> Bilinear {
        let i = i.clamp(0.0, (cols - 1) as f64);
        let j = j.clamp(0.0, (rows - 1) as f64);
        let (i0, j0) = (
            (i.floor() as usize).min(cols.saturating_sub(2)),
            (j.floor() as usize).min(rows.saturating_sub(2)),
        );
        let (i1, j1) = ((i0 + 1).min(cols - 1), (j0 + 1).min(rows - 1));
        let (fi, fj) = ((i - i0 as f64) as f32, (j - j0 as f64) as f32);
        Bilinear {
            idx: [
                j0 * cols + i0,
                j0 * cols + i1,
                j1 * cols + i0,
                j1 * cols + i1,
            ],
            w: [
                (1.0 - fi) * (1.0 - fj),
                fi * (1.0 - fj),
                (1.0 - fi) * fj,
                fi * fj,
            ],
            nearest: j.round() as usize * cols + i.round() as usize,
        }
    }

    /// The value over the corners that are not NaN (weights renormalised); NaN when the
    /// nearest sample is NaN, so holes keep their shape instead of growing by a sample.
    fn apply(&self, a: &[f32]) -> f32 {
        if a[self.nearest].is_nan() {
            return f32::NAN;
        }
        let mut sum = 0.0f32;
        let mut weight = 0.0f32;
        for k in 0..4 {
            let v = a[self.idx[k]];
            if !v.is_nan() && self.w[k] > 0.0 {
                sum += v * self.w[k];
                weight += self.w[k];
            }
        }
        if weight > 0.0 {
            sum / weight
        } else {
            a[self.nearest]
        }
    }
}

/// The 0.5 % and 99.5 % quantiles of the finite heights (a few outliers should not wash out
/// the tint), from at most about a million of them.
fn tint_range(z: &Array2<f32>) -> Option<(f32, f32)> {
    let step = (z.len() / 1_000_000).max(1);
    let mut v: Vec<f32> = z
        .iter()
        .step_by(step)
        .copied()
        .filter(|h| h.is_finite())
        .collect();
    if v.is_empty() {
        return None;
    }
    let n = v.len();
    let lo_k = n / 200;
    let hi_k = (n - 1) - n / 200;
    let lo = *v.select_nth_unstable_by(lo_k, f32::total_cmp).1;
    let hi = *v.select_nth_unstable_by(hi_k, f32::total_cmp).1;
    Some((lo, hi))
}

/// The shaded relief of the whole set (`z`: its heights, assembled from the tiles), the
/// longer side `max_size` pixels (at most 4× the grid).
pub fn relief(set: &SetSummary, z: &Array2<f32>, max_size: usize) -> Picture {
    let [cols, rows] = set.samples;
    // Pixels per world unit: the longer side gets max_size pixels, a sample at most 4.
    let [cx, cy] = set.cell_size;
    let (ew, eh) = (cols as f64 * cx, rows as f64 * cy);
    let per_unit = (max_size as f64 / ew.max(eh)).min(4.0 / cx.min(cy));
    let (width, height) = (
        ((ew * per_unit).round() as usize).max(1),
        ((eh * per_unit).round() as usize).max(1),
    );
    let scale = [width as f64 / cols as f64, height as f64 / rows as f64];
    // Lambert shade per sample (central differences, one-sided at the edge and next to
    // holes), light from the north-west at 45°; pixels interpolate shade and height.
    let alt = 45f64.to_radians();
    let az = 315f64.to_radians();
    let light = [alt.cos() * az.sin(), alt.cos() * az.cos(), alt.sin()];
    let zs = z.as_slice().expect("assembled grid is contiguous");
    let mut shade = vec![0.0f32; cols * rows];
    shade.par_chunks_mut(cols).enumerate().for_each(|(j, row)| {
        for (i, out) in row.iter_mut().enumerate() {
            let here = zs[j * cols + i];
            let h = |a: usize, b: usize| {
                let v = zs[b * cols + a];
                if v.is_nan() {
                    here
                } else {
                    v
                }
            };
            let (i0, i1) = (i.saturating_sub(1), (i + 1).min(cols - 1));
            let (j0, j1) = (j.saturating_sub(1), (j + 1).min(rows - 1));
            let dx = (h(i1, j) - h(i0, j)) as f64 / ((i1 - i0).max(1) as f64 * cx);
            let dy = (h(i, j1) - h(i, j0)) as f64 / ((j1 - j0).max(1) as f64 * cy);
            let dot =
                (-dx * light[0] - dy * light[1] + light[2]) / (dx * dx + dy * dy + 1.0).sqrt();
            *out = if here.is_nan() {
                f32::NAN
            } else {
                dot.max(0.0) as f32
            };
        }
    });
    let (lo, hi) = tint_range(z).unwrap_or((0.0, 1.0));
    let span = (hi - lo).max(f32::EPSILON);
    let mut rgb = vec![0u8; width * height * 3];
    rgb.par_chunks_mut(width * 3)
        .enumerate()
        .for_each(|(py, row)| {
            let gj = rows as f64 - (py as f64 + 0.5) / scale[1] - 0.5;
            for px in 0..width {
                let gi = (px as f64 + 0.5) / scale[0] - 0.5;
                let b = Bilinear::at(cols, rows, gi, gj);
                let h = b.apply(zs);
                let c = if h.is_nan() {
                    HOLE
                } else {
                    let t = tint((h - lo) / span);
                    let sh = b.apply(&shade);
                    t.map(|v| v * (0.3 + 0.85 * sh))
                };
                for k in 0..3 {
                    row[px * 3 + k] = c[k].round().clamp(0.0, 255.0) as u8;
                }
            }
        });
    Picture {
        width,
        height,
        scale,
        rows,
        rgb,
    }
}

/// Coverage of anti-aliased lines, kept as the maximum per pixel (so drawing an edge twice
/// changes nothing).
struct Coverage {
    w: usize,
    h: usize,
    c: Vec<f32>,
}

impl Coverage {
    fn new(w: usize, h: usize) -> Coverage {
        Coverage {
            w,
            h,
            c: vec![0.0; w * h],
        }
    }

    fn plot(&mut self, x: isize, y: isize, v: f32) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            let s = &mut self.c[y as usize * self.w + x as usize];
            *s = s.max(v);
        }
    }

    /// Xiaolin Wu's line from (x0, y0) to (x1, y1), pixel centres at integer + 0.5, with
    /// `ink` (0..=1) the coverage of a pixel the line crosses fully.
    fn line(&mut self, mut x0: f64, mut y0: f64, mut x1: f64, mut y1: f64, ink: f32) {
        x0 -= 0.5;
        y0 -= 0.5;
        x1 -= 0.5;
        y1 -= 0.5;
        let steep = (y1 - y0).abs() > (x1 - x0).abs();
        if steep {
            std::mem::swap(&mut x0, &mut y0);
            std::mem::swap(&mut x1, &mut y1);
        }
        if x0 > x1 {
            std::mem::swap(&mut x0, &mut x1);
            std::mem::swap(&mut y0, &mut y1);
        }
        let dx = x1 - x0;
        let gradient = if dx == 0.0 { 1.0 } else { (y1 - y0) / dx };
        let (start, end) = (x0.round() as isize, x1.round() as isize);
        for x in start..=end {
            let y = y0 + gradient * (x as f64 - x0);
            let yf = y.floor();
            let f = (y - yf) as f32;
            let (a, b) = (yf as isize, yf as isize + 1);
            if steep {
                self.plot(a, x, (1.0 - f) * ink);
                self.plot(b, x, f * ink);
            } else {
                self.plot(x, a, (1.0 - f) * ink);
                self.plot(x, b, f * ink);
            }
        }
    }
}

/// Mesh edges at least this long (in pixels) are drawn with full ink.
const FULL_INK_PX: f64 = 6.0;

/// `base` with the surface edges of `tris` drawn over it, and the tiles' borders.
pub fn wireframe(set: &SetSummary, base: &Picture, tris: &[TileTriangulation]) -> Picture {
    // Shared edges are drawn from both triangles: coverage is a maximum, so that is harmless.
    let mut mesh = Coverage::new(base.width, base.height);
    for t in tris {
        let o = set.tiles[t.tile].origin;
        for f in &t.triangles[..t.surface_triangles] {
            for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
                let (pa, pb) = (t.uv[a as usize], t.uv[b as usize]);
                let [x0, y0] = base.to_pixel(o[0] as f64 + pa[0], o[1] as f64 + pa[1]);
                let [x1, y1] = base.to_pixel(o[0] as f64 + pb[0], o[1] as f64 + pb[1]);
                // Edges shorter than a few pixels are drawn fainter: where the mesh is finer
                // than the picture, its density shows as a shade instead of solid ink, and
                // the coarse triangles stay readable beside it.
                let len = (x1 - x0).hypot(y1 - y0);
                mesh.line(x0, y0, x1, y1, (len / FULL_INK_PX).min(1.0) as f32);
            }
        }
    }
    let mut borders = Coverage::new(base.width, base.height);
    for t in &set.tiles {
        let (i0, j0) = (t.origin[0] as f64, t.origin[1] as f64);
        let (i1, j1) = (i0 + (t.valid[0] - 1) as f64, j0 + (t.valid[1] - 1) as f64);
        let corners = [[i0, j0], [i1, j0], [i1, j1], [i0, j1]];
        for k in 0..4 {
            let [a, b] = [corners[k], corners[(k + 1) % 4]];
            let [x0, y0] = base.to_pixel(a[0], a[1]);
            let [x1, y1] = base.to_pixel(b[0], b[1]);
            borders.line(x0, y0, x1, y1, 1.0);
        }
    }
    let mut out = base.clone();
    let ink = [25.0f32, 25.0, 35.0];
    let red = [215.0f32, 35.0, 35.0];
    for (p, (m, b)) in out.rgb.chunks_mut(3).zip(mesh.c.iter().zip(&borders.c)) {
        for k in 0..3 {
            let mut v = p[k] as f32;
            v += (ink[k] - v) * 0.85 * m;
            v += (red[k] - v) * 0.95 * b;
            p[k] = v.round().clamp(0.0, 255.0) as u8;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wu_lines_cover_their_pixels_and_are_idempotent() {
        let mut c = Coverage::new(10, 10);
        c.line(0.5, 0.5, 9.5, 0.5, 1.0);
        assert!((0..10).all(|x| c.c[x] == 1.0));
        let before = c.c.clone();
        c.line(9.5, 0.5, 0.5, 0.5, 1.0);
        assert_eq!(before, c.c);
        // A diagonal splits its coverage.
        let mut d = Coverage::new(10, 10);
        d.line(0.5, 0.5, 9.5, 9.5, 1.0);
        assert!((0..10).all(|k| d.c[k * 10 + k] == 1.0));
        // Ink scales the coverage.
        let mut e = Coverage::new(10, 10);
        e.line(0.5, 0.5, 9.5, 0.5, 0.25);
        assert!((0..10).all(|x| e.c[x] == 0.25));
    }

    #[test]
    fn tint_runs_from_green_to_white() {
        assert_eq!(tint(0.0), TINT[0].1);
        assert_eq!(tint(1.0), TINT[4].1);
        assert_eq!(tint(-3.0), TINT[0].1);
    }
}
