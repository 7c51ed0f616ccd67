//! Regressions: messages_outputs (issue 14: error messages, outputs that were wrong, a
//! newcomer's path).

use crate::common::{self, terratile};

/// Asserts that stderr is one line with no raw control character (CR, ESC, …) in it.
fn one_clean_line(r: &common::Run) {
    let text = r.stderr.strip_suffix('\n').unwrap_or(&r.stderr);
    assert!(
        !text.is_empty() && !text.chars().any(char::is_control),
        "expected one line without control characters\n{}",
        r.context()
    );
}

/// A file name with CR, LF and an ESC sequence was echoed raw in the error line: the line
/// broke in two and the terminal obeyed the escape (here: clear the screen).
#[test]
fn error_line_escapes_control_characters_in_file_names() {
    let d = tempfile::tempdir().unwrap();
    let name = "a\rb\nc\u{1b}[2Jd.las";
    std::fs::write(d.path().join(name), b"LASF\x01\x02").unwrap();
    let r = terratile(d.path(), &["info", name]);
    assert_eq!(r.code, 2, "{}", r.context());
    one_clean_line(&r);
    assert!(
        r.stderr.contains("a\\rb\\nc\\u{1b}[2Jd.las"),
        "{}",
        r.context()
    );
}

/// A TOML string value holding an escape sequence came back raw in the config error.
#[test]
fn error_line_escapes_control_characters_in_toml_values() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(
        d.path().join("p.toml"),
        "[input]\npaths = [\"x.las\"]\nformat = \"la\\u001b[31ms\\r\"\n",
    )
    .unwrap();
    let r = terratile(d.path(), &["run", "p.toml"]);
    assert_eq!(r.code, 2, "{}", r.context());
    one_clean_line(&r);
    assert!(r.stderr.contains("input.format"), "{}", r.context());
    assert!(r.stderr.contains("la\\u{1b}[31ms\\r"), "{}", r.context());
}

/// Argument-parser (clap) errors took two to three lines (message, usage, a `--help` hint),
/// and echoed control characters of the arguments raw.
#[test]
fn clap_errors_are_one_line_exit_2() {
    let d = tempfile::tempdir().unwrap();
    let cases: [&[&str]; 7] = [
        &[],
        &["bogus"],
        &["--threads", "x", "run"],
        &["run", "--bogus"],
        &["info"],
        &[
            "simplify", "a.obj", "b.obj", "--method", "foo", "--ratio", "0.5",
        ],
        &["generate", "-o", "x.las", "--size", "1\n\u{1b}[31m2"],
    ];
    for args in cases {
        let r = terratile(d.path(), args);
        assert_eq!(r.code, 2, "{}", r.context());
        one_clean_line(&r);
        assert!(r.stderr.starts_with("terratile: "), "{}", r.context());
        assert!(!r.stderr.contains("Usage:"), "{}", r.context());
    }
    let r = terratile(
        d.path(),
        &["simplify", "a", "b", "--method", "foo", "--ratio", "1"],
    );
    assert!(
        r.stderr.contains("uniform, floating, octree"),
        "{}",
        r.context()
    );
    let r = terratile(
        d.path(),
        &["generate", "-o", "x.las", "--size", "1\n\u{1b}[31m2"],
    );
    assert!(r.stderr.contains("1\\n\\u{1b}[31m2"), "{}", r.context());
    // --help and --version print as before, exit 0.
    let r = terratile(d.path(), &["--help"]);
    assert_eq!(r.code, 0, "{}", r.context());
    assert!(r.stdout.contains("Usage: terratile"), "{}", r.context());
    let r = terratile(d.path(), &["run", "--help"]);
    assert_eq!(r.code, 0, "{}", r.context());
    let r = terratile(d.path(), &["--version"]);
    assert_eq!(r.code, 0, "{}", r.context());
    assert!(r.stdout.starts_with("terratile "), "{}", r.context());
}

/// The progress bar cut its label at 40 characters, so `reading /…/shared/data/lidar/`
/// showed the start of the path and never the file name.
#[test]
fn progress_label_shows_the_file_name() {
    use terratile::bar_label;
    let l = bar_label("reading /work/wt/shared/data/lidar/autzen_trim.las", 40);
    assert_eq!(l, "reading …/autzen_trim.las");
    assert_eq!(bar_label("denoise", 40), "denoise");
    let long = format!("parsing /d/{}.xyz", "n".repeat(60));
    let l = bar_label(&long, 40);
    assert_eq!(l.chars().count(), 40);
    assert!(l.starts_with('…') && l.ends_with("nnn.xyz"), "{l}");
    assert_eq!(bar_label("reading a\rb.las", 40), "reading a\\rb.las");
}

/// `run -q` dropped the run summary (the README says `--quiet` only hides progress bars)
/// while `info -q` printed as usual: `--quiet` now means no progress bars, everywhere;
/// results, warnings and errors are printed as without it.
#[test]
fn quiet_hides_only_progress_bars() {
    let job = common::default_job();
    let r = terratile(job.path(), &["run", "-q"]);
    r.ok();
    assert!(
        r.stdout.contains("stages:") && r.stdout.contains("output: "),
        "{}",
        r.context()
    );
    assert!(r.stderr.is_empty(), "{}", r.context());
    let loud = terratile(job.path(), &["info", "fixtures/survey-0-0.las"]);
    let quiet = terratile(job.path(), &["info", "-q", "fixtures/survey-0-0.las"]);
    loud.ok();
    quiet.ok();
    assert!(!quiet.stdout.is_empty());
    assert_eq!(loud.stdout, quiet.stdout);
    let g = terratile(
        job.path(),
        &["--quiet", "generate", "-o", "g.las", "--points", "500"],
    );
    g.ok();
    assert!(g.stdout.contains("g.las: 500 points"), "{}", g.context());
}

/// Positions of a glb file (glTF axes) and its POSITION accessor's min and max.
fn glb_positions(path: &std::path::Path) -> (Vec<[f32; 3]>, [f32; 3], [f32; 3], usize) {
    let bytes = std::fs::read(path).unwrap();
    let g = gltf::Gltf::from_slice(&bytes).unwrap();
    let prim = g.meshes().next().unwrap().primitives().next().unwrap();
    let acc = prim.get(&gltf::Semantic::Positions).unwrap();
    let as3 = |v: serde_json::Value| -> [f32; 3] {
        let a = v.as_array().unwrap();
        [0, 1, 2].map(|k| a[k].as_f64().unwrap() as f32)
    };
    let (min, max) = (as3(acc.min().unwrap()), as3(acc.max().unwrap()));
    let reader = prim.reader(|_| g.blob.as_deref());
    let pos: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
    let used: std::collections::BTreeSet<u32> = reader.read_indices().unwrap().into_u32().collect();
    (pos, min, max, used.len())
}

/// Meshes of padded tiles kept the padding's vertices unused (default job `tile_000_001`:
/// 17,984 vertices, 4,412 used), and the glTF POSITION bounds then covered 517 × 398 m for a
/// 46 × 36 m mesh. Every written mesh now references all its vertices, in every format.
#[test]
fn tile_meshes_hold_only_used_vertices() {
    let job = common::default_job();
    let d = job.path();
    let text: String = std::fs::read_to_string(d.join("pipeline.toml"))
        .unwrap()
        .lines()
        .filter(|l| {
            !["meshes ", "exr ", "png ", "raw "]
                .iter()
                .any(|k| l.starts_with(k))
        })
        .map(|l| format!("{l}\n"))
        .collect();
    let text = text.replace(
        "[output]\n",
        "[output]\nmeshes = [\"ply\", \"obj\", \"glb\"]\nexr = false\npng = false\nraw = false\n",
    );
    std::fs::write(d.join("pipeline.toml"), text).unwrap();
    terratile(d, &["run", "-q"]).ok();
    let mut meshes = 0;
    for e in std::fs::read_dir(d.join("out/meshes")).unwrap().flatten() {
        let p = e.path();
        match p.extension().and_then(|e| e.to_str()) {
            Some("glb") => {
                let (pos, min, max, used) = glb_positions(&p);
                assert_eq!(used, pos.len(), "{}: unused vertices", p.display());
                let mut lo = [f32::INFINITY; 3];
                let mut hi = [f32::NEG_INFINITY; 3];
                for q in &pos {
                    for k in 0..3 {
                        lo[k] = lo[k].min(q[k]);
                        hi[k] = hi[k].max(q[k]);
                    }
                }
                assert_eq!((min, max), (lo, hi), "{}", p.display());
            }
            Some("ply" | "obj") => {
                let m = terratile::mesh::io::read(&p).unwrap();
                let mut used = vec![false; m.vertex_count()];
                for f in &m.indices {
                    for &v in f {
                        used[v as usize] = true;
                    }
                }
                let unused = used.iter().filter(|u| !**u).count();
                assert_eq!(unused, 0, "{}: {unused} unused vertices", p.display());
            }
            _ => continue,
        }
        meshes += 1;
    }
    // 2 × 1 tiles of 257 over the fixtures' grid: 2 padded tiles in each of 3 formats.
    assert!(meshes >= 6, "{meshes} meshes");
}

/// For a CRS in feet (autzen_trim.las: Oregon Lambert, international feet) glb positions
/// were written in feet (glTF is metres) and the manifest's `unity` block (terrain size,
/// position y) in feet, while the `unreal` block was converted.
#[test]
fn engine_facing_numbers_are_metres_for_a_crs_in_feet() {
    let Some(las) = common::data_file("lidar/autzen_trim.las") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    common::write_pipeline(
        d.path(),
        las.to_str().unwrap(),
        "meshes = [\"ply\", \"glb\"]\nexr = false\npng = false\nrelief = false\nwireframe = false\n\
         [tiles]\npreset = \"unity\"\n",
    );
    common::run_p_toml(d.path()).ok();
    let out = d.path().join("out");
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
    let ft = m["crs"]["metres_per_unit"].as_f64().unwrap();
    assert!((ft - 0.3048).abs() < 1e-12, "autzen is in feet: {ft}");
    let size = m["tiling"]["tile_size"].as_f64().unwrap();
    let cell = m["grid"]["cell_size"][0].as_f64().unwrap();
    let u = &m["unity"];
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1.0);
    assert!(
        close(
            u["terrain_size"][0].as_f64().unwrap(),
            (size - 1.0) * cell * ft
        ),
        "{u}"
    );
    let z_scale = m["heightmaps"]["z_scale"].as_f64().unwrap();
    let z_offset = m["heightmaps"]["z_offset"].as_f64().unwrap();
    assert!(
        close(
            u["terrain_size"][1].as_f64().unwrap(),
            65535.0 * z_scale * ft
        ),
        "{u}"
    );
    assert!(
        close(u["position_y"].as_f64().unwrap(), z_offset * ft),
        "{u}"
    );
    // glb: the PLY's positions (CRS units, z up) in metres (y up).
    let ply = terratile::mesh::io::read(&out.join("meshes/tile_000_000.ply")).unwrap();
    let (glb, min, max, _) = glb_positions(&out.join("meshes/tile_000_000.glb"));
    assert_eq!(glb.len(), ply.vertex_count());
    for (g, p) in glb.iter().zip(&ply.positions) {
        let want = [p.x * ft as f32, p.z * ft as f32, -p.y * ft as f32];
        for k in 0..3 {
            assert!((g[k] - want[k]).abs() <= 1e-3, "{g:?} vs {want:?}");
        }
    }
    // The mesh spans a tile of (size − 1) cells at most, in metres.
    let span = (max[0] - min[0]).max(max[2] - min[2]) as f64;
    assert!(span <= (size - 1.0) * cell * ft + 1e-3, "{span} m");
}

/// `baseline.json` carried build and grid times, their ratio and peak memory, which differ
/// on every run, against the promise of byte-identical outputs: the measurements now go to
/// the run summary, and two runs give byte-identical output directories.
#[test]
fn baseline_outputs_are_byte_identical_across_runs() {
    let job = common::default_job();
    let d = job.path();
    common::edit_pipeline(
        d,
        "[baseline]\nenabled = false",
        "[baseline]\nenabled = true",
    );
    let r = terratile(d, &["run", "-q", "--json"]);
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    assert!(
        v["baseline"]["build_s"].as_f64().unwrap() > 0.0,
        "{}",
        r.stdout
    );
    std::fs::rename(d.join("out"), d.join("first")).unwrap();
    terratile(d, &["run", "-q", "--threads", "1"]).ok();
    let a = common::walk(&d.join("first"));
    let b = common::walk(&d.join("out"));
    let rel = |v: &[std::path::PathBuf], root: &str| -> Vec<std::path::PathBuf> {
        v.iter()
            .map(|p| p.strip_prefix(d.join(root)).unwrap().to_path_buf())
            .collect()
    };
    assert_eq!(rel(&a, "first"), rel(&b, "out"));
    assert!(b.iter().any(|p| p.ends_with("baseline.json")));
    for (x, y) in a.iter().zip(&b) {
        if x.is_file() {
            assert!(
                std::fs::read(x).unwrap() == std::fs::read(y).unwrap(),
                "{} differs between runs",
                y.display()
            );
        }
    }
}

/// The README's pipeline example (the one ```toml block).
fn readme_pipeline_block() -> String {
    let readme = std::fs::read_to_string(common::repo().join("README.md")).unwrap();
    let start = readme
        .find("```toml\n")
        .expect("a ```toml block in the README")
        + 8;
    let len = readme[start..].find("```").unwrap();
    readme[start..start + len].to_string()
}

/// The README's pipeline example did not run: it set `size` and `cell_size` together (an
/// error) and named an asset that does not exist. It now runs as printed on the default
/// job's fixtures, and its `[[assets]]` entry, uncommented, runs with a model in place.
#[test]
fn readme_pipeline_example_runs() {
    let job = common::default_job();
    let d = job.path();
    let block = readme_pipeline_block();
    std::fs::write(d.join("readme.toml"), &block).unwrap();
    terratile::config::load(&d.join("readme.toml")).unwrap();
    terratile(d, &["run", "-q", "readme.toml"]).ok();
    // The commented [[assets]] example, switched on.
    let assets: String = block
        .lines()
        .map(|l| {
            let t = l.trim_start();
            let on = [
                "# [[assets]]",
                "# input",
                "# output",
                "# simplify",
                "# place",
            ]
            .iter()
            .any(|k| t.starts_with(k));
            format!("{}\n", if on { &t[2..] } else { l })
        })
        .collect();
    assert!(assets.contains("\n[[assets]]"), "{assets}");
    std::fs::create_dir(d.join("models")).unwrap();
    // A bumpy 12 × 12 patch, y up (288 triangles: enough for the octree at 25 %).
    let n = 13;
    let mut obj = String::new();
    for j in 0..n {
        for i in 0..n {
            let y = ((i as f64 * 0.7).sin() + (j as f64 * 0.5).cos()) * 0.3;
            obj.push_str(&format!("v {i} {y:.4} {j}\n"));
        }
    }
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let v = j * n + i + 1;
            obj.push_str(&format!(
                "f {v} {} {}\nf {v} {} {}\n",
                v + n,
                v + n + 1,
                v + n + 1,
                v + 1
            ));
        }
    }
    std::fs::write(d.join("models/rock.obj"), obj).unwrap();
    std::fs::write(d.join("assets.toml"), assets).unwrap();
    let r = terratile(d, &["run", "-q", "assets.toml"]);
    r.ok();
    assert!(d.join("out/assets/rock.ply").is_file(), "{}", r.context());
}

/// The README said "the defaults are the values shown" while `keep_classes`, `max_points`,
/// `voxel_size`, `cell_size` and `size` were not defaults. Every uncommented key of its
/// example (but the required `paths`) must equal the code's default, and every key the code
/// has must be documented there (set or commented out).
#[test]
fn readme_defaults_match_the_code() {
    let block = readme_pipeline_block();
    let readme: toml::Table = toml::from_str(&block).unwrap();
    let defaults =
        terratile::config::parse(std::path::Path::new("p.toml"), "[input]\npaths = [\"x\"]\n")
            .unwrap();
    let defaults = toml::Table::try_from(&defaults).unwrap();
    let same = |a: &toml::Value, b: &toml::Value| match (a, b) {
        (toml::Value::Integer(x), toml::Value::Float(y))
        | (toml::Value::Float(y), toml::Value::Integer(x)) => *x as f64 == *y,
        _ => a == b,
    };
    let mut checked = 0;
    for (table, keys) in &readme {
        let keys = keys
            .as_table()
            .unwrap_or_else(|| panic!("[{table}] is a table"));
        for (key, value) in keys {
            if (table.as_str(), key.as_str()) == ("input", "paths") {
                continue;
            }
            checked += 1;
            let Some(want) = defaults.get(table).and_then(|t| t.get(key)) else {
                // Keys left out of the serialised config at their default (so that the
                // manifest of a run without them keeps its bytes): setting the README's
                // value must give the default configuration back.
                let text = format!("[input]\npaths = [\"x\"]\n[{table}]\n{key} = {value}\n");
                let set = terratile::config::parse(std::path::Path::new("p.toml"), &text)
                    .unwrap_or_else(|e| panic!("README: {table}.{key} = {value}: {e}"));
                assert_eq!(
                    toml::Table::try_from(&set).unwrap(),
                    defaults,
                    "README: {table}.{key} = {value} is not the code's default"
                );
                continue;
            };
            assert!(
                same(value, want),
                "README: {table}.{key} = {value}, the code's default is {want}"
            );
        }
    }
    assert!(checked >= 30, "{checked} keys checked");
    // Every key the code has (its defaults serialised) appears in the README's block.
    let mut table = String::new();
    let mut documented = std::collections::BTreeSet::new();
    for line in block.lines() {
        let t = line.trim_start_matches(['#', ' ']);
        if let Some(h) = t.strip_prefix('[') {
            table = h
                .trim_matches(|c| c == '[' || c == ']')
                .split(']')
                .next()
                .unwrap()
                .to_string();
        } else if let Some((k, _)) = t.split_once(" = ") {
            documented.insert(format!("{table}.{}", k.trim()));
        }
    }
    for (table, keys) in &defaults {
        for key in keys.as_table().into_iter().flat_map(|t| t.keys()) {
            let k = format!("{table}.{key}");
            assert!(documented.contains(&k), "README does not document {k}");
        }
    }
}

/// `terratile compare A B | head -1` panicked ("failed printing to stdout: Broken pipe") and
/// printed an internal error once `head` had closed the pipe. A closed pipe now ends the
/// process quietly with success, as a Unix filter does.
#[test]
fn closed_stdout_pipe_panicked() {
    use std::process::{Command, Stdio};
    let d = tempfile::tempdir().unwrap();
    let obj = d.path().join("t.obj");
    std::fs::write(
        &obj,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 1\nf 1 2 3\nf 2 4 3\n",
    )
    .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_terratile"))
        .args(["compare", "--json"])
        .arg(&obj)
        .arg(&obj)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The reader goes away before the report is written.
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(out.status.code(), Some(0), "{stderr}");
}

/// `generate --points 0` was refused as "--tiles 1x1: 1 tiles, at most 0": the tile bound
/// ("no more than the points") was checked before the point count itself.
#[test]
fn generate_too_few_points_names_points() {
    let d = tempfile::tempdir().unwrap();
    for n in ["0", "99"] {
        let r = terratile(d.path(), &["generate", "-o", "g.las", "--points", n]);
        assert_eq!(r.code, 2, "{}", r.context());
        one_clean_line(&r);
        assert!(
            r.stderr.contains(&format!("--points {n}: at least 100")),
            "{}",
            r.context()
        );
    }
    assert!(!d.path().join("g.las").exists());
}
