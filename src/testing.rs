//! Support shared by the unit tests of every module.

/// `f` run on a rayon pool of `threads` workers.
pub(crate) fn on_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

/// Runs `f` on 1, 2 and 8 worker threads and asserts that the three results are equal: a
/// parallel stage's output must not depend on the thread count.
pub(crate) fn assert_same_for_any_thread_count<T>(f: impl Fn() -> T + Sync)
where
    T: PartialEq + std::fmt::Debug + Send,
{
    let one = on_threads(1, &f);
    for threads in [2, 8] {
        assert_eq!(on_threads(threads, &f), one, "{threads} threads");
    }
}

/// A 2 × 3 quad of two triangles (z up, heights 1, 1.5, 1, 0.5 at its corners) with normals:
/// the smallest mesh every writer and reader of the glb format must carry exactly.
pub(crate) fn quad() -> crate::mesh::TriMesh {
    use glam::Vec3;
    crate::mesh::TriMesh {
        positions: vec![
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(2.0, 0.0, 1.5),
            Vec3::new(2.0, 3.0, 1.0),
            Vec3::new(0.0, 3.0, 0.5),
        ],
        indices: vec![[0, 1, 2], [0, 2, 3]],
        normals: Some(vec![Vec3::Z; 4]),
        ..Default::default()
    }
}
