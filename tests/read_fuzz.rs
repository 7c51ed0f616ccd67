//! Corrupted files never panic the readers: random byte damage to the header, VLRs and
//! first records of LAS and LAZ files gives either points or an error.

mod common;

use proptest::prelude::*;
use terratile::points::{self, ReadOptions};
use terratile::NoProgress;

fn small_files() -> Vec<(String, Vec<u8>)> {
    let dir = tempfile::tempdir().unwrap();
    let scene = terratile::generate::generate(&terratile::generate::GenerateParams {
        seed: 11,
        points: 300,
        size: Some([30.0, 30.0]),
        ..Default::default()
    })
    .unwrap();
    let las = dir.path().join("s.las");
    terratile::generate::write_scene(&scene, &las, &[terratile::generate::OutFormat::Las], (1, 1))
        .unwrap();
    let mut files = vec![("s.las".to_string(), std::fs::read(&las).unwrap())];
    // A real LAZ (small) when the shared data is there.
    if let Some(p) = common::data_file("lidar/Topography.laz") {
        files.push(("t.laz".to_string(), std::fs::read(p).unwrap()));
    }
    files
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]
    #[test]
    fn damaged_headers_give_errors_not_panics(
        which in 0usize..2,
        edits in proptest::collection::vec((0usize..1400, any::<u8>()), 1..6),
        cut in proptest::option::of(0usize..4000),
    ) {
        let files = small_files();
        let (name, mut bytes) = files[which % files.len()].clone();
        for (at, b) in edits {
            if at < bytes.len() {
                bytes[at] = b;
            }
        }
        if let Some(c) = cut {
            bytes.truncate(c.min(bytes.len()));
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(&name);
        std::fs::write(&path, &bytes).unwrap();
        let r = std::panic::catch_unwind(|| points::read(&path, &ReadOptions::default(), &NoProgress));
        prop_assert!(r.is_ok(), "reader panicked on damaged {name}");
        if let Ok(Err(e)) = r {
            let msg = e.to_string();
            prop_assert!(msg.contains(&name), "error names the file: {msg}");
        }
    }
}
