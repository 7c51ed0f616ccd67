//! Vertical accuracy of a surface at held-out points ("its surface scores the
//! grid"): a seeded split of the points into a training set and a hold-out set, and the
//! RMSE, 95th-percentile and largest absolute error of a surface at the held-out points.

use crate::rng::SplitMix64;
use serde::Serialize;

/// Chooses `fraction` of the points whose `keep` flag is set (all when `None`) as a hold-out
/// set, seeded. Returns (training mask over all points, held-out indices in file order).
pub fn holdout(n: usize, keep: Option<&[bool]>, fraction: f64, seed: u64) -> (Vec<bool>, Vec<u32>) {
    let candidates: Vec<u32> = (0..n as u32)
        .filter(|&i| keep.is_none_or(|k| k[i as usize]))
        .collect();
    let k = ((candidates.len() as f64) * fraction.clamp(0.0, 1.0)).round() as usize;
    let picked = SplitMix64::new(seed).sample_indices(candidates.len(), k);
    let test: Vec<u32> = picked.iter().map(|&p| candidates[p as usize]).collect();
    let mut train: Vec<bool> = (0..n).map(|i| keep.is_none_or(|k| k[i])).collect();
    for &t in &test {
        train[t as usize] = false;
    }
    (train, test)
}

/// Error statistics of a surface against true heights.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct ErrorStats {
    /// Points compared (where the surface has a value).
    pub n: usize,
    /// Points where the surface had no value (outside the TIN's hull, a hole of the grid).
    pub missing: usize,
    /// Root mean square error.
    pub rmse: f64,
    /// 95th percentile of the absolute error.
    pub p95: f64,
    /// Largest absolute error.
    pub max: f64,
}

impl ErrorStats {
    /// Statistics of `(predicted, true)` pairs; a `None` prediction counts as missing.
    pub fn of(pairs: impl IntoIterator<Item = (Option<f64>, f64)>) -> ErrorStats {
        let mut err: Vec<f64> = Vec::new();
        let mut missing = 0;
        for (p, t) in pairs {
            match p {
                Some(p) => err.push((p - t).abs()),
                None => missing += 1,
            }
        }
        if err.is_empty() {
            return ErrorStats {
                missing,
                rmse: f64::NAN,
                p95: f64::NAN,
                max: f64::NAN,
                ..Default::default()
            };
        }
        let rmse = (err.iter().map(|e| e * e).sum::<f64>() / err.len() as f64).sqrt();
        err.sort_by(f64::total_cmp);
        let p95 = err[((err.len() as f64 * 0.95).ceil() as usize).clamp(1, err.len()) - 1];
        ErrorStats {
            n: err.len(),
            missing,
            rmse,
            p95,
            max: err[err.len() - 1],
        }
    }

    /// The same statistics scaled (e.g. feet to metres).
    pub fn scaled(self, k: f64) -> ErrorStats {
        ErrorStats {
            rmse: self.rmse * k,
            p95: self.p95 * k,
            max: self.max * k,
            ..self
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn holdout_is_seeded_and_disjoint() {
        let keep: Vec<bool> = (0..1000).map(|i| i % 10 != 0).collect();
        let (train, test) = holdout(1000, Some(&keep), 0.02, 7);
        assert_eq!(test.len(), 18);
        assert!(test.iter().all(|&t| keep[t as usize] && !train[t as usize]));
        assert_eq!(train.iter().filter(|&&t| t).count(), 900 - 18);
        assert_eq!(holdout(1000, Some(&keep), 0.02, 7).1, test);
        assert_ne!(holdout(1000, Some(&keep), 0.02, 8).1, test);
    }

    #[test]
    fn stats() {
        let s = ErrorStats::of([
            (Some(1.0), 0.0),
            (Some(-1.0), 1.0),
            (None, 3.0),
            (Some(4.0), 4.0),
        ]);
        assert_eq!((s.n, s.missing), (3, 1));
        assert!((s.rmse - (5.0f64 / 3.0).sqrt()).abs() < 1e-12);
        assert_eq!(s.max, 2.0);
        assert_eq!(s.p95, 2.0);
    }
}
