//! The Delaunay baseline of seed 003 §3 (SPEC §6): a 2.5-D Delaunay triangulation (TIN) of
//! the denoised points, built with `spade`, against which the grid pipeline's time, memory
//! and accuracy are measured.
//!
//! Coordinates are taken relative to the centre of the points' bounding box, so that the
//! f64 predicates work on small numbers (UTM eastings of 500 000 m would waste 19 bits).
//! Points sharing x and y (first and last return of one pulse: a third of the ISPRS points)
//! are merged before triangulating, their z averaged; spade itself would keep one of them
//! (`bulk_load` keeps the first, `insert` overwrites with the last), which makes the surface
//! depend on the order. The merged points keep the order of their first occurrence, so
//! incremental insertion still follows the file order (on spatially sorted files such as
//! autzen_full that is much faster than bulk loading: each insertion starts its walk next to
//! the previous vertex).

use crate::error::{Error, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use spade::{DelaunayTriangulation, FloatTriangulation, HasPosition, Point2, Triangulation};

/// A TIN vertex: position relative to the centre, and height.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TinVertex {
    /// x, y relative to [`TinPoints::centre`].
    pub p: Point2<f64>,
    /// World z (mean z of the points merged into this vertex).
    pub z: f64,
}

impl HasPosition for TinVertex {
    type Scalar = f64;
    fn position(&self) -> Point2<f64> {
        self.p
    }
}

/// The points a TIN is built from.
#[derive(Debug, Clone)]
pub struct TinPoints {
    /// Distinct points, in order of first occurrence.
    pub vertices: Vec<TinVertex>,
    /// World x, y subtracted from every point.
    pub centre: [f64; 2],
    /// Input points merged into another one (shared x and y).
    pub merged: usize,
}

/// How to build the triangulation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TinMethod {
    /// Whichever is faster for the input: incremental insertion when the points are
    /// spatially coherent in file order, bulk loading otherwise.
    #[default]
    Auto,
    /// spade's bulk loading (sorts the points along a space-filling order first).
    Bulk,
    /// Insertion one by one, in file order.
    Incremental,
}

/// A built TIN.
pub struct Tin {
    /// The triangulation (vertex positions relative to `centre`).
    pub tri: DelaunayTriangulation<TinVertex>,
    /// World x, y of the origin of the triangulation's coordinates.
    pub centre: [f64; 2],
}

impl std::fmt::Debug for Tin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tin")
            .field("vertices", &self.tri.num_vertices())
            .field("triangles", &self.tri.num_inner_faces())
            .field("centre", &self.centre)
            .finish()
    }
}

/// Centres the points whose `keep` flag is set (all when `None`) and merges those that share
/// x and y (z averaged).
pub fn prepare(x: &[f64], y: &[f64], z: &[f64], keep: Option<&[bool]>) -> Result<TinPoints> {
    let (b, n) = super::bounds_of(x, y, z, keep);
    if n == 0 {
        return Err(Error::Data {
            stage: "delaunay",
            message: "no points to triangulate".into(),
        });
    }
    let centre = [(b.min[0] + b.max[0]) / 2.0, (b.min[1] + b.max[1]) / 2.0];
    // (x bits, y bits, index) of the centred points; + 0.0 turns −0.0 into 0.0 so that equal
    // positions have equal bits.
    let mut keyed: Vec<(u64, u64, u32)> = (0..x.len() as u32)
        .into_par_iter()
        .filter(|&i| keep.is_none_or(|k| k[i as usize]))
        .map(|i| {
            let (px, py) = (
                x[i as usize] - centre[0] + 0.0,
                y[i as usize] - centre[1] + 0.0,
            );
            (px.to_bits(), py.to_bits(), i)
        })
        .collect();
    keyed.par_sort_unstable();
    // Runs of equal position: one vertex each, at the run's first (lowest) index.
    let mut merged: Vec<(u32, TinVertex)> = keyed
        .par_chunk_by(|a, b| a.0 == b.0 && a.1 == b.1)
        .map(|run| {
            let first = run[0].2;
            let zsum: f64 = run.iter().map(|r| z[r.2 as usize]).sum();
            let v = TinVertex {
                p: Point2::new(f64::from_bits(run[0].0), f64::from_bits(run[0].1)),
                z: zsum / run.len() as f64,
            };
            (first, v)
        })
        .collect();
    drop(keyed);
    merged.par_sort_unstable_by_key(|m| m.0);
    let vertices: Vec<TinVertex> = merged.into_par_iter().map(|m| m.1).collect();
    Ok(TinPoints {
        merged: n - vertices.len(),
        vertices,
        centre,
    })
}

/// Builds the TIN of `points` with `method` (`Auto` means incremental insertion).
pub fn triangulate(points: &TinPoints, method: TinMethod) -> Result<Tin> {
    if points.vertices.len() < 3 {
        return Err(Error::Data {
            stage: "delaunay",
            message: format!(
                "{} distinct point(s): a triangulation needs at least three",
                points.vertices.len()
            ),
        });
    }
    let err = |e: spade::InsertionError| Error::Data {
        stage: "delaunay",
        message: format!("spade refused a point: {e}"),
    };
    let tri = match method {
        TinMethod::Bulk => {
            DelaunayTriangulation::bulk_load(points.vertices.clone()).map_err(err)?
        }
        TinMethod::Auto | TinMethod::Incremental => {
            let mut t = DelaunayTriangulation::new();
            for v in &points.vertices {
                t.insert(*v).map_err(err)?;
            }
            t
        }
    };
    if tri.num_inner_faces() == 0 {
        return Err(Error::Data {
            stage: "delaunay",
            message: format!(
                "all {} distinct points are collinear: they span no triangle",
                points.vertices.len()
            ),
        });
    }
    Ok(Tin {
        tri,
        centre: points.centre,
    })
}

impl Tin {
    /// Number of vertices.
    pub fn vertices(&self) -> usize {
        self.tri.num_vertices()
    }

    /// Number of triangles.
    pub fn triangles(&self) -> usize {
        self.tri.num_inner_faces()
    }

    /// World z at (x, y) by linear interpolation in the triangle holding it; None outside
    /// the convex hull.
    pub fn z_at(&self, x: f64, y: f64) -> Option<f64> {
        self.tri.barycentric().interpolate(
            |v| v.data().z,
            Point2::new(x - self.centre[0], y - self.centre[1]),
        )
    }

    /// [`Tin::z_at`] for many points, in parallel (one interpolator per worker).
    pub fn z_at_many(&self, xy: &[[f64; 2]]) -> Vec<Option<f64>> {
        xy.par_chunks(4096)
            .flat_map_iter(|chunk| {
                let bary = self.tri.barycentric();
                chunk
                    .iter()
                    .map(|&[x, y]| {
                        bary.interpolate(
                            |v| v.data().z,
                            Point2::new(x - self.centre[0], y - self.centre[1]),
                        )
                    })
                    .collect::<Vec<_>>()
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn duplicates_merge_with_mean_z_in_first_order() {
        let x = [10.0, 11.0, 10.0, 12.0, 11.0];
        let y = [5.0, 5.0, 5.0, 7.0, 5.0];
        let z = [1.0, 2.0, 3.0, 4.0, 6.0];
        let p = prepare(&x, &y, &z, None).unwrap();
        assert_eq!(p.merged, 2);
        let zs: Vec<f64> = p.vertices.iter().map(|v| v.z).collect();
        assert_eq!(zs, vec![2.0, 4.0, 4.0]);
        assert_eq!(p.centre, [11.0, 6.0]);
        let tin = triangulate(&p, TinMethod::Incremental).unwrap();
        assert_eq!(tin.triangles(), 1);
        assert_eq!(tin.z_at(10.0, 5.0), Some(2.0));
    }

    #[test]
    fn bulk_and_incremental_give_the_same_surface() {
        let mut rng = crate::rng::SplitMix64::new(3);
        let n = 2000;
        let x: Vec<f64> = (0..n).map(|_| 500_000.0 + rng.range(0.0, 100.0)).collect();
        let y: Vec<f64> = (0..n).map(|_| 5_400_000.0 + rng.range(0.0, 80.0)).collect();
        let z: Vec<f64> = x.iter().zip(&y).map(|(x, y)| 0.1 * x - 0.05 * y).collect();
        let p = prepare(&x, &y, &z, None).unwrap();
        let a = triangulate(&p, TinMethod::Bulk).unwrap();
        let b = triangulate(&p, TinMethod::Incremental).unwrap();
        assert_eq!(a.triangles(), b.triangles());
        // A plane is reproduced exactly (to rounding) inside the hull.
        for k in 0..100 {
            let (qx, qy) = (500_010.0 + k as f64 * 0.7, 5_400_010.0 + k as f64 * 0.5);
            let want = 0.1 * qx - 0.05 * qy;
            assert!((a.z_at(qx, qy).unwrap() - want).abs() < 1e-6);
            assert!((b.z_at(qx, qy).unwrap() - want).abs() < 1e-6);
        }
        assert!(a.z_at(0.0, 0.0).is_none());
    }

    #[test]
    fn too_few_or_collinear_points_are_refused() {
        let p = prepare(&[1.0, 1.0, 2.0], &[1.0, 1.0, 2.0], &[0.0; 3], None).unwrap();
        let e = triangulate(&p, TinMethod::Bulk).unwrap_err().to_string();
        assert!(e.starts_with("delaunay: 2 distinct point(s)"), "{e}");
        let x: Vec<f64> = (0..10).map(|i| i as f64).collect();
        let p = prepare(&x, &x, &x, None).unwrap();
        for m in [TinMethod::Bulk, TinMethod::Incremental] {
            let e = triangulate(&p, m).unwrap_err().to_string();
            assert!(
                e.starts_with("delaunay: all 10 distinct points are collinear"),
                "{e}"
            );
        }
    }
}
