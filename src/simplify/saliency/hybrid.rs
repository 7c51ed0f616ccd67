//! The hybrid saliency of An's thesis (§3.4.2–3.4.3) and the weights H of the simplifier.
//!
//! Every quantity is first turned into its percentile rank over the vertices (ties share
//! their mean rank), so that the heavy-tailed curvature and saliency and the image values
//! share one scale. The vertices are then classed, the first class that applies winning:
//!
//! | class | test | value | output range |
//! |---|---|---|---|
//! | A | curvature in the top 5 % | curvature | [0.85, 1] |
//! | B | mesh saliency in the top 10 % | mesh saliency | [0.6, 0.9] |
//! | C | min image saliency > 0 and in the top 10 % | that min | [0.6, 0.9] |
//! | D | max image saliency in the bottom 10 % | that max | [0, 0.15] |
//! | E | the rest | mean of (mean image saliency, mesh saliency) | [0.15, 0.6] |
//!
//! Within a class the value's rank among the class's vertices is mapped linearly onto the
//! range. The thesis' Fig. 3.7 draws such ranges without numbers; these are chosen so that
//! the classes keep the thesis' order (shape features A above everything, what is salient
//! in every view C and salient shape B next, what no view finds salient D at the bottom)
//! and so that the top fifth of the hybrid holds A, B, C and the top of E; the README shows
//! the class sizes on real meshes. C needs the min over *all* views, where a vertex not
//! visible in a view counts 0 (as the thesis does): on a closed mesh no vertex is visible
//! from every direction, so C is empty there and matters for open, sheet-like meshes only.

/// The weighting ([`super::Weighting`]) smooths any map, the hybrid included, by a Gaussian
/// of σ = SMOOTH · ε (ε = 0.3 % of the diagonal, Lee's unit; 3 ε is Lee's second scale):
/// the classes make the raw hybrid jump between neighbouring vertices (a class-A vertex at
/// 0.9 beside a class-E one at 0.3), detail finer than any simplified mesh can keep.
/// Smoothed, it is the salience of a region. The hybrid itself ([`hybrid`]) stays raw.
/// 3 ε with the two phases (one weighted run was best at 4 ε; README).
pub const SMOOTH: f64 = 3.0;

/// Class bounds: (A top share of curvature, B top share of mesh saliency, C top share of
/// min image saliency, D bottom share of max image saliency).
pub const SHARES: (f64, f64, f64, f64) = (0.05, 0.10, 0.10, 0.10);
/// Output ranges of the classes A–E.
pub const RANGES: [(f64, f64); 5] = [
    (0.85, 1.0),
    (0.6, 0.9),
    (0.6, 0.9),
    (0.0, 0.15),
    (0.15, 0.6),
];

/// Calls `f` with each run of equal values of `values` (their indices), lowest value
/// first; the order is total (ties by index).
fn tie_groups(values: &[f64], mut f: impl FnMut(&[u32])) {
    let n = values.len();
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_by(|&a, &b| {
        values[a as usize]
            .total_cmp(&values[b as usize])
            .then(a.cmp(&b))
    });
    let mut i = 0;
    while i < n {
        let mut j = i + 1;
        while j < n && values[order[j] as usize] == values[order[i] as usize] {
            j += 1;
        }
        f(&order[i..j]);
        i = j;
    }
}

/// The percentile rank of every value in [0, 1] (ties get the mean of their ranks; a
/// single value or all equal: 0.5).
pub fn ranks(values: &[f64]) -> Vec<f64> {
    let n = values.len();
    let mut out = vec![0.5; n];
    if n < 2 {
        return out;
    }
    let mut below = 0;
    tie_groups(values, |g| {
        let r = 0.5 * (2 * below + g.len() - 1) as f64 / (n - 1) as f64;
        for &k in g {
            out[k as usize] = r;
        }
        below += g.len();
    });
    out
}

/// σ in ε of the Gaussian over which class A's curvature is averaged before it is ranked
/// ([`class_curvature`]; 0: each vertex's own curvature).
pub const CURVATURE_SMOOTH: f64 = 0.0;

/// The curvature class A ranks: `curvature` averaged over σ = `sigma_eps` · ε
/// ([`super::mesh::smooth`]), or itself for `sigma_eps` = 0.
pub fn class_curvature(mesh: &crate::mesh::TriMesh, curvature: &[f64], sigma_eps: f64) -> Vec<f64> {
    if sigma_eps > 0.0 {
        super::mesh::smooth(mesh, curvature, sigma_eps)
    } else {
        curvature.to_vec()
    }
}

/// The classes' bounds and output ranges (defaults [`SHARES`], [`RANGES`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Classes {
    /// (A top share of curvature, B top share of mesh saliency, C top share of min image
    /// saliency, D bottom share of max image saliency).
    pub shares: (f64, f64, f64, f64),
    /// Output ranges of A–E.
    pub ranges: [(f64, f64); 5],
}

impl Default for Classes {
    fn default() -> Self {
        Classes {
            shares: SHARES,
            ranges: RANGES,
        }
    }
}

/// The hybrid saliency in [0, 1] and the class (0–4 for A–E) of every vertex (the default
/// [`Classes`]).
pub fn hybrid(
    curvature: &[f64],
    mesh: &[f64],
    image_max: &[f64],
    image_min: &[f64],
    image_mean: &[f64],
) -> (Vec<f64>, Vec<u8>) {
    let maps = [curvature, mesh, image_max, image_min, image_mean];
    hybrid_with(maps, &Classes::default())
}

/// [`hybrid`] of the maps (curvature, mesh saliency, image max, min, mean) with `classes`.
pub fn hybrid_with(maps: [&[f64]; 5], classes: &Classes) -> (Vec<f64>, Vec<u8>) {
    let [curvature, mesh, image_max, image_min, image_mean] = maps;
    let n = curvature.len();
    let (rc, rm) = (ranks(curvature), ranks(mesh));
    let (rmax, rmin, rmean) = (ranks(image_max), ranks(image_min), ranks(image_mean));
    let (a, b, c, d) = classes.shares;
    let mut class = vec![4u8; n];
    let mut value = vec![0.0f64; n];
    for v in 0..n {
        (class[v], value[v]) = if curvature[v] > 0.0 && rc[v] >= 1.0 - a {
            (0, rc[v])
        } else if mesh[v] > 0.0 && rm[v] >= 1.0 - b {
            (1, rm[v])
        } else if image_min[v] > 0.0 && rmin[v] >= 1.0 - c {
            (2, rmin[v])
        } else if rmax[v] <= d {
            (3, rmax[v])
        } else {
            (4, 0.5 * (rmean[v] + rm[v]))
        };
    }
    let mut h = vec![0.0f64; n];
    for (k, &(lo, hi)) in classes.ranges.iter().enumerate() {
        let members: Vec<usize> = (0..n).filter(|&v| class[v] == k as u8).collect();
        let vals: Vec<f64> = members.iter().map(|&v| value[v]).collect();
        let r = ranks(&vals);
        for (&v, &x) in members.iter().zip(&r) {
            h[v] = lo + (hi - lo) * x;
        }
    }
    (h, class)
}

/// The simplifier's weights H = h_min^((1 − rank(values))^power), from h_min (the least
/// salient) to 1 (the most). With power 1 the weight is geometric in the rank: every step up
/// the ranks multiplies it by the same factor (the quadric errors it scales spread over
/// orders of magnitude; a linear map leaves the top fifth within 1.25× of the next fifth).
/// A power below 1 keeps the bulk of the surface near h_min and spends the range on the
/// top ranks, as Lee et al. (2005) amplify the salient vertices' weights and leave the rest
/// alone. `None` (plain QEM) when every value is the same (a plane has zero curvature and
/// saliency). These ranks count vertices; the simplifier's default ([`super::Weighting`])
/// ranks by area ([`area_ranks`]).
pub fn weights(values: &[f64], h_min: f64, power: f64) -> Option<Vec<f64>> {
    varies(values).then(|| weights_of_ranks(&ranks(values), h_min, power, 0.0))
}

/// Whether `values` holds two different values (else the weights would be all the same).
pub fn varies(values: &[f64]) -> bool {
    values
        .first()
        .is_some_and(|&f| values.iter().any(|&x| x != f))
}

/// H = h_min^((1 − u')^power) of ranks u ∈ [0, 1], u' = min(1, u / (1 − plateau)): the top
/// `plateau` share of the ranks all get H = 1, the rest spread geometrically below.
pub fn weights_of_ranks(ranks: &[f64], h_min: f64, power: f64, plateau: f64) -> Vec<f64> {
    let span = (1.0 - plateau).max(f64::MIN_POSITIVE);
    ranks
        .iter()
        .map(|&u| h_min.powf((1.0 - (u / span).min(1.0)).powf(power)))
        .collect()
}

/// H of ranks u ∈ [0, 1] with a step at the salient share `top`: 1 for u ≥ 1 − top, and
/// below it h_min · (gap / h_min)^(u / (1 − top)), from h_min at the bottom to `gap` just
/// under the step (`gap` = h_min: flat).
pub fn step_weights(ranks: &[f64], h_min: f64, top: f64, gap: f64) -> Vec<f64> {
    let edge = 1.0 - top;
    ranks
        .iter()
        .map(|&u| {
            if u >= edge {
                1.0
            } else {
                h_min * (gap / h_min).powf(u / edge)
            }
        })
        .collect()
}

/// The percentile rank of every value in [0, 1] by `area`: the share of the total area of
/// the vertices with smaller values plus half of the area of those with the same value
/// (so ties share their rank, and the rank of the top fifth of the area is 0.8 and above).
/// All areas zero: [`ranks`].
pub fn area_ranks(values: &[f64], area: &[f64]) -> Vec<f64> {
    let total: f64 = area.iter().sum();
    if total.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return ranks(values);
    }
    let mut out = vec![0.5; values.len()];
    let mut below = 0.0;
    tie_groups(values, |g| {
        let same: f64 = g.iter().map(|&k| area[k as usize]).sum();
        let r = (below + 0.5 * same) / total;
        for &k in g {
            out[k as usize] = r;
        }
        below += same;
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranks_share_ties_and_span_zero_to_one() {
        assert_eq!(ranks(&[3.0, 1.0, 2.0]), vec![1.0, 0.0, 0.5]);
        assert_eq!(ranks(&[1.0, 1.0, 5.0]), vec![0.25, 0.25, 1.0]);
        assert_eq!(ranks(&[7.0; 4]), vec![0.5; 4]);
    }

    #[test]
    fn area_ranks_count_area_and_share_ties() {
        // Areas 1, 3, 1, 3 of total 8: below the first 0, ties at 2 share (1 + 0.5·4) / 8.
        let r = area_ranks(&[0.0, 2.0, 2.0, 5.0], &[1.0, 3.0, 1.0, 3.0]);
        assert_eq!(r, vec![0.5 / 8.0, 3.0 / 8.0, 3.0 / 8.0, 6.5 / 8.0]);
        // The top fifth of the area ranks 0.8 and above, whatever the vertex count.
        let r = area_ranks(&[1.0, 2.0, 3.0], &[8.0, 0.0, 2.0]);
        assert_eq!(r, vec![0.4, 0.8, 0.9]);
        // No area: the plain ranks.
        assert_eq!(area_ranks(&[3.0, 1.0], &[0.0, 0.0]), ranks(&[3.0, 1.0]));
        // The plateau: the top share all at 1, h_min at the bottom.
        let w = weights_of_ranks(&[0.0, 0.5, 0.8, 1.0], 0.01, 1.0, 0.2);
        assert_eq!(w[0], 0.01);
        assert!((w[1] - 0.01f64.powf(1.0 - 0.5 / 0.8)).abs() < 1e-12);
        assert_eq!(&w[2..], &[1.0, 1.0]);
        // The step: the top fifth at 1, h_min at the bottom, `gap` just below the step.
        let w = step_weights(&[0.0, 0.4, 0.8, 1.0], 0.05, 0.2, 0.45);
        assert_eq!(w[0], 0.05);
        assert!((w[1] - 0.15).abs() < 1e-12, "{w:?}");
        assert_eq!(&w[2..], &[1.0, 1.0]);
        // gap = h_min: flat below the step.
        assert_eq!(
            step_weights(&[0.0, 0.5, 0.9], 0.1, 0.2, 0.1),
            [0.1, 0.1, 1.0]
        );
    }

    #[test]
    fn classes_take_their_ranges() {
        // 100 vertices: vertex 99 has the top curvature (A), 90..98 top mesh saliency (B),
        // 0..9 the lowest max image saliency (D), the rest E.
        let n = 100;
        let curvature: Vec<f64> = (0..n).map(|v| if v == 99 { 9.0 } else { 1.0 }).collect();
        let mesh: Vec<f64> = (0..n).map(|v| v as f64).collect();
        let max: Vec<f64> = (0..n).map(|v| 1.0 + v as f64).collect();
        let zeros = vec![0.0; n];
        let mean: Vec<f64> = (0..n).map(|v| 0.01 * v as f64).collect();
        let (h, class) = hybrid(&curvature, &mesh, &max, &zeros, &mean);
        assert_eq!(class[99], 0);
        assert!((90..99).all(|v| class[v] == 1), "{class:?}");
        assert!((0..10).all(|v| class[v] == 3), "{class:?}");
        assert!((10..90).all(|v| class[v] == 4));
        for v in 0..n {
            let (lo, hi) = RANGES[class[v] as usize];
            assert!(h[v] >= lo && h[v] <= hi);
        }
        // A class of one sits mid-range.
        assert_eq!(h[99], 0.925);
        // Other classes: B's bound at the top fifth, E remapped onto [0.2, 0.3].
        let mut c = Classes {
            shares: (0.05, 0.2, 0.1, 0.1),
            ..Classes::default()
        };
        c.ranges[4] = (0.2, 0.3);
        let (h2, class2) = hybrid_with([&curvature, &mesh, &max, &zeros, &mean], &c);
        assert_eq!(class2[99], 0);
        assert!((80..99).all(|v| class2[v] == 1), "{class2:?}");
        assert!((10..80).all(|v| class2[v] == 4 && (0.2..=0.3).contains(&h2[v])));
        assert!((h2[80] - 0.6).abs() < 1e-12 && (h2[98] - 0.9).abs() < 1e-12);
        // The defaults are `hybrid`'s.
        let d = hybrid_with(
            [&curvature, &mesh, &max, &zeros, &mean],
            &Classes::default(),
        );
        assert_eq!(d, (h, class));
    }

    #[test]
    fn equal_values_give_plain_qem() {
        assert_eq!(weights(&[0.0; 10], 0.1, 1.0), None);
        let w = weights(&[0.0, 2.0, 1.0], 0.01, 1.0).unwrap();
        assert_eq!((w[0], w[1]), (0.01, 1.0));
        assert!((w[2] - 0.1).abs() < 1e-15, "{w:?}");
    }
}
