//! Itti, Koch and Niebur, "A Model of Saliency-Based Visual Attention for Rapid Scene
//! Analysis" (1998), on one rendered image: a dyadic Gaussian pyramid (levels 0–8); the
//! intensity I = (r + g + b)/3; the colour opponents R, G, B, Y of r, g, b normalised by I
//! (0 where I is below a tenth of its maximum, negative values clamped to 0); orientation
//! maps from Gabor filters at 0°, 45°, 90° and 135° on the intensity levels; centre–surround
//! differences at the pairs (2, 5) (2, 6) (3, 6) (3, 7) (4, 7) (4, 8), the surround level
//! interpolated up to the centre's; the normalisation N(·) (scale to [0, 1], multiply by
//! (1 − m̄)², m̄ the mean of the local maxima other than the global one); conspicuity maps
//! summed at level 4; the saliency S = (N(Ī) + N(C̄) + N(Ō)) / 3 scaled to [0, 1].
//!
//! The planes are `image`'s `ImageBuffer<Luma<f32>>`. The pyramid's reduction (Burt and
//! Adelson's 5-tap binomial filter and decimation, what Itti et al. used), the bilinear
//! across-scale interpolation and the Gabor filtering are written here: `image`'s
//! `imageops::resize` (a general resampler) took 36 % of the whole multi-view time on cow
//! and is 4× slower than the fixed dyadic filter, `image` has no general 2D convolution,
//! and the crate that has one (`imageproc`) brings nalgebra and a font stack for a 9 × 9
//! kernel loop.

use image::{ImageBuffer, Luma};

type Plane = ImageBuffer<Luma<f32>, Vec<f32>>;

/// The centre–surround level pairs.
pub const PAIRS: [(usize, usize); 6] = [(2, 5), (2, 6), (3, 6), (3, 7), (4, 7), (4, 8)];
/// Pyramid levels (0 = the image).
const LEVELS: usize = 9;
/// The level the maps are summed at.
const SUM_LEVEL: usize = 4;
/// Gabor kernel: half size, envelope σ and wavelength, in pixels of the level filtered.
const GABOR_HALF: i32 = 4;
const GABOR_SIGMA: f32 = 2.0;
const GABOR_WAVELENGTH: f32 = 5.0;

/// A saliency map at pyramid level 4 (size / 16 per side, at least 1), values in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct SaliencyMap {
    /// Side in pixels.
    pub size: u32,
    /// Row-major values.
    pub values: Vec<f32>,
}

impl SaliencyMap {
    /// The value at (u, v) in [0, 1]² of the image (bilinear).
    pub fn at(&self, u: f64, v: f64) -> f32 {
        let n = self.size as f64;
        let x = (u * n - 0.5).clamp(0.0, n - 1.0);
        let y = (v * n - 0.5).clamp(0.0, n - 1.0);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = (
            (x0 + 1).min(self.size as usize - 1),
            (y0 + 1).min(self.size as usize - 1),
        );
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let s = self.size as usize;
        let g = |x: usize, y: usize| self.values[y * s + x];
        let top = g(x0, y0) * (1.0 - fx) + g(x1, y0) * fx;
        let bottom = g(x0, y1) * (1.0 - fx) + g(x1, y1) * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

/// The saliency of a square linear-RGB image of side `size` (row-major).
pub fn saliency(rgb: &[[f32; 3]], size: u32) -> SaliencyMap {
    let planes: [Plane; 3] = std::array::from_fn(|c| {
        ImageBuffer::from_fn(size, size, |x, y| Luma([rgb[(y * size + x) as usize][c]]))
    });
    // The pyramid of each colour plane.
    let pyr: Vec<[Plane; 3]> = {
        let mut levels = vec![planes];
        for l in 1..LEVELS {
            let prev = &levels[l - 1];
            let next = std::array::from_fn(|c| down(&prev[c]));
            levels.push(next);
        }
        levels
    };
    // Levels 0 and 1 only feed the pyramid: no centre or surround lives there.
    let features: Vec<Option<Features>> = pyr
        .iter()
        .enumerate()
        .map(|(l, p)| (l >= PAIRS[0].0).then(|| Features::new(p)))
        .collect();
    let features: Vec<&Features> = features.iter().flatten().collect();
    let first = PAIRS[0].0;
    let side = features[SUM_LEVEL - first].i.width();
    let mut conspicuity_i = zeros(side);
    let mut conspicuity_c = zeros(side);
    let mut orient = [zeros(side), zeros(side), zeros(side), zeros(side)];
    for &(c, s) in &PAIRS {
        let (fc, fs) = (features[c - first], features[s - first]);
        let i = across(&fc.i, &fs.i, |a, b| (a - b).abs());
        add(&mut conspicuity_i, &normalise(&i), side);
        let rg = across(&fc.rg, &fs.rg, |a, b| (a - b).abs());
        let by = across(&fc.by, &fs.by, |a, b| (a - b).abs());
        add(&mut conspicuity_c, &normalise(&rg), side);
        add(&mut conspicuity_c, &normalise(&by), side);
        for (o, acc) in orient.iter_mut().enumerate() {
            let d = across(&fc.o[o], &fs.o[o], |a, b| (a - b).abs());
            add(acc, &normalise(&d), side);
        }
    }
    let mut conspicuity_o = zeros(side);
    for o in &orient {
        add(&mut conspicuity_o, &normalise(o), side);
    }
    let mut s = zeros(side);
    for m in [&conspicuity_i, &conspicuity_c, &conspicuity_o] {
        add(&mut s, &normalise(m), side);
    }
    let top = s.pixels().fold(0.0f32, |a, p| a.max(p[0]));
    let values = s
        .pixels()
        .map(|p| if top > 0.0 { p[0] / top } else { 0.0 })
        .collect();
    SaliencyMap { size: side, values }
}

/// The feature maps of one level: intensity, the opponent pairs R − G and B − Y, and the
/// four orientations. The colour centre–surround is |(R − G)(c) − (R − G)(s)| (and B − Y
/// alike): the double-opponent contrast as the common implementations of Itti's model
/// (Walther and Koch's SaliencyToolbox) read the paper's (R − G)(c) ⊖ (G − R)(s).
struct Features {
    i: Plane,
    rg: Plane,
    by: Plane,
    o: [Plane; 4],
}

impl Features {
    fn new(level: &[Plane; 3]) -> Features {
        let (w, h) = level[0].dimensions();
        let i = ImageBuffer::from_fn(w, h, |x, y| {
            Luma([(level[0].get_pixel(x, y)[0]
                + level[1].get_pixel(x, y)[0]
                + level[2].get_pixel(x, y)[0])
                / 3.0])
        });
        let imax = i.pixels().fold(0.0f32, |a, p| a.max(p[0]));
        let mut rg = zeros_wh(w, h);
        let mut by = zeros_wh(w, h);
        for (x, y, p) in i.enumerate_pixels() {
            let ii = p[0];
            if ii <= 0.1 * imax || ii <= 0.0 {
                continue;
            }
            let [r, g, b] = [0, 1, 2].map(|c| level[c].get_pixel(x, y)[0] / ii);
            let big_r = (r - (g + b) / 2.0).max(0.0);
            let big_g = (g - (r + b) / 2.0).max(0.0);
            let big_b = (b - (r + g) / 2.0).max(0.0);
            let big_y = ((r + g) / 2.0 - (r - g).abs() / 2.0 - b).max(0.0);
            rg.put_pixel(x, y, Luma([big_r - big_g]));
            by.put_pixel(x, y, Luma([big_b - big_y]));
        }
        let o = [0.0f32, 45.0, 90.0, 135.0].map(|deg| gabor(&i, deg.to_radians()));
        Features { i, rg, by, o }
    }
}

/// |I ∗ ψ_θ|: the magnitude of the response to a zero-mean cosine Gabor kernel.
fn gabor(img: &Plane, theta: f32) -> Plane {
    let n = (2 * GABOR_HALF + 1) as usize;
    let mut k = vec![0.0f32; n * n];
    let (st, ct) = theta.sin_cos();
    for y in -GABOR_HALF..=GABOR_HALF {
        for x in -GABOR_HALF..=GABOR_HALF {
            let (xf, yf) = (x as f32, y as f32);
            let u = xf * ct + yf * st;
            let env = (-(xf * xf + yf * yf) / (2.0 * GABOR_SIGMA * GABOR_SIGMA)).exp();
            k[((y + GABOR_HALF) as usize) * n + (x + GABOR_HALF) as usize] =
                env * (2.0 * std::f32::consts::PI * u / GABOR_WAVELENGTH).cos();
        }
    }
    let mean = k.iter().sum::<f32>() / k.len() as f32;
    k.iter_mut().for_each(|v| *v -= mean);
    let (w, h) = img.dimensions();
    let src = img.as_raw();
    ImageBuffer::from_fn(w, h, |x, y| {
        let mut acc = 0.0f32;
        for ky in -GABOR_HALF..=GABOR_HALF {
            let sy = (y as i32 + ky).clamp(0, h as i32 - 1) as u32;
            for kx in -GABOR_HALF..=GABOR_HALF {
                let sx = (x as i32 + kx).clamp(0, w as i32 - 1) as u32;
                acc += k[((ky + GABOR_HALF) as usize) * n + (kx + GABOR_HALF) as usize]
                    * src[(sy * w + sx) as usize];
            }
        }
        Luma([acc.abs()])
    })
}

/// The across-scale combination f(centre, surround interpolated to the centre's size).
fn across(c: &Plane, s: &Plane, f: impl Fn(f32, f32) -> f32) -> Plane {
    let (w, h) = c.dimensions();
    let up = resize(s, w);
    ImageBuffer::from_fn(w, h, |x, y| {
        Luma([f(c.get_pixel(x, y)[0], up.get_pixel(x, y)[0])])
    })
}

/// Itti's N(·): scale to [0, 1], multiply by (1 − m̄)², m̄ the mean of the local maxima
/// (above their 8 neighbours) other than the global maximum.
fn normalise(m: &Plane) -> Plane {
    let (w, h) = m.dimensions();
    let top = m.pixels().fold(0.0f32, |a, p| a.max(p[0]));
    if top <= 0.0 {
        return zeros_wh(w, h);
    }
    let g = |x: i64, y: i64| -> f32 {
        if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
            f32::NEG_INFINITY
        } else {
            m.get_pixel(x as u32, y as u32)[0]
        }
    };
    let (mut sum, mut count, mut global_seen) = (0.0f32, 0usize, false);
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            let v = g(x, y);
            let mut is_max = v > 0.0;
            for dy in -1..=1 {
                for dx in -1..=1 {
                    if (dx, dy) != (0, 0) && g(x + dx, y + dy) >= v {
                        is_max = false;
                    }
                }
            }
            if is_max {
                if v == top && !global_seen {
                    global_seen = true;
                } else {
                    sum += v / top;
                    count += 1;
                }
            }
        }
    }
    let mean = if count > 0 { sum / count as f32 } else { 0.0 };
    let f = (1.0 - mean).powi(2) / top;
    ImageBuffer::from_fn(w, h, |x, y| Luma([m.get_pixel(x, y)[0] * f]))
}

/// `acc += m` with `m` resized to `side` first.
fn add(acc: &mut Plane, m: &Plane, side: u32) {
    let m = resize(m, side);
    for (a, b) in acc.pixels_mut().zip(m.pixels()) {
        a[0] += b[0];
    }
}

/// One pyramid step: the 5-tap binomial filter [1 4 6 4 1] / 16 in x and y (edges
/// clamped), every other pixel kept (a side of 1 stays 1).
fn down(p: &Plane) -> Plane {
    const K: [f32; 5] = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];
    let (w, h) = p.dimensions();
    let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
    let src = p.as_raw();
    let at = |x: i64, y: i64| -> f32 {
        src[(y.clamp(0, h as i64 - 1) * w as i64 + x.clamp(0, w as i64 - 1)) as usize]
    };
    // Rows first, at the kept columns only.
    let mut rows = vec![0.0f32; (nw * h) as usize];
    for y in 0..h as i64 {
        for x in 0..nw as i64 {
            let cx = if w == 1 { 0 } else { 2 * x };
            rows[(y * nw as i64 + x) as usize] =
                (0..5).map(|k| K[k] * at(cx + k as i64 - 2, y)).sum();
        }
    }
    ImageBuffer::from_fn(nw, nh, |x, y| {
        let cy = if h == 1 { 0 } else { 2 * y as i64 };
        let v = (0..5)
            .map(|k| {
                let yy = (cy + k as i64 - 2).clamp(0, h as i64 - 1);
                K[k] * rows[(yy * nw as i64 + x as i64) as usize]
            })
            .sum();
        Luma([v])
    })
}

/// `m` brought to side `side`: reduced by pyramid steps when larger, interpolated
/// bilinearly (pixel centres aligned) when smaller.
fn resize(m: &Plane, side: u32) -> Plane {
    if m.width() > side {
        let mut r = down(m);
        while r.width() > side {
            r = down(&r);
        }
        return r;
    }
    if m.width() == side {
        return m.clone();
    }
    let map = SaliencyMap {
        size: m.width(),
        values: m.as_raw().clone(),
    };
    let n = side as f64;
    ImageBuffer::from_fn(side, side, |x, y| {
        Luma([map.at((x as f64 + 0.5) / n, (y as f64 + 0.5) / n)])
    })
}

fn zeros(side: u32) -> Plane {
    zeros_wh(side, side)
}

fn zeros_wh(w: u32, h: u32) -> Plane {
    ImageBuffer::new(w, h)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn argmax(m: &SaliencyMap) -> (f64, f64) {
        let (i, _) = m
            .values
            .iter()
            .enumerate()
            .fold((0, f32::MIN), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
        let s = m.size as f64;
        (
            ((i % m.size as usize) as f64 + 0.5) / s,
            ((i / m.size as usize) as f64 + 0.5) / s,
        )
    }

    #[test]
    fn a_red_disc_on_grey_is_the_salient_spot() {
        let n = 256u32;
        for (cx, cy) in [(0.3, 0.7), (0.75, 0.25)] {
            let img: Vec<[f32; 3]> = (0..n * n)
                .map(|i| {
                    let (x, y) = ((i % n) as f64 / n as f64, (i / n) as f64 / n as f64);
                    if (x - cx).hypot(y - cy) < 0.06 {
                        [0.9, 0.1, 0.1]
                    } else {
                        [0.5, 0.5, 0.5]
                    }
                })
                .collect();
            let m = saliency(&img, n);
            assert_eq!(m.size, 16);
            let (x, y) = argmax(&m);
            assert!((x - cx).hypot(y - cy) < 0.1, "({x}, {y}) vs ({cx}, {cy})");
            assert!(m.values.iter().all(|v| (0.0..=1.0).contains(v)));
        }
    }

    #[test]
    fn an_odd_bar_among_others_is_the_salient_spot() {
        // A grid of horizontal bars, one of them vertical: the vertical one stands out.
        let n = 256u32;
        let odd = (2, 1);
        let img: Vec<[f32; 3]> = (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as i32, (i / n) as i32);
                let (cx, cy) = (x / 64, y / 64);
                let (lx, ly) = (x % 64 - 32, y % 64 - 32);
                let (along, across) = if (cx, cy) == odd { (ly, lx) } else { (lx, ly) };
                if along.abs() < 14 && across.abs() < 3 {
                    [1.0; 3]
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        let m = saliency(&img, n);
        let (x, y) = argmax(&m);
        let want = ((odd.0 as f64 + 0.5) / 4.0, (odd.1 as f64 + 0.5) / 4.0);
        assert!(
            (x - want.0).hypot(y - want.1) < 0.13,
            "({x}, {y}) vs {want:?}"
        );
    }
}
