//! Property tests of the terrain stages on random point sets: every output cell is finite
//! (or masked, with `nodata`), filling never changes a measured cell, the fast paths equal
//! their twins, and the results are byte-identical for 1, 2 and 8 threads.

use proptest::prelude::*;
use terratile::terrain::denoise::denoise_xyz;
use terratile::terrain::resample::resample_xyz;
use terratile::terrain::{
    fill, reference, CellState, DenoiseParams, Fallback, FillParams, Heightfield, ResampleParams,
};

/// A random cloud: a tilted, bumpy surface with gaps and a few outliers.
fn cloud() -> impl Strategy<Value = (Vec<f64>, Vec<f64>, Vec<f64>)> {
    (20usize..1500, any::<u64>()).prop_map(|(n, seed)| {
        let mut rng = terratile::SplitMix64::new(seed);
        let (w, h) = (rng.range(5.0, 300.0), rng.range(5.0, 300.0));
        let (ox, oy) = (rng.range(-1e6, 1e6), rng.range(-1e6, 1e6));
        let mut x = Vec::with_capacity(n);
        let mut y = Vec::with_capacity(n);
        let mut z = Vec::with_capacity(n);
        for k in 0..n {
            let (u, v) = (rng.range(0.0, w), rng.range(0.0, h));
            // A hole in the middle third of the scene.
            if (u / w - 0.5).abs() < 0.15 && (v / h - 0.5).abs() < 0.15 {
                continue;
            }
            let mut zz = 100.0 + 0.1 * u - 0.05 * v + (u * 0.3).sin() * 2.0;
            if k % 97 == 0 {
                zz += rng.range(-80.0, 80.0);
            }
            x.push(ox + u);
            y.push(oy + v);
            z.push(zz);
        }
        (x, y, z)
    })
}

fn fill_params() -> impl Strategy<Value = FillParams> {
    (0.5f64..12.0, 0usize..3).prop_map(|(radius, f)| FillParams {
        radius,
        fallback: [Fallback::Smooth, Fallback::Mean, Fallback::Nodata][f],
        ..Default::default()
    })
}

fn grid(x: &[f64], y: &[f64], z: &[f64]) -> Option<(Vec<bool>, Heightfield)> {
    let d = denoise_xyz(x, y, z, &DenoiseParams::default(), 1.0).ok()?;
    let g = resample_xyz(x, y, z, Some(&d.keep), &ResampleParams::default(), None).ok()?;
    Some((d.keep, g.grid))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn cells_are_finite_or_masked_and_measured_cells_never_change((x, y, z) in cloud(), p in fill_params()) {
        let Some((_, before)) = grid(&x, &y, &z) else { return Ok(()) };
        let mut after = before.clone();
        let report = fill(&mut after, &p).unwrap();
        for ((h, s), (h0, s0)) in after.heights.iter().zip(after.state.iter()).zip(before.heights.iter().zip(before.state.iter())) {
            if *s0 == CellState::Measured {
                prop_assert_eq!(*s, CellState::Measured);
                prop_assert_eq!(h.to_bits(), h0.to_bits());
            }
            if p.fallback == Fallback::Nodata {
                prop_assert_eq!(h.is_finite(), *s != CellState::Empty);
            } else {
                prop_assert!(h.is_finite() && *s != CellState::Empty);
            }
        }
        prop_assert_eq!(&after.counts, &before.counts);
        let [empty, measured, interpolated, fallback] = after.census();
        prop_assert_eq!((report.empty, report.measured, report.interpolated, report.fallback), (empty, measured, interpolated, fallback));
    }

    #[test]
    fn filled_heights_stay_within_the_measured_range((x, y, z) in cloud(), p in fill_params()) {
        // Every rule is a convex combination of measured heights (inverse-distance weights,
        // the global mean, push-pull averages), so nothing leaves their range.
        let Some((_, mut g)) = grid(&x, &y, &z) else { return Ok(()) };
        let (lo, hi) = g.z_range().unwrap();
        fill(&mut g, &p).unwrap();
        let (a, b) = g.z_range().unwrap();
        prop_assert!(a >= lo - 1e-3 && b <= hi + 1e-3, "{a}..{b} outside {lo}..{hi}");
    }

    #[test]
    fn fast_paths_equal_their_twins((x, y, z) in cloud(), p in fill_params()) {
        let Ok(d) = denoise_xyz(&x, &y, &z, &DenoiseParams::default(), 1.0) else { return Ok(()) };
        prop_assert_eq!(&d.keep, &reference::denoise(&x, &y, &z, &DenoiseParams::default(), 1.0).unwrap());
        let c = terratile::PointCloud { x: x.clone(), y: y.clone(), z: z.clone(), ..Default::default() };
        let Ok(r) = terratile::terrain::resample(&c, Some(&d.keep), &ResampleParams::default()) else { return Ok(()) };
        prop_assert!(reference::same_grid(&r.grid, &reference::resample(&c, Some(&d.keep), &ResampleParams::default()).unwrap()));
        let mut fast = r.grid.clone();
        fill(&mut fast, &p).unwrap();
        prop_assert!(reference::same_grid(&fast, &reference::fill(&r.grid, &p).unwrap()));
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(12))]

    #[test]
    fn same_bytes_for_1_2_and_8_threads((x, y, z) in cloud(), p in fill_params()) {
        let run = |t: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap().install(|| {
                grid(&x, &y, &z).map(|(keep, mut g)| {
                    fill(&mut g, &p).unwrap();
                    (keep, g)
                })
            })
        };
        let one = run(1);
        for t in [2, 8] {
            let other = run(t);
            match (&one, &other) {
                (Some((k1, g1)), Some((k, g))) => {
                    prop_assert_eq!(k1, k);
                    prop_assert!(reference::same_grid(g1, g));
                }
                (None, None) => {}
                _ => prop_assert!(false, "runs disagree on failing"),
            }
        }
    }
}
