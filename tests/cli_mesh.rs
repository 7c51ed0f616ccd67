//! The mesh commands (`simplify`, `compare`) and `[[assets]]` through the real binary, and
//! every bad input issue 6 lists: a one-line error, exit code 2, no output.

use crate::common;

use common::{terratile, Run};
use std::path::Path;

const TETRA: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n";

fn write(dir: &Path, name: &str, text: &str) {
    std::fs::write(dir.join(name), text).unwrap();
}

/// A closed, finely tessellated surface (a sphere-like grid) as OBJ text.
fn sphere_obj(n: usize) -> String {
    let mut s = String::new();
    for j in 0..=n {
        let theta = std::f64::consts::PI * j as f64 / n as f64;
        for i in 0..n {
            let phi = 2.0 * std::f64::consts::PI * i as f64 / n as f64;
            s += &format!(
                "v {} {} {}\n",
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos()
            );
        }
    }
    let id = |i: usize, j: usize| j * n + (i % n) + 1;
    for j in 0..n {
        for i in 0..n {
            s += &format!("f {} {} {}\n", id(i, j), id(i, j + 1), id(i + 1, j + 1));
            s += &format!("f {} {} {}\n", id(i, j), id(i + 1, j + 1), id(i + 1, j));
        }
    }
    s
}

/// Nothing was written: no output file and no temporary leftovers.
fn nothing_written(r: &Run, out: &str) {
    r.left_nothing(out);
}

fn bad_simplify(dir: &Path, input: &str, extra: &[&str], needles: &[&str]) {
    let mut args = vec!["simplify", "-q", input, "out.obj"];
    args.extend_from_slice(extra);
    let r = terratile(dir, &args);
    r.input_error(needles);
    nothing_written(&r, "out.obj");
}

/// Bad meshes and bad targets: one line naming the file and line (or byte, or the key),
/// exit code 2, nothing written.
#[test]
fn bad_meshes_and_targets() {
    let d = tempfile::tempdir().unwrap();
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
               property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
               0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n";
    // A face with fewer than 3 vertices is skipped with a warning (so this file has no
    // triangles left); `--strict` refuses it.
    let short_face = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n";
    let half = &["--ratio", "0.5"][..];
    let cases: &[(&str, &str, &[&str], &[&str])] = &[
        (
            "m.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n",
            half,
            &["m.obj:5", "index 9 is out of range"],
        ),
        (
            "m.ply",
            ply,
            half,
            &["m.ply:13", "vertex 3 but there are 3"],
        ),
        (
            "m.obj",
            short_face,
            &["--ratio", "0.5", "--strict"],
            &["m.obj:4", "at least 3 vertices"],
        ),
        (
            "m.obj",
            short_face,
            half,
            &["m.obj", "the mesh has no triangles"],
        ),
        (
            "m.obj",
            "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n",
            half,
            &["m.obj:2", "not a finite number"],
        ),
        (
            "none.obj",
            "# nothing here\nv 0 0 0\n",
            half,
            &["none.obj", "no triangles"],
        ),
        ("zero.obj", "", half, &["zero.obj", "empty file"]),
        (
            "t.obj",
            TETRA,
            &["--triangles", "0"],
            &["triangles = 0", "at least 1"],
        ),
        (
            "t.obj",
            TETRA,
            &["--ratio", "0"],
            &["ratio", "must be in (0, 1]"],
        ),
        (
            "t.obj",
            TETRA,
            &["--ratio", "1.5"],
            &["ratio", "must be in (0, 1]"],
        ),
        (
            "t.obj",
            TETRA,
            &["--ratio", "-0.2"],
            &["ratio", "must be in (0, 1]"],
        ),
        (
            "t.obj",
            TETRA,
            &["--ratio", "NaN"],
            &["ratio", "must be in (0, 1]"],
        ),
    ];
    for (name, text, args, needles) in cases {
        write(d.path(), name, text);
        bad_simplify(d.path(), name, args, needles);
    }
    let r = terratile(d.path(), &["compare", "none.obj", "none.obj"]);
    r.input_error(&["none.obj", "no triangles"]);
}

/// A NaN in a binary PLY is named by the byte offset of its vertex.
#[test]
fn nan_coordinates_in_binary_ply() {
    let d = tempfile::tempdir().unwrap();
    let mut ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n\
                    property float y\nproperty float z\nelement face 1\n\
                    property list uchar int vertex_indices\nend_header\n"
        .to_vec();
    let head = ply.len();
    for v in [[0.0f32, 0.0, 0.0], [1.0, f32::NAN, 0.0], [0.0, 1.0, 0.0]] {
        for x in v {
            ply.extend_from_slice(&x.to_le_bytes());
        }
    }
    ply.push(3);
    for i in 0..3i32 {
        ply.extend_from_slice(&i.to_le_bytes());
    }
    std::fs::write(d.path().join("m.ply"), &ply).unwrap();
    let at = format!("byte {}", head + 12);
    bad_simplify(
        d.path(),
        "m.ply",
        &["--ratio", "0.5"],
        &["m.ply", &at, "non-finite"],
    );
}

#[test]
fn unknown_output_format_writes_nothing() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "t.obj", TETRA);
    let r = terratile(
        d.path(),
        &["simplify", "-q", "t.obj", "t.stl", "--ratio", "0.5"],
    );
    r.input_error(&["t.stl", ".obj or .ply"]);
    nothing_written(&r, "t.stl");
}

#[test]
fn simplify_reports_counts_time_and_error() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "s.obj", &sphere_obj(40));
    for method in ["uniform", "floating", "octree"] {
        let out = format!("{method}.ply");
        let r = common::simplify(
            d.path(),
            "s.obj",
            &out,
            &["--method", method, "--ratio", "0.1", "--json"],
        );
        r.ok();
        let v: serde_json::Value =
            serde_json::from_str(&r.stdout).unwrap_or_else(|e| panic!("{e}\n{}", r.context()));
        let tin = v["triangles_in"].as_u64().unwrap();
        let tout = v["triangles_out"].as_u64().unwrap();
        assert_eq!(tin, 3200, "{}", r.context());
        assert!((250..=390).contains(&tout), "{tout}\n{}", r.context());
        let max = v["error"]["max_pct"].as_f64().unwrap();
        assert!(max > 0.0 && max < 5.0, "{max}\n{}", r.context());
        assert!(v["seconds"].as_f64().unwrap() >= 0.0);
        let m = terratile::mesh::io::read(&d.path().join(&out)).unwrap();
        assert_eq!(m.triangle_count() as u64, tout);
    }
    // Text output names the counts and the error.
    let r = common::simplify(d.path(), "s.obj", "o.obj", &["--triangles", "500"]);
    r.ok();
    for needle in ["triangles 3200 →", "ms", "Hausdorff error", "symmetric"] {
        assert!(r.stdout.contains(needle), "`{needle}`\n{}", r.context());
    }
}

#[test]
fn compare_a_mesh_with_itself_and_json() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "s.obj", &sphere_obj(16));
    let r = terratile(
        d.path(),
        &["compare", "s.obj", "s.obj", "--json", "--samples", "20000"],
    );
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    assert!(
        v["error"]["max"].as_f64().unwrap() < 1e-9,
        "{}",
        r.context()
    );
    assert_eq!(v["triangles"][0].as_u64(), Some(512));
    let r = terratile(d.path(), &["compare", "s.obj", "s.obj"]);
    r.ok();
    assert!(r.stdout.contains("queries/s"), "{}", r.context());
}

#[test]
fn same_output_bytes_for_any_thread_count() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "s.obj", &sphere_obj(50));
    for method in ["uniform", "floating", "octree"] {
        let mut outs = Vec::new();
        for threads in ["1", "2", "8"] {
            let out = format!("{method}-{threads}.ply");
            terratile(
                d.path(),
                &[
                    "simplify",
                    "-q",
                    "--threads",
                    threads,
                    "s.obj",
                    &out,
                    "--method",
                    method,
                    "--ratio",
                    "0.2",
                ],
            )
            .ok();
            outs.push(std::fs::read(d.path().join(&out)).unwrap());
        }
        assert_eq!(outs[0], outs[1], "{method}: 1 vs 2 threads");
        assert_eq!(outs[0], outs[2], "{method}: 1 vs 8 threads");
    }
}

#[test]
fn assets_are_simplified_placed_and_listed() {
    let dir = common::default_job();
    let d = dir.path();
    write(d, "ball.obj", &sphere_obj(30));
    let mut toml = std::fs::read_to_string(d.join("pipeline.toml")).unwrap();
    toml += "\n[[assets]]\ninput = \"ball.obj\"\noutput = \"assets/ball.ply\"\n\
             simplify = { method = \"octree\", ratio = 0.2 }\n\
             place = { x = 513050.0, y = 5403100.0, rotation = 45.0, up = \"z\", scale = 2.0 }\n\
             \n[[assets]]\ninput = \"ball.obj\"\noutput = \"assets/raw.obj\"\nplace = { x = 513200.0, y = 5403150.0 }\n";
    std::fs::write(d.join("pipeline.toml"), &toml).unwrap();
    let r = terratile(d, &["run", "--json"]);
    r.ok();
    let v: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    let assets = v["assets"]
        .as_array()
        .unwrap_or_else(|| panic!("{}", r.context()));
    assert_eq!(assets.len(), 2);
    assert_eq!(assets[0]["method"], "octree");
    assert!(assets[0]["error"]["max_pct"].as_f64().unwrap() > 0.0);
    assert!(assets[1]["error"].is_null());
    let m = terratile::mesh::io::read(&d.join("out/assets/ball.ply")).unwrap();
    let b = m.bounds().unwrap();
    // Coordinates are local to the run's origin (the filled grid's corner and z offset, in
    // the assets stage's figures); scale 2, base on the terrain, footprint centred on (x, y).
    let stage = v["stages"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["stage"] == "assets")
        .unwrap_or_else(|| panic!("{}", r.context()));
    let origin: Vec<f64> = stage["figures"]
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f[0] == "origin")
        .unwrap()[1]
        .as_str()
        .unwrap()
        .trim_matches(|c| c == '(' || c == ')')
        .split(", ")
        .map(|t| t.parse().unwrap())
        .collect();
    let ground = assets[0]["position"][2].as_f64().unwrap();
    assert!(ground > 100.0, "placed on the terrain: {ground}");
    let base = ground - origin[2];
    assert!(
        (b.min.z as f64 - base).abs() < 1e-2 && (b.max.z as f64 - base - 4.0).abs() < 0.05,
        "{b:?} base {base}"
    );
    assert!(
        ((b.min.x + b.max.x) as f64 / 2.0 - (513050.0 - origin[0])).abs() < 1.0,
        "{b:?}"
    );
    assert!(d.join("out/assets/raw.obj").is_file());
    let r = terratile(d, &["run"]);
    r.ok();
    assert!(
        r.stdout.contains("assets:") && r.stdout.contains("ball.obj → assets/ball.ply"),
        "{}",
        r.context()
    );
}

#[test]
fn bad_asset_entries_name_the_key_and_line() {
    let dir = common::default_job();
    let d = dir.path();
    write(d, "t.obj", TETRA);
    let base = std::fs::read_to_string(d.join("pipeline.toml")).unwrap();
    let cases = [
        (
            "[[assets]]\ninput = \"t.obj\"\noutput = \"a.obj\"\nsimplify = { method = \"uniform\", ratio = 1.5 }\nplace = { x = 0, y = 0 }\n",
            vec!["assets[0].simplify.ratio", "must be in (0, 1]"],
        ),
        (
            "[[assets]]\ninput = \"t.obj\"\noutput = \"a.obj\"\nplace = { x = 0, y = 0 }\n[assets.simplify]\nmethod = \"octree\"\ntriangles = 0\n",
            vec!["assets[0].simplify.triangles", "at least 1"],
        ),
        (
            "[[assets]]\ninput = \"missing.obj\"\noutput = \"a.obj\"\nplace = { x = 0, y = 0 }\n",
            vec!["assets[0].input", "does not exist"],
        ),
        (
            "[[assets]]\ninput = \"t.obj\"\noutput = \"a.stl\"\nplace = { x = 0, y = 0 }\n",
            vec!["assets[0].output", ".obj or .ply"],
        ),
        (
            "[[assets]]\ninput = \"t.obj\"\noutput = \"a.obj\"\nplace = { x = 0, y = 0, spin = 3 }\n",
            vec!["assets[0].place", "unknown field `spin`"],
        ),
    ];
    for (entry, needles) in cases {
        let text = format!("{base}\n{entry}");
        std::fs::write(d.join("pipeline.toml"), &text).unwrap();
        let r = terratile(d, &["run", "-q"]);
        let line = base.lines().count() + 2;
        // The error line points into the entry (its first line or later).
        r.input_error(&needles);
        assert!(
            (line..line + 8).any(|l| r.stderr.contains(&format!("pipeline.toml:{l}:"))),
            "line of the entry\n{}",
            r.context()
        );
        assert!(!d.join("out").exists(), "no output\n{}", r.context());
    }
}

/// A flat n × n grid (every vertex on the plane z = 0.3x − 0.2y) as OBJ text.
fn plane_obj(n: usize) -> String {
    let mut s = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
            s += &format!("v {x} {y} {}\n", 0.3 * x - 0.2 * y);
        }
    }
    let id = |i: usize, j: usize| j * (n + 1) + i + 1;
    for j in 0..n {
        for i in 0..n {
            s += &format!("f {} {} {}\n", id(i, j), id(i + 1, j), id(i + 1, j + 1));
            s += &format!("f {} {} {}\n", id(i, j), id(i + 1, j + 1), id(i, j + 1));
        }
    }
    s
}

#[test]
fn saliency_bad_input_is_one_line_and_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write(d, "s.obj", &sphere_obj(12));
    write(d, "flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n");
    let simplify = |extra: &[&str]| {
        let mut a = vec![
            "simplify", "s.obj", "out.obj", "--method", "qem", "--ratio", "0.5",
        ];
        a.extend_from_slice(extra);
        terratile(d, &a)
    };
    simplify(&["--saliency", "image", "--views", "1"])
        .input_error(&["views"])
        .left_nothing("out.obj");
    for size in ["15", "4097"] {
        simplify(&["--saliency", "image", "--view-size", size])
            .input_error(&["view_size", size])
            .left_nothing("out.obj");
    }
    for h in ["0", "1.5", "-0.2"] {
        simplify(&["--saliency", "mesh", "--h-min", h])
            .input_error(&["saliency_h_min"])
            .left_nothing("out.obj");
    }
    // Saliency keys belong to QEM.
    common::simplify(
        d,
        "s.obj",
        "out.obj",
        &["--ratio", "0.5", "--saliency", "mesh"],
    )
    .input_error(&["saliency"])
    .left_nothing("out.obj");
    terratile(d, &["saliency", "flat.obj", "--out", "maps"])
        .input_error(&["flat.obj", "no area"])
        .left_nothing("maps");
    terratile(d, &["saliency", "s.obj", "--out", "maps", "--views", "1"])
        .input_error(&["views"])
        .left_nothing("maps");
    // A user's directory with something in it is not written into.
    std::fs::create_dir(d.join("mine")).unwrap();
    write(&d.join("mine"), "keep.txt", "mine");
    terratile(d, &["saliency", "s.obj", "--out", "mine"]).input_error(&["mine", "not empty"]);
    assert_eq!(std::fs::read_dir(d.join("mine")).unwrap().count(), 1);
}

#[test]
fn saliency_on_a_plane_is_plain_qem() {
    // Curvature and mesh saliency are zero everywhere: the weight is dropped, not divided by.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write(d, "p.obj", &plane_obj(16));
    let base = [
        "simplify",
        "p.obj",
        "",
        "--method",
        "qem",
        "--ratio",
        "0.3",
        "--no-error",
    ];
    let mut plain = base;
    plain[2] = "plain.obj";
    terratile(d, &plain).ok();
    let mut weighted = base.to_vec();
    weighted[2] = "mesh.obj";
    weighted.extend(["--saliency", "mesh"]);
    terratile(d, &weighted).ok();
    assert_eq!(
        std::fs::read(d.join("plain.obj")).unwrap(),
        std::fs::read(d.join("mesh.obj")).unwrap()
    );
}

#[test]
fn saliency_maps_of_cow_are_written() {
    let Some(cow) = common::data_file("meshes/cow.obj") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cow = cow.to_str().unwrap();
    let r = terratile(
        d,
        &[
            "saliency",
            cow,
            "--out",
            "maps",
            "--views",
            "6",
            "--view-size",
            "64",
            "--picture-size",
            "64",
            "--json",
        ],
    );
    r.ok();
    let j: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    assert_eq!(j["vertices"], 2903);
    let classes: u64 = j["classes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_u64().unwrap())
        .sum();
    assert_eq!(classes, 2903);
    let ply = std::fs::read(d.join("maps/saliency.ply")).unwrap();
    let head = String::from_utf8_lossy(&ply[..600]);
    for p in terratile::simplify::saliency::pictures::NAMES {
        assert!(head.contains(&format!("property float {p}\n")), "{head}");
        let png = image::open(d.join(format!("maps/{p}.png"))).unwrap();
        assert_eq!(png.height(), 64);
    }
    // The PLY reads back as the same mesh.
    let back = terratile::mesh::io::read(&d.join("maps/saliency.ply")).unwrap();
    assert_eq!(back.vertex_count(), 2903);
    // Hybrid-weighted QEM runs on it and reaches its target.
    let r = common::simplify(
        d,
        cow,
        "h.obj",
        &[
            "--method",
            "qem",
            "--triangles",
            "580",
            "--saliency",
            "hybrid",
            "--views",
            "6",
            "--view-size",
            "64",
            "--no-error",
            "--json",
        ],
    );
    r.ok();
    let j: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
    assert!(j["triangles_out"].as_u64().unwrap() <= 580);
}

/// `terratile saliency --texture`: a textured grid (one `vt` per vertex) with a red/green
/// texture is baked and mapped; a texture that is not an image and a mesh without UVs are
/// refused with exit code 2 and leave no output directory.
#[test]
fn saliency_bakes_a_texture_and_refuses_bad_ones() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let n = 12;
    let mut obj = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
            let z = 0.1 * (6.0 * x).sin() * (4.0 * y).cos();
            obj += &format!("v {x} {y} {z}\nvt {x} {y}\n");
        }
    }
    let id = |i: usize, j: usize| j * (n + 1) + i + 1;
    let mut faces = String::new();
    let mut bare_faces = String::new();
    for j in 0..n {
        for i in 0..n {
            for t in [
                [id(i, j), id(i + 1, j), id(i + 1, j + 1)],
                [id(i, j), id(i + 1, j + 1), id(i, j + 1)],
            ] {
                faces += &format!("f {0}/{0} {1}/{1} {2}/{2}\n", t[0], t[1], t[2]);
                bare_faces += &format!("f {} {} {}\n", t[0], t[1], t[2]);
            }
        }
    }
    let plain: String = obj
        .lines()
        .filter(|l| l.starts_with("v "))
        .fold(String::new(), |s, l| s + l + "\n");
    std::fs::write(d.join("g.obj"), obj + &faces).unwrap();
    std::fs::write(d.join("bare.obj"), plain + &bare_faces).unwrap();
    let tex = image::RgbImage::from_fn(8, 8, |x, _| {
        if x < 4 {
            image::Rgb([255, 0, 0])
        } else {
            image::Rgb([0, 255, 0])
        }
    });
    tex.save(d.join("t.png")).unwrap();
    std::fs::write(d.join("not.png"), "not an image").unwrap();
    let args = |mesh: &'static str, tex: &'static str, out: &'static str| {
        [
            "saliency",
            mesh,
            "--out",
            out,
            "--views",
            "4",
            "--view-size",
            "32",
            "--picture-size",
            "32",
            "--texture",
            tex,
        ]
    };
    terratile(d, &args("g.obj", "t.png", "maps")).ok();
    assert!(d.join("maps/saliency.ply").is_file());
    let r = terratile(d, &args("g.obj", "not.png", "bad1"));
    r.input_error(&["not.png"]);
    assert!(!d.join("bad1").exists());
    let r = terratile(d, &args("bare.obj", "t.png", "bad2"));
    r.input_error(&["bare.obj", "texture coordinates"]);
    assert!(!d.join("bad2").exists());
}
