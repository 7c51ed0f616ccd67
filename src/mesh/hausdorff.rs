//! The Metro-style simplification error (Kim et al. §III.4, after Cignoni, Rocchini
//! & Scopigno's Metro). One-sided from X to Y: points sampled on X — every referenced vertex
//! plus area-proportional samples inside each triangle — are measured against the surface
//! Y through a [`Bvh`], in parallel.
//!
//! - `E_max(X, Y)` = the largest sample distance (one-sided Hausdorff distance);
//! - `E_avg(X, Y)` = Σ_t A_t · d_H(t, Y) / Σ_t A_t with d_H(t, Y) the largest distance over
//!   triangle t's samples and corners (the paper's eq. 11–12);
//! - `sample_mean` = the area-weighted mean of all sample distances (Metro's and MeshLab's
//!   "mean"), reported beside it because other tools print that one.
//!
//! Samples: triangle t with area A_t gets the k² centroids of its similar-triangle
//! subdivision, k = max(1, round(√(A_t · n / A))) for n requested samples over area A, so
//! every triangle is sampled and big ones proportionally more. The symmetric error is the
//! larger of the two directions, for the max and for the mean. Percentages are of the
//! *original* mesh's bbox diagonal (over referenced vertices) in both directions, so that
//! the figures of several simplifications of one model compare.
//!
//! Determinism: the work is cut into fixed chunks of triangles (a warm-start hint runs along
//! each chunk), and sums are taken in triangle order, so the figures are bit-identical for
//! any thread count.

use super::{Bvh, TriMesh};
use crate::error::{Error, Result};
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Triangles per parallel work item.
const CHUNK: usize = 256;

/// Sampling of the error measurement.
#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct HausdorffParams {
    /// Area samples per direction (default 0 = automatic: 10 per triangle of the sampled
    /// mesh, at least 200,000). Vertices are sampled in addition.
    #[serde(default)]
    pub samples: u64,
}

/// The most area samples per direction a measurement takes. The time grows with the
/// samples (a few million point-to-surface queries per second per core); this bound keeps a
/// measurement within minutes on a small machine, where `--samples 1e11` ran for hours.
pub const MAX_SAMPLES: u64 = 100_000_000;

impl HausdorffParams {
    /// Checks `samples` against [`MAX_SAMPLES`].
    pub fn validate(&self) -> Result<()> {
        if self.samples > MAX_SAMPLES {
            return Err(Error::Usage(format!(
                "--samples {}: at most {MAX_SAMPLES} area samples per direction (queries run at a few million per second: 100000000 took 39 s on a 69,000-triangle mesh on 2 cores)",
                self.samples
            )));
        }
        Ok(())
    }

    fn samples_for(&self, m: &TriMesh) -> u64 {
        if self.samples > 0 {
            self.samples
        } else {
            (10 * m.triangle_count() as u64).max(200_000)
        }
    }
}

/// The error in one direction, X → Y.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct OneSided {
    /// E_max: largest distance from a sample of X to Y.
    pub max: f64,
    /// E_avg: area-weighted mean over X's triangles of their largest sample distance.
    pub mean: f64,
    /// Area-weighted mean of all sample distances (Metro's mean).
    pub sample_mean: f64,
    /// `max` in % of the original's bbox diagonal.
    pub max_pct: f64,
    /// `mean` in % of the original's bbox diagonal.
    pub mean_pct: f64,
    /// `sample_mean` in % of the original's bbox diagonal.
    pub sample_mean_pct: f64,
    /// Where on X the largest distance occurs.
    pub max_at: [f64; 3],
    /// Points measured (vertices and area samples).
    pub queries: u64,
}

/// Both directions and the symmetric error between an original and a simplified mesh.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct HausdorffReport {
    /// The original's bbox diagonal (over referenced vertices): the 100 % of the percentages.
    pub diagonal: f64,
    /// Original → simplified.
    pub forward: OneSided,
    /// Simplified → original.
    pub backward: OneSided,
    /// Symmetric max: the larger one-sided max.
    pub max: f64,
    /// Symmetric mean: the larger one-sided E_avg.
    pub mean: f64,
    /// `max` in % of the diagonal.
    pub max_pct: f64,
    /// `mean` in % of the diagonal.
    pub mean_pct: f64,
    /// Symmetric sample (Metro) mean: the larger one-sided `sample_mean`.
    pub sample_mean: f64,
    /// `sample_mean` in % of the diagonal.
    pub sample_mean_pct: f64,
}

impl std::fmt::Display for HausdorffReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let line = |f: &mut std::fmt::Formatter<'_>, name: &str, o: &OneSided| {
            writeln!(
                f,
                "  {name:<22} max {:.6} ({:.4} %)  mean {:.6} ({:.4} %)  sample mean {:.6} ({:.4} %)  [{} points]",
                o.max, o.max_pct, o.mean, o.mean_pct, o.sample_mean, o.sample_mean_pct, o.queries
            )
        };
        writeln!(f, "Hausdorff error (bbox diagonal {:.6}):", self.diagonal)?;
        line(f, "original → simplified", &self.forward)?;
        line(f, "simplified → original", &self.backward)?;
        writeln!(
            f,
            "  {:<22} max {:.6} ({:.4} %)  mean {:.6} ({:.4} %)  sample mean {:.6} ({:.4} %)",
            "symmetric",
            self.max,
            self.max_pct,
            self.mean,
            self.mean_pct,
            self.sample_mean,
            self.sample_mean_pct
        )
    }
}

/// Per-triangle result.
#[derive(Clone, Copy)]
struct TriErr {
    area: f64,
    /// d_H(t, Y).
    worst: f64,
    worst_at: DVec3,
    /// Σ over area samples of distance · (area per sample).
    weighted_sum: f64,
    queries: u64,
}

/// Closest-point queries in sequence, each starting from the triangle the last one found
/// (neighbouring queries mostly end on the same or a nearby triangle).
#[derive(Default)]
struct Probe {
    hint: Option<u32>,
}

impl Probe {
    /// Distance from `p` to the surface in `y` (infinite if `y` is empty).
    fn distance(&mut self, y: &Bvh, p: DVec3) -> f64 {
        let hit = y.closest(p, self.hint, f64::INFINITY);
        self.hint = hit.map(|h| h.slot);
        hit.map_or(f64::INFINITY, |h| h.dist2.sqrt())
    }
}

/// `f(i, probe)` for every `i` in `0..n`, in parallel over chunks of `CHUNK` consecutive
/// items, each chunk in order with one `Probe` (so its hints follow the mesh's own order);
/// the results in index order.
fn in_chunks<T: Send>(n: usize, f: impl Fn(usize, &mut Probe) -> T + Sync) -> Vec<T> {
    (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .flat_map_iter(|c| {
            let mut probe = Probe::default();
            (c * CHUNK..((c + 1) * CHUNK).min(n))
                .map(|i| f(i, &mut probe))
                .collect::<Vec<T>>()
        })
        .collect()
}

/// One-sided error from `x` to the surface in `y` (built over the other mesh); `diagonal` is
/// the 100 % of the percentages.
pub fn one_sided(x: &TriMesh, y: &Bvh, params: &HausdorffParams, diagonal: f64) -> OneSided {
    let areas = x.face_areas();
    let total: f64 = areas.iter().sum();
    let n = params.samples_for(x) as f64;
    let density = if total > 0.0 { n / total } else { 0.0 };

    // Referenced vertices first: each is measured once and shared by its triangles.
    let used = x.referenced();
    let nv = x.vertex_count();
    let vdist: Vec<f64> = in_chunks(nv, |v, probe: &mut Probe| {
        if used[v] {
            probe.distance(y, x.positions[v].as_dvec3())
        } else {
            0.0
        }
    });
    let vqueries = used.iter().filter(|u| **u).count() as u64;

    let per_tri: Vec<TriErr> = in_chunks(x.triangle_count(), |f, probe: &mut Probe| {
        let [a, b, cc] = x.corners(f);
        let (ab, ac) = (b - a, cc - a);
        let mut e = TriErr {
            area: areas[f],
            worst: f64::NEG_INFINITY,
            worst_at: a,
            weighted_sum: 0.0,
            queries: 0,
        };
        for (k, p) in x.indices[f].iter().zip([a, b, cc]) {
            let d = vdist[*k as usize];
            if d > e.worst {
                e.worst = d;
                e.worst_at = p;
            }
        }
        let k = ((areas[f] * density).sqrt().round() as usize).clamp(1, 4096);
        let inv = 1.0 / k as f64;
        let mut sum = 0.0;
        let mut measure = |u: f64, v: f64| {
            let p = a + ab * (u * inv) + ac * (v * inv);
            let d = probe.distance(y, p);
            sum += d;
            if d > e.worst {
                e.worst = d;
                e.worst_at = p;
            }
        };
        // The k² sub-triangle centroids, row by row (neighbouring samples in sequence keep
        // the hint good).
        for i in 0..k {
            for j in 0..k - i {
                measure(i as f64 + 1.0 / 3.0, j as f64 + 1.0 / 3.0);
                if i + j + 1 < k {
                    measure(i as f64 + 2.0 / 3.0, j as f64 + 2.0 / 3.0);
                }
            }
        }
        e.queries = (k * k) as u64;
        e.weighted_sum = sum * areas[f] / (k * k) as f64;
        e
    });

    let mut out = OneSided {
        max: 0.0,
        mean: 0.0,
        sample_mean: 0.0,
        max_pct: 0.0,
        mean_pct: 0.0,
        sample_mean_pct: 0.0,
        max_at: [0.0; 3],
        queries: vqueries,
    };
    let (mut wsum, mut ssum) = (0.0f64, 0.0f64);
    for e in &per_tri {
        if e.worst > out.max {
            out.max = e.worst;
            out.max_at = e.worst_at.to_array();
        }
        wsum += e.area * e.worst;
        ssum += e.weighted_sum;
        out.queries += e.queries;
    }
    if total > 0.0 {
        out.mean = wsum / total;
        out.sample_mean = ssum / total;
    }
    let pct = |v: f64| {
        if diagonal > 0.0 {
            100.0 * v / diagonal
        } else {
            0.0
        }
    };
    out.max_pct = pct(out.max);
    out.mean_pct = pct(out.mean);
    out.sample_mean_pct = pct(out.sample_mean);
    out
}

/// The error between `original` and `simplified`, both ways and symmetric.
pub fn hausdorff(
    original: &TriMesh,
    simplified: &TriMesh,
    params: &HausdorffParams,
) -> Result<HausdorffReport> {
    params.validate()?;
    for (m, what) in [
        (original, "the original mesh"),
        (simplified, "the simplified mesh"),
    ] {
        m.validate(what)?;
        if m.triangle_count() == 0 {
            return Err(Error::Data {
                stage: "hausdorff",
                message: format!("{what} has no triangles"),
            });
        }
    }
    let diagonal = original.diagonal();
    let (bo, bs) = rayon::join(|| Bvh::new(original), || Bvh::new(simplified));
    let (forward, backward) = rayon::join(
        || one_sided(original, &bs, params, diagonal),
        || one_sided(simplified, &bo, params, diagonal),
    );
    let max = forward.max.max(backward.max);
    let mean = forward.mean.max(backward.mean);
    let sample_mean = forward.sample_mean.max(backward.sample_mean);
    let pct = |v: f64| {
        if diagonal > 0.0 {
            100.0 * v / diagonal
        } else {
            0.0
        }
    };
    Ok(HausdorffReport {
        diagonal,
        forward,
        backward,
        max,
        mean,
        max_pct: pct(max),
        mean_pct: pct(mean),
        sample_mean,
        sample_mean_pct: pct(sample_mean),
    })
}

/// What [`compare_files`] measured.
#[derive(Debug, Clone, Serialize)]
pub struct CompareReport {
    /// The original mesh.
    pub original: std::path::PathBuf,
    /// The simplified (or any other) mesh.
    pub simplified: std::path::PathBuf,
    /// Triangles of the original and the simplified mesh.
    pub triangles: [usize; 2],
    /// What the readers noticed in the two files (dropped attributes, skipped faces).
    pub warnings: Vec<String>,
    /// The error.
    pub error: HausdorffReport,
    /// Fold-overs and self-intersections, when asked for (`--check-folds`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub folds: Option<super::intersect::FoldReport>,
    /// Seconds spent measuring the error (reading and the fold check excluded).
    pub seconds: f64,
    /// Point-to-surface queries per second.
    pub queries_per_second: f64,
}

impl std::fmt::Display for CompareReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{} ({} triangles) vs {} ({} triangles)",
            self.original.display(),
            self.triangles[0],
            self.simplified.display(),
            self.triangles[1]
        )?;
        write!(f, "{}", self.error)?;
        if let Some(folds) = &self.folds {
            write!(f, "{folds}")?;
        }
        writeln!(
            f,
            "{:.3} s, {:.2} M point-to-surface queries/s",
            self.seconds,
            self.queries_per_second / 1e6
        )
    }
}

/// Reads two mesh files (as `read` says) and measures the error between them; with
/// `check_folds`, also the fold-overs and self-intersections ([`super::intersect`]).
pub fn compare_files(
    original: &std::path::Path,
    simplified: &std::path::Path,
    params: &HausdorffParams,
    read: &super::io::ReadOptions,
    check_folds: bool,
) -> Result<CompareReport> {
    params.validate()?;
    let (a, mut warnings) = super::io::read_surface_with(original, read)?;
    let (b, more) = super::io::read_surface_with(simplified, read)?;
    for w in more {
        // The same file twice warns once.
        if !warnings.contains(&w) {
            warnings.push(w);
        }
    }
    let t = std::time::Instant::now();
    let error = hausdorff(&a, &b, params)?;
    let seconds = t.elapsed().as_secs_f64();
    let folds = check_folds.then(|| super::intersect::check_folds(&a, &b));
    let queries = (error.forward.queries + error.backward.queries) as f64;
    Ok(CompareReport {
        original: original.to_path_buf(),
        simplified: simplified.to_path_buf(),
        triangles: [a.triangle_count(), b.triangle_count()],
        warnings,
        error,
        folds,
        seconds,
        queries_per_second: if seconds > 0.0 {
            queries / seconds
        } else {
            0.0
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// A `n` × `n` grid of squares over [0, s]² at height z.
    fn plane(n: usize, s: f32, z: f32) -> TriMesh {
        let mut m = TriMesh::default();
        for j in 0..=n {
            for i in 0..=n {
                m.positions.push(Vec3::new(
                    s * i as f32 / n as f32,
                    s * j as f32 / n as f32,
                    z,
                ));
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

    /// Axis-aligned cube [-h, h]³, each face split into 2 triangles.
    fn cube(h: f32) -> TriMesh {
        let mut m = TriMesh::default();
        for i in 0..8 {
            m.positions.push(Vec3::new(
                if i & 1 == 0 { -h } else { h },
                if i & 2 == 0 { -h } else { h },
                if i & 4 == 0 { -h } else { h },
            ));
        }
        m.indices = vec![
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6],
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7],
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5],
        ];
        m
    }

    const P: HausdorffParams = HausdorffParams { samples: 20_000 };

    #[test]
    fn plane_against_offset_plane() {
        let a = plane(4, 1.0, 0.0);
        let b = plane(7, 1.0, 0.25);
        let r = hausdorff(&a, &b, &P).unwrap();
        for o in [r.forward, r.backward] {
            assert!((o.max - 0.25).abs() < 1e-7, "{o:?}");
            assert!((o.mean - 0.25).abs() < 1e-7, "{o:?}");
            assert!((o.sample_mean - 0.25).abs() < 1e-7, "{o:?}");
        }
        assert!((r.max_pct - 25.0 / 2f64.sqrt()).abs() < 1e-5);
    }

    #[test]
    fn cube_against_scaled_cube() {
        let (a, b) = (cube(1.0), cube(1.5));
        let r = hausdorff(&a, &b, &P).unwrap();
        // Inner → outer: every point is 0.5 from the nearest outer face.
        assert!((r.forward.max - 0.5).abs() < 1e-7, "{:?}", r.forward);
        assert!((r.forward.mean - 0.5).abs() < 1e-7);
        // Outer → inner: corners are √3·0.5 away, and every triangle holds a corner.
        let want = 0.5 * 3f64.sqrt();
        assert!((r.backward.max - want).abs() < 1e-7, "{:?}", r.backward);
        assert!((r.backward.mean - want).abs() < 1e-7);
        assert!((r.max - want).abs() < 1e-7);
        assert!(r.backward.sample_mean < want && r.backward.sample_mean > 0.5);
    }

    #[test]
    fn mesh_against_itself_is_zero_and_directions_swap() {
        let a = plane(5, 2.0, 0.0);
        let r = hausdorff(&a, &a, &P).unwrap();
        // Zero up to the rounding of a sample point on its own triangle.
        assert!(r.max < 1e-12 && r.mean < 1e-12, "{r:?}");
        let (a, b) = (cube(1.0), plane(3, 1.0, 2.0));
        let ab = hausdorff(&a, &b, &P).unwrap();
        let ba = hausdorff(&b, &a, &P).unwrap();
        assert_eq!(ab.forward.max, ba.backward.max);
        assert_eq!(ab.forward.mean, ba.backward.mean);
        assert_eq!(ab.max, ba.max);
    }

    #[test]
    fn same_figures_for_any_thread_count() {
        let (a, b) = (cube(1.0), plane(9, 3.0, 0.3));
        crate::testing::assert_same_for_any_thread_count(|| hausdorff(&a, &b, &P).unwrap());
    }

    #[test]
    fn empty_mesh_is_an_error() {
        let e = hausdorff(&cube(1.0), &TriMesh::default(), &P).unwrap_err();
        assert!(e.to_string().contains("no triangles"), "{e}");
    }
}
