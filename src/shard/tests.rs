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

fn bits(v: &NodeValues) -> Vec<u32> {
    let k = (v.size() - 1).trailing_zeros();
    (1..=k)
        .flat_map(|m| v.level(m).iter().map(|x| x.to_bits()).collect::<Vec<_>>())
        .collect()
}

/// Where `a` and `b` differ (None: bit-identical tiles, d2, vertical error and figures).
fn difference(a: &Merged, b: &Merged) -> Option<String> {
    let (sa, sb) = (&a.set, &b.set);
    if (sa.tile_size, sa.grid, sa.samples, sa.corner, sa.cell_size)
        != (sb.tile_size, sb.grid, sb.samples, sb.corner, sb.cell_size)
    {
        return Some("set geometry".into());
    }
    if a.fill != b.fill {
        return Some(format!("fill report {:?} vs {:?}", a.fill, b.fill));
    }
    for (k, (x, y)) in sa.tiles.iter().zip(&sb.tiles).enumerate() {
        if (x.col, x.row, x.origin, x.valid, x.holes) != (y.col, y.row, y.origin, y.valid, y.holes)
        {
            return Some(format!("tile {k} placement"));
        }
        let hb = |t: &Tile| t.heights.iter().map(|h| h.to_bits()).collect::<Vec<_>>();
        if hb(x) != hb(y) {
            return Some(format!("tile {k} heights"));
        }
        if bits(&a.quadtree.d2[k]) != bits(&b.quadtree.d2[k]) {
            return Some(format!("tile {k} d2"));
        }
        if bits(&a.vertical_error[k]) != bits(&b.vertical_error[k]) {
            return Some(format!("tile {k} vertical error"));
        }
    }
    None
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
    assert_ne!(bits(&outs[0].d2[0]), bits(&want.quadtree.d2[0]));
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
    let scene = crate::generate::generate(&crate::generate::GenerateParams {
        seed: 11,
        points: 120_000,
        ..Default::default()
    })
    .unwrap();
    let g = crate::terrain::grid_stages(
        &scene.cloud,
        Some(&Default::default()),
        &Default::default(),
        None,
        &crate::progress::NoProgress,
    )
    .unwrap();
    let hf = g.resampled.grid;
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
