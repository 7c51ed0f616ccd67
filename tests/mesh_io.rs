//! Every mesh in the shared data loads with the counts SOURCES.md gives, and survives OBJ and
//! PLY round trips with everything it carries.

mod common;
#[path = "mesh_corpus/mod.rs"]
mod mesh_corpus;

use proptest::prelude::*;
use std::path::Path;
use terratile::mesh::io::{self, MeshFormat};
use terratile::mesh::{Adjacency, TriMesh};

/// (file, positions in the file, triangles, referenced vertices)
const MESHES: &[(&str, usize, usize, usize)] = &[
    ("bunny.obj", 35_947, 69_451, 34_834),
    ("triceratops.obj", 2_832, 5_660, 2_832),
    ("triceratops_source_polygons.obj", 2_832, 5_660, 2_832),
    ("cow.obj", 2_903, 5_804, 2_903),
    ("fandisk.obj", 6_475, 12_946, 6_475),
    ("spot.obj", 2_930, 5_856, 2_930),
    ("armadillo.obj", 49_999, 99_994, 49_999),
    ("dragon_10k.obj", 10_002, 20_000, 10_002),
    ("igea.ply", 134_345, 268_686, 134_345),
    ("pirate.obj", 2_889, 5_010, 2_889),
    ("colored_airplane.ply", 7_017, 10_796, 5_400),
];

fn distinct_positions(m: &TriMesh) -> usize {
    let w = m.weld_map();
    w.iter()
        .enumerate()
        .filter(|(i, &r)| *i as u32 == r)
        .count()
}

#[test]
fn every_shared_mesh_loads_with_its_documented_counts() {
    let Some(dir) = common::shared_data() else {
        return;
    };
    let dir = dir.join("meshes");
    let mut listed: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".obj") || n.ends_with(".ply"))
        .collect();
    listed.sort();
    let mut known: Vec<String> = MESHES.iter().map(|m| m.0.to_string()).collect();
    known.sort();
    assert_eq!(
        listed, known,
        "a mesh was added to the shared data: add it here"
    );
    for &(name, positions, triangles, referenced) in MESHES {
        let path = dir.join(name);
        let (m, info) = io::read_with_info(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        m.validate(name).unwrap();
        assert_eq!(m.triangle_count(), triangles, "{name}");
        // Seams split vertices (spot, pirate): count distinct positions instead.
        assert!(m.vertex_count() >= positions, "{name}");
        if m.uvs.is_none() && m.normals.is_none() {
            assert_eq!(m.vertex_count(), positions, "{name}");
        }
        let used = m.referenced().iter().filter(|u| **u).count();
        let used_positions = {
            let w = m.weld_map();
            let mut seen = vec![false; m.vertex_count()];
            for t in &m.indices {
                for &v in t {
                    seen[w[v as usize] as usize] = true;
                }
            }
            seen.iter().filter(|s| **s).count()
        };
        assert!(used >= referenced, "{name}");
        assert!(used_positions <= referenced, "{name}: {used_positions}");
        assert!(m.diagonal() > 0.0, "{name}");
        match name {
            "triceratops_source_polygons.obj" => {
                assert!(
                    info.warnings.iter().any(|w| w.contains("0-based")),
                    "{:?}",
                    info.warnings
                );
                assert_eq!(info.faces_in_file, 2_834);
            }
            "spot.obj" => assert!(m.uvs.is_some() && distinct_positions(&m) == 2_930),
            "pirate.obj" => assert!(m.uvs.is_some() && m.normals.is_some()),
            "colored_airplane.ply" => {
                let c = m.colors.as_ref().expect("colours");
                assert!(c.iter().any(|c| c[2] > c[0]), "the blue ramp");
            }
            _ => assert!(info.warnings.is_empty(), "{name}: {:?}", info.warnings),
        }
    }
}

#[test]
fn zero_based_source_matches_the_converted_triceratops() {
    let (Some(a), Some(b)) = (
        common::data_file("meshes/triceratops.obj"),
        common::data_file("meshes/triceratops_source_polygons.obj"),
    ) else {
        return;
    };
    let a = io::read(&a).unwrap();
    let b = io::read(&b).unwrap();
    assert_eq!(a.positions, b.positions);
    assert!(
        (a.area() - b.area()).abs() < 1e-6 * a.area(),
        "{} vs {}",
        a.area(),
        b.area()
    );
    // Same surface: the same edges on the polygon borders, closed and manifold.
    let adj = Adjacency::new(&b);
    assert_eq!(adj.boundary_edge_count(), 0);
    assert_eq!(adj.edge_faces.non_manifold_edges().count(), 0);
}

#[test]
fn shared_meshes_round_trip_through_obj_and_ply() {
    let Some(dir) = common::shared_data() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    for name in ["pirate.obj", "colored_airplane.ply", "spot.obj", "cow.obj"] {
        let m = io::read(&dir.join("meshes").join(name)).unwrap();
        for (ext, format) in [
            ("obj", MeshFormat::Obj),
            ("ply", MeshFormat::PlyBinaryLe),
            ("be.ply", MeshFormat::PlyBinaryBe),
            ("txt.ply", MeshFormat::PlyAscii),
        ] {
            let out = tmp.path().join(format!("{name}.{ext}"));
            io::write_as(&m, &out, format).unwrap();
            let back = io::read(&out).unwrap();
            assert_same(&m, &back, format, &format!("{name} as {ext}"));
        }
    }
}

fn assert_same(a: &TriMesh, b: &TriMesh, format: MeshFormat, what: &str) {
    assert_eq!(a.positions, b.positions, "{what}");
    assert_eq!(a.indices, b.indices, "{what}");
    assert_eq!(a.normals, b.normals, "{what}");
    assert_eq!(a.uvs, b.uvs, "{what}");
    assert_eq!(a.colors.is_some(), b.colors.is_some(), "{what}");
    if let (Some(x), Some(y)) = (&a.colors, &b.colors) {
        for (p, q) in x.iter().zip(y) {
            for k in 0..3 {
                assert!((p[k] - q[k]).abs() < 1e-6, "{what}: {p:?} {q:?}");
            }
            // OBJ has no alpha.
            if format != MeshFormat::Obj {
                assert!((p[3] - q[3]).abs() < 1e-6, "{what}: {p:?} {q:?}");
            }
        }
    }
}

fn arb_mesh() -> impl Strategy<Value = TriMesh> {
    (3usize..40, any::<[bool; 3]>()).prop_flat_map(|(n, [with_n, with_c, with_t])| {
        let coord = -1.0e4f32..1.0e4;
        (
            prop::collection::vec((coord.clone(), coord.clone(), coord), n),
            prop::collection::vec(prop::array::uniform3(0..n as u32), 1..60),
            prop::collection::vec(prop::array::uniform4(0u8..=255), n),
            prop::collection::vec((-2.0f32..2.0, -2.0f32..2.0), n),
        )
            .prop_map(move |(p, t, c, uv)| TriMesh {
                positions: p
                    .iter()
                    .map(|&(x, y, z)| glam::Vec3::new(x, y, z))
                    .collect(),
                indices: t,
                normals: with_n.then(|| {
                    p.iter()
                        .map(|&(x, y, z)| glam::Vec3::new(z, x, y))
                        .collect()
                }),
                colors: with_c.then(|| {
                    c.iter()
                        .map(|c| {
                            let l = |x: u8| terratile::mesh::srgb_to_linear(x as f32 / 255.0);
                            [l(c[0]), l(c[1]), l(c[2]), c[3] as f32 / 255.0]
                        })
                        .collect()
                }),
                uvs: with_t.then(|| uv.iter().map(|&(u, v)| glam::Vec2::new(u, v)).collect()),
            })
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn any_mesh_round_trips(m in arb_mesh()) {
        let tmp = tempfile::tempdir().unwrap();
        for (ext, format) in [("obj", MeshFormat::Obj), ("ply", MeshFormat::PlyBinaryLe), ("a.ply", MeshFormat::PlyAscii)] {
            let out = tmp.path().join(format!("m.{ext}"));
            io::write_as(&m, &out, format).unwrap();
            let back = io::read(&out).unwrap();
            assert_same(&m, &back, format, ext);
        }
    }
}

#[test]
fn unknown_extension_is_a_usage_error() {
    let m = TriMesh {
        positions: vec![glam::Vec3::ZERO; 3],
        indices: vec![[0, 1, 2]],
        ..Default::default()
    };
    let e = io::write(&m, Path::new("/tmp/x.stl")).unwrap_err();
    assert_eq!(e.exit_code(), 2);
    assert!(e.to_string().contains(".obj or .ply"), "{e}");
}

/// A small mesh with every attribute, as bytes in each format the readers take.
fn seed_files() -> Vec<(&'static str, Vec<u8>)> {
    use terratile::mesh::io::{obj, ply};
    let m = TriMesh {
        positions: vec![
            glam::Vec3::new(0.0, 0.0, 0.0),
            glam::Vec3::new(1.0, 0.0, 0.5),
            glam::Vec3::new(0.0, 1.0, -0.25),
            glam::Vec3::new(1.0, 1.0, 2.0),
        ],
        indices: vec![[0, 1, 2], [1, 3, 2]],
        normals: Some(vec![glam::Vec3::Z; 4]),
        colors: Some(vec![[0.2, 0.4, 0.6, 1.0]; 4]),
        uvs: Some(vec![glam::Vec2::new(0.5, 0.25); 4]),
    };
    let mut files = Vec::new();
    let mut o = Vec::new();
    obj::write_obj(&m, &mut o).unwrap();
    // Polygons, negative indices and groups too, for the OBJ reader's other paths.
    o.extend_from_slice(b"g quad\nf -4/-4/-4 -3/-3/-3 -1/-1/-1 -2/-2/-2\n");
    files.push(("m.obj", o));
    for (name, enc) in [
        ("a.ply", ply::Encoding::Ascii),
        ("le.ply", ply::Encoding::BinaryLittleEndian),
        ("be.ply", ply::Encoding::BinaryBigEndian),
    ] {
        let mut b = Vec::new();
        ply::write_ply(&m, &mut b, enc).unwrap();
        files.push((name, b));
    }
    // glb as the tile writer makes it (positions, normals, indices).
    files.push((
        "m.glb",
        terratile::mesh::io::glb_bytes(&m, "m", 1.0).unwrap(),
    ));
    // And the lenient paths: each corpus file (dropped attributes, short faces, line
    // continuations, header counts, glb ranges).
    for c in mesh_corpus::cases() {
        files.push((c.name, c.bytes));
    }
    files
}

/// Parses `bytes` with the reader `name`'s extension picks (glb and PLY also by content,
/// as `io::read` does).
fn parse(name: &str, bytes: &[u8], strict: bool) -> terratile::Result<(TriMesh, io::ReadInfo)> {
    use terratile::mesh::io::{glb, obj, ply, ReadOptions};
    let opts = ReadOptions { strict };
    let path = Path::new(name);
    if bytes.starts_with(b"ply") {
        ply::parse_ply_with(path, bytes, &opts)
    } else if bytes.starts_with(b"glTF") {
        glb::parse_glb(path, bytes, &opts)
    } else if name.ends_with(".obj") {
        obj::parse_obj_with(path, bytes, &opts)
    } else {
        // A damaged magic: the file reader would refuse it by name; the parser of its
        // extension must still cope.
        match name.rsplit('.').next() {
            Some("ply") => ply::parse_ply_with(path, bytes, &opts),
            _ => glb::parse_glb(path, bytes, &opts),
        }
    }
}

/// A read mesh is usable: indices in range, finite positions, attributes one per vertex.
fn usable(m: &TriMesh) -> bool {
    let n = m.positions.len();
    m.indices.iter().flatten().all(|&v| (v as usize) < n)
        && m.positions.iter().all(|p| p.is_finite())
        && m.normals.as_ref().is_none_or(|a| a.len() == n)
        && m.uvs.as_ref().is_none_or(|a| a.len() == n)
        && m.colors.as_ref().is_none_or(|a| a.len() == n)
}

/// One damage to a file: overwrite a byte, cut the file short, or insert bytes.
#[derive(Debug, Clone)]
enum Damage {
    Set(usize, u8),
    Truncate(usize),
    Insert(usize, Vec<u8>),
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Damage::Set(i, b)),
        any::<usize>().prop_map(Damage::Truncate),
        (
            any::<usize>(),
            prop::collection::vec(
                prop_oneof![
                    any::<u8>(),
                    Just(b'\n'),
                    Just(b' '),
                    Just(b'-'),
                    Just(b'/'),
                    Just(b'9')
                ],
                1..12
            )
        )
            .prop_map(|(i, v)| Damage::Insert(i, v)),
    ]
}

fn apply(bytes: &mut Vec<u8>, d: &Damage) {
    let n = bytes.len().max(1);
    match d {
        Damage::Set(i, b) => {
            if !bytes.is_empty() {
                bytes[i % n] = *b;
            }
        }
        Damage::Truncate(i) => bytes.truncate(i % n),
        Damage::Insert(i, v) => {
            let at = i % n;
            bytes.splice(at..at, v.iter().copied());
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]
    /// Damaged OBJ and PLY files never panic the readers: each either still reads (into a
    /// mesh whose indices are all in range) or fails with an error that names the file.
    #[test]
    fn damaged_files_are_errors_not_panics(
        which in 0usize..64,
        damages in prop::collection::vec(damage(), 1..6),
        strict in any::<bool>(),
    ) {
        let mut seeds = seed_files();
        let (name, mut bytes) = seeds.swap_remove(which % seeds.len());
        for d in &damages {
            apply(&mut bytes, d);
        }
        match parse(name, &bytes, strict) {
            Ok((m, info)) => {
                prop_assert!(usable(&m));
                prop_assert!(info.warnings.iter().all(|w| !w.contains('\n')));
            }
            Err(e) => {
                let msg = e.to_string();
                prop_assert!(msg.contains(name), "{}", msg);
                prop_assert!(!msg.contains('\n'), "{}", msg);
            }
        }
    }
}

/// Mutations for the long run: byte damage plus numbers that make counts and indices
/// huge, negative or not numbers at all.
fn mutate(bytes: &mut Vec<u8>, rng: &mut terratile::rng::SplitMix64) {
    const WORDS: &[&[u8]] = &[
        b"4294967295",
        b"1000000000000000000",
        b"-1",
        b"0",
        b"nan",
        b"inf",
        b"1e308",
        b"18446744073709551615",
        b"\\\n",
        b"\n",
        b" ",
        b"/",
        b"-",
        b"9",
        b"}",
        b"[",
        b",",
    ];
    for _ in 0..1 + rng.next_u64() % 4 {
        let n = bytes.len().max(1);
        let at = (rng.next_u64() as usize) % n;
        match rng.next_u64() % 6 {
            0 | 1 => {
                if !bytes.is_empty() {
                    bytes[at] = rng.next_u64() as u8;
                }
            }
            2 => bytes.truncate(at),
            3 => {
                let w = WORDS[(rng.next_u64() as usize) % WORDS.len()];
                bytes.splice(at..at, w.iter().copied());
            }
            4 => {
                // Replace a run of digits with a word (counts, indices, lengths).
                let w = WORDS[(rng.next_u64() as usize) % 8];
                let start = (at..bytes.len()).find(|&i| bytes[i].is_ascii_digit());
                if let Some(s) = start {
                    let e = (s..bytes.len())
                        .find(|&i| !bytes[i].is_ascii_digit())
                        .unwrap_or(bytes.len());
                    bytes.splice(s..e, w.iter().copied());
                }
            }
            _ => {
                // A little-endian u32 of an extreme value (binary counts and lengths).
                let v = [u32::MAX, 0x8000_0000, 0x7fff_ffff, 0][(rng.next_u64() % 4) as usize];
                for (k, b) in v.to_le_bytes().iter().enumerate() {
                    if at + k < bytes.len() {
                        bytes[at + k] = *b;
                    }
                }
            }
        }
    }
}

/// The long run: at least 1,000,000 mutated cases per mesh parser (PLY ASCII, PLY binary,
/// OBJ, glb), each seed's mutants in parallel; counts panics and cases slower than a second
/// (hangs), and prints the figures. Run it under a memory cap:
/// `prlimit --as=8589934592 cargo test --release --test mesh_io -- --ignored --nocapture million`.
#[test]
#[ignore = "long: about a minute per parser"]
fn a_million_mutants_per_parser() {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
    let cases: u64 = std::env::var("MESH_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1_000_000);
    let seeds = seed_files();
    /// Which seeds (name, bytes) a parser's run takes.
    type Pick = fn(&str, &[u8]) -> bool;
    let kinds: [(&str, Pick); 4] = [
        ("PLY ascii", |n, b| {
            n.ends_with(".ply") && b.starts_with(b"ply\nformat ascii")
        }),
        ("PLY binary", |n, b| {
            n.ends_with(".ply") && b.starts_with(b"ply\nformat binary")
        }),
        ("OBJ", |n, _| n.ends_with(".obj")),
        ("glb", |n, _| n.ends_with(".glb")),
    ];
    let prev = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let mut failures = Vec::new();
    for (kind, pick) in kinds {
        let mine: Vec<&(&str, Vec<u8>)> = seeds.iter().filter(|(n, b)| pick(n, b)).collect();
        assert!(!mine.is_empty(), "{kind}: no seeds");
        let (ok, errors, panics, slow) = (
            AtomicU64::new(0),
            AtomicU64::new(0),
            AtomicU64::new(0),
            AtomicU64::new(0),
        );
        let worst = std::sync::Mutex::new(0f64);
        let first = std::sync::Mutex::new(Vec::<String>::new());
        let t = std::time::Instant::now();
        (0..cases).into_par_iter().for_each(|i| {
            let mut rng = terratile::rng::SplitMix64::new(i ^ 0x5eed_0000_0000);
            // Half the cases damage the parser's well-formed seed (the first: a whole mesh,
            // so damage reaches the data paths), half the corpus files.
            let pick = if i % 2 == 0 {
                0
            } else {
                (i as usize / 2) % mine.len()
            };
            let (name, seed) = mine[pick];
            let mut bytes = seed.clone();
            mutate(&mut bytes, &mut rng);
            let strict = i % 4 >= 2;
            let c = std::time::Instant::now();
            let r =
                std::panic::catch_unwind(|| parse(name, &bytes, strict).map(|(m, _)| usable(&m)));
            let secs = c.elapsed().as_secs_f64();
            if secs > 1.0 {
                slow.fetch_add(1, Relaxed);
            }
            {
                let mut w = worst.lock().unwrap();
                *w = w.max(secs);
            }
            match r {
                Ok(Ok(true)) => ok.fetch_add(1, Relaxed),
                Ok(Err(e)) if e.to_string().contains(name) => errors.fetch_add(1, Relaxed),
                other => {
                    let what = match other {
                        Ok(Ok(_)) => "an unusable mesh".to_string(),
                        Ok(Err(e)) => format!("an error without the file name: {e}"),
                        Err(p) => format!(
                            "a panic: {}",
                            p.downcast_ref::<String>()
                                .cloned()
                                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                                .unwrap_or_default()
                        ),
                    };
                    let mut f = first.lock().unwrap();
                    if let Some(dir) = std::env::var_os("MESH_FUZZ_KEEP") {
                        let _ = std::fs::write(Path::new(&dir).join(format!("{i}-{name}")), &bytes);
                    }
                    if f.len() < 3 {
                        f.push(format!("{kind} case {i} ({name}): {what}"));
                    }
                    panics.fetch_add(1, Relaxed)
                }
            };
        });
        let (ok, errors, panics, slow) = (
            ok.into_inner(),
            errors.into_inner(),
            panics.into_inner(),
            slow.into_inner(),
        );
        println!(
            "{kind}: {cases} cases from {} seeds in {:.1} s: {ok} read, {errors} refused, {panics} panics or bad results, {slow} over 1 s (slowest {:.3} s)",
            mine.len(),
            t.elapsed().as_secs_f64(),
            *worst.lock().unwrap()
        );
        for f in first.into_inner().unwrap() {
            println!("  {f}");
        }
        if panics > 0 || slow > 0 {
            failures.push(kind);
        }
    }
    std::panic::set_hook(prev);
    assert!(failures.is_empty(), "failures in {failures:?}");
}
