//! Progressive strips.

use terratile::simplify::strips::stripify::triangle_set;
use terratile::simplify::strips::{dtfs, stss, unstripify, Join};

/// DTFS started each new strip with the triangle as drawn, so a strip restarted at an
/// odd-parity triple (drawn (b, a, c)) could not take the next triple, (b, c, d), as a
/// regular continuation: after a collapse, the survivors of a strip came out as one- and
/// two-triangle strips, more indices than STSS and 3.4 per triangle at the base level of
/// bunny. 3 → 2 in the strip 0..=6 leaves (0 1 2), (2 4 5) odd and (4 5 6): DTFS wrote
/// 11 indices (0 1 2 R 4 2 5 R 4 5 6); the strip itself, 7, is the least.
#[test]
fn dtfs_restarted_strips_lost_the_input_continuation_at_odd_parity() {
    let s = [0, 1, 2, 2, 4, 5, 6];
    for join in [Join::Restart, Join::Degenerate] {
        let d = dtfs(&s, join);
        assert_eq!(triangle_set(unstripify(&d)), triangle_set(unstripify(&s)));
        assert_eq!(d.len(), 7, "{join:?}: {d:?}");
        assert!(d.len() <= stss(&s, join).len());
    }
    // A strip whose first drawn triple is odd: (3 4 5) drawn (4 3 5), then (4 5 6) and
    // (5 6 7). It was 0 1 2 R 4 3 5 R 4 5 6 7 (12); now the run stays whole: 3 3 4 5 6 7.
    const R: u32 = u32::MAX;
    let s = [0, 1, 2, R, 3, 3, 4, 5, 6, 7];
    let d = dtfs(&s, Join::Restart);
    assert_eq!(triangle_set(unstripify(&d)), triangle_set(unstripify(&s)));
    assert_eq!(d.len(), 10, "{d:?}");
}

/// The glb reader turned every window of a `TRIANGLE_STRIP` primitive into a triangle, the
/// windows with a repeated index too: a strip with swaps or joined strips (glTF forbids the
/// restart index, so strips are joined that way) read back with degenerate triangles, 987
/// for the 290 of cow's base level.
#[test]
fn glb_strip_reader_kept_the_degenerate_joining_triangles() {
    use terratile::mesh::io;
    let mesh = terratile::mesh::TriMesh {
        positions: (0..6)
            .map(|i| glam::Vec3::new(i as f32, (i % 2) as f32, 0.0))
            .collect(),
        ..Default::default()
    };
    // Two strips (0 1 2 3) and (3 4 5) joined by repeating 3 twice.
    let strip = [0, 1, 2, 3, 3, 3, 4, 5];
    let glb = io::glb_primitive(&mesh, &strip, io::TRIANGLE_STRIP, "m", 1.0).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.glb");
    std::fs::write(&path, glb).unwrap();
    let back = io::read(&path).unwrap();
    assert_eq!(back.triangle_count(), unstripify(&strip).len());
    assert_eq!(back.triangle_count(), 3);
}

/// The swap case {a, b, c, b, f} never fired: it tested the same condition as the regular
/// case, so a triangle across the other outgoing edge (a fan turning around one vertex)
/// always started a new strip. Four triangles of a fan around vertex 0, given one strip
/// each: DTFS now joins them into one strip (swaps as repeated vertices, no restart).
#[test]
fn dtfs_swap_case_never_fired_so_fans_were_split() {
    const R: u32 = u32::MAX;
    let s = [1, 0, 2, R, 2, 0, 3, R, 3, 0, 4, R, 4, 0, 5];
    let d = dtfs(&s, Join::Restart);
    assert_eq!(triangle_set(unstripify(&d)), triangle_set(unstripify(&s)));
    assert!(!d.contains(&R), "one strip: {d:?}");
    assert_eq!(d, [1, 0, 2, 0, 3, 0, 4, 5]);
}

/// Fig. 4's x axis ran to the next round tick past the last level (40k for bunny's 33,038
/// splits), so the curves stopped at 83 % of the plot's width. The full level is now the
/// axis' right end: the DTFS curve (red) reaches the frame's right edge.
#[test]
fn fig4_x_axis_ran_past_the_last_level() {
    use terratile::simplify::strips::measure::LevelIndices;
    let row = |level: usize| LevelIndices {
        level,
        triangles: 1000 + level,
        unfiltered: 3000,
        stss: 2500 + level / 2,
        dtfs: 2000 + level / 2,
        dtfs_restarts: 10,
        list: 3 * (1000 + level),
    };
    let rows: Vec<LevelIndices> = (0..=10).map(|i| row(i * 33_038 / 10)).collect();
    let png = terratile::simplify::strips::figure::fig4_png(&rows, &[], "test").unwrap();
    let img = image::load_from_memory(&png).unwrap().to_rgb8();
    let red = img
        .enumerate_pixels()
        .filter(|(_, _, p)| p.0 == [200, 40, 40])
        .map(|(x, _, _)| x)
        .max()
        .unwrap();
    // The frame's right edge is at 900 − 30; a 2-pixel stroke may reach one past it.
    assert!(
        (869..=871).contains(&red),
        "rightmost DTFS pixel at x = {red}"
    );
}
