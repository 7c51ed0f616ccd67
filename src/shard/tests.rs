use super::*;
use crate::terrain::fill::tests::holey;
use proptest::prelude::*;

/// The in-memory run's grid half on `hf`: fill, tiles, d2, vertical error.
fn whole(
    hf: &Heightfield,
    fill: Option<&FillParams>,
    tp: &TileParams,
    qp: &QuadtreeParams,
) -> Merged {
    let mut g = hf.clone();
    let report = fill.map(|f| fill::fill(&mut g, f).unwrap());
    let set = tiles::tile(&g, tp).unwrap();
    let quadtree = quadtree::build(&set, qp).unwrap();
    let vertical_error = quadtree::vertical_error(&set);
    Merged {
        set,
        quadtree,
        vertical_error,
        fill: report,
    }
}

/// A generated survey of `points` points.
fn survey(seed: u64, points: u64) -> crate::generate::Scene {
    crate::generate::generate(&crate::generate::GenerateParams {
        seed,
        points,
        ..Default::default()
    })
    .unwrap()
}

fn difference(a: &Merged, b: &Merged) -> Option<String> {
    a.difference(b)
}

/// `holey` plus square voids wider than the fill radius centred on tile borders, so that
/// the fallback's cells straddle shard borders.
fn voids_on_borders(seed: u64, cols: usize, rows: usize, step: usize, half: usize) -> Heightfield {
    let mut hf = holey(seed, cols, rows);
    for cj in (step..rows).step_by(step) {
        for ci in (step..cols).step_by(step) {
            for j in cj.saturating_sub(half)..(cj + half).min(rows) {
                for i in ci.saturating_sub(half)..(ci + half).min(cols) {
                    hf.heights[[j, i]] = f32::NAN;
                    hf.counts[[j, i]] = 0;
                    hf.state[[j, i]] = CellState::Empty;
                }
            }
        }
    }
    hf
}

fn params(size: usize) -> (TileParams, QuadtreeParams) {
    (
        TileParams {
            size: Some(size),
            ..Default::default()
        },
        QuadtreeParams::default(),
    )
}

#[test]
fn sharded_equals_whole_for_every_block_size() {
    let (tp, qp) = params(65);
    let hf = voids_on_borders(3, 64 * 4 + 20, 64 * 3 + 1, 64, 13);
    for fill in [
        Some(FillParams::default()),
        Some(FillParams {
            fallback: Fallback::Nodata,
            radius: 5.0,
            ..Default::default()
        }),
        None,
    ] {
        let want = whole(&hf, fill.as_ref(), &tp, &qp);
        let samples = [hf.cols(), hf.rows()];
        for block in [[1, 1], [2, 1], [1, 2], [2, 2], [3, 2], [4, 3], [5, 5]] {
            let layout = ShardLayout::new(samples, &tp, block).unwrap();
            let got = run_all(&layout, &hf, fill.as_ref(), &tp, &qp).unwrap();
            assert_eq!(difference(&got, &want), None, "{block:?} {fill:?}");
        }
    }
}

#[test]
fn a_void_larger_than_a_tile_fills_the_same() {
    // A void of 3 × 3 tiles: the pyramid goes above the coarse level.
    let (tp, qp) = params(65);
    let mut hf = holey(9, 64 * 6 + 1, 64 * 5 + 7);
    for j in 40..260 {
        for i in 50..280 {
            hf.heights[[j, i]] = f32::NAN;
            hf.counts[[j, i]] = 0;
            hf.state[[j, i]] = CellState::Empty;
        }
    }
    let fill = FillParams::default();
    let want = whole(&hf, Some(&fill), &tp, &qp);
    assert!(want.fill.unwrap().fallback > 40_000);
    for block in [[1, 1], [2, 3], [6, 6]] {
        let layout = ShardLayout::new([hf.cols(), hf.rows()], &tp, block).unwrap();
        let got = run_all(&layout, &hf, Some(&fill), &tp, &qp).unwrap();
        assert_eq!(difference(&got, &want), None, "{block:?}");
    }
}

#[test]
fn fill_halo_is_tight() {
    // Two tiles side by side; shard 0 is the western one (samples 0..=64). Row 10 holds one
    // measured cell r cells east of the shard's last sample: the empty cell (64, 10) takes
    // its height from it alone. An input one cell narrower than the halo misses it.
    let (tp, qp) = params(65);
    let fill = FillParams {
        radius: 6.0,
        fallback: Fallback::Nodata,
        ..Default::default()
    };
    let r = fill_halo(&fill);
    let mut hf = Heightfield::empty(129, 65, [0.0, 0.0], [1.0, 1.0], 0.0, None);
    for j in 0..65 {
        for i in 0..129 {
            if j != 10 {
                hf.heights[[j, i]] = (i + j) as f32;
                hf.state[[j, i]] = CellState::Measured;
                hf.counts[[j, i]] = 1;
            }
        }
    }
    hf.heights[[10, 64 + r]] = 100.0;
    hf.state[[10, 64 + r]] = CellState::Measured;
    let layout = ShardLayout::new([129, 65], &tp, [1, 1]).unwrap();
    let shard = layout.shard(0);
    let input = shard.input(&layout, 0, Some(&fill));
    assert_eq!(input, 0..65 + r);
    let run = |cols: Range<usize>| {
        let inp = crop(&hf, cols.clone(), 0..65);
        let p = prepare(&layout, &shard, &inp, [cols.start, 0], Some(&fill)).unwrap();
        finish(&layout, p, &[], &tp, &qp).unwrap().tiles[0].heights[[10, 64]]
    };
    let want = {
        let mut g = hf.clone();
        fill::fill(&mut g, &fill).unwrap();
        g.heights[[10, 64]]
    };
    assert_eq!(run(input.clone()).to_bits(), want.to_bits());
    // Vertical neighbours exist (rows 9 and 11), so the cell is filled either way, but
    // without the eastern source its height differs.
    assert_ne!(run(0..64 + r).to_bits(), want.to_bits());
}

#[test]
fn smooth_ring_is_needed() {
    // A void straddling the border of two tiles, wider than the radius: the fallback's
    // bilinear pull reads the pyramid across the border. Without the ring (the shard's own
    // cells only, the pyramid of its own tiles) the cells near the border differ.
    let (tp, qp) = params(65);
    let hf = voids_on_borders(5, 129, 65, 64, 20);
    let fill = FillParams::default();
    let want = whole(&hf, Some(&fill), &tp, &qp);
    let layout = ShardLayout::new([129, 65], &tp, [1, 1]).unwrap();
    let got = run_all(&layout, &hf, Some(&fill), &tp, &qp).unwrap();
    assert_eq!(difference(&got, &want), None);
    // The same pull over the western tile alone, as if it were the whole grid.
    let mut west = crop(&hf, 0..65, 0..65);
    fill::fill(&mut west, &fill).unwrap();
    let differ = (0..65)
        .flat_map(|j| (0..65).map(move |i| (i, j)))
        .filter(|&(i, j)| {
            west.heights[[j, i]].to_bits() != want.set.tiles[0].heights[[j, i]].to_bits()
        })
        .count();
    assert!(differ > 0);
}

#[test]
fn d2_needs_the_merge() {
    // A spike in the eastern tile near the shared border: the shards alone disagree with the
    // whole run on the western tile's border nodes and on the roots; the merge restores both.
    let (tp, qp) = params(65);
    let mut hf =
        crate::terrain::testutil::field(129, 65, |i, j| (i as f32 * 0.1).sin() + j as f32 * 0.01);
    hf.heights[[33, 66]] = 40.0;
    let want = whole(&hf, None, &tp, &qp);
    let layout = ShardLayout::new([129, 65], &tp, [1, 1]).unwrap();
    let outs: Vec<ShardOutput> = (0..2)
        .map(|i| {
            let shard = layout.shard(i);
            let (ci, cj) = (shard.input(&layout, 0, None), shard.input(&layout, 1, None));
            let p = prepare(
                &layout,
                &shard,
                &crop(&hf, ci.clone(), cj.clone()),
                [ci.start, cj.start],
                None,
            )
            .unwrap();
            finish(&layout, p, &[], &tp, &qp).unwrap()
        })
        .collect();
    assert_ne!(node_bits(&outs[0].d2[0]), node_bits(&want.quadtree.d2[0]));
    let merged = merge(&layout, &hf, &tp, &qp, outs).unwrap();
    assert_eq!(difference(&merged, &want), None);
}

#[test]
fn bad_layouts_are_refused() {
    let (tp, _) = params(65);
    let e = ShardLayout::new([200, 200], &tp, [0, 1])
        .unwrap_err()
        .to_string();
    assert!(e.contains("block"), "{e}");
    let unreal = TileParams {
        preset: Preset::Unreal,
        ..Default::default()
    };
    let e = ShardLayout::new([200, 200], &unreal, [1, 1])
        .unwrap_err()
        .to_string();
    assert!(e.contains("preset"), "{e}");
    let hf = holey(1, 100, 100);
    let layout = ShardLayout::new([100, 100], &tp, [1, 1]).unwrap();
    let mean = FillParams {
        fallback: Fallback::Mean,
        ..Default::default()
    };
    let e = run_all(&layout, &hf, Some(&mean), &tp, &QuadtreeParams::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("fallback"), "{e}");
}

#[test]
fn the_resampled_survey_shards_the_same() {
    // A generated survey through the in-memory denoise and resample, then the grid half
    // whole and sharded.
    let scene = survey(11, 120_000);
    let c = &scene.cloud;
    let d = crate::terrain::denoise(c, &Default::default(), 1.0).unwrap();
    let hf = crate::terrain::resample(c, Some(&d.keep), &Default::default())
        .unwrap()
        .grid;
    let (tp, qp) = params(65);
    let fill = FillParams::default();
    let want = whole(&hf, Some(&fill), &tp, &qp);
    for block in [[1, 1], [2, 2], [3, 1], [100, 100]] {
        let layout = ShardLayout::new([hf.cols(), hf.rows()], &tp, block).unwrap();
        let got = run_all(&layout, &hf, Some(&fill), &tp, &qp).unwrap();
        assert_eq!(difference(&got, &want), None, "{block:?}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    #[test]
    fn sharded_equals_whole_on_random_grids(
        seed in 0u64..1000,
        cols in 66usize..330,
        rows in 66usize..330,
        big in any::<bool>(),
        radius in 1u32..20,
        half in 0usize..40,
        bx in 1usize..5,
        by in 1usize..5,
        nodata in any::<bool>(),
    ) {
        let size = if big { 129 } else { 65 };
        let (tp, qp) = params(size);
        let hf = voids_on_borders(seed, cols, rows, size - 1, half);
        let fill = FillParams {
            radius: radius as f64,
            fallback: if nodata { Fallback::Nodata } else { Fallback::Smooth },
            ..Default::default()
        };
        let want = whole(&hf, Some(&fill), &tp, &qp);
        let layout = ShardLayout::new([cols, rows], &tp, [bx, by]).unwrap();
        let got = run_all(&layout, &hf, Some(&fill), &tp, &qp).unwrap();
        prop_assert_eq!(difference(&got, &want), None);
    }
}

mod from_points {
    use super::*;
    use crate::shard::points::{run_points, Stages};
    use crate::terrain::denoise::DenoiseParams;
    use crate::terrain::resample::ResampleParams;

    fn stages(denoise: Option<DenoiseParams>, resample: ResampleParams) -> Stages {
        Stages {
            denoise,
            metres_per_unit: 1.0,
            resample,
            fill: Some(FillParams::default()),
            tiles: params(65).0,
            quadtree: QuadtreeParams::default(),
        }
    }

    /// The in-memory run: `grid_stages` (denoise, resample) and the whole grid half.
    fn in_memory(x: &[f64], y: &[f64], z: &[f64], st: &Stages) -> (Option<Vec<bool>>, u32, Merged) {
        let (keep, q) = match &st.denoise {
            Some(p) => {
                let d =
                    crate::terrain::denoise::denoise_xyz(x, y, z, p, st.metres_per_unit).unwrap();
                (Some(d.keep), d.settings.height_steps)
            }
            None => (None, 1),
        };
        let r =
            crate::terrain::resample::resample_xyz(x, y, z, keep.as_deref(), &st.resample, None)
                .unwrap();
        let m = whole(&r.grid, st.fill.as_ref(), &st.tiles, &st.quadtree);
        (keep, q, m)
    }

    fn check(
        x: &[f64],
        y: &[f64],
        z: &[f64],
        st: &Stages,
        groups: u64,
        block: [usize; 2],
    ) -> Option<String> {
        let (keep, q, want) = in_memory(x, y, z, st);
        let got = run_points(x, y, z, None, st, groups, block).unwrap();
        if got.keep != keep {
            let n = keep
                .as_ref()
                .zip(got.keep.as_ref())
                .map_or(0, |(a, b)| a.iter().zip(b).filter(|(p, q)| p != q).count());
            return Some(format!("keep flags differ at {n} points"));
        }
        if got.height_steps != q {
            return Some(format!("voxel height steps {} vs {q}", got.height_steps));
        }
        difference(&got.merged, &want)
    }

    #[test]
    fn a_generated_survey_shards_the_same() {
        let scene = survey(4, 60_000);
        let c = &scene.cloud;
        let st = stages(Some(DenoiseParams::default()), ResampleParams::default());
        for (groups, block) in [(1, [1, 1]), (2, [2, 1]), (5, [1, 3]), (1000, [9, 9])] {
            assert_eq!(
                check(&c.x, &c.y, &c.z, &st, groups, block),
                None,
                "{groups} {block:?}"
            );
        }
    }

    #[test]
    fn taller_voxels_are_chosen_the_same() {
        // min_points so high that a third of the points fail at q = 1: the voxel height
        // adapts, from the shards' summed counts.
        let scene = survey(8, 40_000);
        let c = &scene.cloud;
        let p = DenoiseParams {
            min_points: Some(60),
            ..Default::default()
        };
        let (_, q, _) = in_memory(
            &c.x,
            &c.y,
            &c.z,
            &stages(Some(p.clone()), Default::default()),
        );
        assert!(q > 1, "q = {q}");
        let st = stages(Some(p), ResampleParams::default());
        assert_eq!(check(&c.x, &c.y, &c.z, &st, 2, [1, 1]), None);
    }

    /// The keep flags of the points `of` when the window of voxel columns [0, 4)² is denoised
    /// reading `halo` columns around it, and as the whole run gives them.
    fn window_flags(
        pts: &[[f64; 3]],
        p: &DenoiseParams,
        halo: u64,
        of: std::ops::Range<usize>,
    ) -> (Vec<bool>, Vec<bool>) {
        use crate::terrain::denoise::{
            denoise_xyz, shard_denoise, ColumnWindow, Frame, ShardInput,
        };
        let col = |k: usize| pts.iter().map(|q| q[k]).collect::<Vec<f64>>();
        let (x, y, z) = (col(0), col(1), col(2));
        let whole = denoise_xyz(&x, &y, &z, p, 1.0).unwrap().keep;
        let (bounds, points) = crate::terrain::bounds_of(&x, &y, &z, None);
        let frame = Frame { bounds, points };
        let s = frame.settings(p, 1.0).unwrap();
        let own = ColumnWindow { x: 0..4, y: 0..4 };
        let idx: Vec<usize> = (0..x.len())
            .filter(|&i| {
                let (a, b) = frame.column(&s, x[i], y[i]);
                a < 4 + halo && b < 4 + halo
            })
            .collect();
        let pick = |v: &[f64]| idx.iter().map(|&i| v[i]).collect::<Vec<_>>();
        let (px, py, pz) = (pick(&x), pick(&y), pick(&z));
        let input = ShardInput {
            x: &px,
            y: &py,
            z: &pz,
            frame: &frame,
            params: p,
            metres_per_unit: 1.0,
            owned: &own,
        };
        let d = shard_denoise(&input, 1).unwrap();
        let mut keep = vec![false; x.len()];
        for (&i, &k) in idx.iter().zip(&d.keep) {
            keep[i] = k;
        }
        (keep[of.clone()].to_vec(), whole[of].to_vec())
    }

    /// Unit voxels, 3 points to a block, low layers detached by 4 units (low-layer columns of
    /// 4 × 4 voxel columns, slabs of 2 layers).
    fn unit_voxels(low_layers: bool) -> DenoiseParams {
        DenoiseParams {
            voxel_size: Some(1.0),
            voxel_height: Some(1.0),
            min_points: Some(3),
            low_layers,
            low_gap: Some(4.0),
            ..Default::default()
        }
    }

    /// `n` copies of the centre of voxel (i, j, k).
    fn voxel(i: u32, j: u32, k: u32, n: usize) -> Vec<[f64; 3]> {
        vec![[i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5]; n]
    }

    #[test]
    fn count_halo_is_tight() {
        // A point in the window's last column passes the 3×3×3 count only with the two
        // points in the next column: a halo of one column sees them, none does not.
        let mut pts = vec![[0.0, 0.0, 0.0]]; // anchors the lattice at the origin
        pts.extend(voxel(3, 1, 5, 1));
        pts.extend(voxel(4, 1, 5, 2));
        let p = unit_voxels(false);
        let (got, want) = window_flags(&pts, &p, 1, 1..2);
        assert_eq!((got, want.clone()), (vec![true], vec![true]));
        assert_ne!(window_flags(&pts, &p, 0, 1..2).0, want);
    }

    #[test]
    fn low_layer_halo_is_tight() {
        // Low-layer column (0, 0) holds a low patch of 3 points 20 layers under 20 ground
        // points: 13 % of its window, kept. Its neighbour low-layer column (1, 0) adds ten
        // ground points in its last voxel column (7), one per voxel three layers apart, each
        // passing the count only with two points in column 8: with them the patch is 3 / 33
        // of the window, under 10 %, and removed. A halo of one low-layer column and one
        // voxel column sees column 8; one low-layer column alone does not.
        let mut pts = vec![[0.0, 0.0, 0.0]];
        pts.extend(voxel(2, 2, 0, 3)); // the patch: points 1..4
        pts.extend(voxel(1, 1, 20, 20));
        for k in 0..10 {
            pts.extend(voxel(7, 1, 20 + 3 * k, 1));
            pts.extend(voxel(8, 1, 20 + 3 * k, 2));
        }
        let p = unit_voxels(true);
        let (got, want) = window_flags(&pts, &p, 5, 1..4);
        assert_eq!((got, want.clone()), (vec![false; 3], vec![false; 3]));
        assert_eq!(window_flags(&pts, &p, 4, 1..4).0, vec![true; 3]);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(16))]
        #[test]
        fn random_surveys_shard_the_same(
            seed in 0u64..1000,
            n in 3000usize..9000,
            width in 40u32..120,
            on_lattice in any::<bool>(),
            fixed_voxels in any::<bool>(),
            cell in any::<bool>(),
            groups in 1u64..4,
            bx in 1usize..3,
            by in 1usize..3,
        ) {
            let mut rng = crate::rng::SplitMix64::new(seed);
            let (w, h) = (width as f64, 0.8 * width as f64);
            // A hole of a fifth of the width at a random place, outliers above and below.
            let (hx, hy, hr) = (rng.unit() * w, rng.unit() * h, 0.1 * w);
            let (mut x, mut y, mut z) = (Vec::new(), Vec::new(), Vec::new());
            while x.len() < n {
                let (mut px, mut py) = (rng.unit() * w, rng.unit() * h);
                if on_lattice {
                    // Exactly on 0.5-unit lines: voxel and cell boundaries with the fixed sizes.
                    px = (px * 2.0).floor() / 2.0;
                    py = (py * 2.0).floor() / 2.0;
                }
                if (px - hx).hypot(py - hy) < hr {
                    continue;
                }
                let mut pz = 100.0 + 0.05 * px + (py * 0.2).sin();
                if rng.unit() < 0.003 {
                    pz += if rng.unit() < 0.5 { 60.0 } else { -30.0 };
                }
                x.push(px + 500_000.0);
                y.push(py + 4_000_000.0);
                z.push(pz);
            }
            let denoise = DenoiseParams {
                voxel_size: fixed_voxels.then_some(1.5),
                voxel_height: fixed_voxels.then_some(0.5),
                low_gap: Some(6.0),
                ..Default::default()
            };
            let resample = ResampleParams {
                cell_size: cell.then_some(1.0),
                ..Default::default()
            };
            let st = stages(Some(denoise), resample);
            let (keep, _, _) = in_memory(&x, &y, &z, &st);
            prop_assume!(keep.is_some());
            prop_assert_eq!(check(&x, &y, &z, &st, groups, [bx, by]), None);
        }
    }
}

#[test]
fn a_spilled_prepared_shard_reads_back_bit_for_bit() {
    // The streamed run's prepared shards go to disk between the smooth fill's two steps
    // when they do not fit the budget (`prepared_spill`); what comes back is what went out,
    // every bit of the cells, the pyramid and the offset, for every shard of the layout.
    let (tp, _) = params(65);
    let hf = voids_on_borders(5, 64 * 3 + 9, 64 * 2 + 1, 64, 13);
    let dir = tempfile::tempdir().unwrap();
    let fill = FillParams::default();
    let bits = |v: &[f32]| -> Vec<u32> { v.iter().map(|x| x.to_bits()).collect() };
    for block in [[1, 1], [2, 1], [4, 3]] {
        let layout = ShardLayout::new([hf.cols(), hf.rows()], &tp, block).unwrap();
        for i in 0..layout.count() {
            let shard = layout.shard(i);
            let (ci, cj) = (
                shard.input(&layout, 0, Some(&fill)),
                shard.input(&layout, 1, Some(&fill)),
            );
            let inp = crop(&hf, ci.clone(), cj.clone());
            let p = prepare(&layout, &shard, &inp, [ci.start, cj.start], Some(&fill)).unwrap();
            assert!(prepared_spill::put(dir.path(), &p).unwrap() > 0);
            let q = prepared_spill::take(dir.path(), &layout, i, Some(&fill), None).unwrap();
            let (a, b) = (&p.local, &q.local);
            assert_eq!(
                bits(a.heights.as_slice().unwrap()),
                bits(b.heights.as_slice().unwrap())
            );
            assert_eq!((&a.counts, &a.state), (&b.counts, &b.state));
            assert_eq!(
                (a.corner, a.cell_size, a.z_offset),
                (b.corner, b.cell_size, b.z_offset)
            );
            assert_eq!((&p.shard, p.offset), (&q.shard, q.offset));
            assert_eq!(p.pyramid.len(), q.pyramid.len());
            for ((v, h, w), (u, g, x)) in p.pyramid.iter().zip(&q.pyramid) {
                assert_eq!((bits(v), h, w), (bits(u), g, x));
            }
            let coarse = |p: &Prepared| -> Vec<(usize, u32)> {
                p.coarse(&layout)
                    .iter()
                    .map(|&(k, v)| (k, v.to_bits()))
                    .collect()
            };
            assert_eq!(coarse(&p), coarse(&q));
        }
    }
    // Each file is removed as it is read back.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    // A file damaged on disk is refused with its name and offset, never read as cells.
    let layout = ShardLayout::new([hf.cols(), hf.rows()], &tp, [2, 2]).unwrap();
    let shard = layout.shard(0);
    let (ci, cj) = (
        shard.input(&layout, 0, Some(&fill)),
        shard.input(&layout, 1, Some(&fill)),
    );
    let inp = crop(&hf, ci.clone(), cj.clone());
    let p = prepare(&layout, &shard, &inp, [ci.start, cj.start], Some(&fill)).unwrap();
    prepared_spill::put(dir.path(), &p).unwrap();
    let f = dir.path().join("prepared-0.bin");
    let mut b = std::fs::read(&f).unwrap();
    let last = b.len() - 1;
    b[last] ^= 0x40;
    std::fs::write(&f, &b).unwrap();
    let e = prepared_spill::take(dir.path(), &layout, 0, Some(&fill), None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("prepared-0.bin") && e.contains("checksum"),
        "{e}"
    );
}
