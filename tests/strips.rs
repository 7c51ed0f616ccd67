//! Progressive strips on the shared meshes: stripify against meshoptimizer, every split
//! decoded back to the original, the stream round trip, and the paper's figures.

use crate::common;
use terratile::mesh::{io, TriMesh};
use terratile::simplify::strips::measure::{even_levels, gpu_indices};
use terratile::simplify::strips::progressive::engine_input;
use terratile::simplify::strips::stripify::{acmr, triangle_set};
use terratile::simplify::strips::{figure, format};
use terratile::simplify::strips::{
    progressive, stripify, unstripify, Decoder, Encoding, Join, ProgressiveParams, StripOrder,
    StripParams, RESTART,
};

fn load(name: &str) -> Option<TriMesh> {
    Some(io::read(&common::data_file(&format!("meshes/{name}"))?).unwrap())
}

const MESHES: [&str; 11] = [
    "armadillo.obj",
    "bunny.obj",
    "colored_airplane.ply",
    "cow.obj",
    "dragon_10k.obj",
    "fandisk.obj",
    "igea.ply",
    "pirate.obj",
    "spot.obj",
    "triceratops.obj",
    "triceratops_source_polygons.obj",
];

fn flat(m: &TriMesh) -> Vec<u32> {
    m.indices.iter().flatten().copied().collect()
}

#[test]
fn unstripify_of_stripify_is_the_mesh_on_every_shared_mesh() {
    for name in MESHES {
        let Some(m) = load(name) else { return };
        let want = triangle_set(m.indices.iter().copied());
        for join in [Join::Restart, Join::Degenerate] {
            for window in [0, 8] {
                let s = stripify(&m.indices, &StripParams { join, window });
                assert_eq!(
                    triangle_set(unstripify(&s)),
                    want,
                    "{name} {join:?} {window}"
                );
            }
        }
    }
}

/// Indices per triangle and ACMR (FIFO 16 over the strip's own index sequence) of ours
/// and of meshoptimizer's stripify, from the same triangle order.
fn compare(m: &TriMesh, indices: &[u32]) -> [(f64, f64); 2] {
    let t = indices.len() / 3;
    let tris: Vec<[u32; 3]> = indices.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
    let ours = stripify(&tris, &StripParams::default());
    let theirs = meshopt::stripify(indices, m.vertex_count(), RESTART).unwrap();
    let row = |s: &[u32]| (s.len() as f64 / t as f64, acmr(s, 16, t));
    [row(&ours), row(&theirs)]
}

#[test]
fn stripify_against_meshoptimizer() {
    for name in ["bunny.obj", "cow.obj", "dragon_10k.obj", "armadillo.obj"] {
        let Some(m) = load(name) else { return };
        let own = flat(&m);
        let opt = meshopt::optimize_vertex_cache(&own, m.vertex_count());
        for (what, order) in [("file order", &own), ("after optimize_vertex_cache", &opt)] {
            let [(ours, ours_acmr), (theirs, theirs_acmr)] = compare(&m, order);
            println!(
                "{name} {what}: indices/triangle ours {ours:.3} meshopt {theirs:.3}; \
                 ACMR ours {ours_acmr:.3} meshopt {theirs_acmr:.3}"
            );
            assert!(ours <= theirs, "{name} {what}: {ours} > {theirs}");
            assert!(
                ours_acmr <= 1.05 * theirs_acmr,
                "{name} {what}: ACMR {ours_acmr} > 1.05 × {theirs_acmr}"
            );
        }
    }
}

#[test]
fn every_split_gives_back_the_original_on_every_shared_mesh() {
    for name in MESHES {
        let Some(m) = load(name) else { return };
        let params = ProgressiveParams::default();
        let p = progressive(&m, &params).unwrap();
        let (canon, _) = engine_input(&m, &params);
        let want = triangle_set(canon.indices.iter().copied());
        for encoding in [Encoding::Naive, Encoding::Encoded] {
            let full = p.mesh_at(usize::MAX, encoding);
            // Stream ids differ from the canonical ones: compare through positions and
            // attributes by mapping stream vertices back.
            let mut back = vec![u32::MAX; full.vertex_count()];
            let key = |mm: &TriMesh, v: usize| {
                let mut k = mm.positions[v].to_array().map(f32::to_bits).to_vec();
                if let Some(c) = &mm.colors {
                    k.extend(c[v].map(f32::to_bits));
                }
                if let Some(n) = &mm.normals {
                    k.extend(n[v].to_array().map(f32::to_bits));
                }
                if let Some(u) = &mm.uvs {
                    k.extend(u[v].to_array().map(f32::to_bits));
                }
                k
            };
            let index: std::collections::HashMap<Vec<u32>, u32> = (0..canon.vertex_count())
                .map(|v| (key(&canon, v), v as u32))
                .collect();
            for (v, b) in back.iter_mut().enumerate() {
                *b = index[&key(&full, v)];
            }
            let got = triangle_set(full.indices.iter().map(|t| t.map(|v| back[v as usize])));
            assert_eq!(got, want, "{name} {encoding:?}");
        }
        // The stream decodes to the same.
        let bytes = format::encode(&p, Encoding::Encoded);
        let (q, _) = format::decode(&bytes, std::path::Path::new(name)).unwrap();
        assert_eq!(q.base, p.base, "{name}");
        assert_eq!(q.splits, p.splits, "{name}");
    }
}

#[test]
fn dtfs_sends_fewer_indices_than_a_triangle_list_on_bunny() {
    let Some(m) = load("bunny.obj") else { return };
    let p = progressive(&m, &ProgressiveParams::default()).unwrap();
    let rows = gpu_indices(&p, &even_levels(&p, 21), Join::Restart);
    let sum = |f: fn(&terratile::simplify::strips::measure::LevelIndices) -> usize| {
        rows.iter().map(f).sum::<usize>() as f64
    };
    for r in &rows {
        assert!(r.stss <= r.unfiltered, "{r:?}");
    }
    let (d, s, l) = (sum(|r| r.dtfs), sum(|r| r.stss), sum(|r| r.list));
    println!(
        "bunny over 21 levels: DTFS {:.1} % fewer indices than a triangle list, {:.1} % fewer than STSS",
        100.0 * (1.0 - d / l),
        100.0 * (1.0 - d / s)
    );
    assert!(d < l);
    // The issue's bounds on indices per drawn triangle after DTFS (restarts counted): at
    // most 1.9 averaged over the levels and 2.2 at any level.
    let per: Vec<f64> = rows
        .iter()
        .map(|r| r.dtfs as f64 / r.triangles as f64)
        .collect();
    let mean = per.iter().sum::<f64>() / per.len() as f64;
    let max = per.iter().cloned().fold(0.0, f64::max);
    assert!(mean <= 1.9 && max <= 2.2, "mean {mean:.3}, max {max:.3}");
    // The decoder moves between levels both ways to the same strips.
    let mut d = Decoder::new(&p, Encoding::Encoded);
    d.set_level(1000);
    let at = d.strip().to_vec();
    d.set_level(5000);
    d.set_level(1000);
    assert_eq!(d.strip(), at.as_slice());
}

#[test]
#[ignore]
fn dtfs_window_experiment() {
    use terratile::simplify::strips::filter::dtfs_window_into;
    let Some(m) = load("bunny.obj") else { return };
    let p = progressive(&m, &ProgressiveParams::default()).unwrap();
    let mut d = Decoder::new(&p, Encoding::Encoded);
    let (mut sc, mut out) = (Vec::new(), Vec::new());
    for l in even_levels(&p, 11) {
        d.set_level(l);
        let t = unstripify(d.strip()).len();
        let mut row = format!("level {l} tris {t}:");
        for w in [1, 4, 16, 64, 256] {
            let tm = std::time::Instant::now();
            dtfs_window_into(d.strip(), Join::Restart, w, &mut sc, &mut out);
            row += &format!(
                " w{w} {:.3} ({:.2} ms)",
                out.len() as f64 / t as f64,
                tm.elapsed().as_secs_f64() * 1e3
            );
        }
        println!("{row}");
    }
}

#[test]
fn the_cli_builds_and_decodes_and_refuses_bad_input() {
    let Some(cow) = common::data_file("meshes/cow.obj") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cow = cow.to_str().unwrap();
    common::terratile(d, &["strips", cow, "cow.tps"]).ok();
    for (level, want) in [("0", None), ("full", Some(5804)), ("100", None)] {
        common::terratile(
            d,
            &["strips", "decode", "cow.tps", "--level", level, "l.ply"],
        )
        .ok();
        let m = io::read(&d.join("l.ply")).unwrap();
        if let Some(t) = want {
            assert_eq!(m.triangle_count(), t);
        }
    }
    // A .glb is one TRIANGLE_STRIP primitive.
    common::terratile(
        d,
        &["strips", "decode", "cow.tps", "--level", "100", "l.glb"],
    )
    .ok();
    let (mode, tris) = gltf_triangles(&std::fs::read(d.join("l.glb")).unwrap());
    assert_eq!(mode, gltf::mesh::Mode::TriangleStrip);
    assert_eq!(
        tris.len(),
        io::read(&d.join("l.ply")).unwrap().triangle_count()
    );
    common::terratile(
        d,
        &["strips", "decode", "cow.tps", "--level", "999999", "x.obj"],
    )
    .input_error(&["--level: `999999` is not a level"])
    .left_nothing("x.obj");
    for bad in ["0", "1", "-0.1", "2"] {
        let arg = format!("--base-ratio={bad}");
        common::terratile(d, &["strips", cow, "b.tps", &arg]).input_error(&["--base-ratio"]);
    }
    let bytes = std::fs::read(d.join("cow.tps")).unwrap();
    std::fs::write(d.join("t.tps"), &bytes[..1000]).unwrap();
    common::terratile(d, &["strips", "decode", "t.tps", "--level", "0", "y.obj"])
        .input_error(&["t.tps: byte 28: truncated"])
        .left_nothing("y.obj");
}

/// The paper's experiments (cow, bunny, dragon_10k, igea; base mesh at 5 %):
/// `cargo test --release --test strips paper_table -- --ignored --nocapture`.
#[test]
#[ignore]
fn paper_table() {
    println!("mesh | splits | slots/split naive | E-PS | cut | records naive B | E-PS B | cut | DTFS vs list | DTFS vs STSS | DTFS idx/tri mean | max");
    let mut paper_rows = Vec::new();
    for (name, order) in ["cow.obj", "bunny.obj", "dragon_10k.obj", "igea.ply"]
        .into_iter()
        .flat_map(|n| [(n, StripOrder::Full), (n, StripOrder::Hierarchical)])
    {
        // The paper's order comes first: its rows go on the figure too.
        let Some(m) = load(name) else { return };
        let params = ProgressiveParams {
            order,
            ..ProgressiveParams::default()
        };
        let p = progressive(&m, &params).unwrap();
        let (n, e) = p.mean_updates();
        let (bn, be) = p.paper_record_bytes();
        let rows = gpu_indices(&p, &even_levels(&p, 101), Join::Restart);
        let s = |f: fn(&terratile::simplify::strips::measure::LevelIndices) -> usize| {
            rows.iter().map(f).sum::<usize>() as f64
        };
        let per: Vec<f64> = rows
            .iter()
            .map(|r| r.dtfs as f64 / r.triangles as f64)
            .collect();
        // Strips drawn as separate calls: no restart indices.
        let sep: Vec<f64> = rows
            .iter()
            .map(|r| (r.dtfs - r.dtfs_restarts) as f64 / r.triangles as f64)
            .collect();
        println!(
            "{name} {order:?} | {} | {n:.2} | {e:.2} | {:.1} % | {bn} | {be} | {:.1} % | {:.1} % | {:.1} % | {:.2} | {:.2}",
            p.splits.len(),
            100.0 * (1.0 - e / n),
            100.0 * (1.0 - be as f64 / bn as f64),
            100.0 * (1.0 - s(|r| r.dtfs) / s(|r| r.list)),
            100.0 * (1.0 - s(|r| r.dtfs) / s(|r| r.stss)),
            per.iter().sum::<f64>() / per.len() as f64,
            per.iter().cloned().fold(0.0, f64::max),
        );
        println!(
            "  without restarts: DTFS vs list {:.1} %, idx/tri mean {:.2} max {:.2}",
            100.0 * (1.0 - (s(|r| r.dtfs) - s(|r| r.dtfs_restarts)) / s(|r| r.list)),
            sep.iter().sum::<f64>() / sep.len() as f64,
            sep.iter().cloned().fold(0.0, f64::max),
        );
        let worst = rows
            .iter()
            .max_by(|a, b| (a.dtfs * b.triangles).cmp(&(b.dtfs * a.triangles)))
            .unwrap();
        println!(
            "  worst level {} ({} triangles)",
            worst.level, worst.triangles
        );
        if order == StripOrder::Full {
            paper_rows = rows.clone();
        }
        if name == "bunny.obj" && order == StripOrder::Hierarchical {
            let png = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/strips_fig4.png");
            figure::write_fig4(&rows, &paper_rows, "bunny", &png).unwrap();
            println!("  Fig. 4: {}", png.display());
            for r in &rows {
                println!(
                    "  {} {} {} {} {} {} {}",
                    r.level, r.triangles, r.unfiltered, r.stss, r.dtfs, r.dtfs_restarts, r.list
                );
            }
        }
    }
}

/// Triangles of a glb's first primitive as position triples (glTF's y-up back to z-up),
/// read with the `gltf` crate, which also checks the document; and the primitive's mode.
fn gltf_triangles(glb: &[u8]) -> (gltf::mesh::Mode, Vec<[[u32; 3]; 3]>) {
    let g = gltf::Gltf::from_slice(glb).unwrap();
    let blob = g.blob.as_deref().unwrap();
    let p = g.meshes().next().unwrap().primitives().next().unwrap();
    let r = p.reader(|_| Some(blob));
    let pos: Vec<[f32; 3]> = r.read_positions().unwrap().collect();
    let idx: Vec<u32> = r.read_indices().unwrap().into_u32().collect();
    assert!(!idx.contains(&RESTART));
    let key = |v: u32| {
        let [x, y, z] = pos[v as usize];
        [x, -z, y].map(|c| (c + 0.0).to_bits())
    };
    let tris = unstripify(&idx).into_iter().map(|t| t.map(key)).collect();
    (p.mode(), tris)
}

/// Triangles as position triples, each rotated to start at its least corner, sorted.
fn by_position(mut tris: Vec<[[u32; 3]; 3]>) -> Vec<[[u32; 3]; 3]> {
    for t in &mut tris {
        let k = (0..3).min_by_key(|&k| t[k]).unwrap();
        t.rotate_left(k);
    }
    tris.sort_unstable();
    tris
}

#[test]
fn a_level_writes_as_a_gltf_triangle_strip_that_reads_back() {
    let Some(m) = load("cow.obj") else { return };
    let p = progressive(&m, &ProgressiveParams::default()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for level in [0, 1000, p.splits.len()] {
        let glb = format::glb_at(&p, level, Encoding::Encoded, "cow", 1.0).unwrap();
        let want = p.mesh_at(level, Encoding::Encoded);
        let key = |v: u32| {
            want.positions[v as usize]
                .to_array()
                .map(|c| (c + 0.0).to_bits())
        };
        let want = by_position(want.indices.iter().map(|t| t.map(key)).collect());
        // The gltf crate.
        let (mode, got) = gltf_triangles(&glb);
        assert_eq!(mode, gltf::mesh::Mode::TriangleStrip, "level {level}");
        assert_eq!(by_position(got), want, "level {level}");
        // terratile's own glb reader.
        let path = dir.path().join(format!("l{level}.glb"));
        std::fs::write(&path, &glb).unwrap();
        let back = io::read(&path).unwrap();
        let key = |v: u32| {
            let q = back.positions[v as usize];
            [q.x, q.y, q.z].map(|c| (c + 0.0).to_bits())
        };
        let got = by_position(back.indices.iter().map(|t| t.map(key)).collect());
        assert_eq!(got.len(), want.len(), "level {level}");
    }
}

/// The Khronos glTF validator (npm `gltf-validator`, installed by this test into
/// `target/gltf-validator`; it skips, saying why, without Node or the registry) finds no error
/// and no warning in the strip glb of cow's base level, a middle level and the full mesh.
#[test]
fn strip_glb_passes_the_khronos_validator() {
    let Some(m) = load("cow.obj") else { return };
    let Some(modules) = common::npm_env("gltf-validator", "gltf-validator@2.0.0-dev.3.10") else {
        return;
    };
    let p = progressive(&m, &ProgressiveParams::default()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    for level in [0, 1000, p.splits.len()] {
        let glb = format::glb_at(&p, level, Encoding::Encoded, "cow", 1.0).unwrap();
        let path = dir.path().join(format!("l{level}.glb"));
        std::fs::write(&path, &glb).unwrap();
        files.push(path);
    }
    let script = dir.path().join("validate.js");
    std::fs::write(
        &script,
        r#"const validator = require('gltf-validator');
const fs = require('fs');
(async () => {
  for (const f of process.argv.slice(2)) {
    const r = await validator.validateBytes(new Uint8Array(fs.readFileSync(f)));
    console.log(JSON.stringify({ file: f, errors: r.issues.numErrors,
      warnings: r.issues.numWarnings, messages: r.issues.messages }));
  }
})().catch(e => { console.error(e); process.exit(1); });
"#,
    )
    .unwrap();
    let o = std::process::Command::new("node")
        .env("NODE_PATH", &modules)
        .arg(&script)
        .args(&files)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8(o.stdout).unwrap();
    let reports: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(reports.len(), files.len(), "{out}");
    for r in &reports {
        assert_eq!(r["errors"], 0, "{r}");
        assert_eq!(r["warnings"], 0, "{r}");
    }
}

#[test]
fn strips_in_an_asset_write_the_stream_and_a_strip_glb() {
    let dir = common::default_job();
    let d = dir.path();
    std::fs::write(d.join("m.obj"), crate::simplify::grid_obj(16, "")).unwrap();
    let base = std::fs::read_to_string(d.join("pipeline.toml")).unwrap();
    let entry = |strips: &str| {
        format!(
            "{base}\n[[assets]]\ninput = \"m.obj\"\noutput = \"assets/m.ply\"\n\
             strips = {strips}\nplace = {{ x = 513050.0, y = 5403100.0, up = \"z\" }}\n"
        )
    };
    for (bad, needle) in [
        (
            r#"{ output = "s.tps", base_ratio = 1.0 }"#,
            "assets[0].strips.base_ratio",
        ),
        (r#"{ output = "s.obj" }"#, "assets[0].strips.output"),
        (r#"{ output = "../s.tps" }"#, "assets[0].strips.output"),
        (
            r#"{ output = "s.tps", glb = "s.gltf" }"#,
            "assets[0].strips.glb",
        ),
        (
            r#"{ output = "s.tps", level = 3 }"#,
            "assets[0].strips.level",
        ),
        (r#"{ output = "s.tps", encoding = "fancy" }"#, "encoding"),
    ] {
        std::fs::write(d.join("pipeline.toml"), entry(bad)).unwrap();
        common::terratile(d, &["run", "-q"])
            .input_error(&[needle])
            .left_nothing("out");
    }
    std::fs::write(
        d.join("pipeline.toml"),
        entry(r#"{ output = "assets/m.tps", glb = "assets/m_strip.glb", level = 0 }"#),
    )
    .unwrap();
    let r = common::terratile(d, &["run", "--json", "-q"]);
    let v: serde_json::Value = serde_json::from_str(&r.ok().stdout).unwrap();
    let s = &v["assets"][0]["strips"];
    assert_eq!(s["triangles"], 512, "{}", r.stdout);
    let splits = s["splits"].as_u64().unwrap() as usize;
    assert!(splits > 200, "{s}");
    // The stream decodes to the placed mesh; the glb holds the base level as a strip.
    let bytes = std::fs::read(d.join("out/assets/m.tps")).unwrap();
    let (p, _) = format::decode(&bytes, std::path::Path::new("m.tps")).unwrap();
    let placed = io::read(&d.join("out/assets/m.ply")).unwrap();
    let full = p.mesh_at(splits, Encoding::Encoded);
    assert_eq!(full.triangle_count(), placed.triangle_count());
    let glb = std::fs::read(d.join("out/assets/m_strip.glb")).unwrap();
    let (mode, tris) = gltf_triangles(&glb);
    assert_eq!(mode, gltf::mesh::Mode::TriangleStrip);
    assert_eq!(tris.len(), p.mesh_at(0, Encoding::Encoded).triangle_count());
    // A level past the stream: an error naming the asset, nothing left.
    std::fs::write(
        d.join("pipeline.toml"),
        entry(r#"{ output = "assets/m2.tps", glb = "assets/m2.glb", level = 100000 }"#),
    )
    .unwrap();
    common::terratile(d, &["run", "-q"])
        .input_error(&["strips.level 100000"])
        .left_nothing("out/assets/m2.tps");
}

#[test]
fn fig4_draws_every_series() {
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("g.obj");
    std::fs::write(&obj, crate::simplify::grid_obj(20, "")).unwrap();
    let m = io::read(&obj).unwrap();
    let p = progressive(&m, &ProgressiveParams::default()).unwrap();
    let rows = gpu_indices(&p, &even_levels(&p, 11), Join::Restart);
    // A fifth series apart from the others (the same levels, more indices).
    let paper: Vec<_> = rows
        .iter()
        .map(|r| terratile::simplify::strips::measure::LevelIndices {
            dtfs: 2 * r.dtfs,
            ..*r
        })
        .collect();
    let png = figure::fig4_png(&rows, &paper, "grid").unwrap();
    let img = image::load_from_memory(&png).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (900, 600));
    // Each series' colour is on the canvas (its legend and its line).
    for c in [
        [40, 140, 60],
        [120, 120, 120],
        [30, 90, 200],
        [200, 40, 40],
        [230, 140, 20],
    ] {
        let n = img.pixels().filter(|p| p.0 == c).count();
        assert!(n > 100, "{c:?}: {n} pixels");
    }
}

/// The triangles of `m` by position, sorted (see [`by_position`]).
fn position_set(m: &TriMesh) -> Vec<[[u32; 3]; 3]> {
    let key = |v: u32| {
        m.positions[v as usize]
            .to_array()
            .map(|c| (c + 0.0).to_bits())
    };
    by_position(m.indices.iter().map(|t| t.map(key)).collect())
}

#[test]
fn a_level_is_the_engines_mesh_after_n_minus_k_collapses_on_real_meshes() {
    use terratile::simplify::qem;
    for name in ["cow.obj", "bunny.obj", "dragon_10k.obj"] {
        let Some(m) = load(name) else { return };
        let params = ProgressiveParams::default();
        let p = progressive(&m, &params).unwrap();
        let (canon, qp) = engine_input(&m, &params);
        let n = p.splits.len();
        for k in [0, 1, n / 10, n / 2, n - 1, n] {
            let ours = p.mesh_at(k, Encoding::Encoded);
            let r = qem::simplify(
                &canon,
                &qem::QemParams {
                    triangles: ours.triangle_count() as u64,
                    ..qp.clone()
                },
            )
            .unwrap();
            assert_eq!(r.report.collapses, n - k, "{name} level {k}");
            assert_eq!(
                position_set(&ours),
                position_set(&r.mesh),
                "{name} level {k}"
            );
        }
    }
}

/// `--order hierarchical|paper` and `order = …` in an asset's `strips` table build the
/// stream of that order (the library's bytes for the same parameters); a bad value is
/// refused with exit code 2 naming the switch or key.
#[test]
fn the_strip_order_is_chosen_on_the_command_line_and_in_an_asset() {
    let dir = common::default_job();
    let d = dir.path();
    std::fs::write(d.join("m.obj"), crate::simplify::grid_obj(16, "")).unwrap();
    let mesh = io::read(&d.join("m.obj")).unwrap();
    let want = |order| {
        let params = ProgressiveParams {
            order,
            ..ProgressiveParams::default()
        };
        format::encode(&progressive(&mesh, &params).unwrap(), Encoding::Encoded)
    };
    let (hier, paper) = (want(StripOrder::Hierarchical), want(StripOrder::Full));
    assert_ne!(hier, paper, "the two orders give the same stream");
    for (args, bytes) in [
        (&[][..], &hier),
        (&["--order", "hierarchical"][..], &hier),
        (&["--order", "paper"][..], &paper),
    ] {
        let mut a = vec!["strips", "m.obj", "m.tps"];
        a.extend_from_slice(args);
        common::terratile(d, &a).ok();
        assert!(
            std::fs::read(d.join("m.tps")).unwrap() == *bytes,
            "{args:?}"
        );
        std::fs::remove_file(d.join("m.tps")).unwrap();
    }
    common::terratile(d, &["strips", "m.obj", "x.tps", "--order", "sideways"])
        .input_error(&["--order"])
        .left_nothing("x.tps");

    let base = std::fs::read_to_string(d.join("pipeline.toml")).unwrap();
    let entry = |strips: &str| {
        format!(
            "{base}\n[[assets]]\ninput = \"m.obj\"\noutput = \"assets/m.ply\"\n\
             strips = {strips}\nplace = {{ x = 513050.0, y = 5403100.0, up = \"z\" }}\n"
        )
    };
    std::fs::write(
        d.join("pipeline.toml"),
        entry(r#"{ output = "s.tps", order = "sideways" }"#),
    )
    .unwrap();
    common::terratile(d, &["run", "-q"])
        .input_error(&["order"])
        .left_nothing("out");
    // Both orders decode to the placed mesh, from different streams.
    let mut streams = Vec::new();
    for order in ["hierarchical", "paper"] {
        let strips = format!(r#"{{ output = "assets/{order}.tps", order = "{order}" }}"#);
        std::fs::write(d.join("pipeline.toml"), entry(&strips)).unwrap();
        common::terratile(d, &["run", "-q"]).ok();
        let bytes = std::fs::read(d.join(format!("out/assets/{order}.tps"))).unwrap();
        let (p, _) = format::decode(&bytes, std::path::Path::new("s.tps")).unwrap();
        let full = p.mesh_at(p.splits.len(), Encoding::Encoded);
        let placed = io::read(&d.join("out/assets/m.ply")).unwrap();
        assert_eq!(full.triangle_count(), placed.triangle_count(), "{order}");
        streams.push(bytes);
    }
    assert_ne!(streams[0], streams[1]);
}

/// Where E-PS's cut falls short of the paper's (50–55 %): the slots per split under both
/// orders, both joins and two stripifications of the full mesh, with the floor E-PS cannot
/// go under (the slots that show a removed vertex in the full strip, named there, per
/// split) and the depth of the collapse chains (what Naive-PS piles up):
/// `cargo test --release --test tests strips::e_ps_gap -- --ignored --nocapture`.
#[test]
#[ignore]
fn e_ps_gap() {
    println!("mesh | order | join | window | full strip slots/vertex | naive/split | E-PS/split | cut | E-PS floor | settled/split | cut at the floor");
    for name in ["cow.obj", "bunny.obj", "dragon_10k.obj"] {
        let Some(m) = load(name) else { return };
        for (order, window) in [
            (StripOrder::Hierarchical, 0),
            (StripOrder::Full, 0),
            (StripOrder::Full, 8),
        ] {
            for join in [Join::Restart, Join::Degenerate] {
                let params = ProgressiveParams {
                    order,
                    strip: StripParams { join, window },
                    ..ProgressiveParams::default()
                };
                let p = progressive(&m, &params).unwrap();
                let (n, e) = p.mean_updates();
                let mut d = Decoder::new(&p, Encoding::Encoded);
                d.set_level(p.splits.len());
                let full = d.strip();
                let slots = full.iter().filter(|&&v| v != RESTART).count();
                let own = full
                    .iter()
                    .filter(|&&v| v != RESTART && v >= p.base_vertices)
                    .count() as f64
                    / p.splits.len() as f64;
                println!(
                    "{name} | {order:?} | {join:?} | {window} | {:.2} | {n:.2} | {e:.2} | {:.1} % | {own:.2} | {:.2} | {:.1} %",
                    slots as f64 / p.vertices.vertex_count() as f64,
                    100.0 * (1.0 - e / n),
                    e - own,
                    100.0 * (1.0 - own / n),
                );
            }
        }
    }
}
