//! Corrupted files never panic the readers: random byte damage to the header, VLRs and
//! first records of LAS and LAZ files gives either points or an error.

use crate::common;

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
    terratile::generate::write_cloud(&las, scene.cloud, terratile::generate::OutFormat::Las)
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

use crate::point_corpus as corpus;

/// The seed inputs of every point-side parser: a LAS 1.4 file with an EVLR, a LAS 1.2 and a
/// LAZ in point format 3, XYZ text, and the pipeline TOML of the repository.
fn seeds() -> Vec<(&'static str, Vec<u8>)> {
    vec![
        ("a.las", corpus::las14(40, None, None, 0.01, 1000.0)),
        ("b.las", corpus::las_format3(200, 3, false)),
        ("c.laz", corpus::las_format3(200, 3, true)),
        ("d.xyz", corpus::xyz_grid(300).into_bytes()),
        (
            "p.toml",
            std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/pipeline.toml")).unwrap(),
        ),
    ]
}

/// Values that make header fields interesting: zero, one, the sign and size boundaries, and
/// lengths far beyond any file.
const INTERESTING: [u64; 10] = [
    0,
    1,
    0x7F,
    0xFF,
    0x7FFF_FFFF,
    0x8000_0000,
    0xFFFF_FFFF,
    1 << 35,
    1 << 62,
    u64::MAX,
];

/// One mutant of `seed`, drawn from `r`: 1–8 edits (random bytes, interesting little-endian
/// integers of 1, 2, 4 or 8 bytes, mostly in the first 400 bytes where the LAS header and VLRs
/// live), sometimes an insertion or deletion (text), sometimes a truncation.
fn mutate(seed: &[u8], r: &mut terratile::SplitMix64) -> Vec<u8> {
    let mut b = seed.to_vec();
    let edits = 1 + r.below(8);
    for _ in 0..edits {
        if b.is_empty() {
            break;
        }
        let len = b.len() as u64;
        let at = if r.below(10) < 7 {
            r.below(len.min(400))
        } else {
            r.below(len)
        } as usize;
        match r.below(6) {
            0 | 1 => b[at] = r.next_u64() as u8,
            2 => b[at] ^= 1 << r.below(8),
            3 => {
                let v = INTERESTING[r.below(INTERESTING.len() as u64) as usize];
                let w = [1usize, 2, 4, 8][r.below(4) as usize];
                let end = (at + w).min(b.len());
                let bytes = v.to_le_bytes();
                b[at..end].copy_from_slice(&bytes[..end - at]);
            }
            4 => {
                let c = b"0123456789.-+eE ,\n#\t\xff\x00[]=\"xyz"[r.below(26) as usize];
                b.insert(at, c);
            }
            _ => {
                b.remove(at);
            }
        }
    }
    if r.below(10) == 0 {
        let cut = r.below(b.len() as u64 + 1) as usize;
        b.truncate(cut);
    }
    b
}

/// Parses `bytes` as the parser of `name` would see them (a file `path` with that content):
/// Ok(true) for a result, Ok(false) for an error that names the file, Err(message) for an
/// error that does not.
fn parse_one(name: &str, path: &std::path::Path, bytes: &[u8]) -> Result<bool, String> {
    let r = if name.ends_with(".toml") {
        match String::from_utf8(bytes.to_vec()) {
            Ok(text) => terratile::config::parse(path, &text).map(|_| ()),
            Err(_) => return Ok(false),
        }
    } else {
        points::read_bytes(path, bytes, &ReadOptions::default(), &NoProgress).map(|_| ())
    };
    match r {
        Ok(()) => Ok(true),
        Err(e) if e.to_string().contains(name) => Ok(false),
        Err(e) => Err(format!("error without the file: {e}")),
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]
    // Mutants of LAS 1.4 (with EVLRs), LAS/LAZ in point format 3, XYZ and pipeline TOML give a
    // result or an error naming the file, never a panic (the CI-sized run; see
    // `million_mutants_per_parser` for the long one).
    #[test]
    fn mutated_point_inputs_and_pipelines_never_panic(which in 0usize..5, seed in any::<u64>()) {
        let seeds = seeds();
        let (name, bytes) = &seeds[which];
        let mut r = terratile::SplitMix64::new(seed);
        let m = mutate(bytes, &mut r);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(name);
        let out = std::panic::catch_unwind(|| parse_one(name, &path, &m));
        prop_assert!(out.is_ok(), "{name} panicked on mutant of seed {seed}");
        if let Ok(Err(msg)) = out {
            prop_assert!(false, "{name}, seed {seed}: {msg}");
        }
    }
}

/// The bad inputs of issue 14 (the corpus) all give an error naming the file, in process.
#[test]
fn issue_14_corpus_gives_errors() {
    let dir = tempfile::tempdir().unwrap();
    let cases: Vec<(&str, Vec<u8>)> = vec![
        (
            "evlr35.las",
            corpus::las14(10, Some(1 << 35), None, 0.01, 0.0),
        ),
        (
            "evlr62.las",
            corpus::las14(10, Some(1 << 62), None, 0.01, 0.0),
        ),
        ("evlr1.las", corpus::las14(10, None, Some(1), 0.01, 0.0)),
        ("scale.las", corpus::las14(10, None, None, 1e308, 0.0)),
        ("offset.las", corpus::las14(10, None, None, 0.01, 1.7e308)),
        ("count32.laz", corpus::laz_with_count(u32::MAX)),
        ("count31.laz", corpus::laz_with_count(1 << 31)),
        ("table.laz", corpus::laz_junk_chunk_table()),
    ];
    for (name, bytes) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, &bytes).unwrap();
        let e = points::read(&path, &ReadOptions::default(), &NoProgress)
            .expect_err(name)
            .to_string();
        assert!(e.contains(name) && e.contains("byte "), "{e}");
    }
}

/// The long run: `FUZZ_CASES` (default 1,000,000) mutants per seed input, counting panics,
/// errors without the file name and slow cases (over 5 s: a hang in the making). An abort
/// (allocation failure) ends the process, so finishing is the proof of none; run it under a
/// memory cap:
///
/// `prlimit --as=8589934592 cargo test --release --test tests read_fuzz::million -- --ignored --nocapture`
#[test]
#[ignore]
fn million_mutants_per_parser() {
    let cases: u64 = std::env::var("FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1_000_000);
    let only = std::env::var("FUZZ_ONLY").ok();
    std::panic::set_hook(Box::new(|_| {}));
    let dir = tempfile::tempdir().unwrap();
    let mut failed = Vec::new();
    for (k, (name, seed)) in seeds().into_iter().enumerate() {
        if only.as_deref().is_some_and(|o| o != name) {
            continue;
        }
        let path = dir.path().join(name);
        let mut r = terratile::SplitMix64::new(0x5EED + k as u64);
        let (mut panics, mut unnamed, mut slow, mut ok, mut errors) =
            (0u64, 0u64, 0u64, 0u64, 0u64);
        let mut slowest = 0f64;
        let t0 = std::time::Instant::now();
        for i in 0..cases {
            let m = mutate(&seed, &mut r);
            let t = std::time::Instant::now();
            let out = std::panic::catch_unwind(|| parse_one(name, &path, &m));
            let s = t.elapsed().as_secs_f64();
            slowest = slowest.max(s);
            if s > 5.0 {
                slow += 1;
            }
            match out {
                Err(_) => {
                    panics += 1;
                    if panics <= 3 {
                        let keep = std::env::temp_dir().join(format!("fuzz-panic-{name}-{i}"));
                        std::fs::write(&keep, &m).unwrap();
                        failed.push(keep);
                    }
                }
                Ok(Err(_)) => unnamed += 1,
                Ok(Ok(true)) => ok += 1,
                Ok(Ok(false)) => errors += 1,
            }
        }
        println!(
            "{name}: {cases} mutants, {ok} read, {errors} clean errors, {panics} panics, \
             {unnamed} errors without the file, {slow} over 5 s (slowest {slowest:.3} s), 0 aborts, {:.0} s",
            t0.elapsed().as_secs_f64()
        );
        assert_eq!(panics + unnamed + slow, 0, "{name}: kept {failed:?}");
    }
}
